"""The one validation family: every check of a value the library is given.

Each check returns the value converted (float, int, array, unit quaternion, covariance) or
raises ``error`` (default ``ValueError``; the scenario loader passes
:class:`ConfigError`) with one message shape::

    <field>: got <value>; <what is allowed>

so every refusal names the field, the value and what is allowed - from a YAML field path
(``estimators[0] (single).period_s``) down to a filter core's argument (``covariance0``).
Math layer: numpy only, no Drake.
"""

from __future__ import annotations

import numbers
from typing import NoReturn

import numpy as np

__all__ = [
    "UserInputError",
    "ConfigError",
    "describe",
    "fail",
    "check_finite",
    "check_positive",
    "check_nonnegative",
    "check_int",
    "check_vector",
    "check_weights",
    "check_array",
    "check_quaternion",
    "check_covariance",
    "check_reference_vectors",
    "check_variance_matrix",
    "measurement_or_none",
    "check_seed",
    "SEED_MAX",
]


class UserInputError(ValueError):
    """Something the user gave (a file, a field, an option, a folder) is refused; the message
    names it, the value and what is allowed. The CLI prints it as one line and exits 2."""


class ConfigError(UserInputError):
    """An invalid scenario configuration (the message names the field path)."""


# A value in a message is cut to this many characters (a huge string or list must not make a
# huge message).
DESCRIBE_LIMIT = 200


def describe(value) -> str:
    """A short rendering of ``value`` for a message (arrays abridged, at most
    :data:`DESCRIBE_LIMIT` characters)."""
    if isinstance(value, np.ndarray):
        text = np.array2string(value, precision=10, threshold=12, max_line_width=10**6).replace("\n", "")
    elif isinstance(value, (str, bytes)) and len(value) > DESCRIBE_LIMIT:
        text = repr(value[:DESCRIBE_LIMIT])
    elif isinstance(value, (list, tuple, dict)) and len(value) > 50:
        text = f"<{type(value).__name__} of {len(value)} items>"
    else:
        text = repr(value)
    return text if len(text) <= DESCRIBE_LIMIT else text[:DESCRIBE_LIMIT] + "..."


def fail(field: str, value, allowed: str, error: type = ValueError) -> NoReturn:
    """Raise ``error("<field>: got <value>; <allowed>")``."""
    raise error(f"{field}: got {describe(value)}; {allowed}")


def _is_real(v) -> bool:
    if isinstance(v, np.ndarray):  # a 0-d numeric array is a number
        return v.ndim == 0 and np.issubdtype(v.dtype, np.number) and not np.issubdtype(v.dtype, np.bool_)
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def check_finite(field: str, value, error: type = ValueError) -> float:
    """``value`` as float if it is a finite real number (not a string, not a bool)."""
    if not _is_real(value) or not np.isfinite(float(value)):
        fail(field, value, "must be a finite real scalar", error)
    return float(value)


def check_positive(field: str, value, allow_zero: bool = False, error: type = ValueError) -> float:
    """``value`` as float if it is finite and > 0 (>= 0 with ``allow_zero``)."""
    v = check_finite(field, value, error)
    if v < 0.0 or (v == 0.0 and not allow_zero):
        fail(field, value, "must be >= 0" if allow_zero else "must be > 0", error)
    return v


def check_nonnegative(field: str, value, error: type = ValueError) -> float:
    """``value`` as float if it is finite and >= 0."""
    return check_positive(field, value, allow_zero=True, error=error)


def check_availability(name: str, dropout_probability: float, outage_windows_s) -> tuple[float, tuple]:
    """A sensor's checked drop-out probability (in [0, 1)) and outage windows ``((start, end), ...)``
    (each with end > start); ValueError naming ``name.dropout_probability`` or
    ``name.outage_windows_s``."""
    if not (0.0 <= dropout_probability < 1.0):
        raise ValueError(f"{name}.dropout_probability: got {dropout_probability}; must be in [0, 1)")
    windows = tuple((float(a), float(b)) for a, b in outage_windows_s)
    for a, b in windows:
        if not b > a:
            raise ValueError(f"{name}.outage_windows_s: window ({a}, {b}) must have end > start")
    return float(dropout_probability), windows


def check_int(field: str, value, minimum: int, error: type = ValueError) -> int:
    """``value`` as int if it is an integer (not a bool, not a float) >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        fail(field, value, f"must be an integer >= {minimum}", error)
    return int(value)


# Drake's RandomGenerator (std::mt19937) takes a 32-bit seed: a larger one would wrap and
# alias a smaller one (2^32 would repeat seed 0's run).
SEED_MAX = 2**32 - 1


def check_seed(field: str, value, error: type = ValueError) -> int:
    """A run's seed: an integer in ``[0, 2^32 - 1]`` (not a bool, not a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= SEED_MAX:
        fail(
            field,
            value,
            f"must be an integer in [0, {SEED_MAX}] (Drake's 32-bit seed; a larger one would alias a smaller one)",
            error,
        )
    return int(value)


