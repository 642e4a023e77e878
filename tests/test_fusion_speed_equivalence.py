"""The lean per-evaluation code of the fusion systems equals the numpy code it replaced.

``StarTrackerAverage._calc`` and the four outputs of ``EstimateFusion`` were rewritten for
speed (Python floats, the closed-form two-quaternion average, no re-validation of what the
constructors checked).  The previous implementation is the specification: it is kept here,
method for method, as oracle subclasses (``_Old*``: the same constructor, the old output
methods), and both are evaluated on the same random inputs — nominal samples and every
documented edge: a tracker flagged invalid or with a NaN flag, NaN / inf entries, samples of
another instant (|dt| > 1e-6 s) or within the tolerance, NaN times, quaternions of either
sign and of non-unit, tiny or huge norm, zero quaternions (the old code raised ValueError;
so must the new), N = 2 and 3 inputs, zero weights; for the fusion all three covariance
models, an inactive source (``status[1] == 0`` while another's is > 0), none active, sources
at different estimate times, and for "tracked" a step already applied, one to apply and
sources at different steps, plus its initialization and periodic update events.

Tolerances: quaternions and covariances agree to 1e-12 (relative to their magnitude); the
eigenvector and the closed form differ by round-off only (the random inputs keep the
average unique: the eigen-gap is >= ~0.5, so eigh's error is ~1e-16 / gap).  Validity
flags, counts and times agree exactly.  A quaternion whose scalar part is 0 to round-off
may come out with either sign from eigh (both are the canonical form of the same rotation);
only there the sign is not compared.
"""

import math

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.filters.quaternion_average import average_quaternions
from drake_att.systems import fusion
from drake_att.systems.fusion import TIME_TOLERANCE_S, EstimateFusion, StarTrackerAverage

NAN, INF = math.nan, math.inf
TOL = 1e-12


# =====================================================================================
# The previous implementation (verbatim method bodies), as oracles
# =====================================================================================
class _OldStarTrackerAverage(StarTrackerAverage):
    def _calc(self, context, output):
        meas = [p.Eval(context) for p in self._ports]
        times = np.array([m[0] for m in meas])
        fine = np.array([m[1] > 0.5 and m[1] == m[1] and np.all(np.isfinite(m)) for m in meas])
        t_latest = times[fine].max() if fine.any() else times.max()
        with np.errstate(invalid="ignore"):  # inf - inf when no sample is fine (then unused)
            fine &= np.abs(times - t_latest) < TIME_TOLERANCE_S  # this instant's samples only
        out = np.empty(6)
        q_avg, flag = np.array([1.0, 0.0, 0.0, 0.0]), 0.0
        if fine.all():
            q_B = np.array(
                [rot.quat_multiply(m[2:], rot.quat_conjugate(q)) for m, q in zip(meas, self.q_BS, strict=True)]
            )
            q_avg, flag = average_quaternions(q_B, self.weights), 1.0
        elif fine.any():
            idx = np.flatnonzero(fine)
            q_B = np.array([rot.quat_multiply(meas[i][2:], rot.quat_conjugate(self.q_BS[i])) for i in idx])
            with np.errstate(divide="ignore", invalid="ignore"):  # zero weight sum: NaN -> raises below
                w = self.weights[idx] / self.weights[idx].sum()
            q_avg = q_B[0] if len(idx) == 1 else average_quaternions(q_B, w)
            flag = 1.0 + float(sum(1 << int(i) for i in idx))
        out[0], out[1], out[2:] = t_latest, flag, q_avg
        output.SetFromVector(out)


