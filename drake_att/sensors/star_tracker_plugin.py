"""Sensor plug-in: the star tracker (:class:`drake_att.systems.star_tracker.StarTracker`).

YAML tag ``!StarTrackerConfig``. Output: "quaternion" samples ``[t, valid, q_IS_meas]``
or "vectors" (:class:`~drake_att.contract.VectorObservations`) by ``mode``; logged: the
quaternion measurement (quaternion mode).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Union

import numpy as np

from drake_att import rotations as rot
from drake_att.exclusion import DEFAULT_ATMOSPHERE_HEIGHT_M, DEFAULT_HALF_ANGLES_DEG, ExclusionCones
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.systems.estimator_system import QuaternionSensorModel
from drake_att.systems.star_tracker import StarTracker, mounting_from_paper_s3_angles
from drake_att.units import ARCSEC, DEG

MODES = ("quaternion", "vectors")


@dataclass
class RpyMounting:
    """Sensor frame S relative to the body B: roll/pitch/yaw (x-y-z) of S in B (deg)."""

    rpy_deg: List[float] = field(default_factory=cfg.zeros3)


@dataclass
class PaperS3Eq7Mounting:
    """Paper S3's mounting convention (its eq. 7): three angles ``[psi, phi, theta]`` (deg)
    give a quaternion ``q7``, read as ``R_SB = R(q7)`` (``q_BS = q7^-1``); see
    :func:`drake_att.systems.star_tracker.mounting_from_paper_s3_angles`."""

    psi_phi_theta_deg: List[float] = field(default_factory=cfg.zeros3)


@dataclass
class ExclusionConfig:
    """Exclusion half-angles of a star tracker (deg, each in (0, 180)): a sample is invalid while
    the Sun, the Earth's bright limb (the Earth plus ``atmosphere_height_m``) or the Moon is
    inside its cone. The defaults are ours, in the range published for CubeSat-class trackers
    (module ``drake_att.exclusion``). Needs an orbit with an epoch (``!TleOrbitConfig`` or
    ``!KeplerOrbitConfig``)."""

    sun_deg: float = DEFAULT_HALF_ANGLES_DEG["sun_deg"]
    earth_limb_deg: float = DEFAULT_HALF_ANGLES_DEG["earth_limb_deg"]
    moon_deg: float = DEFAULT_HALF_ANGLES_DEG["moon_deg"]
    atmosphere_height_m: float = DEFAULT_ATMOSPHERE_HEIGHT_M


@dataclass
class StarTrackerConfig:
    """Star tracker (boresight = sensor +z).

    ``mounting``: ``!RpyMounting {rpy_deg: [...]}`` (default: aligned with the body) or
    ``!PaperS3Eq7Mounting {psi_phi_theta_deg: [...]}``.
    ``mode``: "quaternion" (attitude output) or "vectors" (``references_I`` directions).
    ``exclusion``: Sun / Earth-limb / Moon exclusion cones (:class:`ExclusionConfig`; null: none).
    """

    name: str = "st1"
    period_s: float = 1.0
    mode: str = "quaternion"
    mounting: Union[RpyMounting, PaperS3Eq7Mounting] = field(default_factory=RpyMounting)
    sigma_cross_boresight_arcsec: float = 0.0
    sigma_boresight_arcsec: float = 0.0
    references_I: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (m, 3)
    sigma_vector_urad: float = 0.0
    dropout_probability: float = 0.0
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (k, 2) [start, end]
    exclusion: Optional[ExclusionConfig] = None


def star_tracker_mounting(st: StarTrackerConfig) -> np.ndarray:
    """``q_BS`` of a tracker config."""
    m = st.mounting
    if isinstance(m, PaperS3Eq7Mounting):
        psi, phi, theta = np.asarray(m.psi_phi_theta_deg) * DEG
        return mounting_from_paper_s3_angles(psi, phi, theta)
    return rot.rpy_to_quat(np.asarray(m.rpy_deg) * DEG)


def star_tracker_sigmas_S(st: StarTrackerConfig) -> np.ndarray:
    """Sensor-frame rotation-vector noise sigmas (rad): cross-boresight x, y; boresight z."""
    return (
        np.array([st.sigma_cross_boresight_arcsec, st.sigma_cross_boresight_arcsec, st.sigma_boresight_arcsec]) * ARCSEC
    )


def exclusion_cones(c: StarTrackerConfig) -> ExclusionCones | None:
    e = c.exclusion
    return None if e is None else ExclusionCones(e.sun_deg, e.earth_limb_deg, e.moon_deg, e.atmosphere_height_m)


def validate_exclusion(path: str, c: StarTrackerConfig, scenario) -> None:
    """The cones' angles, and an orbit with an epoch to place the Sun, the Earth and the Moon."""
    if c.exclusion is None:
        return
    try:
        exclusion_cones(c).check(f"{path}.exclusion")  # type: ignore[union-attr]
    except ValueError as e:
        raise cfg.ConfigError(str(e)) from None
    cfg.require_orbit_epoch(f"{path}.exclusion", "set", scenario, "to place the Sun, the Earth and the Moon")


