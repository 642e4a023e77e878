"""The posterior Cramér–Rao bound of gyro + star-tracker attitude determination
(drake_att/analysis/bound.py): the recursion against the LTI steady state and against a
brute-force batch information matrix, which estimators have a bound, and the MEKF's
efficiency on paper S3's single-tracker scenario."""

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.analysis import bound as bd
from drake_att.filters.mekf import process_noise, steady_state_covariance, transition_matrix
from drake_att.scenarios.library import load
from drake_att.sensors.star_tracker_plugin import star_tracker_mounting
from drake_att.units import ARCSEC, ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15

ARW = 0.56 * ARW_DEG_PER_RT_H  # paper S3's MEMS gyro
RRW = 123.75 * RRW_DEG_PER_H_15
SIGMAS_S = np.array([5.0, 5.0, 50.0]) * ARCSEC


def _tracker_model(st_name="st1"):
    sc = load("cubesat_dual_star_tracker")
    st = next(s for s in sc.sensors if s.name == st_name)
    R_SB = rot.quat_to_rotmat(star_tracker_mounting(st)).T
    return np.hstack([R_SB, np.zeros((3, 3))]), np.diag(SIGMAS_S**2)


def test_step_noise_is_the_mekf_process_noise_without_rotation():
    """With ``J = dt I`` the bound's interval noise is exactly the MEKF's ``Q``."""
    for dt in (0.1, 1.0, 2.5):
        np.testing.assert_allclose(
            bd.farrenkopf_step_noise(ARW, RRW, dt), process_noise(ARW, RRW, dt), rtol=1e-14, atol=0
        )


@pytest.mark.parametrize("w", [np.zeros(3), np.array([0.01, -0.02, 0.03])])
def test_recursion_converges_to_the_lti_steady_state(w):
    """(a) A constant rate, the S3 gyro and tracker at every step: the recursion's
    posterior after 3000 steps is the steady-state posterior of the DARE
    (:func:`drake_att.filters.mekf.steady_state_covariance`)."""
    dt = 1.0
    Phi = transition_matrix(w, dt)
    Q = bd.farrenkopf_step_noise(ARW, RRW, dt, -Phi[:3, 3:])
    H, R = _tracker_model()
    P0 = np.diag([(5 * DEG) ** 2] * 3 + [(20 * DEG_PER_H) ** 2] * 3)
    n = 3000
    P = bd.covariance_recursion(P0, [Phi] * n, [Q] * n, [[(H, R)]] * n)
    _, P_post = steady_state_covariance(Phi, Q, H, R)
    d = np.sqrt(np.diag(P_post))
    np.testing.assert_allclose(P[-1] / np.outer(d, d), P_post / np.outer(d, d), atol=1e-9)


def _batch_filtered_covariance(P0, transitions, noises, measurements, k_end):
    """Brute force: the information matrix of the whole trajectory x_0..x_k_end (prior,
    every process step, every measurement up to k_end); the filtered covariance of x_k_end
    is the last 6x6 block of its inverse. States in scaled units (arcsec, deg/h) so the
    6(k+1)-square matrix is well conditioned."""
    s = np.array([1 / ARCSEC] * 3 + [1 / DEG_PER_H] * 3)  # rad -> arcsec, rad/s -> deg/h
    S = np.diag(s)
    n = 6 * (k_end + 1)
    L = np.zeros((n, n))
    L[:6, :6] += np.linalg.inv(S @ P0 @ S)
    for k in range(1, k_end + 1):
        Phi = S @ transitions[k] @ np.linalg.inv(S)
        Qi = np.linalg.inv(S @ noises[k] @ S)
        A = np.zeros((6, n))
        A[:, 6 * (k - 1) : 6 * k] = -Phi
        A[:, 6 * k : 6 * k + 6] = np.eye(6)
        L += A.T @ Qi @ A
    for k in range(k_end + 1):
        for H, R in measurements[k]:
            Hs = H @ np.linalg.inv(S)
            L[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] += Hs.T @ np.linalg.solve(R, Hs)
    C = np.linalg.inv(L)[-6:, -6:]
    Si = np.linalg.inv(S)
    return Si @ C @ Si


