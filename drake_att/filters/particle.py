"""Particle filters of paper S0 (Zhang & Sun 2012) as pure filter cores, vectorized over
particles.

Three cores, each a :class:`drake_att.contract.FilterCore` on an immutable
:class:`ParticleSetState` (particles ``(N, 6)`` ``[rho; s]``, normalized weights and their
logs, and the EKPF's per-particle covariances):

* :class:`BootstrapPfCore` — SIR in gyro mode, ``s`` = gyro bias; the proposal is the
  transition prior, the bias static (paper) or roughened by a :class:`RandomWalkRoughening`.
* :class:`EkpfCore` — extended-Kalman PF: every particle carries an MRP EKF (the one of
  :mod:`drake_att.filters.mrp_ekf`, batched) whose posterior is its proposal.
* :class:`GyrolessPfCore` — SIR with ``s`` = body rate, propagated by Euler's equations.

They share one measurement model (star sensor, vectors rotated into the body frame)::

    y = [R_BI u_1; ...; R_BI u_m] + v,   v ~ N(0, sigma^2 I_3m),   R_BI = R(q_IB)'

one update rule (log-weights incremented, normalized by log-sum-exp so they stay finite
when every likelihood underflows; then the resampling components decide) and one estimate:
Markley's weighted quaternion average and the weighted second moment of
``[dtheta_B; s - s_hat]`` about it (:func:`weighted_mean_and_covariance`). Resampling is
two components passed to each core: when (:class:`EffectiveSampleSizeGate`, paper:
``N_eff < 2/3 N``) and which particles (:class:`SystematicResampler`). ``update`` reports
``N_eff``, resampling and degenerate weights in :class:`~drake_att.contract.UpdateInfo`;
the cores count nothing.

Randomness: every draw comes from the ``rng`` passed to ``draw_initial_state``,
``predict`` or ``update``, in a fixed order; the same generators give bit-identical states.

Step arithmetic: the compiled kernels of :mod:`drake_att.filters.particle_kernels` (the
propagations, the likelihood, the EKPF's EKF steps, proposal draw and weights), their one
implementation; the readable numpy form is the tests' oracle (``tests/particle_reference.py``).
Here: the random draws (passed to the kernels), weight normalization, resampling, the
estimate and the EKPF's repair of Cholesky factors that are not positive definite.

Derivations and measured behaviour: docs/derivations/particle_filters.md

Units: SI and radians (rad, rad/s, ARW rad/s^0.5, RRW / process noise rad/s^1.5).

Three cores on one state type with the components they share; apart they would import each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att.contract import SecondQuantity, UpdateInfo
from drake_att.filters import particle_kernels as _kernels
from drake_att.filters.mrp_ekf import attitude_to_mrp_covariance, body_frame_vectors, gyro_rate
from drake_att.filters.quaternion_average import average_quaternions
from drake_att.rotations import (
    mrp_to_quat,
    quat_error_rotvec,
    quat_multiply,
    quat_to_mrp,
    rotvec_to_quat,
)
from drake_att.validation import (
    check_array,
    check_covariance,
    check_int,
    check_positive,
    check_quaternion,
    fail,
)

__all__ = [
    "effective_sample_size",
    "systematic_resample",
    "normalize_log_weights",
    "weighted_mean_and_covariance",
    "SystematicResampler",
    "EffectiveSampleSizeGate",
    "RandomWalkRoughening",
    "ParticleSetState",
    "BootstrapPfCore",
    "EkpfCore",
    "GyrolessPfCore",
]


# ----------------------------------------------------------------------------------
# Weights and resampling
# ----------------------------------------------------------------------------------
def _check_rng(rng, name: str = "rng") -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        fail(name, rng, "must be a numpy.random.Generator (e.g. numpy.random.default_rng(seed))")
    return rng


def _check_weights(weights) -> np.ndarray:
    try:
        w = np.asarray(weights, dtype=float)
    except (TypeError, ValueError):
        fail("weights", weights, "must be a real array of shape (N,)")
    if w.ndim != 1 or w.size < 1:
        fail("weights", w, f"must have shape (N,) with N >= 1, not {w.shape}")
    bad = ~np.isfinite(w) | (w < 0.0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        fail(f"weights[{i}]", w[i], "must be finite and >= 0")
    total = float(np.sum(w))
    if not total > 0.0:
        fail("sum(weights)", total, "must be > 0")
    return w / total


def effective_sample_size(weights) -> float:
    """``N_eff = 1 / sum(w_i^2)`` of the normalized weights (between 1 and N).

    Args:
        weights: ``(N,)`` non-negative weights (normalized internally).
    """
    w = _check_weights(weights)
    return float(1.0 / np.sum(w * w))


def systematic_resample(weights, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: indices of the ``N`` offspring (sorted, int64).

    One uniform ``u ~ U[0, 1)`` gives the positions ``(u + j) / N``, ``j = 0..N-1``;
    particle ``i`` gets ``floor`` or ``ceil`` of ``N w_i`` offspring and exactly
    ``N w_i`` in expectation (unbiased), with the lowest variance of the standard schemes.

    Args:
        weights: ``(N,)`` non-negative weights (normalized internally).
        rng: Random generator (one draw).

    Returns:
        ``(N,)`` integer indices into the particle set.
    """
    w = _check_weights(weights)
    _check_rng(rng)
    n = w.size
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(w)
    cumulative[-1] = 1.0  # guard against round-off: every position < 1 finds a bin
    return np.searchsorted(cumulative, positions, side="right").astype(np.int64)


