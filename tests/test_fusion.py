"""Paper S3 fusion (drake_att.systems.fusion and its scenario wiring).

* StarTrackerAverage and EstimateFusion as Drake systems with fixed inputs: their outputs
  against computations written here in numpy (own quaternion algebra, own eigenvector
  average, own cross-covariance recursion), validity/time logic, unequal weights.
* The dual-tracker scenario with all three decentralized covariance models in one diagram
  (one truth, one noise realization): the tracked model is NEES-consistent, the
  conservative one bounds the error, the independent one is overconfident; and the three
  architectures' accuracy ordering, derived from the filters' own covariances.

Time correlation of filter errors: a filter's error sequence is correlated from step to
step, so N samples carry the information of fewer independent ones.  Every statistical
band below uses n_eff = sum over runs of n / tau, with tau the integrated autocorrelation
time of the tested series (NEES or squared error), estimated with Sokal's automatic window
(smallest M with M >= 5 tau(M)) and never below 1.  Then Var(mean) = Var(x) tau / n, which
is what the chi-square / standard-error bands assume for n_eff independent samples.
"""

import dataclasses

import numpy as np
import pytest
from scipy import stats

from drake_att.analysis.metrics import estimator_errors
from drake_att.noise import ARCSEC
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import load
from drake_att.systems.fusion import EstimateFusion, StarTrackerAverage

SCORE_FROM_S = 100.0  # MEKFs start 5 deg off; errors and covariances settle in ~30 s


# -- independent quaternion algebra (Hamilton, [w, x, y, z]), written for the tests ------
def qmul(p, q):
    """Hamilton product (broadcasts over leading axes)."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    pw, pv, qw, qv = p[..., :1], p[..., 1:], q[..., :1], q[..., 1:]
    return np.concatenate(
        [pw * qw - np.sum(pv * qv, axis=-1, keepdims=True), pw * qv + qw * pv + np.cross(pv, qv)], axis=-1
    )


def qconj(q):
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def qexp(v):
    """Quaternion of the rotation vector v (angle |v| about v; broadcasts)."""
    v = np.asarray(v, float)
    a = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.concatenate([np.cos(a / 2), np.sinc(a / (2 * np.pi)) * 0.5 * v], axis=-1)


def qlog(q):
    """Rotation vector of q (either sign; broadcasts; q must not be the identity)."""
    q = np.asarray(q, float)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    return 2 * np.arctan2(s, q[..., :1]) * q[..., 1:] / s


def rotmat(q):
    """Attitude matrix R(q): R(q_AB) v_B = v_A."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def eig_average(qs, w):
    """Markley's average: dominant eigenvector of sum w_i q_i q_i' (w normalized here)."""
    w = np.asarray(w, float) / np.sum(w)
    M = sum(wi * np.outer(q, q) for wi, q in zip(w, qs, strict=True))
    vals, vecs = np.linalg.eigh(M)
    assert vals[-1] - vals[-2] > 1e-3  # unique average (inputs close to each other)
    return vecs[:, -1]


def assert_same_rotation(q, q_expected, atol=1e-12):
    """Equal as rotations: q = +-q_expected."""
    q, q_expected = np.asarray(q), np.asarray(q_expected) / np.linalg.norm(q_expected)
    s = 1.0 if q @ q_expected >= 0 else -1.0
    np.testing.assert_allclose(q, s * q_expected, atol=atol)


def random_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def random_spd(rng, scale):
    L = rng.normal(size=(6, 6)) * scale
    return L @ L.T + np.diag(np.full(6, scale**2))


def tau_int(x, c=5.0):
    """Integrated autocorrelation time of the series x (Sokal's automatic window), >= 1."""
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    tau = 1.0
    for m in range(1, n):
        tau = 1.0 + 2.0 * acf[1 : m + 1].sum()
        if m >= c * tau:
            break
    return max(tau, 1.0)


def n_effective(series_per_run):
    """Effectively independent samples in independent runs of correlated series."""
    return sum(len(x) / tau_int(x) for x in series_per_run)


# =====================================================================================
# StarTrackerAverage with fixed inputs
# =====================================================================================
def _fix_trackers(system, context, names, meas):
    for n, m in zip(names, meas, strict=True):
        system.GetInputPort(f"q_meas_{n}").FixValue(context, np.asarray(m, float))
    return system.get_output_port(0).Eval(context)


