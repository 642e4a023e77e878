"""Checks and conversions shared by estimator plug-ins (config edge -> SI)."""

from __future__ import annotations

import numpy as np

from drake_att import validation
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY, InnovationGate
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.systems.filter_setups import vector_inputs
from drake_att.units import ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15

# The estimator loop's settings a gyro-driven estimator config may carry (context parameters:
# :class:`~drake_att.systems.estimator_system.EstimatorSetup`'s ``max_time_tag_lag_s`` and
# ``held_rate_rrw_rad_per_s15``): how late a time tag may be and the sample still be carried
# forward (s), and the random walk of a held gyro rate's error (deg/s^1.5).
STEP_FIELDS = ("max_time_tag_lag_s", "held_rate_rrw_deg_per_s15")
# The lag alone: for gyro-driven cores that cannot take attitude process noise (the held-rate
# walk needs :class:`~drake_att.contract.AttitudeProcessNoise`, which only the MEKF has).
LAG_FIELDS = ("max_time_tag_lag_s",)


def check_step_settings(path: str, c) -> None:
    """The config's :data:`STEP_FIELDS`: finite and >= 0, the lag below ``period_s`` (a sample
    later than one step belongs to another step)."""
    for f in STEP_FIELDS:
        cfg.check_nonnegative(f"{path}.{f}", getattr(c, f, 0.0))
    if c.max_time_tag_lag_s >= c.period_s:
        cfg.fail(
            f"{path}.max_time_tag_lag_s",
            c.max_time_tag_lag_s,
            f"must be below the estimator's period_s ({c.period_s} s): a sample later than one step belongs to another",
        )


def with_step_settings(setup, c):
    """``setup`` (an :class:`~drake_att.systems.estimator_system.EstimatorSetup`) with the
    config's :data:`STEP_FIELDS` (those it has; 0 for the others)."""
    import dataclasses

    return dataclasses.replace(setup, **step_settings(c))


def step_settings(c) -> dict:
    """:class:`~drake_att.systems.estimator_system.EstimatorSetup` keywords of the config's
    :data:`STEP_FIELDS` (SI)."""
    return {
        "max_time_tag_lag_s": float(getattr(c, "max_time_tag_lag_s", 0.0)),
        "held_rate_rrw_rad_per_s15": float(getattr(c, "held_rate_rrw_deg_per_s15", 0.0)) * DEG,
    }


def require_sensor(checks, path: str, field: str, name: str, kind: str):
    """The config of sensor ``name`` listed before, whose output is of ``kind``."""
    out = checks.sensor_output(name)
    if out is None or out.kind != kind:
        have = sorted(n for n in checks.sensors if checks.sensor_output(n).kind == kind)
        label = {
            "gyro": "gyro",
            "vectors": "vector sensor",
            "quaternion": "quaternion star tracker",
            "camera": "camera",
        }[kind]
        cfg.fail(f"{path}.{field}", name, f"unknown {label}; {label}s listed before: {have}")
    return checks.sensors[name]


def vector_sensor_names(c) -> tuple:
    """The vector-observation sensors filter config ``c`` reads, in update order (its
    ``star_tracker``, ``""``: none, then its ``vector_sensors``)."""
    return vector_inputs(c.star_tracker, getattr(c, "vector_sensors", ()))


def validate_vector_sensors(path: str, c, checks) -> None:
    """A vector filter's sensors: ``star_tracker`` (``""``: none) and ``vector_sensors``, at least one
    in all, each listed once, each a vector-observation sensor listed before whose period fits
    the filter's (:func:`check_period_multiple`)."""
    names = vector_sensor_names(c)
    if not names:
        cfg.fail(
            f"{path}.star_tracker",
            c.star_tracker,
            "names no sensor and vector_sensors is empty: the filter needs at least one vector-observation sensor",
        )
    cfg.check_listed_once(path, "vector_sensors", names)
    fields = (["star_tracker"] if c.star_tracker else []) + [
        f"vector_sensors[{j}]" for j in range(len(getattr(c, "vector_sensors", ())))
    ]
    for f, n in zip(fields, names, strict=True):
        require_sensor(checks, path, f, n, "vectors")
        check_period_multiple(path, c.period_s, n, checks.sensor_output(n).period_s)


