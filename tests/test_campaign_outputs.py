"""What a Monte Carlo campaign and a comparison show their user, checked from the inputs:

* the campaign progress line (``CampaignProgress``): runs done of the total, the runs reused
  from before, the label, the wall time and the ETA (the pace since the first result), one
  log line per ~5 % of the runs;
* ``run_seeds`` (the paper scripts): the error series of the seeds asked for only, consistent
  with the same run's metrics; a run that goes non-finite raises instead of being returned;
* ``comparison_plan``: a NAME missing from a listed scenario is a skipped cell that says why;
* ``run_comparison``: the per-estimator time is its fastest repeat minus the fastest
  sensors-only run (with staged wall times), a serial comparison runs serially (its
  campaigns say so), and a parallel one connects one cluster of ``--workers`` processes
  before it writes anything.

Imports the library as ``montecarlo`` only, so the file runs both before and after that
module was split (the private names it patches are looked up in ``run_comparison``'s module).
"""

from __future__ import annotations

import io
import json
import math
import os
import sys

import numpy as np
import pytest

from drake_att.analysis import montecarlo as mc

SINGLE = "cubesat_single_star_tracker"
DUAL = "cubesat_dual_star_tracker"
SHORT = ["duration_s=60", "scoring.score_from_s=20"]
SCORE_FROM_S = 20.0


