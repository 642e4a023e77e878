"""Every statistic a Monte Carlo report prints, against its definition written in this file.

Each expected value is computed here from the definition - chi-square and Student quantiles
from ``scipy.stats``, rotations from ``scipy.spatial.transform``, autocorrelations as plain
lag sums, the scoring window as ``t >= score_from_s`` to the 1 us time tolerance - never with
drake_att's helpers. The inputs are synthetic records in the record format of
``drake_att/analysis/ensemble.py`` (its module docstring) or synthetic ``RunLog`` s that go
through the library's own ``per_run_record`` / ``compute_metrics``:

1. ANEES and NIS bands: the degrees of freedom of estimators and inputs of different and of
   mixed dimension, the number of runs, windows that start between samples, on a sample,
   four samples and just before the last sample.
2. The scoring window: exactly which samples are in (on a sample, inside the tolerance, at
   its edge, just beyond it, between samples, the last sample only, from the start), the
   same set in ``metrics.json``, the record, the summary's effective sample size, its NIS
   and the bound's window variance.
3. The effective sample size of the window band: the integrated autocorrelation time as
   written, and against the closed form ``(1 + phi^2) / (1 - phi^2)`` of AR(1) errors' NEES.
4. RMSE confidence intervals: the Student-t interval of the per-run mean squares, per axis,
   total, bias and rate, with its clipping; coverage of the true RMS over 2000 synthetic
   ensembles of 3 and of 10 runs.
5. The bound's frame conventions: a star tracker mounted off-axis, the bound against the
   brute-force information of the measurement model (finite-difference Jacobians of
   ``log((R_IB_nominal R_BS)^T R_IB R_BS)``), static and rotating, no gyro noise.
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from drake_att.analysis import ensemble as ens

TOL = 1e-6  # every window's time tolerance (s): metrics.TIME_MATCH_TOLERANCE_S
DEG = np.pi / 180.0
DEG_PER_H = DEG / 3600.0
QUANTILES = (0.025, 0.975)


# ---------------------------------------------------------------------------------------------
# Definitions, written here
# ---------------------------------------------------------------------------------------------
def in_window(t, score_from_s):
    """The scoring window: ``t >= score_from_s``, to the library's 1 us time tolerance."""
    return np.asarray(t, dtype=float) >= score_from_s - TOL


def integrated_autocorrelation_time(x):
    """``1 + 2 sum rho(l)`` over the initial positive sequence of the pair sums
    ``rho(1) + rho(2), rho(3) + rho(4), ...`` (stop at the first pair <= 0), ``rho`` the
    ensemble autocorrelation: per run (row) demeaned, ``c(l) = sum_t x_t x_{t+l} / n``,
    averaged over runs, ``rho = c / c(0)``; at least 1. Lag sums written out, no FFT."""
    x = np.asarray(x, dtype=float)
    x = x - x.mean(axis=1, keepdims=True)
    n = x.shape[1]

    def c(lag):
        return float(np.mean(np.sum(x[:, : n - lag] * x[:, lag:], axis=1))) / n

    c0 = c(0)
    tau, lag = 1.0, 1
    while lag + 1 < n:
        pair = (c(lag) + c(lag + 1)) / c0
        if pair <= 0:
            break
        tau += 2.0 * pair
        lag += 2
    return max(1.0, tau)


def chi2_band(dof, divisor):
    """Two-sided 95% band ``chi2(dof) / divisor`` (2.5% and 97.5% quantiles)."""
    return stats.chi2.ppf(QUANTILES, dof) / divisor


def assert_band(got, dof, divisor):
    """``got`` is ``chi2_band(dof, divisor)``. ensemble.chi2_q is exact to 1e-12 at integer
    dof up to 1000 and Wilson-Hilferty (< 2e-6) above; a non-integer dof up to 1000 is rounded
    (documented), so there ``got`` must lie between the bands of ``dof -+ 0.5``."""
    assert got is not None
    if dof > 1000 or float(dof).is_integer():
        np.testing.assert_allclose(got, chi2_band(dof, divisor), rtol=1e-5)
    else:
        lo, hi = chi2_band(dof - 0.5, divisor), chi2_band(dof + 0.5, divisor)
        assert np.all(lo * (1 - 1e-9) <= got) and np.all(np.asarray(got) <= hi * (1 + 1e-9)), (got, lo, hi)


def ar1(rng, shape, phi):
    """Stationary unit-variance Gaussian AR(1) series along the last axis."""
    z = rng.standard_normal(shape)
    x = np.empty(shape)
    x[..., 0] = z[..., 0]
    x[..., 1:] = lfilter([np.sqrt(1.0 - phi * phi)], [1.0, -phi], z[..., 1:], axis=-1, zi=phi * x[..., :1])[0]
    return x


# ---------------------------------------------------------------------------------------------
# Synthetic records (the record format of ensemble.py's module docstring)
# ---------------------------------------------------------------------------------------------
def _scenario(score_from_s):
    return SimpleNamespace(
        name="synthetic", scoring=SimpleNamespace(score_from_s=score_from_s, convergence_threshold_deg=0.05)
    )


def _record(seed, score_from_s, estimators):
    """One run's record. ``estimators``: name -> ``{"t", "dtheta" (n, 3), "nees" (n,), "dof"}``
    and optionally ``"second_err"`` (n, 3), ``"kind"``, ``"inputs"`` (names) with ``"nis"``
    (per input ``(t, value, dof)`` arrays, or None: no keys for that input in this run).
    The window fields follow the definition (:func:`in_window`)."""
    rec = {
        "schema": np.array(ens.RECORD_SCHEMA),
        "scenario": np.array("synthetic"),
        "seed": np.array(seed),
        "duration_s": np.array(100.0),
        "score_from_s": np.array(float(score_from_s)),
        "convergence_threshold_deg": np.array(0.05),
        "estimators": np.array(list(estimators), dtype=str),
        "metrics_json": np.array("{}"),
    }
    for name, e in estimators.items():
        p = f"{name}__"
        t = np.asarray(e["t"], dtype=float)
        m = in_window(t, score_from_s)
        d = np.asarray(e["dtheta"], dtype=float)
        nees = np.asarray(e["nees"], dtype=np.float32)
        s2 = e.get("second_err")
        rec.update(
            {
                p + "t": t,
                p + "dtheta": d.astype(np.float32),
                p + "second_kind": np.array(e.get("kind", "gyro_bias")),
                p + "sigma": np.ones((len(t), 6), np.float32),
                p + "nees": nees,
                p + "nees_dof": np.array(int(e["dof"])),
                p + "window_n": np.array(int(m.sum())),
                p + "window_ms": np.mean(d[m] ** 2, axis=0),
                p + "window_ms_second": np.full(3, np.nan) if s2 is None else np.mean(np.asarray(s2)[m] ** 2, axis=0),
                p + "window_nees_sum": np.array(float(np.sum(nees[m].astype(float)))),
                p + "window_nees_n": np.array(int(m.sum())),
                p + "convergence_time_s": np.array(np.nan),
                p + "inputs": np.array(e.get("inputs", []), dtype=str),
                p + "nis_source": np.array("innovations" if e.get("inputs") else "none"),
                p + "bound_json": np.array(json.dumps({"reason": "synthetic"})),
            }
        )
        if s2 is not None:
            rec[p + "second_err"] = np.asarray(s2, dtype=np.float32)
        for i, nis in enumerate(e.get("nis", [])):
            if nis is not None:
                rec[p + f"nis{i}__t"] = np.asarray(nis[0], dtype=np.float64)
                rec[p + f"nis{i}__value"] = np.asarray(nis[1], dtype=np.float64)
                rec[p + f"nis{i}__dof"] = np.asarray(nis[2], dtype=np.int32)
    return rec


