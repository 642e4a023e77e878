"""The sensor monitor's detectors on a standalone system: known samples in, the known verdict
at the known instant out (frozen output, pinned axis, gyro range, the consistency vote,
re-admission), the vote's false-alarm rate against its chi-square threshold, and the bad
configurations refused in one line.

Expected values are computed here from the definitions (rotation vectors by scipy, the
chi-square quantile by scipy.stats), not with the monitor's helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from drake_att import fdir
from drake_att.scenarios.config import load_scenario
from drake_att.scenarios.library import load
from drake_att.systems.sensor_monitor import SensorMonitor
from drake_att.validation import ConfigError

DEG = math.pi / 180.0
ARCSEC = DEG / 3600.0
T = 1.0
W_BODY = np.array([0.02, -0.03, 0.04])  # rad/s, constant body rate of the scripted truth


class Script(LeafSystem):
    """Outputs row k of ``rows`` for t in ((k-1) T, k T] (a sensor's sample-and-hold)."""

    def __init__(self, rows):
        LeafSystem.__init__(self)
        self.rows = np.asarray(rows, dtype=float)
        self.DeclareVectorOutputPort("y", self.rows.shape[1], self._calc, {self.time_ticket()})

    def _calc(self, context, output):
        k = max(0, math.ceil(context.get_time() / T - 1e-9))
        output.SetFromVector(self.rows[min(k, len(self.rows) - 1)])


def wxyz(r: Rotation) -> np.ndarray:
    x, y, z, w = r.as_quat()
    return np.array([w, x, y, z])


def truth(k: int) -> Rotation:
    """Body attitude at sample k: a constant rate from a fixed start."""
    return Rotation.from_rotvec([0.3, -0.2, 0.1]) * Rotation.from_rotvec(W_BODY * k * T)


MOUNTS = (Rotation.from_euler("xyz", [90, 0, 0], degrees=True), Rotation.from_euler("xyz", [0, 90, 0], degrees=True))
SIGMA_S = np.array([5.0, 5.0, 50.0]) * ARCSEC


def tracker_rows(n: int, mount: Rotation, rng, edits=None) -> np.ndarray:
    """``[t, 1, q_IS]`` per sample with the tracker's noise; ``edits[k] = rotation`` applied to sample k."""
    rows = []
    for k in range(n):
        noise = Rotation.from_rotvec(rng.normal(size=3) * SIGMA_S)
        q = truth(k) * mount * noise
        if edits and k in edits:
            q = edits[k](k, q)
        rows.append([k * T, 1.0, *wxyz(q)])
    return np.array(rows)


def gyro_rows(n: int, rng, arw: float, edits=None) -> np.ndarray:
    rows = []
    for k in range(n):
        w = W_BODY + rng.normal(size=3) * arw / math.sqrt(T)
        if edits and k in edits:
            w = edits[k](k, w)
        rows.append([k * T, 1.0, *w])
    return np.array(rows)


def model(readmit_after_s=3.0, frozen_window_s=1.0, gyro_range=math.inf, p=1e-6, tolerance_deg_per_s=0.05, arw=1e-4):
    trackers = [
        fdir.TrackerModel(f"st{i + 1}", wxyz(m), m.as_matrix() @ np.diag(SIGMA_S**2) @ m.as_matrix().T)
        for i, m in enumerate(MOUNTS)
    ]
    return fdir.MonitorModel.make(
        "monitor", trackers, True, T, frozen_window_s, readmit_after_s, p, arw, tolerance_deg_per_s * DEG, gyro_range
    )


def run_monitor(m, gyro, st1, st2) -> np.ndarray:
    """The detector log at every instant, read as an estimator stepping then would read it."""
    builder = DiagramBuilder()
    monitor = builder.AddSystem(SensorMonitor(m, "gyro"))
    for name, rows in (("gyro_measurement", gyro), ("q_meas_st1", st1), ("q_meas_st2", st2)):
        src = builder.AddSystem(Script(rows))
        builder.Connect(src.get_output_port(), monitor.GetInputPort(name))
    diagram = builder.Build()
    sim = Simulator(diagram)
    ctx = monitor.GetMyContextFromRoot(sim.get_mutable_context())
    logs = []
    for k in range(len(gyro)):
        sim.AdvanceTo(k * T)  # the updates at k T run at the next call: the outputs are sample k's
        logs.append(monitor.GetOutputPort("detector_log").Eval(ctx).copy())
    return np.array(logs).reshape(len(gyro), 3, 3)  # [k, sensor (gyro, st1, st2), (verdict, cause, count)]


def nominal(n=20, seed=0, arw=1e-4, gyro_edits=None, st1_edits=None, st2_edits=None):
    rng = np.random.default_rng(seed)
    return (
        gyro_rows(n, rng, arw, gyro_edits),
        tracker_rows(n, MOUNTS[0], rng, st1_edits),
        tracker_rows(n, MOUNTS[1], rng, st2_edits),
    )


def test_nominal_samples_are_all_confirmed_and_nothing_is_excluded():
    log = run_monitor(model(), *nominal(n=30))
    assert np.all(log[:, :, 1] == fdir.CAUSE_NONE)
    assert np.all(log[:, :, 2] == 0)
    # the gyro votes from the second instant on (it needs the first instant's reference)
    assert np.all(log[1:, :, 0] == fdir.CONFIRMED) and np.all(log[0, 1:, 0] == fdir.CONFIRMED)


def test_frozen_tracker_is_excluded_at_its_first_repeat_and_readmitted_after_a_clean_window():
    gyro, st1, st2 = nominal(n=25)
    st1[8:14, 2:] = st1[7, 2:]  # samples 8..13 repeat sample 7's numbers (current time tags)
    log = run_monitor(model(readmit_after_s=3.0), gyro, st1, st2)
    causes, verdicts = log[:, 1, 1], log[:, 1, 0]
    # window = period: the first repeat is frozen
    assert np.all(causes[:8] == fdir.CAUSE_NONE) and np.all(causes[8:14] == fdir.CAUSE_FROZEN)
    assert np.all(verdicts[8:14] == fdir.EXCLUDED)
    # clean from sample 14: re-admitted once the clean time reaches 3 s (14, 15, 16, 17)
    assert np.all(verdicts[14:17] == fdir.EXCLUDED) and verdicts[17] == fdir.CONFIRMED
    assert log[-1, 1, 2] == 1  # one exclusion
    assert np.all(log[:, 2, 1] == 0) and np.all(log[:, 0, 1] == 0)  # the others never accused


def test_frozen_detector_alone_fires_after_its_window_on_a_still_sensor():
    """No vote can see a repeat of a still body's attitude: the window decides (3 s here)."""
    rng = np.random.default_rng(3)
    rest = Rotation.from_rotvec([0.3, -0.2, 0.1])
    gyro = np.array([[k * T, 1.0, *(rng.normal(size=3) * 1e-4)] for k in range(15)])
    st1, st2 = (
        np.array(
            [[k * T, 1.0, *wxyz(rest * mount * Rotation.from_rotvec(rng.normal(size=3) * SIGMA_S))] for k in range(15)]
        )
        for mount in MOUNTS
    )
    st1[5:, 2:] = st1[4, 2:]
    m = model(frozen_window_s=3.0)
    log = run_monitor(m, gyro, st1, st2)
    causes = log[:, 1, 1]
    # unchanged since sample 4: 1 s at 5, 2 s at 6, 3 s at 7 -> frozen from sample 7
    assert np.all(causes[:7] == fdir.CAUSE_NONE), causes
    assert np.all(causes[7:] == fdir.CAUSE_FROZEN)


def test_pinned_gyro_axis_and_range_check():
    # x axis pinned at 0.6 deg/s from sample 6 to 11 (a saturation below the true 1.15 deg/s)
    pin = 0.6 * DEG

    def pinned(k, w):
        return np.array([min(w[0], pin), w[1], w[2]])

    gyro, st1, st2 = nominal(n=20, gyro_edits={k: pinned for k in range(6, 12)})
    log = run_monitor(model(readmit_after_s=2.0), gyro, st1, st2)
    causes = log[:, 0, 1]
    assert causes[6] == fdir.CAUSE_VOTE  # 0.55 deg/s too low on x: the trackers outvote it
    assert np.all(causes[7:12] == fdir.CAUSE_PINNED)
    assert np.all(causes[12:] == fdir.CAUSE_NONE)
    assert np.all(log[6:14, 0, 0] == fdir.EXCLUDED) and log[14, 0, 0] == fdir.CONFIRMED
    # a gyro whose range is 3 deg/s, at its limit on x at sample 6 only: RANGE there, nowhere else
    limit = 3.0 * DEG
    gyro, st1, st2 = nominal(n=12, gyro_edits={6: lambda k, w: np.array([limit, w[1], w[2]])})
    log = run_monitor(model(gyro_range=limit), gyro, st1, st2)
    assert log[6, 0, 1] == fdir.CAUSE_RANGE
    assert np.all(np.delete(log[:, 0, 1], 6) == fdir.CAUSE_NONE)


def test_vote_isolates_a_tracker_outlier_and_a_gyro_outlier():
    kick = Rotation.from_rotvec([0.0, 1.0 * DEG, 0.0])
    gyro, st1, st2 = nominal(
        n=20,
        st1_edits={5: lambda k, q: q * kick},
        gyro_edits={12: lambda k, w: w + np.array([0.5 * DEG, 0.0, 0.0])},
    )
    log = run_monitor(model(readmit_after_s=2.0), gyro, st1, st2)
    assert log[5, 1, 1] == fdir.CAUSE_VOTE and log[5, 2, 0] == fdir.CONFIRMED and log[5, 0, 0] == fdir.CONFIRMED
    assert np.all(log[5:8, 1, 0] == fdir.EXCLUDED) and log[8, 1, 0] == fdir.CONFIRMED
    assert log[12, 0, 1] == fdir.CAUSE_VOTE and log[12, 1, 0] == fdir.CONFIRMED and log[12, 2, 0] == fdir.CONFIRMED
    others = np.ones(20, dtype=bool)
    others[[5, 12]] = False
    assert np.all(log[others, :, 1] == fdir.CAUSE_NONE)


def test_two_disagreeing_voters_accuse_no_one():
    """A tracker outlier while the gyro is out: st1 and st2 disagree and nobody can say which."""
    kick = Rotation.from_rotvec([1.0 * DEG, 0.0, 0.0])
    gyro, st1, st2 = nominal(n=10, st1_edits={5: lambda k, q: q * kick})
    gyro[5, 1] = 0.0  # the gyro's sample at 5 is flagged invalid
    log = run_monitor(model(), gyro, st1, st2)
    assert np.all(log[5, :, 1] == fdir.CAUSE_NONE)
    assert np.all(log[5, :, 0] == fdir.UNASSESSED)


def test_bias_jump_within_the_tolerance_is_left_to_the_estimators():
    jump = np.array([100.0, -100.0, 50.0]) * DEG / 3600.0
    gyro, st1, st2 = nominal(n=30, gyro_edits={k: (lambda k, w: w + jump) for k in range(10, 30)})
    log = run_monitor(model(), gyro, st1, st2)
    assert np.all(log[:, :, 1] == fdir.CAUSE_NONE)


def test_pairwise_test_false_alarm_rate_matches_its_chi_square_quantile():
    """Consistent attitudes with the stated covariances: the test rejects a fraction p."""
    rng = np.random.default_rng(7)
    p, n = 0.02, 8000
    threshold = chi2.ppf(1 - p, 3)
    C_a = np.diag([1.0, 4.0, 0.25]) * 1e-8
    C_b = np.diag([9.0, 1.0, 1.0]) * 1e-8
    base = Rotation.random(random_state=1)
    rejected = 0
    for _ in range(n):
        a = base * Rotation.from_rotvec(rng.multivariate_normal(np.zeros(3), C_a))
        b = base * Rotation.from_rotvec(rng.multivariate_normal(np.zeros(3), C_b))
        rejected += not fdir.consistent(wxyz(a), C_a, wxyz(b), C_b, threshold)
    sd = math.sqrt(p * (1 - p) / n)
    assert abs(rejected / n - p) < 4 * sd, rejected / n
    assert abs(model(p=p).threshold - threshold) < 1e-9 * threshold


def _with_monitor(**fields) -> str:
    from drake_att.scenarios.config import dump_scenario

    text = dump_scenario(load("fault_campaign"))
    entry = {"name": "fdir2", "star_trackers": "[st1, st2]", **fields}
    lines = "".join(f"\n  {k}: {v}" for k, v in entry.items())
    return text.replace(
        "- !StarTrackerAverageConfig", "- !SensorMonitorConfig" + lines + "\n- !StarTrackerAverageConfig", 1
    )


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"frozen_window_s": 5000.0}, "frozen_window_s: got 5000"),
        ({"frozen_window_s": 0.5}, "frozen_window_s: got 0.5"),
        ({"readmit_after_s": -1.0}, "readmit_after_s: got -1"),
        ({"false_alarm_probability": 0.7}, "false_alarm_probability: got 0.7"),
        ({"gyro": "st1"}, "gyro: got 'st1'"),
        ({"star_trackers": "[st1, gyro]"}, "star_trackers: got 'gyro'"),
        ({"period_s": 2.5}, "period_s: got 2.5"),
    ],
)
def test_bad_monitor_config_is_one_line(fields, message):
    with pytest.raises(ConfigError) as e:
        load_scenario(_with_monitor(**fields))
    text = str(e.value)
    assert message in text and "\n" not in text, text