@pytest.mark.parametrize("n_trackers", [2, 3])
def test_star_tracker_average_output_is_the_weighted_average_of_body_attitudes(n_trackers):
    """q_IS_meas,i = q_IB ⊗ q_BS,i ⊗ exp(delta_i): the output must be the eigenvector
    average (unequal weights) of q_IS_meas,i ⊗ q_BS,i^-1, computed here; sign flips of the
    inputs change nothing; the output is valid and stamped with the common sample time;
    and to first order it is q_IB ⊗ exp(sum_i w_i R_BS,i delta_i) (the basis of
    covariance_B)."""
    rng = np.random.default_rng(10 + n_trackers)
    names = [f"st{i}" for i in range(n_trackers)]
    weights = [1.0, 3.0, 2.0][:n_trackers]
    w = np.array(weights) / sum(weights)
    q_BS = [random_quaternion(rng) for _ in names]  # generic mountings (no 180 deg ones)
    sys_ = StarTrackerAverage("avg", names, q_BS, [[5 * ARCSEC, 5 * ARCSEC, 50 * ARCSEC]] * n_trackers, weights)
    ctx = sys_.CreateDefaultContext()
    for trial in range(5):
        q_IB = random_quaternion(rng)
        deltas = rng.normal(size=(n_trackers, 3)) * 1e-3  # ~3.4 arcmin: first order holds to ~1e-6
        q_IS = [qmul(qmul(q_IB, qb), qexp(d)) for qb, d in zip(q_BS, deltas, strict=True)]
        t = 12.3 + trial
        out = _fix_trackers(sys_, ctx, names, [[t, 1.0, *q] for q in q_IS])
        assert out[0] == t and out[1] == 1.0
        q_body = [qmul(q, qconj(qb)) for q, qb in zip(q_IS, q_BS, strict=True)]
        assert_same_rotation(out[2:], eig_average(q_body, w))
        # First-order error model (second-order terms ~ |delta|^2 = 1e-6 rad).
        first_order = sum(wi * rotmat(qb) @ d for wi, qb, d in zip(w, q_BS, deltas, strict=True))
        np.testing.assert_allclose(qlog(qmul(qconj(q_IB), out[2:])), first_order, atol=5e-6)
        # Same rotations with flipped quaternion signs: the same output.
        flips = rng.choice([-1.0, 1.0], size=n_trackers)
        flips[0] = -1.0
        out_flipped = _fix_trackers(sys_, ctx, names, [[t, 1.0, *(s * q)] for s, q in zip(flips, q_IS, strict=True)])
        assert_same_rotation(out_flipped[2:], out[2:], atol=1e-14)


