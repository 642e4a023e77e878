#!/usr/bin/env python3
"""drake_att against a plain-numpy peer loop: the S3 single-tracker case at 10 Hz.

In one process: (a) ``benchmarks/peer_numpy_loop.py`` (hand-written numpy loop, same models)
and (b) drake_att's ``cubesat_single_star_tracker`` with the gyro, the tracker and the MEKF
at 10 Hz (truth by fixed-step RK3 at 0.1 s, as shipped). CPU time (``time.process_time``) of
the peer's loop and of ``ScenarioDiagram.simulate(seed)`` alone (the diagram's build time is
reported separately), best of ``--repeats``; the ratio drake_att / peer; both attitude RMSEs
per axis after 500 s (different random streams: they must agree in class, not in digits).

    python benchmarks/bench_peer.py             # 5000 s, best of 2
    python benchmarks/bench_peer.py --quick     # 1000 s, 1 repeat
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import peer_numpy_loop  # noqa: E402
from drake_att.analysis.metrics import compute_metrics  # noqa: E402
from drake_att.scenarios.builder import ScenarioDiagram  # noqa: E402
from drake_att.scenarios.config import apply_overrides  # noqa: E402
from drake_att.scenarios.library import load  # noqa: E402

TEN_HZ = ["sensors.gyro.period_s=0.1", "sensors.st1.period_s=0.1", "estimators.single.period_s=0.1"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=5000.0, help="simulated seconds (default 5000)")
    ap.add_argument("--repeats", type=int, default=2, help="best of N (default 2)")
    ap.add_argument("--quick", action="store_true", help="1000 s, 1 repeat")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    if a.quick:
        a.duration, a.repeats = 1000.0, 1
    T, seed = a.duration, a.seed
    print(f"S3 single tracker, gyro/ST/MEKF at 10 Hz, {T:.0f} s, seed {seed}, best of {a.repeats} (CPU s)")

    peer_runs = [peer_numpy_loop.run(T, seed, 10.0) for _ in range(a.repeats)]
    peer = min(peer_runs, key=lambda r: r["cpu_s"])

    scenario = apply_overrides(load("cubesat_single_star_tracker"), [f"duration_s={T}"] + TEN_HZ)
    c0 = time.process_time()
    sd = ScenarioDiagram(scenario)
    build = time.process_time() - c0
    lib_cpu, run = [], None
    for _ in range(a.repeats):
        c0 = time.process_time()
        run = sd.simulate(seed)
        lib_cpu.append(time.process_time() - c0)
    m = compute_metrics(run)["estimators"]["single"]
    lib = min(lib_cpu)

    fmt = lambda v: " ".join(f"{x:.2e}" for x in v)  # noqa: E731
    print(f"{'':<10} {'CPU (s)':>9}  {'RMSE x/y/z after ' + str(int(scenario.scoring.score_from_s)) + ' s (deg)':>32}")
    print(f"{'peer':<10} {peer['cpu_s']:9.2f}  {fmt(peer['rmse_deg']):>32}   ({peer['steps']} steps, "
          f"{peer['gate_rejections']} gate rejections)")
    print(f"{'drake_att':<10} {lib:9.2f}  {fmt(m['attitude_rmse_deg']):>32}   (simulate only; build "
          f"{build:.2f} s; {m['measurements_used']} used / {m['measurements_skipped']} skipped)")
    peer_all = ", ".join(f"{r['cpu_s']:.2f}" for r in peer_runs)
    lib_all = ", ".join(f"{c:.2f}" for c in lib_cpu)
    print(f"ratio drake_att / peer: {lib / peer['cpu_s']:.1f}  (all CPU times: peer {peer_all}; drake_att {lib_all})")
    ratios = [x / y for x, y in zip(m["attitude_rmse_deg"], peer["rmse_deg"])]
    same_class = all(0.5 <= r <= 2.0 for r in ratios)
    print(f"RMSE drake_att / peer per axis: {' '.join(f'{r:.2f}' for r in ratios)} -> "
          + ("same class (within a factor 2 per axis; different random streams)" if same_class
             else "NOT the same class (a factor > 2 on some axis): check the models"))


if __name__ == "__main__":
    main()
