"""Lie-group filter of paper S4 (:mod:`drake_att.filters.lie_group`): kinematics against
pydrake, the update's error reduction, the paper's convergence claim (and the failure of its
literal equations), NEES over a Monte Carlo, the body-rate block, and rejections.

Independent reference model (written here, never from the library's helpers):

* rotations: pydrake ``RotationMatrix`` / ``AngleAxis``; the S4 truth is integrated with a
  matrix exponential by its Taylor series (not Rodrigues) over 10 sub-steps per second, each
  with the exact mean of the prescribed rate ``w = 1e-4 [cos 0.1t, cos 0.08t, cos 0.06t]``
  (closed-form integral; the neglected commutator terms are ~1e-10 rad);
* frame sense (SPEC S4, docs/derivations/lie_group.md): the truth matrix is ``R_IB`` with
  ``R_IB_dot = R_IB [w x]`` and stars ``b_B = R_IB' r_I``; eq 34's matrix is ``R_BI(0)``
  (it maps eq 33's references onto eq 35's measured vectors, checked below);
* the error of the project, ``R_err = R_IB_hat' R_IB``, its angle from pydrake.

Consistency bands: at a fixed step the NEES of N independent runs sums to a chi-square
with ``dof N`` degrees of freedom for a consistent linear filter; each checked step uses the
two-sided ``1e-4`` quantiles (8 checks: family-wise false alarm < 1e-3). Power: with
N = 100 a covariance off by a factor 1.5 moves the 3-dof mean NEES to 2 or 4.5, outside the
band (3 +- 0.6).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats
from pydrake.common.eigen_geometry import AngleAxis, Quaternion
from pydrake.math import RollPitchYaw, RotationMatrix

from drake_att.contract import CameraCentroids, FilterCore, QuaternionSample, SecondQuantity, VectorObservations
from drake_att.filters.lie_group import LieGroupFilter, LieGroupState

DEG = math.pi / 180.0
X34 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # S4 eq 34: R_BI(0)
S4_REFS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # eq 33
S4_RATE_FREQ = np.array([0.1, 0.08, 0.06])  # rad/s, eq 36
IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


# -- the independent reference model -------------------------------------------------------
def skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def expm_series(w):
    """exp([w x]) by its Taylor series (25 terms; |w| <= 1 here: remainder < 1e-25)."""
    K = skew(w)
    out, term = np.eye(3), np.eye(3)
    for k in range(1, 25):
        term = term @ K / k
        out = out + term
    return out


def drake_exp(w):
    """exp([w x]) from pydrake's AngleAxis."""
    w = np.asarray(w, dtype=float)
    a = np.linalg.norm(w)
    if a == 0.0:
        return np.eye(3)
    return RotationMatrix(AngleAxis(a, w / a)).matrix()


def error_angle(R_hat, R):
    """Angle (rad) of the project's error R_hat' R (pydrake)."""
    return RotationMatrix(R_hat.T @ R).ToAngleAxis().angle()


def error_vector(R_hat, R):
    """dtheta_B with R = R_hat exp([dtheta x]) (pydrake)."""
    aa = RotationMatrix(R_hat.T @ R).ToAngleAxis()
    return aa.angle() * aa.axis()


def s4_mean_rate(t0, t1):
    """Mean of the prescribed S4 body rate over [t0, t1] (rad/s), closed form."""
    return 1e-4 * (np.sin(S4_RATE_FREQ * t1) - np.sin(S4_RATE_FREQ * t0)) / (S4_RATE_FREQ * (t1 - t0))


def s4_truth(n_steps, substeps=10):
    """R_IB at t = 0, 1, ..., n_steps s (from R_IB(0) = X34'), finely integrated."""
    R = X34.T.copy()
    out = [R]
    h = 1.0 / substeps
    for k in range(n_steps):
        for j in range(substeps):
            t0 = k + j * h
            R = R @ expm_series(s4_mean_rate(t0, t0 + h) * h)
        out.append(R)
    return out


_I3 = np.eye(3)  # default mounting (read only)


def stars(R_IB, refs=S4_REFS, noise=None, q_BS=IDENTITY_Q, R_SB=_I3, t=0.0, sigma=1e-3):
    """VectorObservations of the references seen from attitude R_IB (sensor frame S)."""
    d = refs @ R_IB @ R_SB.T  # rows: R_SB R_IB' r_i
    if noise is not None:
        d = d + noise
    return VectorObservations(float(t), True, d, np.array(refs, dtype=float), sigma, np.array(q_BS, dtype=float))


def run_s4(formulation, truth):
    """The paper's filter (X0 = I, P0 = 5 I3, Q_w = 5e-5 I3, Q_v = 0.125^2 I6, 1 Hz) on
    noise-free truth with a perfect gyro; returns the error angle (deg) after each update."""
    core = LieGroupFilter(Q_w=5e-5, Q_v=0.125**2, formulation=formulation)
    state = core.initial_state(np.eye(3), 5.0)
    errors = []
    for k in range(1, len(truth)):
        state = core.predict(state, s4_mean_rate(k - 1.0, float(k)), 1.0)
        state, info = core.update(state, stars(truth[k], t=k))
        assert info.accepted
        errors.append(error_angle(state.R_IB, truth[k]) / DEG)
    return np.array(errors)


@pytest.fixture(scope="module")
def s4_truth_400():
    return s4_truth(400)


# -- the reference model itself --------------------------------------------------------------
def test_eq34_maps_eq33_references_onto_eq35_measurements_in_the_chosen_frame_sense():
    # l = X r with X = R_BI(0) = eq 34: the measured vectors of eq 35.
    assert np.allclose(X34 @ S4_REFS[0], [0.0, 0.0, 1.0])
    assert np.allclose(X34 @ S4_REFS[1], [1.0, 0.0, 0.0])
    # The initial error from X0 = I is 120 deg.
    assert error_angle(np.eye(3), X34.T) == pytest.approx(120.0 * DEG, abs=1e-12)


def test_truth_exponential_agrees_with_pydrake():
    rng = np.random.default_rng(3)
    for _ in range(20):
        w = rng.normal(size=3)
        w *= rng.uniform(0.0, 1.0) / np.linalg.norm(w)
        assert np.allclose(expm_series(w), drake_exp(w), atol=1e-14)


# -- protocol and state vector ---------------------------------------------------------------
@pytest.mark.parametrize("formulation", ["consistent", "paper_literal"])
def test_core_implements_the_filter_core_protocol(formulation):
    core = LieGroupFilter(formulation=formulation)
    assert isinstance(core, FilterCore)
    assert core.second_quantity is SecondQuantity.BODY_RATE
    assert core.uses_gyro is True and core.is_random is False


