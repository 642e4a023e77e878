"""A star-tracker frame's attitude from identified stars, with its covariance (numpy; the
solve's arithmetic compiled with numba, :func:`drake_att.filters.compiled.jit`).

Inputs: the centroids ``z_i`` (pixels, ``(n, 2)``) of ``n`` identified stars with their pixel
covariances ``C_i`` (``(n, 2, 2)``, or one sigma for all), the stars' catalogue directions
``r_i`` in I, and the camera (:class:`drake_att.star_camera.PinholeCamera`).

* :func:`wahba_svd` — Wahba's problem by the SVD (Markley 1988, "Attitude determination using
  vector observations and the singular value decomposition", J. Astronaut. Sci. 36(3)):
  ``B = sum_i w_i b_i r_i^T = U S V^T`` and ``R_SI = U diag(1, 1, det U det V) V^T`` maximizes
  ``sum_i w_i b_i^T R_SI r_i``.
* :func:`solve_star_attitude` — the SVD solution (unit vectors from the unprojected centroids,
  weights the mean inverse direction variance of each star), then Gauss–Newton steps on the
  pixel residuals ``e_i = z_i - project(R_IS^T r_i)`` weighted by ``C_i^-1``: the weighted least
  squares estimate, efficient also off the boresight and with distortion, where the pixel noise
  is not isotropic on the unit sphere.
* The error is the project's: ``R_IS = R_IS_hat exp([dtheta_S x])`` (true sensor frame relative
  to the estimated one, expressed in S). A rotation ``dtheta_S`` moves star i's pixel by
  ``-J_i dtheta_S`` with ``J_i`` the camera's :meth:`projection_jacobian` (pixels per radian of a
  rotation of the direction), so the frame's Fisher information is
  ``F = sum_i J_i^T C_i^-1 J_i`` (3x3 in S) and ``covariance_S = F^-1`` — the Cramér–Rao bound
  for the given centroid noise, which the estimate attains to first order. The boresight
  (``z_S``) / cross-boresight ratio follows from the stars' spread: about ``z_S`` a star's lever
  arm is its distance from the boresight, across it the focal length. For an ideal pinhole with
  isotropic noise ``sigma_px`` near the boresight, ``F`` tends to QUEST's
  ``sum_i (I - b_i b_i^T) / sigma^2`` with ``sigma = sigma_px / f_px`` (tested).
* ``chi_square = sum_i e_i^T C_i^-1 e_i`` at the solution, ``2 n - 3`` degrees of freedom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.filters.compiled import jit
from drake_att.star_camera import PinholeCamera
from drake_att.validation import fail

#: Gauss–Newton steps after the SVD solution (more move the estimate by < 1e-3 of its sigma for
#: sub-pixel noise, off-axis and with distortion; tested).
GAUSS_NEWTON_STEPS = 2


@dataclass(frozen=True)
class StarAttitude:
    """A frame's attitude from its identified stars.

    Attributes:
        q_IS: (4,) the sensor frame's attitude (wxyz, Hamilton; ``v_I = R(q_IS) v_S``).
        covariance_S: (3, 3) covariance of ``dtheta_S`` (rad^2), ``F^-1``.
        chi_square: the weighted pixel residuals' sum of squares at the solution.
        num_stars: stars used.
    """

    q_IS: np.ndarray
    covariance_S: np.ndarray
    chi_square: float
    num_stars: int

    @property
    def degrees_of_freedom(self) -> int:
        """``2 n - 3``: the chi-square's degrees of freedom."""
        return 2 * self.num_stars - 3

    @property
    def sigma_S_rad(self) -> np.ndarray:
        """1-sigma per axis of S (rad): ``x_S``, ``y_S`` (cross-boresight), ``z_S`` (roll)."""
        return np.sqrt(np.diag(self.covariance_S))


