"""Error figures for people (drake_att.analysis.report): titled with scenario, seed and
estimator; the whole-run figure shows the initial transient, the stable figure zooms in.

No simulation: the run is a hand-built ``RunLog`` whose yaw error is -170 deg for the first
5 s of 100 (a large-error start, as the large-error EKF's) and 0.01 deg afterwards.
"""

import math
import os

import numpy as np
import pytest

from drake_att.analysis import metrics, report
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import RunLog

DEG_ = math.pi / 180.0
DEG_PER_H_ = DEG_ / 3600.0
NAME = "large_error_ekf"
SCENARIO = "s0_large_error_demo"
SEED = 4242


def _qz(angle):
    """Unit quaternion (w, x, y, z) of a rotation by ``angle`` rad about z."""
    return np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])


def _yaw_error_deg(t):
    return np.where(t < 5.0, -170.0, 0.01)


@pytest.fixture(scope="module")
def transient_run():
    t = np.arange(100.0)
    # Truth: identity attitude, so dtheta = log(R_hat^T) = -(estimate's rotation vector):
    # an estimate rotated by +170 deg about z has a yaw error of -170 deg.
    q_true = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    q_hat = np.array([_qz(-e * DEG_) for e in _yaw_error_deg(t)])
    bias_true = np.tile([1.0, -2.0, 3.0], (len(t), 1)) * DEG_PER_H_
    bias_hat = bias_true - np.where(t[:, None] < 5.0, 50.0, 0.1) * DEG_PER_H_
    # 3 sigma: 540 deg at the start (an initial sigma of 180 deg), 0.03 deg afterwards
    s_att = np.where(t < 5.0, 180.0, 0.01) * DEG_
    s_bias = np.where(t < 5.0, 100.0, 0.2) * DEG_PER_H_
    P = np.array([np.diag([a * a] * 3 + [b * b] * 3) for a, b in zip(s_att, s_bias, strict=True)]).reshape(len(t), 36)
    status = np.column_stack([t, np.arange(len(t)), np.zeros(len(t)), np.zeros(len(t))])
    signals = {
        "plant/q_IB": (t, q_true),
        "plant/w_IB_B": (t, np.zeros((len(t), 3))),
        "gyro/bias_B": (t, bias_true),
        f"{NAME}/q_IB_hat": (t, q_hat),
        f"{NAME}/bias_B_hat": (t, bias_hat),
        f"{NAME}/covariance": (t, P),
        f"{NAME}/status": (t, status),
    }
    meta = {
        "schema": 1,
        "scenario": SCENARIO,
        "seed": SEED,
        "wall_time_s": 0.5,
        "signals": list(signals),
        "truth": {"attitude": "plant/q_IB", "rate": "plant/w_IB_B"},
        "estimators": {
            NAME: {
                "second_kind": "gyro_bias",
                "true_bias": "gyro/bias_B",
                "signals": {
                    "attitude": f"{NAME}/q_IB_hat",
                    "second": f"{NAME}/bias_B_hat",
                    "covariance": f"{NAME}/covariance",
                    "status": f"{NAME}/status",
                },
            }
        },
    }
    run = RunLog(scenario=cfg.Scenario(name=SCENARIO), seed=SEED, wall_time_s=0.5, signals=signals, metadata=meta)
    err = metrics.estimator_errors(run, NAME)["dtheta"][:, 2] / DEG_
    np.testing.assert_allclose(err, _yaw_error_deg(t), atol=1e-9)  # the run is what it claims
    return run


def test_full_figure_shows_the_whole_transient(transient_run):
    figs = report.estimator_figures(transient_run, NAME, score_from_s=20.0)
    assert set(figs) == {"full", "stable"}
    full = figs["full"]
    att = full.axes[:3]  # top row: attitude error x, y, z
    lo, hi = att[2].get_ylim()
    assert lo <= -170.0 <= hi, (lo, hi)
    for a in att + full.axes[3:6]:  # every error line (the first line of each axes) is inside
        y = a.get_lines()[0].get_ydata()
        lo, hi = a.get_ylim()
        assert lo <= np.min(y) and np.max(y) <= hi, (a.get_title(), lo, hi, np.min(y), np.max(y))
    # the 540 deg 3-sigma start is clipped (more than 3x the error): the error stays readable
    assert att[2].get_ylim()[1] < 540.0


