"""Calibration of paper S2's indoor star tracker: the screen height ``h`` and the camera offset
``R0_B`` (plain numpy, no Drake).

Geometry and notation: :mod:`drake_att.screen_geometry`. The calibration parameters are
``theta = [h, R0_x, R0_y, R0_z]`` (m; :data:`CALIBRATION_PARAMETERS`): the solver's model of the
layout. Three pieces:

* :class:`CalibrationUncertainty`: the 1-sigma of ``h`` and of each axis of ``R0_B``; its
  covariance enters the solver's attitude covariance as ``J Sigma_cal J^T``, with ``J = d(attitude
  solution) / d theta`` by central differences of the converged solution
  (:func:`calibration_jacobian`).
* :func:`pair_angle_tolerance`: the angle-match tolerance from the centroid noise.
* :func:`self_calibrate`: ``R0_B`` (hence ``h``) and every frame's attitude from frames at
  several tilts, by Gauss-Newton (Levenberg-Marquardt damping) on the centroids, with the
  Cramér-Rao bound of the joint problem.

**What the images determine.** A star's model position is its zero-attitude photo direction
``b0_j`` carried to the screen: ``s_j = R0 + h1 d_j`` with ``d_j = b0_j / (p . b0_j)`` and
``h1 = h - p . R0`` the camera-to-screen distance at zero attitude. At attitude ``A`` the camera
sees ``v_j = A s_j - R0 = (A - I) R0 + h1 A d_j``: a direction, so only ``R0 / h1`` enters —
a laboratory scaled about the rotation centre gives the same images, and ``h`` and ``R0``
cannot both be estimated from stars alone. :func:`self_calibrate` takes one length as known,
the camera-to-screen distance ``h1`` (measured from the camera, e.g. with a laser range finder),
and estimates ``R0_B`` (3 axes) with ``h = h1 + p . R0``.

**Which tilts.** A tilt ``A`` moves the camera by ``(A - I) R0``: a tilt by ``phi`` about x moves
it by ``~phi R0_z`` along y (parallel to the screen: the pattern shifts, non-uniformly over a wide
field) and ``~phi R0_y`` along z (towards the screen: the pattern scales); a tilt about y sees
``R0_z`` and ``R0_x``. Level frames see nothing (``A = I``). Tilts about two axes are needed for
all three components (about x only, ``R0_x`` is unobservable). ``R0_z`` (hence ``h``) is the
least determined (its shift parallel to the screen is nearly a rotation, which the frame's
attitude absorbs), the lateral components the best (they scale the pattern, which no rotation
mimics).

Derivation: docs/derivations/indoor_star_tracker.md ("Calibration").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.screen_geometry import SCREEN_NORMAL_I, camera_to_star_distances, centre_referenced_directions
from drake_att.validation import check_finite, check_int, check_nonnegative, check_positive, fail

CALIBRATION_PARAMETERS = ("screen_height_m", "camera_offset_x_m", "camera_offset_y_m", "camera_offset_z_m")
JACOBIAN_RELATIVE_STEP = 1e-4  # central-difference step of every parameter, as a fraction of h
FIXED_POINT_TOLERANCE_RAD = 1e-14  # the perturbed solutions are iterated to this change
FIXED_POINT_MAX_ITERATIONS = 12  # the iteration contracts ~100x per step (tests/test_indoor_star_tracker.py)


@dataclass(frozen=True)
class CalibrationUncertainty:
    """1-sigma of the solver's screen height ``h`` and of each axis of its camera offset ``R0_B``
    (m, >= 0; 0 and 0: no calibration term)."""

    screen_height_sigma_m: float = 0.0
    camera_offset_sigma_m: float = 0.0

    def __post_init__(self):
        check_nonnegative("screen_height_sigma_m", self.screen_height_sigma_m)
        check_nonnegative("camera_offset_sigma_m", self.camera_offset_sigma_m)

    @property
    def active(self) -> bool:
        return self.screen_height_sigma_m > 0.0 or self.camera_offset_sigma_m > 0.0

    @property
    def covariance(self) -> np.ndarray:
        """``Sigma_cal`` (4, 4) of ``[h, R0_x, R0_y, R0_z]`` (m^2), independent parameters."""
        s, o = self.screen_height_sigma_m, self.camera_offset_sigma_m
        return np.diag([s * s, o * o, o * o, o * o])


def pair_angle_tolerance(centroid_sigma_m: float, quantization_m: float, focal_length_m: float, sigmas: float):
    """Angle-match tolerance (rad): ``k sqrt(2) sigma_c / f`` with ``sigma_c = sqrt(sigma^2 +
    q^2 / 12)`` the centroid's per-axis noise (quantization as a uniform error) and ``k`` =
    ``sigmas``.

    A direction's error normal to it is at most ``sigma_c / f`` per axis (at the boresight; off
    axis the same centroid error turns the direction by less), and the angle between two
    directions moves by the sum of their errors along the arc joining them: variance at most
    ``2 sigma_c^2 / f^2``. ``k`` is the number of standard deviations a true pair may differ by
    (``k^2`` a chi-square(1) bound: ``k = 4`` misses a true pair with probability 6e-5)."""
    check_positive("tolerance_sigmas", sigmas)
    sigma_c = math.sqrt(float(centroid_sigma_m) ** 2 + float(quantization_m) ** 2 / 12.0)
    return sigmas * math.sqrt(2.0) * sigma_c / float(focal_length_m)


def catalogue_directions(b0_B, h_m: float, R0_B) -> np.ndarray:
    """The catalogue's centre-referenced directions ``r_j`` (m, 3) of the zero-attitude photo's
    camera directions ``b0_B`` under the model ``(h, R0_B)``."""
    b0 = np.asarray(b0_B, dtype=float)
    return centre_referenced_directions(b0, camera_to_star_distances(np.eye(3), b0, R0_B, h_m), R0_B)


def calibration_vector(h_m: float, R0_B) -> np.ndarray:
    """``theta = [h, R0_x, R0_y, R0_z]`` (m)."""
    return np.concatenate([[float(h_m)], np.asarray(R0_B, dtype=float)])


def calibration_jacobian(solve_at, theta, step_m: float) -> np.ndarray:
    """``J`` (3, len(theta)): the body-axis rotation of the attitude solution per unit of each
    calibration parameter, by central differences: column ``i`` is
    ``rotvec(A(theta + d e_i) A(theta - d e_i)^T) / (2 d)`` with ``A = solve_at(theta)`` (``R_BI``)."""
    theta = np.asarray(theta, dtype=float)
    J = np.zeros((3, len(theta)))
    for i in range(len(theta)):
        e = np.zeros(len(theta))
        e[i] = step_m
        J[:, i] = rot.rotmat_to_rotvec(solve_at(theta + e) @ solve_at(theta - e).T) / (2.0 * step_m)
    return J


# -- self-calibration --------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationFrame:
    """One frame of a self-calibration: its centroids (n, 2) (m), the catalogue index of each
    (-1: not identified; unidentified stars are left out) and an attitude guess ``R_BI``."""

    centroids_m: np.ndarray
    catalogue_ids: np.ndarray
    R_BI_guess: np.ndarray


@dataclass(frozen=True)
class SelfCalibration:
    """:func:`self_calibrate`'s result.

    Attributes:
        screen_height_m: ``h = h1 + p . R0``; camera_offset_B_m: ``R0_B`` (3,).
        R_BI: (K, 3, 3) every frame's attitude.
        crb: (4, 4) Cramér-Rao bound of ``[h, R0_x, R0_y, R0_z]`` (m^2): the calibration block
            of the inverse Fisher information of the joint problem (every frame's attitude a
            nuisance parameter), at the estimate.
        iterations: Gauss-Newton steps taken; converged: the last step was below the tolerance.
        residual_rms_m: RMS of the centroid residuals at the estimate (m, per axis).
    """

    screen_height_m: float
    camera_offset_B_m: np.ndarray
    R_BI: np.ndarray
    crb: np.ndarray
    iterations: int
    converged: bool
    residual_rms_m: float

    @property
    def sigmas_m(self) -> np.ndarray:
        """The Cramér-Rao 1-sigma of ``[h, R0_x, R0_y, R0_z]`` (m)."""
        return np.sqrt(np.diag(self.crb))


def _frame_model(A, R0, d, h1: float, f: float):
    """Predicted centroids (n, 2) of model directions ``d`` (n, 3) at ``A`` and their Jacobians
    (n, 2, 3) with respect to a body rotation ``phi`` (``A <- exp([phi x]) A``) and to ``R0``."""
    w = h1 * (d @ A.T) + A @ R0  # A s_j
    v = w - R0
    vz = v[:, 2]
    c = f * v[:, :2] / vz[:, None]
    dc_dv = np.zeros((len(v), 2, 3))
    dc_dv[:, 0, 0] = dc_dv[:, 1, 1] = f / vz
    dc_dv[:, :, 2] = -f * v[:, :2] / (vz * vz)[:, None]
    return c, dc_dv @ -rot.skew(w), dc_dv @ (A - np.eye(3))


def self_calibrate(
    frames,
    catalogue_b0_B,
    focal_length_m: float,
    camera_to_screen_m: float,
    camera_offset_guess_B_m,
    centroid_sigma_m: float,
    max_iterations: int = 50,
    tolerance: float = 1e-12,
) -> SelfCalibration:
    """Estimate the camera offset ``R0_B`` (hence the screen height) jointly with every frame's
    attitude from frames at several tilts (see the module docstring for the model and why the
    camera-to-screen distance is taken as known).

    Minimizes ``sum |c_ij - c(A_i, R0; d_j)|^2`` over the identified centroids ``c_ij`` (the
    maximum-likelihood estimate for independent Gaussian centroid noise) by Gauss-Newton with
    Levenberg-Marquardt damping (``lambda`` x10 on a rejected step, /10 on an accepted one).

    Args:
        frames: :class:`CalibrationFrame` sequence (>= 1).
        catalogue_b0_B: (m, 3) camera directions of the zero-attitude photo (the catalogue).
        focal_length_m: the camera's focal length (m).
        camera_to_screen_m: ``h1 = h - p . R0``, the known scale (m).
        camera_offset_guess_B_m: (3,) the starting ``R0_B`` (m).
        centroid_sigma_m: the centroid noise per axis (m, > 0; quantization included as
            ``q^2 / 12``) that scales the Fisher information.
        max_iterations: Gauss-Newton steps (>= 1); tolerance: stop when every step component is
            below it (rad and m).
    """
    frames = list(frames)
    if not frames:
        fail("frames", "[]", "need >= 1 calibration frame")
    f = check_positive("focal_length_m", focal_length_m)
    h1 = check_positive("camera_to_screen_m", camera_to_screen_m)
    sigma = check_positive("centroid_sigma_m", centroid_sigma_m)
    check_int("max_iterations", max_iterations, 1)
    check_nonnegative("tolerance", tolerance)
    b0 = np.asarray(catalogue_b0_B, dtype=float)
    p = SCREEN_NORMAL_I
    d_all = b0 / (b0 @ p)[:, None]
    R0 = np.array(camera_offset_guess_B_m, dtype=float)
    if R0.shape != (3,) or not np.all(np.isfinite(R0)):
        fail("camera_offset_guess_B_m", camera_offset_guess_B_m, "need 3 finite numbers (m)")
    data = []
    for k, fr in enumerate(frames):
        ids = np.asarray(fr.catalogue_ids, dtype=int)
        sel = np.flatnonzero(ids >= 0)
        if len(sel) < 3:
            fail(f"frames[{k}].catalogue_ids", f"{len(sel)} identified", "need >= 3 identified stars per frame")
        data.append((np.asarray(fr.centroids_m, dtype=float).reshape(-1, 2)[sel], d_all[ids[sel]]))
    A = np.array([np.asarray(fr.R_BI_guess, dtype=float) for fr in frames])
    K = len(frames)
    n_par = 3 * K + 3

    def residuals_and_jacobian(A, R0):
        rows, blocks = [], []
        for k, (c_meas, d) in enumerate(data):
            c, J_phi, J_R0 = _frame_model(A[k], R0, d, h1, f)
            rows.append((c - c_meas).ravel())
            J = np.zeros((2 * len(d), n_par))
            J[:, 3 * k : 3 * k + 3] = J_phi.reshape(-1, 3)
            J[:, 3 * K :] = J_R0.reshape(-1, 3)
            blocks.append(J)
        return np.concatenate(rows), np.vstack(blocks)

    r, J = residuals_and_jacobian(A, R0)
    cost = float(r @ r)
    lam, converged, iterations = 1e-3, False, 0
    while iterations < max_iterations:
        iterations += 1
        N = J.T @ J
        g = J.T @ r
        step = np.linalg.solve(N + lam * np.diag(np.diag(N)), -g)
        A_try = np.array([rot.rotvec_to_rotmat(step[3 * k : 3 * k + 3]) @ A[k] for k in range(K)])
        R0_try = R0 + step[3 * K :]
        r_try, J_try = residuals_and_jacobian(A_try, R0_try)
        cost_try = float(r_try @ r_try)
        if cost_try <= cost:
            A, R0, r, J, cost, lam = A_try, R0_try, r_try, J_try, cost_try, max(lam / 10.0, 1e-12)
            if np.max(np.abs(step)) < tolerance:
                converged = True
                break
        else:
            lam *= 10.0
            if lam > 1e12:
                break
    cov = sigma * sigma * np.linalg.inv(J.T @ J)
    T = np.vstack([p, np.eye(3)])  # d[h, R0] / dR0 with h = h1 + p . R0
    crb = T @ cov[3 * K :, 3 * K :] @ T.T
    h = h1 + float(p @ R0)
    check_finite("screen_height_m", h)
    return SelfCalibration(h, R0, A, crb, iterations, converged, float(np.sqrt(cost / len(r))))


__all__ = [
    "CALIBRATION_PARAMETERS",
    "JACOBIAN_RELATIVE_STEP",
    "CalibrationUncertainty",
    "pair_angle_tolerance",
    "catalogue_directions",
    "calibration_vector",
    "calibration_jacobian",
    "CalibrationFrame",
    "SelfCalibration",
    "self_calibrate",
]
