"""The S0 particle filters' and the MRP EKF's step arithmetic (numba ``njit``, cached on disk):
the one implementation. The cores of :mod:`drake_att.filters.particle` and
:class:`~drake_att.filters.mrp_ekf.MrpEkfCore` call these kernels for every step; the readable
numpy form of the same formulas is the tests' oracle (``tests/particle_reference.py``), which
``tests/test_particle_kernels.py`` compares with them to round-off. Each kernel is an explicit
loop over the particles where numpy would need ~50 batched calls.

==========================================  ====================================================
kernel                                       oracle (``tests/particle_reference.py``)
==========================================  ====================================================
:func:`propagate_attitudes`                  ``propagate_attitudes``: ``quat_to_mrp(quat_multiply(
                                             mrp_to_quat(rho), rotvec_to_quat(w dt)))``
                                             (bootstrap PF predict)
:func:`vector_log_likelihood`                ``vector_log_likelihood``
:func:`gyroless_propagate`                   ``gyroless_propagate``: the deterministic part (RK4 +
                                             closed-form attitude, attitude noise) of the
                                             gyroless PF's predict
:func:`ekf_predict`                          ``ekf_predict`` (the MRP EKF's time update)
:func:`ekf_update`                           ``ekf_update`` (its measurement update, iterated
                                             or not, with the innovation and ``S``)
:func:`ekpf_update`                          ``ekpf_proposal_step``: EKF update, Cholesky
                                             factors, proposal draw, the three log densities,
                                             shadow switch
:func:`ekpf_draw`                            the draw and weights of ``ekpf_proposal_step``
                                             from given Cholesky factors
==========================================  ====================================================

**Same maths, equal to round-off.** No ``fastmath`` (no reassociation, no fused multiply-add);
scalar expressions (quaternion products, rotation-vector exponentials, RK4 stages, the
likelihood) are written in the oracle's order of operations, which makes the bootstrap
and gyroless steps bit-identical to it on this machine. The EKF's matrix
algebra differs by round-off, in these places only: small matrix products sum in their own
order (numpy's batched ``matmul``/``einsum`` call BLAS); terms that are *exactly* zero in the
oracle are skipped (the zero rows of the dynamics Jacobian ``F = [[J, -B], [0, 0]]``, so
``Phi = [[Phi_1, Phi_2], [0, I]]``; the zero blocks of ``Qg``; the zero bias columns of
``H = [H_rho, 0]``, so ``I - K H`` has identity bias columns); symmetric results (``S``, the
predicted and the updated covariance) are computed on one triangle and mirrored where the
oracle averages ``(A + A') / 2``; ``S^-1`` is applied by Cholesky (LU with partial
pivoting, numpy's method, if that fails) and the triangular factors by reciprocal pivots,
as LAPACK's ``dpotf2``; ``log det L`` is one log of the product of the pivots (the sum of
logs if that product leaves the normal range). No random numbers are drawn here: the
filters draw them from their ``numpy.random.Generator`` and pass them in, and keep the
weight normalization and the systematic-resampling cumulative sums in numpy. When a
Cholesky factor of some particle's covariance fails, :func:`ekpf_update` returns None; the
EKPF then repairs the factors of the whole batch in numpy (``particle._paired_cholesky``)
and runs :func:`ekpf_draw` on them.

**Cache.** ``cache=True``: the first call of each kernel in a fresh environment compiles it
(about 10 s for all of them; ``benchmarks/README.md`` has the measured figures) and writes
the machine code to numba's cache — ``__pycache__`` next to this file, or, where that is
not writable (a read-only site-packages), the user-wide cache (``~/.cache/numba``, or
``$NUMBA_CACHE_DIR`` when set); later processes load it in milliseconds. If no cache
location is writable at all, the kernels are compiled in every process instead (no
warning, no error): :data:`CACHING` says which.

Shapes: ``rho`` ``(N, 3)`` MRPs; ``x`` ``(N, 6)`` ``[rho; b]``; ``P`` ``(N, 6, 6)`` (MRP chart);
``y`` ``(3m,)``; ``ref_vectors_I`` ``(m, 3)``. Inputs are converted to C-contiguous float64
(one compiled specialization per kernel); outputs are new arrays.

Every compiled particle and MRP-EKF step in one module: they share scalar helpers numba inlines.
"""

from __future__ import annotations

import math

import numpy as np

from drake_att.filters import compiled as _compiled
from drake_att.filters.compiled import jit as _jit
from drake_att.filters.compiled import quat_multiply as _quat_multiply
from drake_att.filters.compiled import rotvec_to_quat as _rotvec_to_quat

__all__ = [
    "CACHING",
    "ekf_predict",
    "ekf_update",
    "ekpf_draw",
    "ekpf_update",
    "gyroless_propagate",
    "propagate_attitudes",
    "vector_log_likelihood",
]


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


# ----------------------------------------------------------------------------------
# Scalar building blocks (drake_att.rotations, one particle at a time)
# ----------------------------------------------------------------------------------
@_jit
def _mrp_to_quat(r0, r1, r2):
    """rotations.mrp_to_quat."""
    n2 = r0 * r0 + r1 * r1 + r2 * r2
    d = 1.0 + n2
    return (1.0 - n2) / d, 2.0 * r0 / d, 2.0 * r1 / d, 2.0 * r2 / d


