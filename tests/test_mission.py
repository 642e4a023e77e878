"""The mission figures (drake_att.analysis.mission) against their definitions: gaps found by
walking the flags by hand, intervals from hand-worked t quantiles, and a scenario whose trackers
are blinded on a schedule (outage windows) so the gaps and the errors inside them are known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drake_att.analysis import mission
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import ScenarioDiagram


def _runs_by_hand(t, out):
    gaps, start = [], None
    for k, (tk, o) in enumerate(zip(t, out, strict=True)):
        if o and start is None:
            start = tk
        if start is not None and (not o or k == len(t) - 1):
            last = tk if o else t[k - 1]
            gaps.append((start, last + (t[1] - t[0])))
            start = None
    return gaps


@pytest.mark.parametrize(
    "flags",
    [
        [0, 1, 1, 0, 0, 1, 0],
        [1, 1, 0, 1],
        [1, 1, 1],
        [0, 0, 0],
        [0, 1],
    ],
)
def test_outage_runs_match_a_walk_over_the_flags(flags):
    t = 10.0 + 0.5 * np.arange(len(flags))
    assert mission.outage_runs(t, np.array(flags, bool)) == _runs_by_hand(t, flags)


def test_outage_runs_random_flags():
    rng = np.random.default_rng(4)
    for _ in range(50):
        flags = rng.random(40) < 0.4
        t = np.arange(40) * 2.0
        assert mission.outage_runs(t, flags) == _runs_by_hand(t, flags)


def test_outage_runs_refuses_mismatched_shapes():
    with pytest.raises(ValueError, match="must be equal 1-D shapes"):
        mission.outage_runs(np.arange(3.0), np.zeros(4, bool))


def test_interval_is_the_student_t_interval():
    """n = 5: t(0.975, 4) = 2.7764451 (tables); n = 20: t(0.975, 19) = 2.0930241."""
    x = [1.0, 2.0, 4.0, 3.0, 5.0]
    s = math.sqrt(sum((v - 3.0) ** 2 for v in x) / 4)
    r = mission.interval(x)
    assert r["mean"] == 3.0 and r["n"] == 5
    assert r["hi"] == pytest.approx(3.0 + 2.7764451 * s / math.sqrt(5), rel=2e-3)
    assert r["lo"] == pytest.approx(3.0 - 2.7764451 * s / math.sqrt(5), rel=2e-3)
    y = list(np.linspace(0.0, 1.0, 20))
    r = mission.interval(y + [None])
    half = 2.0930241 * np.std(y, ddof=1) / math.sqrt(20)
    assert r["n"] == 20 and r["hi"] - r["mean"] == pytest.approx(half, rel=1e-4)
    assert mission.interval([0.0, 0.0, 3.0])["lo"] == 0.0  # clipped: the figures are >= 0
    assert mission.interval([2.0]) == {"mean": 2.0, "lo": None, "hi": None, "n": 1}
    assert mission.interval([None])["mean"] is None


EPOCH = "2026-03-21T00:00:00Z"


def _scheduled_scenario():
    """Two trackers with tiny cones (so the geometry never blinds them) and outage windows that
    overlap on [300, 360) and [600, 700): the all-out gaps are exactly those."""
    text = f"""
name: mission_test
duration_s: 900.0
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 1.0}}
orbit: !KeplerOrbitConfig {{epoch_utc: "{EPOCH}", semi_major_axis_km: 6928.137, inclination_deg: 97.6}}
plant: !RigidBodyConfig {{inertia_kg_m2: [0.042, 0.042, 0.0067], attitude_control: {{}}}}
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.5, rrw_deg_per_h15: 20.0}}
- !StarTrackerConfig {{name: st1, period_s: 1.0, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0,
    mounting: !RpyMounting {{rpy_deg: [180.0, 0.0, 0.0]}},
    outage_windows_s: [[250.0, 360.0], [600.0, 700.0]],
    exclusion: {{sun_deg: 0.001, earth_limb_deg: 0.001, moon_deg: 0.001, atmosphere_height_m: 0.0}}}}
- !StarTrackerConfig {{name: st2, period_s: 1.0, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0,
    mounting: !RpyMounting {{rpy_deg: [180.0, 0.0, 0.0]}},
    outage_windows_s: [[300.0, 400.0], [590.0, 700.0]],
    exclusion: {{sun_deg: 0.001, earth_limb_deg: 0.001, moon_deg: 0.001, atmosphere_height_m: 0.0}}}}
