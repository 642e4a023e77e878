#!/usr/bin/env python3
"""Memory of a run's logs: peak RSS per simulated second, with and without a logging policy.

Each case runs in a fresh subprocess (one build, one ``simulate``) and reports, from inside
that child: ``ru_maxrss`` (``resource.getrusage(RUSAGE_SELF)``: the process's peak resident
set, KB on Linux) after the build and after the run, the bytes of the logged arrays the
run returned (``RunLog.signals``: times and values), and the size of the ``log.npz`` the
result folder would hold (``RunLog.to_npz_dict`` written with ``numpy.savez_compressed``,
as :func:`drake_att.analysis.report.write_results` does). The per-second figures are slopes
between two durations (so the build and the imports cancel):

    slope = (peak RSS(long) - peak RSS(short)) / (long - short)   [KB per simulated s]

    python benchmarks/bench_memory.py                      # dual tracker, 600 s and 3000 s
    python benchmarks/bench_memory.py --durations 600 6000 --policy "{period_s: 10.0}"

Drake's ``VectorLogSink`` keeps its samples in an Eigen matrix that starts with room for
1000 samples and doubles when full, so a logger holds between 1x and 2x its samples: the
RSS slope between two durations is steppy; the logged-array bytes are the exact figure.
No test asserts a figure.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, os, resource, sys, tempfile
import numpy as np
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import ScenarioDiagram

path, duration, policy = sys.argv[1], float(sys.argv[2]), sys.argv[3]
overrides = [f"duration_s={duration}", "scoring.score_from_s=0"] + ([f"logging={policy}"] if policy else [])
scenario = cfg.apply_overrides(cfg.load_scenario(filename=path), overrides)
sd = ScenarioDiagram(scenario)
built_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
run = sd.simulate()
peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
arrays = sum(t.nbytes + x.nbytes for t, x in run.signals.values())
with tempfile.TemporaryDirectory() as d:
    np.savez_compressed(os.path.join(d, "log.npz"), **run.to_npz_dict())
    npz = os.path.getsize(os.path.join(d, "log.npz"))
print(json.dumps({"built_kb": built_kb, "peak_kb": peak_kb, "arrays": arrays, "npz": npz, "wall": run.wall_time_s}))
"""


def run_case(path: str, duration: float, policy: str) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.getcwd(), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run(
        [sys.executable, "-c", CHILD, path, str(duration), policy],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="drake_att/scenarios/cubesat_dual_star_tracker.yaml")
    parser.add_argument("--durations", type=float, nargs=2, default=[600.0, 3000.0], metavar=("SHORT", "LONG"))
    parser.add_argument(
        "--policy", action="append", default=None, help='a logging section, e.g. "{period_s: 10.0}" (repeatable)'
    )
    args = parser.parse_args(argv)
    policies = [""] + (args.policy or ["{period_s: 10.0}"])
    short, long = args.durations
    print(f"{args.scenario}: peak RSS (ru_maxrss of the child) and log sizes, {short:g} s and {long:g} s simulated")
    header = (
        f"{'logging':<22} {'RSS short MB':>12} {'RSS long MB':>11} {'RSS KB/s':>9} {'arrays KB/s':>11} "
        f"{'npz KB/s':>9} {'24 h RSS GB':>11}"
    )
    print(header)
    print("-" * len(header))
    for policy in policies:
        try:
            a, b = run_case(args.scenario, short, policy), run_case(args.scenario, long, policy)
        except subprocess.CalledProcessError as e:
            print(f"{policy:<22} failed: {(e.stderr.strip().splitlines() or ['?'])[-1]}")
            continue
        rss_slope = (b["peak_kb"] - a["peak_kb"]) / (long - short)
        array_slope = (b["arrays"] - a["arrays"]) / 1024 / (long - short)
        npz_slope = (b["npz"] - a["npz"]) / 1024 / (long - short)
        day = (b["peak_kb"] + rss_slope * (86400 - long)) / 2**20
        print(
            f"{policy or '(default)':<22} {a['peak_kb'] / 1024:12.0f} {b['peak_kb'] / 1024:11.0f} {rss_slope:9.2f} "
            f"{array_slope:11.2f} {npz_slope:9.2f} {day:11.2f}"
        )
    print(
        "KB/s: per simulated second, slope between the two durations; 24 h RSS: the long run's peak extrapolated "
        "linearly (the VectorLogSink doubling makes the real peak up to 2x the arrays' share)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
