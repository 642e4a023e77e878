"""Physical ranges of every numeric config field, the memory preflight and duplicate names
in estimators' sensor lists (DESIGN "The edges": every numeric field has a documented
physical range; a run that cannot fit is refused before it allocates).

* Coverage: every numeric field (decided here from the type annotations) of the scenario, its
  sections, the plants and every registered sensor and estimator config (and the dataclasses
  nested in them) resolves to a range - a new field without one fails naming it.
* Boundaries, for every such field: both ends of its range pass ``check_ranges``, just
  outside either end is refused with a message naming the field path (built here the way
  ``config.validate`` names fields: ``sensors[0] (gyro).arw_deg_per_rt_h``).
* ``docs/config_reference.md`` is the rendered table.
* Memory: 1e9 particles refused in milliseconds naming ``num_particles``; the estimate of a
  particle filter's and of a log-heavy run's peak within a factor 2 of the peak RSS measured
  in a fresh process; the shipped scenarios fit.
"""

from __future__ import annotations

import ast
import copy
import dataclasses
import json
import math
import re
import subprocess
import sys
import textwrap
import time
import typing
from pathlib import Path

import numpy as np
import pytest

from drake_att.estimators.bootstrap_pf_plugin import BootstrapPfConfig
from drake_att.estimators.ekpf_plugin import EkpfConfig
from drake_att.estimators.mekf_plugin import MekfConfig
from drake_att.scenarios import config as cfg
from drake_att.scenarios import preflight, registry
from drake_att.scenarios.library import available_scenarios, load
from drake_att.scenarios.ranges import Range, Split, check_ranges, range_for, render_markdown
from drake_att.sensors.faults_plugin import SensorFaultsConfig
from drake_att.sensors.gyro_plugin import GyroConfig
from drake_att.sensors.star_tracker_plugin import StarTrackerConfig
from drake_att.validation import ConfigError

REPO = Path(__file__).resolve().parents[1]


# ======================================================================================
# Which fields are numeric, where each config sits in a scenario
# ======================================================================================
def _numeric(t) -> bool:
    """float, int, Optional of them, lists of them, numpy arrays (not bool, not str)."""
    if t is np.ndarray or t is float or t is int:
        return True
    origin, args = typing.get_origin(t), typing.get_args(t)
    if origin is typing.Union:
        return any(_numeric(a) for a in args if a is not type(None))
    if origin is list:
        return bool(args) and _numeric(args[0])
    if origin is dict:  # a mapping of names to numbers (logging.periods_s)
        return len(args) == 2 and _numeric(args[1])
    return False


def _dataclass_args(t) -> list:
    if isinstance(t, type) and dataclasses.is_dataclass(t):
        return [t]
    return [x for a in typing.get_args(t) for x in _dataclass_args(a)]


def _registered_types() -> list:
    registry.ensure_builtin_plugins()
    return [p.config_type for kind in (registry.SENSOR, registry.ESTIMATOR) for p in registry.plugins(kind).values()]


def _slots():
    """``[(config type, build)]``: ``build() -> (scenario, the config instance in it, path
    prefix of its fields)`` for the scenario, its sections, the three plants, every
    registered sensor and estimator config (alone in its list) and every dataclass nested
    in them (each alternative of a Union)."""

    def nested(t, build):
        yield t, build
        hints = typing.get_type_hints(t)
        for f in dataclasses.fields(t):
            if t is cfg.Scenario and f.name in ("sensors", "estimators"):
                continue
            for sub in _dataclass_args(hints[f.name]):

                def child(build=build, name=f.name, sub=sub):
                    s, obj, prefix = build()
                    setattr(obj, name, sub())
                    return s, getattr(obj, name), f"{prefix}{name}."

                yield from nested(sub, child)

    def scenario():
        s = cfg.Scenario()
        return s, s, ""

    out = list(nested(cfg.Scenario, scenario))
    for t in _registered_types():
        section = (
            "sensors" if t in [p.config_type for p in registry.plugins(registry.SENSOR).values()] else "estimators"
        )

        def build(t=t, section=section):
            s, c = cfg.Scenario(), t()
            setattr(s, section, [c])
            return s, c, f"{section}[0] ({c.name})."

        out += list(nested(t, build))
    seen, unique = set(), []
    for t, b in out:
        if t not in seen:
            seen.add(t)
            unique.append((t, b))
    return unique


def _numeric_fields():
    """``[(config type, build, field name, annotation)]`` of every numeric field."""
    return [
        (t, b, f.name, typing.get_type_hints(t)[f.name])
        for t, b in _slots()
        for f in dataclasses.fields(t)
        if _numeric(typing.get_type_hints(t)[f.name])
    ]


NUMERIC_FIELDS = _numeric_fields()


def test_every_numeric_field_of_every_config_resolves_to_a_range():
    assert len(NUMERIC_FIELDS) > 150  # the enumeration reaches every config
    types = {t for t, *_ in NUMERIC_FIELDS}
    for t in _registered_types() + [
        cfg.Scenario,
        cfg.SimulationConfig,
        cfg.OrbitConfig,
        cfg.RigidBodyConfig,
        cfg.PrescribedRateConfig,
        cfg.PrescribedRpyConfig,
        cfg.ScoringConfig,
    ]:
        assert t in types, t
    assert {"RpyMounting", "PaperS3Eq7Mounting"} <= {t.__name__ for t in types}
    missing = [f"{t.__name__}.{name}" for t, _, name, _ in NUMERIC_FIELDS if range_for(t, name) is None]
    assert not missing, f"numeric fields without a physical range (add one to drake_att/scenarios/ranges.py): {missing}"


def test_the_library_defaults_are_inside_their_ranges():
    for _t, build in _slots():
        s, obj, prefix = build()
        check_ranges(s)


# ======================================================================================
# Boundaries of every field, generated from the table
# ======================================================================================
def _cases():
    out = []
    for t, build, name, ann in NUMERIC_FIELDS:
        entry = range_for(t, name)
        if isinstance(entry, Split):
            for label, r in entry.parts.items():
                out.append(pytest.param(t, build, name, ann, r, label, id=f"{t.__name__}.{name}.{label}"))
        else:
            out.append(pytest.param(t, build, name, ann, entry, None, id=f"{t.__name__}.{name}"))
    return out


