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
import math
import typing
from dataclasses import dataclass, field
from typing import List, Optional, Union

import numpy as np
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed


class ConfigError(ValueError):
    """A scenario value is invalid; the message names the field and the value."""


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


@dataclass
class GyroConfig:
    """Farrenkopf gyro delivering the mean rate over each ``period_s``.

    ``sample_rate_hz`` documents the internal sampling whose mean is delivered; the
    statistics of that mean are exact for any rate (see ``drake_att.noise``).
    ``misalignment_urad`` holds the six off-diagonal terms ``[xy, xz, yx, yz, zx, zy]``.
    """

    name: str = "gyro"
    period_s: float = 1.0
    sample_rate_hz: float = 300.0
    arw_deg_per_rt_h: float = 0.0
    rrw_deg_per_h15: float = 0.0
    initial_bias_deg_per_h: List[float] = field(default_factory=_zeros3)
    initial_bias_sigma_deg_per_h: float = 0.0
    scale_factor_error_ppm: List[float] = field(default_factory=_zeros3)
    misalignment_urad: List[float] = field(default_factory=lambda: [0.0] * 6)


@dataclass
class StarTrackerConfig:
    """Star tracker (boresight = sensor +z).

    Mounting: ``mounting_paper_s3_angles_deg`` = ``[psi, phi, theta]`` of paper S3's
    eq. 7 when non-empty, else ``mounting_rpy_deg`` (roll/pitch/yaw of S in B).
    ``mode``: "quaternion" (attitude output) or "vectors" (``references_I`` directions).
    """

    name: str = "st1"
    period_s: float = 1.0
    mode: str = "quaternion"
    mounting_rpy_deg: List[float] = field(default_factory=_zeros3)
    mounting_paper_s3_angles_deg: List[float] = field(default_factory=list)  # [] = unused
    sigma_cross_boresight_arcsec: float = 0.0
    sigma_boresight_arcsec: float = 0.0
    references_I: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (m, 3)
    sigma_vector_urad: float = 0.0
    dropout_probability: float = 0.0
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (k, 2) [start, end]


@dataclass
class StarTrackerAverageConfig:
    """Virtual sensor: weighted quaternion average of quaternion-mode star trackers
    (paper S3's "centralized" scheme).  Its measurement covariance is derived from the
    trackers' noise, mountings and the weights (``drake_att.systems.fusion``)."""

    name: str = "st_avg"
    star_trackers: List[str] = field(default_factory=lambda: ["st1", "st2"])
    weights: List[float] = field(default_factory=lambda: [0.5, 0.5])


SensorConfig = Union[GyroConfig, StarTrackerConfig, StarTrackerAverageConfig]


@dataclass
class MekfConfig:
    """MEKF fed by one gyro and star trackers (names of sensors).

    The filter's gyro noise defaults to the gyro's configured ARW/RRW (``None``).
    """

    name: str = "mekf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_trackers: List[str] = field(default_factory=lambda: ["st1"])
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=_zeros3)
    initial_attitude_sigma_deg: float = 5.0
    initial_bias_sigma_deg_per_h: float = 20.0
    innovation_gate_chi2: Optional[float] = None


@dataclass
class EstimateFusionConfig:
    """Fusion of several estimators' outputs (paper S3's "decentralized" scheme):
    quaternion average of the attitudes, linear average of the biases.
    ``covariance_model``: "tracked" (exact cross-covariance of two MEKFs sharing a gyro),
    "conservative" (sum w_i P_i, valid for any correlation) or "independent"
    (sum w_i^2 P_i, ignores the shared gyro)."""

    name: str = "fusion"
    sources: List[str] = field(default_factory=lambda: ["mekf1", "mekf2"])
    weights: List[float] = field(default_factory=lambda: [0.5, 0.5])
    covariance_model: str = "conservative"


