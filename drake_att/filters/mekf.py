"""Multiplicative extended Kalman filter (MEKF) for gyro + star-tracker attitude
(Markley & Crassidis 2014, sec. 6.2), no Drake. The propagation, process noise, transition
matrix and quaternion update are the compiled kernels of :mod:`drake_att.filters.mekf_kernels`
(their one implementation); the vector update and the coning correction are numpy.

State: ``q_IB`` (wxyz Hamilton), gyro bias ``bias_B`` (rad/s) and the 6x6 covariance ``P`` of
``x = [dtheta_B (rad); dbias_B (rad/s)]``, truth ``q_IB = q_IB_hat ⊗ exp(dtheta_B)`` (the
project's attitude-error definition) and ``b = b_hat + dbias``.  Gyro: the mean body rate over
the step, ``w_meas = w + b + noise`` (Farrenkopf model, ARW ``sigma_v`` rad/s^0.5, RRW
``sigma_u`` rad/s^1.5).

* :class:`MultiplicativeEKF`: the :class:`drake_att.contract.FilterCore`; updates with a mounted
  star-tracker attitude (residual in the sensor frame) or unit vectors, Joseph form, error reset
  into the reference; opt-in two-sample coning correction (``coning_correction``).
* :class:`MekfState`; :func:`process_noise`, :func:`transition_matrix` (closed-form ``Q`` and
  ``Phi``, also used by other cores), :func:`coning_rotation_vector`,
  :func:`steady_state_covariance` (steady-state Riccati solution).

Derivation and paper notes: docs/derivations/mekf.md
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import QuaternionSample, SecondQuantity, UpdateInfo, VectorObservations
from drake_att.filters import mekf_kernels as _kernels
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
from drake_att.validation import check_nonnegative


@dataclass(frozen=True)
class MekfState:
    """Estimate: attitude ``q_IB`` (4), gyro bias ``bias_B`` (3, rad/s), covariance ``P`` (6x6).

    ``P`` is the covariance of ``[dtheta_B (rad), dbias_B (rad/s)]``.
    ``previous_gyro`` (cores with the coning correction only, else None):
    ``[w_meas_B of the previous step (3, rad/s), its length dt (s)]``, the length 0 when the
    previous step gives no usable increment (start, or a held rate).
    """

    q_IB: np.ndarray
    bias_B: np.ndarray
    P: np.ndarray
    previous_gyro: np.ndarray | None = None

    def attitude_sigma_rad(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P)[:3])


def process_noise(arw: float, rrw: float, dt: float) -> np.ndarray:
    """Discrete process-noise covariance (6x6) of ``[dtheta; dbias]`` over ``dt``
    (:func:`drake_att.filters.mekf_kernels.process_noise`)."""
    Q = np.empty((6, 6))
    _kernels.process_noise(float(arw), float(rrw), float(dt), Q)
    return Q


_EYE6 = np.eye(6)


def transition_matrix(w_hat_B, dt: float) -> np.ndarray:
    """Closed-form state transition (6x6) of ``F = [[-[w x], -I], [0, 0]]`` over ``dt``
    (:func:`drake_att.filters.mekf_kernels.transition`)."""
    wx, wy, wz = np.asarray(w_hat_B, dtype=float).tolist()
    Phi = np.empty((6, 6))
    _kernels.transition(wx, wy, wz, float(dt), Phi)
    return Phi


PREVIOUS_GYRO_SIZE = 4  # [w_meas_B (3), dt] of the previous step (coning correction)


def coning_rotation_vector(previous_gyro, w_meas_B, bias_B, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The step's coning-corrected rotation vector and the new ``previous_gyro`` record.

    ``phi = dtheta + c dtheta_prev x dtheta`` with the bias-corrected increments
    ``dtheta = (w_meas_B - bias_B) dt``, ``dtheta_prev = (w_prev - bias_B) dt_prev`` and
    ``c = dt^2 / (6 dt_prev (dt_prev + dt))`` (1/12 for equal steps: Savage's two-sample
    correction with the previous interval; residual O(dt^4), see docs/derivations/mekf.md).
    No correction without a usable previous increment (``previous_gyro`` None or its length
    0) or when ``w_meas_B`` repeats the previous rate bit for bit (a held rate: the system's
    answer to a missing gyro sample); the returned record then has length 0 for a held rate,
    so the step after it is not corrected either.
    """
    w = np.asarray(w_meas_B, dtype=float)
    dtheta = (w - bias_B) * dt
    held = previous_gyro is not None and bool(np.array_equal(previous_gyro[:3], w))
    phi = dtheta
    if not held and previous_gyro is not None and previous_gyro[3] > 0.0:
        dt_prev = float(previous_gyro[3])
        dtheta_prev = (previous_gyro[:3] - bias_B) * dt_prev
        phi = dtheta + (dt * dt / (6.0 * dt_prev * (dt_prev + dt))) * np.cross(dtheta_prev, dtheta)
    record = np.array([w[0], w[1], w[2], 0.0 if held else float(dt)])
    return phi, record


