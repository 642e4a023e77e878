"""Turn a :class:`~drake_att.scenarios.config.Scenario` into a Drake diagram and run it.

``ScenarioDiagram(scenario)`` builds the diagram once (Python systems are not garbage
collected in pydrake 1.51, so build once per process and reseed per run);
``ScenarioDiagram.simulate(seed)`` runs it and returns a :class:`RunLog` with every
logged signal as numpy arrays.

**Sweeps on one diagram.** ``simulate(seed, overrides=[...], estimators=[...])`` runs the
same diagram with other values of its context parameters — the fields each plug-in
registers as ``parameters`` (filter tunings, initial estimates, sensor noise levels), the
plant's initial attitude and rate, the duration, scoring and integrator settings — and/or
with only some estimators switched on. Overrides that would change the diagram's
structure (a period, a particle count, a sensor list) are refused with a message naming
the field. The run's log carries the scenario actually used.

Sensors and estimators are plug-ins (:mod:`drake_att.scenarios.registry`): the builder
calls each config's registered build function with a
:class:`~drake_att.scenarios.build_context.BuildContext`, logs what each sensor plug-in
names and every estimator's contract ports. Extending means writing a plug-in module,
not editing this file.

One job, config to diagram to ``RunLog``: building, logging, simulating and splitting the logs.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (
    Adder,
    AddRandomInputs,
    ConstantVectorSource,
    LogVectorOutput,
    VectorLogSink,
    ZeroOrderHold,
)

from drake_att import rotations as rot
from drake_att.contract import SecondQuantity
from drake_att.progress import Progress
from drake_att.scenarios import config as cfg
from drake_att.scenarios import logging_policy
from drake_att.scenarios.build_context import BuildContext, attitude_from_rpy_deg, make_orbit  # noqa: F401
from drake_att.scenarios.registry import plugin_for
from drake_att.scenarios.selection import fused_sources, with_estimators
from drake_att.systems.attitude_control import OrbitPointingController, PdAttitudeLaw, orbit_frame_rate_I
from drake_att.systems.estimator_system import EstimatorSetup, EstimatorSystem
from drake_att.systems.plant import PrescribedAttitudeMotion, RigidBodyAttitudePlant
from drake_att.systems.randomness import RANDOM_SOURCE_SAMPLING_INTERVAL_S
from drake_att.units import DEG
from drake_att.validation import check_seed


class NonFiniteRunError(RuntimeError):
    """The truth or an estimate went non-finite during a run (the message names the signal
    and the time)."""


def _first_non_finite(x) -> int | None:
    """Index of the first sample (row) with a non-finite number, or None."""
    bad = np.flatnonzero(~np.all(np.isfinite(x), axis=1))
    return int(bad[0]) if bad.size else None


def _check_truth_finite(signals: dict, keys, scenario_name: str, seed: int) -> None:
    for key in keys:
        t, x = signals[key]
        i = _first_non_finite(x)
        if i is not None:
            raise NonFiniteRunError(
                f"{scenario_name} seed {seed}: the truth signal {key!r} is not finite from t = {t[i]:g} s "
                f"(last finite value {x[i - 1].tolist() if i else 'none'}); the plant's initial conditions, inertia, "
                "torque or integrator step are out of range for this run (see the scenario's plant and simulation "
                "settings). Nothing was scored."
            )


def _check_estimates_finite(signals: dict, run_scenario, scenario_name: str, seed: int, second_names: dict) -> None:
    """Every estimator's attitude, second vector and covariance must stay finite (its status
    may carry a NaN NIS by design): a core that produces NaN is a failed run, not a result."""
    for e in run_scenario.estimators:
        for port in ("q_IB_hat", second_names.get(e.name), "covariance"):
            key = f"{e.name}/{port}"
            if port is None or key not in signals:
                continue
            t, x = signals[key]
            i = _first_non_finite(x)
            if i is not None:
                raise NonFiniteRunError(
                    f"{scenario_name} seed {seed}: the estimate {key!r} is not finite from t = {t[i]:g} s (its core "
                    "produced NaN or inf: a bug or a diverged filter, see its tuning and inputs). Nothing was scored."
                )


def _same(a, b) -> bool:
    """Equal config values (dataclasses, lists, numpy arrays, numbers)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))
    if dataclasses.is_dataclass(a) or dataclasses.is_dataclass(b):
        return type(a) is type(b) and not _changed_fields(a, b)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


def _changed_fields(a, b) -> list[str]:
    """Names of the top-level fields of dataclass ``a`` whose value differs in ``b``."""
    if type(a) is not type(b):
        return ["(type)"]
    return [f.name for f in dataclasses.fields(a) if not _same(getattr(a, f.name), getattr(b, f.name))]


