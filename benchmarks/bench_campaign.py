#!/usr/bin/env python3
"""Campaign throughput: runs per CPU-second of ``drake-att montecarlo`` as a whole process
(imports, start-up, the runs, their records, the summary and the report), for one or two
checkouts in one run, with their records and statistics compared bit for bit::

    git worktree add --detach /tmp/wt_old <old commit>
    .venv/bin/python benchmarks/bench_campaign.py --old /tmp/wt_old              # 20 runs x 2 cases
    .venv/bin/python benchmarks/bench_campaign.py --runs 4 --duration 1000       # quick, this checkout only
    .venv/bin/python benchmarks/bench_campaign.py --old /tmp/wt_old --case ten_hz --report   # and the report's CPU

Cases (``bench_peer.py``'s):

* ``single``: ``cubesat_single_star_tracker`` as shipped (gyro 1 Hz, tracker 10 Hz, MEKF 1 Hz);
* ``ten_hz``: the same with the gyro, the tracker and the MEKF at 10 Hz;
* ``dual`` (``--case dual`` or ``all``): ``cubesat_dual_star_tracker`` as shipped (paper S3's
  five estimators).

Each campaign is a child ``python -m drake_att.cli montecarlo CASE --workers 1`` (serial: the
Dask workers run the very same per-run code) in the checkout's directory with
``PYTHONPATH`` set to it; its CPU is the child's user + system time (``os.wait4``). Before the
timed campaigns each checkout runs a 2-run 20-s one (numba's on-disk kernel cache, first imports).
Sides alternate within each round. Printed per case: CPU seconds per side, runs per
CPU-second, new / old, and whether every record (``runs/seed_*.npz``; the metrics' wall time
aside) and ``summary.json`` (the campaign's wall time and folder paths aside) are identical.
With ``--report``, each side also resumes a copy of the new side's campaign with every run
saved: its CPU is start-up, reading the records, the summary and the report.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CASES = {
    "single": [],
    "ten_hz": ["sensors.gyro.period_s=0.1", "sensors.st1.period_s=0.1", "estimators.single.period_s=0.1"],
    "dual": [],
}
SCENARIO = {"single": "cubesat_single_star_tracker", "ten_hz": "cubesat_single_star_tracker"}
DEFAULT_CASES = ("single", "ten_hz")  # "dual": --case dual or all


def campaign(tree: str, case: str, runs: int, duration: float | None, out: str, resume: bool = False) -> float:
    """Runs one serial campaign of ``case`` from checkout ``tree`` into ``out`` (``resume``: the
    campaign saved there, ``--resume``); returns its process CPU seconds (user + system). A
    ``duration`` below 1000 s scores from its middle."""
    sets = list(CASES[case])
    if duration:
        sets += [f"duration_s={duration:g}"] + ([f"scoring.score_from_s={duration / 2:g}"] if duration < 1000 else [])
    scenario = SCENARIO.get(case, "cubesat_dual_star_tracker")
    cmd = [sys.executable, "-m", "drake_att.cli", "montecarlo", scenario, "--runs", str(runs), "--workers", "1"]
    cmd += ["--out", out, "--quiet"] + [a for s in sets for a in ("--set", s)] + (["--resume"] if resume else [])
    env = dict(os.environ, PYTHONPATH=tree, MPLBACKEND="Agg")
    proc = subprocess.Popen(cmd, cwd=tree, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    err = proc.stderr.read() if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"campaign {case} in {tree} failed:\n{err}")
    return usage.ru_utime + usage.ru_stime


def report_only(tree: str, case: str, runs: int, duration: float | None, saved: str, out: str) -> float:
    """CPU seconds of ``campaign`` resumed from a copy of the runs saved in ``saved`` (every
    run reused): start-up, reading the records, the summary and the report."""
    os.makedirs(out)
    for name in ("config.yaml", "campaign.json"):
        shutil.copy(os.path.join(saved, name), out)
    shutil.copytree(os.path.join(saved, "runs"), os.path.join(out, "runs"))
    return campaign(tree, case, runs, duration, out, resume=True)


def _record_values(path: str) -> dict:
    with np.load(path, allow_pickle=False) as z:
        out = {k: np.asarray(z[k]) for k in z.files}
    metrics = json.loads(str(out["metrics_json"]))
    metrics.pop("wall_time_s", None)
    out["metrics_json"] = np.array(json.dumps(metrics, sort_keys=True))
    return out


def _summary_values(folder: str) -> dict:
    with open(os.path.join(folder, "summary.json")) as f:
        text = f.read().replace(folder, "<folder>")
    summary = json.loads(text)
    for part in (summary, summary.get("campaign", {})):
        part.pop("wall_time_s_of_last_call", None)
    return summary


def differences(a: str, b: str) -> list[str]:
    """What differs between two campaign folders' records and statistics (empty: identical)."""
    runs_a, runs_b = sorted(os.listdir(os.path.join(a, "runs"))), sorted(os.listdir(os.path.join(b, "runs")))
    if runs_a != runs_b:
        return [f"run files {runs_a} vs {runs_b}"]
    out = []
    for name in runs_a:
        ra, rb = _record_values(os.path.join(a, "runs", name)), _record_values(os.path.join(b, "runs", name))
        if ra.keys() != rb.keys():
            out.append(f"{name}: keys {sorted(set(ra) ^ set(rb))}")
            continue
        for k in ra:
            x, y = ra[k], rb[k]
            if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
                out.append(f"{name}: {k}")
    out += [f"summary.json: {path}" for path in _paths_that_differ(_summary_values(a), _summary_values(b))]
    return out


