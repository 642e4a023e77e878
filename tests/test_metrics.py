"""Unit tests of the metrics layer (drake_att.analysis.metrics) on hand-built logs.

No simulation: every log is a ``RunLog`` built here with known truth, known estimate errors
and known covariances, so every expected number is exact and computed in the test itself
(plain loops and this file's own quaternion math), never by the library's rotation helpers.

Tolerances: the attitude error goes through quaternion products and a quaternion -> rotation
vector conversion of O(1e-3) rad angles, exact to a few ulps of 1 (~1e-15 rad absolute), so
``1e-12`` rad (1e-9 relative) leaves three orders of margin while still detecting any
convention error (those are O(1e-3), i.e. the size of the error itself).  Derived
statistics (RMSE, NEES) then agree to ~1e-12 relative; ``rtol=1e-9`` is used.
"""

import math
import re

import numpy as np
import pytest

from drake_att.analysis import metrics
from drake_att.estimators.estimate_fusion_plugin import EstimateFusionConfig
from drake_att.estimators.gyroless_pf_plugin import GyrolessPfConfig
from drake_att.estimators.mekf_plugin import MekfConfig
from drake_att.scenarios import config as cfg
from drake_att.scenarios.builder import RunLog

# Unit constants written out here, independent of drake_att.noise.
DEG_ = math.pi / 180.0
DEG_PER_H_ = math.pi / 180.0 / 3600.0
PLANT = "rigid_body_plant"


# ----------------------------------------------------------------------------------------
# Independent quaternion math (scalar first, Hamilton product; R(p ⊗ q) = R(p) R(q))
# ----------------------------------------------------------------------------------------
def qmul(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return np.array(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ]
    )


def qexp(phi):
    """Unit quaternion of rotation vector ``phi`` (angle |phi| about phi/|phi|)."""
    phi = np.asarray(phi, dtype=float)
    a = math.sqrt(float(phi @ phi))
    if a == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.r_[math.cos(a / 2), math.sin(a / 2) * phi / a]


def rotmat(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rodrigues(phi):
    a = math.sqrt(float(phi @ phi))
    K = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]]) / a
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


# Truth: a constant rotation of 0.3 rad/s about a skew axis from a non-identity q0, so the
# truth changes by 0.3 rad per 1 s step (a one-step misalignment is ~300x the errors used).
Q0 = qexp([0.4, -0.2, 0.7])
AXIS = np.array([1.0, 2.0, -2.0]) / 3.0


def q_true_at(t):
    return qmul(Q0, qexp(0.3 * t * AXIS))


def w_true_at(t):
    return np.array([0.01 + 0.002 * t, -0.02, 0.005 * math.sin(t)])


def bias_true_at(t, offset=0.0):
    """Gyro bias (rad/s) drifting with time, so a misaligned bias sample is visible."""
    return (np.array([3.0, -2.0, 1.0]) + offset + np.array([0.5, 0.25, -0.75]) * t) * DEG_PER_H_


def d_at(t):
    """Known attitude error (rad) of the estimate at estimate time t: O(1e-3), all axes.
    Largest axis per t = 0..4: 2.5, 2.0, 1.5, 1.1, 0.9 mrad (converges below 1.745 mrad =
    0.1 deg at t = 2)."""
    return 1e-3 * np.array([2.5 - 0.5 * t, -2.0 + 0.3 * t, 0.7 - 0.1 * t * t])


def e2_at(t):
    """Known second-vector error (true - estimate), rad/s."""
    return 1e-6 * np.array([2.0 - t, 0.5 * t, -1.0])


def q_hat_for(t, d):
    """Estimate whose error R_hat^T R_true is exp([d x]): q_hat = q_true ⊗ exp(-d)."""
    return qmul(q_true_at(t), qexp(-np.asarray(d)))


def truth_signals(t_grid, with_rate=True):
    t_grid = np.asarray(t_grid, dtype=float)
    sig = {f"{PLANT}/q_IB": (t_grid, np.array([q_true_at(t) for t in t_grid]))}
    if with_rate:
        sig[f"{PLANT}/w_IB_B"] = (t_grid, np.array([w_true_at(t) for t in t_grid]))
    return sig


def estimator_signals(name, t_log, status, q_hat, second, P, second_name="bias_B_hat"):
    t_log = np.asarray(t_log, dtype=float)
    return {
        f"{name}/status": (t_log, np.asarray(status, dtype=float)),
        f"{name}/q_IB_hat": (t_log, np.asarray(q_hat, dtype=float)),
        f"{name}/{second_name}": (t_log, np.asarray(second, dtype=float)),
        f"{name}/covariance": (t_log, np.asarray(P, dtype=float).reshape(len(t_log), 36)),
    }


def make_run(signals, scenario=None, estimators=None):
    """A RunLog with the metadata ScenarioDiagram writes (RunLog.metadata), spelled out here:
    ``estimators`` maps name -> (second output port, gyro whose bias is the truth or None)."""
    kinds = {"bias_B_hat": "gyro_bias", "w_IB_B_hat": "body_rate"}
    meta = {
        "schema": 1,
        "scenario": "tiny",
        "seed": 7,
        "wall_time_s": 1.25,
        "signals": list(signals),
        "truth": {"attitude": f"{PLANT}/q_IB", "rate": f"{PLANT}/w_IB_B"},
        "estimators": {
            name: {
                "second_kind": kinds[second],
                "true_bias": None if gyro is None else f"{gyro}/bias_B",
                "signals": {
                    "attitude": f"{name}/q_IB_hat",
                    "second": f"{name}/{second}",
                    "covariance": f"{name}/covariance",
                    "status": f"{name}/status",
                },
            }
            for name, (second, gyro) in (estimators or {}).items()
        },
    }
    return RunLog(
        scenario=scenario if scenario is not None else cfg.Scenario(),
        seed=7,
        wall_time_s=1.25,
        signals=signals,
        metadata=meta,
    )


def errors_of(run, name, second_name, gyro):
    """metrics.estimator_errors of ``name`` described (in the run's metadata) as estimating
    ``second_name`` and scored against gyro ``gyro``'s bias (None: no bias truth)."""
    run = make_run(run.signals, run.scenario, {name: (second_name, gyro)})
    return metrics.estimator_errors(run, name)


