"""Rate-integrating gyro (Farrenkopf model) delivering the mean rate over its interval.

A real MEMS gyro samples at a high rate (300 Hz in paper S3) and the flight software
averages the samples over the filter step.  This system reproduces that output with one
discrete event per output sample: the joint statistics of the interval-mean noise and
the bias random walk are closed-form (:class:`drake_att.noise.FarrenkopfGyroNoise`), and
the true mean rate is exact, from the plant's ``w_IB_B_integral`` port.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att.contract import GYRO_MEASUREMENT_SIZE  # [t_meas, valid, w_meas_B (3)]
from drake_att.noise import FarrenkopfGyroNoise
from drake_att.validation import check_array, check_nonnegative
from drake_att.systems.randomness import (
    SEED_WORDS, counter_random, declare_seed_port, read_seed_words)





@dataclass(frozen=True)
class GyroModel:
    """The gyro's numbers (its abstract parameter: one diagram, any noise level per run).

    Attributes:
        noise: the Farrenkopf interval statistics (ARW, RRW, period).
        initial_bias: bias at t = 0 (3, rad/s). initial_bias_sigma: its random part (rad/s).
        sensor_matrix: ``I + S + M`` (scale factors and misalignment).
    """

    noise: FarrenkopfGyroNoise
    initial_bias: np.ndarray
    initial_bias_sigma: float
    sensor_matrix: np.ndarray

    @classmethod
    def make(cls, name: str, period_s: float, arw_rad_per_rt_s: float, rrw_rad_per_s15: float,
             initial_bias_rad_per_s=(0.0, 0.0, 0.0), initial_bias_sigma_rad_per_s: float = 0.0,
             scale_factor_error=(0.0, 0.0, 0.0), misalignment=None) -> "GyroModel":
        """Check and convert the arguments of :class:`Gyro` (ValueError naming the field)."""
        try:
            noise = FarrenkopfGyroNoise(arw_rad_per_rt_s, rrw_rad_per_s15, period_s)
        except ValueError as e:
            raise ValueError(f"{name}.{e}") from None
        initial_bias = check_array(f"{name}.initial_bias", initial_bias_rad_per_s, (3,), " (rad/s)")
        check_nonnegative(f"{name}.initial_bias_sigma", initial_bias_sigma_rad_per_s)
        sf = check_array(f"{name}.scale_factor_error", scale_factor_error, (3,), " (dimensionless)")
        M = np.zeros((3, 3)) if misalignment is None else np.asarray(misalignment, dtype=float)
        if M.shape != (3, 3) or not np.all(np.isfinite(M)) or np.any(np.diag(M) != 0):
            raise ValueError(f"{name}.misalignment: got {misalignment!r}; must be 3x3 finite with zero diagonal (rad)")
        return cls(noise, initial_bias, float(initial_bias_sigma_rad_per_s), np.eye(3) + np.diag(sf) + M)


class Gyro(LeafSystem):
    """Three-axis gyro: ``w_meas = (I + S + M) mean(w_IB_B) + mean(b) + e``.

    ``S = diag(scale_factor_error)``, ``M`` the misalignment (zero diagonal), the bias
    ``b`` a random walk (RRW), ``e`` angle-random-walk noise, all per the Farrenkopf
    model with the exact interval statistics.

    Args:
        name: system name (also the noise stream name).
        period_s: output period T (s) > 0.
        arw_rad_per_rt_s: angle random walk (rad/s^0.5) >= 0.
        rrw_rad_per_s15: rate random walk (rad/s^1.5) >= 0.
        initial_bias_rad_per_s: bias at t = 0 (3, rad/s).
        initial_bias_sigma_rad_per_s: optional random part of the initial bias (1-sigma per
            axis, rad/s) drawn per seed; 0 for a deterministic initial bias.
        scale_factor_error: (3,) dimensionless (e.g. 100 ppm = 1e-4).
        misalignment: (3, 3) small-angle misalignment matrix with zero diagonal (rad).

    Input ports:
        w_IB_B (3): true body rate (rad/s), used for the first sample (t = 0).
        w_IB_B_integral (3): integral of the true body rate (rad); the interval mean is its
            difference over the interval divided by the elapsed time.
        seed_uniform (4, random uniform): seed, see ``drake_att.systems.randomness``.
        scale_error (1, optional): the scale-factor error ``s_k`` of the interval ending at the
            sample time (paper S1's multiplicative noise ``kappa zeta_k``); the output is then
            ``(I + S + M) mean(w_IB_B) / (1 + s_k) + mean(b) + e``. Unconnected: 0.
    Parameters: abstract parameter 0: the :class:`GyroModel` (:meth:`set_model` per context).
    Output ports:
        gyro_measurement (5): ``[t_meas (s), valid (1/0), w_meas_B (3, rad/s)]``.
        bias_B (3): true bias at the sample time (rad/s), for scoring only.
    Discrete state (25): ``[seed words (4), sample index, t_sample, meas offset (3),
        bias at sample (3), integral at previous sample (3), has_previous, sensor matrix I + S + M
        (9, row-major; copied from the parameter at initialization, read by the output)]``.
    """

    def __init__(self, name: str, period_s: float, arw_rad_per_rt_s: float, rrw_rad_per_s15: float,
                 initial_bias_rad_per_s=(0.0, 0.0, 0.0), initial_bias_sigma_rad_per_s: float = 0.0,
                 scale_factor_error=(0.0, 0.0, 0.0), misalignment=None):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not np.isfinite(period_s) or period_s <= 0:
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        self.period_s = float(period_s)
        self.default_model = GyroModel.make(name, period_s, arw_rad_per_rt_s, rrw_rad_per_s15, initial_bias_rad_per_s,
                                            initial_bias_sigma_rad_per_s, scale_factor_error, misalignment)
        self._model_index = self.DeclareAbstractParameter(AbstractValue.Make(self.default_model))

        self._w_port = self.DeclareVectorInputPort("w_IB_B", 3)
        self._integral_port = self.DeclareVectorInputPort("w_IB_B_integral", 3)
        self._seed_port = declare_seed_port(self)
        # Optional: a per-step scale-factor error s_k from a correlated-noise source
        # (paper S1, drake_att.systems.correlated_noise); unconnected = 0.
        self._scale_error_port = self.DeclareVectorInputPort("scale_error", 1)
        self._state_index = self.DeclareDiscreteState(np.concatenate([np.zeros(16), self.default_model.sensor_matrix.ravel()]))
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_sample)
        self.DeclareVectorOutputPort(
            "gyro_measurement", GYRO_MEASUREMENT_SIZE, self._calc_measurement,
            {self.time_ticket(), self.xd_ticket(), self.all_input_ports_ticket()})
        self.DeclareVectorOutputPort("bias_B", 3, self._calc_bias, {self.xd_ticket()})

    # -- parameters -----------------------------------------------------------------
    def model(self, context) -> GyroModel:
        """The :class:`GyroModel` in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._model_index).get_value()

    def set_model(self, context, arw_rad_per_rt_s: float, rrw_rad_per_s15: float, initial_bias_rad_per_s=(0.0, 0.0, 0.0),
                  initial_bias_sigma_rad_per_s: float = 0.0, scale_factor_error=(0.0, 0.0, 0.0),
                  misalignment=None) -> None:
        """Give ``context`` (this system's) other noise levels and errors (arguments as the
        constructor's). Takes effect at the next initialization (the first sample's noise
        is drawn there)."""
        model = GyroModel.make(self.get_name(), self.period_s, arw_rad_per_rt_s, rrw_rad_per_s15,
                               initial_bias_rad_per_s, initial_bias_sigma_rad_per_s, scale_factor_error, misalignment)
        context.get_mutable_abstract_parameter(self._model_index).set_value(model)

    # -- events -------------------------------------------------------------------
    def _integral(self, context):
        if self._integral_port.HasValue(context):
            return self._integral_port.Eval(context)
        return None

    def _initialize(self, context, discrete_state):
        words = read_seed_words(self, context, self._seed_port)
        m = self.model(context)
        z = counter_random(words, self.get_name()).normals(0, 9)
        bias0 = m.initial_bias + m.initial_bias_sigma * z[6:9]
        e, _ = m.noise.from_normals(z[:6].reshape(2, 3))
        integral = self._integral(context)
        x = np.concatenate([words, [0.0, context.get_time()], bias0 + e, bias0,
                            np.zeros(3) if integral is None else integral, [0.0], m.sensor_matrix.ravel()])
        discrete_state.set_value(x)
        return EventStatus.Succeeded()

    def _on_sample(self, context, discrete_state):
        x = context.get_discrete_state_vector().value()
        words, index, bias = x[:SEED_WORDS], int(x[4]), x[9:12]
        z = counter_random(words, self.get_name()).normals(index + 1, 9)
        e, db = self.model(context).noise.from_normals(z[:6].reshape(2, 3))
        integral = self._integral(context)
        new = x.copy()
        new[4] = index + 1
        new[5] = context.get_time() + self.period_s
        new[6:9] = bias + e  # mean bias over the coming interval + ARW
        new[9:12] = bias + db  # bias at the end of the coming interval
        if integral is not None:
            new[12:15] = integral
            new[15] = 1.0
        discrete_state.set_value(new)
        return EventStatus.Succeeded()

    # -- outputs ------------------------------------------------------------------
    def _calc_measurement(self, context, output: BasicVector):
        x = context.get_discrete_state_vector().value()
        t = context.get_time()
        integral = self._integral(context)
        elapsed = t - (x[5] - self.period_s)
        if integral is not None and x[15] > 0 and elapsed > 1e-12:
            w_true = (integral - x[12:15]) / elapsed
        else:
            w_true = self._w_port.Eval(context)
        w_meas = x[16:25].reshape(3, 3) @ w_true  # the context's sensor matrix, copied at initialization
        if self._scale_error_port.HasValue(context):
            w_meas = w_meas / (1.0 + self._scale_error_port.Eval(context)[0])
        w_meas = w_meas + x[6:9]
        output.SetFromVector(np.concatenate([[x[5], 1.0], w_meas]))

    def _calc_bias(self, context, output: BasicVector):
        output.SetFromVector(context.get_discrete_state_vector().value()[9:12])
