"""Paper S0's estimators as Drake systems: MRP EKF, bootstrap PF, EKPF and gyroless PF.

Each system is a thin wrapper around a numpy filter core
(:class:`~drake_att.filters.mrp_ekf.MrpEkf`,
:class:`~drake_att.filters.particle.BootstrapParticleFilter`,
:class:`~drake_att.filters.particle.ExtendedKalmanParticleFilter`,
:class:`~drake_att.filters.particle.GyrolessParticleFilter`) and follows the estimator
contract of :mod:`drake_att.systems.estimators` (outputs ``q_IB_hat``, ``bias_B_hat`` or
``w_IB_B_hat``, ``covariance``, ``status``; one periodic discrete update per filter step;
a measurement is used only at its own sample time, at most once; invalid or non-finite
samples are skipped and counted).

**Everything the filter knows lives in the Context.**  The filter's numbers (EKF mean and
covariance, or the particle set with its weights and, for the EKPF, the per-particle
covariances) are a discrete-state group; nothing is kept on the Python object, so one
diagram can be re-run with fresh contexts (Monte Carlo).  Each step maps state -> core
(a shallow copy of a template core whose arrays are replaced, see ``_load_core``), runs
``predict``/``update`` and maps core -> state.

**Randomness.**  The particle filters declare the random input port ``seed_uniform``
(:func:`drake_att.systems.randomness.declare_seed_port`).  An initialization event copies
the seed words into the state and draws the initial particle set with generator index 0
of :func:`~drake_att.systems.randomness.counter_random` ``(seed words, system name)``;
filter step ``k`` (k = 1, 2, ... in order of the periodic events) uses generator index
``k`` for all of its draws (process noise, proposal draws, resampling).  So every number
is a pure function of the diagram's ``RandomGenerator`` seed, the system's name and the
step index: the same seed reproduces a run bit for bit.

**Star-sensor frame.**  The S0 cores assume sensor frame = body frame.  The systems rotate
the measured directions into the body frame, ``y_B = R_BS y_S``; with the isotropic
vector noise of the vector-mode star tracker this is exact for any mounting.

Units: SI and radians (rad, rad/s; ARW rad/s^0.5; RRW / roughening / rate process noise
rad/s^1.5; inertia kg m^2; torque N m).
"""

from __future__ import annotations

import copy

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus

from drake_att import rotations as rot
from drake_att.filters.mrp_ekf import MrpEkf
from drake_att.filters.particle import (
    BootstrapParticleFilter,
    ExtendedKalmanParticleFilter,
    GyrolessParticleFilter,
)
from drake_att.systems.estimators import TIME_TOLERANCE_S, AttitudeEstimatorSystem, pack_estimate
from drake_att.systems.gyro import GYRO_MEASUREMENT_SIZE
from drake_att.systems.randomness import SEED_WORDS, counter_random, declare_seed_port, read_seed_words
from drake_att.systems.star_tracker import VectorObservations

__all__ = [
    "MrpEkfEstimator",
    "BootstrapPfEstimator",
    "EkpfEstimator",
    "GyrolessPfEstimator",
    "PARTICLE_DIAGNOSTICS_SIZE",
]

# Internal bookkeeping group (every S0 system):
_T_LAST, _W_LAST, _T_VEC, _STEP = 0, slice(1, 4), 4, 5
_SEED = slice(6, 6 + SEED_WORDS)
_N_RESAMPLES, _ESS, _N_DEGENERATE = 6 + SEED_WORDS, 7 + SEED_WORDS, 8 + SEED_WORDS
INTERNAL_SIZE = 9 + SEED_WORDS
PARTICLE_DIAGNOSTICS_SIZE = 4


def _empty_observations():
    return VectorObservations(0.0, False, np.zeros((0, 3)), np.zeros((0, 3)), 0.0,
                              np.array([1.0, 0.0, 0.0, 0.0]))


