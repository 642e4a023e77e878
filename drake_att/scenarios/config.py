"""Typed scenario configuration, loaded with ``pydrake.common.yaml.yaml_load_typed``.

Unknown keys are errors (Drake's loader), and :func:`validate` checks every value,
raising ``ConfigError`` that names the field path, the value and what is allowed.
Units are in the field names; angles in degrees at this edge only.

Polymorphic lists use YAML tags with the class name, e.g.::

    sensors:
    - !GyroConfig {name: gyro, period_s: 1.0, ...}
    - !StarTrackerConfig {name: st1, ...}
    estimators:
    - !MekfConfig {name: mekf, gyro: gyro, star_trackers: [st1]}

Attitude frames: when ``orbit`` is set, every initial attitude (truth and estimates) is
roll/pitch/yaw of the body **relative to the orbit (LVLH) frame at t = 0**; otherwise
relative to the inertial frame.  Body rates are always ``w_IB_B`` (inertial rate in body
axes).
"""



import dataclasses
import typing
from dataclasses import dataclass, field
from typing import List, Optional, Union

import numpy as np
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from drake_att import validation


# A scenario value is invalid; the message names the field path and the value. Defined
# with the one validation family (drake_att.validation), whose checks the loader and the
# plug-ins' validators call with error=ConfigError through the check_* functions below.
ConfigError = validation.ConfigError


def _zeros3():
    return [0.0, 0.0, 0.0]


@dataclass
class SimulationConfig:
    """Drake integrator settings (see ``pydrake.systems.analysis.SimulatorConfig``).

    ``integration_scheme``: any Drake scheme name, e.g. runge_kutta3, runge_kutta5,
    radau3, explicit_euler.  With ``use_error_control`` the step is chosen for
    ``accuracy``; ``max_step_size`` bounds it either way (events also end steps).
    """

    integration_scheme: str = "runge_kutta5"
    max_step_size_s: float = 1.0
    accuracy: float = 1e-10
    use_error_control: bool = True


@dataclass
class OrbitConfig:
    """Circular orbit; defines the LVLH frame used for initial attitudes and reporting."""

    altitude_km: float = 500.0
    inclination_deg: float = 97.5
    raan_deg: float = 0.0
    arg_latitude0_deg: float = 0.0


@dataclass
class RigidBodyConfig:
    """Rigid-body truth (Euler's equations + quaternion kinematics)."""

    inertia_kg_m2: List[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_rate_deg_per_s: List[float] = field(default_factory=_zeros3)
    disturbance_torque_N_m: List[float] = field(default_factory=_zeros3)


@dataclass
class PrescribedRateConfig:
    """Kinematic truth: ``w_i(t) = constant_i + amplitude_i cos(frequency_i t + phase_i)``."""

    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    constant_deg_per_s: List[float] = field(default_factory=_zeros3)
    amplitude_deg_per_s: List[float] = field(default_factory=_zeros3)
    frequency_rad_per_s: List[float] = field(default_factory=_zeros3)
    phase_deg: List[float] = field(default_factory=_zeros3)


@dataclass
class PrescribedRpyConfig:
    """Kinematic truth: piecewise-linear roll/pitch/yaw through breakpoints."""

    times_s: List[float] = field(default_factory=lambda: [0.0, 1.0])
    rpy_deg: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))  # (n, 3)


PlantConfig = Union[RigidBodyConfig, PrescribedRateConfig, PrescribedRpyConfig]


# Sensor and estimator configs live in their plug-in modules (drake_att.sensors,
# drake_att.estimators, or a scenario's ``plugins``); the scenario's lists accept every
# registered type (drake_att.scenarios.registry). ``cfg.MekfConfig`` etc. still resolve
# (module __getattr__ below).


@dataclass
class ScoringConfig:
    """How estimates are scored (see ``drake_att.analysis.metrics``).

    ``score_from_s``: start of the "stable stage" for RMSE/MAE/NEES.
    ``convergence_threshold_deg``: the convergence time is the first time after which
    every axis of the attitude error stays within this bound until the end.
    """

    score_from_s: float = 0.0
    convergence_threshold_deg: float = 0.05