def test_state_vector_round_trip_is_exact_and_has_the_declared_size():
    core = LieGroupFilter(Q_w=1e-6, Q_v=1e-6)
    q0 = RollPitchYaw(0.3, -0.2, 1.1).ToQuaternion().wxyz()
    state = core.initial_state(q0, np.diag([1e-2, 2e-2, 3e-2]))
    state = core.predict(state, np.array([1e-3, -2e-3, 5e-4]), 0.5)
    state, info = core.update(state, stars(state.R_IB @ drake_exp([1e-3, -2e-3, 5e-4]), t=0.5))
    assert info.accepted
    v = core.to_vector(state)
    assert v.shape == (core.state_size,)
    back = core.from_vector(v)
    assert isinstance(back, LieGroupState)
    for field in ("R_IB", "P", "w_B", "P_w", "C"):
        assert np.array_equal(getattr(back, field), getattr(state, field)), field
    assert np.array_equal(core.to_vector(back), v)
    with pytest.raises(ValueError, match="39"):
        core.from_vector(v[:-1])


def test_initial_state_from_quaternion_and_matrix_agree_with_pydrake():
    rpy = RollPitchYaw(0.4, 0.3, -2.0)
    from_q = LieGroupFilter.initial_state(rpy.ToQuaternion().wxyz(), 0.01)
    from_R = LieGroupFilter.initial_state(RotationMatrix(rpy).matrix(), 0.01)
    assert np.allclose(from_q.R_IB, RotationMatrix(rpy).matrix(), atol=1e-14)
    assert np.allclose(from_R.R_IB, from_q.R_IB, atol=1e-14)
    q_hat = LieGroupFilter().estimate(from_R)[0]
    assert abs(abs(q_hat @ rpy.ToQuaternion().wxyz()) - 1.0) < 1e-14
    with pytest.raises(ValueError, match="not a rotation"):
        LieGroupFilter.initial_state(2.0 * np.eye(3), 0.01)
    with pytest.raises(ValueError, match="formulation"):
        LieGroupFilter(formulation="left")


# -- predict ---------------------------------------------------------------------------------
@pytest.mark.parametrize("formulation", ["consistent", "paper_literal"])
def test_predict_with_constant_rate_is_the_exact_rotation(formulation):
    core = LieGroupFilter(formulation=formulation)
    R0 = RotationMatrix(RollPitchYaw(0.2, -0.7, 2.5)).matrix()
    state = core.initial_state(R0, 1e-4)
    w = np.array([0.3, -0.1, 0.45])  # rad/s, large enough that Rodrigues' non-series branch is used
    for _ in range(10):
        state = core.predict(state, w, 0.1)
    # Body rate: R_IB(t) = R_IB(0) exp([w t x]); one rotation of 1 s about w.
    assert np.allclose(state.R_IB, R0 @ drake_exp(w * 1.0), atol=1e-13)
    # About body z only: the pydrake elementary rotation.
    state = core.predict(core.initial_state(R0, 1e-4), np.array([0.0, 0.0, 0.7]), 2.0)
    assert np.allclose(state.R_IB, R0 @ RotationMatrix.MakeZRotation(1.4).matrix(), atol=1e-14)
    # Tiny rate (series branch) and the orthonormality kept over many steps.
    state = core.initial_state(R0, 1e-4)
    for _ in range(1000):
        state = core.predict(state, np.array([1e-5, 2e-5, -3e-5]), 1.0)
    assert np.allclose(state.R_IB, R0 @ drake_exp(np.array([1e-2, 2e-2, -3e-2])), atol=1e-13)
    assert np.allclose(state.R_IB.T @ state.R_IB, np.eye(3), atol=1e-14)


def test_predicted_covariance_is_the_propagated_error_covariance_plus_process_noise():
    """Sigma points dtheta_i = +-sqrt(3) L e_i of P: the true errors after a common
    rotation A are log(A' exp(dtheta) A) = A' dtheta exactly, so their covariance is exact."""
    Q_w = np.diag([1e-5, 2e-5, 3e-5])
    core = LieGroupFilter(Q_w=Q_w, step_s=2.0)
    P = np.array([[4e-3, 1e-3, -5e-4], [1e-3, 2e-3, 2e-4], [-5e-4, 2e-4, 1e-3]])
    R0 = RotationMatrix(RollPitchYaw(1.0, 0.2, -0.3)).matrix()
    w, dt = np.array([0.8, -0.5, 0.3]), 0.7
    state = core.predict(core.initial_state(R0, P), w, dt)
    L = np.linalg.cholesky(P)
    errors = []
    for sign in (1.0, -1.0):
        for i in range(3):
            truth = R0 @ drake_exp(sign * math.sqrt(3.0) * L[:, i]) @ drake_exp(w * dt)
            errors.append(error_vector(state.R_IB, truth))
    errors = np.array(errors)
    P_sigma = errors.T @ errors / 6.0
    assert np.allclose(state.P - Q_w * dt / 2.0, P_sigma, atol=1e-12)  # Q_w per 2 s step
    # The literal form keeps the paper's A P A' (different from the exact one here).
    literal = LieGroupFilter(Q_w=Q_w, step_s=2.0, formulation="paper_literal")
    P_lit = literal.predict(literal.initial_state(R0, P), w, dt).P - Q_w * dt / 2.0
    A = drake_exp(w * dt)
    assert np.allclose(P_lit, A @ P @ A.T, atol=1e-15)
    assert not np.allclose(P_lit, P_sigma, atol=1e-5)


def test_predict_over_no_time_changes_nothing():
    core = LieGroupFilter()
    state = core.initial_state(IDENTITY_Q, 0.1)
    assert core.predict(state, np.ones(3), 0.0) is state
    assert core.predict(state, np.ones(3), -1.0) is state


# -- update ----------------------------------------------------------------------------------
def test_update_removes_a_small_error_to_second_order_with_a_mounted_tracker():
    """Noise-free stars and P >> R: one update leaves an error O(|dtheta|^2)."""
    core = LieGroupFilter(Q_v=1e-12)
    R_true = RotationMatrix(RollPitchYaw(0.3, -1.0, 2.0)).matrix()
    q_BS = RollPitchYaw(0.5, 0.2, -0.8).ToQuaternion().wxyz()
    R_SB = RotationMatrix(RollPitchYaw(0.5, 0.2, -0.8)).matrix().T
    refs = np.array([[0.6, 0.8, 0.0], [0.0, 0.6, 0.8], [0.8, 0.0, 0.6]])
    for err in (1e-2, 1e-3):
        dtheta = err * np.array([0.48, -0.6, 0.64])
        state = core.initial_state(R_true @ drake_exp(-dtheta), 1.0)  # truth = hat exp(dtheta)
        m = stars(R_true, refs, q_BS=q_BS, R_SB=R_SB)
        new, info = core.update(state, m)
        assert info.accepted
        # The innovation is the measured minus the predicted sensor-frame directions.
        assert np.allclose(info.innovation, (m.directions_S - refs @ state.R_IB @ R_SB.T).ravel(), atol=1e-15)
        assert error_angle(new.R_IB, R_true) < 2.0 * err**2
        # Posterior covariance: three well-observed axes, P ~ R / (number of stars).
        assert np.all(np.linalg.eigvalsh(new.P) < 1e-11)


