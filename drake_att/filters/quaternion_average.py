"""Weighted quaternion averaging (Markley, Cheng, Crassidis & Oshman, "Averaging Quaternions",
Journal of Guidance, Control, and Dynamics 30(4), 2007).  Pure numpy; no Drake dependency.

The weighted average of unit quaternions ``q_i`` with weights ``w_i >= 0`` is the unit
eigenvector of ``M = sum_i w_i q_i q_i'`` with the largest eigenvalue (it maximizes
``sum_i w_i (q_i' q)^2``); the sign of each ``q_i`` does not matter.

* :func:`average_quaternions`: N quaternions, eigenvector method; result with ``w >= 0``.
* :func:`average_two_quaternions`: two quaternions, closed form; result in ``q1``'s hemisphere.

Conventions: quaternions are ``[w, x, y, z]`` (scalar first, Hamilton, as in
:mod:`drake_att.rotations` and Drake).  The average commutes with a common left or right
factor, so ``q_IB`` or ``q_BI`` inputs both work if all use the same one.  Weights are
dimensionless (only ratios matter); ``w_i = 1 / sigma_i^2`` (small, independent, isotropic
errors of ``sigma_i`` rad) is the minimum-variance combination to first order.

Derivation and paper notes: docs/derivations/quaternion_average.md
"""

from __future__ import annotations

import math

import numpy as np

from drake_att.validation import check_array, check_nonnegative, describe, fail

__all__ = ["average_two_quaternions", "average_quaternions"]


def _check_quaternion(q, name: str) -> np.ndarray:
    """A finite, non-zero quaternion ``(4,)``, normalized without overflow or underflow
    (any magnitude: it is scaled by its largest component first)."""
    arr = check_array(name, q, (4,), " ([w, x, y, z])")
    scale = np.max(np.abs(arr))
    if not scale > 0.0:
        fail(name, arr, "must be non-zero (it is normalized)")
    arr = arr / scale
    return arr / np.linalg.norm(arr)


def _check_weight(w, name: str) -> float:
    """A scalar weight: finite and >= 0."""
    return check_nonnegative(name, w)


def average_two_quaternions(q1, q2, w1: float = 0.5, w2: float = 0.5) -> np.ndarray:
    """Weighted average of two quaternions, closed form (Markley et al. 2007).

    The dominant eigenvector of ``w1 q1 q1' + w2 q2 q2'`` (the same result as
    :func:`average_quaternions`) without an eigen-decomposition; never NaN for valid input.
    In the degenerate case ``w1 == w2``, ``q1' q2 == 0`` (rotations 180 deg apart) it returns
    ``q1``.  Formula, edge cases and sign rules: docs/derivations/quaternion_average.md.

    Args:
        q1, q2: quaternions ``[w, x, y, z]``, shape ``(4,)``, finite and non-zero, in the same
            frame convention; each is normalized before use.
        w1, w2: weights (dimensionless, finite, >= 0, ``w1 + w2 > 0``); default 0.5 each.

    Returns:
        Unit quaternion ``[w, x, y, z]``, shape ``(4,)``, in the hemisphere of ``q1``
        (``q_avg' q1 >= 0``); not forced to ``w >= 0`` (see
        :func:`drake_att.rotations.quat_canonical`).

    Raises:
        ValueError: naming the argument and the offending value, if a quaternion is not shape
            ``(4,)``, not finite or zero, a weight is negative or not finite, or ``w1 + w2 == 0``.
    """
    q1 = _check_quaternion(q1, "q1")
    q2 = _check_quaternion(q2, "q2")
    w1 = _check_weight(w1, "w1")
    w2 = _check_weight(w2, "w2")
    if not max(w1, w2) > 0.0:
        fail("w1 + w2", w1 + w2, "must be > 0 (weights are >= 0)")
    return np.array(_average_two_unit_quaternions(q1.tolist(), q2.tolist(), w1, w2))


def _average_two_unit_quaternions(q1, q2, w1: float, w2: float) -> list:
    """The closed form of :func:`average_two_quaternions` without input checks, in Python
    floats (no numpy call: for per-evaluation use in Drake systems).

    Args:
        q1, q2: unit quaternions ``[w, x, y, z]``, each a sequence of 4 floats (not
            checked: finite and of norm 1 to round-off).
        w1, w2: weights (dimensionless), finite, >= 0, ``max(w1, w2) > 0`` (not checked).

    Returns:
        The unit average as a list of 4 floats, in the hemisphere of ``q1``
        (``q_avg' q1 >= 0``); ``q1`` itself (a copy) in the degenerate case ``z == 0``.
    """
    # Only the ratio matters; normalizing keeps every intermediate O(1) (no under/overflow
    # for extreme weights such as 1e-320 or 1e308).
    wmax = max(w1, w2)
    w1, w2 = w1 / wmax, w2 / wmax
    total = w1 + w2
    w1, w2 = w1 / total, w2 / total
    a0, a1, a2, a3 = q1
    b0, b1, b2, b3 = q2
    d = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3
    sign = -1.0 if d < 0.0 else 1.0
    delta = w1 - w2
    cross = 4.0 * w1 * w2 * d * d
    z = math.sqrt(delta * delta + cross)
    if z == 0.0:
        # Degenerate: w1 == w2 and q1 _|_ q2; any unit vector in span(q1, q2) maximizes.
        return [a0, a1, a2, a3]
    # a_plus = w1 - w2 + z, a_minus = w2 - w1 + z; compute the one that would suffer from
    # cancellation via (z^2 - delta^2) / (z +- delta) = cross / (z +- delta).
    if delta >= 0.0:
        a_plus = z + delta
        a_minus = cross / a_plus
    else:
        a_minus = z - delta
        a_plus = cross / a_minus
    denom = z * (w1 + w2 + z)
    c1 = math.sqrt(w1 * a_plus / denom)
    c2 = sign * math.sqrt(w2 * a_minus / denom)
    r0, r1, r2, r3 = c1 * a0 + c2 * b0, c1 * a1 + c2 * b1, c1 * a2 + c2 * b2, c1 * a3 + c2 * b3
    n = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    return [r0 / n, r1 / n, r2 / n, r3 / n]


