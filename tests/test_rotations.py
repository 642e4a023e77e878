"""Property-based tests for :mod:`drake_att.rotations`, checked against pydrake.

Conventions under test: quaternions ``[w, x, y, z]``, Hamilton product, ``q_IB`` maps
B-vectors into I (``v_I = R(q_IB) v_B``), exactly as Drake's ``Quaternion`` /
``RotationMatrix``. Rotations are compared sign-invariantly (``q`` and ``-q``) wherever
the function does not promise a particular sign.

Tolerances: ~1e-14 for well-conditioned closed-form maps (a few ulps of O(1) numbers),
~1e-12 for round trips, ~1e-9..1e-7 for finite-difference checks (O(h^2) truncation plus
O(eps/h) rounding), and relative tolerances for tiny rotation vectors.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from pydrake.common.eigen_geometry import AngleAxis, Quaternion
from pydrake.math import RollPitchYaw, RotationMatrix
from strategies import unit_quats, unit_vectors

from drake_att import rotations as rot

FAST = settings(max_examples=200, deadline=None)
MEDIUM = settings(max_examples=100, deadline=None)
FEWER = settings(max_examples=60, deadline=None)

PI = np.pi

# ----------------------------------------------------------------------------------
# Strategies and helpers
# ----------------------------------------------------------------------------------


def vectors(scale=10.0):
    x = st.floats(-scale, scale, allow_nan=False)
    return st.tuples(x, x, x).map(np.array)


def rotvecs(lo=0.0, hi=PI):
    return st.builds(lambda n, a: n * a, unit_vectors(), st.floats(lo, hi))


rpy_any = st.builds(
    lambda r, p, y: np.array([r, p, y]),
    st.floats(-PI, PI),
    st.floats(-PI / 2, PI / 2),
    st.floats(-PI, PI),
)
# Away from gimbal lock (|pitch| <= pi/2 - 1e-3): quat -> rpy is well defined.
rpy_regular = st.builds(
    lambda r, p, y: np.array([r, p, y]),
    st.floats(-PI, PI),
    st.floats(-PI / 2 + 1e-3, PI / 2 - 1e-3),
    st.floats(-PI, PI),
)


def drake_quat(q) -> Quaternion:
    q = np.asarray(q, dtype=float)
    return Quaternion(q / np.linalg.norm(q))


def drake_R(q) -> np.ndarray:
    return RotationMatrix(drake_quat(q)).matrix()


def quat_dist(q1, q2) -> float:
    """Sign-invariant distance between quaternions (0 iff same rotation, for unit q)."""
    q1, q2 = np.asarray(q1), np.asarray(q2)
    return min(np.linalg.norm(q1 - q2), np.linalg.norm(q1 + q2))


def vee(S) -> np.ndarray:
    return np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]]) / 2.0


def wrap(a):
    return (np.asarray(a) + PI) % (2 * PI) - PI


def assert_rotation_matrix(R, tol=1e-13):
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=tol)
    assert abs(np.linalg.det(R) - 1.0) < tol


# ----------------------------------------------------------------------------------
# skew, identity, normalize, canonical, conjugate, multiply
# ----------------------------------------------------------------------------------
@MEDIUM
@given(vectors(), vectors())
def test_skew_is_cross_product(a, b):
    K = rot.skew(a)
    np.testing.assert_array_equal(K, -K.T)
    np.testing.assert_allclose(K @ b, np.cross(a, b), rtol=0, atol=1e-13)


@pytest.mark.parametrize("shape", [(), (3,), (2, 5)])
def test_quat_identity(shape):
    q = rot.quat_identity(shape)
    assert q.shape == tuple(shape) + (4,)
    np.testing.assert_array_equal(q[..., 0], 1.0)
    np.testing.assert_array_equal(q[..., 1:], 0.0)
    np.testing.assert_array_equal(rot.quat_to_rotmat(q), np.broadcast_to(np.eye(3), shape + (3, 3)))
    np.testing.assert_array_equal(rot.quat_identity(), Quaternion.Identity().wxyz())


@MEDIUM
@given(unit_quats(), st.floats(1e-3, 1e3))
def test_quat_normalize(q, scale):
    qn = rot.quat_normalize(scale * q)
    assert abs(np.linalg.norm(qn) - 1.0) < 1e-15
    np.testing.assert_allclose(qn, q, rtol=0, atol=1e-15)


@MEDIUM
@given(unit_quats())
def test_quat_canonical(q):
    for qq in (q, -q):
        c = rot.quat_canonical(qq)
        assert c[0] >= 0.0
        assert np.array_equal(c, q) or np.array_equal(c, -q)
        np.testing.assert_array_equal(rot.quat_canonical(c), c)
        np.testing.assert_allclose(rot.quat_to_rotmat(c), drake_R(q), atol=1e-15)


@MEDIUM
@given(unit_quats())
def test_quat_conjugate(q):
    qc = rot.quat_conjugate(q)
    np.testing.assert_allclose(qc, drake_quat(q).conjugate().wxyz(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(rot.quat_multiply(q, qc), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_multiply(qc, q), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_rotmat(qc), drake_R(q).T, atol=1e-15)


@FAST
@given(unit_quats(), unit_quats(), unit_quats())
def test_quat_multiply_composition(p, q, r):
    pq = rot.quat_multiply(p, q)
    # Same as Drake's (Eigen's) Hamilton product, and R(p ⊗ q) = R(p) R(q).
    np.testing.assert_allclose(pq, drake_quat(p).multiply(drake_quat(q)).wxyz(), atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_rotmat(pq), drake_R(p) @ drake_R(q), atol=1e-14)
    # Associativity and identity.
    np.testing.assert_allclose(rot.quat_multiply(pq, r), rot.quat_multiply(p, rot.quat_multiply(q, r)), atol=1e-15)
    np.testing.assert_array_equal(rot.quat_multiply(p, rot.quat_identity()), p)
    np.testing.assert_array_equal(rot.quat_multiply(rot.quat_identity(), p), p)


# ----------------------------------------------------------------------------------
# Quaternion <-> rotation matrix, rotate
# ----------------------------------------------------------------------------------
@FAST
@given(unit_quats(), st.floats(1e-3, 1e3))
def test_quat_to_rotmat_matches_drake(q, scale):
    R = rot.quat_to_rotmat(q)
    np.testing.assert_allclose(R, drake_R(q), rtol=0, atol=2e-15)
    assert_rotation_matrix(R, 1e-14)
    # Non-unit quaternions are normalized first; -q is the same rotation.
    np.testing.assert_allclose(rot.quat_to_rotmat(scale * q), R, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rot.quat_to_rotmat(-q), R, rtol=0, atol=0)


@FAST
@given(unit_quats())
def test_rotmat_to_quat_matches_drake_and_round_trips(q):
    R = drake_R(q)
    qr = rot.rotmat_to_quat(R)
    assert qr[0] >= 0.0
    assert abs(np.linalg.norm(qr) - 1.0) < 1e-15
    assert quat_dist(qr, RotationMatrix(R).ToQuaternion().wxyz()) < 1e-14
    # Round trip recovers the canonical quaternion (sign-invariant only when w ~ 0).
    assert quat_dist(qr, q) < 1e-14
    if abs(q[0]) > 1e-6:
        np.testing.assert_allclose(qr, rot.quat_canonical(q), atol=1e-14)
    np.testing.assert_allclose(rot.quat_to_rotmat(qr), R, atol=1e-14)


@FAST
@given(unit_vectors(), st.floats(PI - 1e-3, PI))
def test_rotmat_to_quat_near_half_turn(axis, angle):
    """Rotations near 180 deg exercise the x/y/z branches of Shepperd's method."""
    R = RotationMatrix(AngleAxis(angle, axis)).matrix()
    qr = rot.rotmat_to_quat(R)
    assert qr[0] >= 0.0
    np.testing.assert_allclose(rot.quat_to_rotmat(qr), R, atol=1e-14)
    assert quat_dist(qr, AngleAxis(angle, axis).quaternion().wxyz()) < 1e-14


