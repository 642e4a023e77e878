"""The scenario's ``logging:`` section (drake_att.scenarios.logging_policy): the default logs
as without a policy, decimated signals hold the full-rate log's samples (estimators: the
estimate of each logged time), scoring a decimated run equals scoring the full-rate run at
those times (RMSE written from its definition here), exclusions, and one-line refusals."""

import numpy as np
import pytest
from pydrake.systems.primitives import ZeroOrderHold

from drake_att.analysis.metrics import compute_metrics
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import ScenarioDiagram

DUAL = "drake_att/scenarios/cubesat_dual_star_tracker.yaml"  # trackers 0.1 s, gyro and filters 1 s
DURATION = 200.0
P = 10.0  # 10 filter steps, 100 tracker samples


def _scenario(path=DUAL, *overrides):
    base = cfg.load_scenario(filename=path)
    return cfg.apply_overrides(base, [f"duration_s={DURATION}", "scoring.score_from_s=20", *overrides])


@pytest.fixture(scope="module")
def full_run():
    return ScenarioDiagram(_scenario()).simulate()


@pytest.fixture(scope="module")
def decimated_run():
    return ScenarioDiagram(_scenario(DUAL, f"logging={{period_s: {P}}}")).simulate()


def _rotvec_error(q_hat, q):
    """rotation vector of q_hat^-1 (x) q (wxyz, Hamilton), written out here."""
    w1, v1 = q_hat[:, 0], -q_hat[:, 1:]
    w2, v2 = q[:, 0], q[:, 1:]
    w = w1 * w2 - np.sum(v1 * v2, axis=1)
    v = w1[:, None] * v2 + w2[:, None] * v1 + np.cross(v1, v2)
    v = np.where((w < 0)[:, None], -v, v)
    w = np.abs(w)
    s = np.linalg.norm(v, axis=1)
    angle = 2 * np.arctan2(s, w)
    return v * np.where(s > 0, angle / np.where(s > 0, s, 1), 2.0)[:, None]


def _at(t_ref, t_query):
    """Index of each query time in t_ref (exact to 1e-9 s)."""
    idx = np.searchsorted(t_ref, t_query - 1e-9)
    assert np.allclose(t_ref[idx], t_query, atol=1e-9, rtol=0)
    return idx


@pytest.mark.parametrize(
    "path", [DUAL, "drake_att/scenarios/s2_indoor_static.yaml", "drake_att/scenarios/s0_gyroless_pf.yaml"]
)
def test_default_logs_every_signal_at_its_own_period_through_no_hold(path):
    scenario = _scenario(path, "duration_s=20", "scoring.score_from_s=0")
    sd = ScenarioDiagram(scenario)
    assert not any(isinstance(s, ZeroOrderHold) for s in sd.diagram.GetSystems())
    run = sd.simulate()
    plan = run.metadata["logging"]
    assert plan["excluded"] == []
    assert set(plan["periods_s"]) == set(run.signals)
    for key, (t, _) in run.signals.items():
        T = plan["periods_s"][key]
        n = int(round(20.0 / T))
        np.testing.assert_allclose(t, np.arange(n + 1) * T, atol=1e-9, err_msg=key)


def test_decimated_samples_are_the_full_rate_samples_at_their_times(full_run, decimated_run):
    plan = decimated_run.metadata["logging"]["periods_s"]
    assert set(plan.values()) == {P}
    t_k = np.arange(0.0, DURATION - P + 1e-9, P)  # k P while k P + P <= duration
    for key in ("rigid_body_plant/q_IB", "rigid_body_plant/w_IB_B", "st1/star_tracker_measurement", "gyro/bias_B"):
        t, x = decimated_run.signals[key]
        np.testing.assert_allclose(t, t_k, atol=1e-9, rtol=0, err_msg=key)
        t_full, x_full = full_run.signals[key]
        np.testing.assert_allclose(x, x_full[_at(t_full, t_k)], rtol=0, atol=1e-12, err_msg=key)
    # An estimator's sample at t_k is its estimate of t_k (the full-rate log holds it one step later).
    for name in ("single", "joint"):
        status = decimated_run.values(f"{name}/status")
        np.testing.assert_allclose(status[:, 0], t_k, atol=1e-9, rtol=0)
        t_full = full_run.times(f"{name}/q_IB_hat")
        i = _at(t_full, t_k + 1.0)
        np.testing.assert_allclose(full_run.values(f"{name}/status")[i, 0], t_k, atol=1e-9, rtol=0)
        for port in ("q_IB_hat", "bias_B_hat", "covariance"):
            np.testing.assert_allclose(
                decimated_run.values(f"{name}/{port}"), full_run.values(f"{name}/{port}")[i], rtol=0, atol=1e-12
            )


