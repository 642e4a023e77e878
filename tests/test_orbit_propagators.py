"""Orbits from a TLE and from Keplerian elements, checked against independent computations:
``sgp4`` called directly with astropy's own TEME->GCRS transform, a numerical integration of
the two-body (and J2) equations of motion written here, and the circular orbit's LVLH frame.
Bad orbit input is a one-line error naming the field."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from drake_att import rotations as rot
from drake_att.orbit import CircularOrbit
from drake_att.orbit_propagators import KeplerOrbit, TleOrbit, lvlh_quaternion, tle_checksum
from drake_att.scenarios import config as cfg
from drake_att.scenarios.library import load

MU = 3.986004418e14  # m^3/s^2, written out here
R_E = 6378137.0
J2 = 1.08262668e-3


def _with_checksum(body: str) -> str:
    """A 68-character TLE line body with its checksum appended (computed here, not by the library)."""
    total = sum(int(c) if c.isdigit() else (1 if c == "-" else 0) for c in body)
    return body + str(total % 10)


# A sun-synchronous LEO (~510 km, i = 97.4 deg) and an ISS-like orbit, epoch 2026-06-01 12:00 UTC.
SSO = (
    _with_checksum("1 99001U 26001A   26152.50000000  .00000500  00000-0  25000-4 0  999"),
    _with_checksum("2 99001  97.4000 120.0000 0010000  90.0000 270.0000 15.20000000 1000"),
)
ISS = (
    _with_checksum("1 25544U 98067A   26152.50000000  .00016717  00000-0  10270-3 0  900"),
    _with_checksum("2 25544  51.6400 208.9163 0006317  69.9862  25.2906 15.50377579 1000"),
)


def _astropy_gcrs(r_teme_m, epoch_jd_utc, t_s):
    """sgp4's TEME position transformed to GCRS by astropy at its own instant."""
    from astropy import units as u
    from astropy.coordinates import GCRS, TEME, CartesianRepresentation
    from astropy.time import Time

    when = Time(epoch_jd_utc, format="jd", scale="utc") + t_s * u.s
    g = TEME(CartesianRepresentation(r_teme_m * u.m), obstime=when).transform_to(GCRS(obstime=when))
    return g.cartesian.xyz.to_value(u.m)


@pytest.mark.parametrize("tle", [SSO, ISS], ids=["sso", "iss"])
def test_tle_position_is_sgp4s_own_output_in_gcrs(tle):
    """Against ``Satrec.sgp4`` (WGS-72, the TLE's own constants) called here and astropy's
    TEME->GCRS at each instant: equal at the epoch (1 µm), within 0.1 m at 10 min and 0.5 m at an
    hour (the held rotation's drift: precession/nutation) and 10 m at one day; the velocity
    within 1 mm/s."""
    from sgp4.api import WGS72, Satrec

    orbit = TleOrbit(tle[0], tle[1], "2026-06-01T13:00:00Z")
    sat = Satrec.twoline2rv(tle[0], tle[1], WGS72)
    epoch_jd = 2461192.5 + 13.0 / 24.0  # 2026-06-01 13:00 UTC
    assert sat.jdsatepoch + sat.jdsatepochF == pytest.approx(2461193.0, abs=1e-9)  # the TLE's own epoch, 12:00
    for t, tol in ((0.0, 1e-6), (600.0, 0.1), (3600.0, 0.5), (86400.0, 10.0)):
        jd = epoch_jd + t / 86400.0
        err, r_km, v_km_s = sat.sgp4(np.floor(jd - 0.5) + 0.5, jd - (np.floor(jd - 0.5) + 0.5))
        assert err == 0
        r, v = orbit.position_velocity_I(t)
        expected = _astropy_gcrs(np.array(r_km) * 1e3, epoch_jd, t)
        assert np.linalg.norm(r - expected) < tol, (t, np.linalg.norm(r - expected))
        assert abs(np.linalg.norm(v) - 1e3 * np.linalg.norm(v_km_s)) < 1e-3


def _elements_to_state(a, e, i, raan, argp, M):
    """Position and velocity from elements, written independently (scipy rotations, Kepler by
    fixed-point iteration)."""
    E = M
    for _ in range(200):
        E = M + e * np.sin(E)
    nu = 2.0 * np.arctan2(np.sqrt(1 + e) * np.sin(E / 2), np.sqrt(1 - e) * np.cos(E / 2))
    p = a * (1 - e * e)
    r_pf = p / (1 + e * np.cos(nu)) * np.array([np.cos(nu), np.sin(nu), 0.0])
    v_pf = np.sqrt(MU / p) * np.array([-np.sin(nu), e + np.cos(nu), 0.0])
    R = Rotation.from_euler("ZXZ", [raan, i, argp]).as_matrix()
    return R @ r_pf, R @ v_pf


