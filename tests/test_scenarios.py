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


@pytest.mark.parametrize(
    "override, field, value",
    [
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
    ],
)
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
    s = apply_overrides(
        load_scenario(text=BASE),
        ["sensors.st1.sigma_boresight_arcsec=20", "estimators.0.initial_attitude_sigma_deg=2", "seed=7"],
    )
    assert s.sensors[1].sigma_boresight_arcsec == 20.0
    assert s.estimators[0].initial_attitude_sigma_deg == 2.0
    assert s.seed == 7
    with pytest.raises(ConfigError, match="no element named"):
        apply_overrides(s, ["sensors.nothere.period_s=1"])
    with pytest.raises(ConfigError, match="unknown field"):
        apply_overrides(s, ["plant.mass=3"])


def test_every_shipped_scenario_loads_and_builds():
    """Every shipped scenario builds a diagram holding each configured sensor and estimator
    under its own name, each estimator exposing the contract ports; a few seconds of
    simulation give unit quaternions and symmetric positive semi-definite covariances."""
    from drake_att.scenarios.builder import ScenarioDiagram

    names = available_scenarios()
    assert DEFAULT_SCENARIO in names
    for name in names:
        s = load(name)
        # A decimated log needs two samples in the run: a 3-s run logs at most every 1 s.
        short = ["logging.period_s=1.0"] if s.logging.period_s is not None else []
        s = apply_overrides(s, ["duration_s=3", "scoring.score_from_s=0", *short])
        sd = ScenarioDiagram(s)
        in_diagram = {sys.get_name() for sys in sd.diagram.GetSystems()}
        configured = {x.name for x in list(s.sensors) + list(s.estimators)}
        assert configured <= in_diagram, (name, configured - in_diagram)
        run = sd.simulate(seed=1)
        for e in s.estimators:
            q = run.values(f"{e.name}/q_IB_hat")
            np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9, err_msg=f"{name}/{e.name}")
            P = run.values(f"{e.name}/covariance")[-1].reshape(6, 6)
            np.testing.assert_allclose(P, P.T, atol=1e-12 * np.abs(P).max())
            # Positive semi-definite (a bootstrap PF's collapsed cloud is singular, not negative).
            assert np.all(np.linalg.eigvalsh(P) >= -1e-12 * np.abs(P).max()), (name, e.name)
            status = run.values(f"{e.name}/status")
            assert status[-1, 0] == pytest.approx(run.times(f"{e.name}/status")[-1], abs=1.0), (name, e.name)


def _rotvec_between(q_hat, q_true):
    """Rotation vector of q_hat^-1 ⊗ q_true (rows wxyz), written out here independently."""
    w1, v1 = q_hat[:, :1], -q_hat[:, 1:]
    w2, v2 = q_true[:, :1], q_true[:, 1:]
    w = w1 * w2 - np.sum(v1 * v2, axis=1, keepdims=True)
    v = w1 * v2 + w2 * v1 + np.cross(v1, v2)
    v = np.where(w < 0, -v, v)
    w = np.abs(w)
    s = np.linalg.norm(v, axis=1, keepdims=True)
    angle = 2.0 * np.arctan2(s, w)
    return v * np.where(s > 0, angle / np.where(s > 0, s, 1.0), 2.0)


def _reject_constant(name):
    raise AssertionError(f"metrics.json must be strict JSON (null, never {name})")


def _read_metrics(out):
    with open(os.path.join(out, "metrics.json")) as f:
        return json.load(f, parse_constant=_reject_constant)


