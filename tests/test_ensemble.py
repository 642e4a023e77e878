"""Ensemble statistics (drake_att/analysis/ensemble.py): the RMSE confidence interval's
coverage, the ANEES bands' coverage and power, convergence and worst-seed bookkeeping on
constructed records, and a real record's round trip through np.savez / np.load."""

import io
import json

import numpy as np
import pytest

from drake_att.analysis import ensemble as ens
from drake_att.units import DEG


def _ar1(rng, shape, phi):
    """Stationary unit-variance AR(1) series along the last axis."""
    z = rng.standard_normal(shape)
    x = np.empty(shape)
    x[..., 0] = z[..., 0]
    c = np.sqrt(1.0 - phi * phi)
    for t in range(1, shape[-1]):
        x[..., t] = phi * x[..., t - 1] + c * z[..., t]
    return x


class _Scoring:
    def __init__(self, score_from_s=0.0, threshold=0.05):
        self.score_from_s, self.convergence_threshold_deg = score_from_s, threshold


class _Scenario:
    def __init__(self, name="synthetic", score_from_s=0.0):
        self.name, self.scoring = name, _Scoring(score_from_s)


def _record(seed, t, dtheta, nees, dof=6, conv=np.nan, score_from_s=0.0, name="f"):
    """A record as per_run_record writes it, from given series (no Drake)."""
    m = t >= score_from_s
    p = f"{name}__"
    fin = np.isfinite(nees[m])
    return {
        "schema": np.array(ens.RECORD_SCHEMA),
        "scenario": np.array("synthetic"),
        "seed": np.array(seed),
        "duration_s": np.array(float(t[-1])),
        "score_from_s": np.array(score_from_s),
        "convergence_threshold_deg": np.array(0.05),
        "estimators": np.array([name]),
        "metrics_json": np.array("{}"),
        p + "t": t,
        p + "dtheta": dtheta.astype(np.float32),
        p + "second_kind": np.array("gyro_bias"),
        p + "sigma": np.ones((len(t), 6), np.float32),
        p + "nees": nees.astype(np.float32),
        p + "nees_dof": np.array(dof),
        p + "window_n": np.array(int(m.sum())),
        p + "window_ms": np.mean(dtheta[m] ** 2, axis=0),
        p + "window_ms_second": np.full(3, np.nan),
        p + "window_nees_sum": np.array(float(nees[m][fin].sum())),
        p + "window_nees_n": np.array(int(fin.sum())),
        p + "convergence_time_s": np.array(float(conv)),
        p + "inputs": np.array([], dtype=str),
        p + "nis_source": np.array("none"),
        p + "bound_json": np.array(json.dumps({"reason": "synthetic"})),
    }


def test_rmse_ci_has_nominal_coverage():
    """95% CI of the mean square from per-run mean squares of AR(1) errors (correlation 0.8,
    100 samples per run), 2000 synthetic ensembles per case: the true variance (1) is
    inside 95% of the time (binomial sd 0.5%: accepted 93.5-96.5%) with 100 and with 20 runs."""
    rng = np.random.default_rng(11)
    for n_runs in (100, 20):
        hits = 0
        for _ in range(20):
            ms = np.mean(_ar1(rng, (100, n_runs, 100), 0.8) ** 2, axis=2)
            for row in ms:
                _, lo, hi = ens.mean_square_ci(row)
                hits += lo <= 1.0 <= hi
        assert 0.935 <= hits / 2000 <= 0.965, (n_runs, hits / 2000)


def test_summary_rmse_and_ci_come_from_the_per_run_mean_squares():
    rng = np.random.default_rng(2)
    t = np.arange(100.0)
    records = [_record(s, t, 1e-4 * (1 + 0.1 * s) * rng.standard_normal((100, 3)), np.full(100, 6.0)) for s in range(8)]
    out = ens.summarize(records, _Scenario())["estimators"]["f"]
    ms = np.array([r["f__window_ms"] for r in records])
    for j in range(3):
        M, lo, hi = ens.mean_square_ci(ms[:, j])
        assert out["attitude_rmse_deg"][j] == pytest.approx(np.sqrt(M) / DEG, rel=1e-12)
        assert out["attitude_rmse_ci95_deg"][j] == pytest.approx([np.sqrt(lo) / DEG, np.sqrt(hi) / DEG], rel=1e-12)
    assert out["bound"]["defined"] is False and out["bound"]["reason"] == "synthetic"