class _OldEstimateFusion(EstimateFusion):
    def _eval(self, context, key):
        return [self._in[s][key].Eval(context) for s in self.source_names]

    def active_weights(self, context):
        used = np.array([self._in[s]["status"].Eval(context)[1] for s in self.source_names])
        active = used > 0
        if active.all() or not active.any():
            return self.weights
        w = self.weights * active
        with np.errstate(divide="ignore", invalid="ignore"):
            return w / w.sum()

    def _calc_q(self, context, output):
        output.SetFromVector(
            average_quaternions(np.array(self._eval(context, "q_IB_hat")), self.active_weights(context))
        )

    def _calc_second(self, context, output):
        output.SetFromVector(
            np.einsum("i,ij->j", self.active_weights(context), np.array(self._eval(context, "second")))
        )

    def _cross_covariance(self, context):
        x = context.get_discrete_state(self._cross_group).value()
        P12, applied = x[:36].reshape(6, 6), x[36]
        l1, l2 = (self._lin[s].Eval(context) for s in self.source_names)
        if l1[108] != l2[108]:
            return np.full((6, 6), np.nan), applied
        if l1[108] > applied:
            Phi1, Q, A1 = (l1[k * 36 : (k + 1) * 36].reshape(6, 6) for k in range(3))
            Phi2, A2 = l2[:36].reshape(6, 6), l2[72:108].reshape(6, 6)
            P12 = A1 @ (Phi1 @ P12 @ Phi2.T + Q) @ A2.T
        return P12, l1[108]

    def _calc_cov(self, context, output):
        P = np.array(self._eval(context, "covariance"))
        weights = self.active_weights(context)
        if weights is not self.weights:  # a dead branch dropped: the live ones' covariance
            live = weights > 0
            if live.sum() == 1:
                output.SetFromVector(P[np.argmax(live)])
                return
            c = weights if self.covariance_model == "conservative" else weights**2
            output.SetFromVector(np.einsum("i,ij->j", c, P))
            return
        if self.covariance_model == "tracked":
            (w1, w2), (P1, P2) = self.weights, P.reshape(2, 6, 6)
            P12, _ = self._cross_covariance(context)
            Pf = w1**2 * P1 + w2**2 * P2 + w1 * w2 * (P12 + P12.T)
            output.SetFromVector(Pf.ravel())
            return
        c = self.weights if self.covariance_model == "conservative" else self.weights**2
        output.SetFromVector(np.einsum("i,ij->j", c, P))

    def _calc_status(self, context, output):
        st = np.array(self._eval(context, "status"))
        t = st[0, 0] if np.ptp(st[:, 0]) < TIME_TOLERANCE_S else np.nan
        output.SetFromVector([t, st[:, 1].sum(), st[:, 2].sum(), np.nan])


# =====================================================================================
# Helpers
# =====================================================================================
def qmul(p, q):
    pw, pv, qw, qv = p[0], np.asarray(p[1:]), q[0], np.asarray(q[1:])
    return np.r_[pw * qw - pv @ qv, pw * qv + qw * pv + np.cross(pv, qv)]


def qexp(v):
    a = np.linalg.norm(v)
    return np.r_[np.cos(a / 2), np.sinc(a / (2 * np.pi)) * 0.5 * np.asarray(v)]


def random_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _eval_or_error(port, context):
    """The port's value, or the ValueError its evaluation raised."""
    try:
        return port.Eval(context).copy()
    except ValueError as e:
        return e


def _assert_same_quaternion(q_new, q_old, what):
    """Equal to TOL relative to |q_old|; the sign is free only when q_old's scalar part is
    zero to round-off (eigh's sign there is arbitrary)."""
    q_new, q_old = np.asarray(q_new), np.asarray(q_old)
    scale = np.linalg.norm(q_old)
    if abs(q_old[0]) < 1e-9 * scale and q_new @ q_old < 0.0:
        q_new = -q_new
    np.testing.assert_allclose(q_new, q_old, rtol=0.0, atol=TOL * scale, err_msg=what)


def _assert_same_outcome(new, old, compare, what):
    """Both raised ValueError, or both returned values equal under ``compare``."""
    if isinstance(old, ValueError) or isinstance(new, ValueError):
        assert isinstance(old, ValueError) and isinstance(new, ValueError), (what, new, old)
        return
    compare(new, old, what)