def wahba_svd(b_S, r_I, weights) -> np.ndarray:
    """``q_IS`` (wxyz) maximizing ``sum_i w_i b_i^T R_SI r_i`` (Markley 1988): unit vectors
    ``b_S`` (n, 3) measured in S, ``r_I`` (n, 3) their references in I, ``weights`` (n,) > 0."""
    B = (np.asarray(weights, dtype=float)[:, None] * np.asarray(b_S, dtype=float)).T @ np.asarray(r_I, dtype=float)
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    R_SI = (U * np.array([1.0, 1.0, d])) @ Vt
    return rot.rotmat_to_quat(R_SI.T)


def centroid_covariances(centroid_cov_px2, n: int, field: str = "centroid_cov_px2") -> np.ndarray:
    """``(n, 2, 2)`` pixel covariances from one sigma (px: ``sigma^2 I``) or an ``(n, 2, 2)``
    array of symmetric positive-definite matrices."""
    c = np.asarray(centroid_cov_px2, dtype=float)
    if c.ndim == 0:
        s = float(c)
        if not (np.isfinite(s) and s > 0):
            fail(field, centroid_cov_px2, "a scalar is the centroid sigma (px) and must be finite and > 0")
        out = np.zeros((n, 2, 2))
        out[:, 0, 0] = out[:, 1, 1] = s * s
        return out
    if c.shape != (n, 2, 2):
        fail(field, c.shape, f"must be a sigma (px) or an array of shape ({n}, 2, 2) (px^2)")
    a, b, d = c[:, 0, 0], c[:, 0, 1], c[:, 1, 1]
    symmetric = np.all(np.abs(b - c[:, 1, 0]) <= 1e-9 * (np.abs(a) + np.abs(d)))
    if not (np.all(np.isfinite(c)) and symmetric and np.all(a > 0) and np.all(a * d - b * b > 0)):
        fail(field, "(array)", "every 2x2 matrix must be finite, symmetric and positive definite (px^2)")
    return c


@jit
def project_pixel(camera_params, dx, dy, dz):
    """Pixel ``(u, v)`` of the direction ``(dx, dy, dz)`` in S (``dz > 0``):
    :meth:`~drake_att.star_camera.PinholeCamera.project`'s formulas, for the compiled kernels.
    ``camera_params``: ``f_px, c_u, c_v, k1, k2`` (:func:`camera_parameters`)."""
    xn = dx / dz
    yn = dy / dz
    r2 = xn * xn + yn * yn
    g = 1.0 + camera_params[3] * r2 + camera_params[4] * r2 * r2
    return camera_params[1] + camera_params[0] * g * xn, camera_params[2] + camera_params[0] * g * yn


@jit
def _project_jacobian_rows(camera_params, dx, dy, dz, out):
    """Pixel ``(u, v)`` of direction ``(dx, dy, dz)`` (``dz > 0``) and the rows ``J_u``, ``J_v`` of
    :meth:`~drake_att.star_camera.PinholeCamera.projection_jacobian` (pixels per radian), into
    ``out`` (8,): ``u, v, J_u (3), J_v (3)``. ``camera_params``: ``f_px, c_u, c_v, k1, k2``."""
    f, k1, k2 = camera_params[0], camera_params[3], camera_params[4]
    xn = dx / dz
    yn = dy / dz
    r2 = xn * xn + yn * yn
    g = 1.0 + k1 * r2 + k2 * r2 * r2
    out[0], out[1] = project_pixel(camera_params, dx, dy, dz)
    # d(xn, yn)/d(phi) for d -> d + phi x d
    nx0, nx1, nx2 = -xn * yn, 1.0 + xn * xn, -yn
    ny0, ny1, ny2 = -(1.0 + yn * yn), xn * yn, xn
    dg = 2.0 * (k1 + 2.0 * k2 * r2)
    a_xx = f * (g + dg * xn * xn)
    a_xy = f * dg * xn * yn
    a_yy = f * (g + dg * yn * yn)
    out[2] = a_xx * nx0 + a_xy * ny0
    out[3] = a_xx * nx1 + a_xy * ny1
    out[4] = a_xx * nx2 + a_xy * ny2
    out[5] = a_xy * nx0 + a_yy * ny0
    out[6] = a_xy * nx1 + a_yy * ny1
    out[7] = a_xy * nx2 + a_yy * ny2


