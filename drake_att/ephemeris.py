"""Sun and Moon positions and Earth's shadow (numpy; astropy only when an ephemeris is built).

Time is a Julian date in UTC (``jd_utc``, days, float or array; a float64 Julian date resolves
~40 µs, which is all the geometry here needs).

Positions are geocentric, in metres, in the GCRS frame, the frame astropy's ``get_body`` returns:
the apparent direction from the Earth's centre (light time, annual aberration and light deflection
included). GCRS axes are within ~0.02 arcsec of J2000/EME2000, so for attitude work the two are the
same inertial frame.

:class:`SunMoonEphemeris` samples astropy's built-in ephemeris (ERFA's ``epv00`` for the Sun and
``moon98`` for the Moon, bundled, no download) once on a 4-hour grid over a time span and
interpolates it with cubic Hermite polynomials, so that one evaluation costs microseconds instead
of astropy's milliseconds. astropy is imported only there (its import takes ~0.5 s) and runs with
downloads disabled.

Supported epochs (:func:`supported_jd_range`): from 1972-01-01 UTC (the start of leap-second UTC)
to the expiry date of the leap-second table astropy loads offline (the ``astropy-iers-data``
package; 2027-06-28 for the release of 2026-11). Beyond that date a leap second not yet announced
could make UTC -> TT wrong by a second, so such epochs are refused rather than guessed.

Eclipse: :func:`cylindrical_shadow` and :func:`shadow_fraction` (conical, with penumbra) for a
spherical Earth of the equatorial radius, optionally grown by an atmosphere height.
"""

from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import dataclass, field

import numpy as np

from drake_att.orbit import EARTH_RADIUS_M

SUN_RADIUS_M = 696_000e3
"""Solar radius used for the apparent solar disk (IAU 2015 nominal value, rounded)."""

GRID_STEP_DAYS = 4.0 / 24.0
"""Sampling step of :class:`SunMoonEphemeris` (4 h). Interpolation error measured at the grid
mid-points (the worst case) over 2026: Moon 1.7e-7 deg in direction and 1.1e-8 relative in
distance, Sun 4e-9 deg and 1.3e-12 (tests/test_ephemeris.py bounds them at 1e-5 deg and 1e-7)."""

MAX_SPAN_DAYS = 731.0
"""Longest time span one :class:`SunMoonEphemeris` covers (two years)."""

JD_UTC_MIN = 2441317.5
"""1972-01-01 00:00 UTC: the start of UTC with leap seconds (earlier UTC is not a fixed offset from TAI)."""

_PAD_NODES = 2  # grid nodes beyond each end of the span, for the central-difference derivatives
_SECONDS_PER_DAY = 86400.0


@contextlib.contextmanager
def _astropy_offline():
    """astropy configured to use only the data installed with it (no IERS or ephemeris downloads)."""
    from astropy.utils import data, iers

    with iers.conf.set_temp("auto_download", False), data.conf.set_temp("allow_internet", False):
        yield


@functools.lru_cache(maxsize=1)
def supported_jd_range() -> tuple[float, float]:
    """``(jd_min, jd_max)`` in UTC that an ephemeris may span: 1972-01-01 to the leap-second table's expiry."""
    with _astropy_offline():
        from astropy.utils.iers import LeapSeconds

        expires = LeapSeconds.auto_open().expires  # a date; taken as 00:00 UTC of that day
    return JD_UTC_MIN, float(expires.jd)


def _as_finite_jd(jd_utc, name: str = "jd_utc") -> np.ndarray:
    jd = np.asarray(jd_utc, dtype=float)
    if not np.all(np.isfinite(jd)):
        bad = jd[~np.isfinite(jd)].flat[0] if jd.ndim else jd
        raise ValueError(f"{name} = {bad}: must be a finite Julian date (UTC, days)")
    return jd


def astropy_geocentric_positions_m(body: str, jd_utc) -> np.ndarray:
    """Geocentric GCRS position of ``body`` ('sun' or 'moon') from astropy's built-in ephemeris (m, (..., 3)).

    The reference that :class:`SunMoonEphemeris` interpolates; costs milliseconds per call.
    """
    jd = _as_finite_jd(jd_utc)
    with _astropy_offline():
        import astropy.units as u
        from astropy.coordinates import get_body, solar_system_ephemeris
        from astropy.time import Time

        with solar_system_ephemeris.set("builtin"):
            coord = get_body(body, Time(jd.ravel(), format="jd", scale="utc"))
        xyz = coord.cartesian.xyz.to_value(u.m)  # (3, n)
    return np.moveaxis(xyz, 0, -1).reshape(jd.shape + (3,))


def _check_span(jd_start: float, jd_end: float) -> None:
    jd_min, jd_max = supported_jd_range()
    for name, value in (("jd_start", jd_start), ("jd_end", jd_end)):
        _as_finite_jd(value, name)
        if not jd_min <= value <= jd_max:
            raise ValueError(
                f"{name} = {value}: outside the offline-supported range [{jd_min}, {jd_max}] (UTC JD, "
                "1972-01-01 to the leap-second table's expiry)"
            )
    if jd_end < jd_start:
        raise ValueError(f"jd_end = {jd_end}: must be >= jd_start = {jd_start}")
    if jd_end - jd_start > MAX_SPAN_DAYS:
        raise ValueError(f"jd_end - jd_start = {jd_end - jd_start} days: at most {MAX_SPAN_DAYS} days per ephemeris")


