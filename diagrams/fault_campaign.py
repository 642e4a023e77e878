#!/usr/bin/env python3
"""Fault campaign: paper S3's dual-tracker CubeSat with every fault kind
injected at known times (scenario ``fault_campaign``), every applicable estimator — the S3
MEKFs (single, centralized, single_st2, joint; ungated, as in the paper), their decentralized
fusion, and MEKF variants with a 99.9% chi-square gate — over several seeds.

All estimators run in ONE diagram per seed (same truth, same noise, same faults); the seeds
are contexts of one diagram per worker process. Usage::

    python diagrams/fault_campaign.py                      # 5 seeds x 3400 s
    python diagrams/fault_campaign.py --seeds 2 --out /tmp/fc
    python diagrams/fault_campaign.py --seeds 1 --duration 700   # the first faults only

Prints, per fault (sensor and kind) and estimator, summed over the seeds: the faulted steps
the estimator saw and what it did at them (detected / rejected / accepted / ignored), its
peak attitude error, its recovery time and its NEES after recovery (definitions:
:mod:`drake_att.analysis.fault_scores`); then the verdicts. Writes ``results.json`` (every seed's
rows, the summary, the verdicts), ``config.yaml`` (the scenario used), ``table.md`` (the
docs/guide/faults.md table) and ``fig_fault_campaign.png`` (attitude error of one seed with the faults
marked).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

from drake_att.analysis.fault_scores import (
    HOLD_S,
    PRE_FAULT_WINDOW_S,
    RECOVERY_FACTOR,
    run_fault_campaign,
    summarize_fault_scores,
)
from drake_att.analysis.report import strict_json
from drake_att.analysis.reproduction import reduced_settings_note
from drake_att.scenarios.config import apply_overrides, dump_scenario
from drake_att.scenarios.library import load

SCENARIO = "fault_campaign"
# Stated survival bound: back within RECOVERY_FACTOR x the pre-fault RMS error within this
# time after every fault ends.
RECOVERY_LIMIT_S = 60.0
# The FDIR MEKFs' bounds: peak error within max(FDIR_PEAK_FACTOR x their fault-free RMS, the best
# ungated MEKF's peak on that fault), back within FDIR_RECOVERY_LIMIT_S of the fault's end.
# Where an FDIR MEKF can do nothing but what its ungated counterpart does (skip an invalid
# sample, coast through a tracker outage) the two peaks differ only by the filters' histories:
# "within" the counterpart's peak allows FDIR_PEAK_SLACK of it.
FDIR_PEAK_FACTOR = 3.0
FDIR_PEAK_SLACK = 0.05
FDIR_RECOVERY_LIMIT_S = 10.0
DEG_SIGN = "°"


def campaign_scenario(duration_s: float | None = None):
    """The ``fault_campaign`` scenario; ``duration_s`` shortens the run (faults after it are
    not reached)."""
    scenario = load(SCENARIO)
    if duration_s is None:
        return scenario
    return apply_overrides(
        scenario,
        [f"duration_s={duration_s}", f"scoring.score_from_s={min(scenario.scoring.score_from_s, duration_s / 2)}"],
    )


def gate_label(config) -> str:
    """How an estimator gates its measurements (from its config)."""
    chi2 = getattr(config, "innovation_gate_chi2", None)
    if chi2 is not None:
        return f"chi2 {chi2:g}"
    p = getattr(config, "innovation_gate_probability", None)
    if p:
        return f"p {p:g}"
    return "none" if hasattr(config, "innovation_gate_chi2") else "-"


def _fault_label(g, magnitudes) -> str:
    m = magnitudes.get((g["sensor"], g["kind"]))
    size = ""
    if g["kind"] == "outlier" and m is not None:
        size = f" {np.degrees(m):g}{DEG_SIGN}" + ("/s" if g["sensor_kind"] == "gyro" else "")
    return f"{g['sensor']} {g['kind']}{size}"


def _outcome(g) -> str:
    """What the estimator did at the faulted steps: rej / acc / acc! (accepted, NIS above the
    99.9% point) / ign, or the counts when mixed; '-' if it never saw the fault."""
    if not g["seen"]:
        return "-"
    n, r, a, i, d = g["steps"], g["rejected"], g["accepted"], g["ignored"], g["detected"]
    if r == n:
        return "rej"
    if a == n:
        return "acc!" if d == n else ("acc" if d == 0 else f"acc({d}!)")
    if i == n:
        return "ign"
    return "/".join(f"{k}{v}" for k, v in (("r", r), ("a", a), ("i", i)) if v)


def _recovery(g, seeds: int) -> str:
    if g["recovered"] < g["events"]:
        return f"NR {g['events'] - g['recovered']}/{g['events']}"
    return f"{g['recovery_time_s']:.0f}"


def summary_table(summary, estimators, magnitudes, seeds: int) -> str:
    """One line per (fault, estimator), summed over the seeds."""
    lines = [
        f"{'fault':<20} {'estimator':<16} {'steps':>5} {'det':>4} {'rej':>4} {'acc':>4} {'ign':>4} "
        f"{'peak (deg)':>10} {'recov (s)':>9} {'NEES':>5} {'during':>6}"
    ]
    lines.append("-" * len(lines[0]))
    last = None
    for g in summary:
        label = _fault_label(g, magnitudes)
        if last is not None and label != last:
            lines.append("")
        last = label
        nees = "-" if g["nees_after_recovery"] is None else f"{g['nees_after_recovery']:.1f}"
        during = "-" if g.get("nees_during") is None else f"{g['nees_during']:.3g}"
        peak = "-" if g["peak_error_deg"] is None else f"{g['peak_error_deg']:.3f}"
        lines.append(
            f"{label:<20} {g['estimator']:<16} {g['steps']:>5} {g['detected']:>4} {g['rejected']:>4} "
            f"{g['accepted']:>4} {g['ignored']:>4} {peak:>10} {_recovery(g, seeds):>9} {nees:>5} {during:>6}"
        )
    return "\n".join(lines)


def markdown_matrix(summary, estimators, magnitudes, seeds: int) -> str:
    """The fault table of docs/guide/faults.md: fault x estimator -> outcome, peak error (deg), recovery (s)."""
    by = {(_fault_label(g, magnitudes), g["estimator"]): g for g in summary}
    faults = list(dict.fromkeys(_fault_label(g, magnitudes) for g in summary))
    lines = ["| fault | " + " | ".join(estimators) + " |", "|---|" + "---|" * len(estimators)]
    for f in faults:
        cells = []
        for e in estimators:
            g = by[(f, e)]
            if not g["seen"]:
                cells.append("-")
                continue
            peak = f"{g['peak_error_deg']:.2f}" if g["peak_error_deg"] is not None else "-"
            cells.append(f"{_outcome(g)} {peak} / {_recovery(g, seeds)}")
        lines.append(f"| {f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def fault_free_rms_deg(rows, name: str) -> float:
    """An estimator's fault-free RMS error: the quadratic mean of its pre-fault RMS errors over
    every event and seed (the windows before each fault, clear of the previous one)."""
    rms = [r["pre_fault_rms_deg"] for r in rows if r["estimator"] == name and r["pre_fault_rms_deg"] is not None]
    return float(np.sqrt(np.mean(np.square(rms)))) if rms else float("nan")


def fdir_checks(results, summary, fdir) -> dict:
    """The FDIR MEKFs' claims, per fault (sensor, kind) over every seed: the peak bound, the
    recovery limit and the trace; ``fdir``: FDIR MEKF -> its ungated counterparts (the ungated
    MEKFs reading the same trackers). Returns ``{"claims": {...}, "failures": [...]}``."""
    rows = [r for res in results for r in res["rows"]]
    failures = []
    peak_ok = recovery_ok = trace_ok = True
    for g in summary:
        if g["estimator"] not in fdir or not g["seen"]:
            continue
        best = [
            u["peak_error_deg"]
            for u in summary
            if (u["sensor"], u["kind"]) == (g["sensor"], g["kind"])
            and u["estimator"] in fdir[g["estimator"]]
            and u["peak_error_deg"] is not None
        ]
        bound = max(
            FDIR_PEAK_FACTOR * fault_free_rms_deg(rows, g["estimator"]),
            (1.0 + FDIR_PEAK_SLACK) * min(best) if best else 0.0,
        )
        if not g["peak_error_deg"] <= bound:
            peak_ok = False
            failures.append(
                f"{g['estimator']} on {g['sensor']} {g['kind']}: peak {g['peak_error_deg']:.3f} > {bound:.3f} deg"
            )
    for r in rows:
        if r["estimator"] not in fdir:
            continue
        if r["recovery_time_s"] is None or r["recovery_time_s"] > FDIR_RECOVERY_LIMIT_S:
            recovery_ok = False
            failures.append(
                f"{r['estimator']} after {r['sensor']} {r['kind']} at {r['t_start']:g} s: recovery "
                f"{r['recovery_time_s']}"
            )
        if r["seen"] and r["detected"] + r["rejected"] + r["excluded"] + r["flagged"] == 0:
            trace_ok = False
            failures.append(f"{r['estimator']}: {r['sensor']} {r['kind']} at {r['t_start']:g} s left no trace")
    claims = {
        f"FDIR MEKFs: on every fault, peak error within max({FDIR_PEAK_FACTOR:g}x their fault-free RMS, the "
        f"ungated MEKF's on the same trackers (+{FDIR_PEAK_SLACK:.0%})) over all seeds": peak_ok,
        f"FDIR MEKFs are back within {RECOVERY_FACTOR:g}x their pre-fault RMS within {FDIR_RECOVERY_LIMIT_S:g} s of the "
        "end of every fault, in every seed": recovery_ok,
        "every fault an FDIR MEKF saw left a trace: rejected or detected in its status (a prediction recovery "
        "included), or excluded or flagged in the monitor's log, in every seed": trace_ok,
    }
    return {"claims": claims, "failures": failures}


def verdicts(results, summary, gates, via_average=frozenset(), fdir=None) -> dict:
    """The claims, checked on every seed's rows (``via_average``: estimators that read the
    trackers only through a tracker average; ``fdir``: estimators reading through a sensor
    monitor -> their ungated counterparts, held to :func:`fdir_checks` and not to the gated
    MEKFs' claims)."""
    fdir = fdir or {}
    rows = [r for res in results for r in res["rows"]]
    gated = {n for n, g in gates.items() if g not in ("none", "-") and n not in fdir}
    ungated_mekfs = {n for n, g in gates.items() if g == "none"}
    tracker_outliers = [r for r in rows if r["kind"] == "outlier" and r["sensor_kind"] != "gyro" and r["seen"]]
    late = sorted(
        {
            (r["sensor"], r["kind"], r["estimator"])
            for r in rows
            if r["recovery_time_s"] is None or r["recovery_time_s"] > RECOVERY_LIMIT_S
        }
    )
    claims = {
        "no estimator crashed and every output stayed finite, in every seed": all(
            all(res["finite"].values()) for res in results
        ),
        f"every estimator is back within {RECOVERY_FACTOR:g}x its pre-fault RMS error within {RECOVERY_LIMIT_S:g} s "
        "of the end of every fault, in every seed": not late,
        # An estimator fed through the tracker average (centralized) reads, at a step where one
        # tracker is out or corrupt, the average of the others (flag 1 + mask, their own
        # covariance): its "accepted" sample is not the faulted one.
        "a NaN, inf, dropped-out or outage sample is never used (accepted by no estimator; the "
        "average carries the other trackers)": all(
            r["accepted"] == 0
            for r in rows
            if r["kind"] in ("nan", "inf", "dropout", "outage")
            and not (r["sensor_kind"] != "gyro" and r["estimator"] in via_average)
        ),
        "gated MEKFs reject every tracker outlier they see": all(
            r["rejected"] == r["steps"] for r in tracker_outliers if r["estimator"] in gated
        ),
        "ungated MEKFs accept every tracker outlier they see and are pulled off by more than 0.1 deg": all(
            r["accepted"] == r["steps"] and r["peak_error_deg"] > 0.1
            for r in tracker_outliers
            if r["estimator"] in ungated_mekfs
        ),
    }
    out = {"claims": claims, "not_recovered_within_limit": [list(x) for x in late]}
    if fdir:
        checked = fdir_checks(results, summary, fdir)
        out["claims"].update(checked["claims"])
        out["fdir_failures"] = checked["failures"]
    return out


