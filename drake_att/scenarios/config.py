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

The typed scenario schema and its one validation family, which belong in one place to stay one family.
"""

import dataclasses
import os
import typing
from dataclasses import dataclass, field
from typing import Dict, List, NoReturn, Optional, Union

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
class TleOrbitConfig:
    """An orbit from a two-line element set, propagated by SGP4 (the ``sgp4`` package) from
    ``epoch_utc`` (the scenario's t = 0, within 30 days of the TLE's epoch); TEME rotated into
    GCRS at the epoch (module ``drake_att.orbit_propagators``)."""

    line1: str = ""
    line2: str = ""
    epoch_utc: str = ""


@dataclass
class KeplerOrbitConfig:
    """Keplerian elements in GCRS at ``epoch_utc`` (the scenario's t = 0): two-body motion,
    with ``j2`` the secular J2 drift of node, perigee and mean anomaly
    (module ``drake_att.orbit_propagators``)."""

    epoch_utc: str = "2026-01-01T00:00:00Z"
    semi_major_axis_km: float = 6878.137
    eccentricity: float = 0.0
    inclination_deg: float = 97.4
    raan_deg: float = 0.0
    arg_perigee_deg: float = 0.0
    mean_anomaly_deg: float = 0.0
    j2: bool = False


OrbitTypes = Union[OrbitConfig, TleOrbitConfig, KeplerOrbitConfig]


@dataclass
class OrbitPointingControlConfig:
    """A PD attitude controller that keeps the truth on the orbit (LVLH) frame turned by
    ``offset_rpy_deg`` - nadir pointing by default - closing its loop on the true state
    (module ``drake_att.systems.attitude_control``). ``torque_noise_N_m``: per-axis sigma of a
    random torque held over each ``period_s`` (the jitter's source with the disturbance torque)."""

    offset_rpy_deg: List[float] = field(default_factory=_zeros3)
    natural_frequency_rad_per_s: float = 0.1
    damping_ratio: float = 0.7
    period_s: float = 1.0
    torque_noise_N_m: float = 0.0


@dataclass
class RigidBodyConfig:
    """Rigid-body truth (Euler's equations + quaternion kinematics).

    ``attitude_control``: null (free body) or an :class:`OrbitPointingControlConfig` (needs an
    orbit); with it, ``initial_rate_deg_per_s`` is relative to the rotating reference (zero: the
    body starts turning with the orbit frame), as ``initial_attitude_rpy_deg`` is relative to the
    orbit frame.
    """

    inertia_kg_m2: List[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_rate_deg_per_s: List[float] = field(default_factory=_zeros3)
    disturbance_torque_N_m: List[float] = field(default_factory=_zeros3)
    attitude_control: Optional[OrbitPointingControlConfig] = None


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
# registered type (drake_att.scenarios.registry).


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
class LoggingConfig:
    """Which signals a run logs and how often (module ``drake_att.scenarios.logging_policy``).

    The default logs every signal at its own period: the truth at the smallest sensor or
    estimator period, each sensor's logged ports at its sample period, each estimator's
    estimate, diagnostics and innovations at its filter step. A signal is named by its key
    in ``log.npz`` (``<system>/<port>``, e.g. ``rigid_body_plant/q_IB``, ``st1/exclusion``,
    ``mekf/q_IB_hat``, ``mekf/innovations``); ``periods_s`` and ``exclude`` take such keys
    or ``fnmatch`` patterns (``"st1/*"``, ``"*/innovations"``).

    ``period_s``: every signal at most this far apart: each is logged every n of its own
    periods, n = floor(period_s / own period) and at least 1 (a signal slower than
    ``period_s`` keeps its own period). ``periods_s``: a period per key or pattern (an exact
    key wins over patterns; patterns that match one key must agree), each a positive
    multiple of the signal's own period; it overrides ``period_s``. ``exclude``: keys or
    patterns of signals not logged; the truth and each estimator's estimate (attitude,
    second quantity, covariance, status) and the true gyro bias it is scored against
    cannot be excluded. A decimated estimator is logged at multiples of its period: each
    sample is its estimate at a multiple of that period, scored against the truth logged
    at that time (its period must be a multiple of the truth's).
    """

    period_s: Optional[float] = None
    periods_s: Dict[str, float] = field(default_factory=dict)
    exclude: List[str] = field(default_factory=list)


@dataclass
class Scenario:
    """A complete, reproducible run: truth, sensors, estimators, scoring and seed."""

    name: str = "unnamed"
    description: str = ""
    plugins: List[str] = field(default_factory=list)  # modules imported before the lists are read
    duration_s: float = 100.0
    seed: int = 1
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    orbit: Optional[OrbitTypes] = None
    plant: PlantConfig = field(default_factory=RigidBodyConfig)
    sensors: List[typing.Any] = field(default_factory=list)  # registered sensor configs
    estimators: List[typing.Any] = field(default_factory=list)  # registered estimator configs
    scoring: ScoringConfig = field(default_factory=ScoringConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)


# --------------------------------------------------------------------------------------
# Loading, dumping, overrides
# --------------------------------------------------------------------------------------
_TAG_KEY = "\x00tag"  # where the pre-parse keeps a mapping's YAML tag (not a valid field name)

# Loading is bounded: a scenario file is at most this many bytes, and its YAML at most this
# many nodes once every alias is expanded (a 1 KB "billion laughs" of nested aliases would
# otherwise expand to gigabytes in the typed loader and in error messages).
MAX_SCENARIO_BYTES = 2**20
MAX_YAML_NODES = 200_000
MAX_YAML_DEPTH = 64


def _check_node_graph(root, where: str) -> None:
    """Refuse a composed YAML node graph whose alias expansion exceeds
    :data:`MAX_YAML_NODES` nodes or that refers to itself (an alias inside its own anchor).
    Iterative, memoized per node: a bomb is refused in microseconds per distinct node."""
    import yaml

    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            if isinstance(node, yaml.SequenceNode):
                children = node.value
            elif isinstance(node, yaml.MappingNode):
                children = [n for pair in node.value for n in pair]
            else:
                children = []
            total = 1 + sum(size[id(c)] for c in children)
            if total > MAX_YAML_NODES:
                raise ConfigError(
                    f"{where}: its YAML expands to more than {MAX_YAML_NODES} nodes (aliases of "
                    "aliases?); a scenario is far smaller - refused"
                )
            size[key] = total
            continue
        if key in size:
            continue
        if key in on_path:
            raise ConfigError(
                f"{where}: line {node.start_mark.line + 1}: a YAML alias refers to its own anchor "
                "(a recursive structure); a scenario cannot hold one"
            )
        on_path.add(key)
        stack.append((node, True))
        if isinstance(node, yaml.SequenceNode):
            stack.extend((c, False) for c in node.value)
        elif isinstance(node, yaml.MappingNode):
            stack.extend((n, False) for pair in node.value for n in pair)


def load_yaml_text(text: str, where: str, loader=None):
    """Parse YAML ``text`` with ``loader`` (default: PyYAML's SafeLoader, which executes no
    tags) within the loading bounds; every failure is a :class:`ConfigError` naming
    ``where`` (a file name, or ``--set PATH``)."""
    import yaml

    base = loader or yaml.SafeLoader

    class _Bounded(base):  # type: ignore[valid-type,misc]  # the loader class is chosen at run time
        depth = 0

        def compose_node(self, parent, index):
            self.depth += 1
            try:
                if self.depth > MAX_YAML_DEPTH:
                    raise ConfigError(
                        f"{where}: its YAML is nested more than {MAX_YAML_DEPTH} levels deep; a "
                        "scenario is far flatter - refused"
                    )
                return super().compose_node(parent, index)
            finally:
                self.depth -= 1

        def get_single_data(self):
            node = self.get_single_node()
            if node is None:
                return None
            _check_node_graph(node, where)
            return self.construct_document(node)

    try:
        return yaml.load(text, Loader=_Bounded)
    except ConfigError:
        raise
    except yaml.YAMLError as e:
        raise ConfigError(f"{where}: invalid YAML: {_one_line(e)}") from None
    except (ValueError, TypeError, OverflowError) as e:  # a scalar PyYAML cannot convert (e.g. 5000 digits)
        raise ConfigError(f"{where}: a value cannot be read: {_one_line(e)}") from None
    except RecursionError:  # a bound above not reached first (a very low recursion limit)
        raise ConfigError(f"{where}: its YAML is nested too deeply to be a scenario") from None


def _one_line(e, limit: int = 300) -> str:
    text = " ".join(str(e).split())
    return text if len(text) <= limit else text[:limit] + "..."


def read_text_bounded(path: str, limit: int) -> str:
    """The UTF-8 text of a small file the user gives (a scenario, a result folder's own
    files), at most ``limit`` bytes; ValueError saying why not - not a regular file (a FIFO
    or a device would block or never end), unreadable, too large, binary, not UTF-8 -
    without the path (the caller names it)."""
    if not os.path.isfile(path):
        raise ValueError("is not a regular file")
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as e:
        raise ValueError(f"cannot be read ({_one_line(e.strerror or e, 80)})") from None
    if len(data) > limit:
        raise ValueError(f"larger than {limit} bytes")
    if b"\x00" in data:
        raise ValueError("a binary file (it holds NUL bytes)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"not UTF-8 text (byte 0x{data[e.start]:02x} at offset {e.start})") from None


def read_scenario_file(filename: str) -> str:
    """The text of a scenario file (:func:`read_text_bounded` to
    :data:`MAX_SCENARIO_BYTES`); :class:`ConfigError` naming the file otherwise."""
    try:
        return read_text_bounded(filename, MAX_SCENARIO_BYTES)
    except ValueError as e:
        raise ConfigError(f"{filename}: {e}; a scenario is a YAML text file in UTF-8 of a few KB") from None


def _preparse(text: str, where: str = "scenario") -> tuple[list, dict]:
    """``(plugins, raw data)`` of a scenario's YAML text, read before the typed load (tags of
    not-yet-imported plug-ins are read as plain mappings, the tag kept under ``_TAG_KEY``). Also refuses, naming what
    and where, what the typed loader would not say clearly: an empty file, a top level that
    is not a mapping, a duplicate key (the typed loader keeps the last silently), a tag on
    anything but a section, and an unknown top-level field (with the allowed ones)."""
    import yaml

    class _Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                if not isinstance(key, (str, int, float, bool)) and key is not None:
                    raise ConfigError(
                        f"{where}: line {key_node.start_mark.line + 1}: a mapping key must be a name, "
                        f"not a {type(key).__name__}"
                    )
                if key in seen:
                    raise ConfigError(
                        f"{where}: duplicate key {key!r} at line {key_node.start_mark.line + 1} "
                        f"(first at line {seen[key] + 1}); each key may appear once"
                    )
                seen[key] = key_node.start_mark.line
            return super().construct_mapping(node, deep=deep)

    def _untagged(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            mapping = loader.construct_mapping(node, deep=True)
            mapping[_TAG_KEY] = suffix
            return mapping
        raise ConfigError(
            f"{where}: line {node.start_mark.line + 1}: YAML tag {node.tag!r} on a value; tags only "
            "name the type of a section (e.g. !RigidBodyConfig, !MekfConfig {...}) and never run code"
        )

    def _int_or_text(loader, node):
        try:
            return yaml.SafeLoader.construct_yaml_int(loader, node)
        except ValueError:  # more digits than Python converts: kept as text, refused by its field's check
            return loader.construct_scalar(node)

    _Loader.add_constructor("tag:yaml.org,2002:int", _int_or_text)
    _Loader.add_multi_constructor("!", _untagged)
    _Loader.add_multi_constructor("tag:", _untagged)
    data = load_yaml_text(text, where, _Loader)
    if data is None:
        raise ConfigError(
            f"{where}: the scenario is empty; it needs at least a name and a plant, sensors and "
            "estimators (see drake_att/scenarios/*.yaml)"
        )
    if not isinstance(data, dict):
        raise ConfigError(
            f"{where}: got a YAML {type(data).__name__} at the top level; a scenario is a mapping "
            f"of the fields {[f.name for f in dataclasses.fields(Scenario)]}"
        )
    tag = data.pop(_TAG_KEY, None)
    if tag is not None:
        raise ConfigError(f"{where}: the top level has the tag !{tag}; a scenario's top level has no tag")
    unknown = [k for k in data if k not in {f.name for f in dataclasses.fields(Scenario)}]
    if unknown:
        raise ConfigError(
            f"{where}: unknown field(s) {_short(unknown)}; allowed: {[f.name for f in dataclasses.fields(Scenario)]}"
        )
    plugins = data.get("plugins", [])
    if plugins is None:
        plugins = []
    if not isinstance(plugins, list) or not all(isinstance(p, str) for p in plugins):
        fail("plugins", plugins, "must be a list of module names, e.g. [my_package.my_filter]")
    return plugins, data


def _short(value, limit: int = 200) -> str:
    text = validation.describe(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _item_path(section: str, i: int, item) -> str:
    name = item.get("name") if isinstance(item, dict) else None
    return f"{section}[{i}]" + (f" ({name[:60]})" if isinstance(name, str) else "")


def _check_raw(value, typ, path: str) -> None:
    """Check the raw YAML ``value`` against the schema type ``typ`` before the typed load, so
    a wrong type or an unknown key anywhere is refused naming its field path (the typed
    loader names neither): numbers where numbers belong, lists where lists belong, sections
    (mappings) with known fields and, for a choice of section types, a registered tag."""
    origin, args = typing.get_origin(typ), typing.get_args(typ)
    if typ is typing.Any:
        return
    if origin is Union:
        return _check_raw_choice(value, args, path)
    if isinstance(typ, type) and dataclasses.is_dataclass(typ):
        return _check_raw_section(value, typ, path)
    if origin in (list, List):
        return _check_raw_list(value, args, path)
    if origin in (dict, Dict):
        return _check_raw_mapping(value, args, path)
    _check_raw_scalar(value, typ, path)


def _check_raw_mapping(value, args: tuple, path: str) -> None:
    """``value`` a mapping of text keys to ``args[1]`` values (e.g. ``logging.periods_s``)."""
    if not isinstance(value, dict) or _TAG_KEY in value:
        fail(path, value, 'must be a mapping of names to values, e.g. {"st1/*": 10.0} (write {} for none)')
    for key, v in value.items():
        if not isinstance(key, str):
            fail(path, key, "keys must be text (a signal key or pattern)")
        _check_raw(v, args[1] if len(args) == 2 else typing.Any, f"{path}[{key[:60]!r}]")


def _check_raw_choice(value, args: tuple, path: str) -> None:
    """``value`` of ``Union[args]``: None where the union is Optional, else the one option or
    the section type its tag names (untagged: the first option)."""
    options = [a for a in args if a is not type(None)]
    if value is None:
        if type(None) in args:
            return
        fail(path, value, "must be set")
    if len(options) == 1:
        return _check_raw(value, options[0], path)
    if not isinstance(value, dict):
        fail(
            path,
            value,
            f"must be a section (a mapping), tagged with its type: one of {['!' + o.__name__ for o in options]}",
        )
    tag = value.get(_TAG_KEY)
    if tag is None:
        return _check_raw(value, options[0], path)
    chosen = next((o for o in options if o.__name__ == tag), None)
    if chosen is None:
        fail(
            path,
            "!" + tag,
            f"allowed types: {['!' + o.__name__ for o in options]} (a plug-in's type needs its module in plugins:)",
        )
    return _check_raw(value, chosen, path)


def _check_raw_section(value, typ: type, path: str) -> None:
    """``value`` a mapping of fields of the dataclass ``typ``, each checked against its type."""
    if not isinstance(value, dict):
        fail(path, value, f"must be a section (a mapping of the fields of {typ.__name__})")
    names = {f.name: f for f in dataclasses.fields(typ)}
    unknown = [k for k in value if k != _TAG_KEY and k not in names]
    if unknown:
        raise ConfigError(f"{path}: unknown field(s) {_short(unknown)}; allowed: {list(names)}")
    hints = _field_types(typ)
    for key, v in value.items():
        if key != _TAG_KEY:
            _check_raw(v, hints[key], f"{path}.{key}" if path else key)


def _check_raw_list(value, args: tuple, path: str) -> None:
    """``value`` a list of ``args[0]``; in ``sensors`` and ``estimators`` a tagged item is
    checked against the registered type its tag names."""
    if not isinstance(value, list):
        fail(path, value, "must be a list" + (" (write [] for none)" if value is None else ""))
    (item_type,) = args or (typing.Any,)
    section = path in ("sensors", "estimators")
    options = (
        [a for a in typing.get_args(item_type) if isinstance(a, type)]
        if typing.get_origin(item_type) is Union
        else [item_type]
    )
    for i, item in enumerate(value):
        tag = item.get(_TAG_KEY) if section and isinstance(item, dict) else None
        if tag is None:
            _check_raw(item, item_type, _item_path(path, i, item) if section else f"{path}[{i}]")
            continue
        chosen = next((o for o in options if o.__name__ == tag), None)
        if chosen is None:
            raise ConfigError(
                f"{path}[{i}]: unknown type !{tag[:100]}; registered: "
                f"{['!' + o.__name__ for o in options]} (a plug-in module must be listed in "
                "plugins:)"
            )
        name = item.get("name")
        _check_raw(item, chosen, f"{path}[{i}] ({name[:60] if isinstance(name, str) else '?'}, !{tag})")


def _check_raw_scalar(value, typ, path: str) -> None:
    """``value`` of a leaf type: float (a number, or text that reads as a finite one), int,
    bool, str or a numpy matrix (a list of rows of numbers); other types are not checked."""
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            fail(path, value, "must be a number")
        if isinstance(value, str):
            try:
                number = float(value)
            except ValueError:
                fail(path, value, "must be a number")
            if not np.isfinite(number):
                fail(path, value, "must be a finite number")
    elif typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            fail(path, value, "must be an integer")
    elif typ is bool:
        if not isinstance(value, bool):
            fail(path, value, "must be true or false")
    elif typ is str:
        if not isinstance(value, str):
            fail(path, value, "must be a text string")
    elif typ is np.ndarray:
        rows = value if isinstance(value, list) else None
        flat = [x for r in rows for x in (r if isinstance(r, list) else [r])] if rows is not None else None
        if flat is None or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in flat):
            fail(path, value, "must be a list of rows of numbers")


def _field_types(typ) -> dict:
    """Each field's type as the typed loader reads it: ``field.type`` (which
    :func:`~drake_att.scenarios.registry.refresh_schema` points at the registered plug-ins),
    resolved from the annotations where it is still a string."""
    fields = dataclasses.fields(typ)
    if not any(isinstance(f.type, str) for f in fields):
        return {f.name: f.type for f in fields}
    try:
        hints = typing.get_type_hints(typ)
    except Exception:  # noqa: BLE001 - unresolvable hints: check nothing below this section
        hints = {}
    return {f.name: hints.get(f.name, typing.Any) if isinstance(f.type, str) else f.type for f in fields}


def prepare_schema(plugins=(), *, new_plugins: bool = True) -> None:
    """Import the built-in and the given plug-ins and point the scenario schema at them
    (``new_plugins=False``: only plug-ins already imported are accepted)."""
    from drake_att.scenarios import registry

    try:
        registry.load_plugins(plugins, new_modules=new_plugins)
    except registry.PluginError as e:
        raise ConfigError(str(e)) from e
    registry.refresh_schema(Scenario)


def load_scenario(text: str | None = None, filename: str | None = None, *, new_plugins: bool = True) -> Scenario:
    """Load and validate a scenario from YAML text or a file (importing its ``plugins``).

    Every failure is a :class:`ConfigError` naming the file (when given), the field path, the
    value and what is allowed: reading (size, encoding), YAML syntax, tags, alias expansion,
    types, unknown fields, the schema and every value's range.

    Args:
        new_plugins: False for a configuration the user did not write (a result folder's
            ``config.yaml``): its ``plugins`` must already be imported; a module that is not
            is refused rather than imported (importing runs its code).
    """
    if filename is not None:
        text = read_scenario_file(filename)
    elif not isinstance(text, str):
        raise ConfigError(f"scenario: got {type(text).__name__}; expected YAML text or a file name")
    elif len(text.encode("utf-8", "surrogatepass")) > MAX_SCENARIO_BYTES:
        raise ConfigError(f"scenario: larger than {MAX_SCENARIO_BYTES} bytes; a scenario is a few KB")
    where = filename or "scenario"
    plugins, raw = _preparse(text, where)
    prepare_schema(plugins, new_plugins=new_plugins)
    prefix = f"{filename}: " if filename else ""
    try:
        _check_raw(raw, Scenario, "")
    except ConfigError as e:
        raise ConfigError(prefix + str(e)) from None
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except Exception as e:  # noqa: BLE001 - Drake reports schema errors as RuntimeError, YAML ones as YAMLError
        raise ConfigError(f"{prefix or 'scenario: '}{_one_line(e)}") from None
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

    scenario = copy.deepcopy(scenario)  # never modify the caller's scenario, even on error
    for item in overrides:
        if not isinstance(item, str) or "=" not in item:
            raise ConfigError(f"--set {_short(item)}: expected PATH=VALUE, e.g. --set duration_s=600")
        path, raw = item.split("=", 1)
        path = path.strip()
        if not path or any(not part for part in path.split(".")):
            raise ConfigError(
                f"--set {_short(item)}: expected PATH=VALUE with a dotted field path, e.g. sensors.st1.period_s=0.5"
            )
        value = load_yaml_text(raw, f"--set {_short(path, 100)}")
        _set_path(scenario, path, value)
    # Round-trip through the typed loader so types and unknown keys are checked again.
    try:
        text = dump_scenario(scenario)
    except Exception as e:  # noqa: BLE001 - any failure of the dump is a value the schema does not take
        raise ConfigError(f"--set: the overridden scenario is not valid: {_one_line(e)}") from None
    return load_scenario(text=text)


def _set_path(root, path: str, value) -> None:
    """Set the field at dotted ``path`` of ``root`` to ``value`` (a mapping given for a
    section sets that section's fields one by one, each checked like its own ``--set``)."""
    parts = path.split(".")
    target = root
    for depth, key in enumerate(parts[:-1]):
        target = _child(target, key, ".".join(parts[: depth + 1]))
    last = parts[-1]
    if isinstance(target, list):
        idx = _list_index(target, last, path)
        current = target[idx]
    else:
        if not dataclasses.is_dataclass(target) or last not in {f.name for f in dataclasses.fields(target)}:
            allowed = [f.name for f in dataclasses.fields(target)] if dataclasses.is_dataclass(target) else []
            raise ConfigError(f"--set {path}: unknown field {_short(last, 100)}; allowed: {allowed}")
        current = getattr(target, last)
    if dataclasses.is_dataclass(current) and isinstance(value, dict):
        for key, v in value.items():
            if not isinstance(key, str):
                raise ConfigError(
                    f"--set {path}: got the key {_short(key, 60)}; keys are field names of {type(current).__name__}"
                )
            _set_path(root, f"{path}.{key}", v)
        return
    if value is None:
        if isinstance(target, list) or not _optional(_field_types(type(target))[last]):
            raise ConfigError(
                f"--set {path}: got null; this field must have a value (null only unsets optional fields such as orbit)"
            )
        setattr(target, last, None)
        return
    _refuse_section(current, value, path)
    if isinstance(target, list):
        target[idx] = value
    else:
        setattr(target, last, _coerce(value, current, path))


def _optional(typ) -> bool:
    return typing.get_origin(typ) is Union and type(None) in typing.get_args(typ)


def _refuse_section(current, value, path):
    """A section (a config dataclass: the plant, a sensor, an estimator) is not replaced by
    a scalar or a list from ``--set``: set its fields."""
    if dataclasses.is_dataclass(current) and not isinstance(value, dict):
        fields = [f.name for f in dataclasses.fields(current)]
        raise ConfigError(
            f"--set {path}: got {_short(value)}; {path} is a section ({type(current).__name__}): set "
            f"one of its fields, e.g. --set {path}.{fields[-1]}=...; fields: {fields}"
        )


def _child(obj, key, path):
    if isinstance(obj, list):
        return obj[_list_index(obj, key, path)]
    if dataclasses.is_dataclass(obj) and key in {f.name for f in dataclasses.fields(obj)}:
        child = getattr(obj, key)
        if child is None:
            raise ConfigError(f"--set {path}: field is not set (None) in this scenario")
        return child
    allowed = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else []
    raise ConfigError(f"--set {path}: unknown field {_short(key, 100)}; allowed: {allowed}")


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
    raise ConfigError(f"--set {path}: no element named {_short(key, 100)}; names: {names}")


def _coerce(value, current, path):
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"--set {path}: got {_short(value)}; expected true/false")
        return value
    if isinstance(current, float) or (current is None and isinstance(value, (int, float))):
        if isinstance(value, str):  # YAML 1.1 reads "1e-10" (no dot) as a string
            try:
                value = float(value)
            except ValueError:
                pass
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ConfigError(f"--set {path}: got {_short(value)}; expected a number")
        return float(value)
    if isinstance(current, int):
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"--set {path}: got {_short(value)}; expected an integer")
        return value
    if isinstance(current, np.ndarray):
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"--set {path}: got {_short(value)}; expected a numeric matrix") from None
        if current.ndim == 2 and arr.size:
            if arr.size % current.shape[1]:
                raise ConfigError(f"--set {path}: got {_short(value)}; expected rows of {current.shape[1]} numbers")
            return arr.reshape((-1,) + current.shape[1:])
        return arr
    if isinstance(current, list) and not isinstance(value, list):
        raise ConfigError(f"--set {path}: got {_short(value)}; expected a list")
    if isinstance(current, list):
        numeric = bool(current) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in current)
        for i, v in enumerate(value):
            if numeric and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ConfigError(f"--set {path}[{i}]: got {_short(v)}; expected a number")
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in value]
    if isinstance(current, str) and not isinstance(value, str):
        raise ConfigError(f"--set {path}: got {_short(value)}; expected a text string")
    return value


