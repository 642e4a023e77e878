#!/usr/bin/env python3
"""A plain-numpy peer of drake_att's S0 EKPF case (no Drake): truth, gyro, vector star tracker
and the extended-Kalman particle filter of ``s0_particle_filters_small_error`` (N = 1000, 1000 s).

One hand-written loop with the models of ``drake_att/scenarios/s0_particle_filters_small_error.yaml``
restricted to its ``ekpf`` estimator, to benchmark the library against (``benchmarks/bench_peer.py
--case ekpf``):

* truth: rigid body (principal inertia 100/200/200 kg m^2, constant torque 1e-5 N m per axis,
  at rest at t = 0, ``q_IB`` = identity: the scenario has no orbit, so its angles are inertial)
  with the plant's norm stabilization and the rate integral the gyro reads; fixed-step RK3
  (Kutta) at 1 s (the YAML's ``simulation:`` block);
* gyro at 1 s: Farrenkopf model, interval-mean rate with the exact discrete statistics
  (ARW 0.2/60 deg/rt-h, i.e. 0.2 deg/h per 1-s sample; RRW 0.02 deg/h^1.5; bias 1 deg/h per
  axis) — ``peer_default_loop.farrenkopf_factors``;
* star tracker at 1 s in vector mode, sensor frame = body frame: ``b_i = R_BI r_i + v_i``,
  ``r = (1, 0, 0), (0, 1, 0)``, ``v_i ~ N(0, (100 urad)^2 I3)``, not re-normalized
  (``drake_att/systems/star_tracker.py``);
* the EKPF: drake_att's plain-numpy EKPF, the numpy oracle of its tests
  (``tests/particle_reference.py``: ``ReferenceEkpfCore``, batched MRP-EKF predict and update
  per particle, proposal draw, weights, systematic resampling below N_eff = 2/3 N) with the
  scenario's numbers: N = 1000, initial estimate [1, 1, 1] deg
  and [2, 2, 2] deg/h with sigmas 1 deg and 1 deg/h, the gyro's ARW and RRW, one
  linearization per particle. Per step: predict with the gyro sample (not at t = 0), update
  with the tracker sample, then the estimate and its covariance (``estimate``: what
  drake_att publishes every step).

The loop keeps the records drake_att's ``RunLog`` holds (truth, gyro, estimates at 1 Hz) in
preallocated arrays; the attitude RMSE is computed from them after the timed part, as
``drake_att.analysis.metrics`` does. The random numbers are this file's own
(``numpy.random.default_rng(seed)`` for the sensors, ``default_rng(seed + 1)`` for the filter):
the same statistics as drake_att's, not the same realization.

    python benchmarks/peer_ekpf_loop.py [--duration 1000] [--seed 1] [--particles 1000] [--kernel numpy|numba]

``--kernel numba`` runs the same loop on drake_att's library core (``EkpfCore``: its compiled
kernels) instead, for comparison.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.append(os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "tests"))

import peer_numpy_loop
from particle_reference import ReferenceEkpfCore  # the tests' numpy oracle: the peer's EKPF core
from peer_default_loop import farrenkopf_factors
from peer_numpy_loop import (
    ARW_DEG_PER_RT_H,
    DEG,
    DEG_PER_H,
    RRW_DEG_PER_H_15,
    qrot,
    rpy_quat,
)

# drake_att's pieces without Drake: the library's EKPF core (``--kernel numba``) and the
# attitude error of the scoring (after the timed loop).
from drake_att.contract import VectorObservations
from drake_att.filters.particle import EffectiveSampleSizeGate, EkpfCore
from drake_att.rotations import quat_error_rotvec

# --- Numbers from drake_att/scenarios/s0_particle_filters_small_error.yaml (hard-coded) ------
STEP_S = 1.0  # simulation.max_step_size_s = gyro, tracker and filter period
INERTIA_T = (100.0, 200.0, 200.0)  # plant.inertia_kg_m2
TORQUE_T = (1.0e-5, 1.0e-5, 1.0e-5)  # plant.disturbance_torque_N_m
INITIAL_RPY_DEG = np.zeros(3)  # plant.initial_attitude_rpy_deg (no orbit: inertial)
INITIAL_RATE = np.zeros(3)  # plant.initial_rate_deg_per_s
ARW = 0.0033333333333333335 * ARW_DEG_PER_RT_H  # sensors.gyro.arw_deg_per_rt_h
RRW = 0.02 * RRW_DEG_PER_H_15  # sensors.gyro.rrw_deg_per_h15
GYRO_BIAS0 = np.array([1.0, 1.0, 1.0]) * DEG_PER_H  # sensors.gyro.initial_bias_deg_per_h
REFERENCES_I = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # sensors.st.references_I
SIGMA_VECTOR = 100.0e-6  # sensors.st.sigma_vector_urad (rad)
NUM_PARTICLES = 1000  # estimators.ekpf.num_particles
EST_RPY_DEG = np.array([1.0, 1.0, 1.0])  # estimators.ekpf.initial_attitude_rpy_deg
EST_BIAS0 = np.array([2.0, 2.0, 2.0]) * DEG_PER_H  # estimators.ekpf.initial_bias_deg_per_h
P0_ATT_SIGMA, P0_BIAS_SIGMA = 1.0 * DEG, 1.0 * DEG_PER_H  # EkpfConfig defaults (initial sigmas)
RESAMPLE_THRESHOLD = 2.0 / 3.0  # EkpfConfig default
PROPOSAL_ITERATIONS = 1  # estimators.ekpf.proposal_iterations
SCORE_FROM_S = 500.0  # scoring.score_from_s


def rk3_step(y, h):
    """``peer_numpy_loop.rk3_step`` with this scenario's inertia and torque."""
    return peer_numpy_loop.rk3_step(y, h, INERTIA_T, TORQUE_T)


