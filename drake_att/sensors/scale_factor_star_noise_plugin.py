"""Sensor plug-in: paper S1's multiplicative, correlated noise
(:class:`drake_att.systems.correlated_noise.ScaleFactorStarNoiseSource`) feeding a gyro's
``scale_error`` and a vector-mode star tracker's ``vector_noise``. YAML tag
``!ScaleFactorStarNoiseConfig``; list it after the gyro and the tracker it drives.

The model (:mod:`drake_att.filters.multiplicative_noise`): ``zeta_k ~ N(0, zeta_variance)``
per gyro step, the gyro reads the interval's mean rate divided by ``1 + scale_per_zeta
zeta_k``, and the tracker's noise at ``t_k`` (per component sigma: its ``sigma_vector_urad``)
is correlated with ``zeta_k`` with coefficient ``correlation``. Defaults: the seed's
``Q_zeta = 0.1`` and ``S = 0.05`` read as ``rho = 0.05 / sqrt(0.1) = 0.158``, ``kappa = 0.01``.
Not logged (its ``zeta`` output port carries the truth of each interval for a user who wants it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att.filters.multiplicative_noise import (
    DEFAULT_SCALE_PER_ZETA,
    PAPER_CORRELATION,
    PAPER_ZETA_VARIANCE,
    MultiplicativeNoiseModel,
)
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.sensors.gyro_plugin import GyroConfig
from drake_att.sensors.star_tracker_plugin import StarTrackerConfig
from drake_att.systems.correlated_noise import ScaleFactorStarNoiseSource


@dataclass
class ScaleFactorStarNoiseConfig:
    """Per-step gyro scale-factor error correlated with a star tracker's noise (paper S1)."""

    name: str = "multiplicative_noise"
    gyro: str = "gyro"
    star_tracker: str = "st"
    zeta_variance: float = PAPER_ZETA_VARIANCE
    correlation: float = PAPER_CORRELATION
    scale_per_zeta: float = DEFAULT_SCALE_PER_ZETA


def noise_model(c: ScaleFactorStarNoiseConfig) -> MultiplicativeNoiseModel:
    return MultiplicativeNoiseModel.make(c.zeta_variance, c.correlation, c.scale_per_zeta)


def validate_scale_factor_star_noise(path: str, c: ScaleFactorStarNoiseConfig, checks) -> None:
    gyro, st = checks.sensors.get(c.gyro), checks.sensors.get(c.star_tracker)
    if not isinstance(gyro, GyroConfig):
        cfg.fail(f"{path}.gyro", c.gyro, "must name a gyro listed before it")
    if not isinstance(st, StarTrackerConfig) or st.mode != "vectors":
        cfg.fail(f"{path}.star_tracker", c.star_tracker, "must name a vector-mode star tracker listed before it")
    ratio = st.period_s / gyro.period_s
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        cfg.fail(
            f"{path}.star_tracker",
            c.star_tracker,
            f"its period ({st.period_s} s) must be a whole multiple of the gyro's ({gyro.period_s} s)",
        )
    for f in ("zeta_variance", "correlation", "scale_per_zeta"):
        cfg.check_finite(f"{path}.{f}", getattr(c, f))
    try:
        model = noise_model(c)
        model.cross_covariance(st.sigma_vector_urad * 1e-6, len(st.references_I))
    except ValueError as e:
        raise cfg.ConfigError(f"{path}: {e}") from e


def configure_scale_factor_star_noise(ctx, c: ScaleFactorStarNoiseConfig, source, context) -> None:
    source.set_model(context, noise_model(c), ctx.sensor_configs[c.star_tracker].sigma_vector_urad * 1e-6)


@register_sensor(
    ScaleFactorStarNoiseConfig,
    output=lambda c, sensors: SensorOutput("scale_factor_noise", "zeta", sensors[c.gyro].period_s),
    validate=validate_scale_factor_star_noise,
    logged_ports=lambda c: [],
    parameters=("zeta_variance", "correlation", "scale_per_zeta"),
    configure=configure_scale_factor_star_noise,
)
def build_scale_factor_star_noise(ctx, c: ScaleFactorStarNoiseConfig):
    gyro, st = ctx.sensor_configs[c.gyro], ctx.sensor_configs[c.star_tracker]
    source = ctx.builder.AddSystem(
        ScaleFactorStarNoiseSource(
            c.name, gyro.period_s, noise_model(c), st.sigma_vector_urad * 1e-6, int(np.shape(st.references_I)[0])
        )
    )
    ctx.builder.Connect(source.GetOutputPort("scale_error"), ctx.sensors[c.gyro].GetInputPort("scale_error"))
    ctx.builder.Connect(source.GetOutputPort("vector_noise"), ctx.sensors[c.star_tracker].GetInputPort("vector_noise"))
    return source