# --------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------
zeros3 = _zeros3  # default factory for 3-vectors in plug-in configs


# The one validation family: plug-ins use these (each raises ConfigError naming the field
# path, the value and what is allowed).
def fail(path: str, value, allowed: str) -> NoReturn:
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


def check_listed_once(path: str, field: str, names, what: str = "sensor") -> None:
    """Each name of the list field ``field`` at most once (a repeated name would wire the same
    input twice: Drake refuses a second port of that name deep in the build)."""
    if len(set(names)) != len(names):
        fail(f"{path}.{field}", list(names), f"each {what} may be listed once")


def require_orbit_epoch(path: str, value, scenario: "Scenario", purpose: str) -> None:
    """An orbit with an epoch (``!TleOrbitConfig`` or ``!KeplerOrbitConfig``) whose run lies within the
    span of the offline Sun/Moon ephemeris (and so of the IGRF coefficients): what a sensor needs that
    reads the orbit, the Sun, the Moon or the magnetic field. ``path``/``value`` name the field asking,
    ``purpose`` says why (e.g. "to place the Sun")."""
    if not isinstance(scenario.orbit, (TleOrbitConfig, KeplerOrbitConfig)):
        kind = "no orbit" if scenario.orbit is None else "a circular orbit without an epoch"
        fail(
            path,
            value,
            f"needs an orbit with an epoch {purpose}; the scenario has {kind} "
            "(use orbit: !TleOrbitConfig or !KeplerOrbitConfig)",
        )
    _check_ephemeris_span(scenario)