def lagged_estimator(name="mekf", n=6, second_name="bias_B_hat", bias_offset=0.0, dup_first_d=None):
    """Estimator logged at t = 0..n-1 whose sample at log time t is the estimate of t - 1
    (the initial estimate at t = 0 is logged twice with t_estimate = 0: at log times 0 and 1).

    Returns (signals, expected estimate times)."""
    t_log = np.arange(n, dtype=float)
    t_est = np.r_[0.0, t_log[:-1]]
    status, q_hat, second, P = [], [], [], []
    for k, (_tl, te) in enumerate(zip(t_log, t_est, strict=True)):
        d = d_at(te) if (k > 0 or dup_first_d is None) else dup_first_d
        status.append([te, 10 * k, k, 0.5])
        q_hat.append(q_hat_for(te, d))
        truth2 = bias_true_at(te, bias_offset) if second_name == "bias_B_hat" else w_true_at(te)
        second.append(truth2 - e2_at(te))
        P.append(np.diag([1e-6, 4e-6, 2.25e-6, 1e-12, 4e-12, 9e-12]) * (1 + k))
    return estimator_signals(name, t_log, status, q_hat, second, P, second_name), t_log[:-1]


def gyro_signals(name="gyro", t_end=6.0, dt=0.5, offset=0.0):
    t = np.arange(0.0, t_end + dt / 2, dt)
    return {f"{name}/bias_B": (t, np.array([bias_true_at(ti, offset) for ti in t]))}


# ----------------------------------------------------------------------------------------
# convergence_time
# ----------------------------------------------------------------------------------------
def reference_convergence_time(t, dtheta, thr):
    """Definition, by brute force: the earliest t[i] with every axis of every sample
    j >= i within thr (|x| <= thr); None if even the last sample is outside."""
    for i in range(len(t)):
        if all(abs(x) <= thr for row in dtheta[i:] for x in row):
            return float(t[i])
    return None


def test_convergence_time_last_crossing_gives_next_sample_time():
    t = 10.0 + 0.5 * np.arange(10)  # 10.0, 10.5, ..., 14.5
    thr = 0.25
    d = np.full((10, 3), 0.1)
    d[0, 0] = 0.3  # outside (also makes the first sample outside)
    d[2, 1] = -0.4  # outside on the negative side
    d[5, 2] = 0.26  # last outside sample -> converged from sample 6
    assert metrics.convergence_time(t, d, thr) == t[6] == 13.0
    # moving the last excursion by one sample moves the answer by one sample
    d2 = d.copy()
    d2[6, 0] = -0.3
    assert metrics.convergence_time(t, d2, thr) == t[7]
    assert reference_convergence_time(t, d, thr) == 13.0


def test_convergence_time_never_converged_is_none():
    t = np.arange(5.0)
    d = np.zeros((5, 3))
    d[-1, 2] = 1.0  # only the last sample is outside
    assert metrics.convergence_time(t, d, 0.5) is None
    assert metrics.convergence_time(t, np.ones((5, 3)), 0.5) is None


def test_convergence_time_converged_from_start_is_first_time():
    t = 3.0 + np.arange(4.0)  # t[0] = 3, not 0
    assert metrics.convergence_time(t, np.full((4, 3), 0.01), 0.5) == 3.0


def test_convergence_time_sample_exactly_at_threshold_counts_as_within():
    t = np.arange(6.0)
    thr = 0.25  # exactly representable
    d = np.zeros((6, 3))
    d[1, 0] = 0.3  # outside
    d[2:, 1] = -thr  # exactly at the bound from sample 2 on: within
    assert metrics.convergence_time(t, d, thr) == 2.0
    d[-1, 2] = np.nextafter(thr, 1.0)  # one ulp above the bound at the end: never
    assert metrics.convergence_time(t, d, thr) is None


def test_convergence_time_counts_a_non_finite_error_as_outside():
    """An estimate that went NaN never converged: a NaN (or inf) sample is outside the bound,
    like a large error (a NaN compares False with everything, so "> thr" alone would call it
    inside and report convergence at t[0])."""
    t = np.arange(6.0)
    d = np.zeros((6, 3))
    d[2, 1] = np.nan
    assert metrics.convergence_time(t, d, 0.1) == 3.0
    d[-1, 0] = np.inf
    assert metrics.convergence_time(t, d, 0.1) is None
    assert metrics.convergence_time(t, np.full((6, 3), np.nan), 0.1) is None


def test_convergence_time_is_per_axis():
    t = np.arange(8.0)
    thr = 0.1
    d = np.zeros((8, 3))
    d[:, 0] = 0.05  # x always within
    d[:, 2] = -0.05  # z always within
    d[4, 1] = 0.2  # y alone outside at sample 4
    assert metrics.convergence_time(t, d, thr) == 5.0
    d[7, 2] = 0.2  # z alone outside at the end: one axis keeps it unconverged
    assert metrics.convergence_time(t, d, thr) is None


def test_convergence_time_matches_brute_force_definition():
    """Many random series (values on a grid including exactly +-thr) vs the definition."""
    rng = np.random.default_rng(12345)
    thr = 0.5
    levels = np.array([0.0, 0.25, 0.5, -0.5, 0.75, -1.0])
    for _ in range(300):
        n = int(rng.integers(1, 9))
        t = np.cumsum(rng.uniform(0.1, 2.0, n))
        d = rng.choice(levels, size=(n, 3), p=[0.3, 0.2, 0.15, 0.15, 0.1, 0.1])
        assert metrics.convergence_time(t, d, thr) == reference_convergence_time(t, d, thr)


# ----------------------------------------------------------------------------------------
# estimator_errors
# ----------------------------------------------------------------------------------------
def test_attitude_error_convention_matches_design():
    """R_err = R_IB_hat^T R_IB = exp([d x]) and dtheta_B = d, for q_hat = q_true ⊗ exp(-d)."""
    t = np.array([0.0, 1.0, 2.0])
    d = [np.array([1e-3, -2e-3, 0.5e-3]), np.array([-0.02, 0.01, 0.03]), np.array([0.4, 0.0, -0.3])]
    # Self-check of the construction against the DESIGN.md definition (matrices, not quaternions).
    for ti, di in zip(t, d, strict=True):
        R_err = rotmat(q_hat_for(ti, di)).T @ rotmat(q_true_at(ti))
        np.testing.assert_allclose(R_err, rodrigues(di), atol=1e-14)
    sig = truth_signals(t)
    sig.update(
        estimator_signals(
            "mekf",
            t,
            [[ti, 0, 0, 0] for ti in t],
            [q_hat_for(ti, di) for ti, di in zip(t, d, strict=True)],
            np.zeros((3, 3)),
            [np.eye(6)] * 3,
        )
    )
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", None)
    np.testing.assert_allclose(errs["dtheta"], np.array(d), rtol=0, atol=1e-12)
    # q_hat and -q_hat are the same attitude: the error must not depend on the sign.
    sig["mekf/q_IB_hat"] = (t, -sig["mekf/q_IB_hat"][1])
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", None)
    np.testing.assert_allclose(errs["dtheta"], np.array(d), rtol=0, atol=1e-12)


