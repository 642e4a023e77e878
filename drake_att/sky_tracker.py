"""A sky star tracker's frame, from the truth to a quaternion with its covariance (plain numpy).

One frame (:meth:`SkyTrackerModel.frame`):

1. the stars in the field: the catalogue (cut at ``render_magnitude_limit``) searched in the cone
   of the detector's half diagonal around the boresight (:class:`~drake_att.sky.SkyIndex`), put
   through the camera (:class:`~drake_att.star_camera.PinholeCamera`);
2. the image in a window around each star and its centroids (:mod:`drake_att.star_image`): photon
   counts from the magnitude, aperture and exposure, smear from the sensor rate, shot, read and
   dark noise, hot pixels, background;
3. identification (:mod:`drake_att.star_identification`). With a memory of the last solutions,
   **tracking**: the attitude is extrapolated at the rate between them, and only the windows of
   the ``max_stars`` brightest catalogue stars predicted on the detector are read out (a star
   whose true image centre is more than ``window_half_size_px - 1`` from its predicted one falls
   outside its window and is not seen; other stars that stray into a window are not rendered).
   Without a memory, or when tracking fails, **lost-in-space** on every star in the field in the
   same frame (the windows of all stars in view: a full frame's stars). A frame whose
   identification is not confirmed is invalid, with its reason;
4. the attitude of all identified stars and its covariance from their geometry and centroid
   covariances (:mod:`drake_att.star_attitude`).

The frame also counts, from the truth it was rendered from, the stars identified as the wrong
catalogue star (``stars_misidentified``): a diagnostic, never used by the solution.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.sky import SkyIndex, StarCatalog
from drake_att.star_attitude import camera_parameters
from drake_att.star_camera import PinholeCamera
from drake_att.star_identification import StarIdentifier
from drake_att.star_image import DetectorModel, HotPixelMap, pixel_velocity, simulate_frame
from drake_att.star_image_kernels import tracked_windows_kernel
from drake_att.validation import check_positive, fail

#: The ``frame_status`` layout.
FRAME_STATUS_NAMES = (
    "t_frame",
    "valid",
    "mode",
    "stars_rendered",
    "stars_detected",
    "stars_identified",
    "stars_misidentified",
    "reason",
    "smear_px",
)
#: ``mode``: how the frame was identified.
MODE_NONE, MODE_LOST_IN_SPACE, MODE_TRACKING = 0, 1, 2
#: ``reason`` of an invalid frame (0: a valid frame).
REASONS = (
    "ok",
    "not_taken",  # a drop-out, an outage or an exclusion cone
    "too_few_stars",
    "no_match",
    "low_probability",
    "residual",
)
REASON_CODE = {name: i for i, name in enumerate(REASONS)}
_INVALID_COVARIANCE = np.eye(3)


@dataclass(frozen=True)
class FrameResult:
    """One frame's output.

    Attributes:
        time_s: mid-exposure time (s). valid: a confirmed solution.
        q_IS_meas: the sensor attitude (wxyz; the identity when invalid).
        covariance_S: (3, 3) its rotation-vector covariance in S (rad^2; the identity when invalid).
        mode, reason: :data:`MODE_NONE` / ... and an index into :data:`REASONS`.
        stars_rendered: the stars in the frame's windows (lost-in-space: every star on the
            detector; tracking: the stars in the windows read out).
        stars_detected: those detected, not saturated and with a centroid sigma at most
            ``max_centroid_sigma_px`` (the others are not used). stars_identified, stars_misidentified: counts.
        smear_px: the largest star track length over the exposure (pixels).
        directions_S, references_I: (m, 3) each identified star's measured unit direction in S
            (its centroid unprojected) and its catalogue direction at the epoch in I ((0, 3)
            when invalid, or when the frame was not asked for them): the frame as vector
            observations.
        vector_sigma_rad: the identified directions' RMS 1-sigma per tangent axis (rad): the
            square root of the mean over the stars of half the trace of each direction's
            covariance (the centroid's, through the inverse projection Jacobian). One number per
            frame, as vector-observation estimators take it: brighter stars are better than it,
            fainter ones worse.
    """

    time_s: float
    valid: bool
    q_IS_meas: np.ndarray
    covariance_S: np.ndarray
    mode: int = MODE_NONE
    reason: int = 0
    stars_rendered: int = 0
    stars_detected: int = 0
    stars_identified: int = 0
    stars_misidentified: int = 0
    smear_px: float = 0.0
    directions_S: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    references_I: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    vector_sigma_rad: float = 0.0

    @classmethod
    def not_taken(cls, time_s: float) -> FrameResult:
        return cls(time_s, False, rot.quat_identity(), _INVALID_COVARIANCE, reason=REASON_CODE["not_taken"])

    def status_vector(self) -> np.ndarray:
        return np.array(
            [
                self.time_s,
                1.0 if self.valid else 0.0,
                self.mode,
                self.stars_rendered,
                self.stars_detected,
                self.stars_identified,
                self.stars_misidentified,
                self.reason,
                self.smear_px,
            ],
            dtype=float,
        )


@dataclass(frozen=True)
class TrackingMemory:
    """The tracker's last two confirmed solutions ``(t, q_IS)``; ``t`` NaN: none.

    :meth:`prior` extrapolates the last one at the constant rate between the two (sensor frame),
    which is what a tracker without a gyro can predict from.
    """

    t_last: float
    q_last: np.ndarray
    t_before: float
    q_before: np.ndarray

    SIZE = 10

    @classmethod
    def empty(cls) -> TrackingMemory:
        return cls(math.nan, rot.quat_identity(), math.nan, rot.quat_identity())

    def to_vector(self) -> np.ndarray:
        return np.concatenate([[self.t_last], self.q_last, [self.t_before], self.q_before])

    @classmethod
    def from_vector(cls, v) -> TrackingMemory:
        v = np.asarray(v, dtype=float)
        return cls(float(v[0]), v[1:5].copy(), float(v[5]), v[6:10].copy())

    def after(self, frame: FrameResult) -> TrackingMemory:
        """The memory once ``frame`` is taken: its solution pushed in if valid, else unchanged."""
        if not frame.valid:
            return self
        return TrackingMemory(frame.time_s, np.asarray(frame.q_IS_meas, dtype=float), self.t_last, self.q_last)

    def prior(self, t: float, max_age_s: float) -> tuple[np.ndarray, float] | None:
        """``(q_IS predicted at t, seconds since the last solution)``, or None when the last
        solution is older than ``max_age_s`` (or there is none). With two solutions less than
        ``max_age_s`` apart the prediction carries on at their rate; with one, it holds it."""
        if not (math.isfinite(self.t_last) and 0.0 <= t - self.t_last <= max_age_s):
            return None
        q = self.q_last
        gap = self.t_last - self.t_before
        if math.isfinite(self.t_before) and 0.0 < gap <= max_age_s:
            w_S = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(self.q_before), self.q_last)) / gap
            q = rot.quat_multiply(q, rot.rotvec_to_quat(w_S * (t - self.t_last)))
        return q, t - self.t_last


#: A neighbour at least this much fainter (mag, 10% of the flux) does not make a star double.
DOUBLE_STAR_MAGNITUDE_GAP = 2.5


def without_close_pairs(catalog: StarCatalog, neighbours: StarCatalog, separation_rad: float, gap_mag: float):
    """``catalog`` without its stars that have a star of ``neighbours`` (other than themselves)
    within ``separation_rad`` and less than ``gap_mag`` fainter: the double-star cut of a
    tracker's catalogue."""
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    if not separation_rad > 0:
        return catalog
    chord = 2.0 * math.sin(0.5 * separation_rad)
    close = cKDTree(neighbours.unit_I).query_ball_point(catalog.unit_I, chord)
    keep = np.ones(len(catalog), dtype=bool)
    for i, js in enumerate(close):
        for j in js:
            if neighbours.hip[j] != catalog.hip[i] and neighbours.magnitude[j] < catalog.magnitude[i] + gap_mag:
                keep[i] = False
                break
    return StarCatalog(
        catalog.hip[keep],
        catalog.unit_I[keep],
        catalog.pm_rad_per_year[keep],
        catalog.magnitude[keep],
        catalog.b_minus_v[keep],
        catalog.epoch_jyear,
    )


@dataclass(frozen=True)
class IdentificationSettings:
    """How a sky tracker identifies its frames.

    Attributes:
        magnitude_limit: the identification catalogue's limit (Hp, mag); fainter stars are
            rendered (down to ``render_magnitude_limit``) but never matched.
        render_magnitude_limit: the faintest stars put in the image (Hp, mag; >= the limit).
        tracking: track from the last solutions (False: every frame lost-in-space).
        max_track_age_s: the memory is used only this long after its last solution (s).
        prior_sigma_rad: the tracking prior's 1-sigma per axis at zero age (rad).
        prior_acceleration_rad_per_s2: the largest angular acceleration the extrapolation must
            cover: the prior's sigma grows by ``a age^2 / 2`` (rad/s^2).
        min_stars, max_false_probability, residual_p_value, gate_sigmas: the identifier's
            (:class:`~drake_att.star_identification.StarIdentifier`).
        max_stars: the windows a tracking frame reads out: the brightest catalogue stars
            predicted on the detector (>= ``min_stars``).
        max_centroid_sigma_px: centroids whose largest 1-sigma exceeds this (px) are not used.
        double_star_separation_px: a star with a rendered neighbour this close (px at the
            boresight) that is less than :data:`DOUBLE_STAR_MAGNITUDE_GAP` fainter is left out of
            the identification catalogue (its image is a blend no centroid separates).
    """

    magnitude_limit: float = 6.5
    render_magnitude_limit: float = 7.0
    tracking: bool = True
    max_track_age_s: float = 1.0
    prior_sigma_rad: float = math.radians(60.0 / 3600.0)
    prior_acceleration_rad_per_s2: float = math.radians(1.0)
    min_stars: int = 4
    max_false_probability: float = 1e-9
    residual_p_value: float = 1e-6
    gate_sigmas: float = 5.0
    max_stars: int = 16
    max_centroid_sigma_px: float = 0.5
    double_star_separation_px: float = 3.0


class SkyTrackerModel:
    """A sky tracker's frame pipeline (module docstring): camera, detector, the catalogue at
    its epoch and the identification settings; :meth:`frame` is a pure function of its
    arguments.

    Args:
        camera, detector: the optics and the detector.
        catalog: the sky at the frame epoch (:meth:`~drake_att.sky.StarCatalog.at_epoch`).
        settings: :class:`IdentificationSettings`.
        hot_pixels: the sensor's hot-pixel map (None: none).
        name: the tracker's name (for messages: ``<name>.magnitude_limit``...).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        detector: DetectorModel,
        catalog: StarCatalog,
        settings: IdentificationSettings = IdentificationSettings(),
        hot_pixels: HotPixelMap | None = None,
        name: str = "st1",
    ):
        if settings.render_magnitude_limit < settings.magnitude_limit:
            fail(
                f"{name}.render_magnitude_limit",
                settings.render_magnitude_limit,
                f"must be at or above magnitude_limit ({settings.magnitude_limit:g}): identified stars are rendered",
            )
        check_positive(f"{name}.max_track_age_s", settings.max_track_age_s)
        check_positive(f"{name}.prior_sigma_rad", settings.prior_sigma_rad)
        self.camera, self.detector, self.settings, self.hot_pixels = camera, detector, settings, hot_pixels
        self.render_catalog = catalog.brighter_than(settings.render_magnitude_limit, f"{name}.render_magnitude_limit")
        identification = without_close_pairs(
            catalog.brighter_than(settings.magnitude_limit, f"{name}.magnitude_limit"),
            self.render_catalog,
            settings.double_star_separation_px * camera.pixel_pitch_m / camera.focal_length_m,
            DOUBLE_STAR_MAGNITUDE_GAP,
        )
        self.sky = SkyIndex(self.render_catalog)
        self.electron_rate = detector.electron_rate_from_hipparcos(
            self.render_catalog.magnitude, self.render_catalog.b_minus_v
        )
        self.identifier = StarIdentifier(
            camera,
            identification,
            settings.min_stars,
            settings.max_false_probability,
            settings.residual_p_value,
            settings.gate_sigmas,
        )
        self._identified_hip = identification.hip
        self._search_half_angle = camera.half_diagonal_fov_rad
        if settings.max_stars < settings.min_stars:
            fail(f"{name}.max_stars", settings.max_stars, f"must be >= min_stars ({settings.min_stars})")
        self._identified_sky = SkyIndex(identification)
        # identification catalogue -> render catalogue (the first is a subset of the second)
        order = np.argsort(self.render_catalog.hip, kind="stable")
        at = np.searchsorted(self.render_catalog.hip, identification.hip, sorter=order)
        self._render_of_identified = order[at]
        self._camera_params = camera_parameters(camera)

    def visible_stars(self, q_IS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(indices into render_catalog, directions in S (n, 3), pixels (n, 2))`` of the
        stars on the detector at attitude ``q_IS``."""
        R_IS = rot.quat_to_rotmat(q_IS)
        index = self.sky.cone(R_IS[:, 2], self._search_half_angle)
        d_S = self.render_catalog.unit_I[index] @ R_IS
        uv, on = self.camera.project(d_S)
        return index[on], d_S[on], uv[on]

    def prior(self, t: float, memory: TrackingMemory) -> tuple[np.ndarray, float] | None:
        """``(q_IS, sigma (rad))`` the frame at ``t`` is tracked from, or None (lost-in-space)."""
        s = self.settings
        if not s.tracking:
            return None
        p = memory.prior(t, s.max_track_age_s)
        if p is None:
            return None
        q, age = p
        sigma = s.prior_sigma_rad + 0.5 * s.prior_acceleration_rad_per_s2 * age * age
        return q, min(sigma, 0.2)

    def tracked_windows(self, q_IS_prior, R_IS_true) -> tuple[np.ndarray, np.ndarray]:
        """``(render-catalogue indices, true pixels)`` of the stars seen in a tracking frame's
        windows: the ``max_stars`` brightest identification-catalogue stars predicted (from the
        prior) with their whole window on the detector, kept where the true image centre lies
        within ``window_half_size_px - 1`` of the prediction (module docstring)."""
        cam, h = self.camera, self.detector.window_half_size_px
        R_prior = rot.quat_to_rotmat(q_IS_prior)
        cone = self._identified_sky.cone(R_prior[:, 2], self._search_half_angle)
        index = np.empty(self.settings.max_stars, dtype=np.int64)
        uv = np.empty((self.settings.max_stars, 2))
        n = tracked_windows_kernel(
            self._camera_params,
            float(cam.width_px),
            float(cam.height_px),
            float(h),
            self._identified_sky.catalog.unit_I,
            self._identified_sky.catalog.magnitude,
            cone,
            R_prior,
            self.settings.max_stars,
            self._render_of_identified,
            self.render_catalog.unit_I,
            np.ascontiguousarray(R_IS_true),
            index,
            uv,
        )
        return index[:n], uv[:n]

    def _centroids(self, index, uv, R_IS, w_IS_S, rng, detector: DetectorModel):
        d_S = self.render_catalog.unit_I[index] @ R_IS
        rate = pixel_velocity(self.camera, d_S, w_IS_S)
        track_px = np.linalg.norm(rate, axis=1) * detector.exposure_s
        smear = float(np.max(track_px)) if len(track_px) else 0.0
        centroids = simulate_frame(self.camera, detector, uv, rate, self.electron_rate[index], rng, self.hot_pixels)
        # brightest first; a saturated star's centroid is biased beyond its covariance, and a
        # centroid too uncertain to tell a star from its neighbours (a faint, smeared streak) is
        # a liability to identification: neither is used
        C = centroids.covariance_px2
        a, b, d = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
        largest = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b * b)
        usable = np.flatnonzero(~centroids.saturated & (largest <= self.settings.max_centroid_sigma_px**2))
        order = usable[np.argsort(-centroids.signal_e[usable], kind="stable")]
        return centroids, order, smear

    def frame(
        self,
        t: float,
        q_IS,
        w_IS_S,
        memory: TrackingMemory,
        rng: np.random.Generator,
        stray_light_e_per_px_per_s: float = 0.0,
        vectors: bool = False,
    ) -> FrameResult:
        """The frame exposed around ``t`` (s) at the true attitude ``q_IS`` turning at ``w_IS_S``
        (rad/s, in S), tracked from ``memory``, with this frame's noise ``rng`` and stray light
        added to the detector's background (e-/s per pixel); a valid frame carries its
        identified stars as vector observations when ``vectors`` (else none: they cost ~10% of
        a tracking frame)."""
        R_IS = rot.quat_to_rotmat(q_IS)
        detector = self.detector
        if stray_light_e_per_px_per_s > 0.0:
            background = detector.background_e_per_px_per_s + stray_light_e_per_px_per_s
            detector = dataclasses.replace(detector, background_e_per_px_per_s=background)
        prior = self.prior(t, memory)
        ident = None
        if prior is not None:
            index, uv = self.tracked_windows(prior[0], R_IS)
            centroids, order, smear = self._centroids(index, uv, R_IS, w_IS_S, rng, detector)
            ident = self.identifier.track(centroids.uv_px[order], centroids.covariance_px2[order], *prior)
        if ident is None or not ident.valid:
            index, _, uv = self.visible_stars(q_IS)
            centroids, order, smear = self._centroids(index, uv, R_IS, w_IS_S, rng, detector)
            ident = self.identifier.lost_in_space(centroids.uv_px[order], centroids.covariance_px2[order])
        counts = dict(stars_rendered=len(index), stars_detected=len(order), smear_px=smear)
        mode = MODE_TRACKING if ident.mode == "tracking" else MODE_LOST_IN_SPACE
        if not ident.valid or ident.attitude is None:
            return FrameResult(
                t, False, rot.quat_identity(), _INVALID_COVARIANCE, mode, REASON_CODE[ident.reason], **counts
            )
        used = order[ident.centroid_index]
        source = index[centroids.star_index[used]]
        wrong = int(np.count_nonzero(self.render_catalog.hip[source] != self._identified_hip[ident.catalog_index]))
        stars = self._vector_observations(centroids, used, ident.catalog_index) if vectors else {}
        return FrameResult(
            t,
            True,
            rot.quat_canonical(ident.attitude.q_IS),
            ident.attitude.covariance_S,
            mode,
            0,
            stars_identified=len(ident.catalog_index),
            stars_misidentified=wrong,
            **counts,
            **stars,
        )

    def _vector_observations(self, centroids, used, catalog_index) -> dict:
        """The identified stars as FrameResult's vector fields (its docstring)."""
        directions_S = self.camera.unproject(centroids.uv_px[used])
        # half the trace of each direction's covariance pinv(J) C pinv(J)^T (J: the 2x3 projection
        # Jacobian, full row rank, pinv(J) = J^T (J J^T)^-1): trace(C (J J^T)^-1), in closed form
        J = self.camera.projection_jacobian(directions_S)
        G = np.einsum("nik,njk->nij", J, J)
        C = centroids.covariance_px2[used]
        trace = (C[:, 0, 0] * G[:, 1, 1] - 2.0 * C[:, 0, 1] * G[:, 0, 1] + C[:, 1, 1] * G[:, 0, 0]) / (
            G[:, 0, 0] * G[:, 1, 1] - G[:, 0, 1] ** 2
        )
        return dict(
            directions_S=directions_S,
            references_I=self._identified_sky.catalog.unit_I[catalog_index],
            vector_sigma_rad=float(np.sqrt(np.mean(0.5 * trace))),
        )


__all__ = [
    "DOUBLE_STAR_MAGNITUDE_GAP",
    "without_close_pairs",
    "IdentificationSettings",
    "SkyTrackerModel",
    "FRAME_STATUS_NAMES",
    "MODE_NONE",
    "MODE_LOST_IN_SPACE",
    "MODE_TRACKING",
    "REASONS",
    "REASON_CODE",
    "FrameResult",
    "TrackingMemory",
]
