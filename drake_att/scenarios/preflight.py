"""Warnings for scenarios that are valid but degenerate (issue 12): checked before a run
starts (:func:`preflight_warnings`) and after it (:func:`run_warnings`).

* **Cost**: the number of discrete events (every sensor sample and estimator step over the
  run) and a rough wall time at :data:`SECONDS_PER_EVENT` (the cost of one Python event with
  its share of integration and logging, measured on the S3 10 Hz case): a 1e-4 s sensor period
  that turns a 5000 s run into hours is announced before it starts.
* **Observability**: a vector-mode star tracker whose reference directions are all parallel
  (or a single one) leaves the attitude unobservable about that direction.
* **Starved estimators** (after the run): an estimator that used no measurement at all
  published only its prediction from the initial state.

The CLI prints these as ``drake-att: warning: ...``; :class:`ScenarioDiagram` raises them as
Python warnings (:class:`DegenerateScenarioWarning`) for notebook and script users.
"""

from __future__ import annotations

import numpy as np

SECONDS_PER_EVENT = 60e-6
EXPENSIVE_WALL_S = 600.0


class DegenerateScenarioWarning(UserWarning):
    """A valid scenario that will not do what its author likely meant."""


def _human(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def event_count(scenario) -> tuple[float, list]:
    """``(events, [(path of a period, period_s), ...])``: the periodic events of a run."""
    periods = []
    for kind, items in (("sensors", scenario.sensors), ("estimators", scenario.estimators)):
        for item in items:
            p = getattr(item, "period_s", None)
            if isinstance(p, (int, float)) and p > 0:
                periods.append((f"{kind}.{item.name}.period_s", float(p)))
    return sum(scenario.duration_s / p for _, p in periods), periods


def preflight_warnings(scenario) -> list[str]:
    """Messages for a validated scenario that is expensive or unobservable."""
    out = []
    events, periods = event_count(scenario)
    wall = events * SECONDS_PER_EVENT
    if wall > EXPENSIVE_WALL_S:
        smallest = min(periods, key=lambda x: x[1])
        out.append(f"scenario {scenario.name!r}: ~{events:.3g} discrete events over {scenario.duration_s:g} s, roughly "
                   f"{_human(wall)} of wall time; the smallest period is {smallest[0]} = {smallest[1]:g} s "
                   "(check the periods or the duration)")
    for s in scenario.sensors:
        refs = getattr(s, "references_I", None)
        if getattr(s, "mode", None) != "vectors" or refs is None:
            continue
        r = np.asarray(refs, dtype=float).reshape(-1, 3)
        r = r / np.linalg.norm(r, axis=1, keepdims=True)
        spread = max((float(np.linalg.norm(np.cross(r[0], v))) for v in r[1:]), default=0.0)
        if spread < 1e-6:
            out.append(f"sensors.{s.name}.references_I: got {r.tolist()}; all parallel (or a single direction): "
                       "the attitude about that direction is unobservable from this tracker")
    return out


def run_warnings(metrics: dict) -> list[str]:
    """Messages after a run: estimators that used no measurement."""
    return [f"estimator {name!r} used no measurement in the whole run ({m['measurements_skipped']} skipped): its "
            "estimate is the prediction from its initial state"
            for name, m in metrics["estimators"].items() if m.get("measurements_used", 1) == 0]