def _check_ephemeris_span(scenario: "Scenario") -> None:
    """The run (epoch to epoch + duration) inside the span the offline Sun/Moon ephemeris covers."""
    from drake_att.ephemeris import supported_jd_range
    from drake_att.orbit_propagators import OrbitError, julian_date_utc, parse_epoch_utc

    try:
        start = julian_date_utc(parse_epoch_utc(scenario.orbit.epoch_utc))  # type: ignore[union-attr]
    except OrbitError as e:
        raise ConfigError(str(e)) from None
    lo, hi = supported_jd_range()
    end = start + (scenario.duration_s + 60.0) / 86400.0
    if start < lo or end > hi:
        raise ConfigError(
            f"orbit.epoch_utc: got {scenario.orbit.epoch_utc!r} with duration_s {scenario.duration_s:g}: the run "  # type: ignore[union-attr]
            f"must lie within the Sun/Moon ephemeris' span, Julian dates [{lo:.1f}, {hi:.1f}] UTC (from the start "
            "of leap seconds to the expiry of astropy's bundled leap-second table)"
        )


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
    _validate_identity(s)
    check_positive("duration_s", s.duration_s)
    validation.check_seed("seed", s.seed, ConfigError)
    _validate_simulation(s.simulation)
    if s.orbit is not None:
        _validate_orbit(s.orbit)
    _validate_plant(s)
    _validate_components(s)
    _validate_scoring(s)
    _validate_logging(s.logging)
    from drake_att.scenarios.ranges import check_ranges

    check_ranges(s)  # every numeric field within its physical range (docs/config_reference.md)


