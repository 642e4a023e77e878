#!/usr/bin/env python3
"""Time per filter step (predict + update) of every filter core, as ratios to the MEKF in one run.

Usage::

    python benchmarks/bench_filter_steps.py [--repeats 7] [--number 0] [--slot-time 0.1]
        [--stars 3] [--particles 100,1000] [--clock cpu|wall] [--burn-in 200]

**Case** (paper S1, the same inputs for every core): 1 s filter step, gyro with the S1
noise (ARW ``sqrt(10)e-7 rad/s^0.5``, RRW ``sqrt(10)e-10 rad/s^1.5``, true bias 0.1 deg/h per
axis), body turning at the 500 km orbit rate about ``-y``, one star-tracker sample per step
with ``--stars`` (3 = S1; 2 allowed) inertial-axis references at 2 arcsec per component,
tracker frame = body frame. Each core starts 0.05 deg/axis off the truth (attitude sigma
0.1 deg, bias sigma 0.1 deg/h) and runs ``--burn-in`` predict + update steps on synthetic
data, so the timed state is a *converged* filter near the truth (the last column of the
table: its attitude error after the timed step). The timed step is then
``core.update(core.predict(state, w, 1.0, rng), observation, rng)`` from that one fixed
state (the cores are pure functions of an immutable state, so every call does the same
work; the particle filters' random draws differ between calls). Only the core is timed:
not the Drake system around it (port reads, packing the state into the Context). In S1
the star sample comes every 10th step; here every step has one (the update's cost).

**Iterated updates stop early.** Near the truth the measurement function is linear over
the prior's spread, so the cubature cores' update (``update_iterations`` = 10 by default)
stops after its first iteration: the script checks this by comparing the result with the
same core at ``update_iterations=1`` (bit for bit) and prints the verdict ("1 iteration").
The MRP EKF and the EKPF run their default single linearization. A filter far from the
truth (S1's first updates from a 167 deg error; already a 0.1 deg prior sigma at 2 arcsec
stars) relinearizes and costs more per update: not timed here.

**Timing** (``timeit`` style, garbage collector off while timing): a *slot* times
``--number`` consecutive steps of one core (0: per core, enough steps for about
``--slot-time`` s, calibrated once). Each repeat is one round-robin pass over the cores
with an MEKF slot between every two: ``M, c1, M, c2, ..., M`` (the order of the others
rotates between repeats), so drifting machine load hits all alike and each core's ratio
in a repeat is to the mean of the two MEKF slots around it, measured within a fraction of
a second. Reported: the best slot in us per step; the median [range] over repeats of the
per-repeat ratio (the figure to read); the ratio of the best slot to the MEKF's best slot
(best/best: the MEKF has a slot beside every other core's, so many times more slots and a
luckier best under load; best/best leans high). Clock: ``time.process_time`` (default: this process's CPU time, robust to other tenants on a
shared VM) or ``--clock wall`` (``time.perf_counter``). The script prints CPU / wall over
the timed loops: below 1 the process waited for a CPU (other load; CPU time still
inflates somewhat under contention), above 1 BLAS worker threads ran. No assertions:
compare ratios within one run, not microseconds between machines or runs.
"""

from __future__ import annotations

import argparse
import datetime
import gc
import math
import os
import platform
import statistics
import time

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import VectorObservations
from drake_att.filters.cubature import CubatureQuaternionEstimator
from drake_att.filters.lie_group import LieGroupFilter
from drake_att.filters.mekf import MultiplicativeEKF
from drake_att.filters.mrp_ekf import MrpEkfCore
from drake_att.filters.multiplicative_noise import MultiplicativeNoiseModel
from drake_att.filters.quaternion_ekf import AdditiveQuaternionEKF
from drake_att.systems.filter_setups import bootstrap_pf_setup, ekpf_setup