class _S0Estimator(AttitudeEstimatorSystem):
    """Shared ports, bookkeeping and step logic of the S0 estimator systems.

    Subclasses define the filter group (``_initial_filter_state``), the
    core mapping (``_load_core``, ``_store_core``) and the calls ``_predict``/``_update``.
    """

    uses_gyro = True
    is_random = False

    def __init__(self, name, period_s, second_output_name, initial_estimate, star_tracker: str):
        super().__init__(name, period_s, second_output_name, initial_estimate)
        self.star_tracker_name = star_tracker
        self._gyro_port = (self.DeclareVectorInputPort("gyro_measurement", GYRO_MEASUREMENT_SIZE)
                           if self.uses_gyro else None)
        self._vector_port = self.DeclareAbstractInputPort(
            f"vectors_{star_tracker}", AbstractValue.Make(_empty_observations()))
        self._seed_port = declare_seed_port(self) if self.is_random else None
        internal = np.zeros(INTERNAL_SIZE)
        internal[_T_LAST] = -np.inf
        internal[_T_VEC] = -np.inf
        internal[_ESS] = np.nan
        self._internal_group = self.DeclareDiscreteState(internal)
        self._filter_group = self.DeclareDiscreteState(np.asarray(self._initial_filter_state(), dtype=float))
        if self.is_random:
            self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
            self.DeclareVectorOutputPort(
                "particle_diagnostics", PARTICLE_DIAGNOSTICS_SIZE, self._calc_diagnostics,
                {self.discrete_state_ticket(self._internal_group)})
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_step)

    # -- subclass interface ---------------------------------------------------------
    def _initial_filter_state(self) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _load_core(self, filter_state: np.ndarray, internal: np.ndarray):  # pragma: no cover
        raise NotImplementedError

    def _store_core(self, core) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _predict(self, core, dt, w_meas, rng):  # pragma: no cover - abstract
        raise NotImplementedError

    def _update(self, core, y, refs, sigma, rng):  # pragma: no cover - abstract
        """Returns ``(used, nis)``."""
        raise NotImplementedError

    # -- events -----------------------------------------------------------------------
    def _initialize(self, context, discrete_state):
        """Random systems: store the seed words, draw the initial particle set (index 0)."""
        words = read_seed_words(self, context, self._seed_port)
        internal = context.get_discrete_state(self._internal_group).value().copy()
        internal[_SEED] = words
        internal[_STEP] = 0.0
        rng = counter_random(words, self.get_name()).generator(0)
        core = self._draw_initial_core(rng)
        internal[_ESS] = float(core.num_particles)
        discrete_state.get_mutable_vector(self._internal_group).SetFromVector(internal)
        discrete_state.get_mutable_vector(self._filter_group).SetFromVector(self._store_core(core))
        return EventStatus.Succeeded()

    def _draw_initial_core(self, rng):  # pragma: no cover - random subclasses override
        raise NotImplementedError

    def _gyro_rate(self, context, t):
        """The gyro's rate for the interval ending at ``t``, or None if missing/invalid."""
        if self._gyro_port is None or not self._gyro_port.HasValue(context):
            return None
        g = self._gyro_port.Eval(context)
        if abs(g[0] - t) < TIME_TOLERANCE_S and g[1] > 0.5 and np.all(np.isfinite(g[2:])):
            return np.array(g[2:])
        return None

    def _on_step(self, context, discrete_state):
        t = context.get_time()
        est = self.estimate_vector(context)
        internal = context.get_discrete_state(self._internal_group).value().copy()
        core = self._load_core(context.get_discrete_state(self._filter_group).value(), internal)
        n_used, n_skipped, nis = est[44], est[45], est[46]
        rng = None
        if self.is_random:
            internal[_STEP] += 1.0
            rng = counter_random(internal[_SEED], self.get_name()).generator(int(internal[_STEP]))

        # -- time update over (t_last, t] -----------------------------------------------
        t_last = internal[_T_LAST]
        if np.isfinite(t_last):
            w_meas = None
            if self.uses_gyro:
                w_meas = self._gyro_rate(context, t)
                if w_meas is None:
                    n_skipped += 1
                    w_meas = internal[_W_LAST].copy()
                else:
                    internal[_W_LAST] = w_meas
            self._predict(core, t - t_last, w_meas, rng)
        elif self.uses_gyro and self._gyro_port.HasValue(context):
            g = self._gyro_port.Eval(context)
            if g[1] > 0.5 and np.all(np.isfinite(g[2:])):
                internal[_W_LAST] = g[2:]
        internal[_T_LAST] = t

        # -- star-sensor update at this instant --------------------------------------------
        if self._vector_port.HasValue(context):
            obs = self._vector_port.Eval(context)
            if abs(obs.time_s - t) < TIME_TOLERANCE_S and obs.time_s > internal[_T_VEC]:
                internal[_T_VEC] = obs.time_s
                dirs = np.asarray(obs.directions_S, dtype=float)
                refs = np.asarray(obs.references_I, dtype=float)
                sigma = float(obs.sigma_rad)
                if (not obs.valid or dirs.size == 0 or dirs.shape != refs.shape
                        or not np.all(np.isfinite(dirs)) or not (np.isfinite(sigma) and sigma > 0)):
                    n_skipped += 1
                else:
                    R_BS = rot.quat_to_rotmat(np.asarray(obs.q_BS, dtype=float))
                    y_B = (dirs @ R_BS.T).ravel()
                    used, step_nis = self._update(core, y_B, refs, sigma, rng)
                    if used:
                        n_used += 1
                        nis = step_nis
                    else:
                        n_skipped += 1

        q_hat, second, P = self._estimate(core)
        if self.is_random:
            internal[_N_RESAMPLES] = core.n_resamples
            internal[_ESS] = core.last_effective_sample_size
            internal[_N_DEGENERATE] = core.n_degenerate
        discrete_state.get_mutable_vector(self._estimate_group).SetFromVector(
            pack_estimate(rot.quat_canonical(q_hat), second, P, t, n_used, n_skipped, nis))
        discrete_state.get_mutable_vector(self._internal_group).SetFromVector(internal)
        discrete_state.get_mutable_vector(self._filter_group).SetFromVector(self._store_core(core))
        return EventStatus.Succeeded()

    def _estimate(self, core):
        q_hat, second = core.mean()
        return q_hat, second, core.covariance()

    def _calc_diagnostics(self, context, output: BasicVector):
        internal = context.get_discrete_state(self._internal_group).value()
        output.SetFromVector([internal[_ESS], internal[_N_RESAMPLES], internal[_N_DEGENERATE],
                              float(self.num_particles)])

    # -- helpers for tests / notebooks ----------------------------------------------------
    def filter_state(self, context) -> np.ndarray:
        """The filter's discrete-state group (copy; layout documented per class)."""
        return context.get_discrete_state(self._filter_group).value().copy()