def test_recursion_equals_batch_information_and_information_form():
    """(b) A time-varying rate, two trackers with different mountings, missing samples:
    the covariance-form recursion equals (1) the brute-force batch information matrix of the
    whole trajectory (marginal of the last state) at every step and (2) the information-form
    recursion."""
    rng = np.random.default_rng(3)
    K, dt = 16, 1.0
    w = rng.normal(0.0, 0.03, (K, 3))  # rad/s, a few deg/s
    transitions, noises = [None], [None]
    for k in range(1, K):
        Phi = transition_matrix(w[k], dt)
        transitions.append(Phi)
        noises.append(bd.farrenkopf_step_noise(ARW, RRW, dt, -Phi[:3, 3:]))
    m1, m2 = _tracker_model("st1"), _tracker_model("st2")
    measurements = []
    for k in range(K):
        meas = [m1] if k % 3 != 2 else []
        if k % 4 == 1:
            meas.append(m2)
        measurements.append(meas)
    P0 = np.diag([(5 * DEG) ** 2] * 3 + [(20 * DEG_PER_H) ** 2] * 3)
    P = bd.covariance_recursion(P0, transitions, noises, measurements)
    P_info = bd.information_recursion(P0, transitions, noises, measurements)
    for k in (0, 1, 2, 5, 9, K - 1):
        d = np.sqrt(np.diag(P[k]))
        batch = _batch_filtered_covariance(P0, transitions, noises, measurements, k)
        np.testing.assert_allclose(batch / np.outer(d, d), P[k] / np.outer(d, d), atol=1e-7, err_msg=f"step {k}")
        np.testing.assert_allclose(P_info[k] / np.outer(d, d), P[k] / np.outer(d, d), atol=1e-7, err_msg=f"step {k}")


def test_which_estimators_have_a_bound():
    """Gyro + star trackers: defined (an average and a fusion read their raw trackers);
    gyroless, camera, fault injection, S1's correlated gyro noise: None with the reason."""
    dual = load("cubesat_dual_star_tracker")
    expect = {
        "single": ["st1"],
        "single_st2": ["st2"],
        "centralized": ["st1", "st2"],
        "joint": ["st1", "st2"],
        "decentralized": ["st1", "st2"],
    }
    for name, trackers in expect.items():
        src = bd.bound_sources(dual, name)
        assert [t.name for t in src["trackers"]] == trackers and src["gyro"].name == "gyro"
    for scenario, estimator, words in (
        ("s0_gyroless_pf", None, "no gyro"),
        ("s2_indoor_dynamic", None, "camera"),
        ("fault_campaign", None, "fault injection"),
        ("s1_cqe", None, "S1"),
    ):
        sc = load(scenario)
        names = [estimator] if estimator else [e.name for e in sc.estimators]
        for name in names:
            with pytest.raises(bd.NoBound, match=words):
                bd.bound_sources(sc, name)
    # S0's gyro + vector tracker filters have one
    s0 = load("s0_particle_filters_small_error")
    for e in s0.estimators:
        assert bd.bound_sources(s0, e.name)["trackers"][0].mode == "vectors"


