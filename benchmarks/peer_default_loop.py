#!/usr/bin/env python3
"""A plain-numpy peer of drake_att's default scenario ``cubesat_dual_star_tracker`` (no Drake).

One hand-written loop with the models of ``drake_att/scenarios/cubesat_dual_star_tracker.yaml``
(paper S3, dual star tracker), to benchmark the library against (``benchmarks/bench_peer.py
--case default``). It reuses the helpers of ``peer_numpy_loop.py`` (quaternions, the truth's
right-hand side and RK3 step, the MEKF's closed-form ``Phi`` and Farrenkopf ``Q``, the gate's
chi-square quantile) and drake_att's plain-numpy ``average_two_quaternions`` (the closed-form
average of two quaternions: what a numpy user would import):

* truth: rigid body + kinematics + rate integral, fixed-step RK3 (Kutta) at 0.1 s, as in
  ``peer_numpy_loop.py`` (the two YAMLs share the plant, the orbit and the gyro);
* gyro at 1 s: Farrenkopf model, interval-mean rate with the exact discrete statistics
  (ARW 0.56 deg/rt-h, RRW 123.75 deg/h^1.5, initial bias 12 deg/h per axis);
* two star trackers at 10 Hz: ``q_IS_meas = q_IB ⊗ q_BS,i ⊗ exp(delta_S)``,
  ``delta_S ~ N(0, diag(5", 5", 50")^2)``, mountings of paper eq. 7 (``st1`` (-90, 45, -90) deg,
  ``st2`` (90, 45, 90) deg);
* four MEKFs at 1 Hz (time update with the gyro, then the updates of this instant; Joseph form;
  the library's default innovation gate, chi-square 3 dof at 0.99999, rejections counted):
  ``single`` (st1), ``single_st2`` (st2), ``centralized`` (the average of both trackers' body
  attitudes ``q_IS,i ⊗ q_BS,i^-1`` with weights 1/2, ``H = [I, 0]`` and the derived covariance
  ``R_avg,B = sum_i w_i^2 R_BS,i diag(sigma_S^2) R_BS,i'``: ``drake_att/systems/fusion.py``'s
  ``StarTrackerAverage``), ``joint`` (the st1 update, then the st2 update);
* ``decentralized`` fusion of ``single`` and ``single_st2`` (``EstimateFusion``, "tracked"):
  quaternion average (weights 1/2), mean bias, and the covariance
  ``1/4 P_1 + 1/4 P_2 + 1/4 (P_12 + P_12')`` with the cross-covariance of the two MEKFs that
  share the gyro, ``P_12 <- A_1 (Phi_1 P_12 Phi_2' + Q) A_2'`` (``A`` = the step's ``I - K H``),
  ``P_12 = P_0`` at the start.

The loop keeps the run's records as drake_att's ``RunLog`` does (truth at 10 Hz, both trackers'
samples at 10 Hz, the gyro at 1 Hz, each estimator's attitude, bias and covariance at 1 Hz), in
preallocated arrays; the attitude RMSEs are computed from them after the timed part, as
``drake_att.analysis.metrics`` does (error ``log(q_hat^-1 ⊗ q)``, estimates at ``t >= score_from_s``).
The random numbers are this file's own (``numpy.random.default_rng(seed)``): the same
statistics as drake_att's, not the same realization.

    python benchmarks/peer_default_loop.py [--duration 5000] [--seed 1]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

# The S3 numbers and helpers (the two YAMLs share the plant, the orbit, the gyro and st1).
from peer_numpy_loop import (
    ARCSEC,
    ARW,
    DEG,
    DEG_PER_H,
    EST_BIAS0,
    EST_RPY_DEG,
    GATE_PROBABILITY,
    GYRO_BIAS0,
    INITIAL_RATE_DEG_S,
    INITIAL_RPY_DEG,
    P0_ATT_SIGMA,
    P0_BIAS_SIGMA,
    RRW,
    chi2_3dof_quantile,
    lvlh_q_IO0,
    mounting_q_BS,
    process_noise,
    qconj,
    qexp,
    qlog,
    qmul,
    qrot,
    rk3_step,
    rpy_quat,
    transition,
)

# drake_att's plain-numpy pieces (no Drake): the closed-form average of two quaternions, and the
# attitude error of the scoring (after the timed loop).
from drake_att.filters.quaternion_average import average_two_quaternions
from drake_att.rotations import quat_error_rotvec

# --- Numbers from drake_att/scenarios/cubesat_dual_star_tracker.yaml (hard-coded) -------------
TRUTH_STEP_S = 0.1  # simulation.max_step_size_s (RK3, no error control) = the trackers' period
TRACKER_PERIOD_S = 0.1  # sensors.st1/st2.period_s
GYRO_PERIOD_S = 1.0  # sensors.gyro.period_s = estimators.*.period_s
ST1_PSI_PHI_THETA_DEG = (-90.0, 45.0, -90.0)
ST2_PSI_PHI_THETA_DEG = (90.0, 45.0, 90.0)
ST_SIGMA_CROSS, ST_SIGMA_BORE = 5.0 * ARCSEC, 50.0 * ARCSEC  # both trackers
AVERAGE_WEIGHTS = (0.5, 0.5)  # sensors.st_avg.weights
FUSION_WEIGHTS = (0.5, 0.5)  # estimators.decentralized.weights
SCORE_FROM_S = 500.0  # scoring.score_from_s
ESTIMATORS = ("single", "centralized", "single_st2", "joint", "decentralized")  # the YAML's order
MEKFS = ("single", "centralized", "single_st2", "joint")


def farrenkopf_factors(arw: float, rrw: float, T: float) -> tuple[float, float, float]:
    """``(l11, l21, l22)``: the Cholesky factor of the covariance of ``(e, b_{k+1} - b_k)`` per
    axis for a gyro delivering its mean rate over ``T``: ``[[sv^2/T + su^2 T/3, su^2 T/2],
    [su^2 T/2, su^2 T]]`` (as ``peer_numpy_loop.run``)."""
    var_e, cov_ed, var_d = arw**2 / T + rrw**2 * T / 3, rrw**2 * T / 2, rrw**2 * T
    l11 = math.sqrt(var_e)
    l21 = cov_ed / l11
    return l11, l21, math.sqrt(max(var_d - l21 * l21, 0.0))


def mekf_predict(q, b, P, w_meas, T, Q):
    """MEKF time update over ``T`` with the interval's mean rate: ``(q, P, Phi)``."""
    w_hat = w_meas - b
    q = qmul(q, qexp(w_hat * T))
    q /= math.sqrt(q @ q)
    Phi = transition(w_hat, T)
    P = Phi @ P @ Phi.T + Q
    return q, 0.5 * (P + P.T), Phi


