"""Scenario-builder functions for paper S0's estimators (MRP EKF, bootstrap PF, EKPF,
gyroless PF).

Each function turns a config (:mod:`drake_att.scenarios.config`, units at the edge: deg,
deg/h, deg/sqrt(h), deg/h^1.5) into an estimator system
(:mod:`drake_att.systems.particle_estimators`, SI units) and wires it to its gyro, its
vector-mode star tracker and (for the particle filters) the diagram's random source.
:func:`register` adds them to the builder's registry::

    from drake_att.scenarios import builder
    from drake_att.scenarios.particle_builders import register
    register(builder.ESTIMATOR_BUILDERS)   # idempotent

Unit conversions (``drake_att.noise``):

* ``arw_deg_per_rt_h``, ``attitude_process_noise_deg_per_rt_h`` -> rad/s^0.5
  (``ARW_DEG_PER_RT_H``); ``rrw_deg_per_h15`` -> rad/s^1.5 (``RRW_DEG_PER_H_15``);
* ``bias_roughening_deg_per_h_per_rt_s`` (deg/h per sqrt(s)) -> rad/s^1.5 (``DEG_PER_H``);
* ``rate_process_noise_deg_per_s_per_rt_s`` (deg/s per sqrt(s)) -> rad/s^1.5 (``DEG``).

Filter noise left as ``None`` defaults to the gyro's configured values; the gyroless
filter's empty ``inertia_kg_m2`` / ``disturbance_torque_N_m`` default to the plant's.
"""

from __future__ import annotations

import numpy as np

from drake_att.noise import ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import BuildContext, attitude_from_rpy_deg
from drake_att.systems.particle_estimators import (
    BootstrapPfEstimator,
    EkpfEstimator,
    GyrolessPfEstimator,
    MrpEkfEstimator,
)

__all__ = ["build_mrp_ekf", "build_bootstrap_pf", "build_ekpf", "build_gyroless_pf", "register"]


def _gyro_noise(ctx: BuildContext, c, need_arw: bool = True):
    """Filter ARW (rad/s^0.5) and RRW (rad/s^1.5): the config's, else the gyro's."""
    g = ctx.sensor_configs[c.gyro]
    arw = g.arw_deg_per_rt_h if getattr(c, "arw_deg_per_rt_h", None) is None else c.arw_deg_per_rt_h
    rrw = g.rrw_deg_per_h15 if getattr(c, "rrw_deg_per_h15", None) is None else c.rrw_deg_per_h15
    if need_arw and not arw > 0:
        raise cfg.ConfigError(f"{c.name}.arw_deg_per_rt_h: got {arw!r} (gyro {c.gyro!r}: "
                              f"{g.arw_deg_per_rt_h!r}); the filter needs an ARW > 0 (deg/sqrt(h))")
    return arw * ARW_DEG_PER_RT_H, rrw * RRW_DEG_PER_H_15


def _initial_gyro_mode(ctx: BuildContext, c):
    q0 = attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg)
    b0 = np.asarray(c.initial_bias_deg_per_h, dtype=float) * DEG_PER_H
    P0 = np.diag([(c.initial_attitude_sigma_deg * DEG) ** 2] * 3
                 + [(c.initial_bias_sigma_deg_per_h * DEG_PER_H) ** 2] * 3)
    return q0, b0, P0


def _connect(ctx: BuildContext, c, est, gyro: bool = True):
    b = ctx.builder
    if gyro:
        b.Connect(ctx.sensors[c.gyro].GetOutputPort("gyro_measurement"), est.GetInputPort("gyro_measurement"))
    b.Connect(ctx.sensors[c.star_tracker].GetOutputPort("vector_observations"),
              est.GetInputPort(f"vectors_{c.star_tracker}"))
    # seed_uniform is a random input port: AddRandomInputs (called by the builder after
    # all estimators are added) wires a RandomSource to it.
    est.gyro_name = c.gyro if gyro else None
    return est


