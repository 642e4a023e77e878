"""Weight recursions of the S0 particle filters against computations written in this file.

* EKPF: in the linear-Gaussian limit the weight increment
  ``log p(y|x) + log pi(x) - log q(x)`` (pi = N(m-, P-), q = the EKF posterior) is the
  predictive likelihood ``log N(y; h(m-), H P- H' + R)`` for EVERY draw ``x``
  (documented in ``docs/derivations/particle_filters.md``); so after an update the normalized
  weights are ``prior weight x predictive likelihood`` and do not depend on the rng.
* Every filter carries its log-weights across updates: without resampling, the weights
  after K updates are the normalized product of the K per-update factors.

The measurement model ``y = [R_BI u_1; R_BI u_2]``, its Jacobian (central differences),
the rigid-body propagation (Rodrigues' formula) and the Gaussian densities are written
here from first principles, not taken from the library.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from particle_reference import vector_measurement_model
from s0_truth import P0_ATT, REFS, SIGMA_STAR, SIGMA_U, SIGMA_V, observation

from drake_att.filters.particle import BootstrapPfCore, EffectiveSampleSizeGate, EkpfCore, GyrolessPfCore

NEVER = EffectiveSampleSizeGate(0.0)  # these tests follow the weights: no resampling

W_TRUE = np.array([1e-3, -5e-4, 2e-4])  # rad/s, S0's constant body rate


# --------------------------------------------------------------------------------------
# Independent model pieces
# --------------------------------------------------------------------------------------
def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _R_IB_from_mrp(rho):
    """Rotation matrix of the MRP ``rho`` of q_IB (v_I = R_IB v_B), via the quaternion
    ``q = [1 - |rho|^2, 2 rho] / (1 + |rho|^2)`` and the Euler-Rodrigues formula."""
    n2 = rho @ rho
    w, v = (1.0 - n2) / (1.0 + n2), 2.0 * rho / (1.0 + n2)
    return (w * w - v @ v) * np.eye(3) + 2.0 * np.outer(v, v) + 2.0 * w * _skew(v)


def _rodrigues(phi):
    """exp([phi x]): the body-frame rotation by the rotation vector phi."""
    a = np.linalg.norm(phi)
    K = _skew(phi / a)
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * K @ K


def _h(R_IB):
    """Star-sensor model: both reference directions seen in the body frame."""
    return np.concatenate([R_IB.T @ u for u in REFS])


def _H(rho, eps=1e-7):
    """(6, 6) Jacobian of h w.r.t. [rho; b] by central differences (bias columns 0);
    truncation error ~ eps^2 |h'''| ~ 1e-14, far below anything compared here."""
    H = np.zeros((6, 6))
    for j in range(3):
        e = np.zeros(3)
        e[j] = eps
        H[:, j] = (_h(_R_IB_from_mrp(rho + e)) - _h(_R_IB_from_mrp(rho - e))) / (2 * eps)
    return H


def _log_predictive(m, P, y, sigma):
    """log N(y; h(m), H P H' + sigma^2 I) (up to the constant -3 log 2 pi)."""
    H = _H(m[:3])
    S = H @ P @ H.T + sigma**2 * np.eye(6)
    r = y - _h(_R_IB_from_mrp(m[:3]))
    return -0.5 * r @ np.linalg.solve(S, r) - 0.5 * np.linalg.slogdet(S)[1]


def _normalized_log(lw):
    lw = np.asarray(lw, dtype=float) - np.max(lw)
    return lw - np.log(np.sum(np.exp(lw)))


def _quat_compose_rotvec(q, phi):
    """q ⊗ exp(phi / 2) with q = [w, x, y, z] (Hamilton), written out."""
    a = np.linalg.norm(phi)
    p = np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * phi / a])
    w1, v1, w2, v2 = q[0], q[1:], p[0], p[1:]
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])


def _mrp(q):
    return q[1:] / (1.0 + q[0]) if q[0] >= 0 else -q[1:] / (1.0 - q[0])


def test_independent_measurement_model_agrees_with_the_library():
    """Guards the helpers above: the hand-written h equals the library's model."""
    rng = np.random.default_rng(0)
    rho = rng.normal(size=(5, 3)) * 0.3
    for r in rho:
        np.testing.assert_allclose(_h(_R_IB_from_mrp(r)), vector_measurement_model(r, REFS), atol=1e-14)


# --------------------------------------------------------------------------------------
# EKPF: one update = prior weight x predictive likelihood, independent of the draw
# --------------------------------------------------------------------------------------
def _ekpf_components(seed, n=16):
    """Particles with distinct predicted means and covariances near the S0 attitude, the
    converged-filter regime: attitude sigmas 10-60 urad (random correlated 6x6 covariances
    in the MRP chart, attitude part (sigma/4)^2 since drho ~ dtheta / 4), means spread by
    ~100 urad around the truth, non-uniform prior weights, one S0 measurement (100 urad)."""
    rng = np.random.default_rng(seed)
    q_c = np.array([0.9, 0.2, -0.3, 0.25])
    q_c /= np.linalg.norm(q_c)
    y = _h(_R_IB_from_mrp(_mrp(q_c))) + SIGMA_STAR * rng.standard_normal(6)
    means = np.zeros((n, 6))
    covs = np.zeros((n, 6, 6))
    for i in range(n):
        means[i, :3] = _mrp(_quat_compose_rotvec(q_c, rng.normal(0.0, 100e-6, 3)))
        means[i, 3:] = rng.normal(0.0, 1e-6, 3)
        s = np.exp(rng.uniform(np.log(10e-6), np.log(60e-6)))
        A = rng.normal(size=(6, 6))
        D = np.diag([s / 4] * 3 + [1e-6] * 3)
        covs[i] = D @ (A @ A.T / 6 + 0.5 * np.eye(6)) @ D
    log_w0 = _normalized_log(rng.normal(0.0, 1.0, n))
    return q_c, y, means, covs, log_w0


def _ekpf_with(q_c, means, covs, log_w0):
    """An EKPF core and a state with the given components."""
    n = len(means)
    core = EkpfCore(n, q_c, np.zeros(3), P0_ATT, SIGMA_V, SIGMA_U, resampling_gate=NEVER)
    state = replace(
        core.draw_initial_state(np.random.default_rng(0)),
        particles=means.copy(),
        covariances=covs.copy(),
        log_weights=log_w0.copy(),
        weights=np.exp(log_w0),
    )
    return core, state


# Tolerance on normalized log-weights, from the residual nonlinearity of h: a draw x lies
# |dtheta| <~ |K r| + 3 sigma+ <~ 1.5e-4 rad from the linearization point m-, so h deviates
# from its linearization by |delta| <~ |dtheta|^2 ~ 2.3e-8 per vector; the log-likelihood
# then changes by <~ |y - h_lin(x)| |delta| / sigma^2 <~ 5e-4 * 3.2e-8 / 1e-8 ~ 1.6e-3
# (measured: ~5e-4). 1e-2 leaves a margin of 6. A wrong sign of log q (or dropping any of
# the three terms) changes the increments by O(chi-square_6 spread + log det ratios) ~ 1-10.
LINEARIZATION_TOL = 1e-2


@pytest.mark.parametrize("seed", [1, 2])
def test_ekpf_update_weights_are_prior_times_predictive_likelihood(seed):
    q_c, y, means, covs, log_w0 = _ekpf_components(seed)
    expected = _normalized_log(
        log_w0 + np.array([_log_predictive(m, P, y, SIGMA_STAR) for m, P in zip(means, covs, strict=True)])
    )
    assert np.ptp(expected) > 3.0  # the test discriminates: weights differ by e^3 and more
    assert np.ptp(log_w0) > 2.0  # ... and the prior weights matter
    results = []
    for draw_seed in (11, 12):
        core, state = _ekpf_with(q_c, means, covs, log_w0)
        state, info = core.update(state, observation(y), np.random.default_rng(draw_seed))
        assert info.accepted and not info.resampled
        np.testing.assert_allclose(state.log_weights, expected, rtol=0, atol=LINEARIZATION_TOL)
        np.testing.assert_allclose(state.weights, np.exp(expected), rtol=LINEARIZATION_TOL, atol=1e-12)
        results.append((state.particles, state.weights))
    # Different draws (the particles moved differently), same weights.
    assert np.min(np.abs(results[0][0][:, :3] - results[1][0][:, :3])) > 0.0
    np.testing.assert_allclose(np.log(results[0][1]), np.log(results[1][1]), rtol=0, atol=LINEARIZATION_TOL)


def test_ekpf_weights_carry_over_updates_as_product_of_predictive_likelihoods():
    """Eight S0 steps (predict + update), never resampling: the EKPF's log-weights are the
    running sum of the predictive log-likelihoods of each particle's (m-, P-), read from the
    filter before each update. Tolerance: K = 8 steps x the per-step linearization error
    (measured ~5e-4 after normalization, it does not grow: the clouds shrink)."""
    n = 30
    data = np.random.default_rng(4)
    q0 = np.array([0.9, 0.2, -0.3, 0.25])
    q0 /= np.linalg.norm(q0)
    P0 = np.diag([(100e-6) ** 2] * 3 + [(1e-7) ** 2] * 3)
    core = EkpfCore(n, q0, np.zeros(3), P0, SIGMA_V, SIGMA_U, resampling_gate=NEVER)
    state = core.draw_initial_state(np.random.default_rng(5))
    rng = np.random.default_rng(6)
    expected = state.log_weights.copy()
    R_true = _R_IB_from_mrp(_mrp(q0))
    for k in range(8):
        if k > 0:
            state = core.predict(state, W_TRUE, 1.0, rng)
            R_true = R_true @ _rodrigues(W_TRUE)
        y = _h(R_true) + SIGMA_STAR * data.standard_normal(6)
        expected += np.array(
            [_log_predictive(m, P, y, SIGMA_STAR) for m, P in zip(state.particles, state.covariances, strict=True)]
        )
        state, info = core.update(state, observation(y), rng)
        np.testing.assert_allclose(state.log_weights, _normalized_log(expected), rtol=0, atol=LINEARIZATION_TOL)
        assert info.accepted and not info.resampled
    assert np.ptp(_normalized_log(expected)) > 10.0  # far from uniform: discriminates


# --------------------------------------------------------------------------------------
# Bootstrap and gyroless PF: weights = normalized product of the K likelihoods
# --------------------------------------------------------------------------------------
def _with_second(state, value):
    particles = state.particles.copy()
    particles[:, 3:] = value
    return replace(state, particles=particles)


def _bootstrap(q0, P0, rng):
    """A bootstrap core, its initial state (zero bias: every particle turns at exactly
    w_meas) and its step ``(state, rng) -> state``."""
    core = BootstrapPfCore(200, q0, np.zeros(3), P0, 0.0, resampling_gate=NEVER)
    state = _with_second(core.draw_initial_state(rng), 0.0)
    return core, state, lambda state, rng: core.predict(state, W_TRUE, 1.0, rng)


def _gyroless(q0, P0, rng):
    # Isotropic inertia and zero torque: w x (I w) = 0, the rate stays W_TRUE exactly.
    core = GyrolessPfCore(200, q0, W_TRUE, P0, 150.0 * np.eye(3), np.zeros(3), 0.0, resampling_gate=NEVER)
    state = _with_second(core.draw_initial_state(rng), W_TRUE)
    return core, state, lambda state, rng: core.predict(state, None, 1.0, rng)


@pytest.mark.parametrize("make", [_bootstrap, _gyroless], ids=["bootstrap", "gyroless"])
def test_weights_after_k_updates_are_the_product_of_the_k_likelihoods(make):
    """No process noise, no resampling: each particle is a fixed hypothesis q_i(0) carried
    by the known rate, so the filter is a grid Bayes filter and after K updates
    w_i ∝ prod_k exp(-|y_k - h(R_i(k))|^2 / (2 sigma^2)) (uniform initial weights).
    R_i(k) = R_i(0) exp([w k dt x]) (Rodrigues), exact for a constant rate.

    Tolerance 1e-6 on log-weights: only rounding differs (attitudes agree to ~1e-15 rad,
    log-likelihoods to ~|r| 1e-15 / sigma^2 ~ 1e-10 per step)."""
    rng = np.random.default_rng(9)
    q0 = np.array([0.9, 0.2, -0.3, 0.25])
    q0 /= np.linalg.norm(q0)
    # Cloud of 150 urad around the estimate: likelihood ratios of order e^1 per update,
    # so the K-fold product is far from uniform (compared in log space, so the
    # light particles count as much as the heavy ones).
    P0 = np.diag([(150e-6) ** 2] * 3 + [1e-20] * 3)
    core, state, predict = make(q0, P0, rng)
    R = np.array([_R_IB_from_mrp(r) for r in state.particles[:, :3]])
    R_true = _R_IB_from_mrp(_mrp(_quat_compose_rotvec(q0, np.array([80e-6, -50e-6, 30e-6]))))
    data = np.random.default_rng(10)
    expected = np.zeros(core.num_particles)
    step = _rodrigues(W_TRUE)
    for k in range(10):
        if k > 0:
            state = predict(state, rng)
            R, R_true = R @ step, R_true @ step
        y = _h(R_true) + SIGMA_STAR * data.standard_normal(6)
        expected += np.array([-0.5 * np.sum((y - _h(Ri)) ** 2) / SIGMA_STAR**2 for Ri in R])
        state, info = core.update(state, observation(y), rng)
        assert info.accepted and not info.resampled
        np.testing.assert_allclose(state.log_weights, _normalized_log(expected), rtol=0, atol=1e-6)
    assert np.ptp(_normalized_log(expected)) > 20.0  # far from uniform: discriminates


@pytest.mark.parametrize("singular", ["every particle", "every other particle"])
def test_ekpf_weights_with_a_zero_variance_bias_are_the_predictive_likelihood(singular):
    """A known bias (zero variance, H has no bias columns) changes nothing in the
    linear-Gaussian argument above: the weights must still be prior x predictive likelihood
    (same tolerance). Singular covariances are reached e.g. from a set whose bias block
    was zeroed by the user (rrw_rad_per_s15 = 0, bias known). This was a strict xfail: the
    Cholesky repair floored the prior's and the proposal's eigenvalues each at its own scale,
    which put the weights off by up to 1.5 in log; both now share one floor
    (``particle._paired_cholesky``). With only some particles singular, the repair of the whole
    batch must leave the others right too."""
    rng = np.random.default_rng(5)
    q0 = np.array([0.9, 0.2, -0.3, 0.25])
    q0 /= np.linalg.norm(q0)
    P0 = np.diag([(100e-6) ** 2] * 3 + [(1e-7) ** 2] * 3)
    core = EkpfCore(16, q0, np.zeros(3), P0, SIGMA_V, SIGMA_U, resampling_gate=NEVER)
    state = core.draw_initial_state(rng)
    damaged = slice(None) if singular == "every particle" else slice(None, None, 2)
    covariances = state.covariances.copy()
    covariances[damaged, 3:, :] = 0.0
    covariances[damaged, :, 3:] = 0.0
    state = replace(state, covariances=covariances)
    y = _h(_R_IB_from_mrp(_mrp(q0))) + SIGMA_STAR * np.random.default_rng(1).standard_normal(6)
    expected = _normalized_log(
        state.log_weights
        + np.array(
            [_log_predictive(m, P, y, SIGMA_STAR) for m, P in zip(state.particles, state.covariances, strict=True)]
        )
    )
    state, _ = core.update(state, observation(y), np.random.default_rng(2))
    np.testing.assert_allclose(state.log_weights, expected, rtol=0, atol=LINEARIZATION_TOL)
