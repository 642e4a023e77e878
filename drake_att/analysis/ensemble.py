"""Ensemble statistics of a Monte Carlo campaign: one compact record per run, one summary.

Two steps, so the heavy part runs where the run is:

* :func:`per_run_record` (in the worker, on one :class:`~drake_att.scenarios.builder.RunLog`)
  returns a flat dict of numpy arrays (``np.savez``-able without pickle; strings are 0-d
  unicode arrays) with what the statistics and the plots need;
* :func:`summarize` (in the parent, on the records of every run) returns plain JSON-able
  numbers (``None`` where a number is undefined, never NaN).

:func:`record_from_npz` turns ``np.load(path)`` of a saved record back into a dict.

Record keys (``<E>`` = an estimator's name; every key of ``<E>`` starts with ``"<E>__"``)
-----------------------------------------------------------------------------------------
``schema`` (int, :data:`RECORD_SCHEMA`), ``scenario`` (str), ``seed`` (int), ``duration_s``,
``score_from_s``, ``convergence_threshold_deg`` (float), ``estimators`` (str array, in the
scenario's order), ``metrics_json`` (str: :func:`drake_att.analysis.metrics.compute_metrics`
of the run, strict JSON). Per estimator:

==================================  ====================================================================
``<E>__t``                          (n,) float64: estimate times (s), as :func:`~drake_att.analysis.metrics.estimator_errors`
``<E>__dtheta``                     (n, 3) float32: attitude error ``dtheta_B`` (rad)
``<E>__second_kind``                str: ``"gyro_bias"`` or ``"body_rate"``
``<E>__second_err``                 (n, 3) float32: bias error (rad/s) or rate error (rad/s); absent when its truth is unknown
``<E>__sigma``                      (n, 6) float32: the filter's 1-sigmas (sqrt of its covariance's diagonal)
``<E>__nees``, ``<E>__nees_dof``    (n,) float32 NEES (NaN where the covariance is singular); int dof (6 or 3)
``<E>__window_n``                   int: estimate samples in the scoring window (``t >= score_from_s``)
``<E>__window_ms``                  (3,) float64: mean over the window of ``dtheta_i^2`` (rad^2)
``<E>__window_ms_second``           (3,) float64: the same for the second error (NaN when unknown)
``<E>__window_nees_sum``            float64: sum of the finite NEES samples in the window
``<E>__window_nees_n``              int: their number
``<E>__convergence_time_s``         float64: :func:`~drake_att.analysis.metrics.convergence_time` (NaN: never)
``<E>__inputs``                     str array: the estimator's measurement inputs (sensor names, in its input order)
``<E>__nis_source``                 str: ``"innovations"`` (the estimator's logged innovations), ``"status"``
                                    (fallback: the status NIS at steps whose used count rose; one-input
                                    estimators only) or ``"none"``
``<E>__nis<i>__t|value|dof``        (m,) float64 / float64 / int32: NIS samples of input ``i`` (update attempts
                                    with a finite NIS: time, value, innovation dimension)
``<E>__bound_sigma``                (n, 6) float32: the bound's 1-sigmas at the estimate times
                                    (:mod:`drake_att.analysis.bound`); absent when no bound is defined
``<E>__bound_window_var``           (6,) float64: the bound's variances averaged over the window
``<E>__bound_json``                 str: the bound's facts (``reason`` when none: why), JSON
==================================  ====================================================================

A 5000-s, 1-Hz run takes ~0.53 MB per estimator (2.7 MB for paper S3's five).

Summary keys (:func:`summarize`)
--------------------------------
Top level: ``scenario``, ``n_runs``, ``seeds``, ``score_from_s``,
``convergence_threshold_deg``, ``methods`` (one sentence per statistic: how it is computed)
and ``estimators``: name ->

* ``n_runs``; ``window_samples_per_run``.
* ``attitude_rmse_deg`` [x, y, z] and ``attitude_rmse_total_deg``: RMSE over the window,
  pooled over runs (``sqrt`` of the mean over runs of each run's mean square);
  ``attitude_rmse_ci95_deg`` [[lo, hi] x 3] and ``attitude_rmse_total_ci95_deg`` [lo, hi]:
  95% confidence intervals (method ``methods["rmse_ci"]``: Student's t on the mean over runs
  of the per-run mean squares, square-rooted; needs >= 2 runs, else None).
* ``second_kind``; ``bias_rmse_deg_per_h`` / ``rate_rmse_deg_per_s`` [3] with
  ``..._ci95`` (same method), or None.
* ``nees_dof``; ``anees``: the mean NEES over runs and window samples;
  ``anees_band_95`` [lo, hi]: the two-sided 95% band of the ANEES at one instant,
  ``chi2(N dof)/N`` quantiles (Bar-Shalom), which also bounds ``history.anees``;
  ``anees_in_band``; ``anees_window_band_95``: the band of the *window* ANEES,
  ``chi2(N n_eff dof)/(N n_eff)`` with ``n_eff = window samples / tau`` independent
  samples per run, ``tau`` = ``nees_correlation_time_samples`` (the integrated
  autocorrelation time of the NEES, estimated from the ensemble) - much narrower, the
  real test of a window average; ``anees_in_window_band``.
* ``nis``: input name -> ``{"source", "count", "mean", "mean_dof", "band_95", "in_band"}``
  over the window's update attempts (mean NIS per attempt; band: ``chi2(D)/M`` quantiles
  with ``M`` attempts and ``D`` their summed dimensions: a consistent filter's
  innovations are white, so no correlation correction); ``{}`` when not available.
* ``convergence``: ``fraction_converged``, ``n_converged``, ``time_s`` (``min``, ``p10``,
  ``median``, ``mean``, ``p90``, ``max`` over converged runs, or None),
  ``time_s_by_seed`` {seed: time or None}.
* ``worst_runs``: the ``worst`` runs with the largest total attitude RMSE, largest first:
  ``{"seed", "attitude_rmse_total_deg", "attitude_rmse_deg", "command"}`` (the command line
  that re-runs it: ``drake-att run SCENARIO --seed S [--set ...]``, see :func:`summarize`).
* ``bound``: ``{"defined", "reason", "attitude_rmse_bound_deg" [3],
  "attitude_rmse_total_bound_deg", "ratio" [3] (RMSE / bound), "ratio_ci95" [[lo, hi] x 3],
  "ratio_total", "bias_rmse_bound_deg_per_h" [3], "bias_ratio" [3], "prior_sensitivity",
  "info"}``: the bound's RMS over the window (``sqrt`` of its mean variance, pooled over
  runs) and each RMSE as a ratio to it; ``info`` holds the first run's sensors, tracker
  sample counts and notes. Not defined: ``defined`` false, ``reason`` says why, numbers None.
* ``history``: for plots, at most ``max_history_points`` instants (every k-th estimate
  time): ``t``, ``attitude_rmse_deg`` (per instant: RMS over runs, [n x 3]), ``anees``
  (per instant), ``anees_band_95`` (as above), ``bound_attitude_sigma_deg`` ([n x 3] or
  None): the "physical limit" line.

Every statistic a campaign reports, each a small function; they share the record layout read here.
"""