def test_literal_update_is_the_papers_equations_26_to_32():
    """eqs 26-32 transcribed on X = R_BI (eq 2): eps = l - X r, H = -[r x], S = H P H' + Q_v,
    K = P H' S^-1, P = (I - K H) P, X <- X exp([K eps x])."""
    q_v = 0.125**2
    core = LieGroupFilter(Q_w=5e-5, Q_v=q_v, formulation="paper_literal")
    R_hat = RotationMatrix(RollPitchYaw(0.2, 0.1, -0.3)).matrix()
    R_true = RotationMatrix(RollPitchYaw(0.25, 0.05, -0.2)).matrix()
    P = np.diag([0.5, 1.0, 2.0])
    new, info = core.update(core.initial_state(R_hat, P), stars(R_true))
    X = R_hat.T
    l_meas = S4_REFS @ R_true  # rows: R_BI r_i
    eps = np.concatenate([l_meas[i] - X @ S4_REFS[i] for i in range(2)])
    H = np.vstack([-skew(S4_REFS[0]), -skew(S4_REFS[1])])
    S = H @ P @ H.T + q_v * np.eye(6)
    K = P @ H.T @ np.linalg.inv(S)
    assert info.accepted and np.allclose(info.innovation, eps, atol=1e-15)
    assert np.allclose(new.R_IB.T, X @ drake_exp(K @ eps), atol=1e-13)
    assert np.allclose(new.P, (np.eye(3) - K @ H) @ P, atol=1e-13)
    assert info.nis == pytest.approx(eps @ np.linalg.solve(S, eps), rel=1e-12)


@pytest.mark.parametrize("m_stars", [1, 2, 5])
def test_any_number_of_stars_is_used(m_stars):
    rng = np.random.default_rng(m_stars)
    refs = rng.normal(size=(m_stars, 3))
    refs /= np.linalg.norm(refs, axis=1, keepdims=True)
    core = LieGroupFilter(Q_v=1e-8)
    R_true = RotationMatrix(RollPitchYaw(-0.4, 0.9, 0.1)).matrix()
    state = core.initial_state(R_true @ drake_exp([2e-3, -1e-3, 3e-3]), 1e-4)
    new, info = core.update(state, stars(R_true, refs))
    assert info.accepted and info.innovation.shape == (3 * m_stars,)
    assert info.innovation_covariance.shape == (3 * m_stars, 3 * m_stars)
    # One star observes the two axes perpendicular to it, not the rotation about it.
    eig = np.linalg.eigvalsh(new.P)
    n_observed = 2 if m_stars == 1 else 3
    assert np.sum(eig < 1e-6) == n_observed
    if m_stars == 1:
        b = state.R_IB.T @ refs[0]  # the predicted direction H is built from
        assert b @ new.P @ b == pytest.approx(1e-4, rel=1e-6)


def test_singular_innovation_covariance_and_gate_are_rejected_not_raised():
    R_true = RotationMatrix(RollPitchYaw(0.1, 0.2, 0.3)).matrix()
    # One star with zero measurement noise: S = H P H' has rank 2.
    core = LieGroupFilter(Q_v=0.0)
    state = core.initial_state(R_true, 1e-4)
    new, info = core.update(state, stars(R_true, S4_REFS[:1]))
    assert info.accepted is False and math.isnan(info.nis) and new is state
    # A zero prior and zero noise: S = 0.
    new, info = core.update(core.initial_state(R_true, 0.0), stars(R_true))
    assert info.accepted is False
    # Gate: a 10-sigma outlier is rejected with its NIS reported; a clean sample passes.
    gated = LieGroupFilter(Q_v=1e-6, innovation_gate_chi2=scipy.stats.chi2.ppf(0.999, 6))
    state = gated.initial_state(R_true, 1e-6)
    noise = np.zeros((2, 3))
    noise[0, 1] = 1e-2
    new, info = gated.update(state, stars(R_true, noise=noise))
    assert info.accepted is False and new is state and info.nis > 50.0
    new, info = gated.update(state, stars(R_true))
    assert info.accepted is True
    # Measurements the core has no model for are refused (a quaternion is accepted since the
    # quaternion update was added; camera centroids are not).
    with pytest.raises(TypeError, match="VectorObservations, QuaternionSample"):
        core.update(state, CameraCentroids(0.0, True, np.zeros((2, 2)), 0.05, 1e-6))
    with pytest.raises(ValueError, match="innovation_gate_chi2"):
        LieGroupFilter(innovation_gate_chi2=0.0)


def test_measurement_noise_defaults_to_the_sample_sigma():
    R_true = np.eye(3)
    core = LieGroupFilter()  # Q_v None
    state = core.initial_state(R_true, 1e-4)
    _, info = core.update(state, stars(R_true, sigma=3e-3))
    H_P_Ht = LieGroupFilter(Q_v=0.0).update(state, stars(R_true, sigma=3e-3))[1].innovation_covariance
    assert np.allclose(info.innovation_covariance - H_P_Ht, 9e-6 * np.eye(6), atol=1e-18)


# -- the paper's claim ------------------------------------------------------------------------
def test_s4_consistent_filter_converges_as_the_paper_and_the_literal_one_does_not(s4_truth_400):
    """SPEC S4: noise-free truth, perfect gyro, X0 = I (120 deg off): the consistent pairing
    reaches 0.005 deg at about step 140-150 and stays there; the paper's literal pairing is
    still ~22 deg off after 400 steps."""
    consistent = run_s4("consistent", s4_truth_400)
    first = int(np.flatnonzero(consistent <= 0.005)[0]) + 1
    assert 140 <= first <= 150, first
    assert np.all(consistent[first - 1 :] <= 0.005)
    assert consistent[-1] < 1e-4  # and it keeps converging (noise-free)
    literal = run_s4("paper_literal", s4_truth_400)
    assert np.all(literal > 10.0)
    assert 15.0 < literal[-1] < 30.0, literal[-1]


# -- statistics --------------------------------------------------------------------------------
def chi2_band(dof, p=1e-4):
    return scipy.stats.chi2.ppf(p / 2, dof), scipy.stats.chi2.ppf(1 - p / 2, dof)


def assert_nees_sums_in_band(nees3, nees6, n_runs):
    """Per check time, the sum over runs of the 3- and 6-dof NEES lies in its two-sided
    chi-square band (``3 n_runs`` / ``6 n_runs`` dof, p = 1e-4)."""
    for dof, nees in ((3, nees3), (6, nees6)):
        lo, hi = chi2_band(dof * n_runs)
        sums = nees.sum(axis=0)
        assert np.all((lo <= sums) & (sums <= hi)), (dof, sums / n_runs, lo / n_runs, hi / n_runs)


