#!/usr/bin/env python3
"""A plain-numpy peer of drake_att's S3 single-tracker case at 10 Hz (no Drake, no drake_att).

One hand-written loop with the same models as
``drake_att/scenarios/cubesat_single_star_tracker.yaml`` with the gyro, the tracker and the
MEKF all at 10 Hz, to benchmark the library against (``benchmarks/bench_peer.py``):

* truth: rigid body, ``I w_dot + w x (I w) = tau`` and ``q_IB_dot = 1/2 q ⊗ [0, w]`` with the
  plant's norm stabilization ``+ (1 - q'q) q`` (``drake_att/systems/plant.py``), plus the rate
  integral the averaging gyro reads; fixed-step 3rd-order Runge-Kutta (Kutta's tableau,
  Drake's ``RungeKutta3Integrator`` without error control) at 0.1 s (the YAML's
  ``simulation:`` block);
* gyro: Farrenkopf model delivering the interval-mean rate every 0.1 s with the exact discrete
  statistics (``drake_att/noise.py``, ``drake_att/systems/gyro.py``);
* star tracker: ``q_IS_meas = q_IB ⊗ q_BS ⊗ exp(delta_S)``, ``delta_S ~ N(0, diag(sc^2, sc^2, sb^2))``
  (``drake_att/systems/star_tracker.py``), mounting of the paper's eq. 7;
* MEKF at 10 Hz (``drake_att/filters/mekf.py``): closed-form propagation and transition matrix,
  Farrenkopf ``Q``, Joseph-form quaternion update ``H = [R_SB, 0]``, reset; the library's default
  innovation gate (chi-square 3 dof at probability 0.99999) is applied and its rejections counted.

The random numbers are this file's own (``numpy.random.default_rng(seed)``), not the library's
counter-based streams: the same statistics, not the same realization.

    python benchmarks/peer_numpy_loop.py [--duration 5000] [--seed 1]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

DEG = math.pi / 180.0
ARCSEC = DEG / 3600.0
DEG_PER_H = DEG / 3600.0
ARW_DEG_PER_RT_H = DEG / 60.0  # rad/s^0.5
RRW_DEG_PER_H_15 = DEG / 3600.0 / 60.0  # rad/s^1.5

# --- Numbers from drake_att/scenarios/cubesat_single_star_tracker.yaml (hard-coded) ---------
INERTIA = np.array([0.042, 0.042, 0.0067])  # plant.inertia_kg_m2 (principal, kg m^2)
INITIAL_RPY_DEG = np.array([2.0, -2.0, 2.0])  # plant.initial_attitude_rpy_deg (relative to LVLH at t = 0)
INITIAL_RATE_DEG_S = np.array([-0.5, 0.5, 0.5])  # plant.initial_rate_deg_per_s (w_IB_B)
TORQUE_N_M = np.array([1.0e-7, 1.0e-7, 1.0e-7])  # plant.disturbance_torque_N_m
ALTITUDE_KM, INCLINATION_DEG = 500.0, 97.5  # orbit (RAAN 0, argument of latitude 0 at t = 0)
ARW = 0.56 * ARW_DEG_PER_RT_H  # sensors.gyro.arw_deg_per_rt_h
RRW = 123.75 * RRW_DEG_PER_H_15  # sensors.gyro.rrw_deg_per_h15
GYRO_BIAS0 = np.array([12.0, 12.0, 12.0]) * DEG_PER_H  # sensors.gyro.initial_bias_deg_per_h
ST_PSI_PHI_THETA_DEG = (-90.0, 45.0, -90.0)  # sensors.st1.mounting (PaperS3Eq7Mounting)
ST_SIGMA_CROSS, ST_SIGMA_BORE = 5.0 * ARCSEC, 50.0 * ARCSEC  # sensors.st1 sigmas
EST_RPY_DEG = np.zeros(3)  # estimators.single.initial_attitude_rpy_deg
EST_BIAS0 = np.zeros(3)  # estimators.single.initial_bias_deg_per_h
P0_ATT_SIGMA, P0_BIAS_SIGMA = 5.0 * DEG, 20.0 * DEG_PER_H  # estimators.single initial sigmas
SCORE_FROM_S = 500.0  # scoring.score_from_s
GATE_PROBABILITY = 0.99999  # drake_att.filters.gating.DEFAULT_GATE_PROBABILITY (the MEKF's default gate)
NORM_GAIN = 1.0  # plant.py NORM_STABILIZATION_GAIN (1/s)
INERTIA_T, TORQUE_T = tuple(INERTIA.tolist()), tuple(TORQUE_N_M.tolist())  # as Python floats for rhs()


# --- Quaternions (wxyz, Hamilton) -------------------------------------------------------------
def qmul(a, b):
    aw, ax, ay, az = a.tolist()
    bw, bx, by, bz = b.tolist()
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def qconj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def qexp(v):
    """Quaternion of rotation vector v (rad)."""
    x, y, z = v.tolist()
    a = math.sqrt(x * x + y * y + z * z)
    s = 0.5 - a * a / 48.0 if a < 1e-8 else math.sin(0.5 * a) / a
    return np.array([math.cos(0.5 * a), s * x, s * y, s * z])


def qlog(q):
    """Shortest rotation vector of q."""
    q = q / math.sqrt(q @ q)
    if q[0] < 0:
        q = -q
    s = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    k = 2.0 / q[0] if s < 1e-12 else 2.0 * math.atan2(s, q[0]) / s
    return k * q[1:]


def qrot(q):
    """R(q): body -> inertial for q_IB."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rpy_quat(rpy):
    """R = Rz(yaw) Ry(pitch) Rx(roll)."""
    q = qexp(np.array([0.0, 0.0, rpy[2]]))
    q = qmul(q, qexp(np.array([0.0, rpy[1], 0.0])))
    return qmul(q, qexp(np.array([rpy[0], 0.0, 0.0])))