# scipy.stats.chi2.ppf / t.ppf (scipy 1.17), not imported here: it takes seconds to import.
CHI2_PPF = {
    (0.025, 1): 0.0009820691171752555,
    (0.025, 3): 0.21579528262389785,
    (0.025, 6): 1.2373442457912027,
    (0.025, 600): 534.0185504659327,
    (0.025, 5000): 4805.904730862248,
    (0.025, 600000): 597854.8619608814,
    (0.5, 1): 0.454936423119572,
    (0.5, 3): 2.3659738843753377,
    (0.5, 6): 5.348120627447118,
    (0.5, 600): 599.3334651808785,
    (0.5, 5000): 4999.33334913811,
    (0.5, 600000): 599999.333333465,
    (0.975, 1): 5.023886187314888,
    (0.975, 3): 9.348403604496148,
    (0.975, 6): 14.44937533544792,
    (0.975, 600): 669.7691522164112,
    (0.975, 5000): 5197.883771923797,
    (0.975, 600000): 602148.9266499715,
}
T_PPF_975 = {
    1: 12.706204736174694,
    2: 4.302652729749462,
    3: 3.1824463052837078,
    6: 2.4469118511449786,
    19: 2.0930240544083087,
    99: 1.9842169515864174,
}


def test_quantile_helpers():
    for (p, dof), x in CHI2_PPF.items():
        assert ens.chi2_q(p, dof) == pytest.approx(x, rel=2e-6), (p, dof)
    for dof, x in T_PPF_975.items():
        assert ens.t_q(0.975, dof) == pytest.approx(x, rel=1.5e-3), dof
        assert ens.t_q(0.025, dof) == pytest.approx(-x, rel=1.5e-3), dof


def test_anees_band_at_one_instant():
    """chi2(N dof)/N band, N = 50 runs, dof 6: consistent Gaussian errors' ANEES inside it
    95% of the time (4000 instants: 94-96%); errors scaled by 1.5 (NEES x 2.25) always out."""
    rng = np.random.default_rng(5)
    lo, hi = ens.anees_band(50, 6)
    anees = np.sum(rng.standard_normal((4000, 50, 6)) ** 2, axis=(1, 2)) / 50
    assert 0.94 <= np.mean((lo <= anees) & (anees <= hi)) <= 0.96
    assert not np.any((lo <= 2.25 * anees) & (2.25 * anees <= hi))


def test_window_anees_band_coverage_and_power():
    """The window ANEES band (N n_eff independent samples, n_eff from the NEES's integrated
    autocorrelation time): 20 runs x 300 samples of AR(1)-correlated (0.8) consistent 6-dof
    errors, 400 ensembles: inside ~95% of the time (the estimated n_eff is approximate:
    accepted 90-99%); scaled by 1.5 (NEES x 2.25): never inside; the per-instant band holds
    the consistent window ANEES always (it is much wider). The summary computes exactly this
    (checked on the last ensemble)."""
    rng = np.random.default_rng(8)
    inside = inside_scaled = inside_instant = 0
    trials, n_runs, n = 400, 20, 300
    lo_i, hi_i = ens.anees_band(n_runs, 6)
    for _ in range(trials):
        e = _ar1(rng, (n_runs, 6, n), 0.8)
        nees = np.sum(e**2, axis=1)
        tau = ens.integrated_autocorrelation_time(nees)
        lo, hi = ens.anees_band(n_runs, 6, samples_per_run=n / tau)
        a = float(np.mean(nees))
        inside += lo <= a <= hi
        inside_scaled += lo <= 2.25 * a <= hi
        inside_instant += lo_i <= a <= hi_i
    assert 0.90 <= inside / trials <= 0.99, inside / trials
    assert inside_scaled == 0
    assert inside_instant == trials
    assert 2.5 < tau < 7  # AR(1) 0.8, squared: (1 + 0.64) / (1 - 0.64) = 4.6
    t = np.arange(float(n))
    out = ens.summarize([_record(s, t, 1e-4 * e[s, :3].T, nees[s]) for s in range(n_runs)], _Scenario())["estimators"][
        "f"
    ]
    assert out["nees_correlation_time_samples"] == pytest.approx(tau, rel=1e-6)
    assert out["anees"] == pytest.approx(a, rel=1e-6)
    assert out["anees_window_band_95"] == pytest.approx([lo, hi], rel=1e-6)
    assert out["anees_in_window_band"] == (lo <= a <= hi) and out["anees_band_95"] == pytest.approx([lo_i, hi_i])


def test_convergence_and_worst_runs():
    t = np.arange(50.0)
    levels = {3: 1.0, 4: 4.0, 5: 2.0, 6: 3.0, 7: 0.5}  # seed -> error level (rad), to order the RMSE
    convs = {3: 2.0, 4: np.nan, 5: 10.0, 6: np.nan, 7: 0.0}
    records = [_record(s, t, np.full((50, 3), levels[s] * 1e-4), np.full(50, 6.0), conv=convs[s]) for s in levels]
    out = ens.summarize(records, _Scenario("cubesat_single_star_tracker"), worst=3)["estimators"]["f"]
    c = out["convergence"]
    assert c["fraction_converged"] == pytest.approx(0.6) and c["n_converged"] == 3
    assert c["time_s"]["min"] == 0.0 and c["time_s"]["median"] == 2.0 and c["time_s"]["max"] == 10.0
    assert c["time_s_by_seed"] == {"3": 2.0, "4": None, "5": 10.0, "6": None, "7": 0.0}
    assert [w["seed"] for w in out["worst_runs"]] == [4, 6, 5]
    assert out["worst_runs"][0]["command"] == "drake-att run cubesat_single_star_tracker --seed 4"
    sets = ens.summarize(
        records,
        _Scenario("x"),
        worst=1,
        scenario_arg="my dir/s.yaml",
        overrides=["duration_s=600", "estimators.f.initial_attitude_sigma_deg=1"],
    )
    assert sets["estimators"]["f"]["worst_runs"][0]["command"] == (
        "drake-att run 'my dir/s.yaml' --seed 4 --set duration_s=600 --set estimators.f.initial_attitude_sigma_deg=1"
    )
    assert out["worst_runs"][0]["attitude_rmse_total_deg"] == pytest.approx(np.sqrt(3) * 4e-4 / DEG, rel=1e-6)