def _covariance0(covariance0) -> np.ndarray:
    P0 = np.asarray(covariance0, dtype=float)
    if P0.shape == (6,):
        P0 = np.diag(P0)
    return P0


# --------------------------------------------------------------------------------------
# MRP EKF
# --------------------------------------------------------------------------------------
class MrpEkfEstimator(_S0Estimator):
    """Paper S0's additive EKF on ``x = [rho; b]`` (:class:`~drake_att.filters.mrp_ekf.MrpEkf`).

    Args:
        name: system name.
        period_s: filter step (s); must equal the gyro period (the gyro delivers the mean
            rate over one step) and be a multiple of the star tracker's period.
        star_tracker: name of the vector-mode star tracker (names the input port).
        q_IB_hat0: initial attitude estimate (4, wxyz).
        bias_hat0: initial bias estimate (3, rad/s).
        covariance0: (6, 6) (or its diagonal (6,)) covariance of
            ``[dtheta_B (rad); b (rad/s)]``.
        arw_sigma: gyro ARW (rad/s^0.5) > 0.
        rrw_sigma: gyro RRW (rad/s^1.5) >= 0.
        update_iterations: linearizations per update (1 = paper's EKF; > 1 iterated EKF).

    Input ports:
        gyro_measurement (5): ``[t, valid, w_meas_B (3, rad/s)]``.
        vectors_<star_tracker> (abstract :class:`VectorObservations`).
    Output ports: the estimator contract with ``bias_B_hat``; ``status[3]`` is the NIS of
        the last used update (6 dof for two vectors).
    Discrete state: group 0 estimate (47); group 1 bookkeeping (13: ``[t_last, last valid
        gyro rate (3), time of last used star sample, step index, seed words (4) unused,
        unused (3)]``); group 2 filter ``[x = [rho; b] (6), P (36, MRP chart, row-major)]``.
    """

    def __init__(self, name: str, period_s: float, star_tracker: str, q_IB_hat0, bias_hat0, covariance0,
                 arw_sigma: float, rrw_sigma: float, update_iterations: int = 1):
        self._template = MrpEkf(q_IB_hat0, bias_hat0, _covariance0(covariance0), arw_sigma, rrw_sigma,
                                update_iterations)
        init = pack_estimate(self._template.q_IB_hat, self._template.bias_hat, self._template.covariance(),
                             0.0, 0, 0, np.nan)
        super().__init__(name, period_s, "bias_B_hat", init, star_tracker)

    def _initial_filter_state(self):
        return np.concatenate([self._template.x, self._template.P.ravel()])

    def _load_core(self, s, internal):
        core = copy.copy(self._template)
        core.x = np.array(s[:6])
        core.P = np.array(s[6:42]).reshape(6, 6)
        return core

    def _store_core(self, core):
        return np.concatenate([core.x, core.P.ravel()])

    def _predict(self, core, dt, w_meas, rng):
        core.predict(dt, w_meas)

    def _update(self, core, y, refs, sigma, rng):
        used = core.update(y, refs, sigma)
        if not used:
            return False, np.nan
        v, S = core.last_innovation, core.last_innovation_covariance
        return True, float(v @ np.linalg.solve(S, v))

    def _estimate(self, core):
        return core.q_IB_hat, core.bias_hat, core.covariance()


