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
      (``Q`` is the common gyro noise, measurement noises are independent), starting from
      ``P_12 = P_0`` (both start from the same estimate, so their initial errors are equal;
      ``P_0`` is read from the first source's covariance at initialization, so it follows
      a context that changes the sources' initial covariance).
    - "conservative": ``sum_i w_i P_i``.  For weights summing to one,
      ``(sum w_i e_i)(sum w_i e_i)' <= sum w_i e_i e_i'`` (convexity), so this bounds the
      true covariance whatever the correlation; tight when fully correlated.
    - "independent": ``sum_i w_i^2 P_i`` - ignores the shared gyro (optimistic).
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.filters.quaternion_average import average_quaternions
from drake_att.systems.star_tracker import QUATERNION_MEASUREMENT_SIZE

TIME_TOLERANCE_S = 1e-6


def _normalized_weights(weights, n, field):
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"{field}: got {list(np.atleast_1d(weights))}; need {n} finite weights >= 0 with positive sum")
    return w / w.sum()


def average_measurement_covariance_B(q_BS_list, sigmas_S_list, weights) -> np.ndarray:
    """``R_avg,B = sum_i w_i^2 R_BS,i diag(sigma_S,i^2) R_BS,i'`` (weights normalized to 1)."""
    w = _normalized_weights(weights, len(q_BS_list), "weights")
    covariance_B = np.zeros((3, 3))
    for wi, q, s in zip(w, q_BS_list, sigmas_S_list):
        R_BS = rot.quat_to_rotmat(rot.quat_normalize(q))
        covariance_B += wi**2 * R_BS @ np.diag(np.asarray(s, dtype=float) ** 2) @ R_BS.T
    return covariance_B


def subset_covariances(q_BS_list, sigmas_S_list, weights) -> tuple:
    """``[mask] -> covariance_B`` of the average of the trackers in bit mask ``mask`` with
    their weights renormalized (index 0 and the full mask: None — flag 1 covers all)."""
    n = len(q_BS_list)
    w = np.asarray(weights, dtype=float)
    out = [None] * (1 << n)
    for mask in range(1, (1 << n) - 1):
        idx = [i for i in range(n) if mask >> i & 1]
        if w[idx].sum() <= 0.0:
            continue
        out[mask] = average_measurement_covariance_B([q_BS_list[i] for i in idx], [sigmas_S_list[i] for i in idx],
                                                     w[idx])
    return tuple(out)