def _check_json(obj):
    json.dumps(obj, allow_nan=False)


def test_real_record_round_trip_and_summary(tmp_path):
    """A real S3 run (60 s): per_run_record -> np.savez -> np.load(allow_pickle=False) ->
    record_from_npz gives the same arrays; the summary of it is strict JSON; the record's
    metrics are compute_metrics'; the status-NIS fallback equals the logged innovations
    (one-input estimator)."""
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.analysis.report import strict_json
    from drake_att.scenarios.builder import diagram_for
    from drake_att.scenarios.library import load

    sd = diagram_for(load("cubesat_single_star_tracker"))
    overrides = ["duration_s=60", "scoring.score_from_s=20"]
    run = sd.simulate(3, overrides=overrides)
    rec = ens.per_run_record(run)
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in rec.values())
    for key in (
        "t",
        "dtheta",
        "second_err",
        "sigma",
        "nees",
        "window_ms",
        "bound_sigma",
        "bound_window_var",
        "convergence_time_s",
        "nis0__t",
        "nis0__value",
        "nis0__dof",
    ):
        assert f"single__{key}" in rec, key
    assert rec["single__dtheta"].dtype == np.float32 and rec["single__t"].dtype == np.float64
    assert json.loads(str(rec["metrics_json"])) == json.loads(json.dumps(strict_json(compute_metrics(run))))
    assert list(rec["single__inputs"]) == ["st1"] and np.all(rec["single__nis0__dof"] == 3)
    # one update per second; the log of t holds what was known before t's update: 0..59
    np.testing.assert_array_equal(rec["single__nis0__t"], np.arange(60.0))

    path = tmp_path / "rec.npz"
    np.savez(path, **rec)
    with np.load(path, allow_pickle=False) as npz:
        back = ens.record_from_npz(npz)
    assert set(back) == set(rec)
    for k, v in rec.items():
        assert back[k].dtype == v.dtype and back[k].shape == v.shape, k
        np.testing.assert_array_equal(back[k], v, err_msg=k)

    summary = ens.summarize([back, rec], sd.scenario_for(overrides))
    _check_json(summary)
    s = summary["estimators"]["single"]
    assert s["bound"]["defined"] and s["nis"]["st1"]["count"] == 2 * 40

    # the status fallback (one input) gives the logged innovations' NIS
    source = str(rec["single__nis_source"])
    if source == "innovations":
        run.metadata = json.loads(json.dumps(run.metadata))
        del run.metadata["estimators"]["single"]["signals"]["innovations"]
        fallback = ens.per_run_record(run)
        assert str(fallback["single__nis_source"]) == "status"
        for k in ("t", "value", "dof"):
            np.testing.assert_allclose(fallback[f"single__nis0__{k}"], rec[f"single__nis0__{k}"], rtol=1e-12)
    else:
        assert source == "status"


def test_constructed_record_round_trip_without_pickle():
    rec = _record(1, np.arange(5.0), np.zeros((5, 3)), np.full(5, 6.0))
    buf = io.BytesIO()
    np.savez(buf, **rec)
    buf.seek(0)
    back = ens.record_from_npz(np.load(buf, allow_pickle=False))
    assert str(back["f__second_kind"]) == "gyro_bias" and back["f__inputs"].shape == (0,)
    assert ens.summarize([back], _Scenario())["estimators"]["f"]["attitude_rmse_ci95_deg"] == [None, None, None]


def test_a_records_metrics_are_each_estimators_own_with_several_estimators():
    """The record computes each estimator's errors once and hands them to the metrics: on the
    five-estimator default scenario (60 s) every estimator's metrics equal compute_metrics' own,
    and the estimators differ (a mix-up between them would show)."""
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.analysis.report import strict_json
    from drake_att.scenarios.builder import diagram_for
    from drake_att.scenarios.library import load

    sd = diagram_for(load("cubesat_dual_star_tracker"))
    run = sd.simulate(2, overrides=["duration_s=60", "scoring.score_from_s=20"])
    rec = json.loads(str(ens.per_run_record(run)["metrics_json"]))
    own = json.loads(json.dumps(strict_json(compute_metrics(run))))
    assert len(own["estimators"]) == 5 and rec == own
    rmse = {name: m["attitude_rmse_deg"] for name, m in own["estimators"].items()}
    assert len({json.dumps(v) for v in rmse.values()}) == 5, rmse