# --------------------------------------------------------------------------------------
# Particle filters
# --------------------------------------------------------------------------------------
class _ParticleEstimator(_S0Estimator):
    """Particle-set <-> state mapping shared by the three particle filters.

    Filter group layout: ``[particles (N*6, row-major [rho; s] per particle),
    weights (N), log weights (N), (EKPF only) covariances (N*36, MRP chart)]``.
    """

    is_random = True
    has_covariances = False

    def _setup(self, name, period_s, star_tracker, second_output_name, q_IB_hat0, second0, covariance0,
               core_args, core_kwargs):
        """Shared constructor: keep the core's arguments, draw a template core (fixed numpy
        seed; replaced from the diagram's seed at initialization) and declare the system."""
        self._args, self._kwargs = core_args, core_kwargs
        self._template = self._draw_initial_core(np.random.default_rng(0))
        self.num_particles = self._template.num_particles
        q0 = rot.quat_canonical(rot.quat_normalize(np.asarray(q_IB_hat0, float)))
        _S0Estimator.__init__(self, name, period_s, second_output_name,
                              pack_estimate(q0, second0, _covariance0(covariance0), 0.0, 0, 0, np.nan), star_tracker)

    def _initial_filter_state(self):
        # Default value only: the initialization event replaces it with the set drawn
        # from the diagram's seed (this one is drawn with a fixed numpy seed 0 and is used
        # only if the system is stepped without Simulator.Initialize()).
        return self._store_core(self._template)

    def _load_core(self, s, internal):
        n = self.num_particles
        core = copy.copy(self._template)
        core.particles = np.array(s[:6 * n]).reshape(n, 6)
        core.weights = np.array(s[6 * n:7 * n])
        core.log_weights = np.array(s[7 * n:8 * n])
        if self.has_covariances:
            core.covariances = np.array(s[8 * n:]).reshape(n, 6, 6)
        core.n_resamples = int(internal[_N_RESAMPLES])
        core.n_degenerate = int(internal[_N_DEGENERATE])
        core.n_skipped = 0
        core.n_updates = 0
        core._estimate_set = None
        core.last_effective_sample_size = float(internal[_ESS])
        return core

    def _store_core(self, core):
        parts = [core.particles.ravel(), core.weights, core.log_weights]
        if self.has_covariances:
            parts.append(core.covariances.ravel())
        return np.concatenate(parts)

    def _update(self, core, y, refs, sigma, rng):
        return core.update(y, refs, sigma, rng), np.nan