def _inverse(S):
    """Inverse of a small symmetric positive-definite matrix (3x3: the closed form of
    :func:`drake_att.filters.mekf_kernels.inverse3`), or None if it is not positive definite
    or not finite."""
    if S.shape == (3, 3):
        out = np.empty((3, 3))
        return out if _kernels.inverse3(np.ascontiguousarray(S, dtype=float), out) else None
    try:
        np.linalg.cholesky(S)  # positive definite, or LinAlgError
        return np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return None


class MultiplicativeEKF(GatedCore):
    """MEKF core: :meth:`predict`, :meth:`update_quaternion`, :meth:`update_vectors`.

    Implements :class:`drake_att.contract.FilterCore` (:meth:`update` dispatches on the
    measurement type; the state vector is ``[q_IB (4), bias_B (3), P (36)]``) and publishes
    its step linearization (:meth:`predict_linearized`, ``UpdateInfo.error_transition``).

    Args:
        arw_rad_per_rt_s: filter's gyro ARW ``sigma_v`` (rad/s^0.5) >= 0.
        rrw_rad_per_s15: filter's gyro RRW ``sigma_u`` (rad/s^1.5) >= 0.
        innovation_gate_chi2: reject a measurement whose NIS exceeds this value, or an
            :class:`~drake_att.filters.gating.InnovationGate` (a probability per innovation
            dimension); None: no gate. Rejections are reported in :class:`UpdateInfo`, never
            silent; :meth:`reacquire` inflates the covariance after repeated rejections.
        coning_correction: propagate with the two-sample coning-corrected rotation vector
            (docs/derivations/mekf.md); the state vector then carries the previous step's gyro
            rate and length (``state_size`` 47 instead of 43).
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True
    is_random = False
    state_size = 43  # per instance: 47 with the coning correction

    def __init__(
        self,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        innovation_gate_chi2=None,
        coning_correction: bool = False,
    ):
        self.arw = check_nonnegative("arw", arw_rad_per_rt_s)
        self.rrw = check_nonnegative("rrw", rrw_rad_per_s15)
        self.gate = InnovationGate.of(innovation_gate_chi2)
        if not isinstance(coning_correction, (bool, np.bool_)):
            raise TypeError(f"coning_correction: got {coning_correction!r}; must be true or false")
        self.coning_correction = bool(coning_correction)
        if self.coning_correction:
            self.state_size = 43 + PREVIOUS_GYRO_SIZE
        self._q_cache: dict = {}
        self._model_cache: dict = {}

    def runs_kernel_step(self) -> bool:
        """Whether a step of this core is exactly the kernels' propagation and quaternion
        update (what :mod:`drake_att.systems.compiled_step` runs in one call): no coning
        correction, and no subclass changing the step."""
        cls = type(self)
        return not self.coning_correction and all(
            getattr(cls, name) is getattr(MultiplicativeEKF, name)
            for name in (
                "predict",
                "predict_linearized",
                "process_noise",
                "update",
                "update_quaternion",
                "reacquire",
                "ungated",
                "add_attitude_variance",
            )
        )

    def process_noise(self, dt: float) -> np.ndarray:
        """:func:`process_noise` for this filter's gyro model (cached per ``dt``)."""
        Q = self._q_cache.get(dt)
        if Q is None:
            if len(self._q_cache) > 64:
                self._q_cache.clear()
            Q = self._q_cache[dt] = process_noise(self.arw, self.rrw, dt)
        return Q

    def initial_state(self, q_IB, bias_B, attitude_sigma_rad, bias_sigma_rad_per_s) -> MekfState:
        """State with diagonal covariance from per-axis (or scalar) 1-sigmas (and, with the
        coning correction, no previous gyro increment)."""
        P = np.diag(
            np.concatenate(
                [np.broadcast_to(attitude_sigma_rad, 3) ** 2, np.broadcast_to(bias_sigma_rad_per_s, 3) ** 2]
            ).astype(float)
        )
        previous = np.zeros(PREVIOUS_GYRO_SIZE) if self.coning_correction else None
        return MekfState(rot.quat_normalize(q_IB), np.asarray(bias_B, dtype=float).copy(), P, previous)

    def predict(self, state: MekfState, w_meas_B, dt: float, rng=None) -> MekfState:
        """Propagate over ``dt`` (s) with the step's mean measured rate ``w_meas_B`` (rad/s)."""
        return self.predict_linearized(state, w_meas_B, dt)[0]

    def update(self, state: MekfState, measurement, rng=None) -> tuple[MekfState, UpdateInfo]:
        """Update with a :class:`~drake_att.contract.QuaternionSample` or
        :class:`~drake_att.contract.VectorObservations` (the contract's entry point)."""
        if isinstance(measurement, QuaternionSample):
            return self.update_quaternion(state, measurement.q_IS_meas, measurement.q_BS, measurement.covariance_S)
        if isinstance(measurement, VectorObservations):
            return self.update_vectors(
                state,
                np.asarray(measurement.directions_S),
                measurement.references_I,
                measurement.sigma_rad,
                measurement.q_BS,
            )
        raise TypeError(
            f"MultiplicativeEKF.update: got a {type(measurement).__name__}; "
            "allowed: QuaternionSample, VectorObservations"
        )

    def reacquire(self, state, info):
        """The state with its covariance inflated after repeated gate rejections (the rule of
        :mod:`drake_att.filters.gating`, applied by the estimator system)."""
        return inflated(state, reacquire_factor(self.gate, info))

    def recover_prediction(self, state: MekfState, measurement, info: UpdateInfo, period_s: float) -> MekfState:
        """The state after a gate rejection of a sample the sensor monitor confirmed: the
        prediction is what is wrong (a gyro fault or a bias jump), applied by the estimator
        system before it retries the sample with :meth:`ungated`.

        The attitude block is inflated as :meth:`reacquire` does (the rejected innovation at
        half the gate); each bias variance grows by ``(dtheta_B_i / period_s)^2``, where
        ``dtheta_B`` is the rejected innovation as a body-frame rotation (quaternion sample:
        ``R_BS z_S``; vectors: the least-squares rotation of ``z = H_theta dtheta_B``): the
        rate error that would make that rotation in one filter step ``period_s`` (s).
        """
        new = inflated(state, reacquire_factor(self.gate, info))
        dtheta_B = self._innovation_rotation_B(state, measurement, info)
        P = np.array(new.P, dtype=float)
        P[3:, 3:] += np.diag((dtheta_B / float(period_s)) ** 2)
        return replace(new, P=P)

    @staticmethod
    def _innovation_rotation_B(state: MekfState, measurement, info: UpdateInfo) -> np.ndarray:
        """The rejected innovation of ``measurement`` as a body-frame rotation vector (rad)."""
        z = np.asarray(info.innovation, dtype=float)
        if isinstance(measurement, QuaternionSample):
            return rot.quat_to_rotmat(measurement.q_BS) @ z  # R_BS z_S
        R_SB = rot.quat_to_rotmat(measurement.q_BS).T
        b_B = np.asarray(measurement.references_I, dtype=float) @ rot.quat_to_rotmat(state.q_IB)
        H = (R_SB @ rot.skew(b_B)).reshape(-1, 3)
        return np.linalg.lstsq(H, z, rcond=None)[0]

    @staticmethod
    def add_attitude_variance(state: MekfState, variance_rad2: float) -> MekfState:
        """The state with ``variance_rad2`` (rad^2) added to each attitude variance (the drift
        of a held gyro rate, :class:`drake_att.contract.AttitudeProcessNoise`)."""
        P = np.array(state.P, dtype=float)
        for k in range(3):
            P[k, k] += variance_rad2
        return replace(state, P=P)

    @staticmethod
    def estimate(state: MekfState):
        """``(q_IB, bias_B, P)`` of the state."""
        return state.q_IB, state.bias_B, state.P

    @staticmethod
    def to_vector(state: MekfState) -> np.ndarray:
        """``[q_IB (4, scalar part >= 0), bias_B (3), P (36, row-major)]``, then
        ``previous_gyro`` (4) if the state has one (coning correction)."""
        parts = [rot.quat_canonical(state.q_IB), state.bias_B, np.asarray(state.P).ravel()]
        if state.previous_gyro is not None:
            parts.append(state.previous_gyro)
        return np.concatenate(parts)

    @staticmethod
    def from_vector(vector) -> MekfState:
        """Inverse of :meth:`to_vector` (the length tells whether there is a ``previous_gyro``:
        43 without, 47 with)."""
        v = np.asarray(vector, dtype=float)  # read-only use: every step returns new arrays
        if v.shape == (43,):
            return MekfState(v[:4], v[4:7], v[7:43].reshape(6, 6))
        if v.shape == (43 + PREVIOUS_GYRO_SIZE,):
            return MekfState(v[:4], v[4:7], v[7:43].reshape(6, 6), v[43:])
        raise ValueError(f"MEKF state vector: got shape {v.shape}; need (43,) or ({43 + PREVIOUS_GYRO_SIZE},)")

    def predict_linearized(self, state: MekfState, w_meas_B, dt: float):
        """:meth:`predict`, also returning the step's ``Phi`` and ``Q`` (6x6 each).

        The error obeys ``e_k = Phi e_{k-1} + w`` with ``cov(w) = Q``; estimators that share
        the gyro share ``w`` (used by the decentralized fusion's cross-covariance).
        """
        if dt <= 0:
            return state, _EYE6, np.zeros((6, 6))
        w_hat = np.asarray(w_meas_B, dtype=float) - state.bias_B
        previous = None
        if self.coning_correction:
            phi, previous = coning_rotation_vector(state.previous_gyro, w_meas_B, state.bias_B, dt)
            w_hat = phi / dt  # the constant rate that makes the corrected rotation
        else:
            phi = w_hat * dt
        Q = self.process_noise(dt)
        q, P, Phi = np.empty(4), np.empty((6, 6)), np.empty((6, 6))
        _kernels.predict(
            np.asarray(state.q_IB, dtype=float), np.asarray(state.P, dtype=float), w_hat, phi, float(dt), Q, q, P, Phi
        )
        return MekfState(q, state.bias_B, P, previous), Phi, Q

    def _update(self, state: MekfState, z, H, R):
        P = state.P
        PHt = P @ H.T
        S = H @ PHt + R
        S = 0.5 * (S + S.T)
        S_inv = _inverse(S)
        if S_inv is None:
            return state, UpdateInfo(z, S, float("nan"), False)
        nis = float(z @ S_inv @ z)
        if self.gate.rejects(nis, len(z)):
            return state, UpdateInfo(z, S, nis, False)
        K = PHt @ S_inv
        dx = K @ z
        I_KH = _EYE6 - K @ H
        P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
        q = rot.quat_normalize(rot.quat_multiply(state.q_IB, rot.rotvec_to_quat(dx[:3])))
        new = MekfState(q, state.bias_B + dx[3:], 0.5 * (P_new + P_new.T), state.previous_gyro)
        return new, UpdateInfo(z, S, nis, True, I_KH)

    def update_quaternion(self, state: MekfState, q_IS_meas, q_BS, noise_S) -> tuple[MekfState, UpdateInfo]:
        """Update with a measured sensor attitude ``q_IS_meas``.

        ``noise_S``: per-axis sigmas (3,) in rad, or a full 3x3 covariance (rad^2), of the
        measurement's rotation-vector error in the sensor frame.
        """
        R, R_SB = self._quaternion_model(q_BS, noise_S)
        q, b, P = np.empty(4), np.empty(3), np.empty((6, 6))
        z, S, I_KH = np.empty(3), np.empty((3, 3)), np.empty((6, 6))
        outcome, nis = _kernels.update_quaternion(
            np.asarray(state.q_IB, dtype=float),
            np.asarray(state.bias_B, dtype=float),
            np.asarray(state.P, dtype=float),
            np.asarray(q_IS_meas, dtype=float),
            np.asarray(q_BS, dtype=float),
            R_SB,
            R,
            self.gate.threshold(3),
            q,
            b,
            P,
            z,
            S,
            I_KH,
        )
        if outcome != _kernels.ACCEPTED:
            return state, UpdateInfo(z, S, nis, False)
        return MekfState(q, b, P, state.previous_gyro), UpdateInfo(z, S, nis, True, I_KH)

    def _quaternion_model(self, q_BS, noise_S):
        """``R`` and ``R_SB`` of a mounted quaternion sensor (cached per sensor)."""
        q_BS = np.asarray(q_BS, dtype=float)
        noise_S = np.asarray(noise_S, dtype=float)
        key = (q_BS.tobytes(), noise_S.tobytes())
        model = self._model_cache.get(key)
        if model is None:
            R = np.ascontiguousarray(noise_S if noise_S.shape == (3, 3) else np.diag(noise_S**2))
            if len(self._model_cache) > 64:
                self._model_cache.clear()
            model = self._model_cache[key] = (R, np.ascontiguousarray(rot.quat_to_rotmat(q_BS).T))
        return model

    def update_vectors(
        self, state: MekfState, directions_S, references_I, sigma_rad: float, q_BS=(1.0, 0.0, 0.0, 0.0)
    ) -> tuple[MekfState, UpdateInfo]:
        """Update with ``m`` measured directions (m, 3) of inertial references (m, 3)."""
        directions_S = np.asarray(directions_S, dtype=float)
        references_I = np.asarray(references_I, dtype=float)
        R_SB = rot.quat_to_rotmat(q_BS).T
        R_BI = rot.quat_to_rotmat(state.q_IB).T
        b_B = references_I @ R_BI.T  # predicted body-frame directions (m, 3)
        m = b_B.shape[0]
        z = (directions_S - b_B @ R_SB.T).ravel()
        H = np.zeros((3 * m, 6))
        H[:, :3] = (R_SB @ rot.skew(b_B)).reshape(3 * m, 3)
        R = (sigma_rad**2) * np.eye(3 * m)
        return self._update(state, z, H, R)


