"""The chi-square innovation gate every Kalman-type core shares (plain numpy/math).

A measurement whose normalized innovation squared ``NIS = z' S^-1 z`` exceeds the gate's
threshold for its dimension is rejected (``UpdateInfo.accepted`` false: the estimator system
skips and counts it). The threshold is either given (``chi2``) or the chi-square quantile of
a probability for the innovation's dimension (``probability``: 0.999 rejects 0.1% of nominal
measurements of a consistent filter, whatever their dimension — a quaternion's 3, two star
vectors' 6). The library's default is :data:`DEFAULT_GATE_PROBABILITY` (1 - 1e-5, see there).

Re-acquisition: a gate that only rejects would reject forever once the filter has drifted
(after an outage, a wrong initialization, a real manoeuvre). The estimator system therefore
calls a core's ``reacquire(state, info)`` after :data:`REACQUIRE_AFTER_REJECTIONS`
consecutive rejections of one input and retries the measurement: the core inflates the
attitude block of its covariance by :func:`reacquire_factor` (so that the rejected
innovation would sit at about half the gate), capped at a pi-radian sigma.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace

import numpy as np

from drake_att.validation import check_positive, fail

# 1 - 1e-5: one false rejection in 1e5 nominal updates. 0.999 is not free: a rejected
# measurement leaves that step at the prior, and where the prior is much worse than the
# posterior (paper S3's MEMS gyro against 5" trackers: ~20x) one false rejection in 1000 raised
# the yaw RMSE of an 800 s run by ~20% (tests/test_fusion.py). At 1e-5 the threshold (3 dof:
# 25.9) still rejects a 0.03 deg outlier of a 5" tracker (NIS ~ 500).
DEFAULT_GATE_PROBABILITY = 0.99999
REACQUIRE_AFTER_REJECTIONS = 5


def _lower_regularized_gamma(a: float, x: float) -> float:
    """``P(a, x)``, the regularized lower incomplete gamma function (series / continued
    fraction, Numerical Recipes' gser/gcf), to ~1e-15."""
    if x <= 0.0:
        return 0.0
    log_prefix = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        ap = a
        for _ in range(10_000):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * 1e-16:
                break
        return total * math.exp(log_prefix)
    b = x + 1.0 - a
    c = 1.0 / 1e-300
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = 1e-300 if abs(d) < 1e-300 else d
        c = b + an / c
        c = 1e-300 if abs(c) < 1e-300 else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return 1.0 - math.exp(log_prefix) * h


def chi2_cdf(x: float, dof: int) -> float:
    """The chi-square distribution function with ``dof`` degrees of freedom."""
    return _lower_regularized_gamma(0.5 * dof, 0.5 * x)


def chi2_quantile(probability: float, dof: int) -> float:
    """The ``probability`` quantile of the chi-square distribution with ``dof`` degrees of
    freedom (bisection on :func:`chi2_cdf`, relative accuracy ~1e-12)."""
    if not 0.0 < probability < 1.0:
        fail("probability", probability, "must be in (0, 1)")
    if not (isinstance(dof, int) and dof >= 1):
        fail("dof", dof, "must be an integer >= 1")
    lo, hi = 0.0, max(4.0 * dof, 10.0)
    while chi2_cdf(hi, dof) < probability:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, dof) < probability:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class InnovationGate:
    """A chi-square gate: a fixed threshold (``chi2``), a probability (threshold per
    innovation dimension), or off (both None)."""

    chi2: float | None = None
    probability: float | None = None
    _thresholds: dict[int, float] = field(default_factory=dict, init=False, repr=False, compare=False)  # per dof

    def __post_init__(self):
        if self.chi2 is not None and self.probability is not None:
            fail("innovation gate", (self.chi2, self.probability), "give a chi2 threshold or a probability, not both")
        if self.chi2 is not None:
            check_positive("innovation_gate_chi2", self.chi2)
        if self.probability is not None and not 0.0 < self.probability < 1.0:
            fail("innovation_gate_probability", self.probability, "must be in (0, 1) (0 in a config: no gate)")

    @classmethod
    def of(cls, gate) -> InnovationGate:
        """``gate`` as an :class:`InnovationGate`: None (off), a chi2 threshold, or a gate."""
        if isinstance(gate, InnovationGate):
            return gate
        return cls() if gate is None else cls(chi2=float(gate))

    @property
    def enabled(self) -> bool:
        return self.chi2 is not None or self.probability is not None

    def threshold(self, dof: int) -> float:
        """The NIS threshold for a ``dof``-dimensional innovation (inf when off)."""
        if self.chi2 is not None:
            return self.chi2
        if self.probability is None:
            return math.inf
        cached = self._thresholds.get(dof)
        if cached is None:
            cached = self._thresholds[dof] = chi2_quantile(self.probability, int(dof))
        return cached

    def rejects(self, nis: float, dof: int) -> bool:
        """True if an update with this NIS must be rejected (a non-finite NIS always is)."""
        return not math.isfinite(nis) or nis > self.threshold(dof)


