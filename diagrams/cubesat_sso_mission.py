#!/usr/bin/env python3
"""A mission day on the bench: the ``cubesat_sso_mission`` scenario over many seeds.

Every seed runs the whole day with every estimator on one noise realization; the Monte Carlo
runner (:func:`~drake_att.analysis.executor.map_runs`) reduces each run to
:func:`~drake_att.analysis.mission.mission_record` in its worker. Usage::

    python diagrams/cubesat_sso_mission.py                      # 20 seeds x 24 h (the docs' table)
    python diagrams/cubesat_sso_mission.py --seeds 3 --duration 7200 --out /tmp/mission

Writes to ``--out``: ``results.json`` (each seed's record and the summary), ``summary.json`` (the
summary and each estimator's per-seed RMSE: ``docs/mission_data/`` holds the 20-seed copy),
``mission_table.md`` (the tables with 95% intervals, the docs' ``table.md``), ``config.yaml`` (the
scenario used) and ``fig_mission_day.png`` (each estimator's attitude error over the day, seed 1,
the all-trackers-out gaps shaded).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from drake_att.analysis.executor import map_runs
from drake_att.analysis.mission import format_mission_tables, mission_record, summarize_mission
from drake_att.analysis.reproduction import reduced_settings_note
from drake_att.outputs import script_folder_problem
from drake_att.scenarios.config import apply_overrides, dump_scenario
from drake_att.scenarios.library import load

SCENARIO = "cubesat_sso_mission"


def plot_day(record: dict, path: str, title: str) -> None:
    """Each estimator's error magnitude (log scale) over the day, with the gaps shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.2))
    for start, end in record["series"]["gaps_s"]:
        ax.axvspan(start / 3600, end / 3600, color="0.85", lw=0)
    for name, s in record["series"]["estimators"].items():
        ax.semilogy([t / 3600 for t in s["t_s"]], [max(e, 1e-5) for e in s["error_deg"]], lw=0.8, label=name)
    ax.set_xlabel("time (h)")
    ax.set_ylabel("attitude error (deg)")
    ax.set_title(title)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="grey: all trackers out")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


OUR_FILES = ("config.yaml", "results.json", "summary.json", "mission_table.md", "fig_mission_day.png")


def check_out_folder(out: str) -> str | None:
    """None if ``out`` may be written: absent, empty, or a folder this script wrote (only its file
    names, and a ``summary.json`` of its shape); else the one-line reason (a user's files are
    never replaced)."""
    return script_folder_problem(out, OUR_FILES, "summary.json", "per_seed_rmse_deg")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=86400.0)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="out/cubesat_sso_mission")
    args = ap.parse_args(argv)
    if args.seeds < 1 or not 600.0 < args.duration <= 86400.0:
        ap.error(f"--seeds: got {args.seeds} (>= 1); --duration: got {args.duration} (in (600, 86400] s)")
    problem = check_out_folder(args.out)
    if problem:
        print(f"cubesat_sso_mission.py: {problem}", file=sys.stderr)
        return 2
    scenario = apply_overrides(load(SCENARIO), [f"duration_s={args.duration}"])
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "config.yaml"), "w") as f:
        f.write(dump_scenario(scenario))
    seeds = list(range(1, args.seeds + 1))
    print(f"Running {len(seeds)} seeds x {args.duration:.0f} s of {SCENARIO} ...", flush=True)
    t0 = time.time()
    records = map_runs(scenario, seeds, mission_record, workers=args.workers, raise_failures=True)
    summary = summarize_mission(records)
    tables = format_mission_tables(summary)
    note = reduced_settings_note(args, ap, ("seeds", "duration"))
    print(tables + (f"\n{note}\n" if note else ""))
    print(f"({time.time() - t0:.0f} s wall)")
    with open(os.path.join(args.out, "mission_table.md"), "w") as f:
        f.write(tables)
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump({"seeds": seeds, "duration_s": args.duration, "summary": summary, "per_seed": records}, f)
    per_seed_rmse = {name: [r["estimators"][name]["rmse_deg"] for r in records] for name in summary["estimators"]}
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump({"duration_s": args.duration, "summary": summary, "per_seed_rmse_deg": per_seed_rmse}, f, indent=1)
    plot_day(records[0], os.path.join(args.out, "fig_mission_day.png"), f"{SCENARIO}: attitude error, seed {seeds[0]}")
    print(f"Wrote {args.out}/results.json, summary.json, mission_table.md, config.yaml, fig_mission_day.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