def check_vector(field: str, value, n: int, error: type = ValueError) -> list:
    """A list (or 1-D array) of ``n`` finite numbers, each checked and named ``field[i]``."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != n:
        fail(field, value, f"must be a list of {n} numbers", error)
    return [check_finite(f"{field}[{i}]", x, error) for i, x in enumerate(value)]


def check_weights(field: str, value, n: int, error: type = ValueError) -> list:
    """``n`` finite weights >= 0 with a positive sum."""
    w = check_vector(field, list(value), n, error)
    if any(x < 0 for x in w) or sum(w) <= 0:
        fail(field, value, "weights must be >= 0 with a positive sum", error)
    return w


def check_array(field: str, value, shape: tuple, unit: str = "", error: type = ValueError) -> np.ndarray:
    """``value`` as a finite float array of exactly ``shape`` (``unit``: e.g. " (rad/s)")."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        fail(field, value, f"must be a finite real array of shape {tuple(shape)}{unit}", error)
    if arr.shape != tuple(shape):
        fail(field, arr, f"must have shape {tuple(shape)}{unit}, not {arr.shape}", error)
    if not np.all(np.isfinite(arr)):
        fail(field, arr, f"must be finite{unit}", error)
    return arr


def check_quaternion(field: str, value, error: type = ValueError) -> np.ndarray:
    """A unit quaternion ``[w, x, y, z]`` from finite ``value`` with ``|q| > 1e-12``."""
    q = check_array(field, value, (4,), " ([w, x, y, z])", error)
    n = np.linalg.norm(q)
    if not n > 1e-12:
        fail(field, q, "must be a non-zero quaternion (|q| > 1e-12)", error)
    return q / n


def check_covariance(field: str, value, n: int, error: type = ValueError) -> np.ndarray:
    """A symmetric positive-definite ``(n, n)`` matrix (symmetrized to round-off)."""
    P = check_array(field, value, (n, n), "", error)
    if not np.allclose(P, P.T, rtol=1e-9, atol=1e-300 + 1e-12 * np.max(np.abs(P))):
        fail(field, P, "must be symmetric", error)
    P = 0.5 * (P + P.T)
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        fail(field, P, f"must be positive definite (its eigenvalues are {describe(np.linalg.eigvalsh(P))})", error)
    return P


def check_reference_vectors(field: str, value, error: type = ValueError) -> np.ndarray:
    """``(m, 3)`` finite, non-zero reference directions, ``m >= 1``."""
    try:
        U = np.array(value, dtype=float)
    except (TypeError, ValueError):
        fail(field, value, "must be a finite real array of shape (m, 3), m >= 1", error)
    if U.ndim != 2 or U.shape[1] != 3 or U.shape[0] < 1:
        fail(field, U, f"must have shape (m, 3) with m >= 1, not {U.shape}", error)
    if not np.all(np.isfinite(U)):
        fail(field, U, "must be finite", error)
    if np.any(np.linalg.norm(U, axis=1) <= 0.0):
        fail(field, U, "rows must be non-zero directions", error)
    return U


def check_variance_matrix(field: str, value, n: int, error: type = ValueError) -> np.ndarray:
    """An ``(n, n)`` symmetric positive semi-definite matrix from a scalar variance (times
    ``I_n``) or an ``(n, n)`` matrix (round-off asymmetry and negativity tolerated)."""
    a = np.asarray(value, dtype=float) if _is_real(value) or isinstance(value, (list, tuple, np.ndarray)) else None
    if a is not None and a.ndim == 0:
        return check_nonnegative(field, float(a), error) * np.eye(n)
    if (
        a is None
        or a.shape != (n, n)
        or not np.all(np.isfinite(a))
        or not np.allclose(a, a.T, rtol=0.0, atol=1e-15 * (1.0 + np.abs(a).max()))
    ):
        fail(field, value, f"must be a finite scalar variance >= 0 or a symmetric {n}x{n} matrix", error)
    if np.linalg.eigvalsh(a).min() < -1e-12 * max(1.0, np.abs(a).max()):
        fail(field, a, "must be positive semi-definite", error)
    return 0.5 * (a + a.T)


def measurement_or_none(field: str, value, shape: tuple, what: str = "") -> np.ndarray | None:
    """A measurement as a finite float array of ``shape``, or None when it is missing (None),
    not numeric or not finite (a data problem: the caller skips and counts it). A wrong
    *shape* is a programming error and raises ValueError naming ``field``."""
    if value is None:
        return None
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if arr.shape != tuple(shape):
        fail(field, arr, f"must have shape {tuple(shape)}{what}, not {arr.shape}")
    if not np.all(np.isfinite(arr)):
        return None
    return arr