def normalize_log_weights(log_weights) -> tuple[np.ndarray, np.ndarray]:
    """Normalize log-weights with log-sum-exp.

    Non-finite entries (NaN, +-inf) are treated as ``-inf`` (weight 0). If all entries
    are ``-inf`` the weights are reset to uniform.

    Returns:
        ``(weights, log_weights)`` — normalized weights (finite, sum 1) and their logs.
    """
    lw = np.array(log_weights, dtype=float)
    lw[~np.isfinite(lw)] = -np.inf
    top = np.max(lw)
    if not np.isfinite(top):
        n = lw.size
        return np.full(n, 1.0 / n), np.full(n, -np.log(n))
    shifted = np.exp(lw - top)
    total = np.sum(shifted)
    w = shifted / total
    return w, lw - (top + np.log(total))


# ----------------------------------------------------------------------------------
# Components the cores take (Stone Soup's split: resampler / when to resample /
# regulariser); each is a small frozen object, tested on its own.
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class SystematicResampler:
    """Which particles survive a resampling: :func:`systematic_resample` (one uniform draw)."""

    def indices(self, weights, rng: np.random.Generator) -> np.ndarray:
        """``(N,)`` offspring indices (sorted) for normalized ``weights``."""
        return systematic_resample(weights, rng)


@dataclass(frozen=True)
class EffectiveSampleSizeGate:
    """When to resample: after an update whose ``N_eff < threshold * N``.

    ``threshold`` in ``[0, 1]``: 0 never resamples, 2/3 is paper S0's rule, 1 resamples
    whenever the weights are not all equal."""

    threshold: float = 2.0 / 3.0

    def __post_init__(self):
        t = check_positive("resample_threshold", self.threshold, allow_zero=True)
        if t > 1.0:
            fail("resample_threshold", t, "must be in [0, 1] (fraction of N; paper 2/3)")

    def should_resample(self, effective_sample_size: float, num_particles: int) -> bool:
        return effective_sample_size < self.threshold * num_particles


@dataclass(frozen=True)
class RandomWalkRoughening:
    """Regulariser: a random walk ``x_i <- x_i + N(0, sigma^2 dt I)`` on a block of every
    particle (e.g. the gyro bias), restoring the diversity resampling removes.

    ``sigma``: density (units of the block per sqrt(s)), >= 0; 0 draws nothing."""

    sigma: float = 0.0

    def __post_init__(self):
        check_positive("roughening sigma", self.sigma, allow_zero=True)

    def apply(self, block: np.ndarray, dt: float, rng: np.random.Generator) -> np.ndarray:
        """The roughened ``(N, k)`` block (a new array; ``block`` itself if ``sigma = 0``)."""
        if self.sigma == 0.0:
            return block
        return block + rng.standard_normal(block.shape) * (self.sigma * np.sqrt(dt))


