"""Sensor plug-in: the Farrenkopf gyro (:class:`drake_att.systems.gyro.Gyro`).

YAML tag ``!GyroConfig``. Output: "gyro" samples ``[t, valid, w_meas_B]`` (the mean rate
over each ``period_s``); logged: the measurement and the true bias ``bias_B``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.systems.gyro import Gyro
from drake_att.units import ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15


@dataclass
class GyroConfig:
    """Farrenkopf gyro delivering the mean rate over each ``period_s``.

    ``sample_rate_hz`` documents the internal sampling whose mean is delivered; the
    statistics of that mean are exact for any rate (see ``drake_att.noise``).
    ``misalignment_urad`` holds the six off-diagonal terms ``[xy, xz, yx, yz, zx, zy]``.
    """

    name: str = "gyro"
    period_s: float = 1.0
    sample_rate_hz: float = 300.0
    arw_deg_per_rt_h: float = 0.0
    rrw_deg_per_h15: float = 0.0
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_sigma_deg_per_h: float = 0.0
    scale_factor_error_ppm: List[float] = field(default_factory=cfg.zeros3)
    misalignment_urad: List[float] = field(default_factory=lambda: [0.0] * 6)
    range_deg_per_s: Optional[float] = None  # per-axis measurement range (None: unlimited)


def validate_gyro(path: str, c: GyroConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    cfg.check_positive(f"{path}.sample_rate_hz", c.sample_rate_hz)
    cfg.check_nonnegative(f"{path}.arw_deg_per_rt_h", c.arw_deg_per_rt_h)
    cfg.check_nonnegative(f"{path}.rrw_deg_per_h15", c.rrw_deg_per_h15)
    cfg.check_vector(f"{path}.initial_bias_deg_per_h", c.initial_bias_deg_per_h, 3)
    cfg.check_nonnegative(f"{path}.initial_bias_sigma_deg_per_h", c.initial_bias_sigma_deg_per_h)
    cfg.check_vector(f"{path}.scale_factor_error_ppm", c.scale_factor_error_ppm, 3)
    cfg.check_vector(f"{path}.misalignment_urad", c.misalignment_urad, 6)
    if c.range_deg_per_s is not None:
        cfg.check_positive(f"{path}.range_deg_per_s", c.range_deg_per_s)


def gyro_output(c: GyroConfig, sensor_configs) -> SensorOutput:
    return SensorOutput("gyro", "gyro_measurement", c.period_s)


def gyro_logged_ports(c: GyroConfig):
    return [("gyro_measurement", c.period_s), ("bias_B", c.period_s)]


def misalignment_matrix(misalignment_urad) -> np.ndarray:
    """The (3, 3) misalignment (rad, zero diagonal) of the six off-diagonal terms
    ``[xy, xz, yx, yz, zx, zy]`` in urad (a config's ``misalignment_urad``)."""
    m = np.zeros((3, 3))
    m[[0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]] = np.asarray(misalignment_urad) * 1e-6
    return m


def gyro_model_si(c: GyroConfig) -> tuple:
    """The config's noise and errors in SI, in :meth:`Gyro.set_model`'s argument order."""
    m = misalignment_matrix(c.misalignment_urad)
    return (
        c.arw_deg_per_rt_h * ARW_DEG_PER_RT_H,
        c.rrw_deg_per_h15 * RRW_DEG_PER_H_15,
        np.asarray(c.initial_bias_deg_per_h) * DEG_PER_H,
        c.initial_bias_sigma_deg_per_h * DEG_PER_H,
        np.asarray(c.scale_factor_error_ppm) * 1e-6,
        m,
        math.inf if c.range_deg_per_s is None else c.range_deg_per_s * DEG,
    )


def configure_gyro(ctx, c: GyroConfig, gyro: Gyro, context) -> None:
    gyro.set_model(context, *gyro_model_si(c))


@register_sensor(
    GyroConfig,
    output=gyro_output,
    validate=validate_gyro,
    logged_ports=gyro_logged_ports,
    parameters=(
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        "initial_bias_deg_per_h",
        "initial_bias_sigma_deg_per_h",
        "scale_factor_error_ppm",
        "misalignment_urad",
        "range_deg_per_s",
    ),
    configure=configure_gyro,
)
def build_gyro(ctx, c: GyroConfig):
    arw, rrw, bias, bias_sigma, scale, misalignment, range_ = gyro_model_si(c)
    gyro = ctx.builder.AddSystem(
        Gyro(c.name, c.period_s, arw, rrw, bias, bias_sigma, scale, misalignment, range_, ctx.realizations)
    )
    ctx.builder.Connect(ctx.truth.GetOutputPort("w_IB_B"), gyro.GetInputPort("w_IB_B"))
    ctx.builder.Connect(ctx.truth.GetOutputPort("w_IB_B_integral"), gyro.GetInputPort("w_IB_B_integral"))
    return gyro
