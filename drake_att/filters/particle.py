"""Particle filters for paper S0 (Zhang & Sun 2012), vectorized over particles, plain numpy.

Three filters share one measurement model (star sensor, sensor frame = body frame)::

    y = [R_BI u_1; ...; R_BI u_m] + v,   v ~ N(0, sigma^2 I_3m),   R_BI = R(q_IB)'

and one output convention: :meth:`mean` returns ``(q_IB_hat, second_hat)`` with the
attitude mean taken on the rotation group (Markley's weighted quaternion average,
:func:`drake_att.filters.quaternion_average.average_quaternions`) and
:meth:`covariance` returns the ``(6, 6)`` weighted second moment of
``[dtheta_B; s - s_hat]`` about the reported estimate, where ``dtheta_B`` is the
body-frame rotation vector of ``q_hat^-1 ⊗ q_i`` (the project's attitude-error
definition) and ``s`` is the bias (gyro mode) or the body rate (gyroless mode).

* :class:`BootstrapParticleFilter` — SIR in gyro mode, ``x = [rho; b]``; the proposal is
  the transition prior, the bias is static (``b_{k+1} = b_k`` as in the paper) unless the
  optional bias roughening is switched on.
* :class:`ExtendedKalmanParticleFilter` — EKPF: every particle carries an MRP EKF
  (:mod:`drake_att.filters.mrp_ekf`, batched); the EKF posterior is the proposal.
* :class:`GyrolessParticleFilter` — SIR with ``x = [rho; w]`` propagated by Euler's
  equations with known inertia and torque.

Randomness: every draw comes from the ``rng`` (``numpy.random.Generator``) passed to the
constructor (initial particle set) or to ``predict``/``update``; the same seed gives
bit-identical results. Weights are kept in log space during an update, normalized with
log-sum-exp, so they stay finite and sum to one even when every likelihood underflows.
Missing or non-finite measurements (``y`` None / NaN, ``w_meas`` None / NaN) are skipped
and counted in ``n_skipped``; for a missing gyro sample the last valid one is held.
Resampling (systematic) happens when ``N_eff = 1 / sum(w^2) < resample_threshold * N``
(paper: 2/3).

Kernels: the code in this module (with :mod:`drake_att.filters.mrp_ekf`) is the readable
specification, run with ``kernel="numpy"``. The default ``kernel="numba"`` runs the same
steps through the compiled loops of :mod:`drake_att.filters.particle_kernels` (imported on
first use): the same random numbers from the same generator in the same order, the weight
normalization and resampling here in numpy, results equal to round-off (EKPF with 1000
particles ~10x faster per step; ``benchmarks/README.md``).

Units: SI and radians (rad, rad/s, ARW rad/s^0.5, RRW / process noise rad/s^1.5).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from drake_att.contract import SecondQuantity, UpdateInfo
from drake_att.filters.compiled import KERNELS  # one home for the kernel names
from drake_att.filters.mrp_ekf import (
    valid_rate_or_none,
    attitude_to_mrp_covariance,
    ekf_predict,
    ekf_update,
    measurement_is_valid,
    switch_to_short_mrp,
    vector_measurement_model,
)
from drake_att.filters.quaternion_average import average_quaternions
from drake_att.validation import (
    check_array,
    check_covariance,
    check_int,
    check_positive,
    check_quaternion,
    check_reference_vectors,
    fail,
)
from drake_att.rotations import (
    mrp_to_quat,
    quat_error_rotvec,
    quat_multiply,
    quat_to_mrp,
    quat_to_rotmat,
    rotvec_to_quat,
)

__all__ = [
    "effective_sample_size",
    "systematic_resample",
    "normalize_log_weights",
    "vector_log_likelihood",
    "BootstrapParticleFilter",
    "ExtendedKalmanParticleFilter",
    "GyrolessParticleFilter",
    "ParticleSetState",
    "ParticleFilterCore",
    "KERNELS",
]


def _check_kernel(kernel) -> str:
    if not (isinstance(kernel, str) and kernel in KERNELS):
        fail("kernel", kernel, "must be 'numba' (compiled loops, default) or 'numpy' (the reference code)")
    return kernel


def _kernels():
    """The compiled kernels (:mod:`drake_att.filters.particle_kernels`), imported on first use
    (importing numba costs ~0.5 s)."""
    from drake_att.filters import particle_kernels

    return particle_kernels


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


def vector_log_likelihood(rho, y, ref_vectors_I, sigma: float) -> np.ndarray:
    """Gaussian log-likelihood (up to a common constant) of ``y`` per particle.

    ``log p(y | rho_i) = -|y - h(rho_i)|^2 / (2 sigma^2)`` with
    ``h(rho) = [R_BI u_1; ...]`` (see :func:`drake_att.filters.mrp_ekf.vector_measurement_model`).

    Args:
        rho: ``(N, 3)`` MRPs of ``q_IB``. y: ``(3m,)``. ref_vectors_I: ``(m, 3)``.
        sigma: Noise std per component (rad).

    Returns:
        ``(N,)`` log-likelihoods (non-finite entries replaced by ``-inf``).
    """
    r = np.asarray(y, dtype=float) - vector_measurement_model(rho, ref_vectors_I)
    ll = -0.5 * np.sum(r * r, axis=-1) / sigma ** 2
    ll[~np.isfinite(ll)] = -np.inf
    return ll


# ----------------------------------------------------------------------------------
# Components the filters take (Stone Soup's split: resampler / when to resample /
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
# Shared machinery
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

    If either is not positive definite (rarely: a zero-variance block, e.g. a known bias, or
    round-off), both are repaired by clipping their eigenvalues at one common floor per
    particle, ``1e-12`` x the larger of the two largest eigenvalues. A direction where both
    are singular (their common null space: the EKF update only moves the mean inside the
    prior's range) then gets the same variance in the prior and in the proposal, so its
    density terms cancel in the weight ``pi / q`` as the exact degenerate densities' would.
    Flooring each at its own scale (an earlier version) left ``3/2 log(f+/f-)`` plus a
    quadratic term per particle: log-weights off the predictive likelihood by up to 1.5."""
    try:
        return np.linalg.cholesky(P_prior), np.linalg.cholesky(P_post)
    except np.linalg.LinAlgError:
        pairs = [np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2))) for P in (P_prior, P_post)]
        largest = np.maximum(pairs[0][0][..., -1:], pairs[1][0][..., -1:])  # eigh: ascending
        floor = 1e-12 * np.maximum(largest, 1e-300)
        return tuple(np.linalg.cholesky((vecs * np.maximum(vals, floor)[..., None, :]) @ np.swapaxes(vecs, -1, -2))
                     for vals, vecs in pairs)


