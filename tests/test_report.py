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
    P = np.array([np.diag([a * a] * 3 + [b * b] * 3) for a, b in zip(s_att, s_bias)]).reshape(len(t), 36)
    status = np.column_stack([t, np.arange(len(t)), np.zeros(len(t)), np.zeros(len(t))])
    signals = {"plant/q_IB": (t, q_true), "plant/w_IB_B": (t, np.zeros((len(t), 3))),
               "gyro/bias_B": (t, bias_true), f"{NAME}/q_IB_hat": (t, q_hat),
               f"{NAME}/bias_B_hat": (t, bias_hat), f"{NAME}/covariance": (t, P), f"{NAME}/status": (t, status)}
    meta = {"schema": 1, "scenario": SCENARIO, "seed": SEED, "wall_time_s": 0.5, "signals": list(signals),
            "truth": {"attitude": "plant/q_IB", "rate": "plant/w_IB_B"},
            "estimators": {NAME: {"second_kind": "gyro_bias", "true_bias": "gyro/bias_B",
                                  "signals": {"attitude": f"{NAME}/q_IB_hat", "second": f"{NAME}/bias_B_hat",
                                              "covariance": f"{NAME}/covariance", "status": f"{NAME}/status"}}}}
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
