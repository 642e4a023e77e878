"""One metrics layer for every estimator.

Attitude error (DESIGN.md): ``R_err = R_IB_hat^T R_IB`` (true body relative to the
estimated body), ``dtheta_B = log(R_err)``; per-axis x/y/z = roll/pitch/yaw.

Each estimate is scored against the truth **at the estimate's own time**
(``status[0]``), not at the time the logger recorded it (Drake publishes before the
discrete update of the same instant, so a log at ``t`` holds the estimate of the previous
step).

* RMSE / MAE per axis and total RMSE (``sqrt(mean |dtheta|^2)``) over
  ``t >= scoring.score_from_s`` (the "stable stage").
* Bias RMSE per axis (deg/h) against the gyro's true bias at the same time.
* Convergence time: the first estimate time after which every axis of ``dtheta`` stays
  within ``scoring.convergence_threshold_deg`` until the end (None if never).
* NEES: ``e' P^-1 e`` with ``e = [dtheta; second-vector error]`` (6-dof) when the second
  vector's truth is known, else the 3-dof attitude NEES; mean over the scored samples.

Which signals are the truth, each estimator's second quantity ("gyro_bias" or "body_rate")
and the true gyro bias it is scored against come from the run's metadata
(:attr:`drake_att.scenarios.builder.RunLog.metadata`), so a saved log scores without the
diagram (``drake-att score``).
"""

from __future__ import annotations

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import TIME_TOLERANCE_S
from drake_att.noise import DEG, DEG_PER_H
from drake_att.scenarios import config as cfg

TIME_MATCH_TOLERANCE_S = TIME_TOLERANCE_S  # signals of one instant (the contract's tolerance)


def _align(t_query, t_ref, what):
    idx = np.searchsorted(t_ref, t_query - TIME_MATCH_TOLERANCE_S)
    idx = np.clip(idx, 0, len(t_ref) - 1)
    bad = np.abs(t_ref[idx] - t_query) > TIME_MATCH_TOLERANCE_S
    if np.any(bad):
        raise ValueError(
            f"{what}: no truth sample at estimate times {t_query[bad][:3]} s "
            "(truth must be logged at every estimate time)"
        )
    return idx


def _metadata(run) -> dict:
    """The run's metadata (ValueError if it has none)."""
    meta = getattr(run, "metadata", None)
    if not meta:
        raise ValueError(
            "the run carries no metadata (which signal is the truth, how each estimator is scored): "
            "use a RunLog from ScenarioDiagram.simulate() or RunLog.load()"
        )
    return meta


def _values(run, key: str, width: int, what: str) -> np.ndarray:
    """``run.values(key)``, checked to hold ``width`` components per sample."""
    x = run.values(key)
    if x.ndim != 2 or x.shape[1] != width:
        raise ValueError(f"{what} {key!r}: expected {width} components per sample, got shape {x.shape}")
    return x


def estimator_errors(run, name: str) -> dict:
    """Aligned errors of one estimator: times, dtheta (rad), second error, covariance, NEES.

    What is compared with what comes from ``run.metadata`` (truth keys, the estimator's
    signal keys, its second-quantity kind and true gyro bias)."""
    meta = _metadata(run)
    if name not in meta["estimators"]:
        raise ValueError(f"{name}: not an estimator of this run; estimators: {list(meta['estimators'])}")
    spec = meta["estimators"][name]
    keys, kind = spec["signals"], spec["second_kind"]
    status = _values(run, keys["status"], 4, f"{name} status")
    valid = np.isfinite(status[:, 0]) & (status[:, 0] >= 0)
    # The first log (t = 0, before the first update) carries the initial estimate with
    # t_estimate = 0 as well; keep only the last sample of each estimate time.
    t_est = status[valid, 0]
    keep = np.r_[np.diff(t_est) > TIME_MATCH_TOLERANCE_S, True]
    sel = np.flatnonzero(valid)[keep]
    t_est = status[sel, 0]
    q_hat = _values(run, keys["attitude"], 4, f"{name} attitude")[sel]
    second_hat = _values(run, keys["second"], 3, f"{name} second quantity")[sel]
    P = _values(run, keys["covariance"], 36, f"{name} covariance")[sel].reshape(-1, 6, 6)
    truth_key = meta["truth"]["attitude"]
    idx = _align(t_est, run.times(truth_key), name)
    q_true = _values(run, truth_key, 4, "truth attitude")[idx]
    dtheta = rot.quat_error_rotvec(q_hat, q_true)
    second_err = None
    if kind == "gyro_bias" and spec["true_bias"] is not None:
        key = spec["true_bias"]
        ib = _align(t_est, run.times(key), f"{name} bias")
        second_err = _values(run, key, 3, f"{name} true bias")[ib] - second_hat
    elif kind == "body_rate":
        key = meta["truth"]["rate"]
        iw = _align(t_est, run.times(key), f"{name} rate")
        second_err = _values(run, key, 3, "truth rate")[iw] - second_hat
    elif kind != "gyro_bias":
        raise ValueError(f"{name}: second_kind {kind!r} is neither 'gyro_bias' nor 'body_rate'")
    if second_err is not None:
        e = np.concatenate([dtheta, second_err], axis=1)
        Pe = P
    else:
        e = dtheta
        Pe = P[:, :3, :3]
    nees = np.full(len(e), np.nan)
    # Per-sample pseudo-check: a singular covariance (e.g. a collapsed particle cloud)
    # makes only that sample's NEES undefined, not the whole series.
    ok = np.linalg.matrix_rank(Pe) == Pe.shape[-1]
    if np.any(ok):
        nees[ok] = np.einsum("ni,ni->n", e[ok], np.linalg.solve(Pe[ok], e[ok][..., None])[..., 0])
    return {
        "t": t_est,
        "dtheta": dtheta,
        "second_err": second_err,
        "P": P,
        "nees": nees,
        "nees_dof": e.shape[1],
        "status": status[sel],
        "q_hat": q_hat,
        "q_true": q_true,
        "second_kind": kind,
    }


