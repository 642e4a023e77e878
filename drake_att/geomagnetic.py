"""The Earth's magnetic field (IGRF) at a spacecraft position given in the inertial frame.

Frames and time:

* Positions come in the GCRS (geocentric, axes of the ICRS) in metres. J2000/EME2000 differs from
  the GCRS by the frame bias (~23 mas, ~1.1e-7 rad); callers may treat the two as the same.
* The Earth-fixed frame is the ITRS; the IGRF is expanded in its geocentric spherical coordinates
  (radius, colatitude, east longitude).
* Times are Julian dates in UTC (days), a float or a numpy array. Every day counts 86400 s, as for
  Python's datetime; on a day that ends with a leap second this differs from ERFA's quasi-JD
  convention (86401-s day) by up to 1 s.

GCRS -> ITRS follows IAU 2006/2000A (CIO based, pyerfa): R(t) = W @ R3(ERA(t)) @ Q, where Q is the
precession-nutation (celestial-to-intermediate) matrix, ERA the Earth rotation angle and W the polar
motion matrix. :class:`EarthRotation` evaluates Q, W and UT1-UTC once at a run's epoch and then only the
ERA, which is linear in UT1 (UT1-TAI is held, so leap seconds are followed). Over 24 h the frozen Q
drifts with precession and nutation: 24 h after the epoch the matrix is within 0.151 arcsec (7.3e-7 rad;
median 0.073 arcsec) of the full transform with the day's EOP, over 5626 epochs in 1973-2029. That moves a
LEO position by < 6 m (the field changes by ~0.02 nT/m there) and turns B by < 1e-6 rad: < 0.2 nT.

UT1-UTC and polar motion come from the IERS table bundled with astropy (``finals2000A.all`` of
astropy-iers-data: measured values and the IERS predictions, 1973-01-02 to 2027-10-29 in its 2026.11
release; read from disk, never downloaded). Outside that table both are taken as zero: |UT1-UTC| < 0.9 s
keeps the rotation error below 6.6e-5 rad (13.5 arcsec), and polar motion below ~0.6 arcsec.

The field: IGRF coefficients from ``ppigrf`` (2.1: its bundled IGRF-14 file, 1900.0-2030.0, the last
five years from the predicted secular variation), interpolated linearly in time to the epoch exactly as
``ppigrf`` does and then held fixed for the run (the secular variation changes the LEO field by < 0.4 nT
per day; 0.35 nT measured). The synthesis (Schmidt semi-normalized Legendre functions to degree 13) is
written here in numpy because ``ppigrf.igrf_gc`` rereads its coefficient file with pandas on every call
(~19 ms); one point here costs ~0.25 ms, a batch ~9 us per point.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import lru_cache

import erfa
import numpy as np
import ppigrf
import ppigrf.ppigrf as _ppigrf_module

J2000_JD = 2451545.0
MJD_OFFSET = 2400000.5
SECONDS_PER_DAY = 86400.0
TT_MINUS_TAI_S = 32.184
ARCSEC_TO_RAD = np.pi / (180.0 * 3600.0)
NANOTESLA_TO_TESLA = 1e-9

WGS84_EQUATORIAL_RADIUS_M = 6378137.0
WGS84_POLAR_RADIUS_M = 6356752.314245
IGRF_REFERENCE_RADIUS_M = _ppigrf_module.RE * 1e3  # 6371.2 km
IGRF_MAX_DEGREE = 13

# ERA(Tu) = 2 pi (0.7790572732640 + 1.00273781191135448 Tu), Tu = JD(UT1) - 2451545.0 (IERS Conventions 2010, 5.15).
_ERA_AT_J2000_TURNS = 0.7790572732640
_ERA_RATE_EXCESS_TURNS_PER_DAY = 0.00273781191135448

IGRF_COEFFICIENT_FILE = _ppigrf_module.shc_fn
IGRF_GENERATION = os.path.splitext(os.path.basename(IGRF_COEFFICIENT_FILE))[0]  # "IGRF14"


# --------------------------------------------------------------------------------------------------
# Time
# --------------------------------------------------------------------------------------------------


def terrestrial_time_jd(jd_utc: float) -> tuple[float, float]:
    """TT as a two-part Julian date (erfa's form): UTC + (TAI-UTC) + 32.184 s."""
    return float(jd_utc), (float(tai_minus_utc_s(jd_utc)) + TT_MINUS_TAI_S) / SECONDS_PER_DAY


@lru_cache(maxsize=1)
def _leap_second_table() -> tuple[np.ndarray, np.ndarray]:
    """Dates (JD, UTC) from which TAI-UTC (s) holds, from erfa's table (steps only; the pre-1972 drift terms
    are left out, < 1.3 ms per day)."""
    table = erfa.leap_seconds.get()
    first_day_jd = np.sum(erfa.cal2jd(table["year"], table["month"], np.ones_like(table["month"])), axis=0)
    return first_day_jd, np.asarray(table["tai_utc"], dtype=float)


def tai_minus_utc_s(jd_utc: np.ndarray | float) -> np.ndarray:
    """TAI-UTC (s) at UTC Julian dates: the leap seconds accumulated so far (0 before 1960)."""
    first_day_jd, offsets = _leap_second_table()
    index = np.searchsorted(first_day_jd, np.asarray(jd_utc, dtype=float), side="right") - 1
    return np.where(index >= 0, offsets[np.maximum(index, 0)], 0.0)


@dataclass(frozen=True)
class EarthOrientation:
    """UT1-UTC (s) and polar motion (rad) at one date, and whether they came from the IERS table."""

    ut1_minus_utc_s: float
    polar_motion_x_rad: float
    polar_motion_y_rad: float
    from_iers_table: bool


@lru_cache(maxsize=1)
def _iers_table():
    """astropy's bundled IERS Bulletin A table (measured + predicted EOP), read from disk only."""
    from astropy.utils import iers

    return iers.IERS_A.open(iers.IERS_A_FILE)


def earth_orientation(jd_utc: float) -> EarthOrientation:
    """Earth orientation parameters at a date from the bundled IERS table, or zeros outside it."""
    table = _iers_table()
    mjd = np.asarray(table["MJD"].value, dtype=float)
    if not mjd[0] <= float(jd_utc) - MJD_OFFSET <= mjd[-1]:
        return EarthOrientation(0.0, 0.0, 0.0, from_iers_table=False)
    dut1 = table.ut1_utc(float(jd_utc), 0.0)
    pm_x, pm_y = table.pm_xy(float(jd_utc), 0.0)
    return EarthOrientation(
        ut1_minus_utc_s=float(dut1.to_value("s")),
        polar_motion_x_rad=float(pm_x.to_value("arcsec")) * ARCSEC_TO_RAD,
        polar_motion_y_rad=float(pm_y.to_value("arcsec")) * ARCSEC_TO_RAD,
        from_iers_table=True,
    )


# --------------------------------------------------------------------------------------------------
# GCRS -> ITRS
# --------------------------------------------------------------------------------------------------


def earth_rotation_angle_rad(jd_ut1: np.ndarray | float) -> np.ndarray:
    """The Earth rotation angle (rad, in [0, 2 pi)) at a UT1 Julian date (IERS Conventions 2010, eq. 5.15)."""
    days = np.asarray(jd_ut1, dtype=float) - J2000_JD
    turns = np.mod(days, 1.0) + _ERA_AT_J2000_TURNS + _ERA_RATE_EXCESS_TURNS_PER_DAY * days
    return 2.0 * np.pi * np.mod(turns, 1.0)


def _rotation_about_z(angle_rad: np.ndarray) -> np.ndarray:
    """R3(angle): the frame rotation about z (passive), shape angle.shape + (3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    matrix = np.zeros(np.shape(angle_rad) + (3, 3))
    matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 1, 0], matrix[..., 1, 1] = c, s, -s, c
    matrix[..., 2, 2] = 1.0
    return matrix


def _rotate_about_z(angle_rad: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R3(angle) @ v for vectors v (N, 3) and angles (N,), without forming the matrices."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    out = np.empty_like(v)
    out[:, 0] = c * v[:, 0] + s * v[:, 1]
    out[:, 1] = c * v[:, 1] - s * v[:, 0]
    out[:, 2] = v[:, 2]
    return out


def gcrs_to_itrs_full(jd_utc: float) -> np.ndarray:
    """The full IAU 2006/2000A GCRS -> ITRS matrix at one date (erfa.c2t06a, EOP from the IERS table)."""
    eop = earth_orientation(jd_utc)
    tt1, tt2 = terrestrial_time_jd(jd_utc)
    ut1_2 = eop.ut1_minus_utc_s / SECONDS_PER_DAY
    return erfa.c2t06a(tt1, tt2, float(jd_utc), ut1_2, eop.polar_motion_x_rad, eop.polar_motion_y_rad)


class EarthRotation:
    """GCRS -> ITRS for a run: precession-nutation, polar motion and UT1-UTC frozen at the epoch, ERA exact."""

    def __init__(self, epoch_jd_utc: float):
        self.epoch_jd_utc = float(epoch_jd_utc)
        self.orientation = earth_orientation(self.epoch_jd_utc)
        tt1, tt2 = terrestrial_time_jd(self.epoch_jd_utc)
        self._celestial_to_intermediate = erfa.c2i06a(tt1, tt2)
        tio_locator = erfa.sp00(tt1, tt2)
        self._polar_motion = erfa.pom00(
            self.orientation.polar_motion_x_rad, self.orientation.polar_motion_y_rad, tio_locator
        )
        # UT1-TAI is continuous (UT1-UTC jumps by the leap seconds), so that is what is held fixed.
        self._ut1_minus_tai_s = self.orientation.ut1_minus_utc_s - float(tai_minus_utc_s(self.epoch_jd_utc))

    def earth_rotation_angle_rad(self, jd_utc: np.ndarray | float) -> np.ndarray:
        """ERA at UTC dates, with the epoch's UT1-TAI and the leap seconds in between."""
        jd = np.asarray(jd_utc, dtype=float)
        ut1_minus_utc_s = tai_minus_utc_s(jd) + self._ut1_minus_tai_s
        return earth_rotation_angle_rad(jd + ut1_minus_utc_s / SECONDS_PER_DAY)

    def gcrs_to_itrs(self, jd_utc: np.ndarray | float) -> np.ndarray:
        """R_EI: ITRS components = R_EI @ GCRS components; shape jd.shape + (3, 3)."""
        spin = _rotation_about_z(self.earth_rotation_angle_rad(jd_utc))
        return self._polar_motion @ spin @ self._celestial_to_intermediate

    def vectors_to_itrs(self, v_I: np.ndarray, jd_utc: np.ndarray) -> np.ndarray:
        """R_EI(t_k) @ v_k for GCRS vectors v_I (N, 3) at UTC dates (N,)."""
        intermediate = v_I @ self._celestial_to_intermediate.T
        return _rotate_about_z(self.earth_rotation_angle_rad(jd_utc), intermediate) @ self._polar_motion.T

    def vectors_to_gcrs(self, v_E: np.ndarray, jd_utc: np.ndarray) -> np.ndarray:
        """R_EI(t_k)^T @ v_k for ITRS vectors v_E (N, 3) at UTC dates (N,)."""
        intermediate = _rotate_about_z(-self.earth_rotation_angle_rad(jd_utc), v_E @ self._polar_motion)
        return intermediate @ self._celestial_to_intermediate


# --------------------------------------------------------------------------------------------------
# IGRF
# --------------------------------------------------------------------------------------------------


@lru_cache(maxsize=1)
def _igrf_coefficient_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The IGRF node dates (JD, UTC) and Gauss coefficients g, h (nT) as arrays (node, n, m), from ppigrf's file."""
    g_frame, h_frame = _ppigrf_module.read_shc(IGRF_COEFFICIENT_FILE)
    node_jd = np.array([timestamp.to_julian_date() for timestamp in g_frame.index])
    g = np.zeros((len(node_jd), IGRF_MAX_DEGREE + 1, IGRF_MAX_DEGREE + 1))
    h = np.zeros_like(g)
    for n, m in g_frame.columns:
        g[:, n, m] = g_frame[(n, m)].to_numpy(dtype=float)
        h[:, n, m] = h_frame[(n, m)].to_numpy(dtype=float)
    return node_jd, g, h


def igrf_date_range_jd() -> tuple[float, float]:
    """First and last dates (JD, UTC) of the bundled IGRF coefficients."""
    node_jd, _, _ = _igrf_coefficient_table()
    return float(node_jd[0]), float(node_jd[-1])


def igrf_coefficients_nt(jd_utc: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss coefficients g[n, m], h[n, m] (nT) at a date, linear in time between IGRF nodes (as ppigrf)."""
    check_date_in_igrf_range("jd_utc", jd_utc)
    node_jd, g, h = _igrf_coefficient_table()
    upper = int(np.clip(np.searchsorted(node_jd, jd_utc, side="right"), 1, len(node_jd) - 1))
    weight = (float(jd_utc) - node_jd[upper - 1]) / (node_jd[upper] - node_jd[upper - 1])
    return (1 - weight) * g[upper - 1] + weight * g[upper], (1 - weight) * h[upper - 1] + weight * h[upper]


def _schmidt_polynomial_coefficients(max_degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Power-series coefficients of Q_n^m(x) and dQ_n^m/dx, where P_n^m(cos t) = sin^m(t) Q_n^m(cos t).

    Schmidt semi-normalized without the Condon-Shortley phase (the geomagnetic convention):
    Q_n^m = S_nm d^m P_n / dx^m, S_n0 = 1, S_nm = sqrt(2 (n-m)! / (n+m)!). Arrays (power k, n, m).
    """
    size = max_degree + 1
    q = np.zeros((size, size, size))
    dq = np.zeros_like(q)
    for n in range(size):
        legendre_power_series = np.polynomial.legendre.leg2poly(np.eye(size)[n])
        for m in range(n + 1):
            schmidt = 1.0 if m == 0 else np.sqrt(2.0 * math.factorial(n - m) / math.factorial(n + m))
            series = schmidt * np.polynomial.polynomial.polyder(legendre_power_series, m)
            q[: series.size, n, m] = series
            derivative = np.polynomial.polynomial.polyder(series)
            dq[: derivative.size, n, m] = derivative
    return q.reshape(size, -1), dq.reshape(size, -1)


_Q_COEFFICIENTS, _DQ_COEFFICIENTS = _schmidt_polynomial_coefficients(IGRF_MAX_DEGREE)


def schmidt_legendre(colatitude_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Schmidt semi-normalized P_n^m(cos t), dP_n^m/dt and m P_n^m / sin t to degree 13, each (N, n, m).

    Evaluated as sin^m(t) times a polynomial in cos(t), so the last one stays finite on the poles.
    """
    size = IGRF_MAX_DEGREE + 1
    cos_t, sin_t = np.cos(colatitude_rad), np.sin(colatitude_rad)
    cos_powers = np.vander(cos_t, size, increasing=True)  # (N, k)
    q = (cos_powers @ _Q_COEFFICIENTS).reshape(-1, size, size)
    dq_dx = (cos_powers @ _DQ_COEFFICIENTS).reshape(-1, size, size)
    sin_powers = np.vander(sin_t, size + 1, increasing=True)  # sin^0 .. sin^(size)
    sin_m = sin_powers[:, None, :size]
    orders = np.arange(size)
    m_sin_m_minus_1 = np.zeros_like(sin_m)
    m_sin_m_minus_1[:, :, 1:] = orders[1:] * sin_powers[:, None, : size - 1]
    p = sin_m * q
    dp = m_sin_m_minus_1 * cos_t[:, None, None] * q - sin_powers[:, None, 1:] * dq_dx
    return p, dp, m_sin_m_minus_1 * q


def igrf_spherical_nt(
    g: np.ndarray, h: np.ndarray, radius_m: np.ndarray, colatitude_rad: np.ndarray, longitude_rad: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B_r, B_theta, B_phi) in nT from Gauss coefficients at N geocentric points (radial, south, east)."""
    degrees = np.arange(g.shape[0])
    orders = np.arange(g.shape[1])
    p, dp, m_p_over_sin = schmidt_legendre(colatitude_rad)
    m_phi = orders * longitude_rad[:, None]
    cos_m_phi, sin_m_phi = np.cos(m_phi)[:, None, :], np.sin(m_phi)[:, None, :]
    cosine_part = g * cos_m_phi + h * sin_m_phi  # (N, n, m)
    sine_part = h * cos_m_phi - g * sin_m_phi
    radius_powers = (IGRF_REFERENCE_RADIUS_M / radius_m[:, None]) ** (degrees + 2)  # (N, n)
    b_r = np.einsum("kn,knm->k", radius_powers * (degrees + 1.0), p * cosine_part)
    b_theta = -np.einsum("kn,knm->k", radius_powers, dp * cosine_part)
    b_phi = -np.einsum("kn,knm->k", radius_powers, m_p_over_sin * sine_part)
    return b_r, b_theta, b_phi


def cartesian_to_spherical(r_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radius, colatitude and east longitude (rad) of Cartesian points (N, 3)."""
    radius = np.linalg.norm(r_m, axis=-1)
    colatitude = np.arctan2(np.hypot(r_m[:, 0], r_m[:, 1]), r_m[:, 2])
    return radius, colatitude, np.arctan2(r_m[:, 1], r_m[:, 0])


def spherical_to_cartesian_vector(
    colatitude_rad: np.ndarray, longitude_rad: np.ndarray, v_r: np.ndarray, v_theta: np.ndarray, v_phi: np.ndarray
) -> np.ndarray:
    """Cartesian components (N, 3) of a vector given along the local unit vectors e_r, e_theta, e_phi."""
    st, ct = np.sin(colatitude_rad), np.cos(colatitude_rad)
    sp, cp = np.sin(longitude_rad), np.cos(longitude_rad)
    x = v_r * st * cp + v_theta * ct * cp - v_phi * sp
    y = v_r * st * sp + v_theta * ct * sp + v_phi * cp
    z = v_r * ct - v_theta * st
    return np.stack([x, y, z], axis=-1)


# --------------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------------


def check_date_in_igrf_range(name: str, jd_utc: np.ndarray | float) -> None:
    """One-line ValueError if a date is non-finite or outside the bundled IGRF coefficients."""
    first, last = igrf_date_range_jd()
    jd = np.asarray(jd_utc, dtype=float)
    bad = ~np.isfinite(jd) | (jd < first) | (jd > last)
    if np.any(bad):
        value = float(jd[bad].flat[0])
        raise ValueError(
            f"{name} = {value!r} (Julian date, UTC) is outside the {IGRF_GENERATION} coefficients of ppigrf "
            f"{ppigrf_version()}: allowed [{first}, {last}] ({_date_text(first)} to {_date_text(last)})"
        )


def _date_text(jd: float) -> str:
    year, month, day, _ = erfa.jd2cal(jd, 0.0)
    return f"{int(year):04d}-{int(month):02d}-{int(day):02d}"


def check_finite_positions(name: str, r_m: np.ndarray) -> None:
    """One-line ValueError for a non-finite position (N, 3)."""
    finite = np.all(np.isfinite(r_m), axis=-1)
    if not np.all(finite):
        raise ValueError(f"{name} = {r_m[~finite][0].tolist()} m is not finite; allowed: finite positions (m)")


def check_outside_earth(name: str, r_m: np.ndarray, r_E_m: np.ndarray) -> None:
    """One-line ValueError for a position (N, 3) whose Earth-fixed coordinates r_E_m lie inside the WGS-84 ellipsoid."""
    equatorial = np.hypot(r_E_m[:, 0], r_E_m[:, 1]) / WGS84_EQUATORIAL_RADIUS_M
    polar = r_E_m[:, 2] / WGS84_POLAR_RADIUS_M
    inside = equatorial**2 + polar**2 < 1.0
    if np.any(inside):
        value = r_m[inside][0]
        raise ValueError(
            f"{name} = {value.tolist()} m (|r| = {np.linalg.norm(value):.1f} m) is inside the Earth; allowed: "
            f"on or above the WGS-84 ellipsoid (a = {WGS84_EQUATORIAL_RADIUS_M} m, b = {WGS84_POLAR_RADIUS_M} m)"
        )


def ppigrf_version() -> str:
    """The installed ppigrf version (its distribution metadata)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ppigrf")
    except PackageNotFoundError:  # pragma: no cover - a source checkout without metadata
        return getattr(ppigrf, "__version__", "unknown")


# --------------------------------------------------------------------------------------------------
# The field in the inertial frame
# --------------------------------------------------------------------------------------------------


class GeomagneticField:
    """The IGRF field at inertial (GCRS) positions for a run that starts at ``epoch_jd_utc``.

    The Gauss coefficients, precession-nutation, polar motion and UT1-UTC are evaluated once at the
    epoch; each call then costs an ERA rotation and a degree-13 synthesis (~0.25 ms for one point, ~9 us
    per point in a batch).
    """

    def __init__(self, epoch_jd_utc: float):
        check_date_in_igrf_range("epoch_jd_utc", epoch_jd_utc)
        self.epoch_jd_utc = float(epoch_jd_utc)
        self.earth_rotation = EarthRotation(self.epoch_jd_utc)
        self._g_nt, self._h_nt = igrf_coefficients_nt(self.epoch_jd_utc)

    def field_E_tesla(self, r_E_m: np.ndarray) -> np.ndarray:
        """B (T) in the ITRS at Earth-fixed positions r_E_m (m), shape (..., 3)."""
        r_E = np.asarray(r_E_m, dtype=float)
        points = r_E.reshape(-1, 3)
        check_finite_positions("r_E_m", points)
        check_outside_earth("r_E_m", points, points)
        return self._field_itrs_tesla(points).reshape(r_E.shape)

    def field_I_tesla(self, r_I_m: np.ndarray, jd_utc: np.ndarray | float) -> np.ndarray:
        """B (T) in the GCRS at inertial positions r_I_m (m, shape (..., 3)) and UTC Julian dates (broadcast to ...)."""
        r_I = np.asarray(r_I_m, dtype=float)
        if r_I.shape[-1:] != (3,):
            raise ValueError(f"r_I_m has shape {r_I.shape}; allowed: (..., 3) positions in metres")
        jd = np.asarray(jd_utc, dtype=float)
        check_date_in_igrf_range("jd_utc", jd)
        shape = np.broadcast_shapes(r_I.shape[:-1], jd.shape)
        points_I = np.broadcast_to(r_I, shape + (3,)).reshape(-1, 3)
        check_finite_positions("r_I_m", points_I)
        times = np.broadcast_to(jd, shape).reshape(-1)
        points_E = self.earth_rotation.vectors_to_itrs(points_I, times)
        check_outside_earth("r_I_m", points_I, points_E)
        field_E = self._field_itrs_tesla(points_E)
        return self.earth_rotation.vectors_to_gcrs(field_E, times).reshape(shape + (3,))

    def _field_itrs_tesla(self, points_E_m: np.ndarray) -> np.ndarray:
        """B (T) in the ITRS at checked Earth-fixed points (N, 3)."""
        radius, colatitude, longitude = cartesian_to_spherical(points_E_m)
        b_r, b_theta, b_phi = igrf_spherical_nt(self._g_nt, self._h_nt, radius, colatitude, longitude)
        return spherical_to_cartesian_vector(colatitude, longitude, b_r, b_theta, b_phi) * NANOTESLA_TO_TESLA
