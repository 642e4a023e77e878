"""Fault injection: a ``LeafSystem`` between a sensor's measurement output and its consumers.

"Faults are part of the model" (DESIGN.md): any sensor's measurements can be corrupted on
purpose, and what was injected is published as truth (``fault_truth``) so the metrics can
say what each estimator saw, rejected, accepted and how it recovered
(:mod:`drake_att.analysis.fault_scores`).

:class:`FaultInjector` reads the sensor's measurement (the same value every consumer would
otherwise read) and outputs the same type: ``"gyro"`` ``[t, valid, w_meas_B (3)]``,
``"quaternion"`` ``[t, valid, q_IS_meas (4)]`` (vector ports), ``"vectors"``
(:class:`~drake_att.contract.VectorObservations`) and ``"camera"``
(:class:`~drake_att.contract.CameraCentroids`) (abstract ports).

**Fault kinds** (codes of ``fault_truth``; a sample can carry several, see ``mask``):

====  ===========  ==================================================================  =====================
code  kind         what the consumers read                                             sensors
====  ===========  ==================================================================  =====================
1     outlier      gyro: ``w + s u`` (``|u| = 1``, random direction, ``s`` in rad/s);  all
                   attitude sensors: the sample rotated by angle ``s`` (rad) about a
                   random sensor-frame axis (quaternion: ``q_IS ⊗ exp(s u)``; vectors:
                   every direction rotated; camera: every centroid shifted by
                   ``f tan(s)`` in a random focal-plane direction)
2     nan          one number of the sample (drawn) is NaN                             all
3     inf          one number of the sample (drawn) is +inf or -inf                    all
4     stuck        the numbers (and flag) of the last clean sample before the window,  all
                   with the current time tag: a frozen sensor that still says "valid"
5     dropout      ``valid = 0`` (random drop-out, a listed sample, or an outage        all
                   window)
6     saturated    gyro: each axis clipped to ``[-r, r]`` (the code is set only when   gyro
                   a value was actually clipped)
7     bias_jump    gyro: a step added to the rate from this sample on (the code marks   gyro
                   the first sample of each step; ``bias_jump_B`` carries the total)
8     time_tag     the sample's time tag is off by ``time_tag_offset_s``               all
====  ===========  ==================================================================  =====================

Order of application on one sample: bias jump, stuck, saturation, outlier, NaN, inf, time
tag, dropout. The primary ``code`` reported for a sample with several faults is the first
of 5, 2, 3, 8, 1, 4, 6, 7 present (what decides the sample's fate first).

**Times.** The injector samples with the sensor's period (offset 0, as every sensor here):
sample ``k`` is at ``t_k = k T``. A fault "at time t" hits the first sample at or after
``t`` (``t <= t_k < t + T``); a window ``[start, end)`` covers every sample with
``start <= t_k < end``. A bias jump at ``t`` applies from that sample on (jumps add up).

**Randomness** (probabilistic outliers, NaN, inf, drop-outs; outlier directions; which
number is NaN/inf): counter-based, a pure function of (diagram seed, system name, sample
index) (:mod:`drake_att.systems.randomness`), drawn by the sample event *before* the sample
(the initialization event for sample 0) and held in the discrete state, never in an output
calculation. Same seed → the same faults; another seed → other faults.

Input ports:
    sensor_measurement: the sensor's measurement (vector 5 / 6, or abstract).
    seed_uniform (4, random uniform): seed.
Output ports:
    measurement: the faulted measurement (same type as the input).
    fault_truth (9): ``[t_sample (s), code, magnitude, mask, bias_jump_B (3, rad/s),
        t_out (the time tag consumers read), valid_out]``. ``mask`` = ``sum 2^(c-1)`` over
        the codes ``c`` present. ``magnitude`` (SI) by code: outlier: the size (rad or
        rad/s); nan / inf: the index of the number set; stuck: time since the held sample
        (s); dropout: 1 in an outage window, 0 for a random or listed drop-out; saturated:
        the largest clipped excess (rad/s); bias_jump: the step's norm (rad/s); time_tag:
        the offset (s).
Parameters: abstract parameter 0: the :class:`FaultModel` (:meth:`FaultInjector.set_model`).
Discrete state (20): ``[seed words (4), sample index k, t_k, mask, outlier vector (3),
    NaN position, inf position, inf sign, bias jump total (3), bias jump onset size,
    time-tag offset, in outage window, saturation range (rad/s; inf: none)]`` — the
    decisions for sample k, made by the discrete event at ``t_{k-1}`` (the initialization
    event for k = 0); the outputs read only the state and the input.
Abstract state: the :class:`Hold` (a stuck window's held clean sample), changed by an
    unrestricted event at the sample times (see the constructor).

One system: its length is the fault kinds times the four measurement types, each written once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.contract import (
    GYRO_MEASUREMENT_SIZE,
    QUATERNION_MEASUREMENT_SIZE,
    CameraCentroids,
    empty_camera_centroids,
    empty_vector_observations,
)
from drake_att.systems.randomness import (
    SEED_WORDS,
    counter_random,
    declare_seed_port,
    read_seed_words,
)
from drake_att.validation import check_finite, check_nonnegative, check_positive, fail

(
    FAULT_NONE,
    FAULT_OUTLIER,
    FAULT_NAN,
    FAULT_INF,
    FAULT_STUCK,
    FAULT_DROPOUT,
    FAULT_SATURATED,
    FAULT_BIAS_JUMP,
    FAULT_TIME_TAG,
) = range(9)
FAULT_NAMES = {
    FAULT_OUTLIER: "outlier",
    FAULT_NAN: "nan",
    FAULT_INF: "inf",
    FAULT_STUCK: "stuck",
    FAULT_DROPOUT: "dropout",
    FAULT_SATURATED: "saturated",
    FAULT_BIAS_JUMP: "bias_jump",
    FAULT_TIME_TAG: "time_tag",
}
# The primary code of a sample with several faults: the first of these present.
FAULT_PRIORITY = (
    FAULT_DROPOUT,
    FAULT_NAN,
    FAULT_INF,
    FAULT_TIME_TAG,
    FAULT_OUTLIER,
    FAULT_STUCK,
    FAULT_SATURATED,
    FAULT_BIAS_JUMP,
)
FAULT_TRUTH_SIZE = 9
# fault_truth columns
TRUTH_T_SAMPLE, TRUTH_CODE, TRUTH_MAGNITUDE, TRUTH_MASK = 0, 1, 2, 3
TRUTH_BIAS_JUMP = slice(4, 7)
TRUTH_T_OUT, TRUTH_VALID_OUT = 7, 8

KINDS = ("gyro", "quaternion", "vectors", "camera")
TIME_TOLERANCE_S = 1e-9

# Discrete-state layout
_K, _T, _MASK = SEED_WORDS, SEED_WORDS + 1, SEED_WORDS + 2
_OUTLIER = slice(SEED_WORDS + 3, SEED_WORDS + 6)
_NAN_AT, _INF_AT, _INF_SIGN = SEED_WORDS + 6, SEED_WORDS + 7, SEED_WORDS + 8
_JUMP = slice(SEED_WORDS + 9, SEED_WORDS + 12)
_JUMP_ONSET, _TAG_OFFSET, _IN_OUTAGE, _SATURATION = range(SEED_WORDS + 12, SEED_WORDS + 16)
STATE_SIZE = SEED_WORDS + 16


def bit(code: int) -> int:
    """The ``mask`` bit of fault ``code``."""
    return 1 << (code - 1)


def _times(field: str, values) -> tuple:
    out = tuple(check_nonnegative(f"{field}[{j}]", v) for j, v in enumerate(values))
    return out


def _windows(field: str, values) -> tuple:
    out = []
    for j, w in enumerate(values):
        w = tuple(w)
        if (
            len(w) != 2
            or not all(isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) for v in w)
            or not w[1] > w[0]
        ):
            fail(f"{field}[{j}]", w, "must be [start, end] (s), finite, with end > start")
        out.append((float(w[0]), float(w[1])))
    return tuple(out)


def _probability(field: str, p) -> float:
    p = check_finite(field, p)
    if not 0.0 <= p < 1.0:
        fail(field, p, "must be in [0, 1)")
    return p


@dataclass(frozen=True)
class FaultModel:
    """What a :class:`FaultInjector` injects (SI units; its abstract parameter).

    Attributes:
        outlier_probability, outlier_times_s: random outliers per sample / at given times.
        outlier_size: rad (attitude sensors: rotation angle) or rad/s (gyro).
        nan_probability, nan_times_s, inf_probability, inf_times_s: non-finite samples.
        dropout_probability, dropout_times_s: samples flagged invalid.
        outage_windows_s: ``((start, end), ...)``: every sample flagged invalid.
        stuck_windows_s: the output repeats the last clean sample before the window.
        saturation_rad_per_s: gyro per-axis range (``inf``: none).
        saturation_windows_s: where the range applies (empty: the whole run).
        bias_jump_times_s, bias_jumps_rad_per_s: gyro rate steps (3-vectors) from those times on.
        time_tag_offset_s: added to the time tag of the samples at ``time_tag_times_s`` and in
            ``time_tag_windows_s``.
    """

    outlier_probability: float = 0.0
    outlier_times_s: tuple = ()
    outlier_size: float = 0.0
    nan_probability: float = 0.0
    nan_times_s: tuple = ()
    inf_probability: float = 0.0
    inf_times_s: tuple = ()
    dropout_probability: float = 0.0
    dropout_times_s: tuple = ()
    outage_windows_s: tuple = ()
    stuck_windows_s: tuple = ()
    saturation_rad_per_s: float = math.inf
    saturation_windows_s: tuple = ()
    bias_jump_times_s: tuple = ()
    bias_jumps_rad_per_s: tuple = ()
    time_tag_offset_s: float = 0.0
    time_tag_times_s: tuple = ()
    time_tag_windows_s: tuple = ()

    @classmethod
    def make(cls, name: str, kind: str, **fields) -> FaultModel:
        """A checked model for a sensor of ``kind`` (ValueError naming ``<name>.<field>``)."""
        if kind not in KINDS:
            fail(f"{name}.kind", kind, f"allowed: {list(KINDS)}")
        known = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(fields) - known)
        if unknown:
            raise TypeError(f"{name}: unknown fault fields {unknown}; allowed: {sorted(known)}")
        m = cls(**fields)
        p = f"{name}."
        _probability(p + "outlier_probability", m.outlier_probability)
        _probability(p + "nan_probability", m.nan_probability)
        _probability(p + "inf_probability", m.inf_probability)
        _probability(p + "dropout_probability", m.dropout_probability)
        # The checked times and windows by field name: keyword arguments of replace() below (Any: a
        # type checker cannot tell which field each key fills).
        times: dict[str, Any] = {
            f: _times(p + f, getattr(m, f))
            for f in (
                "outlier_times_s",
                "nan_times_s",
                "inf_times_s",
                "dropout_times_s",
                "bias_jump_times_s",
                "time_tag_times_s",
            )
        }
        windows: dict[str, Any] = {
            f: _windows(p + f, getattr(m, f))
            for f in ("outage_windows_s", "stuck_windows_s", "saturation_windows_s", "time_tag_windows_s")
        }
        size = check_nonnegative(p + "outlier_size", m.outlier_size)
        if kind != "gyro" and size >= math.pi:
            fail(p + "outlier_size", size, "an attitude outlier is a rotation angle in [0, pi) (rad)")
        if (m.outlier_probability > 0 or times["outlier_times_s"]) and not size > 0:
            fail(p + "outlier_size", size, "outliers need a size > 0")
        sat = float(m.saturation_rad_per_s)
        if not (sat == math.inf or (math.isfinite(sat) and sat > 0)):
            fail(p + "saturation_rad_per_s", sat, "must be > 0 (rad/s), or inf for none")
        if windows["saturation_windows_s"] and sat == math.inf:
            fail(p + "saturation_windows_s", windows["saturation_windows_s"], "need a saturation range")
        jumps = tuple(tuple(float(v) for v in j) for j in m.bias_jumps_rad_per_s)
        if len(jumps) != len(times["bias_jump_times_s"]) or any(
            len(j) != 3 or not all(map(math.isfinite, j)) for j in jumps
        ):
            fail(
                p + "bias_jumps_rad_per_s",
                m.bias_jumps_rad_per_s,
                f"need one finite 3-vector (rad/s) per bias jump time ({len(times['bias_jump_times_s'])})",
            )
        offset = check_finite(p + "time_tag_offset_s", m.time_tag_offset_s)
        if (times["time_tag_times_s"] or windows["time_tag_windows_s"]) and offset == 0.0:
            fail(p + "time_tag_offset_s", offset, "time-tag errors need a non-zero offset (s)")
        if kind != "gyro" and sat != math.inf:
            fail(p + "saturation_rad_per_s", sat, f"only a gyro saturates; this sensor's output is {kind!r}")
        if kind != "gyro" and jumps:
            fail(
                p + "bias_jump_times_s",
                times["bias_jump_times_s"],
                f"only a gyro has bias jumps; this sensor's output is {kind!r}",
            )
        return replace(
            m,
            outlier_size=size,
            saturation_rad_per_s=sat,
            bias_jumps_rad_per_s=jumps,
            time_tag_offset_s=offset,
            **times,
            **windows,
        )


@dataclass(frozen=True)
class Hold:
    """A stuck window's held sample (the injector's abstract state): ``sample`` (the clean
    measurement: vector or abstract) taken at ``t_hold`` (s); ``valid`` False: none held."""

    valid: bool
    t_hold: float
    sample: object


def _hit(times, t: float, period: float) -> bool:
    """A fault at one of ``times`` hits the sample at ``t`` (the first at or after it)."""
    return any(a - TIME_TOLERANCE_S <= t < a + period - TIME_TOLERANCE_S for a in times)


def _inside(windows, t: float) -> bool:
    return any(a - TIME_TOLERANCE_S <= t < b - TIME_TOLERANCE_S for a, b in windows)


class FaultInjector(LeafSystem):
    """Corrupts one sensor's measurements by a :class:`FaultModel` (see the module docstring).

    Args:
        name: system name (the random stream's name; the fault entry's name).
        kind: the sensor's output kind: "gyro", "quaternion", "vectors" or "camera".
        period_s: the sensor's sample period (s).
        model: the :class:`FaultModel` (default: no fault).
    """

    def __init__(self, name: str, kind: str, period_s: float, model: FaultModel | None = None):
        LeafSystem.__init__(self)
        self.set_name(name)
        if kind not in KINDS:
            fail(f"{name}.kind", kind, f"allowed: {list(KINDS)}")
        self.kind = kind
        self.period_s = check_positive(f"{name}.period_s", period_s)
        self.default_model = FaultModel.make(name, kind) if model is None else model
        self._model_index = self.DeclareAbstractParameter(AbstractValue.Make(self.default_model))
        self._seed_port = declare_seed_port(self)
        if kind in ("gyro", "quaternion"):
            size = GYRO_MEASUREMENT_SIZE if kind == "gyro" else QUATERNION_MEASUREMENT_SIZE
            self._in = self.DeclareVectorInputPort("sensor_measurement", size)
            hold: object = np.zeros(size)
        else:
            empty = empty_vector_observations() if kind == "vectors" else empty_camera_centroids()
            self._in = self.DeclareAbstractInputPort("sensor_measurement", AbstractValue.Make(empty))
            hold = empty
        self._state_index = self.DeclareDiscreteState(np.zeros(STATE_SIZE))  # type: ignore[arg-type]  # pydrake stub
        self._no_hold = Hold(False, -math.inf, hold)
        self._hold_index = self.DeclareAbstractState(AbstractValue.Make(self._no_hold))
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        # Decisions: a discrete update (all discrete updates at t see the state from before t,
        # so consumers and loggers at t_k read the decisions of sample k).
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_sample)
        # The stuck window's hold: an unrestricted update (the only kind that may change
        # abstract state). Drake runs it before the discrete updates of the same instant; it
        # changes the hold only when the current sample does not read it, so every reader at
        # t_k still sees sample k's output.
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.period_s, 0.0, self._on_sample_hold)
        deps = {self.xd_ticket(), self.xa_ticket(), self.input_port_ticket(self._in.get_index())}
        if kind in ("gyro", "quaternion"):
            self.DeclareVectorOutputPort("measurement", size, self._calc_vector, deps)
        else:
            self.DeclareAbstractOutputPort("measurement", lambda: AbstractValue.Make(empty), self._calc_abstract, deps)
        self.DeclareVectorOutputPort("fault_truth", FAULT_TRUTH_SIZE, self._calc_truth, deps)

    # -- parameters ---------------------------------------------------------------------------
    def model(self, context) -> FaultModel:
        """The :class:`FaultModel` in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._model_index).get_value()

    def set_model(self, context, model: FaultModel) -> None:
        """Give ``context`` (this system's) another :class:`FaultModel` (checked with
        :meth:`FaultModel.make`); takes effect at the next initialization."""
        if not isinstance(model, FaultModel):
            raise TypeError(f"{self.get_name()}: set_model needs a FaultModel; got {type(model).__name__}")
        fields = {f: getattr(model, f) for f in FaultModel.__dataclass_fields__}
        context.get_mutable_abstract_parameter(self._model_index).set_value(
            FaultModel.make(self.get_name(), self.kind, **fields)
        )

    # -- decisions (events only) ----------------------------------------------------------------
    def _decide(self, m: FaultModel, words, k: int, t: float, x_new: np.ndarray) -> None:
        """Write the decisions for sample ``k`` at ``t`` into ``x_new`` (not the hold)."""
        cr = counter_random(words, self.get_name())
        u = cr.uniforms(k, 6)
        z = cr.normals(k, 3)
        T = self.period_s
        mask = 0
        if _hit(m.outlier_times_s, t, T) or u[0] < m.outlier_probability:
            mask |= bit(FAULT_OUTLIER)
        if _hit(m.nan_times_s, t, T) or u[1] < m.nan_probability:
            mask |= bit(FAULT_NAN)
        if _hit(m.inf_times_s, t, T) or u[2] < m.inf_probability:
            mask |= bit(FAULT_INF)
        in_outage = _inside(m.outage_windows_s, t)
        if in_outage or _hit(m.dropout_times_s, t, T) or u[3] < m.dropout_probability:
            mask |= bit(FAULT_DROPOUT)
        if _inside(m.stuck_windows_s, t):
            mask |= bit(FAULT_STUCK)
        if m.saturation_rad_per_s < math.inf and (not m.saturation_windows_s or _inside(m.saturation_windows_s, t)):
            mask |= bit(FAULT_SATURATED)  # the range applies; the output reports it only where it clips
        if _hit(m.time_tag_times_s, t, T) or _inside(m.time_tag_windows_s, t):
            mask |= bit(FAULT_TIME_TAG)
        jump = np.zeros(3)
        onset = np.zeros(3)
        for tj, dj in zip(m.bias_jump_times_s, m.bias_jumps_rad_per_s, strict=True):
            if t >= tj - TIME_TOLERANCE_S:
                jump += dj
                if t < tj + T - TIME_TOLERANCE_S:
                    onset += dj
        if np.any(onset != 0.0):
            mask |= bit(FAULT_BIAS_JUMP)
        direction = z / max(np.linalg.norm(z), 1e-12)
        if self.kind == "camera":
            xy = z[:2] / max(np.linalg.norm(z[:2]), 1e-12)
            direction = np.array([xy[0], xy[1], 0.0])
        x_new[_K], x_new[_T], x_new[_MASK] = k, t, mask
        x_new[_OUTLIER] = m.outlier_size * direction
        x_new[_NAN_AT], x_new[_INF_AT], x_new[_INF_SIGN] = u[4], u[5], 1.0 if z[0] >= 0 else -1.0
        x_new[_JUMP] = jump
        x_new[_JUMP_ONSET] = np.linalg.norm(onset)
        x_new[_TAG_OFFSET] = m.time_tag_offset_s if mask & bit(FAULT_TIME_TAG) else 0.0
        x_new[_IN_OUTAGE] = float(in_outage)
        x_new[_SATURATION] = m.saturation_rad_per_s if mask & bit(FAULT_SATURATED) else math.inf

    def _clean(self, measurement, x):
        """The sensor's sample with the bias jump applied (what a stuck window holds)."""
        if self.kind == "gyro":
            v = np.array(measurement, dtype=float)
            v[2:5] += x[_JUMP]
            return v
        if self.kind == "quaternion":
            return np.array(measurement, dtype=float)
        return measurement

    def _initialize(self, context, discrete_state):
        words = read_seed_words(self, context, self._seed_port)
        x = np.zeros(STATE_SIZE)
        x[:SEED_WORDS] = words
        self._decide(self.model(context), words, 0, context.get_time(), x)
        discrete_state.get_mutable_vector(self._state_index).SetFromVector(x)
        return EventStatus.Succeeded()

    def _on_sample(self, context, discrete_state):
        x = context.get_discrete_state(self._state_index).value()
        new = x.copy()
        self._decide(self.model(context), x[:SEED_WORDS], int(x[_K]) + 1, context.get_time() + self.period_s, new)
        discrete_state.get_mutable_vector(self._state_index).SetFromVector(new)
        return EventStatus.Succeeded()

    def _on_sample_hold(self, context, state):
        """Start holding this (clean) sample if the next one is in a stuck window and this
        one is not held already; drop the hold after a window."""
        x = context.get_discrete_state(self._state_index).value()
        hold = self._hold(context)
        t = context.get_time()
        if _inside(self.model(context).stuck_windows_s, t + self.period_s):
            if int(x[_MASK]) & bit(FAULT_STUCK) and hold.valid:
                return EventStatus.DidNothing()
            new = Hold(True, t, self._clean(self._in.Eval(context), x))
        elif hold.valid:
            new = self._no_hold
        else:
            return EventStatus.DidNothing()
        state.get_mutable_abstract_state(self._hold_index).set_value(new)
        return EventStatus.Succeeded()

    # -- outputs (no draws: the decisions are in the state) ------------------------------------
    def _apply_numbers(
        self, numbers: np.ndarray, x, mask: int, saturation: float = math.inf, focal_length: float = 0.0
    ):
        """Saturation (``saturation``: the gyro's range, rad/s), outlier, NaN and inf on the
        sample's numbers (a copy; ``focal_length``: the camera's, m); returns the numbers and
        the largest clipped excess (0 if none)."""
        excess = 0.0
        if self.kind == "gyro" and mask & bit(FAULT_SATURATED):
            r = saturation
            clipped = np.clip(numbers, -r, r)
            excess = float(np.max(np.abs(numbers - clipped))) if numbers.size else 0.0
            numbers = clipped
        if mask & bit(FAULT_OUTLIER):
            delta = x[_OUTLIER]
            if self.kind == "gyro":
                numbers = numbers + delta
            elif self.kind == "quaternion":
                numbers = rot.quat_canonical(rot.quat_multiply(numbers, rot.rotvec_to_quat(delta)))
            elif self.kind == "vectors":
                numbers = numbers @ rot.rotvec_to_rotmat(delta)  # b' = exp(delta)^T b (sample attitude off by delta)
            else:
                numbers = numbers + focal_length * math.tan(float(np.linalg.norm(delta))) * (
                    delta[:2] / max(float(np.linalg.norm(delta)), 1e-300)
                )
        if numbers.size and mask & (bit(FAULT_NAN) | bit(FAULT_INF)):
            numbers = np.array(numbers, dtype=float)
            flat = numbers.reshape(-1)
            if mask & bit(FAULT_NAN):
                flat[min(int(x[_NAN_AT] * flat.size), flat.size - 1)] = np.nan
            if mask & bit(FAULT_INF):
                flat[min(int(x[_INF_AT] * flat.size), flat.size - 1)] = x[_INF_SIGN] * np.inf
        return numbers, excess

    def _apply(self, context):
        """``(measurement, effective mask, saturation excess)`` of the current sample."""
        x = context.get_discrete_state(self._state_index).value()
        mask = int(x[_MASK])
        m = self._in.Eval(context)
        hold = self._hold(context)
        stuck = bool(mask & bit(FAULT_STUCK)) and hold.valid
        if not stuck:
            mask &= ~bit(FAULT_STUCK)
        if self.kind in ("gyro", "quaternion"):
            v = np.array(m, dtype=float)
            if self.kind == "gyro":
                v[2:5] += x[_JUMP]
            if stuck:
                v[1:] = hold.sample[1:]
            v[2:], excess = self._apply_numbers(v[2:], x, mask, x[_SATURATION])
            v[0] += x[_TAG_OFFSET]
            if mask & bit(FAULT_DROPOUT):
                v[1] = 0.0
            out = v
        else:
            if stuck:
                m = replace(hold.sample, time_s=m.time_s)
            if isinstance(m, CameraCentroids):
                numbers, excess = self._apply_numbers(
                    np.asarray(m.centroids_m, dtype=float), x, mask, focal_length=float(m.focal_length_m)
                )
                out = replace(m, centroids_m=numbers)
            else:
                numbers, excess = self._apply_numbers(np.asarray(m.directions_S, dtype=float), x, mask)
                out = replace(m, directions_S=numbers)
            out = replace(
                out, time_s=float(out.time_s) + x[_TAG_OFFSET], valid=False if mask & bit(FAULT_DROPOUT) else out.valid
            )
        if excess <= 0.0:
            mask &= ~bit(FAULT_SATURATED)
        return out, mask, excess, x, hold

    def _hold(self, context):
        return context.get_abstract_state(self._hold_index).get_value()

    def _calc_vector(self, context, output: BasicVector):
        output.SetFromVector(self._apply(context)[0])

    def _calc_abstract(self, context, output):
        output.set_value(self._apply(context)[0])

    def _calc_truth(self, context, output: BasicVector):
        out, mask, excess, x, hold = self._apply(context)
        code = next((c for c in FAULT_PRIORITY if mask & bit(c)), FAULT_NONE)
        magnitude = {
            FAULT_OUTLIER: float(np.linalg.norm(x[_OUTLIER])),
            FAULT_NAN: float(int(x[_NAN_AT] * self._numbers_size(out))),
            FAULT_INF: float(int(x[_INF_AT] * self._numbers_size(out))),
            FAULT_STUCK: float(x[_T] - hold.t_hold) if hold.valid else 0.0,
            FAULT_DROPOUT: float(x[_IN_OUTAGE]),
            FAULT_SATURATED: excess,
            FAULT_BIAS_JUMP: float(x[_JUMP_ONSET]),
            FAULT_TIME_TAG: float(x[_TAG_OFFSET]),
        }.get(code, 0.0)
        if self.kind in ("gyro", "quaternion"):
            t_out, valid_out = out[0], out[1]
        else:
            t_out, valid_out = float(out.time_s), float(bool(out.valid))
        truth = np.empty(FAULT_TRUTH_SIZE)
        truth[TRUTH_T_SAMPLE], truth[TRUTH_CODE], truth[TRUTH_MAGNITUDE], truth[TRUTH_MASK] = (
            x[_T],
            code,
            magnitude,
            mask,
        )
        truth[TRUTH_BIAS_JUMP] = x[_JUMP]
        truth[TRUTH_T_OUT], truth[TRUTH_VALID_OUT] = t_out, valid_out
        output.SetFromVector(truth)  # type: ignore[arg-type]  # pydrake stub

    def _numbers_size(self, out) -> int:
        if self.kind == "gyro":
            return 3
        if self.kind == "quaternion":
            return 4
        return int(np.size(out.numbers))


__all__ = [
    "FaultInjector",
    "FaultModel",
    "FAULT_NAMES",
    "FAULT_PRIORITY",
    "FAULT_TRUTH_SIZE",
    "KINDS",
    "bit",
    "FAULT_NONE",
    "FAULT_OUTLIER",
    "FAULT_NAN",
    "FAULT_INF",
    "FAULT_STUCK",
    "FAULT_DROPOUT",
    "FAULT_SATURATED",
    "FAULT_BIAS_JUMP",
    "FAULT_TIME_TAG",
    "TRUTH_T_SAMPLE",
    "TRUTH_CODE",
    "TRUTH_MAGNITUDE",
    "TRUTH_MASK",
    "TRUTH_BIAS_JUMP",
    "TRUTH_T_OUT",
    "TRUTH_VALID_OUT",
]
