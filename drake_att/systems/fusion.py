"""Multi-sensor fusion systems (paper S3): star-tracker averaging and estimate fusion.

Both are stateless ``LeafSystem`` s whose outputs are direct functions of their inputs,
so they add no sample delay.

* :class:`StarTrackerAverage` ("centralized"): converts each tracker's ``q_IS_meas`` into
  a body-attitude measurement ``q_IB_meas,i = q_IS_meas,i ⊗ q_BS,i^-1`` and averages them
  (Markley et al. 2007).  Its measurement covariance is derived, not guessed: with
  ``q_IB_meas,i = q_IB ⊗ exp(R_BS,i delta_i)`` and weights ``w_i`` (sum 1), to first order
  ``q_avg = q_IB ⊗ exp(sum_i w_i R_BS,i delta_i)``, hence
  ``R_avg,B = sum_i w_i^2 R_BS,i diag(sigma_S,i^2) R_BS,i'`` (independent trackers).
* :class:`EstimateFusion` ("decentralized"): averages the attitude estimates of several
  estimators (quaternion average) and their second vectors (linear average).  The fused
  error is ``e = sum_i w_i e_i`` (first order), so its covariance is
  ``sum_ij w_i w_j P_ij``; the estimators share one gyro, so the cross terms are not zero.
  Reported covariance (``covariance_model``):
    - "tracked" (two MEKFs): the cross-covariance is propagated exactly for the linearized
      filters (track-to-track fusion with common process noise, Bar-Shalom 1981):
      ``P_12 <- A_1 (Phi_1 P_12 Phi_2' + Q) A_2'`` from each MEKF's ``step_linearization``
      (``Q`` is the common gyro noise - the first source's model of it, should the two
      filters' gyro-noise tunings differ; measurement noises are independent), starting from
      ``P_12 = P_0`` (both start from the same estimate, so their initial errors are equal;
      ``P_0`` is read from the first source's covariance at initialization, so it follows
      a context that changes the sources' initial covariance).
    - "conservative": ``sum_i w_i P_i``.  For weights summing to one,
      ``(sum w_i e_i)(sum w_i e_i)' <= sum w_i e_i e_i'`` (convexity), so this bounds the
      true covariance whatever the correlation; tight when fully correlated.
    - "independent": ``sum_i w_i^2 P_i`` - ignores the shared gyro (optimistic).

Per-evaluation cost: the outputs are recomputed at every evaluation, so they use Python
floats and the closed-form average of two quaternions (the eigenvector average for more),
and do not re-check values the constructors checked.  An input quaternion that is not
finite, is zero or has an extreme magnitude goes through the checked
:func:`~drake_att.filters.quaternion_average.average_quaternions` instead (which rejects the
first two), so the results are those of the general average to round-off (but in the
degenerate case of two equally weighted rotations 180 deg apart, where every unit
quaternion in their span is an average: the closed form returns the first).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.contract import COVARIANCE, ESTIMATE_SIZE, Q_IB, SECOND, STATUS, TIME_TOLERANCE_S
from drake_att.filters.quaternion_average import (
    _average_two_unit_quaternions,
    _average_unit_quaternions,
    average_quaternions,
)
from drake_att.systems.star_tracker import QUATERNION_MEASUREMENT_SIZE

_UNIT_NORM2_RANGE = (1e-100, 1e100)  # |q|^2 normalized directly in floats (no under/overflow)


def _quat_multiply(p, q) -> list:
    """Hamilton product ``p ⊗ q`` of two quaternions given as 4 floats (the operations of
    :func:`drake_att.rotations.quat_multiply`, in the same order)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return [
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ]


def _unit(q):
    """``q / |q|`` for 4 floats; None when ``|q|^2`` is not in :data:`_UNIT_NORM2_RANGE`
    (not finite, zero, or extreme)."""
    a, b, c, d = q
    n2 = a * a + b * b + c * c + d * d
    if not _UNIT_NORM2_RANGE[0] < n2 < _UNIT_NORM2_RANGE[1]:
        return None
    n = math.sqrt(n2)
    return [a / n, b / n, c / n, d / n]