@pytest.mark.slow
def test_nees_is_chi_square_over_a_monte_carlo_with_truth_matching_the_tuning():
    """The paper's tuning taken as truth (SPEC S4, "tuning-as-truth"): stars l = R_BI r + v,
    v ~ N(0, 0.125^2 I3), and a gyro whose mean-rate error over the 1 s step is
    N(0, 5e-5 I3) (rad/s)^2, so the integrated per-step attitude noise is Q_w = 5e-5 I3 and
    the filter's rate block (Q_w / dt^2) is the truth's. Start: error ~ N(0, P0),
    P0 = (3 deg)^2 I3. The 3-dof attitude NEES and the 6-dof [dtheta; rate error] NEES
    summed over runs must lie in the chi-square bands at steps 25, 50, 100 and 150."""
    n_runs, n_steps, sigma, q_w = 100, 150, 0.125, 5e-5
    checks = (25, 50, 100, 150)
    core = LieGroupFilter(Q_w=q_w, Q_v=sigma**2)
    rng = np.random.default_rng(20200102)
    nees3 = np.zeros((n_runs, len(checks)))
    nees6 = np.zeros((n_runs, len(checks)))
    P0 = (3.0 * DEG) ** 2
    for run in range(n_runs):
        R = RotationMatrix(RollPitchYaw(*rng.uniform(-np.pi, np.pi, 3))).matrix()
        state = core.initial_state(R @ drake_exp(-math.sqrt(P0) * rng.normal(size=3)), P0)
        for k in range(1, n_steps + 1):
            w_true = s4_mean_rate(k - 1.0, float(k))
            R = R @ drake_exp(w_true)
            w_meas = w_true + math.sqrt(q_w) * rng.normal(size=3)
            state = core.predict(state, w_meas, 1.0)
            state, info = core.update(state, stars(R, noise=sigma * rng.normal(size=(2, 3)), t=k))
            assert info.accepted
            if k in checks:
                j = checks.index(k)
                _, w_hat, P6 = core.estimate(state)
                e = np.concatenate([error_vector(state.R_IB, R), w_true - w_hat])
                nees3[run, j] = e[:3] @ np.linalg.solve(P6[:3, :3], e[:3])
                nees6[run, j] = e @ np.linalg.solve(P6, e)
    assert_nees_sums_in_band(nees3, nees6, n_runs)


def test_rate_block_is_the_gyro_noise_and_the_cross_block_follows_the_updates():
    dt = 0.25
    R_true = np.eye(3)
    # No gyro figure: the step's process noise read as integrated rate error.
    core = LieGroupFilter(Q_w=np.diag([1e-6, 2e-6, 4e-6]), Q_v=1e-6)
    state = core.initial_state(R_true, 1e-4, initial_rate_sigma=0.5)
    _, w0, P6 = core.estimate(state)
    assert np.array_equal(w0, np.zeros(3)) and np.allclose(P6[3:, 3:], 0.25 * np.eye(3)) and not P6[:3, 3:].any()
    w = np.array([0.01, -0.02, 0.03])
    state = core.predict(state, w, dt)
    Q = np.diag([1e-6, 2e-6, 4e-6]) * dt
    _, w_hat, P6 = core.estimate(state)
    assert np.array_equal(w_hat, w)
    assert np.allclose(P6[3:, 3:], Q / dt**2, rtol=1e-14)
    assert np.allclose(P6[:3, 3:], Q / dt, rtol=1e-14)
    assert np.allclose(P6, P6.T) and np.linalg.eigvalsh(P6).min() > -1e-18
    state2, info = core.update(state, stars(R_true @ drake_exp(w * dt)))
    assert info.accepted
    _, _, P6b = core.estimate(state2)
    # Joseph update with the optimal gain: (I - K H) from P_post = (I - K H) P.
    I_KH = state2.P @ np.linalg.inv(state.P)
    assert np.allclose(P6b[:3, 3:], I_KH @ (Q / dt), rtol=1e-6)
    assert np.allclose(P6b[3:, 3:], Q / dt**2)
    assert np.linalg.eigvalsh(P6b).min() > -1e-15
    # With a gyro ARW N: rate block N^2/dt, cross N^2, process noise Q_w dt + N^2 dt.
    arw = 1e-3
    core = LieGroupFilter(Q_w=1e-6, gyro_arw_rad_per_rt_s=arw)
    state = core.predict(core.initial_state(R_true, 0.0), w, dt)
    _, _, P6 = core.estimate(state)
    assert np.allclose(P6[3:, 3:], arw**2 / dt * np.eye(3))
    assert np.allclose(P6[:3, 3:], arw**2 * np.eye(3))
    assert np.allclose(P6[:3, :3], (1e-6 * dt + arw**2 * dt) * np.eye(3))


# =============================================================================================
# Beyond the paper: the gyro-bias extension (SO(3) x R^3) and the quaternion update.
#
# Independent reference: pydrake rotations and quaternions, numpy inverses, finite
# differences of the measurement and propagation models written here; a Farrenkopf gyro
# simulated on 10 sub-steps per filter step. The MEKF comparison uses the library's MEKF
# (the point is to compare the two cores).
# =============================================================================================
ARW = 0.1 * DEG / 60.0  # 0.1 deg/rt-h in rad/s^0.5
RRW = 1.0 * DEG / 3600.0 / 60.0  # 1 deg/h^1.5 in rad/s^1.5
DEG_H = DEG / 3600.0  # 1 deg/h in rad/s
Q_BS_TEST = RollPitchYaw(0.5, 0.2, -0.8).ToQuaternion().wxyz()
R_BS_TEST = RotationMatrix(RollPitchYaw(0.5, 0.2, -0.8)).matrix()


def bias_core(**kw):
    kw.setdefault("gyro_arw_rad_per_rt_s", ARW)
    kw.setdefault("gyro_rrw_rad_per_s15", RRW)
    return LieGroupFilter(estimate_gyro_bias=True, **kw)


def random_spd(rng, n, scales):
    A = rng.normal(size=(n, n))
    D = np.diag(scales)
    return D @ (A @ A.T / n + np.eye(n)) @ D


def quat_of(R):
    """wxyz quaternion of a rotation matrix (pydrake)."""
    return RotationMatrix(R).ToQuaternion().wxyz()


_ZERO3 = np.zeros(3)  # default tracker error (read only)


def quaternion_sample(R_IB, cov_S, q_BS=Q_BS_TEST, R_BS=R_BS_TEST, delta_S=_ZERO3, t=0.0, flip=False):
    """QuaternionSample of a tracker mounted by q_BS: R_IS = R_IB R_BS exp([delta_S x])."""
    q = quat_of(R_IB @ R_BS @ drake_exp(delta_S))
    return QuaternionSample(float(t), True, -q if flip else q, np.array(q_BS, dtype=float), np.array(cov_S))