def test_stable_figure_is_zoomed_on_the_scored_stage(transient_run):
    stable = report.estimator_figures(transient_run, NAME, score_from_s=20.0)["stable"]
    x = stable.axes[2].get_lines()[0].get_xdata()
    assert np.min(x) >= 20.0
    lo, hi = stable.axes[2].get_ylim()
    assert -0.1 < lo < 0.01 < hi < 0.1, (lo, hi)  # 0.01 deg error and 0.03 deg 3 sigma


def test_titles_name_scenario_seed_and_estimator(transient_run):
    figs = report.estimator_figures(transient_run, NAME, score_from_s=20.0)
    for stage, fig in figs.items():
        title = fig.get_suptitle()
        assert SCENARIO in title and f"seed {SEED}" in title and NAME in title, (stage, title)
    assert "t >= 20 s" in figs["stable"].get_suptitle()


def test_plot_estimator_saves_both_figures(transient_run, tmp_path):
    files = report.plot_estimator(transient_run, NAME, str(tmp_path), score_from_s=20.0)
    assert [os.path.basename(f) for f in files] == [f"{NAME}_errors_full.png", f"{NAME}_errors_stable.png"]
    for f in files:
        with open(f, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"


def test_no_stable_figure_without_a_stable_stage(transient_run):
    assert set(report.estimator_figures(transient_run, NAME, score_from_s=0.0)) == {"full"}


# --- y-limits, second row, figure size of the per-run error figures --------------------------


def test_zero_error_axis_shows_the_whole_three_sigma_band(transient_run):
    """The fixture's roll and pitch errors are exactly zero: their plots show the whole
    +-3 sigma band (540 deg at the start), not a sliver around zero."""
    full = report.estimator_figures(transient_run, NAME)["full"]
    for a in full.axes[:2]:
        y = a.get_lines()[0].get_ydata()
        assert np.all(y == 0.0), a.get_title()
        band = np.max(a.get_lines()[1].get_ydata())
        assert band == pytest.approx(540.0)
        lo, hi = a.get_ylim()
        assert lo <= -band and band <= hi < 1.2 * band, (a.get_title(), lo, hi)


def test_three_sigma_beyond_three_times_the_error_is_shown_up_to_three_times_the_error(transient_run):
    """Yaw: error 170 deg, 3 sigma 540 deg (> 3 x 170): the band is drawn up to 510 deg."""
    lo, hi = report.estimator_figures(transient_run, NAME)["full"].axes[2].get_ylim()
    assert lo <= -3 * 170.0 and 3 * 170.0 <= hi < 540.0, (lo, hi)


def test_bias_row_plots_the_bias_error_in_deg_per_hour(transient_run):
    """Bottom row: true bias - estimate, in deg/h (+50 deg/h for t < 5 s, +0.1 afterwards),
    versus time, titled and labelled as a bias error."""
    full = report.estimator_figures(transient_run, NAME)["full"]
    t = np.arange(100.0)
    for i, a in enumerate(full.axes[3:6]):
        line = a.get_lines()[0]
        np.testing.assert_array_equal(line.get_xdata(), t)
        np.testing.assert_allclose(line.get_ydata(), np.where(t < 5.0, 50.0, 0.1), rtol=1e-9)
        assert a.get_title() == f"bias error {['x (roll)', 'y (pitch)', 'z (yaw)'][i]}"
        assert a.get_ylabel() == "deg/h"
        assert a.get_xlabel() == "time (s)"


def _steady_run(second_kind):
    """20 s, zero attitude error (3 sigma 1 deg); a constant second-quantity error of
    (10, 20, 30) deg/h (gyro bias) or (0.1, 0.2, 0.3) deg/s (body rate) whose 3 sigma is twice
    the error (so the +-3 sigma lines are inside 3x the error and must be shown whole)."""
    t = np.arange(20.0)
    n = len(t)
    unit = DEG_PER_H_ if second_kind == "gyro_bias" else DEG_
    err = np.array([10.0, 20.0, 30.0]) if second_kind == "gyro_bias" else np.array([0.1, 0.2, 0.3])
    truth2 = np.tile([1.0, -2.0, 3.0], (n, 1)) * unit
    hat2 = truth2 - err * unit
    s2 = 2.0 * err / 3.0 * unit  # 3 sigma = 2 x error
    P = np.tile(np.diag([(DEG_ / 3.0) ** 2] * 3 + list(s2**2)).reshape(36), (n, 1))
    status = np.column_stack([t, np.arange(n), np.zeros(n), np.zeros(n)])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    second = "bias_B_hat" if second_kind == "gyro_bias" else "w_IB_B_hat"
    signals = {
        "plant/q_IB": (t, q),
        "plant/w_IB_B": (t, truth2 if second_kind == "body_rate" else np.zeros((n, 3))),
        f"{NAME}/q_IB_hat": (t, q),
        f"{NAME}/{second}": (t, hat2),
        f"{NAME}/covariance": (t, P),
        f"{NAME}/status": (t, status),
    }
    if second_kind == "gyro_bias":
        signals["gyro/bias_B"] = (t, truth2)
    meta = {
        "schema": 1,
        "scenario": SCENARIO,
        "seed": SEED,
        "wall_time_s": 0.5,
        "signals": list(signals),
        "truth": {"attitude": "plant/q_IB", "rate": "plant/w_IB_B"},
        "estimators": {
            NAME: {
                "second_kind": second_kind,
                "true_bias": "gyro/bias_B" if second_kind == "gyro_bias" else None,
                "signals": {
                    "attitude": f"{NAME}/q_IB_hat",
                    "second": f"{NAME}/{second}",
                    "covariance": f"{NAME}/covariance",
                    "status": f"{NAME}/status",
                },
            }
        },
    }
    return RunLog(scenario=cfg.Scenario(name=SCENARIO), seed=SEED, wall_time_s=0.5, signals=signals, metadata=meta), err


def test_bias_three_sigma_inside_three_times_the_error_is_shown_whole_and_tight():
    run, err = _steady_run("gyro_bias")
    full = report.estimator_figures(run, NAME)["full"]
    for i, a in enumerate(full.axes[3:6]):
        band = np.max(a.get_lines()[1].get_ydata())
        assert band == pytest.approx(2.0 * err[i])  # the 3 sigma line, deg/h
        lo, hi = a.get_ylim()
        assert lo == -hi and band <= hi <= 1.1 * band, (a.get_title(), hi, band)


def test_rate_estimator_figure_labels_the_rate_error_in_deg_per_second():
    run, err = _steady_run("body_rate")
    full = report.estimator_figures(run, NAME)["full"]
    for i, a in enumerate(full.axes[3:6]):
        assert a.get_title() == f"rate error {['x (roll)', 'y (pitch)', 'z (yaw)'][i]}"
        assert a.get_ylabel() == "deg/s"
        np.testing.assert_allclose(a.get_lines()[0].get_ydata(), err[i], rtol=1e-9)


def _png_size(path):
    import struct

    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def test_error_figure_is_14_in_wide_and_3_4_in_a_row_plus_the_title(transient_run):
    """Two rows (attitude and bias): 14 x (2 x 3.4 + 0.4) in."""
    fig = report.estimator_figures(transient_run, NAME)["full"]
    assert tuple(fig.get_size_inches()) == pytest.approx((14.0, 7.2))


def test_plot_estimator_writes_into_the_output_folder(transient_run, tmp_path, monkeypatch):
    """The PNG lands in ``out_dir`` (not the working folder), 14 x 7.2 in at 110 dpi."""
    out, cwd = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    files = report.plot_estimator(transient_run, NAME, str(out))
    assert files == [str(out / f"{NAME}_errors_full.png")]
    assert [p.name for p in out.iterdir()] == [f"{NAME}_errors_full.png"]
    assert list(cwd.iterdir()) == []
    assert _png_size(files[0]) == (1540, 792)


# --- plot_error_grid (paper-style comparison figure) ---------------------------------------


def _grid_series():
    t = np.arange(11.0)
    return {
        n: {
            "t": t,
            "dtheta": np.outer(t, [1.0, 2.0, 3.0]) * k * DEG_ / 10,
            "second_err": np.outer(t, [3.0, 2.0, 1.0]) * k * DEG_PER_H_,
        }
        for k, n in ((1, "ekf"), (2, "ukf"))
    }


@pytest.fixture
def grid_figure(monkeypatch):
    """Call plot_error_grid and keep the figure it closes, to look at its axes."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)

    def draw(*args, **kwargs):
        path = report.plot_error_grid(*args, **kwargs)
        (fig,) = kept
        return path, fig

    yield draw
    for fig in kept:
        plt.figure(fig.number)
        monkeypatch.undo()
        plt.close(fig)


def test_error_grid_plots_each_estimator_on_each_axis(grid_figure, tmp_path):
    series = _grid_series()
    path, fig = grid_figure(
        series,
        ["ekf", "ukf"],
        str(tmp_path / "grid.png"),
        "comparison",
        second_scale=DEG_PER_H_,
        second_unit="deg/h",
        second_label="gyro bias error",
    )
    assert path == str(tmp_path / "grid.png")
    assert _png_size(path) == (1650, 770)  # 15 x 7 in at 110 dpi
    assert tuple(fig.get_size_inches()) == pytest.approx((15.0, 7.0))
    assert fig.get_suptitle() == "comparison"
    axes = np.array(fig.axes).reshape(2, 3)
    axis_names = ["roll (x)", "pitch (y)", "yaw (z)"]
    t = np.arange(11.0)
    for i in range(3):
        top, bottom = axes[0, i], axes[1, i]
        assert top.get_title() == f"attitude error {axis_names[i]}" and top.get_ylabel() == "deg"
        assert bottom.get_title() == f"gyro bias error {axis_names[i]}" and bottom.get_ylabel() == "deg/h"
        assert bottom.get_xlabel() == "time (s)"
        for k, (lt, lb) in enumerate(zip(top.get_lines(), bottom.get_lines(), strict=True), start=1):
            np.testing.assert_array_equal(lt.get_xdata(), t)
            np.testing.assert_allclose(lt.get_ydata(), t * (i + 1) * k / 10, rtol=1e-12)
            np.testing.assert_allclose(lb.get_ydata(), t * (3 - i) * k, rtol=1e-12)
            assert lt.get_linewidth() == lb.get_linewidth() == 0.7
        assert len(top.get_lines()) == len(bottom.get_lines()) == 2
    assert [ax.get_legend() for ax in fig.axes] == [None] * 6  # one legend for the figure, below the plots
    assert [x.get_text() for x in fig.legends[0].get_texts()] == ["ekf", "ukf"]


def test_error_grid_time_range_keeps_both_ends_and_fixed_limits_apply_to_their_row(grid_figure, tmp_path):
    _, fig = grid_figure(
        _grid_series(),
        ["ekf"],
        str(tmp_path / "g.png"),
        "t",
        t_range=(2.0, 5.0),
        att_ylim=(-1.0, 2.0),
        sec_ylim=(-3.0, 4.0),
    )
    axes = np.array(fig.axes).reshape(2, 3)
    for a in fig.axes:
        np.testing.assert_array_equal(a.get_lines()[0].get_xdata(), [2.0, 3.0, 4.0, 5.0])
    assert all(a.get_ylim() == (-1.0, 2.0) for a in axes[0])
    assert all(a.get_ylim() == (-3.0, 4.0) for a in axes[1])


# --- diagram graph, strict JSON, result folder and its manifest ------------------------------


def _tiny_diagram():
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    b = DiagramBuilder()
    b.AddSystem(ConstantVectorSource([1.0])).set_name("source")
    return b.Build()


def test_diagram_graph_is_written_as_dot(tmp_path, monkeypatch):
    d = _tiny_diagram()
    monkeypatch.setattr(report.shutil, "which", lambda name: None)  # no Graphviz
    assert report.write_diagram_graph(d, str(tmp_path)) == [str(tmp_path / "diagram.dot")]
    assert (tmp_path / "diagram.dot").read_text() == d.GetGraphvizString(max_depth=1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diagram.dot"]


@pytest.mark.skipif(__import__("shutil").which("dot") is None, reason="Graphviz dot not installed")
def test_diagram_graph_is_rendered_as_svg_when_graphviz_is_installed(tmp_path):
    files = report.write_diagram_graph(_tiny_diagram(), str(tmp_path))
    assert files == [str(tmp_path / "diagram.dot"), str(tmp_path / "diagram.svg")]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diagram.dot", "diagram.svg"]
    assert b"<svg" in (tmp_path / "diagram.svg").read_bytes()


def test_strict_json_nulls_non_finite_numbers_and_keeps_the_rest():
    value = {
        "a": 1.5,
        "b": float("nan"),
        "c": [float("inf"), -2.0, (float("-inf"), 0.0)],
        "d": 3,
        "e": "x",
        "f": {"g": np.float64(0.25), "h": np.float64("nan")},
    }
    assert report.strict_json(value) == {
        "a": 1.5,
        "b": None,
        "c": [None, -2.0, [None, 0.0]],
        "d": 3,
        "e": "x",
        "f": {"g": 0.25, "h": None},
    }


def test_write_metrics_json_writes_strict_indented_json(tmp_path):
    path = str(tmp_path / "metrics.json")
    assert report.write_metrics_json({"rms": 0.5, "nees": float("nan"), "n": [1, float("inf")]}, path) == path
    assert (tmp_path / "metrics.json").read_bytes() == (
        b'{\n  "rms": 0.5,\n  "nees": null,\n  "n": [\n    1,\n    null\n  ]\n}'
    )


def _sha256(data):
    import hashlib

    return hashlib.sha256(data).hexdigest()


def test_manifest_lists_each_file_with_its_size_and_sha256(transient_run, tmp_path):
    (tmp_path / "sub").mkdir()
    files = {"a.txt": b"hello", "sub/b.bin": bytes(range(256)) * 3}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    paths = [str(tmp_path / n) for n in files]
    expected = [{"file": n, "bytes": len(d), "sha256": _sha256(d)} for n, d in files.items()]
    assert report.manifest_entries(str(tmp_path), paths) == expected
    path = report.write_manifest(str(tmp_path), paths, transient_run)
    assert path == str(tmp_path / "manifest.json")
    import json

    assert json.loads((tmp_path / "manifest.json").read_bytes()) == {
        "scenario": SCENARIO,
        "seed": SEED,
        "files": expected,
    }


def test_write_results_writes_a_complete_folder_a_same_size_edit_is_detected(transient_run, tmp_path, monkeypatch):
    import json
    import types

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    out = tmp_path / "r"
    sd = types.SimpleNamespace(diagram=_tiny_diagram())
    metrics_in = {"estimators": {NAME: {"rms_deg": 0.01, "nees_mean": float("nan")}}}
    written = report.write_results(sd, transient_run, metrics_in, str(out), figures=False)
    names = [os.path.basename(f) for f in written]
    assert names[:3] == ["metrics.json", "config.yaml", "log.npz"] and names[-1] == "manifest.json"
    assert "diagram.dot" in names and not any(n.endswith(".png") for n in names)  # no figures asked
    assert sorted(p.name for p in out.iterdir()) == sorted(names)
    assert list(elsewhere.iterdir()) == []
    assert json.loads((out / "metrics.json").read_bytes()) == {
        "estimators": {NAME: {"rms_deg": 0.01, "nees_mean": None}}
    }
    assert (out / "config.yaml").read_text().startswith(f"# Resolved configuration of this run (seed {SEED}).\n")
    with np.load(out / "log.npz") as npz:
        for key, (t, v) in transient_run.signals.items():
            k = key.replace("/", "__")
            np.testing.assert_array_equal(npz[f"{k}__t"], t)
            np.testing.assert_array_equal(npz[f"{k}__x"], v)
        assert json.loads(str(npz["metadata"]))["seed"] == SEED
    manifest = json.loads((out / "manifest.json").read_bytes())
    assert (manifest["scenario"], manifest["seed"]) == (SCENARIO, SEED)
    assert manifest["files"] == [
        {"file": n, "bytes": (out / n).stat().st_size, "sha256": _sha256((out / n).read_bytes())} for n in names[:-1]
    ]
    assert report.check_manifest(str(out)) == []
    data = bytearray((out / "metrics.json").read_bytes())
    data[data.index(b"0.01") + 3] = ord("2")  # 0.01 -> 0.02: same size, other content
    (out / "metrics.json").write_bytes(bytes(data))
    assert report.check_manifest(str(out)) == ["metrics.json: changed since it was written"]
