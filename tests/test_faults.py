"""Fault injection: every fault kind does what it says, the faults
follow the seed, the injected truth is logged, every consumer reads the faulted sample, and
every library estimator survives every fault kind.

* Standalone :class:`~drake_att.systems.fault_injector.FaultInjector`: inputs FixValue'd, the sample
  decisions stepped with ``EvalUniquePeriodicDiscreteUpdate``; the stuck window's hold is
  abstract state changed by an unrestricted event, so that test runs a Simulator on the
  injector alone (inputs still FixValue'd, changed between samples).
* Expected outputs are written out here from the documented behaviour (the sample rotated by
  the outlier angle, one NaN, a clipped axis, ...), not taken from the library.
* Survival: one small scenario holding an instance of every library estimator, each sensor
  (gyro, quaternion tracker, vector tracker, camera) corrupted by every kind that applies to
  it, kinds 30 s apart; stated bound: every estimator's outputs stay finite and after every
  fault its attitude error is back within max(5x its pre-fault RMS, 0.05 deg) within
  ``RECOVERY_LIMIT_S`` = 15 s of the fault's end and stays there for 30 s or until the next
  fault (reached: at most 9 s). The floor: a filter whose gyro model allows almost no bias
  change (the indoor star tracker's, 0.1 deg/h^1.5) re-learns a 20 deg/h bias jump slowly,
  while its error stays below 0.05 deg.
* Gate: a 99.9% chi-square gate (16.27, 3 dof) rejects every 1 deg outlier of a 5 arcsec
  tracker, and its estimates stay within 0.05 deg of the same run without outliers (reached:
  0.02 deg, the missed updates), while an ungated MEKF accepts them, is pulled off by more
  than 0.5 deg (reached: 0.98 deg) and recovers within 3 s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_att import rotations as rot
from drake_att.analysis.fault_scores import (
    consumed_sensors,
    fault_events,
    finite_outputs,
    score_fault_events,
    summarize_fault_scores,
)
from drake_att.analysis.metrics import estimator_errors
from drake_att.contract import CameraCentroids, VectorObservations
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import ConfigError, load_scenario
from drake_att.scenarios.registry import ESTIMATOR, plugins
from drake_att.systems import fault_injector as flt
from drake_att.systems.fault_injector import FaultInjector, FaultModel

DEG = math.pi / 180.0  # written out here
SEED_A, SEED_B = np.array([0.11, 0.52, 0.23, 0.94]), np.array([0.61, 0.02, 0.73, 0.34])
RECOVERY_LIMIT_S = 15.0


# An MEKF without any gate (the library's default MEKF has one).
UNGATED = ", innovation_gate_probability: 0.0"


# ======================================================================================
# Standalone injector
# ======================================================================================
def _injector(kind, period_s=1.0, seed=SEED_A, **fields):
    inj = FaultInjector("inj", kind, period_s, FaultModel.make("inj", kind, **fields))
    ctx = inj.CreateDefaultContext()
    inj.GetInputPort("seed_uniform").FixValue(ctx, seed)
    return inj, ctx


def _value(port, ctx):
    v = port.Eval(ctx)
    return v.copy() if isinstance(v, np.ndarray) else v


def _run_decisions(inj, ctx, sample, n):
    """``[(measurement out, fault_truth)]`` of samples 0..n-1 (``sample(k, t)`` is the input):
    the initialization event decides sample 0, each periodic update the next one."""
    T = inj.period_s
    ctx.SetTime(0.0)
    inj.GetInputPort("sensor_measurement").FixValue(ctx, sample(0, 0.0))
    inj.ExecuteInitializationEvents(ctx)
    out = []
    for k in range(n):
        t = k * T
        ctx.SetTime(t)
        inj.GetInputPort("sensor_measurement").FixValue(ctx, sample(k, t))
        out.append((_value(inj.GetOutputPort("measurement"), ctx), inj.GetOutputPort("fault_truth").Eval(ctx).copy()))
        ctx.get_mutable_discrete_state().SetFrom(inj.EvalUniquePeriodicDiscreteUpdate(ctx))
    return out


def _truth_code(truth):
    return int(truth[flt.TRUTH_CODE])


def test_gyro_fault_kinds_on_a_standalone_injector():
    w = np.array([0.02, -0.005, 0.001])
    jump = np.array([1e-3, -2e-3, 0.0])
    inj, ctx = _injector(
        "gyro",
        outlier_times_s=(1.0,),
        outlier_size=0.01,
        nan_times_s=(2.0,),
        inf_times_s=(3.0,),
        dropout_times_s=(4.0,),
        time_tag_offset_s=0.25,
        time_tag_times_s=(5.0,),
        saturation_rad_per_s=0.015,
        saturation_windows_s=((6.0, 7.0),),
        bias_jump_times_s=(8.0,),
        bias_jumps_rad_per_s=(tuple(jump),),
        outage_windows_s=((10.0, 12.0),),
    )
    out = _run_decisions(inj, ctx, lambda k, t: np.r_[t, 1.0, w], 13)
    codes = [_truth_code(tr) for _, tr in out]
    assert codes == [0, 1, 2, 3, 5, 8, 6, 0, 7, 0, 5, 5, 0]
    for k, (m, tr) in enumerate(out):
        assert tr[flt.TRUTH_T_SAMPLE] == k and tr[flt.TRUTH_T_OUT] == m[0] and tr[flt.TRUTH_VALID_OUT] == m[1]
        if codes[k]:
            assert int(tr[flt.TRUTH_MASK]) == 1 << (codes[k] - 1)
    clean = [0, 7]
    for k in clean:
        np.testing.assert_array_equal(out[k][0], np.r_[k, 1.0, w])
    # outlier: w + 0.01 u, |u| = 1
    assert np.linalg.norm(out[1][0][2:] - w) == pytest.approx(0.01, rel=1e-12)
    assert out[1][1][flt.TRUTH_MAGNITUDE] == pytest.approx(0.01)
    # NaN / inf: exactly one number, the one the truth names; the others untouched
    for k, bad in ((2, np.isnan), (3, np.isinf)):
        m = out[k][0][2:]
        assert np.sum(bad(m)) == 1 and np.sum(~np.isfinite(m)) == 1
        i = int(np.flatnonzero(bad(m))[0])
        assert out[k][1][flt.TRUTH_MAGNITUDE] == i
        np.testing.assert_array_equal(np.delete(m, i), np.delete(w, i))
    # drop-out: invalid, numbers untouched; time tag: only t moves
    np.testing.assert_array_equal(out[4][0], np.r_[4.0, 0.0, w])
    np.testing.assert_array_equal(out[5][0], np.r_[5.25, 1.0, w])
    assert out[5][1][flt.TRUTH_MAGNITUDE] == 0.25
    # saturation: x clipped to the range, the excess reported; outside the window no clipping
    np.testing.assert_array_equal(out[6][0], np.r_[6.0, 1.0, 0.015, w[1], w[2]])
    assert out[6][1][flt.TRUTH_MAGNITUDE] == pytest.approx(0.005)
    # bias jump: from its sample on; its code only at the first sample; the total logged
    for k in (8, 9, 12):
        np.testing.assert_allclose(out[k][0][2:], w + jump, rtol=0, atol=1e-18)
        np.testing.assert_array_equal(out[k][1][flt.TRUTH_BIAS_JUMP], jump)
    assert out[8][1][flt.TRUTH_MAGNITUDE] == pytest.approx(np.linalg.norm(jump))
    np.testing.assert_array_equal(out[7][1][flt.TRUTH_BIAS_JUMP], 0.0)
    # outage: every sample of [10, 12) invalid, magnitude 1 (window), not 12
    assert [m[1] for m, _ in out[10:]] == [0.0, 0.0, 1.0]
    assert out[10][1][flt.TRUTH_MAGNITUDE] == 1.0 and out[4][1][flt.TRUTH_MAGNITUDE] == 0.0


def _rotation_between(a, b):
    """The rotation R with ``b = a R`` (rows), least squares, and its angle."""
    R, *_ = np.linalg.lstsq(a, b, rcond=None)
    return R, math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0)))


Q_IS = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
DIRS = np.array([[0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [-0.8, 0.0, 0.6]])
CENTROIDS = np.array([[1e-3, 2e-3], [-3e-3, 0.5e-3], [0.0, -1e-3], [2e-3, 2e-3]])
FOCAL = 0.012


def _attitude_sample(kind, k, t):
    if kind == "quaternion":
        return np.r_[t, 1.0, Q_IS]
    if kind == "vectors":
        return VectorObservations(float(t), True, DIRS.copy(), DIRS.copy(), 1e-4, np.array([1.0, 0.0, 0.0, 0.0]))
    return CameraCentroids(float(t), True, CENTROIDS.copy(), FOCAL, 1e-6)


def _numbers(kind, m):
    if kind == "quaternion":
        return m[2:]
    return m.directions_S if kind == "vectors" else m.centroids_m


def _header(kind, m):
    return (m[0], m[1]) if kind == "quaternion" else (m.time_s, bool(m.valid))


@pytest.mark.parametrize("kind", ["quaternion", "vectors", "camera"])
def test_attitude_fault_kinds_on_a_standalone_injector(kind):
    angle = 0.02
    inj, ctx = _injector(
        kind,
        period_s=0.5,
        outlier_times_s=(0.5,),
        outlier_size=angle,
        nan_times_s=(1.0,),
        inf_times_s=(1.5,),
        dropout_times_s=(2.0,),
        time_tag_offset_s=-0.1,
        time_tag_windows_s=((2.5, 3.5),),
    )
    out = _run_decisions(inj, ctx, lambda k, t: _attitude_sample(kind, k, t), 8)
    assert [_truth_code(tr) for _, tr in out] == [0, 1, 2, 3, 5, 8, 8, 0]
    clean = _numbers(kind, _attitude_sample(kind, 0, 0.0))
    np.testing.assert_array_equal(_numbers(kind, out[0][0]), clean)
    got = np.asarray(_numbers(kind, out[1][0]), dtype=float)
    if kind == "quaternion":
        # q_IS ⊗ exp(delta) with |delta| = angle: the relative rotation's angle
        dot = abs(float(got @ clean))
        assert 2.0 * math.acos(min(1.0, dot)) == pytest.approx(angle, rel=1e-9)
    elif kind == "vectors":
        R, a = _rotation_between(clean, got)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert a == pytest.approx(angle, rel=1e-9)
        assert out[1][0].references_I is not None and out[1][0].sigma_rad == 1e-4
    else:
        shift = got - clean
        np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-15)
        assert np.linalg.norm(shift[0]) == pytest.approx(FOCAL * math.tan(angle), rel=1e-12)
    for k, bad in ((2, np.isnan), (3, np.isinf)):
        m = np.asarray(_numbers(kind, out[k][0]), dtype=float).ravel()
        assert np.sum(bad(m)) == 1 and np.sum(~np.isfinite(m)) == 1
        np.testing.assert_array_equal(m[np.isfinite(m)], np.delete(np.ravel(clean), np.flatnonzero(bad(m))))
    assert _header(kind, out[4][0]) == (2.0, False)
    for k in (5, 6):
        t, valid = _header(kind, out[k][0])
        assert t == pytest.approx(k * 0.5 - 0.1, abs=1e-12) and valid
        np.testing.assert_array_equal(_numbers(kind, out[k][0]), clean)
    assert _header(kind, out[7][0]) == (3.5, True)


def _simulate_samples(inj, ctx, sample, n):
    """Outputs of samples 0..n-1 through a Simulator (unrestricted events included): after
    ``Initialize()`` and after ``AdvanceTo(t_k)``, k > 0, the context holds the state from
    before the updates at ``t_k`` (``AdvanceTo(0)`` would run the updates at 0)."""
    port = inj.GetInputPort("sensor_measurement")
    port.FixValue(ctx, sample(0, 0.0))
    sim = Simulator(inj, ctx)
    sim.Initialize()
    out = []
    for k in range(n):
        t = k * inj.period_s
        if k:
            sim.AdvanceTo(t)
        port.FixValue(sim.get_mutable_context(), sample(k, t))
        c = sim.get_context()
        out.append((_value(inj.GetOutputPort("measurement"), c), inj.GetOutputPort("fault_truth").Eval(c).copy()))
    return out


def test_stuck_output_repeats_the_last_clean_sample_before_the_window():
    jump = np.array([1e-4, 0.0, 0.0])
    ramp = lambda k, t: np.r_[t, 1.0, 1e-3 * k, -2e-3 * k, 0.5e-3]  # noqa: E731
    inj, ctx = _injector(
        "gyro",
        stuck_windows_s=((3.0, 6.0),),
        bias_jump_times_s=(2.0,),
        bias_jumps_rad_per_s=(tuple(jump),),
        outlier_times_s=(4.0,),
        outlier_size=0.1,
    )
    out = _simulate_samples(inj, ctx, ramp, 8)
    held = ramp(2, 2.0)[2:] + jump  # the last sample before the window, with the bias jump
    for k in (3, 5):
        np.testing.assert_allclose(out[k][0], np.r_[k, 1.0, held], rtol=0, atol=1e-18)
        assert _truth_code(out[k][1]) == flt.FAULT_STUCK and out[k][1][flt.TRUTH_MAGNITUDE] == k - 2
    # an outlier inside the window is applied to the held value (and outranks "stuck")
    assert np.linalg.norm(out[4][0][2:] - held) == pytest.approx(0.1)
    assert int(out[4][1][flt.TRUTH_MASK]) == (1 << 0) | (1 << 3)
    for k in (6, 7):
        np.testing.assert_allclose(out[k][0], np.r_[k, 1.0, ramp(k, k)[2:] + jump], rtol=0, atol=1e-18)
        assert _truth_code(out[k][1]) == 0

    # vector observations; a window from the first sample holds that sample
    def dirs(k, t):
        R = np.array(
            [[math.cos(0.1 * k), -math.sin(0.1 * k), 0.0], [math.sin(0.1 * k), math.cos(0.1 * k), 0.0], [0.0, 0.0, 1.0]]
        )
        return VectorObservations(float(t), True, DIRS @ R, DIRS.copy(), 1e-4, np.array([1.0, 0.0, 0.0, 0.0]))

    inj, ctx = _injector("vectors", period_s=0.5, stuck_windows_s=((0.0, 1.5),))
    out = _simulate_samples(inj, ctx, dirs, 5)
    for k in range(3):
        assert out[k][0].time_s == 0.5 * k
        np.testing.assert_array_equal(out[k][0].directions_S, dirs(0, 0.0).directions_S)
    np.testing.assert_array_equal(out[3][0].directions_S, dirs(3, 1.5).directions_S)
    assert [_truth_code(tr) for _, tr in out] == [0, 4, 4, 0, 0]  # sample 0 is itself, not held


def _masks(seed, n=400):
    inj, ctx = _injector(
        "gyro",
        seed=seed,
        outlier_probability=0.2,
        outlier_size=0.01,
        nan_probability=0.1,
        inf_probability=0.05,
        dropout_probability=0.1,
    )
    out = _run_decisions(inj, ctx, lambda k, t: np.r_[t, 1.0, 0.01, 0.02, 0.03], n)
    return np.array([int(tr[flt.TRUTH_MASK]) for _, tr in out]), np.array([m for m, _ in out])


def test_random_faults_are_a_function_of_the_seed():
    masks_a, out_a = _masks(SEED_A)
    masks_a2, out_a2 = _masks(SEED_A)
    masks_b, _ = _masks(SEED_B)
    np.testing.assert_array_equal(masks_a, masks_a2)
    np.testing.assert_array_equal(out_a, out_a2)
    assert np.mean(masks_a != masks_b) > 0.2
    n = len(masks_a)
    for code, p in ((flt.FAULT_OUTLIER, 0.2), (flt.FAULT_NAN, 0.1), (flt.FAULT_INF, 0.05), (flt.FAULT_DROPOUT, 0.1)):
        for masks in (masks_a, masks_b):
            rate = np.mean(masks & (1 << (code - 1)) > 0)
            assert abs(rate - p) < 4.0 * math.sqrt(p * (1 - p) / n), (code, rate)
    # outliers point in random directions (not one fixed axis)
    d = out_a[(masks_a & 1) > 0][:, 2:] - np.array([0.01, 0.02, 0.03])
    d = d[np.all(np.isfinite(d), axis=1)]
    assert np.linalg.norm(np.mean(d / np.linalg.norm(d, axis=1)[:, None], axis=0)) < 0.3


# ======================================================================================
# Configuration
# ======================================================================================
BASE = """
name: faults_small
duration_s: 40.0
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}}
plant: !RigidBodyConfig {{inertia_kg_m2: [0.042, 0.042, 0.0067], initial_rate_deg_per_s: [-0.5, 0.5, 0.5],
                          disturbance_torque_N_m: [0.0, 0.0, 0.0]}}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.56, rrw_deg_per_h15: 10.0,
               initial_bias_deg_per_h: [12.0, 12.0, 12.0]}}
{gyro_faults}
- !StarTrackerConfig {{name: st1, period_s: 0.1, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0,
                      mounting: !PaperS3Eq7Mounting {{psi_phi_theta_deg: [-90.0, 45.0, -90.0]}}}}
{st1_faults}
- !StarTrackerConfig {{name: st2, period_s: 0.1, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0,
                      mounting: !PaperS3Eq7Mounting {{psi_phi_theta_deg: [90.0, 45.0, 90.0]}}}}
