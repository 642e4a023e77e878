"""``drake-att score``: a result folder re-scored from its ``log.npz`` + ``config.yaml``.

A run's ``log.npz`` carries the metadata the metrics need (which signal is the truth, each
estimator's second quantity and the true gyro bias it is scored against), so scoring needs
no diagram: ``drake-att score OUT_DIR`` must rewrite ``metrics.json`` byte for byte, and must
really use that metadata (a log whose metadata names another truth scores differently, by
the amount geometry predicts).

One short run of a scenario with every scoring case: two MEKFs on two gyros (different
biases), a fusion whose first source is the second MEKF, and a gyroless PF (body rate).
"""

import json
import math
import os
import shutil

import numpy as np
import pytest
from test_metrics import qmul  # the independent quaternion product written in the metrics tests

from drake_att.cli import main as cli_main
from drake_att.scenarios.builder import RunLog

SCENARIO_YAML = """
name: score_mix
duration_s: 40.0
seed: 4
plant: !RigidBodyConfig
  inertia_kg_m2: [100.0, 200.0, 200.0]
  initial_rate_deg_per_s: [0.01, -0.02, 0.01]
  disturbance_torque_N_m: [1.0e-5, 1.0e-5, 1.0e-5]
sensors:
- !GyroConfig {name: g1, period_s: 1.0, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 1.0,
               initial_bias_deg_per_h: [12.0, 12.0, 12.0]}
- !GyroConfig {name: g2, period_s: 1.0, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 1.0,
               initial_bias_deg_per_h: [-30.0, -30.0, -30.0]}
- !StarTrackerConfig {name: st, period_s: 1.0, mode: vectors, references_I: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                      sigma_vector_urad: 100.0}
estimators:
- !MekfConfig {name: mekf1, period_s: 1.0, gyro: g1, star_trackers: [st]}
- !MekfConfig {name: mekf2, period_s: 1.0, gyro: g2, star_trackers: [st]}
- !EstimateFusionConfig {name: fusion, sources: [mekf2, mekf1]}
- !GyrolessPfConfig {name: gpf, num_particles: 200}
scoring: {score_from_s: 10.0}
"""

DEG_ = math.pi / 180.0
DEG_PER_H_ = DEG_ / 3600.0


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """The result folder of one ``drake-att run`` (never modified: tests copy it)."""
    root = tmp_path_factory.mktemp("score")
    path = root / "score_mix.yaml"
    path.write_text(SCENARIO_YAML)
    out = str(root / "run")
    assert cli_main(["run", str(path), "--out", out, "--quiet", "--no-figures"]) == 0
    return out


def _copy(result, tmp_path, name="copy"):
    dst = str(tmp_path / name)
    shutil.copytree(result, dst)
    return dst


def _read(path):
    with open(path, "rb") as f:
        return f.read()


def _metrics(path):
    with open(path) as f:
        return json.load(f)


def test_metadata_names_the_truth_each_kind_and_each_estimators_gyro(result):
    """The builder's rule, written out: MEKFs are scored against their own gyro's bias, a
    fusion against its first source's gyro (g2 here), the gyroless PF against the true rate."""
    run = RunLog.load(result)
    meta = run.metadata
    assert (meta["schema"], meta["scenario"], meta["seed"]) == (1, "score_mix", 4)
    assert meta["wall_time_s"] == _metrics(os.path.join(result, "metrics.json"))["wall_time_s"]
    assert meta["truth"] == {"attitude": "rigid_body_plant/q_IB", "rate": "rigid_body_plant/w_IB_B"}
    expected = {
        "mekf1": ("gyro_bias", "g1/bias_B", "bias_B_hat"),
        "mekf2": ("gyro_bias", "g2/bias_B", "bias_B_hat"),
        "fusion": ("gyro_bias", "g2/bias_B", "bias_B_hat"),
        "gpf": ("body_rate", None, "w_IB_B_hat"),
    }
    assert list(meta["estimators"]) == list(expected)
    for name, (kind, bias, second) in expected.items():
        e = meta["estimators"][name]
        assert (e["second_kind"], e["true_bias"]) == (kind, bias), name
        signals = {
            "attitude": f"{name}/q_IB_hat",
            "second": f"{name}/{second}",
            "covariance": f"{name}/covariance",
            "status": f"{name}/status",
        }
        if name != "fusion":  # estimators with measurement inputs also log their innovations
            signals["innovations"] = f"{name}/innovations"
            signals["sample_handling"] = f"{name}/sample_handling"  # every EstimatorSystem: its counters
            assert e["inputs"] == ["st"], name
        assert e["signals"] == signals, name
    assert set(meta["signals"]) == set(run.signals)
    # The named bias is the one each MEKF estimates: the gyros' biases differ by 42 deg/h per
    # axis; each MEKF's final bias estimate lies within 3 of its own reported sigmas of its
    # own gyro's true bias (a 99.7% band per axis) and that band excludes the other gyro's.
    for name, own, other in (("mekf1", "g1/bias_B", "g2/bias_B"), ("mekf2", "g2/bias_B", "g1/bias_B")):
        b_hat = run.values(f"{name}/bias_B_hat")[-1]
        sigma = np.sqrt(np.diag(run.values(f"{name}/covariance")[-1].reshape(6, 6))[3:])
        assert np.all(3 * sigma < 21.0 * DEG_PER_H_), sigma / DEG_PER_H_  # bands of the two gyros disjoint
        t_est = run.values(f"{name}/status")[-1, 0]
        i = int(np.flatnonzero(np.abs(run.times(own) - t_est) < 1e-6)[0])
        assert np.all(np.abs(b_hat - run.values(own)[i]) < 3 * sigma), name
        assert np.all(np.abs(b_hat - run.values(other)[i]) > 3 * sigma), name


