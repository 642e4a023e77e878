"""Warnings for scenarios that are valid but degenerate (issue 12): checked before a run
starts (:func:`preflight_warnings`) and after it (:func:`run_warnings`).

* **Cost**: the number of discrete events (every sensor sample and estimator step over the
  run) and a rough wall time at :data:`SECONDS_PER_EVENT` (the cost of one Python event with
  its share of integration and logging, measured on the S3 10 Hz case): a 1e-4 s sensor period
  that turns a 5000 s run into hours is announced before it starts.
* **Observability**: a vector-mode star tracker whose reference directions are all parallel
  (or a single one) leaves the attitude unobservable about that direction.
* **Truth accuracy**: a fixed-step truth integrator whose step turns the body by more than
  :data:`MAX_FIXED_STEP_ANGLE_DEG` at the scenario's peak rate (the shipped RK3 at 0.1 s
  drifts past a 5" tracker above ~5 deg/s: 125" over 2000 s at 10 deg/s).
* **Starved estimators** (after the run): an estimator that used no measurement at all
  published only its prediction from the initial state.

The CLI prints these as ``drake-att: warning: ...``; :class:`ScenarioDiagram` raises them as
Python warnings (:class:`DegenerateScenarioWarning`) for notebook and script users.
"""

from __future__ import annotations

import numpy as np

SECONDS_PER_EVENT = 60e-6
EXPENSIVE_WALL_S = 600.0
MAX_FIXED_STEP_ANGLE_DEG = 0.5


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


def peak_rate_deg_per_s(plant) -> float:
    """An upper bound of the truth's body rate (deg/s): a torque-free rigid body's ``|w|``
    is bounded by ``|I w0| / I_min`` (disturbance torques are small); a prescribed rate by
    ``|constant| + |amplitude|``; roll/pitch/yaw breakpoints by their fastest segment."""
    from drake_att.scenarios import config as cfg

    if isinstance(plant, cfg.RigidBodyConfig):
        inertia = np.asarray(plant.inertia_kg_m2, dtype=float)
        inertia = np.diag(inertia) if inertia.size == 3 else inertia.reshape(3, 3)
        w0 = np.asarray(plant.initial_rate_deg_per_s, dtype=float)
        return float(np.linalg.norm(inertia @ w0) / np.min(np.linalg.eigvalsh(inertia)))
    if isinstance(plant, cfg.PrescribedRateConfig):
        return float(np.linalg.norm(np.abs(plant.constant_deg_per_s) + np.abs(plant.amplitude_deg_per_s)))
    rpy = np.asarray(plant.rpy_deg, dtype=float)
    rates = np.diff(rpy, axis=0) / np.diff(np.asarray(plant.times_s, dtype=float))[:, None]
    return float(np.max(np.linalg.norm(rates, axis=1))) if len(rates) else 0.0


def preflight_warnings(scenario) -> list[str]:
    """Messages for a validated scenario that is expensive, inaccurate or unobservable."""
    out = []
    sim = scenario.simulation
    if not sim.use_error_control:
        _, periods = event_count(scenario)
        step = min([sim.max_step_size_s] + [p for _, p in periods])
        rate = peak_rate_deg_per_s(scenario.plant)
        if rate * step > MAX_FIXED_STEP_ANGLE_DEG:
            out.append(f"simulation: a fixed {step:g} s {sim.integration_scheme} step at the truth's peak rate "
                       f"~{rate:.3g} deg/s turns the body {rate * step:.2g} deg per step (more than "
                       f"{MAX_FIXED_STEP_ANGLE_DEG} deg: the truth drifts by arcseconds); set "
                       "simulation.use_error_control=true or a smaller simulation.max_step_size_s")
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
