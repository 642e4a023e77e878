"""MEKF: discretization against independent computations, Riccati steady state, NEES
consistency over a Monte Carlo, and robustness to missing/invalid measurements."""

import numpy as np
import pytest
import scipy.linalg
from scipy.stats import chi2

from drake_att import rotations as rot
from drake_att.analysis.metrics import estimator_errors
from drake_att.filters.mekf import MultiplicativeEKF, process_noise, transition_matrix
from drake_att.noise import ARCSEC, ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import load_scenario

ARW = 0.56 * ARW_DEG_PER_RT_H
RRW = 123.75 * RRW_DEG_PER_H_15


def _F(w):
    F = np.zeros((6, 6))
    F[:3, :3] = -rot.skew(w)
    F[:3, 3:] = -np.eye(3)
    return F


@pytest.mark.parametrize("w", [[0.0, 0.0, 0.0], [0.01, -0.02, 0.005], [0.3, 0.1, -0.2]])
def test_transition_matrix_equals_matrix_exponential(w):
    dt = 1.0
    Phi = transition_matrix(np.array(w), dt)
    np.testing.assert_allclose(Phi, scipy.linalg.expm(_F(np.array(w)) * dt), atol=1e-12)


def test_process_noise_equals_van_loan_integral_for_non_rotating_error_frame():
    """Q of the integrated Farrenkopf noise, by Van Loan's method at w = 0."""
    dt = 0.7
    G = np.diag([-1.0, -1, -1, 1, 1, 1])
    Qc = np.diag([ARW**2] * 3 + [RRW**2] * 3)
    F = _F(np.zeros(3))
    M = np.zeros((12, 12))
    M[:6, :6] = -F
    M[:6, 6:] = G @ Qc @ G.T
    M[6:, 6:] = F.T
    E = scipy.linalg.expm(M * dt)
    Phi = E[6:, 6:].T
    Q_vanloan = Phi @ E[:6, 6:]
    np.testing.assert_allclose(process_noise(ARW, RRW, dt), Q_vanloan, rtol=1e-9, atol=1e-24)


def test_quaternion_update_reduces_error_and_handles_anisotropic_mounted_sensor():
    core = MultiplicativeEKF(ARW, RRW)
    q_true = rot.rpy_to_quat(np.array([0.3, -0.2, 1.0]))
    q_BS = rot.rpy_to_quat(np.array([0.0, np.pi / 2, 0.4]))
    err0 = np.array([0.02, -0.01, 0.03])
    state = core.initial_state(rot.quat_multiply(q_true, rot.rotvec_to_quat(-err0)), np.zeros(3), 0.05, 1e-4)
    q_meas = rot.quat_multiply(q_true, q_BS)  # noise-free
    new, info = core.update_quaternion(state, q_meas, q_BS, np.array([5, 5, 50]) * ARCSEC)
    assert info.accepted
    residual = rot.quat_error_rotvec(new.q_IB, q_true)
    assert np.linalg.norm(residual) < 1e-3 * np.linalg.norm(err0)
    # The posterior covariance about the boresight (sensor z, in body frame) is the largest.
    boresight_B = rot.quat_to_rotmat(q_BS)[:, 2]
    var_bore = boresight_B @ new.P[:3, :3] @ boresight_B
    assert var_bore == pytest.approx((50 * ARCSEC) ** 2, rel=0.01)


@pytest.mark.parametrize("err0", [[0.1, -0.1, 0.05], [1e-3, -2e-3, 5e-4]])
def test_vector_update_error_reduction_is_second_order(err0):
    """One noise-free two-vector update leaves only the linearization error, O(|e|^2)."""
    core = MultiplicativeEKF(ARW, RRW)
    q_true = rot.rpy_to_quat(np.array([0.1, 0.2, -0.3]))
    refs = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    state = core.initial_state(rot.quat_multiply(q_true, rot.rotvec_to_quat(err0)), np.zeros(3), 0.2, 1e-4)
    dirs = refs @ rot.quat_to_rotmat(q_true)  # rows: R_BI r (noise-free, sensor = body)
    state, info = core.update_vectors(state, dirs, refs, 100e-6)
    assert info.accepted
    e0 = np.linalg.norm(err0)
    assert np.linalg.norm(rot.quat_error_rotvec(state.q_IB, q_true)) < e0**2


def test_gate_rejects_outlier_and_reports_it():
    core = MultiplicativeEKF(ARW, RRW, innovation_gate_chi2=16.0)
    state = core.initial_state([1.0, 0, 0, 0], np.zeros(3), 10 * ARCSEC, 1e-5)
    bad = rot.rotvec_to_quat([0.1, 0, 0])
    new, info = core.update_quaternion(state, bad, [1.0, 0, 0, 0], np.full(3, 10 * ARCSEC))
    assert not info.accepted and info.nis > 16.0
    np.testing.assert_array_equal(new.q_IB, state.q_IB)


