"""Scoring injected faults: what each estimator saw, rejected and accepted, and how it recovered.

Reads only a :class:`~drake_att.scenarios.builder.RunLog`: the fault truth each
``!SensorFaultsConfig`` entry logs (``<entry>/fault_truth``, see
:mod:`drake_att.systems.fault_injector`), each estimator's status ``[t_estimate, used, skipped,
NIS]`` and its errors (:func:`drake_att.analysis.metrics.estimator_errors`).

**Fault events.** :func:`fault_events` groups the faulted samples of one injector: every
outlier, NaN, inf and bias-jump sample is an event of its own; consecutive samples of a
stuck, drop-out, saturation or time-tag fault form one event ``[t_start, t_end]`` (first and
last faulted sample); drop-outs inside an outage window are named "outage".

**Per estimator and event** (:func:`score_fault_events`):

* ``seen``: the estimator reads the faulted sensor (directly, through a virtual sensor such as
  the averaged tracker, or through the estimators it fuses) and takes a step at one of the
  event's faulted sample times (a 1 Hz filter never reads a 10 Hz tracker's sample at
  t = 0.3 s). ``steps``: how many of its steps do.
* At each such step, against the estimator's usual count increments (the median over steps
  without any fault on its sensors): ``rejected`` — its skipped count rose more than usual
  (invalid or non-finite sample, gate rejection, a sample or gyro sample whose time tag
  cannot be this step's);
  ``accepted`` — not rejected and, for a measurement (not a gyro), its used count rose as
  usual; ``ignored`` — neither (the sample was not read at this step: e.g. a sample seen
  before, or one tagged in the future that a later step may still take; the estimator loop
  uses or counts every new sample once, a mis-tagged one as rejected); ``detected`` —
  rejected, or accepted with an NIS above :data:`DETECTION_NIS` (the 99.9% point of
  chi-square with 3 dof: a quaternion update), or accepted after a prediction recovery (a
  sample the monitor confirmed that the gate rejected: the ``sample_handling`` counter).
* ``peak_error_deg``: the largest attitude error ``|dtheta|`` from the event's start to the
  end of its evaluation window (the next event's start, or the end of the run).
* ``recovery_time_s``: time from the event's last faulted sample until the error is back
  within the bound ``RECOVERY_FACTOR x`` the RMS of ``|dtheta|`` over the
  :data:`PRE_FAULT_WINDOW_S` before the event (not reaching back into the previous event)
  and stays there for :data:`HOLD_S` (or to the end of the window if that is sooner, but at
  least :data:`MIN_HOLD_S`; a later excursion is not counted against this fault); 0 if it
  never left; None if it does not recover within its window.
* ``nees_after_recovery``: mean 3-dof attitude NEES ``dtheta' P_att^-1 dtheta`` from the
  recovery to the window's end (3 for a consistent filter); ``nees_during``: the same over the
  estimator's steps from the event's first to its last faulted sample (whether the covariance
  says how wrong the estimate is while the fault lasts, e.g. a gyro outage).

**The monitors' trace** (per event, the same in every estimator's row): a sensor monitor
(``!SensorMonitorConfig``) watching the faulted sensor logs its verdicts
(:mod:`drake_att.fdir`); ``monitor_instants`` counts the event's faulted samples at the
monitor's instants, ``excluded`` those at which it excluded the sensor, and ``flagged`` the
monitor's instants from the event's start to the end of its window at which it logged a cause
against the sensor (a bias shift is found some seconds after it happens, and only logged). An estimator reads a
monitor's sensors only through its own inputs: a monitor is not followed as a source in
:func:`consumed_sensors`.

A gyro fault can be "rejected" without the gyro sample being refused: the faulted
prediction can make the gate refuse that step's tracker sample — the counts say what the
estimator did at the step, not which input it blamed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drake_att.analysis.metrics import estimator_errors
from drake_att.contract import TIME_TOLERANCE_S
from drake_att.noise import DEG
from drake_att.scenarios.registry import plugin_for
from drake_att.systems import fault_injector as flt
from drake_att.systems.estimator_step import N_RECOVERIES

DETECTION_NIS = 16.27  # chi-square 99.9% point, 3 dof
RECOVERY_FACTOR = 5.0
PRE_FAULT_WINDOW_S = 60.0
HOLD_S = 30.0
MIN_HOLD_S = 10.0
POINT_CODES = (flt.FAULT_OUTLIER, flt.FAULT_NAN, flt.FAULT_INF, flt.FAULT_BIAS_JUMP)


@dataclass(frozen=True)
class FaultEvent:
    """One injected fault (see the module docstring).

    Attributes:
        injector: the faults entry's name. sensor: the corrupted sensor. sensor_kind: its
            output kind ("gyro", "quaternion", "vectors", "camera").
        code, kind: the fault code and its name (:data:`drake_att.systems.fault_injector.FAULT_NAMES`;
            "outage" for drop-outs in an outage window).
        t_start, t_end: first and last faulted sample times (s).
        samples: every faulted sample time (s).
        magnitude: the largest magnitude of its samples (SI, as ``fault_truth``).
    """

    injector: str
    sensor: str
    sensor_kind: str
    code: int
    kind: str
    t_start: float
    t_end: float
    samples: np.ndarray = field(repr=False)
    magnitude: float

    @property
    def label(self) -> str:
        return f"{self.sensor} {self.kind}"


def _sensor_configs(scenario) -> dict:
    return {s.name: s for s in scenario.sensors}


def fault_injectors(scenario) -> dict:
    """The scenario's fault entries: entry name -> ``(sensor, sensor kind, period_s)``."""
    from drake_att.sensors.faults_plugin import SensorFaultsConfig

    sensors = _sensor_configs(scenario)
    out = {}
    for s in scenario.sensors:
        if isinstance(s, SensorFaultsConfig):
            target = sensors[s.sensor]
            o = plugin_for(target).output(target, sensors)
            out[s.name] = (s.sensor, o.kind, o.period_s)
    return out