def test_score_rewrites_metrics_json_byte_for_byte(result, tmp_path, capsys):
    out = _copy(result, tmp_path)
    original = _read(os.path.join(out, "metrics.json"))
    # --out: a new file, identical to the one `run` wrote (wall time included, from the metadata)
    other = str(tmp_path / "rescored.json")
    assert cli_main(["score", out, "--out", other]) == 0
    assert _read(other) == original
    # default: OUT_DIR/metrics.json is written again (removed first: the file is really rewritten)
    os.remove(os.path.join(out, "metrics.json"))
    assert cli_main(["score", out]) == 0
    assert _read(os.path.join(out, "metrics.json")) == original
    assert cli_main(["score", out]) == 0
    assert "identical to the file it replaced" in capsys.readouterr().out


def test_score_uses_the_truth_and_bias_the_metadata_names(result, tmp_path):
    """Re-point the metadata at a truth attitude rotated by a = 10 deg about body z, at g2's
    bias plus c, and at no bias truth for mekf1; the scores move exactly as geometry says.

    Bounds: R_err' = R_err Rz(a), and the rotation angle is a bi-invariant metric on SO(3),
    so | |dtheta'| - a | <= |dtheta| per sample; by Minkowski's inequality the total RMSE
    (the RMS of |dtheta|) then obeys |RMSE' - a| <= RMSE.  Likewise per axis
    |bias RMSE' - |c_i|| <= bias RMSE for a constant offset c (the bias errors shift by c)."""
    out = _copy(result, tmp_path)
    before = _metrics(os.path.join(out, "metrics.json"))["estimators"]
    run = RunLog.load(out)
    a = 10.0 * DEG_
    rz = np.array([math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)])
    t_q, q = run.signals["rigid_body_plant/q_IB"]
    run.signals["shifted/q_IB"] = (t_q, np.array([qmul(qi, rz) for qi in q]))
    c = np.array([300.0, -400.0, 500.0]) * DEG_PER_H_
    t_b, b = run.signals["g2/bias_B"]
    run.signals["g2_offset/bias_B"] = (t_b, b + c)
    meta = run.metadata
    meta["signals"] += ["shifted/q_IB", "g2_offset/bias_B"]
    meta["truth"]["attitude"] = "shifted/q_IB"
    meta["estimators"]["mekf2"]["true_bias"] = "g2_offset/bias_B"
    meta["estimators"]["mekf1"]["true_bias"] = None
    np.savez_compressed(os.path.join(out, "log.npz"), **run.to_npz_dict())
    rescored = str(tmp_path / "rescored.json")
    assert cli_main(["score", out, "--out", rescored]) == 0
    after = _metrics(rescored)["estimators"]

    for name in before:
        rmse, rmse2 = before[name]["attitude_rmse_total_deg"], after[name]["attitude_rmse_total_deg"]
        assert abs(rmse2 - 10.0) <= rmse + 1e-9, name
        assert rmse < 5.0, name  # so RMSE' >= 10 - RMSE > RMSE: the shifted truth was scored
        assert after[name]["samples_scored"] == before[name]["samples_scored"]
    b0, b1 = np.array(before["mekf2"]["bias_rmse_deg_per_h"]), np.array(after["mekf2"]["bias_rmse_deg_per_h"])
    assert np.all(np.abs(b1 - np.abs(c) / DEG_PER_H_) <= b0 + 1e-9)
    assert np.all(b0 < 100.0)  # far from the 300-500 deg/h of the offset truth
    # mekf1 without a bias truth: no bias RMSE, 3-dof attitude NEES
    assert after["mekf1"]["bias_rmse_deg_per_h"] is None and after["mekf1"]["nees_dof"] == 3
    assert before["mekf1"]["bias_rmse_deg_per_h"] is not None and before["mekf1"]["nees_dof"] == 6
    # what the metadata did not re-point is scored exactly as before
    assert after["fusion"]["bias_rmse_deg_per_h"] == before["fusion"]["bias_rmse_deg_per_h"]
    assert after["gpf"]["rate_rmse_deg_per_s"] == before["gpf"]["rate_rmse_deg_per_s"]


