"""Additive quaternion EKF: the baseline of paper S4 (Xu, Pei & Jiang 2020), gyro + stars.

Plain numpy (no Drake).  State: the 4 components of ``q_IB`` (wxyz, Hamilton; body B in
inertial I, ``v_I = R(q_IB) v_B``) with the 4x4 covariance ``P_q`` of the *additive* error
``q_true - q_hat``; no gyro-bias state.  Second quantity: the gyro's mean body rate of the last
predict (rad/s) with its error covariance.  Paper defaults: ``q0 = [1, 0, 0, 0]``, ``P0 = I4``,
``Q = 1e-5 I4`` (per 1 s step), ``R = 0.01 I4`` (a quaternion-noise figure).

* :class:`AdditiveQuaternionEKF`: the :class:`drake_att.contract.FilterCore`: closed-form
  quaternion predict; update with the quaternion of the Wahba solution of ``m >= 2`` star
  directions (``H = I4``, Joseph form), then ``q / |q|``.
* :class:`QuaternionEkfState`; :func:`wahba_quaternion`, :func:`transition_matrix`,
  :func:`right_matrix`, :func:`xi_matrix`.

The published covariance is that of ``[dtheta_B; w_true - w_hat]`` with the project's error
``q_IB = q_hat ⊗ exp(dtheta_B)``, mapped to first order (``P_theta = 4 G P_q G'``).

Derivation and paper notes: docs/derivations/quaternion_ekf.md
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import SecondQuantity, UpdateInfo, VectorObservations
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
from drake_att.filters.lie_group import DEFAULT_INITIAL_RATE_SIGMA, _solve_spd, rate_error_model
from drake_att.validation import check_nonnegative, check_positive, check_quaternion, check_variance_matrix

_EYE4 = np.eye(4)
# References this close to collinear fix no attitude: the ratio of the references' two largest
# singular values (for two unit references, tan of half the angle between them) at or below it.
COLLINEAR_SINE = 1e-6


@dataclass(frozen=True)
class QuaternionEkfState:
    """Estimate of :class:`AdditiveQuaternionEKF`.

    Attributes:
        q_IB: (4,) unit quaternion (wxyz) of body B in inertial I.
        P: (4, 4) covariance of the additive error ``q_true - q_IB``.
        w_B: (3,) last gyro mean rate used by predict (rad/s).
        P_w: (3, 3) covariance of the rate error ``w_true - w_B`` ((rad/s)^2).
        C_q: (4, 3) cross covariance ``cov(q_true - q_IB, w_true - w_B)``.
    """

    q_IB: np.ndarray
    P: np.ndarray
    w_B: np.ndarray
    P_w: np.ndarray
    C_q: np.ndarray


def right_matrix(p) -> np.ndarray:
    """``[p]_R`` with ``q ⊗ p = [p]_R q``."""
    w, x, y, z = np.asarray(p, dtype=float).tolist()
    return np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])


def xi_matrix(q) -> np.ndarray:
    """``Xi(q)`` (4x3) with ``q ⊗ [0, v] = Xi(q) v``."""
    w, x, y, z = np.asarray(q, dtype=float).tolist()
    return np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])


def transition_matrix(w_B, dt: float) -> np.ndarray:
    """``Phi`` (4x4) with ``q(t + dt) = Phi q(t)`` for the constant body rate ``w_B`` (rad/s)."""
    return right_matrix(rot.rotvec_to_quat(np.asarray(w_B, dtype=float) * dt))


def wahba_quaternion(directions_B, references_I) -> np.ndarray | None:
    """``q_IB`` best fitting ``b_i = R_IB' r_i`` (equal weights; SVD solution of Wahba's
    problem), or None if fewer than two non-collinear, finite, non-zero references."""
    b = np.atleast_2d(np.asarray(directions_B, dtype=float))
    r = np.atleast_2d(np.asarray(references_I, dtype=float))
    if b.shape != r.shape or b.shape[0] < 2 or not (np.all(np.isfinite(b)) and np.all(np.isfinite(r))):
        return None
    nb, nr = np.linalg.norm(b, axis=1), np.linalg.norm(r, axis=1)
    if np.any(nb < 1e-12) or np.any(nr < 1e-12):
        return None
    b, r = b / nb[:, None], r / nr[:, None]
    sv_r = np.linalg.svd(r, compute_uv=False)  # two non-collinear references <=> sv_r[1] > 0
    if sv_r[1] <= COLLINEAR_SINE * sv_r[0]:
        return None
    U, s, Vt = np.linalg.svd(b.T @ r)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    R_BI = U @ np.diag([1.0, 1.0, d]) @ Vt
    return rot.rotmat_to_quat(R_BI.T)


class AdditiveQuaternionEKF(GatedCore):
    """Additive quaternion EKF core (paper S4's baseline); a
    :class:`drake_att.contract.FilterCore`.

    State vector: ``[q_IB (4), P (16), w_B (3), P_w (9), C_q (12)]`` (44).

    Args:
        Q: quaternion process noise per step of length ``step_s`` (scalar variance or 4x4).
            Paper: ``1e-5``.
        R: quaternion measurement noise (scalar variance or 4x4).  Paper: ``0.01``.
        step_s: the step length ``Q`` refers to (s), default 1.
        gyro_arw_rad_per_rt_s: gyro angle random walk (rad/s^0.5) or None
            (docs/derivations/quaternion_ekf.md).
        innovation_gate_chi2: reject updates whose NIS exceeds this value (None: no gate).
    """

    second_quantity = SecondQuantity.BODY_RATE
    uses_gyro = True
    is_random = False
    state_size = 44

    def __init__(
        self, Q=1e-5, R=0.01, step_s: float = 1.0, gyro_arw_rad_per_rt_s: float | None = None, innovation_gate_chi2=None
    ):
        self.Q = check_variance_matrix("Q", Q, 4)
        self.R = check_variance_matrix("R", R, 4)
        self.step_s = check_positive("step_s", step_s)
        self.arw = (
            None if gyro_arw_rad_per_rt_s is None else check_nonnegative("gyro_arw_rad_per_rt_s", gyro_arw_rad_per_rt_s)
        )
        self.gate = InnovationGate.of(innovation_gate_chi2)

    @staticmethod
    def initial_state(
        q_IB=(1.0, 0.0, 0.0, 0.0), P0=1.0, initial_rate_sigma: float = DEFAULT_INITIAL_RATE_SIGMA
    ) -> QuaternionEkfState:
        """State from ``q_IB`` (4, normalized) and ``P0`` (scalar variance or 4x4); paper:
        ``[1, 0, 0, 0]`` and ``I4``.  The rate block starts at 0 with ``initial_rate_sigma``."""
        q = check_quaternion("q_IB", q_IB)
        check_positive("initial_rate_sigma", initial_rate_sigma)
        return QuaternionEkfState(
            q, check_variance_matrix("P0", P0, 4), np.zeros(3), initial_rate_sigma**2 * np.eye(3), np.zeros((4, 3))
        )

    @staticmethod
    def to_vector(state: QuaternionEkfState) -> np.ndarray:
        return np.concatenate([state.q_IB, np.ravel(state.P), state.w_B, np.ravel(state.P_w), np.ravel(state.C_q)])

    @staticmethod
    def from_vector(vector) -> QuaternionEkfState:
        v = np.asarray(vector, dtype=float)
        if v.shape != (44,):
            raise ValueError(f"AdditiveQuaternionEKF state vector: got shape {v.shape}; need (44,)")
        return QuaternionEkfState(
            v[0:4], v[4:20].reshape(4, 4), v[20:23], v[23:32].reshape(3, 3), v[32:44].reshape(4, 3)
        )

    def reacquire(self, state, info):
        """The state with its covariance inflated after repeated gate rejections (the rule of
        :mod:`drake_att.filters.gating`, applied by the estimator system)."""
        return inflated(state, reacquire_factor(self.gate, info), n=4)  # P: the quaternion's 4x4

    @staticmethod
    def estimate(state: QuaternionEkfState):
        """``(q_IB_hat, w_IB_B_hat, 6x6 covariance of [dtheta_B; w_true - w_hat])`` with
        ``P_theta = 4 G P_q G'`` and cross ``2 G C_q`` (docs/derivations/quaternion_ekf.md)."""
        q = rot.quat_normalize(state.q_IB)
        G = xi_matrix(q).T
        P6 = np.empty((6, 6))
        P_theta = 4.0 * G @ state.P @ G.T
        P6[:3, :3] = 0.5 * (P_theta + P_theta.T)
        P6[:3, 3:] = 2.0 * G @ state.C_q
        P6[3:, :3] = P6[:3, 3:].T
        P6[3:, 3:] = state.P_w
        return q, np.array(state.w_B, dtype=float), P6

    def process_noise(self, q_IB, dt: float) -> np.ndarray:
        """Quaternion process noise of a predict over ``dt`` at ``q_IB`` (4x4)."""
        Q = self.Q * (dt / self.step_s)
        if self.arw:
            Xi = xi_matrix(q_IB)
            Q = Q + (0.25 * self.arw**2 * dt) * (Xi @ Xi.T)
        return Q

    def predict(self, state: QuaternionEkfState, w_meas_B, dt: float, rng=None) -> QuaternionEkfState:
        """Propagate over ``dt`` (s) with the gyro's mean rate ``w_meas_B`` (rad/s, body)."""
        if not dt > 0.0:
            return state
        w = np.zeros(3) if w_meas_B is None else np.asarray(w_meas_B, dtype=float).copy()
        Phi = transition_matrix(w, dt)
        q = Phi @ state.q_IB
        Q = self.process_noise(q, dt)
        P = Phi @ state.P @ Phi.T + Q
        Xi = xi_matrix(q)
        P_w, _ = rate_error_model(4.0 * Xi.T @ Q @ Xi, self.arw, dt)
        C_q = 0.5 * Xi @ P_w * dt
        return QuaternionEkfState(q, 0.5 * (P + P.T), w, P_w, C_q)

    def update(self, state: QuaternionEkfState, measurement, rng=None) -> tuple[QuaternionEkfState, UpdateInfo]:
        """Update with a :class:`~drake_att.contract.VectorObservations` (m >= 2 stars)."""
        if not isinstance(measurement, VectorObservations):
            raise TypeError(
                f"AdditiveQuaternionEKF.update: got a {type(measurement).__name__}; allowed: VectorObservations"
            )
        R_BS = rot.quat_to_rotmat(measurement.q_BS)
        d_S = np.atleast_2d(np.asarray(measurement.directions_S, dtype=float))
        q_meas = wahba_quaternion(d_S @ R_BS.T, measurement.references_I)
        if q_meas is None:
            return state, UpdateInfo(None, None, float("nan"), False)
        q_hat = state.q_IB
        if float(q_meas @ q_hat) < 0.0:
            q_meas = -q_meas
        return self.update_quaternion(state, q_meas)

    def update_quaternion(self, state: QuaternionEkfState, q_meas) -> tuple[QuaternionEkfState, UpdateInfo]:
        """Update with a measured ``q_IB`` (4; used as given: align its sign first)."""
        z = np.asarray(q_meas, dtype=float) - state.q_IB
        P = state.P
        S = 0.5 * (P + P.T) + self.R
        sol = _solve_spd(S, np.column_stack([P, z]))  # [S^-1 P, S^-1 z]
        if sol is None:
            return state, UpdateInfo(z, S, float("nan"), False)
        nis = float(z @ sol[:, 4])
        if self.gate.rejects(nis, len(z)):
            return state, UpdateInfo(z, S, nis, False)
        K = sol[:, :4].T  # P S^-1
        I_K = _EYE4 - K
        P_new = I_K @ P @ I_K.T + K @ self.R @ K.T
        q = state.q_IB + K @ z
        n = math.sqrt(float(q @ q))
        if not (math.isfinite(n) and n > 0.0):
            return state, UpdateInfo(z, S, nis, False)
        new = QuaternionEkfState(q / n, 0.5 * (P_new + P_new.T), state.w_B, state.P_w, I_K @ state.C_q)
        return new, UpdateInfo(z, S, nis, True)


__all__ = [
    "QuaternionEkfState",
    "AdditiveQuaternionEKF",
    "wahba_quaternion",
    "transition_matrix",
    "right_matrix",
    "xi_matrix",
]