def run_metadata(scenario_diagram, seed: int, wall_time_s: float, signal_keys, scenario=None) -> dict:
    """What scoring a run needs, as plain JSON-able data (:attr:`RunLog.metadata`).

    Keys: ``schema`` (:attr:`RunLog.METADATA_SCHEMA`), ``scenario`` (name), ``seed``,
    ``wall_time_s``, ``signals`` (every logged key, in order), ``truth``
    (``{"attitude": key of q_IB, "rate": key of w_IB_B}``) and ``estimators`` (in the
    scenario's order): name -> ``second_kind`` ("gyro_bias" or "body_rate"), ``true_bias``
    (key of the gyro bias it is scored against, or None; a fusion: its first source's gyro)
    and ``signals`` (``{"attitude", "second", "covariance", "status"}`` -> logged key, plus
    ``"innovations"`` for estimators with measurement inputs, whose names are then listed
    in ``inputs``: per input ``[time of its last update, NIS, dimension]``, and
    ``"sample_handling"``: the counters named by
    :data:`~drake_att.systems.estimator_step.SAMPLE_HANDLING_NAMES`; see
    :class:`~drake_att.systems.estimator_system.EstimatorSystem`).
    The second-quantity kind is the contract's (:attr:`~drake_att.contract.SecondQuantity.kind`).
    """
    sd = scenario_diagram
    scenario = sd.scenario if scenario is None else scenario
    configs = {e.name: e for e in scenario.estimators}
    truth = sd.truth.get_name()
    meta = {
        "schema": RunLog.METADATA_SCHEMA,
        "scenario": scenario.name,
        "seed": int(seed),
        "wall_time_s": float(wall_time_s),
        "signals": list(signal_keys),
        "truth": {"attitude": f"{truth}/q_IB", "rate": f"{truth}/w_IB_B"},
        "estimators": {},
    }
    for c in scenario.estimators:
        system = sd.estimators[c.name]
        quantity = SecondQuantity.from_port_name(system.second_output_name)
        second = quantity.port_name
        name = system.get_name()
        meta["estimators"][c.name] = {
            "second_kind": quantity.kind,
            "true_bias": _true_bias_key(sd.sensors, sd.estimators, configs, c),
            "signals": {
                "attitude": f"{name}/q_IB_hat",
                "second": f"{name}/{second}",
                "covariance": f"{name}/covariance",
                "status": f"{name}/status",
            },
        }
        if f"{name}/innovations" in signal_keys:
            meta["estimators"][c.name]["signals"]["innovations"] = f"{name}/innovations"
            meta["estimators"][c.name]["inputs"] = list(system.input_names)
        if f"{name}/sample_handling" in signal_keys:
            meta["estimators"][c.name]["signals"]["sample_handling"] = f"{name}/sample_handling"
    plan = getattr(sd, "logging_plan", None)
    if plan is not None:
        meta["logging"] = plan
    RunLog.check_metadata(meta)
    return meta


def _true_bias_key(sensors: dict, estimators: dict, configs: dict, c) -> str | None:
    """The logged key of the true gyro bias estimator config ``c`` is scored against (a
    fusion: its first source's gyro), or None (a body-rate estimator, or no gyro)."""
    quantity = SecondQuantity.from_port_name(estimators[c.name].second_output_name)
    gyro_config = c
    while fused_sources(gyro_config):
        gyro_config = configs[fused_sources(gyro_config)[0]]
    gyro = getattr(gyro_config, "gyro", None)
    return f"{sensors[gyro].get_name()}/bias_B" if quantity is SecondQuantity.GYRO_BIAS and gyro else None


