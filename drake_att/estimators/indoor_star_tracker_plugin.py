"""Estimator plug-in: paper S2's indoor star tracker
(:class:`drake_att.filters.indoor_star_tracker.IndoorStarTrackerSolver`) on a screen camera
(:mod:`drake_att.sensors.screen_camera_plugin`), alone or — beyond the paper, with ``gyro`` set —
fused with a table gyro in the MEKF
(:class:`~drake_att.filters.indoor_star_tracker.IndoorStarTrackerMekf`). YAML tag
``!IndoorStarTrackerConfig``.

The solver assumes the camera's own geometry (screen height, offset, focal length) and
builds its catalogue from the camera's noise-free view at zero attitude. Documented choices
the paper leaves open: angle tolerance 0.01 deg (with this camera, one iteration from a 3
deg offset identifies ~3 of 7 stars and solves 86% of random 7-star screens, from 6 deg 38-46%
of them: the paper's "3 deg works, 6 deg fails" as a tendency), TRIAD from the
widest identified pair, stop when the attitude changes by less than
``convergence_tolerance_arcsec`` or after ``max_iterations``; the swarm searches
``initial_attitude_rpy_deg +- pso_search_range_deg`` and stops when half the observed stars
are identified. ``camera_offset_error_mm`` (beyond the paper) miscalibrates the solver's
``R0`` (its catalogue is then the real camera's zero-attitude photo converted with the wrong
offset, as a lab would make it). ``tolerance_sigmas: k`` (beyond the paper; the dynamic scenario's
4) derives each frame's tolerance from its centroid noise, ``max(tolerance_deg, k sqrt(2) sigma_c
/ f)`` (:func:`~drake_att.filters.screen_calibration.pair_angle_tolerance`); ``null`` (default)
keeps the fixed ``tolerance_deg`` (the paper's). ``screen_height_sigma_mm`` and
``camera_offset_sigma_mm`` (per axis of ``R0``; beyond the paper, default 0 = no term) are the
1-sigma of the solver's layout: each solution's covariance adds ``J Sigma_cal J^T``
(:meth:`~drake_att.filters.indoor_star_tracker.IndoorStarTrackerSolver.calibration_covariance`).
``initialization: given`` uses ``initial_attitude_rpy_deg`` as the first
frame's ``A0`` (the paper's Tables 1-2); ``swarm`` runs the search first (its dynamic test).

Without a gyro the second output is the body rate (differenced from consecutive solutions)
and the estimator steps at the camera's frames (``period_s`` = a whole multiple of the
camera period). With a gyro it is the MEKF's bias, ``period_s`` = the gyro's, and the MEKF
fields (``arw_deg_per_rt_h`` ..., ``innovation_gate_chi2``) apply; ``gyro`` is structural.
Published diagnostics (``<name>/diagnostics``): stars observed, stars identified,
iterations, swarm generations, swarm searches so far, solved — of the last frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import List, Optional

import numpy as np

from drake_att import validation
from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY
from drake_att.filters.indoor_star_tracker import (
    ATTITUDE_METHODS,
    IDENTIFICATIONS,
    IndoorStarTrackerMekf,
    IndoorStarTrackerSolver,
    SwarmSettings,
)
from drake_att.filters.mekf import MultiplicativeEKF
from drake_att.filters.screen_calibration import CalibrationUncertainty
from drake_att.scenarios import config as cfg
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.registry import register_estimator
from drake_att.sensors.screen_camera_plugin import camera_geometry
from drake_att.systems.estimator_system import EstimatorSetup
from drake_att.units import ARCSEC, DEG, DEG_PER_H

INITIALIZATIONS = ("swarm", "given")


@dataclass
class IndoorStarTrackerConfig:
    """The indoor star tracker on camera ``camera``; with ``gyro``, fused in an MEKF."""

    name: str = "indoor_star_tracker"
    camera: str = "camera"
    period_s: float = 0.2
    gyro: Optional[str] = None
    tolerance_deg: float = 0.01
    tolerance_sigmas: Optional[float] = None
    identification: str = "corrected"
    attitude_method: str = "triad"
    max_iterations: int = 10
    convergence_tolerance_arcsec: float = 1e-4
    initialization: str = "swarm"
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 10.0
    max_lost_frames: int = 5
    sigma_floor_urad: float = 0.001
    camera_offset_error_mm: float = 0.0
    screen_height_sigma_mm: float = 0.0
    camera_offset_sigma_mm: float = 0.0
    pso_particles: int = 5
    pso_inertia: float = 0.8
    pso_c1: float = 1.3
    pso_c2: float = 1.7
    pso_v_max_deg: float = 5.0
    pso_max_generations: int = 200
    pso_search_range_deg: float = 10.0
    pso_stop_fraction: float = 0.5
    # With a gyro (the MEKF):
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_sigma_deg_per_h: float = 20.0
    innovation_gate_chi2: Optional[float] = None
    innovation_gate_probability: float = DEFAULT_GATE_PROBABILITY


_MEKF_FIELDS = ("arw_deg_per_rt_h", "rrw_deg_per_h15", "innovation_gate_chi2")  # None unless fused


def validate_indoor_star_tracker(path: str, c: IndoorStarTrackerConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    camera = common.require_sensor(checks, path, "camera", c.camera, "camera")
    common.check_period_multiple(path, c.period_s, c.camera, camera.period_s)
    if c.gyro is not None:
        gyro = common.require_sensor(checks, path, "gyro", c.gyro, "gyro")
        common.check_gyro_period(path, c.period_s, gyro)
        for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15"):
            if getattr(c, f) is not None:
                cfg.check_nonnegative(f"{path}.{f}", getattr(c, f))
        common.check_initial_bias(path, c)
        common.check_innovation_gate(path, c)
    else:
        if camera.period_s - c.period_s > 1e-9:
            cfg.fail(
                f"{path}.period_s",
                c.period_s,
                f"without a gyro it must be a whole multiple of the camera's "
                f"period ({camera.period_s} s): the solver has nothing to do between frames",
            )
        for f in _MEKF_FIELDS:
            if getattr(c, f) is not None:
                cfg.fail(f"{path}.{f}", getattr(c, f), "is an MEKF setting: it needs a gyro (set 'gyro')")
    cfg.check_positive(f"{path}.tolerance_deg", c.tolerance_deg)
    if c.tolerance_sigmas is not None:
        cfg.check_finite(f"{path}.tolerance_sigmas", c.tolerance_sigmas)
        if not c.tolerance_sigmas > 0.0:
            cfg.fail(
                f"{path}.tolerance_sigmas",
                c.tolerance_sigmas,
                "must be > 0 (standard deviations), or null for the fixed tolerance_deg",
            )
    for f in ("screen_height_sigma_mm", "camera_offset_sigma_mm"):
        cfg.check_nonnegative(f"{path}.{f}", getattr(c, f))
    for f, allowed in (
        ("identification", IDENTIFICATIONS),
        ("attitude_method", ATTITUDE_METHODS),
        ("initialization", INITIALIZATIONS),
    ):
        if getattr(c, f) not in allowed:
            cfg.fail(f"{path}.{f}", getattr(c, f), f"allowed: {list(allowed)}")
    common.check_integers_at_least_one(
        path, c, "max_iterations", "max_lost_frames", "pso_particles", "pso_max_generations"
    )
    cfg.check_nonnegative(f"{path}.convergence_tolerance_arcsec", c.convergence_tolerance_arcsec)
    common.check_initial_attitude(path, c)
    cfg.check_positive(f"{path}.sigma_floor_urad", c.sigma_floor_urad)
    cfg.check_finite(f"{path}.camera_offset_error_mm", c.camera_offset_error_mm)
    offset = camera.h_mm - camera.camera_to_screen_mm + c.camera_offset_error_mm
    if not 0.0 <= offset < camera.h_mm:
        cfg.fail(
            f"{path}.camera_offset_error_mm",
            c.camera_offset_error_mm,
            f"the modelled offset |R0| = {offset} mm must be in [0, h = {camera.h_mm}) mm",
        )
    for f in ("pso_inertia", "pso_c1", "pso_c2"):
        cfg.check_nonnegative(f"{path}.{f}", getattr(c, f))
    for f in ("pso_v_max_deg", "pso_search_range_deg"):
        cfg.check_positive(f"{path}.{f}", getattr(c, f))
    cfg.check_finite(f"{path}.pso_stop_fraction", c.pso_stop_fraction)
    if not 0.0 < c.pso_stop_fraction <= 1.0:
        cfg.fail(f"{path}.pso_stop_fraction", c.pso_stop_fraction, "must be in (0, 1]")
    try:
        camera_geometry(camera).catalogue()
        validation.check_int("star_count", camera.star_count, 3)
    except ValueError as e:
        raise cfg.ConfigError(f"{path}.camera: {e} (the solver needs >= 3 catalogue stars)") from e


def indoor_second_quantity(c: IndoorStarTrackerConfig, checks) -> SecondQuantity:
    """The gyro bias when fused with a gyro, else the body rate."""
    return SecondQuantity.BODY_RATE if c.gyro is None else SecondQuantity.GYRO_BIAS


def solver_for(ctx, c: IndoorStarTrackerConfig) -> IndoorStarTrackerSolver:
    """The solver of a (validated) config: its camera's geometry, with the offset ``R0``
    miscalibrated by ``camera_offset_error_mm``; the catalogue is the real camera's
    noise-free photo at zero attitude converted with that model."""
    camera = ctx.sensor_configs[c.camera]
    photo = camera_geometry(camera).project(np.eye(3))[1]
    model = camera_geometry(replace(camera, camera_to_screen_mm=camera.camera_to_screen_mm - c.camera_offset_error_mm))
    swarm = SwarmSettings(
        c.pso_particles,
        c.pso_inertia,
        c.pso_c1,
        c.pso_c2,
        c.pso_v_max_deg,
        c.pso_max_generations,
        c.pso_search_range_deg,
        c.pso_stop_fraction,
    )
    return IndoorStarTrackerSolver(
        model,
        c.tolerance_deg,
        c.identification,
        c.attitude_method,
        c.max_iterations,
        c.convergence_tolerance_arcsec * ARCSEC,
        c.initialization,
        swarm,
        c.max_lost_frames,
        c.sigma_floor_urad * 1e-6,
        catalogue_centroids_m=photo,
        tolerance_sigmas=c.tolerance_sigmas,
        calibration=CalibrationUncertainty(c.screen_height_sigma_mm * 1e-3, c.camera_offset_sigma_mm * 1e-3),
    )


@register_estimator(
    IndoorStarTrackerConfig,
    second_quantity=indoor_second_quantity,
    validate=validate_indoor_star_tracker,
    parameters=(
        "tolerance_deg",
        "tolerance_sigmas",
        "identification",
        "attitude_method",
        "max_iterations",
        "convergence_tolerance_arcsec",
        "initialization",
        "initial_attitude_rpy_deg",
        "initial_attitude_sigma_deg",
        "max_lost_frames",
        "sigma_floor_urad",
        "camera_offset_error_mm",
        "screen_height_sigma_mm",
        "camera_offset_sigma_mm",
        "pso_particles",
        "pso_inertia",
        "pso_c1",
        "pso_c2",
        "pso_v_max_deg",
        "pso_max_generations",
        "pso_search_range_deg",
        "pso_stop_fraction",
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        "initial_bias_deg_per_h",
        "initial_bias_sigma_deg_per_h",
        *common.GATE_FIELDS,
    ),
)
def build_indoor_star_tracker(ctx, c: IndoorStarTrackerConfig) -> EstimatorSetup:
    solver = solver_for(ctx, c)
    q0 = attitude_from_rpy_deg(ctx.scenario, c.initial_attitude_rpy_deg)
    solver_state = solver.initial_state(q0, c.initial_attitude_sigma_deg * DEG)
    if c.gyro is None:
        return EstimatorSetup(solver, solver_state, c.period_s, camera_sensors=(c.camera,))
    arw, rrw = common.filter_gyro_noise(ctx, c)
    mekf = MultiplicativeEKF(arw, rrw, common.innovation_gate(c))
    mekf_state = mekf.initial_state(
        q0,
        np.asarray(c.initial_bias_deg_per_h, dtype=float) * DEG_PER_H,
        c.initial_attitude_sigma_deg * DEG,
        c.initial_bias_sigma_deg_per_h * DEG_PER_H,
    )
    core = IndoorStarTrackerMekf(solver, mekf)
    return EstimatorSetup(
        core, core.initial_state(mekf_state, solver_state), c.period_s, gyro=c.gyro, camera_sensors=(c.camera,)
    )
