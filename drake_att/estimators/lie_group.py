"""Estimator plug-in: paper S4's Lie-group (SO(3)) filter
(:class:`drake_att.filters.lie_group.LieGroupFilter`), fed by a gyro and one vector-mode star
tracker. YAML tag ``!LieGroupConfig``.

``formulation: consistent`` (default) is the filter in one consistent error convention (the
project's ``R_IB = R_IB_hat exp([dtheta_B x])``); ``formulation: paper_literal`` is eqs
26-32 as printed, which do not converge (SPEC.md S4). Paper tuning (the defaults):
``P0 = 5 I3``, ``Q_w = 5e-5 I3`` per 1 s step, ``Q_v = 0.125^2``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.lie_group import FORMULATIONS, LieGroupFilter
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.estimators import EstimatorSetup
from drake_att.units import ARW_DEG_PER_RT_H


@dataclass
class LieGroupConfig:
    """Paper S4's Lie-group filter (no gyro-bias state; the second vector is the body rate).

    Attributes:
        formulation: "consistent" or "paper_literal".
        initial_attitude_variance_rad2: ``P0 = value * I3`` (rad^2; paper 5).
        process_noise_rad2_per_step: ``Q_w = value * I3`` per ``period_s`` (rad^2; paper 5e-5).
        star_noise_variance_rad2: ``Q_v`` per direction component (rad^2; paper 0.125^2);
            None: the tracker's ``sigma_vector_urad`` squared.
        gyro_arw_deg_per_rt_h: the gyro ARW the filter models (adds ``arw^2 dt`` and sets
            the rate block); None: the process noise is the paper's ``Q_w`` only.
    """

    name: str = "lie_group"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    formulation: str = "consistent"
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_variance_rad2: float = 5.0
    process_noise_rad2_per_step: float = 5e-5
    star_noise_variance_rad2: Optional[float] = 0.015625
    gyro_arw_deg_per_rt_h: Optional[float] = None
    innovation_gate_chi2: Optional[float] = None


def validate_lie_group(path: str, c: LieGroupConfig, checks) -> None:
    common.validate_vector_filter(path, c, checks, initial_bias=False, initial_sigma=False)
    if c.formulation not in FORMULATIONS:
        cfg.fail(f"{path}.formulation", c.formulation, f"allowed: {list(FORMULATIONS)}")
    cfg.check_positive(f"{path}.initial_attitude_variance_rad2", c.initial_attitude_variance_rad2)
    cfg.check_nonnegative(f"{path}.process_noise_rad2_per_step", c.process_noise_rad2_per_step)
    if c.star_noise_variance_rad2 is not None:
        cfg.check_positive(f"{path}.star_noise_variance_rad2", c.star_noise_variance_rad2)
    if c.gyro_arw_deg_per_rt_h is not None:
        cfg.check_nonnegative(f"{path}.gyro_arw_deg_per_rt_h", c.gyro_arw_deg_per_rt_h)
    if c.innovation_gate_chi2 is not None:
        cfg.check_positive(f"{path}.innovation_gate_chi2", c.innovation_gate_chi2)


@register_estimator(LieGroupConfig, second_quantity=SecondQuantity.BODY_RATE, validate=validate_lie_group,
                    parameters=("formulation", "initial_attitude_rpy_deg", "initial_attitude_variance_rad2",
                                "process_noise_rad2_per_step", "star_noise_variance_rad2", "gyro_arw_deg_per_rt_h",
                                "innovation_gate_chi2"))
def build_lie_group(ctx, c: LieGroupConfig) -> EstimatorSetup:
    arw = None if c.gyro_arw_deg_per_rt_h is None else c.gyro_arw_deg_per_rt_h * ARW_DEG_PER_RT_H
    core = LieGroupFilter(Q_w=c.process_noise_rad2_per_step, Q_v=c.star_noise_variance_rad2,
                          formulation=c.formulation, step_s=c.period_s, gyro_arw_rad_per_rt_s=arw,
                          innovation_gate_chi2=c.innovation_gate_chi2)
    init = core.initial_state(attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg),
                              c.initial_attitude_variance_rad2)
    return EstimatorSetup(core, init, c.period_s, gyro=c.gyro, vector_sensors=(c.star_tracker,))