def convergence_time(t, dtheta, threshold_rad) -> float | None:
    """First time after which all axes of ``dtheta`` stay within ``threshold_rad`` (a
    non-finite error is outside: an estimate that went NaN never converged)."""
    outside = ~np.all(np.abs(dtheta) <= threshold_rad, axis=1)
    if outside[-1]:
        return None
    if not np.any(outside):
        return float(t[0])
    last_out = np.flatnonzero(outside)[-1]
    return float(t[last_out + 1])


def score_estimator(errors: dict, scoring: cfg.ScoringConfig, second_kind: str) -> dict:
    """Scalar metrics of :func:`estimator_errors` output (``second_kind``: "gyro_bias" or
    "body_rate", which of the bias / rate RMSE the second error is)."""
    t = errors["t"]
    m = t >= scoring.score_from_s - TIME_MATCH_TOLERANCE_S
    d = errors["dtheta"][m] / DEG
    out = {
        "attitude_rmse_deg": np.sqrt(np.mean(d**2, axis=0)).tolist(),
        "attitude_mae_deg": np.mean(np.abs(d), axis=0).tolist(),
        "attitude_rmse_total_deg": float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
        "attitude_3sigma_final_deg": (3 * np.sqrt(np.diag(errors["P"][-1])[:3]) / DEG).tolist(),
        "bias_rmse_deg_per_h": None,
        "rate_rmse_deg_per_s": None,
        "convergence_time_s": convergence_time(t, errors["dtheta"], scoring.convergence_threshold_deg * DEG),
        "nees_mean": float(np.nanmean(errors["nees"][m])) if np.any(np.isfinite(errors["nees"][m])) else None,
        "nees_dof": int(errors["nees_dof"]),
        "scored_from_s": float(scoring.score_from_s),
        "samples_scored": int(np.sum(m)),
        "measurements_used": int(errors["status"][-1, 1]),
        "measurements_skipped": int(errors["status"][-1, 2]),
    }
    if errors["second_err"] is not None:
        s = errors["second_err"][m]
        if second_kind == "gyro_bias":
            out["bias_rmse_deg_per_h"] = (np.sqrt(np.mean(s**2, axis=0)) / DEG_PER_H).tolist()
        else:
            out["rate_rmse_deg_per_s"] = (np.sqrt(np.mean(s**2, axis=0)) / DEG).tolist()
    return out


def compute_metrics(run, errors: dict | None = None) -> dict:
    """Metrics of every estimator of a run (in its metadata's order), scored by
    ``run.scenario.scoring``; needs only the :class:`RunLog` (no Drake systems).
    ``errors``: estimator name -> its :func:`estimator_errors` of this run, where the caller
    has them already (the others are computed)."""
    scenario = run.scenario
    result = {
        "scenario": scenario.name,
        "seed": run.seed,
        "duration_s": scenario.duration_s,
        "wall_time_s": run.wall_time_s,
        "estimators": {},
    }
    for name, spec in _metadata(run)["estimators"].items():
        e = errors[name] if errors and name in errors else estimator_errors(run, name)
        result["estimators"][name] = score_estimator(e, scenario.scoring, spec["second_kind"])
    sensors = tracker_availability(run)
    if sensors:
        result["sensors"] = sensors
    return result