def _is_int_field(ann) -> bool:
    return (
        ann is int
        or typing.get_args(ann) == (int,)
        or (typing.get_origin(ann) is typing.Union and int in typing.get_args(ann))
    )


def _place(obj, name, ann, value, entry, label):
    """Put ``value`` into field ``name`` of ``obj``; returns the path suffix of where it sits."""
    if isinstance(entry, Split):  # e.g. inertia: find a list size and an entry of that part
        for size in (3, 9, 6, 4, 2, 1):
            for i in range(size):
                if entry.select(i, size) == label:
                    fill = [
                        min(max(1.0, entry.parts[entry.select(k, size)].lo), entry.parts[entry.select(k, size)].hi)
                        for k in range(size)
                    ]
                    fill[i] = value
                    setattr(obj, name, fill)
                    return f"[{i}]"
        raise AssertionError(f"no entry of part {label}")
    if ann is np.ndarray:
        default = getattr(type(obj)(), name)
        cols = default.shape[1] if np.ndim(default) == 2 else 3
        setattr(obj, name, np.full((1, cols), float(value)))
        return "[0][0]"
    if typing.get_origin(ann) is list:
        setattr(obj, name, [value])
        return "[0]"
    setattr(obj, name, value)
    return ""


@pytest.mark.parametrize("t, build, name, ann, r, label", _cases())
def test_each_range_boundary_passes_and_just_outside_is_refused_naming_the_field(t, build, name, ann, r, label):
    entry = range_for(t, name)
    integer = _is_int_field(ann)
    inside = [int(r.lo), int(r.hi)] if integer else [r.lo, r.hi]
    if integer:
        outside = [int(r.lo) - 1, int(r.hi) + 1]
    else:
        outside = [r.lo - max(abs(r.lo), 1.0) * 1e-9, r.hi + max(abs(r.hi), 1.0) * 1e-9]
    for value in inside:
        s, obj, prefix = build()
        _place(obj, name, ann, value, entry, label)
        check_ranges(s)
    for value in outside:
        s, obj, prefix = build()
        where = _place(obj, name, ann, value, entry, label)
        with pytest.raises(ConfigError) as e:
            check_ranges(s)
        message = str(e.value)
        assert message.startswith(f"{prefix}{name}{where}: got "), message
        assert "; must be in [" in message and message.endswith(")"), message


# ======================================================================================
# Spot checks written out by hand: the message shape, nested values, NaN, plug-in fields
# ======================================================================================
def _scenario_with_sensors(*sensors, estimators=()):
    return cfg.Scenario(orbit=cfg.OrbitConfig(), sensors=list(sensors), estimators=list(estimators))


def test_the_issue_examples_are_refused_with_the_one_message_shape():
    gyro = GyroConfig(name="gyro", arw_deg_per_rt_h=1.0e300)
    with pytest.raises(ConfigError) as e:
        check_ranges(_scenario_with_sensors(gyro))
    assert str(e.value) == (
        "sensors[0] (gyro).arw_deg_per_rt_h: got 1e+300; must be in [0, 100] deg/sqrt(h) (an angle "
        "random walk: 1e-4 (navigation grade) to ~10 (the noisiest MEMS))"
    )
    gyro = GyroConfig(name="g", rrw_deg_per_h15=1.0e300)
    with pytest.raises(
        ConfigError,
        match=r"^sensors\[0\] \(g\)\.rrw_deg_per_h15: got 1e\+300; must be in \[0, 1000\] "
        r"deg/h\^1\.5 \(",
    ):
        check_ranges(_scenario_with_sensors(gyro))
    faults = SensorFaultsConfig(name="f", outlier_rate_deg_per_s=1.0e300)
    with pytest.raises(
        ConfigError,
        match=r"^sensors\[1\] \(f\)\.outlier_rate_deg_per_s: got 1e\+300; must be in "
        r"\[-5000, 5000\] deg/s \(",
    ):
        check_ranges(_scenario_with_sensors(GyroConfig(), faults))
    s = _scenario_with_sensors()
    s.orbit.altitude_km = 1.0e300
    with pytest.raises(ConfigError, match=r"^orbit\.altitude_km: got 1e\+300; must be in \[100, 1e6\] km \("):
        check_ranges(s)
    s.orbit.altitude_km = 35786.0  # GEO
    check_ranges(s)
    s.orbit.altitude_km = 384400.0  # the Moon's distance
    check_ranges(s)
    s.plant.inertia_kg_m2 = [0.042, 0.042, 1e300]
    with pytest.raises(ConfigError, match=r"^plant\.inertia_kg_m2\[2\]: got 1e\+300; must be in \[1e-7, 1e9\] kg m\^2"):
        check_ranges(s)
    s.plant.inertia_kg_m2 = [10.0, -2.0, 0.0, -2.0, 12.0, 0.0, 0.0, 0.0, 15.0]  # negative products: physical
    check_ranges(s)
    s.estimators = [MekfConfig(name="m"), EkpfConfig(name="joint", initial_attitude_sigma_deg=1e6)]
    with pytest.raises(
        ConfigError,
        match=r"^estimators\[1\] \(joint\)\.initial_attitude_sigma_deg: got 1000000\.0; "
        r"must be in \[0, 360\] deg \(",
    ):
        check_ranges(s)