def fault_events(run) -> list[FaultEvent]:
    """Every fault event of the run, by start time."""
    events = []
    for injector, (sensor, kind, period) in fault_injectors(run.scenario).items():
        x = run.values(f"{injector}/fault_truth")
        t, codes, mags = x[:, flt.TRUTH_T_SAMPLE], x[:, flt.TRUTH_CODE].astype(int), x[:, flt.TRUTH_MAGNITUDE]
        # The logger's first two rows are both sample 0 (initialization and t = 0): keep one per sample.
        keep = np.r_[True, np.diff(t) > TIME_TOLERANCE_S]
        t, codes, mags = t[keep], codes[keep], mags[keep]
        i = 0
        while i < len(t):
            c = codes[i]
            if c == flt.FAULT_NONE:
                i += 1
                continue
            j = i + 1
            if c not in POINT_CODES:
                while j < len(t) and codes[j] == c and t[j] - t[j - 1] < 1.5 * period:
                    j += 1
            name = flt.FAULT_NAMES[int(c)]
            if c == flt.FAULT_DROPOUT and np.any(mags[i:j] == 1.0):
                name = "outage"  # an outage window (magnitude 1), not a single drop-out
            events.append(
                FaultEvent(
                    injector,
                    sensor,
                    kind,
                    int(c),
                    name,
                    float(t[i]),
                    float(t[j - 1]),
                    t[i:j].copy(),
                    float(np.max(np.abs(mags[i:j]))),
                )
            )
            i = j
    return sorted(events, key=lambda e: (e.t_start, e.sensor))


def consumed_sensors(scenario, estimator: str) -> set:
    """The sensors estimator ``estimator`` reads: the sensors and estimators its config names
    (fields other than ``name``), followed through virtual sensors and fused estimators."""
    from drake_att.sensors.faults_plugin import references

    sensors = _sensor_configs(scenario)
    monitors = set(sensor_monitors(scenario))
    estimators = {e.name: e for e in scenario.estimators}
    found, stack = set(), [estimators[estimator]]
    while stack:
        config = stack.pop()
        for name in list(sensors) + list(estimators):
            if name in found or name in monitors or name == config.name or not references(config, name):
                continue
            if name in sensors:
                found.add(name)
                stack.append(sensors[name])
            else:
                stack.append(estimators[name])
    return found


def sensor_monitors(scenario) -> dict:
    """The scenario's sensor monitors: name -> the sensors they watch, in log order (gyro first)."""
    from drake_att.sensors.sensor_monitor_plugin import SensorMonitorConfig

    return {
        s.name: ([s.gyro] if s.gyro else []) + list(s.star_trackers)
        for s in scenario.sensors
        if isinstance(s, SensorMonitorConfig)
    }


