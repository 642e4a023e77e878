"""The compiled MEKF steps (drake_att.filters.mekf_kernels) against the numpy oracle.

``tests/mekf_reference.py`` writes the same formulas in readable numpy (:class:`ReferenceMEKF`);
the library's :class:`MultiplicativeEKF`, which runs the kernels, must give the same predict
and update to round-off (its 6x6 products sum in another order
than numpy's BLAS): relative differences of a few 1e-16 per step, bounded here by 1e-12
over random states, rates, step lengths, mountings, noise levels, gate outcomes and long
runs. A bug in a kernel (a sign, an index, a missing symmetrization) shows as O(1) relative
differences.
"""

import math

import numpy as np
import pytest
from mekf_reference import ReferenceMEKF
from mekf_reference import process_noise as reference_process_noise
from mekf_reference import transition_matrix as reference_transition_matrix

from drake_att import rotations as rot
from drake_att.filters.gating import InnovationGate
from drake_att.filters.mekf import MekfState, MultiplicativeEKF, process_noise, transition_matrix

RTOL = 1e-12


def _random_state(rng, coning=False):
    A = rng.normal(size=(6, 6)) * np.r_[np.full(3, 10 ** rng.uniform(-5, -1)), np.full(3, 10 ** rng.uniform(-7, -4))]
    P = A @ A.T + 1e-14 * np.eye(6)
    prev = np.r_[rng.normal(scale=0.05, size=3), rng.choice([0.0, 0.1, 1.0])] if coning else None
    return MekfState(rot.quat_normalize(rng.normal(size=4)), rng.normal(scale=1e-4, size=3), P, prev)