@dataclass
class Scenario:
    """A complete, reproducible run: truth, sensors, estimators, scoring and seed."""

    name: str = "unnamed"
    description: str = ""
    plugins: List[str] = field(default_factory=list)  # modules imported before the lists are read
    duration_s: float = 100.0
    seed: int = 1
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    orbit: Optional[OrbitConfig] = None
    plant: PlantConfig = field(default_factory=RigidBodyConfig)
    sensors: List[typing.Any] = field(default_factory=list)  # registered sensor configs
    estimators: List[typing.Any] = field(default_factory=list)  # registered estimator configs
    scoring: ScoringConfig = field(default_factory=ScoringConfig)


# --------------------------------------------------------------------------------------
# Loading, dumping, overrides
# --------------------------------------------------------------------------------------
_TAG_KEY = "\x00tag"  # where the pre-parse keeps a mapping's YAML tag (not a valid field name)


def _preparse(text: str, where: str = "scenario") -> tuple[list, dict]:
    """``(plugins, raw data)`` of a scenario's YAML text, read before the typed load (tags of
    not-yet-imported plug-ins are read as plain mappings, the tag kept under ``_TAG_KEY``). Also refuses, naming what
    and where, what the typed loader would not say clearly: an empty file, a top level that
    is not a mapping, a duplicate key (the typed loader keeps the last silently) and an
    unknown top-level field (with the allowed ones)."""
    import yaml

    class _Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                if key in seen:
                    raise ConfigError(f"{where}: duplicate key {key!r} at line {key_node.start_mark.line + 1} "
                                      f"(first at line {seen[key] + 1}); each key may appear once")
                seen[key] = key_node.start_mark.line
            return super().construct_mapping(node, deep=deep)

    def _untagged(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            mapping = loader.construct_mapping(node, deep=True)
            mapping[_TAG_KEY] = suffix
            return mapping
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        return loader.construct_scalar(node)

    _Loader.add_multi_constructor("!", _untagged)
    _Loader.add_multi_constructor("tag:", _untagged)
    try:
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as e:
        raise ConfigError(f"{where}: invalid YAML: {e}") from e
    if data is None:
        raise ConfigError(f"{where}: the scenario is empty; it needs at least a name and a plant, sensors and "
                          "estimators (see drake_att/scenarios/*.yaml)")
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: got a YAML {type(data).__name__} at the top level; a scenario is a mapping "
                          f"of the fields {[f.name for f in dataclasses.fields(Scenario)]}")
    unknown = [k for k in data if k not in {f.name for f in dataclasses.fields(Scenario)}]
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {unknown}; allowed: {[f.name for f in dataclasses.fields(Scenario)]}")
    plugins = data.get("plugins", [])
    if not isinstance(plugins, list) or not all(isinstance(p, str) for p in plugins):
        fail("plugins", plugins, "must be a list of module names, e.g. [my_package.my_filter]")
    return plugins, data


def _unknown_list_fields(data, where: str) -> None:
    """Name the item, the unknown field(s) and the allowed ones for a ``sensors`` or
    ``estimators`` item (the typed loader says only which field, not where)."""
    from drake_att.scenarios import registry

    for section in ("sensors", "estimators"):
        items = data.get(section) or []
        if not isinstance(items, list):
            continue
        for i, item in enumerate(items):
            if not isinstance(item, dict) or _TAG_KEY not in item:
                continue
            try:
                config_type = registry.config_type(item[_TAG_KEY])
            except AttributeError:
                tags = sorted(registry.plugins(registry.SENSOR if section == "sensors" else registry.ESTIMATOR))
                raise ConfigError(f"{where}: {section}[{i}]: unknown type !{item[_TAG_KEY]}; registered: "
                                  f"{['!' + t for t in tags]} (a plug-in module must be listed in plugins:)") from None
            allowed = [f.name for f in dataclasses.fields(config_type)]
            unknown = [k for k in item if k != _TAG_KEY and k not in allowed]
            if unknown:
                raise ConfigError(f"{where}: {section}[{i}] ({item.get('name', '?')}, !{item[_TAG_KEY]}): unknown "
                                  f"field(s) {unknown}; allowed: {allowed}")


