#!/usr/bin/env python3
"""The floor of this design, measured: the same diagram with none of our Python computing.

Issue 13 asks for the 10 Hz single-tracker case at <= 0.35x a plain numpy loop's cost and the
default scenario >= 3x faster than before its work. This script measures what any change of
our code can reach on this design (pydrake 1.51.1 from PyPI: Python ``LeafSystem``s, a
``SymbolicVectorSystem`` truth, no C++ SDK to write systems in C++), by counting callgrind
instructions of the timed ``simulate`` (or of the peer's loop) for these sides of one case:

* ``peer``: the plain-numpy peer loop of ``bench_peer.py`` (``ten_hz`` and ``default`` only).
* ``drake``: drake_att as shipped.
* ``null``: the very same diagram (same systems, ports, events, loggers, integrator), with
  every Python callback of ours replaced by one that only does what the framework demands of
  it: it reads the same input ports (``HasValue`` / ``Eval``), reads the filter's parameter,
  takes the same writable state views and writes its output — and computes nothing (the
  tracker passes the true attitude through, the gyro and the filters write constants). What is
  left is the truth's integration, the C++ loggers and event dispatch, and the pybind11
  crossings and port reads of our Python systems: what remains if all of our own Python took
  zero time.
* ``truth``: only the truth plant, its torque source and its two loggers, same integrator.

    python benchmarks/bench_floor.py                      # ten_hz and default, 100 s (~6 min)
    python benchmarks/bench_floor.py --case ten_hz --duration 200

The figures go in benchmarks/README.md ("Issue 13 (speed): where it stands").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import bench_peer  # noqa: E402

SIDES = ("peer", "drake", "null", "truth")
CASES = ("ten_hz", "default")
GOAL = {"ten_hz": "<= 0.35x the peer", "default": ">= 3x faster than 66110b6 (<= 0.33x its count)"}


# --- the null callbacks: port reads and writes, no computation --------------------------------
def install_null_callbacks() -> None:
    """Replace our Python callbacks by null ones (before any diagram is built: Drake keeps
    the bound methods it is given at declaration)."""
    import numpy as np
    from pydrake.systems.framework import EventStatus

    from drake_att.systems import estimator_system, fusion, gyro, star_tracker

    def tracker(self, context, output):
        q = self._q_port.Eval(context)  # the read the real callback does
        t = context.get_time()
        output.SetFromVector(np.array([t, 1.0, q[0], q[1], q[2], q[3]]))

    def gyro_out(self, context, output):
        t = context.get_time()
        if self._integral_port.HasValue(context):
            self._integral_port.Eval(context)
            self._held_port.Eval(context)
        self._scale_error_port.HasValue(context)
        output.SetFromVector(np.array([t, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))

    def estimator_step(self, context, discrete_state):
        self.filter_model(context)
        context.get_time()
        if self._gyro_port.HasValue(context):
            self._gyro_port.Eval(context)
        for port in self._quat_ports:
            if port.HasValue(context):
                port.Eval(context)
        group = discrete_state.get_mutable_value
        for g in (
            self._innovation_group,
            self._estimate_group,
            self._book_group,
            self._core_group,
            self._linearization_group,
        ):
            if g is not None:
                group(g)
        return EventStatus.Succeeded()

    def average(self, context, output):
        m = [p.Eval(context) for p in self._ports]
        output.SetFromVector(np.array([m[0][0], 1.0, 1.0, 0.0, 0.0, 0.0]))

    def fusion_estimate(self, context, output):
        for ports in (self._status_ports, self._q_ports, self._second_ports, self._cov_ports):
            for p in ports:
                p.Eval(context)
        if self.covariance_model == "tracked":
            context.get_discrete_state(self._cross_index).value()
            for p in self._lin_ports:
                p.Eval(context)
        x = np.zeros(fusion.ESTIMATE_SIZE)
        x[0] = 1.0
        output.SetFromVector(x)

    def fusion_advance(self, context, discrete_state):
        context.get_discrete_state(self._cross_index).value()
        for p in self._lin_ports:
            p.Eval(context)
        discrete_state.get_mutable_vector(self._cross_group).get_mutable_value()
        return EventStatus.Succeeded()

    star_tracker.StarTracker._calc_quaternion = tracker
    gyro._GyroOutputs._calc_measurement = gyro_out
    estimator_system.EstimatorSystem._on_step = estimator_step
    fusion.StarTrackerAverage._calc = average
    fusion.EstimateFusion._calc_estimate_state = fusion_estimate
    fusion.EstimateFusion._advance_cross = fusion_advance


# --- the truth alone ----------------------------------------------------------------------------
def truth_only(case: str, duration: float):
    """A ``simulate(seed)`` callable running the case's truth plant, torque and two loggers."""
    import numpy as np
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

    from drake_att.systems.plant import RigidBodyAttitudePlant
    from drake_att.units import DEG

    scenario = bench_peer.drake_scenario(case, duration)
    p, sc = scenario.plant, scenario.simulation
    builder = DiagramBuilder()
    truth = builder.AddSystem(RigidBodyAttitudePlant(np.asarray(p.inertia_kg_m2, dtype=float)))
    torque = builder.AddSystem(ConstantVectorSource(np.asarray(p.disturbance_torque_N_m, dtype=float)))
    builder.Connect(torque.get_output_port(), truth.GetInputPort("torque_B"))
    for port in ("q_IB", "w_IB_B"):
        LogVectorOutput(truth.GetOutputPort(port), builder, 0.1)
    diagram = builder.Build()

    def simulate(seed):
        context = diagram.CreateDefaultContext()
        truth.SetInitialState(
            truth.GetMyMutableContextFromRoot(context),
            np.array([1.0, 0.0, 0.0, 0.0]),
            np.asarray(p.initial_rate_deg_per_s) * DEG,
        )
        simulator = Simulator(diagram, context)
        ApplySimulatorConfig(
            SimulatorConfig(
                integration_scheme=sc.integration_scheme,
                max_step_size=sc.max_step_size_s,
                accuracy=sc.accuracy,
                use_error_control=sc.use_error_control,
                target_realtime_rate=0.0,
                publish_every_time_step=False,
            ),
            simulator,
        )
        simulator.Initialize()
        simulator.AdvanceTo(duration)

    return simulate


