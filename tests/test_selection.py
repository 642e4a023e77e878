"""A fusion's sources and estimator selections (:mod:`drake_att.scenarios.selection`): the
breadth-first closure over nested fusions written out by hand, the selection's order and
errors, and that a selection is a copy (editing it never reaches the scenario it came from)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from drake_att.scenarios.config import ConfigError
from drake_att.scenarios.library import load
from drake_att.scenarios.selection import fused_sources, with_estimators, with_fused_sources

# f2 fuses f1 and c; f1 fuses a and b; a, b, c fuse nothing.
CONFIGS = {
    "f2": SimpleNamespace(sources=["f1", "c"]),
    "f1": SimpleNamespace(sources=["a", "b"]),
    "a": SimpleNamespace(),
    "b": SimpleNamespace(),
    "c": SimpleNamespace(),
}


@pytest.mark.timeout(10)
@pytest.mark.parametrize(
    "names, expected",
    [
        (["f2"], ["f2", "f1", "c", "a", "b"]),  # level by level: f2; its sources f1, c; f1's a, b
        (["f1"], ["f1", "a", "b"]),
        (["a", "f1"], ["a", "f1", "b"]),  # a already listed: once
        (["c", "c", "a"], ["c", "a"]),  # duplicates once, order kept
        ([], []),
    ],
)
def test_a_selection_gains_every_source_of_its_fusions_breadth_first_once(names, expected):
    assert with_fused_sources(CONFIGS, names) == expected
    assert fused_sources(CONFIGS["f1"]) == ["a", "b"] and fused_sources(CONFIGS["a"]) == []


def test_a_selection_is_a_copy_in_the_scenarios_order():
    s = load("cubesat_dual_star_tracker")
    names = [e.name for e in s.estimators]
    plain = [e.name for e in s.estimators if not fused_sources(e)]
    assert len(plain) >= 2
    picked = with_estimators(s, [plain[-1], plain[0]])
    assert [e.name for e in picked.estimators] == [plain[0], plain[-1]]
    picked.estimators[0].period_s = 123.0
    picked.sensors[0].name = "renamed"
    picked.duration_s = 1.0
    assert [e.name for e in s.estimators] == names
    assert s.estimators[0].period_s != 123.0 and s.sensors[0].name != "renamed" and s.duration_s != 1.0


def test_a_bad_selection_is_refused_naming_the_field_and_the_choices():
    s = load("cubesat_dual_star_tracker")
    names = [e.name for e in s.estimators]
    with pytest.raises(
        ConfigError,
        match=r"^estimators: got 'single'; choose a list of names from .*\(empty: sensors "
        r"only\)$",
    ):
        with_estimators(s, "single")  # a string, not a list of names
    with pytest.raises(ConfigError, match=r"^--estimators: got \['ghost'\]; choose a list of names from"):
        with_estimators(s, ["ghost"], field="--estimators")
    with pytest.raises(ConfigError) as e:
        with_estimators(s, [], allow_empty=False)
    assert str(e.value) == f"estimators: got []; choose a list of names from {names}"
    assert with_estimators(s, []).estimators == []
    fusions = [e for e in s.estimators if fused_sources(e)]
    assert fusions, "the dual-tracker scenario has a fusion"
    with pytest.raises(ConfigError, match=rf"^estimators: '{fusions[0].name}' fuses .*, which are not selected$"):
        with_estimators(s, [fusions[0].name])


def test_measurement_sensor_names_in_update_order():
    from types import SimpleNamespace as C

    from drake_att.scenarios.selection import measurement_sensor_names

    assert measurement_sensor_names(C(star_trackers=["st1", "st2"])) == ["st1", "st2"]
    assert measurement_sensor_names(C(star_tracker="st", vector_sensors=["sun", "mag"])) == ["st", "sun", "mag"]
    assert measurement_sensor_names(C(star_tracker="", vector_sensors=["sun"])) == ["sun"]
    assert measurement_sensor_names(C(camera="cam")) == []