@jit
def _solve_kernel(camera_params, z, r_I, W, steps, R_IS, F):
    """Wahba SVD + ``steps`` Gauss–Newton steps (module docstring). Writes ``R_IS`` (3x3) and the
    last step's information ``F`` (3x3); returns the chi-square at the solution, or -1 when a
    star falls behind the camera, -2 when ``F`` is singular."""
    f, cu, cv, k1, k2 = camera_params[0], camera_params[1], camera_params[2], camera_params[3], camera_params[4]
    n = z.shape[0]
    B = np.zeros((3, 3))
    for i in range(n):
        xd = (z[i, 0] - cu) / f
        yd = (z[i, 1] - cv) / f
        rd = math.sqrt(xd * xd + yd * yd)
        r = rd
        if (k1 != 0.0 or k2 != 0.0) and rd > 0.0:
            for _ in range(30):
                gg = r * (1.0 + k1 * r * r + k2 * r**4) - rd
                step = gg / (1.0 + 3.0 * k1 * r * r + 5.0 * k2 * r**4)
                r -= step
                if abs(step) <= 1e-15 * max(1.0, r):
                    break
        scale = r / rd if rd > 0.0 else 1.0
        bx, by = xd * scale, yd * scale
        nb = math.sqrt(bx * bx + by * by + 1.0)
        w = (W[i, 0] + W[i, 2]) / nb
        for a in range(3):
            ba = (bx, by, 1.0)[a] * w
            for b in range(3):
                B[a, b] += ba * r_I[i, b]
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    for a in range(3):
        U[a, 2] *= d
    R_IS[:, :] = (U @ Vt).T
    row = np.empty(8)
    g = np.empty(3)
    Fi = np.empty((3, 3))
    for _ in range(steps):
        F[:, :] = 0.0
        g[:] = 0.0
        for i in range(n):
            dx = r_I[i, 0] * R_IS[0, 0] + r_I[i, 1] * R_IS[1, 0] + r_I[i, 2] * R_IS[2, 0]
            dy = r_I[i, 0] * R_IS[0, 1] + r_I[i, 1] * R_IS[1, 1] + r_I[i, 2] * R_IS[2, 1]
            dz = r_I[i, 0] * R_IS[0, 2] + r_I[i, 1] * R_IS[1, 2] + r_I[i, 2] * R_IS[2, 2]
            if not dz > 0.0:
                return -1.0
            _project_jacobian_rows(camera_params, dx, dy, dz, row)
            eu = z[i, 0] - row[0]
            ev = z[i, 1] - row[1]
            wuu, wuv, wvv = W[i, 0], W[i, 1], W[i, 2]
            for a in range(3):
                ta = wuu * row[2 + a] + wuv * row[5 + a]
                sa = wuv * row[2 + a] + wvv * row[5 + a]
                g[a] += ta * eu + sa * ev
                for b in range(3):
                    F[a, b] += ta * row[2 + b] + sa * row[5 + b]
        det = (
            F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
            - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0])
        )
        tr = F[0, 0] + F[1, 1] + F[2, 2]
        if not (math.isfinite(det) and det > 1e-12 * tr * tr * tr):
            return -2.0
        Fi[:, :] = np.linalg.inv(F)
        px = -(Fi[0, 0] * g[0] + Fi[0, 1] * g[1] + Fi[0, 2] * g[2])
        py = -(Fi[1, 0] * g[0] + Fi[1, 1] * g[1] + Fi[1, 2] * g[2])
        pz = -(Fi[2, 0] * g[0] + Fi[2, 1] * g[1] + Fi[2, 2] * g[2])
        R_IS[:, :] = R_IS @ _rotvec_to_rotmat(px, py, pz)
    chi2 = 0.0
    for i in range(n):
        dx = r_I[i, 0] * R_IS[0, 0] + r_I[i, 1] * R_IS[1, 0] + r_I[i, 2] * R_IS[2, 0]
        dy = r_I[i, 0] * R_IS[0, 1] + r_I[i, 1] * R_IS[1, 1] + r_I[i, 2] * R_IS[2, 1]
        dz = r_I[i, 0] * R_IS[0, 2] + r_I[i, 1] * R_IS[1, 2] + r_I[i, 2] * R_IS[2, 2]
        if not dz > 0.0:
            return -1.0
        _project_jacobian_rows(camera_params, dx, dy, dz, row)
        eu = z[i, 0] - row[0]
        ev = z[i, 1] - row[1]
        chi2 += W[i, 0] * eu * eu + 2.0 * W[i, 1] * eu * ev + W[i, 2] * ev * ev
    return chi2


