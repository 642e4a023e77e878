"""Sweeps on one diagram: filter tunings, initial estimates, sensor noise
levels and the plant's initial conditions are context parameters, so a run with other
values reuses the diagram.

The oracle is independent of the mechanism: a diagram *built* with the overridden config.
Runs are pure functions of config + seed, so a context sweep must give exactly (bit for
bit) the metrics of that freshly built diagram - for every kind of parameter, including
values derived from others (a filter whose ARW defaults to its gyro's; the centralized
average's covariance derived from both trackers' sigmas; the tracked fusion's initial
cross covariance, which follows its sources' initial covariance).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drake_att.analysis.metrics import compute_metrics
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import ConfigError, apply_overrides, dump_scenario
from drake_att.scenarios.library import load
from drake_att.systems.estimator_system import EstimatorSetup

SEED = 2
S3_SHORT = ["duration_s=40", "scoring.score_from_s=10"]
S0_SHORT = [
    "duration_s=30",
    "scoring.score_from_s=10",
    "estimators.bootstrap_pf.num_particles=50",
    "estimators.bootstrap_pf_roughened.num_particles=50",
    "estimators.ekpf.num_particles=20",
]


def _metrics(run) -> dict:
    m = compute_metrics(run)
    m.pop("wall_time_s", None)
    return m


def _assert_same_metrics(a: dict, b: dict, where: str = ""):
    """Equal metrics trees (NaN equal to NaN), naming the first difference."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{where}: keys {sorted(a)} != {sorted(b)}"
        for k in a:
            if k != "wall_time_s":
                _assert_same_metrics(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same_metrics(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), f"{where}: {a!r} != {b!r}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


@pytest.fixture(scope="module")
def s3():
    return ScenarioDiagram(apply_overrides(load("cubesat_dual_star_tracker"), S3_SHORT))


@pytest.fixture(scope="module")
def s0():
    return ScenarioDiagram(apply_overrides(load("s0_particle_filters_small_error"), S0_SHORT))


S3_SWEEPS = {
    "filter initial covariance (+ the tracked fusion's P12 follows)": [
        f"estimators.{n}.initial_attitude_sigma_deg=0.05" for n in ("single", "centralized", "single_st2", "joint")
    ],
    # (the tracked fusion needs its two sources to start alike: both change)
    "filter initial estimate": [
        "estimators.single.initial_attitude_rpy_deg=[1.0, -2.0, 3.0]",
        "estimators.single_st2.initial_attitude_rpy_deg=[1.0, -2.0, 3.0]",
        "estimators.joint.initial_bias_deg_per_h=[5.0, 5.0, 5.0]",
    ],
    "filter tuning and gate": ["estimators.single.arw_deg_per_rt_h=2.0", "estimators.joint.innovation_gate_chi2=16.0"],
    "gyro noise (filters that default to it follow)": [
        "sensors.gyro.arw_deg_per_rt_h=1.5",
        "sensors.gyro.rrw_deg_per_h15=60.0",
        "sensors.gyro.initial_bias_deg_per_h=[3.0, -4.0, 5.0]",
    ],
    "tracker noise (the average's derived covariance follows)": [
        "sensors.st1.sigma_cross_boresight_arcsec=20.0",
        "sensors.st2.sigma_boresight_arcsec=120.0",
    ],
    "tracker availability": ["sensors.st2.dropout_probability=0.3", "sensors.st1.outage_windows_s=[[5.0, 15.0]]"],
    "plant initial conditions": [
        "plant.initial_rate_deg_per_s=[0.2, -0.1, 0.3]",
        "plant.initial_attitude_rpy_deg=[10.0, 0.0, -5.0]",
    ],
}


@pytest.mark.parametrize("kind", sorted(S3_SWEEPS))
def test_context_sweep_equals_a_diagram_built_with_the_override(s3, kind):
    over = S3_SWEEPS[kind]
    swept = s3.simulate(SEED, overrides=over)
    fresh = ScenarioDiagram(apply_overrides(s3.scenario, over)).simulate(SEED)
    _assert_same_metrics(_metrics(fresh), _metrics(swept), kind)
    default = _metrics(s3.simulate(SEED))
    assert default["estimators"]["single"] != _metrics(swept)["estimators"]["single"] or "fusion" in kind, (
        f"{kind}: the override changed nothing (the test would not see a parameter that is ignored)"
    )
    # The run carries the scenario it used.
    assert dump_scenario(swept.scenario) == dump_scenario(apply_overrides(s3.scenario, over))


def test_sweep_leaves_no_trace_in_later_runs(s3):
    """Contexts are independent: a default run after a sweep equals the first default run."""
    before = _metrics(s3.simulate(SEED))
    s3.simulate(
        SEED,
        overrides=[
            "sensors.gyro.arw_deg_per_rt_h=3.0",
            "estimators.single.initial_attitude_sigma_deg=9",
            "estimators.single_st2.initial_attitude_sigma_deg=9",
        ],
    )
    _assert_same_metrics(before, _metrics(s3.simulate(SEED)))


def test_particle_filter_sweep_equals_a_fresh_diagram(s0):
    """Random cores: the initial particle set is drawn from the context's core at
    initialization, so a swept initial covariance / threshold / noise is honoured."""
    over = [
        "estimators.bootstrap_pf.initial_attitude_sigma_deg=0.3",
        "estimators.ekpf.resample_threshold=0.9",
        "estimators.ekf.update_iterations=3",
        "sensors.st.sigma_vector_urad=200.0",
    ]
    swept = s0.simulate(SEED, overrides=over)
    fresh = ScenarioDiagram(apply_overrides(s0.scenario, over)).simulate(SEED)
    _assert_same_metrics(_metrics(fresh), _metrics(swept))


def test_estimator_selection_runs_only_the_chosen_ones(s3):
    """Switched-off estimators are not logged or scored; the chosen ones are unchanged (the
    MEKF is deterministic given the data, and the data do not depend on the selection)."""
    full = _metrics(s3.simulate(SEED))
    run = s3.simulate(SEED, estimators=["single", "joint"])
    assert [e.name for e in run.scenario.estimators] == ["single", "joint"]
    assert not [k for k in run.signals if k.startswith(("centralized/", "decentralized/", "single_st2/"))]
    m = _metrics(run)
    assert set(m["estimators"]) == {"single", "joint"}
    _assert_same_metrics(full["estimators"]["single"], m["estimators"]["single"])
    _assert_same_metrics(full["estimators"]["joint"], m["estimators"]["joint"])
    with pytest.raises(ConfigError, match=r"'decentralized' fuses \['single_st2'\]"):
        s3.simulate(SEED, estimators=["single", "decentralized"])
    with pytest.raises(ConfigError, match="choose a list of names from"):
        s3.simulate(SEED, estimators=["nope"])
    sensors_only = s3.simulate(SEED, estimators=[])
    assert not sensors_only.metadata["estimators"] and "gyro/gyro_measurement" in sensors_only.signals


def test_switched_off_estimator_does_nothing(s3):
    """Off: the estimate stays the initial one and no measurement is counted."""
    context = s3.create_context(SEED, estimators=["single"])
    from pydrake.systems.analysis import Simulator

    sim = Simulator(s3.diagram, context)
    sim.Initialize()
    sim.AdvanceTo(5.5)
    off = s3.estimators["joint"]
    on = s3.estimators["single"]
    x_off = off.estimate_vector(off.GetMyContextFromRoot(context))
    x_on = on.estimate_vector(on.GetMyContextFromRoot(context))
    assert x_off[44] == 0 and x_off[45] == 0 and x_off[43] == 0.0  # no step taken
    assert x_on[44] > 0 and x_on[43] == pytest.approx(5.0)


@pytest.mark.parametrize(
    "overrides, field",
    [
        (["estimators.centralized.star_trackers=[st1]"], "estimators.centralized.star_trackers"),
        (["estimators.joint.star_trackers=[st2, st1]"], "estimators.joint.star_trackers"),
        (["sensors.st1.period_s=0.2", "sensors.st2.period_s=0.2"], "sensors.st1.period_s"),
        (["sensors.gyro.sample_rate_hz=100"], "sensors.gyro.sample_rate_hz"),
        (["plant.inertia_kg_m2=[1.0, 2.0, 3.0]"], "plant.inertia_kg_m2"),
        (["orbit.altitude_km=700"], "orbit"),
    ],
)
def test_structural_override_is_refused_naming_the_field(s3, overrides, field):
    """Valid overrides that would need another diagram: refused, naming the field."""
    with pytest.raises(ConfigError) as e:
        s3.simulate(SEED, overrides=overrides)
    assert field in str(e.value) and "new ScenarioDiagram" in str(e.value)
    apply_overrides(s3.scenario, overrides)  # ... and they are valid configs


def test_particle_count_is_structural(s0):
    """The refusal says what to do instead: the field is structural, the estimator's per-run
    fields are listed (the plug-in's declared parameters), and how to build a diagram for it."""
    from drake_att.scenarios.registry import plugin_for

    with pytest.raises(
        ConfigError, match=r"estimators.ekpf.num_particles \(structural; ekpf.s per-run fields: [a-z]"
    ) as e:
        s0.create_context(SEED, overrides=["estimators.ekpf.num_particles=30"])
    text = str(e.value)
    ekpf = next(c for c in s0.scenario.estimators if c.name == "ekpf")
    per_run = text.split("ekpf's per-run fields: ", 1)[1].split(")", 1)[0].split(", ")
    assert per_run == list(plugin_for(ekpf).parameters) and "num_particles" not in per_run, text
    assert "diagram_for(drake_att.scenarios.config.apply_overrides(scenario, overrides))" in text, text
    assert "\n" not in text


def test_invalid_override_is_refused_before_any_run(s3):
    with pytest.raises(ConfigError, match=r"\(gyro\).arw_deg_per_rt_h: got -1.0"):
        s3.simulate(SEED, overrides=["sensors.gyro.arw_deg_per_rt_h=-1"])


def test_set_filter_refuses_a_structural_change(s3):
    """EstimatorSystem.set_filter: another core of another structure is an error naming it."""
    from drake_att.filters.mrp_ekf import MrpEkfCore

    system = s3.estimators["single"]
    context = system.CreateDefaultContext()
    core = MrpEkfCore(1e-4, 1e-6)
    init = core.initial_state(np.array([1.0, 0, 0, 0]), np.zeros(3), np.eye(6) * 1e-4)
    with pytest.raises(ValueError, match="single: the new filter setup changes the"):
        system.set_filter(context, EstimatorSetup(core, init, 1.0, gyro="gyro"))
    model = system.filter_model(context)
    with pytest.raises(ValueError, match=r"period_s \(1.0 -> 2.0\)"):
        system.set_filter(
            context, EstimatorSetup(model.core, model.initial_state, 2.0, quaternion_sensors=model.quaternion_sensors)
        )


@pytest.mark.slow
def test_reproduction_scripts_build_one_diagram_per_scenario_per_process(
    tmp_path, monkeypatch, diagram_builds, load_script
):
    """The S0 script (three scenarios: Monte Carlo, EKF initial-error sweep, per-filter
    timing) and the S3 script's P0 sweep, run in this process (one worker), construct
    exactly one ScenarioDiagram per scenario."""
    built = diagram_builds
    monkeypatch.setenv("MPLBACKEND", "Agg")
    s0 = load_script("particle_filters")
    assert (
        s0.main(
            ["--seeds", "1", "--particles", "8", "--duration", "6", "--workers", "1", "--out", str(tmp_path / "s0")]
        )
        == 0
    )
    assert sorted(built) == sorted(s0.SCENARIOS.values()), built

    built.clear()
    s3 = load_script("cubesat_dual_star_tracker")
    from drake_att.analysis.montecarlo import run_seeds

    scenario = apply_overrides(load("cubesat_dual_star_tracker"), ["duration_s=6", "scoring.score_from_s=2"])
    run_seeds(scenario, [1], workers=1)
    rows = s3.convergence_vs_p0(scenario, [5.0, 0.01], 1, str(tmp_path), duration_s=6.0)
    assert built == ["cubesat_dual_star_tracker"] and len(rows["convergence_s"]) == 2