estimators:
- !MekfConfig {{name: joint, gyro: gyro, star_trackers: [st1, st2]}}
- !MekfConfig {{name: one, gyro: gyro, star_trackers: [st1]}}
scoring: {{score_from_s: 100.0}}
"""
    return cfg.load_scenario(text=text)


@pytest.fixture(scope="module")
def scheduled_runs():
    d = ScenarioDiagram(_scheduled_scenario())
    return [d.simulate(seed) for seed in (1, 2, 3)]


def test_mission_record_finds_the_scheduled_gaps_and_the_errors_in_them(scheduled_runs):
    from drake_att.analysis.metrics import estimator_errors

    run = scheduled_runs[0]
    r = mission.mission_record(run)
    assert r["gaps"] == 2
    assert r["worst_gap"] == {"start_s": 600.0, "end_s": 700.0, "duration_s": 100.0}
    t = run.times("st1/star_tracker_measurement")
    both = ((t >= 300) & (t < 360)) | ((t >= 600) & (t < 700))
    assert r["all_out_fraction"] == pytest.approx(both.mean(), abs=1e-12)
    for tr in ("st1", "st2"):
        assert r["availability"][tr]["available"] == 1.0  # the cones never blind them
    for name in ("joint", "one"):
        e = estimator_errors(run, name)
        inside = (e["t"] >= 600) & (e["t"] < 700)
        mag = np.degrees(np.linalg.norm(e["dtheta"][inside], axis=1))
        assert r["estimators"][name]["gap_rms_deg"] == pytest.approx(np.sqrt(np.mean(mag**2)), rel=1e-12)
        assert r["estimators"][name]["gap_max_deg"] == pytest.approx(mag.max(), rel=1e-12)
        scored = np.degrees(np.linalg.norm(e["dtheta"][e["t"] >= 100], axis=1))
        assert r["estimators"][name]["p95_deg"] == pytest.approx(np.percentile(scored, 95), rel=1e-12)
    # The gyro alone inside the gap: the error grows there, above its median over the day.
    assert r["estimators"]["joint"]["gap_max_deg"] > 3 * r["estimators"]["joint"]["p50_deg"]


def test_summary_pools_the_seeds(scheduled_runs):
    records = [mission.mission_record(run) for run in scheduled_runs]
    s = mission.summarize_mission(records)
    assert s["seeds"] == [1, 2, 3]
    rms = [rec["estimators"]["one"]["gap_rms_deg"] for rec in records]
    half = 4.3026527 * np.std(rms, ddof=1) / math.sqrt(3)  # t(0.975, 2) = 4.3026527
    assert s["estimators"]["one"]["gap_rms_deg"]["mean"] == pytest.approx(np.mean(rms))
    assert s["estimators"]["one"]["gap_rms_deg"]["hi"] == pytest.approx(np.mean(rms) + half, rel=1e-7)
    assert s["worst_gap_s"]["mean"] == 100.0
    lo, hi = s["estimators"]["joint"]["anees_band"]
    assert lo < 6 < hi
    table = mission.format_mission_tables(s)
    assert "| st1 |" in table and "| joint |" in table and "worst lasts 100" in table
    assert s["estimators"]["joint"]["nees_dof"] == 6 and "(6 dof: " in table  # attitude and bias


def test_a_run_without_cones_is_refused():
    text = """
