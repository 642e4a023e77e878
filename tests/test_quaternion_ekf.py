"""Additive quaternion EKF, the baseline of paper S4 (:mod:`drake_att.filters.quaternion_ekf`):
kinematics against pydrake, the Wahba (SVD) measurement, the map of its 4x4 covariance to the
project's attitude error, the S4 run, NEES over a Monte Carlo, and rejections.

Independent reference model (written here): pydrake ``Quaternion`` / ``AngleAxis`` /
``RotationMatrix`` for every rotation; the error map checked against a finite-difference
Jacobian of ``dtheta = log(q_hat^-1 ⊗ normalize(q_hat + dq))``; the Wahba solution checked
by its defining property (no rotation near it has a smaller loss) and, noise-free, against
the truth. The S4 truth (SPEC S4, frame sense in ``test_lie_group.py``) is shared with
``test_lie_group.py``.

Consistency band as in ``test_lie_group.py``: the NEES of N runs at a fixed step sums to a
chi-square with ``dof N`` degrees of freedom; two-sided ``1e-4`` quantiles per check.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats
from pydrake.common.eigen_geometry import AngleAxis, Quaternion
from pydrake.math import RollPitchYaw, RotationMatrix
from test_lie_group import S4_REFS, assert_nees_sums_in_band, drake_exp, error_angle, s4_mean_rate, s4_truth, stars

from drake_att.contract import FilterCore, QuaternionSample, SecondQuantity
from drake_att.filters.quaternion_ekf import (
    AdditiveQuaternionEKF,
    QuaternionEkfState,
    transition_matrix,
    wahba_quaternion,
)

DEG = math.pi / 180.0


def dq_mul(p, q):
    """Hamilton product with pydrake (wxyz arrays)."""
    return (Quaternion(np.asarray(p, dtype=float)).multiply(Quaternion(np.asarray(q, dtype=float)))).wxyz()


def dq_exp(v):
    """Quaternion of the rotation vector v (pydrake)."""
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v)
    return np.array([1.0, 0.0, 0.0, 0.0]) if a == 0.0 else AngleAxis(a, v / a).quaternion().wxyz()


def dq_log(q):
    """Rotation vector of q (pydrake, shortest)."""
    aa = AngleAxis(Quaternion(np.asarray(q, dtype=float) / np.linalg.norm(q)))
    return aa.angle() * aa.axis()


def dtheta(q_hat, q):
    """Project's error: q = q_hat ⊗ exp(dtheta)."""
    q = np.asarray(q, dtype=float)
    e = dq_mul(np.array([q_hat[0], -q_hat[1], -q_hat[2], -q_hat[3]]), q / np.linalg.norm(q))
    return dq_log(e if e[0] >= 0 else -e)


def rotmat(q):
    return RotationMatrix(Quaternion(np.asarray(q, dtype=float) / np.linalg.norm(q))).matrix()


# -- protocol and state vector -----------------------------------------------------------------
def test_core_implements_the_filter_core_protocol_and_the_paper_defaults():
    core = AdditiveQuaternionEKF()
    assert isinstance(core, FilterCore)
    assert core.second_quantity is SecondQuantity.BODY_RATE
    assert core.uses_gyro is True and core.is_random is False
    assert np.array_equal(core.Q, 1e-5 * np.eye(4)) and np.array_equal(core.R, 0.01 * np.eye(4))
    state = core.initial_state()
    assert np.array_equal(state.q_IB, [1.0, 0.0, 0.0, 0.0]) and np.array_equal(state.P, np.eye(4))


def test_state_vector_round_trip_is_exact_and_has_the_declared_size():
    core = AdditiveQuaternionEKF()
    state = core.initial_state(RollPitchYaw(0.1, 0.2, 0.3).ToQuaternion().wxyz(), 0.1)
    state = core.predict(state, np.array([1e-3, 2e-3, -1e-3]), 0.5)
    state, info = core.update(state, stars(rotmat(state.q_IB) @ drake_exp([1e-2, 0.0, 0.0])))
    assert info.accepted
    v = core.to_vector(state)
    assert v.shape == (core.state_size,)
    back = core.from_vector(v)
    assert isinstance(back, QuaternionEkfState)
    for field in ("q_IB", "P", "w_B", "P_w", "C_q"):
        assert np.array_equal(getattr(back, field), getattr(state, field)), field
    with pytest.raises(ValueError, match="44"):
        core.from_vector(v[1:])