@pytest.mark.slow
def test_mekf_is_efficient_and_a_mistuned_one_is_not():
    """(c) Paper S3 single tracker, shortened to 350 s (scored from 50 s), 12 seeds.

    * The MEKF's own covariance is the bound (same data, same linearization up to the
      measured vs the true rate): its window 1-sigmas equal the bound's within 0.5%.
    * Its Monte Carlo RMSE per axis matches the bound: |RMSE/bound - 1| < 3 standard errors.
      The relative standard error of the RMSE is ``s / (2 sqrt(N) M)`` from the N = 12
      per-run mean squares (mean M, standard deviation s; runs independent): about 2.5-3% here
      (300 window samples with a ~5-sample error correlation time per run), so the tolerance
      is ~8%.
    * The same MEKF with 100x the gyro's ARW (6 seeds of 250 s) leans on the tracker alone: roll and
      pitch (where the 50" boresight noise projects) sit >= 25% and > 5 standard errors
      above the bound, its total RMSE >= 20% above.
    """
    from drake_att.analysis.ensemble import per_run_record, summarize
    from drake_att.scenarios.builder import diagram_for

    sd = diagram_for(load("cubesat_single_star_tracker"))

    def campaign(seeds, duration, extra=()):
        overrides = [f"duration_s={duration}", "scoring.score_from_s=50"] + list(extra)
        records = [per_run_record(sd.simulate(seed, overrides=overrides)) for seed in seeds]
        return records, summarize(records, sd.scenario_for(overrides))["estimators"]["single"]

    records, s = campaign(range(1, 13), 350)
    b = s["bound"]
    assert b["defined"] and b["prior_sensitivity"] < 1e-3
    # the MEKF's covariance is the bound
    for r in records:
        m = r["single__t"] >= 50
        np.testing.assert_allclose(r["single__sigma"][m], r["single__bound_sigma"][m], rtol=5e-3)
    ms = np.array([r["single__window_ms"] for r in records])
    se = ms.std(axis=0, ddof=1) / (2 * np.sqrt(len(ms)) * ms.mean(axis=0))
    assert np.all(se < 0.04)
    print("efficient: ratio", b["ratio"], "se", se)
    assert np.all(np.abs(np.array(b["ratio"]) - 1) < 3 * se), (b["ratio"], se)

    records, s = campaign(range(101, 107), 250, ["estimators.single.arw_deg_per_rt_h=56.0"])
    b = s["bound"]
    ms = np.array([r["single__window_ms"] for r in records])
    se = ms.std(axis=0, ddof=1) / (2 * np.sqrt(len(ms)) * ms.mean(axis=0))
    ratio = np.array(b["ratio"])
    print("mistuned: ratio", ratio, "se", se)
    assert np.all(ratio[:2] >= 1.25) and np.all(ratio[:2] - 1 > 5 * se[:2]), (ratio, se)
    assert b["ratio_total"] >= 1.2


# ---------------------------------------------------------------------------------------------
# BoundResult, the prior fallback, the sample index and bound_model on small synthetic logs
# ---------------------------------------------------------------------------------------------
def test_bound_sigma_is_the_root_of_the_diagonal_with_round_off_negatives_at_zero():
    P = np.zeros((2, 6, 6))
    P[0] = np.diag([4.0, 9.0, 16.0, 1e-12, 2.5e-13, 1.0])
    P[1] = np.diag([1.0, -1e-30, 0.25, 0.0, 1e-14, 4.0])  # a round-off negative variance
    s = bd.BoundResult(np.array([0.0, 1.0]), P).sigma()
    np.testing.assert_array_equal(s, [[2.0, 3.0, 4.0, 1e-6, 5e-7, 1.0], [1.0, 0.0, 0.5, 0.0, 1e-7, 2.0]])


def test_bound_at_accepts_float32_times_within_a_microsecond_of_the_gyro_instants():
    """Estimate times read from a float32 log: every one within 1 us of a gyro instant
    (including those rounded up by float32 above 32 s) gives the bound of that instant."""
    t = np.arange(400) * 0.1
    P = np.arange(400, dtype=float)[:, None, None] * np.ones((1, 6, 6))
    res = bd.BoundResult(t, P)
    t32 = t.astype(np.float32)
    near = np.flatnonzero(np.abs(t32.astype(float) - t) <= 1e-6)
    assert np.any(t32[near].astype(float) > t[near] + 5e-7)  # some are rounded up by > 0.5 us
    np.testing.assert_array_equal(res.at(t32[near])[:, 0, 0], near)