def test_real_sensors_and_missions_pass():
    """A few real extremes: a fast spinner, a consumer MEMS gyro, a coarse tracker, a GEO
    mission of 30 days, a navigation-grade gyro, a 100 kHz sample period."""
    gyro = GyroConfig(
        name="mems",
        period_s=1e-5,
        sample_rate_hz=1e5,
        arw_deg_per_rt_h=0.6,
        rrw_deg_per_h15=5.0,
        initial_bias_deg_per_h=[3600.0, -7200.0, 10.0],
        scale_factor_error_ppm=[5000.0, 0, 0],
    )
    nav = GyroConfig(name="nav", arw_deg_per_rt_h=0.001, rrw_deg_per_h15=1e-4, initial_bias_deg_per_h=[0.01] * 3)
    st = StarTrackerConfig(name="st", sigma_cross_boresight_arcsec=100.0, sigma_boresight_arcsec=600.0)
    s = _scenario_with_sensors(gyro, nav, st, estimators=[BootstrapPfConfig(num_particles=10**6)])
    s.duration_s = 30 * 86400.0
    s.orbit.altitude_km = 35786.0
    s.plant.initial_rate_deg_per_s = [600.0, 0.0, 0.0]  # 100 rpm
    s.plant.inertia_kg_m2 = [1.2e8, 1.0e8, 2.0e8]  # ISS-like
    check_ranges(s)


def test_nested_arrays_name_row_and_column_and_nan_is_refused():
    s = cfg.Scenario(plant=cfg.PrescribedRpyConfig(times_s=[0.0, 10.0], rpy_deg=np.array([[0, 0, 0], [0, 0, 2e6]])))
    with pytest.raises(ConfigError, match=r"^plant\.rpy_deg\[1\]\[2\]: got 2000000\.0; must be in \[-1e6, 1e6\] deg"):
        check_ranges(s)
    from drake_att.sensors.star_tracker_plugin import PaperS3Eq7Mounting

    st = StarTrackerConfig(name="st", mounting=PaperS3Eq7Mounting(psi_phi_theta_deg=[0, 400, 0]))
    with pytest.raises(
        ConfigError,
        match=r"^sensors\[0\] \(st\)\.mounting\.psi_phi_theta_deg\[1\]: got 400; must be "
        r"in \[-360, 360\] deg",
    ):
        check_ranges(_scenario_with_sensors(st))
    s = _scenario_with_sensors()
    s.duration_s = float("nan")
    with pytest.raises(ConfigError, match=r"^duration_s: got nan; must be in \[0, 2592000\] s"):
        check_ranges(s)


def test_a_plug_in_field_without_a_range_is_refused_and_one_it_declares_is_used():
    @dataclasses.dataclass
    class _Untyped:
        name: str = "u"
        smoothing: float = 0.5

    @dataclasses.dataclass
    class _Declared:
        RANGES: typing.ClassVar[dict] = {"smoothing": (0.0, 1.0, "", "a fraction")}
        name: str = "d"
        smoothing: float = 0.5
        horizon_s: float = 10.0

    with pytest.raises(
        ConfigError,
        match=r"^estimators\[0\] \(u\)\.smoothing: got 0\.5; no physical range is "
        r"documented for _Untyped\.smoothing",
    ):
        check_ranges(cfg.Scenario(estimators=[_Untyped()]))
    check_ranges(cfg.Scenario(estimators=[_Declared()]))
    with pytest.raises(
        ConfigError,
        match=r"^estimators\[0\] \(d\)\.smoothing: got 1\.5; must be in \[0, 1\] \(a "
        r"fraction\)$",
    ):
        check_ranges(cfg.Scenario(estimators=[_Declared(smoothing=1.5)]))
    with pytest.raises(
        ConfigError,
        match=r"^estimators\[0\] \(d\)\.horizon_s: got 1e\+20; must be in "
        r"\[0, 2592000\] s",
    ):
        check_ranges(cfg.Scenario(estimators=[_Declared(horizon_s=1e20)]))  # the unit suffix's default


@dataclasses.dataclass
class _Nameless:  # a list item without a ``name``: its path says "(?)"
    horizon_s: float = 10.0


def test_a_nameless_list_item_is_named_by_its_index_and_a_question_mark():
    check_ranges(cfg.Scenario(estimators=[_Nameless()]))
    with pytest.raises(ConfigError) as e:
        check_ranges(cfg.Scenario(estimators=[MekfConfig(name="m"), _Nameless(horizon_s=-1.0)]))
    assert str(e.value) == (
        "estimators[1] (?).horizon_s: got -1.0; must be in [0, 2592000] s (a time within the longest run (30 days))"
    )


def test_an_array_names_the_entry_outside_even_after_an_entry_exactly_at_a_bound():
    """The array check finds the first entry outside [lo, hi]: entries exactly at lo or hi
    are inside (closed interval), so the one named is the later entry really outside."""
    for at_bound in (-1e6, 1e6):
        rpy = np.array([[at_bound, 0.0, 0.0], [at_bound, at_bound, 3e6]])
        s = cfg.Scenario(plant=cfg.PrescribedRpyConfig(times_s=[0.0, 10.0], rpy_deg=rpy))
        with pytest.raises(ConfigError) as e:
            check_ranges(s)
        assert str(e.value).startswith("plant.rpy_deg[1][2]: got 3000000.0; must be in [-1e6, 1e6] deg ("), e.value
        rpy[1, 2] = -at_bound
        check_ranges(s)  # every entry at a bound: all inside