def _assert_close_to_magnitude(new, old, what):
    """Equal to TOL relative to the largest |entry| (NaN where the old one is NaN)."""
    finite = np.isfinite(old)
    scale = np.max(np.abs(old[finite]), initial=0.0)
    np.testing.assert_allclose(new, old, rtol=TOL, atol=TOL * scale, equal_nan=True, err_msg=what)


def _assert_exactly_equal(new, old, what):
    np.testing.assert_array_equal(new, old, err_msg=what)  # NaN == NaN here


# =====================================================================================
# StarTrackerAverage
# =====================================================================================
def _tracker_rows(rng, q_BS):
    """One sample per tracker: ``[t, flag, q_IS (4)]`` around a common body attitude, with
    the dropouts and odd values the system must handle (each with some probability)."""
    q_IB = random_quaternion(rng)
    spread = rng.choice([1e-5, 1e-3, 0.3])  # rad: realistic tracker noise ... far apart
    t = rng.uniform(0.0, 1e4)
    rows = []
    for qb in q_BS:
        q = qmul(qmul(q_IB, qb), qexp(rng.normal(size=3) * spread))
        q = q * rng.choice([-1.0, 1.0]) * rng.choice([1.0] * 6 + [1.0 + 1e-9, 3.0, 1e-3, 1e-60, 1e60])
        flag = rng.choice([1.0] * 8 + [0.0, 0.4, 0.6, 2.0, NAN, INF])
        dt = rng.choice(
            [0.0] * 8
            + [
                0.5 * TIME_TOLERANCE_S,
                -0.5 * TIME_TOLERANCE_S,
                2 * TIME_TOLERANCE_S,
                -2 * TIME_TOLERANCE_S,
                1.0,
                NAN,
                INF,
            ]
        )
        row = np.r_[t + dt, flag, q]
        u = rng.random()
        if u < 0.06:  # a non-finite entry in a sample flagged valid
            row[2 + rng.integers(4)] = rng.choice([NAN, INF, -INF])
        elif u < 0.08:  # a zero quaternion flagged valid (the average rejects it)
            row[2:] = 0.0
        rows.append(row)
    return rows


def _trackers(n, weights, rng):
    names = [f"st{i}" for i in range(n)]
    q_BS = [random_quaternion(rng) for _ in names]
    sigmas = [[5e-5, 5e-5, 2e-4]] * n
    new, old = (cls("avg", names, q_BS, sigmas, weights) for cls in (StarTrackerAverage, _OldStarTrackerAverage))
    return names, q_BS, (new, new.CreateDefaultContext()), (old, old.CreateDefaultContext())


def _compare_measurement(new, old, what):
    assert new[1] == old[1], (what, new, old)  # the flag (which trackers were used)
    _assert_exactly_equal(new[:1], old[:1], what)  # the sample time (NaN when undefined)
    if old[1] == 0.0:
        _assert_exactly_equal(new[2:], old[2:], what)  # identity, no tracker used
    else:
        _assert_same_quaternion(new[2:], old[2:], what)


@pytest.mark.parametrize(
    "n, weights", [(2, [1.0, 1.0]), (2, [1.0, 3.0]), (3, [1.0, 3.0, 2.0]), (3, [0.0, 1.0, 2.0]), (3, [0.0, 0.0, 1.0])]
)
def test_star_tracker_average_equals_the_previous_implementation(n, weights):
    """400 random samples per configuration (with dropouts, NaN/inf, misaligned times,
    either sign, non-unit norms, zero quaternions); every flag value the old code produced
    is reproduced, and the quaternion to 1e-12.  Weights with zeros: a subset of trackers
    whose weights sum to zero raised ValueError before and still does."""
    rng = np.random.default_rng(100 + 10 * n + int(sum(weights)))
    names, q_BS, (new, ctx_new), (old, ctx_old) = _trackers(n, weights, rng)
    flags_seen = set()
    for trial in range(400):
        rows = _tracker_rows(rng, q_BS)
        for sys_, ctx in ((new, ctx_new), (old, ctx_old)):
            for name, row in zip(names, rows, strict=True):
                sys_.GetInputPort(f"q_meas_{name}").FixValue(ctx, row)
        out_new = _eval_or_error(new.get_output_port(0), ctx_new)
        out_old = _eval_or_error(old.get_output_port(0), ctx_old)
        _assert_same_outcome(out_new, out_old, _compare_measurement, f"trial {trial}: {rows}")
        if not isinstance(out_old, ValueError):
            flags_seen.add(float(out_old[1]))
    # The random inputs reached every outcome: none fine, all fine, every subset (but those
    # of two or more trackers with zero weight sum, which raise).
    w = np.asarray(weights)
    subsets = [
        m for m in range(1, (1 << n) - 1) if m.bit_count() == 1 or w[[i for i in range(n) if m >> i & 1]].sum() > 0
    ]
    assert flags_seen >= {0.0, 1.0} | {1.0 + m for m in subsets}, flags_seen


