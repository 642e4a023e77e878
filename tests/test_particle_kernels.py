"""The compiled particle-filter and MRP EKF kernels (drake_att.filters.particle_kernels, the
library's one implementation of these steps) against the numpy oracle
(``tests/particle_reference.py``): kernel by kernel, and the library's cores against the
``Reference*`` cores (same random numbers, same decisions) over whole runs.

Tolerances are round-off, measured in the units that carry meaning: a covariance entry
relative to ``sqrt(P_ii P_jj)`` (so a bias block 1e-12 below the attitude block is checked
as tightly as the attitude), a state component relative to ``|x_i| + sqrt(P_ii)``, a
log-weight increment relative to its size plus the round-off of the likelihood itself
(``|y - h|^2 / 2 sigma^2`` is computed from ``y`` and ``h`` of norm 1, so its absolute
round-off is ~``|y - h| eps / sigma^2``). Measured: 1e-15 for states near the measurement,
1e-11 for states far from it (the innovation covariance's condition number, up to ~1e6,
multiplies the round-off of the gain); bounds with 100x-1000x margin.

A first run on a machine compiles the kernels (numba, cached on disk; benchmarks/README.md).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import particle_reference as ref
import pytest
from particle_reference import (
    ReferenceBootstrapPfCore,
    ReferenceEkpfCore,
    ReferenceGyrolessPfCore,
    ReferenceMrpEkfCore,
    vector_measurement_model,
)
from s0_truth import DEG, HOUR, P0_ATT, REFS, SIGMA_STAR, SIGMA_U, SIGMA_V, observation, simulate_gyro_truth

from drake_att import rotations as rot
from drake_att.filters import particle_kernels as pk
from drake_att.filters.gating import InnovationGate
from drake_att.filters.mrp_ekf import MrpEkfCore, attitude_to_mrp_covariance
from drake_att.filters.particle import (
    BootstrapPfCore,
    EffectiveSampleSizeGate,
    EkpfCore,
    GyrolessPfCore,
    RandomWalkRoughening,
)

INERTIA = np.diag([100.0, 200.0, 200.0])
TORQUE = np.full(3, 1e-5)
N = 1500


def _random_covariances(rng, n, log_sigma_attitude=(-6.0, -1.0), log_sigma_bias=(-10.0, -6.0)):
    """SPD ``(n, 6, 6)`` of ``[dtheta; b]`` with random correlations and per-particle scales."""
    sa = 10.0 ** rng.uniform(*log_sigma_attitude, size=n)
    sb = 10.0 ** rng.uniform(*log_sigma_bias, size=n)
    A = rng.normal(size=(n, 6, 6))
    C = A @ A.transpose(0, 2, 1) / 6.0 + 0.05 * np.eye(6)
    d = np.sqrt(np.einsum("nii->ni", C))
    s = np.stack([sa, sa, sa, sb, sb, sb], axis=1)
    return C / d[:, :, None] / d[:, None, :] * s[:, :, None] * s[:, None, :]


def _states_near(rng, n, q_true, **kw):
    """Particles ``(x, P)`` (MRP chart) whose means are draws from their own covariance around
    ``q_true`` (innovations of a few sigmas: a filter's regime)."""
    P_att = _random_covariances(rng, n, **kw)
    e = (np.linalg.cholesky(P_att) @ rng.normal(size=(n, 6, 1)))[:, :, 0]
    rho = rot.quat_to_mrp(rot.quat_multiply(q_true, rot.rotvec_to_quat(-e[:, :3])))
    return np.concatenate([rho, 1e-5 + e[:, 3:]], axis=1), attitude_to_mrp_covariance(rho, P_att)


def _states_anywhere(rng, n):
    """Particles at uniformly random attitudes (|rho| <= 1), unrelated to any measurement."""
    rho = rot.quat_to_mrp(rot.quat_normalize(rng.normal(size=(n, 4))))
    return np.concatenate([rho, 1e-5 * rng.normal(size=(n, 3))], axis=1), _random_covariances(rng, n)


def assert_states_close(x, P, x_ref, P_ref, tol):
    """``|dx_i| <= tol (|x_i| + sqrt(P_ii))`` and ``|dP_ij| <= tol sqrt(P_ii P_jj)``."""
    d = np.sqrt(np.einsum("nii->ni", P_ref))
    assert np.all(d > 0.0)
    ex = np.abs(x - x_ref) / (np.abs(x_ref) + d)
    eP = np.abs(P - P_ref) / (d[:, :, None] * d[:, None, :])
    assert ex.max() <= tol and eP.max() <= tol, (ex.max(), eP.max())


def assert_innovations_close(z, S, z_ref, S_ref, tol):
    """``|dz_l| <= 1e-14`` (the innovation ``y - h`` of unit vectors: its round-off is that of
    ``h``, absolute) and ``|dS_kl| <= tol sqrt(S_kk S_ll)``."""
    assert np.max(np.abs(z - z_ref)) <= 1e-14
    d = np.sqrt(np.einsum("nii->ni", S_ref))
    assert np.max(np.abs(S - S_ref) / (d[:, :, None] * d[:, None, :])) <= tol


def assert_log_weights_close(a, b, sigma):
    """Round-off of a log-likelihood-based weight: relative 1e-12 plus ``|y - h| eps / sigma^2``
    with ``|y - h| / sigma <= sqrt(2 |log w|)`` (and ``|y| ~ 1``)."""
    tol = 1e-12 * np.maximum(1.0, np.abs(b)) + 1e-13 * np.sqrt(2.0 * np.abs(b) + 1.0) / sigma
    assert np.all(np.abs(a - b) <= tol), np.max(np.abs(a - b) / tol)


# --------------------------------------------------------------------------------------
# Kernel by kernel
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("w, dt", [(np.array([1e-3, -5e-4, 2e-4]), 1.0), (np.array([0.9, -0.6, 0.4]), 2.0)])
def test_ekf_predict_equals_the_reference(w, dt):
    """Many random states; the fast rate turns particles by ~2 rad, so many of them cross
    |rho| = 1 and take the shadow switch (checked: same switch, same chart)."""
    rng = np.random.default_rng(1)
    x, P = _states_anywhere(rng, N)
    x_ref, P_ref = ref.ekf_predict(x, P, w, dt, SIGMA_V, SIGMA_U)
    x_new, P_new = pk.ekf_predict(x, P, w, dt, SIGMA_V, SIGMA_U)
    assert_states_close(x_new, P_new, x_ref, P_ref, 1e-13)
    if dt == 2.0:  # the shadow switch happened (|rho| <= 1 both ways) for a good share
        unswitched = ref.propagate_mrp(x[:, :3], w - x[:, 3:], dt)
        assert np.mean(np.sum(unswitched**2, axis=1) > 1.0) > 0.2


@pytest.mark.slow
@pytest.mark.parametrize("sigma", [1e-4, 1e-2])
@pytest.mark.parametrize("iterations", [1, 3, 10])
def test_ekf_update_equals_the_reference(sigma, iterations):
    """Particles near the truth (a filter's regime), classic and iterated (the batch stops
    iterating when no component of any particle moves by more than 1e-12, as the reference).
    Measured 7e-15 (sigma 1e-4), 1e-15 (1e-2)."""
    rng = np.random.default_rng(2)
    q_true = rot.quat_normalize(np.array([0.7, -0.2, 0.5, 0.3]))
    x, P = _states_near(rng, N, q_true, log_sigma_attitude=(-5.0, -2.0))
    y = vector_measurement_model(rot.quat_to_mrp(q_true), REFS) + sigma * rng.normal(size=6)
    x_ref, P_ref, z_ref, S_ref = ref.ekf_update(x, P, y, REFS, sigma, switch=False, iterations=iterations)
    x_new, P_new, z_new, S_new = pk.ekf_update(x, P, y, REFS, sigma, switch=False, iterations=iterations)
    assert_states_close(x_new, P_new, x_ref, P_ref, 1e-12)
    assert_innovations_close(z_new, S_new, z_ref, S_ref, 1e-13)


@pytest.mark.parametrize("iterations", [1, 3])
def test_ekf_update_far_from_the_measurement_agrees_to_its_conditioning(iterations):
    """Random attitudes against one measurement (innovations of up to ~100 prior sigmas, an
    innovation covariance with condition number up to ~1e6): the two solves (numpy's LU, the
    kernel's Cholesky) differ by round-off times that condition number (measured 1e-11)."""
    rng = np.random.default_rng(3)
    x, P = _states_anywhere(rng, N)
    y = vector_measurement_model(x[0, :3], REFS) + 1e-2 * rng.normal(size=6)
    x_ref, P_ref, z_ref, S_ref = ref.ekf_update(x, P, y, REFS, 1e-2, switch=False, iterations=iterations)
    x_new, P_new, z_new, S_new = pk.ekf_update(x, P, y, REFS, 1e-2, switch=False, iterations=iterations)
    assert_states_close(x_new, P_new, x_ref, P_ref, 1e-9)
    assert_innovations_close(z_new, S_new, z_ref, S_ref, 1e-13)


@pytest.mark.parametrize("iterations", [1, 3])
def test_ekf_update_with_the_shadow_switch_equals_the_reference(iterations):
    """The MRP EKF's update (``switch=True``): particles around a truth at 180 deg (|rho| = 1)
    measured near it, so that a good share of the updated states leave the unit ball and are
    mapped to the shadow set, covariance with them."""
    rng = np.random.default_rng(6)
    q_true = rot.quat_normalize(np.array([0.0, 0.6, -0.7, 0.35]))
    x, P = _states_near(rng, N, q_true, log_sigma_attitude=(-3.0, -1.5))
    y = vector_measurement_model(rot.quat_to_mrp(q_true), REFS) + 1e-3 * rng.normal(size=6)
    x_ref, P_ref, z_ref, S_ref = ref.ekf_update(x, P, y, REFS, 1e-3, iterations=iterations)
    x_new, P_new, z_new, S_new = pk.ekf_update(x, P, y, REFS, 1e-3, iterations=iterations)
    assert_states_close(x_new, P_new, x_ref, P_ref, 1e-11)
    assert_innovations_close(z_new, S_new, z_ref, S_ref, 1e-13)
    unswitched, _, _, _ = pk.ekf_update(x, P, y, REFS, 1e-3, switch=False, iterations=iterations)
    assert 0.2 < np.mean(np.sum(unswitched[:, :3] ** 2, axis=1) > 1.0) < 0.8
    assert np.all(np.sum(x_new[:, :3] ** 2, axis=1) <= 1.0)


@pytest.mark.parametrize("sigma", [1e-4, 1e-2])
@pytest.mark.parametrize("iterations", [1, 3])
def test_ekpf_measurement_step_equals_the_reference(sigma, iterations):
    """The fused kernel (EKF update, both Cholesky factors, proposal draw with the given normals,
    log densities, shadow switch) against the oracle's ekpf_proposal_step."""
    rng = np.random.default_rng(4)
    q_true = rot.quat_normalize(np.array([0.2, 0.9, -0.3, 0.25]))
    x, P = _states_near(rng, N, q_true, log_sigma_attitude=(-5.0, -2.0))
    y = vector_measurement_model(rot.quat_to_mrp(q_true), REFS) + sigma * rng.normal(size=6)
    eps = rng.normal(size=(N, 6))
    x_ref, P_ref, inc_ref = ref.ekpf_proposal_step(x, P, y, REFS, sigma, eps, iterations)
    x_new, P_new, inc_new = pk.ekpf_update(x, P, eps, y, REFS, sigma, iterations=iterations)
    assert_states_close(x_new, P_new, x_ref, P_ref, 1e-12)
    assert_log_weights_close(inc_new, inc_ref, sigma)


@pytest.mark.parametrize("iterations", [1, 3])
def test_the_draw_kernel_on_given_factors_is_the_fused_steps_draw(iterations):
    """``ekpf_draw`` (what the EKPF runs on repaired Cholesky factors) on the EKF update and
    numpy's Cholesky factors of healthy covariances gives the fused ``ekpf_update``'s particles,
    covariances and weights: one draw-and-weight kernel, two sources of factors (which differ
    by round-off)."""
    rng = np.random.default_rng(7)
    q_true = rot.quat_normalize(np.array([0.2, 0.9, -0.3, 0.25]))
    x, P = _states_near(rng, N, q_true, log_sigma_attitude=(-5.0, -2.0))
    y = vector_measurement_model(rot.quat_to_mrp(q_true), REFS) + 1e-4 * rng.normal(size=6)
    eps = rng.normal(size=(N, 6))
    m_post, P_post, _, _ = pk.ekf_update(x, P, y, REFS, 1e-4, switch=False, iterations=iterations)
    x_a, P_a, inc_a = pk.ekpf_draw(
        x, m_post, P_post, np.linalg.cholesky(P), np.linalg.cholesky(P_post), eps, y, REFS, 1e-4
    )
    x_b, P_b, inc_b = pk.ekpf_update(x, P, eps, y, REFS, 1e-4, iterations=iterations)
    np.testing.assert_array_equal(P_a, P_b)  # the same EKF update, the same shadow switch
    assert_states_close(x_a, P_a, x_b, P_b, 1e-12)
    assert_log_weights_close(inc_a, inc_b, 1e-4)


def test_log_likelihood_and_attitude_step_equal_the_reference():
    """The bootstrap PF's pieces; a non-finite particle gets -inf in both."""
    rng = np.random.default_rng(5)
    x, _ = _states_anywhere(rng, N)
    rho = x[:, :3].copy()
    rho[7] = np.nan
    y = vector_measurement_model(rot.quat_to_mrp(rot.quat_normalize(rng.normal(size=4))), REFS)
    ll_ref = ref.vector_log_likelihood(rho, y, REFS, SIGMA_STAR)
    ll = pk.vector_log_likelihood(rho, y, REFS, SIGMA_STAR)
    assert ll[7] == ll_ref[7] == -np.inf
    keep = np.arange(N) != 7
    assert_log_weights_close(ll[keep], ll_ref[keep], SIGMA_STAR)
    w = rng.normal(size=(N, 3))
    np.testing.assert_allclose(
        pk.propagate_attitudes(x[:, :3], w, 0.7), ref.propagate_attitudes(x[:, :3], w, 0.7), rtol=0, atol=1e-14
    )


# --------------------------------------------------------------------------------------
# Cores: the same random numbers, the same decisions
# --------------------------------------------------------------------------------------
def _twin_filters(make):
    """The oracle's core and the library's, each with its initial set drawn from the same seed
    (identical sets) and a generator: ``[core, state, rng]`` for the oracle, then the library."""
    twins = []
    for oracle in (True, False):
        core = make(oracle)
        twins.append([core, core.draw_initial_state(np.random.default_rng(11)), np.random.default_rng(12)])
    return twins


def _info_tuple(info):
    return info.accepted, info.resampled, info.degenerate


def _assert_twins_close(ref, new, sigma=SIGMA_STAR, tol=1e-12):
    if ref.covariances is not None:
        assert_states_close(new.particles, new.covariances, ref.particles, ref.covariances, tol)
    else:
        np.testing.assert_allclose(new.particles, ref.particles, rtol=tol, atol=tol * np.abs(ref.particles).max())
    assert_log_weights_close(new.log_weights, ref.log_weights, sigma)


@pytest.mark.parametrize("kind", ["ekpf", "ekpf iterated, 170 deg", "bootstrap", "gyroless"])
def test_filters_equal_the_reference_over_a_run(kind):
    """Each library core and its oracle from the same seed over 25 steps agree to
    round-off at every step, with the same resamplings (same offspring) and the same random
    numbers consumed. Measured: the bootstrap and gyroless PFs bit for bit on this machine
    (their kernels repeat the oracle's scalar expressions; a numpy with other sin/cos
    implementations may differ in the last bit); the EKPF 1e-11 of ``|x| + sqrt(P)`` from its
    first update on (a 1 deg prior against 100 urad vectors: innovations of ~170 sigmas through an
    innovation covariance of condition ~3e4, solved by LU in numpy and by Cholesky here), 8e-11
    for the 170-deg start with the iterated proposal; covariances 3e-15."""
    _, _, ys, wms = simulate_gyro_truth(25, np.random.default_rng(13))
    q0 = rot.rpy_to_quat(np.array([1.0, 1.0, 1.0]) * DEG)
    b0 = np.full(3, 2 * DEG / HOUR)
    tol = 1e-13
    if kind == "ekpf":

        def make(oracle):
            return (ReferenceEkpfCore if oracle else EkpfCore)(300, q0, b0, P0_ATT, SIGMA_V, SIGMA_U)

        tol = 1e-10
    elif kind.startswith("ekpf iterated"):
        q_far = rot.rpy_to_quat(np.array([12.0, -10.0, 170.0]) * DEG)

        def make(oracle):
            return (ReferenceEkpfCore if oracle else EkpfCore)(
                200, q_far, b0, P0_ATT, SIGMA_V, SIGMA_U, proposal_iterations=10
            )

        tol = 1e-9
    elif kind == "bootstrap":

        def make(oracle):
            return (ReferenceBootstrapPfCore if oracle else BootstrapPfCore)(
                500, q0, b0, P0_ATT, 2e-5, bias_roughening=RandomWalkRoughening(1e-7)
            )
    else:
        P0 = np.diag([DEG**2] * 3 + [(0.001 * DEG) ** 2] * 3)

        def make(oracle):
            return (ReferenceGyrolessPfCore if oracle else GyrolessPfCore)(
                500, q0, np.full(3, 1e-5), P0, INERTIA, TORQUE, 1e-6, attitude_process_sigma=3e-5, num_substeps=2
            )

    twins = _twin_filters(make)
    resamplings = 0
    for k in range(len(ys)):
        infos = []
        for twin in twins:
            core, state, rng = twin
            if k > 0:
                state = core.predict(state, None if kind == "gyroless" else wms[k - 1], 1.0, rng)
            twin[1], info = core.update(state, observation(ys[k]), rng)
            infos.append(_info_tuple(info))
        (ref_core, ref, rng_ref), (new_core, new, rng_new) = twins
        assert infos[0] == infos[1]  # the same decisions: accepted, resampled, degenerate
        resamplings += infos[0][1]
        _assert_twins_close(ref, new, tol=tol)
        # both consumed the same random numbers
        assert rng_ref.bit_generator.state == rng_new.bit_generator.state
    assert resamplings > 0
    q_ref, s_ref, _ = ref_core.estimate(ref)
    q_new, s_new, _ = new_core.estimate(new)
    assert np.linalg.norm(rot.quat_error_rotvec(q_ref, q_new)) < 1e-12
    np.testing.assert_allclose(s_new, s_ref, rtol=1e-9)


def test_singular_covariances_take_the_paired_repair_as_the_reference():
    """A zero-variance bias block (the case of
    test_particle_weights.py::test_ekpf_weights_with_a_zero_variance_bias_are_the_predictive_likelihood) and
    an indefinite covariance: a Cholesky factor fails in the fused kernel, the EKPF repairs both
    factors of the whole batch (``particle._paired_cholesky``) and runs the draw-and-weight kernel
    on them; the oracle runs the same repair on its numpy EKF update. Equal to round-off."""
    q0 = rot.quat_normalize(np.array([0.9, 0.2, -0.3, 0.25]))
    P0 = np.diag([(100e-6) ** 2] * 3 + [(1e-7) ** 2] * 3)
    y = vector_measurement_model(rot.quat_to_mrp(q0), REFS) + SIGMA_STAR * np.random.default_rng(1).normal(size=6)
    for damage in ("zero bias block", "indefinite"):
        out = []
        for oracle in (True, False):
            core = (ReferenceEkpfCore if oracle else EkpfCore)(
                16, q0, np.zeros(3), P0, SIGMA_V, SIGMA_U, resampling_gate=EffectiveSampleSizeGate(0.0)
            )
            state = core.draw_initial_state(np.random.default_rng(5))
            covariances = state.covariances.copy()
            if damage == "zero bias block":
                covariances[:, 3:, :] = 0.0
                covariances[:, :, 3:] = 0.0
            else:
                covariances[3, 5, 5] = -1e-20
            assert pk.ekpf_update(state.particles, covariances, np.zeros((16, 6)), y, REFS, SIGMA_STAR) is None
            state, info = core.update(replace(state, covariances=covariances), observation(y), np.random.default_rng(2))
            assert info.accepted
            out.append(state)
        reference, library = out
        scale = np.max(np.abs(reference.covariances), axis=(1, 2))[:, None, None]
        assert np.all(np.abs(library.covariances - reference.covariances) <= 1e-13 * scale)
        np.testing.assert_allclose(library.particles, reference.particles, rtol=0, atol=1e-13)
        assert_log_weights_close(library.log_weights, reference.log_weights, SIGMA_STAR)


def test_the_mrp_ekf_core_equals_the_reference_over_a_run():
    """The MRP EKF core (the kernels, a batch of one) and its oracle over 120 steps of S0,
    classic and iterated, with a gate that rejects the outliers put into three samples: the
    same decisions, states, innovations, covariances and NIS to round-off (measured: states
    6e-12 of ``|x| + sqrt(P)`` at the first updates, whose ~170-sigma innovations go through an
    ill-conditioned ``S`` solved by LU in numpy and by Cholesky in the kernel, as the EKPF's;
    covariances 1e-14)."""
    _, _, ys, wms = simulate_gyro_truth(120, np.random.default_rng(14))
    q0 = rot.rpy_to_quat(np.array([1.0, 1.0, 1.0]) * DEG)
    b0 = np.full(3, 2 * DEG / HOUR)
    outliers = {30, 31, 75}
    for iterations in (1, 3):
        cores = [
            cls(SIGMA_V, SIGMA_U, update_iterations=iterations, innovation_gate_chi2=InnovationGate(probability=0.999))
            for cls in (ReferenceMrpEkfCore, MrpEkfCore)
        ]
        states = [c.initial_state(q0, b0, P0_ATT) for c in cores]
        rejected = 0
        for k in range(len(ys)):
            y = ys[k] + (10 * SIGMA_STAR if k in outliers else 0.0)
            infos = []
            for i, core in enumerate(cores):
                if k > 0:
                    states[i] = core.predict(states[i], wms[k - 1], 1.0)
                states[i], info = core.update(states[i], observation(y))
                infos.append(info)
            (a, b), (ia, ib) = states, infos
            assert ia.accepted == ib.accepted
            rejected += not ia.accepted
            assert_states_close(b.x[None], b.P[None], a.x[None], a.P[None], 1e-10)
            assert_innovations_close(
                ib.innovation[None],
                ib.innovation_covariance[None],
                ia.innovation[None],
                ia.innovation_covariance[None],
                1e-12,
            )
            assert np.isclose(ib.nis, ia.nis, rtol=1e-9)
        assert rejected == len(outliers)


def test_a_whole_s0_scenario_run_equals_the_reference_run(monkeypatch):
    """The shipped S0 small-error scenario (60 s, 1000 particles) with the MRP EKF, the EKPF and
    the roughened bootstrap PF, once as shipped and once built with the oracle's cores, same
    seed: the logged estimates and covariances agree to 1e-10 of each signal's scale (measured
    ~4e-12: round-off of the per-particle matrix products, carried through the weights into the
    weighted mean), with the same resamplings."""
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load
    from drake_att.systems import filter_setups

    names = ["ekf", "ekpf", "bootstrap_pf_roughened"]
    scenario = apply_overrides(load("s0_particle_filters_small_error"), ["duration_s=60", "scoring.score_from_s=20"])
    library = ScenarioDiagram(scenario).simulate(3, estimators=names)
    monkeypatch.setattr(filter_setups, "MrpEkfCore", ReferenceMrpEkfCore)
    monkeypatch.setattr(filter_setups, "EkpfCore", ReferenceEkpfCore)
    monkeypatch.setattr(filter_setups, "BootstrapPfCore", ReferenceBootstrapPfCore)
    oracle = ScenarioDiagram(scenario)
    assert {type(oracle.estimators[n].core) for n in names} == {
        ReferenceMrpEkfCore,
        ReferenceEkpfCore,
        ReferenceBootstrapPfCore,
    }
    reference = oracle.simulate(3, estimators=names)
    compared = 0
    for key, (_t, expected) in reference.signals.items():
        if key.split("/")[0] not in names or key.endswith(("status", "innovations")):
            continue
        new = library.values(key)
        scale = np.max(np.abs(expected), axis=0)
        if key.endswith("particle_diagnostics"):
            np.testing.assert_array_equal(new[:, 1:], expected[:, 1:])  # resamplings, degenerate, N
            scale = np.maximum(scale, 1.0)
        assert np.all(np.abs(new - expected) <= 1e-10 * scale + 1e-300), key
        compared += 1
    assert compared >= 9


# --------------------------------------------------------------------------------------
# Numba's cache
# --------------------------------------------------------------------------------------
_CHILD = """
import warnings
warnings.simplefilter("error")
import numpy as np
from drake_att.filters import particle_kernels
from drake_att.contract import VectorObservations
from drake_att.filters.particle import BootstrapPfCore
r = np.random.default_rng(0)
core = BootstrapPfCore(5, [1, 0, 0, 0], np.zeros(3), np.eye(6) * 1e-6, 1e-6)
obs = VectorObservations(0.0, True, np.eye(3)[:2], np.eye(3)[:2], 1e-3, np.array([1.0, 0, 0, 0]))
assert core.update(core.draw_initial_state(r), obs, r)[1].accepted
print(particle_kernels.CACHING)
"""


@pytest.mark.slow
@pytest.mark.parametrize("locator, caching", [("UserWideCacheLocator", True), ("IPythonCacheLocator", False)])
def test_kernels_work_without_warnings_wherever_numba_can_or_cannot_cache(tmp_path, locator, caching):
    """A read-only package directory (site-packages): numba caches in the user-wide directory
    (here ``$XDG_CACHE_HOME/numba``); no writable location at all (numba raises at decoration):
    the kernels compile in every process. Both without a warning (run with warnings as errors).
    Simulated with numba's ``NUMBA_CACHE_LOCATOR_CLASSES`` (the suite may run as root, which
    ignores read-only permissions); the IPython locator accepts no file outside IPython."""
    env = dict(os.environ, NUMBA_CACHE_LOCATOR_CLASSES=locator, XDG_CACHE_HOME=str(tmp_path), HOME=str(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(_CHILD)], check=False, env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr[-3000:]
    # stderr: only the one-line notice of the first compilation (no warning)
    from drake_att.filters.compiled import COMPILE_MESSAGE

    notice = COMPILE_MESSAGE if caching else COMPILE_MESSAGE.split(" (")[0] + " (no writable cache: every run)"
    assert out.stdout.split() == [str(caching)] and out.stderr.splitlines() == [notice], (
        out.stdout,
        out.stderr[-2000:],
    )
    cached = [f for _, _, fs in os.walk(tmp_path) for f in fs if f.endswith((".nbi", ".nbc"))]
    assert bool(cached) == caching, cached


_FULL_DISK_CHILD = """
import os, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
sys.path.insert(0, sys.argv[1])
import fresh_kernels  # a module no process has compiled: its first call writes numba's cache
hard = resource.getrlimit(resource.RLIMIT_FSIZE)[1]
resource.setrlimit(resource.RLIMIT_FSIZE, (1, hard))  # every file write fails: a full disk
try:
    value = fresh_kernels.plus_one(1.0)
finally:
    resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))
print(value)
"""


@pytest.mark.slow
def test_a_kernel_whose_cache_cannot_be_written_still_runs(tmp_path):
    """A kernel first compiled while its cache file cannot be written (a full disk, a quota, a
    file-size limit) runs compiled in that process: the run goes on (it failed with OSError)."""
    (tmp_path / "fresh_kernels.py").write_text(
        "from drake_att.filters.compiled import jit\n\n\n@jit\ndef plus_one(x):\n    return x + 1.0\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", _FULL_DISK_CHILD, str(tmp_path)], check=False, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.split() == ["2.0"]
    assert not [f for f in os.listdir(tmp_path / "__pycache__") if f.endswith(".nbc")]  # nothing half-written kept


_NOTICE_CHILD = """
from drake_att.filters import compiled
print(compiled.rotvec_to_quat(0.1, 0.2, 0.3)[0])
"""


@pytest.mark.slow
def test_the_first_compilation_is_announced_once_and_a_cache_load_is_silent(tmp_path):
    """A process that compiles prints the notice once (however many kernels it compiles); a
    later process that loads the same kernels from the cache prints nothing."""
    from drake_att.filters.compiled import COMPILE_MESSAGE

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    two_kernels = _NOTICE_CHILD + "print(compiled.quat_multiply(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)[1])\n"
    runs = [
        subprocess.run([sys.executable, "-c", code], check=False, env=env, capture_output=True, text=True)
        for code in (two_kernels, _NOTICE_CHILD)
    ]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr[-2000:]
    assert runs[0].stdout.split() == [str(math.cos(0.5 * math.sqrt(0.14))), "1.0"]
    assert runs[0].stderr.splitlines() == [COMPILE_MESSAGE]
    assert runs[1].stderr == ""
    # another package's numba function compiles silently
    other = subprocess.run(
        [sys.executable, "-c", "import drake_att.filters.compiled, numba\nprint(numba.njit(lambda x: x + 1)(1))"],
        check=False,
        env=env,
        capture_output=True,
        text=True,
    )
    assert other.returncode == 0 and other.stdout.split() == ["2"] and other.stderr == "", other.stderr[-2000:]