def test_a_nine_entry_inertia_checks_the_whole_diagonal_as_principal_moments():
    """9 entries (row-major): indices 0, 4 and 8 are principal moments (>= 1e-7), the rest
    products (either sign, 0 allowed); as a list and as a 3x3 array (named [row][col])."""
    products_ok = [10.0, -2.0, 0.0, -2.0, 12.0, 1e-8, 0.0, 1e-8, 15.0]
    s = _scenario_with_sensors()
    s.plant.inertia_kg_m2 = products_ok
    check_ranges(s)
    s.plant.inertia_kg_m2 = np.array(products_ok).reshape(3, 3)
    check_ranges(s)
    for i in (0, 4, 8):
        inertia = list(products_ok)
        inertia[i] = 1e-8  # fine for a product, below the smallest moment
        s.plant.inertia_kg_m2 = inertia
        with pytest.raises(ConfigError) as e:
            check_ranges(s)
        assert str(e.value).startswith(
            f"plant.inertia_kg_m2[{i}]: got 1e-08; must be in [1e-7, 1e9] kg m^2 (a moment of inertia"
        ), e.value
        s.plant.inertia_kg_m2 = np.array(inertia).reshape(3, 3)
        with pytest.raises(ConfigError) as e:
            check_ranges(s)
        assert str(e.value).startswith(
            f"plant.inertia_kg_m2[{i // 3}][{i % 3}]: got 1e-08; must be in [1e-7, 1e9] kg m^2 (a moment of inertia"
        ), e.value
    s.plant.inertia_kg_m2 = np.array([1.0, 1.0, 1e-8])  # 3 entries: all principal
    with pytest.raises(
        ConfigError,
        match=r"^plant\.inertia_kg_m2\[2\]: got 1e-08; must be in \[1e-7, 1e9\] kg m\^2 "
        r"\(a moment of inertia",
    ):
        check_ranges(s)
    s.plant.inertia_kg_m2 = np.array([[10.0, -2.0, 0.0], [-2.0, 12.0, 0.0], [0.0, 2e9, 15.0]])
    with pytest.raises(
        ConfigError,
        match=r"^plant\.inertia_kg_m2\[2\]\[1\]: got 2000000000\.0; must be in "
        r"\[-1e9, 1e9\] kg m\^2 \(a product of inertia",
    ):
        check_ranges(s)


def test_bounds_are_written_exactly_and_short():
    """``1e9`` not ``1e+09`` (the docs and messages show the bounds this way)."""
    from drake_att.scenarios.ranges import _num

    cases = {
        1e9: "1e9",
        1e5: "1e5",
        10000.0: "10000",
        2592000.0: "2592000",
        4294967295: "4294967295",
        0: "0",
        -1e6: "-1e6",
        1e-6: "1e-6",
        1e-16: "1e-16",
        2.5e-5: "2.5e-5",
        0.1: "0.1",
        3.6e4: "36000",
        1.5e20: "1.5e20",
        1e16: "1e16",
        -1e300: "-1e300",
        0.15811388300841897: "0.15811388300841897",
    }
    for x, text in cases.items():
        assert _num(x) == text, (x, _num(x), text)
        assert float(text) == x  # exact

    @dataclasses.dataclass
    class _Huge:
        RANGES: typing.ClassVar[dict] = {"distance_m": (0.0, 1e20, "m", "beyond the galaxy")}
        name: str = "h"
        distance_m: float = 1.0

    with pytest.raises(ConfigError) as e:
        check_ranges(cfg.Scenario(estimators=[_Huge(distance_m=1e21)]))
    assert str(e.value) == "estimators[0] (h).distance_m: got 1e+21; must be in [0, 1e20] m (beyond the galaxy)"


def test_plug_in_arrays_and_counts_are_checked_like_lists():
    """A numeric array is checked entry by entry (a 1-entry int array too), one without a
    range is refused with the hint how to declare one unless it is empty; arrays of strings
    or bools are not numbers; a ``num_`` field is a count."""

    @dataclasses.dataclass
    class _Arrays:
        name: str = "a"
        gains: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))  # no range: fine while empty
        labels: np.ndarray = dataclasses.field(default_factory=lambda: np.array(["x", "y"]))
        flags: np.ndarray = dataclasses.field(default_factory=lambda: np.array([True, False]))
        horizon_s: np.ndarray = dataclasses.field(default_factory=lambda: np.array([5]))
        num_stars: int = 10

    def refusal(**changes):
        with pytest.raises(ConfigError) as e:
            check_ranges(cfg.Scenario(estimators=[_Arrays(**changes)]))
        return str(e.value)

    check_ranges(cfg.Scenario(estimators=[_Arrays()]))
    check_ranges(cfg.Scenario(estimators=[_Arrays(horizon_s=np.array([0, 2592000]), num_stars=10**6)]))
    assert refusal(gains=np.array([1.0, 2.0])) == (
        "estimators[0] (a).gains: got [1. 2.]; no physical range is documented for _Arrays.gains: name the field with "
        "a unit suffix (e.g. _s, _deg, _hz; see drake_att.scenarios.ranges) or declare RANGES = {'gains': (lo, hi, "
        "unit, why)} on the config class"
    )
    assert refusal(horizon_s=np.array([-1])) == (
        "estimators[0] (a).horizon_s[0]: got -1; must be in [0, 2592000] s (a time within the longest run (30 days))"
    )
    assert refusal(horizon_s=np.array([3, 2592001], dtype=np.int32)).startswith(
        "estimators[0] (a).horizon_s[1]: got 2592001; must be in [0, 2592000] s"
    )
    assert refusal(num_stars=0) == "estimators[0] (a).num_stars: got 0; must be in [1, 1e6] (a count)"


def test_a_plug_in_split_range_sees_each_entry_index_and_its_list_size():
    """A :class:`Split` declared in RANGES: ``select(index, size)`` per number - a scalar is
    entry 0 of 1, a list's entries (each nested list on its own), an array's entries in
    row-major order out of its size."""
    calls = []

    def select(index, size):
        calls.append((index, size))
        return "first" if index == 0 else "rest"

    @dataclasses.dataclass
    class _Parts:
        RANGES: typing.ClassVar[dict] = {
            "mix": Split({"first": Range(0.0, 1.0, "", "the first"), "rest": Range(-1.0, 0.0, "", "the rest")}, select)
        }
        name: str = "p"
        mix: typing.Any = 0.5

    for value, seen in [
        (0.5, [(0, 1)]),
        ([0.5, -0.5, 0.0], [(0, 3), (1, 3), (2, 3)]),
        ([[0.5, -0.5], [1.0]], [(0, 2), (1, 2), (0, 1)]),
        (np.array([[0.5, -0.5], [-0.1, 0.0]]), [(0, 4), (1, 4), (2, 4), (3, 4)]),
    ]:
        calls.clear()
        check_ranges(cfg.Scenario(estimators=[_Parts(mix=value)]))
        assert calls == seen, (value, calls)
    for value, message in [
        (-0.5, "estimators[0] (p).mix: got -0.5; must be in [0, 1] (the first)"),
        ([0.5, 0.5], "estimators[0] (p).mix[1]: got 0.5; must be in [-1, 0] (the rest)"),
        (np.array([[0.5, 0.0], [0.25, 0.0]]), "estimators[0] (p).mix[1][0]: got 0.25; must be in [-1, 0] (the rest)"),
    ]:
        with pytest.raises(ConfigError) as e:
            check_ranges(cfg.Scenario(estimators=[_Parts(mix=value)]))
        assert str(e.value) == message