def lvlh_q_IO0():
    """LVLH frame at t = 0 (RAAN 0, argument of latitude 0): Rx(i) R_PO, R_PO's columns
    x_O = y_P, y_O = -z_P, z_O = -x_P (drake_att/orbit.py)."""
    # R_PO = [[0,0,-1],[1,0,0],[0,-1,0]]: trace 0, so w = 1/2 and (x, y, z) = (R32 - R23, R13 - R31, R21 - R12) / 2.
    q_PO = np.array([0.5, -0.5, -0.5, 0.5])
    return qmul(qexp(np.array([INCLINATION_DEG * DEG, 0.0, 0.0])), q_PO)


def mounting_q_BS(psi, phi, theta):
    """Paper S3 eq. 7 gives q7 with R_SB = R(q7) read as attitude matrix, so q_BS = q7^-1."""
    c = lambda a: math.cos(0.5 * a)  # noqa: E731
    s = lambda a: math.sin(0.5 * a)  # noqa: E731
    th, ph, ps = theta, phi, psi
    q7 = np.array(
        [
            c(th) * c(ph) * c(ps) - s(th) * s(ph) * s(ps),
            c(th) * s(ph) * c(ps) - s(th) * c(ph) * s(ps),
            s(th) * c(ph) * c(ps) + c(th) * s(ph) * s(ps),
            s(th) * s(ph) * c(ps) + c(th) * c(ph) * s(ps),
        ]
    )
    return qconj(q7 / math.sqrt(q7 @ q7))


def chi2_3dof_quantile(p):
    """Chi-square (3 dof) quantile by bisection on cdf = erf(sqrt(x/2)) - sqrt(2x/pi) e^(-x/2)."""
    cdf = lambda x: math.erf(math.sqrt(x / 2)) - math.sqrt(2 * x / math.pi) * math.exp(-x / 2)  # noqa: E731
    lo, hi = 0.0, 200.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < p else (lo, mid)
    return 0.5 * (lo + hi)


