#!/usr/bin/env python3
"""Paper S2 reproduced: the indoor star tracker for a three-axis air-bearing table.

Every number below comes from running the model — the screen camera and the indoor star
tracker solver in the scenario diagrams ``s2_indoor_static`` and ``s2_indoor_dynamic`` (one
diagram each; A0 offsets, iteration counts, noise sources, tilts and identification modes
are context parameters), except the "over 100 random screens" columns, which run the same
solver core (:func:`drake_att.estimators.indoor_star_tracker_plugin.solver_for`) on 100 other star
patterns (a screen's pattern is part of the diagram's structure).

* **Table 1**: stars identified and pitch/roll/yaw errors of the first frame after one
  iteration from ``A0`` = 0, +-3, +-6 deg (all three axes), next to the paper's; and a finer
  sweep of the offset showing where identification breaks, on the scenario's screen and
  over 100 random 7-star screens.
* **Table 2**: errors and stars identified per iteration from ``A0`` = -2 deg, with three
  candidate error sources side by side (noise-free, centroid noise, centroid quantization),
  to show which one gives the paper's ~1e-3 deg floor.
* **Naive vs corrected** angle matching when the table tilts (exact ``A0``).
* **Dynamic test** (50 stars, swarm start, 2/3/0.5 deg static for 40 s then 0.05/0.10/0.01
  deg/s): three-axis truth vs estimate, errors, stars identified, the swarm phase; yaw
  accuracy vs roll/pitch (the paper's point); the camera alone vs fused with a MEMS gyro
  through a camera outage (beyond the paper).

Prints the tables with verdicts computed from the runs, saves PNG figures, ``results.json``
and the configs used.

    python diagrams/indoor_star_tracker.py [--seeds 20] [--screens 100] [--out out/indoor_star_tracker]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import types
from dataclasses import replace

import numpy as np

from drake_att import rotations as rot
from drake_att.analysis.reproduction import reduced_settings_note
from drake_att.contract import CameraCentroids
from drake_att.estimators.indoor_star_tracker_plugin import solver_for
from drake_att.filters.indoor_star_tracker import rpy_deg_to_R_BI
from drake_att.scenarios.builder import diagram_for
from drake_att.scenarios.config import apply_overrides, dump_scenario
from drake_att.scenarios.library import load
from drake_att.sensors.screen_camera_plugin import camera_geometry

EST = "indoor_star_tracker"
FRAME_PERIOD_S = 0.2  # s2_indoor_dynamic's camera
FUSED = "indoor_star_tracker_gyro"
# The paper's printed values (for comparison only): pitch, roll, yaw (deg), stars identified.
TABLE1_PAPER = {
    0: (0.0, 0.0, 0.0, 7),
    3: (0.0017, 0.0074, 0.0003, 3),
    -3: (-0.0004, 0.0007, -0.0001, 3),
    6: None,
    -6: None,
}
TABLE2_PAPER = [(7.9, 6.5, 6.5, 3), (4.9, 4.1, 0.3, 4), (1.5, 4.0, 0.1, 6), (2.4, 3.1, 0.2, 6), (1.3, 3.2, 0.5, 6)]
TABLE2_PAPER_MEAN = (2.5, 3.6, 0.3)  # 1e-3 deg, mean of iterations 2-5
# Error sources for Table 2 (camera parameters; the run seed draws the noise).
SOURCES = {
    "noise_free": [],
    "centroid_noise_0.05px": ["sensors.camera.centroid_noise_px=0.05"],
    "quantization_0.5px": ["sensors.camera.quantization_px=0.5"],
}
TILTS_DEG = [0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0]
FINE_OFFSETS_DEG = [float(x) for x in np.arange(-8.0, 8.01, 0.5)]


def frame_result(run, name: str, t_frame: float = 0.0) -> dict:
    """The estimate of the frame at ``t_frame``: Euler errors (estimate - truth; deg, as the
    paper's tables), stars observed/identified, iterations, solved."""
    status = run.values(f"{name}/status")
    rows = np.flatnonzero((np.abs(status[:, 0] - t_frame) < 1e-9) & (status[:, 1] + status[:, 2] >= 1))
    if rows.size == 0:
        raise RuntimeError(f"{name}: no estimate for the frame at t = {t_frame} s")
    i = rows[-1]
    q_hat = run.values(f"{name}/q_IB_hat")[i]
    truth = run.metadata["truth"]["attitude"]
    j = int(np.argmin(np.abs(run.times(truth) - t_frame)))
    q_true = run.values(truth)[j]
    diag = run.values(f"{name}/diagnostics")[i]
    err = np.degrees(rot.quat_to_rpy(q_hat) - rot.quat_to_rpy(q_true))
    err = (err + 180.0) % 360.0 - 180.0
    return {
        "roll": float(err[0]),
        "pitch": float(err[1]),
        "yaw": float(err[2]),
        "total_deg": float(np.degrees(np.linalg.norm(rot.quat_error_rotvec(q_hat, q_true)))),
        "observed": int(diag[0]),
        "identified": int(diag[1]),
        "iterations": int(diag[2]),
        "solved": bool(diag[5] > 0.5),
    }


def offset_override(offset_deg: float) -> str:
    return f"estimators.{EST}.initial_attitude_rpy_deg=[{offset_deg},{offset_deg},{offset_deg}]"


# -- Table 1 --------------------------------------------------------------------------------
def table1(sd):
    rows = {}
    for off in TABLE1_PAPER:
        rows[off] = frame_result(sd.simulate(overrides=[offset_override(off)]), EST)
    fine = {off: frame_result(sd.simulate(overrides=[offset_override(off)]), EST) for off in FINE_OFFSETS_DEG}
    return rows, fine


def screens_sweep(scenario, n_screens: int):
    """Stars identified after one iteration from each offset over ``n_screens`` random
    screens (pattern seeds 0..n-1), with the scenario's camera and solver settings."""
    cam_cfg = scenario.sensors[0]
    est_cfg = scenario.estimators[0]
    counts = np.zeros((n_screens, len(FINE_OFFSETS_DEG)), dtype=int)
    outcome_matches = []
    for k in range(n_screens):
        cam = replace(cam_cfg, pattern_seed=k)
        solver = solver_for(types.SimpleNamespace(sensor_configs={cam.name: cam}), est_cfg)
        xy = camera_geometry(cam).project(np.eye(3))[1]
        frame = CameraCentroids(0.0, True, xy, cam.focal_length_mm * 1e-3, 0.0)
        for j, off in enumerate(FINE_OFFSETS_DEG):
            counts[k, j] = solver.solve(frame, rpy_deg_to_R_BI([off] * 3)).identified
        c = {off: counts[k, FINE_OFFSETS_DEG.index(float(off))] for off in (0, 3, -3, 6, -6)}
        outcome_matches.append(c[0] == len(xy) and c[3] >= 3 and c[-3] >= 3 and c[6] < 3 and c[-6] < 3)
    return counts, outcome_matches


# -- Table 2 --------------------------------------------------------------------------------
def table2(sd, seeds):
    """Per source: per iteration k = 1..5, the mean |error| per axis (deg) and mean stars."""
    out = {}
    for source, over in SOURCES.items():
        deterministic = source != "centroid_noise_0.05px"
        use = seeds[:1] if deterministic else seeds
        errs = np.zeros((len(use), 5, 3))
        stars = np.zeros((len(use), 5))
        for a, seed in enumerate(use):
            for k in range(1, 6):
                r = frame_result(
                    sd.simulate(
                        seed,
                        overrides=over
                        + [
                            offset_override(-2.0),
                            f"estimators.{EST}.max_iterations={k}",
                            f"estimators.{EST}.convergence_tolerance_arcsec=0.0",
                        ],
                    ),
                    EST,
                )
                errs[a, k - 1] = [abs(r["pitch"]), abs(r["roll"]), abs(r["yaw"])]
                stars[a, k - 1] = r["identified"]
        out[source] = {
            "seeds": len(use),
            "mean_abs_error_pitch_roll_yaw_deg": errs.mean(axis=0).tolist(),
            "stars": stars.mean(axis=0).tolist(),
            "mean_iter2to5_1e3deg": (errs[:, 1:].mean(axis=(0, 1)) * 1e3).tolist(),
            "per_seed_abs_error_pitch_roll_yaw_deg": errs.tolist(),
            "per_seed_stars": stars.tolist(),
        }
    return out


# -- naive vs corrected under tilt ------------------------------------------------------------
def naive_vs_corrected(sd):
    out = {"tilt_deg": TILTS_DEG}
    for mode in ("corrected", "naive"):
        ident, err = [], []
        for tilt in TILTS_DEG:
            att = f"[{tilt},{tilt},0.0]"
            r = frame_result(
                sd.simulate(
                    overrides=[
                        f"plant.initial_attitude_rpy_deg={att}",
                        f"estimators.{EST}.initial_attitude_rpy_deg={att}",
                        f"estimators.{EST}.identification={mode}",
                        f"estimators.{EST}.max_iterations=10",
                    ]
                ),
                EST,
            )
            ident.append(r["identified"])
            err.append(r["total_deg"] if r["solved"] else None)
        out[mode] = {"identified": ident, "error_deg": err}
    return out


# -- dynamic test ------------------------------------------------------------------------------
def dynamic_series(run, name):
    status = run.values(f"{name}/status")
    sel = np.flatnonzero(np.r_[np.diff(status[:, 0]) > 1e-9, True] & (status[:, 0] >= 0))
    t = status[sel, 0]
    q_hat = run.values(f"{name}/q_IB_hat")[sel]
    truth = run.metadata["truth"]["attitude"]
    tt = run.times(truth)
    idx = np.clip(np.searchsorted(tt, t - 1e-9), 0, len(tt) - 1)
    q_true = run.values(truth)[idx]
    rpy_hat = np.degrees(rot.quat_to_rpy(q_hat))
    rpy_true = np.degrees(rot.quat_to_rpy(q_true))
    err = (rpy_hat - rpy_true + 180.0) % 360.0 - 180.0
    diag = run.values(f"{name}/diagnostics")[sel]
    return {"t": t, "rpy_hat": rpy_hat, "rpy_true": rpy_true, "err": err, "diag": diag}


def phase_rmse(s, t0, t1, exclude=None, frames_only=False):
    m = (s["t"] >= t0) & (s["t"] < t1)
    if frames_only:  # the camera's frame instants (5 Hz), where the camera-alone estimate is scored
        m &= np.abs(s["t"] / FRAME_PERIOD_S - np.round(s["t"] / FRAME_PERIOD_S)) < 1e-6
    if exclude is not None:
        m &= ~((s["t"] >= exclude[0]) & (s["t"] < exclude[1]))
    return np.sqrt(np.mean(s["err"][m] ** 2, axis=0)).tolist()


NOISY_DYNAMIC_CASES = ("centroid_noise_0.1px", "least_squares_0.1px")


def solver_settings(method: str) -> list[str]:
    """Both estimators with attitude ``method`` and the paper's fixed 0.01 deg tolerance (the
    scenario's own settings are least squares with the noise-derived tolerance)."""
    return [f"estimators.{n}.{f}" for n in (EST, FUSED) for f in (f"attitude_method={method}", "tolerance_sigmas=null")]


def dynamic(sd, seed, only=None):
    """The dynamic test's cases (``only``: a subset of their names) on noise seed ``seed``."""
    cases = {
        "centroid_noise_0.1px": solver_settings("triad"),
        "noise_free": ["sensors.camera.centroid_noise_px=0.0", *solver_settings("triad")],
        "least_squares_0.1px": solver_settings("least_squares"),
    }
    out, series = {}, {}
    for case, over in cases.items():
        if only is not None and case not in only:
            continue
        run = sd.simulate(seed, overrides=over)
        series[case] = {n: dynamic_series(run, n) for n in (EST, FUSED)}
        s, f = series[case][EST], series[case][FUSED]
        outage = (90.0, 95.2)
        first = s["diag"][0]
        out[case] = {
            "swarm_generations_first_frame": int(first[3]),
            "stars_identified_first_frame": int(first[1]),
            "stars_observed_first_frame": int(first[0]),
            "rmse_static_roll_pitch_yaw_deg": phase_rmse(s, 0.0, 40.0),
            "rmse_moving_roll_pitch_yaw_deg": phase_rmse(s, 40.0, 140.01, exclude=outage),
            "fused_rmse_moving_roll_pitch_yaw_deg": phase_rmse(f, 40.0, 140.01, exclude=outage),
            "fused_rmse_moving_at_frames_roll_pitch_yaw_deg": phase_rmse(
                f, 40.0, 140.01, exclude=outage, frames_only=True
            ),
            "outage_max_error_deg": {
                n: float(np.max(np.abs(x["err"][(x["t"] >= outage[0]) & (x["t"] < outage[1])])))
                for n, x in ((EST, s), (FUSED, f))
            },
            "min_stars_identified": int(np.min(s["diag"][s["diag"][:, 5] > 0.5, 1])),
            "frames_failed_outside_outage": int(
                np.sum((s["diag"][:, 5] < 0.5) & ~((s["t"] >= outage[0]) & (s["t"] < outage[1])))
            ),
        }
    return out, series


# -- verdicts ------------------------------------------------------------------------------------
def verdicts(t1, t1_fine, screens, t2, nvc, dyn):
    v = []

    def add(claim, ok, evidence):
        v.append({"claim": claim, "verdict": "reproduced" if ok else "NOT reproduced", "evidence": evidence})

    add(
        "Table 1: exact A0 identifies all 7 stars, error 0",
        t1[0]["identified"] == 7 and t1[0]["total_deg"] < 1e-9,
        f"{t1[0]['identified']} stars, total error {t1[0]['total_deg']:.1e} deg",
    )
    add(
        "Table 1: +-3 deg A0 identifies ~3 stars",
        all(3 <= t1[o]["identified"] <= 4 for o in (3, -3)),
        f"+3: {t1[3]['identified']} stars; -3: {t1[-3]['identified']} stars",
    )
    worst_paper = max(abs(x) for o in (3, -3) for x in TABLE1_PAPER[o][:3])
    worst = max(abs(t1[o][a]) for o in (3, -3) for a in ("pitch", "roll", "yaw"))
    add(
        "Table 1: +-3 deg A0, errors after one iteration within the paper's order (<= 0.0074 deg)",
        worst <= 2.0 * worst_paper,
        f"largest |axis error| {worst:.4f} deg (paper {worst_paper}); per-axis errors depend on which pair the "
        "3 identified stars give TRIAD and on the screen: same order of magnitude is what a random screen can match",
    )
    add(
        "Table 1: +-6 deg A0: identification fails",
        all(not t1[o]["solved"] for o in (6, -6)),
        f"+6: {t1[6]['identified']} stars, -6: {t1[-6]['identified']} stars",
    )
    counts, matches = screens
    j3 = [FINE_OFFSETS_DEG.index(3.0), FINE_OFFSETS_DEG.index(-3.0)]
    j6 = [FINE_OFFSETS_DEG.index(6.0), FINE_OFFSETS_DEG.index(-6.0)]
    ok3 = float(np.mean(counts[:, j3] >= 3))
    ok6 = float(np.mean(counts[:, j6] >= 3))
    add(
        f"Table 1 over {len(counts)} random 7-star screens: +-3 deg mostly works, +-6 deg mostly fails",
        ok3 > 0.7 and ok6 < 0.5,
        f"solved from +-3 deg on {ok3:.0%} of screens (mean {counts[:, j3].mean():.1f} stars), from +-6 deg on "
        f"{ok6:.0%} (mean {counts[:, j6].mean():.1f}); the paper's exact outcome on {sum(matches)} of {len(matches)}",
    )
    nf = t2["noise_free"]["mean_abs_error_pitch_roll_yaw_deg"]
    add(
        "Table 2 trend: iterating from -2 deg raises the stars identified and shrinks the error",
        t2["noise_free"]["stars"][-1] > t2["noise_free"]["stars"][0] and max(nf[-1]) < 1e-3 * max(nf[0]),
        f"noise-free: stars {t2['noise_free']['stars']}, max |error| per iteration (deg) "
        f"{[float(f'{max(e):.1e}') for e in nf]}",
    )
    floors = {s: max(d["mean_iter2to5_1e3deg"]) for s, d in t2.items()}
    near = [s for s, f in floors.items() if 0.3 <= f <= 10.0]
    add(
        "Table 2's ~1e-3 deg floor needs an error source the paper does not state",
        floors["noise_free"] < 0.1 and bool(near),
        "largest mean |error| of iterations 2-5 (1e-3 deg): "
        + ", ".join(f"{s} {f:.2g}" for s, f in floors.items())
        + f" (paper: {max(TABLE2_PAPER_MEAN)}); in the paper's range: {near}",
    )
    yaw_best = {s: d["mean_iter2to5_1e3deg"][2] < min(d["mean_iter2to5_1e3deg"][:2]) for s, d in t2.items()}
    add(
        "Table 2: yaw is the most accurate axis",
        any(yaw_best[s] for s in near),
        "yaw below pitch and roll: " + ", ".join(f"{s} {b}" for s, b in yaw_best.items()),
    )
    tilt_fail = [t for t, n in zip(nvc["tilt_deg"], nvc["naive"]["identified"], strict=True) if n < 3]
    add(
        "Classic (naive) angle matching fails once the table tilts; the corrected one does not",
        bool(tilt_fail) and all(n >= 3 for n in nvc["corrected"]["identified"]),
        f"naive fails from {min(tilt_fail) if tilt_fail else None} deg of roll+pitch tilt; corrected identifies "
        f"{nvc['corrected']['identified']} over tilts {nvc['tilt_deg']} deg",
    )
    d = dyn["noise_free"]
    add(
        "Dynamic test: the swarm gives an A0 good enough to iterate, then all three angles are tracked",
        d["stars_identified_first_frame"] >= 3
        and max(d["rmse_moving_roll_pitch_yaw_deg"]) < 1e-3
        and d["frames_failed_outside_outage"] == 0,
        f"noise-free: first frame {d['stars_identified_first_frame']}/{d['stars_observed_first_frame']} stars after "
        f"{d['swarm_generations_first_frame']} swarm generations; moving-phase RMSE roll/pitch/yaw "
        f"{[f'{x:.1e}' for x in d['rmse_moving_roll_pitch_yaw_deg']]} deg",
    )
    n = dyn["centroid_noise_0.1px"]
    r = n["rmse_moving_roll_pitch_yaw_deg"]
    add(
        "Dynamic test: yaw is measured about as well as roll and pitch (within 3x; 0.1 px centroid noise, TRIAD)",
        r[2] < 3.0 * max(r[0], r[1]),
        f"moving-phase RMSE roll/pitch/yaw {[f'{x:.4f}' for x in r]} deg (yaw / max(roll, pitch) = "
        f"{r[2] / max(r[0], r[1]):.2f})",
    )
    o = n["outage_max_error_deg"]
    add(
        "Beyond the paper: fused with a MEMS gyro, the attitude survives a 5 s camera outage",
        o[FUSED] < 0.1 * o[EST],
        f"max error during the outage: camera alone {o[EST]:.3f} deg, fused {o[FUSED]:.4f} deg",
    )
    ls = dyn["least_squares_0.1px"]["rmse_moving_roll_pitch_yaw_deg"]
    add(
        "Beyond the paper: the least-squares attitude over all identified stars beats TRIAD (>= 2x, every axis)",
        all(a <= 0.5 * b for a, b in zip(ls, r, strict=True)),
        f"moving-phase RMSE roll/pitch/yaw: least squares {[f'{x:.1e}' for x in ls]}, TRIAD "
        f"{[f'{x:.1e}' for x in r]} deg",
    )
    fr = n["fused_rmse_moving_at_frames_roll_pitch_yaw_deg"]
    add(
        "Beyond the paper: fusing the gyro lowers the error at the frame instants (TRIAD, 0.1 px)",
        all(a < b for a, b in zip(fr, r, strict=True)),
        f"moving-phase RMSE at frames roll/pitch/yaw: fused {[f'{x:.1e}' for x in fr]}, camera alone "
        f"{[f'{x:.1e}' for x in r]} deg (between frames, at 50 Hz: {[f'{x:.1e}' for x in n['fused_rmse_moving_roll_pitch_yaw_deg']]})",
    )
    return v


# -- figures ---------------------------------------------------------------------------------------
def plot(t1_fine, screens, t2, nvc, series, out_dir, static_seed):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []

    def save(fig, name):
        path = os.path.join(out_dir, name)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)

    counts, _ = screens
    fig, ax = plt.subplots(1, 2, figsize=(12, 4))
    ax[0].plot(
        FINE_OFFSETS_DEG,
        [t1_fine[o]["identified"] for o in FINE_OFFSETS_DEG],
        "o-",
        label="scenario screen (pattern seed 18)",
    )
    ax[0].plot(FINE_OFFSETS_DEG, counts.mean(axis=0), "s--", label=f"mean over {len(counts)} screens")
    ax[0].axhline(3, color="k", ls=":", lw=0.8, label="3 = fewest for a solution")
    ax[0].set_xlabel("A0 offset on each axis (deg)")
    ax[0].set_ylabel("stars identified (1 iteration)")
    ax[0].legend()
    ax[1].plot(FINE_OFFSETS_DEG, (counts >= 3).mean(axis=0) * 100.0, "o-")
    ax[1].set_xlabel("A0 offset on each axis (deg)")
    ax[1].set_ylabel(f"screens solved (%, of {len(counts)})")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(f"S2 Table 1: where identification breaks (s2_indoor_static, seed {static_seed}, 7 stars)")
    save(fig, "fig_table1_offset_sweep.png")

    fig, axes = plt.subplots(1, len(t2), figsize=(5 * len(t2), 4), sharey=True)
    for ax, (source, d) in zip(axes, t2.items(), strict=True):
        e = np.array(d["mean_abs_error_pitch_roll_yaw_deg"])
        for k, lab in enumerate(("pitch", "roll", "yaw")):
            ax.semilogy(range(1, 6), np.maximum(e[:, k], 1e-12), "o-", label=lab)
        ax.semilogy(
            range(1, 6), np.array(TABLE2_PAPER)[:, :3].max(axis=1) * 1e-3, "k--", lw=0.8, label="paper (max axis)"
        )
        ax.set_title(f"{source} ({d['seeds']} seed{'s' if d['seeds'] > 1 else ''})")
        ax.set_xlabel("iteration")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("mean |error| (deg)")
    axes[0].legend()
    fig.suptitle("S2 Table 2: iterations from A0 = -2 deg, by error source (s2_indoor_static)")
    save(fig, "fig_table2_iterations.png")

    fig, ax = plt.subplots(figsize=(7, 4))
    for mode in ("corrected", "naive"):
        ax.plot(nvc["tilt_deg"], nvc[mode]["identified"], "o-", label=mode)
    ax.set_xlabel("table tilt: roll = pitch (deg), exact A0")
    ax.set_ylabel("stars identified (of 7)")
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("S2: naive vs corrected angle matching under tilt (s2_indoor_static)")
    save(fig, "fig_naive_vs_corrected.png")

    for case, s in series.items():
        fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
        for k, (ax, lab) in enumerate(zip(axes, ("roll", "pitch", "yaw"), strict=True)):
            ax.plot(s[EST]["t"], s[EST]["rpy_true"][:, k], "k-", lw=2.5, alpha=0.4, label="truth")
            ax.plot(s[EST]["t"], s[EST]["rpy_hat"][:, k], "-", lw=1, label="camera alone")
            ax.plot(s[FUSED]["t"], s[FUSED]["rpy_hat"][:, k], "--", lw=1, label="camera + gyro (MEKF)")
            ax.set_ylabel(f"{lab} (deg)")
            ax.grid(alpha=0.3)
        axes[0].legend()
        axes[-1].set_xlabel("t (s)")
        fig.suptitle(f"S2 dynamic test ({case}): truth vs estimate (s2_indoor_dynamic, seed 1)")
        save(fig, f"fig_dynamic_angles_{case}.png")

        fig, axes = plt.subplots(3, 1, figsize=(11, 9), sharex=True)
        for name, ax in ((EST, axes[0]), (FUSED, axes[1])):
            for k, lab in enumerate(("roll", "pitch", "yaw")):
                ax.semilogy(s[name]["t"], np.maximum(np.abs(s[name]["err"][:, k]), 1e-9), lw=0.8, label=lab)
            ax.axvspan(90, 95, color="0.85", label="camera outage")
            ax.set_ylabel(f"|error| (deg)\n{name}")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(ncol=4)
        d = s[EST]["diag"]
        axes[2].plot(s[EST]["t"], d[:, 0], label="stars in view")
        axes[2].plot(s[EST]["t"], d[:, 1], label="stars identified")
        axes[2].plot(s[EST]["t"][:1], d[:1, 1], "r*", ms=12, label=f"swarm start ({int(d[0, 3])} generations)")
        axes[2].set_ylabel("stars")
        axes[2].set_xlabel("t (s)")
        axes[2].legend()
        axes[2].grid(alpha=0.3)
        fig.suptitle(f"S2 dynamic test ({case}): errors and identification (s2_indoor_dynamic, seed 1)")
        save(fig, f"fig_dynamic_errors_{case}.png")
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="noise seeds for Table 2's centroid-noise source")
    ap.add_argument("--screens", type=int, default=100, help="random screens for the Table 1 statistics")
    ap.add_argument("--dynamic-duration", type=float, default=140.0, help="dynamic test length (s), <= 140")
    ap.add_argument(
        "--dynamic-seeds",
        type=int,
        default=1,
        help="noise seeds 1..N of the dynamic test (seed 1 drives the printed table, figures and verdicts; "
        "seeds 2..N run the 0.1 px cases only; every seed's metrics go to results.json's dynamic_per_seed)",
    )
    ap.add_argument("--out", default=os.path.join("out", "indoor_star_tracker"))
    args = ap.parse_args(argv)
    if args.seeds < 1 or args.screens < 1 or args.dynamic_seeds < 1 or not 0 < args.dynamic_duration <= 140.0:
        ap.error("--seeds, --screens and --dynamic-seeds must be >= 1, --dynamic-duration in (0, 140]")
    os.makedirs(args.out, exist_ok=True)
    static = load("s2_indoor_static")
    dyn_scenario = load("s2_indoor_dynamic")
    if args.dynamic_duration < 140.0:
        dyn_scenario = apply_overrides(dyn_scenario, [f"duration_s={args.dynamic_duration}"])
    sd, sdd = diagram_for(static), diagram_for(dyn_scenario)
    seeds = list(range(1, args.seeds + 1))
    print(
        f"Paper S2: static diagram ({static.sensors[0].star_count} stars), dynamic diagram "
        f"({dyn_scenario.sensors[1].star_count} stars, {dyn_scenario.duration_s:g} s)"
    )

    t1, t1_fine = table1(sd)
    screens = screens_sweep(static, args.screens)
    t2 = table2(sd, seeds)
    nvc = naive_vs_corrected(sd)
    dyn, series = dynamic(sdd, 1) if args.dynamic_duration >= 140.0 else ({}, {})
    if not dyn:
        print("(dynamic test shortened: its verdicts need the full 140 s and are skipped)")
    dyn_per_seed = [{"seed": 1, **dyn}] if dyn else []
    for seed in range(2, args.dynamic_seeds + 1) if dyn else ():
        dyn_per_seed.append({"seed": seed, **dynamic(sdd, seed, only=NOISY_DYNAMIC_CASES)[0]})

    print("\n=== Table 1: first frame after one iteration from A0 (deg; pitch / roll / yaw / stars) ===")
    print(f"  {'A0':>5} | {'paper':^38} | {'ours':^44}")
    for off, paper in TABLE1_PAPER.items():
        r = t1[off]
        ours = (
            f"{r['pitch']:+.4f} {r['roll']:+.4f} {r['yaw']:+.4f} {r['identified']:2d}"
            if r["solved"]
            else f"fails ({r['identified']} stars)"
        )
        p = "fails" if paper is None else f"{paper[0]:+.4f} {paper[1]:+.4f} {paper[2]:+.4f} {paper[3]:2d}"
        print(f"  {off:+5.0f} | {p:^38} | {ours:^44}")
    counts, matches = screens
    print("  finer sweep, this screen: " + " ".join(f"{o:+.1f}:{t1_fine[o]['identified']}" for o in FINE_OFFSETS_DEG))
    print(
        f"  over {len(counts)} screens, % solved: "
        + " ".join(f"{o:+.1f}:{100 * np.mean(counts[:, j] >= 3):.0f}" for j, o in enumerate(FINE_OFFSETS_DEG))
    )

    print("\n=== Table 2: iterations from A0 = -2 deg (mean |error| 1e-3 deg; pitch / roll / yaw / stars) ===")
    print("  iter | paper                | " + " | ".join(f"{s:^27}" for s in t2))
    for k in range(5):
        p = TABLE2_PAPER[k]
        cells = []
        for d in t2.values():
            e = np.array(d["mean_abs_error_pitch_roll_yaw_deg"][k]) * 1e3
            cells.append(f"{e[0]:7.3g} {e[1]:7.3g} {e[2]:7.3g} {d['stars'][k]:3.1f}")
        print(f"  {k + 1:4d} | {p[0]:4.1f} {p[1]:4.1f} {p[2]:4.1f} {p[3]:3d}       | " + " | ".join(cells))
    print(
        "  mean 2-5 | "
        + f"{TABLE2_PAPER_MEAN}  | "
        + " | ".join("{:7.3g} {:7.3g} {:7.3g}    ".format(*d["mean_iter2to5_1e3deg"]) for d in t2.values())
    )

    print("\n=== Naive vs corrected matching, table tilted (roll = pitch), exact A0: stars identified ===")
    print("  tilt (deg): " + " ".join(f"{t:5.1f}" for t in nvc["tilt_deg"]))
    for mode in ("corrected", "naive"):
        print(f"  {mode:>10}: " + " ".join(f"{n:5d}" for n in nvc[mode]["identified"]))

    if dyn:
        print("\n=== Dynamic test (50 stars, swarm start; RMSE deg roll / pitch / yaw) ===")
        for case, d in dyn.items():
            print(
                f"  {case}: first frame {d['stars_identified_first_frame']}/{d['stars_observed_first_frame']} "
                f"stars after {d['swarm_generations_first_frame']} swarm generations"
            )
            print(
                "    static 0-40 s      camera alone "
                + " ".join(f"{x:.2e}" for x in d["rmse_static_roll_pitch_yaw_deg"])
            )
            print(
                "    moving 40-140 s    camera alone "
                + " ".join(f"{x:.2e}" for x in d["rmse_moving_roll_pitch_yaw_deg"])
                + "   fused (at frames) "
                + " ".join(f"{x:.2e}" for x in d["fused_rmse_moving_at_frames_roll_pitch_yaw_deg"])
                + "   fused (50 Hz) "
                + " ".join(f"{x:.2e}" for x in d["fused_rmse_moving_roll_pitch_yaw_deg"])
            )
            print(
                f"    outage 90-95 s max error: camera alone {d['outage_max_error_deg'][EST]:.3f} deg, "
                f"fused {d['outage_max_error_deg'][FUSED]:.4f} deg"
            )
        claims = verdicts(t1, t1_fine, screens, t2, nvc, dyn)
        print("\n=== The paper's claims, our evidence " + "=" * 40)
        note = reduced_settings_note(args, ap, ("seeds", "screens", "dynamic_duration"))
        if note:
            print(note)
        for c in claims:
            print(f"  [{c['verdict']}] {c['claim']}\n      {c['evidence']}")
    else:
        claims = []
    figures = plot(t1_fine, screens, t2, nvc, series, args.out, static.seed)
    with open(os.path.join(args.out, "config_s2_indoor_static.yaml"), "w") as f:
        f.write(dump_scenario(static))
    with open(os.path.join(args.out, "config_s2_indoor_dynamic.yaml"), "w") as f:
        f.write(dump_scenario(dyn_scenario))
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(
            {
                "table1": {str(k): v for k, v in t1.items()},
                "table1_fine": {str(k): v for k, v in t1_fine.items()},
                "screens": {
                    "offsets_deg": FINE_OFFSETS_DEG,
                    "identified": counts.tolist(),
                    "paper_outcome_screens": int(sum(matches)),
                },
                "table2": t2,
                "table2_sources": SOURCES,
                "naive_vs_corrected": nvc,
                "dynamic": dyn,
                "dynamic_per_seed": dyn_per_seed,
                "claims": claims,
                "seeds": seeds,
            },
            f,
            indent=1,
        )
    print(f"\nWrote results.json, 2 configs and {len(figures)} figures to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
