"""A scenario with a sensor monitor and FDIR twins of its MEKFs, for side-by-side studies.

:func:`with_monitor` adds a ``!SensorMonitorConfig`` over the scenario's gyro and quaternion
star trackers (after the last of them and of their fault entries, so it watches what the
estimators read) and, for every MEKF that reads only watched sensors, a twin
``<name><suffix>`` that reads them through the monitor — the same filter, plus the monitor's
verdicts and the held-rate walk during gyro outages. The original estimators are untouched,
so a run scores both on the same truth, noise and faults.
"""

from __future__ import annotations

import dataclasses

from drake_att.scenarios import config as cfg


def with_monitor(
    scenario: cfg.Scenario,
    name: str = "fdir",
    suffix: str = "_fdir",
    held_rate_rrw_deg_per_s15: float = 0.0,
    **monitor_fields,
) -> cfg.Scenario:
    """``scenario`` with a monitor ``name`` and the FDIR twins of its MEKFs (see the module
    docstring); ``monitor_fields`` set the monitor's other fields. Raises
    :class:`~drake_att.validation.ConfigError` when the scenario has nothing to monitor or the
    result is invalid (it is validated like any scenario)."""
    from drake_att.estimators.mekf_plugin import MekfConfig
    from drake_att.scenarios.registry import plugin_for
    from drake_att.sensors.faults_plugin import SensorFaultsConfig
    from drake_att.sensors.sensor_monitor_plugin import SensorMonitorConfig

    sensors = list(scenario.sensors)
    configs = {c.name: c for c in sensors}
    kinds = {}
    for s in sensors:
        output = plugin_for(s).output
        if output is not None:  # every sensor plug-in has one
            kinds[s.name] = output(s, configs).kind
    gyros = [n for n, k in kinds.items() if k == "gyro"]
    trackers = [n for n, k in kinds.items() if k == "quaternion" and _is_real_tracker(sensors, n)]
    if not trackers or len(trackers) + int(bool(gyros)) < 2:
        cfg.fail("sensors", sorted(kinds), "a monitor needs a gyro and a quaternion tracker, or two trackers")
    watched = set(trackers) | set(gyros[:1])
    last = max(
        i
        for i, s in enumerate(sensors)
        if s.name in watched or (isinstance(s, SensorFaultsConfig) and s.sensor in watched)
    )
    monitor = SensorMonitorConfig(name=name, gyro=gyros[0] if gyros else "", star_trackers=trackers, **monitor_fields)
    sensors.insert(last + 1, monitor)
    twins = []
    for e in scenario.estimators:
        if isinstance(e, MekfConfig) and e.gyro in watched and set(e.star_trackers) <= set(trackers):
            if abs(e.period_s - monitor.period_s) > 1e-9:
                continue
            twins.append(
                dataclasses.replace(
                    e, name=e.name + suffix, monitor=name, held_rate_rrw_deg_per_s15=held_rate_rrw_deg_per_s15
                )
            )
    if not twins:
        cfg.fail("estimators", [e.name for e in scenario.estimators], "no MEKF reads only monitored sensors")
    text = cfg.dump_scenario(
        dataclasses.replace(scenario, sensors=sensors, estimators=list(scenario.estimators) + twins)
    )
    return cfg.load_scenario(text)


def _is_real_tracker(sensors, name: str) -> bool:
    """A quaternion sensor that measures (not a virtual one such as a tracker average)."""
    from drake_att.sensors.star_tracker_average_plugin import StarTrackerAverageConfig

    return not any(isinstance(s, StarTrackerAverageConfig) and s.name == name for s in sensors)
