"""Estimator systems: thin Drake wrappers around the numpy filter cores.

Estimator contract (every estimator system):

Output ports:
    q_IB_hat (4): attitude estimate, wxyz.
    bias_B_hat (3) or w_IB_B_hat (3): the second estimated 3-vector (name in
        ``second_output_name``): gyro bias (rad/s) or body rate (rad/s).
    covariance (36): row-major 6x6 covariance of ``[dtheta_B (rad); second-vector error]``
        (the project's attitude error ``q_IB = q_IB_hat ⊗ exp(dtheta_B)``); particle
        filters report their weighted sample covariance.
    status (4): ``[t_estimate (s), measurements used, measurements skipped, last NIS]``.
        ``t_estimate`` is the time the estimate refers to.  Drake publishes (and so logs)
        before the discrete update of the same instant, so the logged estimate at ``t``
        is the one computed at the previous step; the metrics layer scores each estimate
        against the truth at ``t_estimate``, never at the log time.

Discrete state group 0 ("estimate", :data:`ESTIMATE_SIZE`): ``[q_IB_hat (4), second (3),
covariance (36), status (4)]``, also exposed whole as the output port ``estimate_state``
(evaluated in C++; what the scenario builder logs).  Subclasses may declare more state for filter internals.
The update runs in one periodic discrete event per filter step.

Measurement handling: a measurement is used only at its own sample instant
(``|t_meas - t| < 1e-6 s``) and at most once; a sample flagged invalid or carrying
non-finite numbers is skipped and counted in ``status``.  A missing or invalid gyro
sample is counted too; the filter then propagates with the last valid gyro rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.filters.mekf import MekfState, MultiplicativeEKF
from drake_att.systems.gyro import GYRO_MEASUREMENT_SIZE
from drake_att.systems.star_tracker import QUATERNION_MEASUREMENT_SIZE, VectorObservations

ESTIMATE_SIZE = 4 + 3 + 36 + 4
TIME_TOLERANCE_S = 1e-6
_EYE6 = np.eye(6)
_ZERO6 = np.zeros((6, 6))


@dataclass(frozen=True)
class QuaternionSensorModel:
    """What the filter assumes about one attitude-quaternion sensor."""

    name: str
    q_BS: np.ndarray
    covariance_S: np.ndarray  # (3, 3) rotation-vector noise in the sensor frame (rad^2)


def pack_estimate(q, second, P, t, n_used, n_skipped, nis) -> np.ndarray:
    return np.concatenate([q, second, np.asarray(P).ravel(), [t, n_used, n_skipped, nis]])


class AttitudeEstimatorSystem(LeafSystem):
    """Base class implementing the estimator contract (see module docstring).

    Args:
        name: system name.
        period_s: filter step (s) > 0.
        second_output_name: "bias_B_hat" or "w_IB_B_hat".
        initial_estimate: packed estimate vector (:func:`pack_estimate`).
    """

    def __init__(self, name: str, period_s: float, second_output_name: str, initial_estimate):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not np.isfinite(period_s) or period_s <= 0:
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        self.period_s = float(period_s)
        self.second_output_name = second_output_name
        self._estimate_group = self.DeclareDiscreteState(np.asarray(initial_estimate, dtype=float))
        ticket = {self.discrete_state_ticket(self._estimate_group)}
        self.DeclareVectorOutputPort("q_IB_hat", 4, lambda c, o: self._out(c, o, 0, 4), ticket)
        self.DeclareVectorOutputPort(second_output_name, 3, lambda c, o: self._out(c, o, 4, 7), ticket)
        self.DeclareVectorOutputPort("covariance", 36, lambda c, o: self._out(c, o, 7, 43), ticket)
        self.DeclareVectorOutputPort("status", 4, lambda c, o: self._out(c, o, 43, 47), ticket)
        # The whole estimate group as one C++-evaluated port: loggers record this one (no
        # Python callback per logged sample); the builder splits it into the contract signals.
        self.DeclareStateOutputPort("estimate_state", self._estimate_group)

    def _out(self, context, output: BasicVector, a, b):
        output.SetFromVector(context.get_discrete_state(self._estimate_group).value()[a:b])

    def estimate_vector(self, context) -> np.ndarray:
        return context.get_discrete_state(self._estimate_group).value()

    def set_initial_estimate(self, context, packed) -> None:
        context.get_mutable_discrete_state(self._estimate_group).SetFromVector(packed)


class MekfEstimator(AttitudeEstimatorSystem):
    """MEKF with one gyro and any number of quaternion and vector star trackers.

    Args:
        name: system name.
        period_s: filter step (s); must equal the gyro period (the gyro delivers the mean
            rate over exactly one step).
        filter_core: a :class:`MultiplicativeEKF`.
        initial_state: :class:`MekfState` at t = 0.
        quaternion_sensors: list of :class:`QuaternionSensorModel`.
        vector_sensors: names of vector-observation sensors.

    Input ports:
        gyro_measurement (5): ``[t, valid, w_meas_B (3)]``.
        q_meas_<sensor> (6): ``[t, valid, q_IS_meas (4)]`` per quaternion sensor.
        vectors_<sensor> (abstract VectorObservations) per vector sensor.
    Output ports: the estimator contract with ``bias_B_hat``.
    Output ports: additionally ``step_linearization`` (109): the last step's linearized
        error map ``e+ = A (Phi e + w)`` as ``[Phi, Q = cov(w), A]`` (row-major 6x6 each) and
        the number of steps taken.
    Discrete state: group 0 estimate (47); group 1 ``[t_last_step, last valid gyro rate (3),
        time of last used sample per measurement input ...]``; group 2 the step
        linearization (109).
    """

    def __init__(self, name: str, period_s: float, filter_core: MultiplicativeEKF, initial_state: MekfState,
                 quaternion_sensors=(), vector_sensors=()):
        super().__init__(name, period_s, "bias_B_hat",
                         pack_estimate(initial_state.q_IB, initial_state.bias_B, initial_state.P, 0.0, 0, 0, np.nan))
        self.core = filter_core
        self._gyro_port = self.DeclareVectorInputPort("gyro_measurement", GYRO_MEASUREMENT_SIZE)
        self._quat_sensors = list(quaternion_sensors)
        self._quat_ports = [self.DeclareVectorInputPort(f"q_meas_{s.name}", QUATERNION_MEASUREMENT_SIZE)
                            for s in self._quat_sensors]
        self._vector_names = list(vector_sensors)
        self._vector_ports = [
            self.DeclareAbstractInputPort(
                f"vectors_{n}", AbstractValue.Make(VectorObservations(0.0, False, np.zeros((0, 3)),
                                                                      np.zeros((0, 3)), 0.0, np.array([1.0, 0, 0, 0]))))
            for n in self._vector_names]
        n_inputs = len(self._quat_ports) + len(self._vector_ports)
        self._internal_group = self.DeclareDiscreteState(
            np.concatenate([[-np.inf], np.zeros(3), np.full(n_inputs, -np.inf)]))
        # The last step's linearized error map, e+ = A (Phi e + w) + noise, cov(w) = Q:
        # [Phi (36), Q (36), A (36), step count], row-major.  Lets a fusion track the
        # cross-covariance of estimators that share a gyro (drake_att.systems.fusion).
        self._linearization_group = self.DeclareDiscreteState(
            np.concatenate([np.eye(6).ravel(), np.zeros(36), np.eye(6).ravel(), [0.0]]))
        self.DeclareStateOutputPort("step_linearization", self._linearization_group)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_step)

    def _on_step(self, context, discrete_state):
        t = context.get_time()
        est = self.estimate_vector(context)
        internal = context.get_discrete_state(self._internal_group).value().copy()
        state = MekfState(est[:4], est[4:7], est[7:43].reshape(6, 6))
        n_used, n_skipped, nis = est[44], est[45], est[46]

        # -- propagate with the gyro's mean rate over (t_last, t] -----------------------
        t_last = internal[0]
        Phi, Q, A = _EYE6, _ZERO6, _EYE6
        if np.isfinite(t_last):
            w_meas = None
            if self._gyro_port.HasValue(context):
                g = self._gyro_port.Eval(context)
                if abs(g[0] - t) < TIME_TOLERANCE_S and g[1] > 0.5 and np.all(np.isfinite(g[2:])):
                    w_meas = g[2:]
            if w_meas is None:
                n_skipped += 1
                w_meas = internal[1:4]
            else:
                internal[1:4] = w_meas
            state, Phi, Q = self.core.predict_linearized(state, w_meas, t - t_last)
        elif self._gyro_port.HasValue(context):
            g = self._gyro_port.Eval(context)
            if g[1] > 0.5 and np.all(np.isfinite(g[2:])):
                internal[1:4] = g[2:]
        internal[0] = t

        # -- measurement updates at this instant -----------------------------------------
        for i, (sensor, port) in enumerate(zip(self._quat_sensors, self._quat_ports)):
            if not port.HasValue(context):
                continue
            m = port.Eval(context)
            if abs(m[0] - t) >= TIME_TOLERANCE_S or m[0] <= internal[4 + i]:
                continue
            internal[4 + i] = m[0]
            if m[1] < 0.5 or not np.all(np.isfinite(m[2:])) or np.linalg.norm(m[2:]) < 0.5:
                n_skipped += 1
                continue
            state, info = self.core.update_quaternion(state, m[2:], sensor.q_BS, sensor.covariance_S)
            n_used, n_skipped, nis = (n_used + 1, n_skipped, info.nis) if info.accepted else (n_used, n_skipped + 1, info.nis)
            if info.accepted:
                A = info.error_transition @ A
        offset = 4 + len(self._quat_ports)
        for j, port in enumerate(self._vector_ports):
            if not port.HasValue(context):
                continue
            obs = port.Eval(context)
            if abs(obs.time_s - t) >= TIME_TOLERANCE_S or obs.time_s <= internal[offset + j]:
                continue
            internal[offset + j] = obs.time_s
            dirs = np.asarray(obs.directions_S)
            if not obs.valid or dirs.size == 0 or not np.all(np.isfinite(dirs)):
                n_skipped += 1
                continue
            state, info = self.core.update_vectors(state, dirs, obs.references_I, obs.sigma_rad, obs.q_BS)
            n_used, n_skipped, nis = (n_used + 1, n_skipped, info.nis) if info.accepted else (n_used, n_skipped + 1, info.nis)
            if info.accepted:
                A = info.error_transition @ A

        discrete_state.get_mutable_vector(self._estimate_group).SetFromVector(
            pack_estimate(rot.quat_canonical(state.q_IB), state.bias_B, state.P, t, n_used, n_skipped, nis))
        discrete_state.get_mutable_vector(self._internal_group).SetFromVector(internal)
        steps = context.get_discrete_state(self._linearization_group).value()[108] + 1
        discrete_state.get_mutable_vector(self._linearization_group).SetFromVector(
            np.concatenate([Phi.ravel(), Q.ravel(), A.ravel(), [steps]]))
        return EventStatus.Succeeded()
