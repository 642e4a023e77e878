"""Fault detection and isolation for a gyro and attitude-quaternion sensors (plain numpy).

One :func:`assess` call judges the samples of one instant ``t`` against the monitor's memory of
the previous instants and returns the verdicts and the new memory; the Drake system
(:class:`drake_att.systems.sensor_monitor.SensorMonitor`) only reads ports and stores the
memory. Detectors, in this order:

* **frozen output** — a sensor whose numbers have not changed (bit for bit) over
  ``frozen_window_s`` while its time tag advanced: a real sensor's noise never repeats. For the
  gyro each axis is followed on its own: all axes unchanged is ``FROZEN``; some axes only is
  ``PINNED`` (an axis held at a limit: saturation at an unknown range).
* **range** (gyro) — an axis at or beyond the gyro's configured range (``RANGE``): the rate
  is clipped, so the sample is not the body's rate.
* **consistency vote** — the voters are the trackers' body attitudes
  ``q_IB,i = q_IS,i ⊗ q_BS,i⁻¹`` (covariance ``C_i = R_BS,i diag(σ_S,i²) R_BS,iᵀ``) and, with a
  gyro, the gyro-propagated reference ``q_G = q_ref ⊗ exp(ω̄ Δt)`` (``q_ref`` the previous
  instant's consensus, ``ω̄`` the gyro's mean rate over the step) with covariance
  ``P_ref + (σ_ARW² Δt + (ε Δt)²) I`` — ``ε`` the gyro rate error the vote tolerates
  (unestimated bias, a bias jump, scale factor): gross gyro faults are isolated, small ones
  are left to the estimators. Two voters are consistent when the rotation between them,
  ``δ = log(q_a⁻¹ ⊗ q_b)`` (body frame), has ``δᵀ (C_a + C_b)⁻¹ δ`` below the chi-square
  quantile of ``1 - false_alarm_probability`` (3 dof). The largest mutually consistent sets of
  two or more voters decide: a voter in all of them is **confirmed**; a voter consistent with
  no member of any of them is **isolated** (``VOTE``); any other voter is left unassessed
  (two voters that disagree cannot say which one is wrong).

* **gyro bias shift** (``bias_window_s`` > 0) — while the gyro votes and trackers are
  confirmed, the gyro's rate residual ``e_k = log(q_G⁻¹ ⊗ q_consensus) / Δt`` is kept for the
  last ``2N`` such instants (``N = bias_window_s / period_s``); the mean of the last ``N``
  against the mean of the ``N`` before differs by ``d`` with per-axis variance
  ``(s̄_A + s̄_B) / N + q_RRW N Δt`` (``s_k`` the residual's variance from the reference's and
  the consensus' covariances and the ARW; the RRW term for the bias' own drift between the
  windows). ``|d|²`` over that variance above the vote's threshold logs ``BIAS_SHIFT``: a
  change of the gyro's bias too small for the vote, which the estimators absorb; it is logged,
  not excluded.

A detection excludes the sensor (its count of exclusions goes up when it was admitted); an
excluded sensor is re-admitted once its samples have drawn no detection for ``readmit_after_s``
(it keeps voting while excluded, so a clean sensor earns its way back). Verdicts:
:data:`UNASSESSED` (0), :data:`CONFIRMED` (1), :data:`EXCLUDED` (2). A sample that is missing,
flagged invalid, non-finite or not of this instant is not the monitor's to judge: it passes as
it is (the estimators skip and count it) and leaves that sensor's state unchanged; so does a
tracker's quaternion below half the unit norm (:func:`drake_att.contract.quaternion_usable`).

The consensus that becomes the next ``q_ref`` is the information-weighted mean of the confirmed
trackers (first order about the first; covariance ``(Σ C_i⁻¹)⁻¹``); with none confirmed, the
gyro-propagated reference when the gyro is admitted and undetected; at start-up, the admitted
trackers that drew no detection; otherwise the reference lapses until trackers re-establish it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import TIME_TOLERANCE_S, quaternion_usable
from drake_att.filters.gating import chi2_quantile
from drake_att.validation import fail

UNASSESSED, CONFIRMED, EXCLUDED = 0, 1, 2
CAUSE_NONE, CAUSE_FROZEN, CAUSE_PINNED, CAUSE_RANGE, CAUSE_VOTE, CAUSE_BIAS_SHIFT = 0, 1, 2, 3, 4, 5
CAUSE_NAMES = {
    CAUSE_NONE: "none",
    CAUSE_FROZEN: "frozen",
    CAUSE_PINNED: "pinned",
    CAUSE_RANGE: "range",
    CAUSE_VOTE: "vote",
    CAUSE_BIAS_SHIFT: "bias_shift",
}
#: The causes that exclude a sensor (a bias shift is only logged).
EXCLUDING = frozenset({CAUSE_FROZEN, CAUSE_PINNED, CAUSE_RANGE, CAUSE_VOTE})
VERDICT_NAMES = {UNASSESSED: "unassessed", CONFIRMED: "confirmed", EXCLUDED: "excluded"}

# Memory layout, per sensor (gyro first when there is one, then the trackers).
_LAST = slice(0, 6)  # the last judged sample's numbers (gyro: 3 rates; tracker: 4 quaternion numbers)
_CHANGED = slice(6, 10)  # per number: time of the last judged instant at which it changed
_EXCLUDED, _CLEAN_SINCE, _COUNT, _SEEN = 10, 11, 12, 13
SENSOR_BLOCK = 14
# The reference, after the sensors.
_REF_Q, _REF_P, _REF_VALID, _REF_T = slice(0, 4), slice(4, 13), 13, 14
REFERENCE_BLOCK = 15
# The bias-shift residuals, after the reference: a count, then 4 numbers per slot (e_k (3), s_k).
RESIDUAL_SLOT = 4
#: Entries of the detector log per sensor: ``[verdict, cause detected at this instant, exclusions so far]``.
LOG_PER_SENSOR = 3


@dataclass(frozen=True)
class TrackerModel:
    """What the monitor assumes about one quaternion tracker: mounting ``q_BS`` and the
    body-frame covariance of its attitude ``C = R_BS diag(σ_S²) R_BSᵀ`` (rad²)."""

    name: str
    q_BS: np.ndarray
    covariance_B: np.ndarray


@dataclass(frozen=True)
class MonitorModel:
    """The monitor's settings (checked by :meth:`make`).

    Attributes:
        name: the monitor's name (in error messages).
        trackers: :class:`TrackerModel` per quaternion tracker, in input order.
        has_gyro: whether a gyro is monitored (it is sensor 0).
        period_s: the monitor's step (s): it judges the samples of the instants ``k period_s``.
        frozen_window_s: how long a sensor's numbers may stay unchanged (s).
        readmit_after_s: the clean time an excluded sensor needs to be re-admitted (s).
        threshold: the chi-square (3 dof) consistency threshold.
        gyro_arw_rad_per_rt_s: the gyro's angle random walk (rad/sqrt(s)).
        gyro_rate_tolerance_rad_per_s: the gyro rate error the vote tolerates (rad/s).
        gyro_range_rad_per_s: the gyro's per-axis range (rad/s; inf: no range check).
        bias_window_steps: ``N`` of the bias-shift test (0: off).
        gyro_rrw_rad_per_s15: the gyro's rate random walk (rad/s^1.5).
    """

    name: str
    trackers: tuple
    has_gyro: bool
    period_s: float
    frozen_window_s: float
    readmit_after_s: float
    threshold: float
    gyro_arw_rad_per_rt_s: float = 0.0
    gyro_rate_tolerance_rad_per_s: float = 0.0
    gyro_range_rad_per_s: float = math.inf
    bias_window_steps: int = 0
    gyro_rrw_rad_per_s15: float = 0.0

    @classmethod
    def make(
        cls,
        name: str,
        trackers,
        has_gyro: bool,
        period_s: float,
        frozen_window_s: float,
        readmit_after_s: float,
        false_alarm_probability: float,
        gyro_arw_rad_per_rt_s: float = 0.0,
        gyro_rate_tolerance_rad_per_s: float = 0.0,
        gyro_range_rad_per_s: float = math.inf,
        bias_window_s: float = 0.0,
        gyro_rrw_rad_per_s15: float = 0.0,
    ) -> MonitorModel:
        """Check the settings (ValueError naming the field) and derive the threshold."""
        trackers = tuple(trackers)
        if len(trackers) + int(bool(has_gyro)) < 2:
            fail(f"{name}.star_trackers", [t.name for t in trackers], "a monitor needs at least two sensors to vote")
        if not (math.isfinite(period_s) and period_s > 0):
            fail(f"{name}.period_s", period_s, "must be finite and > 0 (s)")
        if not (math.isfinite(frozen_window_s) and frozen_window_s >= period_s - TIME_TOLERANCE_S):
            fail(f"{name}.frozen_window_s", frozen_window_s, f"must be finite and >= the period {period_s:g} s")
        if not (math.isfinite(readmit_after_s) and readmit_after_s >= 0):
            fail(f"{name}.readmit_after_s", readmit_after_s, "must be finite and >= 0 (s)")
        if not 0.0 < false_alarm_probability < 0.5:
            fail(f"{name}.false_alarm_probability", false_alarm_probability, "must be in (0, 0.5) (per test)")
        for field, v in (("gyro_arw", gyro_arw_rad_per_rt_s), ("gyro_rate_tolerance", gyro_rate_tolerance_rad_per_s)):
            if not (math.isfinite(v) and v >= 0):
                fail(f"{name}.{field}", v, "must be finite and >= 0")
        if not (math.isfinite(bias_window_s) and bias_window_s >= 0):
            fail(f"{name}.bias_window_s", bias_window_s, "must be finite and >= 0 (s; 0: no bias-shift test)")
        steps = round(bias_window_s / period_s)
        if bias_window_s > 0 and (steps < 2 or abs(steps * period_s - bias_window_s) > 1e-9 * bias_window_s):
            fail(f"{name}.bias_window_s", bias_window_s, f"must be a whole number (>= 2) of periods ({period_s:g} s)")
        if not (math.isfinite(gyro_rrw_rad_per_s15) and gyro_rrw_rad_per_s15 >= 0):
            fail(f"{name}.gyro_rrw", gyro_rrw_rad_per_s15, "must be finite and >= 0")
        if not gyro_range_rad_per_s > 0:
            fail(f"{name}.gyro_range", gyro_range_rad_per_s, "must be > 0 (rad/s), or inf for no range check")
        for t in trackers:
            C = np.asarray(t.covariance_B, dtype=float)
            if C.shape != (3, 3) or not np.all(np.isfinite(C)) or np.min(np.linalg.eigvalsh(C)) <= 0:
                fail(f"{name}.{t.name}.covariance", C.tolist(), "must be a finite positive-definite 3x3 (rad^2)")
        threshold = chi2_quantile(1.0 - false_alarm_probability, 3)
        return cls(
            name,
            trackers,
            bool(has_gyro),
            float(period_s),
            float(frozen_window_s),
            float(readmit_after_s),
            threshold,
            float(gyro_arw_rad_per_rt_s),
            float(gyro_rate_tolerance_rad_per_s),
            float(gyro_range_rad_per_s),
            int(steps) if bias_window_s > 0 else 0,
            float(gyro_rrw_rad_per_s15),
        )

    @property
    def n_sensors(self) -> int:
        return len(self.trackers) + int(self.has_gyro)

    @property
    def memory_size(self) -> int:
        return SENSOR_BLOCK * self.n_sensors + REFERENCE_BLOCK + 1 + RESIDUAL_SLOT * 2 * self.bias_window_steps

    def initial_memory(self) -> np.ndarray:
        """The memory before any instant: nothing seen, every sensor admitted, no reference."""
        m = np.zeros(self.memory_size)
        for s in range(self.n_sensors):
            b = m[SENSOR_BLOCK * s : SENSOR_BLOCK * (s + 1)]
            b[_LAST] = np.nan
            b[_CHANGED] = -np.inf
            b[_CLEAN_SINCE] = np.nan
            b[_SEEN] = -np.inf
        r = m[SENSOR_BLOCK * self.n_sensors : SENSOR_BLOCK * self.n_sensors + REFERENCE_BLOCK]
        r[_REF_Q] = (1.0, 0.0, 0.0, 0.0)
        r[_REF_T] = -np.inf
        return m


@dataclass(frozen=True)
class Assessment:
    """The monitor's judgement at one instant.

    Attributes:
        verdicts: per sensor (gyro first), :data:`UNASSESSED` / :data:`CONFIRMED` /
            :data:`EXCLUDED`.
        causes: per sensor, the cause detected at this instant (``CAUSE_*``; 0 none).
        exclusions: per sensor, exclusions so far (this instant's included).
        judged: whether ``t`` is one of the monitor's instants (between them nothing is judged
            and the verdicts say only who is excluded).
    """

    verdicts: np.ndarray
    causes: np.ndarray
    exclusions: np.ndarray
    judged: bool

    def log(self) -> np.ndarray:
        """The detector log: ``[verdict, cause, exclusions]`` per sensor."""
        return np.column_stack([self.verdicts, self.causes, self.exclusions]).ravel().astype(float)


def _usable(sample, t: float) -> bool:
    """Flagged valid (a finite flag > 0.5), every number finite, tagged at ``t``."""
    if sample is None:
        return False
    s = np.asarray(sample, dtype=float)
    return bool(np.all(np.isfinite(s)) and s[1] > 0.5 and abs(s[0] - t) < TIME_TOLERANCE_S)


def is_instant(model: MonitorModel, t: float) -> bool:
    """Whether ``t`` is one of the monitor's instants ``k period_s``."""
    k = round(t / model.period_s)
    return abs(t - k * model.period_s) < TIME_TOLERANCE_S