def plot_campaign(result, estimators, path):
    """Attitude error of one seed, per architecture, with every fault marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [[e for e in estimators if e.startswith(p)] for p in ("single", "centralized", "joint")]
    groups.append([e for e in estimators if not any(e in g for g in groups)])
    groups = [g for g in groups if g]
    fig, axes = plt.subplots(len(groups), 1, figsize=(13, 2.8 * len(groups)), sharex=True, squeeze=False)
    colors = {"gyro": "tab:red", "st1": "tab:blue", "st2": "tab:green"}
    for ax, names in zip(axes[:, 0], groups, strict=True):
        for n in names:
            s = result["series"][n]
            ax.semilogy(s["t"], np.maximum(s["error_deg"], 1e-5), lw=0.7, label=n)
        for e in result["events"]:
            c = colors.get(e["sensor"], "tab:gray")
            ax.axvspan(e["t_start"], max(e["t_end"], e["t_start"] + 1.0), color=c, alpha=0.15, lw=0)
        ax.set_ylabel("|attitude error| (deg)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    top = axes[0, 0]
    for e in result["events"]:
        top.annotate(
            f"{e['sensor']} {e['kind']}",
            (e["t_start"], 1.0),
            xycoords=("data", "axes fraction"),
            rotation=90,
            fontsize=6,
            va="top",
            ha="right",
            color=colors.get(e["sensor"], "tab:gray"),
        )
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(f"Fault campaign, seed {result['seed']}: shaded = fault (red gyro, blue st1, green st2)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=None, help="shorter run (s): faults after it are not reached")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="out/fault_campaign")
    ap.add_argument("--no-figure", action="store_true")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    scenario = campaign_scenario(args.duration)
    with open(os.path.join(args.out, "config.yaml"), "w") as f:
        f.write(dump_scenario(scenario))
    seeds = list(range(1, args.seeds + 1))
    estimators = [e.name for e in scenario.estimators]
    gates = {e.name: gate_label(e) for e in scenario.estimators}
    print(
        f"Running {len(seeds)} seeds x {scenario.duration_s:.0f} s of {SCENARIO} (all estimators per seed, "
        "one diagram per worker) ...",
        flush=True,
    )
    results = run_fault_campaign(scenario, seeds, args.workers, keep_series_for=[seeds[0]])
    summary = summarize_fault_scores([r["rows"] for r in results])
    magnitudes = {(e["sensor"], e["kind"]): e["magnitude"] for e in results[0]["events"]}
    print("\nEstimators (gate): " + ", ".join(f"{n} ({gates[n]})" for n in estimators))
    print(
        f"\nFault x estimator over {len(seeds)} seeds: faulted steps seen and what the estimator did at them "
        "(det = rejected, or accepted with NIS > 16.27), peak |attitude error| from the fault to the next one, "
        f"recov = time after the fault's end until the error is back within {RECOVERY_FACTOR:g}x its RMS over "
        f"the {PRE_FAULT_WINDOW_S:g} s before the fault and stays there {HOLD_S:g} s (worst seed; NR = not "
        "recovered before the next fault), NEES = mean 3-dof attitude NEES after recovery (3 = consistent), "
        "during = the same over the fault's own steps\n"
    )
    table = summary_table(summary, estimators, magnitudes, len(seeds))
    print(table)
    matrix = markdown_matrix(summary, estimators, magnitudes, len(seeds))
    with open(os.path.join(args.out, "table.md"), "w") as f:
        f.write(matrix + "\n")
    averages = {s.name for s in scenario.sensors if type(s).__name__ == "StarTrackerAverageConfig"}
    via_average = {
        e.name for e in scenario.estimators if getattr(e, "star_trackers", None) and set(e.star_trackers) <= averages
    }
    fdir = {
        e.name: {
            u.name
            for u in scenario.estimators
            if gates[u.name] == "none" and set(getattr(u, "star_trackers", ())) == set(e.star_trackers)
        }
        for e in scenario.estimators
        if getattr(e, "monitor", "")
    }
    checked = verdicts(results, summary, gates, via_average, fdir)
    print("\nVerdicts:")
    note = reduced_settings_note(args, ap, ("seeds", "duration"))
    if note:
        print(note)
    for claim, holds in checked["claims"].items():
        print(f"  [{'holds' if holds else 'DOES NOT HOLD'}] {claim}")
    for sensor, kind, name in checked["not_recovered_within_limit"]:
        worst = next(g for g in summary if (g["sensor"], g["kind"], g["estimator"]) == (sensor, kind, name))
        print(f"      not within {RECOVERY_LIMIT_S:g} s: {name} after {sensor} {kind} ({_recovery(worst, len(seeds))})")
    for failure in checked.get("fdir_failures", []):
        print(f"      FDIR: {failure}")
    wall = [r["wall_time_s"] for r in results]
    print(f"\nSimulation wall time per seed: {np.mean(wall):.1f} s (mean of {len(wall)})")
    if not args.no_figure:
        plot_campaign(results[0], estimators, os.path.join(args.out, "fig_fault_campaign.png"))
    out = {
        "scenario": SCENARIO,
        "seeds": seeds,
        "duration_s": scenario.duration_s,
        "gates": gates,
        "recovery_limit_s": RECOVERY_LIMIT_S,
        "recovery_factor": RECOVERY_FACTOR,
        "pre_fault_window_s": PRE_FAULT_WINDOW_S,
        "hold_s": HOLD_S,
        "summary": summary,
        "verdicts": checked,
        "per_seed": [{k: v for k, v in r.items() if k != "series"} for r in results],
    }
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(strict_json(out), f, indent=1, allow_nan=False)
    print(
        f"\nWrote results.json, config.yaml, table.md{'' if args.no_figure else ', fig_fault_campaign.png'} "
        f"to {args.out}/"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
