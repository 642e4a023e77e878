"""Physics tests of the truth models (``drake_att.systems.plant``) and the orbit frame.

Reached figures (Drake 1.51.1, runge_kutta5), asserted with a safety margin:

* Torque-free asymmetric body, I = diag(10, 20, 30) kg m^2, w0 = [0.1, 0.02, -0.05] rad/s,
  1e4 s at accuracy 1e-10 (~124k steps, ~10 s wall): kinetic energy conserved to ~4e-13
  relative, inertial angular momentum R_IB I w to ~1.3e-12 relative, | |q| - 1 | ~3e-11.
* Constant torque about a principal axis over 100 s: rate to ~1e-14 rad/s, rotation angle
  to ~3e-12 rad of the closed form.
* MultibodyPlant free body (same inertia, gravity off) over 1000 s: attitudes agree to
  ~3e-11 rad, body rates to ~2e-13 rad/s (the MultibodyPlant reference needs accuracy
  1e-14 *and* max_step 0.05 s to get there; at accuracy 1e-14 with 10 s steps it is
  itself only good to ~4e-9 rad, checked against scipy DOP853 at rtol 1e-13).
* PrescribedAttitudeMotion: closed-form rotations to ~5e-13 rad; rpy breakpoints to
  ~1e-9 rad (rate discontinuities at the breakpoints); w_IB_B output exact.
* Orbit: w_IO_O by finite differences to ~3e-17 rad/s; LVLH axes vs independent Kepler
  position and finite-difference velocity to ~2e-13.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import RotationalInertia, SpatialInertia
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from drake_att import orbit as orb
from drake_att import rotations as rot
from drake_att.systems.plant import (
    PrescribedAttitudeMotion,
    RigidBodyAttitudePlant,
    validate_inertia,
)

DEG = np.pi / 180.0
INERTIA = np.diag([10.0, 20.0, 30.0])
W0 = np.array([0.1, 0.02, -0.05])
Q0 = rot.rpy_to_quat([0.3, -0.2, 1.0])


def angle_between(q_a, q_b) -> np.ndarray:
    """Sign-invariant rotation angle between quaternion(s) (rad)."""
    return np.linalg.norm(rot.quat_error_rotvec(q_a, q_b), axis=-1)


def make_simulator(diagram, context, accuracy, max_step_size):
    simulator = Simulator(diagram, context)
    ApplySimulatorConfig(
        SimulatorConfig(
            integration_scheme="runge_kutta5",
            accuracy=accuracy,
            max_step_size=max_step_size,
            use_error_control=True,
            target_realtime_rate=0.0,
            publish_every_time_step=False,
        ),
        simulator,
    )
    simulator.Initialize()
    return simulator


def rigid_body_rig(inertia, torque_B=(0.0, 0.0, 0.0)):
    """Plant + constant torque; returns (diagram, plant)."""
    builder = DiagramBuilder()
    plant = builder.AddSystem(RigidBodyAttitudePlant(inertia))
    torque = builder.AddSystem(ConstantVectorSource(np.asarray(torque_B, dtype=float)))
    builder.Connect(torque.get_output_port(), plant.GetInputPort("torque_B"))
    return builder.Build(), plant


def run_rigid_body(inertia, q0, w0, times, torque_B=(0.0, 0.0, 0.0), accuracy=1e-10, max_step=10.0):
    """States ``[q (4), w (3), integral (3)]`` of the plant at ``times``, shape (n, 10)."""
    diagram, plant = rigid_body_rig(inertia, torque_B)
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    plant.SetDefaultParametersAndState(plant_context)
    plant.SetInitialState(plant_context, q0, w0)
    simulator = make_simulator(diagram, context, accuracy, max_step)
    out = []
    for t in times:
        simulator.AdvanceTo(float(t))
        out.append(plant.get_continuous_state(plant_context))
    return np.array(out)


def run_outputs(system, times, accuracy=1e-11, max_step=0.1):
    """Outputs (q_IB, w_IB_B, w_IB_B_integral) of a source-only truth system at ``times``."""
    context = system.CreateDefaultContext()
    system.SetDefaultParametersAndState(context)
    simulator = make_simulator(system, context, accuracy, max_step)
    q, w, th = [], [], []
    for t in times:
        simulator.AdvanceTo(float(t))
        q.append(system.GetOutputPort("q_IB").Eval(context).copy())
        w.append(system.GetOutputPort("w_IB_B").Eval(context).copy())
        th.append(system.GetOutputPort("w_IB_B_integral").Eval(context).copy())
    return np.array(q), np.array(w), np.array(th)


# ----------------------------------------------------------------------------------
# Torque-free motion: conservation laws over 1e4 s
# ----------------------------------------------------------------------------------
TORQUE_FREE_TIMES = np.linspace(100.0, 1e4, 100)


@pytest.fixture(scope="module")
def torque_free_run():
    return run_rigid_body(INERTIA, Q0, W0, TORQUE_FREE_TIMES, accuracy=1e-10, max_step=10.0)


def test_torque_free_motion_is_nontrivial(torque_free_run):
    """The body really tumbles: w changes by O(w0) and the attitude turns many times,
    so the conservation checks below exercise the gyroscopic term and the kinematics."""
    w = torque_free_run[:, 4:7]
    assert np.max(np.linalg.norm(w - W0, axis=1)) > 0.02
    total_angle = np.linalg.norm(torque_free_run[-1, 7:10])  # |integral of w|, a lower bound
    assert total_angle > 100.0


def test_torque_free_kinetic_energy_conserved(torque_free_run):
    """Kinetic energy 1/2 w'Iw conserved to 2e-12 relative over 1e4 s (reached ~4e-13)."""
    w = torque_free_run[:, 4:7]
    energy0 = 0.5 * W0 @ INERTIA @ W0
    energy = 0.5 * np.einsum("ni,ij,nj->n", w, INERTIA, w)
    assert np.max(np.abs(energy - energy0)) / energy0 < 2e-12