def test_star_tracker_average_uses_the_trackers_that_are_fine_and_says_which():
    """Documented: every input flagged valid, finite and of this instant (the latest valid
    time, |dt| < 1e-6 s) -> their weighted average, flag 1; only some of them -> the average of
    those (weights renormalized; noise-free: still the truth), flag 1 + bit mask of the
    inputs used; none -> flag 0. The estimator system picks the subset's covariance by the
    flag (QuaternionSensorModel.covariance_for_flag)."""
    from drake_att.systems.estimator_system import QuaternionSensorModel

    rng = np.random.default_rng(3)
    names = ["a", "b", "c"]
    q_BS = [random_quaternion(rng) for _ in names]
    sys_ = StarTrackerAverage("avg", names, q_BS, [[1e-5, 1e-5, 1e-4]] * 3, [1.0, 1.0, 2.0])
    ctx = sys_.CreateDefaultContext()
    q_IB = random_quaternion(rng)
    q_IS = [qmul(q_IB, qb) for qb in q_BS]

    def run(times=(5.0, 5.0, 5.0), flags=(1.0, 1.0, 1.0), quats=q_IS):
        return _fix_trackers(sys_, ctx, names, [[t, f, *q] for t, f, q in zip(times, flags, quats, strict=True)])

    good = run()
    assert good[1] == 1.0 and good[0] == 5.0
    assert_same_rotation(good[2:], q_IB, atol=1e-12)  # noise-free trackers: the truth
    for k in range(3):  # one tracker out: the other two, flag 1 + mask
        flags = [1.0, 1.0, 1.0]
        flags[k] = 0.0
        out = run(flags=flags)
        assert out[1] == 1.0 + (7 - (1 << k)), (k, out[1])
        assert_same_rotation(out[2:], q_IB, atol=1e-12)
    out = run(flags=(0.0, 0.0, 1.0))
    assert out[1] == 1.0 + 4 and out[0] == 5.0
    assert_same_rotation(out[2:], q_IB, atol=1e-12)
    assert run(flags=(0.0, 0.0, 0.0))[1] == 0.0
    assert run(flags=(np.nan, 1.0, 1.0))[1] == 1.0 + 6  # a NaN flag is not valid
    for bad in (np.nan, np.inf):  # flagged valid but non-finite: left out
        quats = [q.copy() for q in q_IS]
        quats[1][2] = bad
        out = run(quats=quats)
        assert out[1] == 1.0 + 5 and np.all(np.isfinite(out[2:]))
    # Different sample instants: the latest instant's samples only; within 1e-6 s: all.
    out = run(times=(5.0, 5.0, 5.1))
    assert out[1] == 1.0 + 4 and out[0] == 5.1
    assert run(times=(5.0, 5.0 + 2e-6, 5.0))[1] == 1.0 + 2
    ok = run(times=(5.0, 5.0 + 2e-7, 5.0))
    assert ok[1] == 1.0 and ok[0] == max(5.0, 5.0 + 2e-7)
    # The covariance the estimator then assumes: the subset's, from its renormalized weights.
    model = QuaternionSensorModel("avg", np.array([1.0, 0, 0, 0]), sys_.covariance_B, sys_.covariance_by_mask)
    np.testing.assert_array_equal(model.covariance_for_flag(1.0), sys_.covariance_B)
    R_c = rotmat(q_BS[2]) @ np.diag([1e-10, 1e-10, 1e-8]) @ rotmat(q_BS[2]).T  # tracker c alone: its own noise
    np.testing.assert_allclose(model.covariance_for_flag(1.0 + 4), R_c, rtol=1e-12, atol=1e-24)
    assert model.covariance_for_flag(1.0 + 7) is None and model.covariance_for_flag(0.0) is sys_.covariance_B


def test_star_tracker_average_covariance_matches_sampled_errors_unequal_weights():
    """Noise drawn here in each sensor frame (different sigmas per tracker, weights 1:2:3),
    pushed through the system's output: the sample covariance of the body-frame error
    log(q_IB^-1 ⊗ q_out) equals covariance_B = sum w_i^2 R_BS,i diag(s_i^2) R_BS,i'.
    Each element within 4 standard errors, se(C_ij) = sqrt((S_ij^2 + S_ii S_jj) / n)
    (Gaussian sample covariance; diagonal: relative se sqrt(2/n) = 2.2% for n = 4000)."""
    rng = np.random.default_rng(7)
    names = ["a", "b", "c"]
    q_BS = [random_quaternion(rng) for _ in names]
    sigmas = np.array([[5.0, 5.0, 50.0], [10.0, 10.0, 30.0], [3.0, 3.0, 80.0]]) * ARCSEC
    weights = [1.0, 2.0, 3.0]
    w = np.array(weights) / 6.0
    sys_ = StarTrackerAverage("avg", names, q_BS, sigmas, weights)
    S = sum(wi**2 * rotmat(qb) @ np.diag(s**2) @ rotmat(qb).T for wi, qb, s in zip(w, q_BS, sigmas, strict=True))
    np.testing.assert_allclose(sys_.covariance_B, S, rtol=1e-12, atol=1e-30)

    ctx = sys_.CreateDefaultContext()
    q_IB = random_quaternion(rng)
    n = 4000
    d = rng.normal(size=(n, 3, 3)) * sigmas  # [sample, tracker, sensor axis]
    q_IS = qmul(qmul(q_IB, np.array(q_BS)), qexp(d))  # (n, 3, 4)
    meas = np.concatenate(
        [np.broadcast_to(0.1 * np.arange(n)[:, None, None], (n, 3, 1)), np.ones((n, 3, 1)), q_IS], axis=-1
    )
    out = np.array([_fix_trackers(sys_, ctx, names, m) for m in meas])
    assert np.all(out[:, 1] == 1.0)
    errs = qlog(qmul(qconj(q_IB), out[:, 2:]))
    C = errs.T @ errs / n  # the mean is zero by construction
    se = np.sqrt((S**2 + np.outer(np.diag(S), np.diag(S))) / n)
    assert np.all(np.abs(C - S) <= 4 * se), (C - S) / se


