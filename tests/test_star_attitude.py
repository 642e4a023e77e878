"""A frame's attitude from identified stars (drake_att.star_attitude): the SVD solution against
Davenport's q-method written here (numpy's eigh), the estimate and its covariance against the
empirical scatter over noisy frames (NEES in its chi-square band), the Fisher information against
QUEST's isotropic covariance near the boresight, and the boresight/cross-boresight ratio against
the small-field closed form."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from drake_att import rotations as rot
from drake_att.star_attitude import fisher_information, solve_star_attitude, wahba_svd
from drake_att.star_camera import PinholeCamera

CAMERA = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024)
DISTORTED = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024, k1=0.08, k2=-0.02)


def random_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def davenport(b, r, w):
    """Davenport's q-method: the eigenvector of K with the largest eigenvalue maximizes
    sum w b^T A r, A = R_SI; K from B = sum w b r^T (Markley & Crassidis 2014, eq. 5.15)."""
    B = (w[:, None] * b).T @ r
    S = B + B.T
    z = np.array([B[1, 2] - B[2, 1], B[2, 0] - B[0, 2], B[0, 1] - B[1, 0]])
    K = np.zeros((4, 4))
    K[0, 0] = np.trace(B)
    K[0, 1:] = K[1:, 0] = z
    K[1:, 1:] = S - np.trace(B) * np.eye(3)
    _, V = np.linalg.eigh(K)
    q = V[:, -1]  # [w, v] of the attitude matrix A = R_SI in the left-handed (JPL-like) sense
    qw, qv = q[0], q[1:]
    A = (
        (qw**2 - qv @ qv) * np.eye(3)
        + 2 * np.outer(qv, qv)
        - 2 * qw * np.array([[0, -qv[2], qv[1]], [qv[2], 0, -qv[0]], [-qv[1], qv[0], 0]])
    )
    return A  # R_SI


def angle(q_a, q_b):
    return np.linalg.norm(rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q_a), q_b)))


def frame(rng, camera, n, half_width_px=None):
    """n stars uniform on the detector (or within half_width_px of its centre) and a random
    attitude: true pixels, their directions in S and in I."""
    c = camera.principal_point_px
    h = half_width_px or 0.5 * camera.width_px - 1
    uv = c + rng.uniform(-h, h, size=(n, 2))
    q = random_quaternion(rng)
    d_S = camera.unproject(uv)
    return q, uv, d_S, rot.quat_rotate(q, d_S)


def test_svd_agrees_with_davenport_q_method():
    rng = np.random.default_rng(1)
    for _ in range(20):
        n = int(rng.integers(2, 12))
        q = random_quaternion(rng)
        b = rng.normal(size=(n, 3))
        b /= np.linalg.norm(b, axis=1)[:, None]
        b_noisy = b + 0.01 * rng.normal(size=b.shape)
        b_noisy /= np.linalg.norm(b_noisy, axis=1)[:, None]
        r = rot.quat_rotate(q, b)
        w = rng.uniform(0.1, 2.0, n)
        R_SI = davenport(b_noisy, r, w)
        q_svd = wahba_svd(b_noisy, r, w)
        assert np.allclose(rot.quat_to_rotmat(q_svd).T, R_SI, atol=1e-9)
        assert angle(wahba_svd(b, r, w), q) < 1e-10  # noise-free: exact


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED])
def test_noise_free_solution_is_exact_and_chi_square_zero(camera):
    rng = np.random.default_rng(2)
    q, uv, _, r_I = frame(rng, camera, 8)
    a = solve_star_attitude(camera, uv, r_I, 0.2)
    assert angle(a.q_IS, q) < 1e-11
    assert a.chi_square < 1e-12 and a.num_stars == 8 and a.degrees_of_freedom == 13


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED])
def test_covariance_matches_the_scatter_over_noisy_frames(camera):
    """1500 frames of 12 stars with correlated, unequal pixel noise: mean NEES in the
    chi-square(3N)/N 99.9% band, per-axis RMS / predicted sigma within 8%, mean chi-square in
    its band (2n - 3 dof)."""
    rng = np.random.default_rng(3)
    q, uv, _, r_I = frame(rng, camera, 12)
    s = rng.uniform(0.1, 0.5, size=(12, 2))
    rho = rng.uniform(-0.6, 0.6, 12)
    C = np.empty((12, 2, 2))
    C[:, 0, 0], C[:, 1, 1] = s[:, 0] ** 2, s[:, 1] ** 2
    C[:, 0, 1] = C[:, 1, 0] = rho * s[:, 0] * s[:, 1]
    L = np.linalg.cholesky(C)
    N = 1500
    errors, nees, chis = np.empty((N, 3)), np.empty(N), np.empty(N)
    P = None
    for k in range(N):
        z = uv + np.einsum("nij,nj->ni", L, rng.normal(size=(12, 2)))
        a = solve_star_attitude(camera, z, r_I, C)
        e = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(a.q_IS), q))
        errors[k], nees[k], chis[k] = e, e @ np.linalg.solve(a.covariance_S, e), a.chi_square
        P = a.covariance_S
    lo, hi = chi2.ppf([0.0005, 0.9995], 3 * N) / N
    assert lo < nees.mean() < hi
    ratio = np.sqrt(np.mean(errors**2, axis=0) / np.diag(P))
    assert np.all(np.abs(ratio - 1) < 0.08), ratio
    lo, hi = chi2.ppf([0.0005, 0.9995], 21 * N) / N
    assert lo < chis.mean() < hi


def test_solver_covariance_is_the_cameras_fisher_information():
    """The compiled solve's covariance equals F^-1 from the camera's own projection_jacobian
    (fisher_information) on a distorted camera, per-star covariances unequal."""
    rng = np.random.default_rng(7)
    q, uv, d_S, r_I = frame(rng, DISTORTED, 9)
    C = np.einsum("n,ij->nij", rng.uniform(0.01, 0.2, 9), np.eye(2)) + 0.005 * np.array([[0, 1], [1, 0]])
    a = solve_star_attitude(DISTORTED, uv, r_I, C)
    J = DISTORTED.projection_jacobian(d_S)
    F = np.einsum("nai,nab,nbj->ij", J, np.linalg.inv(C), J)
    assert np.allclose(a.covariance_S, np.linalg.inv(F), rtol=1e-8)
    assert np.allclose(fisher_information(DISTORTED, d_S, C), F, rtol=1e-12)


def test_fisher_information_is_quest_near_the_boresight():
    """Stars within 0.3 deg of the boresight of an ideal pinhole with isotropic pixel noise:
    F -> sum (I - b b^T) / sigma^2 with sigma = sigma_px / f_px (to 1e-3)."""
    rng = np.random.default_rng(4)
    f = CAMERA.focal_length_px
    _, uv, d_S, _ = frame(rng, CAMERA, 10, half_width_px=math.radians(0.2) * f)
    sigma_px = 0.3
    quest = sum(np.eye(3) - np.outer(b, b) for b in d_S) / (sigma_px / f) ** 2
    F = fisher_information(CAMERA, d_S, sigma_px)
    assert np.allclose(np.linalg.inv(F), np.linalg.inv(quest), rtol=1e-3)


def test_boresight_to_cross_boresight_ratio_emerges():
    """Small field: roll sigma / cross sigma = f_px / rms(radius_px) of the stars (the lever arms),
    and the roll axis is z_S."""
    rng = np.random.default_rng(5)
    _, uv, d_S, r_I = frame(rng, CAMERA, 30, half_width_px=200)
    a = solve_star_attitude(CAMERA, uv, r_I, 0.2)
    sx, sy, sz = a.sigma_S_rad
    rms_radius = np.sqrt(np.mean(np.sum((uv - CAMERA.principal_point_px) ** 2, axis=1)))
    assert sz / math.sqrt(0.5 * (sx**2 + sy**2)) == pytest.approx(CAMERA.focal_length_px / rms_radius, rel=0.03)
    w, V = np.linalg.eigh(a.covariance_S)
    assert abs(V[2, -1]) > 0.999  # the largest uncertainty is about the boresight


def test_gauss_newton_reaches_the_bound_off_axis_with_distortion():
    """Stars far off-axis on a distorted camera, noisy: the estimate is the weighted least-squares
    optimum (a further step moves it by < 1e-3 of its sigma)."""
    rng = np.random.default_rng(6)
    q, uv, _, r_I = frame(rng, DISTORTED, 10)
    z = uv + 0.5 * rng.normal(size=uv.shape)
    a2 = solve_star_attitude(DISTORTED, z, r_I, 0.5)
    a5 = solve_star_attitude(DISTORTED, z, r_I, 0.5, gauss_newton_steps=5)
    assert angle(a2.q_IS, a5.q_IS) < 1e-3 * np.min(a5.sigma_S_rad)


@pytest.mark.parametrize(
    "args, message",
    [
        ((np.zeros((3, 3)), np.ones((3, 3)), 0.2), "centroids_px"),
        ((np.zeros((1, 2)), np.ones((1, 3)), 0.2), "at least 2 stars"),
        ((np.full((3, 2), np.nan), np.ones((3, 3)), 0.2), "centroids_px"),
        ((np.zeros((3, 2)), np.ones((2, 3)), 0.2), "references_I"),
        ((np.zeros((3, 2)), np.ones((3, 3)), -0.2), "centroid_cov_px2"),
        ((np.zeros((3, 2)), np.ones((3, 3)), -np.ones((3, 2, 2))), "centroid_cov_px2"),
        ((np.zeros((3, 2)), np.ones((3, 3)), np.ones((2, 2, 2))), "centroid_cov_px2"),
        ((np.full((3, 2), 512.0), np.tile([0.0, 0.0, 1.0], (3, 1)), 0.2), "undetermined"),
    ],
)
def test_bad_inputs_are_one_line_errors(args, message):
    with pytest.raises(ValueError, match=message) as e:
        solve_star_attitude(CAMERA, *args)
    assert "\n" not in str(e.value)
