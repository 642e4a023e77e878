"""Paper S2's indoor star tracker geometry: a star screen above an air-bearing table and a
pinhole camera mounted off the table's rotation centre (plain numpy, no Drake).

Frames (SPEC.md S2; paper fig. 1):

* I — reference frame at the table's rotation centre. The screen is the plane
  ``p . x = h`` with normal ``p = [0, 0, -1]``: it lies at ``z_I = -h`` (the table's "up"
  is ``-z``), ``h`` = centre-to-screen distance (paper 2000 mm).
* B — the table / camera body frame; the table attitude is ``A = R_BI`` (paper: ``A r = b``).
  The camera's projection centre sits at the body-fixed ``R0_B`` from the rotation centre
  (paper: 200 mm towards the screen, ``R0_B = [0, 0, -0.2]`` m) and looks along ``-z_B``.
* Focal plane: a star at ``v_B = R_BI s_I - R0_B`` (camera-to-star, body axes) with
  ``v_z < 0`` (in front) images at ``(X_c, Y_c) = f (v_x, v_y) / v_z``; its measured
  direction is ``b = [-X_c, -Y_c, -f] / norm`` (the paper's eq. for ``[i, j, k]``), which
  equals ``v / |v|``.

The estimator's model (paper section 2): ``R0 + alpha_i b_i = beta_i r_i`` with ``alpha_i``
the camera-to-star and ``beta_i`` the centre-to-star distance; from an attitude guess ``A0``,
``alpha_i = (h - p' A0' R0_B) / (p' A0' b_i)``, and the centre-referenced direction
``r_i^B = normalize(R0_B + alpha_i b_i)`` is what the inter-star angles are computed from.
The catalogue is the camera's (noise-free) view at zero attitude converted the same way,
``r_i = (R0 + alpha_i b_i) / beta_i``, which is exactly ``s_i / |s_i|``.

Everything here is exact ray-plane geometry; noise and quantization live in the sensor
(:mod:`drake_att.systems.screen_camera`), the solver in
:mod:`drake_att.filters.indoor_star_tracker`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att.validation import check_finite, check_positive, fail

SCREEN_NORMAL_I = np.array([0.0, 0.0, -1.0])


def random_star_pattern(count: int, screen_size_m: float, h_m: float, seed: int) -> np.ndarray:
    """``count`` star positions (m, frame I) uniform on the square screen of side
    ``screen_size_m`` centred above the rotation centre at ``z = -h`` (seeded, like the
    paper's MATLAB random matrix)."""
    if not (isinstance(count, (int, np.integer)) and count >= 1):
        fail("star_count", count, "must be an integer >= 1")
    check_positive("screen_size_m", screen_size_m)
    check_positive("h_m", h_m)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5C2EE4]))
    xy = (rng.random((int(count), 2)) - 0.5) * screen_size_m
    return np.column_stack([xy, np.full(int(count), -h_m)])