def test_step_noise_of_a_float32_bias_block_is_computed_in_double_precision():
    """``J`` given in float32 gives the ``Q`` of its (exact) float64 values: ``C00 J J'``,
    ``-C01 J``, ``C11 I`` with the Farrenkopf interval covariance
    ``[[sv^2/T + su^2 T/3, su^2 T/2], [su^2 T/2, su^2 T]]``."""
    dt = 1.0
    J = (-transition_matrix(np.array([0.3, -0.2, 0.25]), dt)[:3, 3:]).astype(np.float32)
    J64 = J.astype(float)
    c00, c01, c11 = ARW**2 / dt + RRW**2 * dt / 3, RRW**2 * dt / 2, RRW**2 * dt
    expect = np.zeros((6, 6))
    expect[:3, :3] = c00 * (J64 @ J64.T)
    expect[:3, 3:] = -c01 * J64
    expect[3:, :3] = -c01 * J64.T
    expect[3:, 3:] = c11 * np.eye(3)
    Q = bd.farrenkopf_step_noise(ARW, RRW, dt, J)
    assert Q.dtype == np.float64
    np.testing.assert_allclose(Q, expect, rtol=1e-13, atol=0)


@pytest.mark.parametrize(
    "b0, sigma_b0, expect_deg_per_h",
    [([1.0, -3.0, 2.0], 0.0, 3.0), ([1.0, 1.0, 1.0], 5.0, 5.0), ([0.0, 0.2, -0.1], 0.5, 1.0)],
)
def test_prior_without_initial_sigmas_uses_1_rad_and_the_largest_of_b0_sigma_b0_and_1_deg_per_h(
    b0, sigma_b0, expect_deg_per_h
):
    from dataclasses import replace
    from types import SimpleNamespace

    gyro = next(s for s in load("cubesat_single_star_tracker").sensors if s.name == "gyro")
    gyro = replace(gyro, initial_bias_deg_per_h=b0, initial_bias_sigma_deg_per_h=sigma_b0)
    P0, where = bd.prior_covariance({"prior_config": SimpleNamespace(name="bare"), "gyro": gyro})
    np.testing.assert_allclose(P0, np.diag([1.0] * 3 + [(expect_deg_per_h * DEG_PER_H) ** 2] * 3), rtol=1e-15)
    assert "bare" in where and "attitude" in where and "bias" in where


def test_sample_index_finds_the_sample_within_a_microsecond_or_minus_one():
    times = np.array([0.0, 1.0, 2.0])
    grid = np.array([-1.0, 0.0, 1.5, 2.0 + 5e-7, 3.0, 10.0])
    np.testing.assert_array_equal(bd._sample_index(times, grid), [-1, 0, -1, 2, -1, -1])
    # a single sample: found at its own time only, grid points after it are -1
    np.testing.assert_array_equal(
        bd._sample_index(np.array([1.0]), np.array([0.0, 1.0 - 5e-7, 2.0, 3.0])), [-1, 0, -1, -1]
    )
    np.testing.assert_array_equal(bd._sample_index(np.array([]), np.array([0.0, 1.0])), [-1, -1])


_W_TRUE = np.array([0.01, -0.02, 0.03])  # rad/s
_Q0 = rot.rpy_to_quat(np.array([0.3, -0.2, 1.0]))


def _synthetic_run(scenario, K=6, T=1.0, gyro_edit=None, signals=()):
    """A RunLog of ``K`` gyro samples (period ``T``) on a constant-rate truth starting at
    ``_Q0``, plus the extra ``signals``."""
    from drake_att.scenarios.builder import RunLog

    t = np.arange(K) * T
    q = np.array([rot.quat_propagate(_Q0, _W_TRUE, tk) for tk in t])
    g = np.column_stack([t, np.ones(K), np.tile(_W_TRUE, (K, 1))])
    if gyro_edit:
        gyro_edit(g)
    sig = {"gyro/gyro_measurement": (t, g), "truth/q_IB": (t, q), **dict(signals)}
    return RunLog(
        scenario=scenario, seed=1, wall_time_s=0.0, signals=sig, metadata={"truth": {"attitude": "truth/q_IB"}}
    )


