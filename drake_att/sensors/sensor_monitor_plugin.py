"""Sensor plug-in: the sensor monitor (fault detection and isolation,
:class:`drake_att.systems.sensor_monitor.SensorMonitor`).

YAML tag ``!SensorMonitorConfig``, listed after the sensors it watches and their fault entries.
Its own output is the detector log (kind "monitor", logged at every instant); an estimator reads
the watched sensors through it with ``monitor: <name>`` in its config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List

import numpy as np

from drake_att import fdir
from drake_att import rotations as rot
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.systems.sensor_monitor import SensorMonitor
from drake_att.units import ARW_DEG_PER_RT_H, DEG, RRW_DEG_PER_H_15


@dataclass
class SensorMonitorConfig:
    """Fault detection and isolation over a gyro and quaternion star trackers
    (:mod:`drake_att.fdir`).

    ``gyro``: the watched gyro ("" for none). ``period_s``: the monitor's step (the gyro's
    period; the trackers' periods must divide it). ``frozen_window_s``: how long a sensor's
    numbers may stay bit-for-bit unchanged. ``readmit_after_s``: the clean time an excluded
    sensor needs. ``false_alarm_probability``: per consistency test (3-dof chi-square).
    ``gyro_rate_tolerance_deg_per_s``: the gyro rate error (unestimated bias, bias jumps) the
    vote tolerates; gross gyro faults are isolated. The gyro's range check uses its
    ``range_deg_per_s``. ``bias_window_s``: the window of the gyro bias-shift test (a whole
    number of periods, at least two; 0: off): a shift is logged, not excluded.
    """

    name: str = "monitor"
    gyro: str = "gyro"
    star_trackers: List[str] = field(default_factory=lambda: ["st1", "st2"])
    period_s: float = 1.0
    frozen_window_s: float = 1.0
    readmit_after_s: float = 5.0
    false_alarm_probability: float = 1e-6
    gyro_rate_tolerance_deg_per_s: float = 0.05
    bias_window_s: float = 10.0


def validate_sensor_monitor(path: str, c: SensorMonitorConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    if c.gyro:
        out = checks.sensor_output(c.gyro)
        if out is None or out.kind != "gyro":
            gyros = sorted(n for n in checks.sensors if checks.sensor_output(n).kind == "gyro")
            cfg.fail(f"{path}.gyro", c.gyro, f'must name a gyro listed before it (or "" for none); gyros: {gyros}')
        if abs(out.period_s - c.period_s) > 1e-9:
            cfg.fail(f"{path}.period_s", c.period_s, f"must equal the gyro's period ({out.period_s:g} s)")
    cfg.check_listed_once(path, "star_trackers", c.star_trackers)
    quaternion = sorted(n for n in checks.sensors if checks.sensor_output(n).kind == "quaternion")
    for st in c.star_trackers:
        out = checks.sensor_output(st)
        if out is None or out.kind != "quaternion":
            cfg.fail(f"{path}.star_trackers", st, f"must name a quaternion sensor listed before it; have {quaternion}")
        ratio = c.period_s / out.period_s
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            cfg.fail(f"{path}.period_s", c.period_s, f"must be a whole multiple of {st}'s period ({out.period_s:g} s)")
    if len(c.star_trackers) + int(bool(c.gyro)) < 2:
        cfg.fail(f"{path}.star_trackers", c.star_trackers, "a monitor needs at least two sensors (gyro included)")
    duration = checks.scenario.duration_s
    for f in ("frozen_window_s", "readmit_after_s"):
        cfg.check_finite(f"{path}.{f}", getattr(c, f))
    if c.frozen_window_s > duration:  # a re-admission or bias window longer than the run only never acts
        cfg.fail(
            f"{path}.frozen_window_s",
            c.frozen_window_s,
            f"is longer than the run (duration_s {duration:g}): no sensor could ever be found frozen",
        )
    if c.frozen_window_s < c.period_s:
        cfg.fail(f"{path}.frozen_window_s", c.frozen_window_s, f"must be >= period_s ({c.period_s:g} s)")
    if c.readmit_after_s < 0:
        cfg.fail(f"{path}.readmit_after_s", c.readmit_after_s, "must be >= 0 (s)")
    if not 0.0 < c.false_alarm_probability < 0.5:
        cfg.fail(f"{path}.false_alarm_probability", c.false_alarm_probability, "must be in (0, 0.5) (per test)")
    cfg.check_nonnegative(f"{path}.gyro_rate_tolerance_deg_per_s", c.gyro_rate_tolerance_deg_per_s)
    cfg.check_finite(f"{path}.bias_window_s", c.bias_window_s)
    steps = c.bias_window_s / c.period_s
    if c.bias_window_s and (c.bias_window_s < 0 or steps < 2 or abs(steps - round(steps)) > 1e-9 * steps):
        cfg.fail(f"{path}.bias_window_s", c.bias_window_s, f"must be 0 (off) or >= 2 whole periods ({c.period_s:g} s)")


def sensor_monitor_output(c: SensorMonitorConfig, sensor_configs) -> SensorOutput:
    """The entry's own output: the detector log (kind "monitor": no estimator reads it as a measurement)."""
    return SensorOutput("monitor", "detector_log", c.period_s)


def monitor_model(ctx, c: SensorMonitorConfig) -> fdir.MonitorModel:
    """The :class:`~drake_att.fdir.MonitorModel` of ``c``: the trackers' mountings and noise from
    what the filters assume about them, the gyro's ARW and range from its config."""
    trackers = []
    for st in c.star_trackers:
        qm = ctx.quaternion_model(st)
        R_BS = rot.quat_to_rotmat(qm.q_BS)
        trackers.append(fdir.TrackerModel(st, np.asarray(qm.q_BS), R_BS @ np.asarray(qm.covariance_S) @ R_BS.T))
    arw, rrw, rng = 0.0, 0.0, math.inf
    if c.gyro:
        g = ctx.sensor_configs[c.gyro]
        arw = g.arw_deg_per_rt_h * ARW_DEG_PER_RT_H
        rrw = g.rrw_deg_per_h15 * RRW_DEG_PER_H_15
        rng = math.inf if getattr(g, "range_deg_per_s", None) is None else g.range_deg_per_s * DEG
    return fdir.MonitorModel.make(
        c.name,
        trackers,
        bool(c.gyro),
        c.period_s,
        c.frozen_window_s,
        c.readmit_after_s,
        c.false_alarm_probability,
        arw,
        c.gyro_rate_tolerance_deg_per_s * DEG,
        rng,
        c.bias_window_s if c.gyro else 0.0,
        rrw,
    )


@register_sensor(
    SensorMonitorConfig,
    output=sensor_monitor_output,
    validate=validate_sensor_monitor,
    logged_ports=lambda c: [("detector_log", None)],
)
def build_sensor_monitor(ctx, c: SensorMonitorConfig):
    monitor = ctx.builder.AddSystem(SensorMonitor(monitor_model(ctx, c), c.gyro or None))
    if c.gyro:
        ctx.connect_sensor(c.gyro, monitor, "gyro_measurement")
    for st in c.star_trackers:
        ctx.connect_sensor(st, monitor, f"q_meas_{st}")
    return monitor
