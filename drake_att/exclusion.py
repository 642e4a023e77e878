"""Star-tracker exclusion: when the Sun, the Earth's bright limb or the Moon is inside a
tracker's cone, its sample is invalid (no Drake).

A tracker with boresight ``b`` (unit, in I) at position ``r`` (m, in I) is blinded by

* the **Sun** when the angle between ``b`` and the Sun's direction seen from ``r`` is below
  ``sun_deg``, unless the Earth hides the Sun entirely (umbra);
* the **Earth** when the angle between ``b`` and the nadir is below the Earth's apparent
  radius plus ``earth_limb_deg`` (the limb's exclusion is measured from the limb, the
  sphere of radius ``R_E + atmosphere_height_m``);
* the **Moon** when the angle between ``b`` and the Moon's direction is below ``moon_deg``,
  unless the Earth is in front of the Moon.

Causes are bit flags (:data:`SUN`, :data:`EARTH`, :data:`MOON`; 0: clear) so a sample
blinded by two bodies counts for both. The default half-angles (:data:`DEFAULT_HALF_ANGLES_DEG`)
are ours, in the range published for CubeSat-class star trackers (Sun 30-45 deg, Earth limb
15-30 deg, Moon 5-15 deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att.orbit import EARTH_RADIUS_M

CLEAR, SUN, EARTH, MOON = 0, 1, 2, 4
CAUSE_NAMES = {SUN: "sun", EARTH: "earth", MOON: "moon"}
DEFAULT_HALF_ANGLES_DEG = {"sun_deg": 45.0, "earth_limb_deg": 25.0, "moon_deg": 12.0}
DEFAULT_ATMOSPHERE_HEIGHT_M = 100e3  # the bright limb: the Earth's radius plus the lit atmosphere


@dataclass(frozen=True)
class ExclusionCones:
    """A tracker's exclusion half-angles (deg, each in (0, 180)) and the limb's height (m)."""

    sun_deg: float = DEFAULT_HALF_ANGLES_DEG["sun_deg"]
    earth_limb_deg: float = DEFAULT_HALF_ANGLES_DEG["earth_limb_deg"]
    moon_deg: float = DEFAULT_HALF_ANGLES_DEG["moon_deg"]
    atmosphere_height_m: float = DEFAULT_ATMOSPHERE_HEIGHT_M

    def check(self, where: str = "exclusion") -> ExclusionCones:
        """Self, or a one-line ValueError naming the field, the value and the allowed range."""
        for name in ("sun_deg", "earth_limb_deg", "moon_deg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 < value < 180.0):
                raise ValueError(f"{where}.{name}: got {value!r}; must be in (0, 180) deg")
        h = self.atmosphere_height_m
        if not (np.isfinite(h) and 0.0 <= h <= 1e6):
            raise ValueError(f"{where}.atmosphere_height_m: got {h!r}; must be in [0, 1e6] m")
        return self


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between vectors (..., 3), robust near 0 and pi."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _hidden_by_earth(r: np.ndarray, r_body: np.ndarray) -> np.ndarray:
    """The body's centre is behind the Earth (a sphere of the equatorial radius) as seen from ``r``."""
    d = r_body - r
    dist = np.linalg.norm(d, axis=-1)
    to_earth = -r
    earth_dist = np.linalg.norm(r, axis=-1)
    return (_angle(d, to_earth) < np.arcsin(np.minimum(EARTH_RADIUS_M / earth_dist, 1.0))) & (dist > earth_dist)


def exclusion_causes(boresight_I, r_I, r_sun_I, r_moon_I, cones: ExclusionCones) -> np.ndarray:
    """The causes (bit flags, int) blinding a tracker whose boresight is ``boresight_I`` (unit,
    (..., 3)) at position ``r_I`` with the Sun and the Moon at ``r_sun_I``, ``r_moon_I`` (m)."""
    b = np.asarray(boresight_I, dtype=float)
    r, r_sun, r_moon = (np.asarray(x, dtype=float) for x in (r_I, r_sun_I, r_moon_I))
    if b.shape == r.shape == r_sun.shape == r_moon.shape == (3,):
        return np.int64(_causes_one(b.tolist(), r.tolist(), r_sun.tolist(), r_moon.tolist(), cones))
    causes = np.zeros(np.broadcast_shapes(b.shape, r.shape, r_sun.shape, r_moon.shape)[:-1], dtype=np.int64)
    sun_in = (_angle(b, r_sun - r) < np.radians(cones.sun_deg)) & ~_hidden_by_earth(r, r_sun)
    limb_radius = np.arcsin(np.minimum((EARTH_RADIUS_M + cones.atmosphere_height_m) / np.linalg.norm(r, axis=-1), 1.0))
    earth_in = _angle(b, -r) < limb_radius + np.radians(cones.earth_limb_deg)
    moon_in = (_angle(b, r_moon - r) < np.radians(cones.moon_deg)) & ~_hidden_by_earth(r, r_moon)
    return causes | np.where(sun_in, SUN, 0) | np.where(earth_in, EARTH, 0) | np.where(moon_in, MOON, 0)