def monitor_trace(run, e, window_end: float) -> tuple[int, int, int]:
    """``(monitor_instants, excluded, flagged)`` of event ``e``: its faulted samples at the
    instants of the monitors watching its sensor, those at which a monitor excluded the sensor,
    and the instants in ``[t_start, window_end)`` at which a monitor logged a cause against it."""
    from drake_att import fdir

    instants = excluded = flagged = 0
    for name, watched in sensor_monitors(run.scenario).items():
        if e.sensor not in watched:
            continue
        t, log = run.signals[f"{name}/detector_log"]
        t = np.asarray(t)
        log = np.asarray(log).reshape(len(t), -1)
        j = watched.index(e.sensor)
        # the logger's first two rows are both t = 0: keep the last of each instant
        keep = np.r_[np.diff(t) > TIME_TOLERANCE_S, True]
        t, verdict, cause = t[keep], log[keep, fdir.LOG_PER_SENSOR * j], log[keep, fdir.LOG_PER_SENSOR * j + 1]
        hit = _at(t, e.samples)
        instants += int(np.sum(hit))
        excluded += int(np.sum(verdict[hit] == fdir.EXCLUDED))
        window = (t >= e.t_start - TIME_TOLERANCE_S) & (t < window_end - TIME_TOLERANCE_S)
        flagged += int(np.sum(cause[window] != fdir.CAUSE_NONE))
    return instants, excluded, flagged


def _faulty_times(run, sensors: set) -> np.ndarray:
    """Sample times at which any of ``sensors`` carries a fault."""
    times = [np.zeros(0)]
    for injector, (sensor, _, _) in fault_injectors(run.scenario).items():
        if sensor in sensors:
            x = run.values(f"{injector}/fault_truth")
            times.append(x[x[:, flt.TRUTH_MASK] != 0, flt.TRUTH_T_SAMPLE])
    return np.unique(np.concatenate(times))


def _at(t_steps, times) -> np.ndarray:
    """Boolean mask of ``t_steps`` that coincide with one of ``times``."""
    if len(times) == 0:
        return np.zeros(len(t_steps), dtype=bool)
    idx = np.clip(np.searchsorted(times, t_steps - TIME_TOLERANCE_S), 0, len(times) - 1)
    return np.abs(times[idx] - t_steps) < TIME_TOLERANCE_S


def attitude_nees(errors: dict) -> np.ndarray:
    """3-dof attitude NEES ``dtheta' P_att^-1 dtheta`` per estimate (NaN where singular)."""
    d, P = errors["dtheta"], errors["P"][:, :3, :3]
    out = np.full(len(d), np.nan)
    ok = np.all(np.isfinite(P), axis=(1, 2)) & np.all(np.isfinite(d), axis=1)
    ok[ok] = np.linalg.matrix_rank(P[ok]) == 3
    if np.any(ok):
        out[ok] = np.einsum("ni,ni->n", d[ok], np.linalg.solve(P[ok], d[ok][..., None])[..., 0])
    return out


def finite_outputs(run, estimator: str) -> bool:
    """Every logged output of ``estimator`` (attitude, second vector, covariance) is finite."""
    keys = run.metadata["estimators"][estimator]["signals"]
    return all(np.all(np.isfinite(run.values(keys[k]))) for k in ("attitude", "second", "covariance"))


def score_fault_events(
    run,
    estimators=None,
    recovery_factor: float = RECOVERY_FACTOR,
    pre_fault_window_s: float = PRE_FAULT_WINDOW_S,
    hold_s: float = HOLD_S,
    min_hold_s: float = MIN_HOLD_S,
    detection_nis: float = DETECTION_NIS,
    bound_floor_deg: float = 0.0,
) -> list[dict]:
    """One row per (event, estimator) (see the module docstring), events by start time;
    ``bound_floor_deg``: the recovery bound is at least this (deg).

    Row keys: ``estimator``, ``sensor``, ``kind``, ``code``, ``t_start``, ``t_end``,
    ``magnitude`` (SI), ``seen``, ``steps``, ``detected``, ``rejected``, ``accepted``,
    ``ignored``, ``peak_error_deg``, ``pre_fault_rms_deg``, ``bound_deg``,
    ``recovery_time_s``, ``nees_after_recovery``, ``window_end``, ``monitor_instants``,
    ``excluded``, ``flagged``, ``nees_during``.
    """
    events = fault_events(run)
    names = list(run.metadata["estimators"]) if estimators is None else list(estimators)
    t_run_end = float(run.scenario.duration_s)
    starts = np.array([e.t_start for e in events])
    ends = np.array([e.t_end for e in events])
    window_ends = []
    for e in events:
        later = starts[starts > e.t_start + TIME_TOLERANCE_S]
        window_ends.append(float(later.min()) if len(later) else t_run_end)
    traces = [monitor_trace(run, e, w) for e, w in zip(events, window_ends, strict=True)]
    rows = []
    for name in names:
        series = _estimator_series(run, name)
        for k, e in enumerate(events):
            window_end = window_ends[k]
            row = _empty_row(name, e, window_end)
            row["monitor_instants"], row["excluded"], row["flagged"] = traces[k]
            _count_fault_steps(row, e, series, detection_nis)
            pre_from = _pre_fault_start(k, e, ends, pre_fault_window_s)
            _score_error(
                row, e, series, window_end, pre_from, recovery_factor, bound_floor_deg * DEG, hold_s, min_hold_s
            )
            rows.append(row)
    return rows


