"""A star tracker with exclusion cones in a scenario: over one orbit its logged causes and
validity give the geometric fraction computed here; a tracker with cones needs an orbit with
an epoch (one-line error naming the field)."""

from __future__ import annotations

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.exclusion import EARTH, MOON, SUN
from drake_att.orbit_propagators import KeplerOrbit
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import ScenarioDiagram

R_E = 6378137.0
A = R_E + 500e3
EPOCH = "2026-03-20T12:00:00Z"


def _sun_and_moon_directions():
    """At the epoch, from astropy directly (not the library's ephemeris)."""
    from astropy import units as u
    from astropy.coordinates import get_body, solar_system_ephemeris
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False
    when = Time(EPOCH.rstrip("Z"), scale="utc")
    with solar_system_ephemeris.set("builtin"):
        out = []
        for body in ("sun", "moon"):
            xyz = get_body(body, when).cartesian.xyz.to_value(u.m)
            out.append(xyz / np.linalg.norm(xyz))
    return out


def _scenario(orbit_yaml: str, rpy_deg, period_s=10.0, duration_s=None) -> cfg.Scenario:
    duration = duration_s if duration_s is not None else 2 * np.pi * np.sqrt(A**3 / 3.986004418e14)
    text = f"""
name: exclusion_test
duration_s: {float(duration)!r}
seed: 1
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 1.0}}
{orbit_yaml}
plant: !PrescribedRateConfig {{initial_attitude_rpy_deg: {list(map(float, rpy_deg))}}}
sensors:
- !StarTrackerConfig {{name: st1, period_s: {period_s}, sigma_cross_boresight_arcsec: 5.0,
                      sigma_boresight_arcsec: 50.0,
                      exclusion: {{sun_deg: 45.0, earth_limb_deg: 25.0, moon_deg: 12.0}}}}
scoring: {{score_from_s: 0.0}}
"""
    return cfg.load_scenario(text=text)


def test_earth_exclusion_over_an_orbit_is_the_geometric_fraction():
    """A circular orbit whose normal points at the Sun (so the Sun stays 90 deg from any
    in-plane boresight), an inertially fixed boresight in the orbit plane, chosen far from the
    Moon: over one orbit the Earth's limb (100 km of atmosphere) plus 25 deg blinds the tracker
    a fraction 2 (asin((R_E + 100 km) / a) + 25 deg) / 360 deg of the time, and only the Earth;
    a sample is valid exactly when no cause is logged."""
    sun, moon = _sun_and_moon_directions()
    inc = float(np.degrees(np.arccos(sun[2])))
    raan = float(np.degrees(np.arctan2(sun[0], -sun[1])))
    orbit_yaml = (
        f"orbit: !KeplerOrbitConfig {{epoch_utc: '{EPOCH}', semi_major_axis_km: {A / 1e3!r}, "
        f"inclination_deg: {inc!r}, raan_deg: {raan!r}}}"
    )
    orbit = KeplerOrbit(A, 0.0, np.radians(inc), np.radians(raan))
    normal = np.cross(*orbit.position_velocity_I(0.0))
    normal /= np.linalg.norm(normal)
    assert np.degrees(np.arccos(np.clip(normal @ sun, -1, 1))) < 1e-6  # the orbit faces the Sun
    # the in-plane boresight farthest from the Moon
    e1 = orbit.position_velocity_I(0.0)[0] / A
    e2 = np.cross(normal, e1)
    angles = np.radians(np.arange(0.0, 360.0, 1.0))
    candidates = np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2
    b = candidates[np.argmin(candidates @ moon)]
    # body z along b; roll/pitch/yaw relative to the LVLH frame at t = 0
    z = b
    x = np.cross(normal, z)
    R_IB = np.stack([x, np.cross(z, x), z], axis=-1)
    q_OB = rot.quat_multiply(rot.quat_conjugate(orbit.q_IO(0.0)), rot.rotmat_to_quat(R_IB))
    scenario = _scenario(orbit_yaml, [float(x) for x in np.degrees(rot.quat_to_rpy(q_OB))])

    run = ScenarioDiagram(scenario).simulate(1)
    causes = run.values("st1/exclusion")[:, 1].astype(int)
    valid = run.values("st1/star_tracker_measurement")[:, 1]
    assert len(causes) == len(valid) > 500
    limb = np.degrees(np.arcsin((R_E + 100e3) / A))
    expected = 2 * (limb + 25.0) / 360.0
    earth = np.mean((causes & EARTH) != 0)
    assert abs(earth - expected) <= 2.0 / len(causes), (earth, expected)
    assert not np.any(causes & (SUN | MOON))
    np.testing.assert_array_equal(valid == 1.0, causes == 0)
    from drake_att.analysis.metrics import compute_metrics, format_table

    metrics = compute_metrics(run)
    assert metrics["sensors"]["st1"] == {
        "samples": len(causes),
        "availability": {"available": float(np.mean(causes == 0)), "sun": 0.0, "earth": earth, "moon": 0.0},
    }
    assert f"st1: available {100 * np.mean(causes == 0):.1f}% of {len(causes)} samples" in format_table(metrics)