def _single_with_tracker_log():
    ts = np.arange(51) * 0.1  # 10 Hz over the gyro's 0..5 s
    x = np.column_stack([ts, np.ones(51), np.tile([1.0, 0.0, 0.0, 0.0], (51, 1))])
    return load("cubesat_single_star_tracker"), {"st1/star_tracker_measurement": (ts, x)}


def test_quaternion_tracker_bound_model_uses_the_samples_at_gyro_instants_and_reports_them():
    sc, sig = _single_with_tracker_log()
    model = bd.bound_model(_synthetic_run(sc, signals=sig), "single")
    info = model["info"]
    assert info["gyro"] == "gyro" and info["trackers"] == ["st1"] and info["grid_period_s"] == 1.0
    assert info["tracker_samples"] == {
        "st1": {"samples_used": 6, "samples_between_gyro_samples": 45, "samples_invalid": 0}
    }
    st = next(s for s in sc.sensors if s.name == "st1")
    R_SB = rot.quat_to_rotmat(star_tracker_mounting(st)).T
    for meas in model["measurements"]:
        assert len(meas) == 1
        H, R = meas[0]
        np.testing.assert_allclose(H, np.hstack([R_SB, np.zeros((3, 3))]), atol=1e-15)
        np.testing.assert_allclose(R, np.diag(SIGMAS_S**2), rtol=1e-15)


def test_a_flagged_invalid_gyro_sample_has_no_bound():
    sc, sig = _single_with_tracker_log()

    def invalid(g):
        g[3, 1] = 0.0  # time right, flagged invalid

    with pytest.raises(bd.NoBound, match="unusable"):
        bd.bound_model(_synthetic_run(sc, gyro_edit=invalid, signals=sig), "single")


def test_the_gyro_sample_at_t0_is_not_used_so_a_nan_there_keeps_the_bound():
    """No interval ends at t = 0: the first gyro sample is not read (a NaN there is fine)."""
    sc, sig = _single_with_tracker_log()

    def nan_first(g):
        g[0, 2:] = np.nan

    model = bd.bound_model(_synthetic_run(sc, gyro_edit=nan_first, signals=sig), "single")
    assert len(model["t"]) == 6 and all(np.all(np.isfinite(Phi)) for Phi in model["transitions"][1:])


def test_vector_tracker_information_is_sum_of_projections_off_each_true_direction():
    """A vector tracker (S0's ``ekf``; 0.5 s period, an outage over [2, 3) s, non-unit
    references): at each gyro instant outside the outage its directions add
    ``sum_i (I - b_i b_i') / s^2`` to the attitude information (``b_i = R_BI r_i / |r_i|`` at the
    TRUE attitude; ``[b x]' R_SB' R_SB [b x] = I - b b'``) and nothing to the bias."""
    from dataclasses import replace

    sc = load("s0_particle_filters_small_error")
    refs = np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.3, -0.4, 1.2]])
    sensors = [
        replace(s, period_s=0.5, outage_windows_s=np.array([[2.0, 3.0]]), references_I=refs, sigma_vector_urad=100.0)
        if s.name == "st"
        else s
        for s in sc.sensors
    ]
    run = _synthetic_run(replace(sc, sensors=sensors))
    model = bd.bound_model(run, "ekf")
    s = 100e-6
    for k, tk in enumerate(model["t"]):
        info = sum((H.T @ np.linalg.solve(R, H) for H, R in model["measurements"][k]), np.zeros((6, 6)))
        expect = np.zeros((6, 6))
        if not 2.0 <= tk < 3.0:
            R_BI = rot.quat_to_rotmat(rot.quat_propagate(_Q0, _W_TRUE, tk)).T
            for r in refs:
                b = R_BI @ (r / np.linalg.norm(r))
                expect[:3, :3] += (np.eye(3) - np.outer(b, b)) / s**2
        np.testing.assert_allclose(info, expect, rtol=1e-9, atol=1e-9 / s**2, err_msg=f"t = {tk}")
    # 11 samples over 0..5 s: 2 in the outage, 5 at gyro instants, 4 between
    assert model["info"]["tracker_samples"] == {
        "st": {"samples_used": 5, "samples_between_gyro_samples": 4, "samples_invalid": 2}
    }


