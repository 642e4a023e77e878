"""What one estimator step keeps and decides, written once: the bookkeeping layout and the
rules of the loop.

:class:`~drake_att.systems.estimator_system.EstimatorSystem`'s Python loop calls the rules
(plain scalar functions) as they are, and :mod:`drake_att.systems.compiled_step` compiles the
same functions with numba for its one-call MEKF step, so a rule changes in one place for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from drake_att.contract import TIME_TOLERANCE_S
from drake_att.filters.compiled import quat_multiply, rotvec_to_quat
from drake_att.systems.randomness import SEED_WORDS


@dataclass(frozen=True)
class Bookkeeping:
    """The layout of the bookkeeping group (discrete-state group 1) of a system with
    ``n_inputs`` measurement inputs: what the runner counts, by name (the cores count
    nothing)."""

    n_inputs: int
    T_LAST: ClassVar[int] = 0  # time of the last step (-inf before any)
    W_LAST: ClassVar[slice] = slice(1, 4)  # last valid gyro rate (the hold)
    STEP: ClassVar[int] = 4  # step index (random cores' generator)
    SEED: ClassVar[slice] = slice(5, 5 + SEED_WORDS)  # the diagram seed's words
    N_RESAMPLES: ClassVar[int] = 5 + SEED_WORDS  # particle resamplings so far
    ESS: ClassVar[int] = 6 + SEED_WORDS  # N_eff after the last update
    N_DEGENERATE: ClassVar[int] = 7 + SEED_WORDS  # degenerate particle updates so far
    T_GYRO_GOOD: ClassVar[int] = 8 + SEED_WORDS  # step of the last usable gyro sample (the first step before any)
    LAST_SAMPLE: ClassVar[int] = 9 + SEED_WORDS  # per input: time tag of its last handled sample

    @property
    def pending(self) -> int:
        """First per-input time tag of a future-tagged sample seen and not yet handled."""
        return self.LAST_SAMPLE + self.n_inputs

    @property
    def rejections(self) -> int:
        """First per-input count of consecutive gate rejections (re-acquisition)."""
        return self.LAST_SAMPLE + 2 * self.n_inputs

    @property
    def size(self) -> int:
        return self.LAST_SAMPLE + 3 * self.n_inputs

    def initial(self, num_particles: int | None) -> np.ndarray:
        book = np.zeros(self.size)
        book[self.T_LAST] = -np.inf
        book[self.T_GYRO_GOOD] = -np.inf
        book[self.ESS] = float(num_particles) if num_particles is not None else np.nan
        book[self.LAST_SAMPLE : self.rejections] = -np.inf
        return book


#: The sample-handling counters (their own discrete-state group, published whole as the
#: ``sample_handling`` output), by index: late samples carried forward and processed, samples
#: rejected for their time tag, prediction recoveries (confirmed samples the gate rejected),
#: samples the sensor monitor excluded (the gyro's included).
N_LATE, N_TAG_REJECTED, N_RECOVERIES, N_EXCLUDED = 0, 1, 2, 3
SAMPLE_HANDLING_NAMES = (
    "late_samples_processed",
    "time_tag_rejections",
    "prediction_recoveries",
    "monitor_exclusions",
)


#: :func:`sample_disposition` / :func:`tag_disposition`: a sample with no usable time stamp
#: (skipped and counted), one that is not new (handled already: passed over), one of this
#: instant (to use now); :func:`tag_disposition` only: one tagged in the future at or after
#: the next step's reach (pending: it may still become due), one tagged before this instant
#: within the lag (carried forward to this instant), one tagged before the lag, and one tagged
#: in the future but too early for the next step to take it (both rejected and counted).
NO_TIME, NOT_DUE, DUE, FUTURE, LATE, TOO_LATE, TOO_EARLY = 0, 1, 2, 3, 4, 5, 6

#: :func:`verdict_code`: the monitor's verdict on a sample.
NOT_ASSESSED, CONFIRMED, EXCLUDED = 0, 1, 2


def rate_usable(valid: float, wx: float, wy: float, wz: float) -> bool:
    """A gyro sample's flag is true (finite and > 0.5) and its rate is finite."""
    return valid > 0.5 and math.isfinite(valid) and math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)


