"""Setups and systems of the estimators fed by one vector-mode star tracker (paper S0's):
MRP EKF, bootstrap PF, EKPF and gyroless PF.

``*_setup`` functions return the :class:`~drake_att.systems.estimator_system.EstimatorSetup` (core,
initial state, sensors) that the estimator plug-ins build from a config; the ``*Estimator``
constructor functions wrap the same setup in a system for direct use (tests, notebooks).
Each system is the one :class:`~drake_att.systems.estimator_system.EstimatorSystem` running a numpy filter core
(:class:`~drake_att.filters.mrp_ekf.MrpEkfCore`,
:class:`~drake_att.filters.particle.BootstrapPfCore`,
:class:`~drake_att.filters.particle.EkpfCore`,
:class:`~drake_att.filters.particle.GyrolessPfCore`) and follows the estimator
contract of :mod:`drake_att.systems.estimator_system` (outputs ``q_IB_hat``, ``bias_B_hat`` or
``w_IB_B_hat``, ``covariance``, ``status``; one periodic discrete update per filter step;
a measurement is used at its own sample time (or, within the estimator's time-tag lag,
carried forward to the step), at most once; invalid, non-finite or mis-tagged samples are
skipped and counted).

**Everything the filter knows lives in the Context.**  The filter's numbers (EKF mean and
covariance, or the particle set with its weights and, for the EKPF, the per-particle
covariances) are a discrete-state group; nothing is kept on the Python object, so one
diagram can be re-run with fresh contexts (Monte Carlo). A particle setup's initial state
(the value before the initialization event draws one from the seed) is the draw of
``numpy.random.default_rng(0)``.

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

import numpy as np

from drake_att.filters.mrp_ekf import MrpEkfCore
from drake_att.filters.particle import (
    BootstrapPfCore,
    EffectiveSampleSizeGate,
    EkpfCore,
    GyrolessPfCore,
    RandomWalkRoughening,
)
from drake_att.systems.estimator_system import PARTICLE_DIAGNOSTICS_SIZE, EstimatorSetup, EstimatorSystem
from drake_att.validation import check_positive

__all__ = [
    "vector_inputs",
    "mrp_ekf_setup",
    "bootstrap_pf_setup",
    "ekpf_setup",
    "gyroless_pf_setup",
    "MrpEkfEstimator",
    "BootstrapPfEstimator",
    "EkpfEstimator",
    "GyrolessPfEstimator",
    "PARTICLE_DIAGNOSTICS_SIZE",
]


def vector_inputs(star_tracker: str, vector_sensors=()) -> tuple:
    """The vector-observation sensors a filter reads, in update order: ``star_tracker`` (``""``:
    none), then ``vector_sensors`` (e.g. a sun sensor and a magnetometer), each a
    :class:`~drake_att.contract.VectorObservations` input updated on sequentially at the same step."""
    return ((star_tracker,) if star_tracker else ()) + tuple(vector_sensors)


def _covariance0(covariance0) -> np.ndarray:
    P0 = np.asarray(covariance0, dtype=float)
    if P0.shape == (6,):
        P0 = np.diag(P0)
    return P0


def mrp_ekf_setup(
    period_s: float,
    star_tracker: str,
    q_IB_hat0,
    bias_hat0,
    covariance0,
    arw_rad_per_rt_s: float,
    rrw_rad_per_s15: float,
    update_iterations: int = 1,
    gyro: str | None = None,
    innovation_gate=None,
    vector_sensors=(),
) -> EstimatorSetup:
    """The setup of :func:`MrpEkfEstimator` (same arguments; ``gyro``: the gyro's name;
    ``innovation_gate``: a chi2 threshold or an InnovationGate, None: none; ``vector_sensors``:
    further vector-observation sensors after ``star_tracker`` (``""``: none), :func:`vector_inputs`)."""
    core = MrpEkfCore(arw_rad_per_rt_s, rrw_rad_per_s15, update_iterations, innovation_gate)
    return EstimatorSetup(
        core,
        core.initial_state(q_IB_hat0, bias_hat0, _covariance0(covariance0)),
        period_s,
        gyro=gyro,
        vector_sensors=vector_inputs(star_tracker, vector_sensors),
    )


def MrpEkfEstimator(
    name: str,
    period_s: float,
    star_tracker: str,
    q_IB_hat0,
    bias_hat0,
    covariance0,
    arw_rad_per_rt_s: float,
    rrw_rad_per_s15: float,
    update_iterations: int = 1,
) -> EstimatorSystem:
    """Paper S0's additive EKF on ``x = [rho; b]`` (:class:`~drake_att.filters.mrp_ekf.MrpEkfCore`).

    Args:
        name: system name.
        period_s: filter step (s); must equal the gyro period (the gyro delivers the mean
            rate over one step) and be a multiple of the star tracker's period.
        star_tracker: name of the vector-mode star tracker (names the input port).
        q_IB_hat0: initial attitude estimate (4, wxyz).
        bias_hat0: initial bias estimate (3, rad/s).
        covariance0: (6, 6) (or its diagonal (6,)) covariance of
            ``[dtheta_B (rad); b (rad/s)]``.
        arw_rad_per_rt_s: gyro ARW (rad/s^0.5) > 0.
        rrw_rad_per_s15: gyro RRW (rad/s^1.5) >= 0.
        update_iterations: linearizations per update (1 = paper's EKF; > 1 iterated EKF).

    Ports: gyro_measurement, vectors_<star_tracker>; the estimator contract with
    ``bias_B_hat`` (``status[3]`` = NIS of the last update, 6 dof for two vectors).
    """
    return EstimatorSystem.from_setup(
        name,
        mrp_ekf_setup(
            period_s,
            star_tracker,
            q_IB_hat0,
            bias_hat0,
            covariance0,
            arw_rad_per_rt_s,
            rrw_rad_per_s15,
            update_iterations,
        ),
    )


def _particle_setup(period_s, star_tracker, gyro, core, vector_sensors=()) -> EstimatorSetup:
    return EstimatorSetup(
        core,
        core.draw_initial_state(np.random.default_rng(0)),
        period_s,
        gyro=gyro,
        vector_sensors=vector_inputs(star_tracker, vector_sensors),
    )


_PF_PORTS_DOC = """
    Ports: {gyro}vectors_<star_tracker>, seed_uniform (random); the estimator contract with
    ``{second}`` (``covariance`` = the weighted particle covariance of ``[dtheta_B;
    {second_short} error]`` about the reported mean; ``status[3]`` = NaN: a particle filter
    has no innovation covariance), plus particle_diagnostics (4): ``[N_eff after the last
    update (before resampling), resamplings so far, degenerate updates so far, N]``.
"""


def bootstrap_pf_setup(
    period_s: float,
    star_tracker: str,
    num_particles: int,
    q_IB_hat0,
    bias_hat0,
    covariance0,
    arw_rad_per_rt_s: float,
    bias_roughening_sigma: float = 0.0,
    resample_threshold: float = 2.0 / 3.0,
    gyro: str | None = None,
    vector_sensors=(),
) -> EstimatorSetup:
    """The setup of :func:`BootstrapPfEstimator` (same arguments; ``gyro``: the gyro's name;
    ``vector_sensors``: as :func:`mrp_ekf_setup`'s)."""
    roughening = RandomWalkRoughening(check_positive("bias_roughening_sigma", bias_roughening_sigma, allow_zero=True))
    return _particle_setup(
        period_s,
        star_tracker,
        gyro,
        BootstrapPfCore(
            num_particles,
            q_IB_hat0,
            bias_hat0,
            _covariance0(covariance0),
            arw_rad_per_rt_s,
            bias_roughening=roughening,
            resampling_gate=EffectiveSampleSizeGate(resample_threshold),
        ),
        vector_sensors,
    )


def BootstrapPfEstimator(
    name: str,
    period_s: float,
    star_tracker: str,
    num_particles: int,
    q_IB_hat0,
    bias_hat0,
    covariance0,
    arw_rad_per_rt_s: float,
    bias_roughening_sigma: float = 0.0,
    resample_threshold: float = 2.0 / 3.0,
) -> EstimatorSystem:
    return EstimatorSystem.from_setup(
        name,
        bootstrap_pf_setup(
            period_s,
            star_tracker,
            num_particles,
            q_IB_hat0,
            bias_hat0,
            covariance0,
            arw_rad_per_rt_s,
            bias_roughening_sigma,
            resample_threshold,
        ),
    )


BootstrapPfEstimator.__doc__ = """Paper S0's bootstrap (SIR) PF in gyro mode (:class:`~drake_att.filters.particle.BootstrapPfCore`).

    Args:
        name: system name (also the random stream name).
        period_s: filter step (s) = the gyro period.
        star_tracker: name of the vector-mode star tracker.
        num_particles: N >= 1.
        q_IB_hat0, bias_hat0, covariance0: initial estimate (wxyz; rad/s) and the (6, 6)
            (or diagonal (6,)) covariance of ``[dtheta_B (rad); b (rad/s)]`` the initial
            particles are drawn from.
        arw_rad_per_rt_s: attitude process noise of the particles, as an ARW (rad/s^0.5) >= 0.
        bias_roughening_sigma: bias random-walk roughening (rad/s^1.5) >= 0; 0 = paper.
        resample_threshold: resample when ``N_eff < threshold * N`` (paper 2/3).
""" + _PF_PORTS_DOC.format(gyro="gyro_measurement, ", second="bias_B_hat", second_short="bias")


def ekpf_setup(
    period_s: float,
    star_tracker: str,
    num_particles: int,
    q_IB_hat0,
    bias_hat0,
    covariance0,
    arw_rad_per_rt_s: float,
    rrw_rad_per_s15: float,
    proposal_iterations: int = 1,
    resample_threshold: float = 2.0 / 3.0,
    gyro: str | None = None,
    vector_sensors=(),
) -> EstimatorSetup:
    """The setup of :func:`EkpfEstimator` (same arguments; ``gyro``: the gyro's name;
    ``vector_sensors``: as :func:`mrp_ekf_setup`'s)."""
    return _particle_setup(
        period_s,
        star_tracker,
        gyro,
        EkpfCore(
            num_particles,
            q_IB_hat0,
            bias_hat0,
            _covariance0(covariance0),
            arw_rad_per_rt_s,
            rrw_rad_per_s15,
            proposal_iterations=proposal_iterations,
            resampling_gate=EffectiveSampleSizeGate(resample_threshold),
        ),
        vector_sensors,
    )


def EkpfEstimator(
    name: str,
    period_s: float,
    star_tracker: str,
    num_particles: int,
    q_IB_hat0,
    bias_hat0,
    covariance0,
    arw_rad_per_rt_s: float,
    rrw_rad_per_s15: float,
    proposal_iterations: int = 1,
    resample_threshold: float = 2.0 / 3.0,
) -> EstimatorSystem:
    return EstimatorSystem.from_setup(
        name,
        ekpf_setup(
            period_s,
            star_tracker,
            num_particles,
            q_IB_hat0,
            bias_hat0,
            covariance0,
            arw_rad_per_rt_s,
            rrw_rad_per_s15,
            proposal_iterations,
            resample_threshold,
        ),
    )


EkpfEstimator.__doc__ = """Paper S0's extended-Kalman particle filter (:class:`~drake_att.filters.particle.EkpfCore`).

    Args:
        name: system name (also the random stream name).
        period_s: filter step (s) = the gyro period.
        star_tracker: name of the vector-mode star tracker.
        num_particles: N >= 1.
        q_IB_hat0, bias_hat0, covariance0: initial estimate and covariance (as
            :func:`BootstrapPfEstimator`); ``covariance0`` is also every particle's
            initial EKF covariance.
        arw_rad_per_rt_s: gyro ARW (rad/s^0.5) > 0. rrw_rad_per_s15: gyro RRW (rad/s^1.5) >= 0.
        proposal_iterations: linearizations of each particle's EKF update (1 = paper;
            > 1 iterated-EKF proposal, beyond the paper).
        resample_threshold: resample when ``N_eff < threshold * N`` (paper 2/3).
""" + _PF_PORTS_DOC.format(gyro="gyro_measurement, ", second="bias_B_hat", second_short="bias")


def gyroless_pf_setup(
    period_s: float,
    star_tracker: str,
    num_particles: int,
    q_IB_hat0,
    w_hat0,
    covariance0,
    inertia,
    torque,
    rate_process_sigma: float,
    attitude_process_sigma: float = 0.0,
    num_substeps: int = 1,
    resample_threshold: float = 2.0 / 3.0,
    vector_sensors=(),
) -> EstimatorSetup:
    """The setup of :func:`GyrolessPfEstimator` (same arguments; ``vector_sensors``: as
    :func:`mrp_ekf_setup`'s)."""
    I = np.asarray(inertia, dtype=float)
    if I.shape == (3,):
        I = np.diag(I)
    return _particle_setup(
        period_s,
        star_tracker,
        None,
        GyrolessPfCore(
            num_particles,
            q_IB_hat0,
            w_hat0,
            _covariance0(covariance0),
            I,
            torque,
            rate_process_sigma,
            attitude_process_sigma=attitude_process_sigma,
            num_substeps=num_substeps,
            resampling_gate=EffectiveSampleSizeGate(resample_threshold),
        ),
        vector_sensors,
    )


def GyrolessPfEstimator(
    name: str,
    period_s: float,
    star_tracker: str,
    num_particles: int,
    q_IB_hat0,
    w_hat0,
    covariance0,
    inertia,
    torque,
    rate_process_sigma: float,
    attitude_process_sigma: float = 0.0,
    num_substeps: int = 1,
    resample_threshold: float = 2.0 / 3.0,
) -> EstimatorSystem:
    return EstimatorSystem.from_setup(
        name,
        gyroless_pf_setup(
            period_s,
            star_tracker,
            num_particles,
            q_IB_hat0,
            w_hat0,
            covariance0,
            inertia,
            torque,
            rate_process_sigma,
            attitude_process_sigma,
            num_substeps,
            resample_threshold,
        ),
    )


GyrolessPfEstimator.__doc__ = """Paper S0's gyroless bootstrap PF on ``[rho; w]`` (:class:`~drake_att.filters.particle.GyrolessPfCore`).

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
""" + _PF_PORTS_DOC.format(gyro="", second="w_IB_B_hat", second_short="rate")
