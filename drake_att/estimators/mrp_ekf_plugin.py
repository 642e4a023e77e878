"""Estimator plug-in: paper S0's additive EKF on ``[MRP; gyro bias]``
(:class:`drake_att.filters.mrp_ekf.MrpEkfCore`). YAML tag ``!MrpEkfConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.filter_setups import mrp_ekf_setup


@dataclass
class MrpEkfConfig:
    """Paper S0's additive EKF on ``[MRP; gyro bias]`` with shadow-set switching, fed by a
    gyro and one vector-mode star tracker (``star_tracker``; ``""``: none) and any further
    vector-observation sensors (``vector_sensors``: e.g. a sun sensor and a magnetometer),
    updated on one after the other at each step.  ``update_iterations`` > 1 gives an iterated
    EKF (beyond the paper).  Noise defaults (None) come from the gyro's config.

    ``max_time_tag_lag_s``: a sample tagged up to this much before the step is carried forward
    to it and used (:class:`~drake_att.estimators.mekf_plugin.MekfConfig`); 0: none.
    """

    name: str = "ekf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_bias_sigma_deg_per_h: float = 1.0
    update_iterations: int = 1
    innovation_gate_chi2: Optional[float] = None
    innovation_gate_probability: float = DEFAULT_GATE_PROBABILITY
    max_time_tag_lag_s: float = 0.0


def validate_mrp_ekf(path: str, c: MrpEkfConfig, checks) -> None:
    common.validate_vector_filter(path, c, checks, integer_fields=("update_iterations",), filter_gyro_noise=True)
    common.check_innovation_gate(path, c)
    common.check_step_settings(path, c)


@register_estimator(
    MrpEkfConfig,
    second_quantity=SecondQuantity.GYRO_BIAS,
    validate=validate_mrp_ekf,
    parameters=(
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        "update_iterations",
        *common.GATE_FIELDS,
        *common.INITIAL_GYRO_MODE_FIELDS,
        *common.LAG_FIELDS,
    ),
)
def build_mrp_ekf(ctx, c: MrpEkfConfig):
    arw, rrw = common.filter_gyro_noise(ctx, c)
    q0, b0, P0 = common.initial_gyro_mode_estimate(ctx, c)
    setup = mrp_ekf_setup(
        c.period_s,
        c.star_tracker,
        q0,
        b0,
        P0,
        arw,
        rrw,
        c.update_iterations,
        gyro=c.gyro,
        innovation_gate=common.innovation_gate(c),
        vector_sensors=c.vector_sensors,
    )
    return common.with_step_settings(setup, c)
