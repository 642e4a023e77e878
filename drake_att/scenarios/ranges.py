"""Physically plausible ranges of every numeric scenario field (DESIGN "The edges": every
numeric field has a documented physical range).

The specific validators (:func:`drake_att.scenarios.config.validate` and each plug-in's)
check types, signs and consistency; :func:`check_ranges` then refuses magnitudes no real
sensor, spacecraft or mission has (``1e300`` passes ``check_positive`` and overflows deep
inside a run), with the library's one message shape::

    sensors[0] (gyro).arw_deg_per_rt_h: got 1e+300; must be in [0, 100] deg/sqrt(h) (an ARW: ...)

The ranges are generous: a GNC engineer is never blocked by a real sensor or mission.

**Where a field's range comes from**, first match wins:

1. the config class's own ``RANGES`` (a ``ClassVar`` dict, field name -> :class:`Range` or
   ``(lo, hi, unit, why)``): how a plug-in outside the library documents its fields;
2. :data:`BY_CLASS`, keyed by ``(config class name, field name)``;
3. :data:`BY_FIELD`, keyed by the field name (``period_s``, ``num_particles``, ...);
4. :data:`BY_PREFIX` then :data:`BY_SUFFIX` (longest suffix first): the unit in the field
   name (``_deg``, ``_deg_per_s``, ``_arcsec``, ``_s``, ``_hz``, ``_km``, ``_probability``...).

A numeric value whose field has no range is refused (the message says how to declare one):
nothing passes unchecked. ``tests/test_ranges.py`` enumerates every numeric field of the
scenario and of every registered config and checks it resolves, so a new field is covered
by a unit suffix or the test names it.

``docs/config_reference.md`` is this table rendered (:func:`render_markdown`); regenerate it
with ``python -m drake_att.scenarios.ranges > docs/config_reference.md``.

Its length is the table: one physical range, with its reason, per numeric field of every config.
"""

from __future__ import annotations

import dataclasses
import numbers
import typing
from dataclasses import dataclass
from typing import Callable

import numpy as np

from drake_att import validation
from drake_att.validation import ConfigError

__all__ = [
    "Range",
    "Split",
    "BY_CLASS",
    "BY_FIELD",
    "BY_PREFIX",
    "BY_SUFFIX",
    "range_for",
    "check_ranges",
    "render_markdown",
    "DAY_S",
    "MAX_DURATION_S",
]

DAY_S = 86400.0
MAX_DURATION_S = 30 * DAY_S  # a month of attitude history