name: no_cones
duration_s: 10.0
sensors:
- !GyroConfig {name: gyro}
- !StarTrackerConfig {name: st, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}
estimators:
- !MekfConfig {name: m, star_trackers: [st]}
"""
    run = ScenarioDiagram(cfg.load_scenario(text=text)).simulate()
    with pytest.raises(ValueError, match="no star tracker with exclusion cones"):
        mission.mission_record(run)


def test_the_records_series_samples_the_error_each_minute(scheduled_runs):
    from drake_att.analysis.metrics import estimator_errors

    run = scheduled_runs[1]
    r = mission.mission_record(run)
    e = estimator_errors(run, "one")
    s = r["series"]["estimators"]["one"]
    assert s["t_s"] == [float(t) for t in np.arange(0.0, 900.0, 60.0)]
    k = np.searchsorted(e["t"], 540.0)
    assert s["error_deg"][9] == pytest.approx(np.degrees(np.linalg.norm(e["dtheta"][k])), rel=1e-12)
    assert r["series"]["gaps_s"] == [[300.0, 360.0], [600.0, 700.0]]


def test_the_worst_gap_is_chosen_in_the_scored_part(scheduled_runs):
    """Only gaps that start at or after score_from_s compete: from 320 s the [300, 360) gap is
    out; from 650 s both are, and there is no worst gap."""
    import copy

    run = copy.copy(scheduled_runs[0])
    run.scenario = copy.deepcopy(run.scenario)
    run.scenario.scoring.score_from_s = 320.0
    r = mission.mission_record(run)
    assert r["worst_gap"]["start_s"] == 600.0  # [300, 360) starts before 320 s
    run.scenario.scoring.score_from_s = 650.0
    r = mission.mission_record(run)
    assert r["worst_gap"] is None and r["gaps"] == 2
    assert all(e["gap_rms_deg"] is None for e in r["estimators"].values())


def test_the_docs_table_is_the_render_of_its_committed_summary():
    """``docs/mission_data/table.md`` (included in the mission page) is exactly what
    :func:`format_mission_tables` makes of ``summary.json`` (written by
    ``diagrams/cubesat_sso_mission.py``), over at least 20 seeds, and its intervals are the
    Student-t intervals of the committed per-seed values."""
    import json
    import os

    root = os.path.join(os.path.dirname(__file__), "..", "docs", "mission_data")
    with open(os.path.join(root, "summary.json")) as f:
        data = json.load(f)
    with open(os.path.join(root, "table.md")) as f:
        assert f.read() == mission.format_mission_tables(data["summary"])
    assert len(data["summary"]["seeds"]) >= 20
    t_975 = {19: 2.0930241, 29: 2.0452296}  # Student t(0.975, n - 1), from tables
    for name, values in data["per_seed_rmse_deg"].items():
        x = np.array(values)
        half = t_975[len(x) - 1] * np.std(x, ddof=1) / math.sqrt(len(x))
        e = data["summary"]["estimators"][name]["rmse_deg"]
        assert e["mean"] == pytest.approx(x.mean(), rel=1e-12)
        assert e["hi"] == pytest.approx(x.mean() + half, rel=1e-7)


def test_the_worst_gap_is_the_longest_scored_one():
    gaps = [(100.0, 400.0), (500.0, 560.0), (700.0, 750.0), (900.0, 960.0)]
    assert mission.worst_gap(gaps, 0.0) == (100.0, 400.0)  # the longest, not the last
    assert mission.worst_gap(gaps, 450.0) == (500.0, 560.0)  # of two equal, the first
    assert mission.worst_gap(gaps, 500.0) == (500.0, 560.0)  # starting at score_from counts
    assert mission.worst_gap(gaps, 950.0) is None
    assert mission.worst_gap([], 0.0) is None


def test_outage_runs_of_one_and_no_sample():
    assert mission.outage_runs(np.array([5.0]), np.array([True])) == [(5.0, 5.0)]
    assert mission.outage_runs(np.array([5.0]), np.array([False])) == []
    assert mission.outage_runs(np.zeros(0), np.zeros(0, bool)) == []


def test_a_summary_of_one_record_has_means_and_no_intervals(scheduled_runs):
    s = mission.summarize_mission([mission.mission_record(scheduled_runs[0])])
    assert s["worst_gap_s"] == {"mean": 100.0, "lo": None, "hi": None, "n": 1}
    assert s["availability"]["st2"]["available"]["mean"] == 1.0
    assert "| st1 | 100 | 0 | 0 | 0 |" in mission.format_mission_tables(s)  # fractions as percent


def test_the_mission_script_writes_only_into_a_folder_of_its_own(tmp_path):
    """An absent or empty folder, or one the script wrote, may be written; a folder holding a
    user's file (even one named like the script's) is refused with one line and left as it was."""
    import importlib.util
    import json
    import os

    path = os.path.join(os.path.dirname(__file__), "..", "diagrams", "cubesat_sso_mission.py")
    spec = importlib.util.spec_from_file_location("mission_script", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.check_out_folder(str(tmp_path / "new")) is None
    assert script.check_out_folder(str(tmp_path)) is None  # empty
    (tmp_path / "notes.txt").write_text("mine")
    assert "holds ['notes.txt']" in script.check_out_folder(str(tmp_path))
    (tmp_path / "notes.txt").unlink()
    (tmp_path / "config.yaml").write_text("my own scenario")
    assert "has no summary.json of this script" in script.check_out_folder(str(tmp_path))
    (tmp_path / "summary.json").write_text(json.dumps({"per_seed_rmse_deg": {}}))
    assert script.check_out_folder(str(tmp_path)) is None
    (tmp_path / "file").write_text("x")
    assert "is not a folder" in script.check_out_folder(str(tmp_path / "file"))
    code = script.main(["--seeds", "1", "--duration", "700", "--out", str(tmp_path)])
    assert (
        code == 2
        and (tmp_path / "file").read_text() == "x"
        and (tmp_path / "config.yaml").read_text() == "my own scenario"
    )
