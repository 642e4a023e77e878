"""Estimator plug-in: paper S4's baseline, the additive quaternion EKF
(:class:`drake_att.filters.quaternion_ekf.AdditiveQuaternionEKF`), fed by a gyro and one
vector-mode star tracker whose directions it turns into a quaternion measurement (Wahba,
sign-aligned). YAML tag ``!QuaternionEkfConfig``. Paper defaults: ``q0 = [1, 0, 0, 0]``,
``P0 = I4``, ``Q = 1e-5 I4`` per 1 s step, ``R = 0.01 I4``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY
from drake_att.filters.quaternion_ekf import AdditiveQuaternionEKF
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.estimator_system import EstimatorSetup
from drake_att.units import ARW_DEG_PER_RT_H


@dataclass
class QuaternionEkfConfig:
    """Additive quaternion EKF (4-state, normalized after each update; no bias state).

    Attributes:
        initial_quaternion_variance: ``P0 = value * I4`` (paper 1).
        process_noise_per_step: ``Q = value * I4`` per ``period_s`` (paper 1e-5).
        measurement_noise: ``R = value * I4`` of the quaternion measurement (paper 0.01).
        gyro_arw_deg_per_rt_h: the gyro ARW the filter models, or None (paper: none).
    """

    name: str = "quaternion_ekf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_quaternion_variance: float = 1.0
    process_noise_per_step: float = 1e-5
    measurement_noise: float = 0.01
    gyro_arw_deg_per_rt_h: Optional[float] = None
    innovation_gate_chi2: Optional[float] = None
    innovation_gate_probability: float = DEFAULT_GATE_PROBABILITY


def validate_quaternion_ekf(path: str, c: QuaternionEkfConfig, checks) -> None:
    common.validate_vector_filter(path, c, checks, initial_bias=False, initial_sigma=False)
    cfg.check_positive(f"{path}.initial_quaternion_variance", c.initial_quaternion_variance)
    cfg.check_nonnegative(f"{path}.process_noise_per_step", c.process_noise_per_step)
    cfg.check_positive(f"{path}.measurement_noise", c.measurement_noise)
    if c.gyro_arw_deg_per_rt_h is not None:
        cfg.check_nonnegative(f"{path}.gyro_arw_deg_per_rt_h", c.gyro_arw_deg_per_rt_h)
    common.check_innovation_gate(path, c)


@register_estimator(
    QuaternionEkfConfig,
    second_quantity=SecondQuantity.BODY_RATE,
    validate=validate_quaternion_ekf,
    parameters=(
        "initial_attitude_rpy_deg",
        "initial_quaternion_variance",
        "process_noise_per_step",
        "measurement_noise",
        "gyro_arw_deg_per_rt_h",
        *common.GATE_FIELDS,
    ),
)
def build_quaternion_ekf(ctx, c: QuaternionEkfConfig) -> EstimatorSetup:
    arw = None if c.gyro_arw_deg_per_rt_h is None else c.gyro_arw_deg_per_rt_h * ARW_DEG_PER_RT_H
    core = AdditiveQuaternionEKF(
        Q=c.process_noise_per_step,
        R=c.measurement_noise,
        step_s=c.period_s,
        gyro_arw_rad_per_rt_s=arw,
        innovation_gate_chi2=common.innovation_gate(c),
    )
    init = core.initial_state(
        attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg), c.initial_quaternion_variance
    )
    return EstimatorSetup(core, init, c.period_s, gyro=c.gyro, vector_sensors=common.vector_sensor_names(c))