@dataclass(frozen=True)
class ScreenCameraGeometry:
    """The screen, its stars and the camera (SI units).

    Attributes:
        stars_I: (N, 3) star positions on the screen plane ``z = -h`` (m).
        h_m: rotation centre to screen (m).
        R0_B: (3,) rotation centre to camera projection centre, body axes (m).
        focal_length_m: pinhole focal length (m).
        detector_size_m: (width along x_B, height along y_B) of the detector (m).
        pixel_pitch_m: pixel size (m) (for quantization and the noise unit "px").
    """

    stars_I: np.ndarray
    h_m: float
    R0_B: np.ndarray
    focal_length_m: float
    detector_size_m: tuple
    pixel_pitch_m: float

    def __post_init__(self):
        stars = np.asarray(self.stars_I, dtype=float)
        if stars.ndim != 2 or stars.shape[1] != 3 or stars.shape[0] < 1 or not np.all(np.isfinite(stars)):
            fail("stars_I", self.stars_I, "need (N >= 1, 3) finite positions")
        check_positive("h_m", self.h_m)
        if not np.allclose(stars @ SCREEN_NORMAL_I, self.h_m, atol=1e-9):
            fail("stars_I", "off the screen plane", f"every star must satisfy p . s = h = {self.h_m} m")
        R0 = np.asarray(self.R0_B, dtype=float)
        if R0.shape != (3,) or not np.all(np.isfinite(R0)):
            fail("R0_B", self.R0_B, "need 3 finite numbers (m)")
        if not abs(R0 @ SCREEN_NORMAL_I) < self.h_m:
            fail(
                "R0_B",
                R0.tolist(),
                f"the camera must be between the rotation centre plane and the screen (|p . R0| < h = {self.h_m} m)",
            )
        check_positive("focal_length_m", self.focal_length_m)
        size = tuple(float(v) for v in self.detector_size_m)
        if len(size) != 2:
            fail("detector_size_m", self.detector_size_m, "need (width, height) (m)")
        for v in size:
            check_positive("detector_size_m", v)
        check_positive("pixel_pitch_m", self.pixel_pitch_m)
        object.__setattr__(self, "stars_I", stars)
        object.__setattr__(self, "R0_B", R0)
        object.__setattr__(self, "detector_size_m", size)

    def with_layout(self, h_m: float, R0_B) -> ScreenCameraGeometry:
        """This camera and screen with another screen height and camera offset (the stars keep
        their ``x, y`` on the moved screen): a solver's model after a calibration."""
        stars = self.stars_I.copy()
        stars[:, 2] = -float(h_m)
        return ScreenCameraGeometry(
            stars,
            float(h_m),
            np.asarray(R0_B, dtype=float),
            self.focal_length_m,
            self.detector_size_m,
            self.pixel_pitch_m,
        )

    @property
    def half_field_of_view_rad(self) -> np.ndarray:
        """Half field of view along x_B and y_B (rad)."""
        return np.arctan(0.5 * np.asarray(self.detector_size_m) / self.focal_length_m)

    def camera_to_stars_B(self, R_BI: np.ndarray) -> np.ndarray:
        """``v_B = R_BI s_I - R0_B`` for every star (N, 3), m."""
        return self.stars_I @ np.asarray(R_BI).T - self.R0_B

    def project(self, R_BI: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The exact pinhole image at attitude ``R_BI``.

        Returns:
            ``(star_ids (m,), centroids_m (m, 2))`` of the stars in front of the camera and
            on the detector, in raster order (by ``Y_c``, then ``X_c``) as a detector reads
            them out — not in catalogue order.
        """
        v = self.camera_to_stars_B(R_BI)
        in_front = v[:, 2] < 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = self.focal_length_m * v[:, :2] / v[:, 2:3]
        half = 0.5 * np.asarray(self.detector_size_m)
        seen = in_front & np.all(np.abs(xy) <= half, axis=1)
        ids = np.flatnonzero(seen)
        order = np.lexsort((xy[ids, 0], xy[ids, 1]))
        ids = ids[order]
        return ids, xy[ids]

    def catalogue(self, centroids_m=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The navigation catalogue: the camera's noise-free view at zero attitude.

        Args:
            centroids_m: the zero-attitude photo to convert (k, 2), e.g. taken by a real
                camera whose offset differs from this geometry's model (calibration error);
                None: this geometry's own exact view.
        Returns:
            ``(star_ids (m,), r_I (m, 3), b0 (m, 3))``: the ids of the stars seen at zero
            attitude, their centre-referenced unit directions ``r_i = (R0 + alpha_i b_i) /
            beta_i`` (paper) and the camera directions ``b_i`` themselves (the catalogue of
            the classic, uncorrected angle matching). With ``centroids_m`` the ids are
            positions in that photo.
        """
        if centroids_m is None:
            ids, xy = self.project(np.eye(3))
        else:
            xy = np.asarray(centroids_m, dtype=float).reshape(-1, 2)
            ids = np.arange(len(xy))
        b = directions_from_centroids(xy, self.focal_length_m)
        alpha = camera_to_star_distances(np.eye(3), b, self.R0_B, self.h_m)
        r = centre_referenced_directions(b, alpha, self.R0_B)
        return ids, r, b


def directions_from_centroids(centroids_m, focal_length_m: float) -> np.ndarray:
    """Unit camera directions ``b = [-X, -Y, -f] / norm`` (m, 3) of focal-plane centroids."""
    xy = np.asarray(centroids_m, dtype=float).reshape(-1, 2)
    b = np.column_stack([-xy, np.full(len(xy), -float(focal_length_m))])
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def camera_to_star_distances(R_BI_guess, b_B, R0_B, h_m: float) -> np.ndarray:
    """``alpha_i = (h - p' A0' R0_B) / (p' A0' b_i)`` (m), for the attitude guess ``A0``."""
    p_B = np.asarray(R_BI_guess) @ SCREEN_NORMAL_I  # p expressed in B: A0 p
    return (h_m - p_B @ R0_B) / (np.asarray(b_B) @ p_B)


def centre_referenced_directions(b_B, alpha, R0_B) -> np.ndarray:
    """``normalize(R0_B + alpha_i b_i)`` (m, 3): star directions seen from the rotation centre."""
    v = np.asarray(R0_B) + np.asarray(alpha)[:, None] * np.asarray(b_B)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def check_geometry_inputs(name: str, screen_size_m: float, h_m: float, camera_to_screen_m: float) -> None:
    """The paper's layout: ``0 < h1 < h`` and a finite screen."""
    check_positive(f"{name}.screen_size_mm", screen_size_m)
    check_positive(f"{name}.h_mm", h_m)
    check_finite(f"{name}.camera_to_screen_mm", camera_to_screen_m)
    if not 0.0 < camera_to_screen_m <= h_m:
        fail(f"{name}.camera_to_screen_mm", camera_to_screen_m * 1e3, f"must be in (0, h = {h_m * 1e3}] mm")


__all__ = [
    "SCREEN_NORMAL_I",
    "random_star_pattern",
    "ScreenCameraGeometry",
    "directions_from_centroids",
    "camera_to_star_distances",
    "centre_referenced_directions",
    "check_geometry_inputs",
]