def tracker_availability(run) -> dict:
    """Per star tracker with exclusion cones (a logged ``<name>/exclusion`` port), over the
    whole run: its samples and the fractions clear and blinded by each cause
    (:func:`drake_att.exclusion.availability`; a sample blinded by two bodies counts for both)."""
    from drake_att.exclusion import availability

    out = {}
    for key in sorted(run.signals):
        name, _, port = key.rpartition("/")
        if port == "exclusion":
            causes = np.asarray(run.values(key))[:, 1].astype(np.int64)
            out[name] = {"samples": int(causes.size), "availability": availability(causes)}
    return out


def _g(value) -> str:
    """A table number: 3 significant digits, scientific notation where fixed would not fit
    (``0.0123``, ``170``, ``1.2e-07``, ``6.1e+28``); at most 9 characters up to |exponent| 99."""
    return "-" if value is None else f"{value:.3g}"


TABLE_WIDTH = 100  # the run table's lines fit 100 columns (for names up to 30 characters)
_NUM = 9  # a number's column: _g's widest output
NOISE_FREE_MARK = "*"


def _measurement_sensors(config) -> list[str]:
    """The sensors whose measurements estimator ``config`` updates on (not its gyro)."""
    from drake_att.scenarios.selection import measurement_sensor_names

    return measurement_sensor_names(config) + ([config.camera] if getattr(config, "camera", None) else [])


def _sensor_noise_free(sensor, sensors: dict) -> bool:
    """Whether ``sensor``'s config sets its measurement noise to zero (a camera without
    centroid noise and quantization, a tracker with zero sigmas, an average of such
    trackers); False for a sensor type this does not know."""
    from drake_att.sensors.screen_camera_plugin import ScreenCameraConfig
    from drake_att.sensors.star_tracker_average_plugin import StarTrackerAverageConfig
    from drake_att.sensors.star_tracker_plugin import StarTrackerConfig

    if isinstance(sensor, ScreenCameraConfig):
        return sensor.centroid_noise_px == 0 and sensor.quantization_px == 0
    if isinstance(sensor, StarTrackerConfig):
        if sensor.mode == "vectors":
            return sensor.sigma_vector_urad == 0
        return sensor.sigma_cross_boresight_arcsec == 0 and sensor.sigma_boresight_arcsec == 0
    if isinstance(sensor, StarTrackerAverageConfig):
        return all(n in sensors and _sensor_noise_free(sensors[n], sensors) for n in sensor.star_trackers)
    return False


def noise_free_estimators(scenario) -> dict[str, list[str]]:
    """Estimator name -> the sensors it updates on, for the estimators whose every measurement
    sensor is noise-free in ``scenario``'s config (a fusion: every sensor of its sources).

    Their covariance then holds no measurement noise, only the filter's numerical floor
    (e.g. the indoor star tracker's ``sigma_floor_urad``), so the error it is compared with
    in the NEES is not noise it describes: the NEES says nothing about consistency."""
    from drake_att.scenarios.selection import fused_sources, with_fused_sources

    sensors = {s.name: s for s in scenario.sensors}
    configs = {e.name: e for e in scenario.estimators}
    out = {}
    for name in configs:
        reads = list(
            dict.fromkeys(
                s
                for source in with_fused_sources(configs, [name])
                if source in configs and not fused_sources(configs[source])
                for s in _measurement_sensors(configs[source])
            )
        )
        if reads and all(s in sensors and _sensor_noise_free(sensors[s], sensors) for s in reads):
            out[name] = reads
    return out


def _nums(values) -> str:
    return " ".join(f"{_g(v):>{_NUM}}" for v in values)


def _attitude_block(ests: dict, nw: int) -> list[str]:
    """Attitude RMSE and MAE per axis and the total RMSE (deg), one row per estimator."""
    cols = ["RMSE x", "RMSE y", "RMSE z", "RMSE tot", "MAE x", "MAE y", "MAE z"]
    hdr = f"{'estimator':<{nw}} " + " ".join(f"{c:>{_NUM}}" for c in cols)
    lines = ["attitude error (deg; x/y/z = roll/pitch/yaw):", hdr, "-" * len(hdr)]
    for name, m in ests.items():
        values = [*m["attitude_rmse_deg"], m["attitude_rmse_total_deg"], *m["attitude_mae_deg"]]
        lines.append(f"{name:<{nw}} {_nums(values)}")
    return lines