class _ParticleFilterBase:
    """Weights, resampling (a gate and a resampler component), skipped-measurement
    bookkeeping and outputs."""

    def __init__(self, num_particles, resample_threshold, resampler=None, kernel="numba"):
        self.num_particles = check_int("num_particles", num_particles, 1)
        self.kernel = _check_kernel(kernel)
        self.resampling_gate = EffectiveSampleSizeGate(resample_threshold)
        self.resampler = SystematicResampler() if resampler is None else resampler
        n = self.num_particles
        self.weights = np.full(n, 1.0 / n)
        self.log_weights = np.full(n, -np.log(n))
        self.n_skipped = 0
        self.n_updates = 0
        self.n_resamples = 0
        self.n_degenerate = 0
        self.last_effective_sample_size = float(n)
        self._last_w_meas = np.zeros(3)
        self._estimate_set = None
        self.particles = np.zeros((n, 6))

    # -- helpers -------------------------------------------------------------------
    def _begin_update(self, y, ref_vectors_I, sigma, rng):
        """``(y, U, sigma)`` checked for an update, or None (skipped and counted)."""
        _check_rng(rng)
        U = check_reference_vectors("ref_vectors_I", ref_vectors_I)
        sigma = check_positive("sigma", sigma)
        yv = measurement_is_valid(y, U.shape[0])
        if yv is None:
            self.n_skipped += 1
            return None
        self._estimate_set = None
        return yv, U, sigma

    def _gyro(self, w_meas):
        w = valid_rate_or_none(w_meas)
        if w is None:
            self.n_skipped += 1
            return self._last_w_meas
        self._last_w_meas = w
        return w

    def _reweight(self, log_increment) -> None:
        lw = self.log_weights + log_increment
        if not np.any(np.isfinite(lw)):
            self.n_degenerate += 1
        self.weights, self.log_weights = normalize_log_weights(lw)
        self.last_effective_sample_size = float(1.0 / np.sum(self.weights ** 2))

    @property
    def resample_threshold(self) -> float:
        return self.resampling_gate.threshold

    def _maybe_resample(self, rng) -> bool:
        n = self.num_particles
        if not self.resampling_gate.should_resample(self.last_effective_sample_size, n):
            return False
        # Keep the weighted set for the estimates of this step: resampling only adds
        # Monte Carlo noise (the arrays are replaced, not modified, by _take).
        self._estimate_set = (self.particles, self.weights)
        idx = self.resampler.indices(self.weights, rng)
        self._take(idx)
        self.weights = np.full(n, 1.0 / n)
        self.log_weights = np.full(n, -np.log(n))
        self.n_resamples += 1
        return True

    def _take(self, idx) -> None:
        self.particles = self.particles[idx]

    def update(self, y, ref_vectors_I, sigma: float, rng: np.random.Generator) -> bool:
        """Bootstrap update (the bootstrap and gyroless filters): weight by the star-sensor
        likelihood and resample if ``N_eff`` is low.

        Args:
            y: ``(3m,)`` measured body-frame vectors; None / non-finite: skipped.
            ref_vectors_I: ``(m, 3)`` inertial reference directions.
            sigma: Noise std per component (rad), > 0.
            rng: Generator for resampling.

        Returns:
            True if the measurement was used, False if skipped.
        """
        checked = self._begin_update(y, ref_vectors_I, sigma, rng)
        if checked is None:
            return False
        yv, U, sigma = checked
        log_likelihood = _kernels().vector_log_likelihood if self.kernel == "numba" else vector_log_likelihood
        self._reweight(log_likelihood(self.particles[:, :3], yv, U, sigma))
        self.n_updates += 1
        self._maybe_resample(rng)
        return True

    def effective_sample_size(self) -> float:
        """Current ``N_eff = 1 / sum(w^2)``."""
        return float(1.0 / np.sum(self.weights ** 2))

    # -- outputs -------------------------------------------------------------------
    def _weighted_set(self):
        """``(rho (N, 3), s (N, 3), w (N,))`` used for the estimates."""
        particles, weights = self._estimate_set or (self.particles, self.weights)
        return particles[:, :3], particles[:, 3:], weights

    def particle_quaternions(self) -> np.ndarray:
        """``(N, 4)`` current particle attitudes ``q_IB`` (scalar part >= 0)."""
        return mrp_to_quat(self.particles[:, :3])

    def mean(self):
        """Weighted posterior mean ``(q_IB_hat (4,), s_hat (3,))``.

        The attitude is Markley's weighted quaternion average (largest eigenvector of
        ``sum w_i q_i q_i'``, invariant to the sign of each ``q_i``); the second block
        (bias or rate, rad/s) is the weighted arithmetic mean. If the last update
        resampled, the estimates use the weighted set from just before resampling
        (same expectation, less Monte Carlo noise); after the next predict they use the
        current particles.
        """
        rho, s, w = self._weighted_set()
        return average_quaternions(mrp_to_quat(rho), w), w @ s

    def covariance(self) -> np.ndarray:
        """``(6, 6)`` weighted covariance of ``[dtheta_B (rad); s - s_hat (rad/s)]``.

        ``dtheta_B,i = log(q_hat^-1 ⊗ q_i)`` relative to the reported mean ``q_hat`` (so
        this is the particle approximation of the estimate's error covariance). Same
        weighted set as :meth:`mean`.
        """
        return self.mean_and_covariance()[2]

    def mean_and_covariance(self):
        """``(q_IB_hat, s_hat, covariance)``: :meth:`mean` and :meth:`covariance` in one pass
        (the particles' quaternions and their average computed once; the same numbers)."""
        rho, s, w = self._weighted_set()
        q = mrp_to_quat(rho)
        q_hat = average_quaternions(q, w)
        s_hat = w @ s
        e = np.empty((rho.shape[0], 6))
        e[:, :3] = quat_error_rotvec(q_hat, q)
        e[:, 3:] = s - s_hat
        C = (e * w[:, None]).T @ e
        return q_hat, s_hat, 0.5 * (C + C.T)


