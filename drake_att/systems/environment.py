"""The Sun and the Moon, and the Earth's magnetic field, as Drake systems.

``SunMoonSource`` has no state and no input; its outputs are functions of the context's time,
``t`` seconds after the epoch ``jd_epoch_utc`` (a UTC Julian date), through a
:class:`~drake_att.ephemeris.SunMoonEphemeris` built for the run's span.

Output ports:
    r_sun_I: the Sun's position, geocentric, in I (GCRS), m (3).
    r_moon_I: the Moon's position, geocentric, in I, m (3).

``MagneticFieldSource`` gives the IGRF field at the spacecraft (:class:`~drake_att.geomagnetic.GeomagneticField`
of the epoch): input ``r_I`` (m, GCRS), output ``B_I`` (T, GCRS), a function of the context's time and
that position.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem

from drake_att.ephemeris import SunMoonEphemeris
from drake_att.geomagnetic import GeomagneticField

SECONDS_PER_DAY = 86400.0


class SunMoonSource(LeafSystem):
    """Sun and Moon positions at the context's time (see the module)."""

    def __init__(self, jd_epoch_utc: float, duration_s: float):
        super().__init__()
        self.jd_epoch_utc = float(jd_epoch_utc)
        span_s = float(duration_s) + 60.0  # a minute past the end: an output at the last instant is inside
        self.ephemeris = SunMoonEphemeris(self.jd_epoch_utc, self.jd_epoch_utc + span_s / SECONDS_PER_DAY)
        self._cache: tuple[float, np.ndarray, np.ndarray] | None = None
        self.DeclareVectorOutputPort("r_sun_I", 3, lambda c, out: out.SetFromVector(self._positions(c)[0]))  # type: ignore[arg-type]
        self.DeclareVectorOutputPort("r_moon_I", 3, lambda c, out: out.SetFromVector(self._positions(c)[1]))  # type: ignore[arg-type]

    def _positions(self, context) -> tuple[np.ndarray, np.ndarray]:
        t = context.get_time()
        if self._cache is None or self._cache[0] != t:
            jd = self.jd_epoch_utc + t / SECONDS_PER_DAY
            self._cache = (t, self.ephemeris.sun_position_m(jd), self.ephemeris.moon_position_m(jd))
        return self._cache[1], self._cache[2]


class MagneticFieldSource(LeafSystem):
    """The IGRF field ``B_I`` (T, in I) at the position on input ``r_I`` (m, in I) and the context's
    time, ``t`` seconds after the UTC Julian date ``jd_epoch_utc`` (cached per time and position)."""

    def __init__(self, jd_epoch_utc: float):
        super().__init__()
        self.jd_epoch_utc = float(jd_epoch_utc)
        self.field = GeomagneticField(self.jd_epoch_utc)
        self._cache: tuple[float, bytes, np.ndarray] | None = None
        self._r_port = self.DeclareVectorInputPort("r_I", 3)
        self.DeclareVectorOutputPort("B_I", 3, lambda c, out: out.SetFromVector(self._field(c)))  # type: ignore[arg-type]

    def _field(self, context) -> np.ndarray:
        t = context.get_time()
        r = np.asarray(self._r_port.Eval(context), dtype=float)
        key = r.tobytes()
        if self._cache is None or self._cache[0] != t or self._cache[1] != key:
            jd = self.jd_epoch_utc + t / SECONDS_PER_DAY
            self._cache = (t, key, self.field.field_I_tesla(r, jd))
        return self._cache[2]