from __future__ import annotations

import functools
import json
import math

import numpy as np

from drake_att.analysis import metrics as met
from drake_att.analysis.bound import bound_for_estimator
from drake_att.filters.gating import chi2_quantile
from drake_att.scenarios.selection import measurement_sensor_names
from drake_att.units import DEG, DEG_PER_H

RECORD_SCHEMA = 1
_TOL = met.TIME_MATCH_TOLERANCE_S
_CHI2_EXACT_MAX_DOF = 1000


# ---------------------------------------------------------------------------------------------
# Per run (worker side)
# ---------------------------------------------------------------------------------------------
def _str(s: str) -> np.ndarray:
    return np.array(str(s))


def _input_names(scenario, name: str) -> tuple[list[str], list]:
    """The measurement inputs of estimator ``name`` in its input order (quaternion sensors,
    then vector sensors, then cameras) and their NIS dimension (None: unknown)."""
    from drake_att.scenarios.registry import plugin_for

    sensors = {s.name: s for s in scenario.sensors}
    c = next(e for e in scenario.estimators if e.name == name)
    names = measurement_sensor_names(c)
    cameras = [c.camera] if getattr(c, "camera", None) else []
    kinds = {}
    for n in names + cameras:
        s = sensors.get(n)
        kinds[n] = plugin_for(s).output(s, sensors).kind if s is not None else None
    quat = [n for n in names if kinds.get(n) == "quaternion"]
    vec = [n for n in names if kinds.get(n) == "vectors"]
    ordered = quat + vec + [n for n in names if n not in quat + vec] + cameras
    dims = []
    for n in ordered:
        if kinds.get(n) == "quaternion":
            dims.append(3)
        elif kinds.get(n) == "vectors":
            dims.append(3 * len(np.reshape(sensors[n].references_I, (-1, 3))))
        else:
            dims.append(None)
    return ordered, dims