# ----------------------------------------------------------------------------------
# Bootstrap (SIR) particle filter, gyro mode
# ----------------------------------------------------------------------------------
class BootstrapParticleFilter(_ParticleFilterBase):
    """Bootstrap / SIR particle filter on ``x = [rho; b]`` (paper S0, gyro mode).

    Prediction per particle ``i`` (batched)::

        w_i   = w_meas - b_i - n_i,          n_i ~ N(0, arw_rad_per_rt_s^2 / dt I)
        q_i  <- q_i ⊗ exp(w_i dt / 2)          (closed form, exact for constant rate)
        rho_i = MRP(q_i) with |rho_i| <= 1     (shadow switch)
        b_i  <- b_i [+ N(0, bias_roughening_sigma^2 dt I)]

    With ``bias_roughening_sigma = 0`` (default) the bias is static, exactly as in the
    paper; resampling then collapses the bias cloud and the bias estimate cannot
    converge (the paper's Fig. 2 finding). A positive value is a random-walk roughening
    of the bias (the "beyond the paper" remedy); setting it to the true RRW ``sigma_u``
    is the model-consistent SIR, larger values trade bias noise for diversity.

    Update: ``log w_i += -|y - h(rho_i)|^2 / (2 sigma^2)``, log-sum-exp normalization,
    systematic resampling when ``N_eff < resample_threshold * N``.

    Args:
        num_particles: ``N >= 1``.
        q_IB_hat0: Initial attitude estimate ``[w, x, y, z]``.
        bias_hat0: Initial bias estimate ``(3,)`` (rad/s).
        covariance0: ``(6, 6)`` covariance of ``[dtheta_B (rad); b (rad/s)]`` used to draw
            the initial set: ``q_i = q0 ⊗ exp(dtheta_i / 2)``, ``b_i = b0 + db_i``.
        arw_rad_per_rt_s: Gyro ARW ``sigma_v`` (rad/s^0.5) used for the attitude process noise,
            >= 0 (0 means a deterministic attitude propagation).
        rng: Generator for the initial draw.
        bias_roughening_sigma: Bias random-walk density (rad/s per sqrt(s) = rad/s^1.5),
            >= 0; default 0 (paper).
        resample_threshold: Fraction of ``N`` in ``[0, 1]``; default 2/3 (paper)
            (:class:`EffectiveSampleSizeGate`).
        resampler: which particles survive (default :class:`SystematicResampler`); any
            object with ``indices(weights, rng) -> (N,) int array``.
        kernel: ``"numba"`` (default: compiled loops) or ``"numpy"`` (the reference code);
            equal to round-off (module docstring).

    Attributes:
        particles: ``(N, 6)`` ``[rho; b]``. weights: ``(N,)`` normalized weights.
        n_skipped, n_updates, n_resamples, last_effective_sample_size.
    """

    def __init__(self, num_particles: int, q_IB_hat0, bias_hat0, covariance0,
                 arw_rad_per_rt_s: float, rng: np.random.Generator, *,
                 bias_roughening_sigma: float = 0.0, resample_threshold: float = 2.0 / 3.0, resampler=None,
                 kernel: str = "numba"):
        super().__init__(num_particles, resample_threshold, resampler, kernel)
        q0 = check_quaternion("q_IB_hat0", q_IB_hat0)
        b0 = check_array("bias_hat0", bias_hat0, (3,), " (rad/s)")
        P0 = check_covariance("covariance0", covariance0, 6)
        self.arw_rad_per_rt_s = check_positive("arw_rad_per_rt_s", arw_rad_per_rt_s, allow_zero=True)
        self.roughening = RandomWalkRoughening(check_positive("bias_roughening_sigma", bias_roughening_sigma,
                                                              allow_zero=True))
        _check_rng(rng)
        rho, b = _sample_initial_attitudes(self.num_particles, q0, b0, P0, rng)
        self.particles = np.concatenate([rho, b], axis=1)

    @property
    def bias_roughening_sigma(self) -> float:
        """The bias roughening density (rad/s^1.5) of :attr:`roughening`."""
        return self.roughening.sigma

    def predict(self, dt: float, w_meas, rng: np.random.Generator) -> None:
        """Propagate every particle over ``dt`` (s) with gyro rate ``w_meas`` (rad/s).

        Args:
            dt: Step (s), > 0.
            w_meas: Measured body rate ``(3,)`` (rad/s), held over the step. None or
                non-finite: skipped (counted) and the last valid rate is used.
            rng: Generator for the ARW samples (and the bias roughening).
        """
        dt = check_positive("dt", dt)
        self._estimate_set = None
        _check_rng(rng)
        w_meas = self._gyro(w_meas)
        n = self.num_particles
        w = w_meas - self.particles[:, 3:]
        if self.arw_rad_per_rt_s > 0.0:
            w = w - rng.standard_normal((n, 3)) * (self.arw_rad_per_rt_s / np.sqrt(dt))
        if self.kernel == "numba":
            self.particles[:, :3] = _kernels().propagate_attitudes(self.particles[:, :3], w, dt)
        else:
            q = quat_multiply(mrp_to_quat(self.particles[:, :3]), rotvec_to_quat(w * dt))
            self.particles[:, :3] = quat_to_mrp(q)
        self.particles[:, 3:] = self.roughening.apply(self.particles[:, 3:], dt, rng)

