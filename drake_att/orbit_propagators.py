"""Orbits from Keplerian elements or a TLE, and the LVLH frame of any orbit (no Drake).

Every orbit here gives the spacecraft's position and velocity in the inertial frame I at
``t`` seconds after the scenario's epoch (``epoch_utc``), and the LVLH frame O built from
them (:func:`lvlh_quaternion`: ``z_O`` nadir, ``y_O`` along the negative orbit normal,
``x_O = y_O x z_O``; for a circular orbit ``x_O`` is the velocity, as in
:class:`drake_att.orbit.CircularOrbit`).

Frames. I is GCRS (within ~0.02 arcsec of J2000/EME2000).

* :class:`KeplerOrbit` takes its elements in I: two-body motion (Kepler's equation), with
  J2 optionally as the secular drift of the node, the argument of perigee and the mean
  anomaly (mean elements; the short-period J2 terms, ~1 km at LEO, are left out).
* :class:`TleOrbit` is ``sgp4``'s propagation of the TLE (in its TEME frame) rotated into
  GCRS by the TEME->GCRS rotation of the scenario's epoch (astropy, offline), held for the
  run: precession and nutation move it by < 0.2 arcsec per day.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drake_att import rotations as rot
from drake_att.orbit import EARTH_RADIUS_M, mean_motion

EARTH_J2 = 1.08262668e-3  # EGM2008 / WGS-84 (unnormalized)
MAX_TLE_AGE_DAYS = 30.0  # SGP4's error grows ~1-3 km per day from a TLE's epoch


class OrbitError(ValueError):
    """A bad orbit definition; the message names the field, the value and what is allowed."""


# ---------------------------------------------------------------------------------------------
# The LVLH frame of a position and velocity
# ---------------------------------------------------------------------------------------------
def lvlh_rotation(r_I, v_I) -> np.ndarray:
    """``R_IO`` (columns: the O axes in I) for positions and velocities ``(..., 3)``."""
    r_I, v_I = np.asarray(r_I, dtype=float), np.asarray(v_I, dtype=float)
    z = -r_I / np.linalg.norm(r_I, axis=-1, keepdims=True)
    h = np.cross(r_I, v_I)
    y = -h / np.linalg.norm(h, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


def lvlh_quaternion(r_I, v_I) -> np.ndarray:
    """``q_IO`` of the LVLH frame (see the module docstring)."""
    return rot.rotmat_to_quat(lvlh_rotation(r_I, v_I))


# ---------------------------------------------------------------------------------------------
# Time
# ---------------------------------------------------------------------------------------------
def parse_epoch_utc(text: str, field_name: str = "orbit.epoch_utc") -> _dt.datetime:
    """An ISO 8601 UTC instant (``2026-06-01T12:00:00`` or with ``Z`` / ``+00:00``) as a naive
    UTC datetime; :class:`OrbitError` naming ``field_name`` otherwise."""
    if not isinstance(text, str) or not text.strip():
        raise OrbitError(f"{field_name}: got {text!r}; expected an ISO 8601 UTC time such as 2026-06-01T12:00:00Z")
    s = text.strip()
    try:
        t = _dt.datetime.fromisoformat(s[:-1] + "+00:00" if s.endswith(("Z", "z")) else s)
    except ValueError:
        raise OrbitError(
            f"{field_name}: got {text!r}; expected an ISO 8601 UTC time such as 2026-06-01T12:00:00Z"
        ) from None
    if t.tzinfo is not None:
        if t.utcoffset() != _dt.timedelta(0):
            raise OrbitError(f"{field_name}: got {text!r}; the epoch must be in UTC (Z or +00:00)")
        t = t.replace(tzinfo=None)
    if not 1957 <= t.year <= 2099:
        raise OrbitError(f"{field_name}: got {text!r}; must be within 1957-2099 (TLE and time-scale range)")
    return t


def julian_date_utc(t: _dt.datetime) -> float:
    """The Julian date (UTC, days) of a naive UTC datetime."""
    j2000 = _dt.datetime(2000, 1, 1, 12, 0, 0)
    return 2451545.0 + (t - j2000).total_seconds() / 86400.0


# ---------------------------------------------------------------------------------------------
# Two-body (+ secular J2)
# ---------------------------------------------------------------------------------------------
def solve_kepler(mean_anomaly, e: float) -> np.ndarray:
    """Eccentric anomaly ``E`` with ``E - e sin E = M`` (Newton, to round-off), 0 <= e < 1."""
    M = np.mod(np.asarray(mean_anomaly, dtype=float), 2.0 * np.pi)
    E = M + e * np.sin(M) if e < 0.8 else np.full_like(M, np.pi)
    for _ in range(50):
        dE = (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        E = E - dE
        if np.all(np.abs(dE) < 1e-15):
            break
    return E


@dataclass(frozen=True)
class KeplerOrbit:
    """An orbit from Keplerian elements at the epoch (angles in rad, in I).

    Attributes:
        semi_major_axis_m: a (m), with perigee above the Earth's surface.
        eccentricity: e, 0 <= e < 1.
        inclination_rad, raan_rad, arg_perigee_rad, mean_anomaly_rad: i, RAAN, argument of
            perigee and mean anomaly at t = 0.
        j2: add the secular J2 drift of RAAN, argument of perigee and mean anomaly.
    """

    semi_major_axis_m: float
    eccentricity: float = 0.0
    inclination_rad: float = 0.0
    raan_rad: float = 0.0
    arg_perigee_rad: float = 0.0
    mean_anomaly_rad: float = 0.0
    j2: bool = False

    mean_motion_rad_per_s = property(lambda self: mean_motion(self.semi_major_axis_m), doc="n (rad/s)")
    period_s = property(lambda self: 2.0 * np.pi / mean_motion(self.semi_major_axis_m), doc="2 pi / n (s)")

    def secular_rates(self) -> tuple[float, float, float]:
        """``(dRAAN/dt, dargp/dt, dM/dt)`` (rad/s): two-body (0, 0, n), plus J2's secular terms."""
        n, e, i = self.mean_motion_rad_per_s, self.eccentricity, self.inclination_rad
        if not self.j2:
            return 0.0, 0.0, n
        p = self.semi_major_axis_m * (1.0 - e * e)
        k = 1.5 * n * EARTH_J2 * (EARTH_RADIUS_M / p) ** 2
        c = np.cos(i)
        return (
            float(-k * c),
            float(0.5 * k * (5.0 * c * c - 1.0)),
            float(n + 0.5 * k * np.sqrt(1.0 - e * e) * (3.0 * c * c - 1.0)),
        )

    def position_velocity_I(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) in I at ``t`` (s), each ``t.shape + (3,)``."""
        t = np.asarray(t, dtype=float)
        raan_dot, argp_dot, m_dot = self.secular_rates()
        e, a = self.eccentricity, self.semi_major_axis_m
        E = solve_kepler(self.mean_anomaly_rad + m_dot * t, e)
        cos_E, sin_E = np.cos(E), np.sin(E)
        b = np.sqrt(1.0 - e * e)
        r = a * (1.0 - e * cos_E)
        n = self.mean_motion_rad_per_s
        p_perifocal = np.stack([a * (cos_E - e), a * b * sin_E, np.zeros_like(E)], axis=-1)
        v_perifocal = np.stack([-a * n * sin_E / (r / a), a * n * b * cos_E / (r / a), np.zeros_like(E)], axis=-1)
        R = _perifocal_to_inertial(
            self.raan_rad + raan_dot * t, self.inclination_rad, self.arg_perigee_rad + argp_dot * t
        )
        return np.einsum("...ij,...j->...i", R, p_perifocal), np.einsum("...ij,...j->...i", R, v_perifocal)

    def q_IO(self, t) -> np.ndarray:
        return lvlh_quaternion(*self.position_velocity_I(t))


def _perifocal_to_inertial(raan, inc, argp) -> np.ndarray:
    """``Rz(RAAN) Rx(i) Rz(argp)`` for arrays of angles, shape ``(..., 3, 3)``."""
    raan, argp = np.asarray(raan, dtype=float), np.asarray(argp, dtype=float)
    raan, argp = np.broadcast_arrays(raan, argp)
    cO, sO, cw, sw = np.cos(raan), np.sin(raan), np.cos(argp), np.sin(argp)
    ci, si = np.cos(inc), np.sin(inc)
    return np.stack(
        [
            np.stack([cO * cw - sO * sw * ci, -cO * sw - sO * cw * ci, sO * si], axis=-1),
            np.stack([sO * cw + cO * sw * ci, -sO * sw + cO * cw * ci, -cO * si], axis=-1),
            np.stack([sw * si, cw * si, np.full_like(raan, ci)], axis=-1),
        ],
        axis=-2,
    )


# ---------------------------------------------------------------------------------------------
# TLE (sgp4)
# ---------------------------------------------------------------------------------------------
def tle_checksum(line: str) -> int:
    """The TLE checksum of a line's first 68 characters: digits summed, each '-' counts 1, mod 10."""
    return sum(int(c) if c.isdigit() else (1 if c == "-" else 0) for c in line[:68]) % 10