def test_torque_free_inertial_angular_momentum_conserved(torque_free_run):
    """H_I = R_IB I w_IB_B constant to 1e-11 relative over 1e4 s (reached ~1.3e-12).

    Unlike the energy, this fails for a wrong sign of the gyroscopic term or a
    left/right mix-up in the quaternion kinematics.
    """
    q, w = torque_free_run[:, :4], torque_free_run[:, 4:7]
    h0 = rot.quat_to_rotmat(Q0) @ INERTIA @ W0
    h = np.einsum("nij,nj->ni", rot.quat_to_rotmat(q), w @ INERTIA.T)
    # The body-frame momentum does vary a lot (the test is not vacuous).
    assert np.max(np.linalg.norm(w @ INERTIA.T - INERTIA @ W0, axis=1)) > 0.1 * np.linalg.norm(h0)
    assert np.max(np.linalg.norm(h - h0, axis=1)) / np.linalg.norm(h0) < 1e-11


def test_quaternion_norm_does_not_drift(torque_free_run):
    """| |q| - 1 | < 1e-9 over 1e4 s of tumbling (reached ~3e-11)."""
    q = torque_free_run[:, :4]
    assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < 1e-9


def test_rate_integral_port_integrates_rate():
    """w_IB_B_integral is the integral of w (trapezoid rule on a 0.025 s grid, 1e-6 rad)."""
    times = np.linspace(0.0, 50.0, 2001)
    x = run_rigid_body(INERTIA, Q0, W0, times, accuracy=1e-11, max_step=0.1)
    w, integral = x[:, 4:7], x[:, 7:10]
    dt = np.diff(times)[:, None]
    trapezoid = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (w[1:] + w[:-1]) * dt, axis=0)])
    # Trapezoid error ~ T dt^2 max|w''| / 12 (reached 3e-7 rad).
    assert np.max(np.abs(integral - trapezoid)) < 1e-6
    assert np.max(np.abs(integral[-1])) > 0.5


