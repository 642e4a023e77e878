"""What the CLI prints and the report figures draw fit where they are read: the run, campaign
and comparison tables fit 100 columns without trailing spaces (names as long as the longest
shipped estimator's), a noise-free estimator's NEES carries a footnote that says why it means
nothing (decided from the config), the campaign report states the duration that ran next to the
scenario's description, and the figures' y-limits, legends, line styles and texts show every
curve inside the figure."""

from __future__ import annotations

import copy

import pytest

from drake_att.analysis import metrics
from drake_att.cli import main as cli_main
from drake_att.scenarios import library
from drake_att.scenarios.config import apply_overrides

WIDTH = 100


def _shipped():
    return {name: library.load(name) for name in library.available_scenarios()}


@pytest.fixture(scope="module")
def shipped():
    return _shipped()


@pytest.fixture(scope="module")
def longest_name(shipped):
    """The longest estimator name of the shipped scenarios."""
    return max((e.name for s in shipped.values() for e in s.estimators), key=len)


def _assert_fits(text: str) -> None:
    for line in text.splitlines():
        assert len(line) <= WIDTH, (len(line), line)
        assert line == line.rstrip(), repr(line)


# ----------------------------------------------------------------------------------------
# The run table
# ----------------------------------------------------------------------------------------
def _record(second: str, nees):
    """One estimator's metrics with the widest numbers ``.3g`` prints (8 characters)."""
    return {
        "attitude_rmse_deg": [1.23e-05, 0.000123, 1.23e05],
        "attitude_mae_deg": [9.87e-05, 0.000987, 9.87e05],
        "attitude_rmse_total_deg": 1.23e-05,
        "bias_rmse_deg_per_h": [1.23e-05, 0.000123, 1.23e05] if second == "b" else None,
        "rate_rmse_deg_per_s": [4.56e-05, 0.000456, 4.56e05] if second == "w" else None,
        "convergence_time_s": 123456.7,
        "nees_mean": nees,
        "nees_dof": 6 if second else 3,
        "scored_from_s": 500.0,
        "samples_scored": 10,
        "measurements_used": 1234567,
        "measurements_skipped": 89012,
    }


def test_run_table_fits_100_columns_with_the_longest_shipped_name(longest_name):
    assert len(longest_name) >= 20  # the shipped names are not all short (the test is not vacuous)
    est = {longest_name: _record("b", 1.21e08), "mekf": _record("w", 6.05), "plain": _record("", None)}
    text = metrics.format_table(
        {
            "scenario": "cubesat_dual_star_tracker",
            "seed": 123,
            "duration_s": 5000.0,
            "wall_time_s": 22.9,
            "estimators": est,
        }
    )
    _assert_fits(text)
    for needed in ("1.23e-05", "0.000123", "1.23e+05", "9.87e-05", "4.56e-05", "123456.7", "1.21e+08", "1234567/89012"):
        assert needed in text  # every number is still printed
    assert "NEES dof: 3 (plain), 6 (" + longest_name + ", mekf)" in text.replace("\n ", " ")


def test_drake_att_run_prints_a_table_within_100_columns_and_explains_a_noise_free_nees(tmp_path, capsys):
    """``s2_indoor_static``: its camera has no centroid noise and no quantization, so the
    estimator's covariance is only its floor and the NEES (~1e8) is flagged with a footnote."""
    code = cli_main(["run", "s2_indoor_static", "--quiet", "--no-figures", "--out", str(tmp_path / "r")])
    out = capsys.readouterr().out
    assert code == 0
    table = out.split("\nWrote ")[0]
    _assert_fits(table)
    rows = [line for line in table.splitlines() if line.startswith("indoor_star_tracker ")]
    assert len(rows) == 2 and rows[1].split()[-2].endswith("*")  # the NEES, marked
    assert float(rows[1].split()[-2].rstrip("*")) > 1e6
    note = " ".join(line.strip() for line in table.splitlines() if line.startswith(("* ", " ")))
    assert "* noise-free measurements (indoor_star_tracker: camera)" in note
    assert "does not measure consistency" in note


def _metrics_of(scenario, nees=1.0e8):
    return {
        "scenario": scenario.name,
        "seed": 1,
        "duration_s": scenario.duration_s,
        "wall_time_s": 0.0,
        "estimators": {e.name: _record("w", nees) for e in scenario.estimators},
    }


def test_the_noise_free_footnote_follows_the_config_not_the_scenario_name(shipped):
    static = copy.deepcopy(shipped["s2_indoor_static"])
    assert metrics.noise_free_estimators(static) == {"indoor_star_tracker": ["camera"]}
    static.name = "my_bench"  # another name, the same config: still flagged
    assert "* noise-free measurements" in metrics.format_table(_metrics_of(static), static)
    for noisy in ("sensors.camera.centroid_noise_px=0.1", "sensors.camera.quantization_px=1"):
        s = apply_overrides(shipped["s2_indoor_static"], [noisy])
        assert metrics.noise_free_estimators(s) == {}
        text = metrics.format_table(_metrics_of(s), s)
        assert "noise-free" not in text and "*" not in text
    # the dynamic test's camera is noisy; made noise-free, both of its estimators are flagged
    dynamic = apply_overrides(shipped["s2_indoor_dynamic"], ["sensors.camera.centroid_noise_px=0"])
    assert shipped["s2_indoor_dynamic"].sensors[1].centroid_noise_px > 0
    assert metrics.noise_free_estimators(shipped["s2_indoor_dynamic"]) == {}
    assert set(metrics.noise_free_estimators(dynamic)) == {e.name for e in dynamic.estimators}
    # without the config, no footnote
    assert "noise-free" not in metrics.format_table(_metrics_of(static))


def test_no_shipped_scenario_but_s2_static_has_a_noise_free_estimator(shipped):
    """Star trackers (quaternion or vector mode) always have noise: a fusion of trackers
    (``centralized``, ``decentralized``) is never flagged."""
    flagged = {name: metrics.noise_free_estimators(s) for name, s in shipped.items()}
    assert {n: f for n, f in flagged.items() if f} == {"s2_indoor_static": {"indoor_star_tracker": ["camera"]}}