def test_estimate_is_scored_against_truth_at_its_own_time():
    sig, t_expected = lagged_estimator(n=6)
    sig.update(truth_signals(np.arange(6.0)))
    sig.update(gyro_signals())
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", "gyro")
    np.testing.assert_array_equal(errs["t"], t_expected)
    np.testing.assert_allclose(errs["dtheta"], [d_at(t) for t in t_expected], rtol=0, atol=1e-12)
    np.testing.assert_allclose(errs["q_true"], [q_true_at(t) for t in t_expected], rtol=0, atol=1e-15)
    # The test discriminates: scoring at the log time (one step later) would be off by ~0.3 rad.
    wrong = [rodrigues_log(rotmat(q_hat_for(te, d_at(te))).T @ rotmat(q_true_at(te + 1.0))) for te in t_expected[1:]]
    assert min(np.linalg.norm(w - d_at(te)) for w, te in zip(wrong, t_expected[1:], strict=True)) > 0.25


def rodrigues_log(R):
    """Rotation vector of a rotation matrix (angle < pi), for the discrimination check."""
    a = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return v * (a / (2 * math.sin(a))) if a > 1e-12 else v / 2


def test_duplicate_estimate_times_keep_the_last_sample():
    bogus = np.array([0.05, -0.05, 0.05])  # the first t_estimate = 0 sample: not scored
    sig, t_expected = lagged_estimator(n=5, dup_first_d=bogus)
    sig.update(truth_signals(np.arange(5.0)))
    sig.update(gyro_signals())
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", "gyro")
    np.testing.assert_array_equal(errs["t"], t_expected)  # one sample per estimate time
    np.testing.assert_allclose(errs["dtheta"][0], d_at(0.0), rtol=0, atol=1e-12)
    # status / covariance of the kept sample are the last row's (log index 1), too
    np.testing.assert_array_equal(errs["status"][0], [0.0, 10.0, 1.0, 0.5])
    np.testing.assert_array_equal(errs["P"][0], np.diag([1e-6, 4e-6, 2.25e-6, 1e-12, 4e-12, 9e-12]) * 2)