# 100 samples at t = 0, 1, ..., 99 s
WINDOW_STARTS = {
    "between samples": 30.5,
    "on a sample": 30.0,
    "four samples": 96.0,
    "just before the last sample": 99.0 - 1e-3,
}


# ---------------------------------------------------------------------------------------------
# 1. ANEES and NIS bands
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n_runs", [30, 4])
@pytest.mark.parametrize("start", list(WINDOW_STARTS))
def test_anees_bands_use_each_estimators_dof_the_runs_and_the_window(start, n_runs):
    """Two estimators in one campaign, 3-dof and 6-dof NEES (AR(1) errors, 0.7): each one's
    ``anees_band_95`` is ``chi2(N dof)/N``; ``anees`` the mean NEES over runs and window
    samples; ``nees_correlation_time_samples`` the integrated autocorrelation time of the
    window's NEES; ``anees_window_band_95`` ``chi2(N n_eff dof)/(N n_eff)`` with
    ``n_eff = window samples / tau`` (None below 4 window samples). 30 runs put the window
    band's dof above 1000 (Wilson-Hilferty), 4 runs below (rounded dof: bracketed)."""
    s = WINDOW_STARTS[start]
    rng = np.random.default_rng(23 + n_runs)
    t = np.arange(100.0)
    dofs = {"three": 3, "six": 6}
    nees = {name: [] for name in dofs}
    records = []
    for seed in range(n_runs):
        ests = {}
        for name, dof in dofs.items():
            e = ar1(rng, (dof, len(t)), 0.7)
            n32 = np.sum(e**2, axis=0).astype(np.float32)
            nees[name].append(n32.astype(float))
            ests[name] = {"t": t, "dtheta": 1e-4 * e[:3].T, "nees": n32, "dof": dof}
        records.append(_record(seed, s, ests))
    summary = ens.summarize(records, _scenario(s))
    W = in_window(t, s)
    for name, dof in dofs.items():
        out = summary["estimators"][name]
        x = np.array(nees[name])  # (N, n)
        N = n_runs
        assert out["nees_dof"] == dof
        anees = x[:, W].mean()
        assert out["anees"] == pytest.approx(anees, rel=1e-12)
        band = chi2_band(N * dof, N)
        np.testing.assert_allclose(out["anees_band_95"], band, rtol=1e-9)
        assert out["anees_in_band"] == bool(band[0] <= anees <= band[1])
        assert out["history"]["anees_band_95"] == out["anees_band_95"]
        if W.sum() >= 4:
            tau = integrated_autocorrelation_time(x[:, W])
            assert out["nees_correlation_time_samples"] == pytest.approx(tau, rel=1e-9)
            n_eff = max(1.0, W.sum() / tau)
            assert_band(out["anees_window_band_95"], N * n_eff * dof, N * n_eff)
            wband = out["anees_window_band_95"]
            assert out["anees_in_window_band"] == bool(wband[0] <= anees <= wband[1])
        else:
            assert out["nees_correlation_time_samples"] is None
            assert out["anees_window_band_95"] is None and out["anees_in_window_band"] is None


@pytest.mark.parametrize("start", list(WINDOW_STARTS))
def test_nis_bands_of_inputs_of_mixed_dimension(start):
    """Three inputs of one estimator over 5 runs: a quaternion tracker (3-dof), a camera
    (2-dof; absent from the last run's record) and a vector tracker whose dimension changes
    between attempts and runs (6 or 9). Per input: ``count`` M and ``mean`` over the window's
    attempts (``t >= score_from_s``, attempts placed 3 us before, exactly at the 1 us edge,
    0.4 us before and at the start), ``mean_dof`` = D / M, ``band_95`` ``chi2(D)/M`` with D
    the sum of the window attempts' dimensions."""
    s = WINDOW_STARTS[start]
    rng = np.random.default_rng(7)
    t = np.arange(100.0)
    edge = np.array([s - 3e-6, s - TOL, s - 4e-7, s])  # out, in, in, in
    inputs = ["st_q", "cam", "st_v"]
    attempts = {name: [] for name in inputs}
    records = []
    N = 5
    for seed in range(N):
        times = {
            "st_q": np.sort(np.r_[np.arange(0.25, 100.0, 0.5), edge]),
            "cam": np.arange(0.1, 100.0, 1.0),
            "st_v": np.arange(0.1, 100.0, 0.7),
        }
        nis = []
        for name in inputs:
            tn = times[name]
            d = {"st_q": np.full(len(tn), 3), "cam": np.full(len(tn), 2), "st_v": rng.choice([6, 9], len(tn))}[name]
            v = rng.chisquare(d)
            if name == "cam" and seed == N - 1:
                nis.append(None)
                continue
            nis.append((tn, v, d))
            attempts[name].append((tn, v, d))
        ests = {
            "f": {
                "t": t,
                "dtheta": 1e-4 * rng.standard_normal((100, 3)),
                "nees": rng.chisquare(6, 100),
                "dof": 6,
                "inputs": inputs,
                "nis": nis,
            }
        }
        records.append(_record(seed, s, ests))
    out = ens.summarize(records, _scenario(s))["estimators"]["f"]["nis"]
    assert list(out) == inputs
    for name in inputs:
        tn, v, d = (np.concatenate(a) for a in zip(*attempts[name], strict=True))
        w = in_window(tn, s)
        M, D = int(w.sum()), int(d[w].sum())
        got = out[name]
        assert got["source"] == "innovations"
        assert got["count"] == M
        assert got["mean"] == pytest.approx(v[w].mean(), rel=1e-12)
        assert got["mean_dof"] == pytest.approx(D / M, rel=1e-12)
        assert_band(got["band_95"], D, M)
        assert got["in_band"] == bool(got["band_95"][0] <= v[w].mean() <= got["band_95"][1])


# ---------------------------------------------------------------------------------------------
# 2. The scoring window: the same samples in metrics.json, the record, the summary, the bound
# ---------------------------------------------------------------------------------------------
def _quat_wxyz(r: Rotation):
    return np.roll(r.as_quat(), 1, axis=-1)