# -- predict ----------------------------------------------------------------------------------
def test_predict_with_constant_rate_is_the_exact_rotation_and_keeps_the_norm():
    core = AdditiveQuaternionEKF(Q=np.diag([1e-5, 2e-5, 3e-5, 4e-5]), step_s=0.5)
    q0 = RollPitchYaw(0.3, -1.2, 2.0).ToQuaternion().wxyz()
    P0 = np.diag([0.1, 0.2, 0.3, 0.4])
    w, dt = np.array([0.4, -0.2, 0.9]), 0.3
    state = core.predict(core.initial_state(q0, P0), w, dt)
    assert np.allclose(state.q_IB, dq_mul(q0, dq_exp(w * dt)), atol=1e-15)
    Phi = transition_matrix(w, dt)
    assert np.allclose(Phi @ Phi.T, np.eye(4), atol=1e-15)  # orthogonal: |q| kept
    assert np.allclose(state.P, Phi @ P0 @ Phi.T + core.Q * dt / 0.5, atol=1e-15)
    # Phi q = q ⊗ exp(w dt / 2) for any q (the transition is linear in q).
    q1 = RollPitchYaw(-0.5, 0.1, 0.7).ToQuaternion().wxyz()
    assert np.allclose(Phi @ q1, dq_mul(q1, dq_exp(w * dt)), atol=1e-15)
    state = core.initial_state(q0, P0)
    for _ in range(1000):
        state = core.predict(state, np.array([1e-5, -2e-5, 3e-5]), 1.0)
    assert abs(np.linalg.norm(state.q_IB) - 1.0) < 1e-13
    assert error_angle(rotmat(state.q_IB), rotmat(q0) @ drake_exp([1e-2, -2e-2, 3e-2])) < 1e-13
    assert core.predict(state, w, 0.0) is state


# -- measurement ------------------------------------------------------------------------------
@pytest.mark.parametrize("m_stars", [2, 3, 6])
def test_wahba_quaternion_is_exact_without_noise_and_optimal_with_it(m_stars):
    rng = np.random.default_rng(10 + m_stars)
    refs = rng.normal(size=(m_stars, 3))
    refs /= np.linalg.norm(refs, axis=1, keepdims=True)
    q_true = RollPitchYaw(*rng.uniform(-3.0, 3.0, 3)).ToQuaternion().wxyz()
    R_IB = rotmat(q_true)
    q = wahba_quaternion(refs @ R_IB, refs)
    assert abs(abs(q @ q_true) - 1.0) < 1e-13
    b_noisy = refs @ R_IB + 0.02 * rng.normal(size=(m_stars, 3))
    q = wahba_quaternion(b_noisy, refs)
    b_unit = b_noisy / np.linalg.norm(b_noisy, axis=1, keepdims=True)

    def loss(R):
        return np.sum((b_unit - refs @ R) ** 2)

    best = loss(rotmat(q))
    for v in np.vstack([np.eye(3), -np.eye(3), rng.normal(size=(20, 3))]) * 1e-3:
        assert loss(rotmat(q) @ drake_exp(v)) > best