def build_mrp_ekf(ctx: BuildContext, c: cfg.MrpEkfConfig):
    arw, rrw = _gyro_noise(ctx, c)
    q0, b0, P0 = _initial_gyro_mode(ctx, c)
    est = ctx.builder.AddSystem(MrpEkfEstimator(c.name, c.period_s, c.star_tracker, q0, b0, P0, arw, rrw,
                                                c.update_iterations))
    return _connect(ctx, c, est)


def build_bootstrap_pf(ctx: BuildContext, c: cfg.BootstrapPfConfig):
    g = ctx.sensor_configs[c.gyro]
    arw_deg = g.arw_deg_per_rt_h if c.attitude_process_noise_deg_per_rt_h is None \
        else c.attitude_process_noise_deg_per_rt_h
    q0, b0, P0 = _initial_gyro_mode(ctx, c)
    est = ctx.builder.AddSystem(BootstrapPfEstimator(
        c.name, c.period_s, c.star_tracker, c.num_particles, q0, b0, P0, arw_deg * ARW_DEG_PER_RT_H,
        bias_roughening_sigma=c.bias_roughening_deg_per_h_per_rt_s * DEG_PER_H,
        resample_threshold=c.resample_threshold))
    return _connect(ctx, c, est)


def build_ekpf(ctx: BuildContext, c: cfg.EkpfConfig):
    arw, rrw = _gyro_noise(ctx, c)
    q0, b0, P0 = _initial_gyro_mode(ctx, c)
    est = ctx.builder.AddSystem(EkpfEstimator(
        c.name, c.period_s, c.star_tracker, c.num_particles, q0, b0, P0, arw, rrw,
        proposal_iterations=c.proposal_iterations, resample_threshold=c.resample_threshold))
    return _connect(ctx, c, est)


def _plant_dynamics(ctx: BuildContext, c: cfg.GyrolessPfConfig):
    """Inertia (3, 3) and torque (3,) for the gyroless filter: the config's, else the plant's."""
    p = ctx.scenario.plant
    inertia, torque = list(c.inertia_kg_m2), list(c.disturbance_torque_N_m)
    if not inertia or not torque:
        if not isinstance(p, cfg.RigidBodyConfig):
            raise cfg.ConfigError(
                f"{c.name}.inertia_kg_m2 / disturbance_torque_N_m: empty (= the plant's), but the plant is a "
                f"{type(p).__name__}, which has no inertia/torque; give them explicitly")
        inertia = inertia or list(p.inertia_kg_m2)
        torque = torque or list(p.disturbance_torque_N_m)
    I = np.asarray(inertia, dtype=float)
    I = np.diag(I) if I.size == 3 else I.reshape(3, 3)
    return I, np.asarray(torque, dtype=float)


def build_gyroless_pf(ctx: BuildContext, c: cfg.GyrolessPfConfig):
    inertia, torque = _plant_dynamics(ctx, c)
    q0 = attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg)
    w0 = np.asarray(c.initial_rate_deg_per_s, dtype=float) * DEG
    P0 = np.diag([(c.initial_attitude_sigma_deg * DEG) ** 2] * 3 + [(c.initial_rate_sigma_deg_per_s * DEG) ** 2] * 3)
    est = ctx.builder.AddSystem(GyrolessPfEstimator(
        c.name, c.period_s, c.star_tracker, c.num_particles, q0, w0, P0, inertia, torque,
        c.rate_process_noise_deg_per_s_per_rt_s * DEG,
        attitude_process_sigma=c.attitude_process_noise_deg_per_rt_h * ARW_DEG_PER_RT_H,
        num_substeps=c.num_substeps, resample_threshold=c.resample_threshold))
    return _connect(ctx, c, est, gyro=False)


BUILDERS = {
    cfg.MrpEkfConfig: build_mrp_ekf,
    cfg.BootstrapPfConfig: build_bootstrap_pf,
    cfg.EkpfConfig: build_ekpf,
    cfg.GyrolessPfConfig: build_gyroless_pf,
}


def register(registry: dict) -> dict:
    """Add the S0 builders to ``registry`` (config type -> builder function); idempotent."""
    registry.update(BUILDERS)
    return registry