def rotation_between(q_a, q_b) -> np.ndarray:
    """``log(q_a⁻¹ ⊗ q_b)``: the rotation vector (rad, in the frame of ``q_a``) from ``a`` to ``b``."""
    return rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q_a), q_b))


def consistent(q_a, C_a, q_b, C_b, threshold: float) -> bool:
    """Whether two body attitudes agree within their covariances (chi-square, 3 dof)."""
    d = rotation_between(q_a, q_b)
    return bool(d @ np.linalg.solve(np.asarray(C_a) + np.asarray(C_b), d) <= threshold)


def vote(attitudes, covariances, threshold: float) -> tuple[set, set]:
    """``(confirmed, isolated)`` voter indices: see the module docstring."""
    n = len(attitudes)
    ok = np.eye(n, dtype=bool)
    for a, b in itertools.combinations(range(n), 2):
        ok[a, b] = ok[b, a] = consistent(attitudes[a], covariances[a], attitudes[b], covariances[b], threshold)
    for size in range(n, 1, -1):
        cliques = [
            set(c)
            for c in itertools.combinations(range(n), size)
            if all(ok[a, b] for a, b in itertools.combinations(c, 2))
        ]
        if cliques:
            confirmed = set.intersection(*cliques)
            members = set.union(*cliques)
            isolated = {v for v in range(n) if v not in members and not any(ok[v, m] for m in members)}
            return confirmed, isolated
    return set(), set()