# ----------------------------------------------------------------------------------
# Constant torque about a principal axis: closed form
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("w0_about_axis", [0.0, 0.05])
def test_constant_torque_about_principal_axis(axis, w0_about_axis):
    """w(t) = w0 + T/I t (to 1e-13 rad/s; reached 1e-14) and angle = w0 t + T t^2 / (2 I)
    about that axis (to 3e-11 rad; reached 3e-12) over 100 s, from rest and from a spin."""
    torque = 0.02
    e = np.eye(3)[axis]
    times = np.array([10.0, 37.0, 64.5, 100.0])
    x = run_rigid_body(INERTIA, Q0, w0_about_axis * e, times, torque_B=torque * e, accuracy=1e-10)
    alpha = torque / INERTIA[axis, axis]
    w_expected = (w0_about_axis + alpha * times)[:, None] * e
    angle = w0_about_axis * times + 0.5 * alpha * times**2
    q_expected = rot.quat_multiply(Q0, rot.rotvec_to_quat(angle[:, None] * e))
    assert np.max(np.abs(x[:, 4:7] - w_expected)) < 1e-13
    assert np.max(angle_between(x[:, :4], q_expected)) < 3e-11
    assert np.max(np.abs(x[:, 7:10] - angle[:, None] * e)) < 3e-11
    assert angle[-1] > 3.0  # large rotation (> 3 rad): not a small-angle check


# ----------------------------------------------------------------------------------
# Agreement with Drake's MultibodyPlant
# ----------------------------------------------------------------------------------
def multibody_free_body_final_state(inertia_diag, q0, w0_B, t_final):
    """q_WB and w_WB_B of a MultibodyPlant free body after ``t_final`` s (gravity off)."""
    plant = MultibodyPlant(time_step=0.0)
    body = plant.AddRigidBody(
        "body", SpatialInertia.MakeFromCentralInertia(1.0, np.zeros(3), RotationalInertia(*inertia_diag))
    )
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    plant.Finalize()
    context = plant.CreateDefaultContext()
    plant.SetFreeBodyPose(context, body, RigidTransform(Quaternion(q0), np.zeros(3)))
    w0_W = rot.quat_to_rotmat(q0) @ w0_B
    plant.SetFreeBodySpatialVelocity(context, body, SpatialVelocity(w=w0_W, v=np.zeros(3)))
    # Accuracy alone is not enough here: with 10 s max steps MultibodyPlant's free body is
    # ~4e-9 rad off after 1000 s; with 0.05 s steps it matches scipy DOP853 to ~7e-12.
    simulator = make_simulator(plant, context, accuracy=1e-14, max_step_size=0.05)
    simulator.AdvanceTo(t_final)
    X_WB = plant.EvalBodyPoseInWorld(context, body)
    V_WB = plant.EvalBodySpatialVelocityInWorld(context, body)
    R_WB = X_WB.rotation()
    return R_WB.ToQuaternion().wxyz(), R_WB.matrix().T @ V_WB.rotational()


def test_agrees_with_multibody_plant_free_body():
    """Same body, same initial state, 1000 s: attitudes agree to 3e-10 rad (reached ~3e-11)
    and body rates to 2e-12 rad/s (reached ~2e-13)."""
    t_final = 1000.0
    q_mbp, w_mbp = multibody_free_body_final_state(np.diag(INERTIA), Q0, W0, t_final)
    x = run_rigid_body(INERTIA, Q0, W0, [t_final], accuracy=1e-10)[-1]
    assert angle_between(x[:4], q_mbp) < 3e-10
    assert np.max(np.abs(x[4:7] - w_mbp)) < 2e-12
    # Not vacuous: both bodies turned far from where they started.
    assert angle_between(Q0, q_mbp) > 1.0