@dataclass
class RunLog:
    """Everything logged in one run (numpy arrays; times in s, SI units).

    ``signals`` maps ``"<system>/<port>"`` to ``(times (n,), values (n, k))``.
    ``metadata`` (see :func:`run_metadata`) says which signals are the truth and how each
    estimator is scored, so a saved log can be re-scored without the diagram
    (:meth:`load`, ``drake-att score``).
    """

    METADATA_SCHEMA = 1

    scenario: cfg.Scenario
    seed: int
    wall_time_s: float
    signals: dict
    metadata: dict = field(default_factory=dict)

    def times(self, key):
        return self.signals[key][0]

    def values(self, key):
        return self.signals[key][1]

    def to_npz_dict(self) -> dict:
        """Arrays ``<system>__<port>__t`` / ``__x`` and ``metadata`` (a JSON string)."""
        import json

        out = {}
        for key, (t, v) in self.signals.items():
            k = key.replace("/", "__")
            out[f"{k}__t"] = t
            out[f"{k}__x"] = v
        if self.metadata:
            out["metadata"] = np.array(json.dumps(self.metadata))
        return out

    @staticmethod
    def check_metadata(meta) -> None:
        """Raise ValueError saying what is missing or inconsistent in ``meta``."""
        if not isinstance(meta, dict):
            raise ValueError(f"metadata: expected a JSON object, got {type(meta).__name__}")
        missing = [
            k for k in ("schema", "scenario", "seed", "wall_time_s", "signals", "truth", "estimators") if k not in meta
        ]
        if missing:
            raise ValueError(f"metadata: missing {missing}")
        if meta["schema"] != RunLog.METADATA_SCHEMA:
            raise ValueError(f"metadata: schema {meta['schema']!r}, this drake_att reads {RunLog.METADATA_SCHEMA}")
        for key, kind in (("signals", list), ("truth", dict), ("estimators", dict)):
            if not isinstance(meta[key], kind):
                raise ValueError(f"metadata: {key} must be a JSON {'array' if kind is list else 'object'}")
        if not isinstance(meta["seed"], int) or not isinstance(meta["wall_time_s"], (int, float)):
            raise ValueError("metadata: seed must be an integer and wall_time_s a number")
        if not all(isinstance(k, str) for k in meta["signals"]):
            raise ValueError("metadata: signals must be strings '<system>/<port>'")
        logged = set(meta["signals"])
        refs = [("truth.attitude", meta["truth"].get("attitude")), ("truth.rate", meta["truth"].get("rate"))]
        for name, e in meta["estimators"].items():
            if not isinstance(e, dict) or not isinstance(e.get("signals"), dict):
                raise ValueError(f"metadata: estimators.{name} must be an object with a 'signals' object")
            if e.get("second_kind") not in ("gyro_bias", "body_rate"):
                raise ValueError(
                    f"metadata: estimators.{name}.second_kind {e.get('second_kind')!r} is neither "
                    "'gyro_bias' nor 'body_rate'"
                )
            refs += [
                (f"estimators.{name}.signals.{k}", e["signals"].get(k))
                for k in ("attitude", "second", "covariance", "status")
                + tuple(k for k in ("innovations", "sample_handling") if k in e["signals"])
            ]
            if e.get("true_bias") is not None:
                refs.append((f"estimators.{name}.true_bias", e["true_bias"]))
        for where, key in refs:
            if not isinstance(key, str) or key not in logged:
                raise ValueError(f"metadata: {where} = {key!r} is not a logged signal")

    @classmethod
    def from_npz(cls, npz, scenario: cfg.Scenario) -> RunLog:
        """Rebuild a run from :meth:`to_npz_dict` arrays (e.g. ``np.load("log.npz")``) and
        its scenario; ValueError if the arrays lack metadata or do not match ``scenario``."""
        import json

        if "metadata" not in npz:
            raise ValueError(
                "no 'metadata' entry (a log written before runs carried their metadata?); "
                "re-run the scenario to score it"
            )
        try:
            meta = json.loads(str(npz["metadata"]))
        except ValueError as e:
            raise ValueError(f"metadata is not valid JSON: {e}") from e
        cls.check_metadata(meta)
        if meta["scenario"] != scenario.name:
            raise ValueError(f"the log is of scenario {meta['scenario']!r}, the configuration is {scenario.name!r}")
        names = [e.name for e in scenario.estimators]
        if list(meta["estimators"]) != names:
            raise ValueError(f"the log's estimators {list(meta['estimators'])} differ from the configuration's {names}")
        signals = {}
        for key in meta["signals"]:
            k = key.replace("/", "__")
            if f"{k}__t" not in npz or f"{k}__x" not in npz:
                raise ValueError(f"signal {key!r} is listed in the metadata but its arrays {k}__t / {k}__x are missing")
            signals[key] = (np.asarray(npz[f"{k}__t"]), np.asarray(npz[f"{k}__x"]))
        return cls(scenario, int(meta["seed"]), float(meta["wall_time_s"]), signals, meta)

    @classmethod
    def load(cls, path: str, scenario: cfg.Scenario | None = None) -> RunLog:
        """Load a saved run: ``path`` is a result folder or its ``log.npz``; ``scenario``
        defaults to the ``config.yaml`` next to the log."""
        import os

        npz_path = os.path.join(path, "log.npz") if os.path.isdir(path) else path
        import zipfile

        if scenario is None:
            scenario = cfg.load_scenario(filename=os.path.join(os.path.dirname(npz_path), "config.yaml"))
        if not zipfile.is_zipfile(npz_path):
            raise ValueError("not an .npz archive (as written by numpy.savez)")
        check_npz_arrays(npz_path)
        with np.load(npz_path, allow_pickle=False) as npz:
            return cls.from_npz(npz, scenario)


def check_npz_arrays(npz_path: str, available_bytes: float | None = None) -> int:
    """Check an ``.npz`` archive before reading any array, from the array headers alone: each
    member is a numpy array whose header claims no more data than the member holds (a forged
    header would make numpy allocate what it claims), and all of them together fit in half the
    memory available. Returns the bytes the arrays take; ValueError naming the member
    otherwise."""
    import zipfile

    from numpy.lib import format as npy

    from drake_att.scenarios.preflight import available_memory_bytes

    total = 0
    with zipfile.ZipFile(npz_path) as z:
        for info in z.infolist():
            with z.open(info) as f:
                try:
                    version = npy.read_magic(f)
                    reader = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
                    shape, _, dtype = reader(f, max_header_size=10000)
                except (ValueError, EOFError, TypeError) as e:
                    raise ValueError(f"{info.filename} is not a numpy array ({e})") from None
            claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if claimed > info.file_size:
                raise ValueError(
                    f"{info.filename} claims {claimed} bytes of data but holds {info.file_size}; the "
                    "file is damaged or forged"
                )
            total += claimed
    available = available_memory_bytes() if available_bytes is None else available_bytes
    if available and total > 0.5 * available:
        raise ValueError(
            f"its arrays take {total / 2**30:.1f} GiB, more than half of the {available / 2**30:.1f} GiB "
            "of memory available"
        )
    return total


def _listed(names) -> str:
    """Field names as a message lists them (``none`` for an empty list)."""
    return ", ".join(names) if names else "none"


