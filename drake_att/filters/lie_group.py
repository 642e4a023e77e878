"""Lie-group (SO(3)) Kalman filter of paper S4 (Xu, Pei & Jiang 2020): gyro + star vectors.

Plain numpy (no Drake).  State: the attitude ``R_IB`` (body B in inertial I, ``v_I = R_IB v_B``;
published as ``q_IB``, wxyz Hamilton) and the 3x3 covariance ``P`` (rad^2) of the body-frame
error ``dtheta_B``, ``R_IB = R_IB_hat exp([dtheta_B x])``.  Second quantity: the gyro's mean
body rate of the last predict (rad/s, not estimated) with its honest error covariance; with
``estimate_gyro_bias=True`` (beyond the paper) the gyro bias (rad/s), error state SO(3) x R^3.

* :class:`LieGroupFilter`: the :class:`drake_att.contract.FilterCore`, updated with star
  vectors (:class:`~drake_att.contract.VectorObservations`) or a star-tracker attitude
  (:class:`~drake_att.contract.QuaternionSample`); ``formulation="consistent"`` (default) or
  ``"paper_literal"`` (eqs 26-32 as printed: not consistent, star vectors only).
* :class:`LieGroupState`, :class:`LieGroupBiasState`: its states; :func:`rate_error_model`: the
  rate block; :func:`orthonormalize`: keeps ``R_IB`` a rotation.

Conventions: the paper's ``X`` is read as ``R_BI = R_IB'``; gyro rate ``w_IB_B`` (rad/s, body);
star directions in the sensor frame of a tracker mounted by ``q_BS``; ``Q_w``, ``Q_v`` in rad^2.
With a bias state and ``Q_w = 0`` this filter is the MEKF (:mod:`drake_att.filters.mekf`).

Derivation and paper notes: docs/derivations/lie_group.md
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import QuaternionSample, SecondQuantity, UpdateInfo, VectorObservations
from drake_att.filters import mekf as _mekf
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
from drake_att.validation import check_array, check_nonnegative, check_positive, check_variance_matrix, fail

FORMULATIONS = ("consistent", "paper_literal")
_EYE3 = np.eye(3)
_EYE6 = np.eye(6)
DEFAULT_Q_W = 5e-5  # rad^2 per step: the paper's Q_w (no bias state)
STATE_SIZE_NO_BIAS = 39
STATE_SIZE_BIAS = 48
DEFAULT_INITIAL_RATE_SIGMA = 1.0  # rad/s: the rate block before any gyro sample
SINGULAR_PIVOT = 1e-14  # innovation covariances with a smaller relative Cholesky pivot are singular


@dataclass(frozen=True)
class LieGroupState:
    """Estimate of :class:`LieGroupFilter`.

    Attributes:
        R_IB: (3, 3) attitude, body B in inertial I (``v_I = R_IB v_B``).
        P: (3, 3) covariance of ``dtheta_B`` (rad^2), ``R_IB = R_IB_hat exp([dtheta_B x])``.
        w_B: (3,) last gyro mean rate used by predict (rad/s), the published body rate.
        P_w: (3, 3) covariance of the rate error ``w_true - w_B`` ((rad/s)^2).
        C: (3, 3) cross covariance ``cov(dtheta_B, w_true - w_B)`` (rad^2/s).
    """

    R_IB: np.ndarray
    P: np.ndarray
    w_B: np.ndarray
    P_w: np.ndarray
    C: np.ndarray

    def attitude_sigma_rad(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P))


@dataclass(frozen=True)
class LieGroupBiasState:
    """Estimate of :class:`LieGroupFilter` with ``estimate_gyro_bias`` (error state SO(3) x R^3).

    Attributes:
        R_IB: (3, 3) attitude, body B in inertial I.
        bias_B: (3,) gyro-bias estimate (rad/s), ``b = bias_B + dbias``.
        P: (6, 6) covariance of ``[dtheta_B (rad); dbias_B (rad/s)]``.
    """

    R_IB: np.ndarray
    bias_B: np.ndarray
    P: np.ndarray

    def attitude_sigma_rad(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P)[:3])

    def bias_sigma_rad_per_s(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P)[3:])


def orthonormalize(R) -> np.ndarray:
    """One Newton step of the polar decomposition, ``R (3 I - R'R) / 2``: removes the
    O(eps) drift from orthogonality that products of rotation matrices accumulate."""
    R = np.asarray(R, dtype=float)
    return R @ (1.5 * _EYE3 - 0.5 * (R.T @ R))


def rate_error_model(Q_step, arw: float | None, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(cov(e_w), cov(dtheta, e_w))`` right after a predict over ``dt`` (s).

    ``Q_step``: the attitude process noise added by that predict (rad^2, 3x3, body frame).
    With a gyro ARW ``N`` (rad/s^0.5): ``N^2/dt I`` and ``N^2 I``; without (None):
    ``Q_step/dt^2`` and ``Q_step/dt`` (the whole step noise read as integrated rate error).
    Both follow from ``dtheta <- A' dtheta + e_w dt`` with ``e_w`` independent of the prior.
    """
    if arw is not None and arw > 0.0:
        v = arw * arw
        return (v / dt) * _EYE3, v * _EYE3
    return Q_step / (dt * dt), Q_step / dt


def _solve_spd(S, B):
    """``S^-1 B`` for a symmetric positive-definite ``S``, or None (not PD / not finite).

    Positive definiteness is checked by a Cholesky factorization (every pivot must exceed
    :data:`SINGULAR_PIVOT` times the largest); the solve itself is an LU
    solve, which keeps the gain accurate when ``S`` is ill-conditioned (a prior far wider
    than the measurement noise: the explicit inverse from the Cholesky factor loses ~3
    orders of magnitude more there).
    """
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(B))):
        return None
    try:
        pivots = np.diag(np.linalg.cholesky(S)) ** 2
    except np.linalg.LinAlgError:
        return None
    if not pivots.min() > SINGULAR_PIVOT * pivots.max():
        return None  # numerically singular (rounding left a ~1e-17 relative pivot)
    return np.linalg.solve(S, B)


