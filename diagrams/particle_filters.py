#!/usr/bin/env python3
"""Reproduce paper S0: particle filters vs an MRP EKF for star-sensor + gyro attitude
determination (Figs. 2-6 and the paper's four claims), plus the bootstrap-PF bias remedy.

Three scenarios (``drake_att/scenarios/s0_*.yaml``), each ONE diagram per seed in which all
of its filters see the same truth and the same gyro and star-sensor noise realization:

* ``s0_particle_filters_small_error``: EKF, bootstrap PF (paper; and with the gyro's true
  ARW as attitude process noise), bootstrap PF with bias roughening (beyond the paper), EKPF;
* ``s0_particle_filters_large_error``: EKF and EKPF from [12, -10, 170] deg, plus the
  iterated variants (beyond the paper) that separate what the particles buy from what the
  iterated linearization buys;
* ``s0_gyroless_pf``: bootstrap PF with Euler's equations instead of a gyro.

The Monte Carlo repeats each scenario over seeds (``drake_att.analysis.executor``).  The
script prints the paper's four claims with our numbers next to each and a verdict computed
from the runs, the wall time of every 1000-s scenario, the time per step of each filter in
its own diagram, and an EKF-only sweep over the initial yaw error.  Usage::

    python diagrams/particle_filters.py                       # 5 seeds x 1000 s, N = 1000
    python diagrams/particle_filters.py --seeds 2 --particles 300 --duration 300 --out /tmp/s0

Writes to ``--out``: ``results.json`` (every seed's metrics, the claims with their numbers,
wall times), ``config_<scenario>.yaml`` (the scenarios exactly as run) and the figures
``fig2_bootstrap_pf_small_error.png``, ``fig3_ekpf_small_error.png``,
``fig4_5_large_error.png``, ``fig6_gyroless.png``, ``fig_ekf_initial_error_sweep.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from drake_att.analysis.executor import run_seeds
from drake_att.analysis.report import plot_error_grid
from drake_att.analysis.reproduction import reduced_settings_note
from drake_att.estimators.bootstrap_pf_plugin import BootstrapPfConfig
from drake_att.estimators.ekpf_plugin import EkpfConfig
from drake_att.estimators.gyroless_pf_plugin import GyrolessPfConfig
from drake_att.noise import DEG, DEG_PER_H
from drake_att.scenarios import builder as _builder
from drake_att.scenarios import config as cfg
from drake_att.scenarios.config import apply_overrides, dump_scenario
from drake_att.scenarios.library import load

SCENARIOS = {
    "small": "s0_particle_filters_small_error",
    "large": "s0_particle_filters_large_error",
    "gyroless": "s0_gyroless_pf",
}
PARTICLE_CONFIGS = (BootstrapPfConfig, EkpfConfig, GyrolessPfConfig)

# Paper S0's reported figures, typed in for COMPARISON only (never used in a verdict except
# as the reference a "class" is measured against: within a factor CLASS_FACTOR).
PAPER_EKPF_ATTITUDE_DEG = 0.002
PAPER_EKPF_BIAS_DEG_PER_S = 0.00005
PAPER_GYROLESS_ATTITUDE_DEG = 0.01
PAPER_GYROLESS_RATE_DEG_PER_S = 0.004
CLASS_FACTOR = 3.0
INITIAL_BIAS_ERROR_DEG_PER_H = float(np.linalg.norm([1.0, 1.0, 1.0]))  # estimate 2, truth 1 deg/h


def prepare(name: str, particles: int, duration: float) -> cfg.Scenario:
    """A shipped S0 scenario with the run length and particle count of this study."""
    s = load(name)
    over = [f"duration_s={duration}", f"scoring.score_from_s={duration / 2}"]
    over += [f"estimators.{e.name}.num_particles={particles}" for e in s.estimators if isinstance(e, PARTICLE_CONFIGS)]
    return apply_overrides(s, over)


# --------------------------------------------------------------------------------------
# Statistics over seeds
# --------------------------------------------------------------------------------------
def per_seed(results, estimator, key):
    return [r["metrics"]["estimators"][estimator][key] for r in results]


def stable_mask(series, frac=0.5):
    t = series["t"]
    return t >= t[-1] * frac - 1e-9


def rms_norm(x):
    return float(np.sqrt(np.mean(np.sum(x**2, axis=1))))


def final_norm(series, key, scale, frac=0.9):
    """RMS norm of an error over the last 10 % of the run, in units of ``scale``."""
    m = series["t"] >= series["t"][-1] * frac - 1e-9
    return rms_norm(series[key][m] / scale)


def mean_axis(results, estimator, key):
    vals = np.array([v for v in per_seed(results, estimator, key) if v is not None], dtype=float)
    return vals.mean(axis=0)


def verdict(ok: bool) -> str:
    return "holds" if ok else "does not hold"


# --------------------------------------------------------------------------------------
# The paper's claims, evaluated on our runs
# --------------------------------------------------------------------------------------
def evaluate_claims(res: dict, threshold_deg: float, particles: int) -> tuple[list[dict], str]:
    small, large, gyroless = res["small"], res["large"], res["gyroless"]
    claims, lines = [], []

    def add(title, ok, evidence, extra=None):
        claims.append({"claim": title, "holds": bool(ok), "evidence": evidence, **(extra or {})})
        lines.append(f"\n[{verdict(ok)}] {title}")
        lines.extend(f"    {e}" for e in evidence)

    # (1) Bootstrap PF, small error: attitude converges, bias does not.
    n = len(small)
    att = {
        e: mean_axis(small, e, "attitude_rmse_deg")
        for e in ("ekf", "bootstrap_pf", "bootstrap_pf_true_arw", "bootstrap_pf_roughened", "ekpf")
    }
    att_tot = {e: float(np.mean(per_seed(small, e, "attitude_rmse_total_deg"))) for e in att}
    conv = {e: per_seed(small, e, "convergence_time_s") for e in att}
    b_final_seeds = {e: [final_norm(r["series"][e], "second_err", DEG_PER_H) for r in small] for e in att}
    b_final = {e: float(np.mean(v)) for e, v in b_final_seeds.items()}
    b_rmse = {e: float(np.mean([np.linalg.norm(v) for v in per_seed(small, e, "bias_rmse_deg_per_h")])) for e in att}
    b_sigma_end_seeds = {e: [np.linalg.norm(r["series"][e]["sigma"][-1, 3:]) / DEG_PER_H for r in small] for e in att}
    b_sigma_end = {e: float(np.mean(v)) for e, v in b_sigma_end_seeds.items()}
    bpf_att_ok = all(c is not None for c in conv["bootstrap_pf"]) and att_tot["bootstrap_pf"] < threshold_deg
    bpf_bias_frozen = b_final["bootstrap_pf"] > 0.25 * INITIAL_BIAS_ERROR_DEG_PER_H
    add(
        "1. Bootstrap PF, small initial error: the attitude converges, the gyro bias does not "
        "(sample impoverishment, b_k+1 = b_k)",
        bpf_att_ok and bpf_bias_frozen,
        [
            f"attitude RMSE, stable stage (mean of {n} seeds): bootstrap_pf {att_tot['bootstrap_pf']:.4f} deg total "
            f"(x/y/z {' '.join(f'{v:.4f}' for v in att['bootstrap_pf'])}), converged (<{threshold_deg} deg) in "
            f"{sum(c is not None for c in conv['bootstrap_pf'])}/{n} seeds; EKF {att_tot['ekf']:.4f} deg",
            f"bias error |b - b_hat|, last 10% of the run: bootstrap_pf {b_final['bootstrap_pf']:.3f} deg/h "
            f"(initial error {INITIAL_BIAS_ERROR_DEG_PER_H:.2f} deg/h; 'does not converge' = more than 25% of it left) "
            f"vs EKF {b_final['ekf']:.4f} deg/h",
            f"particle bias spread at the end (1-sigma norm): bootstrap_pf {b_sigma_end['bootstrap_pf']:.2e} deg/h "
            f"(collapsed) vs EKF sigma {b_sigma_end['ekf']:.2e} deg/h",
            f"paper-literal attitude process noise (the gyro's ARW): bootstrap_pf_true_arw attitude "
            f"{att_tot['bootstrap_pf_true_arw']:.4f} deg, converged in "
            f"{sum(c is not None for c in conv['bootstrap_pf_true_arw'])}/{n} seeds: with {particles} particles the "
            f"cloud cannot follow the truth without an inflated attitude noise (ours: 2e-5 rad/s^0.5)",
            f"beyond the paper, same data: bias roughening -> bias error {b_final['bootstrap_pf_roughened']:.3f} deg/h "
            f"(stable-stage RMSE {b_rmse['bootstrap_pf_roughened']:.3f} vs {b_rmse['bootstrap_pf']:.3f} deg/h frozen, "
            f"{b_rmse['bootstrap_pf'] / max(b_rmse['bootstrap_pf_roughened'], 1e-12):.1f}x better), attitude "
            f"{att_tot['bootstrap_pf_roughened']:.4f} deg; still far from the EKF's {b_rmse['ekf']:.4f} deg/h",
        ],
        {
            "attitude_rmse_total_deg": att_tot,
            "bias_error_final_deg_per_h": b_final,
            "bias_rmse_deg_per_h": b_rmse,
            "bias_sigma_final_deg_per_h": b_sigma_end,
            "per_seed": {
                "bias_error_final_deg_per_h": b_final_seeds,
                "bias_sigma_final_deg_per_h": b_sigma_end_seeds,
            },
        },
    )

    # (2) EKPF small error: ~0.002 deg, comparable to the EKF.
    ratio = att_tot["ekpf"] / att_tot["ekf"]
    ekpf_axes = att["ekpf"]
    ok2a = bool(
        np.max(ekpf_axes) <= CLASS_FACTOR * PAPER_EKPF_ATTITUDE_DEG and all(c is not None for c in conv["ekpf"])
    )
    ok2b = bool(0.5 <= ratio <= 2.0)
    add(
        "2. EKPF, small initial error: converges, attitude ~0.002 deg (a), comparable to the EKF (b)",
        ok2a and ok2b,
        [
            f"(a) {verdict(ok2a)}: EKPF attitude RMSE per axis x/y/z {' '.join(f'{v:.4f}' for v in ekpf_axes)} deg "
            f"(paper ~{PAPER_EKPF_ATTITUDE_DEG}; 'class' = within {CLASS_FACTOR:g}x), total {att_tot['ekpf']:.4f} deg; "
            f"converged (<{threshold_deg} deg) in {sum(c is not None for c in conv['ekpf'])}/{n} seeds",
            f"(b) {verdict(ok2b)}: EKF attitude RMSE per axis {' '.join(f'{v:.4f}' for v in att['ekf'])} deg, "
            f"total {att_tot['ekf']:.4f} deg; EKPF/EKF = {ratio:.2f} ('comparable' = between 0.5 and 2)",
            f"bias RMSE: EKPF {b_rmse['ekpf']:.3f} deg/h = {b_rmse['ekpf'] / 3600:.6f} deg/s "
            f"(paper {PAPER_EKPF_BIAS_DEG_PER_S} deg/s), EKF {b_rmse['ekf']:.4f} deg/h",
            "the EKPF redraws every particle from its EKF posterior at each step (a kernel jitter), so its weighted "
            "mean carries Monte Carlo noise on top of the EKF-level error",
        ],
        {
            "ekpf_attitude_rmse_deg": ekpf_axes.tolist(),
            "ekf_attitude_rmse_deg": att["ekf"].tolist(),
            "ekpf_over_ekf": ratio,
            "part_a_holds": ok2a,
            "part_b_holds": ok2b,
        },
    )

    # (3) Large error: EKPF converges, EKF does not.
    n = len(large)
    names = [e for e in ("ekf", "ekpf", "ekpf_iterated", "ekf_iterated") if e in large[0]["metrics"]["estimators"]]
    convl = {e: per_seed(large, e, "convergence_time_s") for e in names}
    fin_seeds = {e: [final_norm(r["series"][e], "dtheta", DEG) for r in large] for e in names}
    fin = {e: float(np.mean(v)) for e, v in fin_seeds.items()}
    at100, at100_seeds = {}, {}
    for e in names:
        vals = []
        for r in large:
            s = r["series"][e]
            k = min(np.searchsorted(s["t"], 100.0), len(s["t"]) - 1)
            vals.append(np.linalg.norm(s["dtheta"][k]) / DEG)
        at100[e] = float(np.mean(vals))
        at100_seeds[e] = vals

    def nconv(e):
        return sum(c is not None for c in convl[e])

    ekf_fails = nconv("ekf") == 0
    lines_ev = [
        f"{e:<14} converged (<{threshold_deg} deg to the end) in {nconv(e)}/{n} seeds; |error| at t=100 s "
        f"{at100[e]:.3f} deg, last 10% {fin[e]:.4f} deg"
        + (f"; convergence time {np.mean([c for c in convl[e] if c is not None]):.0f} s" if nconv(e) else "")
        for e in names
    ]
    ok3_paper = nconv("ekpf") == n and ekf_fails
    add(
        "3. Large initial error [12,-10,170] deg: the EKPF converges, the EKF does not -- with the paper's EKPF "
        "(one EKF linearization per particle)",
        ok3_paper,
        lines_ev
        + [
            "our EKF does not diverge (the shadow-set switch keeps the MRP bounded) but creeps: its 1-deg P0 "
            "makes it overconfident, the error falls roughly like 1/t; the paper-literal EKPF creeps the same "
            "way because each particle's EKF step is the same local step (see fig4_5_large_error.png)"
        ],
        {
            "converged_seeds": {e: nconv(e) for e in names},
            "final_error_deg": fin,
            "error_at_100s_deg": at100,
            "per_seed": {"final_error_deg": fin_seeds, "error_at_100s_deg": at100_seeds},
        },
    )
    if "ekpf_iterated" in names:
        ok3_it = nconv("ekpf_iterated") == n and ekf_fails
        extra = ""
        if "ekf_iterated" in names:
            extra = (
                f"; but the iterated EKF (no particles) converges as well ({nconv('ekf_iterated')}/{n}): "
                "the iteration, not the particle set, removes the large error"
            )
        add(
            "3b. (beyond the paper) same, EKPF with the iterated-EKF proposal (<= 10 linearizations per particle)",
            ok3_it,
            [f"ekpf_iterated converged in {nconv('ekpf_iterated')}/{n} seeds, EKF in {nconv('ekf')}/{n}" + extra],
        )

    # (4) Gyroless PF: ~0.01 deg attitude, ~0.004 deg/s rate.
    n = len(gyroless)
    g_names = list(gyroless[0]["metrics"]["estimators"])
    g_att = {e: float(np.mean(per_seed(gyroless, e, "attitude_rmse_total_deg"))) for e in g_names}
    g_rate = {
        e: float(np.mean([np.linalg.norm(v) for v in per_seed(gyroless, e, "rate_rmse_deg_per_s")])) for e in g_names
    }
    g_conv = {e: sum(c is not None for c in per_seed(gyroless, e, "convergence_time_s")) for e in g_names}
    g_peak_rate_seeds = {
        e: [np.max(np.linalg.norm(r["series"][e]["second_err"], axis=1)) / DEG for r in gyroless] for e in g_names
    }
    g_peak_rate = {e: float(np.mean(v)) for e, v in g_peak_rate_seeds.items()}
    g_peak_att, g_peak_att_seeds = {}, {}
    for e in g_names:
        vals = []
        for r in gyroless:
            s = r["series"][e]
            m = s["t"] >= 0.1 * s["t"][-1]
            vals.append(np.max(np.linalg.norm(s["dtheta"][m], axis=1)) / DEG)
        g_peak_att[e] = float(np.mean(vals))
        g_peak_att_seeds[e] = vals
    ok4 = (
        g_att["gyroless_pf"] <= CLASS_FACTOR * PAPER_GYROLESS_ATTITUDE_DEG
        and g_rate["gyroless_pf"] <= CLASS_FACTOR * PAPER_GYROLESS_RATE_DEG_PER_S
    )
    add(
        "4. Gyroless bootstrap PF: attitude ~0.01 deg, rate ~0.004 deg/s (at least that accurate)",
        ok4,
        [
            f"{e:<18} attitude RMSE (stable stage) {g_att[e]:.4f} deg, rate RMSE {g_rate[e]:.2e} deg/s, converged "
            f"{g_conv[e]}/{n} seeds; transient: peak |attitude error| after 10% of the run {g_peak_att[e]:.3f} deg, "
            f"peak |rate error| {g_peak_rate[e]:.4f} deg/s"
            for e in g_names
        ]
        + [
            f"paper: {PAPER_GYROLESS_ATTITUDE_DEG} deg and {PAPER_GYROLESS_RATE_DEG_PER_S} deg/s; ours is more "
            "accurate in the stable stage (the filter's Euler model, inertia and torque, is exact here); the "
            "paper-literal variant (rate noise only) shows the paper's slow oscillating transient of that size "
            "(fig6_gyroless.png), which the attitude process noise removes"
        ],
        {
            "attitude_rmse_total_deg": g_att,
            "rate_rmse_deg_per_s": g_rate,
            "peak_rate_error_deg_per_s": g_peak_rate,
            "peak_attitude_error_after_10pct_deg": g_peak_att,
            "per_seed": {
                "peak_rate_error_deg_per_s": g_peak_rate_seeds,
                "peak_attitude_error_after_10pct_deg": g_peak_att_seeds,
            },
        },
    )
    return claims, "\n".join(lines)


# --------------------------------------------------------------------------------------
# Extra studies
# --------------------------------------------------------------------------------------
def ekf_initial_error_sweep(sd, duration, seed, yaw_errors_deg=(5, 10, 20, 30, 45, 60, 90, 120, 150, 170, 179)):
    """The EKF alone (the particle filters switched off) for each initial yaw error (roll/pitch
    error 0), on the same data (one seed), on the large-error scenario's diagram ``sd``: the
    initial estimate is a context parameter, so no diagram is built."""
    from drake_att.analysis.metrics import compute_metrics, estimator_errors

    rows = []
    for yaw in yaw_errors_deg:
        run = sd.simulate(
            seed,
            estimators=["ekf"],
            overrides=[
                f"estimators.ekf.initial_attitude_rpy_deg=[0.0, 0.0, {float(yaw)}]",
                f"duration_s={duration}",
                f"scoring.score_from_s={duration / 2}",
            ],
        )
        m = compute_metrics(run)["estimators"]["ekf"]
        err = estimator_errors(run, "ekf")
        rows.append(
            {
                "initial_yaw_error_deg": yaw,
                "convergence_time_s": m["convergence_time_s"],
                "final_error_deg": float(np.linalg.norm(err["dtheta"][-1]) / DEG),
                "t": err["t"],
                "error_norm_deg": np.linalg.norm(err["dtheta"], axis=1) / DEG,
            }
        )
    return rows


def time_filters(diagrams, seed=1):
    """Wall time of each filter alone in its scenario's diagram (the others switched off),
    minus the sensors-only run (all switched off); ``diagrams``: key -> ScenarioDiagram."""
    rows = []
    for key in ("small", "large", "gyroless"):
        sd = diagrams[key]
        s = sd.scenario
        t_base = sd.simulate(seed, estimators=[]).wall_time_s
        for e in s.estimators:
            wall = sd.simulate(seed, estimators=[e.name]).wall_time_s
            steps = int(round(s.duration_s / e.period_s)) + 1
            rows.append(
                {
                    "scenario": s.name,
                    "estimator": e.name,
                    "type": type(e).__name__,
                    "particles": getattr(e, "num_particles", 1),
                    "wall_s": wall,
                    "sensors_only_s": t_base,
                    "ms_per_step": 1e3 * (wall - t_base) / steps,
                }
            )
    return rows


# --------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_axes(series, names, second_scale, second_unit, second_label, path, title, att_ylim=None, sec_ylim=None):
    """Paper style: per-axis attitude error (top) and bias/rate error (bottom) vs time."""
    plot_error_grid(
        series, names, path, title, second_scale, second_unit, second_label, att_ylim=att_ylim, sec_ylim=sec_ylim
    )


def plot_norms(series, names, path, title):
    """Paper Figs. 4-5 style: attitude and bias error norms (log scale)."""
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(13, 4.5))
    for name in names:
        s = series[name]
        ax[0].semilogy(s["t"], np.linalg.norm(s["dtheta"], axis=1) / DEG, lw=0.8, label=name)
        ax[1].semilogy(s["t"], np.linalg.norm(s["second_err"], axis=1) / DEG_PER_H, lw=0.8, label=name)
    ax[0].set_ylabel("|attitude error| (deg)")
    ax[1].set_ylabel("|bias error| (deg/h)")
    for a in ax:
        a.set_xlabel("time (s)")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sweep(rows, path, threshold_deg):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in rows:
        ax.semilogy(r["t"], r["error_norm_deg"], lw=0.8, label=f"{r['initial_yaw_error_deg']} deg")
    ax.axhline(threshold_deg, color="k", ls="--", lw=0.8, label="threshold")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("|attitude error| (deg)")
    ax.set_title("MRP EKF (P0 = 1 deg) vs initial yaw error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    return x


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="number of seeds (1..N)")
    parser.add_argument("--particles", type=int, default=1000, help="particles per particle filter")
    parser.add_argument("--duration", type=float, default=1000.0, help="simulated time per run (s)")
    parser.add_argument("--out", default=os.path.join("out", "particle_filters"), help="output folder")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: CPUs)")
    parser.add_argument("--no-timing", action="store_true", help="skip the per-filter timing runs")
    parser.add_argument("--no-sweep", action="store_true", help="skip the EKF initial-error sweep")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    seeds = list(range(1, args.seeds + 1))
    print(f"Paper S0: {args.seeds} seeds x {args.duration:g} s, N = {args.particles} particles, out = {args.out}")

    res, walls, scen = {}, {}, {}
    for key, name in SCENARIOS.items():
        s = prepare(name, args.particles, args.duration)
        scen[key] = s
        with open(os.path.join(args.out, f"config_{name}.yaml"), "w") as f:
            f.write(dump_scenario(s))
        t0 = time.perf_counter()
        res[key] = run_seeds(s, seeds, workers=args.workers, keep_series_for=seeds)
        total = time.perf_counter() - t0
        per_run = [r["metrics"]["wall_time_s"] for r in res[key]]
        walls[name] = {
            "per_seed_s": per_run,
            "mean_s": float(np.mean(per_run)),
            "monte_carlo_total_s": total,
            "estimators": [e.name for e in s.estimators],
        }
        print(
            f"  {name}: {len(s.estimators)} filters in one diagram, {args.duration:g} s simulated: "
            f"{np.mean(per_run):.1f} s wall per seed (min {min(per_run):.1f}, max {max(per_run):.1f}); "
            f"{args.seeds} seeds in {total:.1f} s"
        )

    threshold = scen["small"].scoring.convergence_threshold_deg
    claims, text = evaluate_claims(res, threshold, args.particles)
    note = reduced_settings_note(args, parser, ("seeds", "particles", "duration", "no_timing", "no_sweep"))
    print("\n=== The paper's claims, our evidence " + "=" * 50 + (f"\n{note}" if note else "") + text)

    # This process builds one diagram per scenario (pydrake 1.51 never frees diagrams; the
    # Monte Carlo's, when it ran here); the sweep and the timing runs change contexts.
    def diagram(key):
        return _builder.diagram_for(scen[key])

    sweep = None
    if not args.no_sweep:
        sweep = ekf_initial_error_sweep(diagram("large"), args.duration, seeds[0])
        print("\nEKF (P0 = 1 deg, no particles) vs initial yaw error, seed 1:")
        for r in sweep:
            c = r["convergence_time_s"]
            print(
                f"  yaw error {r['initial_yaw_error_deg']:>4} deg: "
                f"{f'converged at {c:.0f} s' if c is not None else 'not converged':<22} "
                f"|error| at the end {r['final_error_deg']:.4f} deg"
            )
        plot_sweep(sweep, os.path.join(args.out, "fig_ekf_initial_error_sweep.png"), threshold)

    timing = None
    if not args.no_timing:
        timing = time_filters({k: diagram(k) for k in SCENARIOS})
        print(
            f"\nWall time of each filter alone ({args.duration:g} s, seed 1; per step = (wall - sensors-only) / steps):"
        )
        for r in timing:
            print(
                f"  {r['scenario']:<34} {r['estimator']:<24} N={r['particles']:<5} {r['wall_s']:7.2f} s"
                f"  {r['ms_per_step']:7.3f} ms/step"
            )

    # Figures (seed 1).
    s1 = {k: res[k][0]["series"] for k in res}
    plot_axes(
        s1["small"],
        ["bootstrap_pf", "bootstrap_pf_roughened"],
        DEG_PER_H,
        "deg/h",
        "bias error",
        os.path.join(args.out, "fig2_bootstrap_pf_small_error.png"),
        "Fig. 2: bootstrap PF, small initial error (seed 1): attitude converges, bias (paper) does not",
        att_ylim=(-0.05, 0.05),
    )
    plot_axes(
        s1["small"],
        ["ekpf", "ekf"],
        DEG_PER_H,
        "deg/h",
        "bias error",
        os.path.join(args.out, "fig3_ekpf_small_error.png"),
        "Fig. 3: EKPF vs EKF, small initial error (seed 1)",
        att_ylim=(-0.02, 0.02),
    )
    plot_norms(
        s1["large"],
        list(s1["large"]),
        os.path.join(args.out, "fig4_5_large_error.png"),
        "Figs. 4-5: large initial error [12, -10, 170] deg (seed 1)",
    )
    plot_axes(
        s1["gyroless"],
        list(s1["gyroless"]),
        DEG,
        "deg/s",
        "rate error",
        os.path.join(args.out, "fig6_gyroless.png"),
        "Fig. 6: gyroless bootstrap PF (seed 1)",
        att_ylim=(-0.05, 0.05),
    )

    out = {
        "seeds": seeds,
        "particles": args.particles,
        "duration_s": args.duration,
        "claims": claims,
        "claims_text": text,
        "wall_time_s": walls,
        "timing_per_filter": timing,
        "ekf_initial_error_sweep": None
        if sweep is None
        else [{k: v for k, v in r.items() if k not in ("t", "error_norm_deg")} for r in sweep],
        "metrics": {SCENARIOS[k]: [r["metrics"] for r in v] for k, v in res.items()},
    }
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(_jsonable(out), f, indent=1)
    print(f"\nWrote results.json, config_*.yaml and figures to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
