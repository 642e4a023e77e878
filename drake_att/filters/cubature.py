"""Paper S1's filter cores: the cubature quaternion estimator (CQE, Wei & Song 2013) and
CQE-MCNS (the patent's modified Gaussian filter for a multiplicative noise ``zeta``
correlated with the star-sensor noise).

Plain numpy (no Drake). Both implement :class:`drake_att.contract.FilterCore`: gyro-driven
(``predict`` takes the step's mean gyro rate), star vectors
(:class:`~drake_att.contract.VectorObservations`, tracker mounted by ``q_BS`` as in
:mod:`drake_att.filters.mekf`), second quantity the gyro bias.

**Cubature rule** (third-degree spherical-radial, Arasaratnam & Haykin 2009): ``2n`` points
``xi = sqrt(n) [I_n, -I_n]``, weights ``1 / (2n)``; ``E[g(x)]`` for ``x ~ N(m, L L')`` is
approximated by ``mean_i g(m + L xi_i)``, exact for polynomials of degree <= 3
(:func:`cubature_rule`).

**State and conventions.** ``x = [dp; beta]``: ``dp`` the generalized Rodrigues parameters
(GRP, :func:`drake_att.rotations.quat_to_grp`) of the attitude error, ``dp = f dq_vec / (a + dq_w)``,
defaults ``a = 1, f = 4`` (the USQUE convention of Crassidis & Markley 2003, ``|dp|`` ~ the
error angle; the patent names ``0 <= a <= 1`` and a scale ``b`` = our ``f``); ``beta`` the gyro
bias (rad/s). The error is the project's: the truth is ``q_IB = q_ref ⊗ dq(dp)`` (the patent's
``q_i = dq_i ⊗ q_hat`` in its inertial-to-body product is this body-frame right error). The
core keeps a reference quaternion ``q_ref``, the mean ``dp_hat`` relative to it (zero after
every update: the USQUE reset), ``beta_hat`` and a lower-triangular square root ``L`` of
the 6x6 covariance of ``[dp; beta]`` (GRP units). The published estimate is
``q_IB_hat = q_ref ⊗ dq(dp_hat)``, ``beta_hat`` and the covariance of
``[dtheta_B (rad); dbias (rad/s)]`` with ``q_IB = q_IB_hat ⊗ exp(dtheta_B)``, mapped from GRP to
rotation vector to first order: ``dtheta = dp / c``, ``c = f / (2 (1 + a))`` (``c = 1`` for the
USQUE convention), ``P_theta = J L L' J'``, ``J = diag(I_3 / c, I_3)``.

**Predict** over ``dt`` with the mean gyro rate ``w``: cubature points ``X_i`` of
``([dp_hat; beta_hat], L)``; sigma-quaternions ``q_i = q_ref ⊗ dq(dp_i)`` propagated with the
closed-form transition ``q_i ⊗ exp((w - beta_i) dt)`` (:func:`drake_att.rotations.quat_propagate`,
exact for a constant rate); the cubature rule has no central point, so the new reference is
the mean quaternion propagated with ``w - beta_hat``; each point back to GRP relative to it:
``f_i = [dp_i^+; beta_i]``. With the multiplicative-noise terms (CQE-MCNS,
:mod:`drake_att.filters.multiplicative_noise`): ``g_i = Phi u_i``, ``u_i = (w - beta_i) dt``,
``Phi = c kappa [I_3; 0]``, and the conditional moments ``(M, U)`` of ``zeta``::

    x^- = mean_i f_i + M mean_i g_i
    P^- = mean_i (f_i + M g_i - x^-)(...)' + U mean_i g_i g_i' + Q

(the patent's ``(I + M Phi) F (I + M Phi)' + U Phi F Phi' + Q - x x'``). Computed in square-root
form: ``L^- = tria([(f_i + M g_i - x^-) / sqrt(2n), sqrt(U / 2n) g_i, L_Q])`` (QR), so ``P^-``
is positive semi-definite by construction. ``Q`` is the Farrenkopf process noise of
:func:`drake_att.filters.mekf.process_noise` (exact for the interval-mean gyro, rotation of
the error frame within a step neglected), scaled to GRP units by ``diag(c I_3, I_3)``. The
CQE is the same with ``M = U = 0``.

**Update** with ``m`` directions ``d_i`` (sensor frame) of references ``r_i``, noise
``sigma`` per component: fresh cubature points from ``(x^-, L^-)``;
``Z_i = R_SB R(q_ref ⊗ dq(dp_i))' r`` (3m); ``P_zz = cov(Z) + sigma^2 I``, ``P_xz``,
``K = P_xz P_zz^-1``, ``x^+ = x^- + K (y - mean Z)``; square-root Joseph form
``L^+ = tria([(X_i - x^-) - K (Z_i - z^-)] / sqrt(2n), sigma K)`` (= ``P - K P_zz K'``, PSD by
construction); then ``q_ref <- q_ref ⊗ dq(dp^+)``, ``dp_hat <- 0``. This is the paper's update
and the first iteration of the one used here (next paragraph). CQE-MCNS also stores
``M = S' P_zz^-1 nu``, ``S' P_zz^-1 S`` (``U = Q_zeta - S' P_zz^-1 S``) and ``-K S`` in the state for
the next predict, which resets them (a predict not preceded by an update uses ``M = 0``,
``U = Q_zeta``). A singular or non-positive-definite ``P_zz``, non-finite numbers, mismatched
shapes, a negative sigma, or (MCNS) more stars than the noise model admits give
``UpdateInfo(accepted=False)`` and the state unchanged; never a raise.

**Deviations from the paper** (each measured in ``tests/test_cubature.py``; the paper's
behaviour stays available):

* *Iterated update* (``update_iterations``, default 10; 1 = the paper). From the paper's
  [-45, 45, 155] deg initial error (a 175 deg rotation) with 2 arcsec stars, one cubature
  update leaves the estimate ~167 deg off yet explains the measurement by
  a linear fit over the +-98 deg points almost exactly: the attitude sigma collapses to
  ~2 arcsec while the mean moves ~10 deg; the filter then slews its bias to ~1e4 deg/h and
  stays beyond 0.01 deg until ~6800 s (bias RMS over orbits 2-3: 0.3 deg/h). Here the
  update is iterated (iterated posterior linearization, Garcia-Fernandez et al. 2015):
  relinearize ``h`` about the current posterior
  ``N(x_j, L_j L_j')`` (``H = A L_j^-1``, ``A = Zc' xi / sqrt(2n)``, residual
  ``Omega = Zr' Zr``), redo the update of the prior with that linear model, until the mean moves
  less than ``iteration_tolerance`` posterior sigmas. The first iteration is the paper's
  update; if its linearization residual is below ``tol^2 3m sigma^2`` (``h`` linear over the
  prior: every nominal update) it is the only one. Both cores are within arcseconds after the
  first update.
* *Gate on M* (``zeta_gate_sigmas``, default 4; None = the paper). Under the model
  ``M ~ N(0, S' P_zz^-1 S)``; an innovation that puts ``|M|`` beyond 4 of its sigmas is not the
  model's (e.g. a transient) and Lemma 1's ``M`` would be absurd (1e4 at the first update
  above): then ``M = 0, U = Q_zeta``.
* *Optional correction* (``zeta_state_correlation``, default False = the paper). The patent's
  prediction treats ``x_k`` and ``zeta_k`` as independent given the data, but the update used
  ``v_k``: ``Cov(x_k, zeta_k | D_k) = -K S``. With it, ``zeta``'s conditional mean at each cubature
  point is ``M + b' xi_i`` (``b = L^-1 (-K S)``) and its variance ``U - b'b``. Negligible at the
  paper's numbers; with a star sample every step and ``rho = 0.33`` the literal filter's NEES
  is ~200 and the corrected one's ~6.

One implementation: :class:`CubatureQuaternionEstimator` is the core;
:class:`CubatureQuaternionEstimatorMCNS` is the same class given a
:class:`~drake_att.filters.multiplicative_noise.MultiplicativeNoiseModel` (the ``zeta`` terms
are that component; without it they are absent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import SecondQuantity, UpdateInfo, VectorObservations
from drake_att.filters.mekf import process_noise
from drake_att.filters.multiplicative_noise import MultiplicativeNoiseModel
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
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
    R = np.linalg.qr(A_rows, mode="r")
    s = np.where(np.diag(R) < 0.0, -1.0, 1.0)
    return (R * s[:, None]).T


_EYE3 = np.eye(3)
_XI6 = cubature_rule(STATE_DIM)[0]
_W6 = 1.0 / math.sqrt(2 * STATE_DIM)
_XI6W = _XI6 * _W6  # orthonormal columns: _XI6W' _XI6W = I
# Hamilton product as a bilinear form: (p ⊗ q)_i = sum_jk _HAMILTON[i, j, k] p_j q_k.
_HAMILTON = np.array([[rot.quat_multiply(np.eye(4)[j], np.eye(4)[k]) for k in range(4)]
                      for j in range(4)]).transpose(2, 0, 1)
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
    """State of the cubature cores (module docstring).

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

    def __init__(self, arw_rad_per_rt_s: float, rrw_rad_per_s15: float, grp_a: float = 1.0, grp_f: float = 4.0,
                 innovation_gate_chi2=None, noise_model: MultiplicativeNoiseModel | None = None,
                 zeta_gate_sigmas: float | None = 4.0, update_iterations: int = 10,
                 iteration_tolerance: float = 1e-2, zeta_state_correlation: bool = False):
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

    def initial_state(self, q_IB, bias_B, attitude_sigma_rad=None, bias_sigma_rad_per_s=None,
                      covariance0=None) -> CubatureState:
        """State at ``q_IB`` (4), ``bias_B`` (3) with per-axis (or scalar) 1-sigmas (rotation
        vector, rad; bias, rad/s) or a full 6x6 ``covariance0`` of ``[dtheta_B; dbias]``."""
        q = check_quaternion("q_IB", q_IB)
        b = check_array("bias_B", bias_B, (3,), " (rad/s)")
        if covariance0 is None:
            if attitude_sigma_rad is None or bias_sigma_rad_per_s is None:
                fail("covariance0", covariance0, "give covariance0 or both attitude and bias sigmas")
            sig = np.concatenate([np.broadcast_to(np.asarray(attitude_sigma_rad, dtype=float), 3),
                                  np.broadcast_to(np.asarray(bias_sigma_rad_per_s, dtype=float), 3)])
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
        return np.concatenate([state.q_ref, state.dp, state.bias_B, np.asarray(state.sqrt_P).ravel(),
                               [state.zeta_mean, state.zeta_var_reduction], state.zeta_cross])

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
            raise TypeError(f"{type(self).__name__}.update: got a {type(measurement).__name__}; "
                            "allowed: VectorObservations")
        return self.update_vectors(state, measurement.directions_S, measurement.references_I,
                                   measurement.sigma_rad, measurement.q_BS)

    def update_vectors(self, state: CubatureState, directions_S, references_I, sigma_rad: float,
                       q_BS=(1.0, 0.0, 0.0, 0.0)) -> tuple[CubatureState, UpdateInfo]:
        """Update with ``m`` measured directions (m, 3, sensor frame) of inertial references (m, 3)."""
        rejected = UpdateInfo(None, None, float("nan"), False)
        try:
            y = np.asarray(directions_S, dtype=float)
            refs = np.asarray(references_I, dtype=float)
            q_BS = np.asarray(q_BS, dtype=float)
            sigma = float(sigma_rad)
        except (TypeError, ValueError):
            return state, rejected
        if (y.ndim != 2 or y.shape[1] != 3 or y.shape != refs.shape or y.shape[0] < 1 or q_BS.shape != (4,)
                or not (np.all(np.isfinite(y)) and np.all(np.isfinite(refs)) and np.all(np.isfinite(q_BS)))
                or not (math.isfinite(sigma) and sigma >= 0.0) or not float(q_BS @ q_BS) > 1e-18):
            return state, rejected
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
                    return state, UpdateInfo(y.ravel() - z_bar, Zc.T @ Zc + (sigma * sigma) * eye_m, float("nan"), False)
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
        new = CubatureState(q_ref, np.zeros(3), xj[3:], Lj, M, D, cross)
        return new, UpdateInfo(nu, Pzz, nis, True)


