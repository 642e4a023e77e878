"""The MEKF's step arithmetic (numba): propagation, process noise, transition matrix and the
attitude-quaternion update of :mod:`drake_att.filters.mekf`, in plain loops over the 6x6
matrices — the one implementation. :class:`~drake_att.filters.mekf.MultiplicativeEKF` and
the one-call step of :mod:`drake_att.systems.compiled_step` call these kernels; the readable
numpy form of the same formulas is the tests' oracle (``tests/mekf_reference.py``,
compared in ``tests/test_mekf_kernels.py`` to round-off: matrix products sum in another
order than numpy's BLAS, ~1e-16 relative per product). One predict + update costs a few
microseconds instead of ~100 in numpy calls.

Compiled on first use and cached on disk by :func:`drake_att.filters.compiled.jit` (which also
holds the scalar quaternion helpers shared with the particle-filter kernels; see
benchmarks/README.md for the first-compile cost). No ``fastmath``: IEEE semantics, as numpy.
"""

from __future__ import annotations

import math

import numpy as np

from drake_att.filters.compiled import jit as _jit
from drake_att.filters.compiled import quat_multiply, rotvec_to_quat


@_jit
def _quat_mul(p, q, out):
    out[0], out[1], out[2], out[3] = quat_multiply(p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3])


@_jit
def _rotvec_to_quat(x, y, z, out):
    out[0], out[1], out[2], out[3] = rotvec_to_quat(x, y, z)


