"""Rate-integrating gyro (Farrenkopf model) delivering the mean rate over its interval.

A real MEMS gyro samples at a high rate (300 Hz in paper S3) and the flight software
averages the samples over the filter step.  This system reproduces that output exactly: the
joint statistics of the interval-mean noise and the bias random walk are closed-form
(:class:`drake_att.noise.FarrenkopfGyroNoise`), and the true mean rate is exact, from the
plant's ``w_IB_B_integral`` port and its value at the previous sample (held by a C++
``ZeroOrderHold``). No Python code runs per sample unless an output is read: sample ``n``'s
noise is a pure function of (seed, system name, ``n``), drawn for blocks of
:attr:`~drake_att.noise.CounterRandom.BLOCK` samples at once (the bias random walk as a
sequential cumulative sum, the same additions in the same order as one sample at a time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import (
    BasicVector,
    Diagram,
    DiagramBuilder,
    EventStatus,
    LeafSystem,
)
from pydrake.systems.primitives import Demultiplexer, ZeroOrderHold

from drake_att.contract import GYRO_MEASUREMENT_SIZE  # [t_meas, valid, w_meas_B (3)]
from drake_att.noise import CounterRandom, FarrenkopfGyroNoise
from drake_att.systems.randomness import (
    SEED_WORDS,
    NoiseCache,
    counter_random,
    declare_seed_port,
    read_seed_words,
)
from drake_att.validation import check_array, check_nonnegative


@dataclass(frozen=True)
class GyroModel:
    """The gyro's numbers (its abstract parameter: one diagram, any noise level per run).

    Attributes:
        noise: the Farrenkopf interval statistics (ARW, RRW, period).
        initial_bias: bias at t = 0 (3, rad/s). initial_bias_sigma: its random part (rad/s).
        sensor_matrix: ``I + S + M`` (scale factors and misalignment).
        range_rad_per_s: per-axis measurement range (rad/s; inf: none): each axis of a sample is
            clipped to ``[-range, range]`` (the interval's mean rate, clipped: a saturated gyro).
    """

    noise: FarrenkopfGyroNoise
    initial_bias: np.ndarray
    initial_bias_sigma: float
    sensor_matrix: np.ndarray
    range_rad_per_s: float = math.inf

    @classmethod
    def make(
        cls,
        name: str,
        period_s: float,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        initial_bias_rad_per_s=(0.0, 0.0, 0.0),
        initial_bias_sigma_rad_per_s: float = 0.0,
        scale_factor_error=(0.0, 0.0, 0.0),
        misalignment=None,
        range_rad_per_s: float = math.inf,
    ) -> GyroModel:
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
        if not float(range_rad_per_s) > 0:
            raise ValueError(f"{name}.range: got {range_rad_per_s!r}; must be > 0 (rad/s), or inf for none")
        return cls(
            noise,
            initial_bias,
            float(initial_bias_sigma_rad_per_s),
            np.eye(3) + np.diag(sf) + M,
            float(range_rad_per_s),
        )


class _GyroOutputs(LeafSystem):
    """The Python part of :class:`Gyro`: its two signals as one output
    ``measurement_and_bias`` (8: ``gyro_measurement`` (5) then ``bias_B`` (3)), evaluated on
    demand (no per-sample event). Inputs as :class:`Gyro`'s plus ``w_IB_B_integral_held`` (the integral at the
    previous sample instant, from the ``ZeroOrderHold``); discrete state: the seed words (4,
    read at initialization)."""

    def __init__(self, name: str, period_s: float, default_model: GyroModel, realizations: int = 1):
        LeafSystem.__init__(self)
        self.set_name(f"{name}_outputs")
        self.stream = name  # the random stream keeps the gyro's name
        self.period_s = period_s
        self.realizations = N = realizations
        self._model_index = self.DeclareAbstractParameter(AbstractValue.Make(default_model))
        self._w_port = self.DeclareVectorInputPort("w_IB_B", 3)
        self._integral_port = self.DeclareVectorInputPort("w_IB_B_integral", 3)
        self._held_port = self.DeclareVectorInputPort("w_IB_B_integral_held", 3)
        self._seed_port = declare_seed_port(self, N)
        # Optional: a per-step scale-factor error s_k from a correlated-noise source
        # (paper S1, drake_att.systems.correlated_noise); unconnected = 0.
        self._scale_error_port = self.DeclareVectorInputPort("scale_error", N)
        self.DeclareDiscreteState(np.zeros(SEED_WORDS * N))  # type: ignore[arg-type]  # pydrake stub
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        # One Python output for both signals (the Gyro diagram splits it in C++): a logged
        # bias costs no Python call of its own.
        self.DeclareVectorOutputPort(
            "measurement_and_bias",
            (GYRO_MEASUREMENT_SIZE + 3) * N,
            self._calc_measurement,
            {self.time_ticket(), self.xd_ticket(), self.all_parameters_ticket(), self.all_input_ports_ticket()},
        )
        # The context's draws (one _GyroDraws per realization, of its seed words and the
        # model): one cache look-up per output evaluation.
        self._draws_cache = NoiseCache(
            self,
            "draws",
            self.model,
            lambda words, model: tuple(
                _GyroDraws(model, counter_random(w, self.stream)) for w in np.reshape(words, (N, SEED_WORDS))
            ),
        )

    def model(self, context) -> GyroModel:
        return context.get_abstract_parameter(self._model_index).get_value()

    def _initialize(self, context, discrete_state):
        discrete_state.set_value(read_seed_words(self, context, self._seed_port))
        return EventStatus.Succeeded()

    def _sample_index(self, t: float) -> tuple[int, float]:
        """The sample an output at ``t`` carries: index ``n = ceil(t / T)`` (on a sample
        instant, that instant's) and its stamp ``t_n = t_(n-1) + T`` (0 for ``n = 0``)."""
        n = max(0, math.ceil(t / self.period_s - 1e-9))
        return n, ((n - 1) * self.period_s + self.period_s if n else 0.0)

    def _draws(self, context) -> _GyroDraws:
        """The draws of this context's seed words and model (cached; the first realization's)."""
        return self._draws_cache.get(context)[0]

    def _calc_measurement(self, context, output: BasicVector):
        t = context.get_time()
        n, t_n = self._sample_index(t)
        draws = self._draws_cache.get(context)  # one per realization
        elapsed = t - (t_n - self.period_s)
        if n >= 1 and elapsed > 1e-12 and self._integral_port.HasValue(context):
            integral = self._integral_port.Eval(context).tolist()  # type: ignore[attr-defined]  # pydrake stub
            held = self._held_port.Eval(context).tolist()  # type: ignore[attr-defined]  # pydrake stub
            w_true = [(a - b) / elapsed for a, b in zip(integral, held, strict=True)]
        else:
            w_true = self._w_port.Eval(context).tolist()  # type: ignore[attr-defined]  # pydrake stub
        scale_errors = (
            self._scale_error_port.Eval(context).tolist()  # type: ignore[attr-defined]  # pydrake stub
            if self._scale_error_port.HasValue(context)
            else None
        )
        if self.realizations == 1:
            sample = np.array(_sample(draws[0], n, t_n, w_true, None if scale_errors is None else scale_errors[0]))
            r = draws[0].model.range_rad_per_s
            if r < math.inf:
                sample[2:5] = np.clip(sample[2:5], -r, r)
        else:  # realization-major: every measurement (5 each), then every bias (3 each)
            measurements, biases = [], []
            for i, d in enumerate(draws):
                values = _sample(d, n, t_n, w_true, None if scale_errors is None else scale_errors[i])
                measurements += values[:GYRO_MEASUREMENT_SIZE]
                biases += values[GYRO_MEASUREMENT_SIZE:]
            sample = np.array(measurements + biases)
            r = draws[0].model.range_rad_per_s
            if r < math.inf:
                rates = sample[: GYRO_MEASUREMENT_SIZE * self.realizations].reshape(-1, GYRO_MEASUREMENT_SIZE)[:, 2:5]
                rates[:] = np.clip(rates, -r, r)
        output.SetFromVector(sample)  # type: ignore[arg-type]  # pydrake stub


def _sample(draws: _GyroDraws, n: int, t_n: float, w_true: list, scale_error: float | None) -> list:
    """Sample ``n`` (stamp ``t_n``) of one realization, before the range clip: ``[t_n, 1,
    w_meas (3), B_n (3)]`` (floats) from the true mean rate ``w_true`` (3 floats) and the
    scale-factor error ``s_k`` (None: 0)."""
    # (I + S + M) w; skipped for the identity (the same numbers, up to the sign of a zero).
    w_meas = w_true if draws.unit_sensor_matrix else (draws.model.sensor_matrix @ w_true).tolist()
    if scale_error is not None:
        divisor = 1.0 + scale_error
        w_meas = [w / divisor for w in w_meas]
    (ox, oy, oz), (bx, by, bz) = draws.offset_and_bias(n)
    return [t_n, 1.0, w_meas[0] + ox, w_meas[1] + oy, w_meas[2] + oz, bx, by, bz]


class _GyroDraws:
    """The noise of one gyro for one (seed words, :class:`GyroModel`): per sample ``n`` the
    measurement offset (mean bias over its interval plus angle random walk, ``B_(n-1) +
    e_n``; ``B_0 + e_0`` for ``n = 0``) and the bias ``B_n`` at its instant (``B_0`` = the
    initial bias, ``B_n = B_(n-1) + db_n``), with ``(e_n, db_n)`` from the Farrenkopf factor
    of ``normals(n, 9)[:6]``: computed by blocks of ``CounterRandom.BLOCK`` samples, in
    order (each block starts from the previous block's last bias) and kept.  Immutable in
    effect (a memo), so a cloned context shares it (``__deepcopy__``).

    Attributes:
        model: the :class:`GyroModel`.
        unit_sensor_matrix: whether ``model.sensor_matrix`` is the identity.
    """

    def __init__(self, model: GyroModel, cr: CounterRandom):
        self.model = model
        self.unit_sensor_matrix = bool(np.array_equal(model.sensor_matrix, np.eye(3)))
        self._cr = cr
        self._blocks: list = []  # (offsets (BLOCK, 3), biases (BLOCK, 3)) of blocks 0, 1, ...
        self._lists_block = -1  # the last block read by offset_and_bias() and its (offsets, biases) as lists
        self._lists: tuple[list, list] = ([], [])

    def __deepcopy__(self, memo):
        return self

    def _block(self, b: int):
        blocks, model, cr = self._blocks, self.model, self._cr
        while len(blocks) <= b:
            z = cr.normals_block(len(blocks), 9)
            e, db = model.noise.from_normals(np.moveaxis(z[:, :6].reshape(-1, 2, 3), 1, 0))
            if not blocks:
                start = model.initial_bias + model.initial_bias_sigma * z[0, 6:9]  # B_0
                bias = np.add.accumulate(np.vstack([start, db[1:]]), axis=0)
                previous = np.vstack([start, bias[:-1]])  # B_(n-1), with B_0 for n = 0
            else:
                last = blocks[-1][1][-1]
                bias = np.add.accumulate(np.vstack([last, db]), axis=0)[1:]
                previous = np.vstack([last, bias[:-1]])
            blocks.append((previous + e, bias))
        return blocks[b]

    def draw(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(offset_n, B_n)`` (3 each, rad/s) of sample ``n``."""
        b, r = divmod(n, CounterRandom.BLOCK)
        offsets, biases = self._block(b)
        return offsets[r], biases[r]

    def offset_and_bias(self, n: int) -> tuple:
        """``(offset_n, B_n)`` as two lists of 3 floats (rad/s)."""
        b, r = divmod(n, CounterRandom.BLOCK)
        if b != self._lists_block:
            offsets, biases = self._block(b)
            self._lists = (offsets.tolist(), biases.tolist())
            self._lists_block = b
        return self._lists[0][r], self._lists[1][r]


class Gyro(Diagram):
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
        range_rad_per_s: per-axis range (rad/s; inf: none); the output is clipped to it.
        realizations: N independent gyros on the same truth (a batch of Monte Carlo runs in one
            diagram): ``seed_uniform``, ``scale_error``, ``gyro_measurement`` and ``bias_B``
            carry N blocks, realization-major; realization ``i`` is drawn from the ``i``-th seed
            words exactly as a gyro alone would be (the same numbers). The truth ports are shared.

    Input ports:
        w_IB_B (3): true body rate (rad/s), used for the first sample (t = 0).
        w_IB_B_integral (3): integral of the true body rate (rad); the interval mean is its
            difference over the interval divided by the elapsed time.
        seed_uniform (4, random uniform): seed, see ``drake_att.systems.randomness``.
        scale_error (1, optional): the scale-factor error ``s_k`` of the interval ending at the
            sample time (paper S1's multiplicative noise ``kappa zeta_k``); the output is then
            ``(I + S + M) mean(w_IB_B) / (1 + s_k) + mean(b) + e``. Unconnected: 0.
    Parameters: the :class:`GyroModel` (:meth:`set_model` per context).
    Output ports (sample ``n`` at ``t_n = n T``; an output at ``t`` in ``(t_(n-1), t_n]``
    carries sample ``n``):
        gyro_measurement (5): ``[t_n (s), valid (1), w_meas_B (3, rad/s)]``.
        bias_B (3): true bias at ``t_n`` (rad/s), for scoring only.
    Inside: a ``ZeroOrderHold`` (C++) of ``w_IB_B_integral`` at the sample instants, the
    Python output of both signals and a C++ ``Demultiplexer`` splitting it (no per-sample event; see the module docstring).
    """

    def __init__(
        self,
        name: str,
        period_s: float,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        initial_bias_rad_per_s=(0.0, 0.0, 0.0),
        initial_bias_sigma_rad_per_s: float = 0.0,
        scale_factor_error=(0.0, 0.0, 0.0),
        misalignment=None,
        range_rad_per_s: float = math.inf,
        realizations: int = 1,
    ):
        Diagram.__init__(self)
        if not (isinstance(realizations, int) and realizations >= 1):
            raise ValueError(f"{name}.realizations: got {realizations!r}; must be an integer >= 1")
        self.realizations = realizations
        if not np.isfinite(period_s) or period_s <= 0:
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        self.period_s = float(period_s)
        self.default_model = GyroModel.make(
            name,
            period_s,
            arw_rad_per_rt_s,
            rrw_rad_per_s15,
            initial_bias_rad_per_s,
            initial_bias_sigma_rad_per_s,
            scale_factor_error,
            misalignment,
            range_rad_per_s,
        )
        builder = DiagramBuilder()
        outputs = _GyroOutputs(name, self.period_s, self.default_model, realizations)
        builder.AddSystem(outputs)
        hold = builder.AddNamedSystem(f"{name}_integral_hold", ZeroOrderHold(self.period_s, 3))
        builder.ExportInput(outputs.GetInputPort("w_IB_B"), "w_IB_B")
        builder.ExportInput(outputs.GetInputPort("w_IB_B_integral"), "w_IB_B_integral")
        builder.ConnectInput("w_IB_B_integral", hold.get_input_port())
        builder.Connect(hold.get_output_port(), outputs.GetInputPort("w_IB_B_integral_held"))
        builder.ExportInput(outputs.GetInputPort("seed_uniform"), "seed_uniform")
        builder.ExportInput(outputs.GetInputPort("scale_error"), "scale_error")
        split = builder.AddNamedSystem(
            f"{name}_split", Demultiplexer([GYRO_MEASUREMENT_SIZE * realizations, 3 * realizations])
        )
        builder.Connect(outputs.GetOutputPort("measurement_and_bias"), split.get_input_port())
        builder.ExportOutput(split.get_output_port(0), "gyro_measurement")
        builder.ExportOutput(split.get_output_port(1), "bias_B")
        builder.BuildInto(self)
        self.set_name(name)
        self._outputs = outputs

    def _outputs_context(self, context):
        return self.GetSubsystemContext(self._outputs, context)

    # -- parameters -----------------------------------------------------------------
    def model(self, context) -> GyroModel:
        """The :class:`GyroModel` in ``context`` (this system's context)."""
        return self._outputs.model(self._outputs_context(context))

    def set_model(
        self,
        context,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float,
        initial_bias_rad_per_s=(0.0, 0.0, 0.0),
        initial_bias_sigma_rad_per_s: float = 0.0,
        scale_factor_error=(0.0, 0.0, 0.0),
        misalignment=None,
        range_rad_per_s: float = math.inf,
    ) -> None:
        """Give ``context`` (this system's) other noise levels and errors (arguments as the
        constructor's)."""
        model = GyroModel.make(
            self.get_name(),
            self.period_s,
            arw_rad_per_rt_s,
            rrw_rad_per_s15,
            initial_bias_rad_per_s,
            initial_bias_sigma_rad_per_s,
            scale_factor_error,
            misalignment,
            range_rad_per_s,
        )
        sub = self.GetMutableSubsystemContext(self._outputs, context)
        sub.get_mutable_abstract_parameter(0).set_value(model)