def _average(quaternions, weights) -> list:
    """``average_quaternions(quaternions, weights)`` (scalar part >= 0) as 4 floats.

    Args:
        quaternions: N >= 2 quaternions ``[w, x, y, z]``, each 4 floats (any nonzero norm).
        weights: N floats (dimensionless), >= 0 and finite.

    Two inputs: the closed form; more: the eigenvector step; both without re-validation.
    A quaternion outside the float fast path (see :func:`_unit`) or weights without a
    positive sum go to the checked :func:`average_quaternions`, which rescales extreme
    magnitudes and raises ``ValueError`` for invalid input.
    """
    units = [_unit(q) for q in quaternions]
    if None in units or not sum(weights) > 0.0:
        return average_quaternions(np.array(quaternions), np.array(weights)).tolist()
    if len(units) == 2:
        q = _average_two_unit_quaternions(units[0], units[1], weights[0], weights[1])
        return [-x for x in q] if q[0] < 0.0 else q
    w = np.array(weights)
    return _average_unit_quaternions(np.array(units), w / w.sum()).tolist()


def _weighted_sum(coefficients, vectors):
    """``sum_i c_i v_i`` (accumulated in input order) of equal-length vectors: numpy arrays
    (returns an array) or lists of floats (returns a list; cheaper for a few entries)."""
    c0, v0 = coefficients[0], vectors[0]
    if isinstance(v0, list):
        acc = [c0 * x for x in v0]
        for c, v in zip(coefficients[1:], vectors[1:], strict=True):
            acc = [a + c * x for a, x in zip(acc, v, strict=True)]
        return acc
    acc = c0 * v0
    for c, v in zip(coefficients[1:], vectors[1:], strict=True):
        acc = acc + c * v
    return acc


def _check_realizations(name: str, realizations) -> int:
    if not (isinstance(realizations, int) and realizations >= 1):
        raise ValueError(f"{name}.realizations: got {realizations!r}; must be an integer >= 1")
    return realizations


def _normalized_weights(weights, n, field):
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"{field}: got {list(np.atleast_1d(weights))}; need {n} finite weights >= 0 with positive sum")
    return w / w.sum()


def average_measurement_covariance_B(q_BS_list, sigmas_S_list, weights) -> np.ndarray:
    """``R_avg,B = sum_i w_i^2 R_BS,i diag(sigma_S,i^2) R_BS,i'`` (weights normalized to 1)."""
    w = _normalized_weights(weights, len(q_BS_list), "weights")
    covariance_B = np.zeros((3, 3))
    for wi, q, s in zip(w, q_BS_list, sigmas_S_list, strict=True):
        R_BS = rot.quat_to_rotmat(rot.quat_normalize(q))
        covariance_B += wi**2 * R_BS @ np.diag(np.asarray(s, dtype=float) ** 2) @ R_BS.T
    return covariance_B


def subset_covariances(q_BS_list, sigmas_S_list, weights) -> tuple:
    """``[mask] -> covariance_B`` of the average of the trackers in bit mask ``mask`` with
    their weights renormalized (index 0 and the full mask: None — flag 1 covers all)."""
    n = len(q_BS_list)
    w = np.asarray(weights, dtype=float)
    out: list[np.ndarray | None] = [None] * (1 << n)
    for mask in range(1, (1 << n) - 1):
        idx = [i for i in range(n) if mask >> i & 1]
        if w[idx].sum() <= 0.0:
            continue
        out[mask] = average_measurement_covariance_B(
            [q_BS_list[i] for i in idx], [sigmas_S_list[i] for i in idx], w[idx]
        )
    return tuple(out)


