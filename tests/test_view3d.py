"""The 3-D view of a saved run (drake_att.analysis.view3d, ``drake-att view``).

One short run of a scenario with a Keplerian orbit at an epoch and two star trackers with
exclusion cones is written by ``drake-att run`` and viewed once; the checks read back what
the static page carries (Meshcat's embedded commands, decoded here with msgpack) and
compare it with the log, the configuration and astropy, each converted here from its
definition.

With ``DRAKE_ATT_DOCS_SCREENSHOTS=<folder>`` the browser test also writes its screenshot
there as ``view3d.png`` (``docs/screenshots`` holds the committed one).
"""

from __future__ import annotations

import base64
import dataclasses
import os
import re
import shutil

import msgpack
import numpy as np
import pytest

from drake_att import cli
from drake_att.analysis import campaign_report, view3d
from drake_att.orbit_propagators import KeplerOrbit

R_E = 6378137.0
EPOCH = "2026-03-20T12:00:00Z"
FRAMES = 150
PLAYBACK_S = 12.0
STILL_S = 300.0
SCENARIO = f"""
name: view_test
duration_s: 600.0
seed: 1
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.25}}
orbit: !KeplerOrbitConfig {{epoch_utc: '{EPOCH}', semi_major_axis_km: 6878.137, inclination_deg: 97.5,
                          raan_deg: 80.0}}
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  initial_attitude_rpy_deg: [10.0, -20.0, 30.0]
  initial_rate_deg_per_s: [0.1, -0.2, 0.3]
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.56, rrw_deg_per_h15: 123.75,
               initial_bias_deg_per_h: [12.0, 12.0, 12.0]}}
- !StarTrackerConfig
  name: st1
  period_s: 1.0
  mounting: !RpyMounting {{rpy_deg: [90.0, 0.0, 0.0]}}
  sigma_cross_boresight_arcsec: 5.0
  sigma_boresight_arcsec: 50.0
  exclusion: {{sun_deg: 40.0, earth_limb_deg: 20.0, moon_deg: 10.0}}
- !StarTrackerConfig
  name: st2
  period_s: 1.0
  mounting: !RpyMounting {{rpy_deg: [0.0, -90.0, 0.0]}}
  sigma_cross_boresight_arcsec: 5.0
  sigma_boresight_arcsec: 50.0
  exclusion: {{}}
estimators:
- !MekfConfig {{name: mekf, gyro: gyro, star_trackers: [st1, st2], initial_attitude_sigma_deg: 5.0}}
- !MekfConfig {{name: mekf_st1, gyro: gyro, star_trackers: [st1], initial_attitude_sigma_deg: 5.0}}
scoring: {{score_from_s: 0.0}}
"""
# The exclusion half-angles above (st2: the defaults, 45 / 25 / 12 deg), and the boresights in B:
# S's +z turned by Rx(90 deg) is -y_B, by Ry(-90 deg) it is -x_B.
CONES_DEG = {
    "st1": {"sun": 40.0, "earth_limb": 20.0, "moon": 10.0},
    "st2": {"sun": 45.0, "earth_limb": 25.0, "moon": 12.0},
}
BORESIGHT_B = {"st1": [0.0, -1.0, 0.0], "st2": [-1.0, 0.0, 0.0]}


