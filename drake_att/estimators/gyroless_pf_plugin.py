"""Estimator plug-in: paper S0's gyroless bootstrap PF on ``[MRP; body rate]`` propagated
with Euler's equations (:class:`drake_att.filters.particle.GyrolessPfCore`).
YAML tag ``!GyrolessPfConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import numpy as np

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.filter_setups import gyroless_pf_setup
from drake_att.units import ARW_DEG_PER_RT_H, DEG


@dataclass
class GyrolessPfConfig:
    """Paper S0's gyroless bootstrap PF on ``[MRP; body rate]`` propagated with Euler's
    equations (known inertia and disturbance torque; empty lists = the plant's)."""

    name: str = "gyroless_pf"
    period_s: float = 1.0
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    num_particles: int = 1000
    inertia_kg_m2: List[float] = field(default_factory=list)
    disturbance_torque_N_m: List[float] = field(default_factory=list)
    rate_process_noise_deg_per_s_per_rt_s: float = 1e-5
    attitude_process_noise_deg_per_rt_h: float = 0.0
    num_substeps: int = 1
    resample_threshold: float = 0.6666666666666666
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_rate_deg_per_s: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_rate_sigma_deg_per_s: float = 0.001


def plant_dynamics(scenario, c: GyrolessPfConfig, path: str | None = None):
    """Inertia (3, 3) and torque (3,) for the filter: the config's, else the plant's."""
    p = scenario.plant
    inertia, torque = list(c.inertia_kg_m2), list(c.disturbance_torque_N_m)
    if not inertia or not torque:
        if not isinstance(p, cfg.RigidBodyConfig):
            cfg.fail(
                f"{path or c.name}.inertia_kg_m2",
                inertia,
                f"empty (= the plant's), but the plant is a {type(p).__name__}, which has no inertia/torque; "
                "give inertia_kg_m2 and disturbance_torque_N_m explicitly",
            )
        inertia = inertia or list(p.inertia_kg_m2)
        torque = torque or list(p.disturbance_torque_N_m)
    I = np.asarray(inertia, dtype=float)
    I = np.diag(I) if I.size == 3 else I.reshape(3, 3)
    return I, np.asarray(torque, dtype=float)


def validate_gyroless_pf(path: str, c: GyrolessPfConfig, checks) -> None:
    common.validate_vector_filter(
        path,
        c,
        checks,
        uses_gyro=False,
        integer_fields=("num_particles", "num_substeps"),
        resampling=True,
        initial_bias=False,
    )
    cfg.check_nonnegative(f"{path}.attitude_process_noise_deg_per_rt_h", c.attitude_process_noise_deg_per_rt_h)
    cfg.check_nonnegative(f"{path}.rate_process_noise_deg_per_s_per_rt_s", c.rate_process_noise_deg_per_s_per_rt_s)
    cfg.check_vector(f"{path}.initial_rate_deg_per_s", c.initial_rate_deg_per_s, 3)
    cfg.check_positive(f"{path}.initial_rate_sigma_deg_per_s", c.initial_rate_sigma_deg_per_s)
    for f, n in (("inertia_kg_m2", (0, 3, 9)), ("disturbance_torque_N_m", (0, 3))):
        if len(getattr(c, f)) not in n:
            cfg.fail(f"{path}.{f}", getattr(c, f), f"must have one of {n} entries (empty = the plant's)")
    inertia, _ = plant_dynamics(checks.scenario, c, path)
    from drake_att.systems.plant import validate_inertia

    try:
        validate_inertia(inertia, f"{path}.inertia_kg_m2")
    except ValueError as e:
        raise cfg.ConfigError(str(e)) from e


@register_estimator(
    GyrolessPfConfig,
    second_quantity=SecondQuantity.BODY_RATE,
    validate=validate_gyroless_pf,
    parameters=(
        "inertia_kg_m2",
        "disturbance_torque_N_m",
        "rate_process_noise_deg_per_s_per_rt_s",
        "attitude_process_noise_deg_per_rt_h",
        "num_substeps",
        "resample_threshold",
        "initial_attitude_rpy_deg",
        "initial_rate_deg_per_s",
        "initial_attitude_sigma_deg",
        "initial_rate_sigma_deg_per_s",
    ),
)
def build_gyroless_pf(ctx, c: GyrolessPfConfig):
    inertia, torque = plant_dynamics(ctx.scenario, c)
    q0 = attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg)
    w0 = np.asarray(c.initial_rate_deg_per_s, dtype=float) * DEG
    P0 = np.diag([(c.initial_attitude_sigma_deg * DEG) ** 2] * 3 + [(c.initial_rate_sigma_deg_per_s * DEG) ** 2] * 3)
    return gyroless_pf_setup(
        c.period_s,
        c.star_tracker,
        c.num_particles,
        q0,
        w0,
        P0,
        inertia,
        torque,
        c.rate_process_noise_deg_per_s_per_rt_s * DEG,
        attitude_process_sigma=c.attitude_process_noise_deg_per_rt_h * ARW_DEG_PER_RT_H,
        num_substeps=c.num_substeps,
        resample_threshold=c.resample_threshold,
        vector_sensors=c.vector_sensors,
    )