@dataclass
class MrpEkfConfig:
    """Paper S0's additive EKF on ``[MRP; gyro bias]`` with shadow-set switching, fed by a
    gyro and one vector-mode star tracker.  ``update_iterations`` > 1 gives an iterated
    EKF (beyond the paper).  Noise defaults (None) come from the gyro's config."""

    name: str = "ekf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=_zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_bias_sigma_deg_per_h: float = 1.0
    update_iterations: int = 1


@dataclass
class BootstrapPfConfig:
    """Paper S0's bootstrap (SIR) particle filter on ``[MRP; bias]`` in gyro mode.

    ``attitude_process_noise_deg_per_rt_h``: the ARW used to spread the particles'
    attitude (None: the gyro's ARW).  ``bias_roughening_deg_per_h_per_rt_s``: the
    beyond-the-paper bias-diffusion remedy (0 = the paper's frozen particle biases)."""

    name: str = "bootstrap_pf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    num_particles: int = 1000
    attitude_process_noise_deg_per_rt_h: Optional[float] = None
    bias_roughening_deg_per_h_per_rt_s: float = 0.0
    resample_threshold: float = 0.6666666666666666
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=_zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_bias_sigma_deg_per_h: float = 1.0


@dataclass
class EkpfConfig:
    """Paper S0's extended-Kalman particle filter (per-particle EKF proposal).
    ``proposal_iterations`` > 1 iterates each particle's EKF update (beyond the paper)."""

    name: str = "ekpf"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    num_particles: int = 1000
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    proposal_iterations: int = 1
    resample_threshold: float = 0.6666666666666666
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=_zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_bias_sigma_deg_per_h: float = 1.0


@dataclass
class GyrolessPfConfig:
    """Paper S0's gyroless bootstrap PF on ``[MRP; body rate]`` propagated with Euler's
    equations (known inertia and disturbance torque; empty lists = the plant's)."""

    name: str = "gyroless_pf"
    period_s: float = 1.0
    star_tracker: str = "st"
    num_particles: int = 1000
    inertia_kg_m2: List[float] = field(default_factory=list)
    disturbance_torque_N_m: List[float] = field(default_factory=list)
    rate_process_noise_deg_per_s_per_rt_s: float = 1e-5
    attitude_process_noise_deg_per_rt_h: float = 0.0
    num_substeps: int = 1
    resample_threshold: float = 0.6666666666666666
    initial_attitude_rpy_deg: List[float] = field(default_factory=_zeros3)
    initial_rate_deg_per_s: List[float] = field(default_factory=_zeros3)
    initial_attitude_sigma_deg: float = 1.0
    initial_rate_sigma_deg_per_s: float = 0.001


EstimatorConfig = Union[MekfConfig, EstimateFusionConfig, MrpEkfConfig, BootstrapPfConfig, EkpfConfig,
                        GyrolessPfConfig]


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
    duration_s: float = 100.0
    seed: int = 1
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    orbit: Optional[OrbitConfig] = None
    plant: PlantConfig = field(default_factory=RigidBodyConfig)
    sensors: List[SensorConfig] = field(default_factory=list)
    estimators: List[EstimatorConfig] = field(default_factory=list)
    scoring: ScoringConfig = field(default_factory=ScoringConfig)


# --------------------------------------------------------------------------------------
# Loading, dumping, overrides
# --------------------------------------------------------------------------------------
def load_scenario(text: str | None = None, filename: str | None = None) -> Scenario:
    """Load and validate a scenario from YAML text or a file."""
    try:
        if filename is not None:
            scenario = yaml_load_typed(schema=Scenario, filename=filename)
        else:
            scenario = yaml_load_typed(schema=Scenario, data=text)
    except RuntimeError as e:  # Drake reports schema errors as RuntimeError
        raise ConfigError(str(e)) from e
    validate(scenario)
    return scenario


