"""Sun/Moon ephemeris against astropy directly, and Earth's shadow against geometry written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drake_att import ephemeris as eph

JD_2026 = 2461041.5  # 2026-01-01 00:00 UTC
YEAR_DAYS = 365.0
R_E = 6378137.0
R_SUN = 696_000e3
AU = 1.495978707e11
MU = 3.986004418e14


@pytest.fixture(scope="module")
def year_ephemeris():
    return eph.SunMoonEphemeris(JD_2026, JD_2026 + YEAR_DAYS)


def _astropy_gcrs_m(body: str, jd: np.ndarray) -> np.ndarray:
    """astropy's get_body evaluated directly (not through drake_att), offline."""
    import astropy.units as u
    from astropy.coordinates import get_body, solar_system_ephemeris
    from astropy.time import Time
    from astropy.utils import data, iers

    with iers.conf.set_temp("auto_download", False), data.conf.set_temp("allow_internet", False):
        with solar_system_ephemeris.set("builtin"):
            coord = get_body(body, Time(jd, format="jd", scale="utc"))
        assert coord.frame.name == "gcrs"
        return coord.cartesian.xyz.to_value(u.m).T


def _relative_error(got: np.ndarray, expected: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(got - expected, axis=-1) / np.linalg.norm(expected, axis=-1)))


def _angle_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(u * v, axis=-1)))


# --- Sun and Moon against astropy ---------------------------------------------------------------


@pytest.mark.parametrize("body", ["sun", "moon"])
def test_positions_match_astropy_at_random_epochs_over_a_year(year_ephemeris, body):
    jd = JD_2026 + np.sort(np.random.default_rng(26).uniform(0.0, YEAR_DAYS, 250))
    expected = _astropy_gcrs_m(body, jd)
    got = {"sun": year_ephemeris.sun_position_m, "moon": year_ephemeris.moon_position_m}[body](jd)
    assert got.shape == (250, 3)
    assert np.max(_angle_deg(got, expected)) < 0.01
    assert np.max(_angle_deg(got, expected)) < 1e-5  # the measured figure is ~2e-7 deg (Moon)
    relative_distance = np.linalg.norm(got, axis=-1) / np.linalg.norm(expected, axis=-1) - 1.0
    assert np.max(np.abs(relative_distance)) < 1e-7