# --- Truth ----------------------------------------------------------------------------------
def rhs(y, inertia=INERTIA_T, torque=TORQUE_T):
    """[q (4), w (3), theta (3)] -> derivative (Euler's equations, kinematics, rate integral);
    ``inertia``, ``torque``: principal moments and body torque as Python floats."""
    qw, qx, qy, qz, wx, wy, wz = y[:7].tolist()
    k = NORM_GAIN * (1.0 - (qw * qw + qx * qx + qy * qy + qz * qz))
    Ix, Iy, Iz = inertia
    tx, ty, tz = torque
    # w x (I w) written out (np.cross costs tens of microseconds on 3-vectors under numpy 2).
    return np.array(
        [
            0.5 * (-qx * wx - qy * wy - qz * wz) + k * qw,
            0.5 * (qw * wx + qy * wz - qz * wy) + k * qx,
            0.5 * (qw * wy - qx * wz + qz * wx) + k * qy,
            0.5 * (qw * wz + qx * wy - qy * wx) + k * qz,
            (tx - (Iz - Iy) * wy * wz) / Ix,
            (ty - (Ix - Iz) * wz * wx) / Iy,
            (tz - (Iy - Ix) * wx * wy) / Iz,
            wx,
            wy,
            wz,
        ]
    )


def rk3_step(y, h, inertia=INERTIA_T, torque=TORQUE_T):
    """Kutta's 3rd-order tableau (0; 1/2 1/2; 1 -1 2; b = 1/6 2/3 1/6), as Drake's RK3."""
    k1 = rhs(y, inertia, torque)
    k2 = rhs(y + 0.5 * h * k1, inertia, torque)
    k3 = rhs(y + h * (-k1 + 2.0 * k2), inertia, torque)
    return y + (h / 6.0) * (k1 + 4.0 * k2 + k3)


# --- MEKF -----------------------------------------------------------------------------------
def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def transition(w, dt):
    """Phi of F = [[-[w x], -I], [0, 0]]: [[exp(-[w x] dt), -J], [0, I]], J = int_0^dt exp(-[w x] s) ds."""
    n2 = float(w @ w)
    wn = math.sqrt(n2)
    a = wn * dt
    if a < 1e-4:
        c1 = dt * dt / 2 - n2 * dt**4 / 24
        c2 = dt**3 / 6 - n2 * dt**5 / 120
        s1 = dt - n2 * dt**3 / 6
    else:
        c1 = (1 - math.cos(a)) / n2
        c2 = (a - math.sin(a)) / (n2 * wn)
        s1 = math.sin(a) / wn
    K = skew(w)
    K2 = K @ K
    Phi = np.eye(6)
    Phi[:3, :3] = np.eye(3) - s1 * K + c1 * K2
    Phi[:3, 3:] = -(dt * np.eye(3) - c1 * K + c2 * K2)
    return Phi


def process_noise(sv, su, dt):
    Q = np.zeros((6, 6))
    eye = np.eye(3)
    Q[:3, :3] = (sv**2 * dt + su**2 * dt**3 / 3) * eye
    Q[:3, 3:] = Q[3:, :3] = (-(su**2) * dt**2 / 2) * eye
    Q[3:, 3:] = su**2 * dt * eye
    return Q