# --- one side, in a callgrind child --------------------------------------------------------------
_CHILD = """
import json, os, subprocess, sys
sys.path.insert(0, sys.argv[1])
import bench_floor
toggle = lambda state: subprocess.run(["callgrind_control", "-i", state, str(os.getpid())], check=True,
                                      capture_output=True)
print("RESULT " + json.dumps(bench_floor.child_run(sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5]), toggle)))
"""


def child_run(case: str, side: str, duration: float, seed: int, toggle) -> dict:
    if side == "peer":
        return bench_peer.child_run(case, "peer", duration, seed, "numba", toggle)
    if side == "truth":
        simulate = truth_only(case, duration)
        simulate(seed)  # warm-up
        toggle("on")
        simulate(seed)
        toggle("off")
        return {}
    if side == "null":
        install_null_callbacks()
    sd, _ = bench_peer.build_diagram(case, duration)
    bench_peer.warm_up_drake(case, sd, seed)
    toggle("on")
    sd.simulate(seed)
    toggle("off")
    return {}


def count(case: str, side: str, duration: float, seed: int) -> float:
    """Callgrind's instruction count of one side's timed part."""
    out = subprocess.run(
        [
            "valgrind",
            "--tool=callgrind",
            "--instr-atstart=no",
            "--callgrind-out-file=/dev/null",
            sys.executable,
            "-c",
            _CHILD,
            os.path.dirname(os.path.abspath(__file__)),
            case,
            side,
            str(duration),
            str(seed),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    counts = [line.split(":")[-1] for line in out.stderr.splitlines() if "Collected :" in line]
    if out.returncode != 0 or not counts or not any(line.startswith("RESULT ") for line in out.stdout.splitlines()):
        raise SystemExit(f"{case} {side} under callgrind failed:\n{out.stderr[-3000:]}")
    return float(counts[-1].replace(",", ""))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", choices=CASES + ("all",), default="all")
    ap.add_argument("--duration", type=float, default=100.0, help="simulated seconds per side (default 100)")
    ap.add_argument("--seed", type=int, default=2)
    a = ap.parse_args(argv)
    cases = CASES if a.case == "all" else (a.case,)
    summary = {}
    for case in cases:
        steps = round(a.duration / bench_peer.STEP_S[case])
        counts = {side: count(case, side, a.duration, a.seed) for side in SIDES}
        summary[case] = counts
        peer = counts["peer"]
        print(
            f"\n{bench_peer.title(case)}, {a.duration:.0f} s ({steps} steps of 0.1 s), seed {a.seed}; "
            f"callgrind instructions of the timed part"
        )
        print(f"{'side':<8} {'10^6 instr':>11} {'per step':>10} {'/ peer':>8} {'/ drake':>8}")
        for side in SIDES:
            c = counts[side]
            print(f"{side:<8} {c / 1e6:11.1f} {c / steps / 1e3:9.0f}k {c / peer:8.3f} {c / counts['drake']:8.3f}")
        print(
            f"goal: {GOAL[case]}. null / peer = {counts['null'] / peer:.3f}: no change of our Python code "
            f"can go below this on this design; truth alone / peer = {counts['truth'] / peer:.3f}."
        )
    print("\nRESULT " + json.dumps(summary))


if __name__ == "__main__":
    main()