# ----------------------------------------------------------------------------------
# Extended Kalman particle filter, gyro mode
# ----------------------------------------------------------------------------------
class ExtendedKalmanParticleFilter(_ParticleFilterBase):
    """Extended-Kalman particle filter (EKPF, van der Merwe et al. 2000) on ``[rho; b]``.

    Each particle ``i`` is a point ``x_i`` with an EKF covariance ``P_i`` (MRP chart of
    ``x_i``). One cycle, batched over particles with ``(N, 6, 6)`` arrays:

    1. :meth:`predict`: the particle's EKF time update
       (:func:`~drake_att.filters.mrp_ekf.ekf_predict`) gives ``(m_i^-, P_i^-)``; the
       particle is moved to ``m_i^-``.
    2. :meth:`update`: the EKF update with the current measurement gives the proposal
       ``q_i = N(m_i^+, P_i^+)``; draw ``x_i ~ q_i`` and set
       ``log w_i += log p(y | x_i) + log pi(x_i) - log q_i(x_i)``; then ``P_i = P_i^+``,
       shadow switch (with covariance mapping) and resampling (means and covariances
       are copied).

    **Prior approximation.** The exact transition density ``p(x_k | x_{k-1})`` has
    covariance ``Qd``, whose bias block is ``sigma_u^2 dt`` (~1e-18 rad^2/s^2 for S0):
    any proposal draw of the bias would get a vanishing prior and the weights would
    degenerate at the first step. We use the particle's *predicted EKF Gaussian*
    ``pi = N(m_i^-, P_i^-)`` instead (each particle is treated as a Gaussian component,
    as in a Gaussian-sum filter). In the linear-Gaussian limit the weight increment is
    then exactly the predictive likelihood ``N(y; h(m_i^-), H P_i^- H' + R)`` for every
    draw; with the nonlinear measurement it also rewards draws that fit ``y``.
    All three densities are evaluated in the same MRP chart (that of ``m_i^-``).

    Consequences worth knowing (measured on S0): the draw from ``P_i^+`` at every step
    acts as a kernel jitter, so the particle cloud (and :meth:`covariance`) is wider than
    a single EKF's covariance, notably for the bias (~0.1 deg/h spread vs ~0.01 deg/h
    EKF sigma after 1000 s); the attitude error is ~0.002 deg, as in the paper. With the
    paper's single-linearization proposal a 170 deg initial error is *not* removed
    quickly (every particle's EKF step is a local Gauss-Newton step of ~10 deg, then its
    covariance collapses, exactly like the EKF); ``proposal_iterations > 1`` fixes this.

    Without a measurement (skipped) the particles stay at their predicted means with
    their predicted covariances (no draw).

    Args:
        num_particles: ``N >= 1``.
        q_IB_hat0: Initial attitude estimate ``[w, x, y, z]``.
        bias_hat0: Initial bias estimate ``(3,)`` (rad/s).
        covariance0: ``(6, 6)`` covariance of ``[dtheta_B (rad); b (rad/s)]``: used to
            draw the particles and, mapped into each particle's MRP chart, as every
            particle's initial EKF covariance.
        arw_rad_per_rt_s: Gyro ARW ``sigma_v`` (rad/s^0.5), > 0.
        rrw_rad_per_s15: Gyro RRW ``sigma_u`` (rad/s^1.5), >= 0.
        rng: Generator for the initial draw.
        resample_threshold: Fraction of ``N`` in ``[0, 1]``; default 2/3.
        resampler: default :class:`SystematicResampler` (see :class:`BootstrapParticleFilter`).
        proposal_iterations: Linearizations of each particle's EKF update, >= 1.
            1 (default) is the paper's EKF proposal; > 1 uses the iterated EKF update
            (Gauss-Newton), a beyond-the-paper option that lets every particle reach the
            measurement's basin from a large initial error (e.g. 170 deg) in one step.
        kernel: ``"numba"`` (default: compiled loops) or ``"numpy"`` (the reference code:
            :func:`~drake_att.filters.mrp_ekf.ekf_predict`, ``ekf_update`` and the lines of
            :meth:`update`); equal to round-off (module docstring).

    Attributes:
        particles: ``(N, 6)`` ``[rho; b]``. covariances: ``(N, 6, 6)`` (MRP chart).
        weights, n_skipped, n_updates, n_resamples, last_effective_sample_size.
    """

    def __init__(self, num_particles: int, q_IB_hat0, bias_hat0, covariance0,
                 arw_rad_per_rt_s: float, rrw_rad_per_s15: float, rng: np.random.Generator, *,
                 resample_threshold: float = 2.0 / 3.0, proposal_iterations: int = 1, resampler=None,
                 kernel: str = "numba"):
        super().__init__(num_particles, resample_threshold, resampler, kernel)
        self.proposal_iterations = check_int("proposal_iterations", proposal_iterations, 1)
        q0 = check_quaternion("q_IB_hat0", q_IB_hat0)
        b0 = check_array("bias_hat0", bias_hat0, (3,), " (rad/s)")
        P0 = check_covariance("covariance0", covariance0, 6)
        self.arw_rad_per_rt_s = check_positive("arw_rad_per_rt_s", arw_rad_per_rt_s)
        self.rrw_rad_per_s15 = check_positive("rrw_rad_per_s15", rrw_rad_per_s15, allow_zero=True)
        _check_rng(rng)
        rho, b = _sample_initial_attitudes(self.num_particles, q0, b0, P0, rng)
        self.particles = np.concatenate([rho, b], axis=1)
        self.covariances = attitude_to_mrp_covariance(rho, P0)

    def _take(self, idx):
        self.particles = self.particles[idx]
        self.covariances = self.covariances[idx]

    def predict(self, dt: float, w_meas, rng: np.random.Generator | None = None) -> None:
        """EKF time update of every particle (deterministic; ``rng`` is not used).

        Args:
            dt: Step (s), > 0.
            w_meas: Measured body rate ``(3,)`` (rad/s); None / non-finite: skipped
                (counted) and the last valid rate is held.
            rng: Accepted for a uniform interface with the other filters; unused.
        """
        dt = check_positive("dt", dt)
        self._estimate_set = None
        if rng is not None:
            _check_rng(rng)
        w_meas = self._gyro(w_meas)
        predict = _kernels().ekf_predict if self.kernel == "numba" else ekf_predict
        self.particles, self.covariances = predict(
            self.particles, self.covariances, w_meas, dt, self.arw_rad_per_rt_s, self.rrw_rad_per_s15)

    def update(self, y, ref_vectors_I, sigma: float, rng: np.random.Generator) -> bool:
        """Per-particle EKF update as proposal, draw, weight, resample.

        Args:
            y: ``(3m,)`` measured body-frame vectors; None / non-finite: skipped.
            ref_vectors_I: ``(m, 3)`` inertial reference directions.
            sigma: Noise std per component (rad), > 0.
            rng: Generator for the proposal draws and resampling.

        Returns:
            True if the measurement was used, False if skipped.
        """
        checked = self._begin_update(y, ref_vectors_I, sigma, rng)
        if checked is None:
            return False
        yv, U, sigma = checked
        # The proposal's standard normals (no other draw before the resampler's).
        eps = rng.standard_normal((self.num_particles, 6))
        step = None
        if self.kernel == "numba":  # None if a Cholesky factor needs the repair below
            step = _kernels().ekpf_update(self.particles, self.covariances, eps, yv, U, sigma,
                                          iterations=self.proposal_iterations)
        x, P, log_increment = self._proposal_step(yv, U, sigma, eps) if step is None else step
        self._reweight(log_increment)
        self.particles, self.covariances = x, P
        self.n_updates += 1
        self._maybe_resample(rng)
        return True

    def _proposal_step(self, yv, U, sigma, eps):
        """The reference (numpy) measurement step: ``(x, P, log-weight increment)`` of every
        particle for the proposal draws ``x = m+ + L+ eps``."""
        m_prior, P_prior = self.particles, self.covariances
        m_post, P_post, _, _ = ekf_update(m_prior, P_prior, yv, U, sigma, switch=False,
                                          iterations=self.proposal_iterations)
        L_prior, L_post = _paired_cholesky(P_prior, P_post)
        # Proposal draw x = m+ + L eps, log q(x) = -|eps|^2/2 - log det L (+ const).
        x = m_post + (L_post @ eps[:, :, None])[:, :, 0]
        log_q = -0.5 * np.sum(eps * eps, axis=1) - np.sum(
            np.log(np.diagonal(L_post, axis1=1, axis2=2)), axis=1)
        # Prior pi = N(m-, P-) (see the class docstring).
        z = np.linalg.solve(L_prior, (x - m_prior)[:, :, None])[:, :, 0]
        log_pi = -0.5 * np.sum(z * z, axis=1) - np.sum(
            np.log(np.diagonal(L_prior, axis1=1, axis2=2)), axis=1)
        log_lik = vector_log_likelihood(x[:, :3], yv, U, sigma)
        x, P, _ = switch_to_short_mrp(x, P_post)
        return x, P, log_lik + log_pi - log_q


