"""The coarse sensors (sun sensor, magnetometer) and vector filters fed by several vector sensors.

* The magnetometer's noise-free field equals ppigrf's IGRF at the same position and epoch, the
  GCRS -> ITRS rotation taken from astropy here (not the library's erfa chain), to 1 nT; its
  magnitude along a 500 km orbit lies in the LEO range.
* The sun sensor's noise-free direction equals the Sun direction from astropy and the orbit, in the
  sensor frame; its validity drops at eclipse entry and returns at exit within one sample of an
  independent cylindrical-shadow computation; outside the field of view it is invalid.
* Noise statistics over 4000 samples against the configured sigmas, bias, scale factor and
  misalignment: means within 4.5 standard errors, variances within the chi-square 1e-5 quantiles.
* An MRP EKF fed by a gyro, the sun sensor and the magnetometer (no star tracker) converges in
  sunlight; its NEES over three seeds is consistent; eclipse samples and a faulted sample are
  counted as skipped.
* Bad input: one-line ConfigErrors naming the field.
"""

from __future__ import annotations

import datetime

import numpy as np
import pytest
from scipy import stats

from drake_att import rotations as rot
from drake_att.contract import STATUS_SKIPPED, STATUS_T_ESTIMATE
from drake_att.orbit_propagators import KeplerOrbit
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.systems.coarse_sensors import ECLIPSE, OUT_OF_FOV, Magnetometer, SunSensor

R_E = 6378137.0
A_M = R_E + 500e3
INC_DEG = 97.4
EPOCH = "2026-03-20T12:00:00Z"
EPOCH_DT = datetime.datetime(2026, 3, 20, 12, 0, 0)
SUN_MOUNT_RPY_DEG = [0.0, 30.0, 0.0]  # the sun sensor's head tilted from the body z


def _astropy_time(t_s):
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False
    from astropy import units as u

    return Time(EPOCH.rstrip("Z"), scale="utc") + np.atleast_1d(t_s) * u.s


def _sun_I(t_s) -> np.ndarray:
    """The Sun's geocentric GCRS position (m), from astropy's built-in ephemeris, (n, 3)."""
    from astropy import units as u
    from astropy.coordinates import get_body, solar_system_ephemeris

    with solar_system_ephemeris.set("builtin"):
        return get_body("sun", _astropy_time(t_s)).cartesian.xyz.to_value(u.m).T


def _gcrs_to_itrs(t_s: float) -> np.ndarray:
    """R_EI at one time from astropy's frame transformation (geocentric: a rotation), 3x3."""
    from astropy import units as u
    from astropy.coordinates import GCRS, ITRS, CartesianRepresentation

    when = _astropy_time(t_s)[0]
    basis = CartesianRepresentation(np.eye(3) * 7000.0 * u.km)
    itrs = GCRS(basis, obstime=when).transform_to(ITRS(obstime=when))
    return itrs.cartesian.xyz.to_value(u.km) / 7000.0  # column j: the image of GCRS axis j


def _orbit(mean_anomaly_deg: float) -> KeplerOrbit:
    return KeplerOrbit(A_M, 0.0, np.radians(INC_DEG), 0.0, 0.0, np.radians(mean_anomaly_deg))


def _rpy_pointing_at_sun(mean_anomaly_deg: float) -> list:
    """Roll/pitch/yaw (relative to LVLH at t = 0) of a body whose sun-sensor boresight points at the Sun."""
    sun = _sun_I(0.0)[0]
    z = sun / np.linalg.norm(sun)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R_IS = np.stack([x, np.cross(z, x), z], axis=-1)
    R_BS = rot.quat_to_rotmat(rot.rpy_to_quat(np.radians(SUN_MOUNT_RPY_DEG)))
    q_IB = rot.rotmat_to_quat(R_IS @ R_BS.T)
    q_OB = rot.quat_multiply(rot.quat_conjugate(_orbit(mean_anomaly_deg).q_IO(0.0)), q_IB)
    return [float(v) for v in np.degrees(rot.quat_to_rpy(q_OB))]


