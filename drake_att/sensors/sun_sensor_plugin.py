"""Sensor plug-in: a coarse sun sensor (:class:`drake_att.systems.coarse_sensors.SunSensor`).

YAML tag ``!SunSensorConfig``. Output: "vectors" (one direction per sample: the Sun); logged:
``sun_sensor_measurement`` ``[t, valid, s_S (3)]`` and ``sun_sensor_status`` ``[t, causes]``
(bit flags: 1 eclipse, 2 Sun outside the field of view). Needs an orbit with an epoch
(``!TleOrbitConfig`` or ``!KeplerOrbitConfig``). The model (cosine-detector head, noise growing as
``1 / cos`` off the boresight, eclipse and albedo) is documented in :mod:`drake_att.systems.coarse_sensors`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drake_att import rotations as rot
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.sensors.star_tracker_plugin import RpyMounting, validate_availability
from drake_att.systems.coarse_sensors import SunSensor
from drake_att.units import DEG


@dataclass
class SunSensorConfig:
    """Coarse sun sensor head, boresight = sensor +z (defaults ours: a CubeSat-class head).

    ``mounting``: ``{rpy_deg: [roll, pitch, yaw]}`` (deg, S in B; default: aligned with the body).
    ``boresight_sigma_deg``: per-axis direction noise on the boresight, growing as 1/cos off it.
    ``fov_half_angle_deg``: field-of-view half-angle, in (0, 90).
    ``min_sun_fraction``: a sample is invalid when less of the solar disk is visible (eclipse,
    penumbra); 0.5: the middle of the penumbra.
    ``albedo``: the Earth's albedo added as light from nadir (0: none; the Earth's is ~0.3).
    """

    name: str = "sun"
    period_s: float = 1.0
    mounting: RpyMounting = field(default_factory=RpyMounting)
    boresight_sigma_deg: float = 0.5
    fov_half_angle_deg: float = 60.0
    min_sun_fraction: float = 0.5
    albedo: float = 0.0
    dropout_probability: float = 0.0
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (k, 2) [start, end]


def validate_sun_sensor(path: str, c: SunSensorConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    cfg.check_vector(f"{path}.mounting.rpy_deg", c.mounting.rpy_deg, 3)
    cfg.check_positive(f"{path}.boresight_sigma_deg", c.boresight_sigma_deg)
    if not 0.0 < cfg.check_finite(f"{path}.fov_half_angle_deg", c.fov_half_angle_deg) < 90.0:
        cfg.fail(f"{path}.fov_half_angle_deg", c.fov_half_angle_deg, "must be in (0, 90) deg (one cosine head)")
    if not 0.0 < cfg.check_finite(f"{path}.min_sun_fraction", c.min_sun_fraction) <= 1.0:
        cfg.fail(f"{path}.min_sun_fraction", c.min_sun_fraction, "must be in (0, 1] (visible fraction of the Sun)")
    if not 0.0 <= cfg.check_finite(f"{path}.albedo", c.albedo) <= 1.0:
        cfg.fail(f"{path}.albedo", c.albedo, "must be in [0, 1] (0: no albedo; the Earth's is ~0.3)")
    validate_availability(path, c)
    cfg.require_orbit_epoch(path, c.name, checks.scenario, "to place the Sun and the Earth's shadow")


def sun_sensor_noise_si(c: SunSensorConfig) -> tuple:
    """The config's noise in SI, in :meth:`SunSensor.set_noise`'s order."""
    return (
        c.boresight_sigma_deg * DEG,
        float(c.albedo),
        float(c.dropout_probability),
        [tuple(w) for w in np.reshape(c.outage_windows_s, (-1, 2))],
    )


def configure_sun_sensor(ctx, c: SunSensorConfig, sensor: SunSensor, context) -> None:
    sensor.set_noise(context, *sun_sensor_noise_si(c))


@register_sensor(
    SunSensorConfig,
    output=lambda c, sensor_configs: SensorOutput("vectors", "vector_observations", c.period_s),
    validate=validate_sun_sensor,
    logged_ports=lambda c: [("sun_sensor_measurement", c.period_s), ("sun_sensor_status", c.period_s)],
    parameters=("boresight_sigma_deg", "albedo", "dropout_probability", "outage_windows_s"),
    configure=configure_sun_sensor,
)
def build_sun_sensor(ctx, c: SunSensorConfig):
    sigma, albedo, dropout, outages = sun_sensor_noise_si(c)
    sensor = ctx.builder.AddSystem(
        SunSensor(
            c.name,
            c.period_s,
            rot.rpy_to_quat(np.asarray(c.mounting.rpy_deg) * DEG),
            sigma,
            c.fov_half_angle_deg * DEG,
            c.min_sun_fraction,
            albedo,
            dropout,
            outages,
        )
    )
    orbit, sun_moon = ctx.environment()
    ctx.builder.Connect(ctx.truth.GetOutputPort("q_IB"), sensor.GetInputPort("q_IB"))
    ctx.builder.Connect(orbit.GetOutputPort("r_I"), sensor.GetInputPort("r_I"))
    ctx.builder.Connect(sun_moon.GetOutputPort("r_sun_I"), sensor.GetInputPort("r_sun_I"))
    return sensor