class CubatureQuaternionEstimatorMCNS(CubatureQuaternionEstimator):
    """CQE-MCNS: the CQE with the multiplicative-noise terms of ``noise_model`` (module
    docstring; model in :mod:`drake_att.filters.multiplicative_noise`).

    Args: as :class:`CubatureQuaternionEstimator`; ``noise_model`` is required (default:
    :meth:`MultiplicativeNoiseModel.paper`).
    """

    def __init__(self, arw_rad_per_rt_s: float, rrw_rad_per_s15: float, grp_a: float = 1.0, grp_f: float = 4.0,
                 innovation_gate_chi2=None, noise_model: MultiplicativeNoiseModel | None = None,
                 zeta_gate_sigmas: float | None = 4.0, update_iterations: int = 10,
                 iteration_tolerance: float = 1e-2, zeta_state_correlation: bool = False):
        super().__init__(arw_rad_per_rt_s, rrw_rad_per_s15, grp_a, grp_f, innovation_gate_chi2,
                         MultiplicativeNoiseModel.paper() if noise_model is None else noise_model, zeta_gate_sigmas,
                         update_iterations, iteration_tolerance, zeta_state_correlation)


__all__ = ["cubature_rule", "cubature_points", "triangularize", "CubatureState", "CubatureQuaternionEstimator",
           "CubatureQuaternionEstimatorMCNS"]