def _central_derivative(samples: np.ndarray, step: float) -> np.ndarray:
    """Fourth-order central difference along axis 0; the result has 2 fewer rows at each end."""
    s = samples
    return (s[:-4] - 8.0 * s[1:-3] + 8.0 * s[3:-1] - s[4:]) / (12.0 * step)


@dataclass(frozen=True)
class _HermiteTable:
    """Positions and rates on a uniform grid, evaluated by cubic Hermite interpolation."""

    jd0: float
    step_days: float
    positions: np.ndarray  # (n, 3)
    rates: np.ndarray  # (n, 3), per day

    def at_scalar(self, jd: float) -> np.ndarray:
        """The interpolant at one time, with Python floats for the basis (a few µs)."""
        x = (jd - self.jd0) / self.step_days
        i = min(int(math.floor(x)), len(self.positions) - 2)
        t = x - i
        t2 = t * t
        t3 = t2 * t
        h00 = 2.0 * t3 - 3.0 * t2 + 1.0
        h10 = (t3 - 2.0 * t2 + t) * self.step_days
        h01 = -2.0 * t3 + 3.0 * t2
        h11 = (t3 - t2) * self.step_days
        p, m = self.positions, self.rates
        return h00 * p[i] + h10 * m[i] + h01 * p[i + 1] + h11 * m[i + 1]

    def __call__(self, jd: np.ndarray) -> np.ndarray:
        if jd.ndim == 0:
            return self.at_scalar(float(jd))
        x = (jd - self.jd0) / self.step_days
        i = np.minimum(np.floor(x).astype(np.intp), len(self.positions) - 2)
        t = (x - i)[..., None]
        t2 = t * t
        t3 = t2 * t
        h00 = 2.0 * t3 - 3.0 * t2 + 1.0
        h10 = t3 - 2.0 * t2 + t
        h01 = -2.0 * t3 + 3.0 * t2
        h11 = t3 - t2
        p, m = self.positions, self.rates * self.step_days
        return h00 * p[i] + h10 * m[i] + h01 * p[i + 1] + h11 * m[i + 1]


def _hermite_table(body: str, jd_start: float, jd_end: float, step_days: float) -> _HermiteTable:
    n_inner = int(np.ceil((jd_end - jd_start) / step_days)) + 1
    n_inner = max(n_inner, 2)
    nodes = jd_start + step_days * np.arange(-_PAD_NODES, n_inner + _PAD_NODES)
    samples = astropy_geocentric_positions_m(body, nodes)
    return _HermiteTable(
        jd0=jd_start,
        step_days=step_days,
        positions=samples[_PAD_NODES:-_PAD_NODES],
        rates=_central_derivative(samples, step_days),
    )


@dataclass(frozen=True)
class SunMoonEphemeris:
    """Geocentric Sun and Moon positions in GCRS (≈ J2000/EME2000 to ~0.02 arcsec) over ``[jd_start, jd_end]`` UTC.

    Built once from astropy's built-in ephemeris sampled every :data:`GRID_STEP_DAYS` (4 h) and
    interpolated by cubic Hermite polynomials (rates from fourth-order central differences of the
    samples). Interpolation error: < 2e-7 deg in direction for the Moon, far below the built-in
    ephemeris' own accuracy. Build cost: ~0.02 s for a day, ~1.3 s for a year (plus ~0.5 s to import
    astropy the first time); evaluation: ~6 µs for one float time, ~0.1 µs per element for an array.

    Refused: a span outside :func:`supported_jd_range`, longer than :data:`MAX_SPAN_DAYS`, or with
    ``jd_end < jd_start``; an evaluation time outside the span or not finite.
    """

    jd_start: float
    jd_end: float
    _sun: _HermiteTable = field(init=False, repr=False, compare=False)
    _moon: _HermiteTable = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        _check_span(self.jd_start, self.jd_end)
        object.__setattr__(self, "_sun", _hermite_table("sun", self.jd_start, self.jd_end, GRID_STEP_DAYS))
        object.__setattr__(self, "_moon", _hermite_table("moon", self.jd_start, self.jd_end, GRID_STEP_DAYS))

    def _checked_jd(self, jd_utc) -> np.ndarray:
        if isinstance(jd_utc, float) and self.jd_start <= jd_utc <= self.jd_end:
            return np.asarray(jd_utc)  # the common case inside a simulation step, checked cheaply
        jd = _as_finite_jd(jd_utc)
        outside = (jd < self.jd_start) | (jd > self.jd_end)
        if np.any(outside):
            bad = jd[outside].flat[0] if jd.ndim else jd
            raise ValueError(f"jd_utc = {bad}: outside the ephemeris span [{self.jd_start}, {self.jd_end}]")
        return jd

    def sun_position_m(self, jd_utc) -> np.ndarray:
        """Geocentric GCRS position of the Sun (m), shape ``jd_utc.shape + (3,)``."""
        return self._sun(self._checked_jd(jd_utc))

    def moon_position_m(self, jd_utc) -> np.ndarray:
        """Geocentric GCRS position of the Moon (m), shape ``jd_utc.shape + (3,)``."""
        return self._moon(self._checked_jd(jd_utc))

    def sun_direction(self, jd_utc) -> np.ndarray:
        """Unit vector from the Earth's centre to the Sun (GCRS), shape ``jd_utc.shape + (3,)``."""
        return _unit(self.sun_position_m(jd_utc))

    def moon_direction(self, jd_utc) -> np.ndarray:
        """Unit vector from the Earth's centre to the Moon (GCRS), shape ``jd_utc.shape + (3,)``."""
        return _unit(self.moon_position_m(jd_utc))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _check_outside_earth(r_I: np.ndarray, earth_radius_m: float) -> np.ndarray:
    norm = np.linalg.norm(r_I, axis=-1)
    if not np.all(norm > earth_radius_m):
        bad = norm[~(norm > earth_radius_m)].flat[0] if norm.ndim else norm
        raise ValueError(f"|r_I| = {bad} m: must be finite and > the shadowing radius {earth_radius_m} m")
    return norm