@pytest.mark.slow
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
    assert m["scenario"] == "cubesat_dual_star_tracker" and m["duration_s"] == 60.0 and m["seed"] == 1
    # metrics.json holds exactly what the metrics layer computes from the saved log: recompute
    # the per-axis RMSE of every estimator from log.npz (truth at each estimate's own time).
    log = np.load(os.path.join(out1, "log.npz"))
    truth_t, truth_q = log["rigid_body_plant__q_IB__t"], log["rigid_body_plant__q_IB__x"]
    for name, est in m["estimators"].items():
        status = log[f"{name}__status__x"]
        q_hat = log[f"{name}__q_IB_hat__x"]
        ok = np.isfinite(status[:, 0]) & (status[:, 0] >= 10.0 - 1e-6)
        t_est, keep_last = status[ok, 0], np.r_[np.diff(status[ok, 0]) > 1e-6, True]
        idx = np.searchsorted(truth_t, t_est[keep_last] - 1e-6)
        err = _rotvec_between(q_hat[ok][keep_last], truth_q[idx])
        rmse = np.degrees(np.sqrt(np.mean(err**2, axis=0)))
        np.testing.assert_allclose(est["attitude_rmse_deg"], rmse, rtol=1e-9, err_msg=name)
        assert est["samples_scored"] == int(np.sum(keep_last))
    # The saved config is the one actually used: loading it reproduces the run exactly.
    assert cli_main(["run", os.path.join(out1, "config.yaml"), "--quiet", "--no-figures", "--out", out1b]) == 0
    assert cli_main(args + ["--seed", "2", "--out", out2, "--no-figures"]) == 0
    a, b, c = (np.load(os.path.join(o, "log.npz")) for o in (out1, out1b, out2))
    for key in a.files:
        if key != "metadata":  # JSON text holding the run's wall time; compared below without it
            np.testing.assert_array_equal(a[key], b[key])
    meta_a, meta_b = (json.loads(str(x["metadata"])) for x in (a, b))
    assert meta_a.pop("wall_time_s") > 0 and meta_b.pop("wall_time_s") > 0
    assert meta_a == meta_b
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


@pytest.mark.parametrize(
    "plant_yaml",
    [
        "plant: !PrescribedRateConfig {constant_deg_per_s: [0.0, 0.05, 0.0], amplitude_deg_per_s: [0.01, 0.0, 0.0],"
        " frequency_rad_per_s: [0.1, 0.0, 0.0]}",
        "plant: !PrescribedRpyConfig {times_s: [0.0, 20.0, 60.0], rpy_deg: [[2.0, 3.0, 0.5], [2.0, 3.0, 0.5], [4.0, 7.0, 0.9]]}",
    ],
)
def test_kinematic_truth_scenarios_run_end_to_end(plant_yaml):
    """Prescribed (kinematic) truth drives the same sensors and MEKF; the filter tracks it."""
    from drake_att.analysis.metrics import compute_metrics, estimator_errors
    from drake_att.scenarios.builder import ScenarioDiagram

    text = BASE.replace("plant: !RigidBodyConfig\n  inertia_kg_m2: [1.0, 2.0, 2.5]", plant_yaml)
    s = apply_overrides(load_scenario(text=text), ["duration_s=60", "scoring.score_from_s=20"])
    sd = ScenarioDiagram(s)
    run = sd.simulate(seed=3)
    m = compute_metrics(run)["estimators"]["mekf"]
    # The filter is as accurate as it says: pooled over the three axes, the scored RMSE over
    # the root-mean reported attitude variance. 40 one-second samples x 3 axes with a
    # steady-state error correlation time of a few steps leave >= 30 effective samples; the
    # chi-square(30) 99.9% band for the variance ratio is [0.43, 1.85], i.e. [0.66, 1.36] on
    # the RMSE ratio - asserted with a little margin as [0.6, 1.5] (measured 0.9).
    errs = estimator_errors(run, "mekf")
    scored = errs["t"] >= 20.0 - 1e-6
    mean_var = np.einsum("nii->ni", errs["P"][scored])[:, :3].mean(axis=0)
    ratio = np.sqrt(np.sum(np.radians(m["attitude_rmse_deg"]) ** 2) / np.sum(mean_var))
    assert 0.6 < ratio < 1.5, ratio
    from drake_att import rotations as rot

    q = run.values("prescribed_motion/q_IB")
    moved_deg = np.degrees(np.linalg.norm(rot.quat_error_rotvec(q[0], q[-1])))
    assert moved_deg > 2.0, moved_deg  # the truth really moves (3 deg and 4.5 deg here)