# ----------------------------------------------------------------------------------
# Pieces of the cores
# ----------------------------------------------------------------------------------
def _sample_initial_attitudes(num_particles, q0, s0, covariance0, rng):
    """Draw ``q_i = q0 ⊗ exp(dtheta_i / 2)``, ``s_i = s0 + ds_i``, ``[dtheta; ds] ~ N(0, P0)``.

    Sampling on the rotation group (rather than additively in MRP space as the paper)
    gives the same distribution to first order and stays exact for any attitude.
    Returns ``(rho (N, 3), s (N, 3))`` with ``|rho| <= 1``.
    """
    L = np.linalg.cholesky(covariance0)
    d = rng.standard_normal((num_particles, 6)) @ L.T
    q = quat_multiply(q0, rotvec_to_quat(d[:, :3]))
    return quat_to_mrp(q), s0 + d[:, 3:]


def _paired_cholesky(P_prior, P_post):
    """Batched lower Cholesky factors of the EKPF's prior and proposal covariances.

    If either is not positive definite (a zero-variance block, e.g. a known bias, or
    round-off), both are repaired by clipping their eigenvalues at one common floor per
    particle, ``1e-12`` x the larger of the two largest eigenvalues, so a direction
    singular in both gets the same variance in both and cancels in the weight ``pi / q``
    (docs/derivations/particle_filters.md)."""
    try:
        return np.linalg.cholesky(P_prior), np.linalg.cholesky(P_post)
    except np.linalg.LinAlgError:
        pairs = [np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2))) for P in (P_prior, P_post)]
        largest = np.maximum(pairs[0][0][..., -1:], pairs[1][0][..., -1:])  # eigh: ascending
        floor = 1e-12 * np.maximum(largest, 1e-300)
        return tuple(
            np.linalg.cholesky((vecs * np.maximum(vals, floor)[..., None, :]) @ np.swapaxes(vecs, -1, -2))
            for vals, vecs in pairs
        )


def _repaired_proposal_step(m_prior, P_prior, eps, y, ref_vectors_I, sigma: float, iterations: int):
    """The EKPF's measurement step when a Cholesky factor of some ``P-`` or ``P+`` failed: every
    particle's EKF update, both factors repaired together (:func:`_paired_cholesky`), then the
    kernels' draw and weights (:func:`drake_att.filters.particle_kernels.ekpf_draw`) on them."""
    m_post, P_post, _, _ = _kernels.ekf_update(
        m_prior, P_prior, y, ref_vectors_I, sigma, switch=False, iterations=iterations
    )
    L_prior, L_post = _paired_cholesky(P_prior, P_post)
    return _kernels.ekpf_draw(m_prior, m_post, P_post, L_prior, L_post, eps, y, ref_vectors_I, sigma)


def weighted_mean_and_covariance(particles, weights):
    """``(q_IB_hat (4), s_hat (3), covariance (6, 6))`` of a weighted particle set.

    The attitude is Markley's weighted quaternion average (largest eigenvector of
    ``sum w_i q_i q_i'``, invariant to the sign of each ``q_i``), ``s_hat`` the weighted
    mean; the covariance is the weighted second moment of ``[dtheta_B,i; s_i - s_hat]``
    with ``dtheta_B,i = log(q_hat^-1 ⊗ q_i)`` about the reported mean (the particle
    approximation of the estimate's error covariance).
    """
    rho, s = particles[:, :3], particles[:, 3:]
    q = mrp_to_quat(rho)
    q_hat = average_quaternions(q, weights)
    s_hat = weights @ s
    e = np.empty((rho.shape[0], 6))
    e[:, :3] = quat_error_rotvec(q_hat, q)
    e[:, 3:] = s - s_hat
    C = (e * weights[:, None]).T @ e
    return q_hat, s_hat, 0.5 * (C + C.T)


def _component(field: str, value, method: str):
    """``value`` if it has the component's method, else TypeError naming the argument."""
    if not callable(getattr(value, method, None)):
        fail(field, value, f"must have a method {method}()", TypeError)
    return value


