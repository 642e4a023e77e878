"""Batch runs: one diagram carrying N realizations gives, per seed, exactly the run a single
diagram gives (every logged array, bit for bit, and the metadata), through every path a
campaign takes; scenarios a batch cannot carry are named with the reason, and bad arguments
get a clear error."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from drake_att.analysis import executor
from drake_att.analysis.run_records import metrics_record
from drake_att.scenarios import builder, library
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import NonFiniteRunError, ScenarioDiagram, batch_problem, diagram_for

SCENARIO = "cubesat_single_star_tracker"


def _scenario(*overrides) -> cfg.Scenario:
    return cfg.apply_overrides(library.load(SCENARIO), ["duration_s=120", "scoring.score_from_s=30", *overrides])


def assert_runs_identical(single, batched) -> None:
    """Every signal of two RunLogs the same bytes, dtype and shape; the metadata equal but
    for the wall time."""
    assert batched.seed == single.seed
    assert list(batched.signals) == list(single.signals)
    for key, (t, x) in single.signals.items():
        tb, xb = batched.signals[key]
        for a, b in ((t, tb), (x, xb)):
            assert a.dtype == b.dtype and a.shape == b.shape, key
            assert a.tobytes() == b.tobytes(), key
    m1, m2 = dict(single.metadata), dict(batched.metadata)
    m1.pop("wall_time_s"), m2.pop("wall_time_s")
    assert m1 == m2


def _without_wall_time(records: list) -> list:
    """Metrics records with their one non-deterministic number (the wall time) taken out."""
    out = []
    for r in records:
        r = dict(r)
        metrics = json.loads(str(r.pop("metrics_json")))
        metrics.pop("wall_time_s")
        out.append((metrics, sorted(r)))
    return out


# Every noise source and error of the gyro and the tracker switched on, and a 10 Hz filter on a
# 5 Hz tracker (its samples between filter steps and its held ones).
RICH = [
    "sensors.gyro.period_s=0.1",
    "sensors.gyro.initial_bias_sigma_deg_per_h=5.0",
    "sensors.gyro.scale_factor_error_ppm=[300.0, -200.0, 100.0]",
    "sensors.gyro.misalignment_urad=[100.0, -50.0, 20.0, 0.0, 30.0, -10.0]",
    "sensors.gyro.range_deg_per_s=0.6",
    "sensors.st1.period_s=0.2",
    "sensors.st1.dropout_probability=0.2",
    "sensors.st1.outage_windows_s=[[40.0, 55.0]]",
    "estimators.single.period_s=0.1",
    "estimators.single.innovation_gate_probability=0.99",
]


@pytest.mark.parametrize("overrides", [[], RICH], ids=["shipped", "every_noise"])
def test_batch_equals_single_runs_bit_for_bit(overrides):
    scenario = _scenario(*overrides)
    seeds = [3, 1, 12345]
    batch = ScenarioDiagram(scenario, realizations=len(seeds)).simulate_batch(seeds)
    single = diagram_for(scenario)
    for seed, run in zip(seeds, batch, strict=True):
        assert_runs_identical(single.simulate(seed), run)
    # the realizations differ from each other (each reads its own seed's noise)
    q = [run.signals["st1/star_tracker_measurement"][1] for run in batch]
    assert not np.array_equal(q[0], q[1]) and not np.array_equal(q[1], q[2])


DUAL_CASES = {
    "shipped": [],
    # the averaged tracker's subsets and the tracked fusion with a branch that has not yet used a sample
    "dropouts_and_an_outage": [
        "sensors.st1.dropout_probability=0.3",
        "sensors.st2.dropout_probability=0.3",
        "sensors.st2.outage_windows_s=[[0.0, 60.0]]",
    ],
    "conservative_dead_branch": [
        "estimators.decentralized.covariance_model=conservative",
        "sensors.st1.outage_windows_s=[[0.0, 120.0]]",
    ],
}


@pytest.mark.parametrize("case", list(DUAL_CASES))
def test_the_dual_tracker_scenario_batch_equals_single_runs(case):
    """Paper S3's five estimators: MEKFs on one tracker, on the averaged tracker and on both, and
    the fusion of two of them (its tracked cross-covariance per realization)."""
    scenario = cfg.apply_overrides(
        library.load("cubesat_dual_star_tracker"), ["duration_s=120", "scoring.score_from_s=30", *DUAL_CASES[case]]
    )
    seeds = [7, 8]
    batch = ScenarioDiagram(scenario, realizations=2).simulate_batch(seeds)
    single = diagram_for(scenario)
    for seed, run in zip(seeds, batch, strict=True):
        assert_runs_identical(single.simulate(seed), run)
    fused = [run.signals["decentralized/covariance"][1] for run in batch]
    assert np.all(np.isfinite(fused[0])) and not np.array_equal(fused[0], fused[1])


def test_batch_with_parameter_overrides_and_estimator_selection():
    """Per-run context parameters (noise levels) and a switched-off estimator, as a campaign's
    ``--set`` and ``--estimators`` give them, on a batch of two MEKFs."""
    base = _scenario()
    other = dataclasses.replace(base.estimators[0], name="other", initial_attitude_sigma_deg=2.0)
    scenario = cfg.load_scenario(
        text=cfg.dump_scenario(dataclasses.replace(base, estimators=[*base.estimators, other]))
    )
    overrides = ["sensors.st1.sigma_boresight_arcsec=80.0", "sensors.gyro.arw_deg_per_rt_h=0.9"]
    seeds = [5, 6]
    batch_diagram = ScenarioDiagram(scenario, realizations=2)
    single = diagram_for(scenario)
    for estimators in (None, ["other"]):
        runs = batch_diagram.simulate_batch(seeds, overrides=overrides, estimators=estimators)
        for seed, run in zip(seeds, runs, strict=True):
            assert_runs_identical(single.simulate(seed, overrides=overrides, estimators=estimators), run)
    assert not any(k.startswith("single/") for k in runs[0].signals)


def test_batch_problem_names_what_a_batch_cannot_carry():
    expected = {
        "cubesat_single_star_tracker": None,
        "cubesat_dual_star_tracker": None,
        "cubesat_sso_mission": "attitude controller",
        "fault_campaign": "SensorFaultsConfig",
        "s1_cqe": "quaternion mode",
        "s2_indoor_static": "ScreenCameraConfig",
    }
    for name, fragment in expected.items():
        problem = batch_problem(library.load(name))
        assert (problem is None) if fragment is None else (fragment in problem), (name, problem)
    with pytest.raises(ValueError, match="cannot run as a batch: .*quaternion mode"):
        ScenarioDiagram(library.load("s1_cqe"), realizations=2)


def test_an_estimator_off_the_compiled_step_refuses_realizations_and_the_runs_fall_back():
    """Coning correction takes the MEKF off the compiled step: its system refuses N > 1 naming
    the field, and the executor runs the seeds one by one instead (the same records)."""
    scenario = _scenario("estimators.single.coning_correction=true")
    assert batch_problem(scenario) is None  # only building the estimator finds out
    with pytest.raises(ValueError, match=r"single\.realizations: got 2; more than one needs an MEKF with compiled"):
        ScenarioDiagram(scenario, realizations=2)
    batched = executor.map_runs(scenario, [1, 2], metrics_record, workers=1, batch_size=2)
    alone = executor.map_runs(scenario, [1, 2], metrics_record, workers=1, batch_size=1)
    assert _without_wall_time(batched) == _without_wall_time(alone)


def test_map_runs_batches_give_the_records_of_runs_alone():
    scenario = _scenario()
    before = dict(executor._WORKER_STATS)
    seeds = [1, 2, 3, 4, 5]
    batched = executor.map_runs(scenario, seeds, metrics_record, workers=1, batch_size=2)
    after = dict(executor._WORKER_STATS)
    alone = executor.map_runs(scenario, seeds, metrics_record, workers=1, batch_size=1)
    assert _without_wall_time(batched) == _without_wall_time(alone)
    assert after["runs"] - before["runs"] == 5
    # chunks of 2, 2 and 1: the last seed ran alone, the others in batch diagrams of two
    assert executor._WORKER_BATCH_DIAGRAMS.get((cfg.dump_scenario(scenario), 2)) is not None
    assert (cfg.dump_scenario(scenario), 1) not in executor._WORKER_BATCH_DIAGRAMS


def test_a_non_finite_realization_fails_alone(monkeypatch):
    """A realization whose estimate is not finite is that seed's RunFailed; its batch-mates'
    records are kept (as runs alone would give)."""
    scenario = _scenario()
    original = builder._check_estimates_finite

    def fail_seed_2(signals, run_scenario, name, seed, second_names):
        if seed == 2:
            raise NonFiniteRunError(f"{name} seed {seed}: estimate not finite (test)")
        original(signals, run_scenario, name, seed, second_names)

    monkeypatch.setattr(builder, "_check_estimates_finite", fail_seed_2)
    runs = ScenarioDiagram(scenario, realizations=3).simulate_batch([1, 2, 3])
    assert isinstance(runs[1], NonFiniteRunError) and "seed 2" in str(runs[1])
    results = executor.map_runs(scenario, [1, 2, 3], metrics_record, workers=1, batch_size=3)
    assert isinstance(results[1], executor.RunFailed) and results[1].seed == 2
    assert not isinstance(results[0], executor.RunFailed) and not isinstance(results[2], executor.RunFailed)


def test_bad_batch_arguments_are_named():
    scenario = _scenario()
    for bad in (0, -1, 2.5, "3"):
        with pytest.raises(ValueError, match=f"realizations: got {bad!r}"):
            ScenarioDiagram(scenario, realizations=bad)
    batch = ScenarioDiagram(scenario, realizations=2)
    with pytest.raises(ValueError, match="seeds: got 3; this batch diagram runs 2 at once"):
        batch.simulate_batch([1, 2, 3])
    with pytest.raises(ValueError, match="runs seeds with simulate_batch"):
        batch.simulate(1)
    with pytest.raises(ValueError, match="seed"):
        batch.simulate_batch([1, -4])
    for bad in (0, 1.5, None):
        with pytest.raises(executor.CampaignError, match="batch_size: got"):
            executor.map_runs(scenario, [1, 2], metrics_record, workers=1, batch_size=bad)


def test_batches_fit_in_the_available_memory(monkeypatch):
    """A batch holds its realizations' logs and their per-run copies: with memory for less than
    two runs' worth of both, seeds run alone; with memory for three, batches of three."""
    from drake_att.scenarios import preflight

    scenario = _scenario("duration_s=60", "scoring.score_from_s=20")
    per_run = preflight.memory_estimate(scenario).total_bytes
    key = cfg.dump_scenario(scenario)
    seeds = [1, 2, 3, 4, 5, 6]
    monkeypatch.setattr(executor, "_WORKER_BATCH_DIAGRAMS", {})  # this test's batch diagrams only
    monkeypatch.setattr(preflight, "available_memory_bytes", lambda: 2 * per_run * 1.9)
    assert executor._batch_fit(scenario, 1) == 1
    executor.map_runs(scenario, seeds, metrics_record, workers=1, batch_size=6)
    assert not any(k[0] == key for k in executor._WORKER_BATCH_DIAGRAMS)
    monkeypatch.setattr(preflight, "available_memory_bytes", lambda: 2 * per_run * 3.5)
    assert executor._batch_fit(scenario, 1) == 3 and executor._batch_fit(scenario, 2) == 1
    executor.map_runs(scenario, seeds, metrics_record, workers=1, batch_size=6)
    assert [k[1] for k in executor._WORKER_BATCH_DIAGRAMS if k[0] == key] == [3]
    monkeypatch.setattr(preflight, "available_memory_bytes", lambda: None)
    assert executor._batch_fit(scenario, 1) == 1