@pytest.mark.slow
def test_monte_carlo_pool_matches_in_process_runs():
    """Dask worker processes rebuild the diagram from the YAML and give the same metrics as an
    in-process run for each seed (the run is a function of config + seed only)."""
    from drake_att.analysis.montecarlo import metric_mean_std, run_seeds

    s = apply_overrides(load_scenario(text=BASE), ["duration_s=30", "scoring.score_from_s=5"])
    pooled = run_seeds(s, [1, 2, 3], workers=2, keep_series_for=[2])
    local = run_seeds(s, [1, 2, 3], workers=1)
    for a, b in zip(pooled, local, strict=True):
        assert a["metrics"]["seed"] == b["metrics"]["seed"]
        assert (
            a["metrics"]["estimators"]["mekf"]["attitude_rmse_deg"]
            == b["metrics"]["estimators"]["mekf"]["attitude_rmse_deg"]
        )
    assert "series" in pooled[1] and "series" not in pooled[0]
    mean, std = metric_mean_std(pooled, "attitude_rmse_deg", "mekf")
    per_seed = np.array([r["metrics"]["estimators"]["mekf"]["attitude_rmse_deg"] for r in pooled])
    np.testing.assert_allclose(mean, per_seed.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(std, per_seed.std(axis=0, ddof=1), rtol=1e-12)
    assert np.all(std > 0)  # different seeds, different noise


def test_estimator_plugins_start_from_the_configured_estimate_in_si():
    """Every gyro-mode plug-in's initial estimate (the published estimate before the first
    step) is the configured attitude and bias converted to SI (conversions written here):
    bias [deg/h] * pi/180/3600, attitude from roll/pitch/yaw, covariance diag(sigma^2)."""
    from drake_att.scenarios.builder import ScenarioDiagram

    bias_deg_h = [3.0, -2.0, 1.5]
    s = load_scenario(
        text=BASE.replace(
            "!MekfConfig {name: mekf, period_s: 1.0, gyro: gyro, star_trackers: [st1]}",
            "!MekfConfig {name: mekf, period_s: 1.0, gyro: gyro, star_trackers: [st1], initial_bias_deg_per_h: "
            "[3.0, -2.0, 1.5], initial_attitude_rpy_deg: [0.0, 0.0, 10.0], initial_attitude_sigma_deg: 2.0, "
            "initial_bias_sigma_deg_per_h: 4.0}",
        )
    )
    sd = ScenarioDiagram(s)
    est = sd.estimators["mekf"]
    x = est.estimate_vector(est.CreateDefaultContext())
    np.testing.assert_allclose(x[4:7], np.array(bias_deg_h) * np.pi / 180 / 3600, rtol=1e-15)
    np.testing.assert_allclose(x[:4], [np.cos(np.radians(5.0)), 0.0, 0.0, np.sin(np.radians(5.0))], atol=1e-15)
    np.testing.assert_allclose(
        np.diag(x[7:43].reshape(6, 6)), [np.radians(2.0) ** 2] * 3 + [(4.0 * np.pi / 180 / 3600) ** 2] * 3, rtol=1e-14
    )


@pytest.mark.parametrize("seed", [-1, 2**32, 99999999999999999999, 2.0, True, "3"])
def test_seed_outside_drakes_32_bit_range_is_refused_not_aliased(seed):
    """Drake's RandomGenerator takes a 32-bit seed: 2^32 would silently repeat seed 0's run
    and a 20-digit seed crashed in the binding. Refused with the allowed range, from the
    config and from simulate()."""
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import ConfigError, Scenario, validate

    with pytest.raises(ConfigError, match=r"seed: got .*; must be an integer in \[0, 4294967295\]"):
        validate(Scenario(seed=seed))
    sd = ScenarioDiagram(Scenario(duration_s=1.0))
    with pytest.raises(ValueError, match=r"seed: got .*; must be an integer in \[0, 4294967295\]"):
        sd.simulate(seed)


def test_largest_seed_runs_and_differs_from_seed_zero():
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.library import load

    s = load("cubesat_single_star_tracker")
    s.duration_s, s.scoring.score_from_s = 5.0, 1.0
    sd = ScenarioDiagram(s)
    a, b = sd.simulate(0), sd.simulate(2**32 - 1)
    assert not np.array_equal(a.values("gyro/gyro_measurement"), b.values("gyro/gyro_measurement"))


def test_truth_going_non_finite_fails_loudly_and_writes_nothing(tmp_path):
    """A plant driven out of range (1e9 deg/s) used to exit 0 and write NaN into metrics.json:
    the run now fails with a message naming the truth signal and the time, exit code 2, no
    result folder."""
    import subprocess
    import sys

    out = tmp_path / "nan"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "drake_att.cli",
            "run",
            "cubesat_single_star_tracker",
            "--set",
            "plant.initial_rate_deg_per_s=[5000,1000,0]",
            "--set",
            "duration_s=20",
            "--set",
            "scoring.score_from_s=5",
            "--quiet",
            "--no-figures",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert "the truth signal 'rigid_body_plant/q_IB' is not finite from t =" in r.stderr
    assert "Traceback" not in r.stderr and not out.exists()


@pytest.mark.parametrize("compiled", [False, True])
def test_an_estimate_going_non_finite_fails_the_run_naming_it(monkeypatch, compiled):
    """A core that produces NaN (here the MEKF's prediction - or the compiled MEKF step -
    patched to return NaN after 5 steps) fails the run with NonFiniteRunError naming the
    estimate signal and the time, instead of writing NaN-derived metrics."""
    from drake_att.filters import mekf
    from drake_att.scenarios.builder import NonFiniteRunError, ScenarioDiagram
    from drake_att.systems import compiled_step
    from drake_att.systems.estimator_system import EstimatorSystem

    monkeypatch.setattr(EstimatorSystem, "use_compiled_step", compiled)
    steps = {"left": 5}
    if compiled:
        original_step = compiled_step.mekf_steps

        def poisoned_step(*args):
            original_step(*args)
            est, core = args[-5], args[-3]
            if steps["left"] <= 0:
                est[:4] = np.nan
                core[:4] = np.nan
            steps["left"] -= 1

        monkeypatch.setattr(compiled_step, "mekf_steps", poisoned_step)
    else:
        original = mekf.MultiplicativeEKF.predict_linearized

        def poisoned(self, state, w, dt):
            new, Phi, Q = original(self, state, w, dt)
            if float(new.P[0, 0]) > 0 and steps["left"] <= 0:
                return mekf.MekfState(new.q_IB * np.nan, new.bias_B, new.P), Phi, Q
            steps["left"] -= 1
            return new, Phi, Q

        monkeypatch.setattr(mekf.MultiplicativeEKF, "predict_linearized", poisoned)
    sd = ScenarioDiagram(
        apply_overrides(load("cubesat_single_star_tracker"), ["duration_s=20", "scoring.score_from_s=1"])
    )
    with pytest.raises(NonFiniteRunError, match=r"the estimate 'single/q_IB_hat' is not finite from t = "):
        sd.simulate(1)
    assert steps["left"] <= 0  # the poison was reached


def test_metrics_json_is_strict_json_with_null_for_non_finite_numbers(tmp_path):
    """JSON has no NaN or Infinity: they are written as null (a strict parser reads the file)."""
    import json

    from drake_att.analysis.report import write_metrics_json

    path = write_metrics_json(
        {"a": float("nan"), "b": [1.0, float("inf"), -float("inf")], "c": {"d": 2.5}}, str(tmp_path / "m.json")
    )

    def refuse(name):
        raise ValueError(f"non-strict JSON constant {name}")

    assert json.loads(open(path).read(), parse_constant=refuse) == {"a": None, "b": [1.0, None, None], "c": {"d": 2.5}}


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "the scenario is empty"),
        ("- 1\n- 2\n", "got a YAML list at the top level"),
        ("name: x\nduration_s: 5.0\nduration_s: 6.0\n", r"duplicate key 'duration_s' at line 3 \(first at line 2\)"),
        ("name: x\nbogus_key: 1\n", r"unknown field\(s\) \['bogus_key'\]; allowed: \['name', "),
        ("name: x\nduration_s: [\n", "invalid YAML"),
    ],
)
def test_bad_scenario_files_are_refused_with_a_message(text, message):
    """What used to be tracebacks or silent (a duplicate key kept the last value): a message
    naming the file and what is wrong."""
    from drake_att.scenarios.config import ConfigError, load_scenario

    with pytest.raises(ConfigError, match=message):
        load_scenario(text=text)