def _estimator_series(run, name: str) -> dict:
    """What scoring needs of estimator ``name`` in ``run``: sample times ``t``, attitude error
    angle, NEES, per-step used / skipped update increments and NIS, the sensors it reads, and the
    median used / skipped increments over fault-free steps (the baseline a faulted step is judged by)."""
    err = estimator_errors(run, name)
    t = err["t"]
    status = err["status"]
    d_used = np.diff(status[:, 1], prepend=0.0)
    d_skipped = np.diff(status[:, 2], prepend=0.0)
    consumed = consumed_sensors(run.scenario, name)
    d_recovered = np.zeros(len(t))
    key = run.metadata["estimators"][name]["signals"].get("sample_handling")
    if key is not None:  # prediction recoveries so far, at the status's times (last row of each time)
        t_h, x_h = run.signals[key]
        t_h, x_h = np.asarray(t_h), np.asarray(x_h).reshape(len(t_h), -1)
        keep = np.r_[np.diff(t_h) > TIME_TOLERANCE_S, True]
        t_h, recoveries = t_h[keep], x_h[keep, N_RECOVERIES]
        idx = np.clip(np.searchsorted(t_h, t - TIME_TOLERANCE_S), 0, len(t_h) - 1)
        d_recovered = np.diff(recoveries[idx], prepend=0.0)
    quiet = ~_at(t, _faulty_times(run, consumed))
    quiet[0] = False
    return {
        "t": t,
        "angle": np.linalg.norm(err["dtheta"], axis=1),
        "nees": attitude_nees(err),
        "d_used": d_used,
        "d_skipped": d_skipped,
        "d_recovered": d_recovered,
        "nis": status[:, 3],
        "consumed": consumed,
        "base_used": float(np.median(d_used[quiet])) if np.any(quiet) else 0.0,
        "base_skipped": float(np.median(d_skipped[quiet])) if np.any(quiet) else 0.0,
    }


def _event_facts(e) -> dict:
    """What a report says of a fault event (one key order for every table and file)."""
    return {
        "sensor": e.sensor,
        "sensor_kind": e.sensor_kind,
        "kind": e.kind,
        "code": e.code,
        "t_start": e.t_start,
        "t_end": e.t_end,
        "magnitude": e.magnitude,
    }


def _empty_row(name: str, e, window_end: float) -> dict:
    """The row of (event ``e``, estimator ``name``) before scoring: the event's facts, zero
    counts and no error figures."""
    return {
        "estimator": name,
        **_event_facts(e),
        "window_end": window_end,
        "seen": False,
        "steps": 0,
        "detected": 0,
        "rejected": 0,
        "accepted": 0,
        "ignored": 0,
        "peak_error_deg": None,
        "pre_fault_rms_deg": None,
        "bound_deg": None,
        "recovery_time_s": None,
        "nees_after_recovery": None,
        "nees_during": None,
    }


def _count_fault_steps(row: dict, e, series: dict, detection_nis: float) -> None:
    """Fill ``row``'s step counts: the estimator steps that met a faulted sample of ``e`` and
    whether each was rejected, accepted or ignored, and detected (rejected or a large NIS)."""
    t, d_used, d_skipped, nis = series["t"], series["d_used"], series["d_skipped"], series["nis"]
    hit = _at(t, e.samples) if e.sensor in series["consumed"] else np.zeros(len(t), dtype=bool)
    for i in np.flatnonzero(hit):
        rejected = d_skipped[i] > series["base_skipped"]
        accepted = not rejected and (e.sensor_kind == "gyro" or d_used[i] >= series["base_used"])
        row["rejected"] += int(rejected)
        row["accepted"] += int(accepted)
        row["ignored"] += int(not rejected and not accepted)
        large_nis = accepted and np.isfinite(nis[i]) and nis[i] > detection_nis
        row["detected"] += int(rejected or large_nis or series["d_recovered"][i] > 0)
    row["steps"] = int(np.sum(hit))
    row["seen"] = row["steps"] > 0