def _fake_run(scenario, seed, t_est):
    """A RunLog of one MEKF-like estimator ("single": gyro + st1, as the scenario says) with
    estimates at ``t_est``, built from known errors: ``q_IB_hat = q_IB exp(-dtheta)``
    (AR(1) 0.9, ~1 mrad), bias error, a constant diagonal covariance (so the NEES is
    autocorrelated and its correlation time sees every window sample); innovations of two inputs (st1,
    3-dof, at every estimate; "cam", 2-dof, at every other). Returns the run and the known
    series."""
    from drake_att.scenarios.builder import RunLog

    rng = np.random.default_rng(seed)
    n = len(t_est)
    grid = np.arange(0.0, 41.0)  # the gyro's instants (the bound's grid)
    t_truth = np.unique(np.r_[np.arange(0.0, 40.0 + 1e-9, 0.5), t_est])
    w = np.array([0.01, -0.02, 0.015])
    R0 = Rotation.from_rotvec([0.3, -0.2, 1.1])
    truth = R0 * Rotation.from_rotvec(np.outer(t_truth, w))
    bias = 1e-4 + 1e-7 * np.outer(t_truth, [1.0, -2.0, 0.5])
    idx = np.searchsorted(t_truth, t_est)
    assert np.all(t_truth[idx] == t_est)
    dtheta = 1e-3 * ar1(rng, (3, n), 0.9).T
    second_err = 2e-6 * ar1(rng, (3, n), 0.9).T
    sig = np.tile(np.r_[rng.uniform(5e-4, 2e-3, 3), rng.uniform(1e-6, 4e-6, 3)], (n, 1))  # NEES as correlated as e
    P = np.zeros((n, 6, 6))
    P[:, range(6), range(6)] = sig**2
    e = np.c_[dtheta, second_err]
    nees = np.sum(e**2 / sig**2, axis=1)
    q_hat = _quat_wxyz(truth[idx] * Rotation.from_rotvec(-dtheta))
    b_hat = bias[idx] - second_err
    nis0, nis1 = rng.chisquare(3, n), rng.chisquare(2, n)
    # the log: row 0 is the initial estimate (estimate time 0), row i + 1 the estimate of t_est[i]
    logt = np.arange(n + 1.0)
    status = np.c_[np.r_[0.0, t_est], np.arange(n + 1.0), np.zeros(n + 1), np.r_[np.nan, nis0]]
    k1 = 2 * (np.arange(n) // 2)  # input 1 updates at every other estimate (repeated in between)
    innov = np.c_[
        np.r_[-np.inf, t_est],
        np.r_[np.nan, nis0],
        np.r_[0.0, np.full(n, 3.0)],
        np.r_[-np.inf, t_est[k1]],
        np.r_[np.nan, nis1[k1]],
        np.r_[0.0, np.full(n, 2.0)],
    ]
    t_st = np.arange(0.0, 40.0 + 1e-9, 0.5)
    signals = {
        "plant/q_IB": (t_truth, _quat_wxyz(truth)),
        "plant/w_IB_B": (t_truth, np.tile(w, (len(t_truth), 1))),
        "gyro/gyro_measurement": (grid, np.c_[grid, np.ones(len(grid)), np.tile(w, (len(grid), 1))]),
        "gyro/bias_B": (t_truth, bias),
        "st1/star_tracker_measurement": (
            t_st,
            np.c_[t_st, np.ones(len(t_st)), np.tile([1.0, 0, 0, 0], (len(t_st), 1))],
        ),
        "single/q_IB_hat": (logt, np.r_[[[1.0, 0, 0, 0]], q_hat]),
        "single/bias_B_hat": (logt, np.r_[[[0.0, 0, 0]], b_hat]),
        "single/covariance": (logt, np.r_[np.eye(6).reshape(1, 36), P.reshape(n, 36)]),
        "single/status": (logt, status),
        "single/innovations": (logt, innov),
    }
    meta = {
        "schema": RunLog.METADATA_SCHEMA,
        "scenario": scenario.name,
        "seed": seed,
        "wall_time_s": 0.0,
        "signals": list(signals),
        "truth": {"attitude": "plant/q_IB", "rate": "plant/w_IB_B"},
        "estimators": {
            "single": {
                "second_kind": "gyro_bias",
                "true_bias": "gyro/bias_B",
                "inputs": ["st1", "cam"],
                "signals": {
                    "attitude": "single/q_IB_hat",
                    "second": "single/bias_B_hat",
                    "covariance": "single/covariance",
                    "status": "single/status",
                    "innovations": "single/innovations",
                },
            }
        },
    }
    RunLog.check_metadata(meta)
    run = RunLog(scenario=scenario, seed=seed, wall_time_s=0.0, signals=signals, metadata=meta)
    updates1 = k1[::2]  # input 1's distinct update attempts
    known = {
        "dtheta": dtheta,
        "second_err": second_err,
        "nees": nees,
        "nis": [(t_est, nis0), (t_est[updates1], nis1[updates1])],
    }
    return run, known


# estimates at t = 0, 1, ..., 40 s; the one of 10 s may be logged a little early
WINDOW_CASES = {  # name: (score_from_s, time of the 10-s estimate)
    "on a sample": (10.0, 10.0),
    "inside the tolerance": (10.0, 10.0 - 4e-7),
    "at the tolerance's edge": (10.0, 10.0 - TOL),
    "just beyond the tolerance": (10.0, 10.0 - 2e-6),
    "between samples": (10.5, 10.0),
    "just before the last sample": (40.0 - 1e-3, 10.0),
    "from the start": (0.0, 10.0),
}


@pytest.mark.parametrize("case", list(WINDOW_CASES))
def test_scoring_window_is_one_set_of_samples_everywhere(case):
    """Three synthetic runs through the library's own ``per_run_record`` (which stores
    ``compute_metrics``) and ``summarize``: the window is exactly the estimates with
    ``t >= score_from_s`` (1 us tolerance, edge included) in ``metrics.json``
    (``samples_scored``, RMSE, bias RMSE, mean NEES), in the record (``window_n``,
    ``window_ms``, NEES sums, the bound's window variance = the bound's variances (from
    ``bound.run_bound``: the window is what is tested here) averaged over the window), and in
    the summary (samples per run, RMSE, ANEES, the NEES correlation
    time and window band, each input's NIS count and mean)."""
    from drake_att.analysis import bound as bd
    from drake_att.analysis import metrics as met
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios.library import load

    assert met.TIME_MATCH_TOLERANCE_S == TOL and bd.TIME_TOLERANCE_S == TOL
    s, t10 = WINDOW_CASES[case]
    scenario = cfg.apply_overrides(load("cubesat_single_star_tracker"), ["duration_s=40", f"scoring.score_from_s={s}"])
    t_est = np.arange(41.0)
    t_est[10] = t10
    W = in_window(t_est, s)
    expect_n = {
        "on a sample": 31,
        "inside the tolerance": 31,
        "at the tolerance's edge": 31,
        "just beyond the tolerance": 30,
        "between samples": 30,
        "just before the last sample": 1,
        "from the start": 41,
    }[case]
    assert W.sum() == expect_n  # the definition, spelled out
    records, knowns = [], []
    for seed in (1, 2, 3):
        run, known = _fake_run(scenario, seed, t_est)
        rec = ens.per_run_record(run)
        m = met.compute_metrics(run)["estimators"]["single"]
        assert json.loads(str(rec["metrics_json"]))["estimators"]["single"]["samples_scored"] == m["samples_scored"]
        d, se, nees = known["dtheta"][W], known["second_err"][W], known["nees"][W]
        # metrics.json
        assert m["samples_scored"] == W.sum()
        np.testing.assert_allclose(m["attitude_rmse_deg"], np.sqrt(np.mean(d**2, axis=0)) / DEG, rtol=1e-7)
        np.testing.assert_allclose(m["bias_rmse_deg_per_h"], np.sqrt(np.mean(se**2, axis=0)) / DEG_PER_H, rtol=1e-7)
        assert m["nees_mean"] == pytest.approx(nees.mean(), rel=1e-7)
        # the record
        assert int(rec["single__window_n"]) == W.sum()
        np.testing.assert_allclose(rec["single__window_ms"], np.mean(d**2, axis=0), rtol=1e-7)
        np.testing.assert_allclose(rec["single__window_ms_second"], np.mean(se**2, axis=0), rtol=1e-7)
        assert int(rec["single__window_nees_n"]) == W.sum()
        assert float(rec["single__window_nees_sum"]) == pytest.approx(nees.sum(), rel=1e-7)
        # the bound's window (defined where every estimate time is a gyro instant, to 1 us)
        if case == "just beyond the tolerance":
            assert "single__bound_window_var" not in rec
        else:
            P = bd.run_bound(run, "single").at(t_est[W])
            np.testing.assert_allclose(rec["single__bound_window_var"], np.einsum("kii->ki", P).mean(axis=0), rtol=1e-9)
        records.append(rec)
        knowns.append(known)
    out = ens.summarize(records, scenario)["estimators"]["single"]
    assert out["window_samples_per_run"] == W.sum()
    ms = np.array([np.mean(k["dtheta"][W] ** 2, axis=0) for k in knowns])
    np.testing.assert_allclose(out["attitude_rmse_deg"], np.sqrt(ms.mean(axis=0)) / DEG, rtol=1e-7)
    nees = np.array([r["single__nees"] for r in records], dtype=float)  # as stored (float32)
    assert out["anees"] == pytest.approx(np.mean([k["nees"][W] for k in knowns]), rel=1e-7)
    if W.sum() >= 4:
        tau = integrated_autocorrelation_time(nees[:, W])
        assert out["nees_correlation_time_samples"] == pytest.approx(tau, rel=1e-9)
        n_eff = max(1.0, W.sum() / tau)
        assert_band(out["anees_window_band_95"], 3 * n_eff * 6, 3 * n_eff)
    else:
        assert out["nees_correlation_time_samples"] is None
    for i, name in enumerate(["st1", "cam"]):
        tn = np.concatenate([k["nis"][i][0] for k in knowns])
        v = np.concatenate([k["nis"][i][1] for k in knowns])
        w = in_window(tn, s)
        assert out["nis"][name]["count"] == w.sum()
        assert out["nis"][name]["mean"] == pytest.approx(v[w].mean(), rel=1e-12)
        assert out["nis"][name]["mean_dof"] == (3.0 if name == "st1" else 2.0)


# ---------------------------------------------------------------------------------------------
# 3. The effective sample size of the window band
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("phi", [0.0, 0.5, 0.8])
def test_window_band_effective_sample_size_against_the_ar1_closed_form(phi):
    """48 runs x 1500 samples of 3-dof NEES from AR(1) errors (coefficient phi), scored from
    300.5 s (1199 window samples). The NEES autocorrelation is ``phi^(2l)`` (squares of a
    Gaussian AR(1)), so ``tau = (1 + phi^2) / (1 - phi^2)``: 1, 1.667, 4.556. The summary's
    ``nees_correlation_time_samples`` equals the definition on the window's NEES (1e-9) and
    the closed form within 10% (over 100 replications of this design the estimate's s.d. is
    1.0%, 2.0%, 2.6% and its mean +0.5%, -0.2%, -1.8% (per-run demeaning, truncation): 10% is
    more than 3 s.d. + bias); the window band's width is the closed form's (n_eff = 1199 / tau)
    within 6% (width ~ tau^0.5)."""
    rng = np.random.default_rng(int(100 * phi) + 5)
    N, n, s, dof = 48, 1500, 300.5, 3
    t = np.arange(float(n))
    e = ar1(rng, (N, dof, n), phi)
    nees = np.sum(e**2, axis=1).astype(np.float32)
    records = [_record(k, s, {"f": {"t": t, "dtheta": 1e-4 * e[k].T, "nees": nees[k], "dof": dof}}) for k in range(N)]
    out = ens.summarize(records, _scenario(s), max_history_points=10)["estimators"]["f"]
    W = in_window(t, s)
    assert W.sum() == 1199
    tau_hat = integrated_autocorrelation_time(nees[:, W])
    assert out["nees_correlation_time_samples"] == pytest.approx(tau_hat, rel=1e-9)
    tau = (1 + phi**2) / (1 - phi**2)
    assert out["nees_correlation_time_samples"] == pytest.approx(tau, rel=0.10)
    n_eff = W.sum() / tau
    lo, hi = chi2_band(N * n_eff * dof, N * n_eff)
    got = out["anees_window_band_95"]
    assert (got[1] - got[0]) == pytest.approx(hi - lo, rel=0.06)
    assert 0.5 * (got[0] + got[1]) == pytest.approx(dof, rel=0.01)


# ---------------------------------------------------------------------------------------------
# 4. RMSE confidence intervals
# ---------------------------------------------------------------------------------------------
def assert_rms_ci(got, per_run_ms, unit, t_rtol):
    """``got`` ([lo, hi] in ``unit``) is the 95% CI of the RMS from the per-run mean squares
    ``x``: ``M -+ t_{0.975}(N-1) s / sqrt(N)`` on their mean M (s: sample standard deviation,
    ddof 1), the lower end clipped at 0, square-rooted. Checked in mean-square units: the
    ends' squares are ``M -+ half`` with ``half`` to ``t_rtol`` (the library's t quantile)."""
    x = np.asarray(per_run_ms, dtype=float)
    N = len(x)
    M = x.mean()
    half = stats.t.ppf(0.975, N - 1) * x.std(ddof=1) / np.sqrt(N)
    lo2, hi2 = (np.asarray(got, dtype=float) * unit) ** 2
    assert hi2 == pytest.approx(M + half, rel=1e-12, abs=t_rtol * half)
    if M - half > 0:
        assert lo2 == pytest.approx(M - half, rel=1e-12, abs=t_rtol * half)
    else:
        assert lo2 == 0.0


def test_rmse_confidence_intervals_from_the_definition():
    """12 runs: per-axis and total attitude RMSE (deg) with their CIs, the gyro-bias RMSE
    (deg/h) and a body-rate estimator's rate RMSE (deg/s); 3 runs with one outlying run: the
    lower ends clipped at 0. Student's t quantile: the library's Cornish-Fisher expansion is
    within 2.2e-6 of scipy's at 11 dof (4.4e-5 at 6, 1.2e-3 at 3), exact at 2."""
    rng = np.random.default_rng(4)
    t = np.arange(50.0)
    for scale in (np.exp(0.3 * rng.standard_normal(12)), np.array([1.0, 1.2, 10.0])):  # 3 runs: M - half < 0
        N = len(scale)
        records, att, sec, rate = [], [], [], []
        for k in range(N):
            d = scale[k] * np.array([1e-4, 3e-4, 2e-5]) * rng.standard_normal((50, 3))
            b = scale[k] * 1e-6 * rng.standard_normal((50, 3))
            r = scale[k] * 1e-3 * rng.standard_normal((50, 3))
            att.append(np.mean(d[20:] ** 2, axis=0))
            sec.append(np.mean(b[20:] ** 2, axis=0))
            rate.append(np.mean(r[20:] ** 2, axis=0))
            records.append(
                _record(
                    k,
                    20.0,
                    {
                        "bias": {"t": t, "dtheta": d, "nees": np.full(50, 6.0), "dof": 6, "second_err": b},
                        "rate": {
                            "t": t,
                            "dtheta": d,
                            "nees": np.full(50, 6.0),
                            "dof": 6,
                            "second_err": r,
                            "kind": "body_rate",
                        },
                    },
                )
            )
        out = ens.summarize(records, _scenario(20.0))["estimators"]
        t_rtol = 1e-5 if N == 12 else 1e-9  # ensemble.t_q vs scipy: 2.2e-6 at 11 dof, exact at 2
        att, sec, rate = np.array(att), np.array(sec), np.array(rate)
        for name in ("bias", "rate"):
            o = out[name]
            np.testing.assert_allclose(o["attitude_rmse_deg"], np.sqrt(att.mean(axis=0)) / DEG, rtol=1e-9)
            for j in range(3):
                assert_rms_ci(o["attitude_rmse_ci95_deg"][j], att[:, j], DEG, t_rtol)
            assert o["attitude_rmse_total_deg"] == pytest.approx(np.sqrt(att.sum(axis=1).mean()) / DEG, rel=1e-9)
            assert_rms_ci(o["attitude_rmse_total_ci95_deg"], att.sum(axis=1), DEG, t_rtol)
        np.testing.assert_allclose(out["bias"]["bias_rmse_deg_per_h"], np.sqrt(sec.mean(axis=0)) / DEG_PER_H, rtol=1e-9)
        np.testing.assert_allclose(out["rate"]["rate_rmse_deg_per_s"], np.sqrt(rate.mean(axis=0)) / DEG, rtol=1e-9)
        for j in range(3):
            assert_rms_ci(out["bias"]["bias_rmse_ci95_deg_per_h"][j], sec[:, j], DEG_PER_H, t_rtol)
            assert_rms_ci(out["rate"]["rate_rmse_ci95_deg_per_s"][j], rate[:, j], DEG, t_rtol)
        assert out["bias"]["rate_rmse_deg_per_s"] is None and out["rate"]["bias_rmse_deg_per_h"] is None
        if N == 3:
            assert out["bias"]["attitude_rmse_ci95_deg"][0][0] == 0.0  # clipped
        else:
            assert all(ci[0] > 0 for ci in out["bias"]["attitude_rmse_ci95_deg"])


@pytest.mark.slow
@pytest.mark.parametrize("n_runs", [3, 10])
def test_rmse_confidence_interval_covers_the_true_rms_95_percent(n_runs):
    """2000 synthetic campaigns of N runs, each run 100 white Gaussian errors per axis with
    known sigmas (attitude [1, 2, 0.5] x 1e-4 rad, bias 1e-6 rad/s): the summary's 95% CIs of
    the x-axis, total and bias-x RMSE contain the true RMS (sigma_x, |sigma|, sigma_b) in
    95% +- 4 binomial s.d. (0.9305-0.9695) of the campaigns. (A z interval covers ~81% at
    3 runs and ~92% at 10.)"""
    rng = np.random.default_rng(n_runs)
    draws, n = 2000, 100
    sig = np.array([1e-4, 2e-4, 0.5e-4])
    sig_b = 1e-6
    t = np.arange(float(n))
    flat = np.ones(n, np.float32)
    hits = np.zeros(3)
    for _ in range(draws):
        records = []
        for k in range(n_runs):
            d = sig * rng.standard_normal((n, 3))
            b = sig_b * rng.standard_normal((n, 3))
            records.append(_record(k, 0.0, {"f": {"t": t, "dtheta": d, "nees": flat, "dof": 6, "second_err": b}}))
        o = ens.summarize(records, _scenario(0.0), max_history_points=2)["estimators"]["f"]
        for j, (ci, truth) in enumerate(
            (
                (o["attitude_rmse_ci95_deg"][0], sig[0] / DEG),
                (o["attitude_rmse_total_ci95_deg"], np.linalg.norm(sig) / DEG),
                (o["bias_rmse_ci95_deg_per_h"][0], sig_b / DEG_PER_H),
            )
        ):
            hits[j] += ci[0] <= truth <= ci[1]
    coverage = hits / draws
    band = 4 * np.sqrt(0.95 * 0.05 / draws)
    assert np.all(np.abs(coverage - 0.95) <= band), coverage


# ---------------------------------------------------------------------------------------------
# 5. The bound's frame conventions: an off-axis star tracker vs brute-force information
# ---------------------------------------------------------------------------------------------
BOUND_YAML = """
name: off_axis_tracker
duration_s: 12.0
sensors:
- !GyroConfig {name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.0, rrw_deg_per_h15: 0.0}
- !StarTrackerConfig
  name: st1
  period_s: 0.5
  mode: quaternion
  mounting: !RpyMounting {rpy_deg: [100.0, -30.0, 60.0]}
  sigma_cross_boresight_arcsec: 5.0
  sigma_boresight_arcsec: 50.0
estimators:
- !MekfConfig {name: single, period_s: 1.0, gyro: gyro, star_trackers: [st1],
               initial_attitude_sigma_deg: 5.0, initial_bias_sigma_deg_per_h: 20.0}
scoring: {score_from_s: 4.5}
"""


def _brute_force_bound(R0, w, R_BS, sigmas_S, P0, grid, valid):
    """The bound with no gyro noise, from the measurement model.

    Unknowns ``theta = [theta0, db]``: the initial attitude error and the (constant) gyro-bias
    error. The gyro reads the true rate ``w`` exactly, so under ``theta`` the attitude is
    ``R_IB(t) = R0 exp(theta0) exp((w - db) t)`` (the nominal: ``theta = 0``). A tracker
    sample at ``t`` measures ``R_IS = R_IB(t) R_BS exp(delta_S)``, ``delta_S ~ N(0,
    diag(sigmas_S^2))``: its residual is ``h(theta) = log((R_IB_nom(t) R_BS)^T R_IB(t) R_BS)``.
    The information on theta after the samples up to ``t_k`` is
    ``P0^-1 + sum H' R^-1 H`` (``H = dh/dtheta``, central differences); the state
    ``x_k = [log(R_IB_nom(t_k)^T R_IB(t_k)), db]`` is a function of theta (``A_k = dx_k/dtheta``),
    so its bound is ``A_k info^-1 A_k'``."""
    S = Rotation.from_matrix(R_BS)

    def attitude(theta, t):
        return R0 * Rotation.from_rotvec(theta[:3]) * Rotation.from_rotvec((w - theta[3:]) * t)

    def h(theta, t):
        return ((attitude(np.zeros(6), t) * S).inv() * attitude(theta, t) * S).as_rotvec()

    def x(theta, t):
        return np.r_[(attitude(np.zeros(6), t).inv() * attitude(theta, t)).as_rotvec(), theta[3:]]

    steps = np.r_[[1e-6] * 3, [1e-7] * 3]

    def jacobian(f, t):
        cols = []
        for i, step in enumerate(steps):
            dp = np.zeros(6)
            dp[i] = step
            cols.append((f(dp, t) - f(-dp, t)) / (2 * step))
        return np.array(cols).T

    Rinv = np.diag(1.0 / sigmas_S**2)
    info = np.linalg.inv(P0)
    out = []
    for k, tk in enumerate(grid):
        if valid[k]:
            H = jacobian(h, tk)
            info = info + H.T @ Rinv @ H
        A = jacobian(x, tk)
        out.append(A @ np.linalg.solve(info, A.T))
    return np.array(out)


@pytest.mark.parametrize("rate_deg_per_s", [0.0, 3.0])
def test_bound_of_an_off_axis_tracker_is_the_brute_force_information(rate_deg_per_s):
    """A star tracker mounted by roll/pitch/yaw [100, -30, 60] deg (``R_BS = Rz Ry Rx``;
    its boresight +z_S in B is far from where a transposed mounting would put it), 5"/50"
    noise in S, the gyro noiseless: the bound's covariance at each gyro instant equals the
    brute-force information bound of the measurement model, for a static attitude and a
    body rate of 3 deg/s about a skew axis. Tracker samples between gyro instants (t = k + 0.5)
    are not used (documented), an invalid sample at 3 s (and one at 7.5 s) is skipped; the
    counts say so."""
    from drake_att.analysis import bound as bd
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios.builder import RunLog

    scenario = cfg.load_scenario(text=BOUND_YAML)
    R_BS = Rotation.from_euler("xyz", [100.0, -30.0, 60.0], degrees=True).as_matrix()  # extrinsic x-y-z
    assert abs(R_BS[:, 2] @ R_BS[2, :]) < 0.5  # the transposed mounting's boresight is another axis
    sigmas_S = np.array([5.0, 5.0, 50.0]) * DEG / 3600
    P0 = np.diag([(5.0 * DEG) ** 2] * 3 + [(20.0 * DEG_PER_H) ** 2] * 3)
    w = rate_deg_per_s * DEG * np.array([0.48, -0.6, 0.64])
    R0 = Rotation.from_rotvec([0.4, 1.3, -0.7])
    grid = np.arange(13.0)
    t_st = np.arange(0.0, 12.0 + 1e-9, 0.5)
    valid_st = ~np.isin(t_st, [3.0, 7.5])
    truth = R0 * Rotation.from_rotvec(np.outer(t_st, w))
    meas = truth * Rotation.from_matrix(R_BS)
    signals = {
        "plant/q_IB": (t_st, _quat_wxyz(truth)),
        "gyro/gyro_measurement": (grid, np.c_[grid, np.ones(13), np.tile(w, (13, 1))]),
        "st1/star_tracker_measurement": (t_st, np.c_[t_st, valid_st.astype(float), _quat_wxyz(meas)]),
    }
    run = RunLog(
        scenario=scenario, seed=1, wall_time_s=0.0, signals=signals, metadata={"truth": {"attitude": "plant/q_IB"}}
    )
    result = bd.run_bound(run, "single")
    np.testing.assert_allclose(result.t, grid)
    brute = _brute_force_bound(R0, w, R_BS, sigmas_S, P0, grid, valid_st[::2])
    for k in range(len(grid)):
        d = np.sqrt(np.diag(brute[k]))
        np.testing.assert_allclose(
            result.P[k] / np.outer(d, d), brute[k] / np.outer(d, d), atol=1e-6, err_msg=f"t = {grid[k]} s"
        )
    counts = result.info["tracker_samples"]["st1"]
    assert counts == {"samples_used": 12, "samples_between_gyro_samples": 11, "samples_invalid": 2}


# ---------------------------------------------------------------------------------------------
# 6. What a record and a summary say in the corner cases
# ---------------------------------------------------------------------------------------------
def _relog(run, name="single", signals=None, roles=None, **spec):
    """``run`` (of :func:`_fake_run`) logged again: its estimator ``"single"`` named ``name``,
    ``signals`` (key -> (t, values)) added or replaced, the estimator's signal ``roles``
    (role -> key, or None: not logged) and other metadata entries (``spec``) replaced."""
    import copy

    from drake_att.scenarios.builder import RunLog

    meta = copy.deepcopy(run.metadata)
    e = meta["estimators"].pop("single")
    for role, key in (roles or {}).items():
        if key is None:
            del e["signals"][role]
        else:
            e["signals"][role] = key
    e.update(spec)
    meta["estimators"][name] = e
    sig = {**run.signals, **(signals or {})}
    meta["signals"] = list(sig)
    RunLog.check_metadata(meta)
    return RunLog(scenario=run.scenario, seed=run.seed, wall_time_s=0.0, signals=sig, metadata=meta)


def _scenario_40s(name="cubesat_single_star_tracker"):
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios.library import load

    return cfg.apply_overrides(load(name), ["duration_s=40", "scoring.score_from_s=10"])


def test_an_input_never_updated_has_empty_nis_arrays_and_no_summary_entry():
    """An innovations log whose second input ("cam") never attempted an update (time -inf,
    dimension 0 on every row): the record still holds its NIS arrays, empty 1-d arrays of
    the documented dtypes; the first input's are its attempts; the summary lists only the
    input that has attempts in the window."""
    scenario = _scenario_40s()
    t_est = np.arange(41.0)
    records, knowns = [], []
    for seed in (1, 2):
        run, known = _fake_run(scenario, seed, t_est)
        innov = run.values("single/innovations").copy()
        innov[:, 3], innov[:, 4], innov[:, 5] = -np.inf, np.nan, 0.0
        rec = ens.per_run_record(_relog(run, signals={"single/innovations": (run.times("single/innovations"), innov)}))
        assert str(rec["single__nis_source"]) == "innovations"
        assert [str(x) for x in rec["single__inputs"]] == ["st1", "cam"]
        for part, dtype in (("t", np.float64), ("value", np.float64), ("dof", np.int32)):
            a = rec[f"single__nis1__{part}"]
            assert a.shape == (0,) and a.dtype == dtype
        np.testing.assert_array_equal(rec["single__nis0__t"], known["nis"][0][0])
        np.testing.assert_allclose(rec["single__nis0__value"], known["nis"][0][1], rtol=1e-12)
        records.append(rec)
        knowns.append(known)
    out = ens.summarize(records, scenario)["estimators"]["single"]["nis"]
    assert list(out) == ["st1"]
    v = np.concatenate([k["nis"][0][1][in_window(t_est, 10.0)] for k in knowns])
    assert out["st1"]["count"] == v.size and out["st1"]["mean"] == pytest.approx(v.mean(), rel=1e-12)


def test_status_fallback_takes_the_nis_only_where_the_used_count_rose():
    """No innovations log, one quaternion tracker: the NIS samples are the status NIS at the
    estimates whose used-update count rose. The count rises at every other estimate (between
    attempts the status holds the last NIS), so the samples are the even estimates' NIS, each
    once, of dimension 3 (``nis_source`` "status")."""
    scenario = _scenario_40s()
    t_est = np.arange(41.0)
    n = len(t_est)
    records, expected = [], []
    for seed in (1, 2):
        run, known = _fake_run(scenario, seed, t_est)
        nis = known["nis"][0][1]
        k = np.arange(n)
        status = run.values("single/status").copy()
        status[1:, 1] = k // 2 + 1  # 1, 1, 2, 2, ...: an update at every even estimate
        status[1:, 3] = nis[k - k % 2]  # held between updates
        rec = ens.per_run_record(
            _relog(run, signals={"single/status": (run.times("single/status"), status)}, roles={"innovations": None})
        )
        assert str(rec["single__nis_source"]) == "status"
        assert [str(x) for x in rec["single__inputs"]] == ["st1"]
        np.testing.assert_array_equal(rec["single__nis0__t"], t_est[::2])
        np.testing.assert_allclose(rec["single__nis0__value"], nis[::2], rtol=1e-12)
        np.testing.assert_array_equal(rec["single__nis0__dof"], np.full(len(t_est[::2]), 3))
        assert "single__nis1__t" not in rec
        records.append(rec)
        expected.append(nis[::2][in_window(t_est[::2], 10.0)])
    out = ens.summarize(records, scenario)["estimators"]["single"]["nis"]
    v = np.concatenate(expected)
    assert out["st1"]["source"] == "status"
    assert out["st1"]["count"] == v.size and out["st1"]["mean"] == pytest.approx(v.mean(), rel=1e-12)


def test_two_input_estimator_without_innovations_log_has_nis_source_none():
    """An estimator of two trackers ("joint": st1 and st2) that logs no innovations: the
    status NIS cannot be split between its inputs, so the record says ``nis_source`` "none",
    lists both inputs and holds no NIS arrays; the summary's ``nis`` is empty."""
    scenario = _scenario_40s("cubesat_dual_star_tracker")
    run, _ = _fake_run(scenario, 1, np.arange(41.0))
    st = run.signals["st1/star_tracker_measurement"]
    rec = ens.per_run_record(
        _relog(run, name="joint", signals={"st2/star_tracker_measurement": st}, roles={"innovations": None})
    )
    assert str(rec["joint__nis_source"]) == "none"
    assert [str(x) for x in rec["joint__inputs"]] == ["st1", "st2"]
    assert not [k for k in rec if k.startswith("joint__nis") and k != "joint__nis_source"]
    assert ens.summarize([rec], scenario)["estimators"]["joint"]["nis"] == {}


@pytest.mark.parametrize("kind", ["gyro_bias", "body_rate"])
def test_record_and_summary_name_the_second_quantity_and_its_bound(kind):
    """The record's ``second_kind`` and the summary's are the estimator's (from the run's
    metadata), and the second error's RMSE is reported in its unit: bias (deg/h) or body rate
    (deg/s), from the known errors over the window. A body-rate (gyroless) estimator has no
    gyro-driven bound: no bound arrays in the record, its ``bound_json`` and the summary's
    ``bound.reason`` say it estimates the body rate."""
    scenario = _scenario_40s()
    t_est = np.arange(41.0)
    W = in_window(t_est, 10.0)
    records, ms2 = [], []
    for seed in (1, 2, 3):
        run, known = _fake_run(scenario, seed, t_est)
        if kind == "body_rate":
            rate_err = 1e-4 * np.random.default_rng(seed).standard_normal((len(t_est), 3))
            w = run.values("plant/w_IB_B")[0]
            w_hat = np.r_[[w], w - rate_err]  # row 0: the initial estimate
            run = _relog(
                run,
                signals={"single/w_B_hat": (run.times("single/status"), w_hat)},
                roles={"second": "single/w_B_hat"},
                second_kind="body_rate",
            )
            err = rate_err
        else:
            err = known["second_err"]
        rec = ens.per_run_record(run)
        assert str(rec["single__second_kind"]) == kind
        np.testing.assert_allclose(rec["single__second_err"], err, rtol=1e-6, atol=1e-12)
        info = json.loads(str(rec["single__bound_json"]))
        if kind == "body_rate":
            assert "single__bound_sigma" not in rec and "single__bound_window_var" not in rec
            assert "single" in info["reason"] and "body rate" in info["reason"]
        else:
            assert rec["single__bound_sigma"].shape == (len(t_est), 6) and info["reason"] is None
        records.append(rec)
        ms2.append(np.mean(err[W] ** 2, axis=0))
    out = ens.summarize(records, scenario)["estimators"]["single"]
    assert out["second_kind"] == kind
    rms = np.sqrt(np.mean(ms2, axis=0))
    if kind == "body_rate":
        np.testing.assert_allclose(out["rate_rmse_deg_per_s"], rms / DEG, rtol=1e-6)
        assert out["bias_rmse_deg_per_h"] is None
        assert out["bound"]["defined"] is False and out["bound"]["reason"] == info["reason"]
        assert out["history"]["bound_attitude_sigma_deg"] is None
    else:
        np.testing.assert_allclose(out["bias_rmse_deg_per_h"], rms / DEG_PER_H, rtol=1e-6)
        assert out["rate_rmse_deg_per_s"] is None
        assert out["bound"]["defined"] is True and out["bound"]["reason"] is None


def test_anees_is_undefined_when_no_window_nees_is_finite():
    """Every NEES sample in the window NaN (a singular covariance): the record's window NEES
    count is 0, so ``anees`` is None and so are ``anees_in_band`` and the window band; the
    one-instant band ``chi2(N dof)/N`` is still given."""
    t = np.arange(50.0)
    records = []
    for seed in range(4):
        nees = np.r_[np.full(20, 6.0), np.full(30, np.nan)]
        rec = _record(seed, 20.0, {"f": {"t": t, "dtheta": 1e-4 * np.ones((50, 3)), "nees": nees, "dof": 6}})
        rec["f__window_nees_sum"], rec["f__window_nees_n"] = np.array(0.0), np.array(0)  # the finite ones
        records.append(rec)
    out = ens.summarize(records, _scenario(20.0))["estimators"]["f"]
    assert out["anees"] is None
    assert out["anees_in_band"] is None
    assert out["anees_window_band_95"] is None and out["anees_in_window_band"] is None
    np.testing.assert_allclose(out["anees_band_95"], chi2_band(4 * 6, 4), rtol=1e-9)


def test_summary_bound_block_from_the_records_bound_variances():
    """Six runs whose records carry a bound (1-sigmas at the estimate times, float32, and the
    window's mean variances): ``attitude_rmse_bound_deg`` = sqrt(mean over runs of each
    axis' window variance), ``attitude_rmse_total_bound_deg`` = sqrt(mean over runs of
    their sum), ``ratio`` / ``ratio_total`` / ``ratio_ci95`` the RMSEs (and CI ends) over
    them, the bias bound and ratio likewise, ``prior_sensitivity`` the largest run's,
    ``info`` the first run's facts; the history's ``bound_attitude_sigma_deg`` is the RMS over
    runs of the stored 1-sigmas at each instant (computed in float64 from the stored values)."""
    rng = np.random.default_rng(11)
    t = np.arange(50.0)
    W = in_window(t, 20.0)
    N = 6
    records, ms, ms2, bv, bs, sens = [], [], [], [], [], []
    for seed in range(N):
        d = np.array([1e-4, 3e-4, 2e-5]) * rng.standard_normal((50, 3))
        b = 1e-6 * rng.standard_normal((50, 3))
        rec = _record(seed, 20.0, {"f": {"t": t, "dtheta": d, "nees": np.full(50, 6.0), "dof": 6, "second_err": b}})
        sigma = (np.r_[[1e-4, 2e-4, 3e-5], [1e-6, 2e-6, 5e-7]] * rng.uniform(0.5, 2.0, (50, 6))).astype(np.float32)
        var = np.mean(sigma[W].astype(float) ** 2, axis=0)
        ps = float(rng.uniform(0.0, 0.1))
        rec["f__bound_sigma"], rec["f__bound_window_var"] = sigma, var
        rec["f__bound_json"] = np.array(
            json.dumps(
                {"gyro": "gyro", "trackers": ["st1"], "seed_note": seed, "reason": None, "prior_sensitivity": ps}
            )
        )
        records.append(rec)
        ms.append(np.mean(d[W] ** 2, axis=0))
        ms2.append(np.mean(b[W] ** 2, axis=0))
        bv.append(var)
        bs.append(sigma.astype(float))
        sens.append(ps)
    out = ens.summarize(records, _scenario(20.0))["estimators"]["f"]
    bound = out["bound"]
    ms, ms2, bv, bs = np.array(ms), np.array(ms2), np.array(bv), np.array(bs)
    b_att = np.sqrt(bv[:, :3].mean(axis=0))
    b_tot = np.sqrt(bv[:, :3].sum(axis=1).mean())
    b_bias = np.sqrt(bv[:, 3:].mean(axis=0))
    assert bound["defined"] is True and bound["reason"] is None
    np.testing.assert_allclose(bound["attitude_rmse_bound_deg"], b_att / DEG, rtol=1e-12)
    assert bound["attitude_rmse_total_bound_deg"] == pytest.approx(b_tot / DEG, rel=1e-12)
    np.testing.assert_allclose(bound["ratio"], np.sqrt(ms.mean(axis=0)) / b_att, rtol=1e-9)
    assert bound["ratio_total"] == pytest.approx(np.sqrt(ms.sum(axis=1).mean()) / b_tot, rel=1e-9)
    for j in range(3):
        lo, hi = np.array(out["attitude_rmse_ci95_deg"][j]) * DEG
        np.testing.assert_allclose(bound["ratio_ci95"][j], [lo / b_att[j], hi / b_att[j]], rtol=1e-12)
    np.testing.assert_allclose(bound["bias_rmse_bound_deg_per_h"], b_bias / DEG_PER_H, rtol=1e-12)
    np.testing.assert_allclose(bound["bias_ratio"], np.sqrt(ms2.mean(axis=0)) / b_bias, rtol=1e-9)
    assert bound["prior_sensitivity"] == pytest.approx(max(sens), rel=1e-15)
    assert bound["info"] == {"gyro": "gyro", "trackers": ["st1"], "seed_note": 0}
    hist = out["history"]
    np.testing.assert_allclose(hist["t"], t)
    np.testing.assert_allclose(
        hist["bound_attitude_sigma_deg"], np.sqrt(np.mean(bs[:, :, :3] ** 2, axis=0)) / DEG, rtol=1e-12
    )


# -- the times every run has ------------------------------------------------------------------
def _times_of_every_run(time_lists):
    """The times (whole microseconds) that every run has: a set intersection."""
    sets = [{round(t * 1e6) for t in ts} for ts in time_lists]
    return sorted(set.intersection(*sets))


@pytest.mark.parametrize(
    "case",
    [
        "the same grid",
        "gaps and extra samples",
        "the first run shortest",
        "jitter under half a microsecond",
        "a repeated time in every run",
    ],
)
def test_common_times_are_the_times_every_run_has(case):
    from drake_att.analysis.ensemble import common_times

    rng = np.random.default_rng(len(case))
    grid = np.round(np.arange(0.0, 50.0, 0.1), 6)
    runs = [grid.copy() for _ in range(5)]
    if case == "gaps and extra samples":
        runs = [np.sort(np.r_[np.delete(grid, rng.choice(grid.size, 40, replace=False)), 50.05 + k]) for k in range(5)]
        runs[3] = grid.copy()  # a full run between gapped ones
    elif case == "the first run shortest":
        runs[0] = grid[:100]
    elif case == "jitter under half a microsecond":
        runs = [grid + rng.uniform(-0.4e-6, 0.4e-6, grid.size) for _ in range(5)]
    elif case == "a repeated time in every run":
        runs = [np.sort(np.r_[grid, grid[7]]) for _ in range(5)]
    records = [{"e__t": ts} for ts in runs]
    t, idx = common_times(records, "e")
    expected = _times_of_every_run(runs)
    np.testing.assert_allclose(t, np.array(expected) * 1e-6, rtol=0, atol=1e-12)
    for ts, i in zip(runs, idx, strict=True):
        np.testing.assert_allclose(ts[i], t, rtol=0, atol=0.5e-6)