def _validate_identity(s: Scenario) -> None:
    """The scenario's name (a short one-line text) and description (a text)."""
    if not isinstance(s.name, str) or not s.name.strip() or len(s.name) > 200 or any(ord(c) < 32 for c in s.name):
        fail("name", s.name, "must be a non-empty text of at most 200 characters without control characters")
    if not isinstance(s.description, str):
        fail("description", s.description, "must be a text string")


def _validate_simulation(sim) -> None:
    """The simulator's step size, accuracy and a Drake integration scheme name."""
    check_positive("simulation.max_step_size_s", sim.max_step_size_s)
    check_positive("simulation.accuracy", sim.accuracy)
    schemes = {
        "runge_kutta2",
        "runge_kutta3",
        "runge_kutta5",
        "bogacki_shampine3",
        "radau1",
        "radau3",
        "explicit_euler",
        "semi_explicit_euler",
        "implicit_euler",
        "velocity_implicit_euler",
    }
    if sim.integration_scheme not in schemes:
        fail("simulation.integration_scheme", sim.integration_scheme, f"allowed: {sorted(schemes)}")


def _validate_plant(s: Scenario) -> None:
    """The truth model's fields, per plant kind."""
    p = s.plant
    if isinstance(p, RigidBodyConfig):
        _validate_rigid_body(p)
        if p.attitude_control is not None:
            _validate_attitude_control(p.attitude_control, s.orbit)
    elif isinstance(p, PrescribedRateConfig):
        for f in (
            "initial_attitude_rpy_deg",
            "constant_deg_per_s",
            "amplitude_deg_per_s",
            "frequency_rad_per_s",
            "phase_deg",
        ):
            check_vector(f"plant.{f}", getattr(p, f), 3)
    elif isinstance(p, PrescribedRpyConfig):
        _validate_prescribed_rpy(p, s.orbit)


