"""Estimator plug-in: paper S4's Lie-group (SO(3)) filter
(:class:`drake_att.filters.lie_group.LieGroupFilter`), fed by a gyro and one star tracker
(vector mode, or quaternion mode with the consistent formulation). YAML tag ``!LieGroupConfig``.

``formulation: consistent`` (default) is the filter in one consistent error convention (the
project's ``R_IB = R_IB_hat exp([dtheta_B x])``); ``formulation: paper_literal`` is eqs
26-32 as printed, which do not converge (SPEC.md S4). Paper tuning (the defaults):
``P0 = 5 I3``, ``Q_w = 5e-5 I3`` per 1 s step, ``Q_v = 0.125^2``.

``estimate_gyro_bias: true`` (beyond the paper) adds the gyro-bias error state (SO(3) x
R^3, second output ``bias_B_hat``): the process noise is then the Farrenkopf model of the
filter's gyro ARW/RRW (default: the gyro's configured values, as the MEKF plug-in) and
``Q_w`` defaults to 0. With a bias state the filter coincides with the MEKF to round-off
(see :mod:`drake_att.filters.lie_group`). ``estimate_gyro_bias`` is structural (it changes
the state size and the second output); the tunings and initial values are context
parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY
from drake_att.filters.lie_group import FORMULATIONS, LieGroupFilter
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.estimator_system import EstimatorSetup
from drake_att.systems.filter_setups import vector_inputs
from drake_att.units import ARW_DEG_PER_RT_H, DEG_PER_H

TRACKER_KINDS = ("vectors", "quaternion")


@dataclass
class LieGroupConfig:
    """Paper S4's Lie-group filter; without a bias state (the paper) the second vector is the
    body rate, with ``estimate_gyro_bias`` it is the gyro bias.

    Attributes:
        star_tracker: a vector-mode star tracker, or a quaternion-mode one (consistent
            formulation only; its own noise model is used, ``star_noise_variance_rad2`` is not).
        vector_sensors: further vector-observation sensors (sun sensors, a magnetometer) updated
            on after the tracker at the same step; they take ``Q_v`` as the tracker's vectors do
            (``star_noise_from_tracker``: each sample's own sigma).
        formulation: "consistent" or "paper_literal".
        initial_attitude_variance_rad2: ``P0 = value * I3`` (rad^2; paper 5).
        process_noise_rad2_per_step: ``Q_w = value * I3`` per ``period_s`` (rad^2); None:
            the paper's 5e-5 without a bias state, 0 with one.
        star_noise_variance_rad2: ``Q_v`` per direction component (rad^2; paper 0.125^2).
            ``null`` is refused: Drake's YAML dump omits it, so the scenario's round trip
            (overrides, ``diagram_for``) would turn it into the default 0.125^2.
        star_noise_from_tracker: use the tracker's ``sigma_vector_urad`` squared as ``Q_v``
            (instead of ``star_noise_variance_rad2``).
        gyro_arw_deg_per_rt_h: no bias state only: the gyro ARW the filter models (adds
            ``arw^2 dt`` and sets the rate block); None: the process noise is ``Q_w`` only.
        estimate_gyro_bias: add the gyro-bias state (structural: a new diagram).
        arw_deg_per_rt_h, rrw_deg_per_h15: bias state only: the filter's gyro ARW
            (deg/sqrt(h)) and RRW (deg/h^1.5); None: the gyro's configured values.
        initial_bias_deg_per_h, initial_bias_sigma_deg_per_h: bias state only: initial bias
            estimate and its 1-sigma per axis.
    """

    name: str = "lie_group"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    formulation: str = "consistent"
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_variance_rad2: float = 5.0
    process_noise_rad2_per_step: Optional[float] = None
    star_noise_variance_rad2: float = 0.015625
    star_noise_from_tracker: bool = False
    gyro_arw_deg_per_rt_h: Optional[float] = None
    innovation_gate_chi2: Optional[float] = None
    innovation_gate_probability: float = DEFAULT_GATE_PROBABILITY
    estimate_gyro_bias: bool = False
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_sigma_deg_per_h: float = 20.0


def validate_lie_group(path: str, c: LieGroupConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    gyro = common.require_sensor(checks, path, "gyro", c.gyro, "gyro")
    common.check_gyro_period(path, c.period_s, gyro)
    out = checks.sensor_output(c.star_tracker)
    if out is None or out.kind not in TRACKER_KINDS:
        have = sorted(n for n in checks.sensors if checks.sensor_output(n).kind in TRACKER_KINDS)
        cfg.fail(
            f"{path}.star_tracker",
            c.star_tracker,
            f"unknown star tracker (vector or quaternion mode); star trackers listed before: {have}",
        )
    common.check_period_multiple(path, c.period_s, c.star_tracker, out.period_s)
    cfg.check_listed_once(path, "vector_sensors", [c.star_tracker, *c.vector_sensors])
    for j, n in enumerate(c.vector_sensors):
        common.require_sensor(checks, path, f"vector_sensors[{j}]", n, "vectors")
        common.check_period_multiple(path, c.period_s, n, checks.sensor_output(n).period_s)
    if c.formulation not in FORMULATIONS:
        cfg.fail(f"{path}.formulation", c.formulation, f"allowed: {list(FORMULATIONS)}")
    if c.formulation != "consistent" and out.kind == "quaternion":
        cfg.fail(
            f"{path}.formulation",
            c.formulation,
            f"star tracker {c.star_tracker!r} is in quaternion mode: "
            "the paper's literal update is defined for star vectors only; use 'consistent'",
        )
    common.check_flags(path, c, "estimate_gyro_bias")
    if c.estimate_gyro_bias and c.formulation != "consistent":
        cfg.fail(
            f"{path}.estimate_gyro_bias",
            c.estimate_gyro_bias,
            f"the bias state needs formulation 'consistent' (got {c.formulation!r})",
        )
    cfg.check_vector(f"{path}.initial_attitude_rpy_deg", c.initial_attitude_rpy_deg, 3)
    cfg.check_positive(f"{path}.initial_attitude_variance_rad2", c.initial_attitude_variance_rad2)
    if c.process_noise_rad2_per_step is not None:
        cfg.check_nonnegative(f"{path}.process_noise_rad2_per_step", c.process_noise_rad2_per_step)
    cfg.check_positive(f"{path}.star_noise_variance_rad2", c.star_noise_variance_rad2)
    common.check_flags(path, c, "star_noise_from_tracker")
    common.check_innovation_gate(path, c)
    if c.estimate_gyro_bias:
        if c.gyro_arw_deg_per_rt_h is not None:
            cfg.fail(
                f"{path}.gyro_arw_deg_per_rt_h",
                c.gyro_arw_deg_per_rt_h,
                "is the no-bias filter's ARW; with estimate_gyro_bias set arw_deg_per_rt_h (and rrw_deg_per_h15)",
            )
        for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15"):
            if getattr(c, f) is not None:
                cfg.check_nonnegative(f"{path}.{f}", getattr(c, f))
        common.check_initial_bias(path, c)
    else:
        if c.gyro_arw_deg_per_rt_h is not None:
            cfg.check_nonnegative(f"{path}.gyro_arw_deg_per_rt_h", c.gyro_arw_deg_per_rt_h)
        for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15"):
            if getattr(c, f) is not None:
                cfg.fail(
                    f"{path}.{f}",
                    getattr(c, f),
                    "is used only with estimate_gyro_bias: true (without a bias "
                    "state the filter's gyro ARW is gyro_arw_deg_per_rt_h)",
                )


def lie_group_second_quantity(c: LieGroupConfig, checks) -> SecondQuantity:
    """The gyro bias with ``estimate_gyro_bias``, else the body rate (the paper)."""
    return SecondQuantity.GYRO_BIAS if c.estimate_gyro_bias else SecondQuantity.BODY_RATE


@register_estimator(
    LieGroupConfig,
    second_quantity=lie_group_second_quantity,
    validate=validate_lie_group,
    parameters=(
        "formulation",
        "initial_attitude_rpy_deg",
        "initial_attitude_variance_rad2",
        "process_noise_rad2_per_step",
        "star_noise_variance_rad2",
        "star_noise_from_tracker",
        "gyro_arw_deg_per_rt_h",
        *common.GATE_FIELDS,
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        "initial_bias_deg_per_h",
        "initial_bias_sigma_deg_per_h",
    ),
)
def build_lie_group(ctx, c: LieGroupConfig) -> EstimatorSetup:
    if c.estimate_gyro_bias:
        arw, rrw = common.filter_gyro_noise(ctx, c)
    else:
        arw = None if c.gyro_arw_deg_per_rt_h is None else c.gyro_arw_deg_per_rt_h * ARW_DEG_PER_RT_H
        rrw = None
    Q_v = None if c.star_noise_from_tracker else c.star_noise_variance_rad2
    core = LieGroupFilter(
        Q_w=c.process_noise_rad2_per_step,
        Q_v=Q_v,
        formulation=c.formulation,
        step_s=c.period_s,
        gyro_arw_rad_per_rt_s=arw,
        innovation_gate_chi2=common.innovation_gate(c),
        estimate_gyro_bias=c.estimate_gyro_bias,
        gyro_rrw_rad_per_s15=rrw,
    )
    q0 = attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg)
    if c.estimate_gyro_bias:
        P0 = np.diag([c.initial_attitude_variance_rad2] * 3 + [(c.initial_bias_sigma_deg_per_h * DEG_PER_H) ** 2] * 3)
        init = core.initial_state(q0, P0, bias_B=np.asarray(c.initial_bias_deg_per_h, dtype=float) * DEG_PER_H)
    else:
        init = core.initial_state(q0, c.initial_attitude_variance_rad2)
    if ctx.sensor_output(c.star_tracker).kind == "quaternion":
        return EstimatorSetup(
            core,
            init,
            c.period_s,
            gyro=c.gyro,
            quaternion_sensors=(ctx.quaternion_model(c.star_tracker),),
            vector_sensors=tuple(c.vector_sensors),
        )
    return EstimatorSetup(
        core, init, c.period_s, gyro=c.gyro, vector_sensors=vector_inputs(c.star_tracker, c.vector_sensors)
    )
