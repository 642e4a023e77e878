"""Which estimators a run keeps: the estimators a fusion fuses (its sources), and a copy of
a scenario with a selection of its estimators. A fusion is any estimator config with a
``sources`` list of estimator names (:class:`~drake_att.estimators.estimate_fusion_plugin.EstimateFusionConfig`)."""

from __future__ import annotations

import copy

from drake_att.scenarios import config as cfg


def fused_sources(config) -> list[str]:
    """The names of the estimators ``config`` fuses (empty: it fuses none)."""
    return list(getattr(config, "sources", []))


def measurement_sensor_names(config) -> list[str]:
    """The attitude sensors estimator ``config`` reads, in update order: its ``star_trackers`` (or
    its ``star_tracker``; ``""``: none), then its ``vector_sensors`` (a camera is not included)."""
    trackers = getattr(config, "star_trackers", None) or (
        [config.star_tracker] if getattr(config, "star_tracker", None) else []
    )
    return list(trackers) + list(getattr(config, "vector_sensors", None) or [])


def with_fused_sources(configs: dict, names) -> list[str]:
    """``names`` and every estimator they fuse, directly or through another fusion, each
    once, breadth first (``configs``: estimator name -> config)."""
    out = list(dict.fromkeys(names))
    i = 0
    while i < len(out):
        out += [s for s in fused_sources(configs[out[i]]) if s not in out]
        i += 1
    return out


def with_estimators(scenario: cfg.Scenario, names, field: str = "estimators", allow_empty: bool = True) -> cfg.Scenario:
    """A copy of ``scenario`` with only the estimators ``names`` (in the scenario's order).

    Raises:
        ConfigError naming ``field``: ``names`` is a string, names an unknown estimator, is
            empty when ``allow_empty`` is false, or leaves out the source of a selected fusion.
    """
    have = [e.name for e in scenario.estimators]
    unknown = [] if isinstance(names, str) else [n for n in names if n not in have]
    if isinstance(names, str) or unknown or (not allow_empty and not list(names)):
        raise cfg.ConfigError(
            f"{field}: got {names!r}; choose a list of names from {have}"
            + (" (empty: sensors only)" if allow_empty else "")
        )
    names = list(names)
    keep = [e for e in scenario.estimators if e.name in names]
    for e in keep:
        missing = [s for s in fused_sources(e) if s not in names]
        if missing:
            raise cfg.ConfigError(f"{field}: {e.name!r} fuses {missing}, which are not selected")
    scenario = copy.deepcopy(scenario)
    scenario.estimators = copy.deepcopy(keep)
    return scenario
