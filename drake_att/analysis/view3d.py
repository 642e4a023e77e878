"""A 3-D view of a saved run in Drake's Meshcat: ``drake-att view OUT_DIR``.

From a result folder of ``drake-att run`` (``config.yaml`` + ``log.npz``),
:func:`view_geometry` computes what the view draws, as numpy arrays on the frames of the
replay (:class:`ViewGeometry`); :func:`draw` puts it into a ``pydrake.geometry.Meshcat``
and records the replay as a Meshcat animation; :func:`static_html` exports the scene, the
animation and a legend as one self-contained HTML file.

The scene (Drake's z-up world frame is the inertial frame I, centred on the spacecraft;
only directions are drawn, never distances):

* the spacecraft, a box in the truth attitude, with the truth body frame B as a triad
  (x red, y green, z blue);
* each star tracker's boresight (sensor +z, a white rod from the body's centre) and its
  exclusion cones around it, apex at the body's centre, at the configured half-angles:
  Sun (yellow), Earth limb (blue), Moon (grey);
* each estimator's estimated body frame, a triad of one colour per estimator
  (optionally with its error rotation magnified, ``error_scale``);
* the Earth (nadir, blue), Sun (yellow) and Moon (grey) directions from the spacecraft,
  arrows of one fixed length, with the Earth's apparent disk (its bright limb, Earth radius
  plus the ``atmosphere_height_m`` of the first tracker with exclusion cones, else 100 km) as a translucent cone around nadir: the
  Earth blinds a tracker when that disk overlaps the tracker's Earth-limb cone, as in
  :mod:`drake_att.exclusion`. Positions come from the scenario's orbit model, the Sun and
  the Moon from :class:`~drake_att.ephemeris.SunMoonEphemeris` at the orbit's epoch; with a
  circular orbit (no epoch) only nadir is drawn, with no orbit no direction at all (the
  legend says so).

The replay samples the logged truth at most ``frames`` times (default
:data:`DEFAULT_FRAMES`, at most :data:`MAX_FRAMES`), evenly over the run; an estimate is
shown as its latest logged value at or before each frame (the first one before it exists).
The animation plays the whole run in ``playback_s`` seconds (Meshcat interpolates between
frames) and waits for Meshcat's play button; its slider counts playback seconds, the legend
gives the speed-up.

Box size: ``box_m`` when given; otherwise, for a rigid-body plant, the uniform box of density
:data:`DEFAULT_DENSITY_KG_M3` with the plant's principal moments of inertia (for the project's
3U CubeSat, inertia ``[0.042, 0.042, 0.0067]`` kg m², that is 0.100 x 0.100 x 0.339 m,
4.0 kg); a plant without inertia (prescribed motion) gets :data:`DEFAULT_BOX_M`.
"""

from __future__ import annotations

import html
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from drake_att import rotations as rot
from drake_att.orbit import EARTH_RADIUS_M
from drake_att.validation import UserInputError

if TYPE_CHECKING:
    from drake_att.scenarios.config import Scenario

DEFAULT_FRAMES = 500
"""Frames of the replay by default (fewer when the truth has fewer samples)."""
MAX_FRAMES = 2000
"""At most this many frames: Meshcat keeps every keyframe of every animated path in the page."""
DEFAULT_PLAYBACK_S = 30.0
"""The animation plays the whole run in this many seconds by default."""
DEFAULT_DENSITY_KG_M3 = 1200.0
"""The box's density when its size comes from the inertia: a 3U CubeSat's 4 kg in 3.4 litres."""
DEFAULT_BOX_M = (0.1, 0.1, 0.34)
"""The box of a plant without an inertia (the project's 3U CubeSat, m)."""
ROOT = "/drake_att"
"""Every object of the view is under this Meshcat path."""
TRUTH_PATH = f"{ROOT}/truth"
ESTIMATES_PATH = f"{ROOT}/estimates"
DIRECTIONS_PATH = f"{ROOT}/directions"
CONE_KINDS = ("sun", "earth_limb", "moon")