def test_degenerate_star_sets_give_no_quaternion_and_the_update_is_rejected():
    core = AdditiveQuaternionEKF()
    state = core.initial_state()
    assert wahba_quaternion(S4_REFS[:1], S4_REFS[:1]) is None
    collinear = np.array([[1.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])
    assert wahba_quaternion(collinear, collinear) is None
    new, info = core.update(state, stars(np.eye(3), S4_REFS[:1]))
    assert info.accepted is False and new is state
    new, info = core.update(state, stars(np.eye(3), collinear))
    assert info.accepted is False and new is state
    with pytest.raises(TypeError, match="VectorObservations"):
        core.update(state, QuaternionSample(0.0, True, state.q_IB, state.q_IB, np.ones(3)))


def test_wahba_refuses_one_zero_direction_or_one_zero_reference():
    """A zero-length body direction (or reference) has no direction: no quaternion, even when
    every other row is fine."""
    b = S4_REFS.copy()
    b[1] = 0.0
    assert wahba_quaternion(b, S4_REFS) is None
    assert wahba_quaternion(S4_REFS, b) is None
    assert wahba_quaternion(S4_REFS, S4_REFS) is not None


@pytest.mark.parametrize("angle, solvable", [(1.9e-6, False), (2.1e-6, True), (1e-3, True)])
def test_wahba_collinearity_threshold_is_on_the_references_singular_values(angle, solvable):
    """Two references ``angle`` apart: the ratio of their singular values is ``tan(angle / 2)``;
    at or below ``COLLINEAR_SINE`` (1e-6) they fix no attitude. Noise-free, a solvable pair gives
    the true attitude."""
    from drake_att.filters.quaternion_ekf import COLLINEAR_SINE

    assert COLLINEAR_SINE == 1e-6
    refs = np.array([[1.0, 0.0, 0.0], [math.cos(angle), math.sin(angle), 0.0]])
    R_IB = RollPitchYaw(0.3, -0.2, 0.9).ToRotationMatrix().matrix()
    q = wahba_quaternion(refs @ R_IB, refs)
    assert (q is not None) == solvable
    if solvable and angle > 1e-4:
        assert error_angle(rotmat(q), R_IB) < 1e-9


def test_initial_state_is_the_given_attitude_and_covariance_and_a_zero_rate_of_the_given_sigma():
    """``initial_state``: the quaternion normalized, ``P0`` as given (scalar: times I4), the rate
    0 with covariance ``initial_rate_sigma^2 I3``, no attitude-rate correlation; the published
    covariance's rate block is that variance, and the state packs into the declared size."""
    P0 = np.diag([0.3, 0.1, 0.2, 0.05])
    st = AdditiveQuaternionEKF.initial_state([2.0, 0.0, 0.0, 0.0], P0, initial_rate_sigma=0.02)
    np.testing.assert_array_equal(st.q_IB, [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(st.P, P0)
    np.testing.assert_array_equal(st.w_B, np.zeros(3))
    np.testing.assert_allclose(st.P_w, 0.02**2 * np.eye(3), rtol=1e-15)
    np.testing.assert_array_equal(st.C_q, np.zeros((4, 3)))
    np.testing.assert_array_equal(AdditiveQuaternionEKF.initial_state(P0=0.5).P, 0.5 * np.eye(4))
    _, _, P6 = AdditiveQuaternionEKF.estimate(st)
    np.testing.assert_allclose(P6[3:, 3:], 0.02**2 * np.eye(3), rtol=1e-15)
    np.testing.assert_array_equal(P6[:3, 3:], np.zeros((3, 3)))
    assert AdditiveQuaternionEKF.to_vector(st).shape == (AdditiveQuaternionEKF.state_size,)


@pytest.mark.parametrize(
    "call, field",
    [
        (lambda: AdditiveQuaternionEKF(Q=-1.0), "Q"),
        (lambda: AdditiveQuaternionEKF(R=np.full((4, 4), np.nan)), "R"),
        (lambda: AdditiveQuaternionEKF(step_s=0.0), "step_s"),
        (lambda: AdditiveQuaternionEKF(gyro_arw_rad_per_rt_s=-1e-4), "gyro_arw_rad_per_rt_s"),
        (lambda: AdditiveQuaternionEKF.initial_state(P0=-1.0), "P0"),
        (lambda: AdditiveQuaternionEKF.initial_state(initial_rate_sigma=0.0), "initial_rate_sigma"),
        (lambda: AdditiveQuaternionEKF.initial_state(q_IB=[0.0, 0.0, 0.0, 0.0]), "q_IB"),
        (lambda: AdditiveQuaternionEKF.from_vector(np.zeros(43)), "state vector"),
    ],
)
def test_bad_arguments_are_refused_naming_the_field(call, field):
    with pytest.raises(ValueError) as e:
        call()
    assert str(e.value).startswith(field) or f"EKF {field}" in str(e.value), str(e.value)


def test_a_rejected_update_reports_what_it_computed():
    """No Wahba solution: no innovation, NIS NaN (a float). A singular innovation covariance:
    the innovation ``q_meas - q_hat`` and ``S = P + R`` as computed, NIS NaN. A gate
    rejection: innovation, ``S`` and the NIS that failed the gate."""
    q = RollPitchYaw(0.1, 0.2, 0.3).ToQuaternion().wxyz()
    core = AdditiveQuaternionEKF(R=0.0)
    state = core.initial_state(q, 0.0)
    _, info = core.update(state, stars(rotmat(q), S4_REFS[:1]))
    assert info.innovation is None and info.innovation_covariance is None
    assert isinstance(info.nis, float) and math.isnan(info.nis)
    q_meas = RollPitchYaw(0.1, 0.2, 0.31).ToQuaternion().wxyz()
    _, info = core.update_quaternion(state, q_meas)
    assert not info.accepted and math.isnan(info.nis)
    np.testing.assert_array_equal(info.innovation, q_meas - q)
    np.testing.assert_array_equal(info.innovation_covariance, np.zeros((4, 4)))
    gated = AdditiveQuaternionEKF(R=1e-6, innovation_gate_chi2=9.0)
    state = gated.initial_state(q, 1e-6)
    _, info = gated.update_quaternion(state, q_meas)
    assert not info.accepted
    np.testing.assert_array_equal(info.innovation, q_meas - q)
    np.testing.assert_allclose(info.innovation_covariance, 2e-6 * np.eye(4), rtol=1e-15)
    assert info.nis == pytest.approx(float((q_meas - q) @ (q_meas - q)) / 2e-6, rel=1e-12) and info.nis > 9.0


def test_measured_quaternion_uses_the_mounting_and_is_sign_aligned():
    q_true = RollPitchYaw(0.7, -0.4, 2.9).ToQuaternion().wxyz()
    q_BS = RollPitchYaw(0.0, 0.3, 1.2).ToQuaternion().wxyz()
    R_SB = rotmat(q_BS).T
    core = AdditiveQuaternionEKF(R=1e-12)
    for sign in (1.0, -1.0):  # the estimate as q or -q: the measurement follows its sign
        q_hat = sign * dq_mul(q_true, dq_exp([1e-3, 0.0, -1e-3]))
        new, info = core.update(core.initial_state(q_hat, 1.0), stars(rotmat(q_true), S4_REFS, q_BS=q_BS, R_SB=R_SB))
        assert info.accepted and np.linalg.norm(info.innovation) < 2e-3
        assert np.allclose(new.q_IB, sign * q_true, atol=1e-9)


def test_update_is_the_additive_kalman_update_then_normalization():
    core = AdditiveQuaternionEKF(R=np.diag([1e-2, 2e-2, 3e-2, 4e-2]))
    q_hat = RollPitchYaw(0.1, 0.2, 0.3).ToQuaternion().wxyz()
    q_meas = RollPitchYaw(0.15, 0.1, 0.35).ToQuaternion().wxyz()
    P = np.diag([0.3, 0.1, 0.2, 0.05])
    new, info = core.update_quaternion(core.initial_state(q_hat, P), q_meas)
    S = P + core.R
    K = P @ np.linalg.inv(S)
    q = q_hat + K @ (q_meas - q_hat)
    assert np.allclose(new.q_IB, q / np.linalg.norm(q), atol=1e-15)
    assert np.allclose(new.P, (np.eye(4) - K) @ P, atol=1e-15)
    assert info.nis == pytest.approx((q_meas - q_hat) @ np.linalg.solve(S, q_meas - q_hat), rel=1e-12)


def test_singular_innovation_covariance_and_gate_are_rejected_not_raised():
    q = RollPitchYaw(0.1, 0.2, 0.3).ToQuaternion().wxyz()
    core = AdditiveQuaternionEKF(R=0.0)
    state = core.initial_state(q, 0.0)
    new, info = core.update(state, stars(rotmat(q)))
    assert info.accepted is False and math.isnan(info.nis) and new is state
    gated = AdditiveQuaternionEKF(R=1e-6, innovation_gate_chi2=scipy.stats.chi2.ppf(0.999, 4))
    state = gated.initial_state(q, 1e-6)
    new, info = gated.update(state, stars(rotmat(q) @ drake_exp([0.05, 0.0, 0.0])))
    assert info.accepted is False and new is state and info.nis > 100.0
    assert gated.update(state, stars(rotmat(q)))[1].accepted is True


# -- the published covariance -------------------------------------------------------------------
def test_attitude_covariance_is_the_additive_covariance_mapped_by_the_error_jacobian():
    q_hat = RollPitchYaw(0.6, -0.3, 1.7).ToQuaternion().wxyz()
    rng = np.random.default_rng(4)
    M = rng.normal(size=(4, 4))
    P_q = 1e-4 * (M @ M.T + np.eye(4))
    core = AdditiveQuaternionEKF()
    _, _, P6 = core.estimate(QuaternionEkfState(q_hat, P_q, np.zeros(3), np.eye(3), np.zeros((4, 3))))
    # Central finite differences of dq -> dtheta at dq = 0 (O(h^2) ~ 1e-12).
    h = 1e-6
    J = np.column_stack([(dtheta(q_hat, q_hat + h * e) - dtheta(q_hat, q_hat - h * e)) / (2 * h) for e in np.eye(4)])
    assert np.allclose(J @ q_hat, 0.0, atol=1e-9)  # the norm direction is no rotation
    assert np.allclose(P6[:3, :3], J @ P_q @ J.T, rtol=1e-6, atol=1e-14)


# -- the paper's run -----------------------------------------------------------------------------
def test_s4_baseline_from_identity_converges_without_drift_and_keeps_unit_norm():
    """Paper defaults (q0 = [1,0,0,0], P0 = I4, Q = 1e-5 I4, R = 0.01 I4), noise-free S4
    truth, perfect gyro. The quaternion measurement is exact, so the additive EKF converges
    geometrically (gain ~ sqrt(Q/R)); the paper's x-axis drift (Fig 4) is not a property of
    this filter on this truth."""
    truth = s4_truth(300)
    core = AdditiveQuaternionEKF()
    state = core.initial_state()
    errors = []
    for k in range(1, len(truth)):
        state = core.predict(state, s4_mean_rate(k - 1.0, float(k)), 1.0)
        state, info = core.update(state, stars(truth[k], t=k))
        assert info.accepted
        assert abs(np.linalg.norm(state.q_IB) - 1.0) < 1e-14
        errors.append(error_angle(rotmat(state.q_IB), truth[k]) / DEG)
    errors = np.array(errors)
    assert errors[0] < 1.5  # the first update (P0 = I4 >> R) jumps most of the 120 deg
    assert np.all(np.diff(errors) < 0.0)  # monotone: no drift on any axis
    first = int(np.flatnonzero(errors <= 0.005)[0]) + 1
    assert 60 <= first <= 100, first
    assert errors[-1] < 1e-4


def test_nees_is_chi_square_over_a_monte_carlo_with_truth_matching_the_tuning():
    """Isotropic tuning Q = q I4, R = r I4 is, on the tangent space, an attitude process
    noise N(0, 4 q I3) per step and a measured attitude with error N(0, 4 r I3); the
    truth draws exactly that (process noise as gyro noise, so the rate block is the truth's
    too). The filter is fed the measured quaternion (update_quaternion) sign-aligned; the
    3-dof attitude NEES (4 G P G' map) and the 6-dof NEES must lie in chi-square bands."""
    q_var, r_var = 1e-6, 1e-5
    n_runs, n_steps, checks = 100, 120, (20, 60, 120)
    core = AdditiveQuaternionEKF(Q=q_var, R=r_var)
    rng = np.random.default_rng(7)
    nees3 = np.zeros((n_runs, len(checks)))
    nees6 = np.zeros((n_runs, len(checks)))
    for run in range(n_runs):
        q = RollPitchYaw(*rng.uniform(-np.pi, np.pi, 3)).ToQuaternion().wxyz()
        P0 = 1e-4  # additive variance per component: tangent variance 4e-4 rad^2
        q_hat = dq_mul(q, dq_exp(-2.0 * math.sqrt(P0) * rng.normal(size=3)))
        state = core.initial_state(q_hat, P0)
        for k in range(1, n_steps + 1):
            w_true = s4_mean_rate(k - 1.0, float(k))
            q = dq_mul(q, dq_exp(w_true))
            w_meas = w_true + math.sqrt(4.0 * q_var) * rng.normal(size=3)
            state = core.predict(state, w_meas, 1.0)
            q_meas = dq_mul(q, dq_exp(math.sqrt(4.0 * r_var) * rng.normal(size=3)))
            if q_meas @ state.q_IB < 0:
                q_meas = -q_meas
            state, info = core.update_quaternion(state, q_meas)
            assert info.accepted
            if k in checks:
                j = checks.index(k)
                q_est, w_hat, P6 = core.estimate(state)
                e = np.concatenate([dtheta(q_est, q), w_true - w_hat])
                nees3[run, j] = e[:3] @ np.linalg.solve(P6[:3, :3], e[:3])
                nees6[run, j] = e @ np.linalg.solve(P6, e)
    assert_nees_sums_in_band(nees3, nees6, n_runs)


def test_rate_block_follows_the_same_rule_as_the_lie_group_filter():
    dt = 0.5
    core = AdditiveQuaternionEKF(Q=2e-6)
    q0 = RollPitchYaw(0.2, 0.4, -0.1).ToQuaternion().wxyz()
    w = np.array([0.02, 0.01, -0.03])
    state = core.predict(core.initial_state(q0, 1e-4, initial_rate_sigma=0.3), w, dt)
    _, w_hat, P6 = core.estimate(state)
    Q_theta = 4.0 * 2e-6 * dt  # tangent process noise of the step (rad^2)
    assert np.array_equal(w_hat, w)
    assert np.allclose(P6[3:, 3:], Q_theta / dt**2 * np.eye(3), rtol=1e-12)
    assert np.allclose(P6[:3, 3:], Q_theta / dt * np.eye(3), rtol=1e-12)
    assert np.linalg.eigvalsh(P6).min() > -1e-15
    arw = 2e-3
    core = AdditiveQuaternionEKF(Q=0.0, gyro_arw_rad_per_rt_s=arw)
    state = core.predict(core.initial_state(q0, 0.0), w, dt)
    _, _, P6 = core.estimate(state)
    assert np.allclose(P6[:3, :3], arw**2 * dt * np.eye(3), atol=1e-18)
    assert np.allclose(P6[3:, 3:], arw**2 / dt * np.eye(3))
    assert np.allclose(P6[:3, 3:], arw**2 * np.eye(3))


def test_reacquire_inflates_the_whole_quaternion_covariance_by_the_gates_factor():
    """After gate rejections the estimator system calls ``reacquire``: the 4x4 quaternion
    covariance (all of it: the attitude block of this core is the quaternion's) is scaled by
    ``max(2, 2 NIS / threshold)`` — the factor that puts the rejected NIS at half the gate when
    P dominates S — and nothing else changes."""
    from drake_att.filters.gating import reacquire_factor

    q = RollPitchYaw(0.1, 0.2, 0.3).ToQuaternion().wxyz()
    gated = AdditiveQuaternionEKF(R=1e-9, innovation_gate_chi2=9.0)
    P = np.diag([1.0, 2.0, 3.0, 4.0]) * 1e-6
    state = gated.initial_state(q, P, initial_rate_sigma=0.01)
    _, info = gated.update_quaternion(state, RollPitchYaw(0.1, 0.2, 0.32).ToQuaternion().wxyz())
    assert not info.accepted and info.nis > 9.0
    factor = reacquire_factor(gated.gate, info)
    assert factor == pytest.approx(2.0 * info.nis / 9.0) and factor > 2.0
    new = gated.reacquire(state, info)
    np.testing.assert_allclose(new.P, factor * P, rtol=1e-15)
    for field in ("q_IB", "w_B", "P_w", "C_q"):
        np.testing.assert_array_equal(getattr(new, field), getattr(state, field))
    S = new.P + gated.R
    assert float(info.innovation @ np.linalg.solve(S, info.innovation)) == pytest.approx(4.5, rel=1e-3)
