#!/usr/bin/env python3
"""False alarms of the sensor monitor: paper S3's dual-tracker CubeSat with no fault at all.

The scenario ``cubesat_dual_star_tracker`` with a sensor monitor over its gyro and both
trackers and FDIR twins of its MEKFs (:func:`drake_att.scenarios.monitoring.with_monitor`:
``single_fdir``, ``single_st2_fdir``, ``joint_fdir`` next to the paper's ``single``,
``single_st2``, ``joint``), over several seeds. Usage::

    python diagrams/fdir_false_alarms.py                 # 20 seeds x 5000 s
    python diagrams/fdir_false_alarms.py --seeds 3 --duration 1000

Prints, over the seeds: the monitor's judged instants, exclusions and logged causes per sensor
with the exclusion rate's 95% upper bound (none expected: an exclusion needs a sensor to fail
every test it takes part in, each at the configured false-alarm probability); and per MEKF the
attitude RMSE (total and per axis) with its 95% Student-t interval, the FDIR twin's next to
the original's, and the paired difference's interval (the twin "equals today's" when that
interval contains 0 or lies within the original's half-width). Writes ``results.json`` to
``--out`` when given.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

from drake_att import fdir
from drake_att.analysis.ensemble import t_q
from drake_att.analysis.executor import map_runs
from drake_att.analysis.fault_scores import sensor_monitors
from drake_att.analysis.metrics import compute_metrics
from drake_att.analysis.reproduction import reduced_settings_note
from drake_att.outputs import script_folder_problem, write_json_atomically
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import load
from drake_att.scenarios.monitoring import with_monitor

SCENARIO = "cubesat_dual_star_tracker"
MONITOR = "fdir"


def study_scenario(duration_s: float | None = None):
    scenario = with_monitor(load(SCENARIO), name=MONITOR)
    if duration_s is not None:
        score_from = min(scenario.scoring.score_from_s, duration_s / 2)
        scenario = apply_overrides(scenario, [f"duration_s={duration_s}", f"scoring.score_from_s={score_from}"])
    return scenario


def record(run) -> dict:
    """What one seed contributes: the monitor's counts and every estimator's RMSE."""
    t, log = run.signals[f"{MONITOR}/detector_log"]
    t = np.asarray(t)
    log = np.asarray(log).reshape(len(t), -1)
    keep = np.r_[np.diff(t) > 1e-6, True]  # the logger's two rows at t = 0: the last
    log = log[keep]
    sensors = sensor_monitors(run.scenario)[MONITOR]
    monitor = {}
    for j, name in enumerate(sensors):
        verdict, cause, count = (log[:, fdir.LOG_PER_SENSOR * j + k] for k in range(3))
        monitor[name] = {
            "instants": int(len(verdict)),
            "exclusions": int(count[-1]),
            "excluded_instants": int(np.sum(verdict == fdir.EXCLUDED)),
            "causes": {fdir.CAUSE_NAMES[int(c)]: int(np.sum(cause == c)) for c in np.unique(cause) if c},
        }
    metrics = compute_metrics(run)["estimators"]
    return {
        "seed": int(run.seed),
        "monitor": monitor,
        "rmse": {
            n: {"total": m["attitude_rmse_total_deg"], "axes": m["attitude_rmse_deg"]}
            for n, m in metrics.items()
            if "attitude_rmse_total_deg" in m
        },
    }


def mean_interval(x, probability: float = 0.95) -> tuple[float, float]:
    """Mean and Student-t half-width."""
    x = np.asarray(x, dtype=float)
    half = t_q(0.5 + 0.5 * probability, len(x) - 1) * float(np.std(x, ddof=1)) / math.sqrt(len(x))
    return float(np.mean(x)), half


def summarize(records, twins: dict) -> dict:
    sensors = list(records[0]["monitor"])
    monitor = {}
    for s in sensors:
        n = sum(r["monitor"][s]["instants"] for r in records)
        k = sum(r["monitor"][s]["exclusions"] for r in records)
        causes: dict = {}
        for r in records:
            for c, v in r["monitor"][s]["causes"].items():
                causes[c] = causes.get(c, 0) + v
        # 95% upper bound of a rate with k events in n trials (k = 0: 3/n, the rule of three;
        # otherwise the Poisson bound's normal approximation)
        upper = 3.0 / n if k == 0 else (k + 1.96 * math.sqrt(k) + 1.0) / n
        monitor[s] = {"instants": n, "exclusions": k, "rate_upper_95": upper, "causes": causes}
    rmse = {}
    for twin, original in twins.items():
        a = [r["rmse"][original]["total"] for r in records]
        b = [r["rmse"][twin]["total"] for r in records]
        ma, ha = mean_interval(a)
        mb, hb = mean_interval(b)
        md, hd = mean_interval(np.subtract(b, a))
        axes = np.array([r["rmse"][twin]["axes"] for r in records]) - np.array(
            [r["rmse"][original]["axes"] for r in records]
        )
        rmse[twin] = {
            "original": original,
            "original_deg": [ma, ha],
            "fdir_deg": [mb, hb],
            "difference_deg": [md, hd],
            "axes_difference_max_deg": float(np.max(np.abs(axes))),
            "equal": bool(abs(md) <= hd or abs(md) <= ha),
        }
    return {"monitor": monitor, "rmse": rmse}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=None, help="shorter runs (s)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default=None, help="folder for results.json")
    args = ap.parse_args(argv)
    problem = args.out and script_folder_problem(args.out, ("results.json",), "results.json", "summary")
    if problem:
        print(f"fdir_false_alarms.py: {problem}", file=sys.stderr)
        return 2
    if args.seeds < 2:
        ap.error(f"--seeds: got {args.seeds}; an interval needs at least 2 seeds")
    scenario = study_scenario(args.duration)
    twins = {e.name: e.name.removesuffix("_fdir") for e in scenario.estimators if getattr(e, "monitor", "")}
    monitor_config = next(s for s in scenario.sensors if s.name == MONITOR)
    print(
        f"Running {args.seeds} seeds x {scenario.duration_s:.0f} s of {SCENARIO} with a sensor monitor "
        f"(false-alarm probability {monitor_config.false_alarm_probability:g} per test) and FDIR twins ...",
        flush=True,
    )
    records = map_runs(scenario, list(range(1, args.seeds + 1)), record, workers=args.workers, raise_failures=True)
    summary = summarize(records, twins)
    note = reduced_settings_note(args, ap, ("seeds", "duration"))
    if note:
        print(note)
    print(f"\n{'sensor':<8} {'instants':>9} {'exclusions':>10} {'rate (95% upper)':>17}  causes logged")
    for s, m in summary["monitor"].items():
        print(f"{s:<8} {m['instants']:>9} {m['exclusions']:>10} {m['rate_upper_95']:>17.2e}  {m['causes'] or 'none'}")
    print(f"\nAttitude RMSE (deg, total; mean ± 95% half-width over {args.seeds} seeds)")
    print(f"{'estimator':<16} {'original':>22} {'FDIR twin':>22} {'twin - original':>24} {'max |axis diff|':>16}")
    for r in summary["rmse"].values():
        (ma, ha), (mb, hb), (md, hd) = r["original_deg"], r["fdir_deg"], r["difference_deg"]
        print(
            f"{r['original']:<16} {ma:>12.5f} ± {ha:<8.5f} {mb:>12.5f} ± {hb:<8.5f} {md:>+13.2e} ± {hd:<9.2e} "
            f"{r['axes_difference_max_deg']:>16.2e}"
        )
    no_exclusion = all(m["exclusions"] == 0 for m in summary["monitor"].values())
    equal = all(r["equal"] for r in summary["rmse"].values())
    print("\nVerdicts:")
    print(
        f"  [{'holds' if no_exclusion else 'DOES NOT HOLD'}] the monitor excluded nothing in {args.seeds} fault-free seeds"
    )
    print(
        f"  [{'holds' if equal else 'DOES NOT HOLD'}] every FDIR twin's RMSE equals the original's within its interval"
    )
    if args.out:
        write_json_atomically(
            os.path.join(args.out, "results.json"),
            {"seeds": args.seeds, "duration_s": scenario.duration_s, "records": records, "summary": summary},
        )
        print(f"\nWrote results.json to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