def _paths_that_differ(x, y, path: str = "") -> list[str]:
    if isinstance(x, dict) and isinstance(y, dict):
        keys = sorted(set(x) | set(y))
        return [p for k in keys for p in _paths_that_differ(x.get(k), y.get(k), f"{path}/{k}")]
    if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
        return [p for i, (u, v) in enumerate(zip(x, y, strict=True)) for p in _paths_that_differ(u, v, f"{path}[{i}]")]
    return [] if x == y else [f"{path}: {x!r} vs {y!r}"[:200]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", help="another checkout (a git worktree) to compare with")
    ap.add_argument("--new", default=HERE, help="this checkout (default: the one this script is in)")
    ap.add_argument("--case", choices=(*CASES, "both", "all"), default="both", help="both: single and ten_hz")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds per run (default: shipped 5000)")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument(
        "--report", action="store_true", help="also each side's campaign resumed with every run saved (summary, report)"
    )
    args = ap.parse_args(argv)
    if args.runs < 1 or args.rounds < 1 or (args.duration is not None and not args.duration > 0):
        ap.error(f"--runs {args.runs}, --rounds {args.rounds}, --duration {args.duration}: need >= 1, >= 1, > 0")
    sides = {"new": os.path.abspath(args.new)}
    if args.old:
        if not os.path.isdir(os.path.join(args.old, "drake_att")):
            ap.error(f"--old {args.old!r}: not a drake_att checkout (no drake_att/ in it)")
        sides = {"old": os.path.abspath(args.old), **sides}
    cases = {"both": list(DEFAULT_CASES), "all": list(CASES)}.get(args.case, [args.case])
    with tempfile.TemporaryDirectory(prefix="bench_campaign_") as tmp:
        for side, tree in sides.items():
            # two runs: a batch's kernels are compiled (or loaded) here too, not in a timed campaign
            campaign(tree, "single", 2, 20.0, os.path.join(tmp, f"warm_{side}"))
        for case in cases:
            cpu: dict = {side: [] for side in sides}
            for r in range(args.rounds):
                order = list(sides) if r % 2 == 0 else list(reversed(sides))
                for side in order:
                    out = os.path.join(tmp, f"{case}_{side}_{r}")
                    cpu[side].append(campaign(sides[side], case, args.runs, args.duration, out))
            best = {side: min(v) for side, v in cpu.items()}
            line = ", ".join(
                f"{side} {best[side]:.2f} s ({args.runs / best[side]:.3f} runs/CPU-s; rounds {' '.join(f'{c:.2f}' for c in cpu[side])})"
                for side in sides
            )
            print(f"{case}: {args.runs} runs of {args.duration or 5000:g} s: {line}")
            if args.old:
                diff = differences(os.path.join(tmp, f"{case}_old_0"), os.path.join(tmp, f"{case}_new_0"))
                verdict = "records and summary identical" if not diff else f"DIFFER: {diff[:6]}"
                print(f"  throughput new / old: {best['old'] / best['new']:.2f}x; {verdict}")
            if args.report:
                saved = os.path.join(tmp, f"{case}_new_0")  # the same records for both sides
                report = {
                    side: report_only(
                        tree, case, args.runs, args.duration, saved, os.path.join(tmp, f"{case}_{side}_resumed")
                    )
                    for side, tree in sides.items()
                }
                print("  resumed, every run saved: " + ", ".join(f"{side} {c:.2f} s" for side, c in report.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