def test_bias_mode_is_a_filter_core_with_its_own_second_quantity_and_state_size():
    core = bias_core()
    assert isinstance(core, FilterCore)
    assert core.second_quantity is SecondQuantity.GYRO_BIAS and core.state_size == 48
    # Per instance: the class attributes (and a default core) keep the paper's no-bias values.
    assert LieGroupFilter.second_quantity is SecondQuantity.BODY_RATE and LieGroupFilter.state_size == 39
    assert LieGroupFilter().second_quantity is SecondQuantity.BODY_RATE and LieGroupFilter().state_size == 39
    # Q_w default: the paper's 5e-5 without a bias state, 0 with one (the gyro model carries it).
    assert np.array_equal(LieGroupFilter().Q_w, 5e-5 * np.eye(3)) and not core.Q_w.any()
    rng = np.random.default_rng(5)
    P0 = random_spd(rng, 6, [1e-2] * 3 + [1e-4] * 3)
    b0 = np.array([1e-4, -2e-4, 3e-5])
    state = core.initial_state(quat_of(RotationMatrix(RollPitchYaw(0.3, -0.2, 1.1)).matrix()), P0, bias_B=b0)
    state = core.predict(state, np.array([1e-2, -2e-2, 5e-3]), 0.5)
    state, info = core.update(state, stars(state.R_IB @ drake_exp([1e-3, -2e-3, 5e-4]), t=0.5))
    assert info.accepted and info.error_transition.shape == (6, 6)
    v = core.to_vector(state)
    assert v.shape == (core.state_size,)
    back = core.from_vector(v)
    for f in ("R_IB", "bias_B", "P"):
        assert np.array_equal(getattr(back, f), getattr(state, f)), f
    q, b, P = core.estimate(state)
    assert np.array_equal(b, state.bias_B) and np.array_equal(P, state.P)
    assert abs(abs(q @ quat_of(state.R_IB)) - 1.0) < 1e-14
    # A state of the other kind, bad combinations and a bias without a 6x6 P0 are refused.
    with pytest.raises(TypeError, match="LieGroupBiasState"):
        core.predict(core.initial_state(IDENTITY_Q, 1e-4), np.zeros(3), 1.0)
    with pytest.raises(TypeError, match="need a LieGroupState"):
        LieGroupFilter().update(state, stars(state.R_IB))
    with pytest.raises(ValueError, match="estimate_gyro_bias"):
        LieGroupFilter(estimate_gyro_bias=True, formulation="paper_literal")
    with pytest.raises(ValueError, match="gyro_rrw_rad_per_s15"):
        LieGroupFilter(gyro_rrw_rad_per_s15=1e-6)
    with pytest.raises(ValueError, match="6x6"):
        LieGroupFilter.initial_state(IDENTITY_Q, 1e-4, bias_B=np.zeros(3))


def test_bias_mode_measurement_jacobians_match_finite_differences():
    """H of the vector and quaternion models against central differences of the measurement
    the truth R_IB = R_IB_hat exp([dtheta x]) (any bias b = b_hat + dbias) would produce; the
    bias columns are zero (the measurements do not see the bias)."""
    core = bias_core(Q_v=1e-8)
    R_hat = RotationMatrix(RollPitchYaw(-0.4, 0.9, 0.1)).matrix()
    rng = np.random.default_rng(11)
    state = core.initial_state(R_hat, random_spd(rng, 6, [1e-3] * 3 + [1e-5] * 3), bias_B=[1e-4, 0.0, -1e-4])
    refs = np.array([[0.6, 0.8, 0.0], [0.0, 0.6, 0.8], [0.8, 0.0, 0.6]])
    R_SB = R_BS_TEST.T

    def h_vectors(dx):  # sensor-frame directions seen from the perturbed truth
        return (refs @ (R_hat @ drake_exp(dx[:3])) @ R_SB.T).ravel()

    cov_S = np.diag([1e-10, 1e-10, 1e-8])

    def h_quaternion(dx):  # the innovation of a noise-free sample taken at the perturbed truth
        return core.measurement_model(state, quaternion_sample(R_hat @ drake_exp(dx[:3]), cov_S))[0]

    eps = 1e-6
    for h, m in (
        (h_vectors, stars(R_hat, refs, q_BS=Q_BS_TEST, R_SB=R_SB)),
        (h_quaternion, quaternion_sample(R_hat, cov_S)),
    ):
        z0, H, _ = core.measurement_model(state, m)
        assert H.shape == (z0.size, 6)
        H_fd = np.column_stack([(h(eps * e) - h(-eps * e)) / (2 * eps) for e in np.eye(6)])
        assert np.allclose(H, H_fd, atol=1e-9), np.abs(H - H_fd).max()
        assert not H[:, 3:].any()
    # The no-bias model is the bias model's first three columns.
    z3, H3, R3 = LieGroupFilter(Q_v=1e-8).measurement_model(core.initial_state(R_hat, 1e-3), stars(R_hat, refs))
    z6, H6, R6 = core.measurement_model(state, stars(R_hat, refs))
    assert np.array_equal(z3, z6) and np.array_equal(H3, H6[:, :3]) and np.array_equal(R3, R6)


def test_bias_mode_covariance_propagation_matches_finite_differences_of_the_kinematics():
    """P_new - Q = J P J' with J the central-difference Jacobian of the error after one step:
    truth R = R_hat exp(dtheta), b = b_hat + dbias, both integrated over dt with their own
    rate (truth w_meas - b, filter w_meas - b_hat, constant over the step); error
    log(R_hat_new' R_new) and dbias. The process noise is the Farrenkopf covariance."""
    core = bias_core()
    R_hat = RotationMatrix(RollPitchYaw(0.2, -0.7, 2.5)).matrix()
    b_hat = np.array([2e-3, -1e-3, 5e-4])
    w_meas = np.array([0.3, -0.2, 0.5])  # rad/s: |w| dt = 0.3 rad, the frame rotation matters
    dt = 0.5
    rng = np.random.default_rng(2)
    P0 = random_spd(rng, 6, [1e-2] * 3 + [1e-3] * 3)
    state = core.initial_state(R_hat, P0, bias_B=b_hat)
    new = core.predict(state, w_meas, dt)
    R_hat_new = R_hat @ expm_series((w_meas - b_hat) * dt)
    assert np.allclose(new.R_IB, R_hat_new, atol=1e-14) and np.array_equal(new.bias_B, b_hat)

    def error_after(dx):
        R_new = R_hat @ expm_series(dx[:3]) @ expm_series((w_meas - b_hat - dx[3:]) * dt)
        return np.concatenate([error_vector(R_hat_new, R_new), dx[3:]])

    eps = 1e-6
    J = np.column_stack([(error_after(eps * e) - error_after(-eps * e)) / (2 * eps) for e in np.eye(6)])
    sv2, su2 = ARW**2, RRW**2
    Q = np.zeros((6, 6))
    Q[:3, :3] = (sv2 * dt + su2 * dt**3 / 3) * np.eye(3)
    Q[:3, 3:] = Q[3:, :3] = -su2 * dt**2 / 2 * np.eye(3)
    Q[3:, 3:] = su2 * dt * np.eye(3)
    assert np.allclose(core.process_noise(dt), Q, rtol=1e-14, atol=0)
    assert np.allclose(new.P - Q, J @ P0 @ J.T, rtol=1e-7, atol=1e-14)
    # Q_w adds to the attitude block only.
    extra = bias_core(Q_w=1e-6, step_s=2.0)
    assert np.allclose(extra.process_noise(dt) - Q, np.diag([1e-6 * dt / 2.0] * 3 + [0.0] * 3), rtol=1e-12, atol=0)