def _pre_fault_start(k: int, e, ends: np.ndarray, pre_fault_window_s: float) -> float:
    """Start of event ``k``'s pre-fault window: ``pre_fault_window_s`` before it, but not before
    the end of an earlier event."""
    earlier_ends = ends[(np.arange(len(ends)) != k) & (ends < e.t_start - TIME_TOLERANCE_S)]
    return max(e.t_start - pre_fault_window_s, float(earlier_ends.max()) if len(earlier_ends) else -np.inf)


def _score_error(
    row: dict,
    e,
    series: dict,
    window_end: float,
    pre_from: float,
    recovery_factor: float,
    bound_floor: float,
    hold_s: float,
    min_hold_s: float,
) -> None:
    """Fill ``row``'s error figures: the peak error in the event's window and, given enough
    pre-fault samples, the pre-fault RMS, the recovery bound (``bound_floor`` in rad at least),
    the recovery time and the mean NEES from recovery to the window's end."""
    t, angle = series["t"], series["angle"]
    inside = (t >= e.t_start - TIME_TOLERANCE_S) & (t < window_end - TIME_TOLERANCE_S)
    if np.any(inside):
        row["peak_error_deg"] = float(np.max(angle[inside]) / DEG)
    during = (t >= e.t_start - TIME_TOLERANCE_S) & (t <= e.t_end + TIME_TOLERANCE_S)
    nees = series["nees"][during]
    nees = nees[np.isfinite(nees)]
    row["nees_during"] = float(np.mean(nees)) if len(nees) else None
    pre = (t > pre_from + TIME_TOLERANCE_S) & (t < e.t_start - TIME_TOLERANCE_S)
    if np.sum(pre) >= 5 and np.any(inside):
        rms = float(np.sqrt(np.mean(angle[pre] ** 2)))
        bound = max(recovery_factor * rms, bound_floor)
        row["pre_fault_rms_deg"], row["bound_deg"] = rms / DEG, bound / DEG
        after = np.flatnonzero((t >= e.t_end - TIME_TOLERANCE_S) & (t < window_end - TIME_TOLERANCE_S))
        i = _first_recovery(t, angle, after, bound, window_end, hold_s, min_hold_s)
        if i is not None:
            row["recovery_time_s"] = float(max(t[i] - e.t_end, 0.0))
            tail = series["nees"][i : after[-1] + 1]
            tail = tail[np.isfinite(tail)]
            row["nees_after_recovery"] = float(np.mean(tail)) if len(tail) else None


def _first_recovery(t, angle, after, bound: float, window_end: float, hold_s: float, min_hold_s: float):
    """The first index in ``after`` from which the error stays within ``bound`` for ``hold_s``
    (cut at ``window_end``, at least ``min_hold_s`` long), or None."""
    ok = angle[after] <= bound
    for j, i in enumerate(after):
        if not ok[j]:
            continue
        hold_end = min(t[i] + hold_s, window_end)
        if hold_end - t[i] < min_hold_s - TIME_TOLERANCE_S:
            return None  # too close to the window's end to confirm
        span = after[j:][t[after[j:]] < hold_end - TIME_TOLERANCE_S]
        if np.all(angle[span] <= bound):
            return i
    return None