def _integrate(state0, t_end, j2: bool, t_eval):
    def rhs(_, s):
        r, v = s[:3], s[3:]
        rn = np.linalg.norm(r)
        a = -MU * r / rn**3
        if j2:
            z2 = (r[2] / rn) ** 2
            k = 1.5 * J2 * MU * R_E**2 / rn**5
            a = a + k * r * np.array([5 * z2 - 1, 5 * z2 - 1, 5 * z2 - 3])
        return np.concatenate([v, a])

    sol = solve_ivp(rhs, (0.0, t_end), np.concatenate(state0), t_eval=t_eval, rtol=1e-12, atol=1e-6, method="DOP853")
    return sol.y.T


def test_two_body_orbit_follows_an_independent_integration():
    """An eccentric orbit (e = 0.1) over two periods: within 1 m and 1 mm/s of the integrated
    equations of motion started from the same elements."""
    el = dict(a=7500e3, e=0.1, i=np.radians(63.4), raan=np.radians(40.0), argp=np.radians(270.0), M=np.radians(10.0))
    orbit = KeplerOrbit(el["a"], el["e"], el["i"], el["raan"], el["argp"], el["M"])
    t = np.linspace(0.0, 2 * orbit.period_s, 41)
    truth = _integrate(_elements_to_state(**el), t[-1], False, t)
    r, v = orbit.position_velocity_I(t)
    assert np.max(np.linalg.norm(r - truth[:, :3], axis=1)) < 1.0
    assert np.max(np.linalg.norm(v - truth[:, 3:], axis=1)) < 1e-3