def _shadowing_radius(atmosphere_height_m: float) -> float:
    if not (np.isfinite(atmosphere_height_m) and atmosphere_height_m >= 0):
        raise ValueError(f"atmosphere_height_m = {atmosphere_height_m}: must be finite and >= 0")
    return EARTH_RADIUS_M + atmosphere_height_m


def cylindrical_shadow(r_I, r_sun_I, atmosphere_height_m: float = 0.0) -> np.ndarray:
    """True where the spacecraft at ``r_I`` (m, (..., 3)) is in the Earth's cylindrical shadow.

    Model: the Sun at infinity in the direction of ``r_sun_I`` (geocentric, m); the shadow is the
    half-infinite cylinder of radius ``R = 6378137 m + atmosphere_height_m`` behind the Earth.
    In shadow: ``r·s < 0`` and the distance of ``r`` from the Earth-Sun line is < R.
    """
    radius = _shadowing_radius(atmosphere_height_m)
    r = np.asarray(r_I, dtype=float)
    _check_outside_earth(r, radius)
    s = _unit(np.asarray(r_sun_I, dtype=float))
    along = np.sum(r * s, axis=-1)
    across_sq = np.sum(r * r, axis=-1) - along * along
    return (along < 0.0) & (across_sq < radius * radius)


def shadow_fraction(r_I, r_sun_I, atmosphere_height_m: float = 0.0) -> np.ndarray:
    """Fraction of the solar disk visible from ``r_I`` (m, (..., 3)): 1 sunlit, 0 umbra, between: penumbra.

    Conical model (Montenbruck & Gill, *Satellite Orbits*, 3.4.2): the Sun a disk of apparent radius
    ``a = asin(R_sun / |r_sun - r|)`` (``R_sun = 696000 km``), the Earth a disk of apparent radius
    ``b = asin(R / |r|)`` (``R = 6378137 m + atmosphere_height_m``, a sphere of the equatorial
    radius), ``c`` the angle between their centres seen from the spacecraft. The visible fraction
    is one minus the overlap area of the two disks (flat-disk formula) over ``pi a^2``.
    """
    radius = _shadowing_radius(atmosphere_height_m)
    r = np.asarray(r_I, dtype=float)
    r_norm = _check_outside_earth(r, radius)
    to_sun = np.asarray(r_sun_I, dtype=float) - r
    to_sun_norm = np.linalg.norm(to_sun, axis=-1)
    a = np.arcsin(np.minimum(SUN_RADIUS_M / to_sun_norm, 1.0))
    b = np.arcsin(radius / r_norm)
    cos_c = -np.sum(r * to_sun, axis=-1) / (r_norm * to_sun_norm)
    c = np.arccos(np.clip(cos_c, -1.0, 1.0))
    return _visible_fraction(a, b, c)


def _visible_fraction(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Visible fraction of a disk of radius ``a`` behind a disk of radius ``b`` at centre distance ``c``."""
    a, b, c = np.broadcast_arrays(a, b, c)
    fraction = np.ones(a.shape)
    total = c <= b - a  # the Earth covers the whole Sun
    annular = c <= a - b  # the Earth inside the Sun's disk
    partial = (c < a + b) & ~total & ~annular
    fraction[total] = 0.0
    fraction[annular] = 1.0 - (b[annular] / a[annular]) ** 2
    ap, bp, cp = a[partial], b[partial], c[partial]
    x = (cp * cp + ap * ap - bp * bp) / (2.0 * cp)
    y = np.sqrt(np.maximum(ap * ap - x * x, 0.0))
    overlap = (
        ap * ap * np.arccos(np.clip(x / ap, -1.0, 1.0))
        + bp * bp * np.arccos(np.clip((cp - x) / bp, -1.0, 1.0))
        - cp * y
    )
    fraction[partial] = 1.0 - overlap / (np.pi * ap * ap)
    return fraction[()] if fraction.ndim == 0 else fraction
