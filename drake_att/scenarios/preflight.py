"""Warnings for scenarios that are valid but degenerate: checked before a run
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

And one refusal, :func:`check_memory`: a run whose estimated peak memory (particles and
logs, :func:`memory_estimate`) exceeds the memory available raises ``ConfigError`` naming
the field that dominates (``estimators[0] (bpf).num_particles: got 1000000000; needs ~1,000
GB ...``) in milliseconds, before a diagram allocates it.

The CLI prints these as ``drake-att: warning: ...``; :class:`ScenarioDiagram` raises them as
Python warnings (:class:`DegenerateScenarioWarning`) for notebook and script users.
"""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np

from drake_att.contract import ESTIMATE_SIZE, GYRO_MEASUREMENT_SIZE, QUATERNION_MEASUREMENT_SIZE

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
            out.append(
                f"simulation: a fixed {step:g} s {sim.integration_scheme} step at the truth's peak rate "
                f"~{rate:.3g} deg/s turns the body {rate * step:.2g} deg per step (more than "
                f"{MAX_FIXED_STEP_ANGLE_DEG} deg: the truth drifts by arcseconds); set "
                "simulation.use_error_control=true or a smaller simulation.max_step_size_s"
            )
    events, periods = event_count(scenario)
    wall = events * SECONDS_PER_EVENT
    if wall > EXPENSIVE_WALL_S:
        smallest = min(periods, key=lambda x: x[1])
        out.append(
            f"scenario {scenario.name!r}: ~{events:.3g} discrete events over {scenario.duration_s:g} s, roughly "
            f"{_human(wall)} of wall time; the smallest period is {smallest[0]} = {smallest[1]:g} s "
            "(check the periods or the duration)"
        )
    for s in scenario.sensors:
        refs = getattr(s, "references_I", None)
        if getattr(s, "mode", None) != "vectors" or refs is None:
            continue
        r = np.asarray(refs, dtype=float).reshape(-1, 3)
        r = r / np.linalg.norm(r, axis=1, keepdims=True)
        spread = max((float(np.linalg.norm(np.cross(r[0], v))) for v in r[1:]), default=0.0)
        if spread < 1e-6:
            out.append(
                f"sensors.{s.name}.references_I: got {r.tolist()}; all parallel (or a single direction): "
                "the attitude about that direction is unobservable from this tracker"
            )
    return out


def run_warnings(metrics: dict) -> list[str]:
    """Messages after a run: estimators that used no measurement."""
    return [
        f"estimator {name!r} used no measurement in the whole run ({m['measurements_skipped']} skipped): its "
        "estimate is the prediction from its initial state"
        for name, m in metrics["estimators"].items()
        if m.get("measurements_used", 1) == 0
    ]


# --------------------------------------------------------------------------------------
# Memory
# --------------------------------------------------------------------------------------
# Peak memory per particle of the shipped particle filters (bytes), for a whole run: the
# setup's initial set, the core state in the diagram's context, the
# simulator's discrete-update copy and each step's numpy temporaries. Measured as the slope
# of the process's peak RSS (``ru_maxrss``, one fresh process per point) over
# ``ScenarioDiagram(...)`` + ``simulate()`` of a gyro + vector tracker + one filter at N = 1e5
# and 3e5 (and 1e6 bootstrap, 6e5 EKPF to check linearity), 5 s at 1 Hz (the peak is
# the same after 60 s: nothing accumulates per step), rounded up: bootstrap PF 950,
# gyroless PF 950, EKPF 4200 (its per-particle 6x6 covariances and their temporaries).
# tests/test_ranges.py re-measures one of them against this estimate.
PARTICLE_BYTES = {"BootstrapPfConfig": 1000, "GyrolessPfConfig": 1000, "EkpfConfig": 4200}
DEFAULT_PARTICLE_BYTES = 6400  # a plug-in's particle filter: a margin above the largest measured (the EKPF's)

# Logged signals: every logger keeps its times and samples as float64. Drake's VectorLog
# grows its buffer by doubling (up to 2x the samples) and simulate() copies it into numpy
# (1x): peak ~3x the raw samples (measured 2.4x-3.0x on 20k- and 400k-sample sensor logs).
LOG_COPIES = 3
# Widths of the logged sensor ports (drake_att.contract, drake_att.systems.fault_injector); a
# plug-in's port not listed here counts DEFAULT_PORT_WIDTH numbers.
PORT_WIDTHS = {
    "gyro_measurement": GYRO_MEASUREMENT_SIZE,
    "bias_B": 3,
    "star_tracker_measurement": QUATERNION_MEASUREMENT_SIZE,
    "fault_truth": 9,  # fault_injector.FAULT_TRUTH_SIZE
    "stars_in_view": 1,
}
DEFAULT_PORT_WIDTH = 16
# An estimator logs its packed estimate (47: attitude, second vector, covariance, status),
# its innovations (3 per measurement input), its diagnostics (at most ~8 numbers) and its
# sample-handling counters (4).
ESTIMATE_WIDTH, INNOVATION_WIDTH, DIAGNOSTICS_WIDTH = ESTIMATE_SIZE, 3, 8 + 4
TRUTH_WIDTHS = (4, 3)  # q_IB and w_IB_B, at the smallest period of the scenario