def _close(a, b, what, scale=None):
    """|a - b| <= RTOL * scale (default: max |b|; a Joseph-form update cancels, so its
    round-off is relative to the prior covariance it started from)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = max(np.max(np.abs(b)) if scale is None else scale, 1e-300)
    assert np.max(np.abs(a - b)) <= RTOL * scale, f"{what}: max |diff| {np.max(np.abs(a - b)):.3e}, scale {scale:.3e}"


def _pair(**kw):
    return MultiplicativeEKF(1e-5, 1e-7, **kw), ReferenceMEKF(1e-5, 1e-7, **kw)


@pytest.mark.parametrize("coning", [False, True])
def test_predict_equals_numpy_reference(coning):
    rng = np.random.default_rng(11)
    fast, ref = _pair(coning_correction=coning)
    for _ in range(300):
        s = _random_state(rng, coning)
        w = rng.normal(scale=10 ** rng.uniform(-6, 0), size=3)  # both branches of the series
        dt = 10 ** rng.uniform(-3, 0.5)
        a, Phi_a, Q_a = fast.predict_linearized(s, w, dt)
        b, Phi_b, Q_b = ref.predict_linearized(s, w, dt)
        _close(a.q_IB, b.q_IB, "q")
        _close(a.P, b.P, "P")
        _close(Phi_a, Phi_b, "Phi")
        assert np.array_equal(Q_a, Q_b) and np.array_equal(a.bias_B, b.bias_B)
        assert np.array_equal(a.P, a.P.T)
        if coning:
            assert np.array_equal(a.previous_gyro, b.previous_gyro)


@pytest.mark.parametrize("gate", [None, 0.99, 11.3])
def test_quaternion_update_equals_numpy_reference(gate):
    rng = np.random.default_rng(12)
    fast, ref = _pair(innovation_gate_chi2=InnovationGate(probability=gate) if gate and gate < 1 else gate)
    outcomes = set()
    for _ in range(300):
        s = _random_state(rng)
        q_BS = rot.quat_normalize(rng.normal(size=4))
        err = rng.normal(scale=10 ** rng.uniform(-6, -1), size=3)
        q_meas = rot.quat_multiply(rot.quat_multiply(s.q_IB, q_BS), rot.rotvec_to_quat(err))
        noise = rng.uniform(1e-6, 1e-3, size=3) if rng.uniform() < 0.5 else np.diag(rng.uniform(1e-12, 1e-6, size=3))
        a, ia = fast.update_quaternion(s, q_meas, q_BS, noise)
        b, ib = ref.update_quaternion(s, q_meas, q_BS, noise)
        assert ia.accepted == ib.accepted
        outcomes.add(ia.accepted)
        _close(ia.innovation, ib.innovation, "z")
        _close(ia.innovation_covariance, ib.innovation_covariance, "S")
        assert math.isclose(ia.nis, ib.nis, rel_tol=1e-10)
        _close(a.q_IB, b.q_IB, "q")
        _close(a.bias_B, b.bias_B, "bias")
        _close(a.P, b.P, "P", scale=np.max(np.abs(s.P)))
        if ia.accepted:
            _close(ia.error_transition, ib.error_transition, "I - KH")
            assert np.array_equal(a.P, a.P.T)
        else:
            assert a is s  # a rejected update returns the state unchanged
    assert outcomes == ({True, False} if gate else {True})


def test_singular_innovation_covariance_is_rejected_like_the_reference():
    fast, ref = _pair()
    s = MekfState(np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros((6, 6)))
    q = np.array([1.0, 0, 0, 0])
    for noise in (np.zeros(3), np.full(3, np.nan), np.diag([1.0, -1.0, 1.0])):
        (_, ia), (_, ib) = fast.update_quaternion(s, q, q, noise), ref.update_quaternion(s, q, q, noise)
        assert not ia.accepted and not ib.accepted and math.isnan(ia.nis) and math.isnan(ib.nis)


def test_a_long_run_stays_within_round_off_of_the_reference():
    """1000 predict + update steps along a tumbling truth: the two paths never drift apart
    by more than round-off (the filter is stable, so round-off does not grow)."""
    rng = np.random.default_rng(3)
    fast, ref = _pair(innovation_gate_chi2=InnovationGate(probability=0.99999))
    sa = sb = fast.initial_state(rot.rpy_to_quat([0.01, -0.02, 0.03]), np.zeros(3), 0.05, 1e-4)
    q_true, w, q_BS = np.array([1.0, 0, 0, 0]), np.array([0.01, -0.02, 0.015]), rot.rpy_to_quat([0.3, 0.2, 0.1])
    sig = np.array([2.4e-5, 2.4e-5, 2.4e-4])
    for _ in range(1000):
        q_true = rot.quat_propagate(q_true, w, 0.1)
        w_meas = w + 1e-4 + rng.normal(scale=1e-5, size=3)
        sa, sb = fast.predict(sa, w_meas, 0.1), ref.predict(sb, w_meas, 0.1)
        q_meas = rot.quat_multiply(rot.quat_multiply(q_true, q_BS), rot.rotvec_to_quat(sig * rng.normal(size=3)))
        sa, _ = fast.update_quaternion(sa, q_meas, q_BS, sig)
        sb, _ = ref.update_quaternion(sb, q_meas, q_BS, sig)
    _close(sa.q_IB, sb.q_IB, "q")
    _close(sa.bias_B, sb.bias_B, "bias")
    np.testing.assert_allclose(sa.P, sb.P, rtol=1e-9, atol=1e-12 * np.max(np.abs(sb.P)))
    assert np.degrees(np.linalg.norm(rot.quat_error_rotvec(sa.q_IB, q_true))) < 0.01


def test_process_noise_and_transition_equal_the_reference():
    """The library's ``process_noise`` and ``transition_matrix`` (used by other cores too) are
    the kernels'; both series branches of the transition included."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        arw, rrw, dt = 10 ** rng.uniform(-7, -3), 10 ** rng.uniform(-9, -5), 10 ** rng.uniform(-3, 1)
        np.testing.assert_allclose(
            process_noise(arw, rrw, dt), reference_process_noise(arw, rrw, dt), rtol=1e-14, atol=0.0
        )
        w = rng.normal(scale=10 ** rng.uniform(-7, 0), size=3)
        np.testing.assert_allclose(
            transition_matrix(w, dt), reference_transition_matrix(w, dt), rtol=1e-13, atol=1e-15 * dt
        )


def test_only_the_library_step_runs_as_one_compiled_call():
    """A subclass that changes the step (the oracle), or the coning correction, is not the
    kernels' step: the estimator runs it in the Python loop."""
    assert MultiplicativeEKF(1e-5, 1e-7).runs_kernel_step()
    assert not ReferenceMEKF(1e-5, 1e-7).runs_kernel_step()
    assert not MultiplicativeEKF(1e-5, 1e-7, coning_correction=True).runs_kernel_step()
