"""Estimator plug-in: paper S0's bootstrap (SIR) particle filter in gyro mode
(:class:`drake_att.filters.particle.BootstrapPfCore`). YAML tag ``!BootstrapPfConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.filter_setups import bootstrap_pf_setup
from drake_att.units import ARW_DEG_PER_RT_H, DEG_PER_H


@dataclass
class BootstrapPfConfig:
    """Paper S0's bootstrap (SIR) particle filter on ``[MRP; bias]`` in gyro mode.

    ``attitude_process_noise_deg_per_rt_h``: the ARW used to spread the particles'
    attitude (None: the gyro's ARW).  ``bias_roughening_deg_per_h_per_rt_s``: the
    beyond-the-paper bias-diffusion remedy (0 = the paper's frozen particle biases).

    ``max_time_tag_lag_s``: a sample tagged up to this much before the step is carried forward
    to it and used (:class:`~drake_att.estimators.mekf_plugin.MekfConfig`); 0: none.
    """

    name: str = "bootstrap_pf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    num_particles: int = 1000
    attitude_process_noise_deg_per_rt_h: Optional[float] = None
    bias_roughening_deg_per_h_per_rt_s: float = 0.0
    resample_threshold: float = 0.6666666666666666
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_bias_sigma_deg_per_h: float = 1.0
    max_time_tag_lag_s: float = 0.0


def validate_bootstrap_pf(path: str, c: BootstrapPfConfig, checks) -> None:
    common.validate_vector_filter(path, c, checks, integer_fields=("num_particles",), resampling=True)
    if c.attitude_process_noise_deg_per_rt_h is not None:
        cfg.check_nonnegative(f"{path}.attitude_process_noise_deg_per_rt_h", c.attitude_process_noise_deg_per_rt_h)
    cfg.check_nonnegative(f"{path}.bias_roughening_deg_per_h_per_rt_s", c.bias_roughening_deg_per_h_per_rt_s)
    common.check_step_settings(path, c)


@register_estimator(
    BootstrapPfConfig,
    second_quantity=SecondQuantity.GYRO_BIAS,
    validate=validate_bootstrap_pf,
    parameters=(
        "attitude_process_noise_deg_per_rt_h",
        "bias_roughening_deg_per_h_per_rt_s",
        "resample_threshold",
        *common.INITIAL_GYRO_MODE_FIELDS,
        *common.LAG_FIELDS,
    ),
)
def build_bootstrap_pf(ctx, c: BootstrapPfConfig):
    g = ctx.sensor_configs[c.gyro]
    arw_deg = (
        g.arw_deg_per_rt_h if c.attitude_process_noise_deg_per_rt_h is None else c.attitude_process_noise_deg_per_rt_h
    )
    q0, b0, P0 = common.initial_gyro_mode_estimate(ctx, c)
    setup = bootstrap_pf_setup(
        c.period_s,
        c.star_tracker,
        c.num_particles,
        q0,
        b0,
        P0,
        arw_deg * ARW_DEG_PER_RT_H,
        bias_roughening_sigma=c.bias_roughening_deg_per_h_per_rt_s * DEG_PER_H,
        resample_threshold=c.resample_threshold,
        gyro=c.gyro,
        vector_sensors=c.vector_sensors,
    )
    return common.with_step_settings(setup, c)