_SUN_RGBA = (1.0, 0.85, 0.1)
_EARTH_RGBA = (0.25, 0.5, 1.0)
_MOON_RGBA = (0.78, 0.78, 0.82)
_CONE_RGB = {"sun": _SUN_RGBA, "earth_limb": _EARTH_RGBA, "moon": _MOON_RGBA}
_CONE_ALPHA = {"sun": 0.2, "earth_limb": 0.22, "moon": 0.35}
_AXIS_RGB = ((0.9, 0.15, 0.15), (0.15, 0.8, 0.15), (0.2, 0.35, 1.0))
_ESTIMATE_RGB = [
    ("magenta", (0.95, 0.2, 0.85)),
    ("cyan", (0.1, 0.9, 0.95)),
    ("orange", (1.0, 0.55, 0.1)),
    ("lime", (0.6, 1.0, 0.2)),
    ("pink", (1.0, 0.6, 0.7)),
    ("white", (0.95, 0.95, 0.95)),
]


class ViewError(UserInputError):
    """A folder or option the view cannot use (one line naming it and what is expected)."""


@dataclass
class TrackerView:
    """A star tracker as drawn: ``q_BS`` (its mounting; boresight = S's +z) and its
    exclusion half-angles (deg) by kind (``sun``, ``earth_limb``, ``moon``; empty: none)."""

    name: str
    q_BS: np.ndarray
    cones_deg: dict = field(default_factory=dict)


@dataclass
class ViewGeometry:
    """What the view draws, sampled on the replay's frames.

    Attributes:
        scenario, seed, duration_s: the run's.
        times_s: run time of each frame (s), shape (n,).
        q_IB: the truth attitude at each frame (wxyz), (n, 4).
        q_IB_hat: estimator name -> its attitude estimate at each frame (latest logged value
            at or before the frame), (n, 4).
        box_m: the box's edges along its own axes (m); ``q_B_box``: the box's orientation in B
            (its principal axes); ``box_note``: where the size comes from.
        trackers: the star trackers (:class:`TrackerView`).
        directions_I: ``"earth"``, ``"sun"``, ``"moon"`` -> unit vectors from the spacecraft
            in I at each frame, (n, 3); only those the scenario can place.
        earth_disk_deg: the Earth's apparent radius (bright limb) seen from the spacecraft at
            each frame (deg), (n,); None without an orbit.
        limb_height_m: the atmosphere height of that limb (m).
        notes: what is not drawn and why, in words.
    """

    scenario: Scenario
    seed: int
    duration_s: float
    times_s: np.ndarray
    q_IB: np.ndarray
    q_IB_hat: dict
    box_m: np.ndarray
    q_B_box: np.ndarray
    box_note: str
    trackers: list
    directions_I: dict
    earth_disk_deg: np.ndarray | None
    limb_height_m: float
    notes: list

    @property
    def scale_m(self) -> float:
        """The view's unit of length: the box's longest edge (rods, cones and arrows are multiples of it)."""
        return float(np.max(self.box_m))


# ======================================================================================
# Loading a run folder
# ======================================================================================
def load_run(folder: str, allow_plugins: bool = False):
    """The :class:`~drake_att.scenarios.builder.RunLog` of a result folder of ``drake-att run``.

    Raises:
        ViewError: one line naming the folder or file: missing, not a run's result folder (a
            campaign or comparison folder, no ``log.npz``/``config.yaml``), an invalid
            configuration or a damaged log.
    """
    import zipfile

    from drake_att import outputs
    from drake_att.scenarios.builder import RunLog
    from drake_att.scenarios.config import ConfigError, load_scenario

    if not os.path.exists(folder):
        raise ViewError(f"{folder}: no such result folder")
    if not os.path.isdir(folder):
        raise ViewError(f"{folder}: not a folder; give the result folder of `drake-att run` (holding log.npz)")
    kind = outputs.folder_kind(folder)
    if kind in ("campaign", "comparison"):
        raise ViewError(
            f"{folder}: is a {'Monte Carlo campaign' if kind == 'campaign' else 'comparison'} folder, not one run's; "
            "view one run: `drake-att run SCENARIO --seed N --out DIR`, then `drake-att view DIR`"
        )
    npz_path, config_path = os.path.join(folder, "log.npz"), os.path.join(folder, "config.yaml")
    for path in (npz_path, config_path):
        if not os.path.isfile(path):
            raise ViewError(f"{path}: missing (a result folder of `drake-att run` holds log.npz and config.yaml)")
    try:
        scenario = load_scenario(filename=config_path, new_plugins=allow_plugins)
    except ConfigError as e:
        raise ViewError(f"{config_path}: not a valid scenario: {e}") from None
    try:
        run = RunLog.load(npz_path, scenario)
        q = np.asarray(run.values(run.metadata["truth"]["attitude"]), dtype=float)
    except (OSError, ValueError, EOFError, KeyError, TypeError, zipfile.BadZipFile) as e:
        raise ViewError(f"{npz_path}: cannot be viewed: {type(e).__name__}: {e}") from None
    if q.ndim != 2 or q.shape[1] != 4 or len(q) == 0:
        raise ViewError(f"{npz_path}: the truth attitude has shape {q.shape}; expected (n >= 1, 4)")
    return run