@pytest.mark.parametrize(
    "R",
    [
        np.eye(3),
        np.diag([1.0, -1.0, -1.0]),  # 180 deg about x
        np.diag([-1.0, 1.0, -1.0]),  # 180 deg about y
        np.diag([-1.0, -1.0, 1.0]),  # 180 deg about z
    ],
)
def test_rotmat_to_quat_exact_cases(R):
    q = rot.rotmat_to_quat(R)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(rot.quat_to_rotmat(q), R, atol=1e-15)
    assert quat_dist(q, RotationMatrix(R).ToQuaternion().wxyz()) < 1e-15


@FAST
@given(unit_quats(), vectors(), st.floats(1e-3, 1e3))
def test_quat_rotate(q, v, scale):
    expected = RotationMatrix(drake_quat(q)).multiply(v)
    np.testing.assert_allclose(rot.quat_rotate(q, v), expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(rot.quat_rotate(q, v), rot.quat_to_rotmat(q) @ v, atol=1e-13)
    np.testing.assert_allclose(rot.quat_rotate(scale * q, v), expected, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------
# Rotation vectors
# ----------------------------------------------------------------------------------
@FAST
@given(unit_vectors(), st.floats(0.0, 2 * PI))
def test_rotvec_to_quat_and_rotmat_match_drake(axis, angle):
    aa = AngleAxis(angle, axis)
    phi = angle * axis
    q = rot.rotvec_to_quat(phi)
    # Eigen's AngleAxis -> quaternion is [cos(a/2), sin(a/2) n]: same sign as ours.
    np.testing.assert_allclose(q, aa.quaternion().wxyz(), rtol=0, atol=1e-15)
    R_drake = RotationMatrix(aa).matrix()
    np.testing.assert_allclose(rot.rotvec_to_rotmat(phi), R_drake, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rot.quat_to_rotmat(q), R_drake, rtol=0, atol=1e-14)


@FAST
@given(unit_vectors(), st.floats(0.0, PI - 1e-3))
def test_rotvec_round_trip(axis, angle):
    phi = angle * axis
    q = rot.rotvec_to_quat(phi)
    np.testing.assert_allclose(rot.quat_to_rotvec(q), phi, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rot.quat_to_rotvec(-q), phi, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rot.rotmat_to_rotvec(rot.rotvec_to_rotmat(phi)), phi, rtol=0, atol=1e-13)


@FAST
@given(unit_vectors(), st.floats(1e-9, 1e-5))
def test_rotvec_small_angles(axis, angle):
    """Series branches near 0: accuracy relative to the (tiny) angle."""
    phi = angle * axis
    q = rot.rotvec_to_quat(phi)
    # Reference without cancellation: sin(a/2)/a is accurate for a > 0.
    np.testing.assert_allclose(q[1:], np.sin(angle / 2) / angle * phi, rtol=0, atol=1e-15 * angle)
    assert abs(q[0] - np.cos(angle / 2)) <= 1e-16
    np.testing.assert_allclose(q, AngleAxis(angle, axis).quaternion().wxyz(), rtol=0, atol=1e-16)
    # quat -> rotvec keeps the relative accuracy of the tiny vector.
    np.testing.assert_allclose(rot.quat_to_rotvec(q), phi, rtol=0, atol=1e-14 * angle)
    # Rotation matrix: R = I + (sin a / a) K + (2 sin^2(a/2) / a^2) K^2 (no cancellation).
    K = rot.skew(phi)
    R_ref = np.eye(3) + np.sin(angle) / angle * K + 2 * np.sin(angle / 2) ** 2 / angle**2 * K @ K
    R = rot.rotvec_to_rotmat(phi)
    np.testing.assert_allclose(R - np.eye(3), R_ref - np.eye(3), rtol=0, atol=1e-16)
    np.testing.assert_allclose(R, RotationMatrix(AngleAxis(angle, axis)).matrix(), atol=1e-16)
    # rotmat -> rotvec: R has only ~1e-16 absolute resolution, so the absolute error is
    # ~1e-16 (i.e. relative ~1e-16 / angle).
    np.testing.assert_allclose(rot.rotmat_to_rotvec(R), phi, rtol=0, atol=1e-15)


def _expm_minus_identity(phi):
    """exp([phi x]) - I by Rodrigues without cancellation: (sin a / a) K + (2 sin^2(a/2) / a^2) K^2.

    Never forms I + (small), so it is accurate to a few ulps of its own (small) entries.
    """
    a = np.linalg.norm(phi)
    K = rot.skew(phi)
    return np.sin(a) / a * K + 2 * np.sin(a / 2) ** 2 / a**2 * K @ K


# Angles straddling the series switch (1e-4 rad) and deep inside the series branch.
THRESHOLD_ANGLES = [
    1e-8,
    0.5 * rot._SMALL_ANGLE,
    rot._SMALL_ANGLE * (1 - 1e-12),
    rot._SMALL_ANGLE,
    rot._SMALL_ANGLE * (1 + 1e-12),
    2 * rot._SMALL_ANGLE,
]


@pytest.mark.parametrize("batched", [False, True], ids=["scalar", "batched"])
def test_rotvec_series_threshold_is_continuous(batched):
    """Both sides of the series switch (1e-4 rad) agree with the exact maps to rounding.

    The series 1 - a^2/6, 1/2 - a^2/24, 1/2 - a^2/48 are truncated at O(a^4) ~ 1e-16 relative
    at the switch, so the only error left is rounding: the vector part of q is good to a few
    ulps of |phi| (<= 1e-15 a), and R - I to the rounding of the ~1 diagonal (ulp(1)/2 =
    5.6e-17 < 1e-16; the off-diagonals are ~a, their ulps ~1e-20).  rtol=0 everywhere: the
    default rtol=1e-7 would hide an error in the a^2 coefficient (~a^3 ~ 1e-13 in R).
    Scalar (1-D fast path) and batched forms are separate code: both are checked.
    """
    axis = np.array([0.6, -0.48, 0.64])
    phis = np.array([a * axis for a in THRESHOLD_ANGLES])
    if batched:
        qs, Rs = rot.rotvec_to_quat(phis), rot.rotvec_to_rotmat(phis)
    else:
        qs = np.stack([rot.rotvec_to_quat(phi) for phi in phis])
        Rs = np.stack([rot.rotvec_to_rotmat(phi) for phi in phis])
    for a, phi, q, R in zip(THRESHOLD_ANGLES, phis, qs, Rs, strict=True):
        np.testing.assert_allclose(q[1:], np.sin(a / 2) / a * phi, rtol=0, atol=1e-15 * a)
        assert abs(q[0] - np.cos(a / 2)) <= 1.2e-16  # one ulp of a number just below 1
        np.testing.assert_allclose(R - np.eye(3), _expm_minus_identity(phi), rtol=0, atol=1e-16)
        np.testing.assert_allclose(
            R, RotationMatrix(AngleAxis(a, axis)).matrix(), rtol=0, atol=2.3e-16
        )  # Drake's own rounding adds ~1 ulp


def test_batched_zero_rotation_is_exact_identity_without_fp_errors():
    """Identity particles (zero increments) in a batch: exact identity, no 0/0 anywhere.

    The batched exp maps divide by the angle on their non-series branch; a guarded divisor
    must keep 0/0 from being evaluated, so even under np.errstate(all="raise") (users who
    turn floating-point warnings into errors) a zero rotation vector maps to the identity.
    """
    phis = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [0.0, 0.0, 0.0]])
    with np.errstate(all="raise"):
        qs = rot.rotvec_to_quat(phis)
        Rs = rot.rotvec_to_rotmat(phis)
        back = rot.quat_to_rotvec(qs)
    for i in (0, 2):
        np.testing.assert_array_equal(qs[i], [1.0, 0.0, 0.0, 0.0])
        np.testing.assert_array_equal(Rs[i], np.eye(3))
        np.testing.assert_array_equal(back[i], np.zeros(3))
    # The non-zero member is unaffected by its zero neighbours (closed form, ~eps accuracy).
    np.testing.assert_allclose(Rs[1] - np.eye(3), _expm_minus_identity(phis[1]), rtol=0, atol=1e-15)
    a = np.linalg.norm(phis[1])
    q_ref = np.concatenate([[np.cos(a / 2)], np.sin(a / 2) / a * phis[1]])
    np.testing.assert_allclose(qs[1], q_ref, rtol=0, atol=1e-16)