def gyro_sample_usable(
    t: float, tolerance: float, t_gyro: float, valid: float, wx: float, wy: float, wz: float
) -> bool:
    """The gyro sample is this step's (time tag within ``tolerance`` of ``t``) and usable."""
    return abs(t_gyro - t) < tolerance and rate_usable(valid, wx, wy, wz)


def sample_disposition(t_meas: float, t: float, tolerance: float, last_used: float) -> int:
    """Whether a measurement tagged ``t_meas`` whose input last handled a sample tagged
    ``last_used`` is new and of this instant: :data:`NO_TIME`, :data:`NOT_DUE` (not new, or
    not this instant's) or :data:`DUE` (:func:`tag_disposition` without a lag, its off-time
    cases folded into :data:`NOT_DUE`)."""
    disposition = tag_disposition(t_meas, t, tolerance, last_used, 0.0, math.inf)
    return disposition if disposition <= DUE else NOT_DUE


def tag_disposition(t_meas: float, t: float, tolerance: float, last_used: float, lag: float, period: float) -> int:
    """What the step at ``t`` of an estimator with period ``period`` and lag ``lag``
    (``max_time_tag_lag_s``, below the period) does with a measurement tagged ``t_meas`` whose
    input last handled a sample tagged ``last_used``: :data:`NO_TIME` (no finite tag),
    :data:`NOT_DUE` (``t_meas <= last_used``: seen before), :data:`DUE` (``|t_meas - t| <
    tolerance``), :data:`LATE` (``t - lag <= t_meas <= t - tolerance``), :data:`TOO_LATE`
    (``t_meas < t - lag``), :data:`TOO_EARLY` (``t + tolerance <= t_meas < t + period - lag -
    tolerance``: at the next step it would be later than the lag, so no step can take it) or
    :data:`FUTURE` (later: pending; a slower sensor's next sample, tagged at a later step)."""
    if not math.isfinite(t_meas):
        return NO_TIME
    if t_meas <= last_used:
        return NOT_DUE
    if abs(t_meas - t) < tolerance:
        return DUE
    if t_meas > t:
        return TOO_EARLY if t_meas < t + period - lag - tolerance else FUTURE
    return LATE if t - t_meas <= lag else TOO_LATE


def pending_vanished(pending: float, last_used: float, t_meas: float) -> bool:
    """A future-tagged sample seen at an earlier step (tag ``pending``), never handled since
    (``pending > last_used``), is no longer on its port (the port's tag ``t_meas`` is another):
    it can never be used (rejected for its time tag and counted). A sensor slower than the
    filter shows its next sample, tagged at a later filter step, until that step: that sample
    is still on the port when it becomes due, so it does not vanish."""
    return pending > last_used and not t_meas == pending


def verdict_code(value: float) -> int:
    """The monitor's verdict on a sample from its port value: :data:`EXCLUDED` (> 1.5),
    :data:`CONFIRMED` (in (0.5, 1.5]) or :data:`NOT_ASSESSED` (anything else, NaN included)."""
    if value > 1.5:
        return EXCLUDED
    if value > 0.5:
        return CONFIRMED
    return NOT_ASSESSED