@pytest.mark.parametrize(
    "orbit_yaml, kind",
    [("orbit: null", "no orbit"), ("orbit: {altitude_km: 500.0}", "a circular orbit without an epoch")],
)
def test_exclusion_without_an_orbit_epoch_is_refused_naming_the_field(orbit_yaml, kind):
    with pytest.raises(cfg.ConfigError) as e:
        _scenario(orbit_yaml, [0.0, 0.0, 0.0])
    text = str(e.value)
    assert text.startswith("sensors[0] (st1).exclusion: ") and kind in text and "!TleOrbitConfig" in text, text
    assert "\n" not in text


@pytest.mark.parametrize("value", [0.0, 180.0, -1.0])
def test_an_exclusion_angle_outside_0_180_is_refused_in_the_scenario(value):
    orbit_yaml = f"orbit: !KeplerOrbitConfig {{epoch_utc: '{EPOCH}'}}"
    text = cfg.dump_scenario(_scenario(orbit_yaml, [0.0, 0.0, 0.0], duration_s=10.0))
    with pytest.raises(cfg.ConfigError, match=r"sun_deg: got .*; must be in \(0, 180\) deg"):
        cfg.load_scenario(text=text.replace("sun_deg: 45.0", f"sun_deg: {value}"))


def test_a_run_beyond_the_ephemeris_span_is_refused_naming_the_epoch():
    from drake_att.ephemeris import supported_jd_range

    hi = supported_jd_range()[1]
    days_after_j2000 = hi - 2451545.0 + 10.0  # ten days past the table's expiry
    import datetime

    late = (datetime.datetime(2000, 1, 1, 12) + datetime.timedelta(days=days_after_j2000)).strftime(
        "%Y-%m-%dT%H:%M:%SZ"
    )
    with pytest.raises(cfg.ConfigError, match=rf"^orbit\.epoch_utc: got '{late}' with duration_s 10: the run must lie"):
        _scenario(f"orbit: !KeplerOrbitConfig {{epoch_utc: '{late}'}}", [0.0, 0.0, 0.0], duration_s=10.0)


