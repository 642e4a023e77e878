"""Sensor plug-in: fault injection into another sensor's measurements
(:class:`drake_att.systems.fault_injector.FaultInjector`). YAML tag ``!SensorFaultsConfig``.

List it in ``sensors:`` right after the sensor it corrupts (``sensor``) and before any
sensor that reads that sensor (e.g. a ``!StarTrackerAverageConfig``): from then on every
consumer — virtual sensors and estimators — reads the faulted measurement
(:meth:`~drake_att.scenarios.build_context.BuildContext.connect_sensor`); the sensor's own
output (and its logged measurement) stays the clean one. At most one entry per sensor.

Example (paper S3's tracker 1, a 1 deg outlier at t = 100 s, a 20 s outage)::

    - !StarTrackerConfig {name: st1, ...}
    - !SensorFaultsConfig
      name: st1_faults
      sensor: st1
      outlier_times_s: [100.0]
      outlier_angle_deg: 1.0
      outage_windows_s: [[200.0, 220.0]]

Sizes are in the sensor's units: ``outlier_angle_deg`` for attitude sensors (star trackers,
the averaged tracker, a camera: the sample rotated by that angle), ``outlier_rate_deg_per_s``
for a gyro. What each kind does, the times convention (a fault "at t" hits the first sample
at or after t; windows are ``[start, end)``) and the logged truth are documented in
:mod:`drake_att.systems.fault_injector`. Logged: ``fault_truth`` at every sample (what was
injected, and the time tag and validity the consumers read); the sensor's own logged
measurement is the clean one.

Every fault field is a context parameter: a run may change or clear them without a new
diagram (``--set sensors.st1_faults.outlier_times_s=[]``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import PluginError, SensorOutput, plugin_for, register_sensor
from drake_att.systems.fault_injector import KINDS, FaultInjector, FaultModel
from drake_att.units import DEG, DEG_PER_H


@dataclass
class SensorFaultsConfig:
    """Faults injected into sensor ``sensor``'s measurements (each kind off by default).

    Times in s; windows ``[[start, end], ...]`` (s). Probabilities are per sample.
    """

    name: str = "faults"
    sensor: str = "gyro"
    outlier_probability: float = 0.0
    outlier_times_s: List[float] = field(default_factory=list)
    outlier_angle_deg: float = 1.0  # attitude sensors: rotation of the sample
    outlier_rate_deg_per_s: float = 1.0  # gyro: added rate (random direction)
    nan_probability: float = 0.0
    nan_times_s: List[float] = field(default_factory=list)
    inf_probability: float = 0.0
    inf_times_s: List[float] = field(default_factory=list)
    stuck_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    dropout_probability: float = 0.0
    dropout_times_s: List[float] = field(default_factory=list)
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    saturation_deg_per_s: Optional[float] = None  # gyro: per-axis range (None: none)
    saturation_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # empty: the whole run
    bias_jump_times_s: List[float] = field(default_factory=list)  # gyro
    bias_jumps_deg_per_h: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # one row per time
    time_tag_offset_s: float = 0.0
    time_tag_times_s: List[float] = field(default_factory=list)
    time_tag_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


FAULT_FIELDS = tuple(f.name for f in dataclasses.fields(SensorFaultsConfig) if f.name not in ("name", "sensor"))
_TIME_FIELDS = (
    "outlier_times_s",
    "nan_times_s",
    "inf_times_s",
    "dropout_times_s",
    "bias_jump_times_s",
    "time_tag_times_s",
)
_WINDOW_FIELDS = ("stuck_windows_s", "outage_windows_s", "saturation_windows_s", "time_tag_windows_s")
_PROBABILITY_FIELDS = ("outlier_probability", "nan_probability", "inf_probability", "dropout_probability")


def _rows(value, width: int) -> np.ndarray:
    return np.reshape(np.asarray(value, dtype=float), (-1, width)) if np.size(value) else np.zeros((0, width))


def references(config, name: str) -> bool:
    """Whether ``config`` (a sensor or estimator config) names ``name`` in a field other
    than its own ``name`` (a string field or a list of strings): it reads that sensor."""
    for f in dataclasses.fields(config):
        if f.name == "name":
            continue
        v = getattr(config, f.name)
        if v == name if isinstance(v, str) else (isinstance(v, list) and name in [x for x in v if isinstance(x, str)]):
            return True
    return False


def validate_sensor_faults(path: str, c: SensorFaultsConfig, checks) -> None:
    out = checks.sensor_output(c.sensor)
    if out is None:
        cfg.fail(f"{path}.sensor", c.sensor, f"must name a sensor listed before it; sensors: {sorted(checks.sensors)}")
    if out.kind not in KINDS:
        cfg.fail(f"{path}.sensor", c.sensor, f"its output is {out.kind!r}; faults can be injected into {list(KINDS)}")
    names = list(checks.sensors)
    for other in names:
        o = checks.sensors[other]
        if isinstance(o, SensorFaultsConfig) and o.sensor == c.sensor:
            cfg.fail(f"{path}.sensor", c.sensor, f"{other!r} already injects faults into it (one entry per sensor)")
    for other in names[names.index(c.sensor) + 1 :]:
        if references(checks.sensors[other], c.sensor):
            cfg.fail(
                f"{path}.sensor",
                c.sensor,
                f"{other!r} (listed before this entry) reads it and would see the clean output: list this "
                f"entry right after {c.sensor!r}",
            )
    for f in _PROBABILITY_FIELDS:
        cfg.check_finite(f"{path}.{f}", getattr(c, f))
        if not 0.0 <= getattr(c, f) < 1.0:
            cfg.fail(f"{path}.{f}", getattr(c, f), "must be in [0, 1) (per sample)")
    for f in _TIME_FIELDS:
        for j, t in enumerate(getattr(c, f)):
            cfg.check_nonnegative(f"{path}.{f}[{j}]", t)
    for f in _WINDOW_FIELDS:
        v = getattr(c, f)
        if np.size(v) and (np.ndim(v) != 2 or np.shape(v)[1] != 2):
            cfg.fail(f"{path}.{f}", v, "must be a list of [start, end] (s)")
        for j, w in enumerate(_rows(v, 2)):
            if not (np.all(np.isfinite(w)) and w[1] > w[0]):
                cfg.fail(f"{path}.{f}[{j}]", w, "must be [start, end] (s), finite, with end > start")
    gyro = out.kind == "gyro"
    outliers = c.outlier_probability > 0 or len(c.outlier_times_s) > 0
    if gyro:
        size = cfg.check_finite(f"{path}.outlier_rate_deg_per_s", c.outlier_rate_deg_per_s)
        if outliers and not size > 0:
            cfg.fail(f"{path}.outlier_rate_deg_per_s", size, "gyro outliers need a size > 0 (deg/s)")
    else:
        size = cfg.check_finite(f"{path}.outlier_angle_deg", c.outlier_angle_deg)
        if outliers and not 0 < size < 180:
            cfg.fail(f"{path}.outlier_angle_deg", size, "an attitude outlier is a rotation angle in (0, 180) deg")
    if c.saturation_deg_per_s is not None:
        if not gyro:
            cfg.fail(
                f"{path}.saturation_deg_per_s",
                c.saturation_deg_per_s,
                f"only a gyro saturates; {c.sensor!r} outputs {out.kind!r}",
            )
        cfg.check_positive(f"{path}.saturation_deg_per_s", c.saturation_deg_per_s)
    elif np.size(c.saturation_windows_s):
        cfg.fail(f"{path}.saturation_windows_s", c.saturation_windows_s, "needs saturation_deg_per_s")
    if len(c.bias_jump_times_s) and not gyro:
        cfg.fail(
            f"{path}.bias_jump_times_s",
            c.bias_jump_times_s,
            f"only a gyro has bias jumps; {c.sensor!r} outputs {out.kind!r}",
        )
    jumps = c.bias_jumps_deg_per_h
    if (np.size(jumps) or len(c.bias_jump_times_s)) and (
        np.ndim(jumps) != 2 or np.shape(jumps) != (len(c.bias_jump_times_s), 3)
    ):
        cfg.fail(
            f"{path}.bias_jumps_deg_per_h",
            jumps,
            f"need one row [x, y, z] (deg/h) per bias_jump_times_s entry ({len(c.bias_jump_times_s)})",
        )
    for j, row in enumerate(_rows(jumps, 3)):
        cfg.check_vector(f"{path}.bias_jumps_deg_per_h[{j}]", list(row), 3)
    cfg.check_finite(f"{path}.time_tag_offset_s", c.time_tag_offset_s)
    if (len(c.time_tag_times_s) or np.size(c.time_tag_windows_s)) and c.time_tag_offset_s == 0.0:
        cfg.fail(f"{path}.time_tag_offset_s", c.time_tag_offset_s, "time-tag errors need a non-zero offset (s)")
    try:
        fault_model(c, out.kind)
    except ValueError as e:  # anything the system-level check still refuses
        raise cfg.ConfigError(f"{path}: {e}") from e


def fault_model(c: SensorFaultsConfig, kind: str) -> FaultModel:
    """The config's :class:`FaultModel` (SI) for a sensor whose output is ``kind``."""
    saturation = math.inf if c.saturation_deg_per_s is None else c.saturation_deg_per_s * DEG
    size = c.outlier_rate_deg_per_s * DEG if kind == "gyro" else c.outlier_angle_deg * DEG
    return FaultModel.make(
        c.name,
        kind,
        outlier_probability=c.outlier_probability,
        outlier_times_s=tuple(c.outlier_times_s),
        outlier_size=size,
        nan_probability=c.nan_probability,
        nan_times_s=tuple(c.nan_times_s),
        inf_probability=c.inf_probability,
        inf_times_s=tuple(c.inf_times_s),
        dropout_probability=c.dropout_probability,
        dropout_times_s=tuple(c.dropout_times_s),
        outage_windows_s=tuple(map(tuple, _rows(c.outage_windows_s, 2))),
        stuck_windows_s=tuple(map(tuple, _rows(c.stuck_windows_s, 2))),
        saturation_rad_per_s=saturation,
        saturation_windows_s=tuple(map(tuple, _rows(c.saturation_windows_s, 2))),
        bias_jump_times_s=tuple(c.bias_jump_times_s),
        bias_jumps_rad_per_s=tuple(map(tuple, _rows(c.bias_jumps_deg_per_h, 3) * DEG_PER_H)),
        time_tag_offset_s=float(c.time_tag_offset_s),
        time_tag_times_s=tuple(c.time_tag_times_s),
        time_tag_windows_s=tuple(map(tuple, _rows(c.time_tag_windows_s, 2))),
    )