@dataclasses.dataclass
class MemoryPart:
    """One contribution to a run's peak memory: the field that sets it, its value, bytes."""

    path: str
    value: float  # a particle count or a period (s)
    bytes: float
    what: str


@dataclasses.dataclass
class MemoryEstimate:
    total_bytes: float
    parts: list

    def dominant(self) -> MemoryPart | None:
        return max(self.parts, key=lambda p: p.bytes, default=None)


def _human_bytes(b: float) -> str:
    if b >= 1e11:
        return f"{b / 1e9:,.0f} GB"
    if b >= 1e9:
        return f"{b / 1e9:.3g} GB"
    return f"{b / 1e6:.3g} MB"


def available_memory_bytes() -> float | None:
    """This machine's available memory: ``MemAvailable`` of /proc/meminfo, else
    ``os.sysconf`` free pages; None if neither is known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def _loggers(scenario) -> list:
    """``[(path of the period field, period_s, numbers per sample, what)]`` of every logger
    the builder adds (:class:`~drake_att.scenarios.builder.ScenarioDiagram`)."""
    from drake_att.scenarios.registry import plugin_for
    from drake_att.scenarios.selection import fused_sources

    sensors = {s.name: s for s in scenario.sensors}
    by_name = {e.name: e for e in scenario.estimators}
    items = []  # (path, period, item)

    def sensor_period(s):
        try:
            return float(plugin_for(s).output(s, sensors).period_s)
        except Exception:  # a plug-in that cannot say: its period field, if any
            return float(getattr(s, "period_s", math.inf))

    def estimator_period(e, depth=0):
        if isinstance(getattr(e, "period_s", None), (int, float)):
            return float(e.period_s)
        sources = [by_name[n] for n in fused_sources(e) if n in by_name]
        return min((estimator_period(x, depth + 1) for x in sources if depth < 10), default=math.inf)

    for i, s in enumerate(scenario.sensors):
        items.append((f"sensors[{i}] ({s.name})", sensor_period(s), s))
    for i, e in enumerate(scenario.estimators):
        items.append((f"estimators[{i}] ({e.name})", estimator_period(e), e))

    def period_field(path, period, item):
        """The field that sets ``period``: the item's own period_s, else the first item with it."""
        if getattr(item, "period_s", None) == period:
            return f"{path}.period_s"
        for p, _q, x in items:
            if getattr(x, "period_s", None) == period:
                return f"{p}.period_s"
        return "duration_s"

    out = []
    finite = [(p, q, x) for p, q, x in items if math.isfinite(q) and q > 0]
    if finite:
        path, period, item = min(finite, key=lambda x: x[1])
        truth_path = period_field(path, period, item)
    else:
        truth_path, period = "duration_s", 1.0
    from drake_att.scenarios.config import RigidBodyConfig

    truth = "rigid_body_plant" if isinstance(scenario.plant, RigidBodyConfig) else "prescribed_motion"
    out += [(truth_path, period, w, "the truth's attitude and rate", f"{truth}/q_IB") for w in TRUTH_WIDTHS]
    for (path, period, item), s in zip(items, scenario.sensors, strict=False):  # items: sensors, then estimators
        logged = plugin_for(s).logged_ports
        for port, p in logged(s) if logged is not None else []:
            q = period if p is None else float(p)
            key = f"{s.name}/{port}"
            out.append((period_field(path, q, item), q, PORT_WIDTHS.get(port, DEFAULT_PORT_WIDTH), key, key))
    for path, period, e in items[len(scenario.sensors) :]:
        inputs: set[str] = set()
        for f in dataclasses.fields(e):
            v = getattr(e, f.name)
            names = [v] if isinstance(v, str) else [x for x in v if isinstance(x, str)] if isinstance(v, list) else []
            inputs.update(n for n in names if f.name != "name" and n in sensors)
        width = ESTIMATE_WIDTH + INNOVATION_WIDTH * len(inputs) + DIAGNOSTICS_WIDTH
        out.append((period_field(path, period, e), period, width, f"{e.name}'s estimate", f"{e.name}/q_IB_hat"))
    return _with_logging_policy(scenario, out)


