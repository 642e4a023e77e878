"""The MEKF estimator's step as one compiled call (fewer Python crossings per step).

:meth:`drake_att.systems.estimator_system.EstimatorSystem._on_step` is the loop every core
runs: time update with the gyro's mean rate (held and counted when unusable, with the held
rate's drift variance), then the quaternion measurements of this instant in input order (time
tags: once each, late samples within the lag carried forward, later, future and vanished ones
counted; validity, the core's gate, the re-acquisition after
:data:`~drake_att.filters.gating.REACQUIRE_AFTER_REJECTIONS` rejections with the ungated
retry), the counters, the innovations, the step linearization and the packed estimate.
:func:`mekf_steps` is that loop for a :class:`~drake_att.filters.mekf.MultiplicativeEKF` with
quaternion inputs only and no sensor monitor (verdicts take the Python loop), in one numba
call writing the state groups in place, for one realization or for the N of a batch diagram
(the same per-realization code). It has no rules or arithmetic of its own: the loop's
rules are the functions of :mod:`drake_att.systems.estimator_step`,
:mod:`drake_att.filters.gating` and :mod:`drake_att.contract` compiled here
(``register_jitable``), and the filter arithmetic is :mod:`drake_att.filters.mekf_kernels`,
which the core itself runs. ``tests/test_compiled_step.py`` runs both loops on the same inputs,
every branch, and asserts equal state to 1e-12 relative.

Numba's on-disk cache is keyed on this file: after editing a rule or a kernel in another
module, delete ``drake_att/systems/__pycache__/compiled_step*.nb*`` (a fresh install has none).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from drake_att import contract
from drake_att import rotations as rot
from drake_att.contract import STATUS, STATUS_LAST_NIS, STATUS_SKIPPED, STATUS_USED
from drake_att.filters import gating
from drake_att.filters import mekf_kernels as _mekf
from drake_att.filters.compiled import jit as _jit
from drake_att.systems import estimator_step as rules
from drake_att.systems.estimator_step import TIME_TOLERANCE_S, Bookkeeping

for _rule in (
    rules.rate_usable,
    rules.gyro_sample_usable,
    rules.tag_disposition,
    rules.pending_vanished,
    rules.held_rate_variance,
    rules.late_sample_variance,
    rules.carried_quaternion,
    rules.covariance_slot,
    rules.is_gate_rejection,
    gating.inflation_factor,
    gating.capped_factor,
    gating.inflate_attitude_block,
    contract.quaternion_usable,
    contract.flag_is_true,
):
    register_jitable(_rule)  # the Python function stays as it is; compiled code may call it


class StepModel(NamedTuple):
    """Array form of one :class:`~drake_att.systems.estimator_system.FilterModel` and the
    system's layout, for :func:`mekf_steps` (built once per model).

    Attributes:
        q_BS: (n, 4) sensor mountings. R_SB: (n, 3, 3) their rotations (sensor <- body).
        covariance: (n, F, 3, 3) measurement covariance per sensor and
            :func:`~drake_att.systems.estimator_step.covariance_slot` (slot 0: the sensor's
            ``covariance_S``). allowed: (n, F) whether that slot is a usable subset.
            n_subsets: (n,) ``len(covariance_by_flag)`` per sensor.
        threshold: the gate's NIS threshold for 3 degrees of freedom (inf: no gate).
        arw, rrw: the core's gyro model (process noise).
        tolerance, reacquire_after: the loop's time tolerance and re-acquisition count.
        period: the estimator's period (s). lag: the model's ``max_time_tag_lag_s`` (s).
        held_q: the held-rate walk's intensity ``held_rate_rrw_rad_per_s15^2`` (rad^2/s^3).
        last_sample, pending, rejections: offsets of the per-input entries in the bookkeeping
            group.
    """

    q_BS: np.ndarray
    R_SB: np.ndarray
    covariance: np.ndarray
    allowed: np.ndarray
    n_subsets: np.ndarray
    threshold: float
    arw: float
    rrw: float
    tolerance: float
    reacquire_after: float
    period: float
    lag: float
    held_q: float
    last_sample: int
    pending: int
    rejections: int

    @classmethod
    def of(
        cls,
        core,
        quaternion_sensors,
        bookkeeping: Bookkeeping,
        period_s: float,
        max_time_tag_lag_s: float = 0.0,
        held_rate_rrw_rad_per_s15: float = 0.0,
    ) -> StepModel:
        n = len(quaternion_sensors)
        F = max([1] + [len(s.covariance_by_flag) for s in quaternion_sensors])
        q_BS = np.zeros((n, 4))
        R_SB = np.zeros((n, 3, 3))
        cov = np.zeros((n, F, 3, 3))
        allowed = np.zeros((n, F), dtype=np.bool_)
        n_subsets = np.zeros(n, dtype=np.int64)
        for i, s in enumerate(quaternion_sensors):
            q_BS[i] = np.asarray(s.q_BS, dtype=float)
            R_SB[i] = rot.quat_to_rotmat(q_BS[i]).T
            cov[i, 0] = _as_covariance(s.covariance_S)
            allowed[i, 0] = True
            n_subsets[i] = len(s.covariance_by_flag)
            for mask in range(1, len(s.covariance_by_flag)):
                c = s.covariance_by_flag[mask]
                if c is not None:
                    cov[i, mask] = _as_covariance(c)
                    allowed[i, mask] = True
        return cls(
            q_BS,
            R_SB,
            cov,
            allowed,
            n_subsets,
            float(core.gate.threshold(3)),
            float(core.arw),
            float(core.rrw),
            TIME_TOLERANCE_S,
            float(gating.REACQUIRE_AFTER_REJECTIONS),
            float(period_s),
            float(max_time_tag_lag_s),
            float(held_rate_rrw_rad_per_s15) ** 2,
            Bookkeeping.LAST_SAMPLE,
            bookkeeping.pending,
            bookkeeping.rejections,
        )


def _as_covariance(noise_S) -> np.ndarray:
    """A sensor's noise as the MEKF reads it: a 3x3 covariance, or per-axis sigmas (3,)."""
    noise_S = np.asarray(noise_S, dtype=float)
    return noise_S if noise_S.shape == (3, 3) else np.diag(noise_S**2)


