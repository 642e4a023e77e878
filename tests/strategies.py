"""Hypothesis strategies shared by the rotation and quaternion-averaging tests."""

import numpy as np
from hypothesis import assume
from hypothesis import strategies as st

unit_interval = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


def _unit(draw, n):
    v = np.array(draw(st.tuples(*[unit_interval] * n)))
    norm = np.linalg.norm(v)
    assume(norm > 1e-3)
    return v / norm


@st.composite
def unit_quats(draw):
    """Unit quaternions, uniformly signed (both q and -q occur)."""
    return _unit(draw, 4)


@st.composite
def unit_vectors(draw):
    """Unit 3-vectors."""
    return _unit(draw, 3)