def test_nan_and_negative_estimate_times_are_dropped():
    t_log = np.arange(6.0)
    t_est = np.array([np.nan, -1.0, 2.0, np.nan, 4.0, 5.0])
    nan_q = np.full(4, np.nan)
    q_hat = [nan_q if not (te >= 0) else q_hat_for(te, d_at(te)) for te in t_est]
    second = [np.full(3, np.nan) if not (te >= 0) else bias_true_at(te) - e2_at(te) for te in t_est]
    status = [[te, 0, 0, 0] for te in t_est]
    sig = estimator_signals("mekf", t_log, status, q_hat, second, [np.eye(6)] * 6)
    sig.update(truth_signals(t_log))
    sig.update(gyro_signals())
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", "gyro")
    np.testing.assert_array_equal(errs["t"], [2.0, 4.0, 5.0])
    np.testing.assert_allclose(errs["dtheta"], [d_at(t) for t in (2.0, 4.0, 5.0)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(errs["second_err"], [e2_at(t) for t in (2.0, 4.0, 5.0)], rtol=1e-9, atol=0)


def test_estimate_time_without_truth_sample_raises_naming_it():
    t_log = np.arange(4.0)
    t_est = np.array([0.0, 1.0, 2.5, 3.0])  # truth only at whole seconds
    sig = estimator_signals(
        "mekf",
        t_log,
        [[te, 0, 0, 0] for te in t_est],
        [q_true_at(te) for te in t_est],
        np.zeros((4, 3)),
        [np.eye(6)] * 4,
    )
    sig.update(truth_signals(t_log))
    with pytest.raises(ValueError, match=r"mekf.*2\.5"):
        errors_of(make_run(sig), "mekf", "bias_B_hat", None)
    # Within the documented time-match tolerance it aligns (float jitter of logged times).
    t_est[2] = 2.0 + 0.5 * metrics.TIME_MATCH_TOLERANCE_S
    sig["mekf/status"][1][:, 0] = t_est
    sig["mekf/q_IB_hat"][1][2] = q_true_at(2.0)
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", None)
    np.testing.assert_allclose(errs["dtheta"], 0.0, atol=1e-12)


def test_samples_without_an_estimate_time_are_not_scored():
    """A status row whose estimate time is NaN (no estimate yet), infinite or negative is left
    out by its time column, whatever its counters say (they are finite from the start)."""
    t_log = np.arange(5.0)
    t_est = np.array([np.nan, -1.0, 2.0, 3.0, np.inf])
    status = [[te, 1, 0, 0.5] for te in t_est]
    q_hat = [q_true_at(max(te, 0.0)) if np.isfinite(te) else np.full(4, np.nan) for te in t_est]
    sig = estimator_signals("mekf", t_log, status, q_hat, np.zeros((5, 3)), [np.eye(6)] * 5)
    sig.update(truth_signals(t_log))
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", None)
    np.testing.assert_array_equal(errs["t"], [2.0, 3.0])
    np.testing.assert_allclose(errs["dtheta"], 0.0, atol=1e-12)


@pytest.mark.parametrize(
    "t_truth, missing",
    [
        (np.arange(4.0), r"4\."),  # truth stops at 3 s, an estimate at 4 s (after the last sample)
        (np.arange(1.0, 6.0), r"0\."),  # truth starts at 1 s, an estimate at 0 s (before the first)
    ],
)
def test_estimate_time_outside_the_truth_log_raises_naming_it(t_truth, missing):
    """An estimate time beyond either end of the truth log is a missing truth sample too:
    the same ValueError naming the estimator and the time (not an IndexError from the
    search past the end)."""
    t_est = np.arange(5.0)
    sig = estimator_signals(
        "mekf",
        t_est,
        [[te, 0, 0, 0] for te in t_est],
        [q_true_at(te) for te in t_est],
        np.zeros((5, 3)),
        [np.eye(6)] * 5,
    )
    sig.update(truth_signals(t_truth))
    with pytest.raises(ValueError, match=r"mekf: no truth sample at estimate times \[" + missing):
        errors_of(make_run(sig), "mekf", "bias_B_hat", None)


@pytest.mark.parametrize(
    "signal, width, what",
    [
        ("mekf/status", 5, "mekf status"),
        ("mekf/q_IB_hat", 3, "mekf attitude"),  # a rotation vector logged for a quaternion
        ("mekf/bias_B_hat", 4, "mekf second quantity"),
        ("mekf/covariance", 9, "mekf covariance"),  # a 3x3 attitude-only covariance
        (f"{PLANT}/q_IB", 3, "truth attitude"),
        ("gyro/bias_B", 2, "mekf true bias"),
    ],
)
def test_signal_with_wrong_number_of_components_raises_naming_it(signal, width, what):
    """A logged signal with the wrong number of components per sample is rejected, naming
    the estimator's quantity and the signal key, instead of being scored (a 5-column status
    or a 4-column bias would otherwise be read silently; 9 covariance entries x 4 samples
    would even reshape into one 6x6 matrix)."""
    sig, _ = lagged_estimator(n=5)
    sig.update(truth_signals(np.arange(5.0)))
    sig.update(gyro_signals())
    t, x = sig[signal]
    sig[signal] = (t, np.resize(x, (len(t), width)))
    with pytest.raises(ValueError, match=re.escape(f"{what} {signal!r}: expected ")):
        errors_of(make_run(sig), "mekf", "bias_B_hat", "gyro")


def test_bias_error_is_true_minus_estimate_at_estimate_time():
    sig, t_expected = lagged_estimator(n=6)
    sig.update(truth_signals(np.arange(6.0)))
    sig.update(gyro_signals(dt=0.5))  # the gyro logs on its own, finer grid
    errs = errors_of(make_run(sig), "mekf", "bias_B_hat", "gyro")
    # e2_at is bias_true - bias_hat by construction; the bias drifts by ~0.5 deg/h per s
    # (~2.4e-6 rad/s), so a misaligned gyro sample would be off by more than the error itself.
    np.testing.assert_allclose(errs["second_err"], [e2_at(t) for t in t_expected], rtol=1e-9, atol=1e-20)
    assert errs["nees_dof"] == 6
    # The errors say what their second error is (analysis/report.py labels and scales it by
    # this: deg/h for a bias, deg/s for a rate), also when there is no bias truth to score.
    assert errs["second_kind"] == "gyro_bias"
    assert errors_of(make_run(sig), "mekf", "bias_B_hat", None)["second_kind"] == "gyro_bias"


def test_truth_and_true_bias_are_the_signals_the_metadata_names():
    """Decoy ``*/q_IB`` and ``*/bias_B`` signals logged first (0.3 rad and 40 deg/h off the
    truth) are not what the estimate is scored against unless the metadata names them."""
    sig, t_expected = lagged_estimator(n=6)
    t = np.arange(6.0)
    decoy_q = np.array([qmul(q_true_at(ti), qexp([0.3, 0.0, 0.0])) for ti in t])
    signals = {"decoy/q_IB": (t, decoy_q), **gyro_signals("decoy", offset=40.0), **sig}
    signals.update(truth_signals(t))
    signals.update(gyro_signals())
    run = make_run(signals, estimators={"mekf": ("bias_B_hat", "gyro")})
    errs = metrics.estimator_errors(run, "mekf")
    np.testing.assert_allclose(errs["q_true"], [q_true_at(ti) for ti in t_expected], rtol=0, atol=1e-15)
    np.testing.assert_allclose(errs["dtheta"], [d_at(ti) for ti in t_expected], rtol=0, atol=1e-12)
    np.testing.assert_allclose(errs["second_err"], [e2_at(ti) for ti in t_expected], rtol=1e-9, atol=1e-20)
    # Named by the metadata, the decoys are the truth: the decoy quaternion at the estimate
    # times, and a bias error larger by exactly the 40 deg/h offset (bias_true_at is linear).
    run.metadata["truth"]["attitude"] = "decoy/q_IB"
    run.metadata["estimators"]["mekf"]["true_bias"] = "decoy/bias_B"
    errs = metrics.estimator_errors(run, "mekf")
    np.testing.assert_array_equal(errs["q_true"], decoy_q[t_expected.astype(int)])
    np.testing.assert_allclose(
        errs["second_err"], [e2_at(ti) + 40.0 * DEG_PER_H_ for ti in t_expected], rtol=1e-9, atol=1e-20
    )


def test_scoring_a_run_without_metadata_says_so():
    sig, _ = lagged_estimator(n=3)
    sig.update(truth_signals(np.arange(3.0)))
    bare = RunLog(scenario=cfg.Scenario(), seed=1, wall_time_s=0.0, signals=sig)
    with pytest.raises(ValueError, match="metadata"):
        metrics.estimator_errors(bare, "mekf")
    with pytest.raises(ValueError, match="metadata"):
        metrics.compute_metrics(bare)
    run = make_run(sig, estimators={"mekf": ("bias_B_hat", None)})
    with pytest.raises(ValueError, match="not an estimator of this run"):
        metrics.estimator_errors(run, "ekf")
    run.metadata["estimators"]["mekf"]["second_kind"] = "bias_B_hat"  # a port name, not a kind
    with pytest.raises(ValueError, match="neither 'gyro_bias' nor 'body_rate'"):
        metrics.estimator_errors(run, "mekf")


def test_rate_error_for_w_hat_estimators():
    sig, t_expected = lagged_estimator(name="gpf", n=6, second_name="w_IB_B_hat")
    sig.update(truth_signals(np.arange(6.0)))
    errs = errors_of(make_run(sig), "gpf", "w_IB_B_hat", None)
    np.testing.assert_allclose(errs["second_err"], [e2_at(t) for t in t_expected], rtol=1e-9, atol=1e-20)
    assert errs["nees_dof"] == 6
    assert errs["second_kind"] == "body_rate"


def _nees_log(P_list, second_name="bias_B_hat"):
    n = len(P_list)
    t = np.arange(float(n))
    truth2 = (lambda ti: bias_true_at(ti)) if second_name == "bias_B_hat" else w_true_at
    sig = estimator_signals(
        "est",
        t,
        [[ti, 0, 0, 0] for ti in t],
        [q_hat_for(ti, d_at(ti)) for ti in t],
        [truth2(ti) - e2_at(ti) for ti in t],
        P_list,
        second_name,
    )
    sig.update(truth_signals(t))
    sig.update(gyro_signals(t_end=float(n)))
    return make_run(sig), t


def test_nees_six_dof_hand_computed_and_singular_sample_is_nan():
    diag = np.array([1e-6, 4e-6, 2.25e-6, 1e-12, 4e-12, 9e-12])
    P0 = np.diag(diag)
    # attitude-x / bias-x correlated 2x2 block [[a, c], [c, b]] (positive definite)
    a, b, c = 2e-6, 3e-12, 1.5e-9
    P1 = np.diag(diag)
    P1[0, 0], P1[3, 3], P1[0, 3], P1[3, 0] = a, b, c, c
    P2 = np.diag(diag)
    P2[5, 5] = 0.0  # singular (e.g. a collapsed particle cloud)
    P3 = np.diag(diag) * 4.0
    run, t = _nees_log([P0, P1, P2, P3])
    errs = errors_of(run, "est", "bias_B_hat", "gyro")
    e = [np.r_[d_at(ti), e2_at(ti)] for ti in t]
    expected0 = sum(e[0][i] ** 2 / diag[i] for i in range(6))
    # 2x2 inverse: [[b, -c], [-c, a]] / (ab - c^2)
    expected1 = (b * e[1][0] ** 2 - 2 * c * e[1][0] * e[1][3] + a * e[1][3] ** 2) / (a * b - c * c) + sum(
        e[1][i] ** 2 / diag[i] for i in (1, 2, 4, 5)
    )
    expected3 = sum(e[3][i] ** 2 / (4.0 * diag[i]) for i in range(6))
    assert errs["nees_dof"] == 6
    np.testing.assert_allclose(errs["nees"][[0, 1, 3]], [expected0, expected1, expected3], rtol=1e-9)
    assert np.isnan(errs["nees"][2])


def test_nees_six_dof_for_rate_estimators():
    diag = np.array([1e-6, 4e-6, 2.25e-6, 1e-12, 4e-12, 9e-12])
    run, t = _nees_log([np.diag(diag)] * 3, second_name="w_IB_B_hat")
    errs = errors_of(run, "est", "w_IB_B_hat", None)
    expected = [sum(v**2 / s for v, s in zip(np.r_[d_at(ti), e2_at(ti)], diag, strict=True)) for ti in t]
    np.testing.assert_allclose(errs["nees"], expected, rtol=1e-9)


def test_nees_three_dof_without_bias_truth_uses_attitude_block_only():
    # attitude x/y correlated block [[a, c], [c, b]]; the bias block and cross terms are
    # arbitrary and must not matter (no bias truth: 3-dof attitude NEES).
    a, b, c, s2 = 2e-6, 5e-6, 1e-6, 3e-6
    P = np.diag([a, b, s2, 1e-12, 1e-12, 1e-12])
    P[0, 1] = P[1, 0] = c
    P[0, 3] = P[3, 0] = 1e-9
    P_bias_singular = P.copy()
    P_bias_singular[3:, 3:] = 0.0
    P_bias_singular[:3, 3:] = P_bias_singular[3:, :3] = 0.0
    P_att_singular = P.copy()
    P_att_singular[2, 2] = 0.0
    run, t = _nees_log([P, P_bias_singular, P_att_singular])
    errs = errors_of(run, "est", "bias_B_hat", None)
    assert errs["second_err"] is None and errs["nees_dof"] == 3

    def nees3(d):
        return (b * d[0] ** 2 - 2 * c * d[0] * d[1] + a * d[1] ** 2) / (a * b - c * c) + d[2] ** 2 / s2

    np.testing.assert_allclose(errs["nees"][:2], [nees3(d_at(t[0])), nees3(d_at(t[1]))], rtol=1e-9)
    assert np.isnan(errs["nees"][2])


# ----------------------------------------------------------------------------------------
# score_estimator
# ----------------------------------------------------------------------------------------
def _errors_dict(t, d_deg, second=None, nees=None, status=None, P=None):
    n = len(t)
    return {
        "t": np.asarray(t, dtype=float),
        "dtheta": np.asarray(d_deg, dtype=float) * DEG_,
        "second_err": None if second is None else np.asarray(second, dtype=float),
        "P": np.asarray(P) if P is not None else np.tile(np.eye(6), (n, 1, 1)),
        "nees": np.asarray(nees if nees is not None else np.ones(n), dtype=float),
        "nees_dof": 6 if second is not None else 3,
        "status": np.asarray(status if status is not None else [[ti, 0, 0, 0] for ti in t], dtype=float),
    }


D_DEG = [
    [0.9, -0.5, 0.3],  # t = 0 (before score_from_s)
    [0.2, 0.1, -0.04],  # t = 1
    [0.03, -0.02, 0.01],  # t = 2  (== score_from_s)
    [-0.01, 0.04, -0.02],  # t = 3
    [0.02, 0.01, 0.03],  # t = 4
    [-0.04, -0.03, 0.02],
]  # t = 5


def _rms(rows, axis):
    return math.sqrt(sum(r[axis] ** 2 for r in rows) / len(rows))


def test_score_rmse_mae_total_over_stable_stage():
    t = np.arange(6.0)
    m = metrics.score_estimator(_errors_dict(t, D_DEG), cfg.ScoringConfig(score_from_s=2.0), "gyro_bias")
    scored = D_DEG[2:]
    np.testing.assert_allclose(m["attitude_rmse_deg"], [_rms(scored, i) for i in range(3)], rtol=1e-12)
    np.testing.assert_allclose(
        m["attitude_mae_deg"], [sum(abs(r[i]) for r in scored) / 4 for i in range(3)], rtol=1e-12
    )
    total = math.sqrt(sum(x * x for r in scored for x in r) / len(scored))
    assert m["attitude_rmse_total_deg"] == pytest.approx(total, rel=1e-12)
    # total RMSE is not the mean of per-axis RMSEs; check it is the root of their squares' sum
    assert m["attitude_rmse_total_deg"] == pytest.approx(
        math.sqrt(sum(v * v for v in m["attitude_rmse_deg"])), rel=1e-12
    )
    assert m["samples_scored"] == 4 and m["scored_from_s"] == 2.0


@pytest.mark.parametrize(
    "t2, included",
    [
        (2.0, True),  # exactly at score_from_s
        (2.0 - 0.5 * metrics.TIME_MATCH_TOLERANCE_S, True),  # float jitter of a logged time
        (2.0 - 1e-3, False),  # just before: not scored
    ],
)
def test_score_from_s_boundary(t2, included):
    t = np.array([0.0, 1.0, t2, 3.0, 4.0, 5.0])
    m = metrics.score_estimator(_errors_dict(t, D_DEG), cfg.ScoringConfig(score_from_s=2.0), "gyro_bias")
    scored = D_DEG[2:] if included else D_DEG[3:]
    assert m["samples_scored"] == len(scored)
    np.testing.assert_allclose(m["attitude_rmse_deg"], [_rms(scored, i) for i in range(3)], rtol=1e-12)


def test_score_from_s_comparison_is_inclusive_at_the_tolerance_edge():
    """The mask is ``t >= score_from_s - tol`` (inclusive): a sample exactly at the edge of
    the time-match band is scored; one ulp further before it is not."""
    edge = 2.0 - metrics.TIME_MATCH_TOLERANCE_S
    for t2, n_scored in ((edge, 4), (np.nextafter(edge, 0.0), 3)):
        t = np.array([0.0, 1.0, t2, 3.0, 4.0, 5.0])
        m = metrics.score_estimator(_errors_dict(t, D_DEG), cfg.ScoringConfig(score_from_s=2.0), "gyro_bias")
        assert m["samples_scored"] == n_scored


def test_score_bias_rmse_in_deg_per_h():
    t = np.arange(6.0)
    b_deg_h = [[50, -50, 50], [9, 8, 7], [1.5, -2.0, 0.5], [-0.5, 1.0, 2.5], [1.0, 0.0, -1.5], [2.0, -1.0, 0.5]]
    second = np.array(b_deg_h) * DEG_PER_H_
    m = metrics.score_estimator(_errors_dict(t, D_DEG, second=second), cfg.ScoringConfig(score_from_s=2.0), "gyro_bias")
    np.testing.assert_allclose(m["bias_rmse_deg_per_h"], [_rms(b_deg_h[2:], i) for i in range(3)], rtol=1e-12)
    assert m["rate_rmse_deg_per_s"] is None


def test_score_rate_rmse_in_deg_per_s():
    t = np.arange(6.0)
    w_deg_s = [[5, 5, 5], [1, 1, 1], [1e-3, -2e-3, 3e-3], [2e-3, 0.0, -1e-3], [-1e-3, 1e-3, 1e-3], [0.0, 2e-3, 0.0]]
    second = np.array(w_deg_s) * DEG_
    m = metrics.score_estimator(_errors_dict(t, D_DEG, second=second), cfg.ScoringConfig(score_from_s=2.0), "body_rate")
    np.testing.assert_allclose(m["rate_rmse_deg_per_s"], [_rms(w_deg_s[2:], i) for i in range(3)], rtol=1e-12)
    assert m["bias_rmse_deg_per_h"] is None


def test_score_without_second_truth_has_no_second_rmse():
    m = metrics.score_estimator(_errors_dict(np.arange(6.0), D_DEG), cfg.ScoringConfig(), "gyro_bias")
    assert m["bias_rmse_deg_per_h"] is None and m["rate_rmse_deg_per_s"] is None and m["nees_dof"] == 3


def test_nees_mean_over_scored_samples_ignores_nan():
    t = np.arange(6.0)
    nees = [1e6, 1e6, 3.0, np.nan, 5.0, 10.0]  # huge values before score_from_s: not scored
    m = metrics.score_estimator(_errors_dict(t, D_DEG, nees=nees), cfg.ScoringConfig(score_from_s=2.0), "gyro_bias")
    assert m["nees_mean"] == pytest.approx((3.0 + 5.0 + 10.0) / 3, rel=1e-12)
    # all scored samples NaN -> None (even though unscored samples are finite)
    nees = [1.0, 2.0, np.nan, np.nan, np.nan, np.nan]
    m = metrics.score_estimator(_errors_dict(t, D_DEG, nees=nees), cfg.ScoringConfig(score_from_s=2.0), "gyro_bias")
    assert m["nees_mean"] is None


def test_measurement_counts_and_final_three_sigma_from_last_sample():
    t = np.arange(6.0)
    status = [[ti, 3 * k, k // 2, 0.1] for k, ti in enumerate(t)]
    status[-1] = [5.0, 17, 4, 0.2]
    sig_deg = [0.01, 0.02, 0.5]
    P = np.tile(np.eye(6), (6, 1, 1))
    P[-1, :3, :3] = np.diag(np.square(np.array(sig_deg) * DEG_))
    P[-1, 0, 1] = P[-1, 1, 0] = 1e-9  # off-diagonal terms do not enter the per-axis 3-sigma
    P[-1, 3:, 3:] = 42.0
    m = metrics.score_estimator(_errors_dict(t, D_DEG, status=status, P=P), cfg.ScoringConfig(), "gyro_bias")
    assert m["measurements_used"] == 17 and m["measurements_skipped"] == 4
    np.testing.assert_allclose(m["attitude_3sigma_final_deg"], [3 * s for s in sig_deg], rtol=1e-12)


def test_score_convergence_time_uses_all_samples_and_degree_threshold():
    """The threshold is in degrees (0.05 deg), the series is in rad; convergence is judged
    over every sample, not only the scored ones: D_DEG leaves 0.05 deg after t = 1."""
    t = np.arange(6.0)
    m = metrics.score_estimator(
        _errors_dict(t, D_DEG), cfg.ScoringConfig(score_from_s=4.0, convergence_threshold_deg=0.05), "gyro_bias"
    )
    assert m["convergence_time_s"] == 2.0
    m = metrics.score_estimator(_errors_dict(t, D_DEG), cfg.ScoringConfig(convergence_threshold_deg=0.035), "gyro_bias")
    assert m["convergence_time_s"] is None  # |-0.04| deg at the last sample


# ----------------------------------------------------------------------------------------
# compute_metrics and format_table
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny_metrics():
    """Four estimators on one truth: two MEKFs on two gyros, a fusion whose first source is
    the second MEKF (scored against gyro g2's bias), and a gyroless PF (rate)."""
    scenario = cfg.Scenario(
        name="tiny",
        duration_s=5.0,
        estimators=[
            MekfConfig(name="mekf1", gyro="g1"),
            MekfConfig(name="mekf2", gyro="g2"),
            EstimateFusionConfig(name="fusion", sources=["mekf2", "mekf1"]),
            GyrolessPfConfig(name="gpf"),
        ],
        scoring=cfg.ScoringConfig(score_from_s=2.0, convergence_threshold_deg=0.1),
    )
    sig = truth_signals(np.arange(6.0))
    sig.update(gyro_signals("g1", offset=0.0))
    sig.update(gyro_signals("g2", offset=40.0))  # g2's bias is 40 deg/h off g1's
    for name, gyro_offset, second_name in (
        ("mekf1", 0.0, "bias_B_hat"),
        ("mekf2", 40.0, "bias_B_hat"),
        ("fusion", 40.0, "bias_B_hat"),
        ("gpf", None, "w_IB_B_hat"),
    ):
        s, _ = lagged_estimator(name=name, n=6, second_name=second_name, bias_offset=gyro_offset or 0.0)
        sig.update(s)
    # The metadata names each estimator's true bias (the builder's rule, tested in
    # test_score.py: a fusion is scored against its first source's gyro, here g2).
    run = make_run(
        sig,
        scenario,
        {
            "mekf1": ("bias_B_hat", "g1"),
            "mekf2": ("bias_B_hat", "g2"),
            "fusion": ("bias_B_hat", "g2"),
            "gpf": ("w_IB_B_hat", None),
        },
    )
    return metrics.compute_metrics(run)


def test_compute_metrics_on_tiny_scenario(tiny_metrics):
    m = tiny_metrics
    assert (m["scenario"], m["seed"], m["duration_s"], m["wall_time_s"]) == ("tiny", 7, 5.0, 1.25)
    assert list(m["estimators"]) == ["mekf1", "mekf2", "fusion", "gpf"]
    t_scored = [2.0, 3.0, 4.0]  # estimate times 0..4 (lagged log), scored from 2 s
    d_deg = [d_at(t) / DEG_ for t in t_scored]
    e2 = [e2_at(t) for t in t_scored]
    # NEES with the lagged log's covariance diag(...) * (1 + log index), log index = t_est + 1
    diag = [1e-6, 4e-6, 2.25e-6, 1e-12, 4e-12, 9e-12]
    nees = [sum(v * v / (s * (t + 2)) for v, s in zip(np.r_[d_at(t), e2_at(t)], diag, strict=True)) for t in t_scored]
    # convergence: every axis |d| <= 0.1 deg from t = 2 on (see d_at), by brute force too
    conv = reference_convergence_time(np.arange(5.0), [d_at(t) / DEG_ for t in range(5)], 0.1)
    assert conv == 2.0
    for name, rec in m["estimators"].items():
        np.testing.assert_allclose(rec["attitude_rmse_deg"], [_rms(d_deg, i) for i in range(3)], rtol=1e-9)
        assert rec["nees_mean"] == pytest.approx(sum(nees) / 3, rel=1e-9)
        assert rec["convergence_time_s"] == conv
        assert (rec["measurements_used"], rec["measurements_skipped"]) == (50, 5)
        assert rec["samples_scored"] == 3
        if name == "gpf":
            np.testing.assert_allclose(rec["rate_rmse_deg_per_s"], [_rms(e2, i) / DEG_ for i in range(3)], rtol=1e-9)
            assert rec["bias_rmse_deg_per_h"] is None
        else:
            # each bias estimator scored against its own gyro (fusion: its first source's, g2);
            # against the other gyro the error would be ~40 deg/h instead of ~0.1-0.4 deg/h
            np.testing.assert_allclose(
                rec["bias_rmse_deg_per_h"], [_rms(e2, i) / DEG_PER_H_ for i in range(3)], rtol=1e-9
            )


FLOAT = r"[-+]?\d+\.\d+(?:e[-+]\d+)?"
SIG_DIGITS = 3  # format_table prints RMSE, MAE, bias, rate and NEES to 3 significant digits


def _half_unit(token):
    """Half a unit in the last printed digit of ``token`` ("0.0123" -> 5e-5, "6.1e+28" -> 5e26,
    "170" -> 0.5): the largest rounding error the printed number can carry."""
    from decimal import Decimal

    return 0.5 * 10.0 ** Decimal(token).as_tuple().exponent


def assert_printed(token, value, sig=SIG_DIGITS):
    """``token`` is ``value`` printed to ``sig`` significant digits: within half a unit of its
    last digit, and that unit is no coarser than ``sig`` significant digits of ``value``
    (relative error <= 0.5 * 10**(1 - sig); "0.0001" for 1.23e-4 fails)."""
    printed = float(token)
    assert abs(printed - value) <= _half_unit(token) * (1 + 1e-9), (token, value)
    assert abs(printed - value) <= 0.5 * 10.0 ** (1 - sig) * abs(value) * (1 + 1e-9), (token, value)


def _blocks(lines):
    """``(header index, [row lines])`` of each block of the table: a header line starting
    with ``estimator``, a dash line as long as it, rows up to a blank line or the footer."""
    out = []
    for dash, line in enumerate(lines):
        if line and set(line) == {"-"}:
            assert lines[dash - 1].split()[0] == "estimator" and len(line) == len(lines[dash - 1])
            end = dash + 1
            while end < len(lines) and lines[end] and not lines[end].startswith("(scored"):
                end += 1
            out.append((dash - 1, lines[dash + 1 : end]))
    assert len(out) == 2, "two blocks: attitude error, then bias / rate, convergence and consistency"
    return out


def _parse_table(text):
    """Header groups, rows {name: fields as printed (strings)} and the scored-from time."""
    lines = text.splitlines()
    header = re.fullmatch(rf"scenario (\S+)  seed (\d+)  duration ({FLOAT}|\d+) s  wall ({FLOAT}) s", lines[0])
    assert header, lines[0]
    (_, attitude), (_, other) = _blocks(lines)
    assert [ln.split()[0] for ln in attitude] == [ln.split()[0] for ln in other]  # the same rows, in order
    rows = {}
    for line, line2 in zip(attitude, other, strict=True):
        tok = line.split()
        name, rm, tot, ma = tok[0], tok[1:4], tok[4], tok[5:8]
        assert len(tok) == 8, line
        tok = line2.split()
        if tok[1] in ("b", "w"):
            second, rest = (tok[1], tok[2:5]), tok[5:]
        else:
            assert tok[1] == "-"
            second, rest = None, tok[2:]
        conv, nees, used = rest
        nees = nees.rstrip("*")
        for t in rm + ma + [tot] + (second[1] if second else []) + ([] if nees == "-" else [nees]):
            float(t)  # every number parses back
        rows[name] = {
            "rm": rm,
            "ma": ma,
            "tot": tot,
            "second": second,
            "conv": None if conv == "never" else float(conv),
            "conv_text": conv,
            "nees": None if nees == "-" else nees,
            "used": tuple(int(x) for x in used.split("/")),
            "line": line,
            "line2": line2,
        }
    scored_from = float(re.search(r"scored from t >= (\S+) s", text).group(1))
    return header.groups(), rows, scored_from


def _rec(rm, ma, tot, bias=None, rate=None, conv=None, nees=None, used=(0, 0)):
    return {
        "attitude_rmse_deg": rm,
        "attitude_mae_deg": ma,
        "attitude_rmse_total_deg": tot,
        "bias_rmse_deg_per_h": bias,
        "rate_rmse_deg_per_s": rate,
        "convergence_time_s": conv,
        "nees_mean": nees,
        "scored_from_s": 100.0,
        "measurements_used": used[0],
        "measurements_skipped": used[1],
    }


def _check_rows(rows, est):
    """Every printed field of every row is the number it was given, to the printed precision."""
    assert list(rows) == list(est)
    for name, rec in est.items():
        r = rows[name]
        for tokens, values in (
            (r["rm"], rec["attitude_rmse_deg"]),
            (r["ma"], rec["attitude_mae_deg"]),
            ([r["tot"]], [rec["attitude_rmse_total_deg"]]),
        ):
            for t, v in zip(tokens, values, strict=True):
                assert_printed(t, v)
        if rec["bias_rmse_deg_per_h"] is not None:
            assert r["second"][0] == "b"
            for t, v in zip(r["second"][1], rec["bias_rmse_deg_per_h"], strict=True):
                assert_printed(t, v)
        elif rec["rate_rmse_deg_per_s"] is not None:
            assert r["second"][0] == "w"
            for t, v in zip(r["second"][1], rec["rate_rmse_deg_per_s"], strict=True):
                assert_printed(t, v)
        else:
            assert r["second"] is None
        if rec["convergence_time_s"] is None:
            assert r["conv"] is None and r["conv_text"] == "never"
        else:  # .1f: half a unit is 0.05 s
            assert abs(r["conv"] - rec["convergence_time_s"]) <= 0.0501
            assert _half_unit(r["conv_text"]) == pytest.approx(0.05)
        if rec["nees_mean"] is None:
            assert r["nees"] is None
        else:
            assert_printed(r["nees"], rec["nees_mean"])
        assert r["used"] == (rec["measurements_used"], rec["measurements_skipped"])


def _check_aligned(text):
    """In each block every row is as wide as the header, and each column's numbers end at the
    same column on every row (right-aligned; a row with '-' for the bias/rate column has its
    '-' where the others' last bias/rate number ends); the last column ends under its header."""
    lines = text.splitlines()
    for hdr_index, body in _blocks(lines):
        header = lines[hdr_index]
        assert all(len(ln) == len(header) for ln in body), [len(ln) for ln in [header, *body]]
        ends = [[m.end() for m in re.finditer(r"[^\s*]+", ln)][1:] for ln in body]  # after the name
        full = [e for e, ln in zip(ends, body, strict=True) if ln.split()[1] not in ("-",)]
        assert full, "the block has a row with every column filled"
        assert all(e == full[0] for e in full), full
        for e in ends:
            assert set(e) <= set(full[0]), (e, full[0])
        assert ends[-1][-1] == len(header)  # the last column ends the row, under its header


def test_format_table_shows_the_numbers_it_was_given():
    # Distinct values per column (a swapped column fails); formats: RMSE, MAE, bias, rate
    # and NEES to 3 significant digits (half a unit of the last printed digit, and a relative
    # 5e-3 at most), conv %.1f (0.05), wall %.2f (0.005).
    est = {
        "mekf": _rec(
            [0.01234, 0.02345, 0.03456],
            [0.00987, 0.01876, 0.02765],
            0.04567,
            bias=[0.1234, 2.3456, 34.5678],
            conv=123.4,
            nees=6.12,
            used=(950, 12),
        ),
        "gyroless_pf": _rec(
            [1.23456, 2.34567, 3.45678],
            [0.98765, 1.87654, 2.76543],
            4.56789,
            rate=[1.23e-4, 4.56e-5, 7.89e-3],
            conv=None,
            nees=None,
            used=(1000, 0),
        ),
        "plain": _rec([0.5, 0.25, 0.125], [0.4, 0.2, 0.1], 0.57282, conv=0.0, nees=2.98, used=(3, 4)),
    }
    metrics_in = {"scenario": "tiny", "seed": 11, "duration_s": 3600.0, "wall_time_s": 12.3456, "estimators": est}
    text = metrics.format_table(metrics_in)
    (scen, seed, dur, wall), rows, scored_from = _parse_table(text)
    assert (scen, int(seed), float(dur)) == ("tiny", 11, 3600.0)
    assert abs(float(wall) - 12.3456) <= 0.005
    assert scored_from == 100.0
    _check_rows(rows, est)
    _check_aligned(text)
    assert "NEES dof = 6" in text  # the records carry no nees_dof: the 6-dof default


def test_format_table_sizes_to_long_names_and_numbers_spanning_decades():
    """A 30-character name, a NEES of 6.1e28 (a diverged filter), RMSEs of 1.2e-7 and 170 deg
    (a -170 deg yaw transient) in one table: each number reads back to its printed precision
    and every row lines up with the header."""
    long_name = "large_error_ekf_with_long_name"
    assert len(long_name) == 30
    est = {
        long_name: _rec(
            [170.0, 1.2e-7, 0.00012],
            [150.0, 9.87e-8, 0.000101],
            170.0,
            bias=[12345.6, 0.000987, 3.0],
            conv=None,
            nees=6.1e28,
            used=(123456, 7890),
        ),
        "ekf": _rec(
            [1.2e-7, 170.0, 0.0123],
            [1e-7, 99.95, 0.01],
            1.2e-7,
            rate=[6.1e-28, 1.0, 0.0456],
            conv=4999.9,
            nees=0.00012,
            used=(1, 0),
        ),
        "mekf": _rec([0.5, 0.25, 0.125], [0.4, 0.2, 0.1], 0.57282, conv=12.0, nees=None, used=(3, 4)),
    }
    metrics_in = {"scenario": "s", "seed": 0, "duration_s": 5000.0, "wall_time_s": 1.0, "estimators": est}
    text = metrics.format_table(metrics_in)
    _, rows, _ = _parse_table(text)
    _check_rows(rows, est)
    _check_aligned(text)
    for line in (row[key] for row in rows.values() for key in ("line", "line2")):
        assert line[len(long_name)] == " "  # the name column holds the long name, then a space
    assert max(len(line) for line in text.splitlines()) <= metrics.TABLE_WIDTH


def test_format_table_name_column_is_at_least_nine_wide():
    text = metrics.format_table(
        {
            "scenario": "s",
            "seed": 0,
            "duration_s": 1.0,
            "wall_time_s": 1.0,
            "estimators": {"a": _rec([1.0] * 3, [1.0] * 3, 1.0, bias=[1.0] * 3, conv=0.0, nees=1.0)},
        }
    )
    _check_aligned(text)
    _, rows, _ = _parse_table(text)
    assert all(line.startswith("a" + " " * 9) for line in (rows["a"]["line"], rows["a"]["line2"]))
    assert all(text.splitlines()[i].startswith("estimator ") for i, _ in _blocks(text.splitlines()))


def test_format_table_footer_names_each_nees_dof():
    est = {
        "mekf": dict(_rec([1.0] * 3, [1.0] * 3, 1.0, nees=6.0), nees_dof=6),
        "ekf": dict(_rec([1.0] * 3, [1.0] * 3, 1.0, nees=3.0), nees_dof=3),
    }
    text = metrics.format_table({"scenario": "s", "seed": 0, "duration_s": 1.0, "wall_time_s": 1.0, "estimators": est})
    assert "NEES dof: 3 (ekf), 6 (mekf)" in text


def test_format_table_of_compute_metrics_output(tiny_metrics):
    text = metrics.format_table(tiny_metrics)
    _, rows, scored_from = _parse_table(text)
    assert scored_from == 2.0
    _check_aligned(text)
    for name, rec in tiny_metrics["estimators"].items():
        for t, v in zip(rows[name]["rm"], rec["attitude_rmse_deg"], strict=True):
            assert_printed(t, v)
        assert_printed(rows[name]["nees"], rec["nees_mean"])
        assert rows[name]["second"][0] == ("w" if name == "gpf" else "b")
        assert rows[name]["used"] == (50, 5)
    assert "NEES dof = 6" in text  # every estimator here has its second quantity's truth