# -- Drake-level scenarios ---------------------------------------------------------------
def _scenario_yaml(duration, rate_deg_s, st_period=1.0, dropout=0.0, extra_est=""):
    return f"""
name: mekf_test
duration_s: {duration}
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  initial_attitude_rpy_deg: [2.0, -2.0, 2.0]
  initial_rate_deg_per_s: {rate_deg_s}
sensors:
- !GyroConfig
  name: gyro
  period_s: 1.0
  arw_deg_per_rt_h: 0.56
  rrw_deg_per_h15: 123.75
  initial_bias_deg_per_h: [12.0, 12.0, 12.0]
- !StarTrackerConfig
  name: st1
  period_s: {st_period}
  mounting_paper_s3_angles_deg: [-90.0, 45.0, -90.0]
  sigma_cross_boresight_arcsec: 5.0
  sigma_boresight_arcsec: 50.0
  dropout_probability: {dropout}
estimators:
- !MekfConfig
  name: mekf
  period_s: 1.0
  gyro: gyro
  star_trackers: [st1]
  initial_attitude_sigma_deg: 5.0
  initial_bias_sigma_deg_per_h: 20.0
{extra_est}
scoring:
  score_from_s: 100.0
"""


@pytest.fixture(scope="module")
def slow_scenario():
    # Built once per module (pydrake does not garbage-collect Python systems).
    return ScenarioDiagram(load_scenario(text=_scenario_yaml(400.0, "[0.001, -0.001, 0.0005]")))


def test_steady_state_sigma_matches_discrete_riccati_solution(slow_scenario):
    """Slowly rotating body: the filter's steady-state attitude sigma agrees with the DARE
    of the linearized error model (Phi at w = 0, Q, H = [R_SB 0], R) within 10%."""
    run = slow_scenario.simulate(seed=3)
    e = estimator_errors(run, "mekf", "bias_B_hat", "gyro")
    P_filter = e["P"][-1]
    st = slow_scenario.scenario.sensors[1]
    from drake_att.scenarios.builder import star_tracker_mounting, star_tracker_sigmas_S

    R_SB = rot.quat_to_rotmat(star_tracker_mounting(st)).T
    H = np.hstack([R_SB, np.zeros((3, 3))])
    R = np.diag(star_tracker_sigmas_S(st) ** 2)
    Phi = transition_matrix(np.zeros(3), 1.0)
    Q = process_noise(ARW, RRW, 1.0)
    P_prior = scipy.linalg.solve_discrete_are(Phi.T, H.T, Q, R)
    K = P_prior @ H.T @ np.linalg.inv(H @ P_prior @ H.T + R)
    P_post = (np.eye(6) - K @ H) @ P_prior
    sig_filter = np.sqrt(np.diag(P_filter))
    sig_dare = np.sqrt(np.diag(P_post))
    np.testing.assert_allclose(sig_filter[:3], sig_dare[:3], rtol=0.10)
    np.testing.assert_allclose(sig_filter[3:], sig_dare[3:], rtol=0.10)


def test_nees_consistent_over_monte_carlo(slow_scenario):
    """20 seeds: the ensemble-averaged 6-dof NEES lies in its 95% chi-square band at
    >= 90% of the scored times, and its time average lies inside the band too."""
    seeds = range(20)
    nees = []
    for seed in seeds:
        run = slow_scenario.simulate(seed=seed)
        e = estimator_errors(run, "mekf", "bias_B_hat", "gyro")
        nees.append(e["nees"][e["t"] >= 100.0])
    nees = np.array(nees)
    M, dof = nees.shape[0], 6
    lo, hi = chi2.ppf(0.025, M * dof) / M, chi2.ppf(0.975, M * dof) / M
    avg = nees.mean(axis=0)
    assert lo < avg.mean() < hi, (lo, avg.mean(), hi)
    inside = np.mean((avg > lo) & (avg < hi))
    assert inside >= 0.90, inside


def test_empirical_error_matches_reported_sigma_over_seeds(slow_scenario):
    errs, sig = [], []
    for seed in range(10):
        e = estimator_errors(slow_scenario.simulate(seed=100 + seed), "mekf", "bias_B_hat", "gyro")
        m = e["t"] >= 100.0
        errs.append(e["dtheta"][m])
        sig.append(np.sqrt(np.einsum("nii->ni", e["P"][m][:, :3, :3])))
    rms = np.sqrt(np.mean(np.concatenate(errs) ** 2, axis=0))
    reported = np.sqrt(np.mean(np.concatenate(sig) ** 2, axis=0))
    np.testing.assert_allclose(rms, reported, rtol=0.10)