def _validate_rigid_body(p: RigidBodyConfig) -> None:
    """A physical inertia (3 principal moments or a 3x3 matrix) and the 3-vectors."""
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


def _validate_attitude_control(c: OrbitPointingControlConfig, orbit) -> None:
    """The controller's gains, period and noise, and an orbit for its reference frame."""
    path = "plant.attitude_control"
    if orbit is None:
        fail(path, "set", "follows the orbit frame: the scenario needs an orbit section")
    check_vector(f"{path}.offset_rpy_deg", c.offset_rpy_deg, 3)
    check_positive(f"{path}.natural_frequency_rad_per_s", c.natural_frequency_rad_per_s)
    check_positive(f"{path}.damping_ratio", c.damping_ratio)
    check_positive(f"{path}.period_s", c.period_s)
    check_nonnegative(f"{path}.torque_noise_N_m", c.torque_noise_N_m)
    if c.natural_frequency_rad_per_s * c.period_s > 0.5:
        fail(
            f"{path}.natural_frequency_rad_per_s",
            c.natural_frequency_rad_per_s,
            f"times period_s ({c.period_s:g} s) must be <= 0.5 for the sampled loop to follow the continuous design",
        )


def _validate_orbit(o) -> None:
    """The orbit section: the circular orbit's numbers, or the propagator built from the TLE or
    the elements (which checks the TLE's form, the epoch and the elements)."""
    if isinstance(o, OrbitConfig):
        check_positive("orbit.altitude_km", o.altitude_km)
        for f in ("inclination_deg", "raan_deg", "arg_latitude0_deg"):
            check_finite(f"orbit.{f}", getattr(o, f))
        return
    if isinstance(o, KeplerOrbitConfig):
        for f in ("semi_major_axis_km", "eccentricity", "inclination_deg", "raan_deg", "arg_perigee_deg"):
            check_finite(f"orbit.{f}", getattr(o, f))
        check_finite("orbit.mean_anomaly_deg", o.mean_anomaly_deg)
        if not 0.0 <= o.eccentricity < 1.0:
            raise ConfigError(f"orbit.eccentricity: got {o.eccentricity!r}; must be in [0, 1) (a closed orbit)")
        perigee_km = o.semi_major_axis_km * (1.0 - o.eccentricity)
        if perigee_km <= 6478.137:
            raise ConfigError(
                f"orbit.semi_major_axis_km: got {o.semi_major_axis_km!r} with eccentricity {o.eccentricity!r}: perigee "
                f"radius {perigee_km:.1f} km; must be above 6478.137 km (100 km altitude)"
            )
    from drake_att.orbit_propagators import OrbitError

    try:
        from drake_att.scenarios.build_context import orbit_model

        orbit_model(o)
    except OrbitError as e:
        raise ConfigError(str(e)) from None