# ======================================================================================
# Geometry (numpy, no Meshcat)
# ======================================================================================
def box_from_inertia(inertia_kg_m2, density_kg_m3: float = DEFAULT_DENSITY_KG_M3):
    """``(edges (3,) m, q_B_box, mass kg)`` of the uniform box of ``density_kg_m3`` whose
    principal moments are those of ``inertia_kg_m2`` (3 principal moments or a 3x3 matrix):
    with ``I_x = m (b^2 + c^2) / 12`` etc., ``a^2 = 6 (I_y + I_z - I_x) / m`` and
    ``m = density a b c``. ``q_B_box`` turns the box's axes onto the principal axes in B.
    A moment sum that leaves an edge at zero (a flat body) gets 1% of the longest edge."""
    I = np.asarray(inertia_kg_m2, dtype=float)
    if I.size == 3:
        moments, axes = I.ravel(), np.eye(3)
    else:
        moments, axes = np.linalg.eigh(I.reshape(3, 3))
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1.0
    if not (np.all(np.isfinite(moments)) and np.all(moments > 0)):
        raise ViewError(f"plant.inertia_kg_m2: got principal moments {moments.tolist()}; must be > 0 for a box")
    if not (np.isfinite(density_kg_m3) and density_kg_m3 > 0):
        raise ViewError(f"density: got {density_kg_m3!r}; must be > 0 kg/m^3")
    p = 6.0 * (moments.sum() - 2.0 * moments)  # m * edge^2 along each principal axis
    p = np.maximum(p, 1e-4 * p.max())
    u = np.sqrt(p)  # edge * sqrt(m)
    mass = float((density_kg_m3 * np.prod(u)) ** 0.4)  # m = density * prod(u) / m^1.5
    return u / np.sqrt(mass), rot.rotmat_to_quat(axes), mass


def _box(scenario, box_m, density_kg_m3):
    """``(edges, q_B_box, note)`` for the scenario's plant (see the module docstring)."""
    from drake_att.scenarios import config as cfg

    if box_m is not None:
        edges = np.asarray(box_m, dtype=float)
        if edges.shape != (3,) or not (np.all(np.isfinite(edges)) and np.all(edges > 0)):
            raise ViewError(f"--box-m: got {np.asarray(box_m).tolist()}; three edges in metres, each > 0")
        return edges, rot.quat_identity(), "given (--box-m)"
    if isinstance(scenario.plant, cfg.RigidBodyConfig):
        edges, q, mass = box_from_inertia(scenario.plant.inertia_kg_m2, density_kg_m3)
        return (
            edges,
            q,
            f"the uniform box of {density_kg_m3:g} kg/m^3 with the plant's inertia ({mass:.2f} kg)",
        )
    return np.asarray(DEFAULT_BOX_M), rot.quat_identity(), "the plant has no inertia: a 3U CubeSat's box"


def _held(t_log: np.ndarray, x_log: np.ndarray, times: np.ndarray) -> np.ndarray:
    """The latest logged row at or before each of ``times`` (the first row before it exists)."""
    i = np.searchsorted(t_log, times, side="right") - 1
    return x_log[np.clip(i, 0, len(t_log) - 1)]