def prepare_schema(plugins=()) -> None:
    """Import the built-in and the given plug-ins and point the scenario schema at them."""
    from drake_att.scenarios import registry

    try:
        registry.load_plugins(plugins)
    except registry.PluginError as e:
        raise ConfigError(str(e)) from e
    registry.refresh_schema(Scenario)


def load_scenario(text: str | None = None, filename: str | None = None) -> Scenario:
    """Load and validate a scenario from YAML text or a file (importing its ``plugins``)."""
    if filename is not None:
        try:
            with open(filename) as f:
                text = f.read()
        except OSError as e:
            raise ConfigError(f"{filename}: cannot read the scenario: {e.strerror}") from e
    where = filename or "scenario"
    plugins, raw = _preparse(text, where)
    prepare_schema(plugins)
    _unknown_list_fields(raw, where)
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except (RuntimeError, TypeError, ValueError) as e:  # Drake reports schema errors as RuntimeError
        raise ConfigError(f"{filename + ': ' if filename else ''}{e}") from e
    validate(scenario)
    return scenario


def dump_scenario(scenario: Scenario) -> str:
    prepare_schema(scenario.plugins)
    return yaml_dump_typed(scenario)


def apply_overrides(scenario: Scenario, overrides: typing.Sequence[str]) -> Scenario:
    """Apply ``path=value`` overrides (``value`` parsed as YAML) and re-validate.

    ``path`` is dotted; a list element is addressed by index or by its ``name`` field,
    e.g. ``duration_s=600``, ``sensors.st1.sigma_boresight_arcsec=20``,
    ``estimators.0.period_s=0.5``, ``plant.initial_rate_deg_per_s=[0,0,0.1]``.
    Returns a new scenario; the argument is left unchanged (also when an override fails).
    """
    import copy

    import yaml

    scenario = copy.deepcopy(scenario)  # never modify the caller's scenario, even on error
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected PATH=VALUE")
        path, raw = item.split("=", 1)
        value = yaml.safe_load(raw)
        parts = path.strip().split(".")
        target = scenario
        for depth, key in enumerate(parts[:-1]):
            target = _child(target, key, ".".join(parts[: depth + 1]))
        last = parts[-1]
        if isinstance(target, list):
            idx = _list_index(target, last, path)
            _refuse_section(target[idx], value, path)
            target[idx] = value
        else:
            if not dataclasses.is_dataclass(target) or last not in {f.name for f in dataclasses.fields(target)}:
                allowed = [f.name for f in dataclasses.fields(target)] if dataclasses.is_dataclass(target) else []
                raise ConfigError(f"--set {path}: unknown field {last!r}; allowed: {allowed}")
            current = getattr(target, last)
            _refuse_section(current, value, path)
            setattr(target, last, _coerce(value, current, path))
    # Round-trip through the typed loader so types and unknown keys are checked again.
    try:
        text = dump_scenario(scenario)
    except (RuntimeError, TypeError, ValueError) as e:
        raise ConfigError(f"--set: the overridden scenario is not valid: {e}") from e
    return load_scenario(text=text)


def _refuse_section(current, value, path):
    """A section (a config dataclass: the plant, a sensor, an estimator) is not replaced by
    a scalar or a list from ``--set``: set its fields."""
    if dataclasses.is_dataclass(current) and not isinstance(value, dict):
        fields = [f.name for f in dataclasses.fields(current)]
        raise ConfigError(f"--set {path}: got {value!r}; {path} is a section ({type(current).__name__}): set one of "
                          f"its fields, e.g. --set {path}.{fields[-1]}=...; fields: {fields}")


