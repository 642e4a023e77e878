#!/usr/bin/env python3
"""Paper S3's CubeSat with star trackers that see the sky, next to the paper's Gaussian trackers.

Runs ``cubesat_dual_star_tracker`` (the paper's 5"/50" Gaussian trackers) and
``cubesat_dual_sky_tracker`` (the same CubeSat with two ``!SkyStarTrackerConfig`` trackers: frames
rendered from the Hipparcos catalogue, identified and solved) over the same seeds. Usage::

    python diagrams/sky_cubesat.py                      # 20 seeds x 5000 s (about 1 h on 2 cores)
    python diagrams/sky_cubesat.py --seeds 3 --duration 600

Prints per architecture (single, centralized, decentralized, joint) the attitude RMSE per axis
and in total (deg, stable stage, mean ± 95% Student-t half-width over the seeds) and the ANEES
(the NEES of the 6 errors, attitude and gyro bias, averaged over the stable stage and the seeds: 6
for a consistent filter) for both tracker models; and the sky trackers' frames: valid fraction, tracked
fraction, identified stars, misidentified stars (must be 0), and the frames' own sigmas across
and about the boresight (arcsec) — the emergent counterpart of the paper's 5" / 50". Writes
``results.json`` to ``--out`` when given.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

from drake_att.analysis.ensemble import t_q
from drake_att.analysis.executor import map_runs
from drake_att.analysis.metrics import compute_metrics
from drake_att.analysis.reproduction import reduced_settings_note
from drake_att.outputs import script_folder_problem, write_json_atomically
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import load
from drake_att.sky_tracker import FRAME_STATUS_NAMES, MODE_TRACKING

MODELS = {"gaussian": "cubesat_dual_star_tracker", "sky": "cubesat_dual_sky_tracker"}
ARCHITECTURES = ("single", "centralized", "decentralized", "joint")
TRACKERS = ("st1", "st2")
ARCSEC_PER_RAD = 180 / math.pi * 3600


def study_scenario(name: str, duration_s: float | None):
    scenario = load(name)
    if duration_s is not None:
        score_from = min(scenario.scoring.score_from_s, duration_s / 2)
        scenario = apply_overrides(scenario, [f"duration_s={duration_s}", f"scoring.score_from_s={score_from}"])
    return scenario


def _last_per_time(t, x):
    t, x = np.asarray(t), np.asarray(x).reshape(len(t), -1)
    keep = np.r_[np.diff(t) > 1e-9, True]
    return t[keep], x[keep]


def record(run) -> dict:
    """One seed: every architecture's RMSE and ANEES; the sky trackers' frame statistics."""
    metrics = compute_metrics(run)["estimators"]
    out: dict = {
        "seed": int(run.seed),
        "estimators": {
            n: {
                "rmse": metrics[n]["attitude_rmse_deg"],
                "total": metrics[n]["attitude_rmse_total_deg"],
                "anees": metrics[n]["nees_mean"],
                "dof": metrics[n]["nees_dof"],
            }
            for n in ARCHITECTURES
        },
        "frames": {},
    }
    col = {n: i for i, n in enumerate(FRAME_STATUS_NAMES)}
    for st in TRACKERS:
        key = f"{st}/frame_status"
        if key not in run.signals:
            continue
        _, status = _last_per_time(*run.signals[key])
        _, cov = _last_per_time(*run.signals[f"{st}/covariance_S"])
        valid = status[:, col["valid"]] == 1
        sig = np.sqrt(cov[valid][:, [0, 4, 8]]) * ARCSEC_PER_RAD
        out["frames"][st] = {
            "frames": int(len(status)),
            "valid": int(valid.sum()),
            "tracked": int(np.sum(valid & (status[:, col["mode"]] == MODE_TRACKING))),
            "identified_mean": float(np.mean(status[valid, col["stars_identified"]])),
            "misidentified": int(np.sum(status[:, col["stars_misidentified"]])),
            "sigma_cross_arcsec": float(np.sqrt(np.mean(sig[:, :2] ** 2))),
            "sigma_boresight_arcsec": float(np.sqrt(np.mean(sig[:, 2] ** 2))),
        }
    return out


def mean_interval(x, probability: float = 0.95) -> tuple[float, float]:
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return float(np.mean(x)), float("nan")
    half = t_q(0.5 + 0.5 * probability, len(x) - 1) * float(np.std(x, ddof=1)) / math.sqrt(len(x))
    return float(np.mean(x)), half


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=None, help="shorter runs (s)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default=None, help="folder for results.json")
    args = ap.parse_args(argv)
    problem = args.out and script_folder_problem(args.out, ("results.json",), "results.json", "summary")
    if problem:
        print(f"sky_cubesat.py: {problem}", file=sys.stderr)
        return 2
    if args.seeds < 2:
        ap.error(f"--seeds: got {args.seeds}; an interval needs at least 2 seeds")
    seeds = list(range(1, args.seeds + 1))
    records = {}
    for model, name in MODELS.items():
        scenario = study_scenario(name, args.duration)
        print(f"Running {args.seeds} seeds x {scenario.duration_s:.0f} s of {name} ...", flush=True)
        records[model] = map_runs(scenario, seeds, record, workers=args.workers, raise_failures=True)
    note = reduced_settings_note(args, ap, ("seeds", "duration"))
    if note:
        print(note)
    summary: dict = {}
    print(f"\nAttitude RMSE (deg, stable stage; mean ± 95% half-width over {args.seeds} seeds) and ANEES")
    print(f"{'architecture':<14} {'model':<9} {'x':>17} {'y':>17} {'z':>17} {'total':>17} {'ANEES':>6}")
    for arch in ARCHITECTURES:
        for model in MODELS:
            rows = [r["estimators"][arch] for r in records[model]]
            axes = [mean_interval([r["rmse"][k] for r in rows]) for k in range(3)]
            total = mean_interval([r["total"] for r in rows])
            anees = float(np.mean([r["anees"] for r in rows]))
            summary.setdefault(arch, {})[model] = {"axes": axes, "total": total, "anees": anees}
            cells = " ".join(f"{m:>8.5f}±{h:<8.5f}" for m, h in [*axes, total])
            print(f"{arch:<14} {model:<9} {cells} {anees:>6.2f}")
    print(f"\nSky trackers' frames (over {args.seeds} seeds)")
    print(
        f"{'tracker':<8} {'frames':>8} {'valid':>7} {'tracked':>8} {'stars':>6} {'wrong':>6} {'cross':>7} {'boresight':>10}"
    )
    frames = {}
    for st in TRACKERS:
        f = [r["frames"][st] for r in records["sky"]]
        n = sum(x["frames"] for x in f)
        v = sum(x["valid"] for x in f)
        frames[st] = {
            "frames": n,
            "valid_fraction": v / n,
            "tracked_fraction": sum(x["tracked"] for x in f) / n,
            "identified_mean": float(np.mean([x["identified_mean"] for x in f])),
            "misidentified": sum(x["misidentified"] for x in f),
            "sigma_cross_arcsec": float(np.mean([x["sigma_cross_arcsec"] for x in f])),
            "sigma_boresight_arcsec": float(np.mean([x["sigma_boresight_arcsec"] for x in f])),
        }
        x = frames[st]
        print(
            f"{st:<8} {n:>8} {x['valid_fraction']:>7.4f} {x['tracked_fraction']:>8.4f} {x['identified_mean']:>6.1f} "
            f'{x["misidentified"]:>6} {x["sigma_cross_arcsec"]:>6.2f}" {x["sigma_boresight_arcsec"]:>9.1f}"'
        )
    summary["frames"] = frames
    wrong = sum(x["misidentified"] for x in frames.values())
    print(f"\n[{'holds' if wrong == 0 else 'DOES NOT HOLD'}] no star misidentified in any valid frame")
    if args.out:
        write_json_atomically(
            os.path.join(args.out, "results.json"),
            {"seeds": seeds, "duration_s": args.duration, "records": records, "summary": summary},
        )
        print(f"Wrote results.json to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