# ----------------------------------------------------------------------------------
# Prescribed attitude motion
# ----------------------------------------------------------------------------------
def test_prescribed_constant_rate_about_one_axis_is_closed_form():
    """Constant 0.05 rad/s about z: q(t) = q0 ⊗ exp(0.05 t z) to 1e-11 rad (reached 5e-13)."""
    q0 = rot.rpy_to_quat([0.2, -0.4, 0.7])
    rate = 0.05
    motion = PrescribedAttitudeMotion.from_rate_profile((0.0, 0.0, rate), q_IB0=q0)
    times = np.array([1.0, 20.0, 63.0, 150.0])
    q, w, integral = run_outputs(motion, times)
    expected = rot.quat_multiply(q0, rot.rotvec_to_quat(np.outer(rate * times, [0.0, 0.0, 1.0])))
    assert np.max(angle_between(q, expected)) < 1e-11
    assert np.allclose(w, [0.0, 0.0, rate], rtol=0, atol=1e-15)
    assert np.allclose(integral[:, 2], rate * times, rtol=0, atol=1e-11)


def test_prescribed_sinusoidal_rate_about_one_axis_is_closed_form():
    """w_x = c + A cos(f t + phi): angle = c t + A/f (sin(f t + phi) - sin phi) to 1e-11 rad
    (reached 3e-13)."""
    c, a, f, phi = 0.01, 0.2, 0.3, 0.4
    motion = PrescribedAttitudeMotion.from_rate_profile((c, 0, 0), (a, 0, 0), (f, 0, 0), (phi, 0, 0))
    times = np.array([2.0, 7.5, 21.0, 60.0])
    q, w, integral = run_outputs(motion, times)
    angle = c * times + a / f * (np.sin(f * times + phi) - np.sin(phi))
    expected = rot.rotvec_to_quat(np.outer(angle, [1.0, 0.0, 0.0]))
    assert np.max(angle_between(q, expected)) < 1e-11
    assert np.allclose(w[:, 0], c + a * np.cos(f * times + phi), rtol=0, atol=1e-14)
    assert np.allclose(integral[:, 0], angle, rtol=0, atol=1e-11)


RPY_TIMES = np.array([0.0, 20.0, 50.0, 80.0])
RPY_DEG = np.array([[0.0, 0.0, 0.0], [10.0, -5.0, 30.0], [-20.0, 15.0, 90.0], [5.0, 40.0, -60.0]])


def rpy_interp(t):
    """Piecewise-linear roll/pitch/yaw (rad) and rates, held outside the breakpoints."""
    rpy = np.array([np.interp(t, RPY_TIMES, RPY_DEG[:, k] * DEG) for k in range(3)]).T
    seg = np.clip(np.searchsorted(RPY_TIMES, t, side="right") - 1, 0, len(RPY_TIMES) - 2)
    slopes = np.diff(RPY_DEG * DEG, axis=0) / np.diff(RPY_TIMES)[:, None]
    inside = (t > RPY_TIMES[0]) & (t < RPY_TIMES[-1])
    rates = np.where(inside[:, None], slopes[seg], 0.0)
    return rpy, rates


def test_prescribed_rpy_breakpoints_attitude_matches_interpolated_rpy():
    """Integrated attitude = rpy_to_quat(piecewise-linear rpy(t)) to 5e-9 rad (reached
    ~1e-9; the rate jumps at the breakpoints), including after the last breakpoint."""
    motion = PrescribedAttitudeMotion.from_rpy_breakpoints(RPY_TIMES, RPY_DEG * DEG)
    times = np.array([5.0, 19.0, 21.0, 35.0, 49.5, 60.0, 79.0, 80.0, 95.0])
    q, _, _ = run_outputs(motion, times, accuracy=1e-11, max_step=0.1)
    rpy, _ = rpy_interp(times)
    assert np.max(angle_between(q, rot.rpy_to_quat(rpy))) < 5e-9
    # Not vacuous: the attitude really moves between samples.
    assert angle_between(q[0], q[-1]) > 1.0