def _rotation_wxyz(q) -> np.ndarray:
    """R of a Hamilton quaternion [w, x, y, z] (the textbook formula)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )


def _rotation_xyzw(v) -> np.ndarray:
    """three.js keeps quaternions as [x, y, z, w]."""
    x, y, z, w = v
    return _rotation_wxyz([w, x, y, z])


def _commands(page: str) -> list[dict]:
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", page)
    return [msgpack.unpackb(base64.b64decode(b), strict_map_key=False) for b in blobs]


@pytest.fixture(scope="module")
def viewed(tmp_path_factory):
    """The run folder, its log, the geometry, the static page and its decoded commands."""
    from pydrake.geometry import Meshcat

    root = tmp_path_factory.mktemp("view")
    (root / "scenario.yaml").write_text(SCENARIO)
    out = root / "run"
    assert cli.main(["run", str(root / "scenario.yaml"), "--out", str(out), "--quiet", "--no-figures"]) == 0
    meshcat = Meshcat()
    page = root / "view.html"
    _, geometry = view3d.view_run(
        str(out), meshcat=meshcat, html_path=str(page), frames=FRAMES, playback_s=PLAYBACK_S, still_time_s=STILL_S
    )
    text = page.read_text(encoding="utf-8")
    with np.load(out / "log.npz") as npz:
        t_truth, q_truth = npz["rigid_body_plant__q_IB__t"], npz["rigid_body_plant__q_IB__x"]
        est = {n: (npz[f"{n}__q_IB_hat__t"], npz[f"{n}__q_IB_hat__x"]) for n in ("mekf", "mekf_st1")}
    return {
        "out": out,
        "meshcat": meshcat,
        "geometry": geometry,
        "page": page,
        "text": text,
        "commands": _commands(text),
        "t_truth": t_truth,
        "q_truth": q_truth,
        "estimates": est,
    }


def _objects(commands) -> dict:
    return {c["path"]: c["object"] for c in commands if c.get("type") == "set_object"}


def _last_transform(commands, path) -> np.ndarray:
    matrix = [c["matrix"] for c in commands if c.get("type") == "set_transform" and c["path"] == path][-1]
    return np.asarray(matrix, dtype=float).reshape(4, 4).T  # column-major


def _animation(commands) -> dict:
    """path -> (fps, [(frame, [x, y, z, w]), ...]) of the published animation."""
    anim = [c for c in commands if c.get("type") == "set_animation"][-1]
    out = {}
    for a in anim["animations"]:
        track = next(t for t in a["clip"]["tracks"] if t["name"] == ".quaternion")
        out[a["path"]] = (a["clip"]["fps"], [(k["time"], k["value"]) for k in track["keys"]])
    return out, anim["options"]


def test_the_scene_holds_the_spacecraft_trackers_cones_estimates_and_directions(viewed):
    meshcat = viewed["meshcat"]
    truth = view3d.TRUTH_PATH
    expected = [f"{truth}/spacecraft", f"{truth}/triad/x", f"{truth}/triad/z", f"{view3d.ROOT}/inertial/x"]
    for name in ("st1", "st2"):
        expected += [f"{truth}/trackers/{name}/boresight"]
        expected += [f"{truth}/trackers/{name}/cones/{k}" for k in ("sun", "earth_limb", "moon")]
    expected += [f"{view3d.ESTIMATES_PATH}/{n}/{a}" for n in ("mekf", "mekf_st1") for a in "xyz"]
    expected += [f"{view3d.DIRECTIONS_PATH}/{b}/arrow/head" for b in ("earth", "sun", "moon")]
    expected += [f"{view3d.DIRECTIONS_PATH}/earth/disk/rim"]
    assert [p for p in expected if not meshcat.HasPath(p)] == []
    assert not meshcat.HasPath(f"{truth}/trackers/gyro")  # only star trackers have boresights
    # The page carries the same objects, and the box is the 3U CubeSat of the inertia.
    objects = _objects(viewed["commands"])
    assert [p for p in expected if p not in objects] == []
    box = objects[f"{truth}/spacecraft"]["geometries"][0]
    edges = sorted([box["width"], box["height"], box["depth"]])
    np.testing.assert_allclose(edges, [0.0997, 0.0997, 0.3387], atol=2e-4)


def test_the_truth_frame_follows_the_logged_attitude(viewed):
    """Every keyframe of the truth's animated transform is the logged q_IB at the frame's time
    (frames evenly spread over the log's samples), played at (frames - 1) / playback_s frames/s;
    the still scene shows the sample nearest STILL_S."""
    t, q = viewed["t_truth"], viewed["q_truth"]
    animation, options = _animation(viewed["commands"])
    fps, keys = animation[view3d.TRUTH_PATH]
    assert len(keys) == FRAMES and [k for k, _ in keys] == list(range(FRAMES))
    assert fps == pytest.approx((FRAMES - 1) / PLAYBACK_S)
    assert options["play"] is False
    rows = np.round(np.linspace(0, len(t) - 1, FRAMES)).astype(int)
    for k in (0, 37, FRAMES // 2, FRAMES - 1):
        np.testing.assert_allclose(_rotation_xyzw(keys[k][1]), _rotation_wxyz(q[rows[k]]), atol=1e-9)
        # the keyframe's playback time, scaled back to the run, is the sample's time (to a sample)
        assert abs(keys[k][0] / fps * t[-1] / PLAYBACK_S - t[rows[k]]) <= (t[1] - t[0])
    still = int(np.argmin(np.abs(t[rows] - STILL_S)))
    X = _last_transform(viewed["commands"], view3d.TRUTH_PATH)
    np.testing.assert_allclose(X[:3, :3], _rotation_wxyz(q[rows[still]]), atol=1e-9)
    np.testing.assert_allclose(X[:3, 3], 0.0)
    # each estimate: the latest logged value at or before the frame
    for name, (t_hat, q_hat) in viewed["estimates"].items():
        _, keys_hat = animation[f"{view3d.ESTIMATES_PATH}/{name}"]
        for k in (1, FRAMES - 2):
            j = np.flatnonzero(t_hat <= t[rows[k]])[-1]
            np.testing.assert_allclose(_rotation_xyzw(keys_hat[k][1]), _rotation_wxyz(q_hat[j]), atol=1e-9)


def test_sun_moon_and_earth_directions_are_the_ephemeris_seen_from_the_orbit(viewed):
    """The arrows' +z at a few frames: the Sun and the Moon from astropy's built-in ephemeris
    (GCRS) minus the spacecraft's position (two-body Kepler from the config's elements), and
    nadir."""
    from astropy import units as u
    from astropy.coordinates import get_body, solar_system_ephemeris
    from astropy.time import Time, TimeDelta
    from astropy.utils import iers

    iers.conf.auto_download = False
    t = viewed["t_truth"]
    rows = np.round(np.linspace(0, len(t) - 1, FRAMES)).astype(int)
    frames = [0, FRAMES // 3, FRAMES - 1]
    times = t[rows[frames]]
    orbit = KeplerOrbit(6878.137e3, 0.0, np.radians(97.5), np.radians(80.0))
    r = orbit.position_velocity_I(times)[0]
    when = Time(EPOCH.rstrip("Z"), scale="utc") + TimeDelta(times, format="sec")
    animation, _ = _animation(viewed["commands"])
    with solar_system_ephemeris.set("builtin"):
        bodies = {b: get_body(b, when).cartesian.xyz.to_value(u.m).T for b in ("sun", "moon")}
    expected = {"sun": bodies["sun"] - r, "moon": bodies["moon"] - r, "earth": -r}
    for body, vectors in expected.items():
        _, keys = animation[f"{view3d.DIRECTIONS_PATH}/{body}"]
        for i, k in enumerate(frames):
            shown = _rotation_xyzw(keys[k][1])[:, 2]
            want = vectors[i] / np.linalg.norm(vectors[i])
            angle = np.arctan2(np.linalg.norm(np.cross(shown, want)), shown @ want)
            assert angle < 2e-6, (body, k, angle)
    # The Sun's parallax over the orbit is ~4e-5 rad: the test above sees the spacecraft's position.
    assert np.max(np.linalg.norm(r, axis=1)) / 1.496e11 > 4e-5


def test_the_cones_have_the_configured_half_angles_about_each_boresight(viewed):
    """Each cone's geometry (three.js cylinder, radiusBottom 0, in its object matrix) gives the
    configured half-angle with the apex at the body's centre, opening along the sensor's +z;
    the tracker frame turns +z onto the configured boresight in B."""
    objects = _objects(viewed["commands"])
    for name, cones in CONES_DEG.items():
        path = f"{view3d.TRUTH_PATH}/trackers/{name}"
        X = _last_transform(viewed["commands"], path)
        np.testing.assert_allclose(X[:3, 2], BORESIGHT_B[name], atol=1e-12)
        for kind, half_angle in cones.items():
            obj = objects[f"{path}/cones/{kind}"]
            geo = obj["geometries"][0]
            assert geo["type"] == "CylinderGeometry" and geo["radiusBottom"] == 0.0
            M = np.asarray(obj["object"]["matrix"], dtype=float).reshape(4, 4).T
            h = geo["height"]
            apex = (M @ [0.0, -h / 2, 0.0, 1.0])[:3]
            centre = (M @ [0.0, h / 2, 0.0, 1.0])[:3]
            rims = [(M @ [geo["radiusTop"] * np.cos(a), h / 2, geo["radiusTop"] * np.sin(a), 1.0])[:3] for a in (0, 2)]
            np.testing.assert_allclose(apex, 0.0, atol=1e-12)
            assert centre[2] > 0 and np.allclose(centre[:2], 0.0, atol=1e-12)
            for rim in rims:
                angle = np.degrees(np.arctan2(np.linalg.norm(rim - centre), np.linalg.norm(centre - apex)))
                assert angle == pytest.approx(half_angle, abs=1e-9), (name, kind)


def test_the_legend_says_what_is_not_drawn_without_an_epoch_or_an_orbit(viewed):
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios.builder import RunLog

    run = RunLog.load(str(viewed["out"]))
    full = "\n".join(view3d.legend(viewed["geometry"], PLAYBACK_S))
    assert "Sun (yellow)" in full and "Not shown" not in full and f"{FRAMES} frames" in full
    circular = dataclasses.replace(run, scenario=dataclasses.replace(run.scenario, orbit=cfg.OrbitConfig()))
    g = view3d.view_geometry(circular, frames=10)
    assert set(g.directions_I) == {"earth"}
    assert any("no epoch" in line and "Sun" in line for line in view3d.legend(g))
    bare = dataclasses.replace(run, scenario=dataclasses.replace(run.scenario, orbit=None))
    g = view3d.view_geometry(bare, frames=10)
    assert g.directions_I == {} and g.earth_disk_deg is None
    assert any(line.startswith("Not shown: no orbit") for line in view3d.legend(g))


@pytest.mark.parametrize(
    "inertia",
    [[0.042, 0.042, 0.0067], [[0.04, 0.005, 0.0], [0.005, 0.04, 0.0], [0.0, 0.0, 0.015]]],
)
def test_the_box_of_an_inertia_has_that_inertia_and_the_density(inertia):
    """m = density * a b c and I_x = m (b^2 + c^2) / 12 etc. about the box's axes, turned into B."""
    edges, q_B_box, mass = view3d.box_from_inertia(inertia, 1200.0)
    a, b, c = edges
    assert mass == pytest.approx(1200.0 * a * b * c, rel=1e-12)
    I_box = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * mass / 12.0
    R = _rotation_wxyz(q_B_box)
    I = np.asarray(inertia, dtype=float)
    np.testing.assert_allclose(R @ I_box @ R.T, np.diag(I) if I.ndim == 1 else I, atol=1e-14)