def human(seconds: float) -> str:
    """The documented duration text: ``12.3 s``, ``4 min 05 s``, ``2 h 03 min``."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    s = int(round(seconds))
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Clock:
    def __init__(self, now: float = 0.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


def comparison_module():
    """The module whose globals ``run_comparison`` reads (montecarlo before the split,
    comparison after it)."""
    return sys.modules[mc.run_comparison.__module__]


# ----------------------------------------------------------------------------------------
# The progress line
# ----------------------------------------------------------------------------------------
def test_progress_log_prints_one_line_per_twentieth_with_counts_wall_and_eta():
    """40 fresh runs in a log (no tty): a line after every 2nd run (40 // 20), each
    ``  N / 40 runs (P%)  <wall> wall  ETA <left x pace since the first result>``; the last
    says ``done``. No label: no brackets; nothing reused: no "from before"."""
    clock, stream = Clock(), io.StringIO()
    bar = mc.CampaignProgress(40, stream=stream, tty=False, start=0.0, clock=clock)
    first_at, pace = 10.0, 4.0  # the first result after 10 s, then one every 4 s
    for k in range(1, 41):
        clock.now = first_at + pace * (k - 1)
        bar.run_done()
    lines = stream.getvalue().splitlines()
    expected = []
    for done in range(2, 41, 2):
        elapsed = first_at + pace * (done - 1)
        left = 40 - done
        eta = "done" if left == 0 else "ETA " + human((elapsed - first_at) / (done - 1) * left)
        expected.append(f"  {done} / 40 runs ({100 * done // 40:>3d}%)  {human(elapsed)} wall  {eta}")
    assert lines == expected
    assert lines[0] == "  2 / 40 runs (  5%)  14.0 s wall  ETA 2 min 32 s"


def test_progress_line_of_a_resumed_labelled_campaign_names_the_reused_runs():
    """10 runs, 4 reused from before: every run prints (6 // 20 < 1), counts include the
    reused ones; the first line's ETA extrapolates the elapsed time (one result, no pace yet)."""
    clock, stream = Clock(), io.StringIO()
    bar = mc.CampaignProgress(10, 4, "cubesat", stream=stream, tty=False, start=0.0, clock=clock)
    assert bar.line(0) == "  [cubesat] 4 / 10 runs (4 from before) ( 40%)  0.0 s wall  ETA unknown"
    for now in (10.0, 14.0, 20.0, 21.0, 30.0, 36.0):
        clock.now = now
        bar.run_done()
    assert stream.getvalue().splitlines() == [
        "  [cubesat] 5 / 10 runs (4 from before) ( 50%)  10.0 s wall  ETA 50.0 s",  # 10 s x 5 left / 1 done
        "  [cubesat] 6 / 10 runs (4 from before) ( 60%)  14.0 s wall  ETA 16.0 s",  # (14 - 10) / 1 x 4 left
        "  [cubesat] 7 / 10 runs (4 from before) ( 70%)  20.0 s wall  ETA 15.0 s",  # (20 - 10) / 2 x 3
        "  [cubesat] 8 / 10 runs (4 from before) ( 80%)  21.0 s wall  ETA 7.3 s",  # (21 - 10) / 3 x 2
        "  [cubesat] 9 / 10 runs (4 from before) ( 90%)  30.0 s wall  ETA 5.0 s",  # (30 - 10) / 4 x 1
        "  [cubesat] 10 / 10 runs (4 from before) (100%)  36.0 s wall  done",
    ]


# ----------------------------------------------------------------------------------------
# run_seeds (the paper scripts)
# ----------------------------------------------------------------------------------------
def test_run_seeds_keeps_the_error_series_of_the_listed_seeds_consistent_with_their_metrics():
    """``keep_series_for=[2]``: seed 2 has every estimator's series (t, dtheta, second_err,
    sigma = the covariance's 6 standard deviations), seed 1 none; the series reproduce the
    run's own RMSE, bias RMSE and final 3-sigma from their definitions."""
    s = mc.resolve_scenario(DUAL, SHORT, ["single", "centralized"])
    one, two = mc.run_seeds(s, [1, 2], workers=1, keep_series_for=[2])
    assert "series" not in one
    assert set(two["series"]) == {"single", "centralized"}
    for name, series in two["series"].items():
        metrics = two["metrics"]["estimators"][name]
        t, dtheta, sigma = series["t"], series["dtheta"], series["sigma"]
        assert dtheta.shape == (len(t), 3) and sigma.shape == (len(t), 6)
        assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
        scored = t >= SCORE_FROM_S - 1e-6
        assert int(scored.sum()) == metrics["samples_scored"]
        np.testing.assert_allclose(
            np.degrees(np.sqrt(np.mean(dtheta[scored] ** 2, axis=0))), metrics["attitude_rmse_deg"], rtol=1e-12
        )
        np.testing.assert_allclose(
            np.degrees(np.sqrt(np.mean(series["second_err"][scored] ** 2, axis=0))) * 3600.0,
            metrics["bias_rmse_deg_per_h"],
            rtol=1e-12,
        )
        np.testing.assert_allclose(3 * np.degrees(sigma[-1, :3]), metrics["attitude_3sigma_final_deg"], rtol=1e-12)


def test_run_seeds_raises_when_a_run_goes_non_finite():
    """The paper scripts never average a failed run: a truth driven out of range (5000 deg/s)
    raises NonFiniteRunError naming the signal, instead of returning a placeholder."""
    from drake_att.scenarios.builder import NonFiniteRunError

    s = mc.resolve_scenario(
        SINGLE, ["plant.initial_rate_deg_per_s=[5000,1000,0]", "duration_s=20", "scoring.score_from_s=5"]
    )
    with pytest.raises(NonFiniteRunError, match="is not finite from t ="):
        mc.run_seeds(s, [1], workers=1)


# ----------------------------------------------------------------------------------------
# comparison_plan / run_comparison
# ----------------------------------------------------------------------------------------
def test_comparison_plan_names_an_estimator_a_scenario_lacks_as_skipped():
    """``--estimators single,centralized`` over the single- and the dual-tracker scenario:
    the single-tracker scenario has no ``centralized``, so that cell is skipped with the
    reason (the note ``drake-att compare`` prints); the three others run."""
    plan = mc.comparison_plan([SINGLE, DUAL], estimators=["single", "centralized"], overrides=SHORT)
    assert {k for k, why in plan.cells.items() if why is None} == {
        (SINGLE, "single"),
        (DUAL, "single"),
        (DUAL, "centralized"),
    }
    why = plan.cells[(SINGLE, "centralized")]
    assert isinstance(why, str) and "not an estimator of this scenario" in why
    assert plan.skipped == [f"{SINGLE} x centralized: {why}"]
    assert [[e.name for e in s.estimators] for s in plan.scenarios] == [["single"], ["single", "centralized"]]


# Staged wall times of the timing runs (by the estimators a run has, plus a per-seed
# offset): the fastest repeat is seed 2's everywhere.
STAGED_WALL_S = {(): 1.0, ("single",): 3.0, ("centralized",): 2.0}
SEED_OFFSET_S = {1: 0.3, 2: 0.1, 3: 0.2}
TIMING_REPEATS = 3


@pytest.fixture(scope="module")
def serial_comparison(tmp_path_factory):
    """``compare cubesat_dual_star_tracker --estimators single,centralized --runs 2
    --scheduler serial`` (60 s runs) with staged timing-run wall times; connecting to Dask
    fails the fixture (a serial comparison must not)."""
    module = comparison_module()
    real_timing = module.timing_record

    def staged_timing(run):
        rec = real_timing(run)
        rec["wall_time_s"] = STAGED_WALL_S[tuple(sorted(rec["steps"]))] + SEED_OFFSET_S[run.seed]
        return rec

    def no_dask(*args):
        raise AssertionError(f"a serial comparison connected to Dask: _connect{args}")

    out = tmp_path_factory.mktemp("compare") / "cmp"
    plan = mc.comparison_plan([DUAL], estimators=["single", "centralized"], overrides=SHORT)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(module, "timing_record", staged_timing)
        mp.setattr(module, "_connect", no_dask)
        result = mc.run_comparison(
            plan, 2, 1, scheduler="serial", out=str(out), progress=False, timing_repeats=TIMING_REPEATS
        )
    return result, out


def test_compare_times_each_estimator_by_its_fastest_repeat_minus_the_sensors_only_run(serial_comparison):
    """Per estimator: the fastest of its 3 repeats (seed 2: own wall + 0.1 s), minus the
    fastest sensors-only run (1.1 s), per step; the same numbers in comparison.json."""
    result, out = serial_comparison
    base = STAGED_WALL_S[()] + min(SEED_OFFSET_S.values())
    assert set(result.timing) == {(DUAL, "single"), (DUAL, "centralized")}
    cells = {c["estimator"]: c for c in json.loads((out / "comparison.json").read_text())["cells"]}
    for name in ("single", "centralized"):
        t = result.timing[(DUAL, name)]
        wall = STAGED_WALL_S[(name,)] + min(SEED_OFFSET_S.values())
        assert t["selection"] == [name] and t["repeats"] == TIMING_REPEATS
        assert t["steps"] > 0
        assert math.isclose(t["wall_s"], wall) and math.isclose(t["baseline_wall_s"], base)
        assert math.isclose(t["ms_per_step"], 1e3 * (wall - base) / t["steps"])
        assert math.isclose(cells[name]["ms_per_step"], t["ms_per_step"])
        assert math.isclose(cells[name]["timing"]["wall_s"], wall)


def test_a_serial_comparison_runs_serial_campaigns(serial_comparison):
    """``--scheduler serial``: the scenario's campaign ran in this process and its
    campaign.json says so."""
    result, out = serial_comparison
    info = json.loads((out / DUAL / "campaign.json").read_text())
    assert info["executor"] == "serial (this process)"
    assert info["runs"] == 2
    assert result.campaigns[DUAL].ran == 2


@pytest.mark.parametrize("workers", [None, (os.cpu_count() or 1) + 1], ids=["cpu-count", "more-than-cpus"])
def test_a_parallel_comparison_connects_one_cluster_of_workers_processes_before_writing(tmp_path, monkeypatch, workers):
    """A local-cluster comparison asks for one cluster of ``--workers`` processes (default:
    the CPU count), before its folder exists; a failed connection leaves no folder."""

    class Refused(Exception):
        pass

    out = tmp_path / "cmp"
    calls = []

    def refuse(n_workers, scheduler, connect_timeout_s):
        calls.append((n_workers, scheduler, out.exists()))
        raise Refused

    monkeypatch.setattr(comparison_module(), "_connect", refuse)
    plan = mc.comparison_plan([SINGLE], overrides=SHORT)
    with pytest.raises(Refused):
        mc.run_comparison(plan, 1, workers=workers, out=str(out), progress=False)
    assert calls == [(workers or os.cpu_count(), None, False)]
    assert not out.exists()