def test_prescribed_rpy_breakpoints_body_rate_matches_rpy_rates():
    """w_IB_B output = rpy_rates_to_body_rate(rpy, rpy_dot) = Drake's
    RollPitchYaw.CalcAngularVelocityInChildFromRpyDt, to 1e-14 rad/s, inside segments
    and (zero) after the last breakpoint."""
    motion = PrescribedAttitudeMotion.from_rpy_breakpoints(RPY_TIMES, RPY_DEG * DEG)
    times = np.array([3.0, 12.5, 27.0, 44.0, 51.0, 66.0, 79.5, 90.0])
    _, w, _ = run_outputs(motion, times, accuracy=1e-10, max_step=0.5)
    rpy, rates = rpy_interp(times)
    expected = rot.rpy_rates_to_body_rate(rpy, rates)
    drake = np.array(
        [RollPitchYaw(r).CalcAngularVelocityInChildFromRpyDt(rd) for r, rd in zip(rpy, rates, strict=True)]
    )
    assert np.allclose(w, expected, rtol=0, atol=1e-14)
    assert np.allclose(w, drake, rtol=0, atol=1e-14)
    assert np.allclose(w[-1], 0.0, atol=0)
    assert np.min(np.linalg.norm(w[:-1], axis=1)) > 1e-3


# ----------------------------------------------------------------------------------
# Inertia validation
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "inertia, what",
    [
        ([[10.0, 1.0, 0.0], [0.0, 20.0, 0.0], [0.0, 0.0, 30.0]], "symmetric"),
        ([10.0, 20.0, -30.0], "positive definite"),
        ([[10.0, 0.0, 0.0], [0.0, 20.0, 0.0], [0.0, 0.0, 0.0]], "positive definite"),
        ([1.0, 1.0, 3.0], "triangle inequality"),
        # Eigenvalues 1, 10, 19: 1 + 10 < 19.
        ([[10.0, 0.0, 0.0], [0.0, 10.0, 9.0], [0.0, 9.0, 10.0]], "triangle inequality"),
        ([10.0, np.nan, 30.0], "finite"),
        ([10.0, 20.0, np.inf], "finite"),
        ([10.0, 20.0], "finite"),
    ],
)
def test_validate_inertia_rejects_with_field_name(inertia, what):
    with pytest.raises(ValueError, match=r"plant\.inertia_kg_m2") as info:
        validate_inertia(inertia, field="plant.inertia_kg_m2")
    assert what in str(info.value)
    with pytest.raises(ValueError, match="inertia"):
        RigidBodyAttitudePlant(inertia)


@pytest.mark.parametrize(
    "inertia",
    [
        [10.0, 20.0, 30.0],
        [1.0, 1.0, 2.0],  # a thin plate: triangle inequality with equality
        [[20.0, 1.0, 0.5], [1.0, 20.0, -2.0], [0.5, -2.0, 30.0]],
    ],
)
def test_validate_inertia_accepts_physical_bodies(inertia):
    I = validate_inertia(inertia)
    assert I.shape == (3, 3)
    assert np.allclose(I, np.diag(inertia) if np.ndim(inertia) == 1 else inertia)


def test_set_inertia_round_trip():
    diagram, plant = rigid_body_rig(INERTIA)
    context = plant.CreateDefaultContext()
    plant.SetDefaultParametersAndState(context)
    assert np.array_equal(plant.GetInertia(context), INERTIA)
    plant.SetInertia(context, [1.0, 2.0, 2.5])
    assert np.array_equal(plant.GetInertia(context), np.diag([1.0, 2.0, 2.5]))
    with pytest.raises(ValueError, match="inertia"):
        plant.SetInertia(context, [1.0, 1.0, 3.0])


