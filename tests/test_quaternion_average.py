"""Tests for :mod:`drake_att.filters.quaternion_average` (Markley et al. 2007).

The average maximizes ``f(q) = sum_i w_i (q_i' q)^2``. For two quaternions the largest
eigenvalue of ``M = w1 q1 q1' + w2 q2 q2'`` is ``(w1 + w2 + z) / 2`` and the eigengap is
``z = sqrt((w1 - w2)^2 + 4 w1 w2 (q1'q2)^2)``; the averaged *vector* is therefore
conditioned like ``(w1 + w2) / z`` and tolerances on it are scaled accordingly, while the
attained objective value is always well conditioned.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar
from strategies import unit_quats, unit_vectors

from drake_att import rotations as rot
from drake_att.filters.quaternion_average import average_quaternions, average_two_quaternions

FAST = settings(max_examples=200, deadline=None)
MEDIUM = settings(max_examples=100, deadline=None)  # invariance checks: several solves each
PI = np.pi

weights = st.floats(0.0, 10.0, allow_nan=False, allow_infinity=False)


@st.composite
def weight_pairs(draw):
    w1, w2 = draw(weights), draw(weights)
    assume(w1 + w2 > 1e-6)
    return w1, w2


def quat_dist(q1, q2) -> float:
    """Sign-invariant distance (0 iff same rotation for unit quaternions)."""
    q1, q2 = np.asarray(q1), np.asarray(q2)
    return min(np.linalg.norm(q1 - q2), np.linalg.norm(q1 + q2))


def angle_between(q1, q2) -> float:
    """Rotation angle (rad) of q1^-1 ⊗ q2."""
    return float(np.linalg.norm(rot.quat_error_rotvec(q1, q2)))


def objective(q, Q, w) -> float:
    return float(np.sum(w * (Q @ q) ** 2))


def two_quat_gap(q1, q2, w1, w2):
    """(lambda_max, z) of M = w1 q1 q1' + w2 q2 q2' (analytic)."""
    d = q1 @ q2
    z = np.sqrt((w1 - w2) ** 2 + 4 * w1 * w2 * d * d)
    return 0.5 * (w1 + w2 + z), z


def wrap(a):
    return (np.asarray(a) + PI) % (2 * PI) - PI


def axis_quat(axis, angle):
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def signed_angle_about(q, axis):
    """Angle of q about the given unit axis (q must be a rotation about that axis)."""
    return 2.0 * np.arctan2(q[1:] @ axis, q[0])


# ----------------------------------------------------------------------------------
# Closed form vs eigenvector method
# ----------------------------------------------------------------------------------
@FAST
@given(unit_quats(), unit_quats(), weight_pairs())
def test_closed_form_matches_eigenvector_method(q1, q2, w):
    w1, w2 = w
    qa = average_two_quaternions(q1, q2, w1, w2)
    qe = average_quaternions(np.stack([q1, q2]), np.array([w1, w2]))
    assert np.all(np.isfinite(qa))
    assert abs(np.linalg.norm(qa) - 1.0) < 1e-15
    assert qa @ q1 >= 0.0  # returned in q1's hemisphere
    assert qe[0] >= 0.0
    lam, z = two_quat_gap(q1, q2, w1, w2)
    Q, W = np.stack([q1, q2]), np.array([w1, w2])
    # Both attain the largest eigenvalue (well conditioned, relative 1e-14).
    assert abs(objective(qa, Q, W) - lam) <= 1e-14 * (w1 + w2)
    assert abs(objective(qe, Q, W) - lam) <= 1e-14 * (w1 + w2)
    # The vectors agree up to sign with eigenvector conditioning (w1 + w2) / z.
    if z > 1e-6 * (w1 + w2):
        assert quat_dist(qa, qe) <= 1e-14 * (w1 + w2) / z + 1e-15


@FAST
@given(unit_quats(), unit_quats(), weight_pairs())
def test_closed_form_equals_formula_of_spec(q1, q2, w):
    """Literal SPEC S3 formula (valid when z > 0) == implementation."""
    w1, w2 = w
    d = q1 @ q2
    z = np.sqrt((w1 - w2) ** 2 + 4 * w1 * w2 * d**2)
    # The literal formula cancels in (w1 - w2 + z) or (w2 - w1 + z) when 4 w1 w2 d^2 is
    # tiny relative to (w1 - w2)^2; the implementation avoids that (compared with the
    # eigenvector method above), so compare with the literal formula only where it is
    # accurate itself.
    assume(z > 1e-3 * (w1 + w2))
    assume(w1 * w2 == 0.0 or min(w1 - w2 + z, w2 - w1 + z) > 1e-3 * (w1 + w2))
    s = 1.0 if d >= 0 else -1.0
    q_spec = (
        np.sqrt(w1 * (w1 - w2 + z) / (z * (w1 + w2 + z))) * q1
        + s * np.sqrt(w2 * (w2 - w1 + z) / (z * (w1 + w2 + z))) * q2
    )
    assert abs(np.linalg.norm(q_spec) - 1.0) < 1e-10
    np.testing.assert_allclose(average_two_quaternions(q1, q2, w1, w2), q_spec, atol=1e-10)


# ----------------------------------------------------------------------------------
# Identities, symmetries, invariances
# ----------------------------------------------------------------------------------
@MEDIUM
@given(unit_quats(), weight_pairs(), st.integers(1, 6))
def test_average_with_itself(q, w, n):
    w1, w2 = w
    np.testing.assert_allclose(average_two_quaternions(q, q, w1, w2), q, atol=1e-15)
    np.testing.assert_allclose(average_two_quaternions(q, -q, w1, w2), q, atol=1e-15)
    np.testing.assert_allclose(average_two_quaternions(q, 3.0 * q, w1, w2), q, atol=1e-15)
    signs = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)[:, None]
    qn = average_quaternions(signs * q, np.linspace(1.0, 2.0, n))
    assert qn[0] >= 0.0
    assert quat_dist(qn, q) < 1e-14


@MEDIUM
@given(unit_quats(), unit_quats(), weight_pairs())
def test_two_quaternion_sign_invariance(q1, q2, w):
    w1, w2 = w
    qa = average_two_quaternions(q1, q2, w1, w2)
    variants = {
        (1, -1): average_two_quaternions(q1, -q2, w1, w2),
        (-1, 1): average_two_quaternions(-q1, q2, w1, w2),
        (-1, -1): average_two_quaternions(-q1, -q2, w1, w2),
    }
    for (s1, _), q in variants.items():
        if q1 @ q2 != 0.0:
            # q2 -> -q2: identical result; q1 -> -q1: -qa (result follows q1's hemisphere).
            np.testing.assert_allclose(q, s1 * qa, atol=1e-15)
        else:  # sign(0) := +1, so only the rotation (not the sign) is invariant here
            assert quat_dist(q, qa) < 1e-15


@MEDIUM
@given(unit_quats(), unit_quats(), weight_pairs(), st.floats(1e-3, 1e3))
def test_two_quaternion_symmetry_and_weight_scale(q1, q2, w, c):
    w1, w2 = w
    qa = average_two_quaternions(q1, q2, w1, w2)
    _, z = two_quat_gap(q1, q2, w1, w2)
    # Scaling both weights changes nothing (beyond rounding of the weight ratio).
    np.testing.assert_allclose(
        average_two_quaternions(q1, q2, c * w1, c * w2), qa, atol=1e-14 * (w1 + w2) / max(z, 1e-300) + 1e-15
    )
    # Swapping (q1, w1) <-> (q2, w2) gives the same rotation.
    if z > 1e-6 * (w1 + w2):
        qs = average_two_quaternions(q2, q1, w2, w1)
        assert quat_dist(qs, qa) <= 1e-14 * (w1 + w2) / z + 1e-15


@MEDIUM
@given(st.lists(unit_quats(), min_size=1, max_size=8), st.data())
def test_eigen_method_invariances(qs, data):
    Q = np.stack(qs)
    n = len(qs)
    w = np.array(data.draw(st.lists(st.floats(0.01, 10.0), min_size=n, max_size=n)))
    qa = average_quaternions(Q, w)
    assert qa[0] >= 0.0
    assert abs(np.linalg.norm(qa) - 1.0) < 1e-15
    lam = np.linalg.eigvalsh((Q * w[:, None]).T @ Q)
    assert abs(objective(qa, Q, w) - lam[-1]) <= 1e-13 * w.sum()
    gap = (lam[-1] - lam[-2]) / w.sum()
    assume(gap > 1e-6)
    tol = 1e-14 / gap + 1e-15
    signs = np.array(data.draw(st.lists(st.sampled_from([-1.0, 1.0]), min_size=n, max_size=n)))
    perm = np.array(data.draw(st.permutations(range(n))))
    c = data.draw(st.floats(1e-3, 1e3))
    assert quat_dist(average_quaternions(signs[:, None] * Q, w), qa) <= tol
    assert quat_dist(average_quaternions(Q[perm], w[perm]), qa) <= tol
    assert quat_dist(average_quaternions(Q, c * w), qa) <= tol
    assert quat_dist(average_quaternions(7.0 * Q, w), qa) <= tol  # inputs are normalized
    # Zero-weight entries are ignored.
    extra = np.array([[0.1, 0.7, -0.7, 0.1]])
    assert quat_dist(average_quaternions(np.vstack([Q, extra]), np.append(w, 0.0)), qa) <= tol


@MEDIUM
@given(st.lists(unit_quats(), min_size=2, max_size=6), unit_quats(), unit_quats(), st.data())
def test_bi_invariance(qs, p, r, data):
    """avg(p ⊗ q_i ⊗ r) = p ⊗ avg(q_i) ⊗ r: the frame convention does not matter."""
    Q = np.stack(qs)
    n = len(qs)
    w = np.array(data.draw(st.lists(st.floats(0.01, 10.0), min_size=n, max_size=n)))
    lam = np.linalg.eigvalsh((Q * w[:, None]).T @ Q)
    gap = (lam[-1] - lam[-2]) / w.sum()
    assume(gap > 1e-6)
    tol = 1e-13 / gap
    qa = average_quaternions(Q, w)
    Qt = rot.quat_multiply(rot.quat_multiply(p, Q), r)
    expected = rot.quat_multiply(rot.quat_multiply(p, qa), r)
    assert quat_dist(average_quaternions(Qt, w), expected) <= tol
    q1t, q2t = Qt[0], Qt[1]
    e2 = rot.quat_multiply(rot.quat_multiply(p, average_two_quaternions(Q[0], Q[1], w[0], w[1])), r)
    _, z = two_quat_gap(Q[0], Q[1], w[0], w[1])
    if z > 1e-6 * (w[0] + w[1]):
        assert quat_dist(average_two_quaternions(q1t, q2t, w[0], w[1]), e2) <= (1e-13 * (w[0] + w[1]) / z)


# ----------------------------------------------------------------------------------
# Edge cases of the closed form
# ----------------------------------------------------------------------------------
@MEDIUM
@given(unit_quats(), unit_quats(), st.floats(1e-3, 10.0))
def test_zero_weight_returns_other_quaternion(q1, q2, w):
    np.testing.assert_allclose(average_two_quaternions(q1, q2, w, 0.0), q1, atol=1e-15)
    s = -1.0 if q1 @ q2 < 0 else 1.0
    np.testing.assert_allclose(average_two_quaternions(q1, q2, 0.0, w), s * q2, atol=1e-15)
    qe = average_quaternions(np.stack([q1, q2]), [0.0, w])
    assert qe[0] >= 0.0
    assert quat_dist(qe, q2) < 1e-14


@MEDIUM
@given(unit_quats(), unit_quats(), st.floats(0.1, 10.0), st.floats(0.1, 10.0))
def test_orthogonal_quaternions(q, r, w1, w2):
    """q1'q2 == 0 (rotations 180 deg apart): no NaN; heavier wins; equal -> q1."""
    r = r - (r @ q) * q  # make q2 exactly orthogonal to q1 (up to rounding)
    assume(np.linalg.norm(r) > 1e-3)
    q2 = r / np.linalg.norm(r)
    q2 = q2 - (q2 @ q) * q
    q2 /= np.linalg.norm(q2)
    qe = average_two_quaternions(q, q2, 1.0, 1.0)
    assert np.all(np.isfinite(qe))
    # With |q1'q2| ~ 1e-17 the gap z ~ 1e-17: the average is any unit vector in span(q1, q2)
    # (all attain the maximum eigenvalue); the exactly-degenerate case returns q1.
    Q = np.stack([q, q2])
    assert abs(objective(qe, Q, np.ones(2)) - two_quat_gap(q, q2, 1.0, 1.0)[0]) < 1e-14
    assume(abs(w1 - w2) > 1e-3)
    qa = average_two_quaternions(q, q2, w1, w2)
    heavier = q if w1 > w2 else q2 * (1.0 if q @ q2 >= 0 else -1.0)
    assert quat_dist(qa, heavier) < 1e-12 / abs(w1 - w2)