def _nis_samples(run, name: str, errors: dict) -> tuple[str, list[str], list[tuple]]:
    """``(source, input names, [(t, nis, dof) arrays per input])``."""
    spec = run.metadata["estimators"][name]
    key = spec["signals"].get("innovations")
    if key is not None and key in run.signals:
        inputs = list(spec.get("inputs") or [])
        x = run.values(key)
        out = []
        for i in range(x.shape[1] // 3):
            t, v, d = x[:, 3 * i], x[:, 3 * i + 1], x[:, 3 * i + 2]
            ok = np.isfinite(t) & np.isfinite(v) & np.isfinite(d) & (d > 0)
            t, v, d = t[ok], v[ok], d[ok]
            first = np.r_[True, np.diff(t) > _TOL] if len(t) else np.zeros(0, dtype=bool)
            out.append((t[first], v[first], d[first].astype(np.int32)))
        while len(inputs) < len(out):
            inputs.append(f"input{len(inputs)}")
        return "innovations", inputs[: len(out)], out
    try:
        inputs, dims = _input_names(run.scenario, name)
    except StopIteration:
        return "none", [], []
    if len(inputs) != 1 or dims[0] is None:
        return "none", inputs, []
    status = errors["status"]
    used = status[:, 1]
    rose = used > np.r_[0.0, used[:-1]]
    t, v = status[rose, 0], status[rose, 3]
    ok = np.isfinite(v)
    return "status", inputs, [(t[ok], v[ok], np.full(int(np.sum(ok)), dims[0], dtype=np.int32))]


def per_run_record(run) -> dict:
    """The compact record of one run (keys: the module docstring). Numpy arrays only."""
    from drake_att.analysis.report import strict_json

    scenario = run.scenario
    scoring = scenario.scoring
    names = list(run.metadata["estimators"])
    errors = {name: met.estimator_errors(run, name) for name in names}
    rec = {
        "schema": np.array(RECORD_SCHEMA),
        "scenario": _str(scenario.name),
        "seed": np.array(int(run.seed)),
        "duration_s": np.array(float(scenario.duration_s)),
        "score_from_s": np.array(float(scoring.score_from_s)),
        "convergence_threshold_deg": np.array(float(scoring.convergence_threshold_deg)),
        "estimators": np.array(names, dtype=str),
        "metrics_json": _str(json.dumps(strict_json(met.compute_metrics(run, errors)), allow_nan=False)),
    }
    cache = {}
    for name in names:
        p = f"{name}__"
        e = errors[name]
        t = e["t"]
        m = t >= scoring.score_from_s - _TOL
        rec[p + "t"] = t.astype(np.float64)
        rec[p + "dtheta"] = e["dtheta"].astype(np.float32)
        rec[p + "second_kind"] = _str(e["second_kind"])
        if e["second_err"] is not None:
            rec[p + "second_err"] = e["second_err"].astype(np.float32)
        rec[p + "sigma"] = np.sqrt(np.maximum(np.einsum("nii->ni", e["P"]), 0.0)).astype(np.float32)
        rec[p + "nees"] = e["nees"].astype(np.float32)
        rec[p + "nees_dof"] = np.array(int(e["nees_dof"]))
        rec[p + "window_n"] = np.array(int(np.sum(m)))
        rec[p + "window_ms"] = np.mean(e["dtheta"][m] ** 2, axis=0) if np.any(m) else np.full(3, np.nan)
        rec[p + "window_ms_second"] = (
            np.mean(e["second_err"][m] ** 2, axis=0)
            if e["second_err"] is not None and np.any(m)
            else np.full(3, np.nan)
        )
        nees_w = e["nees"][m]
        finite = np.isfinite(nees_w)
        rec[p + "window_nees_sum"] = np.array(float(np.sum(nees_w[finite])))
        rec[p + "window_nees_n"] = np.array(int(np.sum(finite)))
        conv = met.convergence_time(t, e["dtheta"], scoring.convergence_threshold_deg * DEG)
        rec[p + "convergence_time_s"] = np.array(np.nan if conv is None else float(conv))
        source, inputs, nis = _nis_samples(run, name, e)
        rec[p + "nis_source"] = _str(source)
        rec[p + "inputs"] = np.array(inputs, dtype=str)
        for i, (tn, vn, dn) in enumerate(nis):
            rec[p + f"nis{i}__t"] = np.asarray(tn, dtype=np.float64)
            rec[p + f"nis{i}__value"] = np.asarray(vn, dtype=np.float64)
            rec[p + f"nis{i}__dof"] = np.asarray(dn, dtype=np.int32)
        if e["second_kind"] == "gyro_bias":
            sigma, window, info = bound_for_estimator(run, name, t, scoring.score_from_s, cache)
        else:
            sigma, window, info = (
                None,
                None,
                {"reason": f"{name} estimates the body rate, not a gyro bias: no gyro-driven bound"},
            )
        if sigma is not None:
            rec[p + "bound_sigma"] = sigma.astype(np.float32)
            rec[p + "bound_window_var"] = np.full(6, np.nan) if window is None else np.asarray(window, dtype=np.float64)
        rec[p + "bound_json"] = _str(json.dumps(strict_json(info), allow_nan=False))
    return rec


def record_from_npz(npz) -> dict:
    """A record from ``np.load(path)`` of ``np.savez(path, **record)`` (no pickle needed):
    a plain dict of arrays (0-d arrays stay 0-d)."""
    return {k: np.asarray(npz[k]) for k in npz.files}


# ---------------------------------------------------------------------------------------------
# Statistics helpers
# ---------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=256)
def _normal_quantile(p: float) -> float:
    lo, hi = -40.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 0.5 * math.erfc(-mid / math.sqrt(2.0)) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@functools.lru_cache(maxsize=1024)
def chi2_q(probability: float, dof: float) -> float:
    """The chi-square quantile for any dof > 0: exact up to 1000 dof
    (:func:`drake_att.filters.gating.chi2_quantile`; a non-integer dof is rounded, at least
    1), the Wilson-Hilferty approximation above (relative error < 2e-6 there)."""
    if dof <= _CHI2_EXACT_MAX_DOF:
        return chi2_quantile(probability, max(1, round(float(dof))))
    z = _normal_quantile(probability)
    c = 2.0 / (9.0 * dof)
    return dof * (1.0 - c + z * math.sqrt(c)) ** 3


def t_q(probability: float, dof: int) -> float:
    """Student's t quantile: exact for 1 and 2 dof, the Cornish-Fisher expansion (4 terms)
    from 3 dof (relative error < 1.3e-3 at 3 dof, < 5e-5 from 6, < 1e-5 from 9)."""
    if dof == 1:
        return math.tan(math.pi * (probability - 0.5))
    if dof == 2:
        return (2.0 * probability - 1.0) / math.sqrt(2.0 * probability * (1.0 - probability))
    z, v = _normal_quantile(probability), float(dof)
    return (
        z
        + (z**3 + z) / (4 * v)
        + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * v**2)
        + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * v**3)
        + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * v**4)
    )


