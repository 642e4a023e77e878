"""The orbit-pointing controller of the truth: the body follows the real orbit's LVLH frame (a
J2-perturbed, eccentric Kepler orbit), a constant disturbance leaves the steady offset the PD law
predicts (tau / (I wn^2) per axis), the random torque makes a seed-determined jitter, and bad
settings are one-line errors naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.orbit_propagators import KeplerOrbit
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.systems.attitude_control import orbit_frame_rate_I

INERTIA = [0.042, 0.042, 0.0067]
WN = 0.1
DEG = np.pi / 180


def _scenario(torque=(0.0, 0.0, 0.0), noise=0.0, rpy=(0.0, 0.0, 0.0), duration=1500.0, control=None, seed=1, j2=True):
    control = (
        control
        or f"{{natural_frequency_rad_per_s: {WN}, damping_ratio: 0.7, period_s: 1.0, torque_noise_N_m: {noise}}}"
    )
    text = f"""
name: control_test
duration_s: {duration}
seed: {seed}
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}}
orbit: !KeplerOrbitConfig {{epoch_utc: "2026-06-21T00:00:00Z", semi_major_axis_km: 6928.137,
                           eccentricity: 0.01, inclination_deg: 97.6, j2: {str(j2).lower()}}}
plant: !RigidBodyConfig
  inertia_kg_m2: {INERTIA}
  initial_attitude_rpy_deg: {list(rpy)}
  disturbance_torque_N_m: {[float(x) for x in torque]}
  attitude_control: {control}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0}}
"""
    return cfg.load_scenario(text=text)


def _lvlh_from_definition(t, j2=True):
    """The LVLH frame from an independent Kepler orbit: z to nadir, y against the orbit normal."""
    orbit = KeplerOrbit(6928.137e3, 0.01, 97.6 * DEG, 0.0, 0.0, 0.0, j2=j2)
    r, v = orbit.position_velocity_I(t)
    z = -r / np.linalg.norm(r, axis=-1, keepdims=True)
    y = -np.cross(r, v)
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)  # columns: R_IO


def _truth(scenario, seed=None):
    log = ScenarioDiagram(scenario).simulate(seed)
    t, q = (
        log.signals["truth/q_IB"]
        if "truth/q_IB" in log.signals
        else next(v for k, v in log.signals.items() if k.endswith("/q_IB"))
    )
    return t, q, log


def _errors_B(t, q, j2=True):
    """Rotation vector of the body relative to the independent LVLH frame, in the body (rad)."""
    R_IO = _lvlh_from_definition(t, j2)
    R_IB = rot.quat_to_rotmat(q)
    R_OB = np.swapaxes(R_IO, -1, -2) @ R_IB
    return rot.rotmat_to_rotvec(R_OB)


def test_body_follows_the_real_lvlh_frame_from_an_offset():
    """From a 3-deg offset the loop settles (wn = 0.1 rad/s: ~60 s) and then tracks the frame of
    a J2-perturbed orbit with e = 0.01 (its rate varies by 2e over an orbit) to 0.01 deg."""
    t, q, _ = _truth(_scenario(rpy=(3.0, -2.0, 1.0)))
    err = np.degrees(np.linalg.norm(_errors_B(t, q), axis=-1))
    assert err[0] == pytest.approx(
        np.degrees(np.linalg.norm(rot.quat_to_rotvec(rot.rpy_to_quat(np.r_[3, -2, 1] * DEG)))), rel=1e-6
    )
    assert err[t > 150].max() < 0.01
    assert err[t > 150].max() > 1e-6  # not trivially zero: the eccentric orbit's rate changes


def test_initial_rate_is_the_orbit_frames_rate():
    """With no offset, the body starts turning with the orbit frame: no transient at all."""
    t, q, log = _truth(_scenario(duration=200.0))
    err = np.degrees(np.linalg.norm(_errors_B(t, q), axis=-1))
    assert err.max() < 0.005
    w = next(v for k, v in log.signals.items() if k.endswith("/w_IB_B"))[1]
    orbit = KeplerOrbit(6928.137e3, 0.01, 97.6 * DEG, 0.0, 0.0, 0.0, j2=True)
    r, v = orbit.position_velocity_I(0.0)
    w_O = np.cross(r, v) / (r @ r)  # the orbit normal's rate, from the definition
    np.testing.assert_allclose(rot.quat_to_rotmat(q[0]).T @ w_O, w[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(orbit_frame_rate_I(r, v), w_O, rtol=1e-14)


def test_constant_disturbance_leaves_the_pd_steady_offset():
    """A PD loop under a constant torque settles at ``theta_i = tau_i / (I_i wn^2)`` per axis
    (two-body orbit: with secular J2 the propagator's velocity misses the drift of the elements,
    ~1e-6 rad/s of frame rate, which the damping term turns into a 2e-5 rad pitch lag)."""
    tau = np.array([2e-7, -1e-7, 5e-8])
    t, q, _ = _truth(_scenario(torque=tau, duration=400.0, j2=False))
    steady = _errors_B(t, q, j2=False)[t > 250].mean(axis=0)
    np.testing.assert_allclose(steady, tau / (np.array(INERTIA) * WN**2), rtol=0.03, atol=2e-6)


def test_random_torque_jitter_is_seed_determined_and_of_the_loops_size():
    """White torque sigma per 1-s hold: the angle's variance of a second-order loop driven by
    white acceleration of spectral density ``S = (sigma / I)^2 T`` is ``S / (4 zeta wn^3)``; the
    z axis (smallest inertia) in a 2000-s run is within a factor 1.6 of it. Same seed, same jitter."""
    sigma = 2e-7
    s = _scenario(noise=sigma, duration=2000.0)
    t, q, _ = _truth(s)
    z = _errors_B(t, q)[t > 200, 2]
    predicted = np.sqrt((sigma / INERTIA[2]) ** 2 * 1.0 / (4 * 0.7 * WN**3))
    assert predicted / 1.6 < z.std() < predicted * 1.6
    _, q2, _ = _truth(s)
    np.testing.assert_array_equal(q, q2)
    _, q3, _ = _truth(s, seed=2)
    assert np.abs(q3 - q).max() > 1e-6


@pytest.mark.parametrize(
    "control, message",
    [
        ("{natural_frequency_rad_per_s: -0.1}", "plant.attitude_control.natural_frequency_rad_per_s: got -0.1"),
        ("{damping_ratio: 0.0}", "plant.attitude_control.damping_ratio: got 0"),
        ("{torque_noise_N_m: -1.0}", "plant.attitude_control.torque_noise_N_m: got -1"),
        ("{natural_frequency_rad_per_s: 1.0, period_s: 1.0}", "must be <= 0.5"),
        ("{offset_rpy_deg: [1.0, 2.0]}", "plant.attitude_control.offset_rpy_deg"),
    ],
)
def test_bad_control_settings_are_one_line_errors(control, message):
    with pytest.raises(cfg.ConfigError) as e:
        _scenario(control=control)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_control_without_an_orbit_is_refused():
    text = """