def frame_indices(n_samples: int, frames: int) -> np.ndarray:
    """Indices of ``min(frames, n_samples)`` samples spread evenly from the first to the last."""
    k = min(int(frames), int(n_samples))
    return np.unique(np.round(np.linspace(0, n_samples - 1, k)).astype(int))


def check_frames(frames) -> int:
    """``frames`` as an int in [2, :data:`MAX_FRAMES`], or ViewError naming ``--frames``."""
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 2 <= frames <= MAX_FRAMES:
        raise ViewError(f"--frames: got {frames!r}; must be an integer in [2, {MAX_FRAMES}]")
    return int(frames)


def view_geometry(
    run,
    frames: int = DEFAULT_FRAMES,
    box_m=None,
    density_kg_m3: float = DEFAULT_DENSITY_KG_M3,
) -> ViewGeometry:
    """What the view of ``run`` (a :class:`~drake_att.scenarios.builder.RunLog`) draws, on at most
    ``frames`` frames (see the module docstring)."""
    from drake_att.scenarios.build_context import make_orbit
    from drake_att.sensors.star_tracker_plugin import StarTrackerConfig, exclusion_cones, star_tracker_mounting

    frames = check_frames(frames)
    scenario = run.scenario
    meta = run.metadata
    t_truth = np.asarray(run.times(meta["truth"]["attitude"]), dtype=float)
    q_truth = np.asarray(run.values(meta["truth"]["attitude"]), dtype=float)
    idx = frame_indices(len(t_truth), frames)
    times = t_truth[idx]
    q_IB = rot.quat_normalize(q_truth[idx])
    q_IB_hat = {}
    for name, e in meta["estimators"].items():
        key = e["signals"]["attitude"]
        q_IB_hat[name] = rot.quat_normalize(_held(run.times(key), np.asarray(run.values(key), dtype=float), times))
    edges, q_B_box, box_note = _box(scenario, box_m, density_kg_m3)

    trackers = []
    for s in scenario.sensors:
        if isinstance(s, StarTrackerConfig):
            cones = exclusion_cones(s)
            angles = {} if cones is None else {k: float(getattr(cones, f"{k}_deg")) for k in CONE_KINDS}
            trackers.append(TrackerView(s.name, rot.quat_normalize(star_tracker_mounting(s)), angles))
    limb_height = next(
        (float(s.exclusion.atmosphere_height_m) for s in scenario.sensors if getattr(s, "exclusion", None)),
        100e3,
    )

    notes = []
    directions: dict = {}
    earth_disk = None
    orbit = make_orbit(scenario)
    if orbit is None:
        notes.append("no orbit in the scenario: no Earth, Sun or Moon direction is drawn")
    else:
        r_I, _ = orbit.position_velocity_I(times)
        r_I = np.asarray(r_I, dtype=float).reshape(len(times), 3)
        dist = np.linalg.norm(r_I, axis=1)
        directions["earth"] = -r_I / dist[:, None]
        earth_disk = np.degrees(np.arcsin(np.minimum((EARTH_RADIUS_M + limb_height) / dist, 1.0)))
        epoch = getattr(scenario.orbit, "epoch_utc", None)
        if epoch is None:
            notes.append(
                "the orbit has no epoch (a circular orbit): nadir only; the Sun and the Moon are not drawn "
                "(give the scenario a !KeplerOrbitConfig or !TleOrbitConfig orbit)"
            )
        else:
            from drake_att.ephemeris import SunMoonEphemeris
            from drake_att.orbit_propagators import julian_date_utc, parse_epoch_utc

            jd0 = julian_date_utc(parse_epoch_utc(epoch))
            jd = jd0 + times / 86400.0
            try:
                eph = SunMoonEphemeris(jd0, jd0 + (float(times[-1]) + 60.0) / 86400.0)
            except ValueError as e:  # an epoch the offline ephemeris does not cover (no tracker needed it)
                notes.append(f"the Sun and the Moon: the run is outside the offline ephemeris' span ({e})")
            else:
                for body, position in (("sun", eph.sun_position_m(jd)), ("moon", eph.moon_position_m(jd))):
                    d = position - r_I
                    directions[body] = d / np.linalg.norm(d, axis=1, keepdims=True)
    return ViewGeometry(
        scenario=scenario,
        seed=run.seed,
        duration_s=float(scenario.duration_s),
        times_s=times,
        q_IB=q_IB,
        q_IB_hat=q_IB_hat,
        box_m=edges,
        q_B_box=q_B_box,
        box_note=box_note,
        trackers=trackers,
        directions_I=directions,
        earth_disk_deg=earth_disk,
        limb_height_m=limb_height,
        notes=notes,
    )