# ----------------------------------------------------------------------------------
# The state and the cores
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class ParticleSetState:
    """A particle filter's state.

    Attributes:
        particles: ``(N, 6)`` ``[rho; s]`` (MRP of ``q_IB`` with ``|rho| <= 1``; bias or
            body rate, rad/s).
        weights: ``(N,)`` normalized weights. log_weights: ``(N,)`` their logs.
        covariances: ``(N, 6, 6)`` per-particle EKF covariances in each particle's MRP chart
            (EKPF), else None.
        estimate_set: after an update that resampled, the weighted set ``(particles,
            weights)`` from just before resampling, which :meth:`estimate` uses (same
            expectation, less Monte Carlo noise); None otherwise. Not stored by
            ``to_vector``.
    """

    particles: np.ndarray
    weights: np.ndarray
    log_weights: np.ndarray
    covariances: np.ndarray | None = None
    estimate_set: tuple | None = None


_DECLINED = UpdateInfo(None, None, float("nan"), False)


class _ParticleCore:
    """What the three cores share: the prior and its draw, reweighting and resampling, the
    estimate and the state vector ``[particles (N*6, row-major), weights (N), log weights
    (N)]`` (+ ``covariances (N*36)`` for the EKPF)."""

    is_random = True
    _has_covariances = False

    def __init__(self, num_particles, q_IB_hat0, second0, covariance0, second_field: str, resampling_gate, resampler):
        self.num_particles = check_int("num_particles", num_particles, 1)
        self.resampling_gate = _component("resampling_gate", resampling_gate, "should_resample")
        self.resampler = _component("resampler", resampler, "indices")
        self.q_IB_hat0 = check_quaternion("q_IB_hat0", q_IB_hat0)
        self.second0 = check_array(second_field, second0, (3,), " (rad/s)")
        self.covariance0 = check_covariance("covariance0", covariance0, 6)
        self.state_size = self.num_particles * (8 + (36 if self._has_covariances else 0))

    def _uniform(self):
        n = self.num_particles
        return np.full(n, 1.0 / n), np.full(n, -np.log(n))

    def draw_initial_state(self, rng: np.random.Generator) -> ParticleSetState:
        """A particle set drawn from the prior ``N([q_IB_hat0; second0], covariance0)`` on the
        rotation group, with uniform weights (EKPF: every particle's covariance is
        ``covariance0`` in its own MRP chart)."""
        _check_rng(rng)
        rho, s = _sample_initial_attitudes(self.num_particles, self.q_IB_hat0, self.second0, self.covariance0, rng)
        weights, log_weights = self._uniform()
        covariances = attitude_to_mrp_covariance(rho, self.covariance0) if self._has_covariances else None
        return ParticleSetState(np.concatenate([rho, s], axis=1), weights, log_weights, covariances)

    def _reweighted(self, state: ParticleSetState, particles, covariances, log_increment, rng):
        """``(state, info)`` after adding ``log_increment`` to the log-weights of the moved
        ``particles`` (and ``covariances``), resampling if the gate says so."""
        lw = state.log_weights + log_increment
        degenerate = not np.any(np.isfinite(lw))
        weights, log_weights = normalize_log_weights(lw)
        ess = float(1.0 / np.sum(weights**2))
        estimate_set = None
        resampled = bool(self.resampling_gate.should_resample(ess, self.num_particles))
        if resampled:
            estimate_set = (particles, weights)
            idx = self.resampler.indices(weights, rng)
            particles = particles[idx]
            if covariances is not None:
                covariances = covariances[idx]
            weights, log_weights = self._uniform()
        return (
            ParticleSetState(particles, weights, log_weights, covariances, estimate_set),
            UpdateInfo(
                None, None, float("nan"), True, effective_sample_size=ess, resampled=resampled, degenerate=degenerate
            ),
        )

    def update(self, state: ParticleSetState, observations, rng: np.random.Generator):
        """Bootstrap update with a :class:`~drake_att.contract.VectorObservations` sample:
        weight by the star-sensor likelihood, resample if the gate says so. A sample with a
        missing or non-finite direction is declined (state unchanged)."""
        _check_rng(rng)
        y, U, sigma = body_frame_vectors(observations)
        if y is None:
            return state, _DECLINED
        log_likelihood = _kernels.vector_log_likelihood(state.particles[:, :3], y, U, sigma)
        return self._reweighted(state, state.particles, None, log_likelihood, rng)

    @staticmethod
    def estimate(state: ParticleSetState):
        """:func:`weighted_mean_and_covariance` of the state (of its ``estimate_set`` after a
        resampling update)."""
        particles, weights = state.estimate_set or (state.particles, state.weights)
        return weighted_mean_and_covariance(particles, weights)

    def to_vector(self, state: ParticleSetState) -> np.ndarray:
        parts = [np.asarray(state.particles).ravel(), state.weights, state.log_weights]
        if self._has_covariances:
            parts.append(np.asarray(state.covariances).ravel())
        return np.concatenate(parts)

    def from_vector(self, vector) -> ParticleSetState:
        n = self.num_particles
        s = np.asarray(vector, dtype=float)
        covariances = np.array(s[8 * n :]).reshape(n, 6, 6) if self._has_covariances else None
        return ParticleSetState(
            np.array(s[: 6 * n]).reshape(n, 6), np.array(s[6 * n : 7 * n]), np.array(s[7 * n : 8 * n]), covariances
        )