@pytest.mark.parametrize(
    "override, section",
    [("plant=5", "plant"), ("sensors.st1=5", "sensors.st1"), ("estimators.single=[1, 2]", "estimators.single")],
)
def test_overriding_a_whole_section_with_a_value_names_its_fields(override, section):
    from drake_att.scenarios.config import ConfigError, apply_overrides
    from drake_att.scenarios.library import load

    with pytest.raises(
        ConfigError,
        match=rf"--set {section}: got .*; {section} is a section \(\w+Config\): set one "
        r"of its fields",
    ):
        apply_overrides(load("cubesat_single_star_tracker"), [override])


def test_out_naming_an_existing_file_is_refused(tmp_path):
    import subprocess
    import sys

    f = tmp_path / "a_file"
    f.write_text("keep me")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "drake_att.cli",
            "run",
            "cubesat_single_star_tracker",
            "--set",
            "duration_s=5",
            "--set",
            "scoring.score_from_s=1",
            "--quiet",
            "--no-figures",
            "--out",
            str(f),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "is an existing file, not a folder" in r.stderr and "Traceback" not in r.stderr
    assert f.read_text() == "keep me"


def _cli(*args, cwd=None):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "drake_att.cli", *args], capture_output=True, text=True, cwd=cwd)


SHORT = ["--set", "duration_s=5", "--set", "scoring.score_from_s=1", "--quiet"]