def z_onto(d) -> np.ndarray:
    """Rotation matrices (..., 3, 3) whose third column is the unit vector ``d`` (..., 3):
    they turn a shape built along +z onto ``d``."""
    d = np.asarray(d, dtype=float)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    helper = np.where(np.abs(d[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    x = np.cross(helper, d)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(d, x), d], axis=-1)


def magnified_estimate(q_IB, q_IB_hat, error_scale: float) -> np.ndarray:
    """The estimate with its error rotation (``R_IB^T R_IB_hat``) multiplied by ``error_scale``."""
    if error_scale == 1.0:
        return q_IB_hat
    err = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q_IB), q_IB_hat))
    return rot.quat_multiply(q_IB, rot.rotvec_to_quat(error_scale * err))


# ======================================================================================
# The legend
# ======================================================================================
def playback_speedup(geometry: ViewGeometry, playback_s: float) -> float:
    span = float(geometry.times_s[-1] - geometry.times_s[0])
    return span / playback_s if span > 0 else 1.0


def legend(geometry: ViewGeometry, playback_s: float = DEFAULT_PLAYBACK_S, error_scale: float = 1.0) -> list[str]:
    """The view's legend, a line per item (the CLI prints it; the HTML export shows it)."""
    g = geometry
    n = len(g.times_s)
    step = (g.times_s[-1] - g.times_s[0]) / (n - 1) if n > 1 else 0.0
    lines = [
        f"{g.scenario.name} seed {g.seed}: {g.duration_s:g} s, {n} frames (every {step:.3g} s), played in "
        f"{playback_s:g} s ({playback_speedup(g, playback_s):.3g}x)",
        "Inertial frame I (thin grey axes) centred on the spacecraft; directions only, not to scale",
        f"Box {' x '.join(f'{x:.3f}' for x in g.box_m)} m: {g.box_note}",
        "Truth body frame: the box and its triad (x red, y green, z blue)",
    ]
    if g.q_IB_hat:
        names = ", ".join(f"{name} ({_ESTIMATE_RGB[i % len(_ESTIMATE_RGB)][0]})" for i, name in enumerate(g.q_IB_hat))
        scale = (
            f"; errors magnified {error_scale:g}x"
            if error_scale != 1.0
            else " (an error of arcseconds is invisible at this scale)"
        )
        lines.append(f"Estimated body frames: {names}{scale}")
    for t in g.trackers:
        cones = (
            ", ".join(
                f"{label} {t.cones_deg[k]:g} deg ({colour})"
                for k, label, colour in (
                    ("sun", "Sun", "yellow"),
                    ("earth_limb", "Earth limb", "blue"),
                    ("moon", "Moon", "grey"),
                )
            )
            if t.cones_deg
            else "no exclusion configured"
        )
        lines.append(f"Star tracker {t.name}: boresight (white rod); exclusion cones: {cones}")
    shown = [
        label
        for key, label in (("earth", "Earth/nadir (blue)"), ("sun", "Sun (yellow)"), ("moon", "Moon (grey)"))
        if key in g.directions_I
    ]
    if shown:
        lines.append("Directions from the spacecraft: " + ", ".join(shown))
    if g.earth_disk_deg is not None:
        lo, hi = float(np.min(g.earth_disk_deg)), float(np.max(g.earth_disk_deg))
        radius = f"{lo:.1f} deg" if hi - lo < 0.05 else f"{lo:.1f}-{hi:.1f} deg"
        lines.append(
            f"Earth's disk (translucent blue cone around nadir): the bright limb, {g.limb_height_m / 1e3:g} km "
            f"above the Earth's radius, {radius} in radius"
        )
    lines += [f"Not shown: {note}" for note in g.notes]
    return lines


