"""The sensor monitor: fault detection and isolation between the sensors and the estimators.

A thin ``LeafSystem`` around :func:`drake_att.fdir.assess`: at each of its instants ``k
period_s`` it judges the gyro's and the trackers' samples (frozen output, gyro range, the
consistency vote) and passes every sample on — an excluded sensor's with its validity flag set
to 0, so any estimator reading it skips and counts it. Estimators that take the verdicts
(``sensor_verdicts``) also learn which samples the vote *confirmed*: a confirmed sample the gate
rejects says the prediction is wrong, not the sensor.

The outputs are direct functions of this instant's inputs and the memory of the previous
instants (one cache entry), so an estimator stepping at the same instant reads this instant's
verdicts; the periodic update stores the same judgement's memory.

Input ports:
    gyro_measurement (5): ``[t, valid, w_meas_B (3, rad/s)]`` (with a gyro).
    q_meas_<tracker> (6): ``[t, valid, q_IS_meas (4)]`` per tracker.
Output ports:
    measurement_<sensor> (5 or 6): the sensor's sample, flag 0 while it is excluded.
    detector_log (3 per sensor, gyro first): ``[verdict, cause detected at this instant,
        exclusions so far]`` (:mod:`drake_att.fdir` codes).
    verdicts_<consumer> (1 + n): declared per consumer by :meth:`declare_verdicts`: the gyro's
        verdict, then one per named tracker (0 for an input the monitor does not watch).
Discrete state: the monitor's memory (:meth:`drake_att.fdir.MonitorModel.initial_memory`).
"""

from __future__ import annotations

import functools

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import fdir
from drake_att.contract import GYRO_MEASUREMENT_SIZE, QUATERNION_MEASUREMENT_SIZE
from drake_att.systems.value_cache import declare_value_cache


class SensorMonitor(LeafSystem):
    """Runs :func:`drake_att.fdir.assess` (see the module docstring for ports and state).

    Args:
        model: the :class:`~drake_att.fdir.MonitorModel` (its trackers name the input ports).
        gyro_name: the monitored gyro's name (None: no gyro; ``model.has_gyro`` must agree).
    """

    def __init__(self, model: fdir.MonitorModel, gyro_name: str | None = None):
        LeafSystem.__init__(self)
        self.set_name(model.name)
        if model.has_gyro != (gyro_name is not None):
            raise ValueError(f"{model.name}: the model's has_gyro={model.has_gyro} but gyro_name={gyro_name!r}")
        self.model = model
        self.gyro_name = gyro_name
        self.tracker_names = tuple(t.name for t in model.trackers)
        self.sensor_names = ((gyro_name,) if gyro_name else ()) + self.tracker_names
        self._gyro_port = self.DeclareVectorInputPort("gyro_measurement", GYRO_MEASUREMENT_SIZE) if gyro_name else None
        self._tracker_ports = [
            self.DeclareVectorInputPort(f"q_meas_{n}", QUATERNION_MEASUREMENT_SIZE) for n in self.tracker_names
        ]
        self._memory_index = self.DeclareDiscreteState(model.initial_memory())  # type: ignore[arg-type]  # pydrake stub
        self.DeclarePeriodicDiscreteUpdateEvent(model.period_s, 0.0, self._on_step)
        tickets = {self.time_ticket(), self.xd_ticket(), self.all_input_ports_ticket()}
        self._judgement = declare_value_cache(self, "judgement", self._judge, tickets)
        if gyro_name:
            self.DeclareVectorOutputPort(
                f"measurement_{gyro_name}",
                GYRO_MEASUREMENT_SIZE,
                functools.partial(self._calc_sample, index=0),
                tickets,
            )
        for i, n in enumerate(self.tracker_names):
            self.DeclareVectorOutputPort(
                f"measurement_{n}",
                QUATERNION_MEASUREMENT_SIZE,
                functools.partial(self._calc_sample, index=i + int(model.has_gyro)),
                tickets,
            )
        self.DeclareVectorOutputPort("detector_log", fdir.LOG_PER_SENSOR * model.n_sensors, self._calc_log, tickets)
        self._verdict_ports: dict = {}

    def declare_verdicts(self, consumer: str, gyro: str | None, inputs) -> str:
        """Declare (before the diagram is built) the output ``verdicts_<consumer>`` for an
        estimator reading ``gyro`` and the measurement inputs ``inputs`` in its order; returns
        the port's name."""
        index = [self.sensor_names.index(gyro) if gyro in self.sensor_names else -1]
        index += [self.sensor_names.index(n) if n in self.sensor_names else -1 for n in inputs]
        port = f"verdicts_{consumer}"
        if port not in self._verdict_ports:
            self._verdict_ports[port] = tuple(index)
            self.DeclareVectorOutputPort(
                port,
                len(index),
                functools.partial(self._calc_verdicts, index=tuple(index)),
                {self.time_ticket(), self.xd_ticket(), self.all_input_ports_ticket()},
            )
        return port

    def _samples(self, context):
        gyro = None
        if self._gyro_port is not None and self._gyro_port.HasValue(context):
            gyro = self._gyro_port.Eval(context)
        trackers = [p.Eval(context) if p.HasValue(context) else None for p in self._tracker_ports]
        return gyro, trackers

    def _judge(self, context):
        gyro, trackers = self._samples(context)
        memory = context.get_discrete_state(self._memory_index).value()
        return fdir.assess(self.model, memory, context.get_time(), gyro, trackers)

    def assessment(self, context) -> fdir.Assessment:
        """This instant's :class:`~drake_att.fdir.Assessment` in ``context`` (this system's)."""
        return self._judgement(context)[0]

    def _on_step(self, context, discrete_state):
        discrete_state.get_mutable_vector(self._memory_index).SetFromVector(self._judgement(context)[1])
        return EventStatus.Succeeded()

    def _calc_sample(self, context, output: BasicVector, index: int):
        gyro, trackers = self._samples(context)
        sample = gyro if (self.model.has_gyro and index == 0) else trackers[index - int(self.model.has_gyro)]
        size = GYRO_MEASUREMENT_SIZE if (self.model.has_gyro and index == 0) else QUATERNION_MEASUREMENT_SIZE
        value = np.full(size, np.nan) if sample is None else np.array(sample, dtype=float)
        if sample is None:
            value[1] = 0.0
        elif self.assessment(context).verdicts[index] == fdir.EXCLUDED:
            value[1] = 0.0
        output.SetFromVector(value)  # type: ignore[arg-type]  # pydrake stub

    def _calc_log(self, context, output: BasicVector):
        output.SetFromVector(self.assessment(context).log())  # type: ignore[arg-type]  # pydrake stub

    def _calc_verdicts(self, context, output: BasicVector, index: tuple):
        verdicts = self.assessment(context).verdicts
        output.SetFromVector(np.array([float(verdicts[i]) if i >= 0 else 0.0 for i in index]))  # type: ignore[arg-type]


__all__ = ["SensorMonitor"]
