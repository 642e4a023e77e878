"""The sensor monitor inside a scenario: MEKFs that read through it keep their attitude through a
stuck tracker and a gyro outlier that pull the ungated MEKF off, every excluded sample is
counted in the estimator's status, and with no fault at all the FDIR twins equal the originals.

Attitude errors are computed here from the logged truth and estimate quaternions (scipy), not
with the library's metrics."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drake_att import fdir
from drake_att.scenarios.builder import diagram_for
from drake_att.scenarios.config import load_scenario
from drake_att.scenarios.library import load
from drake_att.scenarios.monitoring import with_monitor
from drake_att.validation import ConfigError

SCENARIO = """
name: fdir_small
duration_s: 120.0
seed: 1
simulation: {integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  initial_attitude_rpy_deg: [2.0, -2.0, 2.0]
  initial_rate_deg_per_s: [-0.5, 0.5, 0.5]
sensors:
- !GyroConfig {name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.56, rrw_deg_per_h15: 123.75,
               initial_bias_deg_per_h: [12.0, 12.0, 12.0]}
- !SensorFaultsConfig {name: gyro_faults, sensor: gyro, outlier_times_s: [30.0], outlier_rate_deg_per_s: 0.5}
- !StarTrackerConfig {name: st1, period_s: 0.1, mode: quaternion,
                      mounting: !PaperS3Eq7Mounting {psi_phi_theta_deg: [-90.0, 45.0, -90.0]},
                      sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}
- !SensorFaultsConfig {name: st1_faults, sensor: st1, stuck_windows_s: [[60.0, 70.0]]}
- !StarTrackerConfig {name: st2, period_s: 0.1, mode: quaternion,
                      mounting: !PaperS3Eq7Mounting {psi_phi_theta_deg: [90.0, 45.0, 90.0]},
                      sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}
- !SensorMonitorConfig {name: fdir, gyro: gyro, star_trackers: [st1, st2], readmit_after_s: 5.0}
estimators:
- !MekfConfig {name: joint, period_s: 1.0, gyro: gyro, star_trackers: [st1, st2], innovation_gate_probability: 0.0}
- !MekfConfig {name: joint_fdir, period_s: 1.0, gyro: gyro, star_trackers: [st1, st2],
               innovation_gate_chi2: 16.27, monitor: fdir, held_rate_rrw_deg_per_s15: 0.15}
- !MekfConfig {name: single_fdir, period_s: 1.0, gyro: gyro, star_trackers: [st1],
               innovation_gate_chi2: 16.27, monitor: fdir, held_rate_rrw_deg_per_s15: 0.15}
scoring: {score_from_s: 20.0, convergence_threshold_deg: 0.05}
"""


def _last_per_time(t, x):
    t, x = np.asarray(t), np.asarray(x).reshape(len(t), -1)
    keep = np.r_[np.diff(t) > 1e-9, True]
    return t[keep], x[keep]


def attitude_error_deg(run, name: str):
    """|rotation| between the estimate and the truth at the estimate's times (deg)."""
    meta = run.metadata["estimators"][name]["signals"]
    t_s, status = _last_per_time(*run.signals[meta["status"]])
    _, q_hat = _last_per_time(*run.signals[meta["attitude"]])
    t_q, q_true = _last_per_time(*run.signals[run.metadata["truth"]["attitude"]])
    idx = np.searchsorted(t_q, status[:, 0] - 1e-9)
    r_hat = Rotation.from_quat(q_hat[:, [1, 2, 3, 0]])
    r_true = Rotation.from_quat(q_true[idx][:, [1, 2, 3, 0]])
    return status[:, 0], np.degrees((r_true.inv() * r_hat).magnitude()), status


@pytest.fixture(scope="module")
def small_run():
    return diagram_for(load_scenario(SCENARIO)).simulate(seed=1)


def test_stuck_tracker_and_gyro_outlier_are_isolated_and_the_fdir_mekfs_keep_their_attitude(small_run):
    run = small_run
    t_log, log = _last_per_time(*run.signals["fdir/detector_log"])
    gyro, st1, st2 = (log[:, 3 * j : 3 * j + 3] for j in range(3))
    at = {float(x): i for i, x in enumerate(t_log)}
    # the gyro outlier at 30 s: isolated by the vote, the trackers confirmed
    assert gyro[at[30.0], 1] == fdir.CAUSE_VOTE
    assert st1[at[30.0], 0] == fdir.CONFIRMED and st2[at[30.0], 0] == fdir.CONFIRMED
    # st1 stuck 60-70 s: excluded throughout, re-admitted within 5 s of clean samples after it
    assert all(st1[at[float(k)], 0] == fdir.EXCLUDED for k in range(61, 71))
    assert all(st1[at[float(k)], 1] == fdir.CAUSE_FROZEN for k in range(61, 70))
    assert st1[at[77.0], 0] == fdir.CONFIRMED
    # nothing else accused, st2 never
    assert np.all(st2[:, 1] == 0)
    quiet = (t_log < 29.5) | ((t_log > 36.5) & (t_log < 59.5)) | (t_log > 71.5)
    assert np.all(log[quiet][:, 1::3] == 0)

    t, err_joint, _ = attitude_error_deg(run, "joint")
    _, err_fdir, _ = attitude_error_deg(run, "joint_fdir")
    _, err_single, status_single = attitude_error_deg(run, "single_fdir")
    stuck = (t >= 60) & (t <= 75)
    assert err_joint[stuck].max() > 3.0  # the ungated joint MEKF follows the frozen tracker half-way
    assert err_fdir[stuck].max() < 0.05
    assert err_single[stuck].max() < 0.2  # st1 excluded: coasting on the gyro
    outlier = (t >= 30) & (t <= 35)
    assert err_fdir[outlier].max() < 0.02 and err_single[outlier].max() < 0.1
    # every sample the monitor excluded is skipped and counted
    skipped = np.diff(status_single[:, 2], prepend=0.0)
    for k in range(61, 71):
        assert skipped[np.flatnonzero(np.abs(t - k) < 1e-9)[0]] >= 1
    _, handling = _last_per_time(*run.signals[run.metadata["estimators"]["single_fdir"]["signals"]["sample_handling"]])
    assert handling[-1, 3] >= 11  # monitor_exclusions: st1 61..70 and the gyro at 30 at least


def test_bias_jump_is_logged_not_excluded():
    text = SCENARIO.replace(
        "outlier_times_s: [30.0], outlier_rate_deg_per_s: 0.5",
        "bias_jump_times_s: [40.0], bias_jumps_deg_per_h: [[100.0, -100.0, 50.0]]",
    )
    run = diagram_for(load_scenario(text)).simulate(seed=2)
    t_log, log = _last_per_time(*run.signals["fdir/detector_log"])
    causes = log[:, 1]
    flagged = t_log[causes == fdir.CAUSE_BIAS_SHIFT]
    assert len(flagged) > 0 and flagged.min() >= 40.0 and flagged.max() <= 60.0
    assert np.all(log[t_log < 59.5][:, 0] != fdir.EXCLUDED)
    # scored: the filter took the jump's sample as usual (no rejection, no recovery), the
    # monitor's log holds the trace
    from drake_att.analysis.fault_scores import score_fault_events

    row = next(r for r in score_fault_events(run, ["joint_fdir"]) if (r["sensor"], r["kind"]) == ("gyro", "bias_jump"))
    assert row["accepted"] == 1 and row["rejected"] == 0 and row["detected"] == 0
    assert row["excluded"] == 0 and row["flagged"] == len(flagged)


def test_with_monitor_adds_a_monitor_after_the_trackers_and_fdir_twins():
    s = with_monitor(load("cubesat_dual_star_tracker"), held_rate_rrw_deg_per_s15=0.1)
    names = [x.name for x in s.sensors]
    assert names.index("fdir") > names.index("st2") and names.index("fdir") < names.index("st_avg")
    twins = {e.name: e for e in s.estimators if getattr(e, "monitor", "")}
    assert set(twins) == {"single_fdir", "single_st2_fdir", "joint_fdir"}
    assert all(e.held_rate_rrw_deg_per_s15 == 0.1 for e in twins.values())
    with pytest.raises(ConfigError, match="a monitor needs a gyro and a quaternion tracker"):
        with_monitor(load("s0_particle_filters_small_error"))


def test_estimator_naming_a_missing_monitor_is_refused_in_one_line():
    text = SCENARIO.replace("monitor: fdir, held_rate", "monitor: nope, held_rate")
    with pytest.raises(ConfigError) as e:
        load_scenario(text)
    assert "monitor: got 'nope'" in str(e.value) and "\n" not in str(e.value)


def test_monitor_that_does_not_watch_the_filters_tracker_is_refused():
    text = SCENARIO.replace("star_trackers: [st1, st2], readmit", "star_trackers: [st2], readmit")
    with pytest.raises(ConfigError) as e:
        load_scenario(text)
    assert "does not watch ['st1']" in str(e.value) and "\n" not in str(e.value)


def test_fault_free_study_excludes_nothing_and_twins_equal_the_originals():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "diagrams"))
    import fdir_false_alarms as study

    scenario = study.study_scenario(600.0)
    records = [study.record(diagram_for(scenario).simulate(seed=s)) for s in (1, 2)]
    twins = {e.name: e.name.removesuffix("_fdir") for e in scenario.estimators if getattr(e, "monitor", "")}
    summary = study.summarize(records, twins)
    assert all(m["exclusions"] == 0 for m in summary["monitor"].values())
    for r in records:
        for twin, original in twins.items():
            assert r["rmse"][twin]["total"] == pytest.approx(r["rmse"][original]["total"], rel=1e-9)
    assert all(r["equal"] for r in summary["rmse"].values())