GYRO_RANGE_SCENARIO = """
name: gyro_range
duration_s: 20.0
seed: 1
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  initial_rate_deg_per_s: [2.0, -0.5, 0.3]
sensors:
- !GyroConfig {name: gyro, period_s: 1.0, range_deg_per_s: 1.0}
- !StarTrackerConfig {name: st1, period_s: 1.0, mode: quaternion, sigma_cross_boresight_arcsec: 5.0,
                      sigma_boresight_arcsec: 50.0}
- !SensorMonitorConfig {name: fdir, gyro: gyro, star_trackers: [st1], bias_window_s: 0.0}
estimators:
- !MekfConfig {name: mekf, gyro: gyro, star_trackers: [st1]}
scoring: {score_from_s: 5.0}
"""


def test_gyro_output_is_clipped_at_its_range_and_the_monitor_flags_it():
    from drake_att.scenarios.builder import diagram_for

    run = diagram_for(load_scenario(GYRO_RANGE_SCENARIO)).simulate(seed=1)
    t_g, g = run.signals["gyro/gyro_measurement"]
    g = np.asarray(g).reshape(len(t_g), -1)
    t_w, w = run.signals["rigid_body_plant/w_IB_B"]
    w = np.asarray(w).reshape(len(t_w), -1)
    limit = 1.0 * DEG
    x = g[1:, 2]  # the x rate: the true one is ~2 deg/s (noise-free gyro, no bias)
    assert np.all(np.abs(g[:, 2:5]) <= limit + 1e-15)
    assert np.all(x == limit)  # pinned at the range, exactly
    # the unclipped axes are the true mean rates (|y|, |z| < 1 deg/s): within the interval's change
    idx = np.searchsorted(t_w, np.asarray(t_g)[1:] - 1e-9)
    assert np.allclose(g[1:, 3:5], w[idx, 1:3], atol=0.02 * DEG)
    t_log, log = run.signals["fdir/detector_log"]
    log = np.asarray(log).reshape(len(t_log), -1)
    causes = log[np.asarray(t_log) > 0.5, 1]
    assert np.all(causes == fdir.CAUSE_RANGE)