def test_the_shipped_scenarios_pass_the_ranges_and_fit_in_8_gb():
    for name in available_scenarios():
        s = load(name)
        check_ranges(s)
        estimate = preflight.check_memory(s, available_bytes=8e9)
        assert 0 < estimate.total_bytes < 1e9, (name, estimate)


# ======================================================================================
# The reference document
# ======================================================================================
def test_config_reference_is_the_rendered_table():
    doc = (REPO / "docs" / "config_reference.md").read_text()
    assert "python -m drake_att.scenarios.ranges > docs/config_reference.md" in doc.splitlines()[1]
    assert doc == render_markdown(), (
        "docs/config_reference.md is stale; regenerate it with "
        "python -m drake_att.scenarios.ranges > docs/config_reference.md"
    )
    assert "**none**" not in doc
    for t, _, name, _ in NUMERIC_FIELDS:
        if t.__module__.startswith("drake_att."):
            assert f".{name}`" in doc or f"`{name}`" in doc or f".{name} (" in doc, name


# What the reference shows for each annotation (a new kind of annotation: add how it reads).
_TYPE_TEXT = {
    float: "float",
    int: "int",
    str: "string",
    bool: "bool",
    typing.Optional[float]: "float or null",
    typing.Optional[str]: "string or null",
    typing.List[float]: "list of float",
    typing.List[int]: "list of int",
    typing.List[str]: "list of string",
    typing.Dict[str, float]: "mapping of string to float",
    np.ndarray: "matrix (list of rows)",
}


_HEADER = [
    "<!-- Generated from drake_att/scenarios/ranges.py; do not edit. Regenerate with:",
    "     python -m drake_att.scenarios.ranges > docs/config_reference.md -->",
    "# Scenario configuration reference",
]
_TABLE_HEAD = ["| Field | Type | Default | Unit | Range | Why |", "|---|---|---|---|---|---|"]


def _markdown_sections(doc: str) -> tuple:
    """``(intro, [(title, paragraph or "", [row cells])])`` of the rendered reference, which
    must be laid out as markdown needs: the header, a blank line, the intro, then each
    section: ``## title``, a blank line, optionally a paragraph and a blank line, the table
    (head, separator, one ``| `path` | ... |`` line per field) and a blank line."""
    head, *blocks = doc.split("\n## ")
    top, intro = head.split("\n\n")
    assert top.split("\n") == _HEADER
    assert intro.endswith("\n") and "\n" not in intro[:-1], intro
    sections = []
    for block in blocks:
        assert block.endswith("|\n"), block[-200:]
        title, *paragraph, table = block[:-1].split("\n\n")
        assert "\n" not in title and len(paragraph) <= 1 and all("\n" not in p for p in paragraph), block[:500]
        lines = table.split("\n")
        assert lines[:2] == _TABLE_HEAD and all(line.startswith("| `") and line.endswith(" |") for line in lines[2:]), (
            table
        )
        rows = [[c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line)[1:-1]] for line in lines[2:]]
        sections.append((title, paragraph[0] if paragraph else "", rows))
    return intro[:-1], sections


def _expected_sections() -> list:
    """``[(title, config type, path prefix)]`` in order: the scenario, its sections, the
    plants, scoring, the library's sensors then estimators (registration order), each
    config type once, at its first appearance, its nested config types right after it."""
    top = [
        ("Scenario (top level)", cfg.Scenario, ""),
        ("simulation", cfg.SimulationConfig, "simulation."),
        ("orbit: !OrbitConfig", cfg.OrbitConfig, "orbit."),
        ("orbit: !TleOrbitConfig", cfg.TleOrbitConfig, "orbit."),
        ("orbit: !KeplerOrbitConfig", cfg.KeplerOrbitConfig, "orbit."),
        ("plant: !RigidBodyConfig", cfg.RigidBodyConfig, "plant."),
        ("plant: !PrescribedRateConfig", cfg.PrescribedRateConfig, "plant."),
        ("plant: !PrescribedRpyConfig", cfg.PrescribedRpyConfig, "plant."),
        ("scoring", cfg.ScoringConfig, "scoring."),
        ("logging", cfg.LoggingConfig, "logging."),
    ]
    registry.ensure_builtin_plugins()
    for kind, label in ((registry.SENSOR, "sensors"), (registry.ESTIMATOR, "estimators")):
        top += [
            (f"{label}: !{tag}", p.config_type, f"{label}[i].")
            for tag, p in registry.plugins(kind).items()
            if p.module.startswith("drake_att.")
        ]
    out, seen = [], set()

    def add(title, t, prefix):
        if t in seen:
            return
        seen.add(t)
        out.append((title, t, prefix))
        if t is not cfg.Scenario:
            hints = typing.get_type_hints(t)
            for f in dataclasses.fields(t):
                for sub in _dataclass_args(hints[f.name]):
                    add(f"{prefix}{f.name}: !{sub.__name__}", sub, f"{prefix}{f.name}.")

    for entry in top:
        add(*entry)
    return out


def _parse_default(text: str):
    if text in ("null", "true", "false"):
        return {"null": None, "true": True, "false": False}[text]
    return ast.literal_eval(text)