def eligible(core, vector_inputs: int, is_random: bool) -> bool:
    """Whether :func:`mekf_steps` runs this core: an MEKF whose step is the kernels' (its
    :meth:`~drake_att.filters.mekf.MultiplicativeEKF.runs_kernel_step`), quaternion inputs
    only, not random (everything else takes the Python loop)."""
    from drake_att.filters.mekf import MultiplicativeEKF

    return isinstance(core, MultiplicativeEKF) and core.runs_kernel_step() and vector_inputs == 0 and not is_random


_USED, _SKIPPED, _LAST_NIS = STATUS.start + STATUS_USED, STATUS.start + STATUS_SKIPPED, STATUS.start + STATUS_LAST_NIS
_T_LAST, _W_LAST, _T_GYRO_GOOD = Bookkeeping.T_LAST, Bookkeeping.W_LAST.start, Bookkeeping.T_GYRO_GOOD


@_jit(inline="always")
def _time_update(t, gyro_connected, gyro, book, model, q, b, P, Phi, Q):
    """Propagate ``(q, P)`` over ``(t_last, t]`` (in place; ``Phi``/``Q`` written), holding
    the last valid rate when the gyro sample is unusable, with the held-rate drift's attitude
    variance in ``Q``. Returns the skipped count (0 or 1)."""
    skipped = 0.0
    t_last = book[_T_LAST]
    if math.isfinite(t_last):
        usable = gyro_connected and rules.gyro_sample_usable(
            t, model.tolerance, gyro[0], gyro[1], gyro[2], gyro[3], gyro[4]
        )
        if usable:
            for k in range(3):
                book[_W_LAST + k] = gyro[2 + k]
            book[_T_GYRO_GOOD] = t
        else:
            skipped = 1.0
        dt = t - t_last
        if dt > 0.0:
            w_hat = np.empty(3)
            for k in range(3):
                w_hat[k] = book[_W_LAST + k] - b[k]
            _mekf.process_noise(model.arw, model.rrw, dt, Q)
            if not usable and model.held_q > 0.0:
                variance = rules.held_rate_variance(model.held_q, t_last - book[_T_GYRO_GOOD], dt)
                for k in range(3):
                    Q[k, k] += variance
            q_new = np.empty(4)
            P_new = np.empty((6, 6))
            _mekf.predict(q, P, w_hat, w_hat * dt, dt, Q, q_new, P_new, Phi)
            q[:] = q_new
            P[:, :] = P_new
    else:
        book[_T_GYRO_GOOD] = t
        if gyro_connected and rules.rate_usable(gyro[1], gyro[2], gyro[3], gyro[4]):
            for k in range(3):
                book[_W_LAST + k] = gyro[2 + k]
    book[_T_LAST] = t
    return skipped