def _scenario(body: str, mean_anomaly_deg: float, duration_s: float, rate_z_deg_per_s: float = 0.0) -> cfg.Scenario:
    rpy = _rpy_pointing_at_sun(mean_anomaly_deg)
    text = f"""
name: coarse_sensors_test
duration_s: {duration_s!r}
seed: 1
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 1.0}}
orbit: !KeplerOrbitConfig {{epoch_utc: '{EPOCH}', semi_major_axis_km: {A_M / 1e3!r}, inclination_deg: {INC_DEG},
                           mean_anomaly_deg: {mean_anomaly_deg!r}}}
plant: !PrescribedRateConfig {{initial_attitude_rpy_deg: {rpy}, constant_deg_per_s: [0.0, 0.0, {rate_z_deg_per_s!r}]}}
{body.replace("RPY0", str(rpy))}
scoring: {{score_from_s: 0.0}}
"""
    return cfg.load_scenario(text=text)


# ======================================================================================
# Geometry: a run through an eclipse with (nearly) noise-free sensors
# ======================================================================================
GEOMETRY_M0_DEG = 100.0  # eclipse from ~190 s to ~2330 s (beta angle ~0)
GEOMETRY_DURATION_S = 2500.0


@pytest.fixture(scope="module")
def geometry_run():
    body = f"""
sensors:
- !SunSensorConfig {{name: sun, period_s: 1.0, boresight_sigma_deg: 1.0e-9,
                    mounting: {{rpy_deg: {SUN_MOUNT_RPY_DEG}}}}}
- !MagnetometerConfig {{name: mag, period_s: 50.0, sigma_nT: 1.0e-6, mounting: {{rpy_deg: [10.0, -20.0, 30.0]}}}}
"""
    return ScenarioDiagram(_scenario(body, GEOMETRY_M0_DEG, GEOMETRY_DURATION_S)).simulate(1)


def _truth_q_IB(run, t):
    times, q = run.times("prescribed_motion/q_IB"), run.values("prescribed_motion/q_IB")
    index = np.searchsorted(times, t - 1e-9)
    assert np.allclose(times[index], t)
    return q[index]


def test_magnetometer_field_is_ppigrf_at_the_position_and_epoch(geometry_run):
    import ppigrf

    log = geometry_run.values("mag/magnetic_field")
    t = log[:, 0]
    assert np.all(log[:, 1] == 1.0) and len(t) == 51
    orbit = _orbit(GEOMETRY_M0_DEG)
    R_BS = rot.quat_to_rotmat(rot.rpy_to_quat(np.radians([10.0, -20.0, 30.0])))
    worst = 0.0
    magnitudes = []
    for k in range(0, len(t), 5):
        r_I = orbit.position_velocity_I(t[k])[0]
        R_EI = _gcrs_to_itrs(t[k])
        r_E = R_EI @ r_I / 1e3
        radius = np.linalg.norm(r_E)
        colat = np.degrees(np.arccos(r_E[2] / radius))
        lon = np.degrees(np.arctan2(r_E[1], r_E[0]))
        b_r, b_t, b_p = (float(np.ravel(x)[0]) for x in ppigrf.igrf_gc(radius, colat, lon, EPOCH_DT))
        th, ph = np.radians(colat), np.radians(lon)
        e_r = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
        e_t = np.array([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), -np.sin(th)])
        e_p = np.array([-np.sin(ph), np.cos(ph), 0.0])
        B_I = R_EI.T @ (b_r * e_r + b_t * e_t + b_p * e_p)
        R_IB = rot.quat_to_rotmat(_truth_q_IB(geometry_run, t[k]))
        expected_S = (R_IB @ R_BS).T @ B_I
        worst = max(worst, float(np.max(np.abs(log[k, 2:] - expected_S))))
    magnitudes = np.linalg.norm(log[:, 2:], axis=1)
    assert worst < 1.0, worst  # nT
    assert 15e3 < magnitudes.min() and magnitudes.max() < 60e3, (magnitudes.min(), magnitudes.max())


