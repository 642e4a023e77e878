"""The star tracker's and the gyro's outputs equal those of their earlier implementations.

The output callbacks of :class:`~drake_att.systems.star_tracker.StarTracker` and of the
gyro's Python part (``_GyroOutputs``) were rewritten for speed (a cache entry per context
for the seed words and noise parameter, per-block lists of stamps, flags and noise, the
quaternion product in Python floats).  The oracles below are the earlier implementations
(commit b975017), copied verbatim except that they are free functions of ``(system,
context)`` with their own memo tables; every output must equal theirs exactly (the same
bits; ``assert_array_equal`` takes ``-0.0 == 0.0``, the one difference the rewrite allows:
the gyro no longer multiplies by an identity sensor matrix, which turned a ``-0.0`` rate
into ``+0.0``).

Evaluated at: ``t = 0``, sample instants, times between them and just after them, the
block boundaries ``k = 255, 256, 257`` (and ``511 .. 513``), times going backwards and jumps
past the per-stream block tables; with drop-outs and outage windows, in vector mode with
the ``vector_noise`` input connected and not, the gyro with and without misalignment and
scale-factor errors and with the ``scale_error`` and ``w_IB_B_integral`` inputs connected
and not; several seeds, contexts whose parameter or seed changes, two contexts at once and
a cloned context.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.contract import GYRO_MEASUREMENT_SIZE, QUATERNION_MEASUREMENT_SIZE
from drake_att.noise import CounterRandom
from drake_att.systems.gyro import Gyro, GyroModel, _GyroOutputs
from drake_att.systems.randomness import counter_random
from drake_att.systems.star_tracker import StarTracker

BLOCK = CounterRandom.BLOCK


# ----------------------------------------------------------------------------------
# Oracles: the implementations of commit b975017 (bodies unchanged but for ``self`` ->
# the system argument and the memo tables, which live here).
# ----------------------------------------------------------------------------------
class OldStarTracker:
    """``StarTracker._sample``, ``_block``, ``_calc_quaternion`` and ``_calc_vectors`` of
    commit b975017 for one tracker."""

    def __init__(self, tracker: StarTracker):
        self.s = tracker
        self._blocks: dict = {}

    def _sample(self, context):
        t, period = context.get_time(), self.s.period_s
        index = max(0, math.ceil(t / period - 1e-9))
        t_sample = (index - 1) * period + period if index else 0.0
        noise = self.s.noise(context)
        draws, valid = self._block(context.get_discrete_state_vector().value(), noise, index // CounterRandom.BLOCK)
        r = index % CounterRandom.BLOCK
        return t_sample, bool(valid[r]), draws[r], noise

    def _block(self, words, p, block: int):
        key = (words.tobytes(), id(p), block)
        hit = self._blocks.get(key)
        if hit is not None and hit[0] is p:
            return hit[1], hit[2]
        cr = counter_random(words, self.s.get_name())
        n = CounterRandom.BLOCK
        if self.s.mode == "quaternion":
            phi = p.sigmas_S * cr.normals_block(block, 3)
            x, y, z = phi[:, 0], phi[:, 1], phi[:, 2]
            a = np.sqrt(x * x + y * y + z * z)  # rot.rotvec_to_quat's scalar formula, per row
            with np.errstate(invalid="ignore", divide="ignore"):
                k = np.where(a < rot._SMALL_ANGLE, 0.5 - a * a / 48.0, np.sin(0.5 * a) / a)
            dq = np.stack([np.cos(0.5 * a), k * x, k * y, k * z], axis=-1)
            draws = rot.quat_multiply(np.broadcast_to(self.s.q_BS, dq.shape), dq)
        else:
            draws = p.sigma_vector * cr.normals_block(block, self.s._n_noise)
        index = np.arange(block * n, (block + 1) * n)
        valid = cr.uniforms_block(block, 1)[:, 0] >= p.dropout_probability
        if p.outage_windows_s:
            t = np.where(index > 0, (index - 1) * self.s.period_s + self.s.period_s, 0.0)
            for a, b in p.outage_windows_s:
                valid &= ~((a <= t) & (t < b))
        if len(self._blocks) > 16:
            self._blocks.clear()
        self._blocks[key] = (p, draws, valid)
        return draws, valid

    def quaternion(self, context) -> np.ndarray:
        t_sample, valid, noise, _ = self._sample(context)
        q_meas = rot.quat_canonical(rot.quat_multiply(self.s.GetInputPort("q_IB").Eval(context), noise))
        out = np.empty(QUATERNION_MEASUREMENT_SIZE)
        out[0], out[1], out[2:] = t_sample, float(valid), q_meas
        return out

    def vectors(self, context):
        t_sample, valid, noise, p = self._sample(context)
        q_IS = rot.quat_multiply(self.s.GetInputPort("q_IB").Eval(context), self.s.q_BS)
        R_SI = rot.quat_to_rotmat(q_IS).T
        noise_port = self.s.GetInputPort("vector_noise")
        if noise_port.HasValue(context):
            noise = noise_port.Eval(context)
        dirs = self.s.references_I @ R_SI.T + np.reshape(noise, (-1, 3))
        return float(t_sample), bool(valid), dirs, p.sigma_vector


class OldGyroOutputs:
    """``_GyroOutputs._draw``, ``_calc_measurement`` and ``_calc_bias`` of commit b975017
    for one gyro."""

    def __init__(self, outputs: _GyroOutputs):
        self.s = outputs
        self._draws: dict = {}

    def _draw(self, context, n: int, model):
        words = context.get_discrete_state_vector().value()
        key = (words.tobytes(), id(model))
        entry = self._draws.get(key)
        if entry is None or entry[0] is not model:
            if len(self._draws) > 8:
                self._draws.clear()
            entry = self._draws[key] = (model, counter_random(words, self.s.stream), [])
        model, cr, blocks = entry
        b, r = divmod(n, cr.BLOCK)
        while len(blocks) <= b:  # blocks in order: each starts from the previous block's last bias
            z = cr.normals_block(len(blocks), 9)
            e, db = model.noise.from_normals(np.moveaxis(z[:, :6].reshape(-1, 2, 3), 1, 0))
            if not blocks:
                start = model.initial_bias + model.initial_bias_sigma * z[0, 6:9]  # B_0
                bias = np.add.accumulate(np.vstack([start, db[1:]]), axis=0)
                previous = np.vstack([start, bias[:-1]])  # B_(n-1), with B_0 for n = 0
            else:
                last = blocks[-1][1][-1]
                bias = np.add.accumulate(np.vstack([last, db]), axis=0)[1:]
                previous = np.vstack([last, bias[:-1]])
            blocks.append((previous + e, bias))
        offsets, biases = blocks[b]
        return offsets[r], biases[r]

    def _sample_index(self, t: float):
        n = max(0, math.ceil(t / self.s.period_s - 1e-9))
        return n, ((n - 1) * self.s.period_s + self.s.period_s if n else 0.0)

    def measurement(self, context) -> np.ndarray:
        s = self.s
        t = context.get_time()
        n, t_n = self._sample_index(t)
        model = s.model(context)
        offset, _ = self._draw(context, n, model)
        elapsed = t - (t_n - s.period_s)
        integral_port, held_port = s.GetInputPort("w_IB_B_integral"), s.GetInputPort("w_IB_B_integral_held")
        if n >= 1 and elapsed > 1e-12 and integral_port.HasValue(context):
            w_true = (integral_port.Eval(context) - held_port.Eval(context)) / elapsed
        else:
            w_true = s.GetInputPort("w_IB_B").Eval(context)
        w_meas = model.sensor_matrix @ w_true
        scale_error_port = s.GetInputPort("scale_error")
        if scale_error_port.HasValue(context):
            w_meas = w_meas / (1.0 + scale_error_port.Eval(context)[0])
        w_meas = w_meas + offset
        out = np.empty(GYRO_MEASUREMENT_SIZE)
        out[0], out[1], out[2:] = t_n, 1.0, w_meas
        return out

    def bias(self, context) -> np.ndarray:
        return self._draw(context, self._sample_index(context.get_time())[0], self.s.model(context))[1]


# ----------------------------------------------------------------------------------
# Evaluation times
# ----------------------------------------------------------------------------------
def sample_times(period: float, seed: int = 0) -> list[float]:
    """Times that exercise every branch of the sample-index rule ``k = ceil(t / T - 1e-9)``:
    t = 0, instants, just before/after them, mid-interval, the block boundaries, a jump
    past the block tables and back, and random times in any order."""
    ks = [0, 1, 2, 3, 10, 254, 255, 256, 257, 258, 511, 512, 513, 1000, 3000, 2999, 255, 0, 4]
    times = [0.0, 1e-13, 1e-10, 1e-6]
    for k in ks:
        times += [
            k * period,
            k * period - 0.5 * period,
            k * period + 1e-12,
            k * period - 1e-12,
            k * period + 0.25 * period,
            (k - 1) * period + period,
        ]
    rng = np.random.default_rng(seed)
    times += list(rng.uniform(0.0, 600 * period, 150))
    times += list(np.arange(0.0, 300 * period, 0.37 * period))  # ascending through a block boundary
    times += [k * period for k in range(250, 262)] + [k * period for k in range(9 * BLOCK, 9 * BLOCK + 4)]
    times += [k * period for k in range(BLOCK * 12, BLOCK * 12 + 3)] + [0.5 * period, 0.0]  # back to block 0
    return [t for t in times if t >= 0.0]


def random_unit_quaternion(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def seed_uniform(seed: int) -> np.ndarray:
    return np.random.default_rng(1000 + seed).uniform(size=4)


# ----------------------------------------------------------------------------------
# Star tracker
# ----------------------------------------------------------------------------------
def make_tracker(mode="quaternion", period=0.1, **noise):
    kwargs = {
        "sigma_cross_boresight_rad": 2e-4,
        "sigma_boresight_rad": 1e-3,
        "dropout_probability": 0.2,
        "outage_windows_s": ((3.0, 7.5), (25.55, 25.65)),
    }
    if mode == "vectors":
        kwargs = {
            "sigma_vector_rad": 3e-4,
            "dropout_probability": 0.2,
            "outage_windows_s": ((3.0, 7.5),),
            "references_I": [[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [-0.3, 0.2, 0.9]],
        }
    kwargs.update(noise)
    return StarTracker("st_eq", period, q_BS=(0.8, -0.3, 0.4, 0.2), mode=mode, **kwargs)


def initialized_context(system, seed: int):
    context = system.CreateDefaultContext()
    system.GetInputPort("seed_uniform").FixValue(context, seed_uniform(seed))
    system.ExecuteInitializationEvents(context)
    return context


def check_tracker_quaternion(st, context, oracle, times, rng):
    port, q_port = st.GetOutputPort("star_tracker_measurement"), st.GetInputPort("q_IB")
    valid_seen, signs_seen = set(), set()
    for t in times:
        q_IB = random_unit_quaternion(rng)
        q_port.FixValue(context, q_IB)
        context.SetTime(t)
        got = port.Eval(context)
        expected = oracle.quaternion(context)
        np.testing.assert_array_equal(got, expected, err_msg=f"t = {t!r}")
        valid_seen.add(got[1])
        signs_seen.add(np.sign(rot.quat_multiply(q_IB, st.q_BS)[0]))
    # The cases were exercised: valid and invalid samples, both signs before canonicalization.
    assert valid_seen == {0.0, 1.0} and signs_seen == {-1.0, 1.0}


@pytest.mark.parametrize("seed", [0, 1, 7])
@pytest.mark.parametrize("period", [0.1, 1.0 / 3.0, 0.25])
def test_star_tracker_quaternion_output_equals_earlier_implementation(seed, period):
    st = make_tracker(period=period)
    context = initialized_context(st, seed)
    check_tracker_quaternion(st, context, OldStarTracker(st), sample_times(period, seed), np.random.default_rng(seed))


def test_star_tracker_quaternion_noiseless_and_identity_mounting():
    """Zero noise (the exact-zero rotation vector branch), no drop-outs, identity mount."""
    st = StarTracker("st_zero", 0.1)
    context = initialized_context(st, 3)
    oracle, rng = OldStarTracker(st), np.random.default_rng(3)
    for t in sample_times(0.1, 3):
        st.GetInputPort("q_IB").FixValue(context, random_unit_quaternion(rng))
        context.SetTime(t)
        np.testing.assert_array_equal(st.get_output_port().Eval(context), oracle.quaternion(context))


def test_star_tracker_follows_parameter_and_seed_changes_in_one_context():
    """The per-context cache of the samples is recomputed when the noise parameter or the
    seed words change (set_noise; a new seed and re-initialization)."""
    st = make_tracker()
    context = initialized_context(st, 0)
    oracle, rng, times = OldStarTracker(st), np.random.default_rng(5), sample_times(0.1, 5)[:80]
    check_tracker_quaternion(st, context, oracle, times, rng)
    before = st.get_output_port().Eval(context).copy()
    st.set_noise(
        context,
        sigma_cross_boresight_rad=5e-3,
        sigma_boresight_rad=1e-4,
        dropout_probability=0.5,
        outage_windows_s=((0.05, 1.0),),
    )
    after = st.get_output_port().Eval(context).copy()
    assert not np.array_equal(before, after)
    check_tracker_quaternion(st, context, oracle, times, rng)
    st.GetInputPort("seed_uniform").FixValue(context, seed_uniform(9))
    st.ExecuteInitializationEvents(context)
    check_tracker_quaternion(st, context, oracle, times, rng)


def test_star_tracker_two_contexts_interleaved_and_a_clone():
    st = make_tracker()
    a, b = initialized_context(st, 1), initialized_context(st, 2)
    st.set_noise(b, sigma_cross_boresight_rad=1e-3, sigma_boresight_rad=1e-3, dropout_probability=0.1)
    oracle, rng = OldStarTracker(st), np.random.default_rng(11)
    port = st.get_output_port()
    for t in sample_times(0.1, 11):
        for context in (a, b):
            st.GetInputPort("q_IB").FixValue(context, random_unit_quaternion(rng))
            context.SetTime(t)
            np.testing.assert_array_equal(port.Eval(context), oracle.quaternion(context))
    clone = b.Clone()
    for t in sample_times(0.1, 12)[:60]:
        for context in (clone, b):
            context.SetTime(t)
            np.testing.assert_array_equal(port.Eval(context), oracle.quaternion(context))


def check_vectors(st, context, oracle, times, rng, noise_port_values=None):
    port, q_port = st.GetOutputPort("vector_observations"), st.GetInputPort("q_IB")
    valid_seen = set()
    for i, t in enumerate(times):
        q_port.FixValue(context, random_unit_quaternion(rng))
        if noise_port_values is not None:
            st.GetInputPort("vector_noise").FixValue(context, noise_port_values(i))
        context.SetTime(t)
        got = port.Eval(context)
        t_sample, valid, dirs, sigma = oracle.vectors(context)
        assert (got.time_s, got.valid, got.sigma_rad) == (t_sample, valid, sigma), f"t = {t!r}"
        assert type(got.time_s) is float and type(got.valid) is bool
        np.testing.assert_array_equal(got.directions_S, dirs, err_msg=f"t = {t!r}")
        np.testing.assert_array_equal(got.references_I, st.references_I)
        np.testing.assert_array_equal(got.q_BS, st.q_BS)
        valid_seen.add(got.valid)
    assert valid_seen == {False, True}


@pytest.mark.parametrize("seed", [0, 4])
def test_star_tracker_vector_output_equals_earlier_implementation(seed):
    st = make_tracker("vectors")
    context = initialized_context(st, seed)
    check_vectors(st, context, OldStarTracker(st), sample_times(0.1, seed), np.random.default_rng(seed))


def test_star_tracker_vector_output_with_the_noise_input_connected():
    st = make_tracker("vectors")
    context = initialized_context(st, 2)
    noise_rng = np.random.default_rng(21)
    noises = noise_rng.normal(scale=1e-3, size=(2000, 9))
    check_vectors(
        st,
        context,
        OldStarTracker(st),
        sample_times(0.1, 2),
        np.random.default_rng(2),
        noise_port_values=lambda i: noises[i],
    )


# ----------------------------------------------------------------------------------
# Gyro
# ----------------------------------------------------------------------------------
GYRO_MODELS = {
    "plain": {"arw_rad_per_rt_s": 3e-5, "rrw_rad_per_s15": 2e-7, "initial_bias_rad_per_s": (1e-4, -2e-4, 5e-5)},
    "errors": {
        "arw_rad_per_rt_s": 3e-5,
        "rrw_rad_per_s15": 2e-7,
        "initial_bias_rad_per_s": (1e-4, -2e-4, 5e-5),
        "initial_bias_sigma_rad_per_s": 1e-4,
        "scale_factor_error": (1e-4, -3e-4, 2e-4),
        "misalignment": [[0.0, 1e-3, -2e-3], [5e-4, 0.0, 1e-3], [-1e-3, 2e-3, 0.0]],
    },
    "scale_only": {"arw_rad_per_rt_s": 1e-5, "rrw_rad_per_s15": 0.0, "scale_factor_error": (1e-3, 0.0, 0.0)},
    "noiseless": {"arw_rad_per_rt_s": 0.0, "rrw_rad_per_s15": 0.0},
}


def make_gyro_outputs(period, model_name, seed):
    model = GyroModel.make("gyro_eq", period, **GYRO_MODELS[model_name])
    outputs = _GyroOutputs("gyro_eq", period, model)
    return outputs, initialized_context(outputs, seed)


def check_gyro(outputs, context, oracle, times, rng, integral=True, scale_error=False):
    both = outputs.GetOutputPort("measurement_and_bias")  # gyro_measurement (5), then bias_B (3)
    integral_seen = False
    for t in times:
        w = rng.normal(scale=0.1, size=3)
        outputs.GetInputPort("w_IB_B").FixValue(context, w)
        if integral:
            held = rng.normal(size=3)
            outputs.GetInputPort("w_IB_B_integral_held").FixValue(context, held)
            outputs.GetInputPort("w_IB_B_integral").FixValue(context, held + rng.normal(scale=0.01, size=3))
        if scale_error:
            outputs.GetInputPort("scale_error").FixValue(context, rng.normal(scale=1e-3, size=1))
        context.SetTime(t)
        value = both.Eval(context)
        got = value[:5]
        np.testing.assert_array_equal(got, oracle.measurement(context), err_msg=f"t = {t!r}")
        np.testing.assert_array_equal(value[5:], oracle.bias(context), err_msg=f"t = {t!r}")
        # Whether the interval mean of the integral was used (else the rate input).
        n = max(0, math.ceil(t / outputs.period_s - 1e-9))
        integral_seen |= integral and n >= 1 and t - (got[0] - outputs.period_s) > 1e-12
    assert integral_seen == integral


@pytest.mark.parametrize("model_name", sorted(GYRO_MODELS))
@pytest.mark.parametrize("seed", [0, 3])
def test_gyro_outputs_equal_earlier_implementation(model_name, seed):
    outputs, context = make_gyro_outputs(0.1, model_name, seed)
    check_gyro(outputs, context, OldGyroOutputs(outputs), sample_times(0.1, seed), np.random.default_rng(seed))


@pytest.mark.parametrize("model_name", ["plain", "errors"])
def test_gyro_outputs_with_scale_error_connected(model_name):
    outputs, context = make_gyro_outputs(0.25, model_name, 5)
    check_gyro(
        outputs, context, OldGyroOutputs(outputs), sample_times(0.25, 5), np.random.default_rng(5), scale_error=True
    )


@pytest.mark.parametrize("model_name", ["plain", "errors"])
def test_gyro_outputs_with_the_integral_unconnected(model_name):
    """Without ``w_IB_B_integral`` the output uses the rate input at every sample."""
    outputs, context = make_gyro_outputs(1.0 / 3.0, model_name, 6)
    check_gyro(
        outputs, context, OldGyroOutputs(outputs), sample_times(1.0 / 3.0, 6), np.random.default_rng(6), integral=False
    )


def test_gyro_negative_zero_rate_with_identity_sensor_matrix():
    """An identity sensor matrix is not multiplied by (``I @ [-0.0, ..]`` gave ``+0.0``,
    an equal number); the outputs stay equal."""
    outputs, context = make_gyro_outputs(0.1, "noiseless", 0)
    outputs.GetInputPort("w_IB_B").FixValue(context, np.array([-0.0, 0.0, -0.0]))
    got = outputs.GetOutputPort("measurement_and_bias").Eval(context)[:5]
    np.testing.assert_array_equal(got, OldGyroOutputs(outputs).measurement(context))
    np.testing.assert_array_equal(got[2:], 0.0)
    assert outputs._draws(context).unit_sensor_matrix
    scaled, scaled_context = make_gyro_outputs(0.1, "scale_only", 0)
    assert not scaled._draws(scaled_context).unit_sensor_matrix


@pytest.mark.parametrize("model_name", ["plain", "errors"])
def test_gyro_outputs_with_a_period_below_the_elapsed_time_guard(model_name):
    """With ``T = 1e-4`` an output within 1e-12 s after an instant already carries the next
    sample (``k = ceil(t / T - 1e-9)``) and uses the rate input (elapsed <= 1e-12 s)."""
    period = 1e-4
    outputs, context = make_gyro_outputs(period, model_name, 2)
    times = [k * period + d for k in (1, 2, 255, 256, 300) for d in (0.0, 5e-13, 2e-12, 0.5 * period)]
    check_gyro(outputs, context, OldGyroOutputs(outputs), times, np.random.default_rng(2))
    # The rate-input branch was taken: its output does not depend on the integral inputs.
    context.SetTime(256 * period + 5e-13)
    first = outputs.GetOutputPort("measurement_and_bias").Eval(context).copy()
    outputs.GetInputPort("w_IB_B_integral").FixValue(context, np.array([9.0, 9.0, 9.0]))
    np.testing.assert_array_equal(outputs.GetOutputPort("measurement_and_bias").Eval(context), first)


def test_gyro_follows_model_and_seed_changes_and_contexts():
    """Through the :class:`Gyro` diagram (its ``ZeroOrderHold`` gives the held integral):
    set_model and a new seed in one context, a second context and a clone."""
    gyro = Gyro("gyro_eq", 0.1, **GYRO_MODELS["plain"])
    outputs = gyro._outputs
    oracle = OldGyroOutputs(outputs)
    rng = np.random.default_rng(8)

    def context_for(seed):
        context = gyro.CreateDefaultContext()
        gyro.GetInputPort("seed_uniform").FixValue(context, seed_uniform(seed))
        gyro.GetInputPort("w_IB_B_integral").FixValue(context, np.array([0.3, -0.2, 0.1]))
        gyro.ExecuteInitializationEvents(context)
        return context

    def check(context, times):
        sub = gyro.GetSubsystemContext(outputs, context)
        for t in times:
            gyro.GetInputPort("w_IB_B").FixValue(context, rng.normal(size=3))
            gyro.GetInputPort("w_IB_B_integral").FixValue(context, rng.normal(size=3))
            context.SetTime(t)
            np.testing.assert_array_equal(
                gyro.GetOutputPort("gyro_measurement").Eval(context), oracle.measurement(sub), err_msg=f"t = {t!r}"
            )
            np.testing.assert_array_equal(gyro.GetOutputPort("bias_B").Eval(context), oracle.bias(sub))

    a = context_for(1)
    times = sample_times(0.1, 8)[:120]
    check(a, times)
    before = gyro.GetOutputPort("gyro_measurement").Eval(a).copy()
    gyro.set_model(a, **GYRO_MODELS["errors"])
    assert not np.array_equal(before, gyro.GetOutputPort("gyro_measurement").Eval(a))
    check(a, times)
    gyro.GetInputPort("seed_uniform").FixValue(a, seed_uniform(4))
    gyro.ExecuteInitializationEvents(a)
    check(a, times)
    b = context_for(2)
    for t in times[:40]:
        check(b, [t])
        check(a, [t])
    check(b.Clone(), times)