def _with_logging_policy(scenario, loggers) -> list:
    """``(path, period, width, what)`` of the loggers a run keeps under the scenario's ``logging:``
    (each entry's signal key, its last element, resolved as the builder does; a policy the
    builder would refuse leaves the periods as they are: the build says why)."""
    from drake_att.scenarios.logging_policy import is_excluded, resolve_period
    from drake_att.validation import ConfigError

    policy = getattr(scenario, "logging", None)
    out = []
    for path, period, width, what, key in loggers:
        if policy is not None and math.isfinite(period) and period > 0:
            if is_excluded(policy, key):
                continue
            try:
                period = resolve_period(policy, key, period)[0]
            except ConfigError:
                pass
        out.append((path, period, width, what))
    return out


def log_bytes(scenario) -> float:
    """The raw bytes of a run's logs (float64 times and samples of every logger, one copy)."""
    return sum(
        (math.floor(scenario.duration_s / q) + 1) * (w + 1) * 8.0
        for _, q, w, _ in _loggers(scenario)
        if math.isfinite(q) and q > 0
    )


def result_bytes(scenario) -> int:
    """An upper bound of a run's result folder: its logs uncompressed (the packed estimates
    are split into four signals, each with its times), plus ~1 MB of figures and tables per
    estimator and 1 MB more."""
    return int(
        log_bytes(scenario)
        + 8.0
        * 3
        * sum(
            math.floor(scenario.duration_s / q) + 1
            for _, q, _, what in _loggers(scenario)
            if what.endswith("'s estimate") and math.isfinite(q) and q > 0
        )
        + 1e6 * (len(scenario.estimators) + 1)
    )


def memory_estimate(scenario) -> MemoryEstimate:
    """The peak memory one run of a validated ``scenario`` needs beyond the process's own:
    every particle filter's ``num_particles`` x its measured bytes per particle
    (:data:`PARTICLE_BYTES`) and every logger's samples x (width + 1) x 8 bytes x
    :data:`LOG_COPIES`, grouped by the period field that sets them."""
    parts = []
    for i, e in enumerate(scenario.estimators):
        n = getattr(e, "num_particles", None)
        if isinstance(n, (int, np.integer)) and not isinstance(n, bool):
            per = PARTICLE_BYTES.get(type(e).__name__, DEFAULT_PARTICLE_BYTES)
            parts.append(
                MemoryPart(
                    f"estimators[{i}] ({e.name}).num_particles", int(n), float(n) * per, f"~{per} bytes per particle"
                )
            )
    logs: dict[str, tuple[float, float, int]] = {}  # period field -> (period, bytes, samples)
    for path, q, w, _ in _loggers(scenario):
        if math.isfinite(q) and q > 0:
            samples = math.floor(scenario.duration_s / q) + 1
            value, b, n = logs.get(path, (q, 0.0, 0))
            logs[path] = (value, b + samples * (w + 1) * 8.0 * LOG_COPIES, n + samples)
    for path, (value, b, samples) in logs.items():
        parts.append(
            MemoryPart(path, value, b, f"logs of ~{samples:.3g} samples over duration_s = {scenario.duration_s:g}")
        )
    return MemoryEstimate(sum(p.bytes for p in parts), parts)


def check_memory(scenario, available_bytes: float | None = None, processes: int = 1) -> MemoryEstimate:
    """Refuse a run that would not fit in memory, before anything is allocated.

    Args:
        scenario: a validated scenario.
        available_bytes: the memory the run may use (default: :func:`available_memory_bytes`,
            this machine's MemAvailable); None and unknown: nothing is checked.
        processes: runs at once (parallel Monte Carlo workers), each needing the estimate.

    Returns:
        The :class:`MemoryEstimate` (one run).

    Raises:
        ConfigError: naming the field that dominates the estimate, its value, the memory
            needed and the memory available.
    """
    from drake_att.validation import ConfigError, fail

    estimate = memory_estimate(scenario)
    measured = available_bytes is None
    available = available_memory_bytes() if available_bytes is None else float(available_bytes)
    need = estimate.total_bytes * max(1, int(processes))
    if available is None or need <= available:
        return estimate
    part = estimate.dominant()
    if part is None:  # nothing needs memory: only a negative available_bytes gets here, and nothing is to blame
        return estimate
    where = "this machine's" if measured else "the"
    runs = f" for {processes} runs at once" if processes > 1 else ""
    if part.path.endswith(".num_particles"):
        per = part.bytes / part.value
        others = (estimate.total_bytes - part.bytes) * max(1, int(processes))
        fit = max(0, int((available - others) / max(1, int(processes)) / per))
        fail(
            part.path,
            part.value,
            f"needs ~{_human_bytes(need)}{runs} ({part.what}), more than {where} "
            f"{_human_bytes(available)} available; at most ~{fit:,} particles fit",
            ConfigError,
        )
    fail(
        part.path,
        part.value,
        f"the run needs ~{_human_bytes(need)}{runs}, mostly {part.what} at this period, more "
        f"than {where} {_human_bytes(available)} available; use a longer period or a shorter duration_s",
        ConfigError,
    )