def _child(obj, key, path):
    if isinstance(obj, list):
        return obj[_list_index(obj, key, path)]
    if dataclasses.is_dataclass(obj) and key in {f.name for f in dataclasses.fields(obj)}:
        child = getattr(obj, key)
        if child is None:
            raise ConfigError(f"--set {path}: field is not set (None) in this scenario")
        return child
    allowed = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else []
    raise ConfigError(f"--set {path}: unknown field {key!r}; allowed: {allowed}")


def _list_index(lst, key, path):
    if key.isdigit():
        i = int(key)
        if i >= len(lst):
            raise ConfigError(f"--set {path}: index {i} out of range (list has {len(lst)} items)")
        return i
    for i, item in enumerate(lst):
        if getattr(item, "name", None) == key:
            return i
    names = [getattr(x, "name", None) for x in lst]
    raise ConfigError(f"--set {path}: no element named {key!r}; names: {names}")


def _coerce(value, current, path):
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"--set {path}: got {value!r}; expected true/false")
        return value
    if isinstance(current, float) or (current is None and isinstance(value, (int, float))):
        if isinstance(value, str):  # YAML 1.1 reads "1e-10" (no dot) as a string
            try:
                value = float(value)
            except ValueError:
                pass
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ConfigError(f"--set {path}: got {value!r}; expected a number")
        return float(value)
    if isinstance(current, int):
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"--set {path}: got {value!r}; expected an integer")
        return value
    if isinstance(current, np.ndarray):
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"--set {path}: got {value!r}; expected a numeric matrix") from None
        return arr.reshape((-1,) + current.shape[1:]) if current.ndim == 2 and arr.size else arr
    if isinstance(current, list) and not isinstance(value, list):
        raise ConfigError(f"--set {path}: got {value!r}; expected a list")
    if isinstance(current, list):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in value]
    return value


# --------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------
zeros3 = _zeros3  # default factory for 3-vectors in plug-in configs


# The one validation family: plug-ins use these (each raises ConfigError naming the field
# path, the value and what is allowed).
def fail(path: str, value, allowed: str):
    validation.fail(path, value, allowed, ConfigError)


def check_finite(path: str, value) -> float:
    return validation.check_finite(path, value, ConfigError)


def check_positive(path: str, value) -> float:
    return validation.check_positive(path, value, error=ConfigError)


def check_nonnegative(path: str, value) -> float:
    return validation.check_nonnegative(path, value, ConfigError)


def check_vector(path: str, value, n: int) -> list:
    return validation.check_vector(path, value, n, ConfigError)


def check_weights(path: str, value, n: int) -> list:
    return validation.check_weights(path, value, n, ConfigError)


@dataclass
class ValidationContext:
    """What a plug-in's validate function sees: the scenario and the sensors and estimators
    listed before the one being checked (name -> config)."""

    scenario: "Scenario"
    sensors: dict = field(default_factory=dict)
    estimators: dict = field(default_factory=dict)

    def sensor_output(self, name):
        """:class:`~drake_att.scenarios.registry.SensorOutput` of sensor ``name`` (None if unknown)."""
        from drake_att.scenarios.registry import plugin_for

        c = self.sensors.get(name)
        return None if c is None else plugin_for(c).output(c, self.sensors)

    def second_quantity(self, name):
        """:class:`~drake_att.contract.SecondQuantity` of estimator ``name``."""
        from drake_att.scenarios.registry import plugin_for

        c = self.estimators[name]
        sq = plugin_for(c).second_quantity
        return sq(c, self) if callable(sq) else sq


