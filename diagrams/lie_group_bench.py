#!/usr/bin/env python3
"""Paper S4 beyond the paper: the Lie-group filter, with and without a gyro-bias state, on
the S0 and S3 scenarios next to their MEKF / MRP EKF, on the same noise.

Each scenario gets Lie-group estimators appended (a structural change: one diagram per
scenario per process, :func:`drake_att.scenarios.builder.diagram_for`), all started from
the initial estimate and sigmas of the scenario's own Kalman filter and tuned from the
scenario's gyro and star tracker:

* ``lie_group``: the paper's filter (consistent formulation, no bias state) with the
  paper's process noise ``Q_w = 5e-5 rad^2`` per 1 s step plus the gyro's ARW;
* ``lie_group_arw``: the same filter with the gyro's ARW only (``Q_w = 0``): the honest
  tuning of a filter that ignores the bias;
* ``lie_group_bias``: the bias extension (SO(3) x R^3, the gyro's ARW and RRW);
* S0 only: ``mekf`` (:class:`MekfConfig`), so that the bias extension meets an MEKF there
  too (S3's ``single`` is one).

The particle filters of S0 are switched off (``simulate(estimators=[...])``). Star-vector
noise: the tracker's sigma (``star_noise_from_tracker``); a quaternion-mode tracker (S3)
brings its own noise model.

Per scenario: a table of attitude RMSE per axis and total, gyro-bias RMSE (bias filters),
NEES (6-dof as the metrics layer defines it, and the attitude-only 3-dof NEES, comparable
for every filter), convergence time, pooled over the seeds (RMSE: root mean square of the
per-seed values; NEES: mean; convergence: median over the seeds that converged), plus the
largest difference between ``lie_group_bias`` and the MEKF of the scenario. Saves
``results.json`` (with each scenario's YAML as run) and ``config_<scenario>.yaml``.

    python diagrams/lie_group_bench.py [--seeds 5] [--duration SECONDS] [--out out/lie_group_bench]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time

import numpy as np

from drake_att.analysis.metrics import compute_metrics, estimator_errors
from drake_att.estimators.lie_group_plugin import LieGroupConfig
from drake_att.estimators.mekf_plugin import MekfConfig
from drake_att.estimators.mrp_ekf_plugin import MrpEkfConfig
from drake_att.scenarios.builder import diagram_for
from drake_att.scenarios.config import dump_scenario
from drake_att.scenarios.library import load
from drake_att.units import DEG

SCENARIOS = ("s0_particle_filters_small_error", "cubesat_single_star_tracker")
PAPER_Q_W = 5e-5  # rad^2 per 1 s step (paper S4)
LIE_NAMES = ("lie_group", "lie_group_arw", "lie_group_bias")


def reference_filter(scenario):
    """The scenario's Kalman filter the Lie-group variants copy their start from: its first
    MEKF, else its first MRP EKF."""
    for kind in (MekfConfig, MrpEkfConfig):
        for e in scenario.estimators:
            if isinstance(e, kind):
                return e
    raise ValueError(f"{scenario.name}: no MekfConfig or MrpEkfConfig to compare with")


def bench_scenario(name: str):
    """The scenario with the Lie-group estimators (and, where missing, an MEKF) appended;
    returns ``(scenario, names to run, name of the MEKF)``."""
    scenario = copy.deepcopy(load(name))
    ref = reference_filter(scenario)
    tracker = ref.star_tracker if isinstance(ref, MrpEkfConfig) else ref.star_trackers[0]
    start = dict(
        period_s=ref.period_s,
        gyro=ref.gyro,
        star_tracker=tracker,
        initial_attitude_rpy_deg=list(ref.initial_attitude_rpy_deg),
        initial_attitude_variance_rad2=(ref.initial_attitude_sigma_deg * DEG) ** 2,
        star_noise_from_tracker=True,
    )
    gyro = next(s for s in scenario.sensors if s.name == ref.gyro)
    kalman = [e.name for e in scenario.estimators if isinstance(e, (MekfConfig, MrpEkfConfig))]
    mekf = next((e.name for e in scenario.estimators if isinstance(e, MekfConfig)), None)
    if mekf is None:
        mekf = "mekf"
        scenario.estimators.append(
            MekfConfig(
                name=mekf,
                period_s=ref.period_s,
                gyro=ref.gyro,
                star_trackers=[tracker],
                arw_deg_per_rt_h=ref.arw_deg_per_rt_h,
                rrw_deg_per_h15=ref.rrw_deg_per_h15,
                initial_attitude_rpy_deg=list(ref.initial_attitude_rpy_deg),
                initial_bias_deg_per_h=list(ref.initial_bias_deg_per_h),
                initial_attitude_sigma_deg=ref.initial_attitude_sigma_deg,
                initial_bias_sigma_deg_per_h=ref.initial_bias_sigma_deg_per_h,
            )
        )
        kalman.append(mekf)
    scenario.estimators += [
        LieGroupConfig(
            name="lie_group",
            process_noise_rad2_per_step=PAPER_Q_W,
            gyro_arw_deg_per_rt_h=gyro.arw_deg_per_rt_h,
            **start,
        ),
        LieGroupConfig(
            name="lie_group_arw", process_noise_rad2_per_step=0.0, gyro_arw_deg_per_rt_h=gyro.arw_deg_per_rt_h, **start
        ),
        LieGroupConfig(
            name="lie_group_bias",
            estimate_gyro_bias=True,
            arw_deg_per_rt_h=ref.arw_deg_per_rt_h,
            rrw_deg_per_h15=ref.rrw_deg_per_h15,
            initial_bias_deg_per_h=list(ref.initial_bias_deg_per_h),
            initial_bias_sigma_deg_per_h=ref.initial_bias_sigma_deg_per_h,
            **start,
        ),
    ]
    return scenario, kalman + list(LIE_NAMES), mekf


def run_overrides(scenario, duration, convergence_threshold_deg=None):
    out = []
    if duration is not None:
        score_from = min(scenario.scoring.score_from_s, duration / 2.0)
        out += [f"duration_s={duration}", f"scoring.score_from_s={score_from}"]
    if convergence_threshold_deg is not None:
        out.append(f"scoring.convergence_threshold_deg={convergence_threshold_deg}")
    return out


def one_run(sd, seed, names, mekf, overrides):
    run = sd.simulate(seed, overrides=overrides, estimators=names)
    metrics = compute_metrics(run)
    scored_from = run.scenario.scoring.score_from_s
    extra = {}
    for n in names:
        e = estimator_errors(run, n)
        m = e["t"] >= scored_from - 1e-6
        d, P3 = e["dtheta"][m], e["P"][m, :3, :3]
        extra[n] = {"nees3_mean": float(np.mean(np.einsum("ni,ni->n", d, np.linalg.solve(P3, d[..., None])[..., 0])))}
    a, b = estimator_errors(run, "lie_group_bias"), estimator_errors(run, mekf)
    same = {
        "max_attitude_diff_rad": float(np.abs(a["dtheta"] - b["dtheta"]).max()),
        "max_bias_diff_rad_per_s": float(np.abs(a["second_err"] - b["second_err"]).max()),
    }
    return {
        "seed": seed,
        "wall_time_s": run.wall_time_s,
        "metrics": metrics["estimators"],
        "extra": extra,
        "lie_group_bias_vs_mekf": same,
    }


def aggregate(runs, names):
    out = {}
    for n in names:
        ms = [r["metrics"][n] for r in runs]
        rmse = np.sqrt(np.mean(np.square([m["attitude_rmse_deg"] for m in ms]), axis=0))
        total = float(np.sqrt(np.mean([m["attitude_rmse_total_deg"] ** 2 for m in ms])))
        bias = None
        if all(m["bias_rmse_deg_per_h"] is not None for m in ms):
            bias = np.sqrt(np.mean(np.square([m["bias_rmse_deg_per_h"] for m in ms]), axis=0)).tolist()
        conv = [m["convergence_time_s"] for m in ms if m["convergence_time_s"] is not None]
        nees6 = [m["nees_mean"] for m in ms if m["nees_mean"] is not None]
        out[n] = {
            "attitude_rmse_deg": rmse.tolist(),
            "attitude_rmse_total_deg": total,
            "bias_rmse_deg_per_h": bias,
            "nees_mean": float(np.mean(nees6)) if nees6 else None,
            "nees_dof": ms[0]["nees_dof"],
            "nees3_mean": float(np.mean([r["extra"][n]["nees3_mean"] for r in runs])),
            "convergence_time_median_s": float(np.median(conv)) if conv else None,
            "converged_runs": len(conv),
            "runs": len(ms),
            "second_kind": "gyro_bias" if bias is not None else "body_rate",
        }
    return out


def format_table(name, agg, runs, mekf, scenario) -> str:
    lines = [
        f"{name}: {len(runs)} seeds, {scenario.duration_s:.0f} s, scored from "
        f"{scenario.scoring.score_from_s:.0f} s, convergence threshold {scenario.scoring.convergence_threshold_deg} deg"
    ]
    hdr = (
        f"{'estimator':<16} {'RMSE x/y/z (deg)':>30} {'RMSE tot':>9} {'bias RMSE x/y/z (deg/h)':>27} "
        f"{'NEES':>9} {'NEES3':>7} {'conv (s)':>12}"
    )
    lines += [hdr, "-" * len(hdr)]
    for n, a in agg.items():
        rm = " ".join(f"{v:9.5f}" for v in a["attitude_rmse_deg"])
        br = "-" if a["bias_rmse_deg_per_h"] is None else " ".join(f"{v:8.4f}" for v in a["bias_rmse_deg_per_h"])
        nees = (
            "-"
            if a["nees_mean"] is None
            else f"{a['nees_mean']:.2f}" + ("" if a["second_kind"] == "gyro_bias" else "w")
        )
        conv = "never" if a["convergence_time_median_s"] is None else f"{a['convergence_time_median_s']:.1f}"
        if a["converged_runs"] < a["runs"]:
            conv += f" ({a['converged_runs']}/{a['runs']})"
        lines.append(
            f"{n:<16} {rm:>30} {a['attitude_rmse_total_deg']:9.5f} {br:>27} {nees:>9} {a['nees3_mean']:7.2f} {conv:>12}"
        )
    da = max(r["lie_group_bias_vs_mekf"]["max_attitude_diff_rad"] for r in runs)
    db = max(r["lie_group_bias_vs_mekf"]["max_bias_diff_rad_per_s"] for r in runs)
    lines.append(
        f"lie_group_bias vs {mekf}: largest difference over all runs and steps {da:.1e} rad (attitude), "
        f"{db:.1e} rad/s (bias)"
    )
    lines.append(
        "NEES: 6-dof [attitude; bias] error (w: [attitude; body rate], the no-bias filters' second "
        "vector); NEES3: attitude only (3 expected); conv: median over the seeds that converged"
    )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds 1..N")
    ap.add_argument(
        "--duration",
        type=float,
        default=None,
        help="simulated time per run (s); default: each scenario's (S0 1000 s, S3 5000 s)",
    )
    ap.add_argument(
        "--convergence-threshold-deg",
        type=float,
        default=None,
        help="per-axis threshold of the convergence time (default: each scenario's, 0.05 deg, which "
        "both meet from the first update)",
    )
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--out", default=os.path.join("out", "lie_group_bench"))
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error("--seeds must be >= 1")
    os.makedirs(args.out, exist_ok=True)
    seeds = list(range(1, args.seeds + 1))
    start = time.perf_counter()
    results = {
        "command": " ".join([os.path.basename(sys.argv[0])] + (sys.argv[1:] if argv is None else list(argv))),
        "seeds": seeds,
        "scenarios": {},
    }
    for name in args.scenarios:
        scenario, names, mekf = bench_scenario(name)
        overrides = run_overrides(scenario, args.duration, args.convergence_threshold_deg)
        t0 = time.perf_counter()
        sd = diagram_for(scenario)
        runs = []
        for seed in seeds:
            runs.append(one_run(sd, seed, names, mekf, overrides))
            print(
                f"  [{name}] seed {seed}: {runs[-1]['wall_time_s']:.1f} s simulated wall", file=sys.stderr, flush=True
            )
        used = sd.scenario_for(overrides, names)
        agg = aggregate(runs, names)
        print(format_table(name, agg, runs, mekf, used))
        print()
        yaml_text = dump_scenario(used)
        with open(os.path.join(args.out, f"config_{name}.yaml"), "w") as f:
            f.write(yaml_text)
        results["scenarios"][name] = {
            "config_yaml": yaml_text,
            "overrides": overrides,
            "estimators_run": names,
            "mekf": mekf,
            "aggregate": agg,
            "runs": runs,
            "wall_time_s": time.perf_counter() - t0,
        }
    results["wall_time_s"] = time.perf_counter() - start
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(results, f, indent=1)
    print(f"wall time {results['wall_time_s']:.1f} s; results in {os.path.join(args.out, 'results.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