def _angle_one(a, b) -> float:
    """:func:`_angle` of two 3-lists."""
    cx, cy, cz = a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), a[0] * b[0] + a[1] * b[1] + a[2] * b[2])


def _hidden_one(r, r_body) -> bool:
    """:func:`_hidden_by_earth` of 3-lists."""
    d = [r_body[i] - r[i] for i in range(3)]
    earth_dist = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return _angle_one(d, [-r[0], -r[1], -r[2]]) < math.asin(min(EARTH_RADIUS_M / earth_dist, 1.0)) and dist > earth_dist


def _causes_one(b, r, r_sun, r_moon, cones: ExclusionCones) -> int:
    """:func:`exclusion_causes` of one sample (3-lists), in scalar arithmetic: a tracker evaluates it
    at every sample, where numpy's per-call overhead would dominate."""
    causes = CLEAR
    to_sun = [r_sun[i] - r[i] for i in range(3)]
    if _angle_one(b, to_sun) < math.radians(cones.sun_deg) and not _hidden_one(r, r_sun):
        causes |= SUN
    r_norm = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    limb_radius = math.asin(min((EARTH_RADIUS_M + cones.atmosphere_height_m) / r_norm, 1.0))
    if _angle_one(b, [-r[0], -r[1], -r[2]]) < limb_radius + math.radians(cones.earth_limb_deg):
        causes |= EARTH
    to_moon = [r_moon[i] - r[i] for i in range(3)]
    if _angle_one(b, to_moon) < math.radians(cones.moon_deg) and not _hidden_one(r, r_moon):
        causes |= MOON
    return causes


#: How steeply stray light falls off outside an exclusion cone: ``(cone / angle)^STRAY_LIGHT_POWER``
#: (a baffled tracker's point-source transmittance falls roughly as the cube of the off-axis
#: angle over this range).
STRAY_LIGHT_POWER = 3.0


def stray_light_factor(b, r, r_sun, r_moon, cones: ExclusionCones) -> float:
    """Stray light reaching a tracker with boresight ``b`` (unit, 3-list, in I) at ``r`` (m) in
    units of its level at a cone's edge: the sum over the Sun, the Earth's bright limb and the
    Moon (each unless the Earth hides it) of ``(cone / angle)^STRAY_LIGHT_POWER``, the angle
    measured like the cone (from the limb for the Earth). 1 at a cone's edge, falling outside it;
    inside a cone the sample is excluded anyway."""
    total = 0.0
    r_norm = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    limb_radius = math.asin(min((EARTH_RADIUS_M + cones.atmosphere_height_m) / r_norm, 1.0))
    bodies = (
        (_angle_one(b, [r_sun[i] - r[i] for i in range(3)]), cones.sun_deg, not _hidden_one(r, r_sun)),
        (_angle_one(b, [-r[0], -r[1], -r[2]]) - limb_radius, cones.earth_limb_deg, True),
        (_angle_one(b, [r_moon[i] - r[i] for i in range(3)]), cones.moon_deg, not _hidden_one(r, r_moon)),
    )
    for angle, cone_deg, seen in bodies:
        cone = math.radians(cone_deg)
        if seen:
            total += (cone / max(angle, cone)) ** STRAY_LIGHT_POWER
    return total


def star_occulted(directions_I, r_I, atmosphere_height_m: float) -> np.ndarray:
    """Which stars (unit directions ``(m, 3)`` or ``(..., 3)``, at infinity) the Earth and its
    atmosphere hide from ``r_I`` (m): the direction within ``asin((R_E + h) / |r|)`` of nadir."""
    d, r = np.asarray(directions_I, dtype=float), np.asarray(r_I, dtype=float)
    radius = np.arcsin(np.minimum((EARTH_RADIUS_M + atmosphere_height_m) / np.linalg.norm(r, axis=-1), 1.0))
    return _angle(d, -r) < radius


def availability(causes) -> dict:
    """Per cause, the fraction of samples it blinds, and the fraction clear of all:
    ``{"available": f, "sun": f, "earth": f, "moon": f}`` (a sample may count for several causes)."""
    c = np.asarray(causes, dtype=np.int64).ravel()
    if c.size == 0:
        raise ValueError("availability: got no samples")
    out = {"available": float(np.mean(c == CLEAR))}
    out.update({name: float(np.mean((c & flag) != 0)) for flag, name in CAUSE_NAMES.items()})
    return out