def check_period_multiple(path: str, period_s: float, sensor_name: str, sensor_period_s: float) -> None:
    """The filter's steps and the sensor's samples must coincide: one period a whole multiple
    of the other (a filter uses a sample only at its own instant; e.g. paper S1 steps at the
    1 s gyro and updates at every 10 s star sample)."""

    def whole(r):
        return abs(r - round(r)) <= 1e-9 and round(r) >= 1

    if not (whole(period_s / sensor_period_s) or whole(sensor_period_s / period_s)):
        cfg.fail(
            f"{path}.period_s",
            period_s,
            f"must be a whole multiple or a whole fraction of {sensor_name!r}'s period ({sensor_period_s} s): "
            "the filter uses a sample only at its own instant",
        )


def check_gyro_period(path: str, period_s: float, gyro) -> None:
    if abs(gyro.period_s - period_s) > 1e-9:
        cfg.fail(
            f"{path}.period_s",
            period_s,
            f"must equal the period of gyro {gyro.name!r} ({gyro.period_s} s): "
            "the gyro delivers the mean rate over one filter step",
        )


def filter_gyro_noise_deg(c, gyro):
    """The filter's ARW (deg/sqrt(h)) and RRW (deg/h^1.5): the config's, else the gyro's."""
    arw = gyro.arw_deg_per_rt_h if getattr(c, "arw_deg_per_rt_h", None) is None else c.arw_deg_per_rt_h
    rrw = gyro.rrw_deg_per_h15 if getattr(c, "rrw_deg_per_h15", None) is None else c.rrw_deg_per_h15
    return arw, rrw


def filter_gyro_noise(ctx, c):
    """The filter's ARW (rad/s^0.5) and RRW (rad/s^1.5)."""
    arw, rrw = filter_gyro_noise_deg(c, ctx.sensor_configs[c.gyro])
    return arw * ARW_DEG_PER_RT_H, rrw * RRW_DEG_PER_H_15


# The initial-estimate fields of gyro-mode filters: context parameters (sweepable per run).
INITIAL_GYRO_MODE_FIELDS = (
    "initial_attitude_rpy_deg",
    "initial_bias_deg_per_h",
    "initial_attitude_sigma_deg",
    "initial_bias_sigma_deg_per_h",
)


def check_initial_attitude(path: str, c) -> None:
    cfg.check_vector(f"{path}.initial_attitude_rpy_deg", c.initial_attitude_rpy_deg, 3)
    cfg.check_positive(f"{path}.initial_attitude_sigma_deg", c.initial_attitude_sigma_deg)


def check_initial_bias(path: str, c) -> None:
    cfg.check_vector(f"{path}.initial_bias_deg_per_h", c.initial_bias_deg_per_h, 3)
    cfg.check_positive(f"{path}.initial_bias_sigma_deg_per_h", c.initial_bias_sigma_deg_per_h)


def check_flags(path: str, c, *fields) -> None:
    """Each of ``fields`` is true or false (not 0/1, not a string)."""
    for f in fields:
        if not isinstance(getattr(c, f), bool):
            cfg.fail(f"{path}.{f}", getattr(c, f), "must be true or false")


# The gate fields every Kalman-type estimator config has (context parameters).
GATE_FIELDS = ("innovation_gate_chi2", "innovation_gate_probability")


def check_innovation_gate(path: str, c) -> None:
    """``innovation_gate_chi2``: None or a chi-square threshold > 0 (it overrides the
    probability); ``innovation_gate_probability``: in [0, 1), 0 = no gate."""
    if c.innovation_gate_chi2 is not None:
        cfg.check_positive(f"{path}.innovation_gate_chi2", c.innovation_gate_chi2)
    p = cfg.check_finite(f"{path}.innovation_gate_probability", c.innovation_gate_probability)
    if not 0.0 <= p < 1.0:
        cfg.fail(
            f"{path}.innovation_gate_probability",
            p,
            "must be in [0, 1) (0: no gate; default "
            f"{DEFAULT_GATE_PROBABILITY}: 0.1% of nominal measurements rejected)",
        )


def innovation_gate(c) -> InnovationGate:
    """The config's gate: its chi2 threshold if set, else its probability (0: none)."""
    if c.innovation_gate_chi2 is not None:
        return InnovationGate(chi2=float(c.innovation_gate_chi2))
    p = float(c.innovation_gate_probability)
    return InnovationGate(probability=p) if p > 0.0 else InnovationGate()


def check_integers_at_least_one(path: str, c, *fields) -> None:
    for f in fields:
        validation.check_int(f"{path}.{f}", getattr(c, f), 1, cfg.ConfigError)