def dump_scenario(scenario: Scenario) -> str:
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
            target[idx] = value
        else:
            if not dataclasses.is_dataclass(target) or last not in {f.name for f in dataclasses.fields(target)}:
                allowed = [f.name for f in dataclasses.fields(target)] if dataclasses.is_dataclass(target) else []
                raise ConfigError(f"--set {path}: unknown field {last!r}; allowed: {allowed}")
            current = getattr(target, last)
            setattr(target, last, _coerce(value, current, path))
    # Round-trip through the typed loader so types and unknown keys are checked again.
    return load_scenario(text=dump_scenario(scenario))


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
def _fail(path, value, allowed):
    raise ConfigError(f"{path}: got {value!r}; {allowed}")


def _finite(path, v):
    if not isinstance(v, (int, float)) or not math.isfinite(v):
        _fail(path, v, "must be a finite number")


def _positive(path, v):
    _finite(path, v)
    if v <= 0:
        _fail(path, v, "must be > 0")


def _nonneg(path, v):
    _finite(path, v)
    if v < 0:
        _fail(path, v, "must be >= 0")


def _vec(path, v, n):
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, list) or len(v) != n:
        _fail(path, v, f"must be a list of {n} numbers")
    for i, x in enumerate(v):
        _finite(f"{path}[{i}]", x)


def _validate_vector_filter(path, est, gyros, trackers):
    """Checks shared by the paper-S0 filters (one vector-mode tracker, optional gyro)."""
    if hasattr(est, "gyro"):
        if est.gyro not in gyros:
            _fail(f"{path}.gyro", est.gyro, f"unknown gyro; gyros: {sorted(gyros)}")
        if abs(gyros[est.gyro].period_s - est.period_s) > 1e-9:
            _fail(f"{path}.period_s", est.period_s, f"must equal the period of gyro {est.gyro!r} ({gyros[est.gyro].period_s} s)")
    st = trackers.get(est.star_tracker)
    if st is None or st.mode != "vectors":
        vec = sorted(n for n, t in trackers.items() if t.mode == "vectors")
        _fail(f"{path}.star_tracker", est.star_tracker, f"must name a vector-mode star tracker; have {vec}")
    ratio = est.period_s / st.period_s
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        _fail(f"{path}.period_s", est.period_s, f"must be a whole multiple of {st.name!r}'s period ({st.period_s} s)")
    for f in ("num_particles", "update_iterations", "proposal_iterations", "num_substeps"):
        if hasattr(est, f) and (not isinstance(getattr(est, f), int) or getattr(est, f) < 1):
            _fail(f"{path}.{f}", getattr(est, f), "must be an integer >= 1")
    if hasattr(est, "resample_threshold") and not 0 < est.resample_threshold <= 1:
        _fail(f"{path}.resample_threshold", est.resample_threshold, "must be in (0, 1] (fraction of N)")
    for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15", "attitude_process_noise_deg_per_rt_h"):
        if getattr(est, f, None) is not None:
            _nonneg(f"{path}.{f}", getattr(est, f))
    for f in ("bias_roughening_deg_per_h_per_rt_s", "rate_process_noise_deg_per_s_per_rt_s"):
        if hasattr(est, f):
            _nonneg(f"{path}.{f}", getattr(est, f))
    _vec(f"{path}.initial_attitude_rpy_deg", est.initial_attitude_rpy_deg, 3)
    _positive(f"{path}.initial_attitude_sigma_deg", est.initial_attitude_sigma_deg)
    if hasattr(est, "initial_bias_deg_per_h"):
        _vec(f"{path}.initial_bias_deg_per_h", est.initial_bias_deg_per_h, 3)
        _positive(f"{path}.initial_bias_sigma_deg_per_h", est.initial_bias_sigma_deg_per_h)
    if hasattr(est, "initial_rate_deg_per_s"):
        _vec(f"{path}.initial_rate_deg_per_s", est.initial_rate_deg_per_s, 3)
        _positive(f"{path}.initial_rate_sigma_deg_per_s", est.initial_rate_sigma_deg_per_s)
        for f, n in (("inertia_kg_m2", (0, 3, 9)), ("disturbance_torque_N_m", (0, 3))):
            if len(getattr(est, f)) not in n:
                _fail(f"{path}.{f}", getattr(est, f), f"must have one of {n} entries (empty = the plant's)")