def test_sun_sensor_direction_eclipse_entry_and_exit(geometry_run):
    log = geometry_run.values("sun/sun_sensor_measurement")
    status = geometry_run.values("sun/sun_sensor_status")
    t = log[:, 0]
    valid = log[:, 1] == 1.0
    np.testing.assert_array_equal(valid, status[:, 1] == 0)
    assert not np.any(status[:, 1].astype(int) & OUT_OF_FOV)  # the head points at the Sun throughout
    # Independent shadow: cylindrical, the Sun from astropy (interpolated between 100-s nodes), the
    # orbit's position; transitions located to 0.05 s.
    orbit = _orbit(GEOMETRY_M0_DEG)
    nodes = np.arange(0.0, GEOMETRY_DURATION_S + 100.0, 100.0)
    sun_nodes = _sun_I(nodes)
    fine = np.arange(0.0, GEOMETRY_DURATION_S, 0.05)
    sun = np.stack([np.interp(fine, nodes, sun_nodes[:, j]) for j in range(3)], axis=-1)
    s_hat = sun / np.linalg.norm(sun, axis=1)[:, None]
    r = np.stack([orbit.position_velocity_I(x)[0] for x in fine])
    along = np.sum(r * s_hat, axis=1)
    across2 = np.sum(r * r, axis=1) - along**2
    shadow = (along < 0) & (across2 < R_E**2)
    edges = np.flatnonzero(np.diff(shadow.astype(int)))
    assert len(edges) == 2, edges
    entry, exit_ = fine[edges[0] + 1], fine[edges[1] + 1]
    sensor_edges = np.flatnonzero(np.diff(valid.astype(int)))
    assert len(sensor_edges) == 2, t[sensor_edges]
    first_dark, first_lit = t[sensor_edges[0] + 1], t[sensor_edges[1] + 1]
    assert abs(first_dark - entry) <= 1.0 and abs(first_lit - exit_) <= 1.0, (first_dark, entry, first_lit, exit_)
    assert np.all(status[~valid, 1] == ECLIPSE)
    # The measured direction in sunlight: the Sun seen from the spacecraft, in S.
    R_BS = rot.quat_to_rotmat(rot.rpy_to_quat(np.radians(SUN_MOUNT_RPY_DEG)))
    lit = np.flatnonzero(valid)[:: max(1, int(valid.sum()) // 8)]
    sun_at = _sun_I(t[lit])
    for k, sun_k in zip(lit, sun_at, strict=True):
        to_sun = sun_k - orbit.position_velocity_I(t[k])[0]
        R_IS = rot.quat_to_rotmat(_truth_q_IB(geometry_run, t[k])) @ R_BS
        expected = R_IS.T @ to_sun / np.linalg.norm(to_sun)
        assert np.linalg.norm(log[k, 2:] - expected) < 1e-6, (t[k], log[k, 2:], expected)


# ======================================================================================
# The systems alone: noise statistics, field of view
# ======================================================================================
N_SAMPLES = 4000


def _chi2_bounds(n: int, p: float = 1e-5):
    return stats.chi2.ppf(p / 2, n - 1) / (n - 1), stats.chi2.ppf(1 - p / 2, n - 1) / (n - 1)


def _sun_sensor_samples(theta_deg: float, sigma_rad: float, n: int = N_SAMPLES):
    """(directions (n, 3), sigma_rad (n,), valid (n,), causes) of a head (identity mount, identity
    attitude) seeing the Sun at ``theta_deg`` from its boresight in the x-z plane."""
    sensor = SunSensor("sun", 1.0, sigma_boresight_rad=sigma_rad)
    context = sensor.CreateDefaultContext()
    th = np.radians(theta_deg)
    r = np.array([0.0, 0.0, 7000e3])  # 7000 km over the pole; the Sun far along (sin th, 0, cos th)
    sensor.GetInputPort("q_IB").FixValue(context, [1.0, 0.0, 0.0, 0.0])
    sensor.GetInputPort("r_I").FixValue(context, r)
    sensor.GetInputPort("r_sun_I").FixValue(context, r + 1.5e11 * np.array([np.sin(th), 0.0, np.cos(th)]))
    port = sensor.GetOutputPort("vector_observations")
    dirs, sigmas, valid = [], [], []
    for k in range(1, n + 1):
        context.SetTime(float(k))
        obs = port.Eval(context)
        dirs.append(obs.directions_S[0])
        sigmas.append(obs.sigma_rad)
        valid.append(obs.valid)
        assert obs.time_s == float(k)
    return np.array(dirs), np.array(sigmas), np.array(valid), sensor.causes(context)


def test_sun_sensor_noise_grows_as_one_over_cosine_with_the_configured_sigma():
    sigma0 = np.radians(0.5)
    theta = 50.0
    dirs, sigmas, valid, causes = _sun_sensor_samples(theta, sigma0)
    assert valid.all() and causes == 0
    th = np.radians(theta)
    s = np.array([np.sin(th), 0.0, np.cos(th)])
    e1 = np.array([np.cos(th), 0.0, -np.sin(th)])  # tangent basis at s
    e2 = np.array([0.0, 1.0, 0.0])
    errors = np.stack([dirs @ e1, dirs @ e2], axis=-1)  # small angles (rad)
    expected_sigma = sigma0 / np.cos(th)
    lo, hi = _chi2_bounds(N_SAMPLES)
    for j in range(2):
        assert abs(errors[:, j].mean()) < 4.5 * expected_sigma / np.sqrt(N_SAMPLES)
        ratio = errors[:, j].var(ddof=1) / expected_sigma**2
        assert lo < ratio < hi, (j, ratio, lo, hi)
    assert np.all(np.abs(np.linalg.norm(dirs, axis=1) - 1.0) < 1e-12)
    assert np.all(dirs @ s > np.cos(8.0 * expected_sigma))  # within 8 sigma of the Sun
    np.testing.assert_allclose(np.median(sigmas), expected_sigma, rtol=0.02)


def test_sun_outside_the_field_of_view_is_invalid():
    _, _, valid_in, causes_in = _sun_sensor_samples(59.5, 1e-9, n=3)
    _, _, valid_out, causes_out = _sun_sensor_samples(60.5, 1e-9, n=3)
    assert valid_in.all() and causes_in == 0
    assert not valid_out.any() and causes_out == OUT_OF_FOV


def test_magnetometer_noise_bias_scale_factor_and_misalignment():
    sigma = 100e-9
    bias = np.array([300e-9, -200e-9, 50e-9])
    scale = np.array([2e-3, -1e-3, 5e-4])
    M = np.array([[0.0, 1e-3, -2e-3], [5e-4, 0.0, 1e-3], [-1e-3, 2e-3, 0.0]])
    q_BS = rot.rpy_to_quat(np.radians([10.0, 20.0, -30.0]))
    q_IB = rot.rpy_to_quat(np.radians([-40.0, 5.0, 70.0]))
    B_I = np.array([20e-6, -15e-6, 30e-6])
    mag = Magnetometer("mag", 0.1, q_BS, sigma, bias, scale, M)
    context = mag.CreateDefaultContext()
    mag.GetInputPort("q_IB").FixValue(context, q_IB)
    mag.GetInputPort("B_I").FixValue(context, B_I)
    port = mag.GetOutputPort("magnetic_field")
    samples = []
    for k in range(1, N_SAMPLES + 1):
        context.SetTime(0.1 * k)
        samples.append(port.Eval(context).copy())
    samples = np.array(samples)
    assert np.allclose(samples[:, 0], 0.1 * np.arange(1, N_SAMPLES + 1)) and np.all(samples[:, 1] == 1.0)
    R_SI = (rot.quat_to_rotmat(q_IB) @ rot.quat_to_rotmat(q_BS)).T
    expected_mean_nT = ((np.eye(3) + np.diag(scale) + M) @ R_SI @ B_I + bias) * 1e9
    B = samples[:, 2:]
    sigma_nT = sigma * 1e9
    assert np.all(np.abs(B.mean(axis=0) - expected_mean_nT) < 4.5 * sigma_nT / np.sqrt(N_SAMPLES))
    lo, hi = _chi2_bounds(N_SAMPLES)
    cov = np.cov(B.T)
    for j in range(3):
        assert lo < cov[j, j] / sigma_nT**2 < hi, (j, cov[j, j])
    corr = np.corrcoef(B.T)
    assert np.all(np.abs(corr[np.triu_indices(3, 1)]) < 4.5 / np.sqrt(N_SAMPLES))
    # The observation: B_S / |B_S|, the reference B_I / |B_I|, sigma / |B_S|.
    obs = mag.GetOutputPort("vector_observations").Eval(context)
    b = B[-1] * 1e-9
    np.testing.assert_allclose(obs.directions_S[0], b / np.linalg.norm(b), atol=1e-15)
    np.testing.assert_allclose(obs.references_I[0], B_I / np.linalg.norm(B_I), atol=1e-15)
    np.testing.assert_allclose(obs.sigma_rad, sigma / np.linalg.norm(b), rtol=1e-12)


# ======================================================================================
# An MRP EKF on a gyro, the sun sensor and the magnetometer
# ======================================================================================
EKF_M0_DEG = 60.0  # sunlit to ~820 s, then eclipse
EKF_DURATION_S = 1000.0


@pytest.fixture(scope="module")
def ekf_diagram():
    body = f"""
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.15, rrw_deg_per_h15: 0.02,
               initial_bias_deg_per_h: [3.0, -2.0, 1.0]}}
- !SunSensorConfig {{name: sun, period_s: 1.0, mounting: {{rpy_deg: {SUN_MOUNT_RPY_DEG}}}}}
- !SensorFaultsConfig {{name: sun_faults, sensor: sun, outlier_angle_deg: 20.0}}
- !MagnetometerConfig {{name: mag, period_s: 2.0}}
estimators:
- !MrpEkfConfig {{name: ekf, star_tracker: "", vector_sensors: [sun, mag], initial_attitude_rpy_deg: RPY0,
                 initial_attitude_sigma_deg: 5.0, initial_bias_sigma_deg_per_h: 5.0}}
"""
    scenario = _scenario(body, EKF_M0_DEG, EKF_DURATION_S, rate_z_deg_per_s=0.05)
    # the estimate starts 3 deg off the truth about each axis
    scenario.estimators[0].initial_attitude_rpy_deg = [v + 3.0 for v in scenario.plant.initial_attitude_rpy_deg]
    return ScenarioDiagram(scenario)


def _attitude_error_deg(run, name="ekf"):
    from drake_att.analysis.metrics import compute_metrics  # noqa: F401  (the one error definition lives there)

    q = run.values("prescribed_motion/q_IB")
    q_hat = run.values(f"{name}/q_IB_hat")
    n = min(len(q), len(q_hat))
    err = rot.quat_multiply(rot.quat_conjugate(q_hat[:n]), q[:n])
    return np.degrees(2.0 * np.arcsin(np.clip(np.linalg.norm(err[:, 1:], axis=1), 0.0, 1.0)))


def test_mrp_ekf_on_sun_sensor_and_magnetometer_converges_consistently_and_skips_eclipse(ekf_diagram):
    """Sunlit window 300-800 s: attitude error < 1 deg (the sensors' 0.5 deg and ~0.25 deg noise over
    hundreds of samples). NEES (6 dof) averaged over the window and three seeds: its sampling
    spread is wide (hundreds of strongly correlated steps, ~10 independent stretches per run), so
    the bound [6/2.5, 6 * 2.5] catches a covariance wrong by a factor 2.5 in variance, not finer.
    Skipped: exactly the sun sensor's eclipse samples at the filter's steps (the magnetometer is never
    invalid)."""
    nees_means = []
    for seed in (1, 2, 3):
        run = ekf_diagram.simulate(seed)
        t = run.times("ekf/q_IB_hat")
        error = _attitude_error_deg(run)
        sunlit = (t >= 300.0) & (t <= 800.0)
        assert error[sunlit].max() < 1.0, error[sunlit].max()
        from drake_att.analysis.metrics import compute_metrics

        nees_means.append(compute_metrics(run)["estimators"]["ekf"]["nees_mean"])
        sun = run.values("sun/sun_sensor_measurement")
        dark = sun[(sun[:, 1] == 0.0) & (sun[:, 0] > 0.0), 0]
        assert len(dark) > 100  # the run ends in eclipse
        last = run.values("ekf/status")[-1]
        # every eclipse sample up to the estimate's own time was skipped, and nothing else
        assert last[STATUS_SKIPPED] == np.count_nonzero(dark <= last[STATUS_T_ESTIMATE]), (last, len(dark))
    mean = float(np.mean(nees_means))
    assert 6.0 / 2.5 < mean < 6.0 * 2.5, nees_means


def test_a_sun_sensor_outlier_is_rejected_and_counted(ekf_diagram):
    clean = ekf_diagram.simulate(1)
    faulted = ekf_diagram.simulate(1, overrides=["sensors.sun_faults.outlier_times_s=[500.0]"])

    def skipped(run):
        return run.values("ekf/status")[-1, STATUS_SKIPPED]

    assert skipped(faulted) == skipped(clean) + 1
    t = faulted.times("ekf/q_IB_hat")
    assert _attitude_error_deg(faulted)[(t >= 300.0) & (t <= 800.0)].max() < 1.0  # the 20 deg outlier left no mark


# ======================================================================================
# Bad input
# ======================================================================================
def _bad(sensor_yaml: str, orbit_yaml: str | None = None, estimator_yaml: str = ""):
    orbit = orbit_yaml if orbit_yaml is not None else f"orbit: !KeplerOrbitConfig {{epoch_utc: '{EPOCH}'}}"
    text = f"""
name: bad
duration_s: 10.0
{orbit}
plant: !PrescribedRateConfig {{}}
sensors:
- !GyroConfig {{name: gyro, arw_deg_per_rt_h: 0.1}}
{sensor_yaml}
estimators: [{estimator_yaml}]
scoring: {{score_from_s: 0.0}}
"""
    with pytest.raises(cfg.ConfigError) as e:
        cfg.load_scenario(text=text)
    message = str(e.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(
    "sensor_yaml, field",
    [
        ("- !SunSensorConfig {name: sun, period_s: 0.0}", "sensors[1] (sun).period_s"),
        ("- !SunSensorConfig {name: sun, boresight_sigma_deg: 0.0}", "sensors[1] (sun).boresight_sigma_deg"),
        ("- !SunSensorConfig {name: sun, fov_half_angle_deg: 90.0}", "sensors[1] (sun).fov_half_angle_deg"),
        ("- !SunSensorConfig {name: sun, min_sun_fraction: 0.0}", "sensors[1] (sun).min_sun_fraction"),
        ("- !SunSensorConfig {name: sun, albedo: 1.5}", "sensors[1] (sun).albedo"),
        ("- !SunSensorConfig {name: sun, dropout_probability: 1.0}", "sensors[1] (sun).dropout_probability"),
        ("- !SunSensorConfig {name: sun, outage_windows_s: [[5.0, 1.0]]}", "sensors[1] (sun).outage_windows_s[0]"),
        ("- !SunSensorConfig {name: sun, mounting: {rpy_deg: [1.0, 2.0]}}", "sensors[1] (sun).mounting.rpy_deg"),
        ("- !MagnetometerConfig {name: mag, sigma_nT: -1.0}", "sensors[1] (mag).sigma_nT"),
        ("- !MagnetometerConfig {name: mag, sigma_nT: 1.0e9}", "sensors[1] (mag).sigma_nT"),
        ("- !MagnetometerConfig {name: mag, bias_nT: [1.0, 2.0]}", "sensors[1] (mag).bias_nT"),
        ("- !MagnetometerConfig {name: mag, misalignment_urad: [1.0]}", "sensors[1] (mag).misalignment_urad"),
        ("- !MagnetometerConfig {name: mag, scale_factor_error_ppm: [0, 0, 1e9]}", "scale_factor_error_ppm"),
    ],
)
def test_a_bad_coarse_sensor_field_is_one_line_naming_it(sensor_yaml, field):
    message = _bad(sensor_yaml)
    assert message.startswith(field) or field in message.split(":")[0], message


@pytest.mark.parametrize("tag", ["SunSensorConfig", "MagnetometerConfig"])
@pytest.mark.parametrize(
    "orbit_yaml, kind", [("orbit: null", "no orbit"), ("orbit: {altitude_km: 500.0}", "without an epoch")]
)
def test_a_coarse_sensor_without_an_orbit_epoch_is_refused(tag, orbit_yaml, kind):
    message = _bad(f"- !{tag} {{name: c}}", orbit_yaml)
    assert message.startswith("sensors[1] (c): ") and kind in message and "!KeplerOrbitConfig" in message, message


@pytest.mark.parametrize(
    "estimator_yaml, field",
    [
        ('!MrpEkfConfig {name: ekf, star_tracker: ""}', "estimators[0] (ekf).star_tracker"),
        (
            '!MrpEkfConfig {name: ekf, star_tracker: "", vector_sensors: [nope]}',
            "estimators[0] (ekf).vector_sensors[0]",
        ),
        (
            '!MrpEkfConfig {name: ekf, star_tracker: "", vector_sensors: [gyro]}',
            "estimators[0] (ekf).vector_sensors[0]",
        ),
        (
            '!MrpEkfConfig {name: ekf, star_tracker: "", vector_sensors: [sun, sun]}',
            "estimators[0] (ekf).vector_sensors",
        ),
        (
            '!MrpEkfConfig {name: ekf, period_s: 1.5, star_tracker: "", vector_sensors: [sun]}',
            "estimators[0] (ekf).period_s",
        ),
        (
            '!BootstrapPfConfig {name: pf, star_tracker: "", vector_sensors: [x]}',
            "estimators[0] (pf).vector_sensors[0]",
        ),
    ],
)
def test_a_bad_vector_sensor_list_is_one_line_naming_the_field(estimator_yaml, field):
    message = _bad("- !SunSensorConfig {name: sun}", estimator_yaml=estimator_yaml)
    assert message.startswith(field + ":"), message


@pytest.mark.parametrize(
    "estimator",
    [
        "!LieGroupConfig {name: f, star_tracker: sun, vector_sensors: [mag], estimate_gyro_bias: true,"
        " star_noise_from_tracker: true, initial_attitude_rpy_deg: RPY0, initial_attitude_variance_rad2: 0.01,"
        " initial_bias_sigma_deg_per_h: 5.0}",
        '!CubatureQuaternionConfig {name: f, star_tracker: "", vector_sensors: [sun, mag],'
        " initial_attitude_rpy_deg: RPY0, initial_attitude_sigma_deg: 5.0, initial_bias_sigma_deg_per_h: 5.0}",
        '!BootstrapPfConfig {name: f, star_tracker: "", vector_sensors: [sun, mag], num_particles: 500,'
        " initial_attitude_rpy_deg: RPY0, initial_attitude_sigma_deg: 5.0, initial_bias_sigma_deg_per_h: 5.0}",
        '!EkpfConfig {name: f, star_tracker: "", vector_sensors: [sun, mag], num_particles: 100,'
        " initial_attitude_rpy_deg: RPY0, initial_attitude_sigma_deg: 5.0, initial_bias_sigma_deg_per_h: 5.0}",
    ],
    ids=["lie_group", "cubature", "bootstrap_pf", "ekpf"],
)
def test_every_vector_filter_takes_the_coarse_sensors(estimator):
    """The library's other vector-observation filters on the same gyro, sun sensor and
    magnetometer: from 3 deg off, within 1.5 deg over the sunlit 300-800 s (the sensors' 0.5 and
    ~0.25 deg noise), using both sensors' samples."""
    body = f"""
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.15, rrw_deg_per_h15: 0.02,
               initial_bias_deg_per_h: [3.0, -2.0, 1.0]}}
- !SunSensorConfig {{name: sun, period_s: 1.0, mounting: {{rpy_deg: {SUN_MOUNT_RPY_DEG}}}}}
- !MagnetometerConfig {{name: mag, period_s: 2.0}}
estimators:
- {estimator}
"""
    scenario = _scenario(body, EKF_M0_DEG, 820.0, rate_z_deg_per_s=0.05)
    scenario.estimators[0].initial_attitude_rpy_deg = [v + 3.0 for v in scenario.plant.initial_attitude_rpy_deg]
    run = ScenarioDiagram(scenario).simulate(1)
    t = run.times("f/q_IB_hat")
    error = _attitude_error_deg(run, "f")
    sunlit = (t >= 300.0) & (t <= 800.0)
    assert error[sunlit].max() < 1.5, error[sunlit].max()
    used = run.values("f/status")[-1][1]
    assert used > 1.2 * 800  # the sun sensor's samples and the magnetometer's


def _albedo_direction(r, sun_dir, q_IB, albedo):
    """A noise-free head's measured direction at ``r`` with the Sun far along ``sun_dir``."""
    sensor = SunSensor("sun", 1.0, sigma_boresight_rad=1e-12, albedo=albedo)
    context = sensor.CreateDefaultContext()
    sensor.GetInputPort("q_IB").FixValue(context, q_IB)
    sensor.GetInputPort("r_I").FixValue(context, r)
    sensor.GetInputPort("r_sun_I").FixValue(context, r + 1.5e11 * sun_dir)
    context.SetTime(1.0)
    return sensor.GetOutputPort("vector_observations").Eval(context).directions_S[0]


def test_albedo_pulls_the_direction_toward_nadir_by_the_documented_amount():
    """Earth in the field of view: the light is ``s + a (R_E/|r|)^2 max(0, r_hat.s) (-r_hat)``,
    normalized (computed here); with the Earth outside the field of view, or the sub-satellite
    point dark, the albedo adds nothing."""
    R_E = 6378137.0
    r = np.array([0.0, 0.0, 7000e3])  # over the pole: nadir is -z in I
    # The head (boresight +z_B) looks 70 deg from zenith: the Earth's disk (65.7 deg in radius
    # around nadir, 110 deg from the boresight) overlaps its 60 deg field of view.
    q_IB = rot.rotvec_to_quat(np.radians([70.0, 0.0, 0.0]))
    R_IB = rot.quat_to_rotmat(q_IB)
    sun = R_IB @ np.array([0.0, np.sin(np.radians(20.0)), np.cos(np.radians(20.0))])  # 20 deg off boresight
    a = 0.3
    light_I = sun + a * (R_E / 7000e3) ** 2 * max(0.0, sun @ (r / np.linalg.norm(r))) * -(r / np.linalg.norm(r))
    expected = R_IB.T @ (light_I / np.linalg.norm(light_I))
    got = _albedo_direction(r, sun, q_IB, a)
    np.testing.assert_allclose(got, expected, atol=1e-9)
    assert np.degrees(np.arccos(np.clip(got @ (R_IB.T @ sun), -1, 1))) > 1.0  # a visible pull
    np.testing.assert_allclose(_albedo_direction(r, sun, q_IB, 0.0), R_IB.T @ sun, atol=1e-9)
    # Zenith-pointing head: the Earth (disk up to 65.7 deg from nadir) is out of its 60 deg view.
    q_up = np.array([1.0, 0.0, 0.0, 0.0])
    sun_up = np.array([np.sin(np.radians(20.0)), 0.0, np.cos(np.radians(20.0))])
    np.testing.assert_allclose(_albedo_direction(r, sun_up, q_up, a), sun_up, atol=1e-9)


def test_noise_and_outages_are_context_parameters_of_both_sensors(ekf_diagram):
    """A run's ``--set`` of each sensor's outage windows (and noise) reaches the sensor without a new
    diagram: its samples in the window are invalid, the others not."""
    run = ekf_diagram.simulate(
        1, overrides=["sensors.sun.outage_windows_s=[[100.0, 200.0]]", "sensors.mag.outage_windows_s=[[300.0, 400.0]]"]
    )
    for key, (a, b) in (("sun/sun_sensor_measurement", (100.0, 200.0)), ("mag/magnetic_field", (300.0, 400.0))):
        x = run.values(key)
        inside = (x[:, 0] >= a) & (x[:, 0] < b)
        assert inside.any() and not x[inside, 1].any(), key
        assert x[(x[:, 0] > 10.0) & (x[:, 0] < 90.0), 1].all(), key


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda: Magnetometer("mag", 1.0, bias_S_T=(0.0, 0.0)), "mag.bias"),
        (lambda: Magnetometer("mag", 1.0, dropout_probability=1.0), "mag.dropout_probability"),
        (lambda: SunSensor("sun", 1.0, outage_windows_s=[(5.0, 1.0)]), "sun.outage_windows_s"),
    ],
)
def test_a_bad_sensor_argument_is_named(make, field):
    with pytest.raises(ValueError, match=rf"^{field}"):
        make()