class StarTrackerAverage(LeafSystem):
    """Averaged body-attitude measurement from several star trackers.

    Args:
        name: system name.
        tracker_names: names of the quaternion-mode trackers (input port suffixes).
        q_BS_list: mounting of each tracker (4,).
        sigmas_S_list: (3,) noise sigmas of each tracker in its sensor frame (rad).
        weights: averaging weights (normalized to sum 1).
        realizations: N realizations in one system (a batch of runs): every port carries N
            blocks, realization-major, each averaged as a system alone would.

    Input ports:
        q_meas_<tracker> (6): ``[t, valid, q_IS_meas (4)]`` per tracker.
    Output ports:
        star_tracker_measurement (6): ``[t, valid, q_IB_meas (4)]`` - a measurement of a
            virtual sensor with ``q_BS = identity`` and covariance :attr:`covariance_B`.
            When every input is valid at the same instant: their weighted average, flag 1.
            When only some are (a tracker dropped out): the average of those with their
            weights renormalized, flag ``1 + mask`` (bit i = input i), whose covariance is
            :attr:`covariance_by_mask` ``[mask]`` — the estimator uses the trackers that are
            fine instead of losing the step. None valid: flag 0.
    """

    def __init__(self, name, tracker_names, q_BS_list, sigmas_S_list, weights, realizations: int = 1):
        LeafSystem.__init__(self)
        self.set_name(name)
        self.realizations = N = _check_realizations(name, realizations)
        n = len(tracker_names)
        if n < 2:
            raise ValueError(f"{name}.star_trackers: got {list(tracker_names)}; need at least 2 trackers")
        self.weights = _normalized_weights(weights, n, f"{name}.weights")
        self.q_BS = [rot.quat_normalize(q) for q in q_BS_list]
        self._w = self.weights.tolist()
        self._q_SB = [rot.quat_conjugate(q).tolist() for q in self.q_BS]  # q_BS,i^-1 (unit)
        self.covariance_B = average_measurement_covariance_B(q_BS_list, sigmas_S_list, weights)
        self.covariance_by_mask = subset_covariances(q_BS_list, sigmas_S_list, self.weights)
        size = QUATERNION_MEASUREMENT_SIZE
        self._ports = [self.DeclareVectorInputPort(f"q_meas_{t}", size * N) for t in tracker_names]
        self.DeclareVectorOutputPort("star_tracker_measurement", size * N, self._calc)

    def _calc(self, context, output: BasicVector):
        meas = [p.Eval(context).tolist() for p in self._ports]  # type: ignore[attr-defined]  # pydrake stub
        size, values = QUATERNION_MEASUREMENT_SIZE, []
        for i in range(self.realizations):
            values += self._sample([m[i * size : (i + 1) * size] for m in meas])
        output.SetFromVector(values)  # type: ignore[arg-type]  # pydrake stub

    def _sample(self, meas: list) -> list:
        """The averaged sample ``[t, flag, q_IB_meas (4)]`` of one realization's tracker
        samples (each 6 floats)."""
        # Fine: flagged valid (a NaN flag is not) and every entry finite.
        fine = [m[1] > 0.5 and all(map(math.isfinite, m)) for m in meas]
        if any(fine):
            t_latest = max(m[0] for m, f in zip(meas, fine, strict=True) if f)
        else:
            times = [m[0] for m in meas]
            t_latest = math.nan if any(map(math.isnan, times)) else max(times)
        # This instant's samples only.
        idx = [
            i for i, (m, f) in enumerate(zip(meas, fine, strict=True)) if f and abs(m[0] - t_latest) < TIME_TOLERANCE_S
        ]
        q_avg, flag = [1.0, 0.0, 0.0, 0.0], 0.0
        if idx:
            q_B = [_quat_multiply(meas[i][2:], self._q_SB[i]) for i in idx]
            flag = 1.0 if len(idx) == len(meas) else 1.0 + float(sum(1 << i for i in idx))
            # _average renormalizes the weights of the trackers used.
            q_avg = q_B[0] if len(idx) == 1 else _average(q_B, [self._w[i] for i in idx])
        return [t_latest, flag, *q_avg]


