"""Each shipped scenario's initial truth and initial estimates, recomputed here from the YAML
numbers.

The library composes every initial attitude of a scenario with an orbit (LVLH) frame when the
scenario has one (``scenarios/config.py``: "when ``orbit`` is set, every initial attitude -
truth and estimates - is roll/pitch/yaw of the body relative to the orbit (LVLH) frame at
t = 0; otherwise relative to the inertial frame"). A frame swap in that composition
(``R_OB R_IO`` for ``R_IO R_OB``, or ``R_IO`` transposed) moves S3's initial truth by 4 deg
and S1's estimator start by 176 deg, and only the bit-exact regression record noticed it.
These tests recompute, with numpy only and independently of ``drake_att.rotations`` and
``drake_att.orbit``:

* the LVLH frame at t = 0 of a circular orbit (``orbit.py``'s definition: ``z_O`` to nadir,
  ``y_O`` along the negative orbit normal, ``x_O = y_O x z_O`` along the velocity) from the
  inclination, RAAN and argument of latitude: position direction
  ``Rz(RAAN) Rx(inc) [cos u, sin u, 0]``, orbit normal ``Rz(RAAN) Rx(inc) [0, 0, 1]``;
* roll/pitch/yaw as ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (``rotations.rpy_to_quat``, Drake's
  ``RollPitchYaw``: extrinsic x-y-z), cross-checked against ``pydrake.math.RollPitchYaw``;
* ``R_IB(0) = R_IO(0) R_OB(rpy)`` (or ``R_IB = R(rpy)`` without an orbit),

and compare them to ``1e-12`` with what the diagram holds: the truth system's ``q_IB`` output
in a context made by ``ScenarioDiagram.create_context`` and each estimator's ``q_IB_hat``
output (and its core's state) in that context at t = 0, before any update. Particle filters
report the mean of a drawn cloud (seed 0) there, so for them the default context is checked
to the cloud's Monte Carlo tolerance and the centre to 1e-12 with a negligible spread.

The YAML files are read with a plain ``yaml.safe_load`` (tags kept as a ``!tag`` key); a field
a file leaves out takes the config dataclass's default, read from the loaded scenario.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml
from pydrake.math import RollPitchYaw

from drake_att.scenarios import library
from drake_att.scenarios.build_context import attitude_from_rpy_deg
from drake_att.scenarios.builder import diagram_for
from drake_att.systems.estimator_system import EstimatorSystem

TOL = 1e-12
DEG = math.pi / 180.0
SCENARIOS = sorted(library.available_scenarios())


# ------------------------------------------------------------------------------------------
# The oracle: numpy only
# ------------------------------------------------------------------------------------------
def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def R_from_rpy_deg(rpy_deg):
    """``R = Rz(yaw) Ry(pitch) Rx(roll)``: roll about x, then pitch about the fixed y, then
    yaw about the fixed z."""
    r, p, y = (float(a) * DEG for a in rpy_deg)
    return Rz(y) @ Ry(p) @ Rx(r)


def R_IO_lvlh(inclination_deg, raan_deg, arg_latitude_deg):
    """Columns: the LVLH axes ``x_O, y_O, z_O`` in I for a circular orbit at argument of
    latitude ``u``."""
    M = Rz(raan_deg * DEG) @ Rx(inclination_deg * DEG)
    u = arg_latitude_deg * DEG
    r_hat = M @ np.array([math.cos(u), math.sin(u), 0.0])  # position direction
    v_hat = M @ np.array([-math.sin(u), math.cos(u), 0.0])  # velocity direction
    h_hat = np.cross(r_hat, v_hat)  # orbit normal
    z_O = -r_hat
    y_O = -h_hat
    x_O = np.cross(y_O, z_O)
    return np.column_stack([x_O, y_O, z_O])


def R_IO_tle(line1, line2, epoch_utc):
    """The LVLH axes at the epoch from ``sgp4``'s TEME state turned into GCRS by astropy."""
    from astropy import units as u
    from astropy.coordinates import GCRS, TEME, CartesianDifferential, CartesianRepresentation
    from astropy.time import Time
    from sgp4.api import Satrec, jday

    when = Time(epoch_utc.rstrip("Z"), scale="utc")
    jd, fr = jday(*when.ymdhms)
    err, r, v = Satrec.twoline2rv(line1, line2).sgp4(jd, fr)
    assert err == 0
    teme = TEME(
        CartesianRepresentation(np.array(r) * u.km, differentials=CartesianDifferential(np.array(v) * u.km / u.s)),
        obstime=when,
    )
    g = teme.transform_to(GCRS(obstime=when))
    r_I = g.cartesian.xyz.to_value(u.m)
    v_I = g.cartesian.differentials["s"].d_xyz.to_value(u.m / u.s)
    z_O = -r_I / np.linalg.norm(r_I)
    y_O = -np.cross(r_I, v_I) / np.linalg.norm(np.cross(r_I, v_I))
    return np.column_stack([np.cross(y_O, z_O), y_O, z_O])