# ----------------------------------------------------------------------------------
# Gyroless bootstrap particle filter
# ----------------------------------------------------------------------------------
class GyrolessParticleFilter(_ParticleFilterBase):
    """Bootstrap PF on ``x = [rho; w]`` with Euler's equations (paper S0, gyroless mode).

    Prediction (batched over particles), ``num_substeps`` substeps of ``h = dt / n``:
    RK4 on ``I w_dot = T - w x (I w)`` gives the stage rates ``w_0, w_a, w_b, w_1``; the
    attitude advances by the closed form ``q <- q ⊗ exp(h w_avg / 2)`` with the Simpson
    average ``w_avg = (w_0 + 2 w_a + 2 w_b + w_1) / 6`` (= the RK4 integral of ``w``; the
    neglected non-commutativity term is ``O(|w x w_dot| h^3)``). Then process noise:
    ``w += N(0, rate_process_sigma^2 dt I)`` and, optionally,
    ``q <- q ⊗ exp(N(0, attitude_process_sigma^2 dt I) / 2)``.
    Update and resampling as in :class:`BootstrapParticleFilter`.

    Args:
        num_particles: ``N >= 1``.
        q_IB_hat0: Initial attitude estimate ``[w, x, y, z]``.
        w_hat0: Initial body-rate estimate ``w_IB_B`` ``(3,)`` (rad/s).
        covariance0: ``(6, 6)`` covariance of ``[dtheta_B (rad); w (rad/s)]``.
        inertia: ``(3, 3)`` symmetric positive-definite inertia (kg m^2), body frame.
        torque: ``(3,)`` known body torque ``T`` (N m), held constant (can be overridden
            per :meth:`predict` call).
        rate_process_sigma: Rate process-noise density (rad/s^1.5), >= 0.
        rng: Generator for the initial draw.
        attitude_process_sigma: Attitude process-noise density (rad/s^0.5), >= 0,
            default 0.
        num_substeps: RK4 substeps per :meth:`predict`, >= 1 (default 1).
        resample_threshold: Fraction of ``N`` in ``[0, 1]``; default 2/3.
        resampler: default :class:`SystematicResampler` (see :class:`BootstrapParticleFilter`).
        kernel: ``"numba"`` (default: compiled loops) or ``"numpy"`` (the reference code);
            equal to round-off (module docstring).

    Attributes:
        particles: ``(N, 6)`` ``[rho; w]``. weights, n_skipped, n_updates, n_resamples.
    """

    def __init__(self, num_particles: int, q_IB_hat0, w_hat0, covariance0, inertia, torque,
                 rate_process_sigma: float, rng: np.random.Generator, *,
                 attitude_process_sigma: float = 0.0, num_substeps: int = 1,
                 resample_threshold: float = 2.0 / 3.0, resampler=None, kernel: str = "numba"):
        super().__init__(num_particles, resample_threshold, resampler, kernel)
        q0 = check_quaternion("q_IB_hat0", q_IB_hat0)
        w0 = check_array("w_hat0", w_hat0, (3,), " (rad/s)")
        P0 = check_covariance("covariance0", covariance0, 6)
        self.inertia = check_covariance("inertia", inertia, 3)
        self.inertia_inverse = np.linalg.inv(self.inertia)
        self.torque = check_array("torque", torque, (3,), " (N m)")
        self.rate_process_sigma = check_positive("rate_process_sigma", rate_process_sigma, allow_zero=True)
        self.attitude_process_sigma = check_positive("attitude_process_sigma", attitude_process_sigma, allow_zero=True)
        self.num_substeps = check_int("num_substeps", num_substeps, 1)
        _check_rng(rng)
        rho, w = _sample_initial_attitudes(self.num_particles, q0, w0, P0, rng)
        self.particles = np.concatenate([rho, w], axis=1)

    def _w_dot(self, w, torque):
        Iw = w @ self.inertia.T
        return (torque - np.cross(w, Iw)) @ self.inertia_inverse.T

    def predict(self, dt: float, rng: np.random.Generator, torque=None) -> None:
        """Propagate all particles over ``dt`` (s) with Euler's equations + process noise.

        Args:
            dt: Step (s), > 0.
            rng: Generator for the process noise.
            torque: Optional ``(3,)`` torque (N m) for this step; default: the
                constructor's ``torque``.
        """
        dt = check_positive("dt", dt)
        self._estimate_set = None
        _check_rng(rng)
        T = self.torque if torque is None else check_array("torque", torque, (3,), " (N m)")
        n = self.num_particles
        h = dt / self.num_substeps
        # Attitude noise (applied after the deterministic step): drawn first, as no other draw
        # comes between.
        dtheta = None
        if self.attitude_process_sigma > 0.0:
            dtheta = rng.standard_normal((n, 3)) * (self.attitude_process_sigma * np.sqrt(dt))
        if self.kernel == "numba":
            rho, w = _kernels().gyroless_propagate(self.particles[:, :3], self.particles[:, 3:], self.inertia,
                                                   self.inertia_inverse, T, h, self.num_substeps, dtheta)
        else:
            q = mrp_to_quat(self.particles[:, :3])
            w = self.particles[:, 3:].copy()
            for _ in range(self.num_substeps):
                k1 = self._w_dot(w, T)
                wa = w + 0.5 * h * k1
                k2 = self._w_dot(wa, T)
                wb = w + 0.5 * h * k2
                k3 = self._w_dot(wb, T)
                w1 = w + h * k3
                k4 = self._w_dot(w1, T)
                w_avg = (w + 2.0 * wa + 2.0 * wb + w1) / 6.0
                q = quat_multiply(q, rotvec_to_quat(w_avg * h))
                w = w + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            if dtheta is not None:
                q = quat_multiply(q, rotvec_to_quat(dtheta))
            rho = quat_to_mrp(q)
        if self.rate_process_sigma > 0.0:
            w = w + rng.standard_normal((n, 3)) * (self.rate_process_sigma * np.sqrt(dt))
        self.particles[:, :3] = rho
        self.particles[:, 3:] = w