- !StarTrackerAverageConfig {{name: st_avg, star_trackers: [st1, st2]}}
{late_faults}
estimators:
- !MekfConfig {{name: single, star_trackers: [st1], initial_attitude_sigma_deg: 0.1{ungated}}}
- !MekfConfig {{name: centralized, star_trackers: [st_avg], initial_attitude_sigma_deg: 0.1{ungated}}}
- !MekfConfig {{name: joint, star_trackers: [st1, st2], initial_attitude_sigma_deg: 0.1{ungated}}}
- !MekfConfig {{name: single_st2, star_trackers: [st2], initial_attitude_sigma_deg: 0.1{ungated}}}
- !EstimateFusionConfig {{name: decentralized, sources: [single, single_st2], covariance_model: tracked}}
scoring: {{score_from_s: 5.0}}
"""
ST1_FAULTS = (
    "- !SensorFaultsConfig {name: st1_faults, sensor: st1, nan_times_s: [10.0], outlier_times_s: [20.0],\n"
    "                       outlier_angle_deg: 0.01, outage_windows_s: [[30.0, 33.0]]}"
)


def _scenario_text(gyro_faults="", st1_faults=ST1_FAULTS, late_faults=""):
    return BASE.format(gyro_faults=gyro_faults, st1_faults=st1_faults, late_faults=late_faults, ungated=UNGATED)


@pytest.mark.parametrize(
    "entry, where, message",
    [
        (
            "{name: f, sensor: nosuch}",
            "st1_faults",
            "sensors[2] (f).sensor: got 'nosuch'; must name a sensor listed before",
        ),
        ("{name: f, sensor: st2}", "st1_faults", "must name a sensor listed before it"),
        ("{name: f, sensor: st1}", "late_faults", "'st_avg' (listed before this entry) reads it"),
        ("{name: f, sensor: st1, saturation_deg_per_s: 1.0}", "st1_faults", "only a gyro saturates; 'st1' outputs"),
        (
            "{name: f, sensor: st1, bias_jump_times_s: [1.0], bias_jumps_deg_per_h: [[1.0, 0.0, 0.0]]}",
            "st1_faults",
            "bias_jump_times_s: got [1.0]; only a gyro has bias jumps",
        ),
        (
            "{name: f, sensor: gyro, bias_jump_times_s: [1.0, 2.0], bias_jumps_deg_per_h: [[1.0, 0.0, 0.0]]}",
            "gyro_faults",
            "need one row [x, y, z] (deg/h) per bias_jump_times_s entry (2)",
        ),
        (
            "{name: f, sensor: st1, outlier_probability: 1.0}",
            "st1_faults",
            "outlier_probability: got 1.0; must be in [0, 1)",
        ),
        (
            "{name: f, sensor: st1, outage_windows_s: [[5.0, 4.0]]}",
            "st1_faults",
            "outage_windows_s[0]: got [5. 4.]; must be [start, end] (s), finite, with end > start",
        ),
        (
            "{name: f, sensor: st1, time_tag_times_s: [3.0]}",
            "st1_faults",
            "time_tag_offset_s: got 0.0; time-tag errors need a non-zero offset (s)",
        ),
        (
            "{name: f, sensor: st1, outlier_times_s: [3.0], outlier_angle_deg: 200.0}",
            "st1_faults",
            "outlier_angle_deg: got 200.0; an attitude outlier is a rotation angle in (0, 180) deg",
        ),
        (
            "{name: f, sensor: gyro, outlier_times_s: [3.0], outlier_rate_deg_per_s: 0.0}",
            "gyro_faults",
            "outlier_rate_deg_per_s: got 0.0; gyro outliers need a size > 0 (deg/s)",
        ),
        ("{name: f, sensor: gyro, nan_times_s: [-1.0]}", "gyro_faults", "nan_times_s[0]: got -1.0; must be >= 0"),
        (
            "{name: f, sensor: gyro, saturation_windows_s: [[1.0, 2.0]]}",
            "gyro_faults",
            "saturation_windows_s: got [[1. 2.]]; needs saturation_deg_per_s",
        ),
    ],
)
def test_invalid_fault_configs_name_the_field_the_value_and_what_is_allowed(entry, where, message):
    slots = {"gyro_faults": "", "st1_faults": "", "late_faults": ""}
    slots[where] = "- !SensorFaultsConfig " + entry
    with pytest.raises(ConfigError) as e:
        load_scenario(text=_scenario_text(**slots))
    assert message in str(e.value)


def test_one_fault_entry_per_sensor():
    two = ST1_FAULTS + "\n- !SensorFaultsConfig {name: again, sensor: st1}"
    with pytest.raises(ConfigError, match="'st1_faults' already injects faults into it"):
        load_scenario(text=_scenario_text(st1_faults=two))


# ======================================================================================
# Through a scenario
# ======================================================================================
@pytest.fixture(scope="module")
def small():
    return ScenarioDiagram(load_scenario(text=_scenario_text()))


def test_every_consumer_reads_the_faulted_sample_and_the_truth_is_logged(small):
    run = small.simulate(3)
    # The tracker's own log is clean; the injector's truth names each fault.
    t_st1, st1 = run.signals["st1/star_tracker_measurement"]
    assert np.all(np.isfinite(st1)) and np.all(st1[:, 1] == 1.0)
    events = [(e.sensor, e.kind, round(e.t_start, 6), round(e.t_end, 6)) for e in fault_events(run)]
    assert events == [("st1", "nan", 10.0, 10.0), ("st1", "outlier", 20.0, 20.0), ("st1", "outage", 30.0, 32.9)]
    truth = run.values("st1_faults/fault_truth")
    assert np.all(truth[(truth[:, 0] > 30.0 - 1e-9) & (truth[:, 0] < 33.0 - 1e-9), flt.TRUTH_VALID_OUT] == 0.0)
    # sensor_output still describes the tracker itself
    from drake_att.scenarios.build_context import BuildContext

    ctx = BuildContext(None, small.scenario, small.truth, sensor_configs={s.name: s for s in small.scenario.sensors})
    out = ctx.sensor_output("st1")
    assert (out.kind, out.port, out.period_s) == ("quaternion", "star_tracker_measurement", 0.1)
    assert consumed_sensors(small.scenario, "centralized") == {"gyro", "st_avg", "st1", "st2"}
    assert consumed_sensors(small.scenario, "decentralized") == {"gyro", "st1", "st2"}

    # The NaN sample is skipped by every direct reader of st1 at t = 10; the average carries
    # st2 alone at that step (flag 1 + mask, its own covariance), so the centralized MEKF
    # skips nothing.
    def skipped_at(name, t):
        e = estimator_errors(run, name)
        i = int(np.flatnonzero(np.abs(e["t"] - t) < 1e-6)[0])
        return e["status"][i, 2] - e["status"][i - 1, 2]

    for name in ("single", "joint"):
        assert skipped_at(name, 10.0) == 1, name
    assert skipped_at("centralized", 10.0) == 0
    assert skipped_at("single_st2", 10.0) == 0
    rows = {(r["estimator"], r["kind"]): r for r in score_fault_events(run)}
    assert rows[("single", "nan")]["rejected"] == 1 and rows[("single", "outage")]["rejected"] == 3
    assert rows[("single", "outlier")]["accepted"] == 1  # 0.01 deg: an ungated MEKF takes it
    assert not rows[("single_st2", "nan")]["seen"]
    assert rows[("decentralized", "outage")]["steps"] == 3

    # Fault fields are context parameters: cleared on the same diagram, the run is the clean
    # one; what does not read st1 is bit-identical, what does differs.
    cleared = small.simulate(
        3,
        overrides=[
            "sensors.st1_faults.nan_times_s=[]",
            "sensors.st1_faults.outlier_times_s=[]",
            "sensors.st1_faults.outage_windows_s=[]",
        ],
    )
    assert fault_events(cleared) == []
    np.testing.assert_array_equal(cleared.values("single_st2/q_IB_hat"), run.values("single_st2/q_IB_hat"))
    assert not np.array_equal(cleared.values("single/q_IB_hat"), run.values("single/q_IB_hat"))
    with pytest.raises(ConfigError, match=r"sensors.st1_faults.sensor \(structural; st1_faults.s per-run fields: "):
        small.simulate(3, overrides=["sensors.st1_faults.sensor=gyro"])


GATE_SCENARIO = """
name: gate
duration_s: 330.0
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}}
plant: !RigidBodyConfig {{inertia_kg_m2: [0.042, 0.042, 0.0067], initial_rate_deg_per_s: [-0.5, 0.5, 0.5],
                          disturbance_torque_N_m: [0.0, 0.0, 0.0]}}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.56, rrw_deg_per_h15: 123.75,
               initial_bias_deg_per_h: [12.0, 12.0, 12.0]}}