def _information_mean(attitudes, covariances) -> tuple[np.ndarray, np.ndarray]:
    """Information-weighted mean of body attitudes, first order about the first; its covariance."""
    infos = [np.linalg.inv(C) for C in covariances]
    P = np.linalg.inv(sum(infos))
    q0 = attitudes[0]
    d = P @ sum(I @ rotation_between(q0, q) for I, q in zip(infos, attitudes, strict=True))
    return rot.quat_canonical(rot.quat_multiply(q0, rot.rotvec_to_quat(d))), P


def _frozen_cause(b: np.ndarray, values: np.ndarray, t: float, window: float, per_axis: bool) -> int:
    """Update the change times in block ``b`` with ``values`` and return the frozen cause."""
    n = len(values)
    last = b[_LAST][:n]
    changed = b[_CHANGED][:n]  # a view: written in place
    seen = math.isfinite(b[_SEEN])
    for i in range(n):
        if not (seen and values[i] == last[i]):
            changed[i] = t
    b[_LAST][:n] = values
    b[_SEEN] = t
    still = t - changed >= window - TIME_TOLERANCE_S
    if np.all(still):
        return CAUSE_FROZEN
    if per_axis and np.any(still):
        return CAUSE_PINNED
    return CAUSE_NONE


def _bias_shift(model: MonitorModel, residuals: np.ndarray, e: np.ndarray, v: float, dt: float) -> bool:
    """Push residual ``e`` (variance ``v`` per axis) into the window (in place) and test the
    last ``N`` against the ``N`` before (see the module docstring)."""
    n = model.bias_window_steps
    slots = residuals[1:].reshape(2 * n, RESIDUAL_SLOT)  # a view, oldest first
    slots[:-1] = slots[1:].copy()
    slots[-1, :3], slots[-1, 3] = e, v
    residuals[0] = min(residuals[0] + 1, 2 * n)
    if residuals[0] < 2 * n:
        return False
    older, newer = slots[:n], slots[n:]
    d = newer[:, :3].mean(axis=0) - older[:, :3].mean(axis=0)
    var = (newer[:, 3].mean() + older[:, 3].mean()) / n + model.gyro_rrw_rad_per_s15**2 * n * dt
    return bool(d @ d / var > model.threshold)


