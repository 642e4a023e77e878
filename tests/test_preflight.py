"""Degenerate but valid scenarios are announced: a very expensive run before it
starts, a vector tracker whose references leave the attitude unobservable, and, after a run,
an estimator that never used a measurement."""

from __future__ import annotations

import pytest

from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import available_scenarios, load
from drake_att.scenarios.preflight import (
    SECONDS_PER_EVENT,
    DegenerateScenarioWarning,
    event_count,
    preflight_warnings,
    run_warnings,
)


def test_expensive_run_is_announced_with_its_event_count_and_the_smallest_period():
    s = apply_overrides(
        load("cubesat_single_star_tracker"), ["sensors.gyro.period_s=0.0001", "estimators.single.period_s=0.0001"]
    )
    events, _ = event_count(s)
    # gyro and MEKF at 1e4 Hz, tracker at 10 Hz, over 5000 s
    assert events == pytest.approx(5000 * (1e4 + 1e4 + 10), rel=1e-9)
    (message,) = preflight_warnings(s)
    assert "~1e+08 discrete events" in message and "sensors.gyro.period_s = 0.0001 s" in message
    assert f"{events * SECONDS_PER_EVENT / 60:.0f} min" in message
    with pytest.warns(DegenerateScenarioWarning, match="discrete events"):
        ScenarioDiagram(s)  # built (cheap), not run


@pytest.mark.parametrize("refs", ["[[1,0,0],[-2,0,0]]", "[[0,0,1]]", "[[0.6,0.8,0],[0.6,0.8,1e-9]]"])
def test_parallel_reference_directions_are_announced(refs):
    s = apply_overrides(load("s4_lie_group"), [f"sensors.st.references_I={refs}"])
    (message,) = preflight_warnings(s)
    assert message.startswith("sensors.st.references_I: got") and "unobservable" in message


def test_shipped_scenarios_raise_no_warning():
    for name in available_scenarios():
        assert preflight_warnings(load(name)) == [], name


def test_an_estimator_that_never_used_a_measurement_is_announced_after_the_run(drake_att_cli, tmp_path):
    """The tracker is out for the whole run: the CLI says so after the table."""
    proc = drake_att_cli(
        "run",
        "cubesat_single_star_tracker",
        "--no-figures",
        "--quiet",
        "--out",
        str(tmp_path / "r"),
        "--set",
        "duration_s=10",
        "--set",
        "scoring.score_from_s=1",
        "--set",
        "sensors.st1.outage_windows_s=[[-1.0, 100.0]]",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "drake-att: warning: estimator 'single' used no measurement in the whole run" in proc.stderr
    assert run_warnings({"estimators": {"a": {"measurements_used": 3, "measurements_skipped": 0}}}) == []


def test_a_fixed_step_truth_too_coarse_for_the_peak_rate_is_announced():
    """S3's tumble at 10 deg/s with the shipped fixed 0.1 s RK3 (1 deg per step) is announced;
    the shipped 0.87 deg/s is not, nor is the same tumble with error control."""
    s = apply_overrides(load("cubesat_single_star_tracker"), ["plant.initial_rate_deg_per_s=[0.0,0.0,10.0]"])
    (message,) = preflight_warnings(s)
    assert message.startswith("simulation: a fixed 0.1 s runge_kutta3 step") and "use_error_control" in message
    assert preflight_warnings(apply_overrides(s, ["simulation.use_error_control=true"])) == []
