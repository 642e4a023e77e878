"""Typed scenario configs: validation messages, overrides, shipped scenarios, and the CLI."""

import json
import os

import numpy as np
import pytest

from drake_att.cli import main as cli_main
from drake_att.scenarios.config import ConfigError, apply_overrides, dump_scenario, load_scenario
from drake_att.scenarios.library import DEFAULT_SCENARIO, available_scenarios, load

BASE = """
name: t
duration_s: 20.0
plant: !RigidBodyConfig
  inertia_kg_m2: [1.0, 2.0, 2.5]
sensors:
- !GyroConfig {name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 1.0}
- !StarTrackerConfig {name: st1, period_s: 1.0, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}
estimators:
- !MekfConfig {name: mekf, period_s: 1.0, gyro: gyro, star_trackers: [st1]}
"""


def test_base_scenario_loads_and_round_trips():
    s = load_scenario(text=BASE)
    again = load_scenario(text=dump_scenario(s))
    assert dump_scenario(again) == dump_scenario(s)


@pytest.mark.parametrize("override, field, value", [
    ("sensors.st1.sigma_boresight_arcsec=-1", "sigma_boresight_arcsec", "-1"),
    ("sensors.gyro.period_s=0", "period_s", "0"),
    ("estimators.mekf.star_trackers=[st9]", "star_trackers", "st9"),
    ("estimators.mekf.gyro=nogyro", "gyro", "nogyro"),
    ("plant.inertia_kg_m2=[1.0, -2.0, 2.0]", "inertia_kg_m2", "-2.0"),
    ("plant.inertia_kg_m2=[1.0, 1.0, 5.0]", "inertia_kg_m2", "triangle"),
    ("duration_s=-5", "duration_s", "-5"),
    ("sensors.st1.dropout_probability=1.0", "dropout_probability", "1.0"),
    ("sensors.st1.mode=camera", "mode", "camera"),
    ("estimators.mekf.period_s=0.5", "period_s", "0.5"),
    ("simulation.integration_scheme=magic", "integration_scheme", "magic"),
])
def test_invalid_values_name_the_field_and_the_value(override, field, value):
    with pytest.raises(ConfigError) as info:
        apply_overrides(load_scenario(text=BASE), [override])
    msg = str(info.value)
    assert field in msg and value in msg, msg


def test_overrides_never_modify_the_callers_scenario():
    s = load_scenario(text=BASE)
    before = dump_scenario(s)
    with pytest.raises(ConfigError):
        apply_overrides(s, ["sensors.st1.sigma_boresight_arcsec=-3"])
    changed = apply_overrides(s, ["sensors.st1.sigma_boresight_arcsec=7"])
    assert dump_scenario(s) == before
    assert changed.sensors[1].sigma_boresight_arcsec == 7.0


def test_unknown_key_is_an_error():
    with pytest.raises(ConfigError, match="bogus"):
        load_scenario(text=BASE + "bogus: 1\n")
    with pytest.raises(ConfigError, match="sigma_bore"):
        load_scenario(text=BASE.replace("sigma_boresight_arcsec", "sigma_bore"))


def test_duplicate_sensor_name_is_an_error():
    with pytest.raises(ConfigError, match="name"):
        load_scenario(text=BASE.replace("name: st1", "name: gyro"))


def test_overrides_by_name_and_index():
    s = apply_overrides(load_scenario(text=BASE), ["sensors.st1.sigma_boresight_arcsec=20",
                                                   "estimators.0.initial_attitude_sigma_deg=2", "seed=7"])
    assert s.sensors[1].sigma_boresight_arcsec == 20.0
    assert s.estimators[0].initial_attitude_sigma_deg == 2.0
    assert s.seed == 7
    with pytest.raises(ConfigError, match="no element named"):
        apply_overrides(s, ["sensors.nothere.period_s=1"])
    with pytest.raises(ConfigError, match="unknown field"):
        apply_overrides(s, ["plant.mass=3"])


def test_every_shipped_scenario_loads_and_builds():
    from drake_att.scenarios.builder import ScenarioDiagram

    names = available_scenarios()
    assert DEFAULT_SCENARIO in names
    for name in names:
        s = load(name)
        sd = ScenarioDiagram(s)
        assert len(sd.diagram.GetSystems()) > 3


def _read_metrics(out):
    with open(os.path.join(out, "metrics.json")) as f:
        return json.load(f)