def faults_output(c: SensorFaultsConfig, sensor_configs) -> SensorOutput:
    """The entry's own output: the fault truth, at the corrupted sensor's period (kind
    "faults": no estimator reads it as a measurement)."""
    target = sensor_configs[c.sensor]
    output = plugin_for(target).output
    if output is None:  # validation admits sensors only; a plug-in without an output is a bug
        raise PluginError(f"{c.sensor}: {type(target).__name__} is not a sensor's config")
    return SensorOutput("faults", "fault_truth", output(target, sensor_configs).period_s)


def faults_logged_ports(c: SensorFaultsConfig):
    """``fault_truth`` at every sample (period None: the entry's output period)."""
    return [("fault_truth", None)]


def configure_sensor_faults(ctx, c: SensorFaultsConfig, injector: FaultInjector, context) -> None:
    injector.set_model(context, fault_model(c, ctx.sensor_output(c.sensor).kind))


@register_sensor(
    SensorFaultsConfig,
    output=faults_output,
    validate=validate_sensor_faults,
    logged_ports=faults_logged_ports,
    parameters=FAULT_FIELDS,
    configure=configure_sensor_faults,
)
def build_sensor_faults(ctx, c: SensorFaultsConfig):
    out = ctx.sensor_output(c.sensor)
    injector = ctx.builder.AddSystem(FaultInjector(c.name, out.kind, out.period_s, fault_model(c, out.kind)))
    source, port = ctx.measurement_source(c.sensor)
    ctx.builder.Connect(source.GetOutputPort(port), injector.GetInputPort("sensor_measurement"))
    ctx.measurement_sources[c.sensor] = (injector, "measurement")
    return injector