def anees_band(n_runs: int, dof: int, probability: float = 0.95, samples_per_run: float = 1.0) -> list[float]:
    """Two-sided band of the average NEES of ``n_runs`` consistent runs: ``chi2(N s dof)/(N s)``
    quantiles with ``s`` independent samples per run (1: one instant)."""
    n = n_runs * samples_per_run
    a = 0.5 * (1.0 - probability)
    return [chi2_q(a, n * dof) / n, chi2_q(1.0 - a, n * dof) / n]


def mean_square_ci(per_run_ms, probability: float = 0.95):
    """Confidence interval of the expected mean square from independent per-run mean squares
    (one number per run): Student's t on their mean, ``M -+ t(N-1) s / sqrt(N)`` (``s``: their
    sample standard deviation), the lower end clipped at 0. Runs are independent, so this
    needs no model of the error's correlation in time; measured coverage on AR(1) errors
    (``tests/test_ensemble.py``): nominal from ~20 runs, ~93% with 5-10 runs.
    Returns ``(M, lo, hi)``; ``lo``/``hi`` None with fewer than 2 runs."""
    x = np.asarray(per_run_ms, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return None, None, None
    M = float(np.mean(x))
    if x.size < 2:
        return M, None, None
    half = t_q(0.5 + 0.5 * probability, x.size - 1) * float(np.std(x, ddof=1)) / math.sqrt(x.size)
    return M, max(0.0, M - half), M + half


def integrated_autocorrelation_time(series) -> float:
    """Integrated autocorrelation time (samples) of stationary series (rows: runs, columns:
    time): ``1 + 2 sum rho(l)``, the sum over the initial positive sequence of pair sums
    (Geyer 1992) of the ensemble autocorrelation; >= 1."""
    x = np.asarray(series, dtype=float)
    if x.ndim == 1:
        x = x[None, :]
    x = x[:, np.all(np.isfinite(x), axis=0)]
    n = x.shape[1]
    if n < 4:
        return 1.0
    x = x - x.mean(axis=1, keepdims=True)
    var = float(np.mean(x * x))
    if var <= 0:
        return 1.0
    nfft = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(x, nfft, axis=1)
    acov = np.fft.irfft(f * np.conj(f), nfft, axis=1)[:, :n].mean(axis=0) / n
    rho = acov / acov[0]
    tau = 1.0
    for l in range(1, n - 1, 2):
        pair = rho[l] + rho[l + 1]
        if pair <= 0:
            break
        tau += 2.0 * pair
    return float(max(1.0, tau))


def _f(x):
    """A JSON number: finite float, else None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _fl(a):
    return [_f(v) for v in np.asarray(a, dtype=float).ravel()]


def _rmse_block(per_run_ms, scale):
    """RMSE per axis with CI (``scale``: rad -> output unit), from (N, 3) per-run mean squares."""
    per_run_ms = np.asarray(per_run_ms, dtype=float)
    rmse, ci = [], []
    for j in range(per_run_ms.shape[1]):
        M, lo, hi = mean_square_ci(per_run_ms[:, j])
        rmse.append(None if M is None else _f(math.sqrt(M) / scale))
        ci.append(None if lo is None else [_f(math.sqrt(lo) / scale), _f(math.sqrt(hi) / scale)])
    return rmse, ci


def _nanmean0(x):
    """Column means ignoring NaN; NaN (no warning) where a column has none."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.where(ok, x, 0.0).sum(axis=0) / n, np.nan)


def common_times(records, name):
    """Indices into each record's times of the times every record has (rounded to 1 us)."""
    keys = [np.round(np.asarray(r[f"{name}__t"], dtype=float) / _TOL).astype(np.int64) for r in records]
    common = keys[0]
    increasing = None  # whether ``common`` is strictly increasing (computed when first needed)
    for k in keys[1:]:
        if common.shape == k.shape and np.array_equal(common, k):
            increasing = bool(np.all(np.diff(common) > 0)) if increasing is None else increasing
            if increasing:  # the same times as every record so far (a campaign's usual case)
                continue
        common = np.intersect1d(common, k)
        increasing = True  # intersect1d's result is sorted and unique
    return common * _TOL, [np.searchsorted(k, common) for k in keys]


# ---------------------------------------------------------------------------------------------
# The summary
# ---------------------------------------------------------------------------------------------
METHODS = {
    "rmse": "RMSE over the scoring window t >= score_from_s, pooled over runs: sqrt(mean over runs of each run's "
    "mean square error)",
    "rmse_ci": "95% CI: Student's t on the mean over runs of the per-run mean squares (runs are independent; no "
    "model of the correlation in time needed), lower end clipped at 0, square-rooted",
    "anees": "mean NEES over runs and window samples; anees_band_95 = chi2(N dof)/N 2.5%/97.5% quantiles (one "
    "instant); anees_window_band_95 = the same with N n_eff samples, n_eff = window samples / integrated "
    "autocorrelation time of the NEES (estimated from the ensemble)",
    "nis": "mean NIS per update attempt in the window; band chi2(D)/M quantiles, M attempts, D = sum of their "
    "dimensions (innovations of a consistent filter are white)",
    "convergence": "convergence time: first estimate time after which every attitude axis stays within "
    "convergence_threshold_deg until the end (metrics.convergence_time); converged = has one",
    "bound": "posterior Cramer-Rao bound of gyro-driven attitude determination on each run's true trajectory with "
    "the true sensor noise (drake_att.analysis.bound); RMS over the window = sqrt(mean bound variance), "
    "pooled over runs; ratio = RMSE / bound",
}


def _estimator_summary(records, command, name, worst, max_history_points):
    """Estimator ``name``'s entry of the summary's ``estimators`` (its keys: the module
    docstring); ``command(seed)`` is the line that re-runs a seed."""
    p = f"{name}__"
    N = len(records)
    seeds = [int(r["seed"]) for r in records]
    out = {"n_runs": N, "window_samples_per_run": int(np.median([int(r[p + "window_n"]) for r in records]))}
    ms = np.array([r[p + "window_ms"] for r in records], dtype=float)  # (N, 3)
    ms2 = np.array([r[p + "window_ms_second"] for r in records], dtype=float)
    kind = str(records[0][p + "second_kind"])
    out.update(_error_rmse(ms, ms2, kind))
    dof = int(records[0][p + "nees_dof"])
    band = anees_band(N, dof)
    t_common, idx = common_times(records, name)
    score_from = float(records[0]["score_from_s"])
    nees = np.array([np.asarray(r[p + "nees"], dtype=float)[i] for r, i in zip(records, idx, strict=True)])  # (N, n)
    # the window on the times themselves (t_common is rounded to 1 us), as per_run_record and
    # metrics.json have it: a sample at score_from - _TOL is in
    win = np.asarray(records[0][p + "t"], dtype=float)[idx[0]] >= score_from - _TOL
    out.update(_nees_consistency(records, p, dof, band, nees, win))
    out["nis"] = _nis_consistency(records, p, score_from)
    out["convergence"] = _convergence(records, p, seeds)
    out["worst_runs"] = _worst_runs(ms, seeds, worst, command)
    out["bound"] = _bound_comparison(records, p, ms, ms2, kind, out["attitude_rmse_ci95_deg"])
    out["history"] = _history(records, p, t_common, idx, nees, band, max_history_points)
    return out


def _error_rmse(ms, ms2, kind: str) -> dict:
    """The attitude RMSE (per axis and total) and the second error's (``kind``: the gyro bias or
    the body rate; None where its truth is unknown), with their CIs, from the per-run window
    mean squares ``ms`` and ``ms2`` (N, 3)."""
    out = {}
    out["attitude_rmse_deg"], out["attitude_rmse_ci95_deg"] = _rmse_block(ms, DEG)
    M, lo, hi = mean_square_ci(ms.sum(axis=1))
    out["attitude_rmse_total_deg"] = None if M is None else _f(math.sqrt(M) / DEG)
    out["attitude_rmse_total_ci95_deg"] = None if lo is None else [_f(math.sqrt(lo) / DEG), _f(math.sqrt(hi) / DEG)]
    out["second_kind"] = kind
    out["bias_rmse_deg_per_h"] = out["bias_rmse_ci95_deg_per_h"] = None
    out["rate_rmse_deg_per_s"] = out["rate_rmse_ci95_deg_per_s"] = None
    if np.any(np.isfinite(ms2)):
        if kind == "gyro_bias":
            out["bias_rmse_deg_per_h"], out["bias_rmse_ci95_deg_per_h"] = _rmse_block(ms2, DEG_PER_H)
        else:
            out["rate_rmse_deg_per_s"], out["rate_rmse_ci95_deg_per_s"] = _rmse_block(ms2, DEG)
    return out


def _nees_consistency(records, p: str, dof: int, band, nees, win) -> dict:
    """The ANEES over runs and window samples and its bands: ``band`` at one instant, and the
    window's, with the NEES's correlation time estimated from ``nees`` (N, n) at the common
    times in the window (``win``)."""
    nsum = sum(float(r[p + "window_nees_sum"]) for r in records)
    ncount = sum(int(r[p + "window_nees_n"]) for r in records)
    anees = nsum / ncount if ncount else None
    out = {
        "nees_dof": dof,
        "anees": _f(anees),
        "anees_band_95": _fl(band),
        "anees_in_band": None if anees is None else bool(band[0] <= anees <= band[1]),
    }
    tau = integrated_autocorrelation_time(nees[:, win]) if np.sum(win) >= 4 else None
    out["nees_correlation_time_samples"] = _f(tau)
    if tau is not None and anees is not None:
        n_eff = max(1.0, np.sum(win) / tau)
        wband = anees_band(len(records), dof, samples_per_run=n_eff)
        out["anees_window_band_95"] = _fl(wband)
        out["anees_in_window_band"] = bool(wband[0] <= anees <= wband[1])
    else:
        out["anees_window_band_95"] = None
        out["anees_in_window_band"] = None
    return out


def _nis_consistency(records, p: str, score_from: float) -> dict:
    """Input name -> the mean NIS of the window's update attempts over every run and its band
    (inputs without a sample left out)."""
    nis = {}
    inputs = [str(x) for x in np.atleast_1d(records[0][p + "inputs"])]
    for i, input_name in enumerate(inputs):
        vals, dofs = [], []
        for r in records:
            if p + f"nis{i}__t" not in r:
                continue
            tn = np.asarray(r[p + f"nis{i}__t"], dtype=float)
            w = tn >= score_from - _TOL
            vals.append(np.asarray(r[p + f"nis{i}__value"], dtype=float)[w])
            dofs.append(np.asarray(r[p + f"nis{i}__dof"], dtype=float)[w])
        if not vals:
            continue
        v, d = np.concatenate(vals), np.concatenate(dofs)
        if v.size == 0:
            continue
        D = float(np.sum(d))
        nb = [chi2_q(0.025, D) / v.size, chi2_q(0.975, D) / v.size]
        mean = float(np.mean(v))
        nis[input_name] = {
            "source": str(records[0][p + "nis_source"]),
            "count": int(v.size),
            "mean": _f(mean),
            "mean_dof": _f(D / v.size),
            "band_95": _fl(nb),
            "in_band": bool(nb[0] <= mean <= nb[1]),
        }
    return nis


def _convergence(records, p: str, seeds) -> dict:
    """How many runs converged, the statistics of their convergence times, each seed's."""
    conv = np.array([float(r[p + "convergence_time_s"]) for r in records])
    ok = np.isfinite(conv)
    return {
        "fraction_converged": _f(np.mean(ok)) if len(records) else None,
        "n_converged": int(np.sum(ok)),
        "time_s": None
        if not np.any(ok)
        else {
            "min": _f(np.min(conv[ok])),
            "p10": _f(np.percentile(conv[ok], 10)),
            "median": _f(np.median(conv[ok])),
            "mean": _f(np.mean(conv[ok])),
            "p90": _f(np.percentile(conv[ok], 90)),
            "max": _f(np.max(conv[ok])),
        },
        "time_s_by_seed": {str(s): _f(c) for s, c in zip(seeds, conv, strict=True)},
    }


def _worst_runs(ms, seeds, worst: int, command) -> list:
    """The ``worst`` runs of the largest total attitude mean square ``ms`` (N, 3), largest first."""
    total = ms.sum(axis=1)
    order = [i for i in np.argsort(-np.where(np.isfinite(total), total, -np.inf), kind="stable")][:worst]
    return [
        {
            "seed": seeds[i],
            "attitude_rmse_total_deg": _f(math.sqrt(total[i]) / DEG) if np.isfinite(total[i]) else None,
            "attitude_rmse_deg": _fl(np.sqrt(ms[i]) / DEG),
            "command": command(seeds[i]),
        }
        for i in order
    ]


def _bound_comparison(records, p: str, ms, ms2, kind: str, rmse_ci95_deg) -> dict:
    """The bound's RMS over the window, pooled over runs, and the RMSEs ``ms``, ``ms2`` (with
    their CIs ``rmse_ci95_deg``) as ratios to it; ``defined`` false with the reason when a run
    has no bound."""
    infos = [json.loads(str(r[p + "bound_json"])) for r in records]
    has = [p + "bound_window_var" in r for r in records]
    bound: dict = {
        "defined": bool(all(has)),
        "reason": None,
        "attitude_rmse_bound_deg": None,
        "attitude_rmse_total_bound_deg": None,
        "ratio": None,
        "ratio_ci95": None,
        "ratio_total": None,
        "bias_rmse_bound_deg_per_h": None,
        "bias_ratio": None,
        "prior_sensitivity": None,
        "info": None,
    }
    if not all(has):
        bound["reason"] = next((i.get("reason") for i, h in zip(infos, has, strict=True) if not h), None)
        return bound
    bv = np.array([r[p + "bound_window_var"] for r in records], dtype=float)  # (N, 6)
    if np.all(np.isfinite(bv)):
        b_att = np.sqrt(bv[:, :3].mean(axis=0))
        bound["attitude_rmse_bound_deg"] = _fl(b_att / DEG)
        b_tot = math.sqrt(bv[:, :3].sum(axis=1).mean())
        bound["attitude_rmse_total_bound_deg"] = _f(b_tot / DEG)
        rm = np.sqrt(ms.mean(axis=0))
        bound["ratio"] = _fl(rm / b_att)
        bound["ratio_ci95"] = [
            None if c is None else [_f(c[0] * DEG / b), _f(c[1] * DEG / b)]
            for c, b in zip(rmse_ci95_deg, b_att, strict=True)
        ]
        bound["ratio_total"] = _f(math.sqrt(ms.sum(axis=1).mean()) / b_tot)
        b_bias = np.sqrt(bv[:, 3:].mean(axis=0))
        bound["bias_rmse_bound_deg_per_h"] = _fl(b_bias / DEG_PER_H)
        if kind == "gyro_bias" and np.all(np.isfinite(ms2)):
            bound["bias_ratio"] = _fl(np.sqrt(ms2.mean(axis=0)) / b_bias)
        sens = [i.get("prior_sensitivity") for i in infos if i.get("prior_sensitivity") is not None]
        bound["prior_sensitivity"] = _f(max(sens)) if sens else None
    else:
        bound["reason"] = "the scoring window holds no estimate"
    bound["info"] = {k: v for k, v in infos[0].items() if k not in ("reason", "prior_sensitivity")}
    return bound


def _history(records, p: str, t_common, idx, nees, band, max_history_points: int) -> dict:
    """For plots, at at most ``max_history_points`` of the common times ``t_common`` (``idx``:
    each record's indices of them): the RMS over runs of the attitude error, the mean NEES
    (``nees`` (N, n)) and its band, the bound's RMS 1-sigma (None unless every run has one)."""
    n = len(t_common)
    keep = np.unique(np.linspace(0, n - 1, min(n, max_history_points)).round().astype(int)) if n else np.zeros(0, int)
    d = np.array([np.asarray(r[p + "dtheta"], dtype=float)[i] for r, i in zip(records, idx, strict=True)])  # (N, n, 3)
    hist = {
        "t": _fl(t_common[keep]),
        "attitude_rmse_deg": [_fl(row) for row in np.sqrt(np.mean(d[:, keep] ** 2, axis=0)) / DEG],
        "anees": _fl(_nanmean0(nees[:, keep])),
        "anees_band_95": _fl(band),
        "bound_attitude_sigma_deg": None,
    }
    if all(p + "bound_sigma" in r for r in records):
        bs = np.array([np.asarray(r[p + "bound_sigma"], dtype=float)[i] for r, i in zip(records, idx, strict=True)])
        hist["bound_attitude_sigma_deg"] = [_fl(row) for row in np.sqrt(np.mean(bs[:, keep, :3] ** 2, axis=0)) / DEG]
    return hist


def summarize(
    records: list[dict],
    scenario,
    worst: int = 5,
    max_history_points: int = 1000,
    command_prefix: str = "drake-att run",
    scenario_arg: str | None = None,
    overrides=(),
) -> dict:
    """Ensemble statistics of ``records`` (:func:`per_run_record` of each run of ``scenario``;
    keys: the module docstring). JSON-able: plain floats, lists, dicts; None, never NaN.

    Args:
        worst: how many worst runs to list.
        max_history_points: at most this many instants in each ``history``.
        command_prefix, scenario_arg, overrides: the worst runs' re-run command is
            ``<command_prefix> <scenario_arg> --seed S [--set o ...]`` (``scenario_arg``
            defaults to the scenario's name; pass the YAML path for a scenario file and the
            campaign's ``--set`` overrides so the command repeats the run exactly).
    """
    import shlex

    scenario_text = shlex.quote(scenario_arg if scenario_arg is not None else scenario.name)
    sets = "".join(f" --set {shlex.quote(str(o))}" for o in overrides)

    def command(seed):
        return f"{command_prefix} {scenario_text} --seed {seed}{sets}"

    if not records:
        raise ValueError("summarize: no records (every run failed?)")
    names = [str(x) for x in np.atleast_1d(records[0]["estimators"])]
    scoring = scenario.scoring
    for r in records:
        if abs(float(r["score_from_s"]) - scoring.score_from_s) > _TOL:
            raise ValueError(
                f"seed {int(r['seed'])}: scored from {float(r['score_from_s'])} s, the scenario from "
                f"{scoring.score_from_s} s: records of another configuration?"
            )
        if [str(x) for x in np.atleast_1d(r["estimators"])] != names:
            raise ValueError(f"seed {int(r['seed'])}: estimators differ from the first record's {names}")
    return {
        "scenario": scenario.name,
        "n_runs": len(records),
        "seeds": [int(r["seed"]) for r in records],
        "score_from_s": float(scoring.score_from_s),
        "convergence_threshold_deg": float(scoring.convergence_threshold_deg),
        "methods": dict(METHODS),
        "estimators": {n: _estimator_summary(records, command, n, worst, max_history_points) for n in names},
    }