def test_rotvec_zero():
    np.testing.assert_array_equal(rot.rotvec_to_quat(np.zeros(3)), [1, 0, 0, 0])
    np.testing.assert_array_equal(rot.quat_to_rotvec([1.0, 0, 0, 0]), np.zeros(3))
    np.testing.assert_array_equal(rot.quat_to_rotvec([-1.0, 0, 0, 0]), np.zeros(3))
    np.testing.assert_array_equal(rot.rotvec_to_rotmat(np.zeros(3)), np.eye(3))
    np.testing.assert_array_equal(rot.rotmat_to_rotvec(np.eye(3)), np.zeros(3))


@FAST
@given(unit_vectors(), st.floats(PI - 1e-7, PI))
def test_rotvec_near_pi(axis, angle):
    """Near pi compare rotations: the returned vector may be the antipodal one."""
    phi = angle * axis
    q = rot.rotvec_to_quat(phi)
    R_drake = RotationMatrix(AngleAxis(angle, axis)).matrix()
    for qq in (q, -q):
        phi2 = rot.quat_to_rotvec(qq)
        a2 = np.linalg.norm(phi2)
        assert 0.0 <= a2 <= PI * (1 + 1e-15)  # [0, pi] up to rounding of |k v|
        assert abs(a2 - angle) < 1e-14
        np.testing.assert_allclose(rot.rotvec_to_rotmat(phi2), R_drake, rtol=0, atol=1e-14)
        assert quat_dist(rot.rotvec_to_quat(phi2), q) < 1e-14
    phi3 = rot.rotmat_to_rotvec(R_drake)
    assert abs(np.linalg.norm(phi3) - angle) < 1e-7  # R only resolves the angle to ~sqrt(eps)
    np.testing.assert_allclose(rot.rotvec_to_rotmat(phi3), R_drake, rtol=0, atol=1e-14)