def test_j2_node_drift_matches_an_integration_with_j2():
    """The secular node drift of a sun-synchronous orbit (~0.9856 deg/day) against the node of
    the integrated J2 motion over one day (its short-period wobble averaged by comparing whole
    orbits): within 1 % of the drift."""
    a, i = R_E + 500e3, np.radians(97.4)
    orbit = KeplerOrbit(a, 0.0, i, 0.0, 0.0, 0.0, j2=True)
    raan_dot = orbit.secular_rates()[0]
    assert np.degrees(raan_dot) * 86400 == pytest.approx(0.9856, rel=0.02)  # sun-synchronous, known
    n_orbits = int(86400 // orbit.period_s)
    t = np.arange(0.0, n_orbits * orbit.period_s, orbit.period_s / 50.0)
    states = _integrate(_elements_to_state(a, 0.0, i, 0.0, 0.0, 0.0), t[-1], True, t)
    h = np.cross(states[:, :3], states[:, 3:])
    node = np.unwrap(np.arctan2(h[:, 0], -h[:, 1]))
    first, last = node[:50].mean(), node[-50:].mean()
    measured = (last - first) / (t[-50:].mean() - t[:50].mean())
    assert measured == pytest.approx(raan_dot, rel=0.01)


def test_the_lvlh_frame_of_a_circular_kepler_orbit_is_the_circular_orbits():
    """The same circular orbit two ways: LVLH quaternions equal to round-off, positions too."""
    inc, raan, u0 = np.radians(97.5), np.radians(30.0), np.radians(45.0)
    circ = CircularOrbit(500e3, inc, raan, u0)
    kep = KeplerOrbit(R_E + 500e3, 0.0, inc, raan, 0.0, u0)
    t = np.linspace(0.0, 6000.0, 13)
    dq = rot.quat_error_rotvec(kep.q_IO(t), circ.q_IO(t))
    assert np.max(np.abs(dq)) < 1e-12
    r_k, v_k = kep.position_velocity_I(t)
    r_c, v_c = circ.position_velocity_I(t)
    np.testing.assert_allclose(r_k, r_c, atol=1e-6)
    np.testing.assert_allclose(v_k, v_c, atol=1e-9)
    dq_circ = rot.quat_error_rotvec(lvlh_quaternion(r_c, v_c), circ.q_IO(t))  # O from (r, v) is the orbit's O
    assert np.max(np.abs(dq_circ)) < 1e-12


def test_a_tle_scenario_starts_its_attitude_in_the_real_orbits_lvlh_frame():
    """``initial_attitude_rpy_deg`` is relative to the LVLH frame of the TLE orbit at t = 0."""
    from drake_att.scenarios.build_context import attitude_from_rpy_deg

    text = cfg.dump_scenario(load("cubesat_single_star_tracker"))
    start = text.index("orbit:")
    end = text.index("plant:")
    orbit_yaml = (
        f"orbit: !TleOrbitConfig\n  line1: '{SSO[0]}'\n  line2: '{SSO[1]}'\n  epoch_utc: '2026-06-01T12:00:00Z'\n"
    )
    scenario = cfg.load_scenario(text=text[:start] + orbit_yaml + text[end:])
    orbit = TleOrbit(SSO[0], SSO[1], "2026-06-01T12:00:00Z")
    r, v = orbit.position_velocity_I(0.0)
    q_IO = lvlh_quaternion(r, v)
    q = attitude_from_rpy_deg(scenario, [0.0, 0.0, 0.0])
    assert np.max(np.abs(rot.quat_error_rotvec(q, q_IO))) < 1e-12
    z_B_in_I = rot.quat_to_rotmat(q)[:, 2]
    np.testing.assert_allclose(z_B_in_I, -r / np.linalg.norm(r), atol=1e-12)  # body z is nadir


def _scenario_with_orbit(orbit_yaml: str):
    text = cfg.dump_scenario(load("cubesat_single_star_tracker"))
    start, end = text.index("orbit:"), text.index("plant:")
    return cfg.load_scenario(text=text[:start] + orbit_yaml + text[end:])


def _tle_yaml(line1, line2, epoch="2026-06-01T12:00:00Z"):
    return f"orbit: !TleOrbitConfig\n  line1: '{line1}'\n  line2: '{line2}'\n  epoch_utc: '{epoch}'\n"


@pytest.mark.parametrize(
    "line1, line2, epoch, expected",
    [
        (SSO[0][:-5] + SSO[0][-4:], SSO[1], None, r"^orbit\.line1: got 68 characters; a TLE line has 69"),
        (SSO[0], SSO[1][:-1] + str((int(SSO[1][-1]) + 1) % 10), None, r"^orbit\.line2: checksum '\d' does not match"),
        ("2" + SSO[0][1:], SSO[1], None, r"^orbit\.line1: starts with '2 '; line 1 of a TLE starts with '1 '"),
        (SSO[0], _with_checksum(SSO[1][:2] + "99002" + SSO[1][7:68]), None, r"^orbit\.line2: satellite number"),
        (SSO[0], SSO[1], "2026-08-01T00:00:00Z", r"^orbit\.epoch_utc: got '2026-08-01T00:00:00Z', \+60\.5 days"),
        (SSO[0], SSO[1], "June 1st", r"^orbit\.epoch_utc: got 'June 1st'; expected an ISO 8601 UTC time"),
        (SSO[0], SSO[1], "2026-06-01T12:00:00+02:00", r"^orbit\.epoch_utc: .* must be in UTC"),
        (
            SSO[0][:60] + "\u00e9" + SSO[0][61:],
            SSO[1],
            None,
            r"^orbit\.line1: contains 'é'; a TLE line holds printable",
        ),
    ],
    ids=[
        "short-line",
        "checksum",
        "line-number",
        "satellite",
        "epoch-too-far",
        "epoch-malformed",
        "not-utc",
        "non-ascii",
    ],
)
def test_a_bad_tle_or_epoch_is_one_line_naming_the_field(line1, line2, epoch, expected):
    with pytest.raises(cfg.ConfigError, match=expected) as e:
        _scenario_with_orbit(_tle_yaml(line1, line2, epoch or "2026-06-01T12:00:00Z"))
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "fields, expected",
    [
        ("eccentricity: 1.0", r"^orbit\.eccentricity: got 1\.0; must be in \[0, 1\)"),
        ("semi_major_axis_km: 6400.0", r"^orbit\.semi_major_axis_km: got 6400\.0 .* must be above 6478\.137 km"),
        ("eccentricity: 0.5\n  semi_major_axis_km: 10000.0", r"perigee radius 5000\.0 km"),
        ("epoch_utc: '2026-13-01T00:00:00Z'", r"^orbit\.epoch_utc: got '2026-13-01T00:00:00Z'"),
    ],
)
def test_bad_keplerian_elements_are_one_line_naming_the_field(fields, expected):
    with pytest.raises(cfg.ConfigError, match=expected):
        _scenario_with_orbit(f"orbit: !KeplerOrbitConfig\n  {fields}\n")


def test_tle_checksum_is_the_standard_rule():
    """Digits summed, '-' counts one, modulo 10 (the ISS line from a published set)."""
    line = "1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927"
    assert tle_checksum(line) == int(line[68]) == 7


