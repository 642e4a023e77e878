"""The estimator step compiled for the MEKF (``drake_att.systems.compiled_step``) equals the
Python loop every core runs (``EstimatorSystem._on_step``) on every branch.

Two ``EstimatorSystem`` instances are stepped: the Python loop and the compiled step, both
running the library's MEKF (the loops must agree to 1e-12 relative), or the Python loop running
the numpy oracle of the MEKF (``tests/mekf_reference.py``: end to end, to 1e-9 relative, the
oracle's inverse and products round differently and a long run accumulates it). They are
stepped event by event on the same inputs (``EvalUniquePeriodicDiscreteUpdate``), fuzzed
per step: good samples, gate outliers (long runs of them, so re-acquisition and its ungated
retry happen), stale, repeated and NaN time stamps, invalid and NaN flags, NaN and tiny
quaternions, gyro samples missing, invalid, stale or NaN, a virtual sensor whose flag picks the
covariance of a subset (allowed, not allowed, out of range, infinite), and a singular
innovation covariance. Every discrete-state group must agree after every step, and the branches must actually have been taken (counted below).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from mekf_reference import ReferenceMEKF

from drake_att import rotations as rot
from drake_att.filters.mekf import MultiplicativeEKF
from drake_att.systems import compiled_step
from drake_att.systems.estimator_system import EstimatorSystem, QuaternionSensorModel

DEG = math.pi / 180
ARCSEC = DEG / 3600
ARW, RRW = 0.56 * DEG / 60, 123.75 * DEG / 3600 / 60
PERIOD = 0.5


def _pair(core, init, sensors, oracle=False, **settings):
    """(Python loop with ``core`` or its numpy oracle, compiled step with ``core``);
    ``settings``: the systems' loop settings (``max_time_tag_lag_s``, ...)."""
    python_core = ReferenceMEKF(core.arw, core.rrw, core.gate) if oracle else core
    systems = []
    for compiled, c in ((False, python_core), (True, core)):
        s = EstimatorSystem("mekf", PERIOD, c, init, sensors, **settings)
        s.use_compiled_step = compiled
        systems.append(s)
    assert systems[1]._compiled_model(systems[1].filter_model(systems[1].CreateDefaultContext())) is not None
    return systems


def _groups(system, context):
    return [context.get_discrete_state(i).value().copy() for i in range(context.num_discrete_state_groups())]


def _assert_close(a, b, what, rtol=1e-12):
    for ga, gb in zip(a, b, strict=True):
        finite = np.isfinite(ga)
        assert np.array_equal(finite, np.isfinite(gb)), what
        assert np.array_equal(ga[~finite], gb[~finite]) or np.all(np.isnan(ga[~finite]) == np.isnan(gb[~finite])), what
        scale = np.maximum(np.abs(ga[finite]), 1e-300)
        worst = np.max(np.abs(ga[finite] - gb[finite]) / scale, initial=0.0)
        # Covariance entries can be ~1e-14; compare those against their row's scale too.
        assert worst < rtol or np.max(np.abs(ga[finite] - gb[finite])) < rtol * np.max(np.abs(ga[finite])), (
            what,
            worst,
        )


def _run(systems, inputs, steps, after_step=None, rtol=1e-12):
    contexts = [s.CreateDefaultContext() for s in systems]
    for k in range(steps):
        t = k * PERIOD
        values = inputs(k, t)  # one draw for both systems
        repeats = 1 + values.pop("_repeat", 0)  # a second step at the same instant: dt = 0, samples used
        for s, c in zip(systems, contexts, strict=True):
            c.SetTime(t)
            for name, value in values.items():
                if value is not None:
                    s.GetInputPort(name).FixValue(c, value)
            for _ in range(repeats):
                c.get_mutable_discrete_state().SetFrom(s.EvalUniquePeriodicDiscreteUpdate(c))
        _assert_close(_groups(systems[0], contexts[0]), _groups(systems[1], contexts[1]), f"step {k}", rtol)
        if after_step is not None:
            after_step(systems[1], contexts[1])
    return [s.estimate_vector(c) for s, c in zip(systems, contexts, strict=True)], contexts


def test_compiled_step_is_used_for_an_eligible_mekf_and_not_otherwise():
    core = MultiplicativeEKF(ARW, RRW)
    assert compiled_step.eligible(core, 0, False)
    assert not compiled_step.eligible(ReferenceMEKF(ARW, RRW), 0, False)
    assert not compiled_step.eligible(MultiplicativeEKF(ARW, RRW, coning_correction=True), 0, False)
    assert not compiled_step.eligible(core, 1, False)
    init = core.initial_state([1.0, 0, 0, 0], np.zeros(3), 1 * DEG, 10 * DEG / 3600)
    system = EstimatorSystem("mekf", PERIOD, core, init)
    context = system.CreateDefaultContext()
    assert system._compiled_model(system.filter_model(context)) is not None