@dataclass(frozen=True)
class Range:
    """Closed interval ``[lo, hi]`` in ``unit`` ("" for dimensionless), and why."""

    lo: float
    hi: float
    unit: str
    why: str

    def __post_init__(self):
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.lo <= self.hi):
            raise ValueError(
                f"Range: got [{self.lo}, {self.hi}]; bounds must be finite with lo <= hi (a range is "
                "what a real sensor or mission can have)"
            )

    def allowed(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        return f"must be in [{_num(self.lo)}, {_num(self.hi)}]{unit} ({self.why})"


@dataclass(frozen=True)
class Split:
    """A list field whose entries have different ranges: ``select(index, size)`` names the
    part (a key of ``parts``) of entry ``index`` of a list of ``size`` entries."""

    parts: dict
    select: Callable[[int, int], str]
    describe: str = ""


def _num(x: float) -> str:
    """Exact and short: ``1e9`` (not ``1e+09``), ``2592000``, ``4294967295``, ``1e-6``."""
    x = float(x)
    if x == int(x) and abs(x) < 1e15:
        digits = str(int(x))
        zeros = len(digits) - len(digits.rstrip("0"))
        return f"{digits[:-zeros]}e{zeros}" if zeros >= 5 else digits
    return repr(x).replace("e+", "e").replace("e-0", "e-")


# --------------------------------------------------------------------------------------
# The table
# --------------------------------------------------------------------------------------
_ANGLE = Range(-360.0, 360.0, "deg", "an angle: one turn either way")
_SIGMA_ANGLE = Range(0.0, 360.0, "deg", "a 1-sigma angle: beyond a turn means nothing")
_RATE = Range(
    -5000.0, 5000.0, "deg/s", "a body rate: beyond the widest MEMS gyro (4000 deg/s); spinners turn at up to ~600 deg/s"
)
_TIME = Range(0.0, MAX_DURATION_S, "s", "a time within the longest run (30 days)")
_PROBABILITY = Range(0.0, 1.0, "", "a probability")
_FRACTION = Range(0.0, 1.0, "", "a fraction")
_CORRELATION = Range(-1.0, 1.0, "", "a correlation coefficient")
_ITERATIONS = Range(1, 1000, "", "iterations of one update")
_SEED = Range(0, validation.SEED_MAX, "", "Drake's 32-bit seed")
_VARIANCE_RAD2 = Range(0.0, 100.0, "rad^2", "an angle variance: (10 rad)^2 exceeds any attitude uncertainty")
_QUATERNION_VARIANCE = Range(0.0, 100.0, "", "a quaternion-component variance (the components are in [-1, 1])")
_WEIGHTS = Range(0.0, 1e6, "", "relative weights (normalized)")
_LAB_LENGTH = Range(0.0, 1e5, "mm", "a laboratory length up to 100 m")
_PSO_COEFFICIENT = Range(0.0, 10.0, "", "a particle-swarm coefficient (typically 0.4-2)")


def _inertia_part(index: int, size: int) -> str:
    """3 entries: principal moments; 9 (a row-major matrix): the diagonal is."""
    return "principal" if size == 3 or index in (0, 4, 8) else "product"


_INERTIA = Split(
    {
        "principal": Range(
            1e-7,
            1e9,
            "kg m^2",
            "a moment of inertia: from a gram-scale chip satellite (~1e-6) to beyond the ISS (~1e8)",
        ),
        "product": Range(-1e9, 1e9, "kg m^2", "a product of inertia (off-diagonal, either sign)"),
    },
    _inertia_part,
    "principal moments (3 entries, or the diagonal of 9) and products of inertia",
)

# (config class name, field name) -> range: where a field name means different things.
BY_CLASS: dict = {
    ("OrbitConfig", "altitude_km"): Range(
        100.0, 1e6, "km", "from the lowest orbit (~100 km) to beyond lunar distance (384,400 km)"
    ),
    ("OrbitConfig", "inclination_deg"): Range(0.0, 180.0, "deg", "an inclination (retrograde above 90)"),
    ("ExclusionConfig", "sun_deg"): Range(0.0, 180.0, "deg", "a cone half-angle (checked: strictly inside)"),
    ("ExclusionConfig", "earth_limb_deg"): Range(0.0, 180.0, "deg", "a cone half-angle (checked: strictly inside)"),
    ("ExclusionConfig", "moon_deg"): Range(0.0, 180.0, "deg", "a cone half-angle (checked: strictly inside)"),
    ("ExclusionConfig", "atmosphere_height_m"): Range(0.0, 1e6, "m", "the bright limb's height above the Earth"),
    ("KeplerOrbitConfig", "inclination_deg"): Range(0.0, 180.0, "deg", "an inclination (retrograde above 90)"),
    ("KeplerOrbitConfig", "eccentricity"): Range(0.0, 1.0, "", "a closed orbit (checked: e < 1, perigee above 100 km)"),
    ("KeplerOrbitConfig", "semi_major_axis_km"): Range(
        6478.137, 1e6, "km", "from the lowest orbit (~100 km altitude) to beyond lunar distance"
    ),
    ("PrescribedRpyConfig", "rpy_deg"): Range(-1e6, 1e6, "deg", "unwrapped breakpoints of a multi-turn profile"),
    ("PrescribedRpyConfig", "times_s"): Range(
        -MAX_DURATION_S, MAX_DURATION_S, "s", "breakpoints around the run (before 0 allowed), 30 days either way"
    ),
    ("OrbitPointingControlConfig", "damping_ratio"): Range(
        0.0, 10.0, "", "a closed loop's damping ratio (0.7 typical; above 1 overdamped)"
    ),
    ("OrbitPointingControlConfig", "natural_frequency_rad_per_s"): Range(
        0.0, 10.0, "rad/s", "an attitude loop's bandwidth (CubeSats ~0.01-1 rad/s)"
    ),
    ("OrbitPointingControlConfig", "torque_noise_N_m"): Range(
        0.0, 1.0, "N m", "a random torque's 1-sigma (CubeSat reaction wheels deliver ~1e-3 N m)"
    ),
    ("ScoringConfig", "convergence_threshold_deg"): Range(0.0, 180.0, "deg", "an attitude-error bound"),
    ("LoggingConfig", "period_s"): Range(1e-5, 1e5, "s", "a logging period from 100 kHz to about a day"),
    ("LoggingConfig", "periods_s"): Range(1e-5, 1e5, "s", "each signal's logging period, 100 kHz to about a day"),
    ("SimulationConfig", "accuracy"): Range(
        1e-16, 1.0, "", "a relative accuracy: below 1e-16 is under double round-off"
    ),
    ("SimulationConfig", "max_step_size_s"): Range(1e-6, 1e5, "s", "an integrator step from 1 us to about a day"),
    ("ScreenCameraConfig", "star_count"): Range(1, 1e4, "", "stars on the screen: the paper's ~50, 1e4 a dense screen"),
    ("ScreenCameraConfig", "focal_length_mm"): Range(0.1, 1e4, "mm", "a lens: ~1 mm fisheye to a 10 m telescope"),
    ("ScreenCameraConfig", "pixels"): Range(1, 1e5, "", "detector columns and rows: the largest sensors have ~1e4"),
    ("SensorFaultsConfig", "outlier_angle_deg"): Range(0.0, 180.0, "deg", "a rotation angle"),
    ("SensorFaultsConfig", "time_tag_offset_s"): Range(-DAY_S, DAY_S, "s", "a clock offset up to a day either way"),
    ("ScaleFactorStarNoiseConfig", "zeta_variance"): Range(0.0, 1e6, "", "the variance of the unitless zeta"),
    ("ScaleFactorStarNoiseConfig", "scale_per_zeta"): Range(
        0.0, 1e3, "", "scale-factor error per unit zeta (kappa sqrt(zeta_variance) < 0.1 is checked too)"
    ),
    ("CubatureQuaternionConfig", "grp_a"): Range(0.0, 1.0, "", "the GRP parameter a"),
    ("CubatureQuaternionConfig", "grp_f"): Range(0.0, 100.0, "", "the GRP scale f (USQUE: 2 (a + 1) = 4)"),
    ("CubatureQuaternionConfig", "zeta_gate_sigmas"): Range(0.0, 1e3, "", "a gate in standard deviations"),
    ("IndoorStarTrackerConfig", "tolerance_deg"): Range(0.0, 90.0, "deg", "an identification tolerance angle"),
    ("IndoorStarTrackerConfig", "max_lost_frames"): Range(1, 1e6, "", "camera frames"),
    ("IndoorStarTrackerConfig", "tolerance_sigmas"): Range(
        0.0, 100.0, "", "an angle-match tolerance in standard deviations (4: a true pair missed with probability 6e-5)"
    ),
    ("IndoorStarTrackerConfig", "camera_offset_error_mm"): Range(
        -1e5, 1e5, "mm", "a laboratory length error either way"
    ),
    ("IndoorStarTrackerConfig", "pso_particles"): Range(1, 1e5, "", "particles of the swarm search (paper: 5)"),
    ("IndoorStarTrackerConfig", "pso_max_generations"): Range(1, 1e6, "", "generations of the swarm search"),
    ("IndoorStarTrackerConfig", "pso_inertia"): _PSO_COEFFICIENT,
    ("IndoorStarTrackerConfig", "pso_c1"): _PSO_COEFFICIENT,
    ("IndoorStarTrackerConfig", "pso_c2"): _PSO_COEFFICIENT,
    ("IndoorStarTrackerConfig", "pso_stop_fraction"): _FRACTION,
    ("IndoorStarTrackerConfig", "pso_v_max_deg"): Range(0.0, 360.0, "deg", "a swarm particle's step bound"),
    ("IndoorStarTrackerConfig", "pso_search_range_deg"): Range(0.0, 360.0, "deg", "the swarm's search half-width"),
    ("SunSensorConfig", "fov_half_angle_deg"): Range(
        0.0, 90.0, "deg", "the field-of-view half-angle of one cosine head (checked: strictly inside)"
    ),
    ("SunSensorConfig", "albedo"): Range(0.0, 1.0, "", "a reflectance (the Earth's Bond albedo is ~0.3)"),
    ("MagnetometerConfig", "sigma_nT"): Range(
        0.0, 1e5, "nT", "a 1-sigma noise up to 100 uT (CubeSat magnetometers: ~10-500 nT; the LEO field: 20-60 uT)"
    ),
    ("MagnetometerConfig", "bias_nT"): Range(-1e5, 1e5, "nT", "a bias up to 100 uT, either sign"),
    ("QuaternionEkfConfig", "initial_quaternion_variance"): _QUATERNION_VARIANCE,
    ("QuaternionEkfConfig", "process_noise_per_step"): _QUATERNION_VARIANCE,
    ("QuaternionEkfConfig", "measurement_noise"): _QUATERNION_VARIANCE,
}

# field name -> range, whatever the config.
BY_FIELD: dict = {
    "duration_s": Range(0.0, MAX_DURATION_S, "s", "up to 30 days of attitude history"),
    "seed": _SEED,
    "pattern_seed": _SEED,
    "period_s": Range(1e-5, 1e5, "s", "a sample period from 100 kHz to about a day"),
    "num_particles": Range(1, 1e9, "", "1e9 particles need ~1 TB; the memory preflight sets this machine's limit"),
    "inertia_kg_m2": _INERTIA,
    "weights": _WEIGHTS,
    "references_I": Range(-1e6, 1e6, "", "direction components (normalized on use)"),
    "misalignment_urad": Range(-1e5, 1e5, "urad", "an axis misalignment up to 0.1 rad (5.7 deg)"),
    "sigma_vector_urad": Range(
        0.0,
        1e6,
        "urad",
        "a direction's 1-sigma up to 1 rad: star trackers 5-500 urad, sun sensors ~1e4, paper S4's tuning 1.25e5",
    ),
    "sigma_floor_urad": Range(0.0, 1e6, "urad", "a direction's 1-sigma floor, up to 1 rad"),
    "resample_threshold": Range(0.0, 1.0, "", "a fraction of the particle count"),
    "innovation_gate_chi2": Range(0.0, 1e6, "", "a chi-square threshold (a consistent filter's NIS is ~3-6)"),
    "correlation": _CORRELATION,
    "assumed_correlation": _CORRELATION,
    "num_substeps": Range(1, 1e4, "", "integration substeps per filter step"),
    "max_time_tag_lag_s": Range(
        0.0, 1e5, "s", "how late a sample may be and still be carried forward; below the estimator's period (checked)"
    ),
    "held_rate_rrw_deg_per_s15": Range(
        0.0,
        100.0,
        "deg/s^1.5",
        "the random walk of a held gyro rate's error: the body's unmodelled angular acceleration during an outage, "
        "0 (none) to a tumble's",
    ),
}

# field-name prefix -> range (after the tables, before the unit suffixes).
BY_PREFIX: dict = {
    "num_": Range(1, 1e6, "", "a count"),
}

# unit suffix of the field name -> range; the longest matching suffix wins.
BY_SUFFIX: dict = {
    "_deg": _ANGLE,
    "_sigma_deg": _SIGMA_ANGLE,
    "_deg_per_s": _RATE,
    "_sigma_deg_per_s": Range(0.0, 5000.0, "deg/s", "a body-rate 1-sigma (see the rates' range)"),
    "_deg_per_h": Range(
        -1e5, 1e5, "deg/h", "a gyro bias: navigation grade ~0.01, consumer MEMS up to a few deg/s (~1e4 deg/h)"
    ),
    "_sigma_deg_per_h": Range(0.0, 1e5, "deg/h", "a gyro-bias 1-sigma (see the biases' range)"),
    "_deg_per_rt_h": Range(
        0.0, 100.0, "deg/sqrt(h)", "an angle random walk: 1e-4 (navigation grade) to ~10 (the noisiest MEMS)"
    ),
    "_deg_per_h15": Range(0.0, 1e3, "deg/h^1.5", "a rate random walk: fibre-optic ~1e-4, MEMS up to ~10"),
    "_deg_per_h_per_rt_s": Range(
        0.0, 1e4, "deg/h/sqrt(s)", "a bias random-walk tuning (1e3 deg/h^1.5 is 17 deg/h/sqrt(s))"
    ),
    "_deg_per_s_per_rt_s": Range(
        0.0, 100.0, "deg/s/sqrt(s)", "a rate random-walk tuning: 100 swamps any spacecraft's rate"
    ),
    "_rad_per_s": Range(-1e5, 1e5, "rad/s", "an angular frequency up to ~16 kHz, either sign"),
    "_arcsec": Range(0.0, 3.6e4, "arcsec", "a 1-sigma or tolerance up to 10 deg (star trackers: 0.1-100 arcsec)"),
    "_urad": Range(-1e6, 1e6, "urad", "an angle up to 1 rad"),
    "_ppm": Range(-1e5, 1e5, "ppm", "a scale-factor error up to 10% (MEMS: < 1e4 ppm)"),
    "_rad2": _VARIANCE_RAD2,
    "_rad2_per_step": _VARIANCE_RAD2,
    "_s": _TIME,
    "_times_s": _TIME,
    "_windows_s": Range(
        -MAX_DURATION_S,
        MAX_DURATION_S,
        "s",
        "window edges within 30 days of the start (a start before 0: from the beginning)",
    ),
    "_hz": Range(1e-5, 1e6, "Hz", "a rate from one sample a day to 1 MHz"),
    "_km": Range(0.0, 1e6, "km", "a distance up to beyond lunar distance"),
    "_m": Range(-1e9, 1e9, "m", "a length up to beyond lunar distance"),
    "_mm": _LAB_LENGTH,
    "_um": Range(0.1, 1e3, "um", "a detector pixel: ~1 to ~100 um"),
    "_px": Range(0.0, 1e4, "px", "up to the detector's size"),
    "_kg_m2": _INERTIA,
    "_N_m": Range(-1e3, 1e3, "N m", "a disturbance or thruster torque (large spacecraft thrusters: ~100 N m)"),
    "_probability": _PROBABILITY,
    "_fraction": _FRACTION,
    "_iterations": _ITERATIONS,
    "_gain": Range(0.0, 1e3, "", "a dimensionless gain"),
    "_per_s": Range(0.0, 1e3, "1/s", "a rate constant up to 1 kHz"),
}


def _as_range(entry):
    if entry is None or isinstance(entry, (Range, Split)):
        return entry
    return Range(*entry)


def range_for(owner: type, field_name: str):
    """The :class:`Range` (or :class:`Split`) of ``owner``'s field ``field_name``, or None."""
    own = getattr(owner, "RANGES", None)
    if isinstance(own, dict) and field_name in own:
        return _as_range(own[field_name])
    entry = BY_CLASS.get((owner.__name__, field_name))
    if entry is None:
        entry = BY_FIELD.get(field_name)
    if entry is None:
        entry = next((r for p, r in BY_PREFIX.items() if field_name.startswith(p)), None)
    if entry is None:
        suffix = max((s for s in BY_SUFFIX if field_name.endswith(s)), key=len, default=None)
        entry = None if suffix is None else BY_SUFFIX[suffix]
    return entry


# --------------------------------------------------------------------------------------
# The check
# --------------------------------------------------------------------------------------
def _is_number(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _no_range(path, value, owner, field_name):
    validation.fail(
        path,
        value,
        f"no physical range is documented for {owner.__name__}.{field_name}: name the field "
        "with a unit suffix (e.g. _s, _deg, _hz; see drake_att.scenarios.ranges) or declare "
        f"RANGES = {{{field_name!r}: (lo, hi, unit, why)}} on the config class",
        ConfigError,
    )


def _check_number(path, value, entry, index: int = 0, size: int = 1):
    r = entry.parts[entry.select(index, size)] if isinstance(entry, Split) else entry
    if isinstance(value, np.generic):
        value = value.item()  # "got 2000000.0", not "got np.float64(2000000.0)"
    if not r.lo <= float(value) <= r.hi:  # NaN fails too
        validation.fail(path, value, r.allowed(), ConfigError)


def _check_field(path: str, value, owner: type, field_name: str) -> None:
    """Every number in ``value`` (a number, a list or nested lists, an array)."""
    if value is None or isinstance(value, (str, bytes, bool, np.bool_)):
        return
    if isinstance(value, dict):  # a mapping of names to numbers (logging.periods_s): each value
        for key, v in value.items():
            _check_field(f"{path}[{key!r}]", v, owner, field_name)
        return
    entry = None
    if isinstance(value, np.ndarray) and value.dtype != object:
        if value.size == 0 or not np.issubdtype(value.dtype, np.number):
            return
        entry = range_for(owner, field_name)
        if entry is None:
            _no_range(path, value, owner, field_name)
        if isinstance(entry, Split):
            flat = value.ravel()
            for i, x in enumerate(flat):
                _check_number(
                    path + "".join(f"[{k}]" for k in np.unravel_index(i, value.shape)), x, entry, i, flat.size
                )
            return
        a = value.astype(float)
        bad = ~((a >= entry.lo) & (a <= entry.hi))
        if bad.any():
            where = tuple(int(k) for k in np.argwhere(bad)[0])
            _check_number(path + "".join(f"[{k}]" for k in where), value[where], entry)
        return

    def walk(p, v, index, size):
        nonlocal entry
        if _is_number(v):
            if entry is None:
                entry = range_for(owner, field_name)
                if entry is None:
                    _no_range(p, v, owner, field_name)
            _check_number(p, v, entry, index, size)
        elif isinstance(v, (list, tuple, np.ndarray)):
            for i, x in enumerate(v):
                walk(f"{p}[{i}]", x, i, len(v))

    walk(path, value, 0, 1)


def _check_dataclass(path: str, obj) -> None:
    owner = type(obj)
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        p = f"{path}.{f.name}" if path else f.name
        if dataclasses.is_dataclass(value):
            _check_dataclass(p, value)
        elif isinstance(value, list) and value and all(dataclasses.is_dataclass(x) for x in value):
            for i, item in enumerate(value):  # sensors, estimators: "sensors[0] (gyro)"
                _check_dataclass(f"{p}[{i}] ({getattr(item, 'name', '?')})", item)
        else:
            _check_field(p, value, owner, f.name)


def check_ranges(scenario) -> None:
    """Raise :class:`~drake_att.validation.ConfigError` naming the first numeric field of
    ``scenario`` (a validated :class:`~drake_att.scenarios.config.Scenario`, every nested
    config, list and array included) outside its physical range, or with no documented range."""
    _check_dataclass("", scenario)


# --------------------------------------------------------------------------------------
# The reference document
# --------------------------------------------------------------------------------------
def _type_name(t) -> str:
    if t is type(None):
        return "null"
    if t is np.ndarray:
        return "matrix (list of rows)"
    if isinstance(t, type) and dataclasses.is_dataclass(t):
        return f"!{t.__name__}"
    origin, args = typing.get_origin(t), typing.get_args(t)
    if origin is typing.Union:
        return " or ".join(_type_name(a) for a in args)
    if origin in (list, typing.List):
        return f"list of {_type_name(args[0])}" if args else "list"
    if origin in (dict, typing.Dict) and len(args) == 2:
        return f"mapping of {_type_name(args[0])} to {_type_name(args[1])}"
    return {float: "float", int: "int", str: "string", bool: "bool"}.get(t, getattr(t, "__name__", str(t)))


def _is_numeric_type(t) -> bool:
    if t is np.ndarray or t in (float, int):
        return True
    origin, args = typing.get_origin(t), typing.get_args(t)
    if origin is typing.Union or origin in (list, typing.List):
        return any(_is_numeric_type(a) for a in args if a is not type(None))
    if origin in (dict, typing.Dict) and len(args) == 2:
        return _is_numeric_type(args[1])
    return False


def _default_text(f) -> str:
    if f.default is not dataclasses.MISSING:
        v = f.default
    elif f.default_factory is not dataclasses.MISSING:
        v = f.default_factory()
    else:
        return "(required)"

    def text(x):
        if dataclasses.is_dataclass(x):
            return f"!{type(x).__name__}"
        if isinstance(x, np.ndarray):
            if x.size == 0:
                return "[]"
            x = x.tolist()
        if isinstance(x, (list, tuple)):
            return "[" + ", ".join(text(y) for y in x) + "]"
        if x is None:
            return "null"
        if isinstance(x, bool):
            return "true" if x else "false"
        if isinstance(x, float):
            return _num(x)
        return repr(x) if isinstance(x, str) else str(x)

    return text(v)


def _rows(config_type: type, prefix: str, seen: set) -> tuple[list, list]:
    """``(rows of config_type's fields, nested dataclass sections [(type, prefix)])``."""
    rows, nested = [], []
    hints = typing.get_type_hints(config_type)
    for f in dataclasses.fields(config_type):
        t = hints.get(f.name, f.type)
        path = f"{prefix}{f.name}"
        subs = [a for a in (typing.get_args(t) or (t,)) if isinstance(a, type) and dataclasses.is_dataclass(a)]
        if subs:
            if config_type.__name__ != "Scenario":  # the scenario's sections are listed on their own
                nested += [(s, f"{path}.") for s in subs if s not in seen]
            rows.append((path, " or ".join(f"!{s.__name__}" for s in subs), _default_text(f), "", "(a section)", ""))
            continue
        if t == typing.List[typing.Any]:  # the scenario's sensors and estimators
            rows.append((path, f"list of registered {f.name[:-1]} configs", "[]", "", "(sections)", ""))
            continue
        if not _is_numeric_type(t):
            rows.append((path, _type_name(t), _default_text(f), "", "(not numeric)", ""))
            continue
        entry = range_for(config_type, f.name)
        if entry is None:
            rows.append((path, _type_name(t), _default_text(f), "", "**none**", ""))
        elif isinstance(entry, Split):
            for label, r in entry.parts.items():
                rows.append(
                    (
                        f"{path} ({label})",
                        _type_name(t),
                        _default_text(f),
                        r.unit,
                        f"[{_num(r.lo)}, {_num(r.hi)}]",
                        r.why,
                    )
                )
        else:
            rows.append(
                (path, _type_name(t), _default_text(f), entry.unit, f"[{_num(entry.lo)}, {_num(entry.hi)}]", entry.why)
            )
    return rows, nested


def _sections():
    """``[(title, config type, path prefix)]``: the scenario, its sections, the plants and
    the library's sensor and estimator configs (built-in plug-ins only), with nested types."""
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios import registry

    out = [
        ("Scenario (top level)", cfg.Scenario, ""),
        ("simulation", cfg.SimulationConfig, "simulation."),
    ]
    out += [(f"orbit: !{t.__name__}", t, "orbit.") for t in typing.get_args(cfg.OrbitTypes)]
    out += [(f"plant: !{t.__name__}", t, "plant.") for t in typing.get_args(cfg.PlantConfig)]
    out.append(("scoring", cfg.ScoringConfig, "scoring."))
    out.append(("logging", cfg.LoggingConfig, "logging."))
    builtin = registry.BUILTIN_PLUGIN_PACKAGES
    for kind, label in ((registry.SENSOR, "sensors"), (registry.ESTIMATOR, "estimators")):
        for tag, p in registry.plugins(kind).items():
            if p.module.startswith(tuple(b + "." for b in builtin)):
                out.append((f"{label}: !{tag}", p.config_type, f"{label}[i]."))
    return out


def render_markdown() -> str:
    """``docs/config_reference.md``: every field's path, type, default, unit, range and why."""
    lines = [
        "<!-- Generated from drake_att/scenarios/ranges.py; do not edit. Regenerate with:",
        "     python -m drake_att.scenarios.ranges > docs/config_reference.md -->",
        "# Scenario configuration reference",
        "",
        "Every field of a scenario (`drake_att/scenarios/*.yaml`, `--set PATH=VALUE`) and of the library's "
        "sensor and estimator configs: its type, default, unit and the physically plausible range "
        "`drake_att.scenarios.ranges.check_ranges` enforces after the specific checks (which also check signs, "
        "shapes, names and consistency: a value inside the range may still be refused by them). A number "
        "outside its range is refused naming the field, e.g. "
        "`sensors[0] (gyro).arw_deg_per_rt_h: got 1e+300; must be in [0, 100] deg/sqrt(h) (...)`. "
        "`sensors[i]` / `estimators[i]` stand for the item's index (messages add its name). Lists and matrices: "
        "every entry is in the range. Ranges are closed intervals.",
        "",
    ]
    seen = set()
    queue = list(_sections())
    while queue:
        title, t, prefix = queue.pop(0)
        if t in seen:
            continue
        seen.add(t)
        rows, nested = _rows(t, prefix, seen)
        lines += [f"## {title}", ""]
        doc = " ".join((t.__doc__ or "").strip().split("\n\n")[0].split())
        if doc and not doc.startswith(f"{t.__name__}("):
            lines += [doc, ""]
        lines += ["| Field | Type | Default | Unit | Range | Why |", "|---|---|---|---|---|---|"]
        lines += [
            "| "
            + " | ".join(c.replace("|", "\\|") if c else "" for c in (f"`{r[0]}`", r[1], f"`{r[2]}`", r[3], r[4], r[5]))
            + " |"
            for r in rows
        ]
        lines.append("")
        queue[0:0] = [(f"{p[:-1]}: !{s.__name__}", s, p) for s, p in nested]
    return "\n".join(lines)


if __name__ == "__main__":
    print(render_markdown(), end="")