# ======================================================================================
# Meshcat
# ======================================================================================
def _rgba(rgb, alpha: float = 1.0):
    from pydrake.geometry import Rgba

    r, g, b = (float(x) for x in rgb)
    return Rgba(r, g, b, float(alpha))


def _transform(R=None, p=None, q=None):
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RigidTransform, RotationMatrix

    if q is not None:
        rotation = RotationMatrix(Quaternion(rot.quat_normalize(np.asarray(q, dtype=float))))
    else:
        rotation = RotationMatrix(np.eye(3) if R is None else np.asarray(R, dtype=float))
    return RigidTransform(rotation, np.zeros(3) if p is None else np.asarray(p, dtype=float))


def _rod(meshcat, path: str, axis, length: float, radius: float, rgba) -> None:
    """A cylinder from the origin along the unit ``axis`` of its parent."""
    from pydrake.geometry import Cylinder

    meshcat.SetObject(path, Cylinder(radius, length), rgba)
    axis = np.asarray(axis, dtype=float)
    meshcat.SetTransform(path, _transform(R=z_onto(axis), p=0.5 * length * axis))


def _triad(meshcat, path: str, length: float, radius: float, colours, alpha: float = 1.0) -> None:
    for i, name in enumerate("xyz"):
        _rod(meshcat, f"{path}/{name}", np.eye(3)[i], length, radius, _rgba(colours[i], alpha))


def _cone(meshcat, path: str, half_angle_deg: float, height: float, rgba) -> None:
    """A cone with its apex at the parent's origin, opening along the parent's +z; beyond 80 deg
    the height shrinks so the base radius stays 6 x ``height``."""
    from pydrake.geometry import MeshcatCone

    t = np.tan(np.radians(min(half_angle_deg, 89.9)))
    h = min(height, 6.0 * height / t)
    meshcat.SetObject(path, MeshcatCone(h, h * t, h * t), rgba)


def _arrow(meshcat, path: str, length: float, radius: float, rgba) -> None:
    """An arrow from the parent's origin along its +z."""
    from pydrake.geometry import Cylinder, MeshcatCone

    head = 0.15 * length
    meshcat.SetObject(f"{path}/shaft", Cylinder(radius, length - head), rgba)
    meshcat.SetTransform(f"{path}/shaft", _transform(p=[0.0, 0.0, 0.5 * (length - head)]))
    meshcat.SetObject(f"{path}/head", MeshcatCone(head, 2.5 * radius, 2.5 * radius), rgba)
    # the cone's apex at the tip, opening back toward the shaft
    meshcat.SetTransform(f"{path}/head", _transform(R=np.diag([1.0, -1.0, -1.0]), p=[0.0, 0.0, length]))


def tracker_path(name: str) -> str:
    return f"{TRUTH_PATH}/trackers/{name}"


def estimate_path(name: str) -> str:
    return f"{ESTIMATES_PATH}/{name}"


def direction_path(body: str) -> str:
    return f"{DIRECTIONS_PATH}/{body}"


