"""The IGRF field in the inertial frame: against ppigrf, astropy and erfa, physical ranges, and bad input.

Expected values come from the reference libraries directly (ppigrf.igrf_gc for the field, astropy's
GCRS -> ITRS transform and erfa.c2t06a for the frames) and from spherical coordinates computed here.
"""

import datetime

import erfa
import numpy as np
import ppigrf
import ppigrf.ppigrf
import pytest
from astropy import units as u
from astropy.coordinates import GCRS, ITRS, CartesianRepresentation
from astropy.time import Time
from astropy.utils import iers

from drake_att.geomagnetic import GeomagneticField

EPOCH_JD_UTC = 2460847.5  # 2025-06-21 00:00 UTC
ARCSEC = np.pi / 180 / 3600
EARTH_RADIUS_M = 6371.0e3


@pytest.fixture(scope="module")
def field() -> GeomagneticField:
    return GeomagneticField(EPOCH_JD_UTC)


@pytest.fixture(scope="module", autouse=True)
def offline_iers():
    """astropy reads its bundled IERS tables only (no download, predictions accepted)."""
    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None):
        yield


def utc_datetime(jd_utc: float) -> datetime.datetime:
    return datetime.datetime(2000, 1, 1, 12) + datetime.timedelta(days=jd_utc - 2451545.0)


def astropy_gcrs_to_itrs(jd_utc: float) -> np.ndarray:
    """R_EI from astropy: the ITRS coordinates of the GCRS axes (both geocentric, so a pure rotation)."""
    time = Time(jd_utc, format="jd", scale="utc")
    axes = CartesianRepresentation(np.eye(3) * 1e7, unit=u.m)
    itrs = GCRS(axes, obstime=time).transform_to(ITRS(obstime=time))
    return itrs.cartesian.xyz.to_value(u.m) / 1e7  # column j = GCRS axis j in ITRS