_PF_PORTS_DOC = """
    Input ports:
        {gyro}vectors_<star_tracker> (abstract :class:`VectorObservations`).
        seed_uniform (4, random uniform): seed (``drake_att.systems.randomness``).
    Output ports: the estimator contract with ``{second}`` (``covariance`` = the weighted
        particle covariance of ``[dtheta_B; {second_short} error]`` about the reported
        mean; ``status[3]`` = NaN: a particle filter has no innovation covariance), plus
        particle_diagnostics (4): ``[effective sample size after the last update (before
        resampling), resamplings so far, degenerate updates so far, N]``.
    Discrete state: group 0 estimate (47); group 1 bookkeeping (13: ``[t_last, last valid
        gyro rate (3), time of last used star sample, step index, seed words (4),
        resamplings, last N_eff, degenerate updates]``); group 2 the particle set
        ``[particles (N*6), weights (N), log weights (N){cov}]``.
"""


class BootstrapPfEstimator(_ParticleEstimator):
    """Paper S0's bootstrap (SIR) PF in gyro mode (:class:`~drake_att.filters.particle.BootstrapParticleFilter`).

    Args:
        name: system name (also the random stream name).
        period_s: filter step (s) = the gyro period.
        star_tracker: name of the vector-mode star tracker.
        num_particles: N >= 1.
        q_IB_hat0, bias_hat0, covariance0: initial estimate (wxyz; rad/s) and the (6, 6)
            (or diagonal (6,)) covariance of ``[dtheta_B (rad); b (rad/s)]`` the initial
            particles are drawn from.
        arw_sigma: attitude process noise of the particles, as an ARW (rad/s^0.5) >= 0.
        bias_roughening_sigma: bias random-walk roughening (rad/s^1.5) >= 0; 0 = paper.
        resample_threshold: resample when ``N_eff < threshold * N`` (paper 2/3).
    """ + _PF_PORTS_DOC.format(gyro="gyro_measurement (5): ``[t, valid, w_meas_B (3, rad/s)]``.\n        ",
                               second="bias_B_hat", second_short="bias", cov="")

    def __init__(self, name: str, period_s: float, star_tracker: str, num_particles: int, q_IB_hat0, bias_hat0,
                 covariance0, arw_sigma: float, bias_roughening_sigma: float = 0.0,
                 resample_threshold: float = 2.0 / 3.0):
        self._setup(name, period_s, star_tracker, "bias_B_hat", q_IB_hat0, bias_hat0, covariance0,
                    (num_particles, q_IB_hat0, bias_hat0, _covariance0(covariance0), arw_sigma),
                    dict(bias_roughening_sigma=bias_roughening_sigma, resample_threshold=resample_threshold))

    def _draw_initial_core(self, rng):
        return BootstrapParticleFilter(*self._args, rng, **self._kwargs)

    def _predict(self, core, dt, w_meas, rng):
        core.predict(dt, w_meas, rng)


