"""A star tracker's camera geometry: a pinhole with optional radial distortion (plain numpy).

Frames and pixels:

* S — the sensor frame; the boresight is ``+z_S``. A direction ``d_S`` in front of the camera
  (``d_z > 0``) has ideal normalized image coordinates ``(x, y) = (d_x, d_y) / d_z``.
* Distortion (Brown's radial model, optional): ``(x_d, y_d) = (x, y) (1 + k1 r^2 + k2 r^4)`` with
  ``r^2 = x^2 + y^2``.
* Pixels: ``u = c_u + f_px x_d`` (columns, along ``+x_S``), ``v = c_v + f_px y_d`` (rows, along
  ``+y_S``), with ``f_px = focal_length / pixel_pitch``. Pixel ``(i, j)`` (column ``i``, row ``j``)
  covers ``[i, i + 1) x [j, j + 1)``: its centre is ``(i + 0.5, j + 0.5)``, and the principal point
  ``(c_u, c_v)`` is the detector's centre ``(width / 2, height / 2)``.

:meth:`PinholeCamera.project` and :meth:`PinholeCamera.unproject` are inverse to round-off
(distortion inverted by Newton's method on the radius); :meth:`PinholeCamera.projection_jacobian`
is the derivative of the pixel position with respect to a small rotation of the direction, which
maps a centroid's pixel covariance to the star direction's (the attitude's Cramér–Rao bound).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att.validation import check_finite, check_int, check_positive, fail

#: Focal lengths a star tracker's camera may have (m): CubeSat to large trackers.
FOCAL_LENGTH_RANGE_M = (1e-3, 1.0)
#: Pixel pitches (m).
PIXEL_PITCH_RANGE_M = (1e-6, 50e-6)
#: Detector sizes (pixels per side).
DETECTOR_SIZE_RANGE_PX = (16, 16384)
#: The widest full field of view (along the diagonal) a pinhole star camera may have (deg).
MAX_DIAGONAL_FOV_DEG = 90.0
#: The largest distortion allowed: the radial factor ``1 + k1 r^2 + k2 r^4`` must stay in
#: [0.8, 1.2] and increasing in ``r`` over the field (a monotonic, invertible mapping).
DISTORTION_FACTOR_RANGE = (0.8, 1.2)


@dataclass(frozen=True)
class PinholeCamera:
    """A star camera's intrinsics.

    Attributes:
        focal_length_m: focal length (m). pixel_pitch_m: pixel size (m, square pixels).
        width_px, height_px: detector size (columns, rows).
        k1, k2: radial distortion coefficients (0, 0: an ideal pinhole).
    """

    focal_length_m: float
    pixel_pitch_m: float
    width_px: int
    height_px: int
    k1: float = 0.0
    k2: float = 0.0

    @classmethod
    def make(
        cls,
        focal_length_m: float,
        pixel_pitch_m: float,
        width_px: int,
        height_px: int,
        k1: float = 0.0,
        k2: float = 0.0,
        name: str = "camera",
    ) -> PinholeCamera:
        """A checked camera: each value in its physical range, the field of view at most
        :data:`MAX_DIAGONAL_FOV_DEG`, the distortion small and monotonic (ValueError naming the
        field, e.g. ``st1.focal_length_m``)."""
        f = check_positive(f"{name}.focal_length_m", focal_length_m)
        if not FOCAL_LENGTH_RANGE_M[0] <= f <= FOCAL_LENGTH_RANGE_M[1]:
            fail(f"{name}.focal_length_m", focal_length_m, f"must be in {list(FOCAL_LENGTH_RANGE_M)} m")
        p = check_positive(f"{name}.pixel_pitch_m", pixel_pitch_m)
        if not PIXEL_PITCH_RANGE_M[0] <= p <= PIXEL_PITCH_RANGE_M[1]:
            fail(f"{name}.pixel_pitch_m", pixel_pitch_m, f"must be in {list(PIXEL_PITCH_RANGE_M)} m")
        sizes = []
        for field, v in (("width_px", width_px), ("height_px", height_px)):
            n = check_int(f"{name}.{field}", v, DETECTOR_SIZE_RANGE_PX[0])
            if n > DETECTOR_SIZE_RANGE_PX[1]:
                fail(f"{name}.{field}", v, f"must be in {list(DETECTOR_SIZE_RANGE_PX)} pixels")
            sizes.append(n)
        k1 = check_finite(f"{name}.k1", k1)
        k2 = check_finite(f"{name}.k2", k2)
        camera = cls(f, p, sizes[0], sizes[1], k1, k2)
        fov = math.degrees(2.0 * camera.half_diagonal_fov_rad)
        if fov > MAX_DIAGONAL_FOV_DEG:
            fail(
                f"{name}.focal_length_m",
                focal_length_m,
                f"gives a {fov:.1f} deg diagonal field of view with this detector; at most {MAX_DIAGONAL_FOV_DEG:g}",
            )
        r_max = camera.half_diagonal_px / camera.focal_length_px
        rr = np.linspace(0.0, r_max, 201)
        factor = 1.0 + k1 * rr**2 + k2 * rr**4
        slope = 1.0 + 3.0 * k1 * rr**2 + 5.0 * k2 * rr**4  # d(r factor)/dr
        lo, hi = DISTORTION_FACTOR_RANGE
        if not (np.all((factor >= lo) & (factor <= hi)) and np.all(slope > 0)):
            fail(
                f"{name}.k1, k2",
                [k1, k2],
                f"the radial factor must stay in [{lo}, {hi}] and increase over the field (|r| <= {r_max:.3f})",
            )
        return camera

    @property
    def focal_length_px(self) -> float:
        return self.focal_length_m / self.pixel_pitch_m

    @property
    def principal_point_px(self) -> np.ndarray:
        return np.array([0.5 * self.width_px, 0.5 * self.height_px])

    @property
    def half_diagonal_px(self) -> float:
        return 0.5 * math.hypot(self.width_px, self.height_px)

    @property
    def half_diagonal_fov_rad(self) -> float:
        """Half the diagonal field of view (rad), distortion included: the cone that holds the
        whole detector (a sky index's search cone)."""
        r_d = self.half_diagonal_px / self.focal_length_px
        return math.atan(float(self._undistort_radius(np.array([r_d]))[0]))

    @property
    def fov_rad(self) -> tuple[float, float]:
        """Full field of view along the columns and the rows (rad, distortion included)."""
        out = []
        for half_px in (0.5 * self.width_px, 0.5 * self.height_px):
            r = float(self._undistort_radius(np.array([half_px / self.focal_length_px]))[0])
            out.append(2.0 * math.atan(r))
        return out[0], out[1]

    def _distortion_factor(self, r2):
        return 1.0 + self.k1 * r2 + self.k2 * r2 * r2

    def _undistort_radius(self, r_d: np.ndarray) -> np.ndarray:
        """The ideal radius ``r`` with ``r (1 + k1 r^2 + k2 r^4) = r_d`` (Newton; monotonic by
        :meth:`make`'s check)."""
        r = np.array(r_d, dtype=float)
        if self.k1 == 0.0 and self.k2 == 0.0:
            return r
        for _ in range(30):
            g = r * self._distortion_factor(r * r) - r_d
            dg = 1.0 + 3.0 * self.k1 * r * r + 5.0 * self.k2 * r**4
            step = g / dg
            r = r - step
            if np.all(np.abs(step) <= 1e-15 * np.maximum(1.0, np.abs(r))):
                break
        return r

    def project(self, directions_S) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions ``(n, 2)`` = ``(u, v)`` of directions ``(n, 3)`` in S (any length > 0),
        and a boolean ``(n,)``: in front of the camera and on the detector. Directions behind
        the camera get NaN pixels."""
        d = np.atleast_2d(np.asarray(directions_S, dtype=float))
        front = d[:, 2] > 0.0
        z = np.where(front, d[:, 2], np.nan)
        xy = d[:, :2] / z[:, None]
        xy_d = xy * self._distortion_factor(np.sum(xy * xy, axis=1))[:, None]
        uv = self.principal_point_px + self.focal_length_px * xy_d
        with np.errstate(invalid="ignore"):
            on = front & (uv[:, 0] >= 0) & (uv[:, 0] < self.width_px) & (uv[:, 1] >= 0) & (uv[:, 1] < self.height_px)
        return uv, on

    def unproject(self, pixels) -> np.ndarray:
        """Unit directions ``(n, 3)`` in S of pixel positions ``(n, 2)`` (the inverse of
        :meth:`project`)."""
        uv = np.atleast_2d(np.asarray(pixels, dtype=float))
        xy_d = (uv - self.principal_point_px) / self.focal_length_px
        r_d = np.hypot(xy_d[:, 0], xy_d[:, 1])
        r = self._undistort_radius(r_d)
        scale = np.divide(r, r_d, out=np.ones_like(r), where=r_d > 0)
        d = np.column_stack([xy_d * scale[:, None], np.ones(len(uv))])
        return d / np.linalg.norm(d, axis=1)[:, None]

    def projection_jacobian(self, directions_S) -> np.ndarray:
        """``(n, 2, 3)``: ``d(u, v) / d(phi)`` for a direction rotated by a small rotation
        vector ``phi`` in S (``d -> d + phi x d``): pixels per radian. Its pseudo-inverse maps a
        centroid's pixel covariance to the direction's (rank 2: no information about rotation
        about the direction itself)."""
        d = np.atleast_2d(np.asarray(directions_S, dtype=float))
        xn, yn = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
        # d(xn, yn)/d(phi) for d -> d + phi x d (any length of d):
        #   [[-xn yn, 1 + xn^2, -yn], [-(1 + yn^2), xn yn, xn]]
        N = np.empty((len(d), 2, 3))
        N[:, 0, 0] = -xn * yn
        N[:, 0, 1] = 1.0 + xn * xn
        N[:, 0, 2] = -yn
        N[:, 1, 0] = -(1.0 + yn * yn)
        N[:, 1, 1] = xn * yn
        N[:, 1, 2] = xn
        f = self.focal_length_px
        if self.k1 == 0.0 and self.k2 == 0.0:
            return f * N
        r2 = xn * xn + yn * yn
        g = self._distortion_factor(r2)
        dg = 2.0 * (self.k1 + 2.0 * self.k2 * r2)  # 2 dg/d(r^2)
        # d(x_d, y_d)/d(xn, yn) = g I + 2 dg/d(r^2) [xn, yn][xn, yn]^T
        a_xx, a_xy, a_yy = g + dg * xn * xn, dg * xn * yn, g + dg * yn * yn
        J = np.empty_like(N)
        J[:, 0, :] = a_xx[:, None] * N[:, 0, :] + a_xy[:, None] * N[:, 1, :]
        J[:, 1, :] = a_xy[:, None] * N[:, 0, :] + a_yy[:, None] * N[:, 1, :]
        return f * J


__all__ = [
    "PinholeCamera",
    "FOCAL_LENGTH_RANGE_M",
    "PIXEL_PITCH_RANGE_M",
    "DETECTOR_SIZE_RANGE_PX",
    "MAX_DIAGONAL_FOV_DEG",
    "DISTORTION_FACTOR_RANGE",
]