def check_tle(line1, line2, field_prefix: str = "orbit") -> None:
    """Refuse a malformed TLE: :class:`OrbitError` naming the line, the problem and the rule."""
    for k, line in ((1, line1), (2, line2)):
        name = f"{field_prefix}.line{k}"
        if not isinstance(line, str):
            raise OrbitError(f"{name}: got {line!r}; expected the TLE's line {k} as a string")
        text = line.rstrip()
        if not (text.isascii() and text.isprintable()):
            bad = next(c for c in text if not (c.isascii() and c.isprintable()))
            raise OrbitError(f"{name}: contains {bad!r}; a TLE line holds printable ASCII only")
        if len(text) != 69:
            raise OrbitError(f"{name}: got {len(text)} characters; a TLE line has 69 ({text[:40]!r}...)")
        if text[0] != str(k) or text[1] != " ":
            raise OrbitError(f"{name}: starts with {text[:2]!r}; line {k} of a TLE starts with '{k} '")
        if not text[68].isdigit() or int(text[68]) != tle_checksum(text):
            raise OrbitError(
                f"{name}: checksum {text[68]!r} does not match the line (expected {tle_checksum(text)}); "
                "a character was changed or lost"
            )
    if line1[2:7] != line2[2:7]:
        raise OrbitError(
            f"{field_prefix}.line2: satellite number {line2[2:7].strip()!r} differs from line 1's {line1[2:7].strip()!r}"
        )