def test_the_static_page_is_self_contained(viewed):
    """Every script is inline and nothing is fetched from the network at load (the test of the
    documentation site's pattern); the scene comes as embedded data: URLs. Meshcat's bundled
    three.js names a CDN (jsdelivr's WebXR controller profiles) that only VR mode would fetch."""
    text = viewed["text"]
    fetched = re.compile(
        r"""<(?:script|img|iframe|source|audio|video|embed)\b[^>]*\bsrc\s*=\s*["']?((?:https?:)?//[^"'\s>]+)"""
        r"""|<link\b(?=[^>]*\brel\s*=\s*["']?(?:stylesheet|preload|preconnect|icon|modulepreload))[^>]*\bhref\s*=\s*["']?((?:https?:)?//[^"'\s>]+)"""
        r"""|@import\s+(?:url\()?["']?((?:https?:)?//[^"')\s]+)"""
        r"""|url\(\s*["']?((?:https?:)?//[^"')\s]+)""",
        re.IGNORECASE,
    )
    assert fetched.findall(text) == []
    assert re.findall(r"<script\b[^>]*\bsrc\s*=", text, re.IGNORECASE) == []
    assert re.findall(r"""fetch\(\s*["'](?!data:)""", text) == []
    assert len(viewed["commands"]) > 20 and view3d.LEGEND_ID in text