DEG = math.pi / 180.0
ARCSEC = DEG / 3600.0
HOUR = 3600.0
DT = 1.0
ARW = math.sqrt(10.0) * 1e-7  # rad/s^0.5 (S1)
RRW = math.sqrt(10.0) * 1e-10  # rad/s^1.5 (S1)
SIGMA_STAR = 2.0 * ARCSEC  # rad per component (S1)
ORBIT_RATE = 0.06341402030993613 * DEG  # rad/s at 500 km (S1)
TRUE_BIAS = np.full(3, 0.1 * DEG / HOUR)
Q_TRUE0 = rot.rpy_to_quat(np.array([30.0, -20.0, 50.0]) * DEG)
INITIAL_ERROR = np.full(3, 0.05 * DEG)  # rad, body frame
ATT_SIGMA0 = 0.1 * DEG
BIAS_SIGMA0 = 0.1 * DEG / HOUR
Q_BS = np.array([1.0, 0.0, 0.0, 0.0])
# S0's bootstrap-PF tuning (benchmarks/bench_particle_filters.py): attitude process noise and
# bias roughening wide enough that some particles keep weight at 2 arcsec.
BOOTSTRAP_ARW = 2e-5
BOOTSTRAP_ROUGHENING = 3e-7


def make_data(num_steps: int, num_stars: int, seed: int = 0):
    """Truth quaternions (K+1, 4), gyro mean rates (K, 3) and observations (K+1) of the case."""
    rng = np.random.default_rng(seed)
    refs = np.eye(3)[:num_stars]
    w_true = np.array([0.0, -ORBIT_RATE, 0.0])
    q, b = Q_TRUE0.copy(), TRUE_BIAS.copy()
    qs, ws, obs = [q], [], []
    for k in range(num_steps + 1):
        R_BI = rot.quat_to_rotmat(q).T
        d = refs @ R_BI.T + SIGMA_STAR * rng.standard_normal((num_stars, 3))
        obs.append(VectorObservations(k * DT, True, d, refs, SIGMA_STAR, Q_BS))
        if k == num_steps:
            break
        ws.append(w_true + b + ARW / math.sqrt(DT) * rng.standard_normal(3))
        b = b + RRW * math.sqrt(DT) * rng.standard_normal(3)
        q = rot.quat_normalize(rot.quat_propagate(q, w_true, DT))
        qs.append(q)
    return np.array(qs), np.array(ws), obs


def build_cores(particle_counts):
    """``[(label, core, initial state, rng)]``: every core on the case's tuning."""
    q0 = rot.quat_multiply(Q_TRUE0, rot.rotvec_to_quat(INITIAL_ERROR))
    b0 = np.zeros(3)
    P0 = np.diag([ATT_SIGMA0**2] * 3 + [BIAS_SIGMA0**2] * 3)
    out = []

    mekf = MultiplicativeEKF(ARW, RRW)
    out.append(("MEKF (MultiplicativeEKF)", mekf, mekf.initial_state(q0, b0, ATT_SIGMA0, BIAS_SIGMA0)))
    mrp = MrpEkfCore(ARW, RRW)
    out.append(("MRP EKF (MrpEkfCore)", mrp, mrp.initial_state(q0, b0, P0)))
    lie_bias = LieGroupFilter(estimate_gyro_bias=True, gyro_arw_rad_per_rt_s=ARW, gyro_rrw_rad_per_s15=RRW)
    out.append(("Lie group, gyro-bias state", lie_bias, lie_bias.initial_state(q0, P0, bias_B=b0)))
    # No bias state: a small Q_w absorbs the unmodelled 0.1 deg/h bias (~0.5 urad per step).
    lie = LieGroupFilter(Q_w=1e-12, gyro_arw_rad_per_rt_s=ARW)
    out.append(("Lie group, no bias state (S4)", lie, lie.initial_state(q0, ATT_SIGMA0**2)))
    # Quaternion noise of a rotation-vector sigma s is ~ s/2 per vector component.
    aq = AdditiveQuaternionEKF(Q=1e-14, R=(0.5 * SIGMA_STAR) ** 2, gyro_arw_rad_per_rt_s=ARW)
    out.append(("additive quaternion EKF (S4 baseline)", aq, aq.initial_state(q0, (0.5 * ATT_SIGMA0) ** 2)))
    cqe = CubatureQuaternionEstimator(ARW, RRW)
    out.append(("CQE (cubature, S1)", cqe, cqe.initial_state(q0, b0, ATT_SIGMA0, BIAS_SIGMA0)))
    mcns = CubatureQuaternionEstimator(ARW, RRW, noise_model=MultiplicativeNoiseModel.paper())
    out.append(("CQE-MCNS (paper() noise model, S1)", mcns, mcns.initial_state(q0, b0, ATT_SIGMA0, BIAS_SIGMA0)))
    for n in particle_counts:
        setup = bootstrap_pf_setup(DT, "st", n, q0, b0, P0, BOOTSTRAP_ARW, bias_roughening_sigma=BOOTSTRAP_ROUGHENING)
        out.append((f"bootstrap PF, N = {n}", setup.core, setup.core.draw_initial_state(np.random.default_rng(10 + n))))
    for n in particle_counts:
        setup = ekpf_setup(DT, "st", n, q0, b0, P0, ARW, RRW)
        out.append((f"EKPF, N = {n}", setup.core, setup.core.draw_initial_state(np.random.default_rng(20 + n))))
    return [(label, core, state, np.random.default_rng(1000 + i)) for i, (label, core, state) in enumerate(out)]