- !StarTrackerConfig {{name: st1, period_s: 0.1, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}}
- !SensorFaultsConfig {{name: st1_faults, sensor: st1, outlier_times_s: [{times}], outlier_angle_deg: 1.0}}
estimators:
- !MekfConfig {{name: gated, star_trackers: [st1], innovation_gate_chi2: 16.27}}
- !MekfConfig {{name: ungated, star_trackers: [st1]{ungated}}}
"""


def test_a_chi_square_gate_rejects_outliers_that_pull_an_ungated_mekf_off():
    times = [100.0, 150.0, 200.0, 250.0, 300.0]
    sd = ScenarioDiagram(load_scenario(text=GATE_SCENARIO.format(times=", ".join(map(str, times)), ungated=UNGATED)))
    run = sd.simulate(1)
    rows = score_fault_events(run)
    gated = [r for r in rows if r["estimator"] == "gated"]
    ungated = [r for r in rows if r["estimator"] == "ungated"]
    assert [r["t_start"] for r in gated] == pytest.approx(times)
    for r in gated:
        assert (r["steps"], r["rejected"], r["accepted"], r["detected"]) == (1, 1, 0, 1)
        assert r["recovery_time_s"] == 0.0
    # Against the same run without outliers (same diagram and seed): a rejected outlier costs
    # the gated filter one update (0.02 deg reached), an accepted one pulls the other off.
    clean = sd.simulate(1, overrides=["sensors.st1_faults.outlier_times_s=[]"])

    def deviation_deg(name):
        d = rot.quat_error_rotvec(run.values(f"{name}/q_IB_hat"), clean.values(f"{name}/q_IB_hat"))
        return float(np.max(np.linalg.norm(d, axis=1))) / DEG

    assert deviation_deg("gated") < 0.05 and deviation_deg("ungated") > 0.5
    for r in ungated:
        assert (r["steps"], r["rejected"], r["accepted"], r["detected"]) == (1, 0, 1, 1)  # its NIS flags it
        assert r["peak_error_deg"] > 0.1
        assert r["recovery_time_s"] is not None and r["recovery_time_s"] <= RECOVERY_LIMIT_S


# ======================================================================================
# Survival: every library estimator, every fault kind
# ======================================================================================
SURVIVAL_KINDS = ["outlier", "nan", "inf", "stuck", "outage", "dropout", "time_tag", "saturation", "bias_jump"]
SPACING_S, FIRST_S, WINDOW_S = 30.0, 30.0, 4.0
T_KIND = {k: FIRST_S + SPACING_S * i for i, k in enumerate(SURVIVAL_KINDS)}


def _every_kind(extra: str) -> str:
    t = T_KIND
    return (
        "{" + f"outlier_times_s: [{t['outlier']}], nan_times_s: [{t['nan']}], inf_times_s: [{t['inf']}], "
        f"stuck_windows_s: [[{t['stuck']}, {t['stuck'] + WINDOW_S}]], "
        f"outage_windows_s: [[{t['outage']}, {t['outage'] + WINDOW_S}]], dropout_times_s: [{t['dropout']}], "
        f"time_tag_offset_s: 0.5, time_tag_windows_s: [[{t['time_tag']}, {t['time_tag'] + WINDOW_S}]], " + extra + "}"
    )


SURVIVAL_SCENARIO = f"""
name: fault_survival
duration_s: {FIRST_S + SPACING_S * len(SURVIVAL_KINDS)}
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 1.0}}
plant: !RigidBodyConfig {{inertia_kg_m2: [100.0, 200.0, 200.0], initial_rate_deg_per_s: [0.02, -0.01, 0.03],
                          disturbance_torque_N_m: [0.0, 0.0, 0.0]}}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 0.1}}
