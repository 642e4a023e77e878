"""Unit conversions: multiply a value in the named unit to get SI (radians, seconds).

Degrees, arcseconds and per-hour units appear only at the edges (config fields, plot
labels); inside the library everything is SI and radians.

One spelling for the gyro noise densities: ARW (angle random walk, ``sigma_v``) in
deg/sqrt(h) -> rad/s^0.5 and RRW (rate random walk, ``sigma_u``) in deg/h^1.5
(= deg/h per sqrt(h)) -> rad/s^1.5.
"""

import math

DEG = math.pi / 180.0  # rad
ARCSEC = DEG / 3600.0  # rad
DEG_PER_H = DEG / 3600.0  # rad/s
ARW_DEG_PER_RT_H = DEG / 60.0  # 1 deg/sqrt(h) in rad/s^0.5
RRW_DEG_PER_H_15 = DEG / 3600.0 / 60.0  # 1 deg/h^1.5 in rad/s^1.5

__all__ = ["DEG", "ARCSEC", "DEG_PER_H", "ARW_DEG_PER_RT_H", "RRW_DEG_PER_H_15"]