def test_exactly_degenerate_cases():
    q1 = np.array([1.0, 0.0, 0.0, 0.0])
    q2 = np.array([0.0, 1.0, 0.0, 0.0])  # 180 deg about x: q1'q2 == 0
    np.testing.assert_array_equal(average_two_quaternions(q1, q2, 1.0, 1.0), q1)
    np.testing.assert_array_equal(average_two_quaternions(q2, q1, 2.0, 2.0), q2)
    np.testing.assert_array_equal(average_two_quaternions(q1, q2, 1.0, 2.0), q2)
    np.testing.assert_array_equal(average_two_quaternions(q1, q2, 2.0, 1.0), q1)
    np.testing.assert_array_equal(average_two_quaternions(q1, -q1, 1.0, 1.0), q1)
    np.testing.assert_array_equal(average_two_quaternions(-q1, q1, 1.0, 1.0), -q1)
    # Extreme weights stay finite (weights are normalized internally).
    for w1, w2 in [(1e-320, 0.0), (1e308, 1e308), (1e-300, 1.0), (5e-324, 5e-324)]:
        qa = average_two_quaternions(q1, axis_quat(np.array([0, 0, 1.0]), 0.3), w1, w2)
        assert np.all(np.isfinite(qa)) and abs(np.linalg.norm(qa) - 1) < 1e-15
    qa = average_quaternions(np.stack([q1, q2]), [1e308, 1e308])
    assert np.all(np.isfinite(qa)) and abs(np.linalg.norm(qa) - 1) < 1e-15
    # Extreme quaternion magnitudes are normalized without overflow/underflow.
    q3 = axis_quat(np.array([0, 0, 1.0]), 0.3)
    for c in (1e-300, 1e300):
        np.testing.assert_allclose(average_two_quaternions(c * q1, c * q3), average_two_quaternions(q1, q3), atol=1e-15)
        np.testing.assert_allclose(
            average_quaternions(np.stack([c * q1, c * q3])), average_quaternions(np.stack([q1, q3])), atol=1e-15
        )
    # Nearly degenerate: tiny q1'q2 with equal weights gives a finite unit quaternion.
    for eps in (1e-8, 1e-100, 1e-170, 1e-320):
        q2e = np.array([eps, 1.0, 0.0, 0.0])
        qa = average_two_quaternions(q1, q2e, 1.0, 1.0)
        assert np.all(np.isfinite(qa)) and abs(np.linalg.norm(qa) - 1) < 1e-15