@_jit(inline="always")
def _update_input(i, t, meas_i, model, book, handling, q, b, P, q_out, b_out, P_out, z, S, I_KH):
    """One quaternion input's update at ``t`` (in place on ``q, b, P`` when accepted; ``I_KH``
    written; a late sample carried forward, counted in ``handling``). Returns ``(outcome,
    nis, counted)``: outcome -1 for a sample passed over or skipped before the core sees it
    (``counted``: whether it counts as skipped), else the kernel's outcome after any
    re-acquisition."""
    t_meas = meas_i[0]
    disposition = rules.tag_disposition(
        t_meas, t, model.tolerance, book[model.last_sample + i], model.lag, model.period
    )
    if disposition == rules.NO_TIME:
        return -1, math.nan, True
    if disposition == rules.NOT_DUE:
        return -1, math.nan, False
    if disposition == rules.FUTURE:
        book[model.pending + i] = t_meas
        return -1, math.nan, False
    book[model.last_sample + i] = t_meas
    if disposition == rules.TOO_LATE or disposition == rules.TOO_EARLY:
        handling[rules.N_TAG_REJECTED] += 1.0
        return -1, math.nan, True
    flag = meas_i[1]
    slot = rules.covariance_slot(flag, model.n_subsets[i])
    if slot > 0 and not model.allowed[i, slot]:
        slot = -1
    usable = contract.quaternion_usable(meas_i[2], meas_i[3], meas_i[4], meas_i[5])
    if not contract.flag_is_true(flag) or slot < 0 or not usable:
        return -1, math.nan, True
    q_meas = meas_i[2:6].copy()
    R = model.covariance[i, slot].copy()
    if disposition == rules.LATE:
        # Carried forward with the step's rate (EstimatorSystem._carried_forward).
        gap = t - t_meas
        wx, wy, wz = book[_W_LAST] - b[0], book[_W_LAST + 1] - b[1], book[_W_LAST + 2] - b[2]
        rate_variance = max(P[3, 3], max(P[4, 4], P[5, 5])) + max(t - book[_T_GYRO_GOOD], 0.0) * model.held_q
        extra = rules.late_sample_variance(rate_variance, gap)
        q_meas[0], q_meas[1], q_meas[2], q_meas[3] = rules.carried_quaternion(
            meas_i[2:6], model.q_BS[i], wx, wy, wz, gap
        )
        for k in range(3):
            R[k, k] += extra
        handling[rules.N_LATE] += 1.0
    outcome, nis = _mekf.update_quaternion(
        q, b, P, q_meas, model.q_BS[i], model.R_SB[i], R, model.threshold, q_out, b_out, P_out, z, S, I_KH
    )
    count = model.rejections + i
    if outcome == _mekf.ACCEPTED:
        book[count] = 0.0
    elif rules.is_gate_rejection(False, nis):
        book[count] += 1.0
        if book[count] >= model.reacquire_after:
            book[count] = 0.0
            # The core's reacquire (gating.inflated), then the same measurement without the gate.
            P_try = gating.inflate_attitude_block(P, gating.inflation_factor(nis, model.threshold), 3, math.pi)
            outcome, nis = _mekf.update_quaternion(
                q, b, P_try, q_meas, model.q_BS[i], model.R_SB[i], R, math.inf, q_out, b_out, P_out, z, S, I_KH
            )
            if outcome != _mekf.ACCEPTED:
                P[:, :] = P_try  # the reacquired state is kept even when the retry fails
    if outcome == _mekf.ACCEPTED:
        q[:] = q_out
        b[:] = b_out
        P[:, :] = P_out
    return outcome, nis, outcome != _mekf.ACCEPTED