def _sensor_directions(measurement: VectorObservations) -> tuple[np.ndarray, np.ndarray]:
    """``(directions_S (m, 3), R_SB (3, 3))`` of a star-tracker sample, ``R_SB = R(q_BS)'``."""
    return np.atleast_2d(np.asarray(measurement.directions_S, dtype=float)), rot.quat_to_rotmat(measurement.q_BS).T


class LieGroupFilter(GatedCore):
    """Lie-group filter core (paper S4); implements :class:`drake_att.contract.FilterCore`.

    Without a bias state (default): state vector ``[R_IB (9, row-major), P (9), w_B (3),
    P_w (9), C (9)]`` (39), second quantity the body rate.  With ``estimate_gyro_bias``:
    :class:`LieGroupBiasState`, vector ``[R_IB (9), bias_B (3), P (36)]`` (48), second
    quantity the gyro bias.  ``second_quantity`` and ``state_size`` are per instance (the
    class attributes are the no-bias values).

    Args:
        Q_w: attitude process noise per step of length ``step_s`` (rad^2; scalar or 3x3,
            body frame).  None (default): the paper's ``5e-5`` without a bias state, 0 with
            one (the gyro model then carries the process noise).
        Q_v: per-component star-direction variance (rad^2) or None to use each
            measurement's ``sigma_rad^2``.  Paper: ``0.125**2``.  Not used by quaternion
            measurements (they carry their covariance).
        formulation: "consistent" (default) or "paper_literal" (see docs/derivations/lie_group.md);
            the bias state and quaternion measurements need "consistent".
        step_s: the step length ``Q_w`` refers to (s), default 1.
        gyro_arw_rad_per_rt_s: gyro angle random walk (rad/s^0.5) or None; adds
            ``arw^2 dt I`` to the process noise (without a bias state it also sets the rate
            block, docs/derivations/lie_group.md).
        innovation_gate_chi2: reject updates whose NIS exceeds this value (None: no gate).
        estimate_gyro_bias: add the gyro-bias error state (SO(3) x R^3,
            docs/derivations/lie_group.md).
        gyro_rrw_rad_per_s15: gyro rate random walk (rad/s^1.5), bias state only (None: 0).
    """

    second_quantity = SecondQuantity.BODY_RATE
    uses_gyro = True
    is_random = False
    state_size = STATE_SIZE_NO_BIAS

    def __init__(
        self,
        Q_w=None,
        Q_v=None,
        formulation: str = "consistent",
        step_s: float = 1.0,
        gyro_arw_rad_per_rt_s: float | None = None,
        innovation_gate_chi2=None,
        estimate_gyro_bias: bool = False,
        gyro_rrw_rad_per_s15: float | None = None,
    ):
        if formulation not in FORMULATIONS:
            fail("formulation", formulation, f"allowed: {list(FORMULATIONS)}")
        check_positive("step_s", step_s)
        for name, value in (
            ("Q_v", Q_v),
            ("gyro_arw_rad_per_rt_s", gyro_arw_rad_per_rt_s),
            ("gyro_rrw_rad_per_s15", gyro_rrw_rad_per_s15),
        ):
            if value is not None:
                check_nonnegative(name, value)
        if not isinstance(estimate_gyro_bias, (bool, np.bool_)):
            fail("estimate_gyro_bias", estimate_gyro_bias, "must be True or False")
        if estimate_gyro_bias and formulation != "consistent":
            fail(
                "estimate_gyro_bias",
                True,
                f"with formulation={formulation!r}: the bias state needs "
                "formulation='consistent' (the paper's literal pairing does not converge)",
            )
        if gyro_rrw_rad_per_s15 is not None and not estimate_gyro_bias:
            fail(
                "gyro_rrw_rad_per_s15",
                gyro_rrw_rad_per_s15,
                "the rate random walk is modelled only with estimate_gyro_bias=True",
            )
        self.estimate_gyro_bias = bool(estimate_gyro_bias)
        if Q_w is None:
            Q_w = 0.0 if self.estimate_gyro_bias else DEFAULT_Q_W
        self.Q_w = check_variance_matrix("Q_w", Q_w, 3)
        self.Q_v = None if Q_v is None else float(Q_v)
        self.formulation = formulation
        self.step_s = float(step_s)
        self.arw = None if gyro_arw_rad_per_rt_s is None else float(gyro_arw_rad_per_rt_s)
        self.rrw = None if gyro_rrw_rad_per_s15 is None else float(gyro_rrw_rad_per_s15)
        self.gate = InnovationGate.of(innovation_gate_chi2)
        if self.estimate_gyro_bias:
            self.second_quantity = SecondQuantity.GYRO_BIAS
            self.state_size = STATE_SIZE_BIAS
        self._q_cache: dict = {}

    # -- construction and the state vector --------------------------------------------------
    @staticmethod
    def initial_state(attitude, P0, initial_rate_sigma: float = DEFAULT_INITIAL_RATE_SIGMA, bias_B=None):
        """State from ``q_IB`` (4) or ``R_IB`` (3, 3) and ``P0`` (rad^2).

        ``P0`` a scalar variance or 3x3: a :class:`LieGroupState` (no bias state); the rate
        block starts at ``w_B = 0`` with ``initial_rate_sigma`` (rad/s) per axis.  ``P0``
        6x6 (covariance of ``[dtheta_B; dbias_B]``, rad^2 and (rad/s)^2): a
        :class:`LieGroupBiasState` with the initial bias ``bias_B`` (3, rad/s; None: zero),
        for a core with ``estimate_gyro_bias``.
        """
        a = np.asarray(attitude, dtype=float)
        if a.shape == (4,):
            R = rot.quat_to_rotmat(a)
        elif a.shape == (3, 3):
            if not np.allclose(a.T @ a, _EYE3, atol=1e-9) or np.linalg.det(a) <= 0:
                raise ValueError(f"attitude: got a 3x3 matrix that is not a rotation: {a.tolist()}")
            R = orthonormalize(a)
        else:
            raise ValueError(f"attitude: got shape {a.shape}; need q_IB (4,) or R_IB (3, 3)")
        if np.shape(P0) == (6, 6):
            b = np.zeros(3) if bias_B is None else check_array("bias_B", np.ravel(bias_B), (3,), " (rad/s)")
            return LieGroupBiasState(R, b, check_variance_matrix("P0", P0, 6))
        if bias_B is not None:
            fail("P0", np.shape(P0), "with bias_B a bias state needs a 6x6 P0 (covariance of [dtheta_B; dbias_B])")
        check_positive("initial_rate_sigma", initial_rate_sigma)
        return LieGroupState(
            R, check_variance_matrix("P0", P0, 3), np.zeros(3), initial_rate_sigma**2 * _EYE3, np.zeros((3, 3))
        )

    @staticmethod
    def to_vector(state) -> np.ndarray:
        if isinstance(state, LieGroupBiasState):
            return np.concatenate([np.ravel(state.R_IB), state.bias_B, np.ravel(state.P)])
        return np.concatenate(
            [np.ravel(state.R_IB), np.ravel(state.P), state.w_B, np.ravel(state.P_w), np.ravel(state.C)]
        )

    @staticmethod
    def from_vector(vector):
        """Inverse of :meth:`to_vector` (the length tells the kind: 39 no bias, 48 bias)."""
        v = np.asarray(vector, dtype=float)
        if v.shape == (STATE_SIZE_BIAS,):
            return LieGroupBiasState(v[0:9].reshape(3, 3), v[9:12], v[12:48].reshape(6, 6))
        if v.shape != (STATE_SIZE_NO_BIAS,):
            raise ValueError(
                f"LieGroupFilter state vector: got shape {v.shape}; need ({STATE_SIZE_NO_BIAS},) "
                f"or ({STATE_SIZE_BIAS},) with a gyro-bias state"
            )
        return LieGroupState(
            v[0:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21], v[21:30].reshape(3, 3), v[30:39].reshape(3, 3)
        )

    def _check_state(self, state) -> None:
        if isinstance(state, LieGroupBiasState) != self.estimate_gyro_bias:
            need = "LieGroupBiasState (initial_state with a 6x6 P0)" if self.estimate_gyro_bias else "LieGroupState"
            raise TypeError(
                f"LieGroupFilter(estimate_gyro_bias={self.estimate_gyro_bias}): got a "
                f"{type(state).__name__}; need a {need}"
            )

    def reacquire(self, state, info):
        """The state with its covariance inflated after repeated gate rejections (the rule of
        :mod:`drake_att.filters.gating`, applied by the estimator system)."""
        return inflated(state, reacquire_factor(self.gate, info))

    def estimate(self, state):
        """``(q_IB_hat, second, 6x6 covariance)``: without a bias state the second vector is
        ``w_IB_B_hat`` and the covariance that of ``[dtheta_B; w_true - w_hat]``; with one,
        ``bias_B_hat`` and ``cov([dtheta_B; b - b_hat])``."""
        self._check_state(state)
        if self.estimate_gyro_bias:
            return rot.rotmat_to_quat(state.R_IB), np.array(state.bias_B, dtype=float), np.array(state.P, dtype=float)
        P6 = np.empty((6, 6))
        P6[:3, :3] = state.P
        P6[:3, 3:] = state.C
        P6[3:, :3] = state.C.T
        P6[3:, 3:] = state.P_w
        return rot.rotmat_to_quat(state.R_IB), np.array(state.w_B, dtype=float), P6

    # -- time update ---------------------------------------------------------------------------
    def process_noise(self, dt: float) -> np.ndarray:
        """Process noise of a predict over ``dt`` (s).

        No bias state: the attitude's ``Q_w dt/step_s + arw^2 dt I`` (3x3).  With one:
        :func:`drake_att.filters.mekf.process_noise` (the closed-form Farrenkopf covariance
        of ``[dtheta; dbias]``) plus ``Q_w dt/step_s`` on the attitude block (6x6, cached
        per ``dt``; read only).
        """
        if not self.estimate_gyro_bias:
            Q = self.Q_w * (dt / self.step_s)
            if self.arw:
                Q = Q + (self.arw**2 * dt) * _EYE3
            return Q
        Q_bias = self._q_cache.get(dt)
        if Q_bias is None:
            if len(self._q_cache) > 64:
                self._q_cache.clear()
            Q_bias = _mekf.process_noise(self.arw or 0.0, self.rrw or 0.0, dt)
            Q_bias[:3, :3] += self.Q_w * (dt / self.step_s)
            self._q_cache[dt] = Q_bias
        return Q_bias

    def predict(self, state, w_meas_B, dt: float, rng=None):
        """Propagate over ``dt`` (s) with the gyro's mean rate ``w_meas_B`` (rad/s, body).

        ``dt <= 0`` returns the state unchanged; ``w_meas_B`` None is a zero rate.  With a
        bias state the rate used is ``w_meas_B - bias_B_hat`` and the covariance
        ``Phi P Phi' + Q`` with :func:`drake_att.filters.mekf.transition_matrix`.
        """
        self._check_state(state)
        if not dt > 0.0:
            return state
        w = np.zeros(3) if w_meas_B is None else np.asarray(w_meas_B, dtype=float).copy()
        if self.estimate_gyro_bias:
            w_hat = w - state.bias_B
            Phi = _mekf.transition_matrix(w_hat, dt)
            P = Phi @ state.P @ Phi.T + self.process_noise(dt)
            R = orthonormalize(state.R_IB @ rot.rotvec_to_rotmat(w_hat * dt))
            return LieGroupBiasState(R, state.bias_B, 0.5 * (P + P.T))
        A = rot.rotvec_to_rotmat(w * dt)
        Q = self.process_noise(dt)
        if self.formulation == "consistent":
            P = A.T @ state.P @ A + Q
        else:  # the paper's eq 25
            P = A @ state.P @ A.T + Q
        P_w, C = rate_error_model(Q, self.arw, dt)
        return LieGroupState(orthonormalize(state.R_IB @ A), 0.5 * (P + P.T), w, P_w, C)

    # -- measurement update --------------------------------------------------------------------
    def measurement_model(self, state, measurement) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(z, H, R)`` of one measurement: innovation, Jacobian w.r.t. the error state
        (3 or 6 columns) and noise covariance, as :meth:`update` uses them.

        * :class:`~drake_att.contract.VectorObservations`: consistent or literal
          (docs/derivations/lie_group.md); with a bias state ``H`` has three zero bias columns.
        * :class:`~drake_att.contract.QuaternionSample` (consistent only): ``q_IB_meas =
          q_IS_meas ⊗ q_BS^-1``, ``z = log(q_IB_hat^-1 ⊗ q_IB_meas)`` (body frame),
          ``H = [I, 0]``, ``R = R_BS covariance_S R_BS'`` (``covariance_S`` 3x3, or per-axis
          sigmas (3,) as the MEKF accepts).
        """
        n = 6 if self.estimate_gyro_bias else 3
        if isinstance(measurement, VectorObservations):
            d_S, R_SB = _sensor_directions(measurement)
            r_I = np.atleast_2d(np.asarray(measurement.references_I, dtype=float))
            m = d_S.shape[0]
            var = float(measurement.sigma_rad) ** 2 if self.Q_v is None else self.Q_v
            R_meas = var * np.eye(3 * m)
            X_hat = state.R_IB.T  # the paper's X = R_BI
            if self.formulation == "consistent":
                b_B = r_I @ X_hat.T  # predicted body directions (m, 3)
                z = (d_S - b_B @ R_SB.T).ravel()
                H = (R_SB @ rot.skew(b_B)).reshape(3 * m, 3)
            else:
                l_B = d_S @ R_SB  # R_BS d_i, rows
                z = (l_B - r_I @ X_hat.T).ravel()
                H = (-rot.skew(r_I)).reshape(3 * m, 3)
            if n == 6:
                H = np.hstack([H, np.zeros((3 * m, 3))])
            return z, H, R_meas
        if isinstance(measurement, QuaternionSample):
            if self.formulation != "consistent":
                raise TypeError(
                    "LieGroupFilter.update: formulation='paper_literal' has only the paper's vector "
                    "update (eqs 26-32); a QuaternionSample needs formulation='consistent'"
                )
            q_BS = np.asarray(measurement.q_BS, dtype=float)
            R_BS = rot.quat_to_rotmat(q_BS)
            q_IB_meas = rot.quat_multiply(np.asarray(measurement.q_IS_meas, dtype=float), rot.quat_conjugate(q_BS))
            q_hat = rot.rotmat_to_quat(state.R_IB)
            z = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q_hat), q_IB_meas))
            cov_S = np.asarray(measurement.covariance_S, dtype=float)
            if cov_S.shape == (3,):
                cov_S = np.diag(cov_S**2)
            R_meas = R_BS @ cov_S @ R_BS.T
            H = np.zeros((3, n))
            H[:, :3] = _EYE3
            return z, H, 0.5 * (R_meas + R_meas.T)
        raise TypeError(
            f"LieGroupFilter.update: got a {type(measurement).__name__}; allowed: VectorObservations, QuaternionSample"
        )

    def update(self, state, measurement, rng=None):
        """Update with a :class:`~drake_att.contract.VectorObservations` (m >= 1 stars) or a
        :class:`~drake_att.contract.QuaternionSample` (consistent formulation)."""
        self._check_state(state)
        z, H, R_meas = self.measurement_model(state, measurement)
        n = H.shape[1]
        P = state.P
        HP = H @ P
        S = HP @ H.T + R_meas
        S = 0.5 * (S + S.T)
        sol = _solve_spd(S, np.column_stack([HP, z]))  # [S^-1 H P, S^-1 z]
        if sol is None:
            return state, UpdateInfo(z, S, float("nan"), False)
        nis = float(z @ sol[:, n])
        if self.gate.rejects(nis, len(z)):
            return state, UpdateInfo(z, S, nis, False)
        K = sol[:, :n].T  # P H' S^-1
        dx = K @ z
        I_KH = (_EYE6 if n == 6 else _EYE3) - K @ H
        P_new = I_KH @ P @ I_KH.T + K @ R_meas @ K.T
        if self.formulation == "consistent":
            R_new = state.R_IB @ rot.rotvec_to_rotmat(dx[:3])
        else:  # X_hat <- X_hat exp([dx x])  <=>  R_IB_hat <- exp(-[dx x]) R_IB_hat
            R_new = rot.rotvec_to_rotmat(-dx) @ state.R_IB
        if self.estimate_gyro_bias:
            new = LieGroupBiasState(orthonormalize(R_new), state.bias_B + dx[3:], 0.5 * (P_new + P_new.T))
            return new, UpdateInfo(z, S, nis, True, I_KH)
        new = LieGroupState(orthonormalize(R_new), 0.5 * (P_new + P_new.T), state.w_B, state.P_w, I_KH @ state.C)
        return new, UpdateInfo(z, S, nis, True)


__all__ = [
    "LieGroupState",
    "LieGroupBiasState",
    "LieGroupFilter",
    "FORMULATIONS",
    "rate_error_model",
    "orthonormalize",
    "DEFAULT_INITIAL_RATE_SIGMA",
    "DEFAULT_Q_W",
    "STATE_SIZE_NO_BIAS",
    "STATE_SIZE_BIAS",
]
