"""The MEKF's step in readable numpy: the oracle of the compiled kernels.

:mod:`drake_att.filters.mekf_kernels` is the one implementation the library runs; this module
writes the same formulas (Markley & Crassidis 2014, sec. 6.2; docs/derivations/mekf.md) with
numpy matrices, and :class:`ReferenceMEKF` is a :class:`~drake_att.filters.mekf.MultiplicativeEKF`
whose propagation and quaternion update are these. ``tests/test_mekf_kernels.py`` and
``tests/test_compiled_step.py`` compare the two to round-off.
"""

import math

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import UpdateInfo
from drake_att.filters.mekf import MekfState, MultiplicativeEKF, coning_rotation_vector


def process_noise(arw: float, rrw: float, dt: float) -> np.ndarray:
    """Discrete process-noise covariance (6x6) of ``[dtheta; dbias]`` over ``dt``."""
    sv2, su2 = arw**2, rrw**2
    eye = np.eye(3)
    Q = np.zeros((6, 6))
    Q[:3, :3] = (sv2 * dt + su2 * dt**3 / 3.0) * eye
    Q[:3, 3:] = Q[3:, :3] = (-su2 * dt**2 / 2.0) * eye
    Q[3:, 3:] = su2 * dt * eye
    return Q


def transition_matrix(w_hat_B, dt: float) -> np.ndarray:
    """``Phi = [[exp(-[w x] dt), -J], [0, I]]``, ``J = dt I - c1 [w x] + c2 [w x]^2``,
    ``c1 = (1 - cos a) / |w|^2``, ``c2 = (a - sin a) / |w|^3``, ``a = |w| dt`` (series for
    small ``a``); ``exp(-[w x] dt) = I - s1 [w x] + s2 [w x]^2``."""
    w = np.asarray(w_hat_B, dtype=float)
    n2 = float(w @ w)
    wn = math.sqrt(n2)
    a = wn * dt
    if a < 1e-4:
        c1 = dt * dt / 2.0 - n2 * dt**4 / 24.0
        c2 = dt**3 / 6.0 - n2 * dt**5 / 120.0
        s1 = dt - n2 * dt**3 / 6.0
        s2 = dt * dt / 2.0 - n2 * dt**4 / 24.0
    else:
        c1 = (1.0 - math.cos(a)) / n2
        c2 = (a - math.sin(a)) / (n2 * wn)
        s1 = math.sin(a) / wn
        s2 = c1
    K = rot.skew(w)
    K2 = np.outer(w, w) - n2 * np.eye(3)
    Phi = np.eye(6)
    Phi[:3, :3] = np.eye(3) - s1 * K + s2 * K2
    Phi[:3, 3:] = -(dt * np.eye(3) - c1 * K + c2 * K2)
    return Phi


def inverse(S):
    """Inverse of a symmetric positive-definite matrix, or None (Cholesky fails)."""
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None
    return np.linalg.inv(S) if np.all(np.isfinite(S)) else None


class ReferenceMEKF(MultiplicativeEKF):
    """A :class:`MultiplicativeEKF` whose propagation and quaternion update are the numpy
    formulas above (the vector update is the library's, already numpy)."""

    def predict_linearized(self, state: MekfState, w_meas_B, dt: float):
        if dt <= 0:
            return state, np.eye(6), np.zeros((6, 6))
        w_hat = np.asarray(w_meas_B, dtype=float) - state.bias_B
        previous = None
        if self.coning_correction:
            phi, previous = coning_rotation_vector(state.previous_gyro, w_meas_B, state.bias_B, dt)
            w_hat = phi / dt
        else:
            phi = w_hat * dt
        q = rot.quat_normalize(rot.quat_multiply(state.q_IB, rot.rotvec_to_quat(phi)))
        Phi = transition_matrix(w_hat, dt)
        Q = process_noise(self.arw, self.rrw, dt)
        P = Phi @ state.P @ Phi.T + Q
        return MekfState(q, state.bias_B, 0.5 * (P + P.T), previous), Phi, Q

    def update_quaternion(self, state: MekfState, q_IS_meas, q_BS, noise_S):
        noise_S = np.asarray(noise_S, dtype=float)
        R = noise_S if noise_S.shape == (3, 3) else np.diag(noise_S**2)
        H = np.zeros((3, 6))
        H[:, :3] = rot.quat_to_rotmat(q_BS).T
        z = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(rot.quat_multiply(state.q_IB, q_BS)), q_IS_meas))
        P = state.P
        S = H @ P @ H.T + R
        S = 0.5 * (S + S.T)
        S_inv = inverse(S)
        if S_inv is None:
            return state, UpdateInfo(z, S, float("nan"), False)
        nis = float(z @ S_inv @ z)
        if self.gate.rejects(nis, 3):
            return state, UpdateInfo(z, S, nis, False)
        K = P @ H.T @ S_inv
        dx = K @ z
        I_KH = np.eye(6) - K @ H
        P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
        q = rot.quat_normalize(rot.quat_multiply(state.q_IB, rot.rotvec_to_quat(dx[:3])))
        new = MekfState(q, state.bias_B + dx[3:], 0.5 * (P_new + P_new.T), state.previous_gyro)
        return new, UpdateInfo(z, S, nis, True, I_KH)