@_jit
def mekf_steps(
    t,
    gyro_connected,
    gyro,
    connected,
    meas,
    q_BS,
    R_SB,
    covariance,
    allowed,
    n_subsets,
    threshold,
    arw,
    rrw,
    tolerance,
    reacquire_after,
    period,
    lag,
    held_q,
    last_sample,
    pending,
    rejections,
    handling,
    est,
    book,
    core,
    lin,
    innov,
):
    """One filter step at time ``t`` of an MEKF estimator carrying N realizations (N = 1: a
    run alone), in place on its state groups.

    ``handling`` (the sample-handling counters), ``est`` (47 per realization), ``book``,
    ``core`` (43), ``lin`` (109) and ``innov`` (3 n) are the estimator's discrete-state groups
    as the system holds them (pre-set to the current values; N blocks each, realization-major);
    ``gyro`` (5 N) and ``meas`` (n, 6 N) the input ports' values, one row per quaternion input
    (``gyro_connected``/``connected``: whether the port has a value, shared by the
    realizations); ``q_BS`` to ``rejections`` the fields of the :class:`StepModel`, in its
    order (``mekf_steps(t, ..., meas, *model, handling, est, ...)``): numba unboxes a tuple
    argument ~1.3 us slower than its fields. Realization ``r`` is :func:`_mekf_step` on its
    blocks, exactly as a run alone."""
    model = StepModel(
        q_BS,
        R_SB,
        covariance,
        allowed,
        n_subsets,
        threshold,
        arw,
        rrw,
        tolerance,
        reacquire_after,
        period,
        lag,
        held_q,
        last_sample,
        pending,
        rejections,
    )
    E, G, M = contract.ESTIMATE_SIZE, contract.GYRO_MEASUREMENT_SIZE, contract.QUATERNION_MEASUREMENT_SIZE
    N = est.shape[0] // E
    H, B, C, L, V = (
        handling.shape[0] // N,
        book.shape[0] // N,
        core.shape[0] // N,
        lin.shape[0] // N,
        innov.shape[0] // N,
    )
    for r in range(N):
        _mekf_step(
            t,
            gyro_connected,
            gyro[G * r : G * r + G],
            connected,
            meas[:, M * r : M * r + M],
            model,
            handling[H * r : H * r + H],
            est[E * r : E * r + E],
            book[B * r : B * r + B],
            core[C * r : C * r + C],
            lin[L * r : L * r + L],
            innov[V * r : V * r + V],
        )