def attitude_error_arcsec(core, state, q_true) -> float:
    q_hat = core.estimate(state)[0]
    return float(np.linalg.norm(rot.quat_error_rotvec(q_hat, q_true))) / ARCSEC


def first_iteration_verdict(core, state, w, obs) -> str:
    """Whether the timed update stopped after its first iteration (cubature cores)."""
    if not isinstance(core, CubatureQuaternionEstimator) or core.update_iterations == 1:
        return ""
    single = CubatureQuaternionEstimator(
        core.arw,
        core.rrw,
        core.grp_a,
        core.grp_f,
        core.gate,
        core.noise_model,
        core.zeta_gate_sigmas,
        1,
        core.iteration_tolerance,
        core.zeta_state_correlation,
    )
    prior = core.predict(state, w, DT)
    same = np.array_equal(core.to_vector(core.update(prior, obs)[0]), single.to_vector(single.update(prior, obs)[0]))
    return "1 iteration" if same else f"> 1 iteration (of {core.update_iterations})"


def time_slot(case, clock) -> float:
    """Seconds per step over one slot of ``case["number"]`` consecutive steps."""
    step, number = case["step"], case["number"]
    t0 = clock()
    for _ in range(number):
        step()
    return (clock() - t0) / number


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="timed repeats per core (the best is kept)")
    ap.add_argument(
        "--number",
        type=int,
        default=0,
        help="steps per timed slot for every core (0: per core, about --slot-time per slot)",
    )
    ap.add_argument("--slot-time", type=float, default=0.1, help="target seconds per slot with --number 0")
    ap.add_argument("--stars", type=int, choices=(2, 3), default=3, help="star vectors per sample (S1: 3)")
    ap.add_argument(
        "--particles",
        default="100,1000",
        help="comma-separated particle counts for the bootstrap PF and EKPF ('' or 0: none)",
    )
    ap.add_argument(
        "--clock",
        choices=("cpu", "wall"),
        default="cpu",
        help="cpu: time.process_time (default); wall: time.perf_counter",
    )
    ap.add_argument("--burn-in", type=int, default=200, help="filter steps before the timed state")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.number < 0 or args.burn_in < 1 or not args.slot_time > 0.0:
        ap.error("--repeats >= 1, --number >= 0, --burn-in >= 1, --slot-time > 0")
    counts = [int(s) for s in args.particles.split(",") if s.strip() and int(s) > 0]
    clock = time.process_time if args.clock == "cpu" else time.perf_counter

    K = args.burn_in
    q_true, w_meas, obs = make_data(K + 1, args.stars)
    cases = []
    for label, core, state, rng in build_cores(counts):
        for k in range(K):  # burn-in: predict to t_{k+1}, update with the sample there
            state, info = core.update(core.predict(state, w_meas[k], DT, rng), obs[k + 1], rng)
        w, y = w_meas[K], obs[K + 1]
        after, info = core.update(core.predict(state, w, DT, rng), y, rng)
        check = f'err {attitude_error_arcsec(core, after, q_true[K + 1]):.2f}"'
        if not info.accepted:
            check += ", update REJECTED"
        verdict = first_iteration_verdict(core, state, w, y)
        if verdict:
            check += ", " + verdict
        if getattr(core, "is_random", False):
            check += ", resampled" if info.resampled else ", no resampling"
            if info.degenerate:
                check += ", DEGENERATE"

        def step(core=core, state=state, w=w, y=y, rng=rng):
            core.update(core.predict(state, w, DT, rng), y, rng)

        cases.append({"label": label, "step": step, "check": check, "times": [], "ratios": []})

    # Calibrate once: steps per slot so that a slot lasts about --slot-time.
    for c in cases:
        if args.number:
            c["number"] = args.number
            continue
        n, t0 = 0, clock()
        while clock() - t0 < 0.02 or n < 1:
            c["step"]()
            n += 1
        c["number"] = max(1, math.ceil(args.slot_time * n / (clock() - t0)))

    # Round-robin with the MEKF between every two cores: M, c1, M, c2, ..., M (the order of
    # the others rotates each repeat); each core's ratio in a repeat is to the mean of the
    # two MEKF slots around it (about 2 x --slot-time apart).
    ref_case, others = cases[0], cases[1:]
    load0 = os.getloadavg()[0]
    gc_was_enabled = gc.isenabled()
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        gc.disable()
        for r in range(args.repeats):
            order = others[r % len(others) :] + others[: r % len(others)] if others else []
            prev = time_slot(ref_case, clock)
            ref_case["times"].append(prev)
            for c in order:
                t = time_slot(c, clock)
                nxt = time_slot(ref_case, clock)
                ref_case["times"].append(nxt)
                c["times"].append(t)
                c["ratios"].append(t / (0.5 * (prev + nxt)))
                prev = nxt
    finally:
        if gc_was_enabled:
            gc.enable()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0

    ref = min(ref_case["times"])
    print(
        f"Filter cores, one predict + update step (dt = {DT:g} s, {args.stars} stars at 2 arcsec, S1 gyro), "
        f"converged state after {K} steps; {args.clock} clock "
        f"({'time.process_time' if args.clock == 'cpu' else 'time.perf_counter'}), best of {args.repeats} "
        f"round-robin repeats"
    )
    print(
        f"Python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}, "
        f"{datetime.date.today().isoformat()}; timed loops: {wall:.1f} s wall, CPU / wall = {cpu / wall:.2f}, "
        f"1-min load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after ({os.cpu_count()} CPUs)"
    )
    print()
    print(
        "| core | us/step (best) | x MEKF, median per repeat [range] | x MEKF, best/best | steps x slots | check of the timed step |"
    )
    print("|---|---|---|---|---|---|")
    for c in cases:
        t = c["times"]
        if c is ref_case:
            spread = f"(reference; worst slot / best slot = {max(t) / min(t):.2f})"
        else:
            ratios = sorted(c["ratios"])
            spread = f"{statistics.median(ratios):.2f} [{ratios[0]:.2f}, {ratios[-1]:.2f}]"
        print(
            f"| {c['label']} | {1e6 * min(t):.1f} | {spread} | {min(t) / ref:.2f} | "
            f"{c['number']} x {len(t)} | {c['check']} |"
        )


if __name__ == "__main__":
    main()
