"""The spacecraft's orbit as a Drake system: position and velocity in the inertial frame.

``OrbitSource`` has no state and no input: its outputs are functions of the context's time
through an orbit model (:mod:`drake_att.orbit_propagators`: ``sgp4`` for a TLE, Kepler's
equation with optional secular J2 for elements; :class:`drake_att.orbit.CircularOrbit`).

Output ports:
    r_I: position in I (GCRS), m (3).
    v_I: velocity in I, m/s (3).
    q_IO: the LVLH frame's orientation in I, ``[w, x, y, z]`` (4).

Each port's value is cached per context time, so the three ports and any number of readers
cost one propagation per time.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from drake_att.orbit_propagators import lvlh_quaternion


class OrbitSource(LeafSystem):
    """Position, velocity and LVLH frame of an orbit model at the context's time (see the module)."""

    def __init__(self, orbit):
        super().__init__()
        if not hasattr(orbit, "position_velocity_I"):
            raise TypeError(f"OrbitSource: {type(orbit).__name__} has no position_velocity_I(t)")
        self.orbit = orbit
        self._cache: tuple[float, np.ndarray] | None = None  # (t, [r, v, q]) of the last time asked
        self.DeclareVectorOutputPort("r_I", 3, lambda c, out: out.SetFromVector(self._state(c)[0:3]))
        self.DeclareVectorOutputPort("v_I", 3, lambda c, out: out.SetFromVector(self._state(c)[3:6]))
        self.DeclareVectorOutputPort("q_IO", BasicVector(4), lambda c, out: out.SetFromVector(self._state(c)[6:10]))

    def _state(self, context) -> np.ndarray:
        t = context.get_time()
        if self._cache is None or self._cache[0] != t:
            r, v = self.orbit.position_velocity_I(t)
            self._cache = (t, np.concatenate([r, v, lvlh_quaternion(r, v)]))
        return self._cache[1]