def test_prior_with_both_initial_sigmas_says_they_are_the_estimators_own():
    """Both sigmas given: P0 is diag(sigma_att^2, sigma_bias^2) and the sentence names the estimator."""
    from types import SimpleNamespace

    gyro = next(s for s in load("cubesat_single_star_tracker").sensors if s.name == "gyro")
    prior = SimpleNamespace(name="mine", initial_attitude_sigma_deg=2.0, initial_bias_sigma_deg_per_h=7.0)
    P0, where = bd.prior_covariance({"prior_config": prior, "gyro": gyro})
    np.testing.assert_allclose(P0, np.diag([(2.0 * DEG) ** 2] * 3 + [(7.0 * DEG_PER_H) ** 2] * 3), rtol=1e-15)
    assert where == "mine's initial sigmas", where
    _, only_bias = bd.prior_covariance(
        {"prior_config": SimpleNamespace(name="half", initial_attitude_sigma_deg=2.0), "gyro": gyro}
    )
    assert only_bias == "half gives no initial sigma for the bias (max(|b0|, sigma_b0, 1 deg/h) used)", only_bias


def test_a_fusion_cycle_has_no_bound_instead_of_a_recursion():
    """Two fusions that fuse each other (a loaded scenario refuses this; the bound must not
    rely on it): NoBound naming the cycle, not a RecursionError."""
    from types import SimpleNamespace

    leaf = SimpleNamespace(name="leaf")
    estimators = {
        "a": SimpleNamespace(name="a", sources=["b", "leaf"]),
        "b": SimpleNamespace(name="b", sources=["a"]),
        "leaf": leaf,
    }
    with pytest.raises(bd.NoBound, match="a fusion cycle"):
        bd._leaf_estimators(estimators, "a")
    estimators["b"] = SimpleNamespace(name="b", sources=["leaf"])
    assert bd._leaf_estimators(estimators, "a") == [leaf, leaf]


@pytest.mark.parametrize(
    "scale_ppm, misalign_urad, noted",
    [([0, 0, 0], [0, 0, 0, 0, 0, 0], False), ([0, 300, 0], [0] * 6, True), ([0, 0, 0], [0, 0, 0, 0, 50, 0], True)],
)
def test_a_deterministic_gyro_error_of_either_kind_is_noted_as_outside_the_bound(scale_ppm, misalign_urad, noted):
    from dataclasses import replace

    gyro = next(s for s in load("cubesat_single_star_tracker").sensors if s.name == "gyro")
    gyro = replace(gyro, scale_factor_error_ppm=scale_ppm, misalignment_urad=misalign_urad)
    notes = bd._model_gap_notes("gyro", gyro, [])
    assert any("scale-factor / misalignment" in n for n in notes) == noted, notes


# ---------------------------------------------------------------------------------------------
# Reuse of the recursions across runs with the same inputs
# ---------------------------------------------------------------------------------------------
def _bound_window(run):
    t = run.times("gyro/gyro_measurement")
    return bd.bound_for_estimator(run, "single", t, 2.0)


