"""The estimator contract, in code: estimate layout, measurement types, filter-core protocol.

Every estimator in the library (and a user's own) is a *filter core* — plain numpy, no
Drake — run by the one estimator system (:class:`drake_att.systems.estimator_system.EstimatorSystem`),
which owns the loop they all share. This module is the only definition of what flows
between them. It imports nothing from Drake and nothing from the rest of the library
(layer 1: math).

**Estimate layout.** Every estimator publishes the same packed vector
(:data:`ESTIMATE_SIZE` = 47), exposed as the ports ``q_IB_hat`` (4), the second 3-vector
(``bias_B_hat`` or ``w_IB_B_hat``, named by :class:`SecondQuantity`), ``covariance`` (36)
and ``status`` (4), and whole as ``estimate_state``:

==============  =======  ====================================================================
slice           size     content
==============  =======  ====================================================================
``Q_IB``        4        attitude estimate ``q_IB_hat`` (wxyz, scalar part >= 0)
``SECOND``      3        gyro bias ``b_B`` (rad/s) or body rate ``w_IB_B`` (rad/s)
``COVARIANCE``  36       row-major 6x6 covariance of ``[dtheta_B (rad); second error]``
``STATUS``      4        ``[t_estimate (s), used, skipped, last NIS]``
==============  =======  ====================================================================

``dtheta_B`` is the project's attitude error, ``q_IB = q_IB_hat ⊗ exp(dtheta_B)``.
``t_estimate`` is the time the estimate refers to (Drake publishes before the discrete
update of the same instant; the metrics score each estimate at ``t_estimate``).
``used``/``skipped`` count measurement updates applied and measurements skipped
(invalid, non-finite, missing gyro samples, gate rejections); ``last NIS`` is the
normalized innovation squared of the last update (NaN when the core has none).

**Measurements.** :class:`GyroSample`, :class:`QuaternionSample`,
:class:`VectorObservations` and :class:`CameraCentroids` (the indoor star tracker's
camera frames), each with its time and validity; :func:`is_usable` is the one validity rule
(flag true — a NaN flag is not true —, finite time, finite numbers).

**Filter-core protocol** (:class:`FilterCore`): pure functions of an explicit, immutable
state, in the style of :mod:`drake_att.filters.mekf` — ``predict`` returns the new state,
``update`` returns the new state and an :class:`UpdateInfo`. Cores keep no counters: the
system counts from ``UpdateInfo``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Protocol, TypeVar, runtime_checkable

import numpy as np

# ----------------------------------------------------------------------------------------
# Estimate layout
# ----------------------------------------------------------------------------------------
Q_IB = slice(0, 4)
SECOND = slice(4, 7)
COVARIANCE = slice(7, 43)
STATUS = slice(43, 47)
ESTIMATE_SIZE = 47
# Two times are one instant when they differ by less than this (s): a sample is used at the
# step whose time its tag matches, and scoring pairs logged signals by time the same way.
TIME_TOLERANCE_S = 1e-6
# Fields of the status block (indices into ``status``).
STATUS_T_ESTIMATE, STATUS_USED, STATUS_SKIPPED, STATUS_LAST_NIS = 0, 1, 2, 3
STATUS_SIZE = 4


class SecondQuantity(enum.Enum):
    """What an estimator's second 3-vector is; its value names the output port."""

    GYRO_BIAS = "bias_B_hat"
    BODY_RATE = "w_IB_B_hat"

    @property
    def port_name(self) -> str:
        return self.value

    @property
    def kind(self) -> str:
        """What scoring calls it: ``"gyro_bias"`` or ``"body_rate"`` (a run's metadata)."""
        return self.name.lower()

    def estimate_ports(self) -> tuple[tuple[str, slice], ...]:
        """The contract's output ports and their parts of the packed estimate, in order:
        ``q_IB_hat``, the second vector (this quantity's port), ``covariance``, ``status``."""
        return (("q_IB_hat", Q_IB), (self.port_name, SECOND), ("covariance", COVARIANCE), ("status", STATUS))

    @classmethod
    def from_port_name(cls, name: str) -> SecondQuantity:
        for member in cls:
            if member.value == name:
                return member
        raise ValueError(f"second output port: got {name!r}; allowed: {[m.value for m in cls]}")


