"""Sensor plug-in: a three-axis magnetometer (:class:`drake_att.systems.coarse_sensors.Magnetometer`).

YAML tag ``!MagnetometerConfig``. Output: "vectors" (one direction per sample: ``B_S / |B_S|``,
reference the IGRF field's direction, ``sigma_rad = sigma_nT / |B_S|``); logged: ``magnetic_field``
``[t, valid, B_S (3, nT)]``. The field is the IGRF-14 at the true position
(:class:`~drake_att.systems.environment.MagneticFieldSource`): needs an orbit with an epoch
(``!TleOrbitConfig`` or ``!KeplerOrbitConfig``). The bias, scale factors and misalignment are not
modelled by the filters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import numpy as np

from drake_att import rotations as rot
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.sensors.gyro_plugin import misalignment_matrix
from drake_att.sensors.star_tracker_plugin import RpyMounting, validate_availability
from drake_att.systems.coarse_sensors import TESLA_PER_NANOTESLA, Magnetometer
from drake_att.units import DEG


@dataclass
class MagnetometerConfig:
    """Three-axis magnetometer: ``B_S = (I + S + M) R_SI B_I + bias + noise`` (defaults ours: a
    CubeSat-class magnetometer, 100 nT noise, no bias, scale-factor error or misalignment).

    ``mounting``: ``{rpy_deg: [roll, pitch, yaw]}`` (deg, S in B; default: aligned with the body).
    ``sigma_nT``: per-axis white noise (nT). ``bias_nT``: constant bias in the sensor axes (nT).
    ``scale_factor_error_ppm``: per axis. ``misalignment_urad``: the six off-diagonal terms
    ``[xy, xz, yx, yz, zx, zy]`` of ``M`` (as the gyro's).
    """

    name: str = "mag"
    period_s: float = 1.0
    mounting: RpyMounting = field(default_factory=RpyMounting)
    sigma_nT: float = 100.0
    bias_nT: List[float] = field(default_factory=cfg.zeros3)
    scale_factor_error_ppm: List[float] = field(default_factory=cfg.zeros3)
    misalignment_urad: List[float] = field(default_factory=lambda: [0.0] * 6)
    dropout_probability: float = 0.0
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (k, 2) [start, end]


def validate_magnetometer(path: str, c: MagnetometerConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    cfg.check_vector(f"{path}.mounting.rpy_deg", c.mounting.rpy_deg, 3)
    cfg.check_positive(f"{path}.sigma_nT", c.sigma_nT)
    cfg.check_vector(f"{path}.bias_nT", c.bias_nT, 3)
    cfg.check_vector(f"{path}.scale_factor_error_ppm", c.scale_factor_error_ppm, 3)
    cfg.check_vector(f"{path}.misalignment_urad", c.misalignment_urad, 6)
    validate_availability(path, c)
    cfg.require_orbit_epoch(path, c.name, checks.scenario, "to place the spacecraft in the magnetic field")


def magnetometer_noise_si(c: MagnetometerConfig) -> tuple:
    """The config's noise and errors in SI, in :meth:`Magnetometer.set_noise`'s order."""
    return (
        c.sigma_nT * TESLA_PER_NANOTESLA,
        np.asarray(c.bias_nT, dtype=float) * TESLA_PER_NANOTESLA,
        np.asarray(c.scale_factor_error_ppm, dtype=float) * 1e-6,
        misalignment_matrix(c.misalignment_urad),
        float(c.dropout_probability),
        [tuple(w) for w in np.reshape(c.outage_windows_s, (-1, 2))],
    )


def configure_magnetometer(ctx, c: MagnetometerConfig, sensor: Magnetometer, context) -> None:
    sensor.set_noise(context, *magnetometer_noise_si(c))


@register_sensor(
    MagnetometerConfig,
    output=lambda c, sensor_configs: SensorOutput("vectors", "vector_observations", c.period_s),
    validate=validate_magnetometer,
    logged_ports=lambda c: [("magnetic_field", c.period_s)],
    parameters=(
        "sigma_nT",
        "bias_nT",
        "scale_factor_error_ppm",
        "misalignment_urad",
        "dropout_probability",
        "outage_windows_s",
    ),
    configure=configure_magnetometer,
)
def build_magnetometer(ctx, c: MagnetometerConfig):
    sensor = ctx.builder.AddSystem(
        Magnetometer(
            c.name, c.period_s, rot.rpy_to_quat(np.asarray(c.mounting.rpy_deg) * DEG), *magnetometer_noise_si(c)
        )
    )
    ctx.builder.Connect(ctx.truth.GetOutputPort("q_IB"), sensor.GetInputPort("q_IB"))
    ctx.builder.Connect(ctx.magnetic_field().GetOutputPort("B_I"), sensor.GetInputPort("B_I"))
    return sensor