def steady_state_covariance(
    Phi, Q, H, R, max_iterations: int = 100, rtol: float = 1e-13
) -> tuple[np.ndarray, np.ndarray]:
    """A-priori and a-posteriori steady-state covariances of an LTI Kalman filter.

    Solves the filter Riccati equation ``P = Phi P Phi' - Phi P H' (H P H' + R)^-1 H P Phi' + Q``
    with the structure-preserving doubling algorithm (Chu, Fan, Lin & Wang 2004), which
    converges quadratically; each doubling step squares the horizon of the recursion, so
    ~50 steps reach any time scale of a stabilizable, detectable system. Stops when every
    entry moves less than ``rtol`` times ``sqrt(P_ii P_jj)`` (relative: covariances of
    1e-14 rad^2 converge as well as O(1) ones). Tests compare with scipy's DARE.

    Returns:
        ``(P_prior, P_post)`` with ``P_post = (I - K H) P_prior``.

    Raises:
        ValueError: if the doubling does not converge in ``max_iterations`` steps (the pair
            is not stabilizable/detectable, or the inputs are not finite).
    """
    Phi, Q, H, R = (np.asarray(x, dtype=float) for x in (Phi, Q, H, R))
    n = Phi.shape[0]
    eye = np.eye(n)
    A = Phi.T
    G = H.T @ np.linalg.solve(R, H)
    X = Q.copy()
    for _ in range(max_iterations):
        W_inv_A = np.linalg.solve(eye + G @ X, A)
        A_next = A @ W_inv_A
        G_next = G + A @ np.linalg.solve(eye + G @ X, G) @ A.T
        X_next = X + A.T @ X @ W_inv_A
        X_next = 0.5 * (X_next + X_next.T)
        d = np.sqrt(np.maximum(np.abs(np.diag(X_next)), np.finfo(float).tiny))
        converged = np.max(np.abs(X_next - X) / np.outer(d, d)) <= rtol
        A, G, X = A_next, 0.5 * (G_next + G_next.T), X_next
        if converged:
            break
    else:
        raise ValueError(
            f"steady_state_covariance: no convergence in max_iterations={max_iterations} "
            "doubling steps (is (Phi, H) detectable and (Phi, Q) stabilizable?)"
        )
    if not np.all(np.isfinite(X)):
        raise ValueError("steady_state_covariance: non-finite solution (check Phi, Q, H, R)")
    P = X
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    return P, (eye - K @ H) @ P


__all__ = [
    "MekfState",
    "UpdateInfo",
    "MultiplicativeEKF",
    "process_noise",
    "transition_matrix",
    "coning_rotation_vector",
    "steady_state_covariance",
    "PREVIOUS_GYRO_SIZE",
]