class EstimateFusion(LeafSystem):
    """Weighted fusion of several estimators' outputs (estimator contract in and out).

    Args:
        name: system name.
        source_names: names of the fused estimators (input port prefixes).
        weights: fusion weights (normalized to sum 1).
        second_output_name: "bias_B_hat" or "w_IB_B_hat" (must match the sources).
        covariance_model: "tracked", "conservative" or "independent" (see module docstring).
        period_s: the sources' filter step (s); needed by "tracked", and the period at which
            the scenario builder logs the fused estimate.
        realizations: N realizations in one system (a batch of runs): the inputs are then each
            source's packed ``s_estimate_state`` (47 N) and ``s_linearization`` (109 N), the only
            output ``estimate_state`` (47 N) and the state 37 N, realization-major; each
            realization is fused with the arithmetic of a system alone.

    Input ports (per source ``s``): ``s_q_IB_hat`` (4), ``s_second`` (3),
        ``s_covariance`` (36), ``s_status`` (4); with "tracked" also ``s_linearization``
        (109, the MEKF's ``step_linearization``).
    Output ports: the estimator contract (``q_IB_hat``, second vector, ``covariance``,
        ``status`` with ``t_estimate`` = the sources' common estimate time; NaN time when
        the sources disagree on it). A source that has used no measurement while another has
        is left out (:meth:`active_weights`): a branch whose tracker never delivered does not
        drag the fused estimate to its initial guess. ``estimate_state`` (47): the four in
        the contract's packed layout from one evaluation (what the scenario builder logs).
    Discrete state ("tracked" only, 37): ``[P_12 (36), steps applied]``, advanced by a
        periodic event at ``period_s`` (the sources' step).  The output applies the same
        one-step recursion to the inputs it sees, so the reported covariance always refers
        to the same step as the fused estimate.
    """

    def __init__(
        self,
        name,
        source_names,
        weights,
        second_output_name="bias_B_hat",
        covariance_model="conservative",
        period_s=None,
        realizations: int = 1,
    ):
        LeafSystem.__init__(self)
        self.set_name(name)
        self.realizations = N = _check_realizations(name, realizations)
        n = len(source_names)
        if n < 2:
            raise ValueError(f"{name}.sources: got {list(source_names)}; need at least 2 estimators")
        if covariance_model not in ("tracked", "conservative", "independent"):
            raise ValueError(
                f"{name}.covariance_model: got {covariance_model!r}; allowed: 'tracked', 'conservative', 'independent'"
            )
        if covariance_model == "tracked" and (n != 2 or period_s is None):
            raise ValueError(f"{name}.covariance_model: 'tracked' needs exactly 2 MEKF sources and their period")
        self.weights = _normalized_weights(weights, n, f"{name}.weights")
        self.covariance_model = covariance_model
        self.second_output_name = second_output_name
        self.period_s = None if period_s is None else float(period_s)  # the sources' step
        self.source_names = list(source_names)
        if N == 1:
            self._in = {
                s: {
                    k: self.DeclareVectorInputPort(f"{s}_{k}", size)
                    for k, size in (("q_IB_hat", 4), ("second", 3), ("covariance", 36), ("status", 4))
                }
                for s in source_names
            }
            self._q_ports, self._second_ports, self._cov_ports, self._status_ports = (
                [self._in[s][k] for s in source_names] for k in ("q_IB_hat", "second", "covariance", "status")
            )
        else:  # each source's packed estimate, N blocks
            self._packed_ports = [
                self.DeclareVectorInputPort(f"{s}_estimate_state", ESTIMATE_SIZE * N) for s in source_names
            ]
        self._w = self.weights.tolist()
        self._cov_coefficients = self._w if covariance_model == "conservative" else [w * w for w in self._w]
        if covariance_model == "tracked":  # the coefficients of P_1, P_2 and P_12 + P_12'
            w1, w2 = self._w
            self._tracked_coefficients = (w1 * w1, w2 * w2, w1 * w2)
            self._lin = {s: self.DeclareVectorInputPort(f"{s}_linearization", 109 * N) for s in source_names}
            self._lin_ports = [self._lin[s] for s in source_names]
            self._cross_group = self.DeclareDiscreteState(
                np.tile(np.concatenate([np.eye(6).ravel(), [0.0]]), N)  # type: ignore[arg-type]  # pydrake stub
            )
            self._cross_index = int(self._cross_group)  # an int selects the group faster
            self.DeclareInitializationDiscreteUpdateEvent(self._initialize_cross)
            self.DeclarePeriodicDiscreteUpdateEvent(float(period_s), 0.0, self._advance_cross)
        if N == 1:
            self.DeclareVectorOutputPort("q_IB_hat", 4, self._calc_q)
            self.DeclareVectorOutputPort(second_output_name, 3, self._calc_second)
            self.DeclareVectorOutputPort("covariance", 36, self._calc_cov)
            self.DeclareVectorOutputPort("status", 4, self._calc_status)
        # All four in one evaluation, in the estimator contract's packed layout: what the
        # scenario builder logs (one Python call per logged sample instead of four).
        self.DeclareVectorOutputPort("estimate_state", ESTIMATE_SIZE * N, self._calc_estimate_state)

    def _weights_in_use(self, context) -> tuple:
        """``(weights as floats, configured?)``: :meth:`active_weights` as a list, and
        whether it is the configured weights unchanged."""
        return self._weights_of([p.Eval(context)[1] > 0 for p in self._status_ports])  # type: ignore[index]

    def _weights_of(self, active: list) -> tuple:
        """:meth:`_weights_in_use` for the sources' ``active`` flags (used a measurement)."""
        if all(active) or not any(active):
            return self._w, True
        w = [wi if a else 0.0 for wi, a in zip(self._w, active, strict=True)]
        total = sum(w)
        return ([wi / total for wi in w] if total > 0.0 else [math.nan] * len(w)), False

    def active_weights(self, context) -> np.ndarray:
        """The weights in use: a source that has used no measurement yet while another has
        (a branch whose sensor never delivered) gets weight 0 and the others are renormalized
        — its estimate is only its prediction from the initial state. Otherwise the
        configured weights, unchanged (the array :attr:`weights` itself)."""
        w, configured = self._weights_in_use(context)
        return self.weights if configured else np.array(w)

    def _q(self, context, w):
        return _fused_quaternion([p.Eval(context).tolist() for p in self._q_ports], w)

    def _second(self, context, w):
        return _weighted_sum(w, [p.Eval(context).tolist() for p in self._second_ports])

    def _calc_q(self, context, output):
        output.SetFromVector(self._q(context, self._weights_in_use(context)[0]))

    def _calc_second(self, context, output):
        output.SetFromVector(self._second(context, self._weights_in_use(context)[0]))

    def _calc_cov(self, context, output):
        output.SetFromVector(self._cov(context, *self._weights_in_use(context)))

    def _calc_status(self, context, output):
        output.SetFromVector(self._status(context))

    def _calc_estimate_state(self, context, output):
        """``[q_IB_hat (4), second (3), covariance (36), status (4)]`` (the contract's packed
        estimate), the four outputs' values computed once (N blocks with N realizations)."""
        if self.realizations > 1:
            output.SetFromVector(self._estimate_states(context))
            return
        w, configured = self._weights_in_use(context)
        output.SetFromVector(
            np.concatenate(
                [
                    self._q(context, w),
                    self._second(context, w),
                    self._cov(context, w, configured),
                    self._status(context),
                ]
            )
        )

    def _estimate_states(self, context) -> np.ndarray:
        """The packed fused estimate of every realization (realization-major): per realization
        the single system's arithmetic on that realization's blocks of the inputs."""
        N = self.realizations
        packed = [np.reshape(p.Eval(context), (N, ESTIMATE_SIZE)) for p in self._packed_ports]  # type: ignore[call-overload]
        cross = self._cross_covariances(context) if self.covariance_model == "tracked" else None
        out = np.empty((N, ESTIMATE_SIZE))
        for i in range(N):
            rows = [x[i] for x in packed]
            statuses = [r[STATUS].tolist() for r in rows]
            w, configured = self._weights_of([st[1] > 0 for st in statuses])
            out[i, Q_IB] = _fused_quaternion([r[Q_IB].tolist() for r in rows], w)
            out[i, SECOND] = _weighted_sum(w, [r[SECOND].tolist() for r in rows])
            P12 = None if cross is None else cross[i][0]
            out[i, COVARIANCE] = self._fused_covariance([r[COVARIANCE] for r in rows], w, configured, P12)
            out[i, STATUS] = _fused_status(statuses)
        return out.ravel()

    def _cross_covariances(self, context) -> list:
        """``[(P_12, step), ...]`` per realization: ``P_12`` at the step of the current inputs,
        the stored one advanced once if the sources have taken a step since (NaN if the sources
        disagree on the step)."""
        N = self.realizations
        x = np.reshape(context.get_discrete_state(self._cross_index).value(), (N, 37))
        l1, l2 = (np.reshape(p.Eval(context), (N, 109)) for p in self._lin_ports)  # type: ignore[call-overload]
        return [_advanced_cross_covariance(x[i], l1[i], l2[i]) for i in range(N)]

    def _initialize_cross(self, context, discrete_state):
        """``P_12 = P_0``: the first source's covariance at initialization (its initial one)."""
        if self.realizations == 1:
            P0 = self._in[self.source_names[0]]["covariance"].Eval(context)
            value = np.concatenate([P0, [0.0]])
        else:
            first = np.reshape(self._packed_ports[0].Eval(context), (self.realizations, ESTIMATE_SIZE))
            value = np.concatenate([np.concatenate([row[COVARIANCE], [0.0]]) for row in first])
        discrete_state.get_mutable_vector(self._cross_group).SetFromVector(value)
        return EventStatus.Succeeded()

    def _advance_cross(self, context, discrete_state):
        value = np.concatenate(
            [np.concatenate([P12.ravel(), [steps]]) for P12, steps in self._cross_covariances(context)]
        )
        discrete_state.get_mutable_vector(self._cross_group).SetFromVector(value)
        return EventStatus.Succeeded()

    def _cov(self, context, weights, configured):
        P = [p.Eval(context) for p in self._cov_ports]  # (36,) each
        tracked = configured and self.covariance_model == "tracked"
        P12 = self._cross_covariances(context)[0][0] if tracked else None  # a system alone: one realization
        return self._fused_covariance(P, weights, configured, P12)

    def _fused_covariance(self, P: list, weights, configured: bool, P12):
        """The fused covariance (36) of the sources' ``P`` (36 each) with the weights in use;
        ``P12``: the tracked cross-covariance (6, 6), read only by the "tracked" model with the
        configured weights."""
        if not configured:  # a dead branch dropped: the live ones' covariance
            live = [w > 0.0 for w in weights]
            if sum(live) == 1:
                return P[live.index(True)]
            c = weights if self.covariance_model == "conservative" else [w * w for w in weights]
            return _weighted_sum(c, P)
        if self.covariance_model == "tracked":
            c11, c22, c12 = self._tracked_coefficients  # w1^2, w2^2, w1 w2
            return c11 * P[0] + c22 * P[1] + c12 * (P12 + P12.T).ravel()
        return _weighted_sum(self._cov_coefficients, P)

    def _status(self, context):
        return _fused_status([p.Eval(context).tolist() for p in self._status_ports])


