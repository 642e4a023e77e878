"""Estimator plug-in: paper S0's extended-Kalman particle filter
(:class:`drake_att.filters.particle.EkpfCore`). YAML tag ``!EkpfConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.filter_setups import ekpf_setup


@dataclass
class EkpfConfig:
    """Paper S0's extended-Kalman particle filter (per-particle EKF proposal).
    ``proposal_iterations`` > 1 iterates each particle's EKF update (beyond the paper).

    ``max_time_tag_lag_s``: a sample tagged up to this much before the step is carried forward
    to it and used (:class:`~drake_att.estimators.mekf_plugin.MekfConfig`); 0: none.
    """

    name: str = "ekpf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    num_particles: int = 1000
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    proposal_iterations: int = 1
    resample_threshold: float = 0.6666666666666666
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_bias_sigma_deg_per_h: float = 1.0
    max_time_tag_lag_s: float = 0.0


def validate_ekpf(path: str, c: EkpfConfig, checks) -> None:
    common.validate_vector_filter(
        path,
        c,
        checks,
        integer_fields=("num_particles", "proposal_iterations"),
        resampling=True,
        filter_gyro_noise=True,
    )
    common.check_step_settings(path, c)


@register_estimator(
    EkpfConfig,
    second_quantity=SecondQuantity.GYRO_BIAS,
    validate=validate_ekpf,
    parameters=(
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        "proposal_iterations",
        "resample_threshold",
        *common.INITIAL_GYRO_MODE_FIELDS,
        *common.LAG_FIELDS,
    ),
)
def build_ekpf(ctx, c: EkpfConfig):
    arw, rrw = common.filter_gyro_noise(ctx, c)
    q0, b0, P0 = common.initial_gyro_mode_estimate(ctx, c)
    setup = ekpf_setup(
        c.period_s,
        c.star_tracker,
        c.num_particles,
        q0,
        b0,
        P0,
        arw,
        rrw,
        proposal_iterations=c.proposal_iterations,
        resample_threshold=c.resample_threshold,
        gyro=c.gyro,
        vector_sensors=c.vector_sensors,
    )
    return common.with_step_settings(setup, c)