@pytest.mark.parametrize(
    "bad",
    [
        [5.0, 1.0, 0.0, 0.0, 0.0, 0.0],  # a zero quaternion flagged valid
        [5.0, 1.0, np.nan, 1.0, 0.0, 0.0],
        [5.0, np.nan, 1.0, 0.0, 0.0, 0.0],
        [np.nan, 1.0, 1.0, 0.0, 0.0, 0.0],
        [5.0, 1.0, 1e300, 1e300, 0.0, 0.0],
        [5.0, 1.0, np.inf, 0.0, 0.0, 0.0],
    ],
)
def test_hostile_tracker_samples_are_passed_on_unjudged(bad):
    """No sample crashes the monitor: an unusable one is not judged (the estimators skip and
    count it) and accuses no one."""
    gyro, st1, st2 = nominal(n=10)
    st1[5] = bad
    log = run_monitor(model(), gyro, st1, st2)
    assert np.all(log[:, :, 1] == fdir.CAUSE_NONE)
    assert log[5, 1, 0] == fdir.UNASSESSED


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"readmit_after_s": -1.0}, "monitor.readmit_after_s"),
        ({"frozen_window_s": 0.5}, "monitor.frozen_window_s"),
        ({"false_alarm_probability": 0.0}, "monitor.false_alarm_probability"),
        ({"gyro_arw_rad_per_rt_s": -1e-4}, "monitor.gyro_arw"),
        ({"gyro_rate_tolerance_rad_per_s": -1.0}, "monitor.gyro_rate_tolerance"),
        ({"gyro_range_rad_per_s": 0.0}, "monitor.gyro_range"),
        ({"bias_window_s": 2.5}, "monitor.bias_window_s"),
        ({"bias_window_s": 1.0}, "monitor.bias_window_s"),
        ({"gyro_rrw_rad_per_s15": -1.0}, "monitor.gyro_rrw"),
        ({"covariance": np.diag([1e-8, 1e-8, -1e-8])}, "monitor.st1.covariance"),
    ],
)
def test_monitor_model_refuses_bad_arguments_naming_the_field(kwargs, field):
    kwargs = dict(kwargs)
    C = kwargs.pop("covariance", np.eye(3) * 1e-8)
    args = dict(
        trackers=[fdir.TrackerModel("st1", np.array([1.0, 0, 0, 0]), C)],
        has_gyro=True,
        period_s=1.0,
        frozen_window_s=1.0,
        readmit_after_s=0.0,
        false_alarm_probability=1e-6,
    )
    args.update(kwargs)
    with pytest.raises(ValueError) as e:
        fdir.MonitorModel.make("monitor", **args)
    text = str(e.value)
    assert text.startswith(field + ": got") and "; " in text and "\n" not in text and "None" not in text