def validate(s: Scenario) -> None:
    """Check every value of a scenario; raise :class:`ConfigError` on the first bad one."""
    check_positive("duration_s", s.duration_s)
    validation.check_seed("seed", s.seed, ConfigError)
    check_positive("simulation.max_step_size_s", s.simulation.max_step_size_s)
    check_positive("simulation.accuracy", s.simulation.accuracy)
    schemes = {"runge_kutta2", "runge_kutta3", "runge_kutta5", "bogacki_shampine3", "radau1", "radau3",
               "explicit_euler", "semi_explicit_euler", "implicit_euler", "velocity_implicit_euler"}
    if s.simulation.integration_scheme not in schemes:
        fail("simulation.integration_scheme", s.simulation.integration_scheme, f"allowed: {sorted(schemes)}")
    if s.orbit is not None:
        check_positive("orbit.altitude_km", s.orbit.altitude_km)
        for f in ("inclination_deg", "raan_deg", "arg_latitude0_deg"):
            check_finite(f"orbit.{f}", getattr(s.orbit, f))
    p = s.plant
    if isinstance(p, RigidBodyConfig):
        if not isinstance(p.inertia_kg_m2, list) or len(p.inertia_kg_m2) not in (3, 9):
            fail("plant.inertia_kg_m2", p.inertia_kg_m2, "must be 3 principal moments or 9 matrix entries")
        from drake_att.systems.plant import validate_inertia

        I = np.array(p.inertia_kg_m2, dtype=float)
        try:
            validate_inertia(I if I.size == 3 else I.reshape(3, 3), "plant.inertia_kg_m2")
        except ValueError as e:
            raise ConfigError(str(e)) from e
        check_vector("plant.initial_attitude_rpy_deg", p.initial_attitude_rpy_deg, 3)
        check_vector("plant.initial_rate_deg_per_s", p.initial_rate_deg_per_s, 3)
        check_vector("plant.disturbance_torque_N_m", p.disturbance_torque_N_m, 3)
    elif isinstance(p, PrescribedRateConfig):
        for f in ("initial_attitude_rpy_deg", "constant_deg_per_s", "amplitude_deg_per_s",
                  "frequency_rad_per_s", "phase_deg"):
            check_vector(f"plant.{f}", getattr(p, f), 3)
    elif isinstance(p, PrescribedRpyConfig):
        if len(p.times_s) < 2 or np.ndim(p.rpy_deg) != 2 or len(p.rpy_deg) != len(p.times_s):
            fail("plant.times_s", p.times_s, "need >= 2 breakpoints and one rpy_deg row per time")
        for i in range(1, len(p.times_s)):
            if not p.times_s[i] > p.times_s[i - 1]:
                fail("plant.times_s", p.times_s, "must be strictly increasing")
        for i, row in enumerate(p.rpy_deg):
            check_vector(f"plant.rpy_deg[{i}]", row, 3)

    from drake_att.scenarios.registry import plugin_for

    checks = ValidationContext(s)
    for i, sensor in enumerate(s.sensors):
        path = f"sensors[{i}] ({getattr(sensor, 'name', '?')})"
        if not sensor.name or sensor.name in checks.sensors:
            fail(f"{path}.name", sensor.name, "must be a non-empty name unique among sensors")
        plugin = plugin_for(sensor)
        if plugin.validate is not None:
            plugin.validate(path, sensor, checks)
        checks.sensors[sensor.name] = sensor
    for i, est in enumerate(s.estimators):
        path = f"estimators[{i}] ({getattr(est, 'name', '?')})"
        if not est.name or est.name in checks.estimators or est.name in checks.sensors:
            fail(f"{path}.name", est.name, "must be non-empty and unique among sensors and estimators")
        plugin = plugin_for(est)
        if plugin.validate is not None:
            plugin.validate(path, est, checks)
        checks.estimators[est.name] = est
    check_nonnegative("scoring.score_from_s", s.scoring.score_from_s)
    if s.scoring.score_from_s >= s.duration_s:
        fail("scoring.score_from_s", s.scoring.score_from_s, f"must be < duration_s ({s.duration_s})")
    check_positive("scoring.convergence_threshold_deg", s.scoring.convergence_threshold_deg)


def __getattr__(name):
    """``cfg.GyroConfig``, ``cfg.MekfConfig``, ...: the registered plug-in config classes."""
    if name.endswith("Config"):
        from drake_att.scenarios import registry

        try:
            return registry.config_type(name)
        except AttributeError:
            pass
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