def check_resample_threshold(path: str, c) -> None:
    cfg.check_finite(f"{path}.resample_threshold", c.resample_threshold)
    if not 0 < c.resample_threshold <= 1:
        cfg.fail(f"{path}.resample_threshold", c.resample_threshold, "must be in (0, 1] (fraction of N)")


def initial_gyro_mode_estimate(ctx, c):
    """``(q0, b0 (rad/s), P0 (6, 6))`` from the config's attitude/bias and their sigmas."""
    q0 = attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg)
    b0 = np.asarray(c.initial_bias_deg_per_h, dtype=float) * DEG_PER_H
    P0 = np.diag(
        [(c.initial_attitude_sigma_deg * DEG) ** 2] * 3 + [(c.initial_bias_sigma_deg_per_h * DEG_PER_H) ** 2] * 3
    )
    return q0, b0, P0


def validate_vector_filter(
    path: str,
    c,
    checks,
    uses_gyro: bool = True,
    integer_fields=(),
    resampling: bool = False,
    filter_gyro_noise: bool = False,
    initial_bias: bool = True,
    initial_sigma: bool = True,
):
    """Checks shared by filters fed by vector-observation sensors (and a gyro): paper S0's, with
    one vector-mode tracker, or any sensors of ``vector_sensors`` (:func:`validate_vector_sensors`).

    Args:
        integer_fields: config fields that must be integers >= 1 (particles, iterations).
        resampling: check ``resample_threshold`` in (0, 1].
        filter_gyro_noise: the filter models the gyro noise (its ARW, or the gyro's, > 0).
        initial_bias: check ``initial_bias_deg_per_h`` and its sigma.
        initial_sigma: check ``initial_attitude_sigma_deg`` (filters with another P0 field: False).
    Returns:
        The gyro's config (None without a gyro).
    """
    cfg.check_positive(f"{path}.period_s", c.period_s)
    gyro = None
    if uses_gyro:
        gyro = require_sensor(checks, path, "gyro", c.gyro, "gyro")
        check_gyro_period(path, c.period_s, gyro)
    validate_vector_sensors(path, c, checks)
    if initial_sigma:
        check_initial_attitude(path, c)
    else:
        cfg.check_vector(f"{path}.initial_attitude_rpy_deg", c.initial_attitude_rpy_deg, 3)
    check_integers_at_least_one(path, c, *integer_fields)
    if resampling:
        check_resample_threshold(path, c)
    if filter_gyro_noise:
        validate_filter_gyro_noise(path, c, gyro)
    if initial_bias:
        check_initial_bias(path, c)
    return gyro


def validate_filter_gyro_noise(path: str, c, gyro) -> None:
    """The filter's ARW/RRW (its own or the gyro's) are usable: ARW > 0, RRW >= 0."""
    for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15"):
        if getattr(c, f, None) is not None:
            cfg.check_nonnegative(f"{path}.{f}", getattr(c, f))
    arw, _ = filter_gyro_noise_deg(c, gyro)
    if not arw > 0:
        cfg.fail(
            f"{path}.arw_deg_per_rt_h",
            arw,
            f"the filter needs an ARW > 0 (deg/sqrt(h)); gyro {gyro.name!r} has "
            f"{gyro.arw_deg_per_rt_h!r} and the filter sets none",
        )


def check_monitor(path: str, c, checks, sensors) -> None:
    """``c.monitor`` ("" or the name of a sensor monitor listed before it that watches every one
    of ``sensors`` and steps at the estimator's period)."""
    if not c.monitor:
        return
    from drake_att.sensors.sensor_monitor_plugin import SensorMonitorConfig

    m = checks.sensors.get(c.monitor)
    if not isinstance(m, SensorMonitorConfig):
        monitors = sorted(n for n, s in checks.sensors.items() if isinstance(s, SensorMonitorConfig))
        cfg.fail(
            f"{path}.monitor", c.monitor, f"must name a !SensorMonitorConfig listed before it; monitors: {monitors}"
        )
    watched = ([m.gyro] if m.gyro else []) + list(m.star_trackers)
    missing = [n for n in sensors if n not in watched]
    if missing:
        cfg.fail(f"{path}.monitor", c.monitor, f"does not watch {missing}; it watches {watched}")
    if abs(m.period_s - c.period_s) > 1e-9:
        cfg.fail(
            f"{path}.monitor",
            c.monitor,
            f"steps every {m.period_s:g} s; the filter every {c.period_s:g} s: they must agree",
        )