def test_default_weights_are_equal():
    q1 = axis_quat(np.array([0.0, 0.0, 1.0]), 0.2)
    q2 = axis_quat(np.array([0.0, 0.0, 1.0]), 0.6)
    np.testing.assert_allclose(average_two_quaternions(q1, q2), axis_quat(np.array([0.0, 0.0, 1.0]), 0.4), atol=1e-15)
    Q = np.stack([q1, q2, axis_quat(np.array([1.0, 0, 0]), 0.1)])
    np.testing.assert_allclose(average_quaternions(Q), average_quaternions(Q, [2.0, 2.0, 2.0]), atol=1e-15)


# ----------------------------------------------------------------------------------
# Same-axis rotations: exact relation and the weighted-mean-angle approximation
# ----------------------------------------------------------------------------------
def _dense_argmax(a, w):
    """Maximizer of g(phi) = sum_i w_i cos^2((phi - a_i)/2) by grid search + refinement."""
    grid = np.linspace(-PI, PI, 20001)
    g = (w[None, :] * np.cos((grid[:, None] - a[None, :]) / 2) ** 2).sum(axis=1)
    k = int(np.argmax(g))
    h = grid[1] - grid[0]
    res = minimize_scalar(
        lambda p: -np.sum(w * np.cos((p - a) / 2) ** 2),
        bounds=(grid[k] - 2 * h, grid[k] + 2 * h),
        method="bounded",
        options={"xatol": 1e-12},
    )
    return res.x