@_jit
def _mekf_step(t, gyro_connected, gyro, connected, meas, model, handling, est, book, core, lin, innov):
    """One realization's step: ``gyro`` (5), ``meas`` (n, 6) and the state groups' blocks of
    :func:`mekf_steps`, written in place."""
    q, b, P = _read_core(core)
    Phi, Q, A = np.eye(6), np.zeros((6, 6)), np.eye(6)
    n_skipped = est[_SKIPPED] + _time_update(t, gyro_connected, gyro, book, model, q, b, P, Phi, Q)
    n_used, nis = est[_USED], est[_LAST_NIS]
    q_out, b_out, P_out = np.empty(4), np.empty(3), np.empty((6, 6))
    z, S, I_KH = np.empty(3), np.empty((3, 3)), np.empty((6, 6))
    first = True
    for i in range(meas.shape[0]):
        if not connected[i]:
            continue
        if rules.pending_vanished(book[model.pending + i], book[model.last_sample + i], meas[i, 0]):
            n_skipped += 1.0  # a future-tagged sample that left the port unused
            handling[rules.N_TAG_REJECTED] += 1.0
            book[model.pending + i] = -math.inf
        outcome, info_nis, counted = _update_input(
            i, t, meas[i], model, book, handling, q, b, P, q_out, b_out, P_out, z, S, I_KH
        )
        if outcome < 0:
            n_skipped += 1.0 if counted else 0.0
            continue
        nis = info_nis
        innov[3 * i], innov[3 * i + 1], innov[3 * i + 2] = t, nis, 3.0
        if outcome == _mekf.ACCEPTED:
            n_used += 1.0
            if first:
                A[:, :] = I_KH
            else:
                _mekf.matmul66(I_KH, A.copy(), A)
            first = False
        else:
            n_skipped += 1.0
    est[STATUS.start], est[_USED], est[_SKIPPED], est[_LAST_NIS] = t, n_used, n_skipped, nis
    _write_state(q, b, P, Phi, Q, A, est, core, lin)


@_jit(inline="always")  # compiled into _mekf_step: no call, no reference counts
def _read_core(core):
    """``(q, b, P)`` of the MEKF's state vector ``[q_IB (4), bias_B (3), P (36)]`` (copies)."""
    q, b, P = np.empty(4), np.empty(3), np.empty((6, 6))
    for k in range(4):
        q[k] = core[k]
    for k in range(3):
        b[k] = core[4 + k]
    for r in range(6):
        for c in range(6):
            P[r, c] = core[7 + 6 * r + c]
    return q, b, P


@_jit(inline="always")
def _write_state(q, b, P, Phi, Q, A, est, core, lin):
    """The step's estimate (``q`` sign-canonical, as ``rotations.quat_canonical``) into the
    estimate and core groups, and its linearization ``[Phi, Q, A, steps + 1]`` into ``lin``."""
    sign = -1.0 if q[0] < 0.0 else 1.0
    for k in range(4):
        est[k] = core[k] = sign * q[k]
    for k in range(3):
        est[4 + k] = core[4 + k] = b[k]
    est[7:43] = P.reshape(36)  # views: no copies
    core[7:43] = P.reshape(36)
    lin[0:36] = Phi.reshape(36)
    lin[36:72] = Q.reshape(36)
    lin[72:108] = A.reshape(36)
    lin[108] += 1.0


def warm_up() -> None:
    """Compile (or load from the cache) :func:`mekf_steps` now."""
    from drake_att.filters.mekf import MultiplicativeEKF
    from drake_att.systems.estimator_system import QuaternionSensorModel

    sensor = QuaternionSensorModel("warm_up", np.array([1.0, 0, 0, 0]), np.eye(3))
    model = StepModel.of(MultiplicativeEKF(0.0, 0.0), [sensor], Bookkeeping(1), 1.0)
    mekf_steps(
        0.0,
        True,
        np.zeros(5),
        np.ones(1, dtype=np.bool_),
        np.zeros((1, 6)),
        *model,
        np.zeros(len(rules.SAMPLE_HANDLING_NAMES)),
        np.zeros(47),
        Bookkeeping(1).initial(None),
        np.r_[1.0, np.zeros(42)],
        np.zeros(109),
        np.zeros(3),
    )


__all__ = ["StepModel", "eligible", "mekf_steps", "warm_up"]