class EkpfEstimator(_ParticleEstimator):
    """Paper S0's extended-Kalman particle filter (:class:`~drake_att.filters.particle.ExtendedKalmanParticleFilter`).

    Args:
        name: system name (also the random stream name).
        period_s: filter step (s) = the gyro period.
        star_tracker: name of the vector-mode star tracker.
        num_particles: N >= 1.
        q_IB_hat0, bias_hat0, covariance0: initial estimate and covariance (as
            :class:`BootstrapPfEstimator`); ``covariance0`` is also every particle's
            initial EKF covariance.
        arw_sigma: gyro ARW (rad/s^0.5) > 0. rrw_sigma: gyro RRW (rad/s^1.5) >= 0.
        proposal_iterations: linearizations of each particle's EKF update (1 = paper;
            > 1 iterated-EKF proposal, beyond the paper).
        resample_threshold: resample when ``N_eff < threshold * N`` (paper 2/3).
    """ + _PF_PORTS_DOC.format(gyro="gyro_measurement (5): ``[t, valid, w_meas_B (3, rad/s)]``.\n        ",
                               second="bias_B_hat", second_short="bias",
                               cov=", per-particle EKF covariances (N*36, MRP chart)")

    has_covariances = True

    def __init__(self, name: str, period_s: float, star_tracker: str, num_particles: int, q_IB_hat0, bias_hat0,
                 covariance0, arw_sigma: float, rrw_sigma: float, proposal_iterations: int = 1,
                 resample_threshold: float = 2.0 / 3.0):
        self._setup(name, period_s, star_tracker, "bias_B_hat", q_IB_hat0, bias_hat0, covariance0,
                    (num_particles, q_IB_hat0, bias_hat0, _covariance0(covariance0), arw_sigma, rrw_sigma),
                    dict(proposal_iterations=proposal_iterations, resample_threshold=resample_threshold))

    def _draw_initial_core(self, rng):
        return ExtendedKalmanParticleFilter(*self._args, rng, **self._kwargs)

    def _predict(self, core, dt, w_meas, rng):
        core.predict(dt, w_meas)


class GyrolessPfEstimator(_ParticleEstimator):
    """Paper S0's gyroless bootstrap PF on ``[rho; w]`` (:class:`~drake_att.filters.particle.GyrolessParticleFilter`).

    Propagates every particle with Euler's equations (known inertia and torque), no gyro.

    Args:
        name: system name (also the random stream name).
        period_s: filter step (s), a multiple of the star tracker's period.
        star_tracker: name of the vector-mode star tracker.
        num_particles: N >= 1.
        q_IB_hat0: initial attitude estimate (wxyz). w_hat0: initial rate estimate
            ``w_IB_B`` (3, rad/s).
        covariance0: (6, 6) or (6,) covariance of ``[dtheta_B (rad); w (rad/s)]``.
        inertia: (3, 3) or principal moments (3,) (kg m^2).
        torque: known body torque (3, N m).
        rate_process_sigma: rate process-noise density (rad/s^1.5) >= 0.
        attitude_process_sigma: attitude process-noise density (rad/s^0.5) >= 0.
        num_substeps: RK4 substeps per step >= 1.
        resample_threshold: resample when ``N_eff < threshold * N`` (paper 2/3).
    """ + _PF_PORTS_DOC.format(gyro="", second="w_IB_B_hat", second_short="rate", cov="")

    uses_gyro = False

    def __init__(self, name: str, period_s: float, star_tracker: str, num_particles: int, q_IB_hat0, w_hat0,
                 covariance0, inertia, torque, rate_process_sigma: float, attitude_process_sigma: float = 0.0,
                 num_substeps: int = 1, resample_threshold: float = 2.0 / 3.0):
        I = np.asarray(inertia, dtype=float)
        if I.shape == (3,):
            I = np.diag(I)
        self._setup(name, period_s, star_tracker, "w_IB_B_hat", q_IB_hat0, w_hat0, covariance0,
                    (num_particles, q_IB_hat0, w_hat0, _covariance0(covariance0), I, torque, rate_process_sigma),
                    dict(attitude_process_sigma=attitude_process_sigma, num_substeps=num_substeps,
                         resample_threshold=resample_threshold))

    def _draw_initial_core(self, rng):
        return GyrolessParticleFilter(*self._args, rng, **self._kwargs)

    def _predict(self, core, dt, w_meas, rng):
        core.predict(dt, rng)
