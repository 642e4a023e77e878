"""Sensor plug-in: the averaged star-tracker measurement (paper S3's "centralized" scheme,
:class:`drake_att.systems.fusion.StarTrackerAverage`).

YAML tag ``!StarTrackerAverageConfig``. Output: "quaternion" samples of a virtual sensor
with ``q_BS = identity`` and the derived covariance ``covariance_B``; nothing logged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import numpy as np

from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig
from drake_att.sensors.star_tracker_plugin import StarTrackerConfig, star_tracker_mounting, star_tracker_sigmas_S
from drake_att.systems.estimator_system import QuaternionSensorModel
from drake_att.systems.fusion import StarTrackerAverage, average_measurement_covariance_B, subset_covariances


@dataclass
class StarTrackerAverageConfig:
    """Virtual sensor: weighted quaternion average of quaternion-mode star trackers
    (paper S3's "centralized" scheme).  Its measurement covariance is derived from the
    trackers' noise, mountings and the weights (``drake_att.systems.fusion``)."""

    name: str = "st_avg"
    star_trackers: List[str] = field(default_factory=lambda: ["st1", "st2"])
    weights: List[float] = field(default_factory=lambda: [0.5, 0.5])


def validate_star_tracker_average(path: str, c: StarTrackerAverageConfig, checks) -> None:
    if len(c.star_trackers) < 2:
        cfg.fail(f"{path}.star_trackers", c.star_trackers, "needs at least 2 star trackers")
    cfg.check_listed_once(path, "star_trackers", c.star_trackers)
    trackers = {n: s for n, s in checks.sensors.items() if isinstance(s, (StarTrackerConfig, SkyStarTrackerConfig))}
    for st in c.star_trackers:
        if st not in trackers or getattr(trackers[st], "mode", "quaternion") != "quaternion":
            cfg.fail(
                f"{path}.star_trackers",
                st,
                f"must name a quaternion-mode star tracker listed before it; have {sorted(trackers)}",
            )
    periods = {trackers[st].period_s for st in c.star_trackers}
    if len(periods) != 1:
        cfg.fail(f"{path}.star_trackers", c.star_trackers, f"trackers must share one period; got {sorted(periods)}")
    cfg.check_weights(f"{path}.weights", c.weights, len(c.star_trackers))


def star_tracker_average_output(c: StarTrackerAverageConfig, sensor_configs) -> SensorOutput:
    return SensorOutput("quaternion", "star_tracker_measurement", sensor_configs[c.star_trackers[0]].period_s)


def tracker_sigmas_S(ctx, tracker) -> np.ndarray:
    """A tracker's rotation-vector sigmas in S (rad): a Gaussian tracker's configured ones; a sky
    tracker's from the diagonal of its nominal covariance (nearly diagonal in S: boresight z)."""
    if isinstance(tracker, StarTrackerConfig):
        return star_tracker_sigmas_S(tracker)
    return np.sqrt(np.diag(ctx.quaternion_model(tracker.name).covariance_S))


def star_tracker_average_quaternion_model(ctx, c: StarTrackerAverageConfig) -> QuaternionSensorModel:
    """Identity mounting; the covariance derived from the trackers' configs (so it follows a
    context that changes their noise)."""
    trackers = [ctx.sensor_configs[n] for n in c.star_trackers]
    mountings, sigmas = [star_tracker_mounting(t) for t in trackers], [tracker_sigmas_S(ctx, t) for t in trackers]
    w = np.asarray(c.weights, dtype=float) / np.sum(c.weights)
    return QuaternionSensorModel(
        c.name,
        np.array([1.0, 0.0, 0.0, 0.0]),
        average_measurement_covariance_B(mountings, sigmas, c.weights),
        covariance_by_flag=subset_covariances(mountings, sigmas, w),
    )


@register_sensor(
    StarTrackerAverageConfig,
    output=star_tracker_average_output,
    validate=validate_star_tracker_average,
    quaternion_model=star_tracker_average_quaternion_model,
    logged_ports=lambda c: [],
)
def build_star_tracker_average(ctx, c: StarTrackerAverageConfig):
    trackers = [ctx.sensor_configs[n] for n in c.star_trackers]
    avg = ctx.builder.AddSystem(
        StarTrackerAverage(
            c.name,
            c.star_trackers,
            [star_tracker_mounting(t) for t in trackers],
            [tracker_sigmas_S(ctx, t) for t in trackers],
            c.weights,
            realizations=ctx.realizations,
        )
    )
    for n in c.star_trackers:
        ctx.connect_sensor(n, avg, f"q_meas_{n}")
    return avg
