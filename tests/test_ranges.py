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

import copy
import dataclasses
import json
import math
import subprocess
import sys
import textwrap
import time
import typing
from pathlib import Path

import numpy as np
import pytest

from drake_att.scenarios import config as cfg
from drake_att.scenarios import preflight, registry
from drake_att.scenarios.library import available_scenarios, load
from drake_att.scenarios.ranges import Split, check_ranges, range_for, render_markdown
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
    return False


def _dataclass_args(t) -> list:
    if isinstance(t, type) and dataclasses.is_dataclass(t):
        return [t]
    return [x for a in typing.get_args(t) for x in _dataclass_args(a)]


def _registered_types() -> list:
    registry.ensure_builtin_plugins()
    return [p.config_type for kind in (registry.SENSOR, registry.ESTIMATOR)
            for p in registry.plugins(kind).values()]


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
        section = "sensors" if t in [p.config_type for p in registry.plugins(registry.SENSOR).values()] \
            else "estimators"

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
    return [(t, b, f.name, typing.get_type_hints(t)[f.name]) for t, b in _slots() for f in dataclasses.fields(t)
            if _numeric(typing.get_type_hints(t)[f.name])]


NUMERIC_FIELDS = _numeric_fields()


def test_every_numeric_field_of_every_config_resolves_to_a_range():
    assert len(NUMERIC_FIELDS) > 150  # the enumeration reaches every config
    types = {t for t, *_ in NUMERIC_FIELDS}
    for t in _registered_types() + [cfg.Scenario, cfg.SimulationConfig, cfg.OrbitConfig, cfg.RigidBodyConfig,
                                    cfg.PrescribedRateConfig, cfg.PrescribedRpyConfig, cfg.ScoringConfig]:
        assert t in types, t
    assert {"RpyMounting", "PaperS3Eq7Mounting"} <= {t.__name__ for t in types}
    missing = [f"{t.__name__}.{name}" for t, _, name, _ in NUMERIC_FIELDS if range_for(t, name) is None]
    assert not missing, f"numeric fields without a physical range (add one to drake_att/scenarios/ranges.py): {missing}"


def test_the_library_defaults_are_inside_their_ranges():
    for t, build in _slots():
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
    return ann is int or typing.get_args(ann) == (int,) or (typing.get_origin(ann) is typing.Union and
                                                              int in typing.get_args(ann))


def _place(obj, name, ann, value, entry, label):
    """Put ``value`` into field ``name`` of ``obj``; returns the path suffix of where it sits."""
    if isinstance(entry, Split):  # e.g. inertia: find a list size and an entry of that part
        for size in (3, 9, 6, 4, 2, 1):
            for i in range(size):
                if entry.select(i, size) == label:
                    fill = [min(max(1.0, entry.parts[entry.select(k, size)].lo), entry.parts[entry.select(k, size)].hi)
                            for k in range(size)]
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
    gyro = cfg.GyroConfig(name="gyro", arw_deg_per_rt_h=1.0e300)
    with pytest.raises(ConfigError) as e:
        check_ranges(_scenario_with_sensors(gyro))
    assert str(e.value) == ("sensors[0] (gyro).arw_deg_per_rt_h: got 1e+300; must be in [0, 100] deg/sqrt(h) (an angle "
                            "random walk: 1e-4 (navigation grade) to ~10 (the noisiest MEMS))")
    gyro = cfg.GyroConfig(name="g", rrw_deg_per_h15=1.0e300)
    with pytest.raises(ConfigError, match=r"^sensors\[0\] \(g\)\.rrw_deg_per_h15: got 1e\+300; must be in \[0, 1000\] "
                                          r"deg/h\^1\.5 \("):
        check_ranges(_scenario_with_sensors(gyro))
    faults = cfg.SensorFaultsConfig(name="f", outlier_rate_deg_per_s=1.0e300)
    with pytest.raises(ConfigError, match=r"^sensors\[1\] \(f\)\.outlier_rate_deg_per_s: got 1e\+300; must be in "
                                          r"\[-5000, 5000\] deg/s \("):
        check_ranges(_scenario_with_sensors(cfg.GyroConfig(), faults))
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
    s.estimators = [cfg.MekfConfig(name="m"), cfg.EkpfConfig(name="joint", initial_attitude_sigma_deg=1e6)]
    with pytest.raises(ConfigError, match=r"^estimators\[1\] \(joint\)\.initial_attitude_sigma_deg: got 1000000\.0; "
                                          r"must be in \[0, 360\] deg \("):
        check_ranges(s)


def test_real_sensors_and_missions_pass():
    """A few real extremes: a fast spinner, a consumer MEMS gyro, a coarse tracker, a GEO
    mission of 30 days, a navigation-grade gyro, a 100 kHz sample period."""
    gyro = cfg.GyroConfig(name="mems", period_s=1e-5, sample_rate_hz=1e5, arw_deg_per_rt_h=0.6, rrw_deg_per_h15=5.0,
                          initial_bias_deg_per_h=[3600.0, -7200.0, 10.0], scale_factor_error_ppm=[5000.0, 0, 0])
    nav = cfg.GyroConfig(name="nav", arw_deg_per_rt_h=0.001, rrw_deg_per_h15=1e-4, initial_bias_deg_per_h=[0.01] * 3)
    st = cfg.StarTrackerConfig(name="st", sigma_cross_boresight_arcsec=100.0, sigma_boresight_arcsec=600.0)
    s = _scenario_with_sensors(gyro, nav, st, estimators=[cfg.BootstrapPfConfig(num_particles=10**6)])
    s.duration_s = 30 * 86400.0
    s.orbit.altitude_km = 35786.0
    s.plant.initial_rate_deg_per_s = [600.0, 0.0, 0.0]  # 100 rpm
    s.plant.inertia_kg_m2 = [1.2e8, 1.0e8, 2.0e8]  # ISS-like
    check_ranges(s)


