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
    LAST_SAMPLE: ClassVar[int] = 8 + SEED_WORDS  # per input: time of its last used sample

    @property
    def rejections(self) -> int:
        """First per-input count of consecutive gate rejections (re-acquisition)."""
        return self.LAST_SAMPLE + self.n_inputs

    @property
    def size(self) -> int:
        return self.LAST_SAMPLE + 2 * self.n_inputs

    def initial(self, num_particles: int | None) -> np.ndarray:
        book = np.zeros(self.size)
        book[self.T_LAST] = -np.inf
        book[self.ESS] = float(num_particles) if num_particles is not None else np.nan
        book[self.LAST_SAMPLE : self.rejections] = -np.inf
        return book


#: :func:`sample_disposition`: a sample with no usable time stamp (skipped and counted), one
#: that is not this instant's or was used already (passed over), one to use now.
NO_TIME, NOT_DUE, DUE = 0, 1, 2


def rate_usable(valid: float, wx: float, wy: float, wz: float) -> bool:
    """A gyro sample's flag is true (finite and > 0.5) and its rate is finite."""
    return valid > 0.5 and math.isfinite(valid) and math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)


def gyro_sample_usable(
    t: float, tolerance: float, t_gyro: float, valid: float, wx: float, wy: float, wz: float
) -> bool:
    """The gyro sample is this step's (time tag within ``tolerance`` of ``t``) and usable."""
    return abs(t_gyro - t) < tolerance and rate_usable(valid, wx, wy, wz)


def sample_disposition(t_meas: float, t: float, tolerance: float, last_used: float) -> int:
    """What the step does with a measurement tagged ``t_meas`` whose input last delivered a
    used sample at ``last_used``: :data:`NO_TIME`, :data:`NOT_DUE` or :data:`DUE`."""
    if not math.isfinite(t_meas):
        return NO_TIME
    if abs(t_meas - t) >= tolerance or t_meas <= last_used:
        return NOT_DUE
    return DUE


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
    "NO_TIME",
    "NOT_DUE",
    "DUE",
    "rate_usable",
    "gyro_sample_usable",
    "sample_disposition",
    "covariance_slot",
    "is_gate_rejection",
]
