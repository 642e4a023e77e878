"""The S0 particle filters' and the MRP EKF's steps in readable numpy: the oracle of the
compiled kernels.

:mod:`drake_att.filters.particle_kernels` is the one implementation the library runs; this
module writes the same formulas with batched numpy arrays (docs/derivations/mrp_ekf.md and
particle_filters.md): the MRP EKF's model, Jacobians, time and measurement updates and
shadow switch, the star-sensor log-likelihood, the bootstrap and gyroless propagations and
the EKPF's proposal step. The ``Reference*`` cores are the library's cores
(:mod:`drake_att.filters.particle`, :class:`~drake_att.filters.mrp_ekf.MrpEkfCore`) whose
``predict`` and ``update`` are these: the same random numbers drawn from the same generator
in the same order, the same weight normalization and resampling.
``tests/test_particle_kernels.py`` compares the two to round-off (bit for bit for the
bootstrap and gyroless steps, whose kernels repeat these scalar expressions).
"""

from __future__ import annotations

import numpy as np

from drake_att.contract import UpdateInfo
from drake_att.filters.mrp_ekf import MrpEkfCore, MrpEkfState, body_frame_vectors, gyro_rate, mrp_kinematics_inverse
from drake_att.filters.particle import (
    _DECLINED,
    BootstrapPfCore,
    EkpfCore,
    GyrolessPfCore,
    ParticleSetState,
    _check_rng,
    _paired_cholesky,
)
from drake_att.rotations import (
    mrp_kinematics_matrix,
    mrp_to_quat,
    mrp_to_rotmat,
    quat_multiply,
    quat_propagate,
    quat_to_mrp,
    rotvec_to_quat,
    skew,
)
from drake_att.validation import check_positive


# ----------------------------------------------------------------------------------
# The MRP EKF (batched over leading dimensions)
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
    return 0.5 * (rho[..., :, None] * w[..., None, :] - w[..., :, None] * rho[..., None, :] - skew(w) + rw * eye)


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


def mrp_shadow_jacobian(rho) -> np.ndarray:
    """Jacobian of the shadow map ``s(rho) = -rho / |rho|^2``.

    ``ds/drho = (2 rho rho' - |rho|^2 I) / |rho|^4`` (a scaled reflection; at
    ``|rho| = 1`` it is the Householder-like ``2 rho rho' - I``).
    """
    rho = np.asarray(rho, dtype=float)
    n2 = np.sum(rho * rho, axis=-1)[..., None, None]
    return (2.0 * rho[..., :, None] * rho[..., None, :] - n2 * np.eye(3)) / n2**2


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
    """Discrete process noise of the gyro-mode model (docs/derivations/mrp_ekf.md).

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
    Qg[..., :3, :3] = sigma_v**2 * (B @ np.swapaxes(B, -1, -2))
    Qg[..., 3:, 3:] = sigma_u**2 * np.eye(3)
    FQ = F @ Qg
    return Qg * dt + (FQ + np.swapaxes(FQ, -1, -2)) * (0.5 * dt**2) + (FQ @ np.swapaxes(F, -1, -2)) * (dt**3 / 3.0)


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
    """Batched EKF time update of ``x = [rho; b]`` (docs/derivations/mrp_ekf.md).

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


def ekf_update(
    x, P, y, ref_vectors_I, sigma: float, switch: bool = True, iterations: int = 1, iteration_tolerance: float = 1e-12
):
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
    R = sigma**2 * np.eye(n_meas)
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
    P_new = _sym(IKH @ P @ np.swapaxes(IKH, -1, -2) + (K * sigma**2) @ np.swapaxes(K, -1, -2))
    x_new = x_j
    if switch:
        x_new, P_new, _ = switch_to_short_mrp(x_new, P_new)
    return x_new, P_new, innovation0, S0


# ----------------------------------------------------------------------------------
# The particle filters' steps
# ----------------------------------------------------------------------------------
def vector_log_likelihood(rho, y, ref_vectors_I, sigma: float) -> np.ndarray:
    """Gaussian log-likelihood (up to a common constant) of ``y`` per particle.

    ``log p(y | rho_i) = -|y - h(rho_i)|^2 / (2 sigma^2)`` with
    ``h(rho) = [R_BI u_1; ...]`` (:func:`vector_measurement_model`).

    Args:
        rho: ``(N, 3)`` MRPs of ``q_IB``. y: ``(3m,)``. ref_vectors_I: ``(m, 3)``.
        sigma: Noise std per component (rad).

    Returns:
        ``(N,)`` log-likelihoods (non-finite entries replaced by ``-inf``).
    """
    r = np.asarray(y, dtype=float) - vector_measurement_model(rho, ref_vectors_I)
    ll = -0.5 * np.sum(r * r, axis=-1) / sigma**2
    ll[~np.isfinite(ll)] = -np.inf
    return ll