def _weights(path, w, n):
    _vec(path, list(w), n)
    if any(x < 0 for x in w) or sum(w) <= 0:
        _fail(path, w, "weights must be >= 0 with a positive sum")


def validate(s: Scenario) -> None:
    """Check every value of a scenario; raise :class:`ConfigError` on the first bad one."""
    _positive("duration_s", s.duration_s)
    if not isinstance(s.seed, int) or s.seed < 0:
        _fail("seed", s.seed, "must be an integer >= 0")
    _positive("simulation.max_step_size_s", s.simulation.max_step_size_s)
    _positive("simulation.accuracy", s.simulation.accuracy)
    schemes = {"runge_kutta2", "runge_kutta3", "runge_kutta5", "bogacki_shampine3", "radau1", "radau3",
               "explicit_euler", "semi_explicit_euler", "implicit_euler", "velocity_implicit_euler"}
    if s.simulation.integration_scheme not in schemes:
        _fail("simulation.integration_scheme", s.simulation.integration_scheme, f"allowed: {sorted(schemes)}")
    if s.orbit is not None:
        _positive("orbit.altitude_km", s.orbit.altitude_km)
        for f in ("inclination_deg", "raan_deg", "arg_latitude0_deg"):
            _finite(f"orbit.{f}", getattr(s.orbit, f))
    p = s.plant
    if isinstance(p, RigidBodyConfig):
        if not isinstance(p.inertia_kg_m2, list) or len(p.inertia_kg_m2) not in (3, 9):
            _fail("plant.inertia_kg_m2", p.inertia_kg_m2, "must be 3 principal moments or 9 matrix entries")
        from drake_att.systems.plant import validate_inertia

        I = np.array(p.inertia_kg_m2, dtype=float)
        try:
            validate_inertia(I if I.size == 3 else I.reshape(3, 3), "plant.inertia_kg_m2")
        except ValueError as e:
            raise ConfigError(str(e)) from e
        _vec("plant.initial_attitude_rpy_deg", p.initial_attitude_rpy_deg, 3)
        _vec("plant.initial_rate_deg_per_s", p.initial_rate_deg_per_s, 3)
        _vec("plant.disturbance_torque_N_m", p.disturbance_torque_N_m, 3)
    elif isinstance(p, PrescribedRateConfig):
        for f in ("initial_attitude_rpy_deg", "constant_deg_per_s", "amplitude_deg_per_s",
                  "frequency_rad_per_s", "phase_deg"):
            _vec(f"plant.{f}", getattr(p, f), 3)
    elif isinstance(p, PrescribedRpyConfig):
        if len(p.times_s) < 2 or np.ndim(p.rpy_deg) != 2 or len(p.rpy_deg) != len(p.times_s):
            _fail("plant.times_s", p.times_s, "need >= 2 breakpoints and one rpy_deg row per time")
        for i in range(1, len(p.times_s)):
            if not p.times_s[i] > p.times_s[i - 1]:
                _fail("plant.times_s", p.times_s, "must be strictly increasing")
        for i, row in enumerate(p.rpy_deg):
            _vec(f"plant.rpy_deg[{i}]", row, 3)

    names = set()
    gyros, trackers, averages = {}, {}, {}
    for i, sensor in enumerate(s.sensors):
        path = f"sensors[{i}] ({getattr(sensor, 'name', '?')})"
        if not sensor.name or sensor.name in names:
            _fail(f"{path}.name", sensor.name, "must be a non-empty name unique among sensors")
        names.add(sensor.name)
        if isinstance(sensor, StarTrackerAverageConfig):
            if len(sensor.star_trackers) < 2:
                _fail(f"{path}.star_trackers", sensor.star_trackers, "needs at least 2 star trackers")
            for st in sensor.star_trackers:
                if st not in trackers or trackers[st].mode != "quaternion":
                    _fail(f"{path}.star_trackers", st,
                          f"must name a quaternion-mode star tracker listed before it; have {sorted(trackers)}")
            periods = {trackers[st].period_s for st in sensor.star_trackers}
            if len(periods) != 1:
                _fail(f"{path}.star_trackers", sensor.star_trackers, f"trackers must share one period; got {sorted(periods)}")
            _weights(f"{path}.weights", sensor.weights, len(sensor.star_trackers))
            averages[sensor.name] = sensor
            continue
        _positive(f"{path}.period_s", sensor.period_s)
        if isinstance(sensor, GyroConfig):
            gyros[sensor.name] = sensor
            _positive(f"{path}.sample_rate_hz", sensor.sample_rate_hz)
            _nonneg(f"{path}.arw_deg_per_rt_h", sensor.arw_deg_per_rt_h)
            _nonneg(f"{path}.rrw_deg_per_h15", sensor.rrw_deg_per_h15)
            _vec(f"{path}.initial_bias_deg_per_h", sensor.initial_bias_deg_per_h, 3)
            _nonneg(f"{path}.initial_bias_sigma_deg_per_h", sensor.initial_bias_sigma_deg_per_h)
            _vec(f"{path}.scale_factor_error_ppm", sensor.scale_factor_error_ppm, 3)
            _vec(f"{path}.misalignment_urad", sensor.misalignment_urad, 6)
        else:
            trackers[sensor.name] = sensor
            if sensor.mode not in ("quaternion", "vectors"):
                _fail(f"{path}.mode", sensor.mode, "allowed: 'quaternion', 'vectors'")
            _vec(f"{path}.mounting_rpy_deg", sensor.mounting_rpy_deg, 3)
            if sensor.mounting_paper_s3_angles_deg:
                _vec(f"{path}.mounting_paper_s3_angles_deg", sensor.mounting_paper_s3_angles_deg, 3)
            _nonneg(f"{path}.sigma_cross_boresight_arcsec", sensor.sigma_cross_boresight_arcsec)
            _nonneg(f"{path}.sigma_boresight_arcsec", sensor.sigma_boresight_arcsec)
            _nonneg(f"{path}.sigma_vector_urad", sensor.sigma_vector_urad)
            _finite(f"{path}.dropout_probability", sensor.dropout_probability)
            if not 0 <= sensor.dropout_probability < 1:
                _fail(f"{path}.dropout_probability", sensor.dropout_probability, "must be in [0, 1)")
            if sensor.mode == "vectors":
                if np.ndim(sensor.references_I) != 2 or len(sensor.references_I) < 1:
                    _fail(f"{path}.references_I", sensor.references_I, "vector mode needs >= 1 direction")
                for j, r in enumerate(sensor.references_I):
                    _vec(f"{path}.references_I[{j}]", r, 3)
                    if float(np.linalg.norm(r)) < 1e-9:
                        _fail(f"{path}.references_I[{j}]", r, "must be non-zero")
                if sensor.sigma_vector_urad <= 0:
                    _fail(f"{path}.sigma_vector_urad", sensor.sigma_vector_urad, "vector mode needs > 0")
            else:
                if sensor.sigma_cross_boresight_arcsec <= 0 or sensor.sigma_boresight_arcsec <= 0:
                    _fail(f"{path}.sigma_*_arcsec",
                          [sensor.sigma_cross_boresight_arcsec, sensor.sigma_boresight_arcsec],
                          "quaternion mode needs both sigmas > 0 (a filter cannot use a perfect sensor)")
            if np.size(sensor.outage_windows_s) and np.ndim(sensor.outage_windows_s) != 2:
                _fail(f"{path}.outage_windows_s", sensor.outage_windows_s, "must be a list of [start, end]")
            for j, w in enumerate(np.reshape(sensor.outage_windows_s, (-1, 2))):
                if len(w) != 2 or not w[1] > w[0]:
                    _fail(f"{path}.outage_windows_s[{j}]", w, "must be [start, end] with end > start")

    est_names = set()
    for i, est in enumerate(s.estimators):
        path = f"estimators[{i}] ({getattr(est, 'name', '?')})"
        if not est.name or est.name in est_names or est.name in names:
            _fail(f"{path}.name", est.name, "must be non-empty and unique among sensors and estimators")
        if isinstance(est, EstimateFusionConfig):
            if len(est.sources) < 2:
                _fail(f"{path}.sources", est.sources, "needs at least 2 estimators")
            for src in est.sources:
                if src not in est_names:
                    _fail(f"{path}.sources", src, f"must name an estimator listed before it; have {sorted(est_names)}")
            _weights(f"{path}.weights", est.weights, len(est.sources))
            if est.covariance_model not in ("tracked", "conservative", "independent"):
                _fail(f"{path}.covariance_model", est.covariance_model,
                      "allowed: 'tracked', 'conservative', 'independent'")
            est_names.add(est.name)
            continue
        est_names.add(est.name)
        _positive(f"{path}.period_s", est.period_s)
        if isinstance(est, MekfConfig):
            if est.gyro not in gyros:
                _fail(f"{path}.gyro", est.gyro, f"unknown gyro; gyros: {sorted(gyros)}")
            g = gyros[est.gyro]
            if abs(g.period_s - est.period_s) > 1e-9:
                _fail(f"{path}.period_s", est.period_s,
                      f"must equal the period of gyro {g.name!r} ({g.period_s} s): the gyro delivers the mean rate over one filter step")
            if not est.star_trackers:
                _fail(f"{path}.star_trackers", est.star_trackers, "needs at least one star tracker")
            for st in est.star_trackers:
                if st not in trackers and st not in averages:
                    _fail(f"{path}.star_trackers", st,
                          f"unknown star tracker; star trackers: {sorted(trackers) + sorted(averages)}")
                period = trackers[st].period_s if st in trackers else trackers[averages[st].star_trackers[0]].period_s
                ratio = est.period_s / period
                if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                    _fail(f"{path}.period_s", est.period_s,
                          f"must be a whole multiple of star tracker {st!r}'s period ({period} s)")
            for f in ("arw_deg_per_rt_h", "rrw_deg_per_h15"):
                v = getattr(est, f)
                if v is not None:
                    _nonneg(f"{path}.{f}", v)
            _vec(f"{path}.initial_attitude_rpy_deg", est.initial_attitude_rpy_deg, 3)
            _vec(f"{path}.initial_bias_deg_per_h", est.initial_bias_deg_per_h, 3)
            _positive(f"{path}.initial_attitude_sigma_deg", est.initial_attitude_sigma_deg)
            _positive(f"{path}.initial_bias_sigma_deg_per_h", est.initial_bias_sigma_deg_per_h)
            if est.innovation_gate_chi2 is not None:
                _positive(f"{path}.innovation_gate_chi2", est.innovation_gate_chi2)
        if isinstance(est, (MrpEkfConfig, BootstrapPfConfig, EkpfConfig, GyrolessPfConfig)):
            _validate_vector_filter(path, est, gyros, trackers)
    _nonneg("scoring.score_from_s", s.scoring.score_from_s)
    if s.scoring.score_from_s >= s.duration_s:
        _fail("scoring.score_from_s", s.scoring.score_from_s, f"must be < duration_s ({s.duration_s})")
    _positive("scoring.convergence_threshold_deg", s.scoring.convergence_threshold_deg)