@dataclass(frozen=True)
class Estimate:
    """One published estimate (see the module docstring for units and frames)."""

    q_IB: np.ndarray
    second: np.ndarray
    covariance: np.ndarray  # (6, 6)
    t_estimate: float
    used: int
    skipped: int
    last_nis: float

    def pack(self) -> np.ndarray:
        return pack_estimate(
            self.q_IB, self.second, self.covariance, self.t_estimate, self.used, self.skipped, self.last_nis
        )

    @classmethod
    def unpack(cls, vector) -> Estimate:
        v = np.asarray(vector, dtype=float)
        if v.shape[-1] != ESTIMATE_SIZE:
            raise ValueError(f"estimate vector: got size {v.shape[-1]}; need {ESTIMATE_SIZE}")
        s = v[STATUS]
        return cls(
            v[Q_IB].copy(),
            v[SECOND].copy(),
            v[COVARIANCE].reshape(6, 6).copy(),
            float(s[0]),
            int(s[1]),
            int(s[2]),
            float(s[3]),
        )


def pack_estimate(q, second, P, t, n_used, n_skipped, nis) -> np.ndarray:
    """The packed estimate vector (:data:`ESTIMATE_SIZE`)."""
    return np.concatenate([q, second, np.asarray(P).ravel(), [t, n_used, n_skipped, nis]])


# ----------------------------------------------------------------------------------------
# Measurements
# ----------------------------------------------------------------------------------------
GYRO_MEASUREMENT_SIZE = 5  # port vector [t, valid, w_meas_B (3)]
QUATERNION_MEASUREMENT_SIZE = 6  # port vector [t, valid, q_IS_meas (4)]


def flag_is_true(valid) -> bool:
    """A validity flag from a port: true only for a finite value > 0.5 (NaN is not true)."""
    v = float(valid)
    return v > 0.5 and math.isfinite(v)


@dataclass(frozen=True)
class GyroSample:
    """Mean body rate over the interval ending at ``time_s``: ``w_meas_B`` (3, rad/s)."""

    time_s: float
    valid: bool
    w_meas_B: np.ndarray

    @classmethod
    def from_port(cls, vector) -> GyroSample:
        return cls(float(vector[0]), flag_is_true(vector[1]), np.array(vector[2:5], dtype=float))


@dataclass(frozen=True)
class QuaternionSample:
    """A measured sensor attitude ``q_IS_meas`` with the sensor model the filter assumes.

    ``q_BS``: mounting (4); ``covariance_S``: (3, 3) rotation-vector noise in the sensor
    frame (rad^2).
    """

    time_s: float
    valid: bool
    q_IS_meas: np.ndarray
    q_BS: np.ndarray
    covariance_S: np.ndarray

    @property
    def numbers(self) -> np.ndarray:
        return self.q_IS_meas


@dataclass(frozen=True)
class VectorObservations:
    """Unit-vector observations of one star-tracker sample (abstract port value).

    Attributes:
        time_s: sample time (s).
        valid: False if the sample must not be used.
        directions_S: (m, 3) measured directions in the sensor frame.
        references_I: (m, 3) the matching inertial reference directions.
        sigma_rad: per-component noise 1-sigma (rad).
        q_BS: (4,) sensor mounting.
    """

    time_s: float
    valid: bool
    directions_S: np.ndarray
    references_I: np.ndarray
    sigma_rad: float
    q_BS: np.ndarray

    @property
    def numbers(self) -> np.ndarray:
        return np.asarray(self.directions_S, dtype=float)


def empty_vector_observations() -> VectorObservations:
    """The model value of a vector-observation port (invalid, no stars)."""
    return VectorObservations(0.0, False, np.zeros((0, 3)), np.zeros((0, 3)), 0.0, np.array([1.0, 0.0, 0.0, 0.0]))