def held_rate_variance(q: float, tau: float, dt: float) -> float:
    """The attitude variance (rad^2, per axis) a held gyro rate adds over a step of ``dt`` (s)
    starting ``tau`` (s) after the last usable gyro sample, when the held rate's error is a
    random walk of intensity ``q`` (rad^2/s^3) started at that sample:
    ``q (tau dt^2 + dt^3 / 3)``.

    It is the variance of the step's own drift ``integral_tau^(tau+dt) e(s) ds`` of a rate
    error ``e`` with ``cov(e(s), e(u)) = q min(s, u)``: a rate error of variance ``q tau`` at
    the step's start held over ``dt`` (``q tau dt^2``) plus its walk within the step (``q
    dt^3 / 3``). Added as process noise, it is white from step to step, as a Kalman filter's
    process noise is: the covariance of successive steps' drifts (the same walk) is left out.
    That is right while measurements observe the attitude at every step (each step's drift is
    then what the next measurement sees); over an outage of ``T`` with no measurement at all
    the sum, ``~ q T^2 dt / 2``, is below the true drift variance ``q T^3 / 3`` by a factor
    ``~ 2 T / (3 dt)``. 0 when ``q`` or ``dt`` is not positive (``tau`` below 0 counts as 0)."""
    if not (q > 0.0 and dt > 0.0):
        return 0.0
    tau = max(tau, 0.0)
    return q * (tau * dt * dt + dt * dt * dt / 3.0)


def late_sample_variance(rate_variance: float, gap: float) -> float:
    """The variance (rad^2, per axis) added to a sample carried forward over ``gap`` (s) with
    a rate whose error has variance ``rate_variance`` ((rad/s)^2, per axis): the rotation
    error ``rate error x gap``."""
    return rate_variance * gap * gap


def carried_quaternion(q_IS, q_BS, wx: float, wy: float, wz: float, gap: float):
    """``q_IS ⊗ q_BS^-1 ⊗ exp(w_B gap) ⊗ q_BS`` (4 floats): a sensor attitude measured ``gap``
    (s) before now, carried forward by the body's rotation ``exp(w_B gap)`` over the gap (rate
    ``w_B``, rad/s, constant), expressed in the sensor frame (``q_BS`` a unit quaternion)."""
    aw, ax, ay, az = quat_multiply(q_IS[0], q_IS[1], q_IS[2], q_IS[3], q_BS[0], -q_BS[1], -q_BS[2], -q_BS[3])
    ew, ex, ey, ez = rotvec_to_quat(wx * gap, wy * gap, wz * gap)
    bw, bx, by, bz = quat_multiply(aw, ax, ay, az, ew, ex, ey, ez)
    return quat_multiply(bw, bx, by, bz, q_BS[0], q_BS[1], q_BS[2], q_BS[3])


def covariance_slot(flag: float, n_subsets: int) -> int:
    """Which covariance a quaternion sample with validity ``flag`` takes from a sensor with
    ``n_subsets`` flag-dependent covariances (``QuaternionSensorModel.covariance_by_flag``):
    0 its own ``covariance_S``, ``k >= 1`` the subset ``k = round(flag) - 1``, -1 none (the
    flag names no subset)."""
    if n_subsets == 0 or not flag > 1.5:
        return 0
    if not math.isfinite(flag):
        return -1
    mask = int(round(flag)) - 1  # >= 1: flag > 1.5
    return mask if mask < n_subsets else -1


def is_gate_rejection(accepted: bool, nis: float) -> bool:
    """A rejected update with a NIS (NaN: the core could not form one, e.g. a singular
    innovation covariance) is the gate's: it counts towards re-acquisition."""
    return not accepted and nis == nis


__all__ = [
    "TIME_TOLERANCE_S",
    "Bookkeeping",
    "SAMPLE_HANDLING_NAMES",
    "N_LATE",
    "N_TAG_REJECTED",
    "N_RECOVERIES",
    "N_EXCLUDED",
    "NO_TIME",
    "NOT_DUE",
    "DUE",
    "FUTURE",
    "LATE",
    "TOO_LATE",
    "TOO_EARLY",
    "NOT_ASSESSED",
    "CONFIRMED",
    "EXCLUDED",
    "rate_usable",
    "gyro_sample_usable",
    "sample_disposition",
    "tag_disposition",
    "pending_vanished",
    "verdict_code",
    "held_rate_variance",
    "late_sample_variance",
    "carried_quaternion",
    "covariance_slot",
    "is_gate_rejection",
]