def test_the_cli_batch_size_option(tmp_path):
    """``--batch-size`` out of range exits 2 naming it and writes nothing; ``--batch-size 1``
    and the default give the same records."""
    from drake_att.analysis import montecarlo as mc
    from drake_att.cli import main as cli_main

    short = ["--set", "duration_s=40", "--set", "scoring.score_from_s=10"]
    for bad in ("0", "1001", "-3"):
        out = tmp_path / f"bad{bad}"
        assert (
            cli_main(
                [
                    "montecarlo",
                    SCENARIO,
                    "--runs",
                    "2",
                    "--workers",
                    "1",
                    "--batch-size",
                    bad,
                    "--out",
                    str(out),
                    "--quiet",
                    *short,
                ]
            )
            == 2
        )
        assert not out.exists()
    records = {}
    for size in ("1", None):
        out = tmp_path / f"size{size}"
        args = ["montecarlo", SCENARIO, "--runs", "3", "--workers", "1", "--out", str(out), "--quiet", *short]
        assert cli_main(args + (["--batch-size", size] if size else [])) == 0
        records[size] = [mc.load_record(str(out / "runs" / f"seed_{s}.npz")) for s in (1, 2, 3)]
    for a, b in zip(records["1"], records[None], strict=True):
        assert _without_wall_time([a]) == _without_wall_time([b])
        for key in a:
            if key != "metrics_json":
                x, y = np.asarray(a[key]), np.asarray(b[key])
                assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), key
    with pytest.raises(executor.CampaignError, match="batch_size: got True"):
        mc.run_campaign(SCENARIO, 2, workers=1, batch_size=True, progress=False)


