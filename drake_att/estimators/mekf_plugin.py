"""Estimator plug-in: the multiplicative EKF (:class:`drake_att.filters.mekf.MultiplicativeEKF`)
fed by one gyro and any number of quaternion and vector star trackers (papers S3 and S0's
sensor set). YAML tag ``!MekfConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY
from drake_att.filters.mekf import MultiplicativeEKF
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.estimator_system import EstimatorSetup
from drake_att.units import ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15


@dataclass
class MekfConfig:
    """MEKF fed by one gyro and star trackers (names of sensors).

    The filter's gyro noise defaults to the gyro's configured ARW/RRW (``None``).
    ``coning_correction``: propagate with the two-sample coning-corrected rotation (the
    previous step's gyro increment; :mod:`drake_att.filters.mekf`), for filter steps that
    are long relative to how fast the rate vector turns (a fast tumble). Structural: it adds
    the previous increment to the core's state (47 numbers instead of 43), so changing it
    needs a new diagram (it is not a context parameter). Default off.

    ``max_time_tag_lag_s``: a sample tagged up to this much before the filter step (and after
    the input's last handled sample) is carried forward to the step with the step's rate and
    used, its noise grown by the rate's uncertainty over the gap; later ones, and future tags,
    are rejected and counted (:mod:`drake_att.systems.estimator_system`). Must be below
    ``period_s``; 0 (default): only samples of the step's own instant.
    ``held_rate_rrw_deg_per_s15``: while the gyro sample is unusable the last valid rate is
    held; its error is modelled as a random walk of this intensity from the last usable
    sample, which grows the attitude covariance
    (:func:`drake_att.systems.estimator_step.held_rate_variance`). 0 (default): none.
    ``monitor``: the name of a ``!SensorMonitorConfig`` watching this filter's gyro and
    quaternion trackers: the filter reads them through it (an excluded sensor's samples are
    skipped and counted) with its verdicts (a confirmed sample the gate rejects recovers the
    prediction at once). "" (default): none.
    """

    name: str = "mekf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_trackers: List[str] = field(default_factory=lambda: ["st1"])
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 5.0
    initial_bias_sigma_deg_per_h: float = 20.0
    innovation_gate_chi2: Optional[float] = None
    innovation_gate_probability: float = DEFAULT_GATE_PROBABILITY
    coning_correction: bool = False
    max_time_tag_lag_s: float = 0.0
    held_rate_rrw_deg_per_s15: float = 0.0
    monitor: str = ""


def validate_mekf(path: str, c: MekfConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    gyro = common.require_sensor(checks, path, "gyro", c.gyro, "gyro")
    common.check_gyro_period(path, c.period_s, gyro)
    if not c.star_trackers:
        cfg.fail(f"{path}.star_trackers", c.star_trackers, "needs at least one star tracker")
    cfg.check_listed_once(path, "star_trackers", c.star_trackers)
    trackers = sorted(n for n in checks.sensors if checks.sensor_output(n).kind in ("quaternion", "vectors"))
    for st in c.star_trackers:
        out = checks.sensor_output(st)
        if out is None or out.kind not in ("quaternion", "vectors"):
            cfg.fail(f"{path}.star_trackers", st, f"unknown star tracker; star trackers: {trackers}")
        common.check_period_multiple(path, c.period_s, st, out.period_s)
    for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15"):
        if getattr(c, f) is not None:
            cfg.check_nonnegative(f"{path}.{f}", getattr(c, f))
    common.check_initial_attitude(path, c)
    common.check_initial_bias(path, c)
    common.check_innovation_gate(path, c)
    common.check_flags(path, c, "coning_correction")
    common.check_step_settings(path, c)
    common.check_monitor(path, c, checks, [c.gyro, *c.star_trackers])


@register_estimator(
    MekfConfig,
    second_quantity=SecondQuantity.GYRO_BIAS,
    validate=validate_mekf,
    parameters=(
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        *common.GATE_FIELDS,
        *common.INITIAL_GYRO_MODE_FIELDS,
        *common.STEP_FIELDS,
    ),
)
def build_mekf(ctx, c: MekfConfig) -> EstimatorSetup:
    arw, rrw = common.filter_gyro_noise_deg(c, ctx.sensor_configs[c.gyro])
    core = MultiplicativeEKF(
        arw * ARW_DEG_PER_RT_H, rrw * RRW_DEG_PER_H_15, common.innovation_gate(c), coning_correction=c.coning_correction
    )
    init = core.initial_state(
        attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg),
        np.asarray(c.initial_bias_deg_per_h) * DEG_PER_H,
        c.initial_attitude_sigma_deg * DEG,
        c.initial_bias_sigma_deg_per_h * DEG_PER_H,
    )
    quaternion = [n for n in c.star_trackers if ctx.sensor_output(n).kind == "quaternion"]
    return EstimatorSetup(
        core,
        init,
        c.period_s,
        gyro=c.gyro,
        quaternion_sensors=tuple(ctx.quaternion_model(n) for n in quaternion),
        vector_sensors=tuple(n for n in c.star_trackers if n not in quaternion),
        monitor=c.monitor or None,
        **common.step_settings(c),
    )