_EYE6 = np.eye(6)


def mekf_update(q, b, P, resid, H, R, gate):
    """Joseph-form update with the residual ``resid`` (3,), ``H`` (3x6), ``R`` (3x3) and the
    NIS gate: ``(q, b, P, I - K H)``, the last None when the gate rejects (state unchanged)."""
    PHt = P @ H.T
    S = H @ PHt + R
    S = 0.5 * (S + S.T)
    S_inv = np.linalg.inv(S)
    if float(resid @ S_inv @ resid) > gate:
        return q, b, P, None
    K = PHt @ S_inv
    dx = K @ resid
    IKH = _EYE6 - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    q = qmul(q, qexp(dx[:3]))
    q /= math.sqrt(q @ q)
    return q, b + dx[3:], 0.5 * (P + P.T), IKH


def run(duration_s: float = 5000.0, seed: int = 1, score_from_s: float = SCORE_FROM_S) -> dict:
    """Simulate ``duration_s`` of the default scenario.

    Returns ``{"cpu_s", "rmse_deg": {estimator: [x, y, z] after score_from_s}, "steps" (0.1-s
    truth steps), "filter_steps", "gate_rejections": {MEKF: count}, "samples_scored"}``;
    ``cpu_s`` is ``time.process_time`` of the set-up and the loop (the scoring after it is not
    timed, as drake_att's ``compute_metrics`` is not)."""
    c0 = time.process_time()
    rng = np.random.default_rng(seed)
    T = TRUTH_STEP_S
    per_gyro = round(GYRO_PERIOD_S / T)
    steps = round(duration_s / T)
    n_filter = steps // per_gyro + 1  # filter instants 0, 1, ... s
    # Truth
    q_IO0 = lvlh_q_IO0()
    y = np.concatenate([qmul(q_IO0, rpy_quat(INITIAL_RPY_DEG * DEG)), INITIAL_RATE_DEG_S * DEG, np.zeros(3)])
    # Gyro
    l11, l21, l22 = farrenkopf_factors(ARW, RRW, GYRO_PERIOD_S)
    bias = GYRO_BIAS0.copy()
    theta_prev = y[7:10].copy()  # the rate integral at the previous gyro sample
    # Trackers
    q_BS = [mounting_q_BS(*(np.array(a) * DEG)) for a in (ST1_PSI_PHI_THETA_DEG, ST2_PSI_PHI_THETA_DEG)]
    q_SB = [qconj(q) for q in q_BS]
    sig_S = np.array([ST_SIGMA_CROSS, ST_SIGMA_CROSS, ST_SIGMA_BORE])
    R_S = np.diag(sig_S**2)
    H_S = []
    for q in q_BS:
        H = np.zeros((3, 6))
        H[:, :3] = qrot(q).T  # R_SB
        H_S.append(H)
    # The average's measurement model: identity mounting, derived covariance.
    H_avg = np.zeros((3, 6))
    H_avg[:, :3] = np.eye(3)
    R_avg = sum(w * w * qrot(q) @ R_S @ qrot(q).T for w, q in zip(AVERAGE_WEIGHTS, q_BS, strict=True))
    # Filters: the four MEKFs start from the same estimate.
    q0 = qmul(q_IO0, rpy_quat(EST_RPY_DEG * DEG))
    P0 = np.diag([P0_ATT_SIGMA**2] * 3 + [P0_BIAS_SIGMA**2] * 3)
    est = {n: [q0.copy(), EST_BIAS0 * DEG_PER_H, P0.copy()] for n in MEKFS}
    P12 = P0.copy()  # cross-covariance of single and single_st2
    Q = process_noise(ARW, RRW, GYRO_PERIOD_S)
    gate = chi2_3dof_quantile(GATE_PROBABILITY)
    rejections = dict.fromkeys(MEKFS, 0)
    w1, w2 = FUSION_WEIGHTS
    # Records (what drake_att's RunLog holds): truth [q, w] at 10 Hz, tracker samples at 10 Hz,
    # gyro [w_meas, bias] at 1 Hz, estimates [q, b, P] at 1 Hz.
    truth_log = np.empty((steps + 1, 7))
    tracker_log = np.empty((2, steps + 1, 4))
    gyro_log = np.full((n_filter, 6), np.nan)
    est_log = {n: np.empty((n_filter, 43)) for n in ESTIMATORS}
    for k in range(steps + 1):
        if k > 0:
            y = rk3_step(y, T)
        q_IB = y[:4] / math.sqrt(y[:4] @ y[:4])
        truth_log[k, :4] = q_IB
        truth_log[k, 4:] = y[4:7]
        # Both trackers' samples at t_k.
        q_meas = [qmul(qmul(q_IB, q_BS[i]), qexp(sig_S * rng.standard_normal(3))) for i in (0, 1)]
        tracker_log[0, k] = q_meas[0]
        tracker_log[1, k] = q_meas[1]
        if k % per_gyro:
            continue
        j = k // per_gyro
        # --- filter step at t_j = j s -----------------------------------------------------
        Phi = {}
        if j > 0:
            # Gyro sample: mean true rate over (t_(j-1), t_j] + bias at t_(j-1) + e_j.
            z = rng.standard_normal((2, 3))
            e, db = l11 * z[0], l21 * z[0] + l22 * z[1]
            w_meas = (y[7:10] - theta_prev) / GYRO_PERIOD_S + bias + e
            theta_prev = y[7:10].copy()
            bias = bias + db
            gyro_log[j, :3] = w_meas
            gyro_log[j, 3:] = bias
            for n in MEKFS:
                s = est[n]
                s[0], s[2], Phi[n] = mekf_predict(s[0], s[1], s[2], w_meas, GYRO_PERIOD_S, Q)
        A = {}
        # Single-tracker MEKFs and the joint one: residual in the tracker's frame, H = [R_SB, 0].
        for n, trackers in (("single", (0,)), ("single_st2", (1,)), ("joint", (0, 1))):
            s = est[n]
            A_n = _EYE6
            for i in trackers:
                resid = qlog(qmul(qconj(qmul(s[0], q_BS[i])), q_meas[i]))
                s[0], s[1], s[2], IKH = mekf_update(s[0], s[1], s[2], resid, H_S[i], R_S, gate)
                if IKH is None:
                    rejections[n] += 1
                else:
                    A_n = IKH @ A_n
            A[n] = A_n
        # Centralized: the average of the two trackers' body attitudes.
        q_avg = average_two_quaternions(qmul(q_meas[0], q_SB[0]), qmul(q_meas[1], q_SB[1]), *AVERAGE_WEIGHTS)
        s = est["centralized"]
        s[0], s[1], s[2], IKH = mekf_update(s[0], s[1], s[2], qlog(qmul(qconj(s[0]), q_avg)), H_avg, R_avg, gate)
        if IKH is None:
            rejections["centralized"] += 1
        # Decentralized: fuse single and single_st2, with their tracked cross-covariance.
        (qa, ba, Pa), (qb, bb, Pb) = est["single"], est["single_st2"]
        if j > 0:
            P12 = Phi["single"] @ P12 @ Phi["single_st2"].T + Q
        P12 = A["single"] @ P12 @ A["single_st2"].T
        q_dec = average_two_quaternions(qa, qb, w1, w2)
        b_dec = w1 * ba + w2 * bb
        P_dec = w1 * w1 * Pa + w2 * w2 * Pb + w1 * w2 * (P12 + P12.T)
        for n in MEKFS:
            row = est_log[n][j]
            row[:4], row[4:7], row[7:] = est[n][0], est[n][1], est[n][2].ravel()
        row = est_log["decentralized"][j]
        row[:4], row[4:7], row[7:] = q_dec, b_dec, P_dec.ravel()
    cpu = time.process_time() - c0
    # Scoring (not timed): estimates at t_j >= score_from_s against the truth at t_j.
    t_est = np.arange(n_filter) * GYRO_PERIOD_S
    scored = t_est >= score_from_s - 1e-6
    q_true = truth_log[::per_gyro, :4][:n_filter][scored]
    rmse = {}
    for n in ESTIMATORS:
        d = quat_error_rotvec(est_log[n][scored, :4], q_true) / DEG
        rmse[n] = np.sqrt(np.mean(d * d, axis=0)).tolist() if len(d) else [math.nan] * 3
    return {
        "cpu_s": cpu,
        "rmse_deg": rmse,
        "steps": steps,
        "filter_steps": n_filter - 1,
        "gate_rejections": rejections,
        "samples_scored": int(np.sum(scored)),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=5000.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    r = run(a.duration, a.seed)
    print(
        f"peer default loop: {a.duration:.0f} s, {r['steps']} truth steps, {r['filter_steps']} filter steps, "
        f"seed {a.seed}; CPU time {r['cpu_s']:.2f} s"
    )
    print(f"attitude RMSE after {SCORE_FROM_S:.0f} s (deg, x/y/z):")
    for n in ESTIMATORS:
        print(
            f"  {n:<14} "
            + " ".join(f"{v:.2e}" for v in r["rmse_deg"][n])
            + (f"   gate rejections {r['gate_rejections'][n]}" if n in MEKFS else "")
        )


if __name__ == "__main__":
    main()