@MEDIUM
@given(unit_vectors(), st.lists(st.floats(-PI, PI), min_size=2, max_size=5), st.data())
def test_same_axis_exact_maximizer(axis, angles, data):
    """For rotations about one axis n by angles a_i, q = [cos(phi/2), sin(phi/2) n] and
    (q_i' q)^2 = cos^2((phi - a_i)/2) = (1 + cos(phi - a_i))/2, so the average is the
    rotation about n by the weighted *circular* mean

        phi* = atan2(sum w_i sin a_i, sum w_i cos a_i),

    i.e. the maximizer of sum_i w_i cos^2((phi - a_i)/2). Checked against the closed form
    and against a dense 1-D search. The eigengap equals |sum w_i exp(i a_i)|, which sets
    the conditioning.
    """
    a = np.array(angles)
    n = len(a)
    w = np.array(data.draw(st.lists(st.floats(0.05, 5.0), min_size=n, max_size=n)))
    resultant = abs(np.sum(w * np.exp(1j * a))) / w.sum()
    assume(resultant > 1e-3)
    Q = np.stack([axis_quat(axis, ai) for ai in a])
    qa = average_quaternions(Q, w)
    # The result is a rotation about the same axis.
    assert np.linalg.norm(np.cross(qa[1:], axis)) < 1e-13 / resultant
    phi = signed_angle_about(qa, axis)
    phi_exact = np.arctan2(np.sum(w * np.sin(a)), np.sum(w * np.cos(a)))
    assert abs(wrap(phi - phi_exact)) < 1e-13 / resultant
    assert abs(wrap(phi - _dense_argmax(a, w))) < 1e-6
    if n == 2:
        q2 = average_two_quaternions(Q[0], Q[1], w[0], w[1])
        assert abs(wrap(signed_angle_about(q2, axis) - phi_exact)) < 1e-13 / resultant