def _fused_quaternion(quaternions: list, w) -> list:
    """The weighted average of the sources' quaternions (4 floats each); NaN when one is not
    finite: the run then fails naming it (the builder's finite check) instead of the average
    refusing NaN mid-simulation."""
    if not all(math.isfinite(x) for q in quaternions for x in q):
        return [math.nan] * 4
    return _average(quaternions, w)


def _fused_status(statuses: list) -> list:
    """``[t, used, skipped, nan]`` of the sources' statuses (4 floats each): their common
    estimate time (NaN when they disagree) and their summed counts."""
    times = [s[0] for s in statuses]
    spread = math.nan if any(map(math.isnan, times)) else max(times) - min(times)
    t = times[0] if spread < TIME_TOLERANCE_S else math.nan
    used, skipped = statuses[0][1], statuses[0][2]
    for s in statuses[1:]:
        used, skipped = used + s[1], skipped + s[2]
    return [t, used, skipped, math.nan]


def _advanced_cross_covariance(x, l1, l2) -> tuple:
    """``(P_12, step)``: the stored ``x = [P_12 (36), steps applied]`` advanced once by the
    sources' linearizations ``l1``, ``l2`` (109 each) if they have taken a step since (NaN if
    they disagree on the step)."""
    applied = x[36]
    step = l1[108]
    if step != l2[108]:
        return np.full((6, 6), np.nan), applied
    P12 = x[:36].reshape(6, 6)
    if step > applied:
        Phi1, Q, A1 = l1[:36].reshape(6, 6), l1[36:72].reshape(6, 6), l1[72:108].reshape(6, 6)
        Phi2, A2 = l2[:36].reshape(6, 6), l2[72:108].reshape(6, 6)
        P12 = A1.dot(Phi1.dot(P12).dot(Phi2.T) + Q).dot(A2.T)  # A1 (Phi1 P12 Phi2' + Q) A2'
    return P12, step