# ----------------------------------------------------------------------------------
# The filter-core protocol (drake_att.contract.FilterCore) for the particle filters
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class ParticleSetState:
    """A particle filter's state: particles ``(N, 6)`` ``[rho; s]``, normalized weights and
    log-weights ``(N,)``, per-particle EKF covariances ``(N, 6, 6)`` (EKPF) or None.

    ``estimate_set``: after an update that resampled, the weighted set from just before
    resampling ``(particles, weights)``, which the estimate of that step uses (same
    expectation, less Monte Carlo noise); not part of the stored state.
    """

    particles: np.ndarray
    weights: np.ndarray
    log_weights: np.ndarray
    covariances: np.ndarray | None = None
    estimate_set: tuple | None = None


class ParticleFilterCore:
    """One of the particle filters above as a :class:`drake_att.contract.FilterCore`.

    Each call runs the filter's own ``predict``/``update`` on a shallow copy of a template
    filter whose arrays are replaced by the state's, and returns a new
    :class:`ParticleSetState`; the template is never modified, so the core has no hidden
    state and no counters (resamplings and degenerate updates are reported in
    :class:`~drake_att.contract.UpdateInfo`). State vector: ``[particles (N*6, row-major),
    weights (N), log weights (N), (EKPF) covariances (N*36, MRP chart)]``.

    Args:
        make_filter: ``rng -> filter`` building the filter (and drawing its initial set)
            with every constructor argument but the generator fixed.
        second_quantity: gyro bias (gyro mode) or body rate (gyroless).
    """

    is_random = True

    def __init__(self, make_filter, second_quantity: SecondQuantity):
        self._make_filter = make_filter
        self.template = make_filter(np.random.default_rng(0))
        self.second_quantity = second_quantity
        self.num_particles = self.template.num_particles
        self.uses_gyro = not isinstance(self.template, GyrolessParticleFilter)
        self._has_covariances = isinstance(self.template, ExtendedKalmanParticleFilter)
        self.state_size = self.num_particles * (8 + (36 if self._has_covariances else 0))

    # -- state <-> filter object ------------------------------------------------------
    @staticmethod
    def _state_of(pf) -> ParticleSetState:
        return ParticleSetState(pf.particles, pf.weights, pf.log_weights, getattr(pf, "covariances", None),
                                pf._estimate_set)

    def _filter_of(self, state: ParticleSetState, copy_arrays: bool = True):
        """The template with the state's arrays (copies, unless the caller only reads them)."""
        pf = copy.copy(self.template)
        take = np.array if copy_arrays else np.asarray
        pf.particles = take(state.particles)
        pf.weights = take(state.weights)
        pf.log_weights = take(state.log_weights)
        if self._has_covariances:
            pf.covariances = take(state.covariances)
        pf.n_skipped = pf.n_updates = pf.n_resamples = pf.n_degenerate = 0
        pf._estimate_set = state.estimate_set
        return pf

    def draw_initial_state(self, rng: np.random.Generator) -> ParticleSetState:
        """A fresh initial particle set drawn with ``rng``."""
        return self._state_of(self._make_filter(rng))

    def initial_state(self) -> ParticleSetState:
        """The template's set (drawn with numpy seed 0): the default before initialization."""
        return self._state_of(self.template)

    # -- protocol ---------------------------------------------------------------------
    def predict(self, state, w_meas_B, dt, rng):
        pf = self._filter_of(state)
        if isinstance(pf, GyrolessParticleFilter):
            pf.predict(dt, rng)
        elif isinstance(pf, ExtendedKalmanParticleFilter):
            pf.predict(dt, w_meas_B)
        else:
            pf.predict(dt, w_meas_B, rng)
        return self._state_of(pf)

    def update(self, state, observations, rng):
        """Weight by a :class:`~drake_att.contract.VectorObservations` sample (rotated into the
        body frame, ``y_B = R_BS y_S``: exact for isotropic vector noise) and resample."""
        pf = self._filter_of(state)
        R_BS = quat_to_rotmat(np.asarray(observations.q_BS, dtype=float))
        y_B = (np.asarray(observations.directions_S, dtype=float) @ R_BS.T).ravel()
        used = pf.update(y_B, np.asarray(observations.references_I, dtype=float),
                         float(observations.sigma_rad), rng)
        info = UpdateInfo(None, None, float("nan"), bool(used),
                          effective_sample_size=pf.last_effective_sample_size if used else float("nan"),
                          resampled=pf.n_resamples > 0, degenerate=pf.n_degenerate > 0)
        return self._state_of(pf), info

    def estimate(self, state):
        return self._filter_of(state, copy_arrays=False).mean_and_covariance()

    def to_vector(self, state) -> np.ndarray:
        parts = [np.asarray(state.particles).ravel(), state.weights, state.log_weights]
        if self._has_covariances:
            parts.append(np.asarray(state.covariances).ravel())
        return np.concatenate(parts)

    def from_vector(self, vector) -> ParticleSetState:
        n = self.num_particles
        s = np.asarray(vector, dtype=float)
        covariances = np.array(s[8 * n:]).reshape(n, 6, 6) if self._has_covariances else None
        return ParticleSetState(np.array(s[:6 * n]).reshape(n, 6), np.array(s[6 * n:7 * n]),
                                np.array(s[7 * n:8 * n]), covariances)