def test_star_tracker_average_nominal_samples_take_the_lean_path(monkeypatch):
    """Valid, finite, aligned unit samples (the simulation's case) never reach the checked
    average_quaternions — the speed-up's guard — and its result is still the eigenvector
    average (checked against the oracle)."""
    rng = np.random.default_rng(3)
    for n in (2, 3):
        names, q_BS, (new, ctx_new), (old, ctx_old) = _trackers(n, [1.0, 2.0, 4.0][:n], rng)
        cases = []
        for _ in range(20):
            q_IB = random_quaternion(rng)
            rows = [np.r_[7.0, 1.0, qmul(qmul(q_IB, qb), qexp(rng.normal(size=3) * 1e-4))] for qb in q_BS]
            for k in range(n):
                dropped = [r.copy() for r in rows]
                dropped[k][1] = 0.0
                cases.append(dropped)
            cases.append(rows)
        expected = []
        for rows in cases:
            for name, row in zip(names, rows, strict=True):
                old.GetInputPort(f"q_meas_{name}").FixValue(ctx_old, row)
            expected.append(old.get_output_port(0).Eval(ctx_old).copy())

        def fail(*args, **kwargs):
            raise AssertionError("the checked average_quaternions was called on the nominal path")

        with monkeypatch.context() as m:
            m.setattr(fusion, "average_quaternions", fail)
            for rows, out_old in zip(cases, expected, strict=True):
                for name, row in zip(names, rows, strict=True):
                    new.GetInputPort(f"q_meas_{name}").FixValue(ctx_new, row)
                _compare_measurement(new.get_output_port(0).Eval(ctx_new), out_old, f"n={n}")


# =====================================================================================
# EstimateFusion
# =====================================================================================
OUTPUTS = ("q_IB_hat", "bias_B_hat", "covariance", "status")


def _random_spd(rng, scale):
    L = rng.normal(size=(6, 6)) * scale
    return L @ L.T + np.diag(np.full(6, scale**2))


def _fusions(n, weights, model):
    names = [f"e{i}" for i in range(n)]
    period = 1.0 if model == "tracked" else None
    new, old = (
        cls("fusion", names, weights, "bias_B_hat", model, period) for cls in (EstimateFusion, _OldEstimateFusion)
    )
    return names, (new, new.CreateDefaultContext()), (old, old.CreateDefaultContext())


