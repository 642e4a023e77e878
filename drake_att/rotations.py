"""Rotation math: quaternions, rotation matrices, rotation vectors, MRPs, GRPs.

Conventions (see docs/architecture.md):

* Quaternions are ``[w, x, y, z]`` (scalar first), Hamilton product, the same order
  and sense as Drake's ``Quaternion`` / ``RotationMatrix``: ``q_IB`` rotates a vector
  expressed in B into I, ``v_I = R(q_IB) v_B``.
* Every function accepts a single element (``(4,)``, ``(3,)``, ``(3, 3)``) or a batch
  with leading dimensions (``(N, 4)``, ``(N, 3)``, ``(N, 3, 3)``) and returns the same
  leading shape. Batched forms exist so particle filters can work on whole particle sets.
* Rotation vectors ``phi`` satisfy ``R = exp([phi x])``; ``quat_to_rotvec`` returns the
  shortest one (angle in ``[0, pi]``).
* MRPs: ``p = q_vec / (1 + q_w)``; the shadow set is ``-p / |p|^2`` (same rotation).
* GRPs (generalized Rodrigues parameters, Crassidis & Markley 2003):
  ``p = f q_vec / (a + q_w)``.  ``a = 0, f = 1`` gives Gibbs vectors, ``a = 1, f = 1``
  MRPs, and ``a = 1, f = 4`` makes ``|p|`` approximately the rotation angle.

No Drake dependency: pure numpy so that filter cores stay Drake-free.  The tests check
every conversion against pydrake's ``RotationMatrix`` / ``Quaternion`` / ``RollPitchYaw``.
"""

from __future__ import annotations

import math

import numpy as np

_SMALL_ANGLE = 1e-4  # below this angle (rad) series expansions are used


def _as_array(x) -> np.ndarray:
    return np.asarray(x, dtype=float)


def skew(v) -> np.ndarray:
    """Cross-product matrix ``[v x]`` such that ``skew(a) @ b == cross(a, b)``."""
    v = _as_array(v)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


# ----------------------------------------------------------------------------------
# Quaternions
# ----------------------------------------------------------------------------------
def quat_identity(shape: tuple = ()) -> np.ndarray:
    """Identity quaternion(s) ``[1, 0, 0, 0]`` with leading ``shape``."""
    q = np.zeros(tuple(shape) + (4,))
    q[..., 0] = 1.0
    return q


def quat_normalize(q) -> np.ndarray:
    """Unit quaternion(s) ``q / |q|``."""
    q = _as_array(q)
    if q.ndim == 1:
        return q / math.sqrt(float(q @ q))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_canonical(q) -> np.ndarray:
    """Sign-canonical representative: scalar part >= 0 (q and -q are one rotation)."""
    q = _as_array(q)
    if q.ndim == 1:
        return -q if q[0] < 0.0 else q.copy()
    sign = np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return q * sign