def _without_metadata(out):
    path = os.path.join(out, "log.npz")
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files if k != "metadata"}
    np.savez_compressed(path, **arrays)


def _with_metadata(out, edit):
    path = os.path.join(out, "log.npz")
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays["metadata"]))
    edit(meta)
    arrays["metadata"] = np.array(json.dumps(meta))
    np.savez_compressed(path, **arrays)


def _edit_config(out, old, new):
    path = os.path.join(out, "config.yaml")
    with open(path) as f:
        text = f.read()
    assert text.count(old) == 1
    with open(path, "w") as f:
        f.write(text.replace(old, new))


def _garbage(out, name):
    with open(os.path.join(out, name), "w") as f:
        f.write("not what it should be\n")


BAD_INPUTS = {
    # case: (how to break the copy, file named in the message, what the message says)
    "missing folder": (lambda out: shutil.rmtree(out), "", "no such result folder"),
    "missing log": (lambda out: os.remove(os.path.join(out, "log.npz")), "log.npz", "missing"),
    "missing config": (lambda out: os.remove(os.path.join(out, "config.yaml")), "config.yaml", "missing"),
    "log without metadata": (_without_metadata, "log.npz", "no 'metadata' entry"),
    "log not an npz": (lambda out: _garbage(out, "log.npz"), "log.npz", "not an .npz archive"),
    "metadata naming an unlogged signal": (
        lambda out: _with_metadata(out, lambda m: m["truth"].update(attitude="nowhere/q_IB")),
        "log.npz",
        "truth.attitude = 'nowhere/q_IB' is not a logged signal",
    ),
    "metadata naming a truth of the wrong kind": (
        lambda out: _with_metadata(out, lambda m: m["truth"].update(attitude="g1/bias_B")),
        "log.npz",
        "truth attitude 'g1/bias_B': expected 4 components per sample",
    ),
    "metadata of another schema": (
        lambda out: _with_metadata(out, lambda m: m.update(schema=99)),
        "log.npz",
        "schema 99",
    ),
    "config not YAML of a scenario": (lambda out: _garbage(out, "config.yaml"), "config.yaml", "not a valid scenario"),
    "config with an invalid value": (
        lambda out: _edit_config(out, "duration_s: 40.0", "duration_s: -5.0"),
        "config.yaml",
        "duration_s",
    ),
    "config of another scenario": (
        lambda out: _edit_config(out, "name: score_mix", "name: other"),
        "log.npz",
        "the log is of scenario 'score_mix', the configuration is 'other'",
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_fails_with_a_message_naming_the_file(result, tmp_path, capsys, case):
    out = _copy(result, tmp_path)
    metrics_before = _read(os.path.join(out, "metrics.json"))
    breaker, fname, reason = BAD_INPUTS[case]
    breaker(out)
    capsys.readouterr()
    assert cli_main(["score", out]) == 2
    err = capsys.readouterr().err
    assert err.startswith("drake-att score: ") and "Traceback" not in err
    assert (os.path.join(out, fname) if fname else out) in err and reason in err, err
    if os.path.isdir(out):  # a failed score leaves metrics.json as it was
        assert _read(os.path.join(out, "metrics.json")) == metrics_before
