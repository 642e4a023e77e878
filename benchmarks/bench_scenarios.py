#!/usr/bin/env python3
"""Time the shipped scenarios and show where the time goes.

Prints, for each case: wall time of one simulation (best of ``--repeat``), simulated
seconds per wall second, and number of Python events.  Then the accuracy/speed trade-off
of the truth integrator, and a cProfile breakdown of the 10 Hz case.

    python benchmarks/bench_scenarios.py            # full (5000 s runs)
    python benchmarks/bench_scenarios.py --quick    # 1000 s runs

Figures are compared as ratios within one run of this script (same machine, same load);
no test asserts a time.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time

import numpy as np

from drake_att import rotations as rot
from drake_att.noise import DEG
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import load

TEN_HZ = ["sensors.gyro.period_s=0.1", "sensors.st1.period_s=0.1", "estimators.single.period_s=0.1"]


def time_case(label, scenario, repeat):
    sd = ScenarioDiagram(scenario)
    walls = []
    for k in range(repeat):
        t0 = time.perf_counter()
        run = sd.simulate(seed=1 + k)
        walls.append(time.perf_counter() - t0)
    best = min(walls)
    print(
        f"{label:<58} {scenario.duration_s:7.0f} s  wall {best:6.2f} s  {scenario.duration_s / best:8.0f} sim-s/wall-s"
    )
    return best, run


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="1000 s instead of 5000 s")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)
    T = 1000.0 if args.quick else 5000.0
    dur = [f"duration_s={T}", f"scoring.score_from_s={T / 10}"]
    print(f"== Scenario wall times (best of {args.repeat}) ==")
    single = apply_overrides(load("cubesat_single_star_tracker"), dur)
    dual = apply_overrides(load("cubesat_dual_star_tracker"), dur)
    results = {}
    results["default"] = time_case("default: S3 dual tracker, 4 estimators + fusion (1 Hz)", dual, args.repeat)[0]
    rk5 = apply_overrides(
        single,
        [
            "simulation.integration_scheme=runge_kutta5",
            "simulation.accuracy=1e-10",
            "simulation.use_error_control=true",
            "simulation.max_step_size_s=1.0",
        ],
    )
    results["single"] = time_case("S3 single tracker (gyro 1 Hz, ST 10 Hz, MEKF 1 Hz), RK5 1e-10", rk5, args.repeat)[0]
    fast = apply_overrides(
        single,
        [
            "simulation.integration_scheme=runge_kutta3",
            "simulation.use_error_control=false",
            "simulation.max_step_size_s=0.1",
        ],
    )
    results["single_rk3"] = time_case("  same, truth by fixed-step RK3 (0.1 s) [shipped setting]", fast, args.repeat)[0]
    ten = apply_overrides(fast, TEN_HZ)
    results["ten_hz"] = time_case("S3 single tracker at 10 Hz gyro, ST and MEKF (RK3 0.1 s)", ten, args.repeat)[0]
    dual_ten = apply_overrides(
        dual,
        ["sensors.gyro.period_s=0.1"]
        + [f"estimators.{n}.period_s=0.1" for n in ("single", "centralized", "single_st2", "joint")],
    )
    results["default_ten_hz"] = time_case("default at 10 Hz gyro and all 4 MEKFs", dual_ten, args.repeat)[0]

    print("\n== Truth integrator: accuracy vs speed (S3 single tracker) ==")
    ref = apply_overrides(
        single,
        [
            "simulation.integration_scheme=runge_kutta5",
            "simulation.accuracy=1e-12",
            "simulation.use_error_control=true",
        ],
    )
    _, ref_run = time_case("reference: runge_kutta5, accuracy 1e-12", ref, 1)
    q_ref = ref_run.values("rigid_body_plant/q_IB")
    for label, over in [
        (
            "runge_kutta5, error-controlled 1e-10",
            ["simulation.integration_scheme=runge_kutta5", "simulation.accuracy=1e-10"],
        ),
        (
            "runge_kutta3, fixed 0.1 s",
            [
                "simulation.integration_scheme=runge_kutta3",
                "simulation.use_error_control=false",
                "simulation.max_step_size_s=0.1",
            ],
        ),
        (
            "runge_kutta2, fixed 0.1 s",
            [
                "simulation.integration_scheme=runge_kutta2",
                "simulation.use_error_control=false",
                "simulation.max_step_size_s=0.1",
            ],
        ),
    ]:
        s = apply_overrides(single, over)
        wall, run = time_case(label, s, 1)
        err = np.linalg.norm(rot.quat_error_rotvec(q_ref, run.values("rigid_body_plant/q_IB")), axis=1).max()
        print(f"    max truth attitude difference vs reference: {err / DEG:.2e} deg")

    print("\n== Where the time goes: 10 Hz case, 1000 s, cProfile (top by own time) ==")
    prof_s = apply_overrides(ten, ["duration_s=1000", "scoring.score_from_s=100"])
    sd = ScenarioDiagram(prof_s)
    pr = cProfile.Profile()
    pr.enable()
    sd.simulate(seed=1)
    pr.disable()
    buf = io.StringIO()
    stats = pstats.Stats(pr, stream=buf).sort_stats("tottime")
    total = stats.total_tt
    stats.print_stats(12)
    print(buf.getvalue().split("\n", 6)[-1][:3500])
    own = {k: v for k, v in stats.stats.items()}
    advance = sum(v[2] for k, v in own.items() if k[2] == "<built-in method pydrake.systems.analysis.AdvanceTo>")
    print(
        f"total {total:.2f} s; inside AdvanceTo but not in Python callbacks (C++ integrator, event dispatch, "
        f"loggers): {advance:.2f} s ({100 * advance / total:.0f}%)"
    )
    print("\n== Ratios ==")
    print(
        f"default (4 estimators + fusion) / single (both RK3 fixed): {results['default'] / results['single_rk3']:.2f}"
    )
    print(f"single RK3 fixed / single RK5 error-controlled: {results['single_rk3'] / results['single']:.2f}")
    print(f"10 Hz everything / 1 Hz filter: {results['ten_hz'] / results['single_rk3']:.2f}")


if __name__ == "__main__":
    main()