def test_scenario_st_avg_covariance_structure():
    """The builder's StarTrackerAverage for paper S3's mountings (perpendicular boresights
    b1, b2 in the body x-y plane, weights 1/2): each tracker contributes
    sc^2 I + (sb^2 - sc^2) b_i b_i' and b1 b1' + b2 b2' = diag(1, 1, 0), so
    covariance_B = diag((sb^2 + sc^2)/4, (sb^2 + sc^2)/4, sc^2/2)."""
    sd = ScenarioDiagram(apply_overrides(load("cubesat_dual_star_tracker"), ["duration_s=1", "scoring.score_from_s=0"]))
    sb, sc = 50 * ARCSEC, 5 * ARCSEC
    np.testing.assert_allclose(
        sd.sensors["st_avg"].covariance_B,
        np.diag([(sb**2 + sc**2) / 4, (sb**2 + sc**2) / 4, sc**2 / 2]),
        rtol=1e-9,
        atol=1e-12 * sb**2,
    )


# =====================================================================================
# EstimateFusion with fixed inputs
# =====================================================================================
def _fix_sources(system, context, sources, q, second, P, status, lin=None):
    for i, s in enumerate(sources):
        system.GetInputPort(f"{s}_q_IB_hat").FixValue(context, q[i])
        system.GetInputPort(f"{s}_second").FixValue(context, second[i])
        system.GetInputPort(f"{s}_covariance").FixValue(context, P[i].ravel())
        system.GetInputPort(f"{s}_status").FixValue(context, status[i])
        if lin is not None:
            system.GetInputPort(f"{s}_linearization").FixValue(context, lin[i])


def _outputs(system, context):
    return {k: system.GetOutputPort(k).Eval(context) for k in ("q_IB_hat", "bias_B_hat", "covariance", "status")}


def _random_sources(rng, n):
    q0 = random_quaternion(rng)
    q = [qmul(q0, qexp(rng.normal(size=3) * 0.01)) for _ in range(n)]
    second = [rng.normal(size=3) * 1e-4 for _ in range(n)]
    P = [random_spd(rng, 1e-3) for _ in range(n)]
    status = [[7.0, 10.0 + i, 2.0 * i, 1.5] for i in range(n)]
    return q, second, P, status


@pytest.mark.parametrize("model", ["conservative", "independent"])
def test_estimate_fusion_three_sources_unequal_weights(model):
    """conservative: sum w_i P_i; independent: sum w_i^2 P_i (w normalized: 1:2:5);
    q = eigenvector average (sign of an input irrelevant); second = weighted mean; status
    = [common time, summed used, summed skipped, NaN]; NaN time when the times differ."""
    rng = np.random.default_rng(21)
    names = ["e1", "e2", "e3"]
    w = np.array([1.0, 2.0, 5.0]) / 8.0
    sys_ = EstimateFusion("fusion", names, [1.0, 2.0, 5.0], "bias_B_hat", model)
    ctx = sys_.CreateDefaultContext()
    q, second, P, status = _random_sources(rng, 3)
    _fix_sources(sys_, ctx, names, q, second, P, status)
    out = _outputs(sys_, ctx)
    c = w if model == "conservative" else w**2
    np.testing.assert_allclose(
        out["covariance"].reshape(6, 6), sum(ci * Pi for ci, Pi in zip(c, P, strict=True)), rtol=1e-12
    )
    assert_same_rotation(out["q_IB_hat"], eig_average(q, w))
    np.testing.assert_allclose(out["bias_B_hat"], sum(wi * s for wi, s in zip(w, second, strict=True)), rtol=1e-12)
    assert out["status"][0] == 7.0 and out["status"][1] == 33.0 and out["status"][2] == 6.0
    assert np.isnan(out["status"][3])
    # One source's quaternion negated (same rotation): same fused attitude.
    _fix_sources(sys_, ctx, names, [q[0], -q[1], q[2]], second, P, status)
    assert_same_rotation(sys_.GetOutputPort("q_IB_hat").Eval(ctx), out["q_IB_hat"], atol=1e-14)
    # Sources disagree on the estimate time: NaN time, counts still summed.
    status[2] = [8.0, 1.0, 1.0, 0.0]
    _fix_sources(sys_, ctx, names, q, second, P, status)
    st = sys_.GetOutputPort("status").Eval(ctx)
    assert np.isnan(st[0]) and st[1] == 22.0 and st[2] == 3.0