def test_dropouts_are_skipped_and_counted_and_filter_keeps_tracking():
    sd = ScenarioDiagram(load_scenario(text=_scenario_yaml(300.0, "[-0.5, 0.5, 0.5]", dropout=0.3)))
    run = sd.simulate(seed=5)
    e = estimator_errors(run, "mekf", "bias_B_hat", "gyro")
    used, skipped = e["status"][-1, 1], e["status"][-1, 2]
    # ~300 measurement instants, 30% invalid (binomial: sd ~ 8).
    assert used + skipped == pytest.approx(len(e["t"]), abs=2)
    assert 0.3 * (used + skipped) - 40 < skipped < 0.3 * (used + skipped) + 40
    st_valid = run.values("st1/star_tracker_measurement")[:, 1]
    assert 0.2 < 1 - st_valid.mean() < 0.4
    assert np.sqrt(np.mean(e["dtheta"][e["t"] > 100] ** 2)) < 0.05 * DEG


def test_invalid_measurement_values_are_skipped_not_crashing():
    """Drive the MEKF system directly with NaN and invalid-flagged measurements."""
    from drake_att.systems.estimators import MekfEstimator, QuaternionSensorModel

    core = MultiplicativeEKF(ARW, RRW)
    init = core.initial_state([1.0, 0, 0, 0], np.zeros(3), 1 * DEG, 10 * DEG_PER_H)
    est = MekfEstimator("mekf", 1.0, core, init,
                        [QuaternionSensorModel("st", np.array([1.0, 0, 0, 0]), np.eye(3) * (10 * ARCSEC) ** 2)])
    ctx = est.CreateDefaultContext()
    est.GetInputPort("gyro_measurement").FixValue(ctx, [0.0, 1.0, 0.0, 0.0, 0.0])
    for meas in ([0.0, 1.0, np.nan, 0, 0, 0], [0.0, 0.0, 1.0, 0, 0, 0]):
        est.GetInputPort("q_meas_st").FixValue(ctx, meas)
        values = est.EvalUniquePeriodicDiscreteUpdate(ctx)
        status = values.get_vector(0).value()[43:47]
        assert status[1] == 0 and status[2] == 1
        assert np.all(np.isfinite(values.get_vector(0).value()[:43]))


def test_same_seed_repeats_exactly_and_different_seed_differs(slow_scenario):
    a = slow_scenario.simulate(seed=11)
    b = slow_scenario.simulate(seed=11)
    c = slow_scenario.simulate(seed=12)
    for key in a.signals:
        np.testing.assert_array_equal(a.values(key), b.values(key))
    assert not np.array_equal(a.values("mekf/q_IB_hat"), c.values("mekf/q_IB_hat"))
    assert not np.array_equal(a.values("gyro/gyro_measurement"), c.values("gyro/gyro_measurement"))


VECTOR_SCENARIO = """
name: mekf_vectors
duration_s: 300.0
plant: !RigidBodyConfig
  inertia_kg_m2: [100.0, 200.0, 200.0]
  initial_attitude_rpy_deg: [10.0, -5.0, 30.0]
  initial_rate_deg_per_s: [0.01, -0.02, 0.005]
sensors:
- !GyroConfig {name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.05, rrw_deg_per_h15: 0.5, initial_bias_deg_per_h: [1.0, -2.0, 0.5]}
- !StarTrackerConfig
  name: st
  period_s: 1.0
  mode: vectors
  mounting_rpy_deg: [0.0, 90.0, 20.0]
  references_I: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
  sigma_vector_urad: 100.0
estimators:
- !MekfConfig
  name: mekf
  period_s: 1.0
  gyro: gyro
  star_trackers: [st]
  initial_attitude_rpy_deg: [11.0, -4.0, 31.0]
  initial_attitude_sigma_deg: 2.0
  initial_bias_sigma_deg_per_h: 5.0
scoring:
  score_from_s: 50.0
"""


def test_mekf_with_mounted_vector_tracker_is_consistent():
    """System level: two reference directions from a mounted vector-mode tracker; 8 seeds,
    the time-averaged ensemble NEES lies in its 95% chi-square band and the attitude error
    is at the 100-urad class."""
    sd = ScenarioDiagram(load_scenario(text=VECTOR_SCENARIO))
    nees, errs = [], []
    for seed in range(8):
        e = estimator_errors(sd.simulate(seed=seed), "mekf", "bias_B_hat", "gyro")
        m = e["t"] >= 50.0
        nees.append(e["nees"][m])
        errs.append(e["dtheta"][m])
    nees = np.array(nees)
    M = nees.shape[0]
    avg = nees.mean(axis=0)
    lo, hi = chi2.ppf(0.025, M * 6) / M, chi2.ppf(0.975, M * 6) / M
    assert lo < avg.mean() < hi, (lo, avg.mean(), hi)
    rms = np.sqrt(np.mean(np.concatenate(errs) ** 2))
    assert rms < 100e-6, rms
