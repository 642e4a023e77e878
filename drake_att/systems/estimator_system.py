"""The one estimator system: a Drake ``LeafSystem`` that runs any filter core.

Every estimator — MEKF, MRP EKF, particle filters, a user's own — is a filter core
(:class:`drake_att.contract.FilterCore`, plain numpy) run by :class:`EstimatorSystem`,
which owns the loop they all share, once:

* one periodic discrete update per filter step (``period_s``);
* **time update** over ``(t_last, t]`` with the gyro's mean rate of that interval; a
  missing, invalid, stale (time tag not this step's) or non-finite gyro sample, or one the
  sensor monitor excluded, is counted (``skipped``) and the last valid rate is held. With
  ``held_rate_rrw_rad_per_s15`` (``r`` > 0; cores with
  :class:`~drake_att.contract.AttitudeProcessNoise`) the held rate's error is a random walk
  of intensity ``q = r^2`` from the last usable gyro sample: a held step starting ``tau``
  after it and lasting ``dt`` adds ``q (tau dt^2 + dt^3 / 3)`` to each attitude variance
  (:func:`~drake_att.systems.estimator_step.held_rate_variance`: that step's drift, white from
  step to step) and to the published ``Q``;
* **measurement updates** at this instant, inputs in declaration order (quaternion sensors,
  then vector sensors). Every *new* sample (time tag after the input's last handled one) is
  used or counted once (:func:`~drake_att.systems.estimator_step.tag_disposition`); a sample
  seen again (a held one, tag at or before the last handled) is passed over uncounted:

  - tagged at this step (``|t_meas - t| < 1e-6 s``): used;
  - tagged before it within ``max_time_tag_lag_s`` (``t - lag <= t_meas``): carried forward
    to ``t`` with the step's rate ``w_B = w_meas - bias_B_hat`` — a quaternion ``q_IS ⊗
    q_BS^-1 ⊗ exp(w_B gap) ⊗ q_BS``, vectors rotated likewise in the sensor frame — its noise
    variance grown by ``sigma_w^2 gap^2`` (``sigma_w^2``: the estimate's largest gyro-bias
    variance, plus ``q tau`` while the rate is held), then used like an on-time sample
    (counted ``late_samples_processed``); cores that cannot carry a sample (no gyro, no bias
    estimate; camera frames) reject it;
  - tagged before the lag: rejected;
  - tagged in the future before ``t + period - lag`` (no step can take it: at the next one
    it would be later than the lag): rejected at once;
  - tagged later: pending. A slower sensor shows its next sample, tagged at a later filter
    step, until that step (then it is used); a pending sample that leaves the port before it
    is due (a tag off the filter's steps, a time-tag fault) is rejected when the port shows
    another;
  - rejected for its tag: counted in ``skipped`` and ``time_tag_rejections``;

  then a sample the sensor monitor excluded (verdict 2) is skipped and counted
  (``monitor_exclusions``), whatever its flag; one that fails
  :func:`drake_att.contract.is_usable` (invalid or NaN flag, NaN time, non-finite numbers)
  is skipped and counted; the core's own rejection (innovation gate, singular innovation
  covariance: ``UpdateInfo.accepted`` false) is counted as skipped too;
* **prediction recovery**: a sample the monitor confirmed (verdict 1: consistent with
  another independent sensor) that the gate rejects says the prediction is wrong (a gyro
  fault, a bias jump): a :class:`~drake_att.contract.PredictionRecovery` core's
  ``recover_prediction`` at once, then the same measurement retried with ``ungated()``; the
  retry's outcome is counted, the recovery in ``prediction_recoveries``. Cores without it, and
  samples not assessed (verdict 0), follow the re-acquisition rule;
* **re-acquisition**: after :data:`~drake_att.filters.gating.REACQUIRE_AFTER_REJECTIONS`
  consecutive rejections of one input by a :class:`~drake_att.contract.Reacquisition` core
  (the Kalman-type cores: covariance inflated so the rejected innovation sits at half the
  gate), the state is re-acquired and the same measurement retried once with ``ungated()`` — a gate
  never rejects forever (a filter that has lost track, or starts far from the truth, takes
  the measurement back after N rejections); the retry's outcome is what is counted;
* **randomness** (cores with ``is_random``): the seed comes from the diagram's
  ``RandomGenerator`` through the random input port ``seed_uniform``; the initialization
  event draws the initial state with generator 0 of
  ``counter_random(seed words, system name)``, step ``k`` uses generator ``k`` — every
  number is a pure function of (seed, system name, step index);
* publishes the estimator contract (:mod:`drake_att.contract`).

Input ports:
    gyro_measurement (5): ``[t, valid, w_meas_B (3, rad/s)]`` (cores with ``uses_gyro``).
    q_meas_<sensor> (6): ``[t, valid, q_IS_meas (4)]`` per quaternion sensor.
    vectors_<sensor> (abstract :class:`~drake_att.contract.VectorObservations`) per vector
        sensor.
    centroids_<sensor> (abstract :class:`~drake_att.contract.CameraCentroids`) per camera
        (the indoor star tracker, paper S2).
    seed_uniform (4, random uniform) (cores with ``is_random``).
    sensor_verdicts (1 + inputs) (systems built with ``verdicts``, i.e. a setup naming a
        ``monitor``): the sensor monitor's verdict on the gyro, then on each measurement
        input in :attr:`input_names` order: 0 not assessed, 1 confirmed, 2 excluded
        (:func:`~drake_att.systems.estimator_step.verdict_code`). Unconnected: none assessed.
    q_cov_<sensor> (9) per quaternion sensor whose model has ``sample_covariance``: that sample's
        covariance (row-major 3x3, rad^2, sensor frame), used in place of the model's.
Output ports:
    q_IB_hat (4), bias_B_hat or w_IB_B_hat (3, named by the core's ``second_quantity``),
    covariance (36), status (4): the contract (see :mod:`drake_att.contract`).
    estimate_state (47): the packed estimate (C++-evaluated; what the builder logs).
    step_linearization (109) (:class:`~drake_att.contract.LinearizedPrediction` cores, e.g. the MEKF): the last
        step's linearized error map ``e+ = A (Phi e + w)`` as ``[Phi, Q = cov(w), A]``
        (row-major 6x6 each) and the number of steps taken (for track-to-track fusion).
    particle_diagnostics (4) (:class:`~drake_att.contract.ParticleSet` cores): ``[N_eff after the last
        update (before resampling), resamplings so far, degenerate updates so far, N]``.
    diagnostics (n) (:class:`~drake_att.contract.CoreDiagnostics` cores): ``core.diagnostics(state)``, e.g. the
        indoor star tracker's stars identified and iterations of the last frame.
    innovations (3 per measurement input, C++-evaluated; estimators with inputs): per input,
        in :attr:`input_names` order, ``[time of its last update (s; -inf before any), that
        update's NIS (NaN when the core has none, e.g. particle filters), innovation
        dimension (0 when none)]`` — rejected updates included (per-sensor NIS statistics).
    sample_handling (4, C++-evaluated): counts so far of
        :data:`~drake_att.systems.estimator_step.SAMPLE_HANDLING_NAMES` — late samples
        processed, samples rejected for their time tag, prediction recoveries, monitor
        exclusions (gyro samples included).
Parameters (per Context, so one diagram serves a whole sweep or Monte Carlo):
    abstract parameter 0: the :class:`FilterModel` — the core (its tuning), the initial
        state, the quaternion sensor models (mounting, noise), whether the estimator
        runs, the time-tag lag and the held-rate walk. :meth:`set_filter` replaces it (and
        the state it implies) in a context; structure (state size, ports, period, the sensor
        monitor) cannot change.
Discrete state:
    group 0: the packed estimate (47).
    group 1: the runner's counters and times, laid out by :class:`Bookkeeping`.
    group 2: the core's state vector (``core.to_vector``).
    group 3 (linearizing cores): the step linearization (109).
    next group (estimators with measurement inputs): the innovations (3 per input).
    last group: the sample-handling counters (4).

The one runner: every estimator's ports, state groups, outputs and loop, kept together on purpose.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Any, cast

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, InputPort, LeafSystem

from drake_att import contract
from drake_att import rotations as rot
from drake_att.contract import (
    ESTIMATE_SIZE,
    GYRO_MEASUREMENT_SIZE,
    QUATERNION_MEASUREMENT_SIZE,
    STATUS,
    STATUS_LAST_NIS,
    STATUS_SKIPPED,
    STATUS_USED,
    CoreCapabilities,
    QuaternionSample,
    SecondQuantity,
    pack_estimate,
)
from drake_att.filters.gating import REACQUIRE_AFTER_REJECTIONS
from drake_att.systems import compiled_step
from drake_att.systems import estimator_step as rules
from drake_att.systems.estimator_step import (
    SAMPLE_HANDLING_NAMES,
    TIME_TOLERANCE_S,
    Bookkeeping,
    covariance_slot,
    gyro_sample_usable,
    is_gate_rejection,
    rate_usable,
)
from drake_att.systems.randomness import (
    counter_random,
    declare_seed_port,
    read_seed_words,
)
from drake_att.validation import check_nonnegative, fail

LINEARIZATION_SIZE = 3 * 36 + 1
PARTICLE_DIAGNOSTICS_SIZE = 4
_EYE6 = np.eye(6)
_ZERO6 = np.zeros((6, 6))
_ATTITUDE_BLOCK = np.diag([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])

# The status entries of the packed estimate the runner counts in.
_USED, _SKIPPED, _LAST_NIS = (STATUS.start + i for i in (STATUS_USED, STATUS_SKIPPED, STATUS_LAST_NIS))
_NO_GYRO = np.full(GYRO_MEASUREMENT_SIZE, np.nan)
_NO_INNOVATIONS = np.zeros(0)

__all__ = [
    "EstimatorSystem",
    "EstimatorSetup",
    "FilterModel",
    "QuaternionSensorModel",
    "MekfEstimator",
    "Bookkeeping",
    "pack_estimate",
    "ESTIMATE_SIZE",
    "TIME_TOLERANCE_S",
    "PARTICLE_DIAGNOSTICS_SIZE",
    "LINEARIZATION_SIZE",
    "SAMPLE_HANDLING_NAMES",
    "check_step_settings",
]


def _sample_covariance(port, context) -> np.ndarray | None:
    """A sample's own covariance (3, 3) from a ``q_cov_<name>`` input, or None if it is
    unconnected or not finite, symmetric and positive definite (the sample is then skipped)."""
    if not port.HasValue(context):
        return None
    C = np.asarray(port.Eval(context), dtype=float).reshape(3, 3)
    if not np.all(np.isfinite(C)) or not np.allclose(C, C.T, rtol=1e-9, atol=0.0):
        return None
    try:
        np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        return None
    return C


@dataclass(frozen=True)
class QuaternionSensorModel:
    """What the filter assumes about one attitude-quaternion sensor.

    ``covariance_by_flag``: for a virtual sensor whose validity flag says which of its
    inputs formed the sample (the star-tracker average): flag 1 = all of them
    (``covariance_S``), flag ``1 + mask`` = the inputs in the bit mask only, with
    ``covariance_by_flag[mask]`` (None where that subset is not allowed: such a sample is
    skipped and counted)."""

    name: str
    q_BS: np.ndarray
    covariance_S: np.ndarray  # (3, 3) rotation-vector noise in the sensor frame (rad^2)
    covariance_by_flag: tuple = ()
    #: The sensor gives each sample's own covariance (its ``covariance_S`` output, 9 numbers,
    #: row-major, rad^2), read on the estimator's ``q_cov_<name>`` input in place of
    #: ``covariance_S``; a sample whose covariance is not finite, symmetric and positive
    #: definite is skipped and counted.
    sample_covariance: bool = False

    def covariance_for_flag(self, flag: float):
        """The covariance of a sample with validity ``flag`` (None: not a usable subset;
        :func:`~drake_att.systems.estimator_step.covariance_slot`)."""
        slot = covariance_slot(flag, len(self.covariance_by_flag))
        if slot < 0:
            return None
        return self.covariance_S if slot == 0 else self.covariance_by_flag[slot]


@dataclass(frozen=True)
class EstimatorSetup:
    """What an estimator plug-in's build function returns: the builder turns it into an
    :class:`EstimatorSystem` wired to the named sensors (one home for that wiring), and
    re-evaluates it for a context whose parameters change (:meth:`EstimatorSystem.set_filter`).

    Attributes:
        core: the :class:`~drake_att.contract.FilterCore` (its tuning included).
        initial_state: the core's state at t = 0.
        period_s: filter step (s).
        gyro: name of the gyro feeding ``gyro_measurement`` (cores with ``uses_gyro``).
        quaternion_sensors: :class:`QuaternionSensorModel` per attitude-quaternion input.
        vector_sensors: names of the vector-observation sensors.
        camera_sensors: names of the cameras (focal-plane centroids).
        max_time_tag_lag_s: how late a sample's time tag may be and the sample still be used,
            carried forward to the step (s, >= 0, < ``period_s``; 0: only on-time samples).
        held_rate_rrw_rad_per_s15: intensity of the random walk that models a held gyro
            rate's error (rad/s^1.5, >= 0; 0: a held rate adds no attitude variance).
        monitor: name of the sensor-monitor system whose ``sensor_verdicts`` the estimator
            reads (None: no monitor; the system then has no ``sensor_verdicts`` port).
    """

    core: Any
    initial_state: Any
    period_s: float
    gyro: str | None = None
    quaternion_sensors: tuple = ()
    vector_sensors: tuple = ()
    camera_sensors: tuple = ()
    max_time_tag_lag_s: float = 0.0
    held_rate_rrw_rad_per_s15: float = 0.0
    monitor: str | None = None


@dataclass(frozen=True)
class FilterModel:
    """The per-context part of an estimator (its abstract parameter): the core, the initial
    state, what it assumes about its quaternion sensors, whether it runs at all
    (``enabled`` false: every step does nothing; the estimate stays the initial one) and the
    loop's settings (:class:`EstimatorSetup`'s ``max_time_tag_lag_s`` and
    ``held_rate_rrw_rad_per_s15``)."""

    core: Any
    initial_state: Any
    quaternion_sensors: tuple
    enabled: bool = True
    max_time_tag_lag_s: float = 0.0
    held_rate_rrw_rad_per_s15: float = 0.0
    capabilities: CoreCapabilities = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "capabilities", CoreCapabilities.of(self.core))


def check_step_settings(
    path: str, period_s: float, max_time_tag_lag_s, held_rate_rrw_rad_per_s15, core=None, error: type = ValueError
) -> tuple[float, float]:
    """``(max_time_tag_lag_s, held_rate_rrw_rad_per_s15)`` as floats, checked: finite, >= 0,
    the lag below the period ``period_s`` (a sample later than one step is another step's),
    and a held-rate walk only for a core that can take attitude process noise
    (:class:`~drake_att.contract.AttitudeProcessNoise`). ``error`` (one line naming the field)
    otherwise."""
    lag = check_nonnegative(f"{path}.max_time_tag_lag_s", max_time_tag_lag_s, error)
    if lag >= period_s:
        fail(
            f"{path}.max_time_tag_lag_s",
            max_time_tag_lag_s,
            f"must be below the estimator's period ({period_s} s): a sample later than one step belongs to another",
            error,
        )
    rrw = check_nonnegative(f"{path}.held_rate_rrw_rad_per_s15", held_rate_rrw_rad_per_s15, error)
    if rrw > 0.0 and core is not None and not CoreCapabilities.of(core).attitude_process_noise:
        fail(
            f"{path}.held_rate_rrw_rad_per_s15",
            held_rate_rrw_rad_per_s15,
            f"must be 0 for core {type(core).__name__}: it cannot take attitude process noise "
            "(drake_att.contract.AttitudeProcessNoise)",
            error,
        )
    return lag, rrw


class EstimatorSystem(LeafSystem):
    """Runs one filter core as a Drake system (see the module docstring for ports and state).

    Args:
        name: system name (also the random stream name of random cores).
        period_s: filter step (s), finite and > 0; for gyro-driven cores it must equal the
            gyro period (the gyro delivers the mean rate over exactly one step).
        core: a :class:`~drake_att.contract.FilterCore`.
        initial_state: the core's state at t = 0 (for random cores with a
            ``draw_initial_state(rng)``: the default, replaced at initialization by a draw).
        quaternion_sensors: :class:`QuaternionSensorModel` per attitude-quaternion input.
        vector_sensors: names of vector-observation inputs.
        camera_sensors: names of camera (focal-plane centroid) inputs.
        max_time_tag_lag_s: the default context's lag (:class:`EstimatorSetup`).
        held_rate_rrw_rad_per_s15: the default context's held-rate walk (:class:`EstimatorSetup`).
        verdicts: declare the ``sensor_verdicts`` input (a sensor monitor's verdicts).
        realizations: N realizations in one system (a batch of runs; only an MEKF on the
            compiled step, without a monitor or per-sample covariances): every input, output
            and state group carries N blocks, realization-major, and each step runs
            :func:`~drake_att.systems.compiled_step.mekf_steps` on every realization's blocks
            (the same per-realization step as a run alone).
    """

    def __init__(
        self,
        name: str,
        period_s: float,
        core,
        initial_state,
        quaternion_sensors=(),
        vector_sensors=(),
        camera_sensors=(),
        max_time_tag_lag_s: float = 0.0,
        held_rate_rrw_rad_per_s15: float = 0.0,
        verdicts: bool = False,
        realizations: int = 1,
    ):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not (isinstance(realizations, int) and realizations >= 1):
            raise ValueError(f"{name}.realizations: got {realizations!r}; must be an integer >= 1")
        self.realizations = realizations
        self._no_gyro = np.tile(_NO_GYRO, realizations)  # the compiled step's gyro input, port unconnected
        if not isinstance(core, contract.FilterCore):
            raise TypeError(f"{name}: core {type(core).__name__} does not implement drake_att.contract.FilterCore")
        if not (isinstance(period_s, (int, float)) and math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        self.period_s = float(period_s)
        lag, rrw = check_step_settings(name, self.period_s, max_time_tag_lag_s, held_rate_rrw_rad_per_s15, core)
        self.verdicts = bool(verdicts)
        self.core = core  # the default core (a context may carry another: FilterModel)
        self.second_quantity: SecondQuantity = core.second_quantity
        self.second_output_name = core.second_quantity.port_name
        self.capabilities = CoreCapabilities.of(core)
        self._linearizing = self.capabilities.linearized_prediction
        self.num_particles = self.capabilities.num_particles
        self._declare_inputs(core, quaternion_sensors, vector_sensors, camera_sensors)
        self.diagnostic_names = self.capabilities.diagnostic_names
        self._compiled_models: dict = {}
        if realizations > 1:
            problem = self._batch_problem(core, quaternion_sensors)
            if problem:
                raise ValueError(f"{name}.realizations: got {realizations}; more than one needs {problem}")
        self._model_index = self.DeclareAbstractParameter(
            AbstractValue.Make(FilterModel(core, initial_state, tuple(self._quat_sensors), True, lag, rrw))
        )
        self._declare_state(core, initial_state)
        self._declare_outputs()
        if core.is_random:
            self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_step)

    def _batch_problem(self, core, quaternion_sensors) -> str | None:
        """Why this estimator cannot carry several realizations (None: it can): only the
        compiled MEKF step runs them, each on its own slice of the state groups."""
        if not (self._linearizing and compiled_step.eligible(core, len(self._vector_ports), core.is_random)):
            return "an MEKF with compiled kernels, quaternion inputs only and no random core"
        if not self.use_compiled_step:
            return "the compiled step, which EstimatorSystem.use_compiled_step switches off"
        if self.verdicts or any(s.sample_covariance for s in quaternion_sensors):
            return "no sensor monitor and no per-sample covariance"
        if self.diagnostic_names or self.num_particles is not None:
            return "a core without diagnostics outputs"
        return None

    def _declare_inputs(self, core, quaternion_sensors, vector_sensors, camera_sensors) -> None:
        """The input ports; their order matters for the diagram's random streams: keep it stable."""
        N = self.realizations
        self._gyro_port = (
            self.DeclareVectorInputPort("gyro_measurement", GYRO_MEASUREMENT_SIZE * N) if core.uses_gyro else None
        )
        self._quat_sensors = list(quaternion_sensors)
        self._quat_ports = [
            self.DeclareVectorInputPort(f"q_meas_{s.name}", QUATERNION_MEASUREMENT_SIZE * N) for s in self._quat_sensors
        ]
        self._vector_ports = [
            self.DeclareAbstractInputPort(f"vectors_{n}", AbstractValue.Make(contract.empty_vector_observations()))
            for n in vector_sensors
        ]
        self._vector_ports += [
            self.DeclareAbstractInputPort(f"centroids_{n}", AbstractValue.Make(contract.empty_camera_centroids()))
            for n in camera_sensors
        ]
        self._seed_port = declare_seed_port(self) if core.is_random else None
        self._vector_names = tuple(vector_sensors)
        self._camera_names = tuple(camera_sensors)
        n_inputs = len(self._quat_ports) + len(self._vector_ports)
        self._verdict_port = self.DeclareVectorInputPort("sensor_verdicts", 1 + n_inputs) if self.verdicts else None
        self._covariance_ports = [
            self.DeclareVectorInputPort(f"q_cov_{s.name}", 9) if s.sample_covariance else None
            for s in self._quat_sensors
        ]

    def _declare_state(self, core, initial_state) -> None:
        """The discrete-state groups (see the module docstring)."""
        q0, second0, P0 = core.estimate(initial_state)
        self._estimate_group = self._declare_group(
            pack_estimate(rot.quat_canonical(q0), second0, P0, 0.0, 0, 0, np.nan)
        )
        n_inputs = len(self._quat_ports) + len(self._vector_ports)
        self.bookkeeping = Bookkeeping(n_inputs)
        self._rejections = self.bookkeeping.rejections
        self._book_group = self._declare_group(self.bookkeeping.initial(self.num_particles))
        self._core_group = self._declare_group(core.to_vector(initial_state))
        if self._linearizing:
            self._linearization_group = self._declare_group(
                np.concatenate([_EYE6.ravel(), _ZERO6.ravel(), _EYE6.ravel(), [0.0]])
            )
        self.input_names = tuple(s.name for s in self._quat_sensors) + self._vector_names + self._camera_names
        self._innovation_group = None
        if n_inputs:
            self._innovation_group = self._declare_group(np.tile([-np.inf, np.nan, 0.0], n_inputs))
        self._handling_group = self._declare_group(np.zeros(len(SAMPLE_HANDLING_NAMES)))

    def _declare_outputs(self) -> None:
        """The contract's ports, the logged state ports and the capabilities' outputs."""
        ticket = {self.discrete_state_ticket(self._estimate_group)}
        for port, part in self.second_quantity.estimate_ports():
            self.DeclareVectorOutputPort(
                port, (part.stop - part.start) * self.realizations, functools.partial(self._out, part=part), ticket
            )
        # The whole estimate group as one C++-evaluated port: loggers record this one (no
        # Python callback per logged sample); the builder splits it into the contract signals.
        self.DeclareStateOutputPort("estimate_state", self._estimate_group)
        if self._linearizing:
            self.DeclareStateOutputPort("step_linearization", self._linearization_group)
        if self._innovation_group is not None:
            self.DeclareStateOutputPort("innovations", self._innovation_group)
        self.DeclareStateOutputPort("sample_handling", self._handling_group)
        if self.num_particles is not None:
            self.DeclareVectorOutputPort(
                "particle_diagnostics",
                PARTICLE_DIAGNOSTICS_SIZE,
                self._calc_diagnostics,
                {self.discrete_state_ticket(self._book_group)},
            )
        if self.diagnostic_names:
            self.DeclareVectorOutputPort(
                "diagnostics",
                len(self.diagnostic_names),
                self._calc_core_diagnostics,
                {self.discrete_state_ticket(self._core_group)},
            )

    def _declare_group(self, values):
        """A discrete-state group with these initial values (once per realization); its index."""
        return self.DeclareDiscreteState(self._per_realization(values))

    def _per_realization(self, values) -> np.ndarray:
        """``values`` (one realization's group) repeated for every realization."""
        values = np.asarray(values, dtype=float)
        return values if self.realizations == 1 else np.tile(values, self.realizations)

    @classmethod
    def from_setup(cls, name: str, setup: EstimatorSetup, realizations: int = 1) -> EstimatorSystem:
        """The system for a plug-in's :class:`EstimatorSetup` (ports unconnected)."""
        return cls(
            name,
            setup.period_s,
            setup.core,
            setup.initial_state,
            setup.quaternion_sensors,
            setup.vector_sensors,
            setup.camera_sensors,
            setup.max_time_tag_lag_s,
            setup.held_rate_rrw_rad_per_s15,
            verdicts=setup.monitor is not None,
            realizations=realizations,
        )

    # -- per-context parameters ---------------------------------------------------------------
    def filter_model(self, context) -> FilterModel:
        """The :class:`FilterModel` in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._model_index).get_value()

    def set_filter(self, context, setup: EstimatorSetup | None = None, enabled: bool | None = None) -> None:
        """Give ``context`` (this system's) another core / initial state / sensor models
        (``setup``) and/or switch the estimator on or off, and reset the filter state to the
        new initial state. The structure must not change.

        Raises:
            ValueError: naming what differs (state size, gyro use, randomness, second
                quantity, linearization, particle count, period or sensors).
        """
        model = self.filter_model(context)
        if setup is not None:
            self._check_compatible(setup)
            lag, rrw = check_step_settings(
                self.get_name(),
                self.period_s,
                setup.max_time_tag_lag_s,
                setup.held_rate_rrw_rad_per_s15,
                setup.core,
            )
            model = FilterModel(
                setup.core, setup.initial_state, tuple(setup.quaternion_sensors), model.enabled, lag, rrw
            )
        if enabled is not None:
            model = replace(model, enabled=bool(enabled))
        context.get_mutable_abstract_parameter(self._model_index).set_value(model)
        if setup is not None:
            core, state = model.core, model.initial_state
            q0, second0, P0 = core.estimate(state)
            context.get_mutable_discrete_state(self._estimate_group).SetFromVector(
                self._per_realization(pack_estimate(rot.quat_canonical(q0), second0, P0, 0.0, 0, 0, np.nan))
            )
            context.get_mutable_discrete_state(self._core_group).SetFromVector(
                self._per_realization(core.to_vector(state))
            )

    def _check_compatible(self, setup: EstimatorSetup) -> None:
        name, old, new = self.get_name(), self.core, setup.core
        if not isinstance(new, contract.FilterCore):
            raise TypeError(f"{name}: core {type(new).__name__} does not implement drake_att.contract.FilterCore")
        caps = CoreCapabilities.of(new)
        checks = [
            ("period_s", self.period_s, float(setup.period_s)),
            ("state size", old.state_size, new.state_size),
            ("uses_gyro", old.uses_gyro, new.uses_gyro),
            ("is_random", old.is_random, new.is_random),
            ("second quantity", old.second_quantity, new.second_quantity),
            ("linearizing", self._linearizing, caps.linearized_prediction),
            ("num_particles", self.num_particles, caps.num_particles),
            ("quaternion sensors", [s.name for s in self._quat_sensors], [s.name for s in setup.quaternion_sensors]),
            (
                "per-sample covariances",
                [s.sample_covariance for s in self._quat_sensors],
                [s.sample_covariance for s in setup.quaternion_sensors],
            ),
            ("vector sensors", list(self._vector_names), list(setup.vector_sensors)),
            ("cameras", list(self._camera_names), list(setup.camera_sensors)),
            ("diagnostics", list(self.diagnostic_names), list(caps.diagnostic_names)),
            ("sensor monitor", self.verdicts, setup.monitor is not None),
        ]
        for what, was, now in checks:
            if was != now:
                raise ValueError(
                    f"{name}: the new filter setup changes the {what} ({was!r} -> {now!r}); "
                    "that changes the diagram's structure: build a new diagram"
                )

    # -- outputs and accessors -------------------------------------------------------------
    def _out(self, context, output: BasicVector, part: slice):
        est = context.get_discrete_state(self._estimate_group).value()
        if self.realizations > 1:
            est = est.reshape(self.realizations, -1)[:, part].ravel()
            part = slice(None)
        output.SetFromVector(est[part])

    def _calc_diagnostics(self, context, output: BasicVector):
        book = context.get_discrete_state(self._book_group).value()
        values = [
            book[Bookkeeping.ESS],
            book[Bookkeeping.N_RESAMPLES],
            book[Bookkeeping.N_DEGENERATE],
            float(cast(int, self.num_particles)),
        ]
        output.SetFromVector(np.array(values))  # type: ignore[arg-type]  # pydrake stub

    def _calc_core_diagnostics(self, context, output: BasicVector):
        core = self.filter_model(context).core
        output.SetFromVector(core.diagnostics(core.from_vector(context.get_discrete_state(self._core_group).value())))

    def estimate_vector(self, context) -> np.ndarray:
        """The packed estimate (47) in ``context`` (this system's context)."""
        return context.get_discrete_state(self._estimate_group).value()

    def filter_state(self, context) -> np.ndarray:
        """A copy of the core's state vector in ``context`` (layout: the core's ``to_vector``)."""
        return context.get_discrete_state(self._core_group).value().copy()

    # -- events ------------------------------------------------------------------------------
    def _initialize(self, context, discrete_state):
        """Random cores: keep the seed words, draw the initial state with generator 0 (cores
        without ``draw_initial_state`` start from the model's initial state)."""
        words = read_seed_words(self, context, self._seed_port)
        book = context.get_discrete_state(self._book_group).value().copy()
        book[Bookkeeping.SEED] = words
        book[Bookkeeping.STEP] = 0.0
        model = self.filter_model(context)
        core = model.core
        state = (
            core.draw_initial_state(counter_random(words, self.get_name()).generator(0))
            if model.capabilities.random_initial_state
            else model.initial_state
        )
        discrete_state.get_mutable_vector(self._book_group).SetFromVector(book)
        discrete_state.get_mutable_vector(self._core_group).SetFromVector(core.to_vector(state))
        return EventStatus.Succeeded()

    def _gyro_rate(self, context, t):
        """The gyro's mean rate over the interval ending at ``t``, or None if unusable."""
        if not self._gyro_port.HasValue(context):
            return None
        t_g, valid, wx, wy, wz = self._gyro_port.Eval(context).tolist()  # the GyroSample layout
        return np.array([wx, wy, wz]) if gyro_sample_usable(t, TIME_TOLERANCE_S, t_g, valid, wx, wy, wz) else None

    def _measurements(self, context, quaternion_sensors):
        """``(input index, measurement)`` for every connected measurement input, in order."""
        for i, (sensor, port) in enumerate(zip(quaternion_sensors, self._quat_ports, strict=True)):
            if port.HasValue(context):
                m = port.Eval(context)
                flag = float(m[1])
                cov = sensor.covariance_for_flag(flag)
                if sensor.sample_covariance:
                    cov = _sample_covariance(self._covariance_ports[i], context)
                yield (
                    i,
                    QuaternionSample(
                        float(m[0]),
                        flag > 0.5 and math.isfinite(flag) and cov is not None,
                        m[2:6].copy(),
                        sensor.q_BS,
                        sensor.covariance_S if cov is None else cov,
                    ),
                )
        offset = len(self._quat_ports)
        for j, port in enumerate(self._vector_ports):
            if port.HasValue(context):
                yield offset + j, port.Eval(context)

    #: Run eligible steps (an MEKF with compiled kernels, quaternion inputs only, no sensor
    #: monitor) as one
    #: compiled call (:mod:`drake_att.systems.compiled_step`); False: always this Python loop
    #: (the specification; the tests compare the two).
    use_compiled_step = True

    def _compiled_model(self, model: FilterModel):
        """The :class:`~drake_att.systems.compiled_step.CompiledStepModel` of ``model``, or
        None if its steps take the Python loop (built once per model; estimators with a
        sensor monitor always take the Python loop)."""
        hit = self._compiled_models.get(id(model))
        if hit is not None and hit[0] is model:
            return hit[1]
        array_model = None
        if (
            self._linearizing
            and not self.verdicts
            and not any(s.sample_covariance for s in model.quaternion_sensors)
            and compiled_step.eligible(model.core, len(self._vector_ports), model.core.is_random)
        ):
            array_model = compiled_step.StepModel.of(
                model.core,
                model.quaternion_sensors,
                self.bookkeeping,
                self.period_s,
                model.max_time_tag_lag_s,
                model.held_rate_rrw_rad_per_s15,
            )
        if len(self._compiled_models) > 8:
            self._compiled_models.clear()
        self._compiled_models[id(model)] = (model, array_model)
        return array_model

    def _on_step_compiled(self, context, discrete_state, m) -> EventStatus:
        """:meth:`_on_step` by :func:`~drake_att.systems.compiled_step.mekf_steps`: the port
        reads here, the rest in one compiled call writing every realization's blocks of the
        state groups in place."""
        gyro_port = cast(InputPort, self._gyro_port)  # an MEKF reads the gyro
        gyro_connected = gyro_port.HasValue(context)
        gyro = gyro_port.Eval(context) if gyro_connected else self._no_gyro
        n = len(self._quat_ports)
        meas = np.zeros((n, QUATERNION_MEASUREMENT_SIZE * self.realizations))
        connected = np.zeros(n, dtype=np.bool_)
        for i, port in enumerate(self._quat_ports):
            if port.HasValue(context):
                meas[i] = port.Eval(context)  # type: ignore[call-overload]  # pydrake stub: Eval returns object
                connected[i] = True
        group = discrete_state.get_mutable_value  # a writable view of a group (one pybind call)
        innovations = group(self._innovation_group) if self._innovation_group is not None else _NO_INNOVATIONS
        compiled_step.mekf_steps(
            context.get_time(),
            gyro_connected,
            gyro,
            connected,
            meas,
            *m,
            group(self._handling_group),
            group(self._estimate_group),
            group(self._book_group),
            group(self._core_group),
            group(self._linearization_group),
            innovations,
        )
        return EventStatus.Succeeded()

    def _verdicts(self, context):
        """The sensor monitor's verdict codes ``[gyro, input 0, input 1, ...]``
        (:func:`~drake_att.systems.estimator_step.verdict_code`), or None (no monitor, or its port unconnected: every
        sample not assessed)."""
        if self._verdict_port is None or not self._verdict_port.HasValue(context):
            return None
        return [rules.verdict_code(v) for v in self._verdict_port.Eval(context).tolist()]

    def _on_step(self, context, discrete_state):
        model = self.filter_model(context)
        if not model.enabled:
            return EventStatus.DidNothing()
        if self.use_compiled_step:
            array_model = self._compiled_model(model)
            if array_model is not None:
                return self._on_step_compiled(context, discrete_state, array_model)
        if self.realizations > 1:
            raise RuntimeError(
                f"{self.get_name()}: this context's filter model does not run the compiled MEKF step, "
                "which several realizations need"
            )
        core = model.core
        t = context.get_time()
        est = self.estimate_vector(context)
        book = context.get_discrete_state(self._book_group).value().copy()
        handling = context.get_discrete_state(self._handling_group).value().copy()
        state = core.from_vector(context.get_discrete_state(self._core_group).value())
        n_used, n_skipped, nis = est[_USED], est[_SKIPPED], est[_LAST_NIS]
        verdicts = self._verdicts(context)
        rng = None
        if core.is_random:
            book[Bookkeeping.STEP] += 1.0
            rng = counter_random(book[Bookkeeping.SEED], self.get_name()).generator(int(book[Bookkeeping.STEP]))
        state, Phi, Q, held = self._time_update(context, model, state, book, handling, t, rng, verdicts)
        n_skipped += held

        # -- measurement updates at this instant ------------------------------------------------
        A = _EYE6
        innovations = None
        lag = model.max_time_tag_lag_s
        pending, last = self.bookkeeping.pending, Bookkeeping.LAST_SAMPLE
        for i, m in self._measurements(context, model.quaternion_sensors):
            t_meas = float(m.time_s)
            if rules.pending_vanished(book[pending + i], book[last + i], t_meas):
                n_skipped += 1  # a future-tagged sample that left the port unused
                handling[rules.N_TAG_REJECTED] += 1
                book[pending + i] = -np.inf
            disposition = rules.tag_disposition(t_meas, t, TIME_TOLERANCE_S, book[last + i], lag, self.period_s)
            if disposition == rules.NOT_DUE:
                continue
            if disposition == rules.NO_TIME:
                n_skipped += 1  # a sample with no usable time stamp is counted
                continue
            if disposition == rules.FUTURE:
                book[pending + i] = t_meas  # may still become due
                continue
            book[last + i] = t_meas
            late = disposition == rules.LATE
            if disposition in (rules.TOO_LATE, rules.TOO_EARLY) or (late and not self._can_carry(core, m)):
                n_skipped += 1
                handling[rules.N_TAG_REJECTED] += 1
                continue
            verdict = rules.NOT_ASSESSED if verdicts is None else verdicts[1 + i]
            if verdict == rules.EXCLUDED:
                n_skipped += 1
                handling[rules.N_EXCLUDED] += 1
                continue
            if not contract.is_usable(m):
                n_skipped += 1
                continue
            if late:
                m = self._carried_forward(model, core, state, m, book, t, t - t_meas)
                handling[rules.N_LATE] += 1
            state, info = self._update(
                model, state, m, book, self._rejections + i, rng, verdict == rules.CONFIRMED, handling, self.period_s
            )
            nis = info.nis
            if innovations is None:
                innovations = context.get_discrete_state(self._innovation_group).value().copy()
            innovations[3 * i : 3 * i + 3] = (t, nis, 0 if info.innovation is None else len(info.innovation))
            if info.accepted:
                n_used += 1
                if self._linearizing and info.error_transition is not None:
                    A = info.error_transition if A is _EYE6 else info.error_transition @ A
            else:
                n_skipped += 1
            book[Bookkeeping.N_RESAMPLES] += info.resampled
            book[Bookkeeping.N_DEGENERATE] += info.degenerate
            if math.isfinite(info.effective_sample_size):
                book[Bookkeeping.ESS] = info.effective_sample_size

        q_hat, second, P = core.estimate(state)
        discrete_state.get_mutable_vector(self._estimate_group).SetFromVector(
            pack_estimate(rot.quat_canonical(q_hat), second, P, t, n_used, n_skipped, nis)
        )
        if innovations is not None:
            discrete_state.get_mutable_vector(self._innovation_group).SetFromVector(innovations)
        discrete_state.get_mutable_vector(self._book_group).SetFromVector(book)
        discrete_state.get_mutable_vector(self._handling_group).SetFromVector(handling)
        discrete_state.get_mutable_vector(self._core_group).SetFromVector(core.to_vector(state))
        if self._linearizing:
            steps = context.get_discrete_state(self._linearization_group).value()[-1] + 1
            discrete_state.get_mutable_vector(self._linearization_group).SetFromVector(
                np.concatenate([Phi.ravel(), Q.ravel(), A.ravel(), [steps]])
            )
        return EventStatus.Succeeded()

    def _time_update(self, context, model: FilterModel, state, book, handling, t, rng, verdicts):
        """The time update over ``(t_last, t]`` (none at the first step): ``(state, Phi, Q,
        held)``, ``held`` 1 when the gyro sample was unusable (or excluded by the monitor)
        and the last valid rate held, then with the held-rate drift's attitude variance
        (:func:`~drake_att.systems.estimator_step.held_rate_variance`) added (``book`` keeps
        the rate, the step's time and the last usable gyro sample's step)."""
        core = model.core
        t_last = float(book[Bookkeeping.T_LAST])
        Phi, Q, held = _EYE6, _ZERO6, 0
        excluded = verdicts is not None and verdicts[0] == rules.EXCLUDED and core.uses_gyro
        handling[rules.N_EXCLUDED] += excluded
        if math.isfinite(t_last):
            w_meas = None
            if core.uses_gyro:
                w_meas = None if excluded else self._gyro_rate(context, t)
                if w_meas is None:
                    held = 1
                    w_meas = book[Bookkeeping.W_LAST].copy()
                else:
                    book[Bookkeeping.W_LAST] = w_meas
                    book[Bookkeeping.T_GYRO_GOOD] = t
            if self._linearizing:
                state, Phi, Q = core.predict_linearized(state, w_meas, t - t_last)
            else:
                state = core.predict(state, w_meas, t - t_last, rng)
            q_hold = model.held_rate_rrw_rad_per_s15**2
            if held and q_hold > 0.0:
                variance = rules.held_rate_variance(q_hold, t_last - book[Bookkeeping.T_GYRO_GOOD], t - t_last)
                if variance > 0.0:
                    state = core.add_attitude_variance(state, variance)
                    Q = Q + variance * _ATTITUDE_BLOCK
        else:
            book[Bookkeeping.T_GYRO_GOOD] = t  # the held rate's walk starts at the first step at the latest
            gyro_port = self._gyro_port
            if core.uses_gyro and not excluded and gyro_port is not None and gyro_port.HasValue(context):
                t_g, valid, wx, wy, wz = np.asarray(gyro_port.Eval(context), dtype=float).tolist()
                if rate_usable(valid, wx, wy, wz):
                    book[Bookkeeping.W_LAST] = (wx, wy, wz)
        book[Bookkeeping.T_LAST] = t
        return state, Phi, Q, held

    def _can_carry(self, core, measurement) -> bool:
        """Whether a late ``measurement`` can be carried forward: a gyro-driven core that
        estimates the gyro bias, and a quaternion or vector-observation sample."""
        return (
            core.uses_gyro
            and self.second_quantity is SecondQuantity.GYRO_BIAS
            and isinstance(measurement, (QuaternionSample, contract.VectorObservations))
        )

    @staticmethod
    def _carried_forward(model: FilterModel, core, state, measurement, book, t, gap):
        """A late, usable sample carried forward over ``gap`` (s) to this step, with the
        step's rate ``w_B = w_meas - bias_B_hat`` (the rate this step propagated with, the
        held one included, minus the estimate's bias): a quaternion ``q_IS ⊗ q_BS^-1 ⊗
        exp(w_B gap) ⊗ q_BS`` (:func:`~drake_att.systems.estimator_step.carried_quaternion`),
        vectors rotated by ``exp(-R_SB w_B gap)`` in the sensor frame. Its noise grows by
        :func:`~drake_att.systems.estimator_step.late_sample_variance` of the rate's error
        variance: the estimate's largest gyro-bias variance, plus ``q tau`` of the held-rate
        walk when the gyro is held (the gyro's white noise over the gap is left out)."""
        _, bias, P = core.estimate(state)
        w = np.asarray(book[Bookkeeping.W_LAST], dtype=float) - np.asarray(bias, dtype=float)
        rate_variance = float(np.max(np.diag(np.asarray(P))[3:6]))
        rate_variance += max(t - book[Bookkeeping.T_GYRO_GOOD], 0.0) * model.held_rate_rrw_rad_per_s15**2
        extra = rules.late_sample_variance(rate_variance, gap)
        wx, wy, wz = w.tolist()
        if isinstance(measurement, QuaternionSample):
            q = np.array(rules.carried_quaternion(measurement.q_IS_meas, measurement.q_BS, wx, wy, wz, gap))
            cov = np.asarray(measurement.covariance_S, dtype=float)
            cov = (cov if cov.shape == (3, 3) else np.diag(cov**2)) + extra * np.eye(3)
            return replace(measurement, time_s=t, q_IS_meas=q, covariance_S=cov)
        R_SB = rot.quat_to_rotmat(measurement.q_BS).T
        R_turn = rot.quat_to_rotmat(rot.rotvec_to_quat(-(R_SB @ w) * gap))  # the sensor's rotation over the gap
        directions = np.asarray(measurement.directions_S, dtype=float) @ R_turn.T
        sigma = math.sqrt(float(measurement.sigma_rad) ** 2 + extra)
        return replace(measurement, time_s=t, directions_S=directions, sigma_rad=sigma)

    @staticmethod
    def _update(
        model: FilterModel, state, measurement, book, rejections: int, rng, confirmed, handling, period_s: float
    ):
        """The core's update with one due, usable measurement, and the rules after a gate
        rejection: for a sample the sensor monitor ``confirmed``, by a
        :class:`~drake_att.contract.PredictionRecovery` core, the core's
        ``recover_prediction`` at once (counted in ``handling``) and one retry with its
        ``ungated()`` twin; otherwise, after
        :data:`~drake_att.filters.gating.REACQUIRE_AFTER_REJECTIONS` consecutive gate
        rejections of this input (count at ``book[rejections]``), the core's ``reacquire``
        and one retry with its ``ungated()`` twin."""
        core = model.core
        new_state, info = core.update(state, measurement, rng)
        if info.accepted:
            book[rejections] = 0.0
        elif is_gate_rejection(info.accepted, info.nis) and confirmed and model.capabilities.prediction_recovery:
            book[rejections] = 0.0
            handling[rules.N_RECOVERIES] += 1
            recovered = core.recover_prediction(state, measurement, info, period_s)
            new_state, info = core.ungated().update(recovered, measurement, rng)
        elif is_gate_rejection(info.accepted, info.nis) and model.capabilities.reacquisition:
            book[rejections] += 1.0
            if book[rejections] >= REACQUIRE_AFTER_REJECTIONS:
                book[rejections] = 0.0
                new_state, info = core.ungated().update(core.reacquire(state, info), measurement, rng)
        return new_state, info


def MekfEstimator(
    name: str, period_s: float, filter_core, initial_state, quaternion_sensors=(), vector_sensors=()
) -> EstimatorSystem:
    """An :class:`EstimatorSystem` running a :class:`~drake_att.filters.mekf.MultiplicativeEKF`.

    Ports as :class:`EstimatorSystem`, with ``bias_B_hat`` and ``step_linearization``.
    """
    return EstimatorSystem(name, period_s, filter_core, initial_state, quaternion_sensors, vector_sensors)