def _validate_prescribed_rpy(p: PrescribedRpyConfig, orbit) -> None:
    """No orbit (the table is relative to the inertial frame) and a strictly increasing time
    table with one roll/pitch/yaw row per time."""
    if orbit is not None:
        fail(
            "orbit",
            "set",
            "a PrescribedRpyConfig truth is roll/pitch/yaw relative to the inertial frame, while "
            "with an orbit every estimate starts relative to the orbit frame; remove orbit (or use another "
            "plant)",
        )
    if len(p.times_s) < 2 or np.ndim(p.rpy_deg) != 2 or len(p.rpy_deg) != len(p.times_s):
        fail("plant.times_s", p.times_s, "need >= 2 breakpoints and one rpy_deg row per time")
    for i in range(1, len(p.times_s)):
        if not p.times_s[i] > p.times_s[i - 1]:
            fail("plant.times_s", p.times_s, "must be strictly increasing")
    for i, row in enumerate(p.rpy_deg):
        check_vector(f"plant.rpy_deg[{i}]", row, 3)


def _validate_components(s: Scenario) -> None:
    """Sensors, then estimators, in list order: unique names and each plug-in's own checks,
    which see only the components listed before."""
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


def _validate_scoring(s: Scenario) -> None:
    """The scoring window starts inside the run; a positive convergence threshold."""
    check_nonnegative("scoring.score_from_s", s.scoring.score_from_s)
    if s.scoring.score_from_s >= s.duration_s:
        fail(
            "scoring.score_from_s",
            s.scoring.score_from_s,
            f"must be < duration_s ({s.duration_s}); a shorter run needs its scoring window moved too, "
            f"e.g. --set scoring.score_from_s={s.duration_s / 2:g}",
        )
    check_positive("scoring.convergence_threshold_deg", s.scoring.convergence_threshold_deg)