@jit
def _rotvec_to_rotmat(x, y, z):
    a = math.sqrt(x * x + y * y + z * z)
    if a < 1e-8:
        s, c1 = 1.0 - a * a / 6.0, 0.5 - a * a / 24.0
    else:
        s, c1 = math.sin(a) / a, (1.0 - math.cos(a)) / (a * a)
    R = np.empty((3, 3))
    R[0, 0] = 1.0 - c1 * (y * y + z * z)
    R[1, 1] = 1.0 - c1 * (x * x + z * z)
    R[2, 2] = 1.0 - c1 * (x * x + y * y)
    R[0, 1] = -s * z + c1 * x * y
    R[1, 0] = s * z + c1 * x * y
    R[0, 2] = s * y + c1 * x * z
    R[2, 0] = -s * y + c1 * x * z
    R[1, 2] = -s * x + c1 * y * z
    R[2, 1] = s * x + c1 * y * z
    return R


@jit
def _rotmat_to_quat(R, q):
    """rotations.rotmat_to_quat for one matrix (Shepperd's method, ``w >= 0``) into ``q``."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    c0, c1, c2, c3 = 1.0 + tr, 1.0 + 2.0 * R[0, 0] - tr, 1.0 + 2.0 * R[1, 1] - tr, 1.0 + 2.0 * R[2, 2] - tr
    if c0 >= c1 and c0 >= c2 and c0 >= c3:
        s = 2.0 * math.sqrt(c0)
        q[0], q[1], q[2], q[3] = s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif c1 >= c2 and c1 >= c3:
        s = 2.0 * math.sqrt(c1)
        q[0], q[1], q[2], q[3] = (R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif c2 >= c3:
        s = 2.0 * math.sqrt(c2)
        q[0], q[1], q[2], q[3] = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(c3)
        q[0], q[1], q[2], q[3] = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = -1.0 if q[0] < 0.0 else 1.0
    for k in range(4):
        q[k] = sign * q[k] / n


def camera_parameters(camera: PinholeCamera) -> np.ndarray:
    """``[f_px, c_u, c_v, k1, k2]``: what the compiled kernels read of a camera."""
    c = camera.principal_point_px
    return np.array([camera.focal_length_px, c[0], c[1], camera.k1, camera.k2])


def _weights(C: np.ndarray) -> np.ndarray:
    """``(n, 3)``: ``[w_uu, w_uv, w_vv]`` of ``W_i = C_i^-1``."""
    a, b, d = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
    det = a * d - b * b
    return np.column_stack([d / det, -b / det, a / det])


def fisher_information(camera: PinholeCamera, directions_S, centroid_cov_px2) -> np.ndarray:
    """``F = sum_i J_i^T C_i^-1 J_i`` (3x3 in S, 1/rad^2) of stars at ``directions_S`` (n, 3)
    with pixel covariances ``centroid_cov_px2`` (a sigma in px, or (n, 2, 2) px^2)."""
    d = np.atleast_2d(np.asarray(directions_S, dtype=float))
    J = camera.projection_jacobian(d)
    W = np.linalg.inv(centroid_covariances(centroid_cov_px2, len(d)))
    return np.einsum("nai,nab,nbj->ij", J, W, J)


def _check_inputs(centroids_px, references_I) -> tuple[np.ndarray, np.ndarray]:
    z = np.asarray(centroids_px, dtype=float)
    r = np.asarray(references_I, dtype=float)
    if z.ndim != 2 or z.shape[1] != 2 or not np.all(np.isfinite(z)):
        fail("centroids_px", z.shape if z.ndim != 2 else "(array)", "must be a finite array of shape (n, 2) (px)")
    if r.shape != (len(z), 3) or not np.all(np.isfinite(r)):
        fail("references_I", r.shape, f"must be a finite array of shape ({len(z)}, 3), one per centroid")
    if len(z) < 2:
        fail("centroids_px", len(z), "an attitude needs at least 2 stars")
    norm = np.sqrt(np.sum(r * r, axis=1))
    if not np.all(norm > 0):
        fail("references_I", "(array)", "rows must be non-zero directions")
    return z, r / norm[:, None]


_UNDETERMINED = "the stars' geometry leaves the attitude undetermined"


def solve_star_attitude(
    camera: PinholeCamera,
    centroids_px,
    references_I,
    centroid_cov_px2,
    gauss_newton_steps: int = GAUSS_NEWTON_STEPS,
) -> StarAttitude:
    """The frame's attitude and covariance from ``n >= 2`` identified stars (module docstring).

    Args:
        camera: the camera that took the frame.
        centroids_px: (n, 2) centroids ``(u, v)`` (px).
        references_I: (n, 3) the identified stars' catalogue directions in I.
        centroid_cov_px2: the centroids' covariance: a sigma (px) or (n, 2, 2) (px^2).
        gauss_newton_steps: weighted least-squares steps after the SVD solution (>= 1); the
            covariance is ``F^-1`` at the last step's linearization point (the step moves the
            estimate by a fraction of its sigma, which changes ``F`` by far less).

    Raises:
        ValueError: one line for inputs of the wrong shape, non-finite, fewer than 2 stars, a
            covariance that is not positive definite, or stars whose geometry leaves the
            attitude undetermined (e.g. two stars along one direction).
    """
    z, r_I = _check_inputs(centroids_px, references_I)
    W = _weights(centroid_covariances(centroid_cov_px2, len(z)))
    return _solve_checked(camera_parameters(camera), z, r_I, W, max(1, int(gauss_newton_steps)))


def _solve_checked(
    camera_params: np.ndarray, z: np.ndarray, r_I: np.ndarray, W: np.ndarray, steps: int
) -> StarAttitude:
    """The compiled solve on checked inputs (unit ``r_I``, ``W`` rows ``[w_uu, w_uv, w_vv]``)."""
    R_IS = np.empty((3, 3))
    F = np.empty((3, 3))
    chi2 = _solve_kernel(camera_params, z, r_I, W, steps, R_IS, F)
    if chi2 == -1.0:
        fail("references_I", "(array)", "a star is behind the camera at the solved attitude")
    if chi2 < 0.0:
        fail("references_I", "(array)", "the stars' geometry leaves the attitude undetermined")
    P = np.linalg.inv(F)
    q = np.empty(4)
    _rotmat_to_quat(R_IS, q)
    return StarAttitude(q, 0.5 * (P + P.T), float(chi2), len(z))


__all__ = [
    "GAUSS_NEWTON_STEPS",
    "StarAttitude",
    "wahba_svd",
    "camera_parameters",
    "centroid_covariances",
    "fisher_information",
    "solve_star_attitude",
]