def test_a_vector_tracker_drops_the_stars_the_earth_hides():
    """At positions around an orbit, the vector-mode tracker's sample keeps exactly the
    references whose line of sight misses the Earth plus 100 km of atmosphere (computed here by
    intersecting each ray with the sphere), and a sample with none left is invalid."""
    from drake_att.exclusion import ExclusionCones
    from drake_att.systems.star_tracker import StarTracker

    refs = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
    st = StarTracker(
        "st",
        1.0,
        mode="vectors",
        references_I=refs,
        sigma_vector_rad=0.0,
        exclusion=ExclusionCones(0.1, 0.1, 0.1, 100e3),
    )
    ctx = st.CreateDefaultContext()
    st.GetInputPort("q_IB").FixValue(ctx, [1.0, 0.0, 0.0, 0.0])
    st.GetInputPort("r_sun_I").FixValue(ctx, [1.5e11, 1e9, 0.0])
    st.GetInputPort("r_moon_I").FixValue(ctx, [0.0, 0.0, -3.8e8])
    radius = R_E + 100e3
    seen_counts = set()
    for k, angle in enumerate(np.linspace(0.0, 2 * np.pi, 73)):
        r = (
            A
            * np.array([np.cos(angle), 0.3 * np.sin(angle), np.sin(angle)])
            / np.linalg.norm([np.cos(angle), 0.3 * np.sin(angle), np.sin(angle)])
        )
        st.GetInputPort("r_I").FixValue(ctx, r)
        ctx.SetTime(float(k))
        obs = st.GetOutputPort("vector_observations").Eval(ctx)
        # A ray r + s d (s > 0) meets the sphere iff the discriminant is positive and s > 0.
        b = refs @ r
        disc = b * b - (r @ r - radius**2)
        hidden = (disc > 0) & (-b - np.sqrt(np.maximum(disc, 0.0)) > 0)
        np.testing.assert_allclose(obs.references_I, refs[~hidden])
        np.testing.assert_allclose(obs.directions_S, refs[~hidden])  # body = sensor = inertial here
        clear = st.GetOutputPort("exclusion").Eval(ctx)[1] == 0  # the cones (tested above)
        assert obs.valid == (bool((~hidden).any()) and clear)
        seen_counts.add(int((~hidden).sum()))
    assert len(seen_counts) >= 2  # the geometry varies the star count


def test_every_vector_filter_runs_on_a_tracker_that_loses_stars():
    """A nadir-pointing spacecraft with a zenith tracker on an orbit whose nadir sweeps the
    reference stars: the star count of each sample varies with the occultation, and every
    vector-observation filter of the library uses the samples and stays within 0.5 deg."""
    refs = "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-0.6, 0.0, 0.8]]"
    init = "initial_attitude_rpy_deg: [0.2, -0.2, 0.2], initial_attitude_sigma_deg: 1.0"
    text = f"""
name: occultation_filters
duration_s: 1200.0
seed: 3
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 1.0}}
orbit: !KeplerOrbitConfig {{epoch_utc: "{EPOCH}", semi_major_axis_km: {A / 1e3}, inclination_deg: 97.4}}
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  attitude_control: {{}}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.05, rrw_deg_per_h15: 0.02}}
- !StarTrackerConfig {{name: st, period_s: 1.0, mode: vectors, references_I: {refs}, sigma_vector_urad: 100.0,
                      mounting: !RpyMounting {{rpy_deg: [180.0, 0.0, 0.0]}},
                      exclusion: {{sun_deg: 1.0, earth_limb_deg: 1.0, moon_deg: 1.0}}}}
estimators:
- !MrpEkfConfig {{name: ekf, {init}}}
- !BootstrapPfConfig {{name: pf, num_particles: 300, {init}}}
- !EkpfConfig {{name: ekpf, num_particles: 100, {init}}}
- !LieGroupConfig {{name: lie}}
- !CubatureQuaternionConfig {{name: cqe}}
- !MekfConfig {{name: mekf, star_trackers: [st], {init}}}
scoring: {{score_from_s: 300.0}}
"""
    from drake_att.analysis.metrics import compute_metrics

    s = cfg.load_scenario(text=text)
    log = ScenarioDiagram(s).simulate()
    metrics = compute_metrics(log)["estimators"]
    for name in ("ekf", "pf", "ekpf", "lie", "cqe", "mekf"):
        m = metrics[name]
        assert np.isfinite(m["attitude_rmse_total_deg"]) and m["attitude_rmse_total_deg"] < 0.5, name
        assert m["measurements_used"] > 600, name
    sizes = log.values("ekf/innovations")[:, 2]  # [t, NIS, 3 m] of each step's tracker update
    assert {3, 6, 9, 12} & set(sizes.astype(int).tolist()) and len(set(sizes[sizes > 0].astype(int).tolist())) >= 2
