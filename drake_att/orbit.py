"""Circular orbit and the LVLH (orbit) frame O (no Drake).

Frame O (local vertical, local horizontal), as in most attitude papers (S1, S3):
``z_O`` points to the Earth's centre (nadir), ``y_O`` along the negative orbit normal,
``x_O = y_O x z_O`` along the velocity for a circular orbit.  Then the angular velocity
of O in I, expressed in O, is ``w_IO_O = [0, -n, 0]`` with ``n`` the orbit rate, which is
the ``w_oi = [0, -w0, 0]`` of paper S3.

``q_IO(t) = q(Rz(RAAN) Rx(inclination) Rz(u(t))) ⊗ q_PO`` where ``u = u0 + n t`` is the
argument of latitude and ``q_PO`` maps the LVLH axes at ``u = 0`` into the perifocal-like
frame P (x_P radial, y_P along-track, z_P orbit normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot

EARTH_MU_M3_PER_S2 = 3.986004418e14
EARTH_RADIUS_M = 6378137.0

# Columns of R_PO are the O axes expressed in P: x_O = y_P, y_O = -z_P, z_O = -x_P.
_R_PO = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_Q_PO = rot.rotmat_to_quat(_R_PO)


def mean_motion(semi_major_axis_m: float) -> float:
    """Orbit rate ``n = sqrt(mu / a^3)`` (rad/s) of a semi-major axis ``a`` (m)."""
    return float(np.sqrt(EARTH_MU_M3_PER_S2 / semi_major_axis_m**3))


@dataclass(frozen=True)
class CircularOrbit:
    """A circular orbit.

    Attributes:
        altitude_m: altitude above the equatorial radius (m), > 0.
        inclination_rad: inclination (rad).
        raan_rad: right ascension of the ascending node (rad).
        arg_latitude0_rad: argument of latitude at t = 0 (rad).
    """

    altitude_m: float
    inclination_rad: float = 0.0
    raan_rad: float = 0.0
    arg_latitude0_rad: float = 0.0

    def __post_init__(self):
        if not np.isfinite(self.altitude_m) or self.altitude_m <= 0:
            raise ValueError(f"altitude: got {self.altitude_m} m; must be finite and > 0")

    @property
    def semi_major_axis_m(self) -> float:
        return EARTH_RADIUS_M + self.altitude_m

    @property
    def mean_motion_rad_per_s(self) -> float:
        """Orbit rate ``n = sqrt(mu / a^3)`` (rad/s)."""
        return mean_motion(self.semi_major_axis_m)

    @property
    def period_s(self) -> float:
        return 2.0 * np.pi / self.mean_motion_rad_per_s

    def w_IO_O(self) -> np.ndarray:
        """Angular velocity of O in I, expressed in O: ``[0, -n, 0]`` (rad/s)."""
        return np.array([0.0, -self.mean_motion_rad_per_s, 0.0])

    def q_IO(self, t) -> np.ndarray:
        """Orientation of the LVLH frame in I at time(s) t, shape ``t.shape + (4,)``."""
        t = np.asarray(t, dtype=float)
        u = self.arg_latitude0_rad + self.mean_motion_rad_per_s * t
        q_raan = rot.rotvec_to_quat(np.array([0.0, 0.0, self.raan_rad]))
        q_inc = rot.rotvec_to_quat(np.array([self.inclination_rad, 0.0, 0.0]))
        u_vec = np.zeros(t.shape + (3,))
        u_vec[..., 2] = u
        q_u = rot.rotvec_to_quat(u_vec)
        return rot.quat_multiply(rot.quat_multiply(rot.quat_multiply(q_raan, q_inc), q_u), _Q_PO)

    def position_I(self, t) -> np.ndarray:
        """Position of the spacecraft in I (m): ``-a z_O``."""
        R_IO = rot.quat_to_rotmat(self.q_IO(t))
        return -self.semi_major_axis_m * R_IO[..., :, 2]

    def position_velocity_I(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position ``-a z_O`` (m) and velocity ``a n x_O`` (m/s) in I."""
        R_IO = rot.quat_to_rotmat(self.q_IO(t))
        a = self.semi_major_axis_m
        return -a * R_IO[..., :, 2], a * self.mean_motion_rad_per_s * R_IO[..., :, 0]


def attitude_relative_to_orbit(q_IB, q_IO) -> np.ndarray:
    """``q_OB = q_IO^-1 ⊗ q_IB``."""
    return rot.quat_multiply(rot.quat_conjugate(q_IO), q_IB)


def rpy_relative_to_orbit(q_IB, q_IO) -> np.ndarray:
    """Roll, pitch, yaw (rad) of the body relative to the orbit frame."""
    return rot.quat_to_rpy(attitude_relative_to_orbit(q_IB, q_IO))