def run(
    duration_s: float = 1000.0,
    seed: int = 1,
    score_from_s: float = SCORE_FROM_S,
    num_particles: int = NUM_PARTICLES,
    kernel: str = "numpy",
) -> dict:
    """Simulate ``duration_s`` of the S0 EKPF case.

    ``kernel``: the EKPF core, ``"numpy"`` (default: the plain-numpy peer, the tests' oracle) or
    ``"numba"`` (drake_att's library core, its compiled kernels, for comparison).
    Returns ``{"cpu_s", "rmse_deg": {"ekpf": [x, y, z] after score_from_s}, "steps",
    "resamplings", "samples_scored"}``; ``cpu_s`` is ``time.process_time`` of the set-up
    (the initial particle draw included) and the loop, not of the scoring after it."""
    c0 = time.process_time()
    rng = np.random.default_rng(seed)  # sensors
    pf_rng = np.random.default_rng(seed + 1)  # filter
    T = STEP_S
    steps = round(duration_s / T)
    y = np.concatenate([rpy_quat(INITIAL_RPY_DEG * DEG), INITIAL_RATE, np.zeros(3)])
    l11, l21, l22 = farrenkopf_factors(ARW, RRW, T)
    bias = GYRO_BIAS0.copy()
    P0 = np.diag([P0_ATT_SIGMA**2] * 3 + [P0_BIAS_SIGMA**2] * 3)
    core = (ReferenceEkpfCore if kernel == "numpy" else EkpfCore)(
        num_particles,
        rpy_quat(EST_RPY_DEG * DEG),
        EST_BIAS0,
        P0,
        ARW,
        RRW,
        proposal_iterations=PROPOSAL_ITERATIONS,
        resampling_gate=EffectiveSampleSizeGate(RESAMPLE_THRESHOLD),
    )
    pf = core.draw_initial_state(pf_rng)
    q_BS = np.array([1.0, 0.0, 0.0, 0.0])
    resamplings = 0
    # Records: truth [q, w], gyro [w_meas, bias], estimates [q, b, P].
    truth_log = np.empty((steps + 1, 7))
    gyro_log = np.full((steps + 1, 6), np.nan)
    est_log = np.empty((steps + 1, 43))
    for k in range(steps + 1):
        if k > 0:
            theta_prev = y[7:10].copy()
            y = rk3_step(y, T)
            # Gyro sample: mean true rate over (t_(k-1), t_k] + bias at t_(k-1) + e_k.
            z = rng.standard_normal((2, 3))
            e, db = l11 * z[0], l21 * z[0] + l22 * z[1]
            w_meas = (y[7:10] - theta_prev) / T + bias + e
            bias = bias + db
            gyro_log[k, :3], gyro_log[k, 3:] = w_meas, bias
            pf = core.predict(pf, w_meas, T, pf_rng)
        q_IB = y[:4] / math.sqrt(y[:4] @ y[:4])
        truth_log[k, :4], truth_log[k, 4:] = q_IB, y[4:7]
        # Tracker sample at t_k: b_i = R_BI r_i + v_i (body = sensor frame).
        meas = REFERENCES_I @ qrot(q_IB) + SIGMA_VECTOR * rng.standard_normal(REFERENCES_I.shape)
        pf, info = core.update(pf, VectorObservations(k * T, True, meas, REFERENCES_I, SIGMA_VECTOR, q_BS), pf_rng)
        resamplings += info.resampled
        q_hat, b_hat, P = core.estimate(pf)
        row = est_log[k]
        row[:4], row[4:7], row[7:] = q_hat, b_hat, P.ravel()
    cpu = time.process_time() - c0
    scored = np.arange(steps + 1) * T >= score_from_s - 1e-6
    d = quat_error_rotvec(est_log[scored, :4], truth_log[scored, :4]) / DEG
    rmse = np.sqrt(np.mean(d * d, axis=0)).tolist() if len(d) else [math.nan] * 3
    return {
        "cpu_s": cpu,
        "rmse_deg": {"ekpf": rmse},
        "steps": steps,
        "resamplings": resamplings,
        "samples_scored": int(np.sum(scored)),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=1000.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--particles", type=int, default=NUM_PARTICLES)
    ap.add_argument("--kernel", choices=("numpy", "numba"), default="numpy")
    a = ap.parse_args(argv)
    r = run(a.duration, a.seed, num_particles=a.particles, kernel=a.kernel)
    print(
        f"peer EKPF loop ({a.kernel} core): {a.duration:.0f} s, {r['steps']} steps, N = {a.particles}, seed {a.seed}; "
        f"CPU time {r['cpu_s']:.2f} s; {r['resamplings']} resamplings"
    )
    print(
        f"attitude RMSE after {SCORE_FROM_S:.0f} s (deg, x/y/z): " + " ".join(f"{v:.2e}" for v in r["rmse_deg"]["ekpf"])
    )


if __name__ == "__main__":
    main()
