#!/usr/bin/env python3
"""A/B speed of two checkouts of drake_att on the same cases, in one run, as ratios.

    git worktree add /tmp/drake_att_old <old commit>
    .venv/bin/python benchmarks/bench_ab.py --old /tmp/drake_att_old [--new .] [--rounds 3] [--clock cpu|wall|instructions] [--repeats 3]

Each measurement is a fresh interpreter with ``PYTHONPATH`` pointing at one checkout: it
builds the case's diagram, runs it once (warm-up, seed 1), then times ``simulate`` for
seed 2. Each round measures old then new back to back, so drifting machine load hits both
alike; reported: the best time of each, the ratio of the bests, and the median of the
per-round ratios with its range (below 1: new is faster). On a shared VM single rounds
scatter by 10-30%: read the median over several rounds.

``--clock instructions`` counts the machine instructions of the timed ``simulate`` instead
(valgrind's callgrind, switched on for that call only with ``callgrind_control``): the same
count for the same code and inputs whatever else the machine is doing, so one round
suffices (a VM shared with other jobs scatters CPU times by 2x; instruction counts do not
see that). It is no clock: a cache miss and an add count alike; use it for A/B ratios.

Cases: the default scenario (S3 dual tracker, 4 MEKFs + fusion, 1 Hz) and the S3 single
tracker with gyro, tracker and MEKF all at 10 Hz, each over ``--duration`` seconds.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

CASES = {
    "default (S3 dual tracker, 1 Hz)": ("cubesat_dual_star_tracker", []),
    "S3 single tracker, 10 Hz gyro + ST + MEKF": (
        "cubesat_single_star_tracker",
        [
            "simulation.integration_scheme=runge_kutta3",
            "simulation.use_error_control=false",
            "simulation.max_step_size_s=0.1",
            "sensors.gyro.period_s=0.1",
            "sensors.st1.period_s=0.1",
            "estimators.single.period_s=0.1",
        ],
    ),
}

CHILD = """
import sys, time
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import load
clock_name, repeats, name, duration, *over = sys.argv[1:]
clock = time.process_time if clock_name == "cpu" else time.perf_counter
s = apply_overrides(load(name), [f"duration_s={duration}", f"scoring.score_from_s={float(duration) / 10}"] + over)
sd = ScenarioDiagram(s)
sd.simulate(seed=1)
if clock_name == "instructions":  # under valgrind --tool=callgrind --instr-atstart=no
    import os, subprocess
    subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], check=True, capture_output=True)
    sd.simulate(seed=2)
    subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], check=True, capture_output=True)
    print("instrumented")
    raise SystemExit(0)
best = float("inf")
for k in range(int(repeats)):
    t0 = clock()
    sd.simulate(seed=2 + k)
    best = min(best, clock() - t0)
print(best)
"""


def measure(checkout: str, scenario: str, duration: float, overrides, clock: str = "cpu", repeats: int = 1) -> float:
    env = dict(os.environ, PYTHONPATH=os.path.abspath(checkout), MPLBACKEND="Agg")
    command = [sys.executable, "-c", CHILD, clock, str(repeats), scenario, str(duration), *overrides]
    if clock == "instructions":
        command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--callgrind-out-file=/dev/null"] + command
    out = subprocess.run(command, env=env, capture_output=True, text=True, cwd=os.path.abspath(checkout))
    if out.returncode != 0:
        raise SystemExit(f"{checkout}: {scenario} failed:\n{out.stderr[-2000:]}")
    if clock == "instructions":
        counts = [line.split(":")[-1] for line in out.stderr.splitlines() if "Collected :" in line]
        if not counts:
            raise SystemExit(f"{checkout}: {scenario}: no callgrind count in:\n{out.stderr[-2000:]}")
        return float(counts[-1].replace(",", "")) / 1e9  # giga-instructions
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--old", required=True, help="checkout of the reference commit (git worktree)")
    ap.add_argument("--new", default=os.path.join(os.path.dirname(__file__), os.pardir))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=1000.0, help="simulated seconds per case")
    ap.add_argument(
        "--clock",
        choices=("cpu", "wall", "instructions"),
        default="cpu",
        help="cpu: the child's process time; wall; instructions: callgrind's count of the "
        "timed simulate (deterministic; needs valgrind; ~50x slower)",
    )
    ap.add_argument("--repeats", type=int, default=1, help="timed runs per child (seeds 2, 3, ...; the best is kept)")
    args = ap.parse_args(argv)
    print(
        f"old: {os.path.abspath(args.old)}\nnew: {os.path.abspath(args.new)}\n"
        f"{args.rounds} alternating rounds, {args.duration:.0f} s simulated per case, best of {args.repeats} "
        f"{args.clock} time(s) per child shown"
    )
    unit = "G instr" if args.clock == "instructions" else "s"
    print(
        f"{'case':<45} {'old (' + unit + ')':>11} {'new (' + unit + ')':>11} {'best/best':>9} {'median ratio [range]':>24}"
    )
    for label, (scenario, overrides) in CASES.items():
        old, new = [], []
        for _ in range(args.rounds):
            old.append(measure(args.old, scenario, args.duration, overrides, args.clock, args.repeats))
            new.append(measure(args.new, scenario, args.duration, overrides, args.clock, args.repeats))
        ratios = sorted(n / o for n, o in zip(new, old, strict=True))
        median = (
            ratios[len(ratios) // 2]
            if len(ratios) % 2
            else 0.5 * (ratios[len(ratios) // 2 - 1] + ratios[len(ratios) // 2])
        )
        print(
            f"{label:<45} {min(old):11.3f} {min(new):11.3f} {min(new) / min(old):9.3f} "
            f"{median:10.3f} [{ratios[0]:.2f}, {ratios[-1]:.2f}]"
        )


if __name__ == "__main__":
    main()
