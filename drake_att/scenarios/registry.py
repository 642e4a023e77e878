"""The plug-in registry: every estimator and every sensor is one module that registers itself.

A plug-in module holds a config dataclass (its class name is the YAML tag, e.g.
``!MekfConfig``; it must have a ``name`` field), a build function and, optionally, a
validation function, registered with one decorator::

    from drake_att.scenarios.registry import register_estimator

    @dataclass
    class MyFilterConfig:
        name: str = "my_filter"
        ...

    def validate_my_filter(path, config, checks):  # checks: ValidationContext
        ...                                          # raise ConfigError naming path.field

    @register_estimator(MyFilterConfig, second_quantity=SecondQuantity.GYRO_BIAS,
                        validate=validate_my_filter, parameters=("gain",))
    def build_my_filter(ctx, config):                # ctx: drake_att.scenarios.build_context.BuildContext
        return EstimatorSetup(core, initial_state, config.period_s, gyro=..., vector_sensors=(...,))

An estimator's build returns an :class:`~drake_att.systems.estimator_system.EstimatorSetup` (the
builder adds the one estimator system and wires it) or, for an estimator that is not a
filter core (e.g. a fusion of estimators), a system it added and wired itself.

**Context parameters.** ``parameters`` names the config fields a run may change without a
new diagram (tunings, initial estimates, noise levels): for such a change the builder
calls the build function again on the changed config and puts the result in the run's
Context (:meth:`EstimatorSystem.set_filter`); sensors say how with ``configure``. Any
other field is structural (ports, periods, particle counts, sensor lists): changing it
needs a new diagram, and ``ScenarioDiagram.create_context`` says so.

Sensors register the same way (:func:`register_sensor`) and also say what they output
(:class:`SensorOutput`: gyro samples, attitude quaternions or vector observations, which
port, which period), what the filter should assume about them (``quaternion_model``) and
what the builder logs for them (``logged_ports``).

The scenario schema's ``sensors`` and ``estimators`` lists accept exactly the registered
config types (:func:`refresh_schema`); nothing central grows. The library's own plug-ins
live in :mod:`drake_att.estimators` and :mod:`drake_att.sensors`; a scenario's
``plugins: [module.name, ...]`` are imported by the loader before it reads the lists, so a
user's estimator runs from the CLI, the notebooks and Monte Carlo without editing the
library. Plug-ins import this module and :mod:`drake_att.scenarios.build_context`, never
the scenario builder.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing
from dataclasses import dataclass, field
from typing import Callable

ESTIMATOR, SENSOR = "estimator", "sensor"
BUILTIN_PLUGIN_PACKAGES = ("drake_att.sensors", "drake_att.estimators")


class PluginError(ValueError):
    """A plug-in could not be registered or imported (the message names it)."""


@dataclass(frozen=True)
class SensorOutput:
    """What a sensor delivers to estimators.

    Attributes:
        kind: "gyro" (``[t, valid, w_meas_B]``), "quaternion" (``[t, valid, q_IS_meas]``),
            "vectors" (abstract :class:`~drake_att.contract.VectorObservations`) or "camera"
            (abstract :class:`~drake_att.contract.CameraCentroids`).
        port: the sensor system's output port name.
        period_s: sample period (s).
    """

    kind: str
    port: str
    period_s: float


@dataclass(frozen=True)
class Plugin:
    """One registered estimator or sensor."""

    kind: str
    config_type: type
    build: Callable
    validate: Callable | None = None
    module: str = ""
    # Estimators only: a SecondQuantity, or (config, checks) -> SecondQuantity.
    second_quantity: object = None
    # Sensors only:
    output: Callable | None = None  # (config, sensor_configs: dict) -> SensorOutput
    quaternion_model: Callable | None = None  # (ctx, config) -> QuaternionSensorModel
    logged_ports: Callable | None = None  # (config) -> [(port, period_s or None: the output's), ...]
    configure: Callable | None = None  # (ctx, config, system, system_context) -> None
    # Config fields a context may change without a new diagram (see the module docstring).
    parameters: tuple = ()
    extra: dict = field(default_factory=dict)

    @property
    def tag(self) -> str:
        return self.config_type.__name__


_PLUGINS: dict[str, dict[str, Plugin]] = {ESTIMATOR: {}, SENSOR: {}}


def _register(kind, config_type, build, **kwargs) -> None:
    if not (isinstance(config_type, type) and dataclasses.is_dataclass(config_type)):
        raise PluginError(f"{kind} plug-in {build.__name__!r}: config_type must be a dataclass; got {config_type!r}")
    if "name" not in {f.name for f in dataclasses.fields(config_type)}:
        raise PluginError(f"{kind} config {config_type.__name__}: needs a 'name' field (names the system)")
    _resolve_field_types(config_type, kind)
    for f in dataclasses.fields(config_type):
        optional = typing.get_origin(f.type) is typing.Union and type(None) in typing.get_args(f.type)
        if optional and f.default is not None and f.default is not dataclasses.MISSING:
            # The YAML dump omits a None, and the load then restores the default: a None that
            # is not the default would silently become the default on every round trip
            # (overrides, saved configs, Monte Carlo workers).
            raise PluginError(
                f"{kind} config {config_type.__name__}.{f.name}: an Optional field must default to "
                f"None (got {f.default!r}); a None set by a user would not survive a YAML round trip"
            )
    names = {f.name for f in dataclasses.fields(config_type)}
    bad = [p for p in kwargs.get("parameters", ()) if p not in names]
    if bad:
        raise PluginError(f"{kind} config {config_type.__name__}: parameters {bad} are not fields of the config")
    tag = config_type.__name__
    for other_kind, plugins in _PLUGINS.items():
        existing = plugins.get(tag)
        if existing is not None and (existing.config_type is not config_type or other_kind != kind):
            raise PluginError(
                f"{kind} config {tag} (module {build.__module__}): the tag {tag!r} is already "
                f"registered by {existing.module} as a {other_kind}; rename the config class"
            )
    _PLUGINS[kind][tag] = Plugin(kind, config_type, build, module=build.__module__, **kwargs)


def _resolve_field_types(config_type: type, kind: str, seen=None) -> None:
    """Drake's YAML loader reads each dataclass field's ``type``: resolve postponed (string)
    annotations (``from __future__ import annotations`` in a plug-in module) into real types,
    for the config and every dataclass nested in it (e.g. a ``Union`` of mounting types)."""
    seen = set() if seen is None else seen
    if config_type in seen:
        return
    seen.add(config_type)
    try:
        hints = typing.get_type_hints(config_type)
    except Exception as e:
        raise PluginError(f"{kind} config {config_type.__name__}: cannot resolve its field types: {e}") from e
    for f in dataclasses.fields(config_type):
        f.type = hints.get(f.name, f.type)
        stack = [f.type]
        while stack:
            t = stack.pop()
            if isinstance(t, type) and dataclasses.is_dataclass(t):
                _resolve_field_types(t, kind, seen)
            stack.extend(typing.get_args(t))


def register_estimator(config_type: type, *, second_quantity, validate: Callable | None = None, parameters=()):
    """Decorator registering ``build(ctx, config) -> EstimatorSetup | system`` for ``config_type``.

    Args:
        second_quantity: what the estimator's second 3-vector is
            (:class:`~drake_att.contract.SecondQuantity`), or ``(config, checks) ->
            SecondQuantity`` when it depends on the config (e.g. a fusion of estimators).
        validate: ``(path, config, checks) -> None`` raising ``ConfigError``; ``checks`` is a
            :class:`~drake_att.scenarios.config.ValidationContext`.
        parameters: config fields a context may change (build must return an
            ``EstimatorSetup`` for them to apply).
    """

    def decorate(build):
        _register(
            ESTIMATOR,
            config_type,
            build,
            validate=validate,
            second_quantity=second_quantity,
            parameters=tuple(parameters),
        )
        return build

    return decorate


def register_sensor(
    config_type: type,
    *,
    output: Callable,
    validate: Callable | None = None,
    quaternion_model: Callable | None = None,
    logged_ports: Callable | None = None,
    parameters=(),
    configure: Callable | None = None,
):
    """Decorator registering a sensor's ``build(ctx, config) -> system``.

    Args:
        output: ``(config, sensor_configs) -> SensorOutput``.
        validate: ``(path, config, checks) -> None``.
        quaternion_model: for "quaternion" outputs, ``(ctx, config) -> QuaternionSensorModel``
            (what a filter assumes about the sensor: mounting and noise covariance).
        logged_ports: ``(config) -> [(port, period_s), ...]`` logged by the builder
            (``period_s`` None: the sensor's output period, its ``SensorOutput.period_s``).
        parameters: config fields a context may change; ``configure(ctx, config, system,
            system_context)`` writes them (and anything derived from other sensors) into
            the system's context. Called for every sensor with a ``configure`` whenever a
            context changes any parameter, so derived values (e.g. an average's
            covariance) follow the sensors they derive from.
    """
    if parameters and configure is None:
        raise PluginError(
            f"sensor config {config_type.__name__}: parameters {list(parameters)} need a configure function"
        )

    def decorate(build):
        _register(
            SENSOR,
            config_type,
            build,
            validate=validate,
            output=output,
            quaternion_model=quaternion_model,
            logged_ports=logged_ports,
            parameters=tuple(parameters),
            configure=configure,
        )
        return build

    return decorate


def ensure_builtin_plugins() -> None:
    """Import the library's own plug-in packages (idempotent)."""
    for package in BUILTIN_PLUGIN_PACKAGES:
        importlib.import_module(package)


def load_plugins(module_names, *, new_modules: bool = True) -> None:
    """Import the built-in plug-ins and ``module_names`` (a scenario's ``plugins``).

    Importing a module runs its code, so a plug-in is imported only from a place the user
    chose (:func:`plugin_origin_problem`: the current folder, a ``PYTHONPATH`` folder or the
    installed packages), and with ``new_modules=False`` (a configuration the user did not
    write: a result folder read by ``score`` or ``--resume``) only if it is imported already.
    """
    import sys

    ensure_builtin_plugins()
    for i, name in enumerate(module_names or ()):
        if (
            not isinstance(name, str)
            or not name.strip()
            or len(name) > 200
            or not all(part.isidentifier() for part in name.split("."))
        ):
            raise PluginError(f"plugins[{i}]: got {name!r:.200}; expected a module name such as 'my_package.my_filter'")
        if name in sys.modules:
            continue
        if not new_modules:
            raise PluginError(
                f"plugins[{i}]: {name!r} is not imported; a configuration from a result folder names "
                "code that importing would run - pass --allow-plugins if you trust that folder and "
                "the module"
            )
        problem = plugin_origin_problem(name)
        if problem:
            raise PluginError(f"plugins[{i}]: {name!r}: {problem}")
        try:
            importlib.import_module(name)
        except Exception as e:  # report any import failure as a config error naming the module
            raise PluginError(
                f"plugins[{i}]: cannot import {name!r}: {type(e).__name__}: {str(e)[:300]} "
                "(is its folder on PYTHONPATH?)"
            ) from e


def _trusted_roots() -> list[str]:
    """Folders plug-ins may come from: the current folder, ``PYTHONPATH``'s folders and the
    installed packages (the interpreter's prefixes and site folders)."""
    import os
    import site
    import sys
    import sysconfig

    roots: list[str | None] = [os.getcwd()]
    roots += [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    roots += [sys.prefix, sys.base_prefix, sys.exec_prefix]
    roots += [sysconfig.get_paths().get(k) for k in ("purelib", "platlib", "stdlib")]
    try:
        roots += site.getsitepackages() + [site.getusersitepackages()]
    except AttributeError:  # a virtualenv's old site module
        pass
    return [os.path.realpath(r) for r in roots if r]


def plugin_origin_problem(name: str) -> str | None:
    """Why module ``name`` may not be imported as a plug-in (None: it may): it must be found
    (without running it) in :func:`_trusted_roots`, never only through another folder that
    happens to be on ``sys.path``."""
    import importlib.util
    import os

    try:
        spec = importlib.util.find_spec(name.split(".")[0])
    except (ImportError, ValueError) as e:
        return f"cannot be found ({e})"
    if spec is None:
        return "no such module (is its folder the current folder or on PYTHONPATH?)"
    places = [spec.origin] if spec.origin and spec.origin not in ("built-in", "frozen") else []
    places += list(spec.submodule_search_locations or [])
    if not places:
        return None  # a built-in or frozen module
    roots = _trusted_roots()
    for place in places:
        real = os.path.realpath(place)
        if not any(real == r or real.startswith(r.rstrip(os.sep) + os.sep) for r in roots):
            return (
                f"found in {os.path.dirname(real)}, which is neither the current folder, a PYTHONPATH folder "
                "nor the installed packages; plug-ins are imported only from places you chose"
            )
    return None


def plugins(kind: str) -> dict[str, Plugin]:
    """Registered plug-ins of ``kind`` ("estimator" or "sensor"), by tag."""
    ensure_builtin_plugins()
    return dict(_PLUGINS[kind])


def plugin_for(config) -> Plugin:
    """The plug-in registered for ``type(config)``."""
    tag = type(config).__name__
    for kind in (ESTIMATOR, SENSOR):
        p = _PLUGINS[kind].get(tag)
        if p is not None and p.config_type is type(config):
            return p
    raise PluginError(f"{getattr(config, 'name', tag)}: no plug-in is registered for config type {tag}")


def union_of(kind: str):
    """``typing.Union`` of the registered config types of ``kind`` (in registration order)."""
    types = tuple(p.config_type for p in plugins(kind).values())
    return typing.Union[types] if len(types) > 1 else types[0]


def refresh_schema(scenario_type: type) -> None:
    """Point ``scenario_type``'s ``sensors``/``estimators`` list fields at the registered types.

    Drake's YAML loader reads each dataclass field's ``type``; updating it after plug-ins
    are imported is what lets a plug-in's tag appear in a scenario.
    """
    fields = {f.name: f for f in dataclasses.fields(scenario_type)}
    # The item types are known only at run time (the registered plug-ins).
    fields["sensors"].type = typing.List[union_of(SENSOR)]  # type: ignore[misc]
    fields["estimators"].type = typing.List[union_of(ESTIMATOR)]  # type: ignore[misc]