def test_bias_window_is_counted_in_periods():
    m = fdir.MonitorModel.make(
        "m",
        [fdir.TrackerModel("st1", np.array([1.0, 0, 0, 0]), np.eye(3) * 1e-8)],
        True,
        0.5,
        0.5,
        0.0,
        1e-6,
        bias_window_s=10.0,
    )
    assert m.bias_window_steps == 20
    assert m.memory_size == fdir.SENSOR_BLOCK * 2 + fdir.REFERENCE_BLOCK + 1 + fdir.RESIDUAL_SLOT * 40


def test_unconnected_inputs_are_passed_on_as_invalid_and_judged_by_no_one():
    """A monitor whose gyro and second tracker are not wired: their outputs say 'invalid'
    (flag 0, NaN numbers), and the lone tracker is neither confirmed nor accused."""
    gyro, st1, _ = nominal(n=6)
    builder = DiagramBuilder()
    monitor = builder.AddSystem(SensorMonitor(model(), "gyro"))
    src = builder.AddSystem(Script(st1))
    builder.Connect(src.get_output_port(), monitor.GetInputPort("q_meas_st1"))
    sim = Simulator(builder.Build())
    ctx = monitor.GetMyContextFromRoot(sim.get_mutable_context())
    for k in range(6):
        sim.AdvanceTo(k * T)
        g = monitor.GetOutputPort("measurement_gyro").Eval(ctx)
        s2 = monitor.GetOutputPort("measurement_st2").Eval(ctx)
        assert g[1] == 0.0 and np.all(np.isnan(g[2:])) and s2[1] == 0.0 and np.all(np.isnan(s2[2:]))
        log = monitor.GetOutputPort("detector_log").Eval(ctx).reshape(3, 3)
        assert np.all(log[:, 1] == fdir.CAUSE_NONE) and log[1, 0] == fdir.UNASSESSED
        assert np.array_equal(monitor.GetOutputPort("measurement_st1").Eval(ctx), st1[k])