def test_the_reference_lists_every_field_with_its_type_default_and_range():
    """The rendered reference against the configs and the table, read back from the markdown:
    its sections in order, every field (inertia twice: principal moments and products), its
    type, its default (read back equal to the dataclass's), the unit, exact bounds and why
    of its range; sections, lists of sections and non-numeric fields marked as such."""
    intro, sections = _markdown_sections(render_markdown())
    assert intro.startswith(
        "Every field of a scenario (`drake_att/scenarios/*.yaml`, `--set PATH=VALUE`) and of the "
        "library's sensor and estimator configs: its type, default, unit and the physically "
        "plausible range `drake_att.scenarios.ranges.check_ranges` enforces"
    ), intro
    assert not re.search(r"\. [a-z]", intro), intro  # sentences start with a capital (or code)
    with pytest.raises(ConfigError) as e:  # its example is the message check_ranges gives
        check_ranges(_scenario_with_sensors(GyroConfig(name="gyro", arw_deg_per_rt_h=1e300)))
    why = range_for(GyroConfig, "arw_deg_per_rt_h").why
    assert str(e.value).endswith(f" ({why})")
    example = f"{str(e.value)[: -len(why) - 3]} (...)"
    assert (
        "(which also check signs, shapes, names and consistency: a value inside the range may still be refused "
        f"by them). A number outside its range is refused naming the field, e.g. `{example}`. `sensors[i]` / "
        "`estimators[i]` stand for the item's index (messages add its name). Lists and matrices: every entry is "
        "in the range. Ranges are closed intervals."
    ) in intro, (example, intro)
    assert intro.endswith("Ranges are closed intervals."), intro

    expected = _expected_sections()
    assert [s[0] for s in sections] == [title for title, _, _ in expected]
    assert len(expected) > 20
    checked = 0
    for (title, text, rows), (_, t, prefix) in zip(sections, expected, strict=True):
        paragraph = " ".join((t.__doc__ or "").strip().split("\n\n")[0].split())
        assert text == ("" if paragraph.startswith(f"{t.__name__}(") else paragraph), title
        hints = typing.get_type_hints(t)
        want = []
        for f in dataclasses.fields(t):
            entry = range_for(t, f.name)
            parts = list(entry.parts.items()) if isinstance(entry, Split) else [(None, entry)]
            want += [(f, label, r) for label, r in parts] if _numeric(hints[f.name]) else [(f, None, None)]
        assert [r[0] for r in rows] == [
            f"`{prefix}{f.name}" + (f" ({label})" if label else "") + "`" for f, label, _ in want
        ], title
        for cells, (f, _label, r) in zip(rows, want, strict=True):
            ann = hints[f.name]
            where = f"{title}: {cells}"
            assert len(cells) == 6, where
            subs = _dataclass_args(ann)
            if f.default is not dataclasses.MISSING:
                default = f.default
            else:
                default = f.default_factory()
            assert cells[2].startswith("`") and cells[2].endswith("`"), where
            default_text = cells[2][1:-1]
            if subs:
                assert cells[1:] == [" or ".join(f"!{s.__name__}" for s in subs), cells[2], "", "(a section)", ""], (
                    where
                )
                assert default_text == ("null" if default is None else f"!{type(default).__name__}"), where
                continue
            if t is cfg.Scenario and f.name in ("sensors", "estimators"):
                assert cells[1:] == [f"list of registered {f.name[:-1]} configs", "`[]`", "", "(sections)", ""]
                continue
            assert cells[1] == _TYPE_TEXT[ann], where
            value = _parse_default(default_text)
            if r is None:
                assert cells[3:] == ["", "(not numeric)", ""], where
                assert value == default, where
                continue
            lo, hi = re.fullmatch(r"\[(\S+), (\S+)\]", cells[4]).groups()
            assert (float(lo), float(hi), cells[3], cells[5]) == (r.lo, r.hi, r.unit, r.why), where
            if default is None:
                assert value is None, where
            elif isinstance(default, dict):
                assert value == default, where
            else:
                assert np.array_equal(np.asarray(value, float).ravel(), np.asarray(default, float).ravel()), where
            checked += 1
    assert checked > 150  # every numeric field


@dataclasses.dataclass
class _Inner:
    """Inner part,
    first paragraph.

    Not shown."""

    tilt_deg: float = 1.0


@dataclasses.dataclass
class _Other:
    """Another section."""

    RANGES: typing.ClassVar[dict] = {"ratio": (0.0, 1.0, "", "numerator | denominator")}
    ratio: float = 0.5


@dataclasses.dataclass
class _Toy:
    name: str = "toy"
    smoothing: float = 0.5  # no range anywhere
    inner: _Inner = dataclasses.field(default_factory=_Inner)
    spare: typing.Optional[_Inner] = None
    window_s: float = dataclasses.field(default=2.0)


@dataclasses.dataclass
class _Defaults:
    required_s: float
    small: float = 1e-7
    month_s: float = 2592000.0
    count: int = 3
    off: bool = False
    on: bool = True
    nothing: typing.Optional[float] = None
    label: str = "x"
    pair: tuple = (1.0, None)
    gains: typing.List[float] = dataclasses.field(default_factory=lambda: [0.5, 1.0, 1e6])
    empty: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    matrix: np.ndarray = dataclasses.field(default_factory=lambda: np.array([[1.0, 2.5], [-3.0, 4.0]]))
    flags: typing.List[bool] = dataclasses.field(default_factory=lambda: [True, False])
    inner: _Inner = dataclasses.field(default_factory=_Inner)
    one: np.ndarray = dataclasses.field(default_factory=lambda: np.array([2.0]))
    count64: int = np.int64(7)  # a numpy scalar reads as its number, not np.int64(7)


def test_the_reference_rows_of_a_plug_in_config():
    """A field without a range shows **none** (the coverage test keeps the library's out of
    the reference); nested configs become sections unless already listed; the scenario's
    own sections are listed on their own."""
    from drake_att.scenarios.ranges import _rows

    rows, nested = _rows(_Toy, "estimators[i].", set())
    assert rows == [
        ("estimators[i].name", "string", "'toy'", "", "(not numeric)", ""),
        ("estimators[i].smoothing", "float", "0.5", "", "**none**", ""),
        ("estimators[i].inner", "!_Inner", "!_Inner", "", "(a section)", ""),
        ("estimators[i].spare", "!_Inner", "null", "", "(a section)", ""),
        ("estimators[i].window_s", "float", "2", "s", "[0, 2592000]", "a time within the longest run (30 days)"),
    ]
    assert nested == [(_Inner, "estimators[i].inner."), (_Inner, "estimators[i].spare.")]
    assert _rows(_Toy, "", {_Inner})[1] == []
    rows, nested = _rows(cfg.Scenario, "", set())
    assert nested == []
    assert [r[4] for r in rows if r[0] in ("simulation", "orbit", "plant", "scoring")] == ["(a section)"] * 4