def quat_conjugate(q) -> np.ndarray:
    """Conjugate ``[w, -x, -y, -z]`` (the inverse of a unit quaternion)."""
    q = _as_array(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_multiply(p, q) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (``R(p ⊗ q) = R(p) R(q)``); broadcasts batches."""
    p = _as_array(p)
    q = _as_array(q)
    if p.ndim == 1 and q.ndim == 1:
        # Scalar fast path (Python floats): ~15x faster than the broadcasting form for the
        # per-event work of Drake systems.
        pw, px, py, pz = p.tolist()
        qw, qx, qy, qz = q.tolist()
        return np.array(
            [
                pw * qw - px * qx - py * qy - pz * qz,
                pw * qx + px * qw + py * qz - pz * qy,
                pw * qy - px * qz + py * qw + pz * qx,
                pw * qz + px * qy - py * qx + pz * qw,
            ]
        )
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_to_rotmat(q) -> np.ndarray:
    """Rotation matrix ``R(q)`` of (not necessarily unit) quaternion(s)."""
    q = quat_normalize(q)
    if q.ndim == 1:  # scalar fast path
        w, x, y, z = q.tolist()
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotmat_to_quat(R) -> np.ndarray:
    """Unit quaternion (scalar part >= 0) of rotation matrix(es); Shepperd's method."""
    R = _as_array(R)
    batch = R.shape[:-2]
    R = R.reshape((-1, 3, 3))
    trace = np.trace(R, axis1=1, axis2=2)
    diag = np.diagonal(R, axis1=1, axis2=2)
    # Candidates for 4 q_i^2: [1+tr, 1+2R00-tr, 1+2R11-tr, 1+2R22-tr]
    cand = np.column_stack([1.0 + trace, 1.0 + 2.0 * diag - trace[:, None]])
    best = np.argmax(cand, axis=1)
    q = np.empty((R.shape[0], 4))
    for k in range(4):
        sel = best == k
        if not np.any(sel):
            continue
        Rs = R[sel]
        s = 2.0 * np.sqrt(cand[sel, k])  # = 4 |q_k|
        if k == 0:
            q[sel] = np.column_stack(
                [
                    s / 4,
                    (Rs[:, 2, 1] - Rs[:, 1, 2]) / s,
                    (Rs[:, 0, 2] - Rs[:, 2, 0]) / s,
                    (Rs[:, 1, 0] - Rs[:, 0, 1]) / s,
                ]
            )
        elif k == 1:
            q[sel] = np.column_stack(
                [
                    (Rs[:, 2, 1] - Rs[:, 1, 2]) / s,
                    s / 4,
                    (Rs[:, 0, 1] + Rs[:, 1, 0]) / s,
                    (Rs[:, 0, 2] + Rs[:, 2, 0]) / s,
                ]
            )
        elif k == 2:
            q[sel] = np.column_stack(
                [
                    (Rs[:, 0, 2] - Rs[:, 2, 0]) / s,
                    (Rs[:, 0, 1] + Rs[:, 1, 0]) / s,
                    s / 4,
                    (Rs[:, 1, 2] + Rs[:, 2, 1]) / s,
                ]
            )
        else:
            q[sel] = np.column_stack(
                [
                    (Rs[:, 1, 0] - Rs[:, 0, 1]) / s,
                    (Rs[:, 0, 2] + Rs[:, 2, 0]) / s,
                    (Rs[:, 1, 2] + Rs[:, 2, 1]) / s,
                    s / 4,
                ]
            )
    q = quat_canonical(quat_normalize(q))
    return q.reshape(batch + (4,))


def quat_rotate(q, v) -> np.ndarray:
    """``R(q) v`` for quaternion(s) q and vector(s) v (broadcasting)."""
    q = quat_normalize(q)
    v = _as_array(v)
    qv = q[..., 1:]
    t = 2.0 * np.cross(qv, v)
    return v + q[..., :1] * t + np.cross(qv, t)


# ----------------------------------------------------------------------------------
# Rotation vectors (exp / log)
# ----------------------------------------------------------------------------------
def rotvec_to_quat(phi) -> np.ndarray:
    """Quaternion ``exp(phi / 2)`` of rotation vector(s) phi (angle |phi| about phi)."""
    phi = _as_array(phi)
    if phi.ndim == 1:  # scalar fast path
        x, y, z = phi.tolist()
        a = math.sqrt(x * x + y * y + z * z)
        k = 0.5 - a * a / 48.0 if a < _SMALL_ANGLE else math.sin(0.5 * a) / a
        return np.array([math.cos(0.5 * a), k * x, k * y, k * z])
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a, with its Taylor series near 0.
    small = angle < _SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def quat_to_rotvec(q) -> np.ndarray:
    """Shortest rotation vector (angle in [0, pi]) of quaternion(s) q.

    Uses ``2 atan2(|v|, w)`` so it is accurate both near 0 and near pi.
    """
    q = quat_canonical(quat_normalize(q))
    if q.ndim == 1:  # scalar fast path
        w, x, y, z = q.tolist()
        s = math.sqrt(x * x + y * y + z * z)
        k = 2.0 / w if s < 1e-12 else 2.0 * math.atan2(s, w) / s
        return np.array([k * x, k * y, k * z])
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    w = q[..., :1]
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-12
    safe = np.where(small, 1.0, s)
    k = np.where(small, 2.0 / np.where(small, w, 1.0), angle / safe)
    return k * v


def rotvec_to_rotmat(phi) -> np.ndarray:
    """``exp([phi x])`` (Rodrigues formula, series near 0)."""
    phi = _as_array(phi)
    if phi.ndim == 1:  # scalar fast path
        x, y, z = phi.tolist()
        ang = math.sqrt(x * x + y * y + z * z)
        if ang < _SMALL_ANGLE:
            a, b = 1.0 - ang * ang / 6.0, 0.5 - ang * ang / 24.0
        else:
            a, b = math.sin(ang) / ang, (1.0 - math.cos(ang)) / (ang * ang)
        return np.array(
            [
                [1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z],
                [a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z],
                [-a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y)],
            ]
        )
    angle = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = angle < _SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(angle) / safe)
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(angle)) / safe**2)
    K = skew(phi)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def rotmat_to_rotvec(R) -> np.ndarray:
    """Rotation vector of rotation matrix(es), via the quaternion (accurate near pi)."""
    return quat_to_rotvec(rotmat_to_quat(R))