def draw(
    meshcat,
    geometry: ViewGeometry,
    playback_s: float = DEFAULT_PLAYBACK_S,
    error_scale: float = 1.0,
    still_time_s: float | None = None,
    autoplay: bool = False,
) -> None:
    """Draw ``geometry`` into ``meshcat`` (a ``pydrake.geometry.Meshcat``; what was under
    :data:`ROOT` is replaced) and publish the replay as its animation.

    Args:
        playback_s: the animation's length (s) for the whole run.
        error_scale: magnify each estimate's error rotation by this factor (1: as estimated).
        still_time_s: the run time the scene shows outside the animation (nearest frame;
            default: the first frame).
        autoplay: start the animation when the page opens.
    """
    from pydrake.geometry import Box, MeshcatAnimation

    if not (np.isfinite(playback_s) and playback_s > 0):
        raise ViewError(f"--playback-s: got {playback_s!r}; must be > 0 seconds")
    if not (np.isfinite(error_scale) and error_scale > 0):
        raise ViewError(f"--error-scale: got {error_scale!r}; must be > 0")
    g = geometry
    if still_time_s is not None and not (np.isfinite(still_time_s) and 0.0 <= still_time_s <= g.duration_s):
        raise ViewError(f"--at: got {still_time_s!r}; a run time in [0, {g.duration_s:g}] s")
    s = g.scale_m
    meshcat.Delete(ROOT)
    meshcat.SetProperty("/Grid", "visible", False)
    meshcat.SetProperty("/Axes", "visible", False)
    meshcat.SetProperty("/Background/<object>", "top_color", [0.02, 0.03, 0.10])
    meshcat.SetProperty("/Background/<object>", "bottom_color", [0.0, 0.0, 0.0])
    _triad(meshcat, f"{ROOT}/inertial", 4.5 * s, 0.004 * s, ((0.6, 0.6, 0.6),) * 3, 0.8)

    box = f"{TRUTH_PATH}/spacecraft"
    meshcat.SetObject(box, Box(*g.box_m), _rgba((0.72, 0.72, 0.76)))
    meshcat.SetTransform(box, _transform(q=g.q_B_box))
    _triad(meshcat, f"{TRUTH_PATH}/triad", 0.95 * s, 0.03 * s, _AXIS_RGB)
    for t in g.trackers:
        path = tracker_path(t.name)
        meshcat.SetTransform(path, _transform(q=t.q_BS))
        _rod(meshcat, f"{path}/boresight", [0.0, 0.0, 1.0], 2.6 * s, 0.015 * s, _rgba((1.0, 1.0, 1.0)))
        for k, angle in t.cones_deg.items():
            _cone(meshcat, f"{path}/cones/{k}", angle, 1.6 * s, _rgba(_CONE_RGB[k], _CONE_ALPHA[k]))
    for i, name in enumerate(g.q_IB_hat):
        colour = _ESTIMATE_RGB[i % len(_ESTIMATE_RGB)][1]
        _triad(meshcat, estimate_path(name), 1.15 * s, 0.015 * s, (colour,) * 3)
    rgb = {"earth": _EARTH_RGBA, "sun": _SUN_RGBA, "moon": _MOON_RGBA}
    for body, _ in g.directions_I.items():
        _arrow(meshcat, f"{direction_path(body)}/arrow", 3.6 * s, 0.025 * s, _rgba(rgb[body]))
    if g.earth_disk_deg is not None:
        disk = f"{direction_path('earth')}/disk"
        angle = float(np.mean(g.earth_disk_deg))
        h = 0.9 * s
        _cone(meshcat, f"{disk}/cone", angle, h, _rgba(_EARTH_RGBA, 0.07))
        r = h * np.tan(np.radians(angle))
        phi = np.linspace(0.0, 2.0 * np.pi, 97)
        rim = np.vstack([r * np.cos(phi), r * np.sin(phi), np.full_like(phi, h)])
        meshcat.SetLine(f"{disk}/rim", rim, 2.0, _rgba(_EARTH_RGBA, 0.9))

    # Poses: the animation's keyframes, and the still scene at one frame.
    n = len(g.times_s)
    poses: dict = {TRUTH_PATH: g.q_IB}
    for name, q in g.q_IB_hat.items():
        poses[estimate_path(name)] = magnified_estimate(g.q_IB, q, error_scale)
    for body, d in g.directions_I.items():
        poses[direction_path(body)] = rot.rotmat_to_quat(z_onto(d))
    fps = (n - 1) / playback_s if n > 1 else 1.0
    animation = MeshcatAnimation(fps)
    animation.set_autoplay(autoplay)
    animation.set_loop_mode(MeshcatAnimation.LoopMode.kLoopRepeat)
    for path, q in poses.items():
        for k in range(n):
            animation.SetTransform(k, path, _transform(q=q[k]))
    still = 0 if still_time_s is None else int(np.argmin(np.abs(g.times_s - float(still_time_s))))
    for path, q in poses.items():
        meshcat.SetTransform(path, _transform(q=q[still]))
    meshcat.SetAnimation(animation)
    view_camera(meshcat, g)