def test_held_rate_walk_keeps_the_covariance_honest_through_a_gyro_outage():
    """A 30-s gyro outage on the turning body: the gated MEKF holding the rate with the normal
    process noise is overconfident (NEES >> 3); with the held-rate walk the NEES over the
    outage is ~3 (mean of 4 seeds x 31 steps; [2, 4] allows for the steps' correlation)."""
    text = SCENARIO.replace(
        "outlier_times_s: [30.0], outlier_rate_deg_per_s: 0.5", "outage_windows_s: [[40.0, 70.0]]"
    ).replace("stuck_windows_s: [[60.0, 70.0]]", "outlier_times_s: []")
    text = text.replace(
        "name: joint, period_s: 1.0, gyro: gyro, star_trackers: [st1, st2], innovation_gate_probability: 0.0",
        "name: single, period_s: 1.0, gyro: gyro, star_trackers: [st1], innovation_gate_chi2: 16.27",
    )
    scenario = load_scenario(text)
    nees: dict = {"single": [], "single_fdir": [], "joint_fdir": []}
    for seed in (1, 2, 3, 4):
        run = diagram_for(scenario).simulate(seed=seed)
        t_q, q_true = _last_per_time(*run.signals[run.metadata["truth"]["attitude"]])
        for name in nees:
            keys = run.metadata["estimators"][name]["signals"]
            _, status = _last_per_time(*run.signals[keys["status"]])
            _, q_hat = _last_per_time(*run.signals[keys["attitude"]])
            _, cov = _last_per_time(*run.signals[keys["covariance"]])
            t = status[:, 0]
            m = (t >= 40.0) & (t <= 70.5)
            truth = Rotation.from_quat(q_true[np.searchsorted(t_q, t[m] - 1e-9)][:, [1, 2, 3, 0]])
            d = (Rotation.from_quat(q_hat[m][:, [1, 2, 3, 0]]).inv() * truth).as_rotvec()  # body-frame error
            P = cov[m].reshape(-1, 6, 6)[:, :3, :3]
            nees[name] += [float(x @ np.linalg.solve(Pk, x)) for x, Pk in zip(d, P, strict=True)]
    assert np.mean(nees["single"]) > 10.0
    for name in ("single_fdir", "joint_fdir"):
        assert 2.0 <= np.mean(nees[name]) <= 4.0, (name, np.mean(nees[name]))