def test_the_reference_layout_of_nested_sections_written_out(monkeypatch):
    """render_markdown over a toy list of sections: a class without a docstring shows no
    paragraph, a nested config follows its parent once (the second field of the same type
    adds no section), later sections still follow, a "|" in a cell is escaped."""
    from drake_att.scenarios import ranges

    monkeypatch.setattr(ranges, "_sections", lambda: [("toy: !_Toy", _Toy, "toy."), ("other", _Other, "other.")])
    head, body = render_markdown().split("\n## ", 1)
    assert head.split("\n")[:3] == _HEADER
    table = "| Field | Type | Default | Unit | Range | Why |\n|---|---|---|---|---|---|\n"
    assert body == (
        "toy: !_Toy\n\n" + table + "| `toy.name` | string | `'toy'` |  | (not numeric) |  |\n"
        "| `toy.smoothing` | float | `0.5` |  | **none** |  |\n"
        "| `toy.inner` | !_Inner | `!_Inner` |  | (a section) |  |\n"
        "| `toy.spare` | !_Inner | `null` |  | (a section) |  |\n"
        "| `toy.window_s` | float | `2` | s | [0, 2592000] | a time within the longest run (30 days) |\n"
        "\n## toy.inner: !_Inner\n\nInner part, first paragraph.\n\n"
        + table
        + "| `toy.inner.tilt_deg` | float | `1` | deg | [-360, 360] | an angle: one turn either way |\n"
        "\n## other\n\nAnother section.\n\n"
        + table
        + "| `other.ratio` | float | `0.5` |  | [0, 1] | numerator \\| denominator |\n"
    )


def test_the_reference_writes_defaults_and_types_as_yaml_reads_them():
    """Defaults as YAML (null, true/false, short exact numbers, lists, "!Type" for sections,
    "(required)"); which annotations are numeric; how each type reads."""
    from drake_att.scenarios.ranges import _default_text, _is_numeric_type, _type_name

    texts = {f.name: _default_text(f) for f in dataclasses.fields(_Defaults)}
    assert texts == {
        "required_s": "(required)",
        "small": "1e-7",
        "month_s": "2592000",
        "count": "3",
        "off": "false",
        "on": "true",
        "nothing": "null",
        "label": "'x'",
        "pair": "[1, null]",
        "gains": "[0.5, 1, 1e6]",
        "empty": "[]",
        "matrix": "[[1, 2.5], [-3, 4]]",
        "flags": "[true, false]",
        "inner": "!_Inner",
        "one": "[2]",
        "count64": "7",
    }
    numeric = [
        float,
        int,
        np.ndarray,
        typing.Optional[float],
        typing.List[float],
        typing.List[int],
        typing.List[typing.List[float]],
        typing.Optional[typing.List[float]],
        typing.Union[str, int],
    ]
    other = [
        bool,
        str,
        type(None),
        typing.Optional[str],
        typing.List[str],
        typing.List,
        typing.List[bool],
        _Inner,
        typing.Optional[_Inner],
        typing.List[typing.Any],
        complex,
    ]
    assert [t for t in numeric if not _is_numeric_type(t)] == []
    assert [t for t in other if _is_numeric_type(t)] == []
    names = {
        float: "float",
        int: "int",
        str: "string",
        bool: "bool",
        type(None): "null",
        np.ndarray: "matrix (list of rows)",
        _Inner: "!_Inner",
        typing.Optional[float]: "float or null",
        typing.Optional[_Inner]: "!_Inner or null",
        typing.List[typing.List[float]]: "list of list of float",
        typing.List: "list",
        typing.Union[str, int, None]: "string or int or null",
        complex: "complex",
        "ForwardRef": "ForwardRef",
    }
    assert {t: _type_name(t) for t in names} == names


# ======================================================================================
# Duplicate names in an estimator's lists
# ======================================================================================
_DUPLICATES = """
name: duplicates
duration_s: 10.0
plant: !RigidBodyConfig {inertia_kg_m2: [1.0, 1.0, 1.0]}
sensors:
- !GyroConfig {name: gyro, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 0.1}
- !StarTrackerConfig {name: st1, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 40.0}
- !StarTrackerConfig {name: st2, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 40.0}
estimators:
- !MekfConfig {name: m1, star_trackers: %s}
- !MekfConfig {name: m2, star_trackers: [st2]}
- !EstimateFusionConfig {name: f, sources: %s}
"""


def test_a_sensor_listed_twice_in_an_mekf_is_refused_naming_the_list():
    with pytest.raises(ConfigError) as e:
        cfg.load_scenario(text=_DUPLICATES % ("[st1, st1]", "[m1, m2]"))
    assert str(e.value) == "estimators[0] (m1).star_trackers: got ['st1', 'st1']; each sensor may be listed once"
    with pytest.raises(
        ConfigError,
        match=r"^estimators\[0\] \(m1\)\.star_trackers: got \['st1', 'st2', 'st1'\]; "
        "each sensor may be listed once$",
    ):
        cfg.load_scenario(text=_DUPLICATES % ("[st1, st2, st1]", "[m1, m2]"))
    cfg.load_scenario(text=_DUPLICATES % ("[st1, st2]", "[m1, m2]"))


def test_an_estimator_listed_twice_in_a_fusion_is_refused_naming_the_list():
    with pytest.raises(ConfigError) as e:
        cfg.load_scenario(text=_DUPLICATES % ("[st1]", "[m1, m1]"))
    assert str(e.value) == "estimators[2] (f).sources: got ['m1', 'm1']; each estimator may be listed once"