def test_scoring_a_decimated_run_equals_the_full_rate_run_at_its_times(full_run, decimated_run):
    metrics = compute_metrics(decimated_run)
    t_k = np.arange(20.0, DURATION - P + 1e-9, P)  # the scored times: t >= score_from_s
    t_truth, q_truth = full_run.signals["rigid_body_plant/q_IB"]
    t_bias, bias = full_run.signals["gyro/bias_B"]
    for name, m in metrics["estimators"].items():
        status = full_run.values(f"{name}/status")
        i = _at(full_run.times(f"{name}/q_IB_hat"), t_k + 1.0)  # the estimate of t_k, logged a step later
        assert np.allclose(status[i, 0], t_k, atol=1e-9)
        dtheta = _rotvec_error(full_run.values(f"{name}/q_IB_hat")[i], q_truth[_at(t_truth, t_k)])
        rmse_deg = np.degrees(np.sqrt(np.mean(dtheta**2, axis=0)))
        assert m["samples_scored"] == len(t_k)
        np.testing.assert_allclose(m["attitude_rmse_deg"], rmse_deg, rtol=1e-9, err_msg=name)
        bias_err = bias[_at(t_bias, t_k)] - full_run.values(f"{name}/bias_B_hat")[i]
        deg_per_h = np.pi / 180 / 3600
        np.testing.assert_allclose(
            m["bias_rmse_deg_per_h"], np.sqrt(np.mean(bias_err**2, axis=0)) / deg_per_h, rtol=1e-9, err_msg=name
        )


def test_periods_per_pattern_and_exclusion():
    scenario = _scenario(DUAL, 'logging={periods_s: {"st1/*": 0.5, "*/innovations": 5.0}, exclude: ["st2/*"]}')
    run = ScenarioDiagram(scenario).simulate()
    assert "st2/star_tracker_measurement" not in run.signals
    assert run.metadata["logging"]["excluded"] == ["st2/star_tracker_measurement"]
    np.testing.assert_allclose(np.diff(run.times("st1/star_tracker_measurement")), 0.5, atol=1e-9)
    np.testing.assert_allclose(np.diff(run.times("joint/innovations")), 5.0, atol=1e-9)
    np.testing.assert_allclose(np.diff(run.times("rigid_body_plant/q_IB")), 0.1, atol=1e-9)
    assert run.metadata["logging"]["periods_s"]["joint/innovations"] == 5.0
    assert set(compute_metrics(run)["estimators"]) == {"single", "centralized", "single_st2", "joint", "decentralized"}


def test_period_s_rounds_down_to_a_multiple_of_each_signals_own_period():
    run = ScenarioDiagram(
        _scenario(DUAL, 'logging={period_s: 2.55, periods_s: {"rigid_body_plant/*": 1.0}}')
    ).simulate()
    periods = run.metadata["logging"]["periods_s"]
    assert periods["rigid_body_plant/q_IB"] == pytest.approx(1.0)  # periods_s wins
    assert periods["st1/star_tracker_measurement"] == pytest.approx(2.5)  # floor(2.55 / 0.1) = 25
    assert periods["joint/q_IB_hat"] == pytest.approx(2.0)  # floor(2.55 / 1) = 2
    np.testing.assert_allclose(np.diff(run.times("st1/star_tracker_measurement")), 2.5, atol=1e-9)
    np.testing.assert_allclose(run.values("joint/status")[:, 0], np.arange(0.0, DURATION - 2.0 + 1e-9, 2.0), atol=1e-9)
    assert compute_metrics(run)["estimators"]["joint"]["samples_scored"] == len(np.arange(20.0, 198.0 + 1e-9, 2.0))