@pytest.mark.parametrize("with_bias", [False, True])
def test_quaternion_update_against_an_independent_computation(with_bias):
    """Measured q_IS from a mounted tracker: innovation log(R_hat' R_IS R_BS') (pydrake),
    H = [I 0], R = R_BS C_S R_BS', K = P H' S^-1 (numpy inverse), right update, Joseph
    covariance (= (I - K H) P for this optimal gain); the sign of q_IS does not matter, and
    the innovation is the MEKF's sensor-frame residual rotated into B."""
    rng = np.random.default_rng(7 + with_bias)
    n = 6 if with_bias else 3
    core = bias_core() if with_bias else LieGroupFilter(Q_w=1e-6)
    R_hat = RotationMatrix(RollPitchYaw(0.2, 0.1, -0.3)).matrix()
    R_true = R_hat @ drake_exp([3e-3, -2e-3, 4e-3])
    P = random_spd(rng, n, [2e-3] * 3 + [1e-4] * (n - 3))
    b_hat = np.array([1e-4, 2e-4, -3e-4])
    state = core.initial_state(R_hat, P, bias_B=b_hat) if with_bias else core.initial_state(R_hat, P)
    if not with_bias:  # a non-trivial cross block (after a predict)
        state = core.predict(state, np.array([1e-3, 0.0, 2e-3]), 1.0)
        R_hat, P = state.R_IB, state.P
    C_S = np.diag([(5 * DEG / 3600) ** 2, (5 * DEG / 3600) ** 2, (50 * DEG / 3600) ** 2])
    delta_S = np.array([2e-5, -1e-5, 3e-4])
    m = quaternion_sample(R_true, C_S, delta_S=delta_S)
    new, info = core.update(state, m)
    flipped, info_f = core.update(state, quaternion_sample(R_true, C_S, delta_S=delta_S, flip=True))
    assert info.accepted and info_f.accepted
    R_IS = RotationMatrix(Quaternion(m.q_IS_meas)).matrix()
    z = error_vector(R_hat, R_IS @ R_BS_TEST.T)
    z_S_mekf = error_vector(R_hat @ R_BS_TEST, R_IS)  # log((q_IB_hat q_BS)^-1 q_IS)
    assert np.allclose(info.innovation, z, atol=1e-14) and np.allclose(info_f.innovation, z, atol=1e-14)
    assert np.allclose(z, R_BS_TEST @ z_S_mekf, atol=1e-14)
    H = np.hstack([np.eye(3), np.zeros((3, n - 3))])
    R_B = R_BS_TEST @ C_S @ R_BS_TEST.T
    S = H @ P @ H.T + R_B
    K = P @ H.T @ np.linalg.inv(S)
    dx = K @ z
    assert np.allclose(info.innovation_covariance, S, rtol=1e-12, atol=1e-22)
    assert info.nis == pytest.approx(z @ np.linalg.solve(S, z), rel=1e-9)
    assert np.allclose(new.R_IB, R_hat @ drake_exp(dx[:3]), atol=1e-14)
    assert np.allclose(new.P, (np.eye(n) - K @ H) @ P, rtol=1e-8, atol=1e-20)
    assert np.allclose(flipped.R_IB, new.R_IB, atol=1e-15)
    if with_bias:
        assert np.allclose(new.bias_B, b_hat + dx[3:], rtol=1e-9, atol=1e-18)
    else:
        assert np.allclose(new.C, (np.eye(3) - K @ H) @ state.C, rtol=1e-8, atol=1e-20)
        assert np.array_equal(new.P_w, state.P_w) and np.array_equal(new.w_B, state.w_B)
    # The update removes the error to the tracker's accuracy (5"/50" -> ~1e-4 rad).
    assert error_angle(new.R_IB, R_true) < 4e-4 < error_angle(R_hat, R_true)
    with pytest.raises(TypeError, match="paper_literal"):
        LieGroupFilter(formulation="paper_literal").update(LieGroupFilter.initial_state(R_hat, 1e-4), m)


def simulate_farrenkopf_run(rng, core, n_steps, checks, P0, dt=1.0, substeps=10, sigma=1e-4, refs=S4_REFS):
    """One Monte Carlo run of gyro + mounted-free star vectors (numpy only).

    Truth: body rate w(t) = 0.02 [sin 0.05t, cos 0.03t, 0.5] rad/s (held over each step),
    initial error ~ N(0, P0) (attitude and bias). Gyro (Farrenkopf): each sub-step of dt /
    substeps has bias b_j (random walk, RRW) and white rate noise of density ARW; the
    sample is the mean rate over the step. Stars: b_S = R_IB' r + N(0, sigma^2 I).
    Returns the 6-dof NEES at ``checks`` and the final (bias error, bias sigma)."""
    h = dt / substeps
    R = RotationMatrix(RollPitchYaw(*rng.uniform(-np.pi, np.pi, 3))).matrix()
    e0 = np.linalg.cholesky(P0) @ rng.normal(size=6)
    b_hat0 = np.array([12.0, 12.0, 12.0]) * DEG_H
    state = core.initial_state(R @ drake_exp(-e0[:3]), P0, bias_B=b_hat0)
    b = b_hat0 + e0[3:]
    nees = []
    for k in range(1, n_steps + 1):
        t = (k - 1) * dt
        w = 0.02 * np.array([math.sin(0.05 * t), math.cos(0.03 * t), 0.5])
        acc = np.zeros(3)
        for _ in range(substeps):
            acc += (w + b + ARW / math.sqrt(h) * rng.normal(size=3)) * h
            b = b + RRW * math.sqrt(h) * rng.normal(size=3)
        R = R @ expm_series(w * dt)
        state = core.predict(state, acc / dt, dt)
        state, info = core.update(
            state, stars(R, refs, noise=sigma * rng.normal(size=(len(refs), 3)), t=k * dt, sigma=sigma)
        )
        assert info.accepted
        if k in checks:
            e = np.concatenate([error_vector(state.R_IB, R), b - state.bias_B])
            nees.append(e @ np.linalg.solve(state.P, e))
    return np.array(nees), b - state.bias_B, np.sqrt(np.diag(state.P)[3:])