class BootstrapPfCore(_ParticleCore):
    """Bootstrap / SIR particle filter on ``x = [rho; b]`` (paper S0, gyro mode).

    Prediction per particle ``i`` (batched)::

        w_i   = w_meas - b_i - n_i,          n_i ~ N(0, arw_rad_per_rt_s^2 / dt I)
        q_i  <- q_i ⊗ exp(w_i dt / 2)          (closed form, exact for constant rate)
        rho_i = MRP(q_i) with |rho_i| <= 1     (shadow switch)
        b_i  <- bias_roughening(b_i)

    Update: ``log w_i += -|y - h(rho_i)|^2 / (2 sigma^2)``, then the resampling components.
    Without roughening the bias is static as in the paper, and resampling collapses the bias
    cloud (the paper's Fig. 2 finding); a :class:`RandomWalkRoughening` at the true RRW is the
    model-consistent SIR, larger values trade bias noise for diversity.

    Args:
        num_particles: ``N >= 1``.
        q_IB_hat0, bias_hat0, covariance0: the prior the initial set is drawn from:
            attitude (wxyz), bias (3, rad/s) and the (6, 6) covariance of
            ``[dtheta_B (rad); b (rad/s)]``.
        arw_rad_per_rt_s: gyro ARW ``sigma_v`` (rad/s^0.5) >= 0 of the attitude process
            noise (0: deterministic attitude propagation).
        bias_roughening: the bias regulariser (default: none, the paper).
        resampling_gate: when to resample (default ``N_eff < 2/3 N``, the paper).
        resampler: which particles survive (default systematic); any object with
            ``indices(weights, rng) -> (N,) int array``.
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True

    def __init__(
        self,
        num_particles: int,
        q_IB_hat0,
        bias_hat0,
        covariance0,
        arw_rad_per_rt_s: float,
        *,
        bias_roughening=RandomWalkRoughening(),
        resampling_gate=EffectiveSampleSizeGate(),
        resampler=SystematicResampler(),
    ):
        super().__init__(num_particles, q_IB_hat0, bias_hat0, covariance0, "bias_hat0", resampling_gate, resampler)
        self.arw_rad_per_rt_s = check_positive("arw_rad_per_rt_s", arw_rad_per_rt_s, allow_zero=True)
        self.bias_roughening = _component("bias_roughening", bias_roughening, "apply")

    def predict(self, state: ParticleSetState, w_meas_B, dt: float, rng: np.random.Generator) -> ParticleSetState:
        """Every particle propagated over ``dt`` (s) > 0 with the mean gyro rate ``w_meas_B``
        (rad/s); ``rng`` draws the ARW samples, then the roughening."""
        dt = check_positive("dt", dt)
        _check_rng(rng)
        w_meas = gyro_rate(w_meas_B)
        rho, b = state.particles[:, :3], np.ascontiguousarray(state.particles[:, 3:])  # b: read twice
        w = w_meas - b
        if self.arw_rad_per_rt_s > 0.0:
            w = w - rng.standard_normal((self.num_particles, 3)) * (self.arw_rad_per_rt_s / np.sqrt(dt))
        particles = np.empty_like(state.particles)
        particles[:, :3] = _kernels.propagate_attitudes(rho, w, dt)
        particles[:, 3:] = self.bias_roughening.apply(b, dt, rng)
        return ParticleSetState(particles, state.weights, state.log_weights)


class EkpfCore(_ParticleCore):
    """Extended-Kalman particle filter (EKPF, van der Merwe et al. 2000) on ``[rho; b]``.

    Each particle is a point ``x_i`` with an EKF covariance ``P_i`` (MRP chart of ``x_i``),
    batched with ``(N, 6, 6)`` arrays. ``predict``: every particle's EKF time update
    (:func:`~drake_att.filters.particle_kernels.ekf_predict`, deterministic). ``update``: every
    particle's EKF update is its proposal ``N(m+, P+)``; draw ``x_i`` from it and weight by
    ``p(y | x_i) pi(x_i) / q(x_i)`` with the particle's predicted Gaussian as the prior
    ``pi`` (:func:`~drake_att.filters.particle_kernels.ekpf_update`; why that prior, and what it
    costs: docs/derivations/particle_filters.md); then ``P_i = P+``, shadow switch, resampling
    (means and covariances copied). A declined sample leaves the predicted set (no draw).

    Args:
        num_particles: ``N >= 1``.
        q_IB_hat0, bias_hat0, covariance0: the prior (as :class:`BootstrapPfCore`);
            ``covariance0`` is also every particle's initial EKF covariance.
        arw_rad_per_rt_s: gyro ARW ``sigma_v`` (rad/s^0.5) > 0.
        rrw_rad_per_s15: gyro RRW ``sigma_u`` (rad/s^1.5) >= 0.
        proposal_iterations: linearizations of each particle's EKF update, >= 1: 1 is the
            paper's proposal, > 1 the iterated EKF update (reaches the measurement's basin
            from e.g. 170 deg in one step; beyond the paper).
        resampling_gate, resampler: as :class:`BootstrapPfCore`.
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True
    _has_covariances = True

    def __init__(
        self,
        num_particles: int,
        q_IB_hat0,
        bias_hat0,
        covariance0,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        *,
        proposal_iterations: int = 1,
        resampling_gate=EffectiveSampleSizeGate(),
        resampler=SystematicResampler(),
    ):
        super().__init__(num_particles, q_IB_hat0, bias_hat0, covariance0, "bias_hat0", resampling_gate, resampler)
        self.proposal_iterations = check_int("proposal_iterations", proposal_iterations, 1)
        self.arw_rad_per_rt_s = check_positive("arw_rad_per_rt_s", arw_rad_per_rt_s)
        self.rrw_rad_per_s15 = check_positive("rrw_rad_per_s15", rrw_rad_per_s15, allow_zero=True)

    def predict(self, state: ParticleSetState, w_meas_B, dt: float, rng=None) -> ParticleSetState:
        """Every particle's EKF time update over ``dt`` (s) > 0 with the mean gyro rate
        ``w_meas_B`` (rad/s); draws nothing."""
        dt = check_positive("dt", dt)
        if rng is not None:
            _check_rng(rng)
        particles, covariances = _kernels.ekf_predict(
            state.particles, state.covariances, gyro_rate(w_meas_B), dt, self.arw_rad_per_rt_s, self.rrw_rad_per_s15
        )
        return ParticleSetState(particles, state.weights, state.log_weights, covariances)

    def update(self, state: ParticleSetState, observations, rng: np.random.Generator):
        """Proposal draw (``rng``: ``N x 6`` standard normals, then the resampler's draws),
        weights, resampling; a declined sample leaves the state unchanged."""
        _check_rng(rng)
        y, U, sigma = body_frame_vectors(observations)
        if y is None:
            return state, _DECLINED
        eps = rng.standard_normal((self.num_particles, 6))
        step = _kernels.ekpf_update(
            state.particles, state.covariances, eps, y, U, sigma, iterations=self.proposal_iterations
        )
        if step is None:  # a Cholesky factor failed
            step = _repaired_proposal_step(
                state.particles, state.covariances, eps, y, U, sigma, self.proposal_iterations
            )
        particles, covariances, log_increment = step
        return self._reweighted(state, particles, covariances, log_increment, rng)