# ======================================================================================
# Memory
# ======================================================================================
_PF = """
name: memory_{n}
duration_s: {duration}
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 1.0}}
plant: !RigidBodyConfig {{inertia_kg_m2: [100.0, 200.0, 200.0]}}
sensors:
- !GyroConfig {{name: gyro, arw_deg_per_rt_h: 0.0033, rrw_deg_per_h15: 0.02}}
- !StarTrackerConfig {{name: st, mode: vectors, references_I: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                      sigma_vector_urad: 100.0}}
estimators:
- !MrpEkfConfig {{name: ekf}}
- !BootstrapPfConfig {{name: bootstrap_pf, num_particles: {n}}}
"""
_LOGS = """
name: logs_{duration}
duration_s: {duration}
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.01}}
plant: !RigidBodyConfig {{inertia_kg_m2: [100.0, 200.0, 200.0]}}
sensors:
- !GyroConfig {{name: gyro, period_s: 0.005, arw_deg_per_rt_h: 0.0033, rrw_deg_per_h15: 0.02}}
- !StarTrackerConfig {{name: st, period_s: 0.005, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 40.0}}
"""


def test_a_billion_particles_are_refused_in_milliseconds_naming_num_particles():
    s = cfg.load_scenario(text=_PF.format(n=10**9, duration=5.0))
    start = time.process_time()  # CPU time: a hang guard that a loaded machine does not fail
    with pytest.raises(ConfigError) as e:
        preflight.check_memory(s, available_bytes=23e9)
    assert time.process_time() - start < 0.5
    message = str(e.value)
    assert message.startswith("estimators[1] (bootstrap_pf).num_particles: got 1000000000; needs ~1,000 GB"), message
    assert "more than the 23 GB available; at most ~2" in message  # ~23e9 / 1000 bytes
    # this machine's memory (a terabyte would be needed)
    if (preflight.available_memory_bytes() or math.inf) < 1e12:
        with pytest.raises(
            ConfigError,
            match=r"num_particles: got 1000000000; needs ~1,000 GB .* more than this "
            r"machine's",
        ):
            preflight.check_memory(s)
    # parallel runs multiply the need
    small = cfg.load_scenario(text=_PF.format(n=10**6, duration=5.0))
    assert preflight.check_memory(small, available_bytes=2e9).total_bytes == pytest.approx(1e9, rel=0.01)
    with pytest.raises(ConfigError, match=r"num_particles: got 1000000; needs ~2(\.\d+)? GB for 2 runs at once"):
        preflight.check_memory(small, available_bytes=2e9, processes=2)


def test_log_dominated_runs_name_the_period_that_sets_the_logs():
    s = copy.deepcopy(cfg.load_scenario(text=_LOGS.format(duration=10.0)))
    s.sensors[0].period_s = s.sensors[1].period_s = 1e-5
    s.duration_s = 2e6
    with pytest.raises(
        ConfigError,
        match=r"^sensors\[0\] \(gyro\)\.period_s: got 1e-05; the run needs ~[\d,]+ GB, "
        r"mostly logs of ~.* over duration_s = 2e\+06 .*use a longer period",
    ):
        preflight.check_memory(s, available_bytes=16e9)
    # the raw log size, written out: 5 loggers at 0.005 s over 10 s = 2001 samples each, widths
    # q 4, w 3, gyro 5, bias 3, tracker 6, each with its times; and what a run logs
    from drake_att.scenarios.builder import ScenarioDiagram

    s = cfg.load_scenario(text=_LOGS.format(duration=10.0))
    assert preflight.log_bytes(s) == 2001 * (5 + 4 + 6 + 4 + 7) * 8
    run = ScenarioDiagram(s).simulate(1)
    assert preflight.log_bytes(s) == sum(t.nbytes + x.nbytes for t, x in run.signals.values())


_MEASURE = textwrap.dedent("""
    import json, sys
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios.builder import ScenarioDiagram

    def status(key):
        with open("/proc/self/status") as f:
            return next(int(l.split()[1]) * 1024 for l in f if l.startswith(key))

    def peak_increase(text):
        s = cfg.load_scenario(text=text)
        open("/proc/self/clear_refs", "w").write("5")  # reset the peak (VmHWM) to the current RSS
        before = status("VmRSS:")
        ScenarioDiagram(s).simulate(1)
        return status("VmHWM:") - before

    texts = json.loads(sys.stdin.read())
    for t in texts["warm"]:
        ScenarioDiagram(cfg.load_scenario(text=t)).simulate(1)
    print(json.dumps([peak_increase(t) for t in texts["measure"]]))
""")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc peak-RSS reset")
def test_the_estimate_is_within_a_factor_2_of_the_measured_peak():
    """A fresh process builds and runs (after a warm-up of the same shapes) a log-heavy run
    (80001 samples of 5 loggers) and a 150000-particle bootstrap PF; the peak RSS each adds
    (VmHWM reset before each) is within a factor 2 of :func:`memory_estimate`."""
    logs, pf = _LOGS.format(duration=400.0), _PF.format(n=150000, duration=5.0)
    texts = {"warm": [_LOGS.format(duration=1.0), _PF.format(n=10, duration=2.0)], "measure": [logs, pf]}
    proc = subprocess.run(
        [sys.executable, "-c", _MEASURE], input=json.dumps(texts), capture_output=True, text=True, timeout=300, cwd=REPO
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    measured = json.loads(proc.stdout.strip().splitlines()[-1])
    for text, peak in zip((logs, pf), measured, strict=True):
        estimate = preflight.memory_estimate(cfg.load_scenario(text=text)).total_bytes
        assert 0.5 < estimate / peak < 2.0, (estimate / 1e6, peak / 1e6)


def test_a_range_has_finite_ordered_bounds():
    """A plug-in's declared range must be a real interval: inf or lo > hi is refused when the
    range is made, not later when a refusal message formats an infinite bound."""
    import math

    from drake_att.scenarios.ranges import Range

    for lo, hi in ((0.0, math.inf), (-math.inf, 1.0), (math.nan, 1.0), (2.0, 1.0)):
        with pytest.raises(ValueError, match="finite with lo <= hi"):
            Range(lo, hi, "unit", "why")
    assert Range(1.0, 1.0, "", "a point").allowed() == "must be in [1, 1] (a point)"