@_jit
def _quat_to_mrp(w, x, y, z):
    """rotations.quat_to_mrp: MRP of the normalized, sign-canonical quaternion (|p| <= 1)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    d = 1.0 + w
    return x / d, y / d, z / d


@_jit
def _mrp_step(r0, r1, r2, w0, w1, w2, dt):
    """``q(rho) ⊗ exp(w dt / 2)`` as a quaternion (not normalized, sign kept)."""
    qw, qx, qy, qz = _mrp_to_quat(r0, r1, r2)
    dw, dx, dy, dz = _rotvec_to_quat(w0 * dt, w1 * dt, w2 * dt)
    return _quat_multiply(qw, qx, qy, qz, dw, dx, dy, dz)


@_jit
def _propagate_mrp(r0, r1, r2, w0, w1, w2, dt):
    """The MRP after a constant-rate step, same chart (sign of q kept; the oracle's ``propagate_mrp``)."""
    qw, qx, qy, qz = _mrp_step(r0, r1, r2, w0, w1, w2, dt)
    d = 1.0 + qw
    return qx / d, qy / d, qz / d


@_jit
def _kinematics_matrix(r0, r1, r2, B):
    """rotations.mrp_kinematics_matrix into ``B`` (3, 3):
    ``1/4 [(1 - p'p) I + 2 [p x] + 2 p p']``."""
    n2 = r0 * r0 + r1 * r1 + r2 * r2
    c = 1.0 - n2
    B[0, 0] = 0.25 * (c + 2.0 * r0 * r0)
    B[0, 1] = 0.25 * (2.0 * -r2 + 2.0 * r0 * r1)
    B[0, 2] = 0.25 * (2.0 * r1 + 2.0 * r0 * r2)
    B[1, 0] = 0.25 * (2.0 * r2 + 2.0 * r1 * r0)
    B[1, 1] = 0.25 * (c + 2.0 * r1 * r1)
    B[1, 2] = 0.25 * (2.0 * -r0 + 2.0 * r1 * r2)
    B[2, 0] = 0.25 * (2.0 * -r1 + 2.0 * r2 * r0)
    B[2, 1] = 0.25 * (2.0 * r0 + 2.0 * r2 * r1)
    B[2, 2] = 0.25 * (c + 2.0 * r2 * r2)


@_jit
def _measurement(r0, r1, r2, U, h):
    """The measurement model (the oracle's ``vector_measurement_model``) into ``h`` (3m,): ``[R_BI u_1; ...]`` with
    ``R_IB = I + (8 [p x]^2 + 4 (1 - p'p) [p x]) / (1 + p'p)^2`` (rotations.mrp_to_rotmat)."""
    n2 = r0 * r0 + r1 * r1 + r2 * r2
    den = (1.0 + n2) * (1.0 + n2)
    c4 = 4.0 * (1.0 - n2)
    # [p x]^2 = p p' - n2 I (written as the oracle's 3-term matrix product)
    K00, K01, K02 = 0.0, -r2, r1
    K10, K11, K12 = r2, 0.0, -r0
    K20, K21, K22 = -r1, r0, 0.0
    S00 = K00 * K00 + K01 * K10 + K02 * K20
    S01 = K00 * K01 + K01 * K11 + K02 * K21
    S02 = K00 * K02 + K01 * K12 + K02 * K22
    S10 = K10 * K00 + K11 * K10 + K12 * K20
    S11 = K10 * K01 + K11 * K11 + K12 * K21
    S12 = K10 * K02 + K11 * K12 + K12 * K22
    S20 = K20 * K00 + K21 * K10 + K22 * K20
    S21 = K20 * K01 + K21 * K11 + K22 * K21
    S22 = K20 * K02 + K21 * K12 + K22 * K22
    R00 = 1.0 + (8.0 * S00 + c4 * K00) / den
    R01 = (8.0 * S01 + c4 * K01) / den
    R02 = (8.0 * S02 + c4 * K02) / den
    R10 = (8.0 * S10 + c4 * K10) / den
    R11 = 1.0 + (8.0 * S11 + c4 * K11) / den
    R12 = (8.0 * S12 + c4 * K12) / den
    R20 = (8.0 * S20 + c4 * K20) / den
    R21 = (8.0 * S21 + c4 * K21) / den
    R22 = 1.0 + (8.0 * S22 + c4 * K22) / den
    for m in range(U.shape[0]):
        u0, u1, u2 = U[m, 0], U[m, 1], U[m, 2]
        # (R_IB' u)_k = sum_j R_IB[j, k] u_j
        h[3 * m] = R00 * u0 + R10 * u1 + R20 * u2
        h[3 * m + 1] = R01 * u0 + R11 * u1 + R21 * u2
        h[3 * m + 2] = R02 * u0 + R12 * u1 + R22 * u2


@_jit
def _log_likelihood(r0, r1, r2, y, U, sigma2, h):
    """The log-likelihood of one particle, ``-|y - h(rho)|^2 / (2 sigma^2)`` (``-inf`` if not finite;
    ``h``: scratch (3m,))."""
    _measurement(r0, r1, r2, U, h)
    s = 0.0
    for k in range(y.shape[0]):
        r = y[k] - h[k]
        s += r * r
    ll = -0.5 * s / sigma2
    if not math.isfinite(ll):
        return -math.inf
    return ll


@_jit
def _switch_to_short_mrp(x, P, T, TP):
    """The shadow switch of one particle, in place (the oracle's ``switch_to_short_mrp``): if ``|rho| > 1``, ``rho ->
    -rho / |rho|^2`` and ``P -> sym(T P T')`` with ``T = diag(ds/drho, I)``
    (``T``, ``TP``: (3, 3) and (6, 6) scratch)."""
    r0, r1, r2 = x[0], x[1], x[2]
    n2 = r0 * r0 + r1 * r1 + r2 * r2
    if not n2 > 1.0:
        return
    n4 = n2 * n2
    for a in range(3):
        for b in range(3):
            T[a, b] = (2.0 * x[a] * x[b] - (n2 if a == b else 0.0)) / n4
    x[0], x[1], x[2] = -r0 / n2, -r1 / n2, -r2 / n2
    for a in range(6):
        for c in range(6):
            if a < 3:
                TP[a, c] = T[a, 0] * P[0, c] + T[a, 1] * P[1, c] + T[a, 2] * P[2, c]
            else:
                TP[a, c] = P[a, c]
    for a in range(6):
        for b in range(3):
            P[a, b] = TP[a, 0] * T[b, 0] + TP[a, 1] * T[b, 1] + TP[a, 2] * T[b, 2]
        for b in range(3, 6):
            P[a, b] = TP[a, b]
    for a in range(6):
        for b in range(a + 1, 6):
            s = 0.5 * (P[a, b] + P[b, a])
            P[a, b] = s
            P[b, a] = s


@_jit
def _lu_solve(A, B):
    """``A^-1 B`` in place of ``B`` (n, r) by Gaussian elimination with partial pivoting (as
    LAPACK's dgesv behind numpy.linalg.solve); ``A`` (n, n) is overwritten. Returns False for an
    exactly singular ``A``."""
    n = A.shape[0]
    r = B.shape[1]
    for j in range(n):
        p = j
        big = abs(A[j, j])
        for i in range(j + 1, n):
            if abs(A[i, j]) > big:
                big = abs(A[i, j])
                p = i
        if big == 0.0:
            return False
        if p != j:
            for c in range(n):
                A[j, c], A[p, c] = A[p, c], A[j, c]
            for c in range(r):
                B[j, c], B[p, c] = B[p, c], B[j, c]
        for i in range(j + 1, n):
            f = A[i, j] / A[j, j]
            if f != 0.0:
                for c in range(j + 1, n):
                    A[i, c] -= f * A[j, c]
                for c in range(r):
                    B[i, c] -= f * B[j, c]
    for j in range(n - 1, -1, -1):
        for c in range(r):
            s = B[j, c]
            for k in range(j + 1, n):
                s -= A[j, k] * B[k, c]
            B[j, c] = s / A[j, j]
    return True


# ----------------------------------------------------------------------------------
# Bootstrap and gyroless particle filters
# ----------------------------------------------------------------------------------
@_jit
def _propagate_attitudes(rho, w, dt):
    n = rho.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        qw, qx, qy, qz = _mrp_step(rho[i, 0], rho[i, 1], rho[i, 2], w[i, 0], w[i, 1], w[i, 2], dt)
        out[i, 0], out[i, 1], out[i, 2] = _quat_to_mrp(qw, qx, qy, qz)
    return out


def propagate_attitudes(rho, w, dt: float) -> np.ndarray:
    """``(N, 3)`` short MRPs (``|rho| <= 1``) of ``q(rho_i) ⊗ exp(w_i dt / 2)``, the bootstrap
    PF's attitude step (``w``: ``(N, 3)`` rad/s, ``dt`` s)."""
    return _propagate_attitudes(_f64(rho), _f64(w), float(dt))


@_jit
def _vector_log_likelihood(rho, y, U, sigma2):
    n = rho.shape[0]
    out = np.empty(n)
    h = np.empty(y.shape[0])
    for i in range(n):
        out[i] = _log_likelihood(rho[i, 0], rho[i, 1], rho[i, 2], y, U, sigma2, h)
    return out


def vector_log_likelihood(rho, y, ref_vectors_I, sigma: float) -> np.ndarray:
    """Gaussian log-likelihood (up to a common constant) of ``y`` per particle: ``(N,)``
    ``-|y - h(rho_i)|^2 / (2 sigma^2)`` with ``h(rho) = [R_BI u_1; ...]``, non-finite entries ``-inf``."""
    return _vector_log_likelihood(_f64(rho), _f64(y), _f64(ref_vectors_I), float(sigma) ** 2)


@_jit
def _w_dot(w0, w1, w2, I, Iinv, T):
    """``I^-1 (T - w x (I w))`` (Euler's equations)."""
    a0 = w0 * I[0, 0] + w1 * I[0, 1] + w2 * I[0, 2]
    a1 = w0 * I[1, 0] + w1 * I[1, 1] + w2 * I[1, 2]
    a2 = w0 * I[2, 0] + w1 * I[2, 1] + w2 * I[2, 2]
    c0 = T[0] - (w1 * a2 - w2 * a1)
    c1 = T[1] - (w2 * a0 - w0 * a2)
    c2 = T[2] - (w0 * a1 - w1 * a0)
    return (
        c0 * Iinv[0, 0] + c1 * Iinv[0, 1] + c2 * Iinv[0, 2],
        c0 * Iinv[1, 0] + c1 * Iinv[1, 1] + c2 * Iinv[1, 2],
        c0 * Iinv[2, 0] + c1 * Iinv[2, 1] + c2 * Iinv[2, 2],
    )


@_jit
def _gyroless_propagate(rho, w_in, I, Iinv, T, h, num_substeps, dtheta, use_dtheta):
    n = rho.shape[0]
    rho_out = np.empty((n, 3))
    w_out = np.empty((n, 3))
    hh = 0.5 * h
    h6 = h / 6.0
    for i in range(n):
        qw, qx, qy, qz = _mrp_to_quat(rho[i, 0], rho[i, 1], rho[i, 2])
        w0, w1, w2 = w_in[i, 0], w_in[i, 1], w_in[i, 2]
        for _ in range(num_substeps):
            k10, k11, k12 = _w_dot(w0, w1, w2, I, Iinv, T)
            a0, a1, a2 = w0 + hh * k10, w1 + hh * k11, w2 + hh * k12
            k20, k21, k22 = _w_dot(a0, a1, a2, I, Iinv, T)
            b0, b1, b2 = w0 + hh * k20, w1 + hh * k21, w2 + hh * k22
            k30, k31, k32 = _w_dot(b0, b1, b2, I, Iinv, T)
            e0, e1, e2 = w0 + h * k30, w1 + h * k31, w2 + h * k32
            k40, k41, k42 = _w_dot(e0, e1, e2, I, Iinv, T)
            v0 = (w0 + 2.0 * a0 + 2.0 * b0 + e0) / 6.0
            v1 = (w1 + 2.0 * a1 + 2.0 * b1 + e1) / 6.0
            v2 = (w2 + 2.0 * a2 + 2.0 * b2 + e2) / 6.0
            dw, dx, dy, dz = _rotvec_to_quat(v0 * h, v1 * h, v2 * h)
            qw, qx, qy, qz = _quat_multiply(qw, qx, qy, qz, dw, dx, dy, dz)
            w0 = w0 + h6 * (k10 + 2.0 * k20 + 2.0 * k30 + k40)
            w1 = w1 + h6 * (k11 + 2.0 * k21 + 2.0 * k31 + k41)
            w2 = w2 + h6 * (k12 + 2.0 * k22 + 2.0 * k32 + k42)
        if use_dtheta:
            dw, dx, dy, dz = _rotvec_to_quat(dtheta[i, 0], dtheta[i, 1], dtheta[i, 2])
            qw, qx, qy, qz = _quat_multiply(qw, qx, qy, qz, dw, dx, dy, dz)
        rho_out[i, 0], rho_out[i, 1], rho_out[i, 2] = _quat_to_mrp(qw, qx, qy, qz)
        w_out[i, 0], w_out[i, 1], w_out[i, 2] = w0, w1, w2
    return rho_out, w_out


def gyroless_propagate(rho, w, inertia, inertia_inverse, torque, h: float, num_substeps: int, dtheta=None):
    """The deterministic step of ``GyrolessPfCore.predict`` (``num_substeps`` RK4
    substeps of ``h`` s on Euler's equations, attitude by the Simpson-averaged rate), then
    ``q <- q ⊗ exp(dtheta / 2)`` if ``dtheta`` ``(N, 3)`` is given.

    Returns:
        ``(rho (N, 3) short MRPs, w (N, 3) rad/s)`` (rate process noise not included).
    """
    use = dtheta is not None
    d = _f64(dtheta) if use else np.zeros((0, 3))
    return _gyroless_propagate(
        _f64(rho), _f64(w), _f64(inertia), _f64(inertia_inverse), _f64(torque), float(h), int(num_substeps), d, use
    )


# ----------------------------------------------------------------------------------
# The MRP EKF (one per EKPF particle; a batch of one for MrpEkfCore) and the EKPF's proposal.
# The measurement update's matrix algebra runs on blocks of W particles at once, the particle
# ("lane") as the last axis of every block array: the long dependency chains of one particle
# (Cholesky pivots, triangular solves) then interleave with those of W - 1 independent others
# (25% faster than one particle at a time; each lane's arithmetic is exactly the one-particle
# arithmetic). The time update, mostly per-particle rotations, goes one particle at a time.
# ----------------------------------------------------------------------------------
W = 4  # particles per block


@_jit
def _block(i0, n, ix):
    """Indices ``ix`` (W,) of the block starting at particle ``i0`` (past ``n - 1`` the last
    particle repeats, computed and not stored) and the number of real particles in it."""
    for j in range(W):
        ix[j] = min(i0 + j, n - 1)
    return min(W, n - i0)


@_jit
def _cholesky_lanes(A, L, inv, d, ok):
    """Lower Cholesky factors of the symmetric ``A[:d, :d, j]`` (lower triangles read) into ``L``
    (upper triangles not written) and the reciprocals of their pivots into ``inv`` (LAPACK's
    dpotf2 also scales by the reciprocal pivot); ``ok[j]`` False where ``A`` is not positive
    definite (a pivot <= 0 or NaN; that lane's factor is then unusable). Returns all(ok)."""
    s = np.empty(W)
    for j in range(W):
        ok[j] = True
    for c in range(d):
        for j in range(W):
            s[j] = A[c, c, j]
        for k in range(c):
            for j in range(W):
                s[j] -= L[c, k, j] * L[c, k, j]
        for j in range(W):
            if not s[j] > 0.0:
                ok[j] = False
                s[j] = 1.0
            r = math.sqrt(s[j])
            L[c, c, j] = r
            inv[c, j] = 1.0 / r
        for a in range(c + 1, d):
            for j in range(W):
                s[j] = A[a, c, j]
            for k in range(c):
                for j in range(W):
                    s[j] -= L[a, k, j] * L[c, k, j]
            for j in range(W):
                L[a, c, j] = s[j] * inv[c, j]
    all_ok = True
    for j in range(W):
        all_ok = all_ok and ok[j]
    return all_ok


@_jit
def _log_det(L, j):
    """``log det L = sum log L_cc`` of lane ``j``'s 6x6 Cholesky factor, as one log of the
    product of the pivots (the sum of logs where that product leaves the normal range)."""
    prod = 1.0
    for c in range(6):
        prod *= L[c, c, j]
    if 1e-300 < prod < 1e300:
        return math.log(prod)
    s = 0.0
    for c in range(6):
        s += math.log(L[c, c, j])
    return s


@_jit
def _ekf_predict(x, P, w_meas, dt, half_dt, c2, c3, sv2, su2):
    """:func:`ekf_predict`'s loop: every particle's mean, ``F``, ``Phi``, ``Qd`` and ``P+``.
    Long on purpose: one compiled loop over the particles with its scratch arrays allocated once;
    split into helpers, each particle's step would pass them through a dozen calls."""
    n = x.shape[0]
    x_out = np.empty((n, 6))
    P_out = np.empty((n, 6, 6))
    B = np.empty((3, 3))
    F = np.zeros((3, 6))  # the rows of F = [[J, -B], [0, 0]] that are not zero
    A = np.empty((3, 6))
    A2 = np.empty((3, 6))
    Phi = np.empty((3, 6))  # the rows of Phi = [[Phi_1, Phi_2], [0, I]] that are not those of I
    Qg = np.empty((3, 3))  # its rho-rho block (sv2 B B'); the bias block is su2 I
    FQ = np.empty((3, 6))
    M = np.empty((6, 6))
    T = np.empty((3, 3))
    TP = np.empty((6, 6))
    for i in range(n):
        Pi = P[i]
        Pn = P_out[i]
        b0, b1, b2 = x[i, 3], x[i, 4], x[i, 5]
        w0, w1, w2 = w_meas[0] - b0, w_meas[1] - b1, w_meas[2] - b2
        # F at the half-step mean (mrp_dynamics_jacobian): J = d(B w)/drho =
        # 1/2 [rho w' - w rho' - [w x] + (rho'w) I]
        m0, m1, m2 = _propagate_mrp(x[i, 0], x[i, 1], x[i, 2], w0, w1, w2, half_dt)
        rw = m0 * w0 + m1 * w1 + m2 * w2
        F[0, 0] = 0.5 * (m0 * w0 - w0 * m0 - 0.0 + rw)
        F[0, 1] = 0.5 * (m0 * w1 - w0 * m1 - -w2 + 0.0)
        F[0, 2] = 0.5 * (m0 * w2 - w0 * m2 - w1 + 0.0)
        F[1, 0] = 0.5 * (m1 * w0 - w1 * m0 - w2 + 0.0)
        F[1, 1] = 0.5 * (m1 * w1 - w1 * m1 - 0.0 + rw)
        F[1, 2] = 0.5 * (m1 * w2 - w1 * m2 - -w0 + 0.0)
        F[2, 0] = 0.5 * (m2 * w0 - w2 * m0 - -w1 + 0.0)
        F[2, 1] = 0.5 * (m2 * w1 - w2 * m1 - w0 + 0.0)
        F[2, 2] = 0.5 * (m2 * w2 - w2 * m2 - 0.0 + rw)
        _kinematics_matrix(m0, m1, m2, B)
        for a in range(3):
            for c in range(3):
                F[a, 3 + c] = -B[a, c]
        # Phi = I + A + A^2 / 2 + A^3 / 6, A = F dt (discrete_transition_matrix)
        for a in range(3):
            for c in range(6):
                A[a, c] = F[a, c] * dt
        for a in range(3):
            for c in range(6):
                A2[a, c] = A[a, 0] * A[0, c] + A[a, 1] * A[1, c] + A[a, 2] * A[2, c]
        for a in range(3):
            for c in range(6):
                A3 = A2[a, 0] * A[0, c] + A2[a, 1] * A[1, c] + A2[a, 2] * A[2, c]
                Phi[a, c] = (((1.0 if a == c else 0.0) + A[a, c]) + 0.5 * A2[a, c]) + A3 / 6.0
        # Qd = Qg dt + (F Qg + Qg F') dt^2 / 2 + F Qg F' dt^3 / 3 with Qg = diag(sv2 B B', su2 I)
        # (discrete_process_noise); F Qg = [[J sv2 B B', -B su2], [0, 0]]
        for a in range(3):
            for c in range(3):
                Qg[a, c] = sv2 * (B[a, 0] * B[c, 0] + B[a, 1] * B[c, 1] + B[a, 2] * B[c, 2])
        for a in range(3):
            for c in range(3):
                FQ[a, c] = F[a, 0] * Qg[0, c] + F[a, 1] * Qg[1, c] + F[a, 2] * Qg[2, c]
            for c in range(3, 6):
                FQ[a, c] = F[a, c] * su2
        # mean: exact for the constant rate over dt (propagate_mrp); the bias is constant
        x_out[i, 0], x_out[i, 1], x_out[i, 2] = _propagate_mrp(x[i, 0], x[i, 1], x[i, 2], w0, w1, w2, dt)
        x_out[i, 3], x_out[i, 4], x_out[i, 5] = b0, b1, b2
        # P+ = sym(Phi P Phi' + Qd): M = Phi P, then the lower triangle of M Phi' + Qd
        for a in range(3):
            for c in range(6):
                s = 0.0
                for k in range(6):
                    s += Phi[a, k] * Pi[k, c]
                M[a, c] = s
        for a in range(3, 6):
            for c in range(6):
                M[a, c] = Pi[a, c]
        for a in range(6):
            for c in range(a + 1):
                if c < 3:
                    s = 0.0
                    for k in range(6):
                        s += M[a, k] * Phi[c, k]
                else:
                    s = M[a, c]
                if a < 3:  # Qd: the rho-rho block
                    q = Qg[a, c] * dt + (FQ[a, c] + FQ[c, a]) * c2
                    f = 0.0
                    for k in range(6):
                        f += FQ[a, k] * F[c, k]
                    q += f * c3
                elif c < 3:  # the bias-rho block (Qg's is zero)
                    q = FQ[c, a] * c2
                else:
                    q = (su2 if a == c else 0.0) * dt
                s += q
                Pn[a, c] = s
                Pn[c, a] = s
        _switch_to_short_mrp(x_out[i], Pn, T, TP)
    return x_out, P_out


def ekf_predict(x, P, w_meas, dt: float, sigma_v: float, sigma_u: float):
    """Every particle's EKF time update of ``(N, 6)`` states ``[rho; b]`` and ``(N, 6, 6)``
    covariances with one ``(3,)`` measured rate held over ``dt``: the mean exact for the constant
    rate, ``Phi`` and ``Qd`` from ``F`` at the half-step mean (docs/derivations/mrp_ekf.md).

    Returns:
        ``(x_pred, P_pred)``, shadow switch applied.
    """
    dt = float(dt)
    return _ekf_predict(
        _f64(x), _f64(P), _f64(w_meas), dt, 0.5 * dt, 0.5 * dt**2, dt**3 / 3.0, float(sigma_v) ** 2, float(sigma_u) ** 2
    )


@_jit
def _measurement_jacobian(r0, r1, r2, U, h, Hr, B):
    """The measurement Jacobian (the oracle's ``vector_measurement_jacobian``): the rho columns ``Hr`` (3m, 3) (the bias columns
    are zero) and the model ``h`` (3m,) at ``rho``; ``B``: (3, 3) scratch."""
    _measurement(r0, r1, r2, U, h)
    n2 = r0 * r0 + r1 * r1 + r2 * r2
    f = 16.0 / ((1.0 + n2) * (1.0 + n2))
    _kinematics_matrix(r0, r1, r2, B)
    # Binv = f B'; Hrho_m = [hb_m x] Binv
    for m in range(U.shape[0]):
        h0, h1, h2 = h[3 * m], h[3 * m + 1], h[3 * m + 2]
        for c in range(3):
            bi0, bi1, bi2 = f * B[c, 0], f * B[c, 1], f * B[c, 2]
            Hr[3 * m, c] = 0.0 * bi0 + -h2 * bi1 + h1 * bi2
            Hr[3 * m + 1, c] = h2 * bi0 + 0.0 * bi1 + -h0 * bi2
            Hr[3 * m + 2, c] = -h1 * bi0 + h0 * bi1 + 0.0 * bi2


@_jit
def _ekf_gain(x, xj, Pb, y, U, sigma2, x_next, Hr, Kt, w):
    """One linearization of the (iterated) EKF update (:func:`ekf_update`) of a block: at the
    iterates ``xj`` (6, W) (``xj = x``: the classic EKF), ``Hr`` (3m, 3, W) = the rho columns of
    ``H`` (its bias columns are zero), ``Kt`` (3m, 6, W) = ``K' = S^-1 H P`` with
    ``S = H P H' + sigma^2 I``, and ``x_next = x + K (y - h(x_j) - H (x - x_j))`` (6, W).
    ``w``: scratch ``(h (3m, W), S, C (3m, 3m, W), inv (3m, W), corr (3m, W), ok (W,), h1 (3m,),
    Hr1 (3m, 3), B1 (3, 3), S1 (3m, 3m), K1 (3m, 6))``. Returns False if some ``S`` is exactly
    singular."""
    h, S, C, inv, corr, ok, h1, Hr1, B1, S1, K1 = w
    nm = y.shape[0]
    for j in range(W):
        _measurement_jacobian(xj[0, j], xj[1, j], xj[2, j], U, h1, Hr1, B1)
        for l in range(nm):
            h[l, j] = h1[l]
            for c in range(3):
                Hr[l, c, j] = Hr1[l, c]
    # (P H')' and the lower triangle of S
    for l in range(nm):
        for a in range(6):
            for j in range(W):
                Kt[l, a, j] = Pb[a, 0, j] * Hr[l, 0, j] + Pb[a, 1, j] * Hr[l, 1, j] + Pb[a, 2, j] * Hr[l, 2, j]
    for l in range(nm):
        for l2 in range(l + 1):
            for j in range(W):
                S[l, l2, j] = Hr[l, 0, j] * Kt[l2, 0, j] + Hr[l, 1, j] * Kt[l2, 1, j] + Hr[l, 2, j] * Kt[l2, 2, j]
        for j in range(W):
            S[l, l, j] += sigma2
    # K' = S^-1 (P H')': by Cholesky (S is symmetric positive definite for sigma > 0) ...
    _cholesky_lanes(S, C, inv, nm, ok)
    for r in range(nm):  # C Z = (P H')'
        for c in range(6):
            for j in range(W):
                Kt[r, c, j] *= inv[r, j]
        for a in range(r + 1, nm):
            for c in range(6):
                for j in range(W):
                    Kt[a, c, j] -= C[a, r, j] * Kt[r, c, j]
    for r in range(nm - 1, -1, -1):  # C' K' = Z
        for c in range(6):
            for j in range(W):
                Kt[r, c, j] *= inv[r, j]
        for a in range(r):
            for c in range(6):
                for j in range(W):
                    Kt[a, c, j] -= C[r, a, j] * Kt[r, c, j]
    # ... and where a factorization failed, by LU with partial pivoting (numpy.linalg.solve's)
    for j in range(W):
        if not ok[j]:
            for l in range(nm):
                for l2 in range(nm):
                    S1[l, l2] = S[max(l, l2), min(l, l2), j]
                for a in range(6):
                    K1[l, a] = Pb[a, 0, j] * Hr[l, 0, j] + Pb[a, 1, j] * Hr[l, 1, j] + Pb[a, 2, j] * Hr[l, 2, j]
            if not _lu_solve(S1, K1):
                return False
            for l in range(nm):
                for a in range(6):
                    Kt[l, a, j] = K1[l, a]
    for l in range(nm):
        for j in range(W):
            d0, d1, d2 = x[0, j] - xj[0, j], x[1, j] - xj[1, j], x[2, j] - xj[2, j]
            corr[l, j] = (y[l] - h[l, j]) - (Hr[l, 0, j] * d0 + Hr[l, 1, j] * d1 + Hr[l, 2, j] * d2)
    for a in range(6):
        for j in range(W):
            x_next[a, j] = 0.0
    for l in range(nm):
        for a in range(6):
            for j in range(W):
                x_next[a, j] += Kt[l, a, j] * corr[l, j]
    for a in range(6):
        for j in range(W):
            x_next[a, j] = x[a, j] + x_next[a, j]
    return True


@_jit
def _gain_scratch(nm):
    return (
        np.empty((nm, W)),
        np.empty((nm, nm, W)),
        np.empty((nm, nm, W)),
        np.empty((nm, W)),
        np.empty((nm, W)),
        np.empty(W, np.bool_),
        np.empty(nm),
        np.empty((nm, 3)),
        np.empty((3, 3)),
        np.empty((nm, nm)),
        np.empty((nm, 6)),
    )


@_jit
def _gather(ix, v, vb):
    """``vb[a, j] = v[ix[j], a]``: the block's rows of an ``(N, r)`` array."""
    for j in range(W):
        for a in range(v.shape[1]):
            vb[a, j] = v[ix[j], a]


@_jit
def _gather_matrices(ix, v, vb):
    """``vb[a, c, j] = v[ix[j], a, c]``: the block's matrices of an ``(N, r, c)`` array."""
    for j in range(W):
        for a in range(v.shape[1]):
            for c in range(v.shape[2]):
                vb[a, c, j] = v[ix[j], a, c]


@_jit
def _ekf_iterate(x, P, y, U, sigma2, iterations, tol, Hs, Ks, zs, Ss):
    """The mean of every particle's (iterated) EKF update (the oracle's ``ekf_update``): the last
    iterates ``(N, 6)`` and whether every innovation covariance was invertible. The batch
    stops iterating when no component of any particle moved by more than ``tol``, as the
    oracle. ``Hs`` ``(N, 3m, 3)`` and ``Ks`` ``(N, 3m, 6)`` receive the last linearization's
    ``H_rho`` and ``K'``; ``zs`` ``(N, 3m)`` and ``Ss`` ``(N, 3m, 3m)``, unless empty, the innovation
    ``y - h(x)`` and its covariance ``S`` at the prior (the first linearization)."""
    n = x.shape[0]
    nm = y.shape[0]
    w = _gain_scratch(nm)
    ix = np.empty(W, np.int64)
    xb, xjb, x_next = np.empty((6, W)), np.empty((6, W)), np.empty((6, W))
    Pb = np.empty((6, 6, W))
    Hr, Kt = np.empty((nm, 3, W)), np.empty((nm, 6, W))
    x_j = x.copy()
    for iteration in range(iterations):
        converged = True
        for i0 in range(0, n, W):
            count = _block(i0, n, ix)
            _gather(ix, x, xb)
            _gather(ix, x_j, xjb)
            _gather_matrices(ix, P, Pb)
            if not _ekf_gain(xb, xjb, Pb, y, U, sigma2, x_next, Hr, Kt, w):
                return x_j, False
            if iteration == 0 and zs.shape[0] > 0:
                _store_innovations(ix, count, y, w[0], w[1], zs, Ss)
            for j in range(count):
                i = ix[j]
                for a in range(6):
                    if not abs(x_next[a, j] - x_j[i, a]) <= tol:  # NaN: not converged (max(...) <= tol)
                        converged = False
                    x_j[i, a] = x_next[a, j]
                for l in range(nm):
                    for c in range(3):
                        Hs[i, l, c] = Hr[l, c, j]
                    for c in range(6):
                        Ks[i, l, c] = Kt[l, c, j]
        if converged:
            break
    return x_j, True


@_jit
def _store_innovations(ix, count, y, h, S, zs, Ss):
    """The block's innovations ``y - h`` and covariances ``S`` (lower triangles of ``S`` read,
    both written) into the particles' rows of ``zs`` and ``Ss``."""
    nm = y.shape[0]
    for j in range(count):
        i = ix[j]
        for l in range(nm):
            zs[i, l] = y[l] - h[l, j]
            for l2 in range(l + 1):
                Ss[i, l, l2] = S[l, l2, j]
                Ss[i, l2, l] = S[l, l2, j]


@_jit
def _joseph(Pb, Hr, Kt, sigma2, IKH, M, Pn):
    """Lower triangles of ``(I - K H) P (I - K H)' + sigma^2 K K'`` of a block into ``Pn``
    (6, 6, W), ``H = [Hr 0]`` (so ``I - K H`` has the bias columns of ``I``), ``Kt = K'``;
    ``IKH`` (6, 3, W), ``M`` (6, 6, W): scratch. (The oracle symmetrizes the full product.)"""
    nm = Hr.shape[0]
    s = np.empty(W)
    for a in range(6):
        for c in range(3):
            for j in range(W):
                s[j] = 0.0
            for l in range(nm):
                for j in range(W):
                    s[j] += Kt[l, a, j] * Hr[l, c, j]
            e = 1.0 if a == c else 0.0
            for j in range(W):
                IKH[a, c, j] = e - s[j]
    for a in range(6):  # M = (I - K H) P
        for c in range(6):
            for j in range(W):
                M[a, c, j] = IKH[a, 0, j] * Pb[0, c, j] + IKH[a, 1, j] * Pb[1, c, j] + IKH[a, 2, j] * Pb[2, c, j]
            if a >= 3:
                for j in range(W):
                    M[a, c, j] += Pb[a, c, j]
    for a in range(6):  # M (I - K H)'
        for c in range(a + 1):
            for j in range(W):
                Pn[a, c, j] = M[a, 0, j] * IKH[c, 0, j] + M[a, 1, j] * IKH[c, 1, j] + M[a, 2, j] * IKH[c, 2, j]
            if c >= 3:
                for j in range(W):
                    Pn[a, c, j] += M[a, c, j]
    for l in range(nm):
        for a in range(6):
            for c in range(a + 1):
                for j in range(W):
                    Pn[a, c, j] += (Kt[l, a, j] * sigma2) * Kt[l, c, j]


@_jit
def _ekf_update(x, P, y, U, sigma2, iterations, tol, switch):
    n = x.shape[0]
    nm = y.shape[0]
    Hs = np.empty((n, nm, 3))
    Ks = np.empty((n, nm, 6))
    zs = np.empty((n, nm))
    Ss = np.empty((n, nm, nm))
    x_post, ok = _ekf_iterate(x, P, y, U, sigma2, iterations, tol, Hs, Ks, zs, Ss)
    P_post = np.empty((n, 6, 6))
    if ok:
        ix = np.empty(W, np.int64)
        Pb, Pn = np.empty((6, 6, W)), np.empty((6, 6, W))
        Hr, Kt = np.empty((nm, 3, W)), np.empty((nm, 6, W))
        IKH, M = np.empty((6, 3, W)), np.empty((6, 6, W))
        for i0 in range(0, n, W):
            count = _block(i0, n, ix)
            _gather_matrices(ix, P, Pb)
            _gather_matrices(ix, Hs, Hr)
            _gather_matrices(ix, Ks, Kt)
            _joseph(Pb, Hr, Kt, sigma2, IKH, M, Pn)
            for j in range(count):
                for a in range(6):
                    for c in range(a + 1):
                        P_post[ix[j], a, c] = Pn[a, c, j]
                        P_post[ix[j], c, a] = Pn[a, c, j]
        if switch:
            T, TP = np.empty((3, 3)), np.empty((6, 6))
            for i in range(n):
                _switch_to_short_mrp(x_post[i], P_post[i], T, TP)
    return x_post, P_post, zs, Ss, ok


def ekf_update(
    x, P, y, ref_vectors_I, sigma: float, switch: bool = True, iterations: int = 1, iteration_tolerance: float = 1e-12
):
    """Every particle's EKF measurement update of ``(N, 6)`` states and ``(N, 6, 6)`` covariances
    with ``y`` ``(3m,)``: Joseph form; iterated when ``iterations > 1`` (Gauss-Newton, relinearized
    at the latest iterate, all iterates in the prior's MRP chart), the batch stopping when no
    component of any particle moved by more than the tolerance; then the shadow switch if
    ``switch``.

    Returns:
        ``(x_post, P_post, innovation (N, 3m), S (N, 3m, 3m))``: the innovation ``y - h(x^-)``
        and its covariance ``S = H P H' + sigma^2 I`` at the prior.

    Raises:
        numpy.linalg.LinAlgError: an exactly singular innovation covariance.
    """
    x_post, P_post, innovation, S, ok = _ekf_update(
        _f64(x),
        _f64(P),
        _f64(y),
        _f64(ref_vectors_I),
        float(sigma) ** 2,
        int(iterations),
        float(iteration_tolerance),
        bool(switch),
    )
    if not ok:
        raise np.linalg.LinAlgError("Singular matrix")
    return x_post, P_post, innovation, S


@_jit(inline="always")  # compiled into each caller: as a call, it cost the fused step ~5% (measured)
def _draw_and_weigh(
    count,
    ix,
    mb,
    m_post,
    eb,
    Pn,
    L_post,
    L_prior,
    inv_prior,
    y,
    U,
    sigma2,
    xb,
    z,
    s,
    h1,
    T,
    TP,
    x_out,
    P_out,
    log_increment,
):
    """The proposal step of a block, given the lower Cholesky factors ``L_post`` of ``P+`` and
    ``L_prior`` of ``P-`` (6, 6, W) and the reciprocals of ``L_prior``'s pivots: the draw
    ``x = m+ + L+ eps``, the log-weight increment ``log p(y | x) + log N(x; m-, P-) -
    log N(x; m+, P+)`` and the shadow switch of ``(x, P+)`` (``Pn``: lower triangles read),
    written to the block's particles' rows of ``x_out``, ``P_out`` and ``log_increment``.
    ``xb``, ``z`` (6, W), ``s`` (W,), ``h1`` (3m,), ``T`` (3, 3), ``TP`` (6, 6): scratch."""
    # x = m+ + L+ eps; log q(x) = -|eps|^2 / 2 - log det L+
    for a in range(6):
        for j in range(W):
            s[j] = 0.0
        for k in range(a + 1):
            for j in range(W):
                s[j] += L_post[a, k, j] * eb[k, j]
        for j in range(W):
            xb[a, j] = m_post[a, j] + s[j]
    # log pi(x) = -|L-^-1 (x - m-)|^2 / 2 - log det L-
    for a in range(6):
        for j in range(W):
            s[j] = xb[a, j] - mb[a, j]
        for k in range(a):
            for j in range(W):
                s[j] -= L_prior[a, k, j] * z[k, j]
        for j in range(W):
            z[a, j] = s[j] * inv_prior[a, j]
    for j in range(count):
        ee = 0.0
        zz = 0.0
        for a in range(6):
            ee += eb[a, j] * eb[a, j]
            zz += z[a, j] * z[a, j]
        log_q = -0.5 * ee - _log_det(L_post, j)
        log_pi = -0.5 * zz - _log_det(L_prior, j)
        log_lik = _log_likelihood(xb[0, j], xb[1, j], xb[2, j], y, U, sigma2, h1)
        i = ix[j]
        log_increment[i] = log_lik + log_pi - log_q
        for a in range(6):
            x_out[i, a] = xb[a, j]
            for c in range(a + 1):
                P_out[i, a, c] = Pn[a, c, j]
                P_out[i, c, a] = Pn[a, c, j]
        _switch_to_short_mrp(x_out[i], P_out[i], T, TP)


@_jit
def _ekpf_update(m_prior, P_prior, eps, y, U, sigma2, iterations, tol):
    """:func:`ekpf_update`'s loop over blocks of ``W`` particles; status 0, 1 (a factor not
    positive definite) or 2 (a singular innovation covariance)."""
    n = m_prior.shape[0]
    nm = y.shape[0]
    x_out = np.empty((n, 6))
    P_out = np.empty((n, 6, 6))
    log_increment = np.empty(n)
    ix = np.empty(W, np.int64)
    mb, m_post, xb, eb = np.empty((6, W)), np.empty((6, W)), np.empty((6, W)), np.empty((6, W))
    Pb, Pn = np.empty((6, 6, W)), np.empty((6, 6, W))
    L_post, L_prior = np.empty((6, 6, W)), np.empty((6, 6, W))
    inv_post, inv_prior = np.empty((6, W)), np.empty((6, W))
    ok = np.empty(W, np.bool_)
    Hr, Kt = np.empty((nm, 3, W)), np.empty((nm, 6, W))
    IKH, M = np.empty((6, 3, W)), np.empty((6, 6, W))
    z = np.empty((6, W))
    s = np.empty(W)
    h1 = np.empty(nm)
    T = np.empty((3, 3))
    TP = np.empty((6, 6))
    w = _gain_scratch(nm)
    # Iterated: the batch's iterations first (they stop together); classic: each block's EKF
    # update right before its proposal step (one pass over the particles).
    one_pass = iterations == 1
    Hs = np.empty((0 if one_pass else n, nm, 3))
    Ks = np.empty((0 if one_pass else n, nm, 6))
    m_posts = m_prior
    if not one_pass:
        m_posts, ok_all = _ekf_iterate(
            m_prior, P_prior, y, U, sigma2, iterations, tol, Hs, Ks, np.empty((0, nm)), np.empty((0, nm, nm))
        )
        if not ok_all:
            return x_out, P_out, log_increment, 2
    for i0 in range(0, n, W):
        count = _block(i0, n, ix)
        _gather(ix, m_prior, mb)
        _gather_matrices(ix, P_prior, Pb)
        _gather(ix, eps, eb)
        if one_pass:
            if not _ekf_gain(mb, mb, Pb, y, U, sigma2, m_post, Hr, Kt, w):
                return x_out, P_out, log_increment, 2
        else:
            _gather(ix, m_posts, m_post)
            _gather_matrices(ix, Hs, Hr)
            _gather_matrices(ix, Ks, Kt)
        _joseph(Pb, Hr, Kt, sigma2, IKH, M, Pn)
        if not (_cholesky_lanes(Pn, L_post, inv_post, 6, ok) and _cholesky_lanes(Pb, L_prior, inv_prior, 6, ok)):
            return x_out, P_out, log_increment, 1
        _draw_and_weigh(
            count,
            ix,
            mb,
            m_post,
            eb,
            Pn,
            L_post,
            L_prior,
            inv_prior,
            y,
            U,
            sigma2,
            xb,
            z,
            s,
            h1,
            T,
            TP,
            x_out,
            P_out,
            log_increment,
        )
    return x_out, P_out, log_increment, 0


def ekpf_update(
    m_prior, P_prior, eps, y, ref_vectors_I, sigma: float, iterations: int = 1, iteration_tolerance: float = 1e-12
):
    """The EKPF's measurement step before the reweighting: every particle's EKF update
    ``(m+, P+)`` (as :func:`ekf_update`, no shadow switch), the lower Cholesky factors ``L+``,
    ``L-`` of ``P+`` and ``P-``, then :func:`ekpf_draw`'s draw, weight increment and shadow switch,
    in one pass over the particles.

    Returns:
        ``(x (N, 6), P (N, 6, 6), log_increment (N,))``, or None if some ``P+`` or ``P-`` is
        not positive definite: the caller then repairs the factors of the whole batch
        (``particle._paired_cholesky``) and calls :func:`ekpf_draw` with them.

    Raises:
        numpy.linalg.LinAlgError: an exactly singular innovation covariance.
    """
    x, P, log_increment, status = _ekpf_update(
        _f64(m_prior),
        _f64(P_prior),
        _f64(eps),
        _f64(y),
        _f64(ref_vectors_I),
        float(sigma) ** 2,
        int(iterations),
        float(iteration_tolerance),
    )
    if status == 2:
        raise np.linalg.LinAlgError("Singular matrix")
    return None if status == 1 else (x, P, log_increment)


@_jit
def _ekpf_draw(m_prior, m_post, P_post, L_prior, L_post, eps, y, U, sigma2):
    n = m_prior.shape[0]
    x_out = np.empty((n, 6))
    P_out = np.empty((n, 6, 6))
    log_increment = np.empty(n)
    ix = np.empty(W, np.int64)
    mb, mpb, eb = np.empty((6, W)), np.empty((6, W)), np.empty((6, W))
    Pn, Lpo, Lpr = np.empty((6, 6, W)), np.empty((6, 6, W)), np.empty((6, 6, W))
    inv_prior = np.empty((6, W))
    nm = y.shape[0]
    xb, z, s, h1, T, TP = (
        np.empty((6, W)),
        np.empty((6, W)),
        np.empty(W),
        np.empty(nm),
        np.empty((3, 3)),
        np.empty((6, 6)),
    )
    for i0 in range(0, n, W):
        count = _block(i0, n, ix)
        _gather(ix, m_prior, mb)
        _gather(ix, m_post, mpb)
        _gather(ix, eps, eb)
        _gather_matrices(ix, P_post, Pn)
        _gather_matrices(ix, L_post, Lpo)
        _gather_matrices(ix, L_prior, Lpr)
        for a in range(6):
            for j in range(W):
                inv_prior[a, j] = 1.0 / Lpr[a, a, j]
        _draw_and_weigh(
            count,
            ix,
            mb,
            mpb,
            eb,
            Pn,
            Lpo,
            Lpr,
            inv_prior,
            y,
            U,
            sigma2,
            xb,
            z,
            s,
            h1,
            T,
            TP,
            x_out,
            P_out,
            log_increment,
        )
    return x_out, P_out, log_increment


def ekpf_draw(m_prior, m_post, P_post, L_prior, L_post, eps, y, ref_vectors_I, sigma: float):
    """The EKPF's proposal draw and weights from given lower Cholesky factors ``L_prior`` of the
    prior covariances ``P-`` and ``L_post`` of the proposal covariances ``P+`` (``(N, 6, 6)``
    each): ``x = m+ + L+ eps`` with the ``(N, 6)`` standard normals ``eps``, the weight increment
    ``log p(y | x) + log N(x; m-, P-) - log N(x; m+, P+)`` (up to a common constant) and the
    shadow switch of ``(x, P+)`` — the arithmetic :func:`ekpf_update` runs on its own factors.

    Returns:
        ``(x (N, 6), P (N, 6, 6), log_increment (N,))``.
    """
    return _ekpf_draw(
        _f64(m_prior),
        _f64(m_post),
        _f64(P_post),
        _f64(L_prior),
        _f64(L_post),
        _f64(eps),
        _f64(y),
        _f64(ref_vectors_I),
        float(sigma) ** 2,
    )


CACHING = _compiled.CACHING  # after every kernel's decoration: False if none could be cached