@dataclass(frozen=True)
class CameraCentroids:
    """Star centroids on a camera's focal plane (the indoor star tracker, paper S2).

    Attributes:
        time_s: exposure time (s). valid: False if the frame must not be used.
        centroids_m: (m, 2) focal-plane centroids ``(X_c, Y_c)`` (m).
        focal_length_m: focal length (m). sigma_m: centroid noise 1-sigma (m).
        quantization_m: centroid quantization step (m; 0: none).
    """

    time_s: float
    valid: bool
    centroids_m: np.ndarray
    focal_length_m: float
    sigma_m: float
    quantization_m: float = 0.0

    @property
    def numbers(self) -> np.ndarray:
        return np.asarray(self.centroids_m, dtype=float)


def empty_camera_centroids() -> CameraCentroids:
    """The model value of a camera port (invalid, no stars)."""
    return CameraCentroids(0.0, False, np.zeros((0, 2)), 1.0, 0.0)


def quaternion_usable(w: float, x: float, y: float, z: float) -> bool:
    """A measured quaternion's numbers are finite and near unit norm (``|q| >= 0.5``; below
    that it is not a quaternion), its squared norm finite (numbers near 1e300 overflow it: not
    a quaternion either). A plain scalar function: the compiled MEKF step compiles this same
    rule."""
    if not (math.isfinite(w) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return False
    n2 = w * w + x * x + y * y + z * z  # products overflow to inf (a power of a float raises)
    return 0.25 <= n2 < math.inf


def is_usable(measurement) -> bool:
    """The one validity rule: flag true, finite time, at least one number, all finite.

    Vector observations must also pair each direction with a finite, non-zero reference and
    carry a finite, positive sigma; a quaternion must be near unit norm (> 0.5).
    """
    if not flag_is_true(measurement.valid):
        return False
    if not math.isfinite(float(measurement.time_s)):
        return False
    numbers = measurement.numbers
    if isinstance(measurement, QuaternionSample):  # the per-step case: 4 floats, no numpy reduction
        values = np.ravel(numbers).tolist()
        return len(values) == 4 and quaternion_usable(*values)
    if numbers.size == 0 or not np.all(np.isfinite(numbers)):
        return False
    if isinstance(measurement, VectorObservations):
        refs = np.asarray(measurement.references_I, dtype=float)
        sigma = float(measurement.sigma_rad)
        if numbers.shape != refs.shape or not (math.isfinite(sigma) and sigma > 0.0):
            return False
        if not np.all(np.isfinite(refs)) or np.any(np.linalg.norm(refs, axis=-1) < 1e-9):
            return False  # a reference direction must be a finite, non-zero vector
    if isinstance(measurement, CameraCentroids):
        f, sigma, q = (float(measurement.focal_length_m), float(measurement.sigma_m), float(measurement.quantization_m))
        if numbers.ndim != 2 or numbers.shape[1] != 2 or not (math.isfinite(f) and f > 0.0):
            return False
        if not (math.isfinite(sigma) and sigma >= 0.0 and math.isfinite(q) and q >= 0.0):
            return False
    return True


# ----------------------------------------------------------------------------------------
# Update diagnostics and the core protocol
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class UpdateInfo:
    """Diagnostics of one measurement update.

    Attributes:
        innovation, innovation_covariance: the residual and its predicted covariance
            (None for cores without one, e.g. particle filters).
        nis: normalized innovation squared (NaN when undefined).
        accepted: False if the core rejected the measurement (gate, singular S); the
            system counts it as skipped.
        error_transition: ``I - K H`` of an accepted Kalman update (6x6), for estimators
            that publish their step linearization.
        effective_sample_size: particle filters: ``N_eff`` after the update, before any
            resampling (NaN otherwise).
        resampled: particle filters: the update resampled the set.
        degenerate: particle filters: every weight underflowed (reset to uniform).
    """

    innovation: np.ndarray | None
    innovation_covariance: np.ndarray | None
    nis: float
    accepted: bool
    error_transition: np.ndarray | None = None
    effective_sample_size: float = float("nan")
    resampled: bool = False
    degenerate: bool = False


StateT = TypeVar("StateT")
StateT_co = TypeVar("StateT_co", covariant=True)  # a capability that only returns states
StateT_contra = TypeVar("StateT_contra", contravariant=True)  # a capability that only reads them


@runtime_checkable
class FilterCore(Protocol[StateT]):
    """What the estimator system needs from every filter core (all plain numpy), generic in
    the core's frozen state type.

    Attributes:
        second_quantity: what the second 3-vector of the estimate is.
        uses_gyro: the system feeds ``predict`` the gyro's mean rate (else None).
        is_random: the core draws random numbers; the system passes a generator that is a
            pure function of (diagram seed, system name, step index).
        state_size: length of ``to_vector(state)`` (the Context's discrete-state group).

    Optional capabilities are the protocols below; :class:`CoreCapabilities` reads them.
    """

    second_quantity: SecondQuantity
    uses_gyro: bool
    is_random: bool
    state_size: int

    def predict(self, state: StateT, w_meas_B: np.ndarray | None, dt: float, rng: np.random.Generator | None) -> StateT:
        """The state propagated over ``dt`` (s) (``w_meas_B``: mean gyro rate, rad/s)."""

    def update(self, state: StateT, measurement, rng: np.random.Generator | None) -> tuple[StateT, UpdateInfo]:
        """The state updated with one usable measurement, and what happened."""

    def estimate(self, state: StateT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q_IB_hat (4), second (3), covariance (6, 6))`` of the state."""

    def to_vector(self, state: StateT) -> np.ndarray:
        """The state as a flat vector (stored in the Context)."""

    def from_vector(self, vector: np.ndarray) -> StateT:
        """Inverse of :meth:`to_vector`."""


@runtime_checkable
class LinearizedPrediction(Protocol[StateT]):
    """A core that publishes its step linearization (``step_linearization``, used by the
    tracked decentralized fusion). Its updates report ``UpdateInfo.error_transition``."""

    def predict_linearized(
        self, state: StateT, w_meas_B: np.ndarray | None, dt: float
    ) -> tuple[StateT, np.ndarray, np.ndarray]:
        """``(predicted state, Phi (6, 6), Q (6, 6))``: the prediction and its error map."""


@runtime_checkable
class Reacquisition(Protocol[StateT]):
    """A gated core the system re-acquires after repeated gate rejections: it calls
    ``reacquire`` and retries the measurement once with ``ungated()``."""

    def reacquire(self, state: StateT, info: UpdateInfo) -> StateT:
        """The state with its attitude covariance inflated for the rejected innovation."""

    def ungated(self) -> FilterCore[StateT]:
        """The same core with its innovation gate off."""


@runtime_checkable
class PredictionRecovery(Protocol[StateT]):
    """A gated core the system recovers when the gate rejects a sample the sensor monitor
    confirmed (consistent with another independent sensor): the prediction, not the sample, is
    wrong (a gyro fault, a bias jump). The system calls ``recover_prediction`` and retries the
    measurement once with ``ungated()``."""

    def recover_prediction(self, state: StateT, measurement, info: UpdateInfo, period_s: float) -> StateT:
        """The state with the covariance widened for the rejected innovation ``info`` of
        ``measurement``: enough attitude uncertainty to take it, and the rate (bias)
        uncertainty that explains it over one filter step ``period_s`` (s)."""

    def ungated(self) -> FilterCore[StateT]:
        """The same core with its innovation gate off."""


@runtime_checkable
class AttitudeProcessNoise(Protocol[StateT]):
    """A core whose covariance can take extra attitude process noise: the system adds the
    drift of a held gyro rate (``held_rate_rrw_deg_per_s15``)."""

    def add_attitude_variance(self, state: StateT, variance_rad2: float) -> StateT:
        """The state with ``variance_rad2`` (rad^2) added to each attitude variance (its
        covariance's attitude block plus ``variance_rad2 I``)."""


@runtime_checkable
class RandomInitialState(Protocol[StateT_co]):
    """A random core whose initial state is drawn at initialization with generator 0."""

    def draw_initial_state(self, rng: np.random.Generator) -> StateT_co:
        """A draw of the initial state (e.g. a particle set)."""


@runtime_checkable
class ParticleSet(Protocol):
    """A particle core: the system publishes ``particle_diagnostics`` (``N_eff``,
    resamplings, degenerate updates, ``N``) from its ``UpdateInfo``."""

    num_particles: int


@runtime_checkable
class CoreDiagnostics(Protocol[StateT_contra]):
    """A core with named diagnostics, published on ``diagnostics`` and logged."""

    diagnostic_names: tuple[str, ...]

    def diagnostics(self, state: StateT_contra) -> np.ndarray:
        """One number per name of ``diagnostic_names``."""


@dataclass(frozen=True)
class CoreCapabilities:
    """Which optional capabilities a core has (read once, when its system is built).

    Attributes:
        linearized_prediction: :class:`LinearizedPrediction`.
        reacquisition: :class:`Reacquisition`.
        random_initial_state: :class:`RandomInitialState` (only read for ``is_random`` cores).
        num_particles: :class:`ParticleSet`'s ``N`` (None: not a particle core).
        diagnostic_names: :class:`CoreDiagnostics`' names (empty: none).
        prediction_recovery: :class:`PredictionRecovery`.
        attitude_process_noise: :class:`AttitudeProcessNoise`.
    """

    linearized_prediction: bool = False
    reacquisition: bool = False
    random_initial_state: bool = False
    num_particles: int | None = None
    diagnostic_names: tuple[str, ...] = ()
    prediction_recovery: bool = False
    attitude_process_noise: bool = False

    @classmethod
    def of(cls, core) -> CoreCapabilities:
        """The capabilities of ``core``.

        Raises:
            TypeError: a core with half a capability (``reacquire`` without ``ungated``,
                ``diagnostic_names`` without ``diagnostics``), naming what is missing.
        """
        name = type(core).__name__
        for half, whole, protocol in (
            ("reacquire", "ungated", Reacquisition),
            ("diagnostic_names", "diagnostics", CoreDiagnostics),
            ("recover_prediction", "ungated", PredictionRecovery),
        ):
            if hasattr(core, half) and not isinstance(core, protocol):
                raise TypeError(
                    f"core {name} has {half!r} but not {whole!r}: drake_att.contract.{protocol.__name__} needs both"
                )
        return cls(
            linearized_prediction=isinstance(core, LinearizedPrediction),
            reacquisition=isinstance(core, Reacquisition),
            random_initial_state=isinstance(core, RandomInitialState),
            num_particles=core.num_particles if isinstance(core, ParticleSet) else None,
            diagnostic_names=tuple(core.diagnostic_names) if isinstance(core, CoreDiagnostics) else (),
            prediction_recovery=isinstance(core, PredictionRecovery),
            attitude_process_noise=isinstance(core, AttitudeProcessNoise),
        )


__all__ = [
    "Q_IB",
    "SECOND",
    "COVARIANCE",
    "STATUS",
    "ESTIMATE_SIZE",
    "STATUS_SIZE",
    "TIME_TOLERANCE_S",
    "STATUS_T_ESTIMATE",
    "STATUS_USED",
    "STATUS_SKIPPED",
    "STATUS_LAST_NIS",
    "GYRO_MEASUREMENT_SIZE",
    "QUATERNION_MEASUREMENT_SIZE",
    "SecondQuantity",
    "Estimate",
    "pack_estimate",
    "flag_is_true",
    "GyroSample",
    "QuaternionSample",
    "VectorObservations",
    "empty_vector_observations",
    "CameraCentroids",
    "empty_camera_centroids",
    "quaternion_usable",
    "is_usable",
    "UpdateInfo",
    "FilterCore",
    "LinearizedPrediction",
    "Reacquisition",
    "PredictionRecovery",
    "AttitudeProcessNoise",
    "RandomInitialState",
    "ParticleSet",
    "CoreDiagnostics",
    "CoreCapabilities",
]