- !SensorFaultsConfig {
    _every_kind(
        "name: gyro_faults, sensor: gyro, outlier_rate_deg_per_s: 0.2, saturation_deg_per_s: 0.01, "
        f"saturation_windows_s: [[{T_KIND['saturation']}, {T_KIND['saturation'] + WINDOW_S}]], "
        f"bias_jump_times_s: [{T_KIND['bias_jump']}], bias_jumps_deg_per_h: [[20.0, -10.0, 10.0]]"
    )
}
- !StarTrackerConfig {{name: stq, period_s: 1.0, mode: quaternion, sigma_cross_boresight_arcsec: 5.0,
                      sigma_boresight_arcsec: 50.0}}
- !SensorFaultsConfig {_every_kind("name: stq_faults, sensor: stq, outlier_angle_deg: 1.0")}
- !StarTrackerConfig {{name: stv, period_s: 1.0, mode: vectors, references_I: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                      sigma_vector_urad: 1000.0}}
- !SensorFaultsConfig {_every_kind("name: stv_faults, sensor: stv, outlier_angle_deg: 1.0")}
- !ScreenCameraConfig {{name: cam, period_s: 1.0, star_count: 12, centroid_noise_px: 0.1}}
- !SensorFaultsConfig {_every_kind("name: cam_faults, sensor: cam, outlier_angle_deg: 1.0")}
estimators:
- !MekfConfig {{name: mekf, star_trackers: [stq, stv]}}
- !MekfConfig {{name: mekf_q, star_trackers: [stq]}}
- !MekfConfig {{name: mekf_gated, star_trackers: [stq], innovation_gate_chi2: 16.27}}
- !EstimateFusionConfig {{name: fusion, sources: [mekf, mekf_q]}}
- !MrpEkfConfig {{name: mrp_ekf, star_tracker: stv}}
- !BootstrapPfConfig {{name: bootstrap_pf, star_tracker: stv, num_particles: 50, bias_roughening_deg_per_h_per_rt_s: 0.05}}
- !EkpfConfig {{name: ekpf, star_tracker: stv, num_particles: 20}}
- !GyrolessPfConfig {{name: gyroless_pf, star_tracker: stv, num_particles: 50, initial_rate_deg_per_s: [0.02, -0.01, 0.03]}}
- !LieGroupConfig {{name: lie_group, star_tracker: stv}}
- !QuaternionEkfConfig {{name: quaternion_ekf, star_tracker: stv}}
- !CubatureQuaternionConfig {{name: cqe, star_tracker: stv}}
- !IndoorStarTrackerConfig {{name: indoor, camera: cam, period_s: 1.0}}
- !IndoorStarTrackerConfig {{name: indoor_gyro, camera: cam, gyro: gyro, period_s: 1.0}}
"""


@pytest.mark.slow
def test_every_library_estimator_survives_every_fault_kind():
    scenario = load_scenario(text=SURVIVAL_SCENARIO)
    library = {tag for tag, p in plugins(ESTIMATOR).items() if p.module.startswith("drake_att.")}
    assert library <= {type(e).__name__ for e in scenario.estimators}, "add the new estimator to SURVIVAL_SCENARIO"
    run = ScenarioDiagram(scenario).simulate(1)
    rows = score_fault_events(run, bound_floor_deg=0.05)
    kinds = {e.kind for e in fault_events(run)}
    assert kinds == set(flt.FAULT_NAMES.values()) | {"outage"}  # every kind was injected (and logged)
    for name in run.metadata["estimators"]:
        assert finite_outputs(run, name), name
        mine = [r for r in rows if r["estimator"] == name]
        late = [
            (r["sensor"], r["kind"], r["recovery_time_s"])
            for r in mine
            if r["recovery_time_s"] is None or r["recovery_time_s"] > RECOVERY_LIMIT_S
        ]
        assert not late, (name, late)
        seen = {r["kind"] for r in mine if r["seen"]}
        reads = consumed_sensors(run.scenario, name)
        expected = {"outlier", "nan", "inf", "stuck", "outage", "dropout", "time_tag"}
        if "gyro" in reads:
            expected |= {"saturated", "bias_jump"}
        assert expected <= seen, (name, expected - seen)
    summary = summarize_fault_scores([rows])
    assert all(g["recovered"] == g["events"] for g in summary)


# ======================================================================================
# The campaign script
# ======================================================================================
@pytest.mark.slow
def test_fault_campaign_script_short_run(tmp_path, load_script, diagram_builds):
    """diagrams/fault_campaign.py on its first two faults (gyro outlier at 300 s, NaN at 450 s):
    one diagram, strict results.json with the verdicts, the table and the matrix of docs/guide/faults.md."""
    import json

    script = load_script("fault_campaign")
    assert (
        script.main(["--seeds", "1", "--duration", "560", "--workers", "1", "--no-figure", "--out", str(tmp_path)]) == 0
    )
    assert diagram_builds == ["fault_campaign"]
    with open(tmp_path / "results.json") as f:
        results = json.load(f, parse_constant=lambda c: pytest.fail(f"results.json holds {c}"))
    assert [(e["sensor"], e["kind"]) for e in results["per_seed"][0]["events"]] == [
        ("gyro", "outlier"),
        ("gyro", "nan"),
    ]
    assert all(results["verdicts"]["claims"].values()), results["verdicts"]
    gates = results["gates"]
    assert gates["single"] == "none" and gates["single_gated"] == "chi2 16.27" and gates["decentralized"] == "-"
    matrix = (tmp_path / "table.md").read_text().splitlines()
    assert matrix[0] == "| fault | " + " | ".join(gates) + " |" and len(matrix) == 4
    assert matrix[3].startswith("| gyro nan | rej ")