def test_estimate_fusion_of_a_non_finite_source_is_non_finite_not_an_exception():
    """A source whose estimate went NaN (a diverged filter): the fused attitude is NaN too, so
    the run ends in the builder's clean non-finite failure instead of an exception from the
    quaternion average in the middle of the simulation."""
    rng = np.random.default_rng(3)
    names = ["e1", "e2"]
    sys_ = EstimateFusion("fusion", names, [1.0, 1.0], "bias_B_hat", "conservative")
    ctx = sys_.CreateDefaultContext()
    q, second, P, status = _random_sources(rng, 2)
    q[1] = np.full(4, np.nan)
    _fix_sources(sys_, ctx, names, q, second, P, status)
    assert np.all(np.isnan(sys_.GetOutputPort("q_IB_hat").Eval(ctx)))


def _lin(Phi, Q, A, steps):
    return np.concatenate([Phi.ravel(), Q.ravel(), A.ravel(), [steps]])


def test_estimate_fusion_tracked_cross_covariance_recursion():
    """tracked: w1^2 P1 + w2^2 P2 + w1 w2 (P12 + P12'), P12 advanced once per source step
    by P12 <- A1 (Phi1 P12 Phi2' + Q) A2' (computed here), starting from P12 = the first
    source's covariance at initialization (their common initial one); the periodic event stores the advanced P12 so the same step is not applied
    twice; NaN covariance when the sources are at different steps.  Weights 1:3."""
    rng = np.random.default_rng(5)
    w1, w2 = 0.25, 0.75
    sys_ = EstimateFusion("fusion", ["m1", "m2"], [1.0, 3.0], "bias_B_hat", "tracked", 1.0)
    ctx = sys_.CreateDefaultContext()
    q, second, P, status = _random_sources(rng, 2)
    P0 = P[0]
    Phi1, Phi2 = np.eye(6) + 0.1 * rng.normal(size=(6, 6)), np.eye(6) + 0.1 * rng.normal(size=(6, 6))
    A1, A2 = np.eye(6) - 0.3 * rng.random((6, 6)), np.eye(6) - 0.3 * rng.random((6, 6))
    Q = random_spd(rng, 1e-3)

    def fused(P12):
        return w1**2 * P[0] + w2**2 * P[1] + w1 * w2 * (P12 + P12.T)

    # No source step yet (step count 0 = applied 0): initialization sets P12 = P0.
    _fix_sources(sys_, ctx, ["m1", "m2"], q, second, P, status, [_lin(np.eye(6), np.zeros((6, 6)), np.eye(6), 0)] * 2)
    sys_.ExecuteInitializationEvents(ctx)
    np.testing.assert_array_equal(ctx.get_discrete_state(0).value(), np.r_[P0.ravel(), 0.0])
    np.testing.assert_allclose(sys_.GetOutputPort("covariance").Eval(ctx).reshape(6, 6), fused(P0), rtol=1e-12)
    # One step taken by both sources: advanced once.
    P12_1 = A1 @ (Phi1 @ P0 @ Phi2.T + Q) @ A2.T
    _fix_sources(sys_, ctx, ["m1", "m2"], q, second, P, status, [_lin(Phi1, Q, A1, 1), _lin(Phi2, Q, A2, 1)])
    out = _outputs(sys_, ctx)
    np.testing.assert_allclose(out["covariance"].reshape(6, 6), fused(P12_1), rtol=1e-12)
    assert_same_rotation(out["q_IB_hat"], eig_average(q, [w1, w2]))
    np.testing.assert_allclose(out["bias_B_hat"], w1 * second[0] + w2 * second[1], rtol=1e-12)
    # The periodic event stores [P12_1, 1]; with the same inputs nothing is applied again.
    ctx.get_mutable_discrete_state().SetFrom(sys_.EvalUniquePeriodicDiscreteUpdate(ctx))
    np.testing.assert_allclose(ctx.get_discrete_state(0).value(), np.r_[P12_1.ravel(), 1.0], rtol=1e-12)
    np.testing.assert_allclose(sys_.GetOutputPort("covariance").Eval(ctx).reshape(6, 6), fused(P12_1), rtol=1e-12)
    # Second step with other matrices: advanced from the stored P12_1.
    Phi1b, A2b = Phi2.T, A1.T
    P12_2 = A1 @ (Phi1b @ P12_1 @ Phi2.T + Q) @ A2b.T
    _fix_sources(sys_, ctx, ["m1", "m2"], q, second, P, status, [_lin(Phi1b, Q, A1, 2), _lin(Phi2, Q, A2b, 2)])
    np.testing.assert_allclose(sys_.GetOutputPort("covariance").Eval(ctx).reshape(6, 6), fused(P12_2), rtol=1e-12)
    # Sources at different steps: no consistent cross covariance -> NaN.
    _fix_sources(sys_, ctx, ["m1", "m2"], q, second, P, status, [_lin(Phi1b, Q, A1, 3), _lin(Phi2, Q, A2b, 2)])
    assert np.all(np.isnan(sys_.GetOutputPort("covariance").Eval(ctx)))


