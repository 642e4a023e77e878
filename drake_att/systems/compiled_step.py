"""The estimator loop's step for the MEKF as one compiled call (issue 13: fewer Python crossings).

:meth:`drake_att.systems.estimator_system.EstimatorSystem._on_step` is the loop's specification:
time update with the gyro's mean rate (held and counted when unusable), then the quaternion
measurements of this instant in input order (once each, validity, the core's gate, the
re-acquisition after :data:`~drake_att.filters.gating.REACQUIRE_AFTER_REJECTIONS`
rejections with the ungated retry), the counters, the innovations, the step linearization and
the packed estimate. :func:`mekf_step` does exactly that for a
:class:`~drake_att.filters.mekf.MultiplicativeEKF` (compiled kernels, no coning correction)
with quaternion sensors only, writing the estimator's discrete-state groups in place, so a
filter step costs one Python event, the input port reads and one compiled call instead of
~40 Python-level operations. ``tests/test_compiled_step.py`` runs both on the same inputs,
all branches included, and asserts equal state to 1e-12 relative (the compiled kernels'
round-off).

:class:`CompiledStepModel` holds the per-``FilterModel`` constants (sensor mountings,
covariances per validity flag, the gate threshold, the gyro noise) in arrays, built once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.filters import mekf_kernels as _mekf
from drake_att.filters.compiled import jit as _jit
from drake_att.filters.gating import REACQUIRE_AFTER_REJECTIONS


@dataclass(frozen=True)
class CompiledStepModel:
    """Array form of one :class:`~drake_att.systems.estimator_system.FilterModel` for :func:`mekf_step`.

    Attributes:
        q_BS: (n, 4) sensor mountings. R_SB: (n, 3, 3) their rotations (sensor <- body).
        covariance: (n, F, 3, 3) measurement covariance per sensor and validity-flag mask
            (slot 0: the sensor's own ``covariance_S``; slot ``mask``: the subset's, for a
            sensor with ``covariance_by_flag``). allowed: (n, F) whether that slot is a usable
            subset. n_masks: (n,) 0 for a sensor without flag-dependent covariances, else
            ``len(covariance_by_flag)``.
        threshold: the gate's NIS threshold for 3 degrees of freedom (inf: no gate).
        arw, rrw: the core's gyro model (process noise).
    """

    q_BS: np.ndarray
    R_SB: np.ndarray
    covariance: np.ndarray
    allowed: np.ndarray
    n_masks: np.ndarray
    threshold: float
    arw: float
    rrw: float

    @classmethod
    def of(cls, core, quaternion_sensors) -> CompiledStepModel:
        n = len(quaternion_sensors)
        F = max([1] + [len(s.covariance_by_flag) for s in quaternion_sensors])
        q_BS = np.zeros((n, 4))
        R_SB = np.zeros((n, 3, 3))
        cov = np.zeros((n, F, 3, 3))
        allowed = np.zeros((n, F), dtype=np.bool_)
        n_masks = np.zeros(n, dtype=np.int64)
        for i, s in enumerate(quaternion_sensors):
            q_BS[i] = np.asarray(s.q_BS, dtype=float)
            R_SB[i] = rot.quat_to_rotmat(q_BS[i]).T
            cov[i, 0] = _as_covariance(s.covariance_S)
            allowed[i, 0] = True
            n_masks[i] = len(s.covariance_by_flag)
            for mask in range(1, len(s.covariance_by_flag)):
                c = s.covariance_by_flag[mask]
                if c is not None:
                    cov[i, mask] = _as_covariance(c)
                    allowed[i, mask] = True
        return cls(q_BS, R_SB, cov, allowed, n_masks, float(core.gate.threshold(3)), float(core.arw),
                   float(core.rrw))


def _as_covariance(noise_S) -> np.ndarray:
    """A sensor's noise as the MEKF reads it: a 3x3 covariance, or per-axis sigmas (3,)."""
    noise_S = np.asarray(noise_S, dtype=float)
    return noise_S if noise_S.shape == (3, 3) else np.diag(noise_S**2)


def eligible(core, vector_inputs: int, is_random: bool) -> bool:
    """Whether :func:`mekf_step` runs this core: a compiled-kernel MEKF without the coning
    correction, quaternion inputs only, not random (everything else takes the Python loop)."""
    from drake_att.filters.mekf import MultiplicativeEKF

    return (type(core) is MultiplicativeEKF and core.kernel == "numba" and not core.coning_correction
            and vector_inputs == 0 and not is_random)


