"""The sky: the Hipparcos catalogue read from its file, proper motion against astropy's space
motion, the cone search against a brute-force dot product, and the one-line errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drake_att.sky import HIPPARCOS_EPOCH_JYEAR, SkyIndex, hipparcos_path, load_hipparcos


@pytest.fixture(scope="module")
def catalog():
    return load_hipparcos()


def test_catalogue_holds_every_star_and_sirius_is_where_and_how_bright_it_is(catalog):
    assert len(catalog) == 117955
    assert catalog.epoch_jyear == HIPPARCOS_EPOCH_JYEAR
    np.testing.assert_allclose(np.linalg.norm(catalog.unit_I, axis=1), 1.0, atol=1e-14)
    i = int(np.argmin(catalog.magnitude))
    assert catalog.hip[i] == 32349  # Sirius, Hp -1.09
    ra = math.degrees(math.atan2(catalog.unit_I[i, 1], catalog.unit_I[i, 0])) % 360.0
    dec = math.degrees(math.asin(catalog.unit_I[i, 2]))
    assert abs(ra - 101.2872) < 0.01 and abs(dec + 16.7161) < 0.01
    assert -1.2 < catalog.magnitude[i] < -1.0
    # the file's own row for HIP 1 (RA, Dec in rad) read back
    j = int(np.flatnonzero(catalog.hip == 1)[0])
    row = hipparcos_path().read_text().splitlines()[0].split()
    ra1, dec1 = float(row[4]), float(row[5])
    expected = [math.cos(dec1) * math.cos(ra1), math.cos(dec1) * math.sin(ra1), math.sin(dec1)]
    np.testing.assert_allclose(catalog.unit_I[j], expected, atol=1e-15)
    assert catalog.magnitude[j] == float(row[19])


def test_proper_motion_matches_astropys_space_motion(catalog):
    """Straight-line space motion without radial velocity, as astropy computes it, for the
    fastest stars (Barnard's star: 10.4 arcsec/yr) and random ones, over 35 years."""
    import astropy.units as u
    from astropy.coordinates import SkyCoord
    from astropy.time import Time

    speed = np.linalg.norm(catalog.pm_rad_per_year, axis=1)
    rng = np.random.default_rng(0)
    picks = np.r_[np.argsort(speed)[-5:], rng.choice(len(catalog), 15, replace=False)]
    assert catalog.hip[np.argmax(speed)] == 87937  # Barnard's star
    moved = catalog.at_epoch(2026.5)
    rows = {int(r.split()[0]): r.split() for r in hipparcos_path().read_text().splitlines()}
    for k in picks:
        r = rows[int(catalog.hip[k])]
        c = SkyCoord(
            ra=float(r[4]) * u.rad,
            dec=float(r[5]) * u.rad,
            pm_ra_cosdec=float(r[7]) * u.mas / u.yr,
            pm_dec=float(r[8]) * u.mas / u.yr,
            distance=1 * u.pc,  # any distance: without radial velocity the direction moves alike
            radial_velocity=0 * u.km / u.s,
            obstime=Time(HIPPARCOS_EPOCH_JYEAR, format="jyear"),
            frame="icrs",
        ).apply_space_motion(new_obstime=Time(2026.5, format="jyear"))
        expected = c.cartesian.xyz.value / np.linalg.norm(c.cartesian.xyz.value)
        angle = math.atan2(np.linalg.norm(np.cross(moved.unit_I[k], expected)), moved.unit_I[k] @ expected)
        assert angle < 1e-3 * math.pi / 180 / 3600, (catalog.hip[k], angle)  # < 1 mas
    moved_barnard = math.degrees(math.acos(moved.unit_I[np.argmax(speed)] @ catalog.unit_I[np.argmax(speed)])) * 3600
    assert 355 < moved_barnard < 370  # 10.4 arcsec/yr x 35.25 yr


def test_cone_search_equals_a_brute_force_dot_product(catalog):
    bright = catalog.brighter_than(6.5)
    index = SkyIndex(bright)
    rng = np.random.default_rng(1)
    for _ in range(40):
        d = rng.normal(size=3)
        half = math.radians(rng.uniform(0.5, 15.0))
        got = index.cone(d * 3.0, half)
        cosines = bright.unit_I @ (d / np.linalg.norm(d))
        expected = np.flatnonzero(cosines >= math.cos(half) - 1e-12)
        np.testing.assert_array_equal(got, expected)
    assert len(bright) > 4000  # the naked-eye sky: several thousand stars to 6.5 mag
    assert np.all(bright.magnitude <= 6.5)


def test_bad_inputs_are_one_line_errors(catalog, tmp_path):
    with pytest.raises(ValueError) as e:
        catalog.brighter_than(-3.0, field="sensors.st1.magnitude_limit")
    assert str(e.value).startswith("sensors.st1.magnitude_limit: got -3") and "leaves no star" in str(e.value)
    for text, expected in (("", "holds no star"), ("1 2 3\n", "is not a hip2.dat table"), ("garbage here\n", "is not")):
        p = tmp_path / "bad.dat"
        p.write_text(text)
        with pytest.raises(ValueError) as e:
            load_hipparcos(p)
        assert expected in str(e.value) and "\n" not in str(e.value), str(e.value)
    with pytest.raises(ValueError, match="no such file"):
        load_hipparcos(tmp_path / "missing.dat")
    index = SkyIndex(catalog.brighter_than(3.0))
    for bad, field in (((0, 0, 0), "direction_I"), ((1, 0), "direction_I"), ((np.nan, 0, 1), "direction_I")):
        with pytest.raises(ValueError, match=field):
            index.cone(bad, 0.1)
    with pytest.raises(ValueError, match="half_angle_rad"):
        index.cone((1, 0, 0), 0.0)
    with pytest.raises(ValueError, match="epoch_jyear"):
        catalog.at_epoch(float("nan"))