FULL_INERTIA = np.array([[20.0, 1.0, 0.5], [1.0, 20.0, -2.0], [0.5, -2.0, 30.0]])


@pytest.mark.parametrize("inertia, principal", [(INERTIA, True), (FULL_INERTIA, False)])
def test_derivatives_equal_euler_equations_in_both_forms(inertia, principal):
    """Principal-axes and general forms: the derivatives equal an independent numpy evaluation
    of ``w_dot = I^-1 (tau - w x I w)``, ``q_dot = 1/2 q ⊗ [0, w] + (1 - |q|^2) q``,
    ``theta_dot = w`` at random states (not unit quaternions, so the norm term is exercised),
    to 1e-13 relative; SetInertia changes them per context."""
    from drake_att.systems.plant import NORM_STABILIZATION_GAIN

    rng = np.random.default_rng(4)
    plant = RigidBodyAttitudePlant(inertia)
    assert plant.principal_axes is principal
    context = plant.CreateDefaultContext()
    plant.SetDefaultParametersAndState(context)
    for k in range(20):
        I = (
            inertia
            if k < 10
            else (np.diag(rng.uniform(5, 9, 3)) if principal else FULL_INERTIA + np.diag(rng.uniform(0, 3, 3)))
        )
        plant.SetInertia(context, I)
        q, w, tau = rng.normal(size=4), rng.normal(size=3), rng.normal(size=3)
        sub = plant.GetMutableSubsystemContext(plant._symbolic, context)
        sub.SetContinuousState(np.concatenate([q, w, rng.normal(size=3)]))
        plant.GetInputPort("torque_B").FixValue(context, tau)
        xdot = plant.EvalTimeDerivatives(context).CopyToVector()
        w_dot = np.linalg.solve(I, tau - np.cross(w, I @ w))
        q_dot = 0.5 * rot.quat_multiply(q, np.r_[0.0, w]) + NORM_STABILIZATION_GAIN * (1 - q @ q) * q
        expected = np.concatenate([q_dot, w_dot, w])
        assert np.allclose(xdot, expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())


def test_principal_axes_plant_takes_only_diagonal_inertias():
    plant = RigidBodyAttitudePlant(INERTIA)
    context = plant.CreateDefaultContext()
    with pytest.raises(ValueError, match=r"inertia: got .*principal axes.*full inertia"):
        plant.SetInertia(context, FULL_INERTIA)
    general = RigidBodyAttitudePlant(FULL_INERTIA)
    general_context = general.CreateDefaultContext()
    general.SetInertia(general_context, INERTIA)  # the general form takes any inertia
    assert np.array_equal(general.GetInertia(general_context), INERTIA)


def test_full_inertia_torque_free_conserves_energy_and_momentum():
    """The general form, 2000 s torque-free: energy and inertial angular momentum to 1e-10."""
    x = run_rigid_body(FULL_INERTIA, Q0, W0, [0.0, 1000.0, 2000.0], accuracy=1e-10)
    energy = [0.5 * s[4:7] @ FULL_INERTIA @ s[4:7] for s in x]
    momentum = [rot.quat_to_rotmat(s[:4]) @ (FULL_INERTIA @ s[4:7]) for s in x]
    assert np.allclose(energy, energy[0], rtol=1e-10, atol=0)
    assert np.allclose(momentum, momentum[0], rtol=0, atol=1e-10 * np.linalg.norm(momentum[0]))
    assert angle_between(x[0, :4], x[-1, :4]) > 0.5  # not vacuous: the body turned


# ----------------------------------------------------------------------------------
# Orbit / LVLH frame
# ----------------------------------------------------------------------------------
ORBIT = orb.CircularOrbit(500e3, inclination_rad=97.5 * DEG, raan_rad=30.0 * DEG, arg_latitude0_rad=20.0 * DEG)