@pytest.mark.parametrize(
    "jobs, processes, batch_size, fit, expected",
    [
        (20, 1, 10, 100, 10),  # serial: batches of batch_size
        (20, 2, 10, 100, 10),  # two workers, ten each
        (20, 4, 10, 100, 5),  # four workers: an even share, none idle
        (7, 2, 10, 100, 4),  # ceil(7 / 2)
        (100, 2, 10, 3, 3),  # memory holds three
        (3, 4, 10, 100, 1),  # more workers than runs: no batches
    ],
)
def test_batch_chunk_size(jobs, processes, batch_size, fit, expected):
    assert executor.batch_chunk_size(jobs, processes, batch_size, fit) == expected


def test_with_the_compiled_step_off_seeds_run_alone(monkeypatch):
    """``EstimatorSystem.use_compiled_step = False`` (the Python loop, the specification) leaves
    no batch: the estimator refuses realizations and the executor runs each seed alone."""
    from drake_att.systems.estimator_system import EstimatorSystem

    scenario = _scenario("duration_s=40", "scoring.score_from_s=10")
    monkeypatch.setattr(EstimatorSystem, "use_compiled_step", False)
    monkeypatch.setattr(executor, "_WORKER_BATCH_DIAGRAMS", {})
    with pytest.raises(ValueError, match="use_compiled_step switches off"):
        ScenarioDiagram(scenario, realizations=2)
    records = executor.map_runs(scenario, [1, 2], metrics_record, workers=1, batch_size=2)
    assert len(records) == 2 and list(executor._WORKER_BATCH_DIAGRAMS.values()) == [None]