def average_quaternions(quaternions, weights=None) -> np.ndarray:
    """Weighted average of N quaternions, eigenvector method (Markley et al. 2007).

    Returns the unit eigenvector of ``M = sum_i w_i q_i q_i'`` (``q_i`` normalized) with
    the largest eigenvalue. This maximizes ``sum_i w_i (q_i' q)^2`` and minimizes
    ``sum_i w_i |R(q) - R(q_i)|_F^2``; it is invariant to the sign of each ``q_i``, to
    permutations of the inputs and to a common positive scaling of the weights.

    If the largest eigenvalue of ``M`` is repeated the average is not unique (e.g. two
    equally weighted rotations 180 deg apart); one maximizer is returned. Inputs with zero
    weight are ignored.

    Args:
        quaternions: Array of shape ``(N, 4)``, ``N >= 1``, rows ``[w, x, y, z]`` in one
            common frame convention. Rows must be finite and non-zero; each is
            normalized before use.
        weights: Array of shape ``(N,)`` of dimensionless weights, finite, >= 0, with a
            positive sum. ``None`` (default) means equal weights.

    Returns:
        Unit quaternion ``[w, x, y, z]``, shape ``(4,)``, with scalar part ``w >= 0``.

    Raises:
        ValueError: If ``quaternions`` is not ``(N, 4)`` with ``N >= 1``, contains
            non-finite values or a zero row; or ``weights`` is not ``(N,)``, contains
            negative or non-finite values, or sums to zero. The message names the argument
            and the offending value.
    """
    try:
        Q = np.asarray(quaternions, dtype=float)
    except (TypeError, ValueError):
        fail("quaternions", quaternions, "must be a real array of shape (N, 4)")
    if Q.ndim != 2 or Q.shape[1] != 4 or Q.shape[0] < 1:
        fail("quaternions", Q, f"must have shape (N, 4) with N >= 1 (rows [w, x, y, z]), not {Q.shape}")
    bad = ~np.all(np.isfinite(Q), axis=1)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        fail(f"quaternions[{i}]", Q[i], "must be finite")
    scale = np.max(np.abs(Q), axis=1)
    zero = ~(scale > 0.0)
    if np.any(zero):
        i = int(np.flatnonzero(zero)[0])
        fail(f"quaternions[{i}]", Q[i], "must be non-zero (rows are normalized)")
    Q = Q / scale[:, None]  # avoids overflow/underflow in the norm for extreme magnitudes
    Q = Q / np.linalg.norm(Q, axis=1, keepdims=True)
    n = Q.shape[0]

    if weights is None:
        w = np.full(n, 1.0 / n)
    else:
        try:
            w = np.asarray(weights, dtype=float)
        except (TypeError, ValueError):
            fail("weights", weights, f"must be a real array of shape ({n},)")
        if w.shape != (n,):
            fail("weights", w, f"must have shape ({n},) to match quaternions (N={n}), not {w.shape}")
        badw = ~np.isfinite(w) | (w < 0.0)
        if np.any(badw):
            i = int(np.flatnonzero(badw)[0])
            fail(f"weights[{i}]", float(w[i]), f"must be finite and >= 0 (weights={describe(w)})")
        w = w / np.max(w) if np.max(w) > 0.0 else w  # scale-free; avoids sum overflow
        total = float(np.sum(w))
        if not total > 0.0:
            fail("weights", np.asarray(weights), "must have a positive sum")
        w = w / total  # keeps M well scaled

    return _average_unit_quaternions(Q, w)


def _average_unit_quaternions(Q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The eigenvector step of :func:`average_quaternions` without input checks.

    Args:
        Q: ``(N, 4)`` array of unit quaternions (rows ``[w, x, y, z]``; not checked).
        w: ``(N,)`` array of weights, finite, >= 0, summing to 1 (not checked; another
            positive sum only scales ``M``).

    Returns:
        The unit dominant eigenvector of ``M = sum_i w_i q_i q_i'``, shape ``(4,)``, with
        scalar part ``w >= 0``.
    """
    M = (Q * w[:, None]).T @ Q
    M = 0.5 * (M + M.T)
    _, vecs = np.linalg.eigh(M)
    q = vecs[:, -1]
    q = q / np.linalg.norm(q)
    if q[0] < 0.0:
        q = -q
    return q