def _console_errors(stderr: str) -> list[str]:
    """The page's console messages and uncaught errors, less SwiftShader's "GPU stall due to
    ReadPixels" performance notes (the software WebGL driver's, on every read-back)."""
    return [
        line
        for line in stderr.splitlines()
        if (":CONSOLE" in line or "Uncaught" in line) and "GL Driver Message (OpenGL, Performance" not in line
    ]


# Software WebGL (Chromium has no GPU here): SwiftShader, opted in explicitly.
WEBGL = ["--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--virtual-time-budget=6000"]


@pytest.mark.skipif(
    campaign_report.find_chromium() is None,
    reason="no Chromium on PATH (Debian: apt-get install chromium); the page is not opened in a browser",
)
def test_the_static_page_renders_in_headless_chromium_without_console_errors(viewed, tmp_path):
    chromium = campaign_report.find_chromium()
    shot = tmp_path / "view3d.png"
    proc = campaign_report.run_headless_chromium(
        chromium, str(viewed["page"]), [*WEBGL, f"--screenshot={shot}", "--window-size=1280,800"], 120
    )
    assert proc.returncode == 0 and shot.is_file(), proc.stderr[-1000:]
    assert _console_errors(proc.stderr) == [], _console_errors(proc.stderr)[:3]
    from PIL import Image

    with Image.open(shot) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=float)
    assert rgb.shape == (800, 1280, 3)
    # The scene was drawn: the Sun cones' translucent yellow (the background is a dark blue, never
    # warm), and the nadir arrow's and the Earth disk's blue.
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    assert np.mean((r - b > 15) & (g - b > 10)) > 0.01
    assert np.mean((b > 150) & (r < 120)) > 0.0005
    folder = os.environ.get("DRAKE_ATT_DOCS_SCREENSHOTS")
    if folder:
        os.makedirs(folder, exist_ok=True)
        shutil.copyfile(shot, os.path.join(folder, "view3d.png"))
    # The detector works: a script error on the same page is caught.
    broken = tmp_path / "broken.html"
    broken.write_text(viewed["text"].replace("</body>", "<script>undefinedFunction();</script></body>", 1))
    caught = campaign_report.run_headless_chromium(chromium, str(broken), [*WEBGL, "--dump-dom"], 120)
    assert any("undefinedFunction" in line for line in _console_errors(caught.stderr))