def reacquire_factor(gate: InnovationGate, info) -> float:
    """Covariance inflation after repeated rejections (:func:`inflation_factor` of the last
    rejected innovation's NIS and the gate's threshold for its dimension)."""
    dof = 3 if info.innovation is None else int(len(info.innovation))
    return inflation_factor(info.nis, gate.threshold(dof))


def inflation_factor(nis: float, threshold: float) -> float:
    """The factor that puts a rejected innovation's NIS at half the gate (``2 NIS /
    threshold``), at least 2; 2 without a gate (or a NIS). A plain scalar function: the
    compiled MEKF step compiles this same rule."""
    if not math.isfinite(threshold):
        return 2.0
    return max(2.0, 2.0 * (nis if math.isfinite(nis) else 0.0) / threshold)


def capped_factor(factor: float, largest_variance: float, max_sigma_rad: float = math.pi) -> float:
    """``factor`` reduced so the largest attitude variance ``largest_variance`` grows to at
    most ``max_sigma_rad^2`` (never below 1: a re-acquisition does not shrink ``P``)."""
    if largest_variance > 0.0:
        return min(factor, max(1.0, max_sigma_rad**2 / largest_variance))
    return factor


def inflate_attitude_block(P, factor: float, n: int = 3, max_sigma_rad: float = math.pi):
    """``P`` with its leading ``n x n`` (attitude) block multiplied by ``factor`` — the
    cross-covariances and the rest untouched, ``P + (factor - 1) blockdiag(P_aa, 0)``, still
    positive semi-definite — and each attitude variance capped at ``max_sigma_rad^2``
    (:func:`capped_factor`). Inflating the bias block too would let one re-acquisition throw
    the bias estimate away."""
    P = np.asarray(P, dtype=np.float64).copy()  # numba compiles this function too (no np.array of an array)
    block = P[:n, :n]
    k = capped_factor(float(factor), float(np.max(np.diag(block))), max_sigma_rad)
    P[:n, :n] = block + (k - 1.0) * block
    return P


def inflated(state, factor: float, field: str = "P", square_root: bool = False, n: int = 3):
    """``state`` with the attitude block of its covariance ``field`` inflated by ``factor``
    (:func:`inflate_attitude_block`; for a square-root ``field``, its factor recomputed): the
    one implementation of the cores' ``reacquire``."""
    value = np.asarray(getattr(state, field), dtype=float)
    if square_root:
        new = np.linalg.cholesky(inflate_attitude_block(value @ value.T, factor, n))
    else:
        new = inflate_attitude_block(value, factor, n)
    return replace(state, **{field: new})


__all__ = [
    "DEFAULT_GATE_PROBABILITY",
    "REACQUIRE_AFTER_REJECTIONS",
    "chi2_cdf",
    "chi2_quantile",
    "InnovationGate",
    "reacquire_factor",
    "inflation_factor",
    "capped_factor",
    "inflated",
]


class GatedCore:
    """Mixin of the cores that gate their updates with an :class:`InnovationGate` held in
    ``self.gate``: :meth:`ungated` is the core re-acquisition retries with
    (:class:`drake_att.contract.Reacquisition`)."""

    gate: InnovationGate

    def ungated(self):
        """A shallow copy of this core whose gate rejects nothing (the tuning is shared)."""
        twin = copy.copy(self)
        twin.gate = InnovationGate()
        return twin