@pytest.mark.slow
def test_rerun_replaces_the_whole_folder_and_says_so(tmp_path):
    """A run with figures, then one without: no PNG of the first run is left next to the
    second run's metrics; the CLI says it replaced the folder; no staging folder is left."""
    out = tmp_path / "r"
    assert _cli("run", "cubesat_single_star_tracker", *SHORT, "--out", str(out)).returncode == 0
    assert any(p.suffix == ".png" for p in out.iterdir())
    r = _cli("run", "cubesat_single_star_tracker", *SHORT, "--no-figures", "--seed", "2", "--out", str(out))
    assert r.returncode == 0 and "replacing the previous results" in r.stdout
    assert not any(p.suffix == ".png" for p in out.iterdir())
    assert "(seed 2)" in (out / "config.yaml").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_a_failed_write_leaves_the_previous_results_untouched(tmp_path, monkeypatch):
    """An interruption while writing (here: the log write raises KeyboardInterrupt) leaves
    the previous folder as it was and no staging folder behind."""
    from drake_att.analysis import report
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load

    sd = ScenarioDiagram(
        apply_overrides(load("cubesat_single_star_tracker"), ["duration_s=5", "scoring.score_from_s=1"])
    )
    run = sd.simulate(1)
    out = tmp_path / "r"
    report.write_results(sd, run, compute_metrics(run), str(out), figures=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(report.np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        report.write_results(sd, sd.simulate(2), compute_metrics(sd.simulate(2)), str(out), figures=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_result_folder_carries_a_manifest_of_its_files(tmp_path):
    """manifest.json lists every file the run wrote (bytes, SHA-256), is written last, and
    check_manifest finds a folder complete; it reports a changed, a missing and a foreign file."""
    from drake_att.analysis import report
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load

    sd = ScenarioDiagram(
        apply_overrides(load("cubesat_single_star_tracker"), ["duration_s=5", "scoring.score_from_s=1"])
    )
    run = sd.simulate(1)
    out = tmp_path / "r"
    written = report.write_results(sd, run, compute_metrics(run), str(out), figures=False)
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["scenario"], manifest["seed"]) == ("cubesat_single_star_tracker", 1)
    assert sorted(e["file"] for e in manifest["files"]) == sorted(
        p.name for p in out.iterdir() if p.name != "manifest.json"
    )
    assert written[-1].endswith("manifest.json")
    assert report.check_manifest(str(out)) == []
    (out / "metrics.json").write_text("{}")
    (out / "config.yaml").unlink()
    (out / "stray.png").write_bytes(b"x")
    problems = report.check_manifest(str(out))
    assert any(p.startswith("metrics.json: changed") for p in problems)
    assert any(p.startswith("config.yaml: missing") for p in problems)
    assert any(p.startswith("stray.png: not written") for p in problems)


@pytest.mark.slow
def test_default_folder_of_a_modified_run_differs_from_the_unmodified_one(tmp_path):
    import re

    outs = []
    for duration in (5, 6):
        r = _cli(
            "run",
            "cubesat_single_star_tracker",
            "--no-figures",
            "--quiet",
            "--set",
            f"duration_s={duration}",
            "--set",
            "scoring.score_from_s=1",
            cwd=tmp_path,
        )
        assert r.returncode == 0, r.stderr[-1000:]
        outs.append(re.search(r"Wrote \d+ files to (\S+)/", r.stdout).group(1))
    assert outs[0] != outs[1] and all(o.startswith("out/cubesat_single_star_tracker_seed1_") for o in outs)
    assert all((tmp_path / o / "metrics.json").is_file() for o in outs)


@pytest.mark.parametrize(
    "item, message",
    [
        (
            "!GyroConfig {name: g, bogus: 1}",
            r"sensors\[0\] \(g, !GyroConfig\): unknown field\(s\) \['bogus'\]; allowed: "
            r"\['name', 'period_s'",
        ),
        ("!NopeConfig {name: g}", r"sensors\[0\]: unknown type !NopeConfig; registered: \["),
    ],
)
def test_unknown_field_or_type_in_a_list_item_names_the_item_and_what_is_allowed(item, message):
    from drake_att.scenarios.config import ConfigError, load_scenario

    with pytest.raises(ConfigError, match=message):
        load_scenario(text=f"name: x\nsensors:\n- {item}\n")