def test_mean_motion_500_km_matches_paper_s3():
    """n = sqrt(mu / a^3) = 1.1068e-3 rad/s at 500 km: paper S3's w0 = 0.0011 rad/s (1%)."""
    n = ORBIT.mean_motion_rad_per_s
    assert abs(n - 0.0011) / 0.0011 < 0.01
    assert np.isclose(n, np.sqrt(3.986004418e14 / (6378137.0 + 500e3) ** 3), rtol=1e-14)
    assert abs(ORBIT.period_s - 94.6 * 60.0) < 10.0  # ~94.6 min


def test_lvlh_rate_from_finite_differences():
    """rotvec(q_IO(t-h)^-1 ⊗ q_IO(t+h)) / 2h = [0, -n, 0] to 1e-15 rad/s (reached 3e-17;
    exact for a constant-rate frame, so only rounding remains)."""
    h = 10.0
    n = ORBIT.mean_motion_rad_per_s
    for t in (0.0, 1234.5, 4000.0):
        q_step = rot.quat_multiply(rot.quat_conjugate(ORBIT.q_IO(t - h)), ORBIT.q_IO(t + h))
        w_fd = rot.quat_to_rotvec(q_step) / (2 * h)
        assert np.allclose(w_fd, [0.0, -n, 0.0], rtol=0, atol=1e-15)
        assert np.allclose(w_fd, ORBIT.w_IO_O(), rtol=0, atol=1e-15)


def kepler_position_I(orbit, t):
    """Independent circular-orbit position: Rz(RAAN) Rx(i) [cos u, sin u, 0] a."""
    u = orbit.arg_latitude0_rad + orbit.mean_motion_rad_per_s * t
    O, i = orbit.raan_rad, orbit.inclination_rad
    return orbit.semi_major_axis_m * np.array(
        [
            np.cos(O) * np.cos(u) - np.sin(O) * np.sin(u) * np.cos(i),
            np.sin(O) * np.cos(u) + np.cos(O) * np.sin(u) * np.cos(i),
            np.sin(u) * np.sin(i),
        ]
    )


@pytest.mark.parametrize("t", [0.0, 700.0, 2500.0])
def test_lvlh_axes_nadir_velocity_and_negative_orbit_normal(t):
    """z_O = -r/|r| (nadir), x_O = v/|v| (velocity by finite differences of position_I),
    y_O = -(r x v)/|r x v| (all to 1e-12; reached 2e-13); position_I equals the Kepler
    position to 1e-6 m (reached 2e-9 m); |v| = n a to 1e-7 (FD truncation 5e-8)."""
    R_IO = rot.quat_to_rotmat(ORBIT.q_IO(t))
    r = kepler_position_I(ORBIT, t)
    assert np.allclose(ORBIT.position_I(t), r, rtol=0, atol=1e-6)
    h = 0.5
    v = (ORBIT.position_I(t + h) - ORBIT.position_I(t - h)) / (2 * h)  # O(h^2 n^2) ~ 1e-7 rel.
    a, n = ORBIT.semi_major_axis_m, ORBIT.mean_motion_rad_per_s
    assert abs(np.linalg.norm(v) - n * a) / (n * a) < 1e-7
    assert np.allclose(R_IO[:, 2], -r / np.linalg.norm(r), rtol=0, atol=1e-12)
    assert np.allclose(R_IO[:, 0], v / np.linalg.norm(v), rtol=0, atol=1e-12)
    normal = np.cross(r, v)
    assert np.allclose(R_IO[:, 1], -normal / np.linalg.norm(normal), rtol=0, atol=1e-12)
    # The orbit normal makes the inclination with the inertial z axis.
    inclination = np.arccos(normal[2] / np.linalg.norm(normal))
    assert abs(inclination - ORBIT.inclination_rad) < 1e-12


def test_orbit_rejects_bad_altitude():
    with pytest.raises(ValueError, match="altitude"):
        orb.CircularOrbit(-1.0)
    with pytest.raises(ValueError, match="altitude"):
        orb.CircularOrbit(float("nan"))