name: no_orbit
plant: !RigidBodyConfig {attitude_control: {}}
"""
    with pytest.raises(cfg.ConfigError, match=r"^plant.attitude_control: .*needs an orbit section"):
        cfg.load_scenario(text=text)


def test_the_law_is_its_formula():
    """``tau = I (-wn^2 dtheta - 2 zeta wn (w - R_BI w_IO)) + w x I w`` for a turned body at a
    high rate (so the gyroscopic term matters), each term computed here."""
    from drake_att.systems.attitude_control import PdAttitudeLaw

    I = np.array([[0.05, 0.001, 0.0], [0.001, 0.04, 0.002], [0.0, 0.002, 0.01]])
    law = PdAttitudeLaw(I, 0.2, 0.8, np.array([1.0, 0.0, 0.0, 0.0]))
    q_IO = rot.rpy_to_quat(np.radians([10.0, -20.0, 30.0]))
    dtheta_true = np.radians([2.0, -1.0, 3.0])
    q_IB = rot.quat_multiply(q_IO, rot.rotvec_to_quat(dtheta_true))
    r, v = np.array([7e6, 1e5, -2e5]), np.array([100.0, 7.5e3, 10.0])
    w = np.radians([5.0, -3.0, 8.0])
    R_IB = rot.quat_to_rotmat(q_IB)
    w_ref = R_IB.T @ (np.cross(r, v) / (r @ r))
    expected = I @ (-0.04 * dtheta_true - 2 * 0.8 * 0.2 * (w - w_ref)) + np.cross(w, I @ w)
    np.testing.assert_allclose(law.torque(q_IB, w, q_IO, r, v), expected, rtol=1e-10, atol=1e-15)


@pytest.mark.parametrize("period, noise", [(0.0, 0.0), (-1.0, 0.0), (float("nan"), 0.0), (1.0, -1e-6)])
def test_the_controller_refuses_a_bad_period_or_noise(period, noise):
    from drake_att.systems.attitude_control import OrbitPointingController, PdAttitudeLaw

    law = PdAttitudeLaw(np.eye(3), 0.1, 0.7, np.array([1.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"^attitude_control\.(period_s|torque_noise_N_m): got"):
        OrbitPointingController(law, period, noise)