@FAST
@given(unit_quats())
def test_quat_to_rotvec_matches_drake_angle_axis(q):
    phi = rot.quat_to_rotvec(q)
    angle = np.linalg.norm(phi)
    assert 0.0 <= angle <= PI * (1 + 1e-15)  # [0, pi] up to rounding of |k v|
    aa = RotationMatrix(drake_quat(q)).ToAngleAxis()
    assert abs(angle - aa.angle()) < 1e-7  # Drake's angle comes from R (sqrt(eps) near 0/pi)
    np.testing.assert_allclose(rot.rotvec_to_rotmat(phi), drake_R(q), rtol=0, atol=1e-14)
    # The vector itself: direct quaternion -> angle-axis in Drake (Eigen) is accurate.
    if not 1e-100 < angle < PI - 1e-6:
        return  # Drake rejects (sub)normal-tiny axes; near pi see test_rotvec_near_pi
    aq = AngleAxis(drake_quat(rot.quat_canonical(q)))
    np.testing.assert_allclose(phi, aq.angle() * aq.axis(), rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------
# Propagation and attitude error
# ----------------------------------------------------------------------------------
@MEDIUM
@given(unit_quats(), vectors(1.0), st.floats(0.0, 2.0), st.floats(0.0, 2.0))
def test_quat_propagate(q, w, dt1, dt2):
    q1 = rot.quat_propagate(q, w, dt1)
    np.testing.assert_allclose(q1, rot.quat_multiply(q, rot.rotvec_to_quat(w * dt1)), atol=0)
    # Body-frame rate: R(t + dt) = R(t) exp([w dt x]).
    wn = np.linalg.norm(w)
    axis = w / wn if wn > 1e-100 else np.array([1.0, 0.0, 0.0])
    R_step = RotationMatrix(AngleAxis(wn * dt1, axis / np.linalg.norm(axis))).matrix()
    np.testing.assert_allclose(rot.quat_to_rotmat(q1), drake_R(q) @ R_step, atol=1e-14)
    # Exact for constant rate: semigroup property.
    np.testing.assert_allclose(rot.quat_propagate(q1, w, dt2), rot.quat_propagate(q, w, dt1 + dt2), atol=1e-14)


@MEDIUM
@given(unit_quats(), vectors(1.0))
def test_quat_propagate_derivative_is_kinematics(q, w):
    """d/dt q = 0.5 q ⊗ [0, w] (central difference)."""
    h = 1e-5
    qdot = (rot.quat_propagate(q, w, h) - rot.quat_propagate(q, w, -h)) / (2 * h)
    expected = 0.5 * rot.quat_multiply(q, np.concatenate([[0.0], w]))
    np.testing.assert_allclose(qdot, expected, rtol=0, atol=1e-10)


@FAST
@given(unit_quats(), rotvecs(0.0, PI - 1e-3))
def test_quat_error_rotvec(q_hat, dtheta):
    q = rot.quat_multiply(q_hat, rot.rotvec_to_quat(dtheta))
    np.testing.assert_allclose(rot.quat_error_rotvec(q_hat, q), dtheta, rtol=0, atol=1e-13)
    # Sign-invariant in both arguments.
    np.testing.assert_allclose(rot.quat_error_rotvec(-q_hat, q), dtheta, rtol=0, atol=1e-13)
    np.testing.assert_allclose(rot.quat_error_rotvec(q_hat, -q), dtheta, rtol=0, atol=1e-13)
    np.testing.assert_allclose(rot.quat_error_rotvec(q, q), 0.0, rtol=0, atol=1e-15)
    # Body-frame error: R(q) = R(q_hat) exp([dtheta x]).
    R_err = drake_R(q_hat).T @ drake_R(q)
    np.testing.assert_allclose(rot.rotvec_to_rotmat(dtheta), R_err, atol=1e-14)


# ----------------------------------------------------------------------------------
# MRPs
# ----------------------------------------------------------------------------------
@FAST
@given(unit_quats())
def test_quat_mrp_round_trip(q):
    p = rot.quat_to_mrp(q)
    assert np.linalg.norm(p) <= 1.0 + 1e-15
    # p = tan(theta / 4) n with the shortest rotation (theta in [0, pi]).
    phi = rot.quat_to_rotvec(q)
    theta = np.linalg.norm(phi)
    if theta > 0:
        np.testing.assert_allclose(p, np.tan(theta / 4) * phi / theta, rtol=0, atol=1e-15)
    np.testing.assert_allclose(rot.mrp_to_quat(p), rot.quat_canonical(q), rtol=0, atol=1e-15)
    np.testing.assert_allclose(rot.mrp_to_rotmat(p), drake_R(q), rtol=0, atol=1e-14)


@FAST
@given(vectors(10.0))
def test_mrp_to_quat_and_rotmat(p):
    q = rot.mrp_to_quat(p)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-15
    R = rot.mrp_to_rotmat(p)
    # Absolute accuracy of R degrades like eps |p|^2 for large |p| (shadow region).
    tol = 1e-14 * (1.0 + np.dot(p, p))
    np.testing.assert_allclose(R, rot.quat_to_rotmat(q), rtol=0, atol=tol)
    np.testing.assert_allclose(R, drake_R(q), rtol=0, atol=tol)
    assert_rotation_matrix(R, tol)


@FAST
@given(vectors(10.0))
def test_mrp_shadow(p):
    n2 = np.dot(p, p)
    assume(n2 > 1e-6)
    ps = rot.mrp_shadow(p)
    assert abs(np.linalg.norm(ps) * np.sqrt(n2) - 1.0) < 1e-14
    # Same rotation: the shadow set gives exactly -q.
    np.testing.assert_allclose(rot.mrp_to_quat(ps), -rot.mrp_to_quat(p), rtol=0, atol=1e-14)
    np.testing.assert_allclose(rot.mrp_to_rotmat(ps), rot.mrp_to_rotmat(p), rtol=0, atol=1e-13 * (1 + n2 + 1 / n2))
    np.testing.assert_allclose(rot.mrp_shadow(ps), p, rtol=1e-14, atol=1e-300)


@MEDIUM
@given(vectors(10.0))
def test_mrp_switch(p):
    n2 = np.dot(p, p)
    sw = rot.mrp_switch(p)
    assert np.linalg.norm(sw) <= 1.0 + 1e-15
    assert quat_dist(rot.mrp_to_quat(sw), rot.mrp_to_quat(p)) < 1e-14
    if n2 <= 1.0:
        np.testing.assert_array_equal(sw, p)
    else:
        np.testing.assert_allclose(sw, rot.mrp_shadow(p), rtol=1e-15, atol=0)
        # Switching selects the canonical (q_w >= 0) set, i.e. the shortest rotation.
        np.testing.assert_allclose(sw, rot.quat_to_mrp(rot.mrp_to_quat(p)), rtol=0, atol=1e-14)


def test_mrp_switch_boundary_and_batch():
    p = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [3.0, 0.0, 4.0]])
    sw = rot.mrp_switch(p)
    np.testing.assert_array_equal(sw[0], 0.0)
    np.testing.assert_array_equal(sw[1], p[1])  # |p| == 1 is not switched
    np.testing.assert_allclose(sw[2], [0.0, -0.5, 0.0], rtol=1e-15)
    np.testing.assert_allclose(sw[3], -p[3] / 25.0, rtol=1e-15)


