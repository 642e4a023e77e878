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
    python benchmarks/bench_peer.py --instructions --duration 500   # callgrind counts instead

``--instructions``: each side runs once in its own child under valgrind's callgrind, counting
only the timed part (the peer's loop; ``simulate`` after a warm-up run) - the same count for
the same code whatever else the machine does (a shared VM moves CPU times by 2x). ~50x slower.
The children import drake_att from the current directory first: to measure another checkout,
run from it, e.g. ``cd /tmp/old && PYTHONPATH=/tmp/old python /path/to/bench_peer.py --instructions``.
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


_CHILD = """
import os, subprocess, sys
sys.path.insert(0, {bench_dir!r})
which, T, seed = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
toggle = lambda state: subprocess.run(["callgrind_control", "-i", state, str(os.getpid())], check=True,
                                      capture_output=True)
if which == "peer":
    import peer_numpy_loop
    peer_numpy_loop.run(min(T, 20.0), seed, 10.0)  # warm-up (imports, first calls)
    toggle("on"); peer_numpy_loop.run(T, seed, 10.0); toggle("off")
else:
    from bench_peer import TEN_HZ
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load
    sd = ScenarioDiagram(apply_overrides(load("cubesat_single_star_tracker"),
                                         [f"duration_s={{T}}", f"scoring.score_from_s={{T / 10}}"] + TEN_HZ))
    sd.simulate(seed)
    toggle("on"); sd.simulate(seed); toggle("off")
"""


def count_instructions(which: str, duration: float, seed: int) -> float:
    """Callgrind's instruction count of one side's timed part (see the module docstring)."""
    import subprocess

    code = _CHILD.format(bench_dir=os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run(["valgrind", "--tool=callgrind", "--instr-atstart=no", "--callgrind-out-file=/dev/null",
                          sys.executable, "-c", code, which, str(duration), str(seed)],
                         capture_output=True, text=True, check=False)
    counts = [line.split(":")[-1] for line in out.stderr.splitlines() if "Collected :" in line]
    if out.returncode != 0 or not counts:
        raise SystemExit(f"{which} under callgrind failed:\n{out.stderr[-2000:]}")
    return float(counts[-1].replace(",", ""))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=5000.0, help="simulated seconds (default 5000)")
    ap.add_argument("--repeats", type=int, default=2, help="best of N (default 2)")
    ap.add_argument("--quick", action="store_true", help="1000 s, 1 repeat")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--instructions", action="store_true",
                    help="count instructions under callgrind instead of timing (deterministic; ~50x slower)")
    a = ap.parse_args(argv)
    if a.quick:
        a.duration, a.repeats = 1000.0, 1
    T, seed = a.duration, a.seed
    if a.instructions:
        peer_n, lib_n = count_instructions("peer", T, seed), count_instructions("drake_att", T, seed)
        steps = round(T * 10)
        print(f"S3 single tracker, gyro/ST/MEKF at 10 Hz, {T:.0f} s ({steps} steps), seed {seed}: instructions "
              f"(callgrind)\n{'peer':<10} {peer_n / 1e9:8.3f} G  ({peer_n / steps / 1e3:.0f} k per step)\n"
              f"{'drake_att':<10} {lib_n / 1e9:8.3f} G  ({lib_n / steps / 1e3:.0f} k per step)\n"
              f"ratio drake_att / peer: {lib_n / peer_n:.2f}")
        return
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