@pytest.mark.slow
def test_bias_converges_and_six_dof_nees_is_chi_square_over_a_monte_carlo():
    """30 runs, 300 s: the estimated bias converges from a 20 deg/h prior to well under
    1 deg/h, and the summed 6-dof NEES lies in the chi-square band at 30, 100 and 300 s."""
    n_runs, n_steps, checks = 30, 300, (30, 100, 300)
    core = bias_core(Q_v=None)
    P0 = np.diag([(0.5 * DEG) ** 2] * 3 + [(20.0 * DEG_H) ** 2] * 3)
    rng = np.random.default_rng(20240614)
    nees = np.zeros((n_runs, len(checks)))
    final_err = np.zeros((n_runs, 3))
    for run in range(n_runs):
        nees[run], final_err[run], final_sigma = simulate_farrenkopf_run(rng, core, n_steps, checks, P0)
    lo, hi = chi2_band(6 * n_runs)
    sums = nees.sum(axis=0)
    assert np.all((lo <= sums) & (sums <= hi)), (sums / n_runs, lo / n_runs, hi / n_runs)
    rms = np.sqrt(np.mean(final_err**2, axis=0))
    assert np.all(rms < 0.5 * DEG_H), rms / DEG_H  # from 20 deg/h (1-sigma) to < 0.5 deg/h
    assert np.all(final_sigma < 0.5 * DEG_H), final_sigma / DEG_H


@pytest.mark.slow
def test_bias_mode_equals_the_mekf_to_round_off():
    """The finding (docs/derivations/lie_group.md): with a bias state and Q_w = 0 the Lie-group filter is
    the MEKF (same right error, Phi, Q, vector model, quaternion model up to the rotation
    R_BS of z/H/R, same reset). 2000 steps with a 12 deg/h bias, a fast-turning body and
    alternating mounted-quaternion and vector updates: attitude, bias, covariance and NIS
    agree to round-off; the no-bias filter on the same data is not (the check has power)."""
    from drake_att.filters.mekf import MultiplicativeEKF

    rng = np.random.default_rng(3)
    arw, rrw = 0.56 * DEG / 60.0, 123.75 * DEG / 3600.0 / 60.0  # paper S3's MEMS gyro
    lie = bias_core(gyro_arw_rad_per_rt_s=arw, gyro_rrw_rad_per_s15=rrw)
    mekf = MultiplicativeEKF(arw, rrw)
    no_bias = LieGroupFilter(Q_w=0.0, Q_v=None, gyro_arw_rad_per_rt_s=arw)
    R = RotationMatrix(RollPitchYaw(0.31, -0.22, 1.05)).matrix()
    R0 = R @ drake_exp([0.05, -0.03, 0.04])
    s_lie = lie.initial_state(R0, np.diag([0.01] * 3 + [(20 * DEG_H) ** 2] * 3))
    s_mekf = mekf.initial_state(quat_of(R0), np.zeros(3), 0.1, 20 * DEG_H)
    s_nb = no_bias.initial_state(R0, 0.01)
    b = 12.0 * DEG_H * np.ones(3)
    C_S = np.diag([(5 * DEG / 3600) ** 2, (5 * DEG / 3600) ** 2, (50 * DEG / 3600) ** 2])
    worst = np.zeros(4)
    gap_no_bias = 0.0
    for k in range(2000):
        w = 0.05 * np.array([math.cos(0.01 * k), math.sin(0.013 * k), 0.5])
        R = R @ drake_exp(w)
        w_meas = w + b + arw * rng.normal(size=3)
        s_lie, s_mekf, s_nb = (
            lie.predict(s_lie, w_meas, 1.0),
            mekf.predict(s_mekf, w_meas, 1.0),
            no_bias.predict(s_nb, w_meas, 1.0),
        )
        if k % 2:
            m = quaternion_sample(R, C_S, delta_S=np.sqrt(np.diag(C_S)) * rng.normal(size=3), t=k)
        else:
            m = stars(R, noise=1e-4 * rng.normal(size=(2, 3)), q_BS=Q_BS_TEST, R_SB=R_BS_TEST.T, t=k, sigma=1e-4)
        (s_lie, i_lie), (s_mekf, i_mekf), (s_nb, _) = (
            lie.update(s_lie, m),
            mekf.update(s_mekf, m),
            no_bias.update(s_nb, m),
        )
        R_mekf = RotationMatrix(Quaternion(s_mekf.q_IB / np.linalg.norm(s_mekf.q_IB))).matrix()
        d = np.sqrt(np.outer(np.diag(s_mekf.P), np.diag(s_mekf.P)))
        worst = np.maximum(
            worst,
            [
                error_angle(s_lie.R_IB, R_mekf),
                np.abs(s_lie.bias_B - s_mekf.bias_B).max(),
                np.abs((s_lie.P - s_mekf.P) / d).max(),
                abs(i_lie.nis - i_mekf.nis) / (1 + i_mekf.nis),
            ],
        )
        gap_no_bias = max(gap_no_bias, error_angle(s_nb.R_IB, R_mekf))
    assert worst[0] < 1e-10, worst  # rad (measured ~1e-12: the first, ill-conditioned updates)
    assert worst[1] < 1e-11, worst  # rad/s (measured ~2e-13)
    assert worst[2] < 1e-10, worst  # correlation-scaled covariance entries (measured ~2e-13)
    assert worst[3] < 1e-8, worst
    assert gap_no_bias > 1e-5  # rad: the no-bias filter on the same data (7 orders above the bound)
    assert np.all(np.abs(s_lie.bias_B - b) < 3 * np.sqrt(np.diag(s_lie.P)[3:]) + 5 * DEG_H)


# -- the plug-in ---------------------------------------------------------------------------------
PLUGIN_SCENARIO = f"""
name: lie_group_bias_plugin
duration_s: 60.0
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.5}}
plant: !RigidBodyConfig {{inertia_kg_m2: [100.0, 200.0, 200.0], initial_rate_deg_per_s: [0.5, -0.3, 0.2],
                         disturbance_torque_N_m: [0.0, 0.0, 0.0]}}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 1.0,
               initial_bias_deg_per_h: [12.0, -8.0, 5.0]}}
- !StarTrackerConfig {{name: stq, period_s: 0.5, mode: quaternion,
                      mounting: !PaperS3Eq7Mounting {{psi_phi_theta_deg: [-90.0, 45.0, -90.0]}},
                      sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}}
- !StarTrackerConfig {{name: stv, period_s: 1.0, mode: vectors, references_I: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                      sigma_vector_urad: 100.0}}
estimators:
- !MekfConfig {{name: mekf_q, star_trackers: [stq], initial_attitude_rpy_deg: [1.0, -1.0, 0.5],
               initial_attitude_sigma_deg: 2.0}}
- !LieGroupConfig {{name: lg_q, star_tracker: stq, estimate_gyro_bias: true, initial_attitude_rpy_deg: [1.0, -1.0, 0.5],
                   initial_attitude_variance_rad2: {(2.0 * DEG) ** 2!r}}}
- !MekfConfig {{name: mekf_v, star_trackers: [stv], initial_attitude_sigma_deg: 2.0}}
- !LieGroupConfig {{name: lg_v, star_tracker: stv, estimate_gyro_bias: true, star_noise_from_tracker: true,
                   initial_attitude_variance_rad2: {(2.0 * DEG) ** 2!r}}}
- !LieGroupConfig {{name: lg_q_no_bias, star_tracker: stq}}
"""


@pytest.fixture(scope="module")
def plugin_diagram():
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import load_scenario

    return ScenarioDiagram(load_scenario(text=PLUGIN_SCENARIO))


