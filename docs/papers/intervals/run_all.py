#!/usr/bin/env python3
"""Run the 30-seed computations behind ``docs/papers/intervals/sN.md`` and record, in each result
folder's ``provenance.json``, the command, its wall time and the date (what ``make_tables.py``
prints under each table). Usage, from the repository root::

    .venv/bin/python docs/papers/intervals/run_all.py                  # every paper, into out/paper_intervals/
    .venv/bin/python docs/papers/intervals/run_all.py --papers s2 s4   # some of them
    .venv/bin/python docs/papers/intervals/run_all.py record DIR --command "..." --wall-s 812
                                                                       # a run made by hand

then ``.venv/bin/python docs/papers/intervals/make_tables.py``. Runs one command at a time; a
command that exits non-zero stops the script and records nothing for it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import subprocess
import sys
import time

PROVENANCE_FILE = "provenance.json"
DEFAULT_ROOT = os.path.join("out", "paper_intervals")
SEEDS = 30
PY = ".venv/bin/python"
CLI = ".venv/bin/drake-att"
# paper -> [(result folder name, command with {out} for the folder)]
COMMANDS = {
    "s0": [
        ("s0", f"{PY} diagrams/particle_filters.py --seeds {SEEDS} --no-timing --no-sweep --workers 2 --out {{out}}")
    ],
    "s1": [("s1", f"{CLI} montecarlo s1_cqe --runs {SEEDS} --workers 1 --out {{out}}")],
    "s2": [("s2", f"{PY} diagrams/indoor_star_tracker.py --seeds {SEEDS} --dynamic-seeds {SEEDS} --out {{out}}")],
    "s3": [("s3", f"{CLI} montecarlo cubesat_dual_star_tracker --runs {SEEDS} --workers 1 --out {{out}}")],
    "s4": [
        ("s4", f"{PY} diagrams/lie_group_filter.py --seeds {SEEDS} --out {{out}}"),
        ("s4_bench", f"{PY} diagrams/lie_group_bench.py --seeds {SEEDS} --out {{out}}"),
    ],
}


def write_provenance(folder: str, command: str, wall_s: float, date: str | None = None) -> str:
    """``folder/provenance.json``: the command that filled ``folder``, its wall time (s), the date."""
    date = date or datetime.date.today().isoformat()
    path = os.path.join(folder, PROVENANCE_FILE)
    with open(path, "w") as f:
        json.dump({"command": command, "wall_s": float(wall_s), "date": date}, f, indent=1)
        f.write("\n")
    return path


def run_and_record(command: str, folder: str) -> float:
    """Run ``command`` (a shell-free argv), then record it; returns its wall time (s)."""
    t0 = time.perf_counter()
    subprocess.run(shlex.split(command), check=True)
    wall = time.perf_counter() - t0
    write_provenance(folder, command, wall)
    return wall


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["record"]:
        ap = argparse.ArgumentParser(prog="run_all.py record", description="record a run made by hand")
        ap.add_argument("folder")
        ap.add_argument("--command", required=True)
        ap.add_argument("--wall-s", type=float, required=True)
        ap.add_argument("--date", default=None, help="YYYY-MM-DD (default: today)")
        a = ap.parse_args(argv[1:])
        print(write_provenance(a.folder, a.command, a.wall_s, a.date))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=DEFAULT_ROOT)
    ap.add_argument("--papers", nargs="+", default=list(COMMANDS), choices=list(COMMANDS))
    a = ap.parse_args(argv)
    total = 0.0
    for paper in a.papers:
        for name, template in COMMANDS[paper]:
            folder = os.path.join(a.root, name)
            command = template.format(out=folder)
            print(f"[{paper}] {command}", flush=True)
            total += run_and_record(command, folder)
    print(f"total wall time {total / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