@pytest.mark.parametrize(
    "script", ["fdir_false_alarms", "s2_calibration", "sky_identification", "sky_rate_sweep", "sky_cubesat"]
)
def test_study_scripts_leave_a_users_folder_untouched(script, tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "diagrams"))
    module = __import__(script)
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "results.json").write_text('{"mine": 1}')
    assert module.main(["--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "holds ['notes.txt']" in err and "left untouched" in err
    assert (tmp_path / "results.json").read_text() == '{"mine": 1}'
    (tmp_path / "notes.txt").unlink()  # a results.json that is not the script's: refused too
    assert module.main(["--out", str(tmp_path)]) == 2
    assert "has no results.json of this script" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert module.main(["--out", str(tmp_path / "file")]) == 2
    assert "is not a folder" in capsys.readouterr().err


def test_write_json_atomically_replaces_whole_or_not_at_all(tmp_path):
    from drake_att.outputs import write_json_atomically

    target = tmp_path / "results.json"
    write_json_atomically(str(target), {"a": 1})
    with pytest.raises(TypeError):
        write_json_atomically(str(target), {"a": object()})  # not serializable: the old file stays
    assert target.read_text() == '{\n "a": 1\n}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json"]


def test_fault_scores_read_the_monitors_trace_and_the_nees_during_a_fault(small_run):
    """score_fault_events against the logs read here: the stuck window's samples at the
    monitor's instants, those at which it excluded st1, the instants it flagged st1 until the
    run's end, and the NEES over the window's steps."""
    from drake_att.analysis.fault_scores import score_fault_events
    from drake_att.systems import fault_injector as flt

    run = small_run
    rows = {(r["estimator"], r["sensor"], r["kind"]): r for r in score_fault_events(run)}
    row = rows[("single_fdir", "st1", "stuck")]
    t_f, truth = _last_per_time(*run.signals["st1_faults/fault_truth"])
    stuck_t = truth[truth[:, flt.TRUTH_CODE] == flt.FAULT_STUCK, flt.TRUTH_T_SAMPLE]
    t_log, log = _last_per_time(*run.signals["fdir/detector_log"])
    at_instants = np.isin(np.round(t_log, 6), np.round(stuck_t, 6))
    assert row["monitor_instants"] == int(np.sum(at_instants)) >= 10
    assert row["excluded"] == int(np.sum(log[at_instants, 3] == fdir.EXCLUDED)) >= 9
    window = t_log >= stuck_t.min() - 1e-9  # the last event: its window runs to the end
    assert row["flagged"] == int(np.sum(log[window, 4] != 0)) >= 9
    # NEES over the window's steps, from the logged estimate and covariance
    keys = run.metadata["estimators"]["single_fdir"]["signals"]
    _, status = _last_per_time(*run.signals[keys["status"]])
    _, q_hat = _last_per_time(*run.signals[keys["attitude"]])
    _, cov = _last_per_time(*run.signals[keys["covariance"]])
    t_q, q_true = _last_per_time(*run.signals[run.metadata["truth"]["attitude"]])
    t = status[:, 0]
    m = (t >= stuck_t.min() - 1e-6) & (t <= stuck_t.max() + 1e-6)
    truth_r = Rotation.from_quat(q_true[np.searchsorted(t_q, t[m] - 1e-9)][:, [1, 2, 3, 0]])
    d = (Rotation.from_quat(q_hat[m][:, [1, 2, 3, 0]]).inv() * truth_r).as_rotvec()
    P = cov[m].reshape(-1, 6, 6)[:, :3, :3]
    nees = [float(x @ np.linalg.solve(Pk, x)) for x, Pk in zip(d, P, strict=True)]
    assert row["nees_during"] == pytest.approx(np.mean(nees), rel=1e-6)
    # the gyro outlier: excluded at its instant, and no monitor trace for the ungated filter's own sensors
    gyro_row = rows[("joint_fdir", "gyro", "outlier")]
    assert gyro_row["monitor_instants"] == 1 and gyro_row["excluded"] == 1
    # a point fault's NEES is its own step's
    keys = run.metadata["estimators"]["joint_fdir"]["signals"]
    _, status = _last_per_time(*run.signals[keys["status"]])
    _, q_hat = _last_per_time(*run.signals[keys["attitude"]])
    _, cov = _last_per_time(*run.signals[keys["covariance"]])
    k = int(np.flatnonzero(np.abs(status[:, 0] - 30.0) < 1e-9)[0])
    r_true = Rotation.from_quat(q_true[np.searchsorted(t_q, 30.0 - 1e-9)][[1, 2, 3, 0]])
    d = (Rotation.from_quat(q_hat[k][[1, 2, 3, 0]]).inv() * r_true).as_rotvec()
    assert gyro_row["nees_during"] == pytest.approx(
        float(d @ np.linalg.solve(cov[k].reshape(6, 6)[:3, :3], d)), rel=1e-6
    )
