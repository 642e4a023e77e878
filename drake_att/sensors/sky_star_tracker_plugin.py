"""Sensor plug-in: the star tracker that sees the sky
(:class:`drake_att.systems.sky_star_tracker.SkyStarTracker`).

YAML tag ``!SkyStarTrackerConfig``. Output: "quaternion" samples ``[t, valid, q_IS_meas]`` like
``!StarTrackerConfig`` — so it replaces the Gaussian tracker in any scenario, faults, averages and
monitors included — plus each frame's covariance (``covariance_S``) and what the frame saw and did
(``frame_status``, logged). An estimator uses either each frame's covariance
(``filter_covariance: per_frame``) or the tracker's nominal covariance (``nominal``: the mean
covariance of 200 frames at random attitudes turning at ``nominal_rate_deg_per_s``, what a
datasheet states; also what a star-tracker average and a sensor monitor assume). With
``mode: vectors`` its output is the frame's identified stars as
:class:`~drake_att.contract.VectorObservations` (directions, catalogue references, the frame's RMS
sigma) instead, for the vector-observation estimators.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import ClassVar, Optional, Union

import numpy as np

from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.sensors.star_tracker_plugin import (
    MODES,
    ExclusionConfig,
    PaperS3Eq7Mounting,
    RpyMounting,
    exclusion_cones,
    star_tracker_mounting,
    validate_availability,
    validate_exclusion,
)
from drake_att.star_image import DetectorModel
from drake_att.systems.estimator_system import QuaternionSensorModel
from drake_att.units import ARCSEC, DEG

#: The detector model's defaults: the config's, from their one home.
_DETECTOR = DetectorModel()

FILTER_COVARIANCES = ("per_frame", "nominal")
#: The catalogue's epoch when the scenario has no orbit epoch and the config gives none (Julian year).
DEFAULT_EPOCH_JYEAR = 2026.0
#: Frames (random attitudes) whose mean covariance is the nominal covariance.
NOMINAL_FRAMES = 200


@dataclass
class SkyCameraConfig:
    """The optics' geometry: a pinhole with optional radial distortion
    (:class:`drake_att.star_camera.PinholeCamera`; boresight +z of the sensor)."""

    focal_length_mm: float = 16.0
    pixel_pitch_um: float = 5.5
    width_px: int = 1024
    height_px: int = 1024
    distortion_k1: float = 0.0
    distortion_k2: float = 0.0

    RANGES: ClassVar[dict] = {
        "focal_length_mm": (1.0, 1000.0, "mm", "a star camera's focal length (also checked: field of view <= 90 deg)"),
        "pixel_pitch_um": (1.0, 50.0, "um", "a detector's pixel size"),
        "width_px": (16, 16384, "px", "detector columns"),
        "height_px": (16, 16384, "px", "detector rows"),
        "distortion_k1": (-10.0, 10.0, "", "radial distortion (also checked: factor in [0.8, 1.2], monotonic)"),
        "distortion_k2": (-100.0, 100.0, "", "radial distortion (also checked: factor in [0.8, 1.2], monotonic)"),
    }


@dataclass
class SkyDetectorConfig:
    """The detector and its photometry (:class:`drake_att.star_image.DetectorModel`, whose
    docstring gives the defaults' sources; SI units as named). ``hot_pixel_seed``: the seed of the
    sensor's hot-pixel map (a property of the unit, the same in every run)."""

    aperture_diameter_m: float = _DETECTOR.aperture_diameter_m
    exposure_s: float = _DETECTOR.exposure_s
    optical_efficiency: float = _DETECTOR.optical_efficiency
    read_noise_e: float = _DETECTOR.read_noise_e
    dark_current_e_per_s: float = _DETECTOR.dark_current_e_per_s
    full_well_e: float = _DETECTOR.full_well_e
    gain_e_per_adu: float = _DETECTOR.gain_e_per_adu
    adc_bits: int = _DETECTOR.adc_bits
    black_level_adu: float = _DETECTOR.black_level_adu
    psf_sigma_px: float = _DETECTOR.psf_sigma_px
    background_e_per_px_per_s: float = _DETECTOR.background_e_per_px_per_s
    hot_pixel_fraction: float = _DETECTOR.hot_pixel_fraction
    hot_pixel_dark_e_per_s: float = _DETECTOR.hot_pixel_dark_e_per_s
    window_half_size_px: int = _DETECTOR.window_half_size_px
    detection_threshold_sigma: float = _DETECTOR.detection_threshold_sigma
    zero_point_photons_per_m2_s: float = 0.0  # 0: the detector model's default
    hot_pixel_seed: int = 1

    #: :class:`~drake_att.star_image.DetectorModel`'s ranges (open lower bounds are checked
    #: by the model), a zero point of 0 for the model's default, and the map's seed.
    RANGES: ClassVar[dict] = {
        **{key: (lo, hi, unit, what) for key, (lo, hi, unit, _, what) in DetectorModel.RANGES.items()},
        **DetectorModel.INT_RANGES,
        "zero_point_photons_per_m2_s": (
            0.0,
            DetectorModel.RANGES["zero_point_photons_per_m2_s"][1],
            "photons/s/m^2",
            "a V = 0 star's flux in the band (0: the default; else >= "
            f"{DetectorModel.RANGES['zero_point_photons_per_m2_s'][0]:g})",
        ),
        "hot_pixel_seed": (0, 2**32 - 1, "", "the hot-pixel map's seed"),
    }


@dataclass
class SkyIdentificationConfig:
    """Identification (:class:`drake_att.sky_tracker.IdentificationSettings`): lost-in-space with
    tetra3rs, tracking from the tracker's own last solutions, every frame confirmed by its
    residuals."""

    magnitude_limit: float = 6.5
    render_magnitude_limit: float = 7.0
    tracking: bool = True
    max_track_age_s: float = 1.0
    prior_sigma_arcsec: float = 60.0
    prior_acceleration_deg_per_s2: float = 1.0
    min_stars: int = 4
    max_false_probability: float = 1e-9
    residual_p_value: float = 1e-6
    gate_sigmas: float = 5.0
    max_stars: int = 16
    max_centroid_sigma_px: float = 0.5
    double_star_separation_px: float = 3.0

    RANGES: ClassVar[dict] = {
        "magnitude_limit": (-2.0, 12.0, "mag", "Hp; the catalogue holds stars to about 12"),
        "render_magnitude_limit": (-2.0, 12.0, "mag", "Hp; at or above magnitude_limit"),
        "max_track_age_s": (0.0, 3600.0, "s", "how old a solution tracking may start from"),
        "prior_sigma_arcsec": (0.0, 3600.0, "arcsec", "the tracking prior's sigma"),
        "prior_acceleration_deg_per_s2": (0.0, 100.0, "deg/s^2", "the acceleration tracking covers"),
        "min_stars": (3, 100, "", "stars a valid frame needs"),
        "max_false_probability": (0.0, 1.0, "", "tetra3rs's false-match probability accepted"),
        "residual_p_value": (0.0, 0.5, "", "the residual tests' false-rejection probability"),
        "gate_sigmas": (1.0, 20.0, "sigma", "the tracking gate"),
        "max_stars": (3, 1000, "", "windows a tracking frame reads out (also checked: >= min_stars)"),
        "max_centroid_sigma_px": (0.0, 100.0, "px", "the largest centroid sigma used"),
        "double_star_separation_px": (0.0, 100.0, "px", "the double-star cut of the identification catalogue"),
    }


@dataclass
class SkyStarTrackerConfig:
    """A star tracker whose frames are rendered from the Hipparcos catalogue, centroided,
    identified and solved (boresight = sensor +z; ``mounting`` as ``!StarTrackerConfig``'s).

    ``mode``: what estimators take, ``quaternion`` (the frame's attitude and covariance) or
    ``vectors`` (its identified stars' directions, catalogue references and RMS sigma:
    :class:`~drake_att.contract.VectorObservations`, for the vector-observation estimators).

    ``epoch_jyear``: the sky's epoch (proper motion; Julian year; null: the orbit's epoch, or
    2026.0 without one). ``filter_covariance``: what estimators use, ``per_frame`` (each frame's
    own covariance) or ``nominal`` (module docstring), computed from frames turning at
    ``nominal_rate_deg_per_s`` (the rate a datasheet states its accuracy at; smear grows it).
    ``exclusion``: Sun / Earth-limb / Moon cones (a frame inside one is not taken); outside them
    stray light adds ``stray_light_e_per_px_per_s`` (ours: ~60x the dark sky's background) times
    ``(cone / angle)^3`` per body to the background (:func:`drake_att.exclusion.stray_light_factor`).
    """

    name: str = "st1"
    period_s: float = 0.1
    mode: str = "quaternion"
    mounting: Union[RpyMounting, PaperS3Eq7Mounting] = field(default_factory=RpyMounting)
    camera: SkyCameraConfig = field(default_factory=SkyCameraConfig)
    detector: SkyDetectorConfig = field(default_factory=SkyDetectorConfig)
    identification: SkyIdentificationConfig = field(default_factory=SkyIdentificationConfig)
    epoch_jyear: Optional[float] = None
    filter_covariance: str = "per_frame"
    nominal_rate_deg_per_s: float = 0.0
    dropout_probability: float = 0.0
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (k, 2) [start, end]
    exclusion: Optional[ExclusionConfig] = None
    stray_light_e_per_px_per_s: float = 1000.0

    RANGES: ClassVar[dict] = {
        "stray_light_e_per_px_per_s": (0.0, 1e9, "e-/s", "stray light per pixel at an exclusion cone's edge"),
        "epoch_jyear": (1900.0, 2200.0, "yr", "a Julian year"),
        "nominal_rate_deg_per_s": (0.0, 100.0, "deg/s", "the rate the nominal covariance is stated at"),
    }


# -- the model ------------------------------------------------------------------------------
def sky_epoch_jyear(c: SkyStarTrackerConfig, scenario) -> float:
    """The sky's epoch: the config's, else the orbit's epoch, else :data:`DEFAULT_EPOCH_JYEAR`."""
    if c.epoch_jyear is not None:
        return float(c.epoch_jyear)
    epoch = getattr(scenario.orbit, "epoch_utc", "") if scenario is not None else ""
    if epoch:
        from drake_att.orbit_propagators import julian_date_utc, parse_epoch_utc

        return 2000.0 + (julian_date_utc(parse_epoch_utc(epoch)) - 2451545.0) / 365.25
    return DEFAULT_EPOCH_JYEAR


def _camera(path: str, c: SkyCameraConfig):
    from drake_att.star_camera import PinholeCamera

    return PinholeCamera.make(
        c.focal_length_mm * 1e-3,
        c.pixel_pitch_um * 1e-6,
        c.width_px,
        c.height_px,
        c.distortion_k1,
        c.distortion_k2,
        name=path,
    )


def _detector(path: str, c: SkyDetectorConfig):
    from drake_att.star_image import DetectorModel

    fields = {f.name: getattr(c, f.name) for f in dataclasses.fields(c) if f.name != "hot_pixel_seed"}
    if fields["zero_point_photons_per_m2_s"] == 0.0:
        del fields["zero_point_photons_per_m2_s"]
    return DetectorModel.make(name=path, **fields)


def _settings(c: SkyIdentificationConfig):
    from drake_att.sky_tracker import IdentificationSettings

    return IdentificationSettings(
        magnitude_limit=float(c.magnitude_limit),
        render_magnitude_limit=float(c.render_magnitude_limit),
        tracking=bool(c.tracking),
        max_track_age_s=float(c.max_track_age_s),
        prior_sigma_rad=float(c.prior_sigma_arcsec) * ARCSEC,
        prior_acceleration_rad_per_s2=float(c.prior_acceleration_deg_per_s2) * DEG,
        min_stars=int(c.min_stars),
        max_false_probability=float(c.max_false_probability),
        residual_p_value=float(c.residual_p_value),
        gate_sigmas=float(c.gate_sigmas),
        max_stars=int(c.max_stars),
        max_centroid_sigma_px=float(c.max_centroid_sigma_px),
        double_star_separation_px=float(c.double_star_separation_px),
    )


@functools.lru_cache(maxsize=1)
def _hipparcos():
    from drake_att.sky import load_hipparcos

    return load_hipparcos()


def _key(c: SkyStarTrackerConfig, epoch: float) -> tuple:
    return (
        repr(dataclasses.astuple(c.camera)),
        repr(dataclasses.astuple(c.detector)),
        repr(dataclasses.astuple(c.identification)),
        epoch,
        c.name,
    )


_MODELS: dict = {}


def sky_tracker_model(c: SkyStarTrackerConfig, epoch_jyear: float, path: str | None = None):
    """The :class:`~drake_att.sky_tracker.SkyTrackerModel` of a config (memoized per process: a
    Monte Carlo's runs share it)."""
    key = _key(c, epoch_jyear)
    model = _MODELS.get(key)
    if model is None:
        from drake_att.sky_tracker import SkyTrackerModel
        from drake_att.star_image import draw_hot_pixels

        path = path or c.name
        camera = _camera(f"{path}.camera", c.camera)
        detector = _detector(f"{path}.detector", c.detector)
        hot = draw_hot_pixels(detector, camera, int(c.detector.hot_pixel_seed))
        catalog = _hipparcos().at_epoch(epoch_jyear)
        model = SkyTrackerModel(camera, detector, catalog, _settings(c.identification), hot, f"{path}.identification")
        if len(_MODELS) > 8:
            _MODELS.clear()
        _MODELS[key] = model
    return model


_NOMINAL: dict = {}


def nominal_covariance_S(c: SkyStarTrackerConfig, epoch_jyear: float) -> np.ndarray:
    """The tracker's nominal covariance (rad^2, S): the mean of the covariances of
    :data:`NOMINAL_FRAMES` valid frames at random attitudes (seed 0), each turning at
    ``nominal_rate_deg_per_s`` about a random axis, tracked from the true attitude — the mean
    squared error a datasheet states (the inverse of the mean information would be the good
    frames' figure: optimistic for the sparse fields)."""
    key = (*_key(c, epoch_jyear), float(c.nominal_rate_deg_per_s))
    if key not in _NOMINAL:
        from drake_att import rotations as rot
        from drake_att.sky_tracker import TrackingMemory

        model = sky_tracker_model(c, epoch_jyear)
        rng = np.random.default_rng(0)
        total, n = np.zeros((3, 3)), 0
        for _ in range(NOMINAL_FRAMES):
            q = rot.quat_normalize(rng.standard_normal(4))
            axis = rng.standard_normal(3)
            w_S = c.nominal_rate_deg_per_s * DEG * axis / np.linalg.norm(axis)
            memory = TrackingMemory(0.0, q, math.nan, rot.quat_identity())
            frame = model.frame(0.0, q, w_S, memory, rng)
            if frame.valid:
                total += frame.covariance_S
                n += 1
        if n == 0:
            cfg.fail(f"{c.name}.identification", "no frame", "identifies no frame at random attitudes")
        _NOMINAL[key] = total / n
    return _NOMINAL[key]


# -- the plug-in --------------------------------------------------------------------------------
def validate_camera(path: str, c: SkyCameraConfig) -> None:
    """The camera in the config's own fields and units: focal length and pixel pitch in range,
    the diagonal field of view at most 90 deg, the distortion small and monotonic."""
    from drake_att.star_camera import MAX_DIAGONAL_FOV_DEG

    for name, (lo, hi, unit, _) in SkyCameraConfig.RANGES.items():
        v = cfg.check_finite(f"{path}.{name}", getattr(c, name))
        if not lo <= v <= hi:
            cfg.fail(f"{path}.{name}", v, f"must be in [{lo:g}, {hi:g}] {unit}".rstrip())
    for name in ("width_px", "height_px"):
        if int(getattr(c, name)) != getattr(c, name):
            cfg.fail(f"{path}.{name}", getattr(c, name), "must be a whole number of pixels")
    half_diagonal_mm = 0.5 * math.hypot(c.width_px, c.height_px) * c.pixel_pitch_um * 1e-3
    fov = 2.0 * math.degrees(math.atan(half_diagonal_mm / c.focal_length_mm))
    if fov > MAX_DIAGONAL_FOV_DEG:
        cfg.fail(
            f"{path}.focal_length_mm",
            c.focal_length_mm,
            f"gives a {fov:.1f} deg diagonal field of view with this detector; at most {MAX_DIAGONAL_FOV_DEG:g}",
        )
    try:
        _camera(path, c)
    except ValueError as e:  # the distortion (the rest is checked above)
        message = str(e).replace(f"{path}.k1, k2", f"{path}.distortion_k1, distortion_k2")
        raise cfg.ConfigError(message) from None


def validate_sky_star_tracker(path: str, c: SkyStarTrackerConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    validate_exclusion(path, c, checks.scenario)  # type: ignore[arg-type]  # the same fields
    if isinstance(c.mounting, PaperS3Eq7Mounting):
        cfg.check_vector(f"{path}.mounting.psi_phi_theta_deg", c.mounting.psi_phi_theta_deg, 3)
    else:
        cfg.check_vector(f"{path}.mounting.rpy_deg", c.mounting.rpy_deg, 3)
    validate_availability(path, c)
    if c.mode not in MODES:
        cfg.fail(f"{path}.mode", c.mode, f"allowed: {list(MODES)}")
    if c.filter_covariance not in FILTER_COVARIANCES:
        cfg.fail(f"{path}.filter_covariance", c.filter_covariance, f"allowed: {list(FILTER_COVARIANCES)}")
    if c.epoch_jyear is not None:
        cfg.check_finite(f"{path}.epoch_jyear", c.epoch_jyear)
    cfg.check_nonnegative(f"{path}.nominal_rate_deg_per_s", c.nominal_rate_deg_per_s)
    cfg.check_nonnegative(f"{path}.stray_light_e_per_px_per_s", c.stray_light_e_per_px_per_s)
    validate_camera(f"{path}.camera", c.camera)
    try:
        _detector(f"{path}.detector", c.detector)
    except ValueError as e:
        raise cfg.ConfigError(str(e)) from None
    if c.detector.exposure_s > c.period_s:
        cfg.fail(f"{path}.detector.exposure_s", c.detector.exposure_s, f"must be <= period_s ({c.period_s:g} s)")
    i = c.identification
    if i.render_magnitude_limit < i.magnitude_limit:
        cfg.fail(
            f"{path}.identification.render_magnitude_limit",
            i.render_magnitude_limit,
            f"must be at or above magnitude_limit ({i.magnitude_limit:g}): identified stars are rendered",
        )
    if i.max_stars < i.min_stars:
        cfg.fail(f"{path}.identification.max_stars", i.max_stars, f"must be >= min_stars ({i.min_stars})")
    try:
        brightest = float(np.min(_hipparcos().magnitude))
    except ValueError as e:  # the catalogue failed to load: its one-line reason, under this path
        raise cfg.ConfigError(f"{path}: {e}") from None
    if i.magnitude_limit < brightest:
        cfg.fail(
            f"{path}.identification.magnitude_limit",
            i.magnitude_limit,
            f"leaves no star (the brightest is {brightest:.2f} mag)",
        )


def sky_star_tracker_output(c: SkyStarTrackerConfig, sensor_configs) -> SensorOutput:
    if c.mode == "vectors":
        return SensorOutput("vectors", "vector_observations", c.period_s)
    return SensorOutput("quaternion", "star_tracker_measurement", c.period_s)


def sky_star_tracker_quaternion_model(ctx, c: SkyStarTrackerConfig) -> QuaternionSensorModel:
    epoch = sky_epoch_jyear(c, ctx.scenario)
    return QuaternionSensorModel(
        c.name,
        star_tracker_mounting(c),  # type: ignore[arg-type]  # the same mounting fields
        nominal_covariance_S(c, epoch),
        sample_covariance=c.filter_covariance == "per_frame",
    )


def sky_star_tracker_logged_ports(c: SkyStarTrackerConfig):
    ports = [("star_tracker_measurement", c.period_s), ("covariance_S", c.period_s), ("frame_status", c.period_s)]
    return ports + ([("exclusion", c.period_s)] if c.exclusion is not None else [])


def configure_sky_star_tracker(ctx, c: SkyStarTrackerConfig, system, context) -> None:
    system.set_availability(context, c.dropout_probability, [tuple(w) for w in np.reshape(c.outage_windows_s, (-1, 2))])


@register_sensor(
    SkyStarTrackerConfig,
    output=sky_star_tracker_output,
    validate=validate_sky_star_tracker,
    quaternion_model=sky_star_tracker_quaternion_model,
    logged_ports=sky_star_tracker_logged_ports,
    parameters=("dropout_probability", "outage_windows_s"),
    configure=configure_sky_star_tracker,
)
def build_sky_star_tracker(ctx, c: SkyStarTrackerConfig):
    from drake_att.systems.sky_star_tracker import SkyStarTracker

    model = sky_tracker_model(c, sky_epoch_jyear(c, ctx.scenario))
    st = ctx.builder.AddSystem(
        SkyStarTracker(
            c.name,
            c.period_s,
            star_tracker_mounting(c),  # type: ignore[arg-type]  # the same mounting fields
            model,
            c.dropout_probability,
            [tuple(w) for w in np.reshape(c.outage_windows_s, (-1, 2))],
            exclusion_cones(c),  # type: ignore[arg-type]  # the same exclusion field
            c.stray_light_e_per_px_per_s,
            vector_observations=c.mode == "vectors",
        )
    )
    ctx.builder.Connect(ctx.truth.GetOutputPort("q_IB"), st.GetInputPort("q_IB"))
    ctx.builder.Connect(ctx.truth.GetOutputPort("w_IB_B"), st.GetInputPort("w_IB_B"))
    if c.exclusion is not None:
        orbit, sun_moon = ctx.environment()
        ctx.builder.Connect(orbit.GetOutputPort("r_I"), st.GetInputPort("r_I"))
        ctx.builder.Connect(sun_moon.GetOutputPort("r_sun_I"), st.GetInputPort("r_sun_I"))
        ctx.builder.Connect(sun_moon.GetOutputPort("r_moon_I"), st.GetInputPort("r_moon_I"))
    return st


__all__ = [
    "SkyStarTrackerConfig",
    "SkyCameraConfig",
    "SkyDetectorConfig",
    "SkyIdentificationConfig",
    "sky_epoch_jyear",
    "sky_tracker_model",
    "nominal_covariance_S",
]