def test_cli_run_writes_results_and_seeds_reproduce(tmp_path, capsys):
    args = ["run", "--set", "duration_s=60", "--set", "scoring.score_from_s=10", "--quiet"]
    out1, out1b, out2 = (str(tmp_path / n) for n in ("s1", "s1b", "s2"))
    assert cli_main(args + ["--seed", "1", "--out", out1]) == 0
    table = capsys.readouterr().out
    assert "RMSE" in table and "NEES" in table
    for f in ("metrics.json", "log.npz", "config.yaml", "diagram.dot"):
        assert os.path.isfile(os.path.join(out1, f)), f
    assert any(f.endswith(".png") for f in os.listdir(out1))
    m = _read_metrics(out1)
    for key in ("scenario", "seed", "duration_s", "wall_time_s", "estimators"):
        assert key in m
    est = next(iter(m["estimators"].values()))
    for key in ("attitude_rmse_deg", "attitude_mae_deg", "attitude_rmse_total_deg", "bias_rmse_deg_per_h",
                "convergence_time_s", "nees_mean", "scored_from_s"):
        assert key in est
    assert len(est["attitude_rmse_deg"]) == 3 and m["duration_s"] == 60.0 and m["seed"] == 1
    # The saved config is the one actually used: loading it reproduces the run exactly.
    assert cli_main(["run", os.path.join(out1, "config.yaml"), "--quiet", "--no-figures", "--out", out1b]) == 0
    assert cli_main(args + ["--seed", "2", "--out", out2, "--no-figures"]) == 0
    a, b, c = (np.load(os.path.join(o, "log.npz")) for o in (out1, out1b, out2))
    for key in a.files:
        np.testing.assert_array_equal(a[key], b[key])
    est_key = next(k for k in a.files if k.endswith("q_IB_hat__x"))
    assert not np.array_equal(a[est_key], c[est_key])
    m1b = _read_metrics(out1b)
    for name, e in m["estimators"].items():
        assert e["attitude_rmse_deg"] == m1b["estimators"][name]["attitude_rmse_deg"]


def test_cli_reports_invalid_override(capsys):
    assert cli_main(["run", "--set", "sensors.gyro.period_s=-1", "--quiet"]) == 2
    assert "period_s" in capsys.readouterr().err


def test_cli_list(capsys):
    assert cli_main(["list"]) == 0
    assert DEFAULT_SCENARIO in capsys.readouterr().out


@pytest.mark.parametrize("plant_yaml", [
    "plant: !PrescribedRateConfig {constant_deg_per_s: [0.0, 0.05, 0.0], amplitude_deg_per_s: [0.01, 0.0, 0.0],"
    " frequency_rad_per_s: [0.1, 0.0, 0.0]}",
    "plant: !PrescribedRpyConfig {times_s: [0.0, 20.0, 60.0], rpy_deg: [[2.0, 3.0, 0.5], [2.0, 3.0, 0.5], [4.0, 7.0, 0.9]]}",
])
def test_kinematic_truth_scenarios_run_end_to_end(plant_yaml):
    """Prescribed (kinematic) truth drives the same sensors and MEKF; the filter tracks it."""
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.scenarios.builder import ScenarioDiagram

    text = BASE.replace("plant: !RigidBodyConfig\n  inertia_kg_m2: [1.0, 2.0, 2.5]", plant_yaml)
    s = apply_overrides(load_scenario(text=text), ["duration_s=60", "scoring.score_from_s=20"])
    sd = ScenarioDiagram(s)
    run = sd.simulate(seed=3)
    m = compute_metrics(run, sd.estimators)["estimators"]["mekf"]
    assert m["attitude_rmse_total_deg"] < 0.05
    from drake_att import rotations as rot

    q = run.values("prescribed_motion/q_IB")
    moved_deg = np.degrees(np.linalg.norm(rot.quat_error_rotvec(q[0], q[-1])))
    assert moved_deg > 2.0, moved_deg  # the truth really moves (3 deg and 4.5 deg here)


def test_monte_carlo_pool_matches_in_process_runs():
    """Worker processes rebuild the diagram from the YAML and give the same metrics as an
    in-process run for each seed (the run is a function of config + seed only)."""
    from drake_att.analysis.montecarlo import run_monte_carlo, summarize

    s = apply_overrides(load_scenario(text=BASE), ["duration_s=30", "scoring.score_from_s=5"])
    pooled = run_monte_carlo(s, [1, 2, 3], workers=2, keep_series_for=[2])
    local = run_monte_carlo(s, [1, 2, 3], workers=1)
    for a, b in zip(pooled, local):
        assert a["metrics"]["seed"] == b["metrics"]["seed"]
        assert a["metrics"]["estimators"]["mekf"]["attitude_rmse_deg"] == b["metrics"]["estimators"]["mekf"]["attitude_rmse_deg"]
    assert "series" in pooled[1] and "series" not in pooled[0]
    mean, std = summarize(pooled, "attitude_rmse_deg", "mekf")
    assert mean.shape == (3,) and np.all(std > 0)