def view_camera(meshcat, geometry: ViewGeometry) -> None:
    """Place the camera ~5 box lengths away, looking at the spacecraft from above its x-z side."""
    s = geometry.scale_m
    meshcat.SetCameraPose(np.array([3.4, -3.8, 2.4]) * s, np.zeros(3))


LEGEND_ID = "drake-att-legend"


def static_html(
    meshcat, geometry: ViewGeometry, playback_s: float = DEFAULT_PLAYBACK_S, error_scale: float = 1.0
) -> str:
    """``meshcat.StaticHtml()`` (Meshcat's page with its scripts inline and the scene and
    animation as embedded ``data:`` commands: it needs no server and no network) with the
    legend as an overlay box."""
    page = meshcat.StaticHtml()
    items = "".join(f"<li>{html.escape(line)}</li>" for line in legend(geometry, playback_s, error_scale))
    box = (
        f'<div id="{LEGEND_ID}" style="position:fixed;left:8px;top:8px;max-width:44em;padding:6px 10px;'
        "background:rgba(0,0,0,0.6);color:#eee;font:11px/1.3 sans-serif;border-radius:4px;"
        f'pointer-events:none"><b>drake-att view</b><ul style="margin:2px 0 0 1em;padding:0">{items}</ul></div>'
    )
    end = page.rfind("</body>")
    if end < 0:
        return page + box
    return page[:end] + box + page[end:]


def check_html_target(path: str) -> str:
    """``path`` if the page may be written there: a new file, or a page this command wrote before
    (it ends with the legend box); ViewError otherwise (a user's file is never replaced)."""
    if not path.strip():
        raise ViewError(f"--html: got {path!r}; name a file for the page")
    if not os.path.lexists(path):
        return path
    if os.path.islink(path) or not os.path.isfile(path):
        raise ViewError(f"--html {path}: exists and is not a regular file; name a new file")
    try:
        with open(path, "rb") as f:
            f.seek(max(0, os.path.getsize(path) - 65536))
            tail = f.read()
    except OSError as e:
        raise ViewError(f"--html {path}: cannot read the existing file ({e.strerror or e})") from None
    if f'id="{LEGEND_ID}"'.encode() not in tail:
        raise ViewError(
            f"--html {path}: exists and is not a page drake-att view wrote; it is left untouched (name a new file)"
        )
    return path


def write_static_html(meshcat, geometry: ViewGeometry, path: str, **kwargs) -> str:
    """Write :func:`static_html` to ``path`` (atomically); returns ``path``."""
    from drake_att.outputs import write_file_atomic

    write_file_atomic(path, static_html(meshcat, geometry, **kwargs).encode("utf-8"))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)  # a page to share: the usual mode of a new file, not the temporary file's 0600
    return path


def view_run(
    folder: str,
    meshcat=None,
    html_path: str | None = None,
    frames: int = DEFAULT_FRAMES,
    box_m=None,
    playback_s: float = DEFAULT_PLAYBACK_S,
    error_scale: float = 1.0,
    still_time_s: float | None = None,
    allow_plugins: bool = False,
):
    """Load the run in ``folder``, draw it into ``meshcat`` (default: a new
    ``pydrake.geometry.Meshcat``, which serves the view at ``meshcat.web_url()``), write the
    static page to ``html_path`` when given; returns ``(meshcat, geometry)``."""
    frames = check_frames(frames)
    if html_path is not None:
        check_html_target(html_path)  # before any work
    run = load_run(folder, allow_plugins=allow_plugins)
    geometry = view_geometry(run, frames=frames, box_m=box_m)
    if meshcat is None:
        from pydrake.geometry import Meshcat

        meshcat = Meshcat()
    draw(meshcat, geometry, playback_s=playback_s, error_scale=error_scale, still_time_s=still_time_s)
    if html_path is not None:
        try:
            write_static_html(meshcat, geometry, html_path, playback_s=playback_s, error_scale=error_scale)
        except OSError as e:
            raise ViewError(f"--html {html_path}: cannot write ({e.strerror or e})") from None
    return meshcat, geometry