# =====================================================================================
# The dual-tracker scenario with the three covariance models
# =====================================================================================
MODELS = ("tracked", "conservative", "independent")


@pytest.fixture(scope="module")
def dual_run():
    """The S3 dual-tracker scenario, 800 s, 3 seeds, one diagram: the shipped
    "decentralized" fusion (covariance_model: tracked) plus copies of it set to the other
    two models through the scenario override syntax.  Adding systems does not change any
    noise (each noise stream is keyed by its system's name), and the fusions are stateless
    for the estimate, so all three see the same truth and the same two MEKFs."""
    s = apply_overrides(load("cubesat_dual_star_tracker"), ["duration_s=800", f"scoring.score_from_s={SCORE_FROM_S}"])
    dec = next(e for e in s.estimators if e.name == "decentralized")
    assert dec.covariance_model == "tracked"
    s.estimators += [dataclasses.replace(dec, name=f"decentralized_{m}") for m in MODELS[1:]]
    s = apply_overrides(s, [f"estimators.decentralized_{m}.covariance_model={m}" for m in MODELS[1:]])
    sd = ScenarioDiagram(s)
    return sd, [sd.simulate(seed) for seed in (1, 2, 3)]


def _scored(run, name):
    e = estimator_errors(run, name)
    m = e["t"] >= SCORE_FROM_S
    return {
        "err": np.concatenate([e["dtheta"], e["second_err"]], axis=1)[m],
        "P": e["P"][m],
        "nees": e["nees"][m],
        "q_hat": e["q_hat"][m],
    }


def _fusion_name(model):
    return "decentralized" if model == "tracked" else f"decentralized_{model}"


def test_three_architectures_share_one_truth_and_one_noise_realization(dual_run):
    sd, runs = dual_run
    run = runs[0]
    # One plant and one set of sensors in the diagram: every estimator is scored against the
    # same truth log, and the centralized average is built from the same tracker samples.
    assert sum(1 for k in run.signals if k.endswith("/q_IB")) == 1
    assert sum(1 for k in run.signals if k.endswith("/gyro_measurement")) == 1
    e_single = estimator_errors(run, "single")
    e_cent = estimator_errors(run, "centralized")
    np.testing.assert_array_equal(e_single["q_true"], e_cent["q_true"])