def spherical(r_E_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radius (km), colatitude (deg), east longitude (deg)."""
    x, y, z = r_E_m.T
    return (
        np.sqrt(x * x + y * y + z * z) / 1e3,
        np.degrees(np.arccos(z / np.sqrt(x * x + y * y + z * z))),
        np.degrees(np.arctan2(y, x)),
    )


def ppigrf_field_E_nt(r_E_m: np.ndarray, jd_utc: float) -> np.ndarray:
    """ppigrf's geocentric field at ITRS points, as ITRS Cartesian components (nT)."""
    radius_km, colat_deg, lon_deg = spherical(r_E_m)
    b_r, b_t, b_p = (c[0] for c in ppigrf.igrf_gc(radius_km, colat_deg, lon_deg, utc_datetime(jd_utc)))
    t, p = np.radians(colat_deg), np.radians(lon_deg)
    e_r = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    e_t = np.stack([np.cos(t) * np.cos(p), np.cos(t) * np.sin(p), -np.sin(t)], -1)
    e_p = np.stack([-np.sin(p), np.cos(p), np.zeros_like(p)], -1)
    return b_r[:, None] * e_r + b_t[:, None] * e_t + b_p[:, None] * e_p


def random_leo_positions(rng: np.random.Generator, count: int) -> np.ndarray:
    radius = EARTH_RADIUS_M + rng.uniform(400e3, 800e3, count)
    direction = rng.normal(size=(count, 3))
    return radius[:, None] * direction / np.linalg.norm(direction, axis=1, keepdims=True)


def rotation_angle(R: np.ndarray) -> float:
    """The angle of a rotation matrix, accurate for small angles too (from its skew part)."""
    sine_axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2
    return float(np.arctan2(np.linalg.norm(sine_axis), (np.trace(R) - 1) / 2))


def test_inertial_field_equals_ppigrf_after_astropy_frame_conversion(field):
    rng = np.random.default_rng(1)
    jd = EPOCH_JD_UTC + 0.3
    r_I = random_leo_positions(rng, 40)
    R_EI = astropy_gcrs_to_itrs(jd)
    expected_I = ppigrf_field_E_nt(r_I @ R_EI.T, jd) @ R_EI
    got_I = field.field_I_tesla(r_I, jd) * 1e9
    assert np.max(np.abs(got_I - expected_I)) < 1.0
    # one position at a time and dates as an array broadcast the same way
    assert np.allclose(field.field_I_tesla(r_I[0], jd) * 1e9, expected_I[0], atol=1.0)
    assert field.field_I_tesla(r_I, np.full(40, jd)).shape == (40, 3)


def test_earth_fixed_synthesis_equals_ppigrf_to_round_off(field):
    rng = np.random.default_rng(2)
    r_E = np.vstack([random_leo_positions(rng, 200), [[0.0, 1.0, 7e6], [1.0, 0.0, -7e6], [6.4e6, 0.0, 1e-3]]])
    # nT; ppigrf divides by sin(colatitude), which costs it ~1e-5 nT at 1.4e-7 rad from the pole
    np.testing.assert_allclose(field.field_E_tesla(r_E) * 1e9, ppigrf_field_E_nt(r_E, EPOCH_JD_UTC), atol=1e-4)


def test_field_on_the_polar_axis_is_finite_and_continuous(field):
    on_axis = field.field_E_tesla(np.array([0.0, 0.0, 7e6]))
    beside = field.field_E_tesla(np.array([1.0, 0.0, 7e6]))
    assert np.all(np.isfinite(on_axis))
    assert np.max(np.abs(on_axis - beside)) < 1e-10  # 0.1 nT; a metre changes B by ~0.01 nT here


def test_secular_variation_over_a_day_is_below_half_a_nanotesla(field):
    r_E = random_leo_positions(np.random.default_rng(3), 100)
    later = ppigrf_field_E_nt(r_E, EPOCH_JD_UTC + 1.0)
    assert np.max(np.abs(field.field_E_tesla(r_E) * 1e9 - later)) < 0.5


def test_leo_magnitude_is_within_the_physical_range(field):
    """At 400-800 km the field spans ~16-55 uT (the surface's 22-66 uT scaled by (R/r)^3): the minimum in the
    South Atlantic Anomaly, the maximum near the south magnetic pole."""
    altitudes = np.array([400e3, 600e3, 800e3])
    colat, lon = np.meshgrid(np.radians(np.arange(0.5, 180, 3)), np.radians(np.arange(-180, 180, 3)))
    unit = np.stack([np.sin(colat) * np.cos(lon), np.sin(colat) * np.sin(lon), np.cos(colat)], -1).reshape(-1, 3)
    r_I = (EARTH_RADIUS_M + altitudes)[:, None, None] * unit
    magnitude = np.linalg.norm(field.field_I_tesla(r_I, EPOCH_JD_UTC), axis=-1)
    assert 15e-6 < magnitude.min() and magnitude.max() < 60e-6
    r_E = r_I[0] @ field.earth_rotation.gcrs_to_itrs(EPOCH_JD_UTC).T
    weakest = r_E[np.argmin(magnitude[0])] / np.linalg.norm(r_E[np.argmin(magnitude[0])])
    latitude, longitude = np.degrees(np.arcsin(weakest[2])), np.degrees(np.arctan2(weakest[1], weakest[0]))
    assert -35 < latitude < -10 and -75 < longitude < -40
    dipole_scaling = ((EARTH_RADIUS_M + altitudes[0]) / (EARTH_RADIUS_M + altitudes[-1])) ** 3
    for extreme in (np.min, np.max):
        assert extreme(magnitude[-1]) / extreme(magnitude[0]) == pytest.approx(dipole_scaling, rel=0.05)


def test_field_is_about_twice_as_strong_and_radial_at_the_dipole_poles(field):
    g, h = ppigrf.ppigrf.read_shc(ppigrf.ppigrf.shc_fn)
    year_2025 = g.index.year == 2025
    axis = np.array(
        [g[(1, 1)].to_numpy()[year_2025][0], h[(1, 1)].to_numpy()[year_2025][0], g[(1, 0)].to_numpy()[year_2025][0]]
    )
    axis /= np.linalg.norm(axis)
    radius = EARTH_RADIUS_M + 600e3
    ortho = np.cross(axis, [0.0, 0.0, 1.0])
    ortho /= np.linalg.norm(ortho)
    angles = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    equator = radius * (np.cos(angles)[:, None] * ortho + np.sin(angles)[:, None] * np.cross(axis, ortho))
    poles = radius * np.array([axis, -axis])
    pole_field = field.field_E_tesla(poles)
    pole_mean = np.linalg.norm(pole_field, axis=-1).mean()
    equator_mean = np.linalg.norm(field.field_E_tesla(equator), axis=-1).mean()
    assert 1.6 < pole_mean / equator_mean < 2.2  # 2 for a pure dipole; IGRF-14 in 2025 at 600 km: 1.78
    # g10 < 0: the +axis end is the southern geomagnetic pole, where the field leaves the Earth nearly radially
    cos_to_radial = np.sum(pole_field * poles, axis=-1) / (np.linalg.norm(pole_field, axis=-1) * radius)
    assert cos_to_radial[0] > np.cos(np.radians(20)) and cos_to_radial[1] < -np.cos(np.radians(20))


def test_era_only_rotation_stays_within_a_fifth_arcsec_of_the_full_transform_after_a_day(field):
    """Measured at +24 h: 0.091 arcsec for this epoch; at most 0.151 arcsec over 5626 epochs in 1973-2029."""
    for jd in (EPOCH_JD_UTC, EPOCH_JD_UTC + 1.0):
        time = Time(jd, format="jd", scale="utc")
        tt, ut1 = time.tt, time.ut1
        x_p, y_p = iers.earth_orientation_table.get().pm_xy(time)
        full = erfa.c2t06a(tt.jd1, tt.jd2, ut1.jd1, ut1.jd2, x_p.to_value(u.rad), y_p.to_value(u.rad))
        approx = field.earth_rotation.gcrs_to_itrs(jd)
        tolerance = 1e-3 if jd == EPOCH_JD_UTC else 0.2  # arcsec
        assert rotation_angle(approx @ full.T) / ARCSEC < tolerance
    # astropy's own GCRS -> ITRS (no CIP offsets, its own EOP interpolation) agrees at the epoch too
    assert rotation_angle(field.earth_rotation.gcrs_to_itrs(EPOCH_JD_UTC) @ astropy_gcrs_to_itrs(EPOCH_JD_UTC).T) < (
        0.01 * ARCSEC
    )


def test_fixed_earth_point_turns_in_gcrs_at_the_earth_rotation_rate(field):
    """Over one hour: the ERA rate (7.2921150e-5 rad/s, about the CIO) and the sidereal rate about the equinox
    (7.2921159e-5 rad/s) differ by 1.2e-7 relative; both are within the 1e-6 tolerance."""
    point_E = np.array([[7e6, 0.0, 0.0]])
    start, end = EPOCH_JD_UTC + 0.2, EPOCH_JD_UTC + 0.2 + 1 / 24
    a, b = (field.earth_rotation.vectors_to_gcrs(point_E, np.array([jd]))[0] for jd in (start, end))
    angle = np.arccos(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    rate = angle / ((end - start) * 86400.0)
    assert rate == pytest.approx(7.2921159e-5, rel=1e-6)
    # and the vector round trip is the identity
    back = field.earth_rotation.vectors_to_itrs(b[None], np.array([end]))
    np.testing.assert_allclose(back, point_E, atol=1e-6)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: GeomagneticField(2414000.5), r"^epoch_jd_utc = 2414000\.5 .*outside the IGRF14.*allowed \[2415020\.5"),
        (lambda: GeomagneticField(2463000.5), r"^epoch_jd_utc = 2463000\.5 .*allowed \[2415020\.5, 2462502\.5\]"),
        (lambda: GeomagneticField(float("nan")), r"^epoch_jd_utc = nan "),
    ],
)
def test_epoch_outside_the_coefficients_is_a_one_line_error(call, match):
    with pytest.raises(ValueError, match=match) as error:
        call()
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(
    "r_I, jd, match",
    [
        ([7e6, 0, 0], 2463000.5, r"^jd_utc = 2463000\.5 .*allowed \["),
        (
            [6.0e6, 0, 0],
            EPOCH_JD_UTC,
            r"^r_I_m = \[6000000\.0, 0\.0, 0\.0\] m .*inside the Earth; allowed: on or above",
        ),
        ([0, 0, 6.35e6], EPOCH_JD_UTC, r"^r_I_m = .*inside the Earth"),
        ([7e6, np.nan, 0], EPOCH_JD_UTC, r"^r_I_m = \[7000000\.0, nan, 0\.0\] m is not finite; allowed: finite"),
        ([7e6, 0], EPOCH_JD_UTC, r"^r_I_m has shape \(2,\); allowed: \(\.\.\., 3\)"),
    ],
)
def test_bad_position_or_date_is_a_one_line_error(field, r_I, jd, match):
    with pytest.raises(ValueError, match=match) as error:
        field.field_I_tesla(np.array(r_I, dtype=float), jd)
    assert "\n" not in str(error.value)


def test_the_earth_is_the_wgs84_ellipsoid_for_the_inside_check(field):
    """6360 km is above the surface at a pole (b = 6356.75 km) but below it on the equator (a = 6378.14 km)."""
    assert np.all(np.isfinite(field.field_E_tesla(np.array([0.0, 0.0, 6.36e6]))))
    with pytest.raises(ValueError, match=r"^r_E_m = \[6360000\.0, 0\.0, 0\.0\] m .*inside the Earth"):
        field.field_E_tesla(np.array([6.36e6, 0.0, 0.0]))