def propagate_attitudes(rho, w, dt: float) -> np.ndarray:
    """The bootstrap PF's attitude step: short MRPs of ``q(rho_i) ⊗ exp(w_i dt / 2)``."""
    return quat_to_mrp(quat_multiply(mrp_to_quat(rho), rotvec_to_quat(w * dt)))


def euler_rate_derivative(w, torque, inertia, inertia_inverse):
    """``I^-1 (T - w x (I w))`` for ``(N, 3)`` rates."""
    Iw = w @ inertia.T
    return (torque - np.cross(w, Iw)) @ inertia_inverse.T


def gyroless_propagate(rho, w, inertia, inertia_inverse, torque, h: float, num_substeps: int, dtheta=None):
    """The deterministic step of the gyroless PF: ``num_substeps`` RK4 substeps of ``h`` on
    Euler's equations, the attitude advanced by the closed form with the Simpson average of the
    stage rates, then ``q <- q ⊗ exp(dtheta / 2)`` if ``dtheta`` is given.
    Returns ``(rho (N, 3) short MRPs, w (N, 3))``."""
    I, I_inv, T = inertia, inertia_inverse, torque
    q = mrp_to_quat(rho)
    w = np.array(w, dtype=float)
    for _ in range(num_substeps):
        k1 = euler_rate_derivative(w, T, I, I_inv)
        wa = w + 0.5 * h * k1
        k2 = euler_rate_derivative(wa, T, I, I_inv)
        wb = w + 0.5 * h * k2
        k3 = euler_rate_derivative(wb, T, I, I_inv)
        w1 = w + h * k3
        k4 = euler_rate_derivative(w1, T, I, I_inv)
        w_avg = (w + 2.0 * wa + 2.0 * wb + w1) / 6.0
        q = quat_multiply(q, rotvec_to_quat(w_avg * h))
        w = w + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    if dtheta is not None:
        q = quat_multiply(q, rotvec_to_quat(dtheta))
    return quat_to_mrp(q), w


def ekpf_proposal_step(m_prior, P_prior, y, ref_vectors_I, sigma: float, eps, iterations: int = 1):
    """The EKPF's measurement step.

    Every particle's EKF update of ``(m-, P-)`` gives the proposal ``N(m+, P+)``; the draw is
    ``x = m+ + L+ eps`` with the given standard normals ``eps`` ``(N, 6)``, and the log-weight
    increment ``log p(y | x) + log pi(x) - log q(x)`` with the prior ``pi = N(m-, P-)``
    (docs/derivations/particle_filters.md), all in the MRP chart of ``m-``. The Cholesky
    factors are the library's :func:`~drake_att.filters.particle._paired_cholesky` (repaired
    together when either is not positive definite).

    Returns:
        ``(x (N, 6), P+ (N, 6, 6), log-weight increments (N,))``, shadow switch applied.
    """
    m_post, P_post, _, _ = ekf_update(m_prior, P_prior, y, ref_vectors_I, sigma, switch=False, iterations=iterations)
    L_prior, L_post = _paired_cholesky(P_prior, P_post)
    # Proposal draw x = m+ + L eps, log q(x) = -|eps|^2/2 - log det L (+ const).
    x = m_post + (L_post @ eps[:, :, None])[:, :, 0]
    log_q = -0.5 * np.sum(eps * eps, axis=1) - np.sum(np.log(np.diagonal(L_post, axis1=1, axis2=2)), axis=1)
    z = np.linalg.solve(L_prior, (x - m_prior)[:, :, None])[:, :, 0]
    log_pi = -0.5 * np.sum(z * z, axis=1) - np.sum(np.log(np.diagonal(L_prior, axis1=1, axis2=2)), axis=1)
    log_lik = vector_log_likelihood(x[:, :3], y, ref_vectors_I, sigma)
    x, P, _ = switch_to_short_mrp(x, P_post)
    return x, P, log_lik + log_pi - log_q