def test_a_second_run_with_the_same_inputs_reuses_the_recursions_and_gets_the_same_bound(monkeypatch):
    """The memo is keyed by content: the same truth, grid and tracker validity give the very
    bound a fresh computation gives (it is not recomputed); any change of them recomputes."""
    sc, sig = _single_with_tracker_log()
    monkeypatch.setattr(bd, "_RECURSIONS", {})
    calls = []
    real = bd.covariance_recursion
    monkeypatch.setattr(bd, "covariance_recursion", lambda *a: calls.append(1) or real(*a))
    sigma1, window1, info1 = _bound_window(_synthetic_run(sc, signals=sig))
    assert len(calls) == 2  # the bound and the 100x-prior one
    sigma2, window2, info2 = _bound_window(_synthetic_run(sc, signals=sig))
    assert len(calls) == 2
    np.testing.assert_array_equal(sigma1, sigma2)
    np.testing.assert_array_equal(window1, window2)
    assert info1 == info2
    assert info1["reason"] is None and info1["prior"] == "single's initial sigmas"
    assert info1["tracker_samples"]["st1"] == {
        "samples_used": 6,
        "samples_between_gyro_samples": 45,
        "samples_invalid": 0,
    }
    # independently: the recursion written out on the model of the run
    model = bd.bound_model(_synthetic_run(sc, signals=sig), "single")
    P = real(model["P0"], model["transitions"], model["noises"], model["measurements"])
    np.testing.assert_array_equal(sigma1, np.sqrt(np.einsum("kii->ki", P)))

    # one tracker sample flagged invalid: another model, recomputed, a larger variance there
    ts, x = sig["st1/star_tracker_measurement"]
    x = x.copy()
    x[30, 1] = 0.0  # the sample at t = 3 s
    sigma3, _, info3 = _bound_window(_synthetic_run(sc, signals={"st1/star_tracker_measurement": (ts, x)}))
    assert len(calls) == 4
    assert info3["tracker_samples"]["st1"]["samples_used"] == 5
    assert sigma3[3, 0] > sigma1[3, 0]

    # a different truth (a slower rotation): recomputed
    run = _synthetic_run(sc, signals=sig)
    run.signals["truth/q_IB"] = (
        run.signals["truth/q_IB"][0],
        np.array([rot.quat_propagate(_Q0, 0.5 * _W_TRUE, tk) for tk in run.signals["truth/q_IB"][0]]),
    )
    _bound_window(run)
    assert len(calls) == 6


def test_the_recursion_memo_keeps_two_entries_and_digests_dtype_and_shape():
    sc, sig = _single_with_tracker_log()
    inputs = bd._model_inputs(_synthetic_run(sc, signals=sig), "single")
    d = bd._inputs_digest(inputs)
    other = dict(inputs, grid=inputs["grid"].astype(np.float32).astype(np.float64) + 0.0)
    assert bd._inputs_digest(other) == d  # the same values, the same digest
    other = dict(inputs, q_true=inputs["q_true"].reshape(-1))  # same bytes, another shape
    assert bd._inputs_digest(other) != d
    saved = dict(bd._RECURSIONS)
    try:
        bd._RECURSIONS.clear()
        keys = []
        for k in range(4):
            prior = dict(inputs, P0=inputs["P0"] * (1 + k))
            keys.append(bd._inputs_digest(prior))
            bd._bound_and_loose(prior)
        assert list(bd._RECURSIONS) == keys  # four small entries: all kept
        entry = sum(a.nbytes for a in bd._RECURSIONS[keys[0]])
        bd._RECURSIONS_BYTES, budget = 2.5 * entry, bd._RECURSIONS_BYTES
        try:
            bd._bound_and_loose(dict(inputs, P0=inputs["P0"] * 9))
            assert list(bd._RECURSIONS)[:-1] == keys[3:]  # the oldest dropped: two entries within the budget
            bd._RECURSIONS_BYTES = 0.5 * entry  # the newest is kept whatever the budget
            bd._bound_and_loose(dict(inputs, P0=inputs["P0"] * 10))
            assert len(bd._RECURSIONS) == 1
        finally:
            bd._RECURSIONS_BYTES = budget
    finally:
        bd._RECURSIONS.clear()
        bd._RECURSIONS.update(saved)


def test_a_run_without_the_gyros_log_gets_no_bound_and_the_reason():
    sc, sig = _single_with_tracker_log()
    run = _synthetic_run(sc, signals=sig)
    del run.signals["gyro/gyro_measurement"]
    sigma, window, info = _bound_window_at(run, np.arange(6.0))
    assert sigma is None and window is None
    assert info == {"reason": "the gyro's samples (gyro/gyro_measurement) are not logged"}


def _bound_window_at(run, t):
    return bd.bound_for_estimator(run, "single", t, 2.0)