@FAST
@given(unit_vectors(), st.floats(-PI, PI), st.floats(-PI + 1e-3, PI - 1e-3), st.floats(0.1, 10))
def test_same_axis_equal_weights_is_exact_mean(axis, a1, delta, w):
    """Equal weights: exactly the mean angle (a1 + a2)/2 for |a2 - a1| < pi."""
    a2 = a1 + delta
    qa = average_two_quaternions(axis_quat(axis, a1), axis_quat(axis, a2), w, w)
    assert abs(wrap(signed_angle_about(qa, axis) - (a1 + a2) / 2)) < 1e-13 / np.cos(delta / 2)


@FAST
@given(unit_vectors(), st.floats(-PI, PI), st.floats(-0.5, 0.5), st.floats(0.01, 10), st.floats(0.01, 10))
def test_same_axis_weighted_mean_angle_approximation(axis, a1, delta, w1, w2):
    """Unequal weights: close to, but not exactly, the linear weighted mean angle.

    With u = w2/(w1 + w2) and delta = a2 - a1, the exact average angle is
    a1 + atan(u sin(delta) / (1 - u + u cos(delta))), whose expansion is

        phi = (w1 a1 + w2 a2)/(w1 + w2) - u (1 - u) (1 - 2u) delta^3 / 6 + O(delta^5).

    So the linear weighted mean is exact for equal weights (u = 1/2) and otherwise off by at
    most max_u |u(1-u)(1-2u)|/6 = 0.01604 |delta|^3 (+ O(delta^5)) -- e.g. 1.6e-5 rad for
    delta = 0.1 rad, i.e. negligible for averaging star-tracker-grade estimates. The
    O(delta^5) remainder is <= 0.0013 |delta|^5 for |delta| <= 0.5 (numerically bounded).
    """
    a2 = a1 + delta
    qa = average_two_quaternions(axis_quat(axis, a1), axis_quat(axis, a2), w1, w2)
    phi = signed_angle_about(qa, axis)
    u = w2 / (w1 + w2)
    linear = (w1 * a1 + w2 * a2) / (w1 + w2)
    err = wrap(phi - linear)
    c3 = -u * (1 - u) * (1 - 2 * u) / 6
    assert abs(err) <= 0.01604 * abs(delta) ** 3 + 0.0013 * abs(delta) ** 5 + 1e-13
    assert abs(err - c3 * delta**3) <= 0.0013 * abs(delta) ** 5 + 1e-13
    exact = a1 + np.arctan2(u * np.sin(delta), 1 - u + u * np.cos(delta))
    assert abs(wrap(phi - exact)) < 1e-13