def _validate_logging(c: LoggingConfig) -> None:
    """The logging policy's shape: a positive period, positive per-signal periods keyed by
    non-empty keys or patterns, non-empty exclusion patterns. Which signals they match, and
    that each period is a multiple of its signal's own, is checked when the diagram is built
    (:func:`drake_att.scenarios.logging_policy.plan_logging`: the signals are the plug-ins')."""
    if c.period_s is not None:
        check_positive("logging.period_s", c.period_s)
    if not isinstance(c.periods_s, dict):
        fail("logging.periods_s", c.periods_s, "must be a mapping of signal keys or patterns to periods (s)")
    for key, period in c.periods_s.items():
        if not isinstance(key, str) or not key.strip():
            fail("logging.periods_s", key, "keys must be non-empty signal keys or patterns, e.g. 'st1/*'")
        check_positive(f"logging.periods_s[{key!r}]", period)
    if not isinstance(c.exclude, list):
        fail("logging.exclude", c.exclude, "must be a list of signal keys or patterns, e.g. ['*/innovations']")
    for i, pattern in enumerate(c.exclude):
        if not isinstance(pattern, str) or not pattern.strip():
            fail(f"logging.exclude[{i}]", pattern, "must be a non-empty signal key or pattern, e.g. '*/innovations'")