def test_distances_and_directions_are_physical(year_ephemeris):
    jd = JD_2026 + np.linspace(0.0, YEAR_DAYS, 50)
    sun, moon = year_ephemeris.sun_position_m(jd), year_ephemeris.moon_position_m(jd)
    assert np.all((0.98 * AU < np.linalg.norm(sun, axis=-1)) & (np.linalg.norm(sun, axis=-1) < 1.02 * AU))
    assert np.all((356e6 < np.linalg.norm(moon, axis=-1)) & (np.linalg.norm(moon, axis=-1) < 407e6))
    np.testing.assert_allclose(np.linalg.norm(year_ephemeris.sun_direction(jd), axis=-1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(year_ephemeris.moon_direction(jd), moon / np.linalg.norm(moon, axis=-1)[:, None])
    # The Sun is near the vernal equinox (+x of GCRS/J2000) around 20 March.
    march_20 = JD_2026 + 78.6
    assert _angle_deg(year_ephemeris.sun_direction(march_20), np.array([1.0, 0.0, 0.0])) < 0.5


@pytest.mark.parametrize("body", ["sun", "moon"])
def test_interpolation_at_grid_midpoints(body):
    """Mid-way between grid nodes is where a cubic interpolant is worst."""
    table = eph.SunMoonEphemeris(JD_2026 + 100.0, JD_2026 + 130.0)
    step = eph.GRID_STEP_DAYS
    midpoints = table.jd_start + step * (np.arange(int(30.0 / step)) + 0.5)
    expected = _astropy_gcrs_m(body, midpoints)
    got = {"sun": table.sun_position_m, "moon": table.moon_position_m}[body](midpoints)
    assert np.max(_angle_deg(got, expected)) < 1e-5
    relative_distance = np.linalg.norm(got, axis=-1) / np.linalg.norm(expected, axis=-1) - 1.0
    assert np.max(np.abs(relative_distance)) < 1e-7
    # On the nodes the interpolant reproduces the samples, up to the motion in one float64 ulp of a JD (~40 µs).
    nodes = table.jd_start + step * np.arange(int(30.0 / step))
    nodes_got = {"sun": table.sun_position_m, "moon": table.moon_position_m}[body](nodes)
    assert _relative_error(nodes_got, _astropy_gcrs_m(body, nodes)) < 2e-10


def test_scalar_and_array_evaluation_agree_including_the_span_ends():
    table = eph.SunMoonEphemeris(JD_2026, JD_2026 + 0.7)
    times = [JD_2026, JD_2026 + 0.123456, JD_2026 + 0.7]
    array_result = table.moon_position_m(np.array(times))
    for k, jd in enumerate(times):
        assert table.moon_position_m(jd).shape == (3,)
        np.testing.assert_allclose(table.moon_position_m(jd), array_result[k], rtol=1e-14)
    assert _relative_error(table.sun_position_m(JD_2026 + 0.7), _astropy_gcrs_m("sun", [JD_2026 + 0.7])[0]) < 2e-10
    assert table.sun_position_m(np.full((2, 4), JD_2026 + 0.5)).shape == (2, 4, 3)


def test_importing_drake_att_ephemeris_does_not_import_astropy():
    import subprocess
    import sys

    code = "import sys, drake_att.ephemeris; print('astropy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_supported_range_is_utc_with_leap_seconds_up_to_the_table_expiry():
    from astropy.utils.iers import LeapSeconds

    jd_min, jd_max = eph.supported_jd_range()
    assert jd_min == 2441317.5  # 1972-01-01
    assert jd_max == pytest.approx(LeapSeconds.auto_open().expires.jd)
    assert jd_max > JD_2026 + YEAR_DAYS


# --- bad input ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("start", "end", "pattern"),
    [
        (float("nan"), JD_2026 + 1, r"jd_start = nan: must be a finite"),
        (JD_2026, float("inf"), r"jd_end = inf: must be a finite"),
        (2441000.5, 2441001.5, r"jd_start = 2441000.5: outside the offline-supported range \[2441317.5, "),
        (JD_2026, 2470000.5, r"jd_end = 2470000.5: outside the offline-supported range"),
        (JD_2026, JD_2026 - 1, r"jd_end = 2461040.5: must be >= jd_start = 2461041.5"),
        (2451544.5, 2451544.5 + 800, r"jd_end - jd_start = 800.0 days: at most 731.0 days"),
    ],
)
def test_bad_spans_are_refused_naming_the_field(start, end, pattern):
    with pytest.raises(ValueError, match=pattern) as info:
        eph.SunMoonEphemeris(start, end)
    assert "\n" not in str(info.value)


@pytest.fixture(scope="module")
def day_ephemeris():
    return eph.SunMoonEphemeris(JD_2026, JD_2026 + 1.0)


@pytest.mark.parametrize(
    ("jd", "pattern"),
    [
        (JD_2026 + 1.5, r"jd_utc = 2461043.0: outside the ephemeris span \[2461041.5, 2461042.5\]"),
        (np.array([JD_2026 + 0.5, JD_2026 - 0.25]), r"jd_utc = 2461041.25: outside the ephemeris span"),
        (float("nan"), r"jd_utc = nan: must be a finite Julian date"),
        (np.array([JD_2026, np.inf]), r"jd_utc = inf: must be a finite Julian date"),
    ],
)
def test_bad_times_are_refused_naming_the_field(day_ephemeris, jd, pattern):
    for method in (day_ephemeris.sun_position_m, day_ephemeris.moon_direction):
        with pytest.raises(ValueError, match=pattern):
            method(jd)


def test_bad_shadow_inputs_are_refused_naming_the_field():
    sun = np.array([AU, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"\|r_I\| = 6000000.0 m: must be finite and > the shadowing radius 6378137.0"):
        eph.shadow_fraction(np.array([-6.0e6, 0.0, 0.0]), sun)
    with pytest.raises(ValueError, match=r"\|r_I\| = nan m"):
        eph.cylindrical_shadow(np.array([[7e6, 0.0, 0.0], [np.nan, 0.0, 0.0]]), sun)
    with pytest.raises(ValueError, match=r"atmosphere_height_m = -1.0: must be finite and >= 0"):
        eph.cylindrical_shadow(np.array([7e6, 0.0, 0.0]), sun, atmosphere_height_m=-1.0)


# --- eclipse on a circular 500 km orbit ---------------------------------------------------------

A_ORBIT = R_E + 500e3
MEAN_MOTION = math.sqrt(MU / A_ORBIT**3)
PERIOD_S = 2.0 * math.pi / MEAN_MOTION


def _orbit_positions(t_s: np.ndarray, beta_rad: float) -> np.ndarray:
    """Circular orbit whose plane is tilted by beta from the Sun direction +x: r = a (cos b cos nt, sin nt, sin b cos nt)."""
    theta = MEAN_MOTION * np.asarray(t_s)
    return A_ORBIT * np.stack(
        [math.cos(beta_rad) * np.cos(theta), np.sin(theta), math.sin(beta_rad) * np.cos(theta)], axis=-1
    )


def _transitions(t_s: np.ndarray, flag: np.ndarray) -> tuple[float, float]:
    """First and last sample times where the flag holds (one contiguous interval)."""
    idx = np.flatnonzero(flag)
    assert idx.size and np.all(np.diff(idx) == 1)
    return float(t_s[idx[0]]), float(t_s[idx[-1]])


@pytest.mark.parametrize("beta_deg", [0.0, 30.0, 60.0])
def test_cylindrical_eclipse_entry_and_exit_within_one_sample(beta_deg):
    beta = math.radians(beta_deg)
    sun = np.array([AU, 0.0, 0.0])
    t = np.arange(0.0, PERIOD_S, 1.0)
    shadow = eph.cylindrical_shadow(_orbit_positions(t, beta), sun)
    # In shadow: r.s < 0 and a^2 - (r.s)^2 < R_E^2, with r.s = a cos(beta) cos(theta): |theta - pi| < phi.
    cos_phi = math.sqrt(1.0 - (R_E / A_ORBIT) ** 2) / math.cos(beta)
    if cos_phi >= 1.0:
        assert not shadow.any()  # beyond the critical beta angle there is no eclipse
        return
    phi = math.acos(cos_phi)
    entry, exit_ = (math.pi - phi) / MEAN_MOTION, (math.pi + phi) / MEAN_MOTION
    first, last = _transitions(t, shadow)
    assert entry <= first < entry + 1.0
    assert exit_ - 1.0 < last <= exit_
    if beta_deg == 0.0:  # the half-angle of the shadow is asin(R_E / a) in the Sun's plane
        assert phi == pytest.approx(math.asin(R_E / A_ORBIT), rel=1e-12)


def test_beta_beyond_the_critical_angle_has_no_eclipse():
    beta = math.acos(math.sqrt(1.0 - (R_E / A_ORBIT) ** 2)) + math.radians(0.5)
    t = np.arange(0.0, PERIOD_S, 5.0)
    r = _orbit_positions(t, beta)
    sun = np.array([AU, 0.0, 0.0])
    assert not eph.cylindrical_shadow(r, sun).any()
    assert np.all(eph.shadow_fraction(r, sun) == 1.0)


def _separation_minus(t_s: float, offset_sign: float) -> float:
    """c - (b + sign * a) at time t for the beta = 0 orbit, from the definitions (Sun at 1 AU on +x)."""
    r = _orbit_positions(np.array(t_s), 0.0)
    to_sun = np.array([AU, 0.0, 0.0]) - r
    a = math.asin(R_SUN / np.linalg.norm(to_sun))
    b = math.asin(R_E / np.linalg.norm(r))
    c = math.acos(float(-r @ to_sun) / (np.linalg.norm(r) * np.linalg.norm(to_sun)))
    return c - (b + offset_sign * a)


def _bisect(f, lo: float, hi: float) -> float:
    f_lo = f(lo)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if (f(mid) > 0) == (f_lo > 0):
            lo, f_lo = mid, f(mid)
        else:
            hi = mid
    return 0.5 * (lo + hi)


def test_conical_penumbra_and_umbra_times_and_duration():
    sun = np.array([AU, 0.0, 0.0])
    t = np.arange(0.0, PERIOD_S, 1.0)
    fraction = eph.shadow_fraction(_orbit_positions(t, 0.0), sun)
    half = PERIOD_S / 2.0
    # Independent: entry into the penumbra where c = b + a, into the umbra where c = b - a (bisection).
    penumbra_entry = _bisect(lambda s: _separation_minus(s, +1.0), half - 1200.0, half)
    umbra_entry = _bisect(lambda s: _separation_minus(s, -1.0), half - 1200.0, half)
    umbra_exit = _bisect(lambda s: _separation_minus(s, -1.0), half, half + 1200.0)
    penumbra_exit = _bisect(lambda s: _separation_minus(s, +1.0), half, half + 1200.0)
    first_dimmed, last_dimmed = _transitions(t, fraction < 1.0)
    first_dark, last_dark = _transitions(t, fraction == 0.0)
    assert penumbra_entry < first_dimmed <= penumbra_entry + 1.0
    assert umbra_entry <= first_dark < umbra_entry + 1.0
    assert umbra_exit - 1.0 < last_dark <= umbra_exit
    assert penumbra_exit - 1.0 <= last_dimmed < penumbra_exit
    # Closed form: in the Sun's plane c changes at the orbit rate and b is constant, so each
    # penumbra lasts 2 a / n with a = asin(R_sun / 1 AU) (~8.4 s at 500 km), up to the parallax of r.
    closed_form = 2.0 * math.asin(R_SUN / AU) / MEAN_MOTION
    assert 5.0 < closed_form < 12.0
    assert umbra_entry - penumbra_entry == pytest.approx(closed_form, abs=0.05)
    assert penumbra_exit - umbra_exit == pytest.approx(closed_form, abs=0.05)
    # The cylindrical shadow lies between the umbra and the penumbra.
    cyl_first, cyl_last = _transitions(t, eph.cylindrical_shadow(_orbit_positions(t, 0.0), sun))
    assert first_dimmed <= cyl_first <= first_dark and last_dark <= cyl_last <= last_dimmed


def test_shadow_fraction_sunlit_dark_and_monotonic_through_the_penumbra():
    sun = np.array([AU, 0.0, 0.0])
    assert eph.shadow_fraction(_orbit_positions(np.array([0.0, PERIOD_S / 4]), 0.0), sun).tolist() == [1.0, 1.0]
    assert eph.shadow_fraction(_orbit_positions(np.array(PERIOD_S / 2), 0.0), sun) == 0.0
    entry = (math.pi - math.asin(R_E / A_ORBIT)) / MEAN_MOTION  # the cylindrical shadow's entry
    t = np.linspace(entry - 50.0, entry + 50.0, 2001)  # through the entry penumbra, 0.05 s apart
    fraction = eph.shadow_fraction(_orbit_positions(t, 0.0), sun)
    assert fraction[0] == 1.0 and fraction[-1] == 0.0
    assert np.all(np.diff(fraction) <= 0.0)
    assert np.sum((fraction > 0.0) & (fraction < 1.0)) > 100  # resolved, not a step


def _visible_fraction_by_sampling(a: float, b: float, c: float, n: int = 1201) -> float:
    """Fraction of a flat disk of radius a (centre 0) outside a disk of radius b at (c, 0), on a grid."""
    u = np.linspace(-a, a, n)
    x, y = np.meshgrid(u, u)
    in_sun = x * x + y * y <= a * a
    behind_earth = (x - c) ** 2 + y * y <= b * b
    return float(np.sum(in_sun & ~behind_earth) / np.sum(in_sun))


@pytest.mark.parametrize("depth", [0.1, 0.35, 0.5, 0.8, 0.95])
def test_penumbra_fraction_equals_the_uncovered_area_of_the_solar_disk(depth):
    sun = np.array([AU, 0.0, 0.0])
    r_norm = A_ORBIT
    a = math.asin(R_SUN / AU)  # the spacecraft below sits on the Earth-Sun line's normal plane side: |r_sun - r| ~ AU
    b = math.asin(R_E / r_norm)
    c = (b + a) - depth * 2.0 * a  # from first contact (depth 0) to full cover (depth 1)
    # Place r so that the angle between -r and the Sun direction (as seen from r) is c.
    r = -r_norm * np.array([math.cos(c), math.sin(c), 0.0])
    to_sun = sun - r
    a_true = math.asin(R_SUN / np.linalg.norm(to_sun))
    c_true = math.acos(float(-r @ to_sun) / (r_norm * np.linalg.norm(to_sun)))
    expected = _visible_fraction_by_sampling(a_true, b, c_true)
    assert float(eph.shadow_fraction(r, sun)) == pytest.approx(expected, abs=2e-3)


def test_annular_eclipse_far_from_earth_and_atmosphere_grows_the_shadow():
    sun = np.array([AU, 0.0, 0.0])
    r = np.array([-3.0e9, 0.0, 0.0])  # far behind the Earth its disk is smaller than the Sun's
    a = math.asin(R_SUN / (AU + 3.0e9))
    b = math.asin(R_E / 3.0e9)
    assert b < a
    assert float(eph.shadow_fraction(r, sun)) == pytest.approx(1.0 - (b / a) ** 2, rel=1e-12)
    assert not eph.cylindrical_shadow(np.array([-7e6, R_E + 10e3, 0.0]), sun)
    assert eph.cylindrical_shadow(np.array([-7e6, R_E + 10e3, 0.0]), sun, atmosphere_height_m=50e3)
    r_limb = np.array([-7e6, R_E + 1e3, 0.0])
    assert eph.shadow_fraction(r_limb, sun, atmosphere_height_m=50e3) < eph.shadow_fraction(r_limb, sun)