def _mrp_along(q0, w, t, shadow=False):
    """MRP of q0 ⊗ exp(w t / 2), staying on one branch (no canonicalization)."""
    q = rot.quat_propagate(q0, w, t)
    if shadow:
        return -q[1:] / (1.0 - q[0])
    return q[1:] / (1.0 + q[0])


@FAST
@given(unit_quats(), vectors(1.0), st.booleans())
def test_mrp_kinematics_matrix_finite_difference(q, w, shadow):
    """p_dot = B(p) w_IB_B for both the regular and the shadow set."""
    q = rot.quat_canonical(q)
    if shadow:
        assume(1.0 - q[0] > 0.1)  # shadow MRP finite and moderate
    h = 1e-5
    p = _mrp_along(q, w, 0.0, shadow)
    pdot = (_mrp_along(q, w, h, shadow) - _mrp_along(q, w, -h, shadow)) / (2 * h)
    B = rot.mrp_kinematics_matrix(p)
    n2 = np.dot(p, p)
    np.testing.assert_allclose(B @ w, pdot, rtol=0, atol=1e-9 * (1 + n2) ** 2)
    if not shadow:
        np.testing.assert_allclose(p, rot.quat_to_mrp(q), rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------
# GRPs
# ----------------------------------------------------------------------------------
GRP_PARAMS = [(1.0, 4.0), (0.0, 1.0), (1.0, 1.0), (0.5, 2.0), (2.0, 1.0)]


@pytest.mark.parametrize("a,f", GRP_PARAMS)
@FEWER
@given(q=unit_quats())
def test_grp_round_trip(a, f, q):
    if a == 0.0:
        assume(abs(q[0]) > 1e-3)  # Gibbs vector is infinite at 180 deg
    p = rot.quat_to_grp(q, a, f)
    qc = rot.quat_canonical(q)
    np.testing.assert_allclose(p, f * qc[1:] / (a + qc[0]), rtol=1e-15, atol=0)
    q2 = rot.grp_to_quat(p, a, f)
    assert q2[0] >= -1e-15  # q_w >= 0 branch, up to rounding at exactly 180 deg
    assert abs(np.linalg.norm(q2) - 1.0) < 1e-14
    np.testing.assert_allclose(q2, qc, rtol=0, atol=1e-14)
    # Exactly at 180 deg, grp_to_quat may return q_w = -1e-16, which quat_to_grp
    # canonicalizes to the antipodal GRP: same rotation, so compare sign-invariantly.
    assert quat_dist(rot.grp_to_quat(rot.quat_to_grp(q2, a, f), a, f), q2) < 1e-14


@MEDIUM
@given(unit_quats())
def test_grp_special_cases(q):
    qc = rot.quat_canonical(q)
    # a = 1, f = 1: MRPs.
    np.testing.assert_allclose(rot.quat_to_grp(q, 1.0, 1.0), rot.quat_to_mrp(q), rtol=1e-15, atol=0)
    # a = 1, f = 4: |p| = 4 tan(theta / 4) ~ theta (+ theta^3 / 48).
    theta = np.linalg.norm(rot.quat_to_rotvec(q))
    p4 = rot.quat_to_grp(q, 1.0, 4.0)
    assert abs(np.linalg.norm(p4) - 4 * np.tan(theta / 4)) < 1e-14
    assert np.linalg.norm(p4) >= theta - 1e-14
    if theta < 0.1:
        assert abs(np.linalg.norm(p4) - theta) <= theta**3 / 48 * 1.01 + 1e-15
    # a = 0, f = 1: Gibbs vector q_vec / q_w = tan(theta / 2) n.
    if qc[0] > 1e-3:
        np.testing.assert_allclose(rot.quat_to_grp(q, 0.0, 1.0), qc[1:] / qc[0], rtol=1e-15, atol=0)
        g = rot.quat_to_grp(q, 0.0, 1.0)
        np.testing.assert_allclose(rot.grp_to_quat(g, 0.0, 1.0), qc, rtol=0, atol=1e-14)


@pytest.mark.parametrize("a,f", GRP_PARAMS)
def test_grp_identity_and_default(a, f):
    np.testing.assert_array_equal(rot.quat_to_grp([1.0, 0, 0, 0], a, f), np.zeros(3))
    np.testing.assert_array_equal(rot.grp_to_quat(np.zeros(3), a, f), [1, 0, 0, 0])
    q = rot.rotvec_to_quat([0.1, -0.2, 0.3])
    np.testing.assert_array_equal(rot.quat_to_grp(q), rot.quat_to_grp(q, 1.0, 4.0))


def test_grp_defaults_are_a1_f4():
    """The documented default GRP (a = 1, f = 4: |p| ~ rotation angle) in both directions.

    quat_to_grp and grp_to_quat must share the default so that the default round trip is
    the identity map; |p| = 4 tan(theta / 4) = theta + theta^3 / 48 + ... for the default.
    """
    q = rot.rotvec_to_quat([0.1, -0.2, 0.3])
    theta = np.linalg.norm([0.1, -0.2, 0.3])
    p = rot.quat_to_grp(q)
    np.testing.assert_array_equal(p, rot.quat_to_grp(q, 1.0, 4.0))
    assert abs(np.linalg.norm(p) - 4 * np.tan(theta / 4)) < 1e-15
    np.testing.assert_array_equal(rot.grp_to_quat(p), rot.grp_to_quat(p, 1.0, 4.0))
    np.testing.assert_allclose(rot.grp_to_quat(p), q, rtol=0, atol=1e-15)  # round-trip ulps


# ----------------------------------------------------------------------------------
# Roll-pitch-yaw
# ----------------------------------------------------------------------------------
@FAST
@given(rpy_any)
def test_rpy_to_quat_matches_drake(rpy):
    q = rot.rpy_to_quat(rpy)
    r = RollPitchYaw(rpy)
    np.testing.assert_allclose(q, r.ToQuaternion().wxyz(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_rotmat(q), r.ToRotationMatrix().matrix(), atol=1e-14)
    # R = Rz(yaw) Ry(pitch) Rx(roll).
    R = (
        RotationMatrix.MakeZRotation(rpy[2]).matrix()
        @ RotationMatrix.MakeYRotation(rpy[1]).matrix()
        @ RotationMatrix.MakeXRotation(rpy[0]).matrix()
    )
    np.testing.assert_allclose(rot.quat_to_rotmat(q), R, atol=1e-14)


@FAST
@given(rpy_regular)
def test_quat_to_rpy_round_trip_and_drake(rpy):
    q = rot.rpy_to_quat(rpy)
    rpy2 = rot.quat_to_rpy(q)
    assert abs(rpy2[1]) <= PI / 2
    np.testing.assert_allclose(wrap(rpy2 - rpy), 0.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(wrap(rot.quat_to_rpy(-q) - rpy2), 0.0, rtol=0, atol=1e-12)
    rpy_drake = RollPitchYaw(RotationMatrix(drake_quat(q))).vector()
    np.testing.assert_allclose(wrap(rpy2 - rpy_drake), 0.0, rtol=0, atol=1e-9)


@MEDIUM
@given(unit_quats())
def test_quat_to_rpy_reconstructs_rotation(q):
    rpy = rot.quat_to_rpy(q)
    R = drake_R(q)
    assume(abs(R[2, 0]) < 1 - 1e-6)  # away from gimbal lock
    np.testing.assert_allclose(RollPitchYaw(rpy).ToRotationMatrix().matrix(), R, atol=1e-10)


@pytest.mark.parametrize("pitch", [PI / 2, -PI / 2])
@pytest.mark.parametrize("offset", [0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1e-3])
def test_quat_to_rpy_at_and_near_gimbal_lock(pitch, offset):
    """At pitch = +-90 deg (and within 1e-15 .. 1e-3 rad of it) the angles still reproduce the
    rotation to 1e-11 rad (the old asin/atan2 form was 5.7 deg off at rpy (0.3, pi/2, 0.2)),
    pitch is within 2e-8 rad of the truth, and they agree with Drake's RollPitchYaw on the
    rotation (compared as rotations: at the lock only yaw -+ roll is defined)."""
    rng = np.random.default_rng(int(offset * 1e15) % 1000 + (pitch > 0))
    cases = [np.array([0.3, pitch, 0.2])] + [
        np.array([rng.uniform(-PI, PI), pitch, rng.uniform(-PI, PI)]) for _ in range(50)
    ]
    for rpy in cases:
        rpy[1] -= np.sign(pitch) * offset
        q = rot.rpy_to_quat(rpy)
        back = rot.quat_to_rpy(q)
        assert abs(back[1] - rpy[1]) < 2e-8, (rpy, back)
        err = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q), rot.rpy_to_quat(back)))
        assert np.linalg.norm(err) < 1e-11, (rpy, back, err)
        R_drake = RollPitchYaw(RotationMatrix(drake_quat(q))).ToRotationMatrix().matrix()
        np.testing.assert_allclose(RollPitchYaw(back).ToRotationMatrix().matrix(), R_drake, atol=1e-11)