def test_the_orbit_source_system_outputs_the_models_values():
    """In a diagram with a logger: r_I, v_I and q_IO at every logged time equal the model's."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput

    from drake_att.systems.orbit_source import OrbitSource

    orbit = TleOrbit(SSO[0], SSO[1], "2026-06-01T12:00:00Z")
    builder = DiagramBuilder()
    source = builder.AddSystem(OrbitSource(orbit))
    logs = {p: LogVectorOutput(source.GetOutputPort(p), builder, 10.0) for p in ("r_I", "v_I", "q_IO")}
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(100.0)
    ctx = sim.get_context()
    t = logs["r_I"].FindLog(ctx).sample_times()
    assert len(t) == 11
    r, v = orbit.position_velocity_I(t)
    np.testing.assert_allclose(logs["r_I"].FindLog(ctx).data().T, r, rtol=1e-15, atol=1e-8)  # sgp4: one call
    np.testing.assert_allclose(logs["v_I"].FindLog(ctx).data().T, v, rtol=1e-15, atol=1e-11)  # vs an array call
    np.testing.assert_allclose(logs["q_IO"].FindLog(ctx).data().T, lvlh_quaternion(r, v), atol=1e-14)


@pytest.mark.parametrize("e", [0.0, 0.3, 0.8, 0.95, 0.99])
def test_kepler_equation_is_solved_to_round_off_for_any_eccentricity(e):
    from drake_att.orbit_propagators import solve_kepler

    M = np.linspace(-7.0, 7.0, 301)
    E = solve_kepler(M, e)
    residual = E - e * np.sin(E) - np.mod(M, 2 * np.pi)
    assert np.max(np.abs(residual)) < 1e-13


def test_secular_j2_rates_are_the_closed_forms():
    """Node, perigee and mean-anomaly rates of an eccentric, inclined orbit against the
    textbook closed forms written here (Vallado, eqs. 9-39 to 9-41)."""
    a, e, i = 8000e3, 0.1, np.radians(63.0)
    n = np.sqrt(MU / a**3)
    p = a * (1 - e * e)
    f = n * J2 * (R_E / p) ** 2
    expected = (
        -1.5 * f * np.cos(i),
        0.75 * f * (4 - 5 * np.sin(i) ** 2),
        n + 0.75 * f * np.sqrt(1 - e * e) * (2 - 3 * np.sin(i) ** 2),
    )
    got = KeplerOrbit(a, e, i, j2=True).secular_rates()
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    assert KeplerOrbit(a, e, i).secular_rates() == (0.0, 0.0, pytest.approx(n, rel=1e-15))


def test_an_array_of_times_of_any_shape_gives_the_flat_evaluation():
    orbit = KeplerOrbit(7500e3, 0.05, 1.0, 0.3, 0.2, 0.1, j2=True)
    t = np.arange(6.0).reshape(2, 3) * 700.0
    r, v = orbit.position_velocity_I(t)
    r_flat, v_flat = orbit.position_velocity_I(t.ravel())
    assert r.shape == (2, 3, 3)
    np.testing.assert_array_equal(r.reshape(6, 3), r_flat)
    np.testing.assert_array_equal(v.reshape(6, 3), v_flat)


@pytest.mark.parametrize(
    "orbit_yaml, expected",
    [
        (_tle_yaml(SSO[0][:-1], SSO[1]), "drake-att: orbit.line1: got 68 characters; a TLE line has 69"),
        (_tle_yaml(SSO[0], SSO[1], "2099-12-31T00:00:00Z"), "drake-att: orbit.epoch_utc: got '2099-12-31T00:00:00Z'"),
        (
            "orbit: !KeplerOrbitConfig\n  eccentricity: 1.5\n",
            "drake-att: orbit.eccentricity: got 1.5; must be in [0, 1)",
        ),
        ("orbit: !TleOrbitConfig\n  line1: 12\n", ": orbit.line1: got 12; must be a text string"),
    ],
    ids=["tle-length", "tle-epoch", "eccentricity", "not-a-string"],
)
def test_the_cli_refuses_a_bad_orbit_with_exit_2_and_one_line(tmp_path, capsys, orbit_yaml, expected):
    from drake_att.cli import main as cli_main

    text = cfg.dump_scenario(load("cubesat_single_star_tracker"))
    start, end = text.index("orbit:"), text.index("plant:")
    path = tmp_path / "bad_orbit.yaml"
    path.write_text(text[:start] + orbit_yaml + text[end:])
    assert cli_main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