@pytest.mark.slow
@pytest.mark.parametrize("seed, oracle", [(0, False), (1, False), (2, False), (3, True)])
def test_compiled_step_equals_python_loop_on_fuzzed_inputs(seed, oracle):
    rng = np.random.default_rng(seed)
    core = MultiplicativeEKF(ARW, RRW, innovation_gate_chi2=16.0)
    q_true = rot.rpy_to_quat([0.3, -0.2, 1.1])
    init = core.initial_state(
        rot.quat_multiply(q_true, rot.rotvec_to_quat([0.01, -0.02, 0.01])), np.zeros(3), 2 * DEG, 20 * DEG / 3600
    )
    q_BS = [rot.rpy_to_quat([0.1, 0.7, -0.4]), rot.rpy_to_quat([-1.0, 0.2, 2.0])]
    sigma = np.array([5.0, 5.0, 50.0]) * ARCSEC
    cov = np.diag(sigma**2)
    subset = (None, cov * 2.0, None, cov * 3.0)  # masks 1 and 3 allowed, 2 not
    sensors = [
        QuaternionSensorModel("a", q_BS[0], cov),
        QuaternionSensorModel("b", q_BS[1], cov, covariance_by_flag=subset),
    ]
    systems = _pair(core, init, sensors, oracle)
    w_true = np.array([0.01, -0.02, 0.015])
    seen = {"outlier_run": 0, "gyro_bad": 0, "flags": set()}
    outlier_until = {0: -1, 1: -1}

    def inputs(k, t):
        R = rot.rotvec_to_quat(w_true * t)
        q_IB = rot.quat_multiply(q_true, R)
        gyro = [t, 1.0, *(w_true + rng.normal(0, 1e-5, 3))]
        u = rng.uniform()
        if u < 0.08:
            gyro[1] = 0.0
        elif u < 0.12:
            gyro[2] = np.nan
        elif u < 0.16:
            gyro[0] = t - 0.25
        elif u < 0.18:
            gyro[1] = np.nan
        if u < 0.18:
            seen["gyro_bad"] += 1
        out = {"gyro_measurement": gyro, "_repeat": int(rng.uniform() < 0.05)}
        for i, name in enumerate(("a", "b")):
            noise = rng.normal(0, 1, 3) * sigma
            q_meas = rot.quat_multiply(rot.quat_multiply(q_IB, q_BS[i]), rot.rotvec_to_quat(noise))
            m = [t, 1.0, *q_meas]
            if k > outlier_until[i] + 2 and rng.uniform() < 0.1:
                outlier_until[i] = k + int(rng.integers(3, 9))  # long enough to re-acquire
                seen["outlier_run"] += 1
            if k <= outlier_until[i]:
                m[2:] = rot.quat_multiply(np.asarray(m[2:]), rot.rotvec_to_quat([0.0, 0.02, 0.0]))
            v = rng.uniform()
            if v < 0.04:
                m[0] = np.nan
            elif v < 0.08:
                m[0] = t - PERIOD  # stale (and, after the first step, already used)
            elif v < 0.12:
                m[1] = 0.0
            elif v < 0.14:
                m[1] = np.nan
            elif v < 0.17:
                m[3] = np.nan
            elif v < 0.19:
                m[2:] = [0.1, 0.0, 0.1, 0.0]  # not a quaternion
            if name == "b" and rng.uniform() < 0.4:
                m[1] = float(rng.choice([2.0, 3.0, 4.0, 5.0, 9.0, np.inf]))
                seen["flags"].add(m[1])
            out[f"q_meas_{name}"] = m
        return out

    def count_reacquisitions(system, context):
        # An accepted update with an NIS above the gate: the ungated retry after re-acquisition.
        innovations = context.get_discrete_state(system._innovation_group).value().reshape(-1, 3)
        used = system.estimate_vector(context)[44]
        t = context.get_time()
        if used > seen["used"] and np.any((innovations[:, 0] == t) & (innovations[:, 1] > 16.0)):
            seen["reacquired"] += 1
        seen["used"] = used

    seen.update(reacquired=0, used=0.0)
    (python, compiled), _ = _run(systems, inputs, 400, count_reacquisitions, 1e-9 if oracle else 1e-12)
    assert seen["reacquired"] >= 2, seen
    assert seen["outlier_run"] >= 5 and seen["gyro_bad"] >= 20 and len(seen["flags"]) >= 5
    # The branches were taken: updates used and skipped, and the filter still tracks.
    assert python[44] > 200 and python[45] > 100
    assert np.linalg.norm(rot.quat_error_rotvec(python[:4], compiled[:4])) < 1e-12