def _source_inputs(rng, n, tracked):
    """Random inputs of n sources, and for "tracked" their linearizations and a stored
    ``[P_12, steps applied]``: the step already applied, one to apply, or disagreeing."""
    q0 = random_quaternion(rng)
    spread = rng.choice([1e-4, 1e-2, 0.3])
    t = rng.uniform(0.0, 1e4)
    inputs = []
    for _i in range(n):
        q = qmul(q0, qexp(rng.normal(size=3) * spread))
        q = q * rng.choice([-1.0, 1.0]) * rng.choice([1.0] * 6 + [1.0 + 1e-9, 3.0, 1e-3, 1e-60, 1e60])
        used = rng.choice([0.0, 0.0, 1.0, 37.0, NAN])
        dt = rng.choice([0.0] * 6 + [0.5 * TIME_TOLERANCE_S, 2 * TIME_TOLERANCE_S, NAN])
        inputs.append(
            {
                "q_IB_hat": q,
                "second": rng.normal(size=3) * 10.0 ** rng.integers(-6, 1),
                "covariance": _random_spd(rng, 10.0 ** rng.integers(-4, 0)).ravel(),
                "status": np.r_[t + dt, used, float(rng.integers(0, 5)), rng.normal()],
            }
        )
    state = None
    if tracked:
        applied = float(rng.integers(0, 5))
        steps = {0: (applied, applied), 1: (applied + 1, applied + 1), 2: (applied + 1, applied + 2)}[rng.integers(3)]
        for src, step in zip(inputs, steps, strict=True):
            Phi, A = np.eye(6) + 0.1 * rng.normal(size=(6, 6)), np.eye(6) - 0.3 * rng.random((6, 6))
            src["linearization"] = np.r_[Phi.ravel(), _random_spd(rng, 1e-3).ravel(), A.ravel(), step]
        state = np.r_[(rng.normal(size=(6, 6)) * 1e-3).ravel(), applied]
    return inputs, state


def _fix(sys_, ctx, names, inputs, state):
    for name, src in zip(names, inputs, strict=True):
        for key, value in src.items():
            sys_.GetInputPort(f"{name}_{key}").FixValue(ctx, value)
    if state is not None:
        ctx.SetDiscreteState(0, state)


_COMPARE = {
    "q_IB_hat": lambda new, old, what: _assert_same_quaternion(new, old, what),
    "bias_B_hat": _assert_close_to_magnitude,
    "covariance": _assert_close_to_magnitude,
    "status": _assert_exactly_equal,
}


@pytest.mark.parametrize(
    "n, weights, model",
    [
        (2, [1.0, 1.0], "tracked"),
        (2, [1.0, 3.0], "tracked"),
        (2, [0.0, 1.0], "tracked"),
        (2, [1.0, 1.0], "conservative"),
        (2, [2.0, 1.0], "independent"),
        (2, [0.0, 1.0], "conservative"),
        (3, [1.0, 2.0, 5.0], "conservative"),
        (3, [1.0, 2.0, 5.0], "independent"),
        (3, [0.0, 2.0, 5.0], "independent"),
    ],
)
def test_estimate_fusion_equals_the_previous_implementation(n, weights, model):
    """300 random input sets per configuration: all four outputs and active_weights equal
    the old code's (quaternion and covariances to 1e-12, status exactly); the cases reached
    include all sources active, some inactive (renormalized weights, a single live source's
    covariance passed through), none active, and the zero-weight-sum case where the old
    average raised ValueError (the new one must too). "tracked": the initialization and
    periodic update events store the same ``[P_12, steps]``."""
    rng = np.random.default_rng(7 + 31 * n + 3 * len(model) + int(weights[0]))
    names, (new, ctx_new), (old, ctx_old) = _fusions(n, weights, model)
    tracked = model == "tracked"
    reached = set()
    for trial in range(300):
        inputs, state = _source_inputs(rng, n, tracked)
        _fix(new, ctx_new, names, inputs, state)
        _fix(old, ctx_old, names, inputs, state)
        what = f"trial {trial}"
        for name in OUTPUTS:
            _assert_same_outcome(
                _eval_or_error(new.GetOutputPort(name), ctx_new),
                _eval_or_error(old.GetOutputPort(name), ctx_old),
                _COMPARE[name],
                f"{what} {name}",
            )
        w_new, w_old = new.active_weights(ctx_new), old.active_weights(ctx_old)
        assert (w_new is new.weights) == (w_old is old.weights), what
        np.testing.assert_allclose(w_new, w_old, rtol=1e-15, atol=0.0, equal_nan=True, err_msg=what)
        active = tuple(bool(st[1] > 0) for st in (src["status"] for src in inputs))
        reached.add("all" if all(active) else "none" if not any(active) else "some")
        if isinstance(_eval_or_error(old.GetOutputPort("q_IB_hat"), ctx_old), ValueError):
            reached.add("raises")
        if tracked:
            x_new = new.EvalUniquePeriodicDiscreteUpdate(ctx_new).get_vector(0).value()
            x_old = old.EvalUniquePeriodicDiscreteUpdate(ctx_old).get_vector(0).value()
            _assert_close_to_magnitude(x_new, x_old, f"{what} periodic update")
            if trial % 50 == 0:
                new.ExecuteInitializationEvents(ctx_new)
                old.ExecuteInitializationEvents(ctx_old)
                _assert_exactly_equal(
                    ctx_new.get_discrete_state(0).value(),
                    ctx_old.get_discrete_state(0).value(),
                    f"{what} initialization",
                )
    assert {"all", "some", "none"} <= reached, reached
    # Zero weight on a source that is the only active one: the old code raised (NaN weights).
    assert ("raises" in reached) == (weights[0] == 0.0), reached