def _add_attitude_control(ctx: BuildContext, p: cfg.RigidBodyConfig, disturbance_torque_B):
    """Add the orbit-pointing controller of ``p.attitude_control`` and an adder of its torque and
    the disturbance; returns the adder's output (the plant's torque)."""
    c = p.attitude_control
    assert c is not None and ctx.builder is not None
    I = np.asarray(p.inertia_kg_m2, dtype=float)
    law = PdAttitudeLaw(
        np.diag(I) if I.size == 3 else I.reshape(3, 3),
        c.natural_frequency_rad_per_s,
        c.damping_ratio,
        rot.rpy_to_quat(np.asarray(c.offset_rpy_deg) * DEG),
    )
    control = ctx.builder.AddSystem(OrbitPointingController(law, c.period_s, c.torque_noise_N_m))
    orbit = ctx.orbit_source()
    for port in ("q_IB", "w_IB_B"):
        ctx.builder.Connect(ctx.truth.GetOutputPort(port), control.GetInputPort(port))  # type: ignore[attr-defined]
    for port in ("r_I", "v_I", "q_IO"):
        ctx.builder.Connect(orbit.GetOutputPort(port), control.GetInputPort(port))
    adder = ctx.builder.AddNamedSystem("torque_sum", Adder(2, 3))
    ctx.builder.Connect(disturbance_torque_B, adder.get_input_port(0))
    ctx.builder.Connect(control.GetOutputPort("torque_B"), adder.get_input_port(1))
    return adder.get_output_port()


def initial_rate_B(scenario: cfg.Scenario, q_IB0) -> np.ndarray:
    """The rigid body's ``w_IB_B`` at t = 0 (rad/s): ``initial_rate_deg_per_s``, plus, under
    attitude control, the reference frame's rate (the orbit frame's, in the body frame)."""
    p = scenario.plant
    w = np.asarray(p.initial_rate_deg_per_s, dtype=float) * DEG  # type: ignore[union-attr]  # rigid body
    if isinstance(p, cfg.RigidBodyConfig) and p.attitude_control is not None:
        r, v = make_orbit(scenario).position_velocity_I(0.0)  # validated: an orbit
        w = w + rot.quat_to_rotmat(q_IB0).T @ orbit_frame_rate_I(r, v)
    return w


#: Sensor configs whose systems carry several realizations (a batch), and the estimator configs.
BATCH_SENSORS = ("GyroConfig", "StarTrackerConfig", "StarTrackerAverageConfig")
BATCH_ESTIMATORS = ("MekfConfig", "EstimateFusionConfig")


def batch_problem(scenario: cfg.Scenario) -> str | None:
    """Why ``scenario``'s runs cannot share one diagram as a batch (None: they can).

    A batch carries N runs on one truth: the truth must not depend on the seed (no attitude
    controller, whose torque noise is drawn per seed), and every sensor and estimator must
    carry N realizations: gyros, quaternion star trackers without exclusion, their averages,
    MEKFs on the compiled step (checked when the batch diagram is built) and their fusions."""
    if isinstance(scenario.plant, cfg.RigidBodyConfig) and scenario.plant.attitude_control is not None:
        return "its attitude controller drives the truth with torque noise drawn per seed (each run has its own truth)"
    for s in scenario.sensors:
        if type(s).__name__ not in BATCH_SENSORS:
            return f"sensor {s.name!r} is a {type(s).__name__} (a batch has {_listed(BATCH_SENSORS)} only)"
        if type(s).__name__ == "StarTrackerConfig" and (s.mode != "quaternion" or s.exclusion is not None):
            return f"star tracker {s.name!r} is not in quaternion mode without exclusion"
    for e in scenario.estimators:
        if type(e).__name__ not in BATCH_ESTIMATORS:
            return f"estimator {e.name!r} is a {type(e).__name__} (a batch has {_listed(BATCH_ESTIMATORS)} only)"
        if getattr(e, "monitor", ""):
            return f"estimator {e.name!r} reads its sensors through a monitor"
    return None