# ----------------------------------------------------------------------------------
# The cores on the numpy steps
# ----------------------------------------------------------------------------------
class ReferenceMrpEkfCore(MrpEkfCore):
    """:class:`MrpEkfCore` with the numpy time and measurement updates above."""

    def predict(self, state: MrpEkfState, w_meas_B, dt: float, rng=None) -> MrpEkfState:
        dt = check_positive("dt", dt)
        x, P = ekf_predict(state.x, state.P, gyro_rate(w_meas_B), dt, self.arw_rad_per_rt_s, self.rrw_rad_per_s15)
        return MrpEkfState(x, P)

    def update(self, state: MrpEkfState, observations, rng=None):
        y_B, U, sigma = body_frame_vectors(observations)
        if y_B is None:
            return state, UpdateInfo(None, None, float("nan"), False)
        x, P, innov, S = ekf_update(state.x, state.P, y_B, U, sigma, iterations=self.update_iterations)
        nis = float(innov @ np.linalg.solve(S, innov))
        if self.gate.rejects(nis, len(innov)):
            return state, UpdateInfo(innov, S, nis, False)
        return MrpEkfState(x, P), UpdateInfo(innov, S, nis, True)


class _NumpyLikelihood:
    """The bootstrap update (weight by the star-sensor likelihood, resample) on
    :func:`vector_log_likelihood`."""

    def update(self, state: ParticleSetState, observations, rng: np.random.Generator):
        _check_rng(rng)
        y, U, sigma = body_frame_vectors(observations)
        if y is None:
            return state, _DECLINED
        log_likelihood = vector_log_likelihood(state.particles[:, :3], y, U, sigma)
        return self._reweighted(state, state.particles, None, log_likelihood, rng)


class ReferenceBootstrapPfCore(_NumpyLikelihood, BootstrapPfCore):
    """:class:`BootstrapPfCore` with the numpy propagation and likelihood."""

    def predict(self, state: ParticleSetState, w_meas_B, dt: float, rng: np.random.Generator) -> ParticleSetState:
        dt = check_positive("dt", dt)
        _check_rng(rng)
        rho, b = state.particles[:, :3], state.particles[:, 3:]
        w = gyro_rate(w_meas_B) - b
        if self.arw_rad_per_rt_s > 0.0:
            w = w - rng.standard_normal((self.num_particles, 3)) * (self.arw_rad_per_rt_s / np.sqrt(dt))
        particles = np.empty_like(state.particles)
        particles[:, :3] = propagate_attitudes(rho, w, dt)
        particles[:, 3:] = self.bias_roughening.apply(b, dt, rng)
        return ParticleSetState(particles, state.weights, state.log_weights)


class ReferenceGyrolessPfCore(_NumpyLikelihood, GyrolessPfCore):
    """:class:`GyrolessPfCore` with the numpy propagation and likelihood."""

    def predict(self, state: ParticleSetState, w_meas_B, dt: float, rng: np.random.Generator) -> ParticleSetState:
        dt = check_positive("dt", dt)
        _check_rng(rng)
        n = self.num_particles
        dtheta = None  # the attitude noise, applied after the deterministic step, drawn first
        if self.attitude_process_sigma > 0.0:
            dtheta = rng.standard_normal((n, 3)) * (self.attitude_process_sigma * np.sqrt(dt))
        rho, w = gyroless_propagate(
            state.particles[:, :3],
            state.particles[:, 3:],
            self.inertia,
            self.inertia_inverse,
            self.torque,
            dt / self.num_substeps,
            self.num_substeps,
            dtheta,
        )
        if self.rate_process_sigma > 0.0:
            w = w + rng.standard_normal((n, 3)) * (self.rate_process_sigma * np.sqrt(dt))
        return ParticleSetState(np.concatenate([rho, w], axis=1), state.weights, state.log_weights)


class ReferenceEkpfCore(EkpfCore):
    """:class:`EkpfCore` with the numpy EKF time update and proposal step."""

    def predict(self, state: ParticleSetState, w_meas_B, dt: float, rng=None) -> ParticleSetState:
        dt = check_positive("dt", dt)
        particles, covariances = ekf_predict(
            state.particles, state.covariances, gyro_rate(w_meas_B), dt, self.arw_rad_per_rt_s, self.rrw_rad_per_s15
        )
        return ParticleSetState(particles, state.weights, state.log_weights, covariances)

    def update(self, state: ParticleSetState, observations, rng: np.random.Generator):
        _check_rng(rng)
        y, U, sigma = body_frame_vectors(observations)
        if y is None:
            return state, _DECLINED
        eps = rng.standard_normal((self.num_particles, 6))
        particles, covariances, log_increment = ekpf_proposal_step(
            state.particles, state.covariances, y, U, sigma, eps, self.proposal_iterations
        )
        return self._reweighted(state, particles, covariances, log_increment, rng)