def quat_propagate(q, w, dt) -> np.ndarray:
    """Closed-form kinematics ``q(t+dt) = q(t) ⊗ exp(w dt / 2)`` for constant body rate w.

    ``q`` is ``q_IB`` and ``w`` is ``w_IB_B`` (rad/s).  Exact for constant ``w``.
    """
    return quat_multiply(q, rotvec_to_quat(_as_array(w) * dt))


def quat_error_rotvec(q_hat, q) -> np.ndarray:
    """Attitude error ``dtheta_B = log(q_hat^-1 ⊗ q)`` (true body relative to estimate)."""
    return quat_to_rotvec(quat_multiply(quat_conjugate(q_hat), q))


# ----------------------------------------------------------------------------------
# Modified Rodrigues parameters
# ----------------------------------------------------------------------------------
def quat_to_mrp(q) -> np.ndarray:
    """MRP ``q_vec / (1 + q_w)`` of the canonical (q_w >= 0) quaternion: |p| <= 1."""
    q = quat_canonical(quat_normalize(q))
    return q[..., 1:] / (1.0 + q[..., :1])


def mrp_to_quat(p) -> np.ndarray:
    """Quaternion of MRP(s) p (either set: p and its shadow give q and -q)."""
    p = _as_array(p)
    n2 = np.sum(p * p, axis=-1, keepdims=True)
    return np.concatenate([(1.0 - n2), 2.0 * p], axis=-1) / (1.0 + n2)


def mrp_shadow(p) -> np.ndarray:
    """Shadow MRP ``-p / |p|^2`` (same rotation)."""
    p = _as_array(p)
    return -p / np.sum(p * p, axis=-1, keepdims=True)


def mrp_switch(p) -> np.ndarray:
    """Map MRP(s) with ``|p| > 1`` to their shadow set so that ``|p| <= 1``."""
    p = _as_array(p)
    n2 = np.sum(p * p, axis=-1, keepdims=True)
    return np.where(n2 > 1.0, -p / np.where(n2 > 1.0, n2, 1.0), p)


def mrp_to_rotmat(p) -> np.ndarray:
    """Rotation matrix of MRP(s): ``I + (8 [p x]^2 + 4 (1 - p'p) [p x]) / (1 + p'p)^2``."""
    p = _as_array(p)
    n2 = np.sum(p * p, axis=-1)[..., None, None]
    K = skew(p)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + (8.0 * (K @ K) + 4.0 * (1.0 - n2) * K) / (1.0 + n2) ** 2


def mrp_kinematics_matrix(p) -> np.ndarray:
    """``B(p)`` with ``p_dot = B(p) w``: ``1/4 [(1 - p'p) I + 2 [p x] + 2 p p']``.

    Here ``p`` parameterizes ``q_IB`` and ``w`` is ``w_IB_B``.
    """
    p = _as_array(p)
    n2 = np.sum(p * p, axis=-1)[..., None, None]
    eye = np.broadcast_to(np.eye(3), p.shape[:-1] + (3, 3))
    return 0.25 * ((1.0 - n2) * eye + 2.0 * skew(p) + 2.0 * p[..., :, None] * p[..., None, :])


