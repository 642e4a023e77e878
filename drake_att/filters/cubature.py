"""Paper S1's filter cores: the cubature quaternion estimator (CQE, Wei & Song 2013) and
CQE-MCNS (the patent's filter for the multiplicative noise ``zeta`` correlated with the
star-sensor noise, :mod:`drake_att.filters.multiplicative_noise`).  Plain numpy (no Drake).

State ``x = [dp; beta]``: ``dp`` the generalized Rodrigues parameters (GRP; default ``a = 1,
f = 4``, USQUE) of the attitude error, truth ``q_IB = q_ref ⊗ dq(dp)``; ``beta`` the gyro bias
(rad/s); a lower-triangular square root of the 6x6 covariance (GRP units).  Published:
``q_IB_hat`` (wxyz Hamilton), ``beta_hat`` and the covariance of ``[dtheta_B (rad); dbias
(rad/s)]``, ``q_IB = q_IB_hat ⊗ exp(dtheta_B)`` (first order, ``dtheta = 2 (1 + a) dp / f``).

* :class:`CubatureQuaternionEstimator`: the :class:`drake_att.contract.FilterCore` (gyro-driven,
  star vectors of a tracker mounted by ``q_BS``, second quantity the gyro bias); given a
  ``noise_model`` it is the CQE-MCNS, :class:`CubatureQuaternionEstimatorMCNS` requires one.
  An update that cannot be made (singular ``P_zz``, bad numbers or shapes) is rejected
  (``accepted=False``, state unchanged), not raised.
* :class:`CubatureState`; :func:`cubature_rule`, :func:`cubature_points`, :func:`triangularize`.
* Beyond the paper, each switchable: iterated update (``update_iterations=1``: the paper), a
  gate on ``M`` (``zeta_gate_sigmas=None``), the ``Cov(x, zeta)`` term (``zeta_state_correlation``).

Derivation and paper notes: docs/derivations/cubature_and_mcns.md
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import SecondQuantity, UpdateInfo, VectorObservations
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
from drake_att.filters.mekf import process_noise
from drake_att.filters.multiplicative_noise import MultiplicativeNoiseModel
from drake_att.validation import (
    check_array,
    check_covariance,
    check_finite,
    check_int,
    check_nonnegative,
    check_positive,
    check_quaternion,
    fail,
)

STATE_DIM = 6


def cubature_rule(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit cubature points ``xi`` (2n, n) = ``sqrt(n) [I; -I]`` and weights (2n,) ``1 / (2n)``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        fail("n", n, "must be an integer >= 1")
    eye = np.eye(int(n))
    return math.sqrt(n) * np.vstack([eye, -eye]), np.full(2 * int(n), 1.0 / (2 * int(n)))


def cubature_points(mean, sqrt_cov) -> np.ndarray:
    """Points ``mean + L xi_i`` (2n, n) of ``N(mean, L L')``."""
    mean = np.asarray(mean, dtype=float)
    L = np.asarray(sqrt_cov, dtype=float)
    xi, _ = cubature_rule(mean.size)
    return mean + xi @ L.T


def triangularize(A_rows) -> np.ndarray:
    """Lower-triangular ``L`` (positive diagonal) with ``L L' = A_rows' A_rows`` (QR)."""
    R = cast(np.ndarray, np.linalg.qr(A_rows, mode="r"))  # numpy's stub: mode="r" returns R, not a QRResult
    s = np.where(np.diag(R) < 0.0, -1.0, 1.0)
    return (R * s[:, None]).T


_EYE3 = np.eye(3)
_XI6 = cubature_rule(STATE_DIM)[0]
_W6 = 1.0 / math.sqrt(2 * STATE_DIM)
_XI6W = _XI6 * _W6  # orthonormal columns: _XI6W' _XI6W = I
# Hamilton product as a bilinear form: (p ⊗ q)_i = sum_jk _HAMILTON[i, j, k] p_j q_k.
_HAMILTON = np.array([[rot.quat_multiply(np.eye(4)[j], np.eye(4)[k]) for k in range(4)] for j in range(4)]).transpose(
    2, 0, 1
)
_HAMILTON_FLAT = np.ascontiguousarray(_HAMILTON.reshape(4, 16).T)  # (16, 4)


def left_matrix(p) -> np.ndarray:
    """4x4 matrix of ``q -> p ⊗ q`` (wxyz)."""
    return np.einsum("ijk,j->ik", _HAMILTON, np.asarray(p, dtype=float))


def right_matrix(q) -> np.ndarray:
    """4x4 matrix of ``p -> p ⊗ q`` (wxyz)."""
    return np.einsum("ijk,k->ij", _HAMILTON, np.asarray(q, dtype=float))


def quat_products(p, q) -> np.ndarray:
    """Row-wise ``p_n ⊗ q_n`` of (N, 4) stacks (one matrix product; = rotations.quat_multiply)."""
    N = p.shape[0]
    return (p[:, :, None] * q[:, None, :]).reshape(N, 16) @ _HAMILTON_FLAT


_ZERO6 = np.zeros(6)
_ZERO6.flags.writeable = False


@dataclass(frozen=True)
class CubatureState:
    """State of the cubature cores (docs/derivations/cubature_and_mcns.md).

    Attributes:
        q_ref: reference quaternion ``q_IB`` (4). dp: mean GRP error relative to it (3),
        zero after an update. bias_B: gyro bias (3, rad/s). sqrt_P: lower-triangular square
        root of the covariance of ``[dp; beta]`` (6x6, GRP units). zeta_mean: ``M`` of the last
        update (0 otherwise). zeta_var_reduction: ``S' P_zz^-1 S`` of the last update
        (0 otherwise; ``U = Q_zeta - zeta_var_reduction``). zeta_cross: ``Cov([dp; beta], zeta | D)
        = -K S`` of the last update (6, GRP units; 0 otherwise), used only with
        ``zeta_state_correlation``.
    """

    q_ref: np.ndarray
    dp: np.ndarray
    bias_B: np.ndarray
    sqrt_P: np.ndarray
    zeta_mean: float = 0.0
    zeta_var_reduction: float = 0.0
    zeta_cross: np.ndarray = field(default_factory=lambda: _ZERO6)

    @property
    def P_grp(self) -> np.ndarray:
        """Covariance of ``[dp; beta]`` (GRP units)."""
        return self.sqrt_P @ self.sqrt_P.T


def _process_noise_sqrt(arw: float, rrw: float, dt: float, c: float) -> np.ndarray:
    """Lower-triangular square root of ``diag(c I, I) Q diag(c I, I)`` (closed-form 2x2 per axis)."""
    Q = process_noise(arw, rrw, dt)
    a, b, d = Q[0, 0] * c * c, Q[0, 3] * c, Q[3, 3]
    l11 = math.sqrt(a)
    l21 = b / l11 if l11 > 0.0 else 0.0
    l22 = math.sqrt(max(d - l21 * l21, 0.0))
    L = np.zeros((6, 6))
    L[:3, :3] = l11 * _EYE3
    L[3:, :3] = l21 * _EYE3
    L[3:, 3:] = l22 * _EYE3
    return L


class CubatureQuaternionEstimator(GatedCore):
    """Cubature quaternion estimator (CQE); with ``noise_model`` the CQE-MCNS.

    Implements :class:`drake_att.contract.FilterCore` (state vector
    ``[q_ref (4), dp (3), bias_B (3), sqrt_P (36, row-major), zeta_mean, zeta_var_reduction,
    zeta_cross (6)]``, 54 numbers).

    Args:
        arw_rad_per_rt_s: filter's gyro ARW ``sigma_v`` (rad/s^0.5) >= 0.
        rrw_rad_per_s15: filter's gyro RRW ``sigma_u`` (rad/s^1.5) >= 0.
        grp_a: GRP parameter ``a`` in [0, 1] (default 1).
        grp_f: GRP scale ``f`` > 0 (default 4; ``a = 1, f = 4`` is the USQUE convention).
        innovation_gate_chi2: reject an update whose NIS exceeds this (None: no gate).
        noise_model: the multiplicative noise the filter models (None: the plain CQE).
        zeta_gate_sigmas: reset ``M`` to 0 (``U`` to ``Q_zeta``) when ``|M|`` exceeds this many of
            its sigmas under the model (None: never, the patent).
        update_iterations: maximum iterations of the measurement update (1: the paper).
        iteration_tolerance: stop iterating when the mean moves less than this many
            posterior sigmas.
        zeta_state_correlation: include ``Cov(x, zeta | D) = -K S`` in the predict (False: the
            patent's formula).
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True
    is_random = False
    state_size = 54

    def __init__(
        self,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        grp_a: float = 1.0,
        grp_f: float = 4.0,
        innovation_gate_chi2=None,
        noise_model: MultiplicativeNoiseModel | None = None,
        zeta_gate_sigmas: float | None = 4.0,
        update_iterations: int = 10,
        iteration_tolerance: float = 1e-2,
        zeta_state_correlation: bool = False,
    ):
        self.arw = check_nonnegative("arw", arw_rad_per_rt_s)
        self.rrw = check_nonnegative("rrw", rrw_rad_per_s15)
        self.grp_a = check_finite("grp_a", grp_a)
        if not 0.0 <= self.grp_a <= 1.0:
            fail("grp_a", grp_a, "must be in [0, 1]")
        self.grp_f = check_positive("grp_f", grp_f)
        self.gate = InnovationGate.of(innovation_gate_chi2)
        if noise_model is not None and not isinstance(noise_model, MultiplicativeNoiseModel):
            fail("noise_model", noise_model, "must be a MultiplicativeNoiseModel or None")
        self.noise_model = noise_model
        if zeta_gate_sigmas is not None:
            check_positive("zeta_gate_sigmas", zeta_gate_sigmas)
        self.zeta_gate_sigmas = zeta_gate_sigmas
        if not isinstance(zeta_state_correlation, (bool, np.bool_)):
            fail("zeta_state_correlation", zeta_state_correlation, "must be True or False")
        self.zeta_state_correlation = bool(zeta_state_correlation)
        self.update_iterations = check_int("update_iterations", update_iterations, 1)
        self.iteration_tolerance = check_positive("iteration_tolerance", iteration_tolerance)
        # First-order GRP factor: dp = c dtheta.
        self.c = self.grp_f / (2.0 * (1.0 + self.grp_a))
        self._J = np.diag([1.0 / self.c] * 3 + [1.0] * 3)  # GRP -> rotation vector (first order)
        self._lq_cache: dict = {}

    # -- conversions ---------------------------------------------------------------------
    def _to_quat(self, dp) -> np.ndarray:
        return rot.grp_to_quat(dp, self.grp_a, self.grp_f)

    def _to_grp(self, q) -> np.ndarray:
        return rot.quat_to_grp(q, self.grp_a, self.grp_f)

    def process_noise_sqrt(self, dt: float) -> np.ndarray:
        """Square root of the GRP-unit process noise over ``dt`` (cached per ``dt``)."""
        L = self._lq_cache.get(dt)
        if L is None:
            if len(self._lq_cache) > 64:
                self._lq_cache.clear()
            L = self._lq_cache[dt] = _process_noise_sqrt(self.arw, self.rrw, dt, self.c)
        return L

    def initial_state(
        self, q_IB, bias_B, attitude_sigma_rad=None, bias_sigma_rad_per_s=None, covariance0=None
    ) -> CubatureState:
        """State at ``q_IB`` (4), ``bias_B`` (3) with per-axis (or scalar) 1-sigmas (rotation
        vector, rad; bias, rad/s) or a full 6x6 ``covariance0`` of ``[dtheta_B; dbias]``."""
        q = check_quaternion("q_IB", q_IB)
        b = check_array("bias_B", bias_B, (3,), " (rad/s)")
        if covariance0 is None:
            if attitude_sigma_rad is None or bias_sigma_rad_per_s is None:
                fail("covariance0", covariance0, "give covariance0 or both attitude and bias sigmas")
            sig = np.concatenate(
                [
                    np.broadcast_to(np.asarray(attitude_sigma_rad, dtype=float), 3),
                    np.broadcast_to(np.asarray(bias_sigma_rad_per_s, dtype=float), 3),
                ]
            )
            if not np.all(np.isfinite(sig)) or np.any(sig <= 0.0):
                fail("sigmas", sig, "must be finite and > 0")
            P = np.diag(sig**2)
        else:
            P = check_covariance("covariance0", covariance0, 6)
        T = np.diag([self.c] * 3 + [1.0] * 3)
        L = np.linalg.cholesky(T @ P @ T)
        return CubatureState(q, np.zeros(3), b.copy(), L)

    # -- contract ------------------------------------------------------------------------

    def reacquire(self, state, info):
        """The state with its covariance inflated after repeated gate rejections (the rule of
        :mod:`drake_att.filters.gating`, applied by the estimator system)."""
        return inflated(state, reacquire_factor(self.gate, info), "sqrt_P", square_root=True)

    def estimate(self, state: CubatureState):
        """``(q_IB_hat, bias_B_hat, P)``, ``P`` the covariance of ``[dtheta_B; dbias]``."""
        q = rot.quat_canonical(rot.quat_normalize(rot.quat_multiply(state.q_ref, self._to_quat(state.dp))))
        JL = self._J @ state.sqrt_P
        return q, state.bias_B, JL @ JL.T

    @staticmethod
    def to_vector(state: CubatureState) -> np.ndarray:
        return np.concatenate(
            [
                state.q_ref,
                state.dp,
                state.bias_B,
                np.asarray(state.sqrt_P).ravel(),
                [state.zeta_mean, state.zeta_var_reduction],
                state.zeta_cross,
            ]
        )

    @staticmethod
    def from_vector(vector) -> CubatureState:
        v = np.asarray(vector, dtype=float)
        return CubatureState(v[:4], v[4:7], v[7:10], v[10:46].reshape(6, 6), float(v[46]), float(v[47]), v[48:54])

    # -- predict -------------------------------------------------------------------------
    def zeta_moments(self, state: CubatureState) -> tuple[float, float]:
        """``(M, U)`` the next predict uses (``(0, 0)`` for the plain CQE)."""
        if self.noise_model is None:
            return 0.0, 0.0
        return state.zeta_mean, max(self.noise_model.zeta_variance - state.zeta_var_reduction, 0.0)

    def predict(self, state: CubatureState, w_meas_B, dt: float, rng=None) -> CubatureState:
        """Propagate over ``dt`` (s) with the step's mean measured rate ``w_meas_B`` (rad/s)."""
        if not dt > 0.0:
            return state
        w = np.asarray(w_meas_B, dtype=float)
        n = STATE_DIM
        x_hat = np.concatenate([state.dp, state.bias_B])
        X = x_hat + _XI6 @ state.sqrt_P.T  # (2n, n)
        u = (w - X[:, 3:]) * dt  # each point's increment (2n, 3)
        u_hat = (w - state.bias_B) * dt
        # Propagated mean quaternion relative to q_ref: dq(dp_hat) ⊗ exp(u_hat); each point's
        # error relative to it: (dq(dp_hat) ⊗ exp(u_hat))^-1 ⊗ dq(dp_i) ⊗ exp(u_i).
        ref_step = rot.quat_multiply(self._to_quat(state.dp), rot.rotvec_to_quat(u_hat))
        to_ref = left_matrix(rot.quat_conjugate(ref_step)).T
        e = quat_products(self._to_quat(X[:, :3]), rot.rotvec_to_quat(u)) @ to_ref
        F = np.empty_like(X)
        F[:, :3] = self._to_grp(e)
        F[:, 3:] = X[:, 3:]
        M, U = self.zeta_moments(state)
        scale = 1.0 / math.sqrt(2 * n)
        if self.noise_model is not None:
            G = np.zeros_like(X)
            G[:, :3] = (self.c * self.noise_model.scale_per_zeta) * u  # g_i = Phi u_i
            if self.zeta_state_correlation and np.any(state.zeta_cross):
                # zeta | x, D ~ N(M + c' P^-1 (x - x_hat), U - c' P^-1 c); at X_i = x_hat + L xi_i
                # the mean is M + b' xi_i with b = L^-1 c.
                b = np.linalg.solve(state.sqrt_P, state.zeta_cross)
                Fm = F + (M + _XI6 @ b)[:, None] * G
                U = max(U - float(b @ b), 0.0)
            else:
                Fm = F + M * G
            x_new = Fm.mean(axis=0)
            rows = np.vstack([(Fm - x_new) * scale, (math.sqrt(U) * scale) * G, self.process_noise_sqrt(dt).T])
        else:
            x_new = F.mean(axis=0)
            rows = np.vstack([(F - x_new) * scale, self.process_noise_sqrt(dt).T])
        L = triangularize(rows)
        q_ref = rot.quat_normalize(rot.quat_multiply(state.q_ref, ref_step))
        return CubatureState(q_ref, x_new[:3], x_new[3:], L)

    # -- update --------------------------------------------------------------------------
    def update(self, state: CubatureState, measurement, rng=None) -> tuple[CubatureState, UpdateInfo]:
        """Update with :class:`~drake_att.contract.VectorObservations` (the contract's entry point)."""
        if not isinstance(measurement, VectorObservations):
            raise TypeError(
                f"{type(self).__name__}.update: got a {type(measurement).__name__}; allowed: VectorObservations"
            )
        return self.update_vectors(
            state, measurement.directions_S, measurement.references_I, measurement.sigma_rad, measurement.q_BS
        )

    def update_vectors(
        self, state: CubatureState, directions_S, references_I, sigma_rad: float, q_BS=(1.0, 0.0, 0.0, 0.0)
    ) -> tuple[CubatureState, UpdateInfo]:
        """Update with ``m`` measured directions (m, 3, sensor frame) of inertial references (m, 3)."""
        rejected = UpdateInfo(None, None, float("nan"), False)
        measurement = _vector_measurement(directions_S, references_I, q_BS, sigma_rad)
        if measurement is None:
            return state, rejected
        y, refs, q_BS, sigma = measurement
        m = y.shape[0]
        nm = self.noise_model
        if nm is not None and not nm.admits(m):
            return state, rejected
        n = STATE_DIM
        x0 = np.concatenate([state.dp, state.bias_B])
        L0 = state.sqrt_P
        C = (left_matrix(state.q_ref) @ right_matrix(q_BS)).T  # dq -> q_ref ⊗ dq ⊗ q_BS (rows)
        eye_m = np.eye(3 * m)
        xj, Lj = x0, L0
        for j in range(self.update_iterations):
            # Statistical linearization of h about N(xj, Lj Lj'): z ~ H x + b, residual Omega.
            X = xj + _XI6 @ Lj.T
            R_IS = rot.quat_to_rotmat(self._to_quat(X[:, :3]) @ C)  # (2n, 3, 3)
            Z = np.einsum("kji,mj->kmi", R_IS, refs).reshape(2 * n, 3 * m)  # R_SI r per point
            z_bar = Z.mean(axis=0)
            Zc = (Z - z_bar) * _W6
            A = Zc.T @ _XI6W  # H Lj (3m, n); its bias columns are exactly 0 (h ignores beta)
            Zr = Zc - _XI6W @ A.T  # rows of Omega^(1/2): the part of Zc no linear map explains
            try:
                if j == 0:
                    HL0_j, nu_j = A, y.ravel() - z_bar
                else:
                    H_att = np.linalg.solve(Lj[:3, :3].T, A[:, :3].T).T
                    HL0_j = H_att @ L0[:3]
                    nu_j = y.ravel() - z_bar - H_att @ (x0[:3] - xj[:3])
                Pzz_j = HL0_j @ HL0_j.T + Zr.T @ Zr + (sigma * sigma) * eye_m
                Pzz_j = 0.5 * (Pzz_j + Pzz_j.T)
                Lz_j = np.linalg.cholesky(Pzz_j)
                if not (np.all(np.isfinite(Lz_j)) and np.min(np.diag(Lz_j)) > 0.0 and np.all(np.isfinite(nu_j))):
                    raise np.linalg.LinAlgError("innovation covariance not positive definite")
            except np.linalg.LinAlgError:
                if j == 0:  # the paper's update itself is impossible: reject
                    return state, UpdateInfo(
                        y.ravel() - z_bar, Zc.T @ Zc + (sigma * sigma) * eye_m, float("nan"), False
                    )
                break  # a relinearization is impossible: keep the last iterate
            HL0, nu, Pzz, Lz = HL0_j, nu_j, Pzz_j, Lz_j
            w_nu = np.linalg.solve(Lz, nu)
            K = np.linalg.solve(Lz.T, np.linalg.solve(Lz, HL0 @ L0.T)).T  # P0 H' Pzz^-1
            x_next = x0 + K @ nu
            L_next = triangularize(np.vstack([L0.T - HL0.T @ K.T, Zr @ K.T, sigma * K.T]))
            step = x_next - xj
            xj, Lj = x_next, L_next
            tol = self.iteration_tolerance
            if j == 0:
                # h linear over the prior's spread (its residual negligible against the noise):
                # relinearizing about the posterior cannot move the result.
                if float(np.sum(Zr * Zr)) <= tol * tol * 3 * m * sigma * sigma:
                    break
            elif np.all(np.abs(step) <= tol * np.sqrt(np.sum(Lj * Lj, axis=1))):
                break
        nis = float(w_nu @ w_nu)
        if not np.all(np.isfinite(xj)) or self.gate.rejects(nis, len(nu)):
            return state, UpdateInfo(nu, Pzz, nis, False)
        q_ref = rot.quat_normalize(rot.quat_multiply(state.q_ref, self._to_quat(xj[:3])))
        M, D, cross = self._zeta_moments(Lz, w_nu, K, sigma, m)
        new = CubatureState(q_ref, np.zeros(3), xj[3:], Lj, M, D, cross)
        return new, UpdateInfo(nu, Pzz, nis, True)

    def _zeta_moments(
        self, Lz: np.ndarray, w_nu: np.ndarray, K: np.ndarray, sigma: float, m: int
    ) -> tuple[float, float, np.ndarray]:
        """``(M, D, Cov([dp; beta], zeta | D))`` of the multiplicative noise after an update with
        innovation covariance factor ``Lz``, whitened innovation ``w_nu`` and gain ``K``
        (``(0, 0, 0)`` without a noise model or when ``M`` is gated out)."""
        nm = self.noise_model
        M = D = 0.0
        if nm is not None:
            w_S = np.linalg.solve(Lz, nm.cross_covariance(sigma, m))  # Lz^-1 S
            M, D = float(w_S @ w_nu), float(w_S @ w_S)
            # Under the model M ~ N(0, D); far outside, the innovation is not the model's and
            # Lemma 1's moments are meaningless: fall back to the prior (M = 0, U = Q_zeta).
            if self.zeta_gate_sigmas is not None and M * M > self.zeta_gate_sigmas**2 * D:
                M = D = 0.0
        cross = _ZERO6
        if nm is not None and (M != 0.0 or D != 0.0):
            cross = -K @ nm.cross_covariance(sigma, m)  # Cov(x, zeta | D) = -K S
        return M, D, cross


def _vector_measurement(
    directions_S, references_I, q_BS, sigma_rad
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """``(directions (m, 3), references (m, 3), q_BS (4,), sigma)`` as floats, or None when they
    cannot make an update: not numbers, wrong or unequal shapes, not finite, a negative sigma
    or a zero ``q_BS``."""
    try:
        y = np.asarray(directions_S, dtype=float)
        refs = np.asarray(references_I, dtype=float)
        q = np.asarray(q_BS, dtype=float)
        sigma = float(sigma_rad)
    except (TypeError, ValueError):
        return None
    if (
        y.ndim != 2
        or y.shape[1] != 3
        or y.shape != refs.shape
        or y.shape[0] < 1
        or q.shape != (4,)
        or not (np.all(np.isfinite(y)) and np.all(np.isfinite(refs)) and np.all(np.isfinite(q)))
        or not (math.isfinite(sigma) and sigma >= 0.0)
        or not float(q @ q) > 1e-18
    ):
        return None
    return y, refs, q, sigma


class CubatureQuaternionEstimatorMCNS(CubatureQuaternionEstimator):
    """CQE-MCNS: the CQE with the multiplicative-noise terms of ``noise_model``
    (docs/derivations/cubature_and_mcns.md; model in :mod:`drake_att.filters.multiplicative_noise`).

    Args: as :class:`CubatureQuaternionEstimator`; ``noise_model`` is required (default:
    :meth:`MultiplicativeNoiseModel.paper`).
    """

    def __init__(
        self,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        grp_a: float = 1.0,
        grp_f: float = 4.0,
        innovation_gate_chi2=None,
        noise_model: MultiplicativeNoiseModel | None = None,
        zeta_gate_sigmas: float | None = 4.0,
        update_iterations: int = 10,
        iteration_tolerance: float = 1e-2,
        zeta_state_correlation: bool = False,
    ):
        super().__init__(
            arw_rad_per_rt_s,
            rrw_rad_per_s15,
            grp_a,
            grp_f,
            innovation_gate_chi2,
            MultiplicativeNoiseModel.paper() if noise_model is None else noise_model,
            zeta_gate_sigmas,
            update_iterations,
            iteration_tolerance,
            zeta_state_correlation,
        )


__all__ = [
    "cubature_rule",
    "cubature_points",
    "triangularize",
    "CubatureState",
    "CubatureQuaternionEstimator",
    "CubatureQuaternionEstimatorMCNS",
]