def test_between_instants_the_monitor_judges_nothing_and_keeps_its_counts():
    """Outputs read between the monitor's instants (a faster consumer or logger): no cause, the
    excluded sensor still excluded, the others unassessed, the exclusion counts unchanged."""
    gyro, st1, st2 = nominal(n=12)
    st1[4:9, 2:] = st1[3, 2:]  # frozen 4..8
    builder = DiagramBuilder()
    monitor = builder.AddSystem(SensorMonitor(model(readmit_after_s=3.0), "gyro"))
    for name, rows in (("gyro_measurement", gyro), ("q_meas_st1", st1), ("q_meas_st2", st2)):
        src = builder.AddSystem(Script(rows))
        builder.Connect(src.get_output_port(), monitor.GetInputPort(name))
    sim = Simulator(builder.Build())
    ctx = monitor.GetMyContextFromRoot(sim.get_mutable_context())
    sim.AdvanceTo(6.0)
    at_instant = monitor.GetOutputPort("detector_log").Eval(ctx).reshape(3, 3).copy()
    sim.AdvanceTo(6.5)
    between = monitor.GetOutputPort("detector_log").Eval(ctx).reshape(3, 3)
    assert at_instant[1, 0] == fdir.EXCLUDED and at_instant[1, 1] == fdir.CAUSE_FROZEN
    assert np.array_equal(between[:, 0], [fdir.UNASSESSED, fdir.EXCLUDED, fdir.UNASSESSED])
    assert np.all(between[:, 1] == fdir.CAUSE_NONE)
    assert np.array_equal(between[:, 2], at_instant[:, 2]) and between[1, 2] == 1