@pytest.mark.slow
def test_plugin_bias_mode_on_quaternion_and_vector_trackers_equals_the_mekf_plugin(plugin_diagram):
    from drake_att.analysis.metrics import estimator_errors

    sd = plugin_diagram
    assert sd.estimators["lg_q"].second_output_name == "bias_B_hat"
    assert sd.estimators["lg_q_no_bias"].second_output_name == "w_IB_B_hat"
    for overrides in (
        [],
        [
            "estimators.lg_q.initial_bias_sigma_deg_per_h=5",
            "estimators.mekf_q.initial_bias_sigma_deg_per_h=5",
            "estimators.lg_v.arw_deg_per_rt_h=0.3",
            "estimators.mekf_v.arw_deg_per_rt_h=0.3",
        ],
    ):
        run = sd.simulate(4, overrides=overrides)
        assert run.metadata["estimators"]["lg_q"]["second_kind"] == "gyro_bias"
        assert run.metadata["estimators"]["lg_q"]["true_bias"] is not None
        for lie, mekf in (("lg_q", "mekf_q"), ("lg_v", "mekf_v")):
            a, b = estimator_errors(run, lie), estimator_errors(run, mekf)
            assert a["t"].size == 60 and np.array_equal(a["t"], b["t"])
            assert np.abs(a["dtheta"] - b["dtheta"]).max() < 1e-12
            assert np.abs(a["second_err"] - b["second_err"]).max() < 1e-14  # rad/s
            diag = np.einsum("nii->ni", b["P"])
            scale = np.sqrt(diag[:, :, None] * diag[:, None, :])
            assert np.abs((a["P"] - b["P"]) / scale).max() < 1e-9  # correlation-scaled entries
            # every step's sample used or (the default 99.9% gate) rejected, identically
            assert np.array_equal(a["status"][-1, 1:3], b["status"][-1, 1:3])
            assert int(a["status"][-1, 1] + a["status"][-1, 2]) == 60 and a["status"][-1, 1] >= 57
    # The YAML round trip (overrides, diagram_for) keeps star_noise_from_tracker (a null
    # star_noise_variance_rad2 did not survive it, hence the flag).
    run = sd.simulate(4, overrides=["estimators.lg_q.initial_bias_sigma_deg_per_h=5"])
    assert np.abs(estimator_errors(run, "lg_v")["dtheta"] - estimator_errors(run, "mekf_v")["dtheta"]).max() < 1e-12
    # The context parameter is applied (a different run from the default).
    base = estimator_errors(sd.simulate(4), "lg_q")
    swept = estimator_errors(sd.simulate(4, overrides=["estimators.lg_q.initial_bias_sigma_deg_per_h=5"]), "lg_q")
    assert not np.allclose(base["P"][-1], swept["P"][-1], rtol=1e-3, atol=0)


def test_plugin_validation_names_the_field(plugin_diagram):
    from drake_att.scenarios.config import ConfigError, apply_overrides

    scenario = plugin_diagram.scenario
    cases = {
        "estimators.lg_q.formulation=paper_literal": "lg_q.formulation",
        "estimators.lg_v.formulation=paper_literal": "lg_v.estimate_gyro_bias",
        "estimators.lg_q_no_bias.arw_deg_per_rt_h=0.1": "lg_q_no_bias.arw_deg_per_rt_h",
        "estimators.lg_q_no_bias.rrw_deg_per_h15=0.1": "lg_q_no_bias.rrw_deg_per_h15",
        "estimators.lg_q.gyro_arw_deg_per_rt_h=0.1": "lg_q.gyro_arw_deg_per_rt_h",
        "estimators.lg_q.rrw_deg_per_h15=-1": "lg_q.rrw_deg_per_h15",
        "estimators.lg_q.initial_bias_sigma_deg_per_h=0": "lg_q.initial_bias_sigma_deg_per_h",
        "estimators.lg_q.initial_bias_deg_per_h=[1, 2]": "lg_q.initial_bias_deg_per_h",
        "estimators.lg_v.star_tracker=gyro": "lg_v.star_tracker",
        "estimators.lg_v.estimate_gyro_bias=3": "lg_v.estimate_gyro_bias",
        "estimators.lg_v.process_noise_rad2_per_step=-1": "lg_v.process_noise_rad2_per_step",
        "estimators.lg_v.star_noise_variance_rad2=null": "lg_v.star_noise_variance_rad2",
    }
    for override, field in cases.items():
        with pytest.raises(ConfigError, match=field.replace(".", r"\W+")):
            apply_overrides(scenario, [override])
    # The bias state is structural: it changes the state size and the second output.
    with pytest.raises(ConfigError, match="estimate_gyro_bias"):
        plugin_diagram.simulate(1, overrides=["estimators.lg_q.estimate_gyro_bias=false"])


def test_bad_arguments_are_refused_naming_the_field_and_the_rule():
    """Each refusal names its field first and says what is allowed."""
    cases = [
        (lambda: LieGroupFilter(estimate_gyro_bias=1), "estimate_gyro_bias: ", "must be True or False"),
        (
            lambda: LieGroupFilter(estimate_gyro_bias=True, formulation="paper_literal"),
            "estimate_gyro_bias: ",
            "needs formulation='consistent'",
        ),
        (
            lambda: LieGroupFilter(gyro_rrw_rad_per_s15=1e-6),
            "gyro_rrw_rad_per_s15: ",
            "the rate random walk is modelled only with estimate_gyro_bias=True",
        ),
        (lambda: LieGroupFilter(formulation="literal"), "formulation: ", "allowed: "),
        (lambda: LieGroupFilter(step_s=0.0), "step_s: ", "must be > 0"),
        (lambda: LieGroupFilter(Q_v=-1.0), "Q_v: ", "must be >= 0"),
    ]
    for call, field, rule in cases:
        with pytest.raises(ValueError) as e:
            call()
        assert str(e.value).startswith(field) and rule in str(e.value), str(e.value)


def test_a_quaternion_sample_with_three_sigmas_is_read_as_their_diagonal_covariance():
    """``covariance_S`` given as three per-axis sigmas (rad) is the covariance
    ``diag(sigma^2)``: the update equals the one with the 3x3 matrix, to the last bit."""
    core = LieGroupFilter()
    q_true = RollPitchYaw(0.2, -0.1, 0.4).ToQuaternion().wxyz()
    state = core.initial_state(RollPitchYaw(0.21, -0.1, 0.39).ToQuaternion().wxyz(), 1e-4)
    sig = np.array([1e-3, 2e-3, 5e-3])
    a = core.update(state, QuaternionSample(0.0, True, q_true, IDENTITY_Q, sig))
    b = core.update(state, QuaternionSample(0.0, True, q_true, IDENTITY_Q, np.diag(sig**2)))
    assert a[1].accepted and b[1].accepted
    np.testing.assert_array_equal(a[0].R_IB, b[0].R_IB)
    np.testing.assert_array_equal(a[0].P, b[0].P)
    np.testing.assert_array_equal(a[1].innovation_covariance, b[1].innovation_covariance)