def test_decentralized_covariance_models_through_estimate_fusion(dual_run):
    """The fused error e = (e1 + e2)/2 of two MEKFs sharing one gyro, with the covariance
    each EstimateFusion instance reports (3 seeds x 700 scored samples, 6-dof NEES):

    * tracked: consistent, mean NEES inside the 99.8% chi-square band
      chi2(6 n_eff)/n_eff with n_eff from the NEES series' autocorrelation time;
    * conservative (sum w_i P_i): Jensen, (sum w_i e_i)^2 <= sum w_i e_i^2, so for
      consistent branches each axis' mean-square error <= mean reported variance, up to
      3 standard errors of a mean square, sqrt(2 / n_eff); and the mean NEES is below the
      band's lower edge (significantly below dof);
    * independent (sum w_i^2 P_i): overconfident, mean NEES above the band's upper edge.
    Also the wiring: the three fusions give the same estimate (the model changes only the
    covariance); conservative = (P_single + P_single_st2)/2 from the MEKFs' own logs; and
    conservative - tracked = w1 w2 E[(e1 - e2)(e1 - e2)'] is positive semidefinite."""
    sd, runs = dual_run
    assert [sd.estimators[_fusion_name(m)].covariance_model for m in MODELS] == list(MODELS)
    res = {m: [_scored(r, _fusion_name(m)) for r in runs] for m in MODELS}
    branches = [[_scored(r, n) for r in runs] for n in ("single", "single_st2")]
    for k in range(len(runs)):
        for m in MODELS[1:]:
            np.testing.assert_array_equal(res[m][k]["q_hat"], res["tracked"][k]["q_hat"])
            np.testing.assert_array_equal(res[m][k]["err"], res["tracked"][k]["err"])
        np.testing.assert_allclose(
            res["conservative"][k]["P"], 0.5 * (branches[0][k]["P"] + branches[1][k]["P"]), rtol=1e-12
        )
        D = res["conservative"][k]["P"] - res["tracked"][k]["P"]
        scale = np.trace(res["tracked"][k]["P"], axis1=1, axis2=2)
        assert np.all(np.linalg.eigvalsh(D).min(axis=1) >= -1e-9 * scale)

    def band(n_eff, dof=6, p=0.001):
        return stats.chi2.ppf([p, 1 - p], dof * n_eff) / n_eff

    nees, lo, hi = {}, {}, {}
    for m in MODELS:
        series = [x["nees"] for x in res[m]]
        nees[m] = np.concatenate(series).mean()
        lo[m], hi[m] = band(n_effective(series))
    assert lo["tracked"] < nees["tracked"] < hi["tracked"], (nees, lo, hi)
    assert nees["conservative"] < lo["conservative"], (nees, lo, hi)
    assert nees["independent"] > hi["independent"], (nees, lo, hi)

    err = [x["err"] for x in res["conservative"]]
    ms = np.concatenate(err).__pow__(2).mean(axis=0)
    n_eff = np.array([n_effective([e[:, i] ** 2 for e in err]) for i in range(6)])
    var_reported = {m: np.concatenate([x["P"].diagonal(axis1=1, axis2=2) for x in res[m]]).mean(axis=0) for m in MODELS}
    assert np.all(ms <= var_reported["conservative"] * (1 + 3 * np.sqrt(2 / n_eff))), ms / var_reported["conservative"]
    # Independent: the shared gyro makes the bias errors of the branches strongly
    # correlated, so on the bias axes the true variance is ~2x what it reports.
    assert np.any(ms > var_reported["independent"] * (1 + 3 * np.sqrt(2 / n_eff))), ms / var_reported["independent"]


def test_architecture_ordering_derived_from_the_filters_covariances(dual_run):
    """Paper S3's claim (centralized and decentralized beat single on every axis) and the
    joint MEKF (optimal: all data in one filter) at least as good as both, with thresholds
    from the filters' own covariances:

    * each filter is calibrated: per-axis RMSE / sqrt(mean reported variance) within
      1 +- 3 se, se = sqrt(1 / (2 n_eff)) the relative standard error of an RMS;
    * the ratio of two filters' RMSE agrees with the ratio of their reported sigmas within
      3 se_ratio, se_ratio = sqrt(se_a^2 + se_b^2) (errors of filters fed by the same gyro
      are positively correlated, which only makes the true se smaller);
    * the predicted ratios make the ordering significant: sigma_cent / sigma_single and
      sigma_dec / sigma_single < 1 - 3 se_ratio on every axis, sigma_joint <= sigma_other."""
    sd, runs = dual_run
    rms, sig, se = {}, {}, {}
    for name in ("single", "centralized", "decentralized", "joint"):
        sc = [_scored(r, name) for r in runs]
        d = [x["err"][:, :3] for x in sc]
        rms[name] = np.sqrt(np.concatenate(d).__pow__(2).mean(axis=0))
        sig[name] = np.sqrt(np.concatenate([x["P"][:, :3, :3].diagonal(axis1=1, axis2=2) for x in sc]).mean(axis=0))
        se[name] = np.sqrt(1 / (2 * np.array([n_effective([x[:, i] ** 2 for x in d]) for i in range(3)])))
        assert np.all(np.abs(rms[name] / sig[name] - 1) <= 3 * se[name]), (name, rms[name] / sig[name], se[name])

    def ratios(a, b):
        return rms[a] / rms[b], sig[a] / sig[b], np.sqrt(se[a] ** 2 + se[b] ** 2)

    for a in ("centralized", "decentralized"):
        emp, pred, s = ratios(a, "single")
        assert np.all(pred < 1 - 3 * s), (a, pred, s)
        assert np.all(np.abs(emp - pred) <= 3 * s * pred), (a, emp, pred, s)
        assert np.all(emp < 1), (a, emp)
    for b in ("centralized", "decentralized"):
        emp, pred, s = ratios("joint", b)
        assert np.all(pred <= 1 + 1e-3), (b, pred)
        assert np.all(emp <= pred * (1 + 3 * s)), (b, emp, pred, s)


