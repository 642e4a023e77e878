"""Star-tracker exclusion geometry: constructed cases just inside and just outside each cone,
occultation by the Earth, and availability over an orbit against the geometric fraction
computed here."""

from __future__ import annotations

import numpy as np
import pytest

from drake_att.exclusion import CLEAR, EARTH, MOON, SUN, ExclusionCones, availability, exclusion_causes

AU = 1.495978707e11
R_E = 6378137.0
MOON_DIST = 3.844e8
R = 7000e3  # spacecraft radius (m)
CONES = ExclusionCones(sun_deg=45.0, earth_limb_deg=25.0, moon_deg=12.0, atmosphere_height_m=100e3)


def _dir(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([np.cos(a), np.sin(a), 0.0])


R_SC = np.array([R, 0.0, 0.0])  # on +x: nadir is -x, zenith +x
FAR_MOON = np.array([0.0, 0.0, -MOON_DIST])  # well away from every boresight below


@pytest.mark.parametrize("offset_deg, expected", [(-0.01, SUN), (0.01, CLEAR)])
def test_the_sun_just_inside_or_outside_the_cone(offset_deg, expected):
    """Boresight to the zenith, the Sun at 45 deg -+ 0.01 deg from it (seen from the spacecraft)."""
    sun = R_SC + AU * _dir(45.0 + offset_deg)
    assert int(exclusion_causes(_dir(0.0), R_SC, sun, FAR_MOON, CONES)) == expected


@pytest.mark.parametrize("offset_deg, expected", [(-0.01, EARTH), (0.01, CLEAR)])
def test_the_earth_limb_just_inside_or_outside_the_cone(offset_deg, expected):
    """The cone is measured from the bright limb: the Earth's apparent radius with 100 km of
    atmosphere, asin((R_E + 100 km) / r), plus 25 deg from the nadir."""
    limb = np.degrees(np.arcsin((R_E + 100e3) / R))
    boresight = _dir(180.0 - (limb + 25.0 + offset_deg))  # measured from the nadir (-x)
    sun = -AU * _dir(0.0) + np.array([0.0, 0.0, AU])  # far from the boresight
    assert int(exclusion_causes(boresight, R_SC, sun, FAR_MOON, CONES)) == expected


@pytest.mark.parametrize("offset_deg, expected", [(-0.01, MOON), (0.01, CLEAR)])
def test_the_moon_just_inside_or_outside_the_cone(offset_deg, expected):
    moon = R_SC + MOON_DIST * _dir(12.0 + offset_deg)
    sun = np.array([0.0, 0.0, -AU])
    assert int(exclusion_causes(_dir(0.0), R_SC, sun, moon, CONES)) == expected


def test_a_body_behind_the_earth_does_not_blind_but_the_earth_does():
    """Looking at the nadir with the Sun and the Moon straight behind the Earth: only the
    Earth blinds the tracker (the Sun in umbra, the Moon occulted)."""
    nadir = -_dir(0.0)
    causes = exclusion_causes(nadir, R_SC, -AU * _dir(0.0), -MOON_DIST * _dir(0.0), CONES)
    assert int(causes) == EARTH


def test_two_bodies_in_their_cones_count_for_both():
    sun = R_SC + AU * _dir(10.0)
    moon = R_SC + MOON_DIST * _dir(-5.0)
    assert int(exclusion_causes(_dir(0.0), R_SC, sun, moon, CONES)) == SUN | MOON
    a = availability([SUN | MOON, CLEAR, EARTH, CLEAR])
    assert a == {"available": 0.5, "sun": 0.25, "earth": 0.25, "moon": 0.25}


def test_sun_availability_over_an_orbit_is_the_geometric_fraction():
    """A circular orbit in the x-y plane, the Sun far along +x in that plane, the boresight
    fixed 30 deg from the zenith along the track: the Sun is in the 45-deg cone while
    |u + 30 deg| < 45 deg (u the orbit angle), a quarter of the orbit; the Earth (150 deg from
    the nadir) never is. Sampled at 3600 points: the fraction within one sample of 0.25."""
    u = np.linspace(0.0, 2 * np.pi, 3600, endpoint=False)
    r = R * np.stack([np.cos(u), np.sin(u), np.zeros_like(u)], axis=-1)
    boresight = np.stack([np.cos(u + np.radians(30.0)), np.sin(u + np.radians(30.0)), np.zeros_like(u)], axis=-1)
    sun = np.array([AU, 0.0, 0.0])
    causes = exclusion_causes(boresight, r, sun, np.array([0.0, 0.0, MOON_DIST]), CONES)
    a = availability(causes)
    expected_sun = 2 * 45.0 / 360.0  # parallax of the Sun over the orbit: < 1e-4 deg
    assert abs(a["sun"] - expected_sun) <= 1.0 / 3600
    assert a["earth"] == 0.0 and a["moon"] == 0.0
    assert a["available"] == pytest.approx(1.0 - a["sun"])


@pytest.mark.parametrize("field", ["sun_deg", "earth_limb_deg", "moon_deg"])
@pytest.mark.parametrize("value", [0.0, 180.0, -5.0, float("nan")])
def test_an_exclusion_angle_outside_0_180_is_refused_naming_it(field, value):
    with pytest.raises(
        ValueError, match=rf"^sensors\[1\] \(st1\)\.exclusion\.{field}: got .*; must be in \(0, 180\) deg$"
    ):
        ExclusionCones(**{field: value}).check("sensors[1] (st1).exclusion")


def test_no_samples_is_refused():
    with pytest.raises(ValueError, match="no samples"):
        availability([])


def test_a_batch_is_evaluated_row_by_row():
    """Random geometry, some rows with the Sun or the Moon behind the Earth, evaluated as one
    batch (positions, boresights and bodies each batched) and one row at a time: the same causes."""
    rng = np.random.default_rng(3)
    n = 400
    r = rng.normal(size=(n, 3))
    r *= (R_E + rng.uniform(300e3, 2000e3, size=(n, 1))) / np.linalg.norm(r, axis=1, keepdims=True)
    b = rng.normal(size=(n, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    sun = AU * rng.normal(size=(n, 3)) / np.sqrt(3)
    moon = MOON_DIST * rng.normal(size=(n, 3)) / np.sqrt(3)
    sun[:100] = -r[:100] / np.linalg.norm(r[:100], axis=1, keepdims=True) * AU  # behind the Earth
    b[:100] = -r[:100] / np.linalg.norm(r[:100], axis=1, keepdims=True)  # and looked at through it
    batch = exclusion_causes(b, r, sun, moon, CONES)
    rows = np.array([int(exclusion_causes(b[k], r[k], sun[k], moon[k], CONES)) for k in range(n)])
    np.testing.assert_array_equal(batch, rows)
    assert len(set(rows.tolist())) >= 3  # clear, Earth and others occur


@pytest.mark.parametrize("offset_deg, expected", [(-0.001, SUN), (0.001, CLEAR)])
def test_the_sun_is_seen_from_the_spacecraft_not_the_earths_centre(offset_deg, expected):
    """The Sun 45 deg -+ 0.001 deg from the boresight as seen from the spacecraft, whose
    parallax against the Earth's centre (~0.004 deg here) is larger than the margin."""
    sun = R_SC + AU * _dir(45.0 + offset_deg)
    boresight = _dir(0.0)
    assert int(exclusion_causes(boresight, R_SC, sun, FAR_MOON, CONES)) == expected


def test_the_cones_accept_the_bounds_of_the_limb_height():
    ExclusionCones(atmosphere_height_m=0.0).check()
    ExclusionCones(atmosphere_height_m=1e6).check()
    for h in (-1.0, 1e6 + 1.0, float("inf")):
        with pytest.raises(ValueError, match=r"^exclusion\.atmosphere_height_m: got .*; must be in \[0, 1e6\] m$"):
            ExclusionCones(atmosphere_height_m=h).check()


def test_availability_reads_causes_logged_as_floats():
    assert availability(np.array([2.0, 0.0, 3.0, 4.0])) == {"available": 0.25, "sun": 0.25, "earth": 0.5, "moon": 0.25}