def test_estimate_fusion_nominal_evaluations_take_the_lean_path(monkeypatch):
    """Two active sources with unit quaternions (the simulation's case) and a dead branch:
    the outputs never reach the checked average_quaternions, and equal the oracle's."""
    rng = np.random.default_rng(11)
    for model in ("tracked", "conservative"):
        names, (new, ctx_new), (old, ctx_old) = _fusions(2, [1.0, 1.0], model)
        for trial in range(20):
            inputs, state = _source_inputs(rng, 2, model == "tracked")
            for k, src in enumerate(inputs):
                src["q_IB_hat"] /= np.linalg.norm(src["q_IB_hat"])
                src["status"][:2] = [5.0, 0.0 if (trial % 3 == 1 and k == 1) else 10.0]
            _fix(old, ctx_old, names, inputs, state)
            expected = {k: old.GetOutputPort(k).Eval(ctx_old).copy() for k in OUTPUTS}
            with monkeypatch.context() as m:
                m.setattr(
                    fusion,
                    "average_quaternions",
                    lambda *a, **k: pytest.fail("the checked average_quaternions was called"),
                )
                _fix(new, ctx_new, names, inputs, state)
                for k in OUTPUTS:
                    _COMPARE[k](new.GetOutputPort(k).Eval(ctx_new), expected[k], f"{model} {trial} {k}")


@pytest.mark.parametrize("model", ["tracked", "conservative", "independent"])
def test_estimate_fusion_packed_output_equals_the_four_contract_ports(model):
    """``estimate_state`` (what the builder logs) is ``[q_IB_hat, second, covariance, status]``
    of the same inputs, bit for bit (NaN where they are NaN), over random inputs."""
    rng = np.random.default_rng(11)
    names = ["a", "b"]
    fusion = EstimateFusion("fusion", names, [0.3, 0.7], "bias_B_hat", model, 1.0)
    context = fusion.CreateDefaultContext()
    checked = 0
    for k in range(60):
        for s in names:
            q = random_quaternion(rng)
            status = [float(k), float(rng.integers(0, 3)), float(rng.integers(0, 3)), 1.0]
            fusion.GetInputPort(f"{s}_q_IB_hat").FixValue(context, q)
            fusion.GetInputPort(f"{s}_second").FixValue(context, rng.normal(size=3))
            A = rng.normal(size=(6, 6))
            fusion.GetInputPort(f"{s}_covariance").FixValue(context, (A @ A.T).ravel())
            fusion.GetInputPort(f"{s}_status").FixValue(context, status)
            if model == "tracked":
                lin = np.r_[np.eye(6).ravel(), 1e-3 * np.eye(6).ravel(), np.eye(6).ravel(), [float(k % 3)]]
                fusion.GetInputPort(f"{s}_linearization").FixValue(context, lin)
        try:
            parts = [
                fusion.GetOutputPort(p).Eval(context).copy() for p in ("q_IB_hat", "bias_B_hat", "covariance", "status")
            ]
        except ValueError:
            continue  # the zero-weight corner (see the fusion tests): both paths raise
        packed = fusion.GetOutputPort("estimate_state").Eval(context)
        np.testing.assert_array_equal(packed, np.concatenate(parts))
        checked += 1
    assert checked > 40