class StarTrackerAverage(LeafSystem):
    """Averaged body-attitude measurement from several star trackers.

    Args:
        name: system name.
        tracker_names: names of the quaternion-mode trackers (input port suffixes).
        q_BS_list: mounting of each tracker (4,).
        sigmas_S_list: (3,) noise sigmas of each tracker in its sensor frame (rad).
        weights: averaging weights (normalized to sum 1).

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

    def __init__(self, name, tracker_names, q_BS_list, sigmas_S_list, weights):
        LeafSystem.__init__(self)
        self.set_name(name)
        n = len(tracker_names)
        if n < 2:
            raise ValueError(f"{name}.star_trackers: got {list(tracker_names)}; need at least 2 trackers")
        self.weights = _normalized_weights(weights, n, f"{name}.weights")
        self.q_BS = [rot.quat_normalize(q) for q in q_BS_list]
        self.covariance_B = average_measurement_covariance_B(q_BS_list, sigmas_S_list, weights)
        self.covariance_by_mask = subset_covariances(q_BS_list, sigmas_S_list, self.weights)
        self._ports = [self.DeclareVectorInputPort(f"q_meas_{t}", QUATERNION_MEASUREMENT_SIZE) for t in tracker_names]
        self.DeclareVectorOutputPort("star_tracker_measurement", QUATERNION_MEASUREMENT_SIZE, self._calc)

    def _calc(self, context, output: BasicVector):
        meas = [p.Eval(context) for p in self._ports]
        times = np.array([m[0] for m in meas])
        fine = np.array([m[1] > 0.5 and m[1] == m[1] and np.all(np.isfinite(m)) for m in meas])
        t_latest = times[fine].max() if fine.any() else times.max()
        fine &= np.abs(times - t_latest) < TIME_TOLERANCE_S  # this instant's samples only
        out = np.empty(QUATERNION_MEASUREMENT_SIZE)
        q_avg, flag = np.array([1.0, 0.0, 0.0, 0.0]), 0.0
        if fine.all():
            q_B = np.array([rot.quat_multiply(m[2:], rot.quat_conjugate(q)) for m, q in zip(meas, self.q_BS)])
            q_avg, flag = average_quaternions(q_B, self.weights), 1.0
        elif fine.any():
            idx = np.flatnonzero(fine)
            q_B = np.array([rot.quat_multiply(meas[i][2:], rot.quat_conjugate(self.q_BS[i])) for i in idx])
            w = self.weights[idx] / self.weights[idx].sum()
            q_avg = q_B[0] if len(idx) == 1 else average_quaternions(q_B, w)
            flag = 1.0 + float(sum(1 << int(i) for i in idx))
        out[0], out[1], out[2:] = t_latest, flag, q_avg
        output.SetFromVector(out)


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

    Input ports (per source ``s``): ``s_q_IB_hat`` (4), ``s_second`` (3),
        ``s_covariance`` (36), ``s_status`` (4); with "tracked" also ``s_linearization``
        (109, the MEKF's ``step_linearization``).
    Output ports: the estimator contract (``q_IB_hat``, second vector, ``covariance``,
        ``status`` with ``t_estimate`` = the sources' common estimate time; NaN time when
        the sources disagree on it). A source that has used no measurement while another has
        is left out (:meth:`active_weights`): a branch whose tracker never delivered does not
        drag the fused estimate to its initial guess.
    Discrete state ("tracked" only, 37): ``[P_12 (36), steps applied]``, advanced by a
        periodic event at ``period_s`` (the sources' step).  The output applies the same
        one-step recursion to the inputs it sees, so the reported covariance always refers
        to the same step as the fused estimate.
    """

    def __init__(self, name, source_names, weights, second_output_name="bias_B_hat",
                 covariance_model="conservative", period_s=None):
        LeafSystem.__init__(self)
        self.set_name(name)
        n = len(source_names)
        if n < 2:
            raise ValueError(f"{name}.sources: got {list(source_names)}; need at least 2 estimators")
        if covariance_model not in ("tracked", "conservative", "independent"):
            raise ValueError(f"{name}.covariance_model: got {covariance_model!r}; "
                             "allowed: 'tracked', 'conservative', 'independent'")
        if covariance_model == "tracked" and (n != 2 or period_s is None):
            raise ValueError(f"{name}.covariance_model: 'tracked' needs exactly 2 MEKF sources and their period")
        self.weights = _normalized_weights(weights, n, f"{name}.weights")
        self.covariance_model = covariance_model
        self.second_output_name = second_output_name
        self.period_s = None if period_s is None else float(period_s)  # the sources' step
        self.source_names = list(source_names)
        self._in = {s: {k: self.DeclareVectorInputPort(f"{s}_{k}", size)
                        for k, size in (("q_IB_hat", 4), ("second", 3), ("covariance", 36), ("status", 4))}
                    for s in source_names}
        if covariance_model == "tracked":
            self._lin = {s: self.DeclareVectorInputPort(f"{s}_linearization", 109) for s in source_names}
            self._cross_group = self.DeclareDiscreteState(np.concatenate([np.eye(6).ravel(), [0.0]]))
            self.DeclareInitializationDiscreteUpdateEvent(self._initialize_cross)
            self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._advance_cross)
        self.DeclareVectorOutputPort("q_IB_hat", 4, self._calc_q)
        self.DeclareVectorOutputPort(second_output_name, 3, self._calc_second)
        self.DeclareVectorOutputPort("covariance", 36, self._calc_cov)
        self.DeclareVectorOutputPort("status", 4, self._calc_status)

    def _eval(self, context, key):
        return [self._in[s][key].Eval(context) for s in self.source_names]

    def active_weights(self, context) -> np.ndarray:
        """The weights in use: a source that has used no measurement yet while another has
        (a branch whose sensor never delivered) gets weight 0 and the others are renormalized
        — its estimate is only its prediction from the initial state. Otherwise the
        configured weights, unchanged."""
        used = np.array([self._in[s]["status"].Eval(context)[1] for s in self.source_names])
        active = used > 0
        if active.all() or not active.any():
            return self.weights
        w = self.weights * active
        return w / w.sum()

    def _calc_q(self, context, output):
        output.SetFromVector(average_quaternions(np.array(self._eval(context, "q_IB_hat")), self.active_weights(context)))

    def _calc_second(self, context, output):
        output.SetFromVector(np.einsum("i,ij->j", self.active_weights(context), np.array(self._eval(context, "second"))))

    def _cross_covariance(self, context):
        """``P_12`` at the step of the current inputs: the stored one, advanced once if the
        sources have taken a step since (NaN if the sources disagree on the step)."""
        x = context.get_discrete_state(self._cross_group).value()
        P12, applied = x[:36].reshape(6, 6), x[36]
        l1, l2 = (self._lin[s].Eval(context) for s in self.source_names)
        if l1[108] != l2[108]:
            return np.full((6, 6), np.nan), applied
        if l1[108] > applied:
            Phi1, Q, A1 = (l1[k * 36:(k + 1) * 36].reshape(6, 6) for k in range(3))
            Phi2, A2 = l2[:36].reshape(6, 6), l2[72:108].reshape(6, 6)
            P12 = A1 @ (Phi1 @ P12 @ Phi2.T + Q) @ A2.T
        return P12, l1[108]

    def _initialize_cross(self, context, discrete_state):
        """``P_12 = P_0``: the first source's covariance at initialization (its initial one)."""
        P0 = self._in[self.source_names[0]]["covariance"].Eval(context)
        discrete_state.get_mutable_vector(self._cross_group).SetFromVector(np.concatenate([P0, [0.0]]))
        return EventStatus.Succeeded()

    def _advance_cross(self, context, discrete_state):
        P12, steps = self._cross_covariance(context)
        discrete_state.get_mutable_vector(self._cross_group).SetFromVector(np.concatenate([P12.ravel(), [steps]]))
        return EventStatus.Succeeded()

    def _calc_cov(self, context, output):
        P = np.array(self._eval(context, "covariance"))
        weights = self.active_weights(context)
        if weights is not self.weights:  # a dead branch dropped: the live ones' covariance
            live = weights > 0
            if live.sum() == 1:
                output.SetFromVector(P[np.argmax(live)])
                return
            c = weights if self.covariance_model == "conservative" else weights**2
            output.SetFromVector(np.einsum("i,ij->j", c, P))
            return
        if self.covariance_model == "tracked":
            (w1, w2), (P1, P2) = self.weights, P.reshape(2, 6, 6)
            P12, _ = self._cross_covariance(context)
            Pf = w1**2 * P1 + w2**2 * P2 + w1 * w2 * (P12 + P12.T)
            output.SetFromVector(Pf.ravel())
            return
        c = self.weights if self.covariance_model == "conservative" else self.weights**2
        output.SetFromVector(np.einsum("i,ij->j", c, P))

    def _calc_status(self, context, output):
        st = np.array(self._eval(context, "status"))
        t = st[0, 0] if np.ptp(st[:, 0]) < TIME_TOLERANCE_S else np.nan
        output.SetFromVector([t, st[:, 1].sum(), st[:, 2].sum(), np.nan])