class GyrolessPfCore(_ParticleCore):
    """Bootstrap PF on ``x = [rho; w]`` with Euler's equations (paper S0, gyroless mode).

    Prediction (batched over particles), ``num_substeps`` substeps of ``h = dt / n``:
    RK4 on ``I w_dot = T - w x (I w)`` gives the stage rates ``w_0, w_a, w_b, w_1``; the
    attitude advances by the closed form ``q <- q ⊗ exp(h w_avg / 2)`` with the Simpson
    average ``w_avg = (w_0 + 2 w_a + 2 w_b + w_1) / 6`` (= the RK4 integral of ``w``; the
    neglected non-commutativity term is ``O(|w x w_dot| h^3)``). Then process noise:
    ``q <- q ⊗ exp(N(0, attitude_process_sigma^2 dt I) / 2)`` (if > 0) and
    ``w += N(0, rate_process_sigma^2 dt I)``. Update and resampling as
    :class:`BootstrapPfCore`. ``predict`` ignores ``w_meas_B`` (``uses_gyro`` is false).

    Args:
        num_particles: ``N >= 1``.
        q_IB_hat0, w_hat0, covariance0: the prior: attitude (wxyz), body rate ``w_IB_B``
            (3, rad/s) and the (6, 6) covariance of ``[dtheta_B (rad); w (rad/s)]``.
        inertia: ``(3, 3)`` symmetric positive-definite inertia (kg m^2), body frame.
        torque: ``(3,)`` known body torque ``T`` (N m), constant.
        rate_process_sigma: rate process-noise density (rad/s^1.5) >= 0.
        attitude_process_sigma: attitude process-noise density (rad/s^0.5) >= 0 (default 0).
        num_substeps: RK4 substeps per step >= 1 (default 1).
        resampling_gate, resampler: as :class:`BootstrapPfCore`.
    """

    second_quantity = SecondQuantity.BODY_RATE
    uses_gyro = False

    def __init__(
        self,
        num_particles: int,
        q_IB_hat0,
        w_hat0,
        covariance0,
        inertia,
        torque,
        rate_process_sigma: float,
        *,
        attitude_process_sigma: float = 0.0,
        num_substeps: int = 1,
        resampling_gate=EffectiveSampleSizeGate(),
        resampler=SystematicResampler(),
    ):
        super().__init__(num_particles, q_IB_hat0, w_hat0, covariance0, "w_hat0", resampling_gate, resampler)
        self.inertia = check_covariance("inertia", inertia, 3)
        self.inertia_inverse = np.linalg.inv(self.inertia)
        self.torque = check_array("torque", torque, (3,), " (N m)")
        self.rate_process_sigma = check_positive("rate_process_sigma", rate_process_sigma, allow_zero=True)
        self.attitude_process_sigma = check_positive("attitude_process_sigma", attitude_process_sigma, allow_zero=True)
        self.num_substeps = check_int("num_substeps", num_substeps, 1)

    def predict(self, state: ParticleSetState, w_meas_B, dt: float, rng: np.random.Generator) -> ParticleSetState:
        """Every particle propagated over ``dt`` (s) > 0 by Euler's equations; ``rng`` draws
        the attitude noise, then the rate noise."""
        dt = check_positive("dt", dt)
        _check_rng(rng)
        n, T, h = self.num_particles, self.torque, dt / self.num_substeps
        I, I_inv = self.inertia, self.inertia_inverse
        dtheta = None  # the attitude noise, applied after the deterministic step, drawn first
        if self.attitude_process_sigma > 0.0:
            dtheta = rng.standard_normal((n, 3)) * (self.attitude_process_sigma * np.sqrt(dt))
        rho, w = _kernels.gyroless_propagate(
            state.particles[:, :3], state.particles[:, 3:], I, I_inv, T, h, self.num_substeps, dtheta
        )
        if self.rate_process_sigma > 0.0:
            w = w + rng.standard_normal((n, 3)) * (self.rate_process_sigma * np.sqrt(dt))
        particles = np.empty_like(state.particles)
        particles[:, :3] = rho
        particles[:, 3:] = w
        return ParticleSetState(particles, state.weights, state.log_weights)