def summarize_fault_scores(rows_per_run: list) -> list[dict]:
    """Aggregate :func:`score_fault_events` rows of several runs (seeds) per (sensor, kind,
    estimator): sums of steps / detected / rejected / accepted / ignored, the largest peak
    error and recovery time, the mean NEES after recovery, ``recovered`` / ``events``
    (events seen or not; recovered = a recovery time was found) and ``t_first`` (the first
    event's start); ordered by fault (first start), then estimator (first appearance)."""
    groups: dict = {}
    order: dict = {}
    for rows in rows_per_run:
        for r in rows:
            key = (r["sensor"], r["kind"], r["estimator"])
            g = groups.setdefault(
                key,
                {
                    "sensor": r["sensor"],
                    "sensor_kind": r["sensor_kind"],
                    "kind": r["kind"],
                    "estimator": r["estimator"],
                    "events": 0,
                    "seen": 0,
                    "steps": 0,
                    "detected": 0,
                    "rejected": 0,
                    "accepted": 0,
                    "ignored": 0,
                    "monitor_instants": 0,
                    "excluded": 0,
                    "flagged": 0,
                    "recovered": 0,
                    "peak_error_deg": None,
                    "recovery_time_s": None,
                    "_nees": [],
                    "_nees_during": [],
                },
            )
            g["t_first"] = min(g.get("t_first", np.inf), r["t_start"])
            order.setdefault(r["estimator"], len(order))
            g["events"] += 1
            g["seen"] += int(r["seen"])
            for k in (
                "steps",
                "detected",
                "rejected",
                "accepted",
                "ignored",
                "monitor_instants",
                "excluded",
                "flagged",
            ):
                g[k] += r.get(k, 0)
            if r["peak_error_deg"] is not None:
                g["peak_error_deg"] = max(g["peak_error_deg"] or 0.0, r["peak_error_deg"])
            if r["recovery_time_s"] is not None:
                g["recovered"] += 1
                g["recovery_time_s"] = max(g["recovery_time_s"] or 0.0, r["recovery_time_s"])
            if r["nees_after_recovery"] is not None:
                g["_nees"].append(r["nees_after_recovery"])
            if r.get("nees_during") is not None:
                g["_nees_during"].append(r["nees_during"])
    out = []
    for g in groups.values():
        nees = g.pop("_nees")
        g["nees_after_recovery"] = float(np.mean(nees)) if nees else None
        during = g.pop("_nees_during")
        g["nees_during"] = float(np.mean(during)) if during else None
        out.append(g)
    return sorted(out, key=lambda g: (g["t_first"], g["sensor"], g["kind"], order[g["estimator"]]))


# ----------------------------------------------------------------------------------------
# A campaign over seeds: the shared runner (analysis.executor.map_runs)
# ----------------------------------------------------------------------------------------
def fault_campaign_record(run, keep_series_for=()) -> dict:
    """What :func:`run_fault_campaign` keeps of one run (computed in the worker)."""
    out = {
        "seed": int(run.seed),
        "wall_time_s": float(run.wall_time_s),
        "rows": score_fault_events(run),
        "finite": {n: bool(finite_outputs(run, n)) for n in run.metadata["estimators"]},
        "events": [{"injector": e.injector, **_event_facts(e)} for e in fault_events(run)],
    }
    if run.seed in keep_series_for:
        out["series"] = {}
        for name in run.metadata["estimators"]:
            err = estimator_errors(run, name)
            sigma = np.sqrt(np.maximum(np.einsum("nii->n", err["P"][:, :3, :3]), 0.0))
            out["series"][name] = {
                "t": err["t"],
                "error_deg": np.linalg.norm(err["dtheta"], axis=1) / DEG,
                "sigma_deg": sigma / DEG,
            }
    return out


def run_fault_campaign(scenario, seeds, workers: int | None = None, keep_series_for=(), scheduler=None) -> list[dict]:
    """Run ``scenario`` for every seed and score its faults; per seed: ``seed``,
    ``wall_time_s``, ``rows`` (:func:`score_fault_events`), ``finite`` (estimator ->
    :func:`finite_outputs`), ``events`` (the events as dicts) and, for the seeds in
    ``keep_series_for``, ``series`` (estimator -> ``t``, ``error_deg`` = ``|dtheta|``,
    ``sigma_deg`` = the attitude covariance's RMS sigma ``sqrt(trace P_att)``).

    Runs on :func:`drake_att.analysis.executor.map_runs` (``workers=1``: in this process;
    otherwise Dask worker processes, each building the diagram once)."""
    import functools

    from drake_att.analysis.executor import map_runs

    record = functools.partial(fault_campaign_record, keep_series_for=frozenset(int(s) for s in keep_series_for))
    return map_runs(
        scenario, [int(s) for s in seeds], record, workers=workers, scheduler=scheduler, raise_failures=True
    )


__all__ = [
    "FaultEvent",
    "fault_injectors",
    "fault_events",
    "consumed_sensors",
    "sensor_monitors",
    "monitor_trace",
    "attitude_nees",
    "finite_outputs",
    "score_fault_events",
    "summarize_fault_scores",
    "run_fault_campaign",
    "fault_campaign_record",
    "DETECTION_NIS",
    "RECOVERY_FACTOR",
    "PRE_FAULT_WINDOW_S",
    "HOLD_S",
    "MIN_HOLD_S",
]