# ----------------------------------------------------------------------------------
# Statistics: averaging noisy measurements
# ----------------------------------------------------------------------------------
def _noisy_cluster(rng, q0, sigmas):
    dtheta = rng.normal(size=(len(sigmas), 3)) * np.asarray(sigmas)[:, None]
    return rot.quat_multiply(q0, rot.rotvec_to_quat(dtheta))


def test_average_of_noisy_cluster_beats_single_samples():
    """N isotropic samples (sigma = 0.01 rad) around q0: the average's error is ~1/sqrt(N)
    of a single sample's, and smaller on average than that of every individual sample."""
    rng = np.random.default_rng(20070101)
    n, trials, sigma = 25, 400, 0.01
    err_avg = np.empty(trials)
    err_avg2 = np.empty(trials)
    err_single = np.empty((trials, n))
    for t in range(trials):
        q0 = rot.quat_normalize(rng.normal(size=4))
        Q = _noisy_cluster(rng, q0, np.full(n, sigma))
        Q *= rng.choice([-1.0, 1.0], size=(n, 1))  # random signs must not matter
        err_avg[t] = angle_between(q0, average_quaternions(Q))
        err_avg2[t] = angle_between(q0, average_two_quaternions(Q[0], Q[1]))
        err_single[t] = [angle_between(q0, q) for q in Q]
    mean_single = err_single.mean(axis=0)
    assert err_avg.mean() < mean_single.min()
    ratio = err_avg.mean() / mean_single.mean()
    assert 0.85 / np.sqrt(n) < ratio < 1.15 / np.sqrt(n)
    # Two samples: error ~ 1/sqrt(2) of a single one.
    ratio2 = err_avg2.mean() / mean_single.mean()
    assert 0.85 / np.sqrt(2) < ratio2 < 1.15 / np.sqrt(2)
    # Per trial, the average beats the median single sample almost always.
    assert np.mean(err_avg < np.median(err_single, axis=1)) > 0.95


def test_inverse_variance_weights_reach_theoretical_accuracy():
    """Heteroscedastic samples: w_i = 1/sigma_i^2 beats equal weights, and the error matches
    the small-angle minimum-variance value E|e| = 2 sqrt(2/pi) / sqrt(sum 1/sigma_i^2)."""
    rng = np.random.default_rng(7)
    sigmas = np.geomspace(0.001, 0.05, 12)
    w = 1.0 / sigmas**2
    trials = 400
    e_w, e_eq = np.empty(trials), np.empty(trials)
    for t in range(trials):
        q0 = rot.quat_normalize(rng.normal(size=4))
        Q = _noisy_cluster(rng, q0, sigmas)
        e_w[t] = angle_between(q0, average_quaternions(Q, w))
        e_eq[t] = angle_between(q0, average_quaternions(Q))
    theory = 2 * np.sqrt(2 / np.pi) / np.sqrt(w.sum())
    assert 0.85 < e_w.mean() / theory < 1.15
    assert e_w.mean() < 0.5 * e_eq.mean()
    # Two-quaternion closed form with inverse-variance weights.
    s1, s2 = 0.002, 0.006
    e2 = np.empty(trials)
    for t in range(trials):
        q0 = rot.quat_normalize(rng.normal(size=4))
        q1, q2 = _noisy_cluster(rng, q0, [s1, s2])
        e2[t] = angle_between(q0, average_two_quaternions(q1, q2, 1 / s1**2, 1 / s2**2))
    theory2 = 2 * np.sqrt(2 / np.pi) / np.sqrt(1 / s1**2 + 1 / s2**2)
    assert 0.85 < e2.mean() / theory2 < 1.15