@FAST
@given(rpy_any, vectors(2.0))
def test_rpy_rates_to_body_rate(rpy, rpy_dot):
    w = rot.rpy_rates_to_body_rate(rpy, rpy_dot)
    np.testing.assert_allclose(w, RollPitchYaw(rpy).CalcAngularVelocityInChildFromRpyDt(rpy_dot), rtol=0, atol=1e-14)
    # Finite difference of the rotation: w_B = vee(R^T R_dot).
    h = 1e-6
    Rp = rot.quat_to_rotmat(rot.rpy_to_quat(rpy + h * rpy_dot))
    Rm = rot.quat_to_rotmat(rot.rpy_to_quat(rpy - h * rpy_dot))
    R = rot.quat_to_rotmat(rot.rpy_to_quat(rpy))
    Rdot = (Rp - Rm) / (2 * h)
    np.testing.assert_allclose(w, vee(R.T @ Rdot), rtol=0, atol=1e-8)
    # Drake's analytic R_dot as a second reference.
    Rdot_drake = RollPitchYaw(rpy).CalcRotationMatrixDt(rpy_dot)
    np.testing.assert_allclose(w, vee(R.T @ Rdot_drake), rtol=0, atol=1e-13)


# ----------------------------------------------------------------------------------
# Batched forms == loop over scalar forms
# ----------------------------------------------------------------------------------
def _rand_quats(rng, shape):
    q = rng.normal(size=shape + (4,))
    # Include exact half turns (w = 0) and identities to hit every branch.
    flat = q.reshape(-1, 4)
    if flat.shape[0] >= 3:
        flat[0] = [0.0, 0.0, 1.0, 0.0]
        flat[1] = [1.0, 0.0, 0.0, 0.0]
        flat[2, 0] = 0.0
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _rand_vecs(rng, shape, scale=1.0):
    return scale * rng.normal(size=shape + (3,))