def R_of_quat_wxyz(q):
    """Rotation matrix of a unit Hamilton quaternion ``[w, x, y, z]`` (asserted unit)."""
    q = np.asarray(q, dtype=float)
    assert q.shape == (4,) and abs(np.linalg.norm(q) - 1.0) < TOL, q
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def angle_deg(R_a, R_b):
    c = (np.trace(R_a.T @ R_b) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def assert_attitude(q_library, R_expected, what, tol=TOL):
    R = R_of_quat_wxyz(q_library)
    err = np.max(np.abs(R - R_expected))
    assert err <= tol, (
        f"{what}: the library's initial attitude is {angle_deg(R, R_expected):.6g} deg from the one "
        f"computed from the YAML (max matrix entry error {err:.3g})"
    )


# ------------------------------------------------------------------------------------------
# Plain YAML reading
# ------------------------------------------------------------------------------------------
class _TaggedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that keeps a mapping's ``!Tag`` under the key ``"!tag"``."""


def _tagged_mapping(loader, tag_suffix, node):
    out = loader.construct_mapping(node, deep=True)
    out["!tag"] = tag_suffix
    return out


_TaggedLoader.add_multi_constructor("!", _tagged_mapping)


def raw_yaml(name):
    with open(library.available_scenarios()[name]) as f:
        return yaml.load(f, Loader=_TaggedLoader)


def field_value(raw: dict, loaded, field: str):
    """The YAML's value of ``field``, or the loaded config's (the dataclass default) when the
    file leaves it out; a value the file gives must be the one the loader kept."""
    if field in raw:
        assert np.allclose(
            np.asarray(raw[field], dtype=float), np.asarray(getattr(loaded, field), dtype=float), rtol=0, atol=0
        ), field
        return raw[field]
    return getattr(loaded, field)


class Expected:
    """The initial attitudes of one scenario, computed from its YAML."""

    def __init__(self, name):
        self.raw = raw_yaml(name)
        self.scenario = library.load(name)
        self.tol = TOL
        orbit = self.raw.get("orbit")
        assert (orbit is None) == (self.scenario.orbit is None)
        if orbit is None:
            self.R_ref = np.eye(3)
        elif orbit.get("!tag") == "TleOrbitConfig":
            self.R_ref = R_IO_tle(orbit["line1"], orbit["line2"], orbit["epoch_utc"])
            # astropy's GCRS velocity (with the frame's own motion) turns the LVLH frame by ~1 mas
            self.tol = 1e-8
        else:
            inc, raan, u0 = (
                float(field_value(orbit, self.scenario.orbit, f))
                for f in ("inclination_deg", "raan_deg", "arg_latitude0_deg")
            )
            self.R_ref = R_IO_lvlh(inc, raan, u0)
        plant = self.raw.get("plant", {})
        tag = plant.get("!tag", type(self.scenario.plant).__name__)
        assert tag == type(self.scenario.plant).__name__
        if tag == "PrescribedRpyConfig":
            rpy0 = np.asarray(field_value(plant, self.scenario.plant, "rpy_deg"), dtype=float)[0]
        else:
            rpy0 = field_value(plant, self.scenario.plant, "initial_attitude_rpy_deg")
        self.truth = self.R_ref @ R_from_rpy_deg(rpy0)
        self.estimates = {}
        configs = {e.name: e for e in self.scenario.estimators}
        raw_estimators = self.raw.get("estimators", [])
        assert [e["name"] for e in raw_estimators] == list(configs)
        for e in raw_estimators:
            c = configs[e["name"]]
            if hasattr(c, "initial_attitude_rpy_deg"):
                self.estimates[c.name] = self.R_ref @ R_from_rpy_deg(field_value(e, c, "initial_attitude_rpy_deg"))
            else:  # a fusion of other estimators (S3's decentralized): starts where its sources start
                sources = e["sources"]
                starts = [self.estimates[s] for s in sources]
                assert all(np.allclose(s, starts[0], rtol=0, atol=TOL) for s in starts), (c.name, "sources differ")
                self.estimates[c.name] = starts[0]


_EXPECTED: dict[str, Expected] = {}


def expected(name) -> Expected:
    if name not in _EXPECTED:
        _EXPECTED[name] = Expected(name)
    return _EXPECTED[name]


def is_particle_filter(system) -> bool:
    return isinstance(system, EstimatorSystem) and system.num_particles is not None


def particle_tolerance(config, num_particles) -> float:
    """Bound on the matrix-entry error of a particle cloud's mean: a draw of N points with
    per-axis sigma s has a mean error of about s sqrt(3 / N) rad; 6 times that (a fixed
    draw, seed 0: not flaky, and 0.3 deg for S0's 1 deg / 1000 particles - far below any
    frame error)."""
    return 6.0 * config.initial_attitude_sigma_deg * DEG * math.sqrt(3.0 / num_particles)


# ------------------------------------------------------------------------------------------
# The oracle itself
# ------------------------------------------------------------------------------------------
def test_oracle_rpy_matches_pydrake_roll_pitch_yaw():
    rng = np.random.default_rng(23)
    for rpy in [[30.0, 0, 0], [0, 30.0, 0], [0, 0, 30.0], [-45.0, 45.0, 155.0], [90.0, 0.0, 90.0]] + list(
        rng.uniform(-180, 180, (20, 3))
    ):
        R_drake = RollPitchYaw(np.asarray(rpy, dtype=float) * DEG).ToRotationMatrix().matrix()
        np.testing.assert_allclose(R_from_rpy_deg(rpy), R_drake, rtol=0, atol=1e-15)
    # roll, pitch and yaw are about x, y, z: yaw 90 takes x to y; roll 90 takes y to z.
    np.testing.assert_allclose(R_from_rpy_deg([0, 0, 90]) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(R_from_rpy_deg([90, 0, 0]) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    # S4's comment: roll 90, yaw 90 is eq. 34's R_BI = [[0,1,0],[0,0,1],[1,0,0]] transposed.
    np.testing.assert_allclose(R_from_rpy_deg([90, 0, 90]).T, [[0, 1, 0], [0, 0, 1], [1, 0, 0]], atol=1e-15)


def test_oracle_lvlh_axes():
    """z_O to nadir, y_O along -h, x_O along the velocity; a rotation; equatorial prograde
    orbit at u = 0: x_O = y_I, y_O = -z_I, z_O = -x_I."""
    np.testing.assert_allclose(R_IO_lvlh(0.0, 0.0, 0.0), [[0, 0, -1], [1, 0, 0], [0, -1, 0]], atol=1e-15)
    R = R_IO_lvlh(97.5, 40.0, 70.0)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)


# ------------------------------------------------------------------------------------------
# Every shipped scenario
# ------------------------------------------------------------------------------------------
def test_every_shipped_scenario_is_covered():
    assert len(SCENARIOS) >= 10 and {"s1_cqe", "cubesat_dual_star_tracker", "s2_indoor_dynamic", "s4_lie_group"} <= set(
        SCENARIOS
    )


@pytest.mark.parametrize("name", SCENARIOS)
def test_initial_truth_and_estimates(name):
    exp = expected(name)
    sd = diagram_for(exp.scenario)
    context = sd.create_context(exp.scenario.seed)
    assert context.get_time() == 0.0
    truth_context = sd.truth.GetMyContextFromRoot(context)
    assert_attitude(sd.truth.GetOutputPort("q_IB").Eval(truth_context), exp.truth, f"{name}: truth q_IB", exp.tol)
    assert_attitude(sd.initial_q_IB(), exp.truth, f"{name}: ScenarioDiagram.initial_q_IB", exp.tol)
    assert set(sd.estimators) == set(exp.estimates)
    for est_name, R_expected in exp.estimates.items():
        system = sd.estimators[est_name]
        sub = system.GetMyContextFromRoot(context)
        q_hat = system.GetOutputPort("q_IB_hat").Eval(sub)
        what = f"{name}: estimator {est_name!r} q_IB_hat at t = 0"
        if is_particle_filter(system):  # its centre is checked to 1e-12 below
            assert name in WITH_PARTICLE_FILTERS, f"{est_name}: add its tag to PARTICLE_FILTER_TAGS"
            config = next(e for e in exp.scenario.estimators if e.name == est_name)
            assert_attitude(q_hat, R_expected, what, particle_tolerance(config, system.num_particles))
            continue
        assert_attitude(q_hat, R_expected, what, exp.tol)
        if isinstance(system, EstimatorSystem):  # the core's own state agrees with its output
            core = system.filter_model(sub).core
            q_core = core.estimate(core.from_vector(system.filter_state(sub)))[0]
            assert_attitude(q_core, R_expected, f"{name}: estimator {est_name!r} core state at t = 0", exp.tol)


PARTICLE_FILTER_TAGS = ("BootstrapPfConfig", "EkpfConfig", "GyrolessPfConfig")
WITH_PARTICLE_FILTERS = [
    n for n in SCENARIOS if any(e.get("!tag") in PARTICLE_FILTER_TAGS for e in raw_yaml(n).get("estimators", []))
]


@pytest.mark.parametrize("name", WITH_PARTICLE_FILTERS)
def test_particle_filter_cloud_centre(name):
    """The centre of each particle filter's initial cloud, to 1e-12: the same diagram with
    the initial attitude sigma made negligible (a context parameter), so the cloud's mean is
    its centre; checked in the default context and after the initialization event's draw."""
    from pydrake.systems.analysis import Simulator

    exp = expected(name)
    sd = diagram_for(exp.scenario)
    pfs = [n for n, s in sd.estimators.items() if is_particle_filter(s)]
    assert pfs
    tiny = 1e-10  # deg: a spread of ~2e-12 rad
    context = sd.create_context(
        exp.scenario.seed, overrides=[f"estimators.{n}.initial_attitude_sigma_deg={tiny}" for n in pfs]
    )
    for n in pfs:
        system = sd.estimators[n]
        sub = system.GetMyContextFromRoot(context)
        assert_attitude(system.GetOutputPort("q_IB_hat").Eval(sub), exp.estimates[n], f"{name}: {n} cloud centre")
    simulator = Simulator(sd.diagram, context)
    simulator.Initialize()  # the initialization event draws each run's cloud (no filter step yet)
    for n in pfs:
        system = sd.estimators[n]
        sub = system.GetMyContextFromRoot(context)
        core = system.filter_model(sub).core
        q_drawn = core.estimate(core.from_vector(system.filter_state(sub)))[0]
        assert_attitude(q_drawn, exp.estimates[n], f"{name}: {n} drawn cloud's mean", tol=1e-10)


# ------------------------------------------------------------------------------------------
# The composition itself, for orbits and angles no shipped scenario uses
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "orbit_deg, rpy_deg",
    [
        ((97.5, 0.0, 0.0), (2.0, -2.0, 2.0)),
        ((51.6, 120.0, 35.0), (-45.0, 45.0, 155.0)),
        ((0.0, 0.0, 0.0), (10.0, 20.0, 30.0)),
        ((180.0, -30.0, 200.0), (170.0, -80.0, -120.0)),
        ((63.4, 275.0, -90.0), (0.0, 0.0, 0.0)),
    ],
)
def test_attitude_from_rpy_deg_with_any_orbit(orbit_deg, rpy_deg):
    """``attitude_from_rpy_deg`` (what the plant and every estimator plug-in call) is
    ``R_IO(0) R(rpy)`` for any inclination, RAAN and argument of latitude (the shipped
    scenarios all have RAAN = u0 = 0, under which a swapped RAAN/inclination order or a sign of
    u would go unseen)."""
    base = library.load("s1_cqe")
    inc, raan, u0 = orbit_deg
    scenario = dataclasses.replace(
        base, orbit=dataclasses.replace(base.orbit, inclination_deg=inc, raan_deg=raan, arg_latitude0_deg=u0)
    )
    assert_attitude(
        attitude_from_rpy_deg(scenario, rpy_deg),
        R_IO_lvlh(inc, raan, u0) @ R_from_rpy_deg(rpy_deg),
        f"orbit {orbit_deg}, rpy {rpy_deg}",
    )
    no_orbit = dataclasses.replace(base, orbit=None)
    assert_attitude(attitude_from_rpy_deg(no_orbit, rpy_deg), R_from_rpy_deg(rpy_deg), f"no orbit, rpy {rpy_deg}")


@pytest.mark.parametrize("name", ["s1_cqe", "cubesat_single_star_tracker", "s4_lie_group"])
def test_overridden_initial_attitudes(name):
    """The sweep path (``create_context(overrides=...)``, parameters rebuilt by the plug-ins)
    composes new initial attitudes the same way."""
    exp = expected(name)
    sd = diagram_for(exp.scenario)
    truth_rpy, est_rpy = [12.0, -7.0, 33.0], [-60.0, 25.0, -140.0]
    est_name = next(n for n, s in sd.estimators.items() if isinstance(s, EstimatorSystem))
    context = sd.create_context(
        exp.scenario.seed,
        overrides=[
            f"plant.initial_attitude_rpy_deg={truth_rpy}",
            f"estimators.{est_name}.initial_attitude_rpy_deg={est_rpy}",
        ],
    )
    truth_context = sd.truth.GetMyContextFromRoot(context)
    assert_attitude(
        sd.truth.GetOutputPort("q_IB").Eval(truth_context),
        exp.R_ref @ R_from_rpy_deg(truth_rpy),
        f"{name}: overridden truth",
    )
    system = sd.estimators[est_name]
    assert_attitude(
        system.GetOutputPort("q_IB_hat").Eval(system.GetMyContextFromRoot(context)),
        exp.R_ref @ R_from_rpy_deg(est_rpy),
        f"{name}: overridden {est_name}",
    )
