"""The Sun and the Moon as a Drake system: their geocentric positions in the inertial frame.

``SunMoonSource`` has no state and no input; its outputs are functions of the context's time,
``t`` seconds after the epoch ``jd_epoch_utc`` (a UTC Julian date), through a
:class:`~drake_att.ephemeris.SunMoonEphemeris` built for the run's span.

Output ports:
    r_sun_I: the Sun's position, geocentric, in I (GCRS), m (3).
    r_moon_I: the Moon's position, geocentric, in I, m (3).
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem

from drake_att.ephemeris import SunMoonEphemeris

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