def _rand_rpy(rng, shape):
    return rng.uniform([-PI, -PI / 2 + 0.1, -PI], [PI, PI / 2 - 0.1, PI], size=shape + (3,))


BATCH_CASES = {
    "skew": (rot.skew, lambda r, s: (_rand_vecs(r, s),)),
    "quat_normalize": (rot.quat_normalize, lambda r, s: (3 * _rand_quats(r, s),)),
    "quat_canonical": (rot.quat_canonical, lambda r, s: (_rand_quats(r, s),)),
    "quat_conjugate": (rot.quat_conjugate, lambda r, s: (_rand_quats(r, s),)),
    "quat_multiply": (rot.quat_multiply, lambda r, s: (_rand_quats(r, s), _rand_quats(r, s))),
    "quat_to_rotmat": (rot.quat_to_rotmat, lambda r, s: (_rand_quats(r, s),)),
    "rotmat_to_quat": (rot.rotmat_to_quat, lambda r, s: (rot.quat_to_rotmat(_rand_quats(r, s)),)),
    "quat_rotate": (rot.quat_rotate, lambda r, s: (_rand_quats(r, s), _rand_vecs(r, s))),
    "rotvec_to_quat": (rot.rotvec_to_quat, lambda r, s: (_rand_vecs(r, s, 2.0),)),
    "rotvec_to_quat_small": (rot.rotvec_to_quat, lambda r, s: (_rand_vecs(r, s, 1e-6),)),
    "quat_to_rotvec": (rot.quat_to_rotvec, lambda r, s: (_rand_quats(r, s),)),
    "rotvec_to_rotmat": (rot.rotvec_to_rotmat, lambda r, s: (_rand_vecs(r, s, 2.0),)),
    "rotvec_to_rotmat_small": (rot.rotvec_to_rotmat, lambda r, s: (_rand_vecs(r, s, 1e-6),)),
    "rotmat_to_rotvec": (rot.rotmat_to_rotvec, lambda r, s: (rot.quat_to_rotmat(_rand_quats(r, s)),)),
    "quat_propagate": (lambda q, w: rot.quat_propagate(q, w, 0.3), lambda r, s: (_rand_quats(r, s), _rand_vecs(r, s))),
    "quat_error_rotvec": (rot.quat_error_rotvec, lambda r, s: (_rand_quats(r, s), _rand_quats(r, s))),
    "quat_to_mrp": (rot.quat_to_mrp, lambda r, s: (_rand_quats(r, s),)),
    "mrp_to_quat": (rot.mrp_to_quat, lambda r, s: (_rand_vecs(r, s, 2.0),)),
    "mrp_shadow": (rot.mrp_shadow, lambda r, s: (_rand_vecs(r, s, 2.0),)),
    "mrp_switch": (rot.mrp_switch, lambda r, s: (_rand_vecs(r, s, 2.0),)),
    "mrp_to_rotmat": (rot.mrp_to_rotmat, lambda r, s: (_rand_vecs(r, s, 2.0),)),
    "mrp_kinematics_matrix": (rot.mrp_kinematics_matrix, lambda r, s: (_rand_vecs(r, s),)),
    "quat_to_grp": (lambda q: rot.quat_to_grp(q, 1.0, 4.0), lambda r, s: (_rand_quats(r, s),)),
    "quat_to_grp_gibbs": (
        lambda q: rot.quat_to_grp(q, 0.0, 1.0),
        lambda r, s: (_rand_quats(r, s) + [3.0, 0, 0, 0],),
    ),  # w > 0
    "grp_to_quat": (lambda p: rot.grp_to_quat(p, 1.0, 4.0), lambda r, s: (_rand_vecs(r, s),)),
    "grp_to_quat_gibbs": (lambda p: rot.grp_to_quat(p, 0.0, 1.0), lambda r, s: (_rand_vecs(r, s, 3.0),)),
    "rpy_to_quat": (rot.rpy_to_quat, lambda r, s: (_rand_rpy(r, s),)),
    "quat_to_rpy": (rot.quat_to_rpy, lambda r, s: (rot.rpy_to_quat(_rand_rpy(r, s)),)),
    "rpy_rates_to_body_rate": (rot.rpy_rates_to_body_rate, lambda r, s: (_rand_rpy(r, s), _rand_vecs(r, s))),
}