def run(duration_s: float, seed: int, rate_hz: float = 10.0) -> dict:
    """Simulate ``duration_s`` at ``rate_hz`` (gyro, tracker, MEKF and the RK3 step).

    Returns ``{"cpu_s", "rmse_deg" (3, per body axis after SCORE_FROM_S), "steps",
    "gate_rejections", "samples_scored"}``; ``cpu_s`` is ``time.process_time`` of the loop
    (set-up included: it is microseconds)."""
    c0 = time.process_time()
    rng = np.random.default_rng(seed)
    T = 1.0 / rate_hz
    steps = int(round(duration_s * rate_hz))
    # Truth
    q_IO0 = lvlh_q_IO0()
    y = np.concatenate([qmul(q_IO0, rpy_quat(INITIAL_RPY_DEG * DEG)), INITIAL_RATE_DEG_S * DEG, np.zeros(3)])
    # Gyro: given b_k at the interval start, (e, b_{k+1} - b_k) per axis ~ N(0, C),
    # C = [[sv^2/T + su^2 T/3, su^2 T/2], [su^2 T/2, su^2 T]]; Cholesky factor below.
    var_e, cov_ed, var_d = ARW**2 / T + RRW**2 * T / 3, RRW**2 * T / 2, RRW**2 * T
    l11 = math.sqrt(var_e)
    l21 = cov_ed / l11
    l22 = math.sqrt(max(var_d - l21 * l21, 0.0))
    bias = GYRO_BIAS0.copy()
    # Tracker
    q_BS = mounting_q_BS(*(np.array(ST_PSI_PHI_THETA_DEG) * DEG))
    sig_S = np.array([ST_SIGMA_CROSS, ST_SIGMA_CROSS, ST_SIGMA_BORE])
    H = np.zeros((3, 6))
    H[:, :3] = qrot(q_BS).T  # R_SB
    R = np.diag(sig_S**2)
    # Filter
    q_hat = qmul(q_IO0, rpy_quat(EST_RPY_DEG * DEG))
    b_hat = EST_BIAS0 * DEG_PER_H
    P = np.diag([P0_ATT_SIGMA**2] * 3 + [P0_BIAS_SIGMA**2] * 3)
    Q = process_noise(ARW, RRW, T)
    gate = chi2_3dof_quantile(GATE_PROBABILITY)
    eye6 = np.eye(6)
    rejections = 0
    sq = np.zeros(3)
    n_scored = 0
    for k in range(steps + 1):
        t = k * T
        if k > 0:
            # Gyro sample at t_k: mean true rate over (t_{k-1}, t_k] + bias at t_{k-1} + e_k.
            theta_prev = y[7:10].copy()
            y = rk3_step(y, T)
            z = rng.standard_normal((2, 3))
            e, db = l11 * z[0], l21 * z[0] + l22 * z[1]
            w_meas = (y[7:10] - theta_prev) / T + bias + e
            bias = bias + db
            # MEKF time update with the interval's mean rate.
            w_hat = w_meas - b_hat
            q_hat = qmul(q_hat, qexp(w_hat * T))
            q_hat /= math.sqrt(q_hat @ q_hat)
            Phi = transition(w_hat, T)
            P = Phi @ P @ Phi.T + Q
            P = 0.5 * (P + P.T)
        # Star tracker sample at t_k and the MEKF measurement update (Joseph form).
        q_IB = y[:4] / math.sqrt(y[:4] @ y[:4])
        q_meas = qmul(qmul(q_IB, q_BS), qexp(sig_S * rng.standard_normal(3)))
        resid = qlog(qmul(qconj(qmul(q_hat, q_BS)), q_meas))
        PHt = P @ H.T
        S = H @ PHt + R
        S = 0.5 * (S + S.T)
        S_inv = np.linalg.inv(S)
        if float(resid @ S_inv @ resid) > gate:
            rejections += 1
        else:
            K = PHt @ S_inv
            dx = K @ resid
            IKH = eye6 - K @ H
            P = IKH @ P @ IKH.T + K @ R @ K.T
            P = 0.5 * (P + P.T)
            q_hat = qmul(q_hat, qexp(dx[:3]))
            q_hat /= math.sqrt(q_hat @ q_hat)
            b_hat = b_hat + dx[3:]
        if t >= SCORE_FROM_S - 1e-6:
            d = qlog(qmul(qconj(q_hat), q_IB))  # dtheta_B = log(q_hat^-1 ⊗ q)
            sq += d * d
            n_scored += 1
    cpu = time.process_time() - c0
    rmse = np.sqrt(sq / max(n_scored, 1)) / DEG
    return {
        "cpu_s": cpu,
        "rmse_deg": rmse.tolist(),
        "steps": steps,
        "gate_rejections": rejections,
        "samples_scored": n_scored,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=5000.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rate-hz", type=float, default=10.0)
    a = ap.parse_args(argv)
    r = run(a.duration, a.seed, a.rate_hz)
    print(f"peer numpy loop: {a.duration:.0f} s at {a.rate_hz:g} Hz, {r['steps']} steps, seed {a.seed}")
    print(
        f"CPU time {r['cpu_s']:.2f} s; attitude RMSE after {SCORE_FROM_S:.0f} s (deg, x/y/z): "
        + " ".join(f"{v:.2e}" for v in r["rmse_deg"])
        + f"; gate rejections {r['gate_rejections']}"
    )


if __name__ == "__main__":
    main()