@_jit
def _normalize(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        q[i] = q[i] / n


@_jit
def process_noise(arw, rrw, dt, Q):
    """Discrete process-noise covariance of ``[dtheta; dbias]`` over ``dt`` into ``Q`` (6x6):
    Farrenkopf's model with ARW ``arw`` (rad/s^0.5) and RRW ``rrw`` (rad/s^1.5)."""
    sv2, su2 = arw * arw, rrw * rrw
    a = sv2 * dt + su2 * dt**3 / 3.0
    c = -su2 * dt**2 / 2.0
    d = su2 * dt
    for i in range(6):
        for j in range(6):
            Q[i, j] = 0.0
    for i in range(3):
        Q[i, i] = a
        Q[i, i + 3] = c
        Q[i + 3, i] = c
        Q[i + 3, i + 3] = d


@_jit
def transition(wx, wy, wz, dt, Phi):
    """Closed-form state transition of ``F = [[-[w x], -I], [0, 0]]`` over ``dt`` into
    ``Phi`` (6x6): ``Phi = [[exp(-[w x] dt), -J], [0, I]]`` with ``J = integral_0^dt
    exp(-[w x] s) ds = dt I - c1 [w x] + c2 [w x]^2``, ``c1 = (1 - cos a) / |w|^2``,
    ``c2 = (a - sin a) / |w|^3``, ``a = |w| dt`` (series for small ``a``)."""
    n2 = wx * wx + wy * wy + wz * wz
    wn = math.sqrt(n2)
    a = wn * dt
    if a < 1e-4:
        c1 = dt * dt / 2.0 - n2 * dt**4 / 24.0
        c2 = dt**3 / 6.0 - n2 * dt**5 / 120.0
        s1 = dt - n2 * dt**3 / 6.0
        s2 = dt * dt / 2.0 - n2 * dt**4 / 24.0
    else:
        c1 = (1.0 - math.cos(a)) / n2
        c2 = (a - math.sin(a)) / (n2 * wn)
        s1 = math.sin(a) / wn
        s2 = c1
    k = np.empty((3, 3))
    k[0, 0], k[0, 1], k[0, 2] = 0.0, -wz, wy
    k[1, 0], k[1, 1], k[1, 2] = wz, 0.0, -wx
    k[2, 0], k[2, 1], k[2, 2] = -wy, wx, 0.0
    k2 = np.empty((3, 3))
    k2[0, 0], k2[0, 1], k2[0, 2] = wx * wx - n2, wx * wy, wx * wz
    k2[1, 0], k2[1, 1], k2[1, 2] = wy * wx, wy * wy - n2, wy * wz
    k2[2, 0], k2[2, 1], k2[2, 2] = wz * wx, wz * wy, wz * wz - n2
    for r in range(6):
        for c in range(6):
            Phi[r, c] = 0.0
    for r in range(3):
        for c in range(3):
            eye = 1.0 if r == c else 0.0
            Phi[r, c] = eye - s1 * k[r, c] + s2 * k2[r, c]
            Phi[r, 3 + c] = -((dt if r == c else 0.0) - c1 * k[r, c] + c2 * k2[r, c])
        Phi[3 + r, 3 + r] = 1.0


def fixed_product(rows: int, inner: int, cols: int):
    """The compiled ``product(X, Y, out)``: ``out = X @ Y`` for ``(rows, inner) @ (inner, cols)``
    (``Y`` may be a transposed view), summed in index order. One definition of the product
    loop, compiled per size: constant bounds let LLVM unroll it (with the sizes read at run
    time the MEKF step costs ~50% more instructions); numba's ``@`` needs SciPy's BLAS."""

    def product(X, Y, out):
        for i in range(rows):
            for j in range(cols):
                acc = 0.0
                for m in range(inner):
                    acc += X[i, m] * Y[m, j]
                out[i, j] = acc

    return _jit(product)


matmul66 = fixed_product(6, 6, 6)
_matmul63 = fixed_product(6, 3, 3)
_matmul33 = fixed_product(3, 3, 3)
_matmul636 = fixed_product(6, 3, 6)


@_jit
def _symmetric_sandwich(A, P, Q, out):
    """``out = sym(A P A' + Q)`` for 6x6 matrices (``sym(X) = (X + X')/2``)."""
    T = np.empty((6, 6))
    matmul66(A, P, T)
    M = np.empty((6, 6))
    matmul66(T, A.T, M)
    for i in range(6):
        for j in range(6):
            out[i, j] = 0.5 * ((M[i, j] + Q[i, j]) + (M[j, i] + Q[j, i]))


@_jit
def predict(q, P, w_hat, rotation_vector, dt, Q, q_out, P_out, Phi_out):
    """One MEKF propagation: ``q_out = normalize(q ⊗ exp(rotation_vector))``, ``Phi_out`` the
    closed-form transition of the constant rate ``w_hat`` over ``dt``, ``P_out = sym(Phi P
    Phi' + Q)``."""
    dq = np.empty(4)
    _rotvec_to_quat(rotation_vector[0], rotation_vector[1], rotation_vector[2], dq)
    _quat_mul(q, dq, q_out)
    _normalize(q_out)
    transition(w_hat[0], w_hat[1], w_hat[2], dt, Phi_out)
    _symmetric_sandwich(Phi_out, P, Q, P_out)


@_jit
def inverse3(S, out):
    """The inverse of a symmetric 3x3 matrix into ``out`` (closed form); False (``out``
    unset) if it is not positive definite (Sylvester: every leading minor > 0) or not finite."""
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, i = S[2, 0], S[2, 1], S[2, 2]
    A, B, C = e * i - f * h, -(d * i - f * g), d * h - e * g
    det = a * A + b * B + c * C
    if not (a > 0.0 and a * e - b * d > 0.0 and det > 0.0) or not math.isfinite(det):
        return False
    out[0, 0], out[0, 1], out[0, 2] = A / det, -(b * i - c * h) / det, (b * f - c * e) / det
    out[1, 0], out[1, 1], out[1, 2] = B / det, (a * i - c * g) / det, -(a * f - c * d) / det
    out[2, 0], out[2, 1], out[2, 2] = C / det, -(a * h - b * g) / det, (a * e - b * d) / det
    return True


ACCEPTED, REJECTED_BY_GATE, SINGULAR = 0, 1, 2


@_jit
def update_quaternion(q, b, P, q_meas, q_BS, R_SB, R, threshold, q_out, b_out, P_out, z, S, I_KH):
    """One MEKF attitude-quaternion update (``MultiplicativeEKF.update_quaternion``).

    Writes the residual ``z`` (sensor frame), its covariance ``S`` and, when accepted, the new
    ``q_out``, ``b_out``, ``P_out`` and ``I_KH`` (6x6). Returns ``(outcome, nis)``: outcome
    :data:`ACCEPTED`, :data:`REJECTED_BY_GATE` (NIS not finite or above ``threshold``; inf
    for no gate) or :data:`SINGULAR` (S not positive definite; NIS NaN)."""
    # Residual z = log((q ⊗ q_BS)^-1 ⊗ q_meas), as rot.quat_to_rotvec (normalized, canonical).
    qs = np.empty(4)
    _quat_mul(q, q_BS, qs)
    qs[1], qs[2], qs[3] = -qs[1], -qs[2], -qs[3]
    dq = np.empty(4)
    _quat_mul(qs, q_meas, dq)
    _normalize(dq)
    if dq[0] < 0.0:
        for i in range(4):
            dq[i] = -dq[i]
    s = math.sqrt(dq[1] * dq[1] + dq[2] * dq[2] + dq[3] * dq[3])
    k = 2.0 / dq[0] if s < 1e-12 else 2.0 * math.atan2(s, dq[0]) / s
    z[0], z[1], z[2] = k * dq[1], k * dq[2], k * dq[3]
    # H = [R_SB, 0]: P H' = P[:, :3] R_SB', S = R_SB P[:3, :3] R_SB' + R.
    PHt = np.empty((6, 3))
    _matmul63(P, R_SB.T, PHt)
    S0 = np.empty((3, 3))
    _matmul33(R_SB, PHt, S0)
    for i in range(3):
        for j in range(3):
            S[i, j] = 0.5 * ((S0[i, j] + R[i, j]) + (S0[j, i] + R[j, i]))
    S_inv = np.empty((3, 3))
    if not inverse3(S, S_inv):
        return SINGULAR, math.nan
    nis = 0.0
    for i in range(3):
        acc = 0.0
        for j in range(3):
            acc += S_inv[i, j] * z[j]
        nis += z[i] * acc
    if not math.isfinite(nis) or nis > threshold:
        return REJECTED_BY_GATE, nis
    K = np.empty((6, 3))
    _matmul63(PHt, S_inv, K)
    dx = np.empty(6)
    for i in range(6):
        dx[i] = K[i, 0] * z[0] + K[i, 1] * z[1] + K[i, 2] * z[2]
    # I - K H with H = [R_SB, 0].
    for i in range(6):
        for j in range(6):
            kh = 0.0
            if j < 3:
                for m in range(3):
                    kh += K[i, m] * R_SB[m, j]
            I_KH[i, j] = (1.0 if i == j else 0.0) - kh
    # Joseph form: (I - KH) P (I - KH)' + K R K'.
    KR = np.empty((6, 3))
    _matmul63(K, R, KR)
    KRKt = np.empty((6, 6))
    _matmul636(KR, K.T, KRKt)
    _symmetric_sandwich(I_KH, P, KRKt, P_out)
    dq2 = np.empty(4)
    _rotvec_to_quat(dx[0], dx[1], dx[2], dq2)
    _quat_mul(q, dq2, q_out)
    _normalize(q_out)
    for i in range(3):
        b_out[i] = b[i] + dx[3 + i]
    return ACCEPTED, nis


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now, e.g. before timing a run."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    P = np.eye(6)
    out4, out6, out66 = np.empty(4), np.empty(6), np.empty((6, 6))
    predict(q, P, np.zeros(3), np.zeros(3), 1.0, np.eye(6), out4, out66, np.empty((6, 6)))
    update_quaternion(
        q,
        np.zeros(3),
        P,
        q,
        q,
        np.eye(3),
        np.eye(3),
        math.inf,
        out4,
        np.empty(3),
        out66,
        np.empty(3),
        np.empty((3, 3)),
        np.empty((6, 6)),
    )
    del out6


__all__ = [
    "fixed_product",
    "matmul66",
    "process_noise",
    "transition",
    "inverse3",
    "predict",
    "update_quaternion",
    "warm_up",
    "ACCEPTED",
    "REJECTED_BY_GATE",
    "SINGULAR",
]
