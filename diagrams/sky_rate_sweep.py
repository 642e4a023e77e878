#!/usr/bin/env python3
"""A sky star tracker's availability and accuracy against the body rate: where smear costs
accuracy and where lock is lost.

The default sky tracker (``!SkyStarTrackerConfig``: 16 mm f/1.2, 1024x1024 5.5-um pixels,
Hp <= 6.5, 10 Hz, 100-ms exposure unless ``--exposure``) at each rate from 0 to 6 deg/s: per
rate, ``--sequences`` sequences of ``--frames`` frames, each from a random attitude turning
about a random axis at that rate, identified as in flight (the first frame lost-in-space, the
next ones tracked from the tracker's own last solutions, lost-in-space again when tracking
fails). Usage::

    python diagrams/sky_rate_sweep.py                       # 100 sequences x 30 frames per rate
    python diagrams/sky_rate_sweep.py --sequences 5 --out results/sky_rate_sweep

Prints per rate: the smear (px), the valid fraction with its 95% interval (Student t over the
sequences, each one independent draw of star fields and axis), the fraction
tracked, the stars detected and identified, the RMS error across and about the boresight
(arcsec, from the truth) next to the frames' own sigmas, the mean NEES with its chi-square band,
and misidentified stars (must be 0). Writes ``results.json`` and ``rate_sweep.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

from drake_att import rotations as rot
from drake_att.analysis.ensemble import t_q
from drake_att.outputs import script_folder_problem, write_json_atomically
from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model
from drake_att.sky_tracker import MODE_TRACKING, TrackingMemory

RATES_DEG_PER_S = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0)
EPOCH_JYEAR = 2026.0
ARCSEC = math.pi / 180 / 3600
OUR_FILES = ("results.json", "rate_sweep.png")


def over_sequences(fractions) -> tuple[float, float]:
    """The 95% interval of the mean of the sequences' valid fractions (Student t over the
    sequences, clipped to [0, 1]): a sequence's frames share its star fields and turn axis, so
    the sequence, not the frame, is the independent draw."""
    x = np.asarray(fractions, dtype=float)
    if len(x) < 2:
        return (0.0, 1.0)
    half = t_q(0.975, len(x) - 1) * float(np.std(x, ddof=1)) / math.sqrt(len(x))
    return (max(0.0, float(np.mean(x)) - half), min(1.0, float(np.mean(x)) + half))


def chi2_band(dof: int, probability: float = 0.95) -> tuple[float, float]:
    """The two-sided band of a chi-square(dof) variable divided by its count (scipy)."""
    from scipy.stats import chi2  # type: ignore[import-untyped]

    a = 0.5 * (1 - probability)
    return (float(chi2.ppf(a, dof)), float(chi2.ppf(1 - a, dof)))


def sweep_rate(model, rate_deg_per_s: float, sequences: int, frames: int, period_s: float, seed: int) -> dict:
    """Run ``sequences`` x ``frames`` frames at one rate; the raw per-frame numbers' summary.
    The sequences' attitudes and axes and the frames' noise come from two streams of ``seed``:
    the same geometry whatever the image model draws."""
    geometry = np.random.default_rng([seed, 0])
    rng = np.random.default_rng([seed, 1])
    valid = tracked = 0
    per_sequence = []
    errors, sigmas, nees, detected, identified, smear, wrong = [], [], [], [], [], [], 0
    t0 = time.perf_counter()
    for _ in range(sequences):
        q0 = rot.quat_normalize(geometry.standard_normal(4))
        axis = geometry.standard_normal(3)
        valid_before = valid
        w_S = math.radians(rate_deg_per_s) * axis / np.linalg.norm(axis)
        memory = TrackingMemory.empty()
        for k in range(frames):
            t = k * period_s
            q = rot.quat_multiply(q0, rot.rotvec_to_quat(w_S * t))
            f = model.frame(t, q, w_S, memory, rng)
            memory = memory.after(f)
            smear.append(f.smear_px)
            detected.append(f.stars_detected)
            wrong += f.stars_misidentified
            if not f.valid:
                continue
            valid += 1
            tracked += f.mode == MODE_TRACKING
            identified.append(f.stars_identified)
            e = rot.quat_error_rotvec(f.q_IS_meas, q)
            errors.append(e)
            sigmas.append(np.sqrt(np.diag(f.covariance_S)))
            nees.append(float(e @ np.linalg.solve(f.covariance_S, e)))
        per_sequence.append((valid - valid_before) / frames)
    n = sequences * frames
    e = np.array(errors).reshape(-1, 3) / ARCSEC
    s = np.array(sigmas).reshape(-1, 3) / ARCSEC
    return {
        "rate_deg_per_s": rate_deg_per_s,
        "frames": n,
        "valid": valid,
        "valid_interval": over_sequences(per_sequence),
        "tracked": tracked,
        "smear_px": float(np.mean(smear)),
        "detected_mean": float(np.mean(detected)),
        "identified_mean": float(np.mean(identified)) if identified else 0.0,
        "rms_cross_arcsec": float(np.sqrt(np.mean(e[:, :2] ** 2))) if valid else None,
        "rms_boresight_arcsec": float(np.sqrt(np.mean(e[:, 2] ** 2))) if valid else None,
        "sigma_cross_arcsec": float(np.sqrt(np.mean(s[:, :2] ** 2))) if valid else None,
        "sigma_boresight_arcsec": float(np.sqrt(np.mean(s[:, 2] ** 2))) if valid else None,
        "nees_mean": float(np.mean(nees)) if valid else None,
        "nees_band": [b / valid for b in chi2_band(3 * valid)] if valid else None,
        "misidentified": int(wrong),
        "ms_per_frame": 1e3 * (time.perf_counter() - t0) / n,
    }


def figure(rows, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = [x["rate_deg_per_s"] for x in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    avail = [x["valid"] / x["frames"] for x in rows]
    lo = [x["valid_interval"][0] for x in rows]
    hi = [x["valid_interval"][1] for x in rows]
    yerr = np.maximum(0.0, [np.subtract(avail, lo), np.subtract(hi, avail)])  # round-off at 0 and 1
    a.errorbar(r, avail, yerr=yerr, marker="o", capsize=3)
    a.plot(r, [x["tracked"] / x["frames"] for x in rows], "s--", label="tracked")
    a.set_xlabel("body rate (deg/s)")
    a.set_ylabel("fraction of frames")
    a.set_title("availability (valid; 95% over sequences)")
    a.set_ylim(-0.02, 1.02)
    a.grid(alpha=0.3)
    a.legend(["tracked", "valid"], loc="lower left")
    ok = [x for x in rows if x["valid"]]
    rr = [x["rate_deg_per_s"] for x in ok]
    b.semilogy(rr, [x["rms_cross_arcsec"] for x in ok], "o-", label="cross-boresight RMS")
    b.semilogy(rr, [x["rms_boresight_arcsec"] for x in ok], "s-", label="about boresight RMS")
    b.semilogy(rr, [x["sigma_cross_arcsec"] for x in ok], "o:", color="C0", alpha=0.6, label="cross sigma (frames')")
    b.semilogy(rr, [x["sigma_boresight_arcsec"] for x in ok], "s:", color="C1", alpha=0.6, label="boresight sigma")
    b.set_xlabel("body rate (deg/s)")
    b.set_ylabel("arcsec")
    b.set_title("accuracy of valid frames")
    b.grid(alpha=0.3, which="both")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequences", type=int, default=100)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--exposure", type=float, default=None, help="exposure (s); default the detector's")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None, help="folder for results.json and rate_sweep.png")
    args = ap.parse_args(argv)
    problem = args.out and script_folder_problem(args.out, OUR_FILES, "results.json", "rows")
    if problem:
        print(f"sky_rate_sweep.py: {problem}", file=sys.stderr)
        return 2
    if args.sequences < 1 or args.frames < 2:
        ap.error(f"--sequences {args.sequences}, --frames {args.frames}: need >= 1 and >= 2")
    config = SkyStarTrackerConfig()
    if args.exposure is not None:
        config.detector.exposure_s = args.exposure
    model = sky_tracker_model(config, EPOCH_JYEAR)
    print(
        f"Sky tracker: {config.camera.focal_length_mm:g} mm, {config.camera.width_px}x{config.camera.height_px} px, "
        f"exposure {config.detector.exposure_s * 1e3:g} ms, Hp <= {config.identification.magnitude_limit:g}; "
        f"{args.sequences} sequences x {args.frames} frames per rate",
        flush=True,
    )
    rows = []
    for j, rate in enumerate(RATES_DEG_PER_S):
        rows.append(sweep_rate(model, rate, args.sequences, args.frames, config.period_s, args.seed + 1000 * j))
    print(
        f"\n{'rate':>5} {'smear':>6} {'valid (95%)':>20} {'track':>6} {'det':>5} {'id':>5} "
        f"{'cross':>7} {'sig':>6} {'bore':>7} {'sig':>6} {'NEES':>5} {'wrong':>5}"
    )
    print(f"{'deg/s':>5} {'px':>6} {'':>20} {'':>6} {'':>5} {'':>5} {'arcsec':>7} {'':>6} {'arcsec':>7}")
    for x in rows:
        lo, hi = x["valid_interval"]
        v = f"{x['valid'] / x['frames']:.3f} [{lo:.3f},{hi:.3f}]"
        if x["valid"]:
            acc = (
                f"{x['rms_cross_arcsec']:>7.2f} {x['sigma_cross_arcsec']:>6.2f} "
                f"{x['rms_boresight_arcsec']:>7.1f} {x['sigma_boresight_arcsec']:>6.1f} {x['nees_mean']:>5.2f}"
            )
        else:
            acc = f"{'-':>7} {'-':>6} {'-':>7} {'-':>6} {'-':>5}"
        print(
            f"{x['rate_deg_per_s']:>5.2f} {x['smear_px']:>6.1f} {v:>20} {x['tracked'] / x['frames']:>6.3f} "
            f"{x['detected_mean']:>5.1f} {x['identified_mean']:>5.1f} {acc} {x['misidentified']:>5}"
        )
    wrong = sum(x["misidentified"] for x in rows)
    print(f"\n[{'holds' if wrong == 0 else 'DOES NOT HOLD'}] no star misidentified in a valid frame")
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        figure(rows, os.path.join(args.out, "rate_sweep.png"))
        write_json_atomically(
            os.path.join(args.out, "results.json"),
            {
                "config": {
                    "sequences": args.sequences,
                    "frames": args.frames,
                    "seed": args.seed,
                    "exposure_s": config.detector.exposure_s,
                    "epoch_jyear": EPOCH_JYEAR,
                },
                "rows": rows,
            },
        )
        print(f"Wrote results.json and rate_sweep.png to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