@pytest.mark.parametrize(
    "logging, expected",
    [
        ('{exclude: ["rigid_body_plant/*"]}', "logging.exclude[0]: got 'rigid_body_plant/*', which matches"),
        ('{exclude: ["joint/covariance"]}', "'joint/covariance' (the estimate of 'joint')"),
        ('{exclude: ["gyro/bias_B"]}', "'gyro/bias_B' (the true gyro bias"),
        ('{exclude: ["nothing/*"]}', "logging.exclude[0]: got 'nothing/*', which matches no logged signal"),
        ('{periods_s: {"st1/*": 0.25}}', "logging.periods_s['st1/*']: got 0.25 for 'st1/star_tracker_measurement'"),
        ('{periods_s: {"nothing": 1.0}}', "logging.periods_s['nothing']: matches no logged signal"),
        ('{periods_s: {"st*": 1.0, "*measurement": 2.0}}', "logging.periods_s: the patterns"),
        ('{periods_s: {"joint/q_IB_hat": 2.0}}', "they are one logged port (joint/estimate_state)"),
        (
            '{periods_s: {"rigid_body_plant/*": 10.0, "single/*": 5.0}}',
            "the estimate of 'single' would be logged every 5 s",
        ),
        (
            '{periods_s: {"gyro/bias_B": 4.0, "*/q_IB_hat": 6.0, "*/status": 6.0, "*/covariance": 6.0, "*/bias_B_hat": 6.0}}',
            "'gyro/bias_B' (the true gyro bias) every 4 s",
        ),
        ("{period_s: 150.0}", "a run of 200 s would hold at most one sample"),
        (
            "{period_s: 2.55}",
            "'single' would be logged every 2 s and 'rigid_body_plant/q_IB' (the truth attitude) every 2.5 s",
        ),
    ],
)
def test_refusals_name_the_field_in_one_line(logging, expected):
    with pytest.raises(cfg.ConfigError) as e:
        ScenarioDiagram(_scenario(DUAL, f"logging={logging}"))
    assert expected in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "logging, expected",
    [
        ("{period_s: -1.0}", "logging.period_s: got -1.0; must be > 0"),
        ("{periods_s: [1.0]}", "logging.periods_s: got [1.0]; must be a mapping"),
        ('{periods_s: {"st1/*": 1e9}}', "logging.periods_s['st1/*']: got 1000000000.0; must be in [1e-5, 1e5] s"),
        ('{periods_s: {"st1/*": x}}', "logging.periods_s['st1/*']: got 'x'; must be a number"),
        ('{exclude: [""]}', "logging.exclude[0]: got ''; must be a non-empty signal key or pattern"),
    ],
)
def test_loading_refuses_a_malformed_section(logging, expected):
    text = open(DUAL).read() + f"\nlogging: {logging}\n"
    with pytest.raises(cfg.ConfigError) as e:
        cfg.load_scenario(text=text)
    assert expected in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("command", ["check", "run"])
def test_the_cli_refuses_a_policy_that_matches_no_signal_in_one_line(command, tmp_path, capsys):
    """``check`` builds the diagram too, so it refuses what ``run`` would (exit 2, one line)."""
    from drake_att.cli import main

    args = [command, "cubesat_single_star_tracker", "--set", "duration_s=5", "--set", "scoring.score_from_s=1"]
    args += ["--set", 'logging.periods_s={"nosuch/*": 1.0}'] + (
        ["--out", str(tmp_path / "o")] if command == "run" else []
    )
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("drake-att: logging.periods_s['nosuch/*']: matches no logged signal")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "policy", [None, {"period_s": 10.0}, {"period_s": 10.0, "periods_s": {"st1/*": 0.1}}, {"exclude": ["st2/*"]}]
)
def test_the_memory_preflight_follows_the_policy(policy):
    """The preflight's log estimate (the memory check and the result folder's size) is an upper
    bound of what the run logs, within 30%, with or without a policy: the mission's day is
    checked at what it keeps, not at full rate."""
    from drake_att.scenarios import preflight
    from drake_att.scenarios.library import load

    s = cfg.apply_overrides(load("cubesat_dual_star_tracker"), ["duration_s=200", "scoring.score_from_s=50"])
    if policy is not None:
        s.logging = cfg.LoggingConfig(**policy)
    run = ScenarioDiagram(s).simulate(1)
    logged = sum(t.nbytes + x.nbytes for t, x in run.signals.values())
    assert logged <= preflight.log_bytes(s) <= 1.3 * logged