def validate_availability(path: str, c) -> None:
    """A sensor's ``dropout_probability`` in [0, 1) and ``outage_windows_s`` a list of [start, end]
    with end > start."""
    cfg.check_finite(f"{path}.dropout_probability", c.dropout_probability)
    if not 0 <= c.dropout_probability < 1:
        cfg.fail(f"{path}.dropout_probability", c.dropout_probability, "must be in [0, 1)")
    if np.size(c.outage_windows_s) and np.ndim(c.outage_windows_s) != 2:
        cfg.fail(f"{path}.outage_windows_s", c.outage_windows_s, "must be a list of [start, end]")
    for j, w in enumerate(np.reshape(c.outage_windows_s, (-1, 2))):
        if len(w) != 2 or not w[1] > w[0]:
            cfg.fail(f"{path}.outage_windows_s[{j}]", w, "must be [start, end] with end > start")


def validate_star_tracker(path: str, c: StarTrackerConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    validate_exclusion(path, c, checks.scenario)
    if c.mode not in MODES:
        cfg.fail(f"{path}.mode", c.mode, "allowed: 'quaternion', 'vectors'")
    if isinstance(c.mounting, PaperS3Eq7Mounting):
        cfg.check_vector(f"{path}.mounting.psi_phi_theta_deg", c.mounting.psi_phi_theta_deg, 3)
    else:
        cfg.check_vector(f"{path}.mounting.rpy_deg", c.mounting.rpy_deg, 3)
    cfg.check_nonnegative(f"{path}.sigma_cross_boresight_arcsec", c.sigma_cross_boresight_arcsec)
    cfg.check_nonnegative(f"{path}.sigma_boresight_arcsec", c.sigma_boresight_arcsec)
    cfg.check_nonnegative(f"{path}.sigma_vector_urad", c.sigma_vector_urad)
    validate_availability(path, c)
    if c.mode == "vectors":
        if np.ndim(c.references_I) != 2 or len(c.references_I) < 1:
            cfg.fail(f"{path}.references_I", c.references_I, "vector mode needs >= 1 direction")
        for j, r in enumerate(c.references_I):
            cfg.check_vector(f"{path}.references_I[{j}]", r, 3)
            if float(np.linalg.norm(r)) < 1e-9:
                cfg.fail(f"{path}.references_I[{j}]", r, "must be non-zero")
        if c.sigma_vector_urad <= 0:
            cfg.fail(f"{path}.sigma_vector_urad", c.sigma_vector_urad, "vector mode needs > 0")
    elif c.sigma_cross_boresight_arcsec <= 0 or c.sigma_boresight_arcsec <= 0:
        cfg.fail(
            f"{path}.sigma_*_arcsec",
            [c.sigma_cross_boresight_arcsec, c.sigma_boresight_arcsec],
            "quaternion mode needs both sigmas > 0 (a filter cannot use a perfect sensor)",
        )


def star_tracker_output(c: StarTrackerConfig, sensor_configs) -> SensorOutput:
    if c.mode == "vectors":
        return SensorOutput("vectors", "vector_observations", c.period_s)
    return SensorOutput("quaternion", "star_tracker_measurement", c.period_s)


def star_tracker_quaternion_model(ctx, c: StarTrackerConfig) -> QuaternionSensorModel:
    return QuaternionSensorModel(c.name, star_tracker_mounting(c), np.diag(star_tracker_sigmas_S(c) ** 2))


def star_tracker_logged_ports(c: StarTrackerConfig):
    ports = [("star_tracker_measurement", c.period_s)] if c.mode == "quaternion" else []
    return ports + ([("exclusion", c.period_s)] if c.exclusion is not None else [])


def star_tracker_noise_si(c: StarTrackerConfig) -> tuple:
    """The config's noise and availability in SI, in :meth:`StarTracker.set_noise`'s order."""
    return (
        c.sigma_cross_boresight_arcsec * ARCSEC,
        c.sigma_boresight_arcsec * ARCSEC,
        c.sigma_vector_urad * 1e-6,
        c.dropout_probability,
        [tuple(w) for w in np.reshape(c.outage_windows_s, (-1, 2))],
    )


def configure_star_tracker(ctx, c: StarTrackerConfig, st: StarTracker, context) -> None:
    st.set_noise(context, *star_tracker_noise_si(c))


@register_sensor(
    StarTrackerConfig,
    output=star_tracker_output,
    validate=validate_star_tracker,
    quaternion_model=star_tracker_quaternion_model,
    logged_ports=star_tracker_logged_ports,
    parameters=(
        "sigma_cross_boresight_arcsec",
        "sigma_boresight_arcsec",
        "sigma_vector_urad",
        "dropout_probability",
        "outage_windows_s",
    ),
    configure=configure_star_tracker,
)
def build_star_tracker(ctx, c: StarTrackerConfig):
    sc, sb, sv, dropout, outages = star_tracker_noise_si(c)
    st = ctx.builder.AddSystem(
        StarTracker(
            c.name,
            c.period_s,
            star_tracker_mounting(c),
            c.mode,
            sc,
            sb,
            c.references_I if c.mode == "vectors" else None,
            sv,
            dropout,
            outages,
            exclusion_cones(c),
            realizations=ctx.realizations,
        )
    )
    ctx.builder.Connect(ctx.truth.GetOutputPort("q_IB"), st.GetInputPort("q_IB"))
    if c.exclusion is not None:
        orbit, sun_moon = ctx.environment()
        ctx.builder.Connect(orbit.GetOutputPort("r_I"), st.GetInputPort("r_I"))
        ctx.builder.Connect(sun_moon.GetOutputPort("r_sun_I"), st.GetInputPort("r_sun_I"))
        ctx.builder.Connect(sun_moon.GetOutputPort("r_moon_I"), st.GetInputPort("r_moon_I"))
    return st