# ----------------------------------------------------------------------------------
# Generalized Rodrigues parameters
# ----------------------------------------------------------------------------------
def quat_to_grp(q, a: float = 1.0, f: float = 4.0) -> np.ndarray:
    """GRP ``f q_vec / (a + q_w)`` of the canonical quaternion (q_w >= 0)."""
    q = quat_canonical(quat_normalize(q))
    return f * q[..., 1:] / (a + q[..., :1])


def grp_to_quat(p, a: float = 1.0, f: float = 4.0) -> np.ndarray:
    """Quaternion (q_w >= 0 branch) of GRP(s) p, inverse of :func:`quat_to_grp`."""
    p = _as_array(p)
    n2 = np.sum(p * p, axis=-1, keepdims=True)
    w = (-a * n2 + f * np.sqrt(f * f + (1.0 - a * a) * n2)) / (f * f + n2)
    return np.concatenate([w, (a + w) * p / f], axis=-1)


# ----------------------------------------------------------------------------------
# Euler angles (roll-pitch-yaw, Drake's RollPitchYaw convention)
# ----------------------------------------------------------------------------------
def rpy_to_quat(rpy) -> np.ndarray:
    """Quaternion of roll-pitch-yaw angles (rad), ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Same convention as ``pydrake.math.RollPitchYaw`` (extrinsic x-y-z).
    """
    rpy = _as_array(rpy)
    hr, hp, hy = 0.5 * rpy[..., 0], 0.5 * rpy[..., 1], 0.5 * rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=-1,
    )


def quat_to_rpy(q) -> np.ndarray:
    """Roll-pitch-yaw angles (rad) of quaternion(s), inverse of :func:`rpy_to_quat`.

    Correct at and near gimbal lock (pitch = +-pi/2): pitch from ``atan2`` (not ``asin``, which
    loses half the digits there); yaw from the first column, or — when that column has no
    horizontal part left (|cos pitch| < 1e-12, where only yaw -+ roll is defined) — from the
    second with roll = 0; roll last, from the rotation with yaw and pitch removed, so the
    angles always reproduce the rotation (``rpy_to_quat(quat_to_rpy(q)) = +-q`` to round-off).
    """
    R = quat_to_rotmat(q)
    horizontal = np.hypot(R[..., 0, 0], R[..., 1, 0])  # |cos pitch|
    pitch = np.arctan2(-R[..., 2, 0], horizontal)
    locked = horizontal < 1e-12
    yaw = np.where(locked, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    sp, cp, sy, cy = np.sin(pitch), np.cos(pitch), np.sin(yaw), np.cos(yaw)
    # Third row of Ry(pitch)^T Rz(yaw)^T R = Rx(roll): [0, sin roll, cos roll].
    s_roll = sp * (cy * R[..., 0, 1] + sy * R[..., 1, 1]) + cp * R[..., 2, 1]
    c_roll = sp * (cy * R[..., 0, 2] + sy * R[..., 1, 2]) + cp * R[..., 2, 2]
    roll = np.arctan2(s_roll, c_roll)
    return np.stack([roll, pitch, yaw], axis=-1)


def rpy_rates_to_body_rate(rpy, rpy_dot) -> np.ndarray:
    """Body angular velocity ``w_IB_B`` from roll-pitch-yaw angles and their rates."""
    rpy = _as_array(rpy)
    rpy_dot = _as_array(rpy_dot)
    r, p = rpy[..., 0], rpy[..., 1]
    rd, pd, yd = rpy_dot[..., 0], rpy_dot[..., 1], rpy_dot[..., 2]
    sr, cr, sp, cp = np.sin(r), np.cos(r), np.sin(p), np.cos(p)
    return np.stack([rd - sp * yd, cr * pd + sr * cp * yd, -sr * pd + cr * cp * yd], axis=-1)