def test_nested_arrays_name_row_and_column_and_nan_is_refused():
    s = cfg.Scenario(plant=cfg.PrescribedRpyConfig(times_s=[0.0, 10.0], rpy_deg=np.array([[0, 0, 0], [0, 0, 2e6]])))
    with pytest.raises(ConfigError, match=r"^plant\.rpy_deg\[1\]\[2\]: got 2000000\.0; must be in \[-1e6, 1e6\] deg"):
        check_ranges(s)
    from drake_att.sensors.star_tracker import PaperS3Eq7Mounting

    st = cfg.StarTrackerConfig(name="st", mounting=PaperS3Eq7Mounting(psi_phi_theta_deg=[0, 400, 0]))
    with pytest.raises(ConfigError, match=r"^sensors\[0\] \(st\)\.mounting\.psi_phi_theta_deg\[1\]: got 400; must be "
                                          r"in \[-360, 360\] deg"):
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

    with pytest.raises(ConfigError, match=r"^estimators\[0\] \(u\)\.smoothing: got 0\.5; no physical range is "
                                          r"documented for _Untyped\.smoothing"):
        check_ranges(cfg.Scenario(estimators=[_Untyped()]))
    check_ranges(cfg.Scenario(estimators=[_Declared()]))
    with pytest.raises(ConfigError, match=r"^estimators\[0\] \(d\)\.smoothing: got 1\.5; must be in \[0, 1\] \(a "
                                          r"fraction\)$"):
        check_ranges(cfg.Scenario(estimators=[_Declared(smoothing=1.5)]))
    with pytest.raises(ConfigError, match=r"^estimators\[0\] \(d\)\.horizon_s: got 1e\+20; must be in "
                                          r"\[0, 2592000\] s"):
        check_ranges(cfg.Scenario(estimators=[_Declared(horizon_s=1e20)]))  # the unit suffix's default


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
    assert doc == render_markdown(), ("docs/config_reference.md is stale; regenerate it with "
                                      "python -m drake_att.scenarios.ranges > docs/config_reference.md")
    assert "**none**" not in doc
    for t, _, name, _ in NUMERIC_FIELDS:
        if t.__module__.startswith("drake_att."):
            assert f".{name}`" in doc or f"`{name}`" in doc or f".{name} (" in doc, name


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
    with pytest.raises(ConfigError, match=r"^estimators\[0\] \(m1\)\.star_trackers: got \['st1', 'st2', 'st1'\]; "
                                          "each sensor may be listed once$"):
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
- !BootstrapPfConfig {{name: bootstrap_pf, num_particles: {n}, kernel: numpy}}
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
    start = time.perf_counter()
    with pytest.raises(ConfigError) as e:
        preflight.check_memory(s, available_bytes=23e9)
    assert time.perf_counter() - start < 0.05
    message = str(e.value)
    assert message.startswith("estimators[1] (bootstrap_pf).num_particles: got 1000000000; needs ~1,000 GB"), message
    assert "more than the 23 GB available; at most ~2" in message  # ~23e9 / 1000 bytes
    # this machine's memory (a terabyte would be needed)
    if (preflight.available_memory_bytes() or math.inf) < 1e12:
        with pytest.raises(ConfigError, match=r"num_particles: got 1000000000; needs ~1,000 GB .* more than this "
                                              r"machine's"):
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
    with pytest.raises(ConfigError, match=r"^sensors\[0\] \(gyro\)\.period_s: got 1e-05; the run needs ~[\d,]+ GB, "
                                          r"mostly logs of ~.* over duration_s = 2e\+06 .*use a longer period"):
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


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc peak-RSS reset")
def test_the_estimate_is_within_a_factor_2_of_the_measured_peak():
    """A fresh process builds and runs (after a warm-up of the same shapes) a log-heavy run
    (80001 samples of 5 loggers) and a 150000-particle bootstrap PF; the peak RSS each adds
    (VmHWM reset before each) is within a factor 2 of :func:`memory_estimate`."""
    logs, pf = _LOGS.format(duration=400.0), _PF.format(n=150000, duration=5.0)
    texts = {"warm": [_LOGS.format(duration=1.0), _PF.format(n=10, duration=2.0)], "measure": [logs, pf]}
    proc = subprocess.run([sys.executable, "-c", _MEASURE], input=json.dumps(texts), capture_output=True, text=True,
                          timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-3000:]
    measured = json.loads(proc.stdout.strip().splitlines()[-1])
    for text, peak in zip((logs, pf), measured):
        estimate = preflight.memory_estimate(cfg.load_scenario(text=text)).total_bytes
        assert 0.5 < estimate / peak < 2.0, (estimate / 1e6, peak / 1e6)