@dataclass(frozen=True)
class TleOrbit:
    """``sgp4``'s propagation of a TLE from the scenario's epoch, in I (see the module docstring).

    Attributes:
        line1, line2: the TLE (checked: length, line numbers, checksums, satellite number).
        epoch_utc: the scenario's t = 0 (ISO 8601 UTC), within :data:`MAX_TLE_AGE_DAYS` of the
            TLE's own epoch.
    """

    line1: str
    line2: str
    epoch_utc: str
    _sat: Any = field(init=False, repr=False, compare=False)
    _offset_min: float = field(init=False, repr=False, compare=False)
    _R_GCRS_TEME: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        from sgp4.api import WGS72, Satrec

        check_tle(self.line1, self.line2)
        epoch = parse_epoch_utc(self.epoch_utc)
        sat = Satrec.twoline2rv(self.line1.rstrip(), self.line2.rstrip(), WGS72)
        if sat.error:
            raise OrbitError(f"orbit.line2: sgp4 cannot initialize this TLE (error code {sat.error})")
        offset_days = julian_date_utc(epoch) - (sat.jdsatepoch + sat.jdsatepochF)
        if abs(offset_days) > MAX_TLE_AGE_DAYS:
            raise OrbitError(
                f"orbit.epoch_utc: got {self.epoch_utc!r}, {offset_days:+.1f} days from the TLE's epoch; must be "
                f"within {MAX_TLE_AGE_DAYS:g} days of it (SGP4's error grows ~1-3 km per day)"
            )
        object.__setattr__(self, "_sat", sat)
        object.__setattr__(self, "_offset_min", offset_days * 1440.0)
        object.__setattr__(self, "_R_GCRS_TEME", teme_to_gcrs_rotation(julian_date_utc(epoch)))

    def position_velocity_teme(self, t) -> tuple[np.ndarray, np.ndarray]:
        """sgp4's position (m) and velocity (m/s) in TEME at ``t`` s after the epoch."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        jd = self._sat.jdsatepoch + np.zeros_like(t)
        fr = self._sat.jdsatepochF + (self._offset_min + t / 60.0) / 1440.0
        err, r_km, v_km_s = self._sat.sgp4_array(jd, fr)
        if np.any(err):
            raise OrbitError(
                f"orbit: sgp4 failed at t = {float(t[np.argmax(err != 0)]):g} s (error code {int(err.max())}: "
                "the orbit decayed or the elements went out of range)"
            )
        return 1e3 * r_km, 1e3 * v_km_s

    def position_velocity_I(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) in I at ``t`` (s), each ``t.shape + (3,)``."""
        shape = np.shape(t)
        r, v = self.position_velocity_teme(t)
        R = self._R_GCRS_TEME
        return (r @ R.T).reshape(shape + (3,)), (v @ R.T).reshape(shape + (3,))

    def q_IO(self, t) -> np.ndarray:
        return lvlh_quaternion(*self.position_velocity_I(t))


def teme_to_gcrs_rotation(jd_utc: float) -> np.ndarray:
    """The rotation ``R_GCRS_TEME`` at a UTC Julian date, from astropy's TEME and GCRS frames
    (offline: its bundled IERS tables, no download)."""
    from astropy import units as u
    from astropy.coordinates import GCRS, TEME, CartesianRepresentation
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False
    when = Time(jd_utc, format="jd", scale="utc")
    axes = CartesianRepresentation(np.eye(3) * u.km)  # the three TEME unit vectors, km
    gcrs = TEME(axes, obstime=when).transform_to(GCRS(obstime=when))
    origin = TEME(CartesianRepresentation(np.zeros((3, 3)) * u.km), obstime=when).transform_to(GCRS(obstime=when))
    columns = (gcrs.cartesian.xyz - origin.cartesian.xyz).to_value(u.km)  # (3, 3): column k = image of e_k
    U, _, Vt = np.linalg.svd(columns)  # the nearest rotation (removes round-off)
    return U @ Vt