# ----------------------------------------------------------------------------------
# Input validation
# ----------------------------------------------------------------------------------
Q_OK = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
q_ok = np.array([1.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize(
    "call, needles",
    [
        (lambda: average_two_quaternions([0.0, 0, 0, 0], q_ok), ["q1", "non-zero", "0."]),
        (lambda: average_two_quaternions(q_ok, [np.nan, 0, 0, 1]), ["q2", "finite", "nan"]),
        (lambda: average_two_quaternions(q_ok, [np.inf, 0, 0, 1]), ["q2", "finite", "inf"]),
        (lambda: average_two_quaternions([1.0, 0, 0], q_ok), ["q1", "(4,)", "(3,)"]),
        (lambda: average_two_quaternions(q_ok, "abc"), ["q2", "abc"]),
        (lambda: average_two_quaternions(q_ok, q_ok, -1.0, 1.0), ["w1", ">= 0", "-1.0"]),
        (lambda: average_two_quaternions(q_ok, q_ok, 1.0, np.nan), ["w2", "finite", "nan"]),
        (lambda: average_two_quaternions(q_ok, q_ok, 1.0, np.inf), ["w2", "finite", "inf"]),
        (lambda: average_two_quaternions(q_ok, q_ok, [1.0, 2.0], 1.0), ["w1", "scalar"]),
        (lambda: average_two_quaternions(q_ok, q_ok, 1j, 1.0), ["w1", "real", "1j"]),
        (lambda: average_two_quaternions(q_ok, q_ok, 1.0, "abc"), ["w2", "real", "abc"]),
        (lambda: average_two_quaternions(q_ok, q_ok, 0.0, 0.0), ["w1 + w2", "> 0", "0.0"]),
        (lambda: average_quaternions(np.zeros((0, 4))), ["quaternions", "(N, 4)", "(0, 4)"]),
        (lambda: average_quaternions(np.ones((3, 3))), ["quaternions", "(N, 4)", "(3, 3)"]),
        (lambda: average_quaternions(np.ones(4)), ["quaternions", "(N, 4)", "(4,)"]),
        (lambda: average_quaternions([[1.0, 0, 0, 0], [0, 0, 0, 0]]), ["quaternions[1]", "non-zero", "0."]),
        (lambda: average_quaternions([[1.0, 0, 0, np.nan]]), ["quaternions[0]", "finite", "nan"]),
        # A missing value (None, e.g. a null in a parsed log) is a NaN, not a TypeError.
        (lambda: average_quaternions([[1.0, 0, 0, None]]), ["quaternions[0]", "finite", "nan"]),
        (lambda: average_quaternions([[1.0 + 1j, 0, 0, 0]]), ["quaternions", "real", "1j"]),
        (lambda: average_quaternions([[1.0, 0, 0, 0], [0, 0, np.nan, 1.0]]), ["quaternions[1]", "finite", "nan"]),
        (lambda: average_quaternions(Q_OK, [1.0, -2.0]), ["weights[1]", ">= 0", "-2.0", "weights=[ 1. -2.]"]),
        (lambda: average_quaternions(Q_OK, "abc"), ["weights", "real", "abc", "(2,)"]),
        (lambda: average_quaternions(Q_OK, [1j, 1.0]), ["weights", "real", "1j"]),
        (lambda: average_quaternions(Q_OK, [1.0, np.nan]), ["weights[1]", "finite", "nan"]),
        (lambda: average_quaternions(Q_OK, [np.inf, 1.0]), ["weights[0]", "finite", "inf"]),
        (lambda: average_quaternions(Q_OK, [0.0, 0.0]), ["weights", "positive sum", "0."]),
        (lambda: average_quaternions(Q_OK, [1.0, 2.0, 3.0]), ["weights", "(2,)", "(3,)"]),
        (lambda: average_quaternions(Q_OK, [[1.0, 2.0]]), ["weights", "(2,)", "(1, 2)"]),
    ],
)
def test_invalid_inputs_raise_value_error(call, needles):
    """The documented ValueError, naming the argument and the offending value.

    Argument names must appear as whole words (a mangled "XXw1XX" does not name w1). Run
    under np.errstate(all="raise"): validation must reject the input before any arithmetic
    on it (e.g. no 0/0 while scaling all-zero weights), so a caller who turns floating-point
    warnings into errors still gets the ValueError.
    """
    with np.errstate(all="raise"), pytest.raises(ValueError) as info:
        call()
    msg = str(info.value)
    for needle in needles:
        if re.fullmatch(r"\w+(\[\d+\])?", needle):
            assert re.search(rf"(?<!\w){re.escape(needle)}(?!\w)", msg), f"{needle!r} not a whole word in {msg!r}"
        else:
            assert needle in msg, f"{needle!r} not in {msg!r}"