def test_the_cli_writes_the_page_without_serving(viewed, tmp_path, capsys):
    page = tmp_path / "cli.html"
    code = cli.main(["view", str(viewed["out"]), "--no-serve", "--html", str(page), "--frames", "20"])
    out = capsys.readouterr().out
    assert code == 0 and page.is_file()
    assert "20 frames" in out and "Star tracker st1" in out and f"Wrote {page}" in out
    animation, _ = _animation(_commands(page.read_text(encoding="utf-8")))
    assert len(animation[view3d.TRUTH_PATH][1]) == 20


def test_the_page_replaces_only_a_page_of_its_own(viewed, tmp_path, capsys):
    """--html rewrites a page drake-att view wrote; a user's file, a folder or a link stays
    untouched and the command exits 2 with one line."""
    page = tmp_path / "again.html"
    page.write_text(viewed["text"], encoding="utf-8")  # a page of ours: replaced
    assert cli.main(["view", str(viewed["out"]), "--no-serve", "--html", str(page), "--frames", "10"]) == 0
    capsys.readouterr()
    animation, _ = _animation(_commands(page.read_text(encoding="utf-8")))
    assert len(animation[view3d.TRUTH_PATH][1]) == 10
    notes = tmp_path / "notes.html"
    notes.write_text("<html><body>my notes</body></html>")
    line = _refusal(capsys, ["view", str(viewed["out"]), "--no-serve", "--html", str(notes)])
    assert "is not a page drake-att view wrote; it is left untouched" in line
    assert notes.read_text() == "<html><body>my notes</body></html>"
    link = tmp_path / "link.html"
    link.symlink_to(page)
    assert "is not a regular file" in _refusal(capsys, ["view", str(viewed["out"]), "--no-serve", "--html", str(link)])
    assert "is not a regular file" in _refusal(
        capsys, ["view", str(viewed["out"]), "--no-serve", "--html", str(tmp_path)]
    )