class ScenarioDiagram:
    """A scenario's diagram, built once; :meth:`simulate` runs it for any seed.

    With ``realizations`` N > 1 the diagram is a *batch*: one truth and, for each sensor and
    estimator, one system carrying N realizations (:func:`batch_problem` says when a scenario
    allows it); :meth:`simulate_batch` runs N seeds at once and returns the N runs a single
    diagram would give, bit for bit (each realization reads its seed's noise streams and runs
    the same per-sample code).

    Attributes:
        diagram: the Drake ``Diagram``.
        truth: the plant or prescribed-motion system.
        sensors, estimators: name -> system.
        loggers: ``"<system>/<port>"`` -> ``VectorLogSink``.
        realizations: the runs one simulation carries (1: a single run).
    """

    def __init__(self, scenario: cfg.Scenario, realizations: int = 1):
        cfg.validate(scenario)
        if not (isinstance(realizations, int) and realizations >= 1):
            raise ValueError(f"realizations: got {realizations!r}; must be an integer >= 1")
        if realizations > 1:
            problem = batch_problem(scenario)
            if problem:
                raise ValueError(
                    f"realizations: got {realizations}; {scenario.name!r} cannot run as a batch: {problem}"
                )
        self.realizations = realizations
        from drake_att.scenarios.preflight import DegenerateScenarioWarning, preflight_warnings

        for message in preflight_warnings(scenario):
            warnings.warn(message, DegenerateScenarioWarning, stacklevel=2)
        self.scenario = scenario
        builder = DiagramBuilder()
        p = scenario.plant
        truth: RigidBodyAttitudePlant | PrescribedAttitudeMotion
        if isinstance(p, cfg.RigidBodyConfig):
            I = np.asarray(p.inertia_kg_m2, dtype=float)
            truth = RigidBodyAttitudePlant(I if I.size == 3 else I.reshape(3, 3))
            builder.AddSystem(truth)
            torque_N_m = np.asarray(p.disturbance_torque_N_m, dtype=float)
            torque = builder.AddNamedSystem("disturbance_torque", ConstantVectorSource(torque_N_m))  # type: ignore[arg-type]  # pydrake stub
        elif isinstance(p, cfg.PrescribedRateConfig):
            truth = PrescribedAttitudeMotion.from_rate_profile(
                np.asarray(p.constant_deg_per_s) * DEG,
                np.asarray(p.amplitude_deg_per_s) * DEG,
                p.frequency_rad_per_s,
                np.asarray(p.phase_deg) * DEG,
                attitude_from_rpy_deg(scenario, p.initial_attitude_rpy_deg),
            )
            builder.AddSystem(truth)
        else:
            truth = PrescribedAttitudeMotion.from_rpy_breakpoints(p.times_s, np.asarray(p.rpy_deg) * DEG)
            builder.AddSystem(truth)
        self.truth = truth
        ctx = BuildContext(builder, scenario, truth, realizations=realizations)
        if isinstance(p, cfg.RigidBodyConfig):
            torque_B = torque.get_output_port()
            if p.attitude_control is not None:
                torque_B = _add_attitude_control(ctx, p, torque_B)
            builder.Connect(torque_B, truth.GetInputPort("torque_B"))
        for s in scenario.sensors:
            ctx.sensor_configs[s.name] = s
            ctx.sensors[s.name] = plugin_for(s).build(ctx, s)
        for e in scenario.estimators:
            ctx.estimator_configs[e.name] = e
            built = plugin_for(e).build(ctx, e)
            ctx.estimators[e.name] = ctx.add_estimator(e.name, built) if isinstance(built, EstimatorSetup) else built
        self.sensors, self.estimators = ctx.sensors, ctx.estimators
        # A batch's seeds: each sensor's seed words come from a source set per batch (the values
        # a single run's random source gives that sensor for each seed: _seed_uniforms).
        self._seed_sources: dict[str, ConstantVectorSource] = {}
        if realizations > 1:
            for name, system in self.sensors.items():
                if system.HasInputPort("seed_uniform"):
                    port = system.GetInputPort("seed_uniform")
                    seeds = ConstantVectorSource(np.zeros(port.size()))
                    builder.AddNamedSystem(f"{name}__batch_seeds", seeds)
                    builder.Connect(seeds.get_output_port(), port)
                    self._seed_sources[name] = seeds
        AddRandomInputs(RANDOM_SOURCE_SAMPLING_INTERVAL_S, builder)

        periods = [self.estimator_period(e.name) for e in scenario.estimators] + [
            ctx.sensor_output(s.name).period_s for s in scenario.sensors
        ]
        self.truth_log_period_s = min(periods) if periods else 1.0
        self.loggers: dict[str, VectorLogSink] = {}
        self._packed_estimators: dict[str, SecondQuantity] = {}
        candidates = self._loggable(scenario, ctx)
        # Logged once for all realizations (the truth's signals); the others carry one block each.
        self._shared_keys = {signal.key for signal, system, _ in candidates if system is self.truth}
        plan = logging_policy.plan_logging(
            scenario.logging,
            [signal for signal, _, _ in candidates],
            self._required_signals(scenario),
            self._alignments(scenario),
            scenario.duration_s,
        )
        # log key -> the logged period of a decimated signal: its samples are shifted back by
        # it after the run (they reach the logger one period after they were taken).
        self._held: dict[str, float] = {}
        for signal, system, port_name in candidates:
            if signal.key not in plan:
                continue
            period, n = plan[signal.key]
            port = system.GetOutputPort(port_name)
            if n == 1:
                self.loggers[signal.key] = LogVectorOutput(port, builder, signal.period_s)
                continue
            # Decimated: a hold samples the port between two of its own updates (half a
            # period after t_k = k P) and the logger records it at t_k + P.
            if signal.estimator:
                # An estimator's port just after its update at t_k: the estimate of t_k.
                source = port
            else:
                # The truth or a sensor's port: first held at its own instants (what the
                # full-rate logger records: the value before that instant's updates).
                own = builder.AddSystem(ZeroOrderHold(signal.period_s, port.size()))
                own.set_name(f"{signal.key.replace('/', '__')}__held")
                builder.Connect(port, own.get_input_port())
                source = own.get_output_port()
            hold = builder.AddSystem(ZeroOrderHold(period, port.size(), 0.5 * signal.period_s))
            hold.set_name(f"{signal.key.replace('/', '__')}__every_{n}")
            builder.Connect(source, hold.get_input_port())
            self.loggers[signal.key] = LogVectorOutput(hold.get_output_port(), builder, period)
            self._held[signal.key] = period
        self.logging_plan = logging_policy.describe_plan([signal for signal, _, _ in candidates], plan)
        self.diagram = builder.Build()
        self.diagram.set_name(scenario.name)

    def _loggable(self, scenario: cfg.Scenario, ctx: BuildContext) -> list:
        """``[(Signal, system, port name)]``: every signal the builder can log, in its order
        (the truth, each sensor's logged ports, each estimator's estimate, diagnostics and
        innovations); a packed estimate (``estimate_state``) is split after the run."""
        out = []

        def add(system, port_name, period, parts=None, estimator=False):
            key = f"{system.get_name()}/{port_name}"
            out.append(
                (logging_policy.Signal(key, tuple(parts or (key,)), float(period), estimator), system, port_name)
            )

        add(self.truth, "q_IB", self.truth_log_period_s)
        add(self.truth, "w_IB_B", self.truth_log_period_s)
        for s in scenario.sensors:
            logged = plugin_for(s).logged_ports
            for port, period in logged(s) if logged is not None else []:
                add(self.sensors[s.name], port, ctx.sensor_output(s.name).period_s if period is None else period)
        for e in scenario.estimators:
            system = self.estimators[e.name]
            name, period = system.get_name(), self.estimator_period(e.name)
            ports = SecondQuantity.from_port_name(system.second_output_name).estimate_ports()
            if system.HasOutputPort("estimate_state"):
                # One C++ state port instead of four Python ports; split after the run.
                add(system, "estimate_state", period, [f"{name}/{port}" for port, _ in ports], estimator=True)
                self._packed_estimators[e.name] = SecondQuantity.from_port_name(system.second_output_name)
            else:
                for port, _ in ports:
                    add(system, port, period, estimator=True)
            for port in ("diagnostics", "innovations", "sample_handling"):
                if system.HasOutputPort(port):
                    add(system, port, period, estimator=True)
        return out

    def _required_signals(self, scenario: cfg.Scenario) -> dict:
        """Part key -> what it is, for every signal scoring needs (never excluded)."""
        truth = self.truth.get_name()
        out = {f"{truth}/q_IB": "the truth attitude", f"{truth}/w_IB_B": "the truth rate"}
        configs = {e.name: e for e in scenario.estimators}
        for e in scenario.estimators:
            system = self.estimators[e.name]
            for port, _ in SecondQuantity.from_port_name(system.second_output_name).estimate_ports():
                out[f"{system.get_name()}/{port}"] = f"the estimate of {e.name!r}"
            bias = _true_bias_key(self.sensors, self.estimators, configs, e)
            if bias is not None:
                out[bias] = f"the true gyro bias {e.name!r} is scored against"
        return out

    def _alignments(self, scenario: cfg.Scenario) -> list:
        """Each estimate and the signals it is scored against at its own times."""
        truth = self.truth.get_name()
        configs = {e.name: e for e in scenario.estimators}
        out = []
        for e in scenario.estimators:
            system = self.estimators[e.name]
            quantity = SecondQuantity.from_port_name(system.second_output_name)
            refs = [(f"{truth}/q_IB", "the truth attitude")]
            if quantity is SecondQuantity.BODY_RATE:
                refs.append((f"{truth}/w_IB_B", "the truth rate"))
            bias = _true_bias_key(self.sensors, self.estimators, configs, e)
            if bias is not None:
                refs.append((bias, "the true gyro bias"))
            out.append(logging_policy.Alignment(e.name, f"{system.get_name()}/q_IB_hat", tuple(refs)))
        return out

    def estimator_period(self, name: str) -> float:
        return self.estimators[name].period_s

    def initial_q_IB(self, scenario: cfg.Scenario | None = None) -> np.ndarray:
        scenario = self.scenario if scenario is None else scenario
        p = scenario.plant
        if isinstance(p, cfg.PrescribedRpyConfig):
            return rot.rpy_to_quat(np.asarray(p.rpy_deg[0]) * DEG)
        return attitude_from_rpy_deg(scenario, p.initial_attitude_rpy_deg)

    # -- per-run scenarios: context parameters instead of new diagrams ------------------------
    # Scenario fields that never touch the diagram, and plant fields set in the context.
    _RUN_FIELDS = ("name", "description", "duration_s", "seed", "simulation", "scoring")
    _PLANT_CONTEXT_FIELDS = ("initial_attitude_rpy_deg", "initial_rate_deg_per_s")

    def scenario_for(self, overrides=None, estimators=None) -> cfg.Scenario:
        """The scenario a run with ``overrides`` (``path=value`` strings, as ``--set``) and
        the selected ``estimators`` (names; None = all; [] = none, e.g. to time the sensors
        alone) uses on this diagram.

        Raises:
            ConfigError: an override fails validation, changes the diagram's structure
                (naming the field and the fields that may change), or the selection names
                an unknown estimator or leaves out the source of a selected fusion.
        """
        scenario = self.scenario
        if overrides:
            scenario = cfg.apply_overrides(scenario, overrides)
            structural = self._structural_changes(self._normalized_scenario(), scenario)
            if structural:
                raise cfg.ConfigError(
                    "a run on a built diagram may change only its parameters, and these overrides change its "
                    "structure: "
                    + "; ".join(structural)
                    + ". Build a new ScenarioDiagram for them: drake_att.scenarios.builder.diagram_for("
                    "drake_att.scenarios.config.apply_overrides(scenario, overrides))"
                )
        if estimators is not None:
            scenario = with_estimators(scenario, estimators)
        return scenario

    def _normalized_scenario(self) -> cfg.Scenario:
        """The diagram's scenario as the YAML round trip gives it (what overrides compare to)."""
        if not hasattr(self, "_normalized"):
            self._normalized = cfg.load_scenario(text=cfg.dump_scenario(self.scenario))
        return self._normalized

    def _structural_changes(self, base: cfg.Scenario, new: cfg.Scenario) -> list[str]:
        """Messages for every changed field of ``new`` that is not a context parameter."""
        out = []
        for f in dataclasses.fields(cfg.Scenario):
            a, b = getattr(base, f.name), getattr(new, f.name)
            if f.name in self._RUN_FIELDS or _same(a, b):
                continue
            if f.name == "plant":
                out += [
                    f"plant.{p} (structural; the plant's per-run fields: {_listed(self._PLANT_CONTEXT_FIELDS)})"
                    for p in _changed_fields(a, b)
                    if type(a) is not type(b) or p not in self._PLANT_CONTEXT_FIELDS
                ]
            elif f.name in ("sensors", "estimators"):
                if [x.name for x in a] != [x.name for x in b] or [type(x) for x in a] != [type(x) for x in b]:
                    out.append(f"{f.name} (structural: the list of {f.name}, their names or their types)")
                    continue
                for x, y in zip(a, b, strict=True):
                    allowed = plugin_for(x).parameters
                    out += [
                        f"{f.name}.{x.name}.{p} (structural; {x.name}'s per-run fields: {_listed(allowed)})"
                        for p in _changed_fields(x, y)
                        if p not in allowed
                    ]
            else:
                out.append(f"{f.name} (structural)")
        return out

    def _apply_parameters(self, context, scenario: cfg.Scenario) -> None:
        """Write ``scenario``'s sensor and estimator parameters into ``context``."""
        ctx = BuildContext(None, scenario, self.truth, sensors=dict(self.sensors), estimators=dict(self.estimators))
        for s in scenario.sensors:
            ctx.sensor_configs[s.name] = s
        for s in scenario.sensors:
            configure = plugin_for(s).configure
            if configure is not None:
                system = self.sensors[s.name]
                configure(ctx, s, system, system.GetMyMutableContextFromRoot(context))
        for e in scenario.estimators:
            ctx.estimator_configs[e.name] = e
            system = self.estimators[e.name]
            if isinstance(system, EstimatorSystem) and plugin_for(e).parameters:
                setup = plugin_for(e).build(ctx, e)
                system.set_filter(system.GetMyMutableContextFromRoot(context), setup)

    def create_context(self, seed: int, overrides=None, estimators=None):
        """A context randomized by ``seed`` with the initial conditions and parameters of
        :meth:`scenario_for` ``(overrides, estimators)`` (estimators not selected are
        switched off)."""
        return self._prepared_context(self.scenario_for(overrides, estimators), seed, overrides, estimators)

    def _prepared_context(self, scenario: cfg.Scenario, seed: int, overrides, estimators):
        context = self.diagram.CreateDefaultContext()
        # SetRandomContext resets every state and parameter to its default: set initial
        # conditions and parameters after it.
        self.diagram.SetRandomContext(context, RandomGenerator(check_seed("seed", seed)))
        if overrides:
            self._apply_parameters(context, scenario)
        if estimators is not None:
            for name, system in self.estimators.items():
                if isinstance(system, EstimatorSystem) and name not in estimators:
                    system.set_filter(system.GetMyMutableContextFromRoot(context), enabled=False)
        truth = self.truth
        truth_ctx = truth.GetMyMutableContextFromRoot(context)
        truth.SetDefaultParametersAndState(truth_ctx)
        p = scenario.plant
        q0 = self.initial_q_IB(scenario)
        if isinstance(truth, RigidBodyAttitudePlant) and isinstance(p, cfg.RigidBodyConfig):
            truth.SetInitialState(truth_ctx, q0, initial_rate_B(scenario, q0))
        elif isinstance(truth, PrescribedAttitudeMotion):
            truth.SetInitialState(truth_ctx, q0)
        return context

    def _seed_uniforms(self, seed: int) -> dict:
        """Sensor name -> the uniforms its ``seed_uniform`` port reads in a run of ``seed``
        (what ``SetRandomContext`` gives it; a batch sets these per realization)."""
        context = self.diagram.CreateDefaultContext()
        self.diagram.SetRandomContext(context, RandomGenerator(check_seed("seed", seed)))
        return {
            name: np.array(system.GetInputPort("seed_uniform").Eval(system.GetMyContextFromRoot(context)))
            for name, system in self.sensors.items()
            if system.HasInputPort("seed_uniform")
        }

    def simulate(self, seed: int | None = None, progress: bool = False, overrides=None, estimators=None) -> RunLog:
        """Run the scenario for ``seed`` (default: the scenario's) and return its logs.

        Args:
            overrides: ``path=value`` changes of context parameters for this run (see
                :meth:`scenario_for`); the diagram is reused.
            estimators: names of the estimators to run and log (default: all); the others
                are switched off for this run.
        """
        if self.realizations > 1:
            raise ValueError(f"{self.scenario.name}: a batch diagram runs seeds with simulate_batch()")
        scenario = self.scenario_for(overrides, estimators)
        seed = scenario.seed if seed is None else check_seed("seed", seed)
        context = self.create_context(seed, overrides, estimators)
        label = f"{scenario.name} seed {seed}"
        wall, logged = self._advance(context, scenario, progress, label)
        return self._run_log(scenario, seed, wall, self._signals(logged, scenario))

    def simulate_batch(self, seeds, overrides=None, estimators=None) -> list:
        """Run ``seeds`` (exactly :attr:`realizations` of them) in one simulation of this batch
        diagram: per seed, in order, the :class:`RunLog` :meth:`simulate` gives for it (the
        same arrays; ``wall_time_s`` is the batch's share), or the
        :class:`NonFiniteRunError` it raises."""
        seeds = [check_seed("seed", s) for s in seeds]
        if len(seeds) != self.realizations:
            raise ValueError(f"seeds: got {len(seeds)}; this batch diagram runs {self.realizations} at once")
        scenario = self.scenario_for(overrides, estimators)
        context = self._prepared_context(scenario, seeds[0], overrides, estimators)
        single = diagram_for(self.scenario)
        uniforms = [single._seed_uniforms(seed) for seed in seeds]
        for name, source in self._seed_sources.items():
            value = np.concatenate([u[name] for u in uniforms])
            source.get_mutable_source_value(source.GetMyMutableContextFromRoot(context)).set_value(value)  # type: ignore[arg-type]  # pydrake stub
        label = f"{scenario.name} seeds {seeds[0]}..{seeds[-1]}"
        wall, logged = self._advance(context, scenario, False, label)
        out: list = []
        N = self.realizations
        for i, seed in enumerate(seeds):
            mine = {}
            for key, (t, x) in logged.items():
                if key in self._shared_keys:
                    mine[key] = (t.copy(), x.copy())
                else:
                    width = x.shape[1] // N
                    mine[key] = (t.copy(), x[:, i * width : (i + 1) * width].copy())
            try:
                out.append(self._run_log(scenario, seed, wall / N, self._signals(mine, scenario)))
            except NonFiniteRunError as e:
                out.append(e)
        return out

    def _advance(self, context, scenario: cfg.Scenario, progress: bool, label: str) -> tuple:
        """Simulate ``context`` to the scenario's duration; ``(wall time (s), key -> (t, x))``
        of every logger (a decimated signal's samples shifted back to when they were taken;
        estimators switched off in ``scenario`` left out)."""
        simulator = Simulator(self.diagram, context)
        sc = scenario.simulation
        ApplySimulatorConfig(
            SimulatorConfig(
                integration_scheme=sc.integration_scheme,
                max_step_size=sc.max_step_size_s,
                accuracy=sc.accuracy,
                use_error_control=sc.use_error_control,
                target_realtime_rate=0.0,
                publish_every_time_step=False,
            ),
            simulator,
        )
        start = time.perf_counter()
        simulator.Initialize()
        duration = scenario.duration_s
        chunks = 20 if progress else 1
        bar = Progress(duration, label, start=start) if progress else None
        try:
            for k in range(1, chunks + 1):
                simulator.AdvanceTo(duration * k / chunks)
                if bar:
                    bar.update(duration * k / chunks)
        finally:
            if bar:
                bar.close()
        wall = time.perf_counter() - start
        logged = {}
        dropped = {self.estimators[e.name].get_name() for e in self.scenario.estimators} - {
            self.estimators[e.name].get_name() for e in scenario.estimators
        }
        for key, logger in self.loggers.items():
            if key.split("/", 1)[0] in dropped:
                continue
            log = logger.FindLog(context)
            t, x = log.sample_times().copy(), log.data().T.copy()
            if key in self._held:
                # A held sample reaches the logger one logged period after it was taken; the
                # first log (t = 0) precedes every sample.
                period = self._held[key]
                keep = t > 0.5 * period
                t, x = t[keep] - period, x[keep]
            logged[key] = (t, x)
        return wall, logged

    def _signals(self, logged: dict, scenario: cfg.Scenario) -> dict:
        """The run's signals from its loggers' ``(t, x)``: a packed estimate split into the
        contract's signals."""
        signals = {}
        for key, (t, x) in logged.items():
            name = key.split("/", 1)[0]
            if key.endswith("/estimate_state") and name in self._packed_estimators:
                for port, part in self._packed_estimators[name].estimate_ports():
                    signals[f"{name}/{port}"] = (t, x[:, part].copy())
            else:
                signals[key] = (t, x)
        return signals

    def _run_log(self, scenario: cfg.Scenario, seed: int, wall: float, signals: dict) -> RunLog:
        """The checked :class:`RunLog` (NonFiniteRunError if its truth or an estimate is not finite)."""
        truth = self.truth.get_name()
        _check_truth_finite(signals, (f"{truth}/q_IB", f"{truth}/w_IB_B"), scenario.name, seed)
        _check_estimates_finite(
            signals,
            scenario,
            scenario.name,
            seed,
            {name: getattr(system, "second_output_name", None) for name, system in self.estimators.items()},
        )
        return RunLog(scenario, seed, wall, signals, run_metadata(self, seed, wall, signals, scenario))


_DIAGRAMS: dict[str, ScenarioDiagram] = {}


def diagram_for(scenario: cfg.Scenario) -> ScenarioDiagram:
    """This process's diagram of ``scenario``, built on first use (pydrake 1.51 never frees a
    diagram: build once per process, then change contexts - seeds, :meth:`ScenarioDiagram.simulate`
    ``overrides`` and ``estimators``). Keyed by the scenario's YAML text."""
    key = cfg.dump_scenario(scenario)
    if key not in _DIAGRAMS:
        _DIAGRAMS[key] = ScenarioDiagram(cfg.load_scenario(text=key))
    return _DIAGRAMS[key]