@_jit
def _covariance_for_flag(model_cov, allowed, n_masks, i, flag):
    """Slot of ``covariance_for_flag`` for input ``i`` (-1: no usable subset)."""
    if n_masks[i] == 0 or not flag > 1.5:
        return 0
    if not math.isfinite(flag):
        return -1
    mask = int(round(flag)) - 1
    if 0 < mask < n_masks[i] and allowed[i, mask]:
        return mask
    return -1


@_jit
def _process_noise(arw, rrw, dt, Q):
    """``drake_att.filters.mekf.process_noise`` into ``Q``."""
    sv2, su2 = arw * arw, rrw * rrw
    a = sv2 * dt + su2 * dt ** 3 / 3.0
    c = -su2 * dt ** 2 / 2.0
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
def _matmul6(X, Y):
    """``X @ Y`` of 6x6 matrices (numba's ``@`` needs SciPy's BLAS)."""
    out = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for m in range(6):
                acc += X[i, m] * Y[m, j]
            out[i, j] = acc
    return out


@_jit
def _canonical_into(q, out, offset):
    s = -1.0 if q[0] < 0.0 else 1.0
    for k in range(4):
        out[offset + k] = s * q[k]


@_jit
def mekf_step(t, tolerance, gyro_connected, gyro, connected, meas, q_BS, R_SB, cov, allowed, n_masks,
              threshold, arw, rrw, reacquire_after, last_sample, rejections, est, book, core, lin, innov):
    """One filter step of an MEKF estimator at time ``t``, in place on its state groups.

    ``est`` (47), ``book``, ``core`` (43), ``lin`` (109) and ``innov`` (3 n) are the
    estimator's discrete-state groups (pre-set to the current values); ``gyro`` (5) and
    ``meas`` (n, 6) the input ports' values (``gyro_connected``/``connected``: whether the
    port has a value). ``last_sample``/``rejections``: offsets of the per-input entries in
    ``book``. Same semantics as ``EstimatorSystem._on_step`` (its docstring)."""
    n_used, n_skipped, nis = est[44], est[45], est[46]
    q = np.empty(4)
    b = np.empty(3)
    P = np.empty((6, 6))
    for k in range(4):
        q[k] = core[k]
    for k in range(3):
        b[k] = core[4 + k]
    for i in range(6):
        for j in range(6):
            P[i, j] = core[7 + 6 * i + j]
    Phi = np.eye(6)
    Q = np.zeros((6, 6))
    A = np.eye(6)
    A_set = False
    t_last = book[0]
    if math.isfinite(t_last):
        usable = False
        if gyro_connected:
            tg, valid = gyro[0], gyro[1]
            usable = (abs(tg - t) < tolerance and valid > 0.5 and math.isfinite(valid) and math.isfinite(gyro[2])
                      and math.isfinite(gyro[3]) and math.isfinite(gyro[4]))
        if usable:
            w0, w1, w2 = gyro[2], gyro[3], gyro[4]
            book[1], book[2], book[3] = w0, w1, w2
        else:
            n_skipped += 1.0
            w0, w1, w2 = book[1], book[2], book[3]
        dt = t - t_last
        if dt > 0.0:
            w_hat = np.empty(3)
            w_hat[0], w_hat[1], w_hat[2] = w0 - b[0], w1 - b[1], w2 - b[2]
            phi = np.empty(3)
            phi[0], phi[1], phi[2] = w_hat[0] * dt, w_hat[1] * dt, w_hat[2] * dt
            _process_noise(arw, rrw, dt, Q)
            q_new = np.empty(4)
            P_new = np.empty((6, 6))
            _mekf.predict(q, P, w_hat, phi, dt, Q, q_new, P_new, Phi)
            q, P = q_new, P_new
    elif gyro_connected:
        valid = gyro[1]
        if (valid > 0.5 and math.isfinite(valid) and math.isfinite(gyro[2]) and math.isfinite(gyro[3])
                and math.isfinite(gyro[4])):
            book[1], book[2], book[3] = gyro[2], gyro[3], gyro[4]
    book[0] = t

    q_out = np.empty(4)
    b_out = np.empty(3)
    P_out = np.empty((6, 6))
    z = np.empty(3)
    S = np.empty((3, 3))
    I_KH = np.empty((6, 6))
    P_try = np.empty((6, 6))
    for i in range(meas.shape[0]):
        if not connected[i]:
            continue
        t_meas = meas[i, 0]
        if not math.isfinite(t_meas):
            n_skipped += 1.0
            continue
        if abs(t_meas - t) >= tolerance or t_meas <= book[last_sample + i]:
            continue
        book[last_sample + i] = t_meas
        flag = meas[i, 1]
        slot = _covariance_for_flag(cov, allowed, n_masks, i, flag)
        q0, q1, q2, q3 = meas[i, 2], meas[i, 3], meas[i, 4], meas[i, 5]
        if (not (flag > 0.5 and math.isfinite(flag)) or slot < 0 or not math.isfinite(q0) or not math.isfinite(q1)
                or not math.isfinite(q2) or not math.isfinite(q3) or q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3 < 0.25):
            n_skipped += 1.0
            continue
        q_meas = meas[i, 2:6].copy()
        R = cov[i, slot].copy()
        outcome, info_nis = _mekf.update_quaternion(q, b, P, q_meas, q_BS[i], R_SB[i], R, threshold, q_out, b_out,
                                                    P_out, z, S, I_KH)
        if outcome == _mekf.ACCEPTED:
            book[rejections + i] = 0.0
        elif info_nis == info_nis:  # a gate rejection (finite NIS): re-acquisition count
            book[rejections + i] += 1.0
            if book[rejections + i] >= reacquire_after:
                book[rejections + i] = 0.0
                # The core's reacquire: the attitude block inflated so the rejected NIS sits
                # at half the gate (at least 2x; attitude sigmas capped at pi), then the same
                # measurement once more without the gate.
                factor = 2.0
                if math.isfinite(threshold):
                    factor = max(2.0, 2.0 * (info_nis if math.isfinite(info_nis) else 0.0) / threshold)
                largest = max(P[0, 0], max(P[1, 1], P[2, 2]))
                if largest > 0.0:
                    factor = min(factor, max(1.0, math.pi ** 2 / largest))
                for r in range(6):
                    for c in range(6):
                        P_try[r, c] = P[r, c]
                for r in range(3):
                    for c in range(3):
                        P_try[r, c] = P[r, c] + (factor - 1.0) * P[r, c]
                outcome, info_nis = _mekf.update_quaternion(q, b, P_try, q_meas, q_BS[i], R_SB[i], R, math.inf,
                                                            q_out, b_out, P_out, z, S, I_KH)
                if outcome != _mekf.ACCEPTED:
                    P = P_try.copy()  # the reacquired state is kept even when the retry fails
        nis = info_nis
        innov[3 * i], innov[3 * i + 1], innov[3 * i + 2] = t, nis, 3.0
        if outcome == _mekf.ACCEPTED:
            q, b, P = q_out.copy(), b_out.copy(), P_out.copy()
            n_used += 1.0
            if not A_set:
                A = I_KH.copy()
                A_set = True
            else:
                A = _matmul6(I_KH, A)
        else:
            n_skipped += 1.0

    _canonical_into(q, est, 0)
    _canonical_into(q, core, 0)
    for k in range(3):
        est[4 + k] = b[k]
        core[4 + k] = b[k]
    for i in range(6):
        for j in range(6):
            est[7 + 6 * i + j] = P[i, j]
            core[7 + 6 * i + j] = P[i, j]
    est[43], est[44], est[45], est[46] = t, n_used, n_skipped, nis
    for i in range(6):
        for j in range(6):
            lin[6 * i + j] = Phi[i, j]
            lin[36 + 6 * i + j] = Q[i, j]
            lin[72 + 6 * i + j] = A[i, j]
    lin[108] += 1.0


def warm_up() -> None:
    """Compile (or load from the cache) :func:`mekf_step` now."""
    n = 1
    mekf_step(0.0, 1e-6, True, np.zeros(5), np.ones(n, dtype=np.bool_), np.zeros((n, 6)), np.zeros((n, 4)),
              np.zeros((n, 3, 3)), np.zeros((n, 1, 3, 3)), np.ones((n, 1), dtype=np.bool_), np.zeros(n, dtype=np.int64),
              math.inf, 0.0, 0.0, float(REACQUIRE_AFTER_REJECTIONS), 13, 14, np.zeros(47), np.full(15, -np.inf),
              np.r_[1.0, np.zeros(42)], np.zeros(109), np.zeros(3))


__all__ = ["CompiledStepModel", "eligible", "mekf_step", "warm_up"]