def test_decentralized_fusion_leaves_out_a_branch_whose_tracker_never_delivered():
    """st2 is out for the whole run: its MEKF (single_st2) never uses a measurement and stays
    near its initial guess. The decentralized fusion leaves it out (weight 0) and equals the
    live branch (single) bit for bit — estimate and covariance — instead of averaging a
    predicted-only attitude in (the quaternion average with weights [1, 0] equals the live
    branch to round-off, the covariance exactly)."""
    from drake_att.analysis.metrics import estimator_errors

    s = apply_overrides(
        load("cubesat_dual_star_tracker"),
        ["duration_s=60", "scoring.score_from_s=10", "sensors.st2.outage_windows_s=[[-1.0, 1000.0]]"],
    )
    run = ScenarioDiagram(s).simulate(1)
    dec, single, dead = (estimator_errors(run, n) for n in ("decentralized", "single", "single_st2"))
    assert int(dead["status"][-1, 1]) == 0 and int(single["status"][-1, 1]) > 50
    live = dec["t"] > 0.0
    np.testing.assert_allclose(dec["dtheta"][live], single["dtheta"][live], rtol=0, atol=1e-14)
    np.testing.assert_array_equal(dec["P"][live], single["P"][live])
    assert np.degrees(np.abs(dec["dtheta"][-1])).max() < 0.05


def test_centralized_mekf_keeps_updating_with_the_tracker_that_is_fine():
    """st2 is out for 10-50 s of a 60 s run: the averaged measurement carries st1 alone (flag
    1 + 1) with st1's own covariance, so the centralized MEKF skips nothing (it used to lose
    every step of the outage), and its errors stay consistent with its covariance (NEES over
    the outage within the 99.9% chi-square band of 6 dof times the steps, conservatively)."""
    s = apply_overrides(
        load("cubesat_dual_star_tracker"),
        ["duration_s=60", "scoring.score_from_s=10", "sensors.st2.outage_windows_s=[[10.0, 50.0]]"],
    )
    run = ScenarioDiagram(s).simulate(1)
    cen = estimator_errors(run, "centralized")
    assert int(cen["status"][-1, 2]) == 0 and int(cen["status"][-1, 1]) == 60  # t = 0..59
    out = (cen["t"] >= 12.0) & (cen["t"] < 50.0)
    d = cen["dtheta"][out]
    P = cen["P"][out][:, :3, :3]
    nees = np.einsum("ni,ni->n", d, np.linalg.solve(P, d[..., None])[..., 0])
    assert nees.sum() < stats.chi2.ppf(0.999, 3 * out.sum()), nees.mean()


@pytest.mark.parametrize(
    "override, field",
    [
        ("estimators.single_st2.coning_correction=true", "coning_correction"),
        ("estimators.single_st2.initial_attitude_sigma_deg=4.0", "initial_attitude_sigma_deg"),
        ("estimators.single_st2.initial_bias_deg_per_h=[1.0, 0.0, 0.0]", "initial_bias_deg_per_h"),
    ],
)
def test_tracked_fusion_refuses_sources_that_do_not_propagate_alike(override, field):
    """The tracked cross-covariance recursion is the two filters' model of their common error
    only if both propagate alike from the same start. A source with another coning setting
    (another error transition) or another initial estimate or sigma is refused, naming the
    fusion's field and what differs."""
    from drake_att.scenarios.config import ConfigError

    with pytest.raises(ConfigError) as e:
        apply_overrides(load("cubesat_dual_star_tracker"), [override])
    text = str(e.value)
    assert "(decentralized).covariance_model" in text and "'tracked'" in text and repr([field]) in text, text


def test_tracked_fusion_accepts_another_gyro_noise_tuning_of_one_branch():
    """A gyro-noise tuning is a context parameter (a sweep may change one branch's): accepted,
    the common noise of the cross term being the first source's."""
    s = apply_overrides(
        load("cubesat_dual_star_tracker"),
        ["estimators.single_st2.arw_deg_per_rt_h=2.0", "estimators.single_st2.rrw_deg_per_h15=60.0"],
    )
    assert [e.covariance_model for e in s.estimators if e.name == "decentralized"] == ["tracked"]