def _second_cell(m: dict) -> str:
    """``b`` and the gyro-bias RMSE per axis, ``w`` and the body-rate RMSE, or ``-``."""
    if m.get("bias_rmse_deg_per_h") is not None:
        return "b " + _nums(m["bias_rmse_deg_per_h"])
    if m.get("rate_rmse_deg_per_s") is not None:
        return "w " + _nums(m["rate_rmse_deg_per_s"])
    return "-"


def _other_block(ests: dict, nw: int, flagged) -> list[str]:
    """Bias or rate RMSE per axis, convergence time, NEES (marked for ``flagged`` estimators)
    and the measurement counts, one row per estimator."""
    sw = 2 + 3 * _NUM + 2
    hdr = (
        f"{'estimator':<{nw}} {'bias|rate RMSE x/y/z':>{sw}} {'conv (s)':>{_NUM}} {'NEES':>{_NUM}}  "
        f"{'used/skipped':>13}"
    )
    lines = ["gyro bias (b, deg/h) or body rate (w, deg/s), convergence, consistency:", hdr, "-" * len(hdr)]
    for name, m in ests.items():
        conv = "never" if m["convergence_time_s"] is None else f"{m['convergence_time_s']:.1f}"
        mark = NOISE_FREE_MARK if name in flagged else " "
        used = f"{m['measurements_used']}/{m['measurements_skipped']}"
        lines.append(
            f"{name:<{nw}} {_second_cell(m):>{sw}} {conv:>{_NUM}} {_g(m['nees_mean']):>{_NUM}}{mark} {used:>13}"
        )
    return lines


def _nees_dof_text(ests: dict) -> str:
    dofs = {}
    for name, m in ests.items():
        dofs.setdefault(m.get("nees_dof", 6), []).append(name)
    if len(dofs) <= 1:
        return f"NEES dof = {next(iter(dofs), 6)}"
    return "NEES dof: " + ", ".join(f"{d} ({', '.join(names)})" for d, names in sorted(dofs.items()))


def _wrapped(text: str) -> list[str]:
    import textwrap

    return textwrap.wrap(text, TABLE_WIDTH, subsequent_indent=" ", break_long_words=False, break_on_hyphens=False)


def format_table(metrics: dict, scenario=None) -> str:  # pragma: no mutate block (presentation: column text and widths)
    """Human-readable table of :func:`compute_metrics` output, in two blocks that each fit
    :data:`TABLE_WIDTH` columns for names up to 30 characters: the attitude error (RMSE and MAE
    per axis, total RMSE), then the bias or rate RMSE, convergence time, NEES and measurement
    counts; a footer says what the columns mean.

    The name column is as wide as the longest estimator name (at least 9); RMSE, MAE, bias,
    rate and NEES are printed to 3 significant digits (``.3g``: ``0.0123``, ``170``,
    ``6.1e+28``) right-aligned in 9 characters, so every row lines up and every number parses
    back with ``float``; convergence time ``.1f`` s or ``never``. With ``scenario`` (the run's
    config), the NEES of an estimator whose measurements are all noise-free
    (:func:`noise_free_estimators`) is marked ``*`` and a footnote says why it is meaningless."""
    ests = metrics["estimators"]
    nw = max([9] + [len(name) for name in ests])
    flagged = {} if scenario is None else {n: s for n, s in noise_free_estimators(scenario).items() if n in ests}
    lines = [
        (
            f"scenario {metrics['scenario']}  seed {metrics['seed']}  duration {metrics['duration_s']:.0f} s"
            f"  wall {metrics['wall_time_s']:.2f} s"
        )
    ]
    lines += _attitude_block(ests, nw) + [""] + _other_block(ests, nw, flagged)
    first = next(iter(ests.values()), {"scored_from_s": 0.0})
    lines += _wrapped(
        f"(scored from t >= {first['scored_from_s']:.0f} s; conv = the time after which every attitude axis "
        f"stays within scoring.convergence_threshold_deg; {_nees_dof_text(ests)}; used/skipped = measurement updates "
        "applied / invalid or rejected measurements skipped)"
    )
    for name, s in metrics.get("sensors", {}).items():
        a = s["availability"]
        lines += _wrapped(
            f"{name}: available {100 * a['available']:.1f}% of {s['samples']} samples (blinded by the Sun "
            f"{100 * a['sun']:.1f}%, the Earth {100 * a['earth']:.1f}%, the Moon {100 * a['moon']:.1f}%)"
        )
    if flagged:
        reads = "; ".join(f"{n}: {', '.join(s)}" for n, s in flagged.items())
        lines += _wrapped(
            f"{NOISE_FREE_MARK} noise-free measurements ({reads}): the covariance holds only the filter's "
            "numerical floor, not the error's spread, so this NEES does not measure consistency"
        )
    return "\n".join(lines)