def test_compiled_step_singular_innovation_and_unconnected_inputs():
    """Zero prior attitude covariance and a zero-noise sensor: S is singular (NIS NaN,
    counted skipped, no re-acquisition count); an unconnected sensor and gyro are ignored
    (the gyro's absence counted every step after the first)."""
    core = MultiplicativeEKF(0.0, 0.0)
    init = core.initial_state([1.0, 0, 0, 0], np.zeros(3), 0.0, 0.0)
    sensors = [
        QuaternionSensorModel("a", np.array([1.0, 0, 0, 0]), np.zeros((3, 3))),
        QuaternionSensorModel("b", np.array([1.0, 0, 0, 0]), np.eye(3) * 1e-8),
    ]
    systems = _pair(core, init, sensors)

    def inputs(k, t):
        return {"q_meas_a": [t, 1.0, 1.0, 0.0, 0.0, 0.0], "gyro_measurement": None, "q_meas_b": None}

    (python, compiled), contexts = _run(systems, inputs, 6)
    assert np.isnan(python[46]) and python[44] == 0
    assert python[45] == 6 + 5  # six singular updates, five steps without a gyro sample
    innovations = contexts[1].get_discrete_state(systems[1]._innovation_group).value()
    assert innovations[0] == pytest.approx(5 * PERIOD) and np.isnan(innovations[1]) and innovations[2] == 3


def test_compiled_step_equals_python_loop_on_time_tags_and_a_held_rate_walk():
    """The time-tag and held-rate branches, fuzzed: tags on time, late within the lag (carried
    forward), late beyond it, in the future on and off the filter's steps (pending, vanishing),
    held samples seen again; gyro outages with the held-rate walk. The branches are counted."""
    rng = np.random.default_rng(7)
    core = MultiplicativeEKF(ARW, RRW, innovation_gate_chi2=16.0)
    q_true = rot.rpy_to_quat([0.3, -0.2, 1.1])
    init = core.initial_state(q_true, np.zeros(3), 2 * DEG, 20 * DEG / 3600)
    q_BS = [rot.rpy_to_quat([0.1, 0.7, -0.4]), rot.rpy_to_quat([-1.0, 0.2, 2.0])]
    cov = np.diag((np.array([5.0, 5.0, 50.0]) * ARCSEC) ** 2)
    sensors = [QuaternionSensorModel("a", q_BS[0], cov), QuaternionSensorModel("b", q_BS[1], cov)]
    lag = 0.2
    systems = _pair(core, init, sensors, max_time_tag_lag_s=lag, held_rate_rrw_rad_per_s15=1e-4)
    w_true = np.array([0.01, -0.02, 0.015])
    last = {"a": [0.0, 1.0, 1.0, 0, 0, 0], "b": [0.0, 1.0, 1.0, 0, 0, 0]}
    outage = {"until": -1}

    def inputs(k, t):
        gyro = [t, 1.0, *(w_true + rng.normal(0, 1e-5, 3))]
        if k > outage["until"] + 3 and rng.uniform() < 0.1:
            outage["until"] = k + int(rng.integers(2, 8))
        if k <= outage["until"]:
            gyro[1] = 0.0
        out = {"gyro_measurement": gyro}
        for i, name in enumerate(("a", "b")):
            v = rng.uniform()
            tag = t
            if v < 0.15:
                tag = t - rng.uniform(0.01, lag)  # late within the lag
            elif v < 0.25:
                tag = t - rng.uniform(lag + 0.01, 0.45)  # beyond it
            elif v < 0.35:
                tag = t + rng.uniform(0.01, 0.45)  # future, off the steps
            elif v < 0.45:
                tag = t + PERIOD * int(rng.integers(1, 3))  # future, on a later step
            elif v < 0.55:
                out[f"q_meas_{name}"] = last[name]  # the same sample again
                continue
            q_meas = rot.quat_multiply(
                rot.quat_multiply(rot.quat_multiply(q_true, rot.rotvec_to_quat(w_true * tag)), q_BS[i]),
                rot.rotvec_to_quat(rng.normal(0, 1, 3) * np.sqrt(np.diag(cov))),
            )
            m = [tag, 1.0, *q_meas]
            last[name] = m
            out[f"q_meas_{name}"] = m
        return out

    counts = {"late": 0.0, "tag": 0.0}

    def count(system, context):
        handling = context.get_discrete_state(system._handling_group).value()
        counts["late"], counts["tag"] = handling[0], handling[1]

    (python, compiled), _ = _run(systems, inputs, 300, count)
    assert counts["late"] >= 30 and counts["tag"] >= 60, counts
    assert python[44] > 200 and python[45] > 60
    assert np.linalg.norm(rot.quat_error_rotvec(python[:4], compiled[:4])) < 1e-12