def test_the_cli_serves_until_ctrl_c(viewed, capsys, monkeypatch):
    """Without --no-serve the command prints Meshcat's URL and waits; Ctrl-C ends it with exit 0."""
    import time

    def interrupted(seconds):
        raise KeyboardInterrupt

    monkeypatch.setattr(time, "sleep", interrupted)
    code = cli.main(["view", str(viewed["out"]), "--frames", "5"])
    captured = capsys.readouterr()
    assert code == 0
    assert re.search(r"Meshcat: http://\S+:\d+ \(Ctrl-C to stop\)", captured.out), captured.out
    assert captured.err.strip().endswith("drake-att view: stopped")


def _refusal(capsys, argv) -> str:
    code = cli.main(argv)
    captured = capsys.readouterr()
    assert code == 2, (argv, captured.err)
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    return lines[0]


def test_bad_folders_and_options_are_refused_in_one_line(viewed, tmp_path, capsys):
    run = str(viewed["out"])
    missing = tmp_path / "missing"
    assert _refusal(capsys, ["view", str(missing)]) == f"drake-att view: {missing}: no such result folder"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "log.npz: missing" in _refusal(capsys, ["view", str(empty)])
    assert "not a folder" in _refusal(capsys, ["view", str(viewed["page"])])
    campaign = tmp_path / "campaign"
    campaign.mkdir()
    (campaign / "campaign.json").write_text("{}")
    assert "is a Monte Carlo campaign folder" in _refusal(capsys, ["view", str(campaign)])
    corrupt = tmp_path / "corrupt"
    shutil.copytree(run, corrupt)
    (corrupt / "log.npz").write_bytes(b"not a zip archive")
    assert "log.npz: cannot be viewed: ValueError: not an .npz archive" in _refusal(capsys, ["view", str(corrupt)])
    (corrupt / "log.npz").unlink()
    shutil.copyfile(os.path.join(run, "log.npz"), corrupt / "log.npz")
    (corrupt / "config.yaml").write_text("name: [")
    assert "config.yaml: not a valid scenario" in _refusal(capsys, ["view", str(corrupt)])
    for argv, words in (
        (["--frames", "1"], "--frames: got 1; must be an integer in [2, 2000]"),
        (["--box-m", "0.1", "-1", "0.3"], "--box-m: got [0.1, -1.0, 0.3]"),
        (["--playback-s", "0"], "--playback-s: got 0.0"),
        (["--error-scale", "nan"], "--error-scale: got nan"),
        (["--at", "601"], "--at: got 601.0; a run time in [0, 600] s"),
        (["--html", " "], "--html: got ' '"),
        (["--frames", "x"], "argument --frames: invalid int value"),
    ):
        line = _refusal(capsys, ["view", run, "--no-serve", *argv])
        assert line.startswith("drake-att view") and words in line, (argv, line)