def assess(model: MonitorModel, memory, t: float, gyro=None, trackers=()) -> tuple[Assessment, np.ndarray]:
    """Judge the samples of instant ``t``: ``(Assessment, new memory)``.

    Args:
        model: the :class:`MonitorModel`.
        memory: the memory after the previous instant (:meth:`MonitorModel.initial_memory` first).
        t: the time (s). Off the monitor's instants nothing is judged and the memory is returned
            unchanged.
        gyro: the gyro sample ``[t, valid, w_meas_B (3, rad/s)]`` (None: none or no gyro).
        trackers: per tracker its sample ``[t, valid, q_IS (4)]`` or None.
    """
    m = np.array(memory, dtype=float)
    ns, ng = model.n_sensors, int(model.has_gyro)
    blocks = [m[SENSOR_BLOCK * s : SENSOR_BLOCK * (s + 1)] for s in range(ns)]
    ref = m[SENSOR_BLOCK * ns : SENSOR_BLOCK * ns + REFERENCE_BLOCK]
    residuals = m[SENSOR_BLOCK * ns + REFERENCE_BLOCK :]
    causes = np.zeros(ns, dtype=int)
    if not is_instant(model, t):
        verdicts = np.array([EXCLUDED if b[_EXCLUDED] else UNASSESSED for b in blocks])
        return Assessment(verdicts, causes, np.array([b[_COUNT] for b in blocks]), False), m

    judged = np.zeros(ns, dtype=bool)
    # -- per-sensor detectors ---------------------------------------------------------------
    w = None
    if ng and _usable(gyro, t):
        judged[0] = True
        w = np.asarray(gyro, dtype=float)[2:5]
        causes[0] = _frozen_cause(blocks[0], w, t, model.frozen_window_s, per_axis=True)
        if np.any(np.abs(w) >= model.gyro_range_rad_per_s * (1.0 - 1e-12)):
            causes[0] = CAUSE_RANGE  # an axis held at the range is named by the range
    q_B, C_B = {}, {}
    for i, (tm, sample) in enumerate(zip(model.trackers, trackers, strict=True)):
        s = ng + i
        if not (_usable(sample, t) and quaternion_usable(*np.asarray(sample, dtype=float)[2:6].tolist())):
            continue  # the estimators' own rule decides what to do with it
        judged[s] = True
        q_IS = np.asarray(sample, dtype=float)[2:6]
        causes[s] = _frozen_cause(blocks[s], q_IS, t, model.frozen_window_s, per_axis=False)
        if causes[s] == CAUSE_NONE:
            q_B[s] = rot.quat_normalize(rot.quat_multiply(q_IS, rot.quat_conjugate(tm.q_BS)))
            C_B[s] = np.asarray(tm.covariance_B, dtype=float)

    # -- the vote ------------------------------------------------------------------------------
    voters = sorted(q_B)
    attitudes = [q_B[s] for s in voters]
    covariances = [C_B[s] for s in voters]
    gyro_votes = False
    if w is not None and causes[0] == CAUSE_NONE and ref[_REF_VALID] > 0.5:
        dt = t - ref[_REF_T]
        q_G = rot.quat_multiply(ref[_REF_Q], rot.rotvec_to_quat(w * dt))
        growth = model.gyro_arw_rad_per_rt_s**2 * dt + (model.gyro_rate_tolerance_rad_per_s * dt) ** 2
        voters.insert(0, 0)
        attitudes.insert(0, q_G)
        covariances.insert(0, ref[_REF_P].reshape(3, 3) + growth * np.eye(3))
        gyro_votes = True
    confirmed: set = set()
    if len(voters) >= 2:
        conf_idx, iso_idx = vote(attitudes, covariances, model.threshold)
        confirmed = {voters[k] for k in conf_idx}
        for k in iso_idx:
            causes[voters[k]] = CAUSE_VOTE

    # -- exclusion and re-admission -------------------------------------------------------------
    for s in range(ns):
        b = blocks[s]
        if causes[s] in EXCLUDING:
            if not b[_EXCLUDED]:
                b[_COUNT] += 1
            b[_EXCLUDED], b[_CLEAN_SINCE] = 1.0, np.nan
        elif judged[s] and b[_EXCLUDED]:
            if math.isnan(b[_CLEAN_SINCE]):
                b[_CLEAN_SINCE] = t
            if t - b[_CLEAN_SINCE] >= model.readmit_after_s - TIME_TOLERANCE_S:
                b[_EXCLUDED], b[_CLEAN_SINCE] = 0.0, np.nan
    verdicts = np.array(
        [EXCLUDED if blocks[s][_EXCLUDED] else (CONFIRMED if s in confirmed else UNASSESSED) for s in range(ns)]
    )

    # -- the next reference -----------------------------------------------------------------------
    chosen = [s for s in sorted(q_B) if s in confirmed]
    if chosen:
        q_cons, P_cons = _information_mean([q_B[s] for s in chosen], [C_B[s] for s in chosen])
        if model.bias_window_steps and gyro_votes and 0 in confirmed:
            dt = t - ref[_REF_T]
            e = rotation_between(attitudes[0], q_cons) / dt
            v = (
                np.trace(ref[_REF_P].reshape(3, 3)) + np.trace(P_cons)
            ) / 3.0 / dt**2 + model.gyro_arw_rad_per_rt_s**2 / dt
            if _bias_shift(model, residuals, e, v, dt):
                causes[0] = CAUSE_BIAS_SHIFT
    if not chosen and ref[_REF_VALID] < 0.5:
        chosen = [s for s in sorted(q_B) if not blocks[s][_EXCLUDED]]
    if chosen:
        q_ref, P_ref = _information_mean([q_B[s] for s in chosen], [C_B[s] for s in chosen])
        ref[_REF_Q], ref[_REF_P], ref[_REF_VALID] = q_ref, P_ref.ravel(), 1.0
    elif gyro_votes and not blocks[0][_EXCLUDED]:
        ref[_REF_Q], ref[_REF_P] = rot.quat_canonical(attitudes[0]), covariances[0].ravel()
    else:
        ref[_REF_VALID] = 0.0
    ref[_REF_T] = t
    return Assessment(verdicts, causes, np.array([b[_COUNT] for b in blocks]), True), m


__all__ = [
    "UNASSESSED",
    "CONFIRMED",
    "EXCLUDED",
    "CAUSE_NONE",
    "CAUSE_FROZEN",
    "CAUSE_PINNED",
    "CAUSE_RANGE",
    "CAUSE_VOTE",
    "CAUSE_BIAS_SHIFT",
    "EXCLUDING",
    "CAUSE_NAMES",
    "VERDICT_NAMES",
    "LOG_PER_SENSOR",
    "TrackerModel",
    "MonitorModel",
    "Assessment",
    "assess",
    "vote",
    "consistent",
    "rotation_between",
    "is_instant",
]
