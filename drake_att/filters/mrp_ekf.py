"""Additive extended Kalman filter on modified Rodrigues parameters (paper S0, gyro mode).
Plain numpy (no Drake).

State ``x = [rho; b]``: ``rho`` (3, dimensionless) is the MRP of ``q_IB`` (body to inertial,
``v_I = R(q_IB) v_B``; ``|rho| <= 1`` between calls, the shadow set taken when it grows
past 1) and ``b`` (3, rad/s) the gyro bias; ``P`` (6x6) the covariance of ``x`` in the MRP
chart. Gyro: the mean body rate over the step (Farrenkopf model, ARW ``sigma_v``
rad/s^0.5, RRW ``sigma_u`` rad/s^1.5); measurements: star vectors
``y = [R_BI u_1; ...; R_BI u_m] + v``, ``v ~ N(0, sigma^2 I_3m)`` (rad).

* :class:`MrpEkfCore` on :class:`MrpEkfState`: the :class:`drake_att.contract.FilterCore`.
* :func:`ekf_predict`, :func:`ekf_update` and the model functions and Jacobians they use,
  all batched over leading dimensions: the EKPF of :mod:`drake_att.filters.particle` runs
  one EKF per particle with them, without a Python loop.
* :func:`body_frame_vectors`, :func:`gyro_rate`: the checks of a vector-fed core's inputs.

Derivation (mean, transition matrix, process noise, update, shadow switch) and measured
behaviour: docs/derivations/mrp_ekf.md
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att.contract import SecondQuantity, UpdateInfo
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
from drake_att.rotations import (
    mrp_kinematics_matrix,
    mrp_to_quat,
    mrp_to_rotmat,
    quat_propagate,
    quat_to_mrp,
    quat_to_rotmat,
    skew,
)
from drake_att.validation import (
    check_array,
    check_covariance,
    check_int,
    check_positive,
    check_quaternion,
    check_reference_vectors,
    measurement_or_none,
)

__all__ = [
    "MrpEkfCore",
    "MrpEkfState",
    "mrp_rate_jacobian",
    "mrp_dynamics_jacobian",
    "mrp_kinematics_inverse",
    "mrp_shadow_jacobian",
    "propagate_mrp",
    "vector_measurement_model",
    "vector_measurement_jacobian",
    "discrete_transition_matrix",
    "discrete_process_noise",
    "ekf_predict",
    "ekf_update",
    "body_frame_vectors",
    "gyro_rate",
    "switch_to_short_mrp",
    "attitude_to_mrp_covariance",
    "mrp_to_attitude_covariance",
]


def body_frame_vectors(observations) -> tuple[np.ndarray | None, np.ndarray, float]:
    """The vectors of a :class:`~drake_att.contract.VectorObservations` sample in the body frame.

    Returns ``(y_B (3m,) or None, references_I (m, 3), sigma (rad))``: ``y_B = R_BS y_S``
    stacked (exact for the isotropic vector noise of the vector-mode tracker); None when
    a direction is missing or not finite (the caller declines the update). A wrong shape,
    bad references or a sigma <= 0 raise ValueError naming the field.
    """
    U = check_reference_vectors("ref_vectors_I", observations.references_I)
    sigma = check_positive("sigma", observations.sigma_rad)
    y_S = measurement_or_none("directions_S", observations.directions_S, (U.shape[0], 3),
                              " (one direction per reference vector)")
    if y_S is None:
        return None, U, sigma
    q_BS = np.asarray(observations.q_BS, dtype=float)
    if q_BS.tolist() == _IDENTITY:  # a body-mounted sensor: R_BS = I (the product is exact)
        return y_S.ravel(), U, sigma
    return (y_S @ quat_to_rotmat(q_BS).T).ravel(), U, sigma


_IDENTITY = [1.0, 0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------------
# Model functions and Jacobians (batched over leading dimensions)
# ----------------------------------------------------------------------------------
def mrp_rate_jacobian(rho, w) -> np.ndarray:
    """Jacobian ``d(B(rho) w)/d rho`` of the MRP kinematics at fixed rate.

    ``B(rho) w = 1/4 [(1 - rho'rho) w + 2 rho x w + 2 rho (rho'w)]``, hence
    ``d/drho = 1/2 [rho w' - w rho' - [w x] + (rho'w) I]``.

    Args:
        rho: MRP(s), shape ``(..., 3)`` (dimensionless).
        w: Body rate(s) ``w_IB_B``, shape ``(..., 3)`` (rad/s).

    Returns:
        ``(..., 3, 3)`` Jacobian (1/s).
    """
    rho = np.asarray(rho, dtype=float)
    w = np.asarray(w, dtype=float)
    rw = np.sum(rho * w, axis=-1)[..., None, None]
    eye = np.eye(3)
    return 0.5 * (rho[..., :, None] * w[..., None, :] - w[..., :, None] * rho[..., None, :]
                  - skew(w) + rw * eye)


def mrp_dynamics_jacobian(x, w_meas) -> np.ndarray:
    """Jacobian ``F = d(x_dot)/dx`` of the gyro-mode model ``x = [rho; b]``.

    ``x_dot = [B(rho) (w_meas - b); 0]`` so
    ``F = [[d(B w)/drho, -B(rho)], [0, 0]]`` with ``w = w_meas - b``.

    Args:
        x: State(s) ``[rho; b]``, shape ``(..., 6)`` (-, rad/s).
        w_meas: Measured rate(s), shape ``(..., 3)`` or ``(3,)`` (rad/s).

    Returns:
        ``(..., 6, 6)`` Jacobian (1/s in the rho rows).
    """
    x = np.asarray(x, dtype=float)
    rho, b = x[..., :3], x[..., 3:]
    w = np.asarray(w_meas, dtype=float) - b
    F = np.zeros(x.shape[:-1] + (6, 6))
    F[..., :3, :3] = mrp_rate_jacobian(rho, w)
    F[..., :3, 3:] = -mrp_kinematics_matrix(rho)
    return F


def mrp_kinematics_inverse(rho) -> np.ndarray:
    """``B(rho)^-1 = 16 / (1 + rho'rho)^2 B(rho)'`` (maps ``drho`` to body angle, rad).

    ``B`` is ``(1 + rho'rho)/4`` times an orthogonal matrix, so the inverse is exact.
    """
    rho = np.asarray(rho, dtype=float)
    n2 = np.sum(rho * rho, axis=-1)[..., None, None]
    return 16.0 / (1.0 + n2) ** 2 * np.swapaxes(mrp_kinematics_matrix(rho), -1, -2)


def mrp_shadow_jacobian(rho) -> np.ndarray:
    """Jacobian of the shadow map ``s(rho) = -rho / |rho|^2``.

    ``ds/drho = (2 rho rho' - |rho|^2 I) / |rho|^4`` (a scaled reflection; at
    ``|rho| = 1`` it is the Householder-like ``2 rho rho' - I``).
    """
    rho = np.asarray(rho, dtype=float)
    n2 = np.sum(rho * rho, axis=-1)[..., None, None]
    return (2.0 * rho[..., :, None] * rho[..., None, :] - n2 * np.eye(3)) / n2 ** 2


def propagate_mrp(rho, w, dt: float) -> np.ndarray:
    """MRP after a step of constant body rate ``w`` (rad/s) over ``dt`` (s), same chart.

    Closed form through the quaternion: ``q = q(rho)``, ``q+ = q ⊗ exp(w dt / 2)``,
    ``rho+ = q+_vec / (1 + q+_w)`` *without* canonicalizing the sign of ``q+``, so the
    result is the MRP reached by integrating ``rho_dot = B(rho) w`` (it may have
    ``|rho+| > 1``; callers apply :func:`switch_to_short_mrp`).
    """
    q = quat_propagate(mrp_to_quat(rho), w, dt)
    return q[..., 1:] / (1.0 + q[..., :1])


def vector_measurement_model(rho, ref_vectors_I) -> np.ndarray:
    """``h(rho) = [R_BI u_1; ...; R_BI u_m]`` with ``R_BI = R(q_IB(rho))'``.

    Args:
        rho: MRP(s) of ``q_IB``, shape ``(..., 3)``.
        ref_vectors_I: Reference directions in the inertial frame, shape ``(m, 3)``.

    Returns:
        ``(..., 3m)`` predicted body-frame vectors.
    """
    R_IB = mrp_to_rotmat(rho)
    U = np.asarray(ref_vectors_I, dtype=float)
    # (R_IB' u)_k = sum_j R_IB[j, k] u_j
    hb = np.einsum("...jk,mj->...mk", R_IB, U)
    return hb.reshape(hb.shape[:-2] + (3 * U.shape[0],))


def vector_measurement_jacobian(rho, ref_vectors_I) -> np.ndarray:
    """Jacobian ``dh/dx`` of :func:`vector_measurement_model` w.r.t. ``x = [rho; b]``.

    A body-frame rotation ``dtheta`` gives ``R_BI -> exp(-[dtheta x]) R_BI``, so
    ``d(R_BI u) = [(R_BI u) x] dtheta`` and ``dtheta = B(rho)^-1 drho``:
    ``dh/drho = [(R_BI u) x] B(rho)^-1``; the bias columns are zero.

    Returns:
        ``(..., 3m, 6)``.
    """
    rho = np.asarray(rho, dtype=float)
    U = np.asarray(ref_vectors_I, dtype=float)
    m = U.shape[0]
    hb = vector_measurement_model(rho, U).reshape(rho.shape[:-1] + (m, 3))
    Binv = mrp_kinematics_inverse(rho)  # (..., 3, 3)
    Hrho = skew(hb) @ Binv[..., None, :, :]  # (..., m, 3, 3)
    H = np.zeros(rho.shape[:-1] + (3 * m, 6))
    H[..., :3] = Hrho.reshape(rho.shape[:-1] + (3 * m, 3))
    return H


def discrete_transition_matrix(F, dt: float) -> np.ndarray:
    """``Phi = I + F dt + (F dt)^2 / 2 + (F dt)^3 / 6`` (batched)."""
    A = np.asarray(F, dtype=float) * dt
    A2 = A @ A
    return np.eye(A.shape[-1]) + A + 0.5 * A2 + (A2 @ A) / 6.0


def discrete_process_noise(x, F, dt: float, sigma_v: float, sigma_u: float) -> np.ndarray:
    """Discrete process noise of the gyro-mode model (see the module docstring).

    ``Qg = G Q_c G'`` with ``G = [-B(rho) 0; 0 I]``, ``Q_c = diag(sigma_v^2 I, sigma_u^2 I)``;
    ``Qd = Qg dt + (F Qg + Qg F') dt^2 / 2 + F Qg F' dt^3 / 3``.

    Args:
        x: State(s) ``(..., 6)``; only ``rho`` is used.
        F: Jacobian(s) ``(..., 6, 6)`` from :func:`mrp_dynamics_jacobian`.
        dt: Step (s).
        sigma_v: ARW (rad/s^0.5).
        sigma_u: RRW (rad/s^1.5).
    """
    x = np.asarray(x, dtype=float)
    B = mrp_kinematics_matrix(x[..., :3])
    Qg = np.zeros(x.shape[:-1] + (6, 6))
    Qg[..., :3, :3] = sigma_v ** 2 * (B @ np.swapaxes(B, -1, -2))
    Qg[..., 3:, 3:] = sigma_u ** 2 * np.eye(3)
    FQ = F @ Qg
    return (Qg * dt + (FQ + np.swapaxes(FQ, -1, -2)) * (0.5 * dt ** 2)
            + (FQ @ np.swapaxes(F, -1, -2)) * (dt ** 3 / 3.0))


def _sym(P):
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def switch_to_short_mrp(x, P=None):
    """Map states with ``|rho| > 1`` to the shadow set (covariance with its Jacobian).

    Args:
        x: States ``(..., 6)`` (or ``(..., 3)`` MRPs if ``P`` is None).
        P: Covariances ``(..., 6, 6)`` or None.

    Returns:
        ``(x, P, switched)`` with new arrays (inputs are not modified) and the boolean
        mask ``switched`` of shape ``x.shape[:-1]``.
    """
    x = np.array(x, dtype=float)
    rho = x[..., :3]
    n2 = np.sum(rho * rho, axis=-1)
    switched = n2 > 1.0
    if not np.any(switched):
        return x, (None if P is None else np.array(P, dtype=float)), switched
    rho_s = rho[switched]
    J = mrp_shadow_jacobian(rho_s)
    x[switched, :3] = -rho_s / n2[switched][:, None]
    if P is None:
        return x, None, switched
    P = np.array(P, dtype=float)
    Ps = P[switched]
    T = np.broadcast_to(np.eye(P.shape[-1]), Ps.shape).copy()
    T[:, :3, :3] = J
    P[switched] = _sym(T @ Ps @ np.swapaxes(T, -1, -2))
    return x, P, switched


def ekf_predict(x, P, w_meas, dt: float, sigma_v: float, sigma_u: float):
    """Batched EKF time update of ``x = [rho; b]`` (see the module docstring).

    Args:
        x: ``(..., 6)`` states; P: ``(..., 6, 6)`` covariances.
        w_meas: ``(3,)`` or ``(..., 3)`` measured rate (rad/s), held over the step.
        dt: Step (s) > 0. sigma_v: ARW (rad/s^0.5). sigma_u: RRW (rad/s^1.5).

    Returns:
        ``(x_pred, P_pred)`` with ``|rho| <= 1`` (shadow switch applied). ``F`` (for
        ``Phi`` and ``Qd``) is evaluated at the half-step mean.
    """
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    w = np.asarray(w_meas, dtype=float) - x[..., 3:]
    x_mid = x.copy()
    x_mid[..., :3] = propagate_mrp(x[..., :3], w, 0.5 * dt)
    F = mrp_dynamics_jacobian(x_mid, w_meas)
    Phi = discrete_transition_matrix(F, dt)
    Qd = discrete_process_noise(x_mid, F, dt, sigma_v, sigma_u)
    x_new = np.empty_like(x)
    x_new[..., :3] = propagate_mrp(x[..., :3], w, dt)
    x_new[..., 3:] = x[..., 3:]
    P_new = _sym(Phi @ P @ np.swapaxes(Phi, -1, -2) + Qd)
    x_new, P_new, _ = switch_to_short_mrp(x_new, P_new)
    return x_new, P_new


def ekf_update(x, P, y, ref_vectors_I, sigma: float, switch: bool = True,
               iterations: int = 1, iteration_tolerance: float = 1e-12):
    """Batched EKF measurement update with Joseph-form covariance.

    With ``iterations > 1`` this is the iterated EKF (Gauss-Newton on the prior plus
    likelihood cost, Bell & Cathey 1993), relinearizing ``h`` at the latest iterate
    ``x_j``: ``x_{j+1} = x^- + K_j (y - h(x_j) - H_j (x^- - x_j))``; the covariance uses the
    last gain and Jacobian (evaluated at the second-to-last iterate, the standard IEKF
    choice). All iterates stay in the MRP chart of ``x^-``.

    Args:
        x: ``(..., 6)`` prior states; P: ``(..., 6, 6)`` prior covariances.
        y: ``(3m,)`` measured body-frame vectors (or ``(..., 3m)``).
        ref_vectors_I: ``(m, 3)`` inertial reference directions.
        sigma: Measurement noise standard deviation per component (rad).
        switch: Apply the shadow switch (with covariance mapping) to the result.
        iterations: Maximum number of linearizations, >= 1 (1 = the classic EKF).
        iteration_tolerance: Stop iterating when no state component (whole batch)
            changed by more than this (state units) in the last iteration.

    Returns:
        ``(x_post, P_post, innovation, S)``: the innovation ``y - h(x^-)`` ``(..., 3m)`` and
        its covariance ``S = H P H' + sigma^2 I`` ``(..., 3m, 3m)`` at the prior.
    """
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    U = np.asarray(ref_vectors_I, dtype=float)
    y = np.asarray(y, dtype=float)
    n_meas = 3 * U.shape[0]
    R = sigma ** 2 * np.eye(n_meas)
    x_j = x
    innovation0 = S0 = None
    for _ in range(iterations):
        H = vector_measurement_jacobian(x_j[..., :3], U)
        residual = y - vector_measurement_model(x_j[..., :3], U)
        PHt = P @ np.swapaxes(H, -1, -2)
        S = _sym(H @ PHt + R)
        # K = P H' S^-1  ->  K' = S^-1 H P  (S symmetric)
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
        if innovation0 is None:
            innovation0, S0 = residual, S
        correction = residual - (H @ (x - x_j)[..., :, None])[..., 0]
        x_next = x + (K @ correction[..., :, None])[..., 0]
        converged = np.max(np.abs(x_next - x_j)) <= iteration_tolerance
        x_j = x_next
        if converged:
            break
    IKH = np.eye(6) - K @ H
    P_new = _sym(IKH @ P @ np.swapaxes(IKH, -1, -2) + (K * sigma ** 2) @ np.swapaxes(K, -1, -2))
    x_new = x_j
    if switch:
        x_new, P_new, _ = switch_to_short_mrp(x_new, P_new)
    return x_new, P_new, innovation0, S0


def attitude_to_mrp_covariance(rho, P_att) -> np.ndarray:
    """Map a covariance of ``[dtheta_B (rad); b (rad/s)]`` to ``[rho; b]`` at ``rho``.

    ``drho = B(rho) dtheta`` (first order), ``dtheta`` the body-frame error
    ``q_IB = q_IB_hat ⊗ exp(dtheta / 2)``.
    """
    T = np.zeros(np.shape(rho)[:-1] + (6, 6))
    T[..., :3, :3] = mrp_kinematics_matrix(rho)
    T[..., 3:, 3:] = np.eye(3)
    return _sym(T @ P_att @ np.swapaxes(T, -1, -2))


def mrp_to_attitude_covariance(rho, P) -> np.ndarray:
    """Inverse of :func:`attitude_to_mrp_covariance`: ``[rho; b]`` -> ``[dtheta; b]``."""
    T = np.zeros(np.shape(rho)[:-1] + (6, 6))
    T[..., :3, :3] = mrp_kinematics_inverse(rho)
    T[..., 3:, 3:] = np.eye(3)
    return _sym(T @ P @ np.swapaxes(T, -1, -2))


# ----------------------------------------------------------------------------------
# The filter core
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class MrpEkfState:
    """MRP EKF state: ``x = [rho; b]`` (6, ``|rho| <= 1``) and its covariance ``P`` (6x6, MRP chart)."""

    x: np.ndarray
    P: np.ndarray


class MrpEkfCore(GatedCore):
    """Paper S0's additive EKF on ``x = [rho; b]`` (gyro mode) as a
    :class:`drake_att.contract.FilterCore`: :func:`ekf_predict` and :func:`ekf_update` on an
    immutable :class:`MrpEkfState`.

    ``predict`` takes the step's mean gyro rate (rad/s, held over the step); ``update`` a
    :class:`~drake_att.contract.VectorObservations` sample, rotated into the body frame
    (:func:`body_frame_vectors`); a sample with a missing or non-finite direction, or one
    the innovation gate rejects, is declined (``UpdateInfo.accepted`` false, state
    unchanged). State vector: ``[x (6), P (36, MRP chart, row-major)]``.

    Args:
        arw_rad_per_rt_s: gyro ARW ``sigma_v`` (rad/s^0.5) > 0 (a white-noise std ``s`` per
            sample of period ``T`` is ``s sqrt(T)``).
        rrw_rad_per_s15: gyro RRW ``sigma_u`` (rad/s^1.5) >= 0.
        update_iterations: linearizations per update, >= 1: 1 is the paper's EKF, > 1 the
            iterated EKF (:func:`ekf_update`), which converges from large initial errors.
        innovation_gate_chi2: a chi-square threshold or an
            :class:`~drake_att.filters.gating.InnovationGate`; None: no gate (the paper).
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True
    is_random = False
    state_size = 42

    def __init__(self, arw_rad_per_rt_s: float, rrw_rad_per_s15: float = 0.0, update_iterations: int = 1,
                 innovation_gate_chi2=None):
        self.gate = InnovationGate.of(innovation_gate_chi2)
        self.arw_rad_per_rt_s = check_positive("arw_rad_per_rt_s", arw_rad_per_rt_s)
        self.rrw_rad_per_s15 = check_positive("rrw_rad_per_s15", rrw_rad_per_s15, allow_zero=True)
        self.update_iterations = check_int("update_iterations", update_iterations, 1)

    @staticmethod
    def initial_state(q_IB_hat0, bias_hat0, covariance0) -> MrpEkfState:
        """The state of an attitude ``q_IB_hat0`` (wxyz, normalized), a bias (3, rad/s) and
        the (6, 6) covariance of ``[dtheta_B (rad); b (rad/s)]`` (``q_IB = q_IB_hat ⊗
        exp(dtheta_B / 2)``), mapped to the MRP chart with ``B(rho0)``
        (:func:`attitude_to_mrp_covariance`)."""
        q0 = check_quaternion("q_IB_hat0", q_IB_hat0)
        b0 = check_array("bias_hat0", bias_hat0, (3,), " (rad/s)")
        P_att = check_covariance("covariance0", covariance0, 6)
        rho0 = quat_to_mrp(q0)
        return MrpEkfState(np.concatenate([rho0, b0]), attitude_to_mrp_covariance(rho0, P_att))

    def predict(self, state: MrpEkfState, w_meas_B, dt: float, rng=None) -> MrpEkfState:
        """The state propagated over ``dt`` (s) > 0 with the mean measured rate ``w_meas_B``."""
        dt = check_positive("dt", dt)
        x, P = ekf_predict(state.x, state.P, gyro_rate(w_meas_B), dt, self.arw_rad_per_rt_s, self.rrw_rad_per_s15)
        return MrpEkfState(x, P)

    def update(self, state: MrpEkfState, observations, rng=None) -> tuple[MrpEkfState, UpdateInfo]:
        """Update with a :class:`~drake_att.contract.VectorObservations` sample; the
        ``UpdateInfo`` carries the innovation ``y - h(x^-)``, its covariance and the NIS."""
        y_B, U, sigma = body_frame_vectors(observations)
        if y_B is None:
            return state, UpdateInfo(None, None, float("nan"), False)
        x, P, innov, S = ekf_update(state.x, state.P, y_B, U, sigma, iterations=self.update_iterations)
        nis = float(innov @ np.linalg.solve(S, innov))
        if self.gate.rejects(nis, len(innov)):
            return state, UpdateInfo(innov, S, nis, False)
        return MrpEkfState(x, P), UpdateInfo(innov, S, nis, True)

    def reacquire(self, state, info):
        """The state with its covariance inflated after repeated gate rejections (the rule of
        :mod:`drake_att.filters.gating`, applied by the estimator system)."""
        return inflated(state, reacquire_factor(self.gate, info))

    @staticmethod
    def estimate(state: MrpEkfState):
        """``(q_IB_hat (scalar part >= 0), bias_hat (rad/s), covariance of [dtheta_B; b])``."""
        return mrp_to_quat(state.x[:3]), state.x[3:].copy(), mrp_to_attitude_covariance(state.x[:3], state.P)

    @staticmethod
    def to_vector(state: MrpEkfState) -> np.ndarray:
        return np.concatenate([state.x, np.asarray(state.P).ravel()])

    @staticmethod
    def from_vector(vector) -> MrpEkfState:
        v = np.array(vector, dtype=float)
        return MrpEkfState(v[:6], v[6:42].reshape(6, 6))


def gyro_rate(w_meas_B) -> np.ndarray:
    """The step's mean gyro rate as a finite ``(3,)`` float array (rad/s).

    A core never sees a missing sample (the estimator system holds the last valid rate);
    anything else raises ValueError naming ``w_meas_B``."""
    return check_array("w_meas_B", w_meas_B, (3,), " (rad/s)")