@pytest.mark.parametrize("name", sorted(BATCH_CASES))
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), shape=st.sampled_from([(1,), (7,), (2, 3)]))
def test_batched_equals_loop(name, seed, shape):
    fn, make = BATCH_CASES[name]
    args = make(np.random.default_rng(seed), shape)
    out = fn(*args)
    n = int(np.prod(shape))
    flat_args = [a.reshape((n,) + a.shape[len(shape) :]) for a in args]
    loop = np.stack([fn(*(a[i] for a in flat_args)) for i in range(n)])
    assert out.shape == shape + loop.shape[1:]
    # numpy's SIMD ufunc loops (sin, arctan2, ...) on arrays may differ from the 0-d path by
    # an ulp; quat_to_rpy near gimbal lock (|pitch| <= pi/2 - 0.1) amplifies that ~10x.
    np.testing.assert_allclose(out.reshape(loop.shape), loop, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("name", sorted(BATCH_CASES))
def test_batched_empty(name):
    fn, make = BATCH_CASES[name]
    args = make(np.random.default_rng(0), (0,))
    out = fn(*args)
    assert out.shape[0] == 0


def test_single_precision_input_is_computed_in_double():
    """float32 data (a logged or float32 particle cloud) is converted, not computed in float32.

    float32 values are exactly representable in double, so the result must be the double
    result of the same numbers: bit-identical to passing the float64 copy, unit quaternions
    unit to a few ulps (|q| - 1 <= 4 eps = 8.9e-16) and rotation matrices orthonormal to
    1e-14 (3-term dot products of O(1) entries, ~45 eps).  Arithmetic in float32 would be
    off by ~eps32 = 1.2e-7 in both.
    """
    rng = np.random.default_rng(7)
    phi = rng.normal(size=(200, 3)).astype(np.float32)
    q4 = rng.normal(size=(200, 4)).astype(np.float32)
    eps = np.finfo(float).eps
    for fn, x in (
        (rot.rotvec_to_quat, phi),
        (rot.quat_normalize, q4),
        (rot.rotmat_to_quat, rot.quat_to_rotmat(q4).astype(np.float32)),
    ):
        q = fn(x)
        assert q.dtype == np.float64
        np.testing.assert_array_equal(q, fn(x.astype(np.float64)))
        assert np.max(np.abs(np.linalg.norm(q, axis=-1) - 1.0)) <= 4 * eps
    for fn, x in ((rot.rotvec_to_rotmat, phi), (rot.quat_to_rotmat, q4), (rot.mrp_to_rotmat, 0.3 * phi)):
        R = fn(x)
        assert R.dtype == np.float64
        np.testing.assert_array_equal(R, fn(x.astype(np.float64)))
        np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), rtol=0, atol=1e-14)


def test_broadcasting_single_against_batch():
    rng = np.random.default_rng(1)
    qs = _rand_quats(rng, (5,))
    q = _rand_quats(rng, ())
    v = _rand_vecs(rng, ())
    vs = _rand_vecs(rng, (5,))
    np.testing.assert_allclose(rot.quat_multiply(q, qs), np.stack([rot.quat_multiply(q, x) for x in qs]), atol=1e-16)
    np.testing.assert_allclose(rot.quat_multiply(qs, q), np.stack([rot.quat_multiply(x, q) for x in qs]), atol=1e-16)
    np.testing.assert_allclose(rot.quat_rotate(qs, v), np.stack([rot.quat_rotate(x, v) for x in qs]), atol=1e-15)
    np.testing.assert_allclose(rot.quat_rotate(q, vs), np.stack([rot.quat_rotate(q, x) for x in vs]), atol=1e-15)
    np.testing.assert_allclose(
        rot.quat_propagate(qs, v, 0.5), np.stack([rot.quat_propagate(x, v, 0.5) for x in qs]), atol=1e-16
    )
