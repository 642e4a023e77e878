"""Unit tests of drake_att.noise called directly (no Drake): counter-based random streams,
the Farrenkopf interval map and the overlapping Allan deviation.

The statistical behaviour of the gyro model (interval moments vs a brute-force 300 Hz
model, Allan-deviation recovery of ARW/RRW, the Drake sensors) is in test_sensors.py.
This file checks what those tests reach only through the sensors' cached streams
(``drake_att.systems.randomness`` caches one ``CounterRandom`` per (seed, stream), so a
process that already built a stream never calls ``stream_key`` again) and what their
fixed choices (dt = 1 s, 1e6 samples) cannot see: dt != 1, short series, the validity
boundary of tau, float32 input, degenerate noise parameters.

Statistics over n iid draws are checked within 4 standard errors (mean: 1/sqrt(n) for
unit variance; variance: sqrt(2/n); correlation: 1/sqrt(n)): a false alarm has probability
~6e-5 per check, and the seeds/keys are fixed, so each run gives the same verdict.
"""

import math

import numpy as np
import pytest

from drake_att.noise import CounterRandom, FarrenkopfGyroNoise, overlapping_allan_deviation, stream_key

# Two uint64 words, one >= 2^63 and one below: as Python ints, numpy would make such a pair
# float64 (losing the low bits) unless told uint64.
KEY_WORDS = [2**64 - 12345, 2**40 + 678]


# ----------------------------------------------------------------------------------------
# stream_key / CounterRandom
# ----------------------------------------------------------------------------------------
def test_stream_key_is_a_128_bit_function_of_seed_words_and_stream_name():
    """Same (seed words, name) -> same key; a different seed word or name -> a different
    key; the two words use all 64 bits (a 32-bit key would leave the high halves zero:
    the chance that 64 random 64-bit words are all < 2^32 is 2^-2048)."""
    names = ["gyro", "star_tracker_1", "star_tracker_2", "mekf"]
    keys = {}
    for seed in range(8):
        for name in names:
            k = stream_key([seed, 7, 8, 9], name)
            assert k.shape == (2,) and k.dtype == np.uint64
            np.testing.assert_array_equal(k, stream_key([seed, 7, 8, 9], name))
            keys[(seed, name)] = tuple(int(w) for w in k)
    assert len(set(keys.values())) == len(keys)  # 32 distinct streams
    words = np.array(list(keys.values()), dtype=np.uint64).ravel()
    assert np.all(words >= np.uint64(2**32))
    # Seed words arrive as floats (the sensors keep them in their discrete state).
    np.testing.assert_array_equal(stream_key(np.array([3.0, 7.0, 8.0, 9.0]), "gyro"), stream_key([3, 7, 8, 9], "gyro"))


def test_counter_draws_depend_only_on_key_and_index():
    """Draws are a pure function of (key, kind, width, index): two instances queried in
    different orders (crossing block boundaries and the block-cache eviction after 9
    blocks) give bit-identical rows; a key given as Python ints (as read back from a log or
    JSON; words >= 2^63 must not go through float64) gives the same draws as the uint64
    array."""
    a = CounterRandom(np.array(KEY_WORDS, dtype=np.uint64))
    b = CounterRandom(list(KEY_WORDS))
    idx = [0, 1, 255, 256, 257, 1000, 5000, 70000, 3 * 256 + 5]
    first = {i: (a.normals(i, 3).copy(), a.uniforms(i, 2).copy()) for i in idx}
    for i in reversed(idx):  # other order; widths interleaved to churn the block cache
        b.normals(i, 9)
        np.testing.assert_array_equal(b.uniforms(i, 2), first[i][1])
        np.testing.assert_array_equal(b.normals(i, 3), first[i][0])
    for i in idx:  # and again on the first instance after its cache was churned
        np.testing.assert_array_equal(a.normals(i, 3), first[i][0])
    g1, g2 = a.generator(42).standard_normal(5), b.generator(42).standard_normal(5)
    np.testing.assert_array_equal(g1, g2)
    # A different key is a different stream.
    c = CounterRandom(np.array([KEY_WORDS[0], KEY_WORDS[1] - 1], dtype=np.uint64))
    assert not np.any(c.normals(5, 3) == a.normals(5, 3))
    assert not np.any(c.generator(42).standard_normal(5) == g1)


def test_counter_draws_are_iid_with_the_documented_distributions():
    """4096 samples x width 3: normals have mean 0 and variance 1, uniforms lie in [0, 1)
    with mean 1/2 and variance 1/12 (SE of a sample variance: sqrt((mu4 - var^2)/n), with the
    uniform's fourth central moment mu4 = 1/80); consecutive samples and columns are
    uncorrelated; normals and uniforms of the same sample are uncorrelated (separate
    streams).  Bounds: 4 SE, see the module docstring."""
    cr = CounterRandom(np.array(KEY_WORDS, dtype=np.uint64))
    n = 4096
    z = np.array([cr.normals(i, 3) for i in range(n)])
    u = np.array([cr.uniforms(i, 3) for i in range(n)])
    se = 1.0 / math.sqrt(n)
    assert np.all(np.abs(z.mean(axis=0)) < 4 * se)
    assert np.all(np.abs(z.var(axis=0) - 1.0) < 4 * math.sqrt(2.0 / n))
    assert np.all((u >= 0.0) & (u < 1.0))
    assert np.all(np.abs(u.mean(axis=0) - 0.5) < 4 * math.sqrt(1.0 / 12.0 / n))
    se_var_u = math.sqrt((1.0 / 80.0 - (1.0 / 12.0) ** 2) / n)
    assert np.all(np.abs(u.var(axis=0) - 1.0 / 12.0) < 4 * se_var_u)
    for x in (z, (u - 0.5) * math.sqrt(12.0)):
        c = np.corrcoef(np.hstack([x[:-1], x[1:]]).T)
        off = c[~np.eye(6, dtype=bool)]
        assert np.all(np.abs(off) < 4 * se)
    assert np.all(np.abs(np.corrcoef(z.T, u.T)[:3, 3:]) < 4 * se)


def test_generator_per_sample_streams_are_reproducible_and_independent():
    """``generator(i)`` (the particle filters' per-step generator): a fresh instance with the
    same key reproduces it; the first normal of generator(i) over 2000 indices is iid
    N(0, 1) (mean, variance, lag-1 correlation within 4 SE), so each index is its own
    stream; and it is not a re-use of the normals()/uniforms() blocks."""
    key = np.array(KEY_WORDS, dtype=np.uint64)
    cr, again = CounterRandom(key), CounterRandom(key)
    n = 2000
    x = np.array([cr.generator(i).standard_normal() for i in range(n)])
    np.testing.assert_array_equal(x[:50], [again.generator(i).standard_normal() for i in range(50)])
    assert len(np.unique(x)) == n
    assert abs(x.mean()) < 4 / math.sqrt(n)
    assert abs(x.var() - 1.0) < 4 * math.sqrt(2.0 / n)
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1]) < 4 / math.sqrt(n)
    # Disjoint from the per-sample blocks: no generator draw equals any block draw.
    block = np.concatenate([cr.normals(i, 1) for i in range(n)])
    assert not np.any(np.isin(x, block))
    many = cr.generator(7).standard_normal(1000)  # one generator gives many fresh numbers
    assert len(np.unique(many)) == 1000


def test_counter_streams_are_the_recorded_ones():
    """Known answers, recorded at commit 1e812f0: every seeded result (the shipped metrics
    that test_regression.py keeps across the redesign, stored logs) is a function of these
    streams, so a refactoring must reproduce them bit for bit: the Philox key of a
    (seed words, stream name) pair, the sample rows of normals/uniforms, and the
    per-sample generator.  (Philox and numpy's uniform/normal transforms are
    platform-independent.)"""
    key = stream_key([11, 22, 33, 44], "star_tracker_1")
    assert [int(w) for w in key] == [5315835376973959908, 3259614782597255119]
    cr = CounterRandom(key)
    assert cr.normals(300, 3).tolist() == [-0.5101681277643437, -0.37735588393397035, -0.9502623279153176]
    assert cr.uniforms(300, 2).tolist() == [0.918877947281174, 0.026269931234540245]
    assert cr.generator(5).bit_generator.random_raw(2).tolist() == [7828017827934065287, 9250446304528704028]
    assert cr.generator(5).standard_normal(2).tolist() == [0.6251060384931103, 0.00918914624369117]


# ----------------------------------------------------------------------------------------
# FarrenkopfGyroNoise: the map from standard normals, the vectorized static gyro
# ----------------------------------------------------------------------------------------
def interval_moments(arw, rrw, T):
    """(var e, cov(e, db), var db) of the continuous Farrenkopf model over an interval T:
    e = (1/T) int_0^T (b(t) - b(0) + n_v) dt, db = b(T) - b(0), b a Wiener process of
    intensity rrw^2: var(e) = arw^2/T + rrw^2 T/3, cov = rrw^2 T/2, var(db) = rrw^2 T."""
    return arw**2 / T + rrw**2 * T / 3.0, rrw**2 * T / 2.0, rrw**2 * T


@pytest.mark.parametrize(
    "arw, rrw, T",
    [
        (1.63e-4, 1.0e-5, 1.0),
        (1e-3, 2e-3, 1.0),
        (2e-4, 2e-3, 0.5),
        (0.0, 3e-4, 0.2),
    ],
)
def test_from_normals_is_the_lower_cholesky_factor_of_the_derived_covariance(arw, rrw, T):
    """(e, db) = L z with L the (unique, positive-diagonal) lower Cholesky factor of the
    interval covariance derived above: so (e, db) has exactly that covariance for z ~ N(0, I),
    and a sensor's seeded output is a fixed function of its counter normals.  Exact to
    rounding (rtol 1e-12), per axis, on asymmetric z of shape (2, 4)."""
    var_e, cov_ed, var_d = interval_moments(arw, rrw, T)
    L = np.linalg.cholesky(np.array([[var_e, cov_ed], [cov_ed, var_d]]))
    z = np.array([[0.3, -1.7, 2.2, 0.05], [1.1, 0.4, -0.9, -2.5]])
    e, db = FarrenkopfGyroNoise(arw, rrw, T).from_normals(z)
    expected = L @ z
    np.testing.assert_allclose(e, expected[0], rtol=1e-12, atol=0)
    np.testing.assert_allclose(db, expected[1], rtol=1e-12, atol=0)


def test_from_normals_degenerate_models():
    """rrw = 0: the bias never moves (db = 0 exactly) and e = arw/sqrt(T) z0; arw = rrw = 0
    (a noise-free gyro): e = db = 0 exactly, no 0/0 NaN."""
    z = np.array([[0.3, -1.7, 2.2], [1.1, 0.4, -0.9]])
    e, db = FarrenkopfGyroNoise(2e-4, 0.0, 0.25).from_normals(z)
    np.testing.assert_allclose(e, 2e-4 / math.sqrt(0.25) * z[0], rtol=1e-15, atol=0)
    np.testing.assert_array_equal(db, 0.0)
    e, db = FarrenkopfGyroNoise(0.0, 0.0, 1.0).from_normals(z)
    np.testing.assert_array_equal(e, 0.0)
    np.testing.assert_array_equal(db, 0.0)


def test_simulate_static_is_the_interval_recursion_from_zero_bias():
    """simulate_static(n, rng) is the vectorized form of n successive intervals: output_k =
    b_k + e_k, b_{k+1} = b_k + db_k with (e_k, db_k) = draw(rng), starting from the default
    bias0 = 0 (a static gyro with no initial bias).  Written here as a loop over draw() on
    an identically seeded generator: equal to rounding (the bias is a cumulative sum)."""
    gyro = FarrenkopfGyroNoise(1e-3, 2e-3, 0.5)
    n = 40
    out = gyro.simulate_static(n, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    b = np.zeros(3)
    expected = []
    for _ in range(n):
        e, db = gyro.draw(rng)
        expected.append(b + e)
        b = b + db
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-15)
    bias0 = np.array([1e-4, -2e-4, 3e-4])
    np.testing.assert_allclose(
        gyro.simulate_static(n, np.random.default_rng(5), bias0=bias0), np.array(expected) + bias0, rtol=0, atol=1e-15
    )


# ----------------------------------------------------------------------------------------
# overlapping_allan_deviation
# ----------------------------------------------------------------------------------------
def reference_adev(y, m):
    """IEEE Std 952 overlapping Allan deviation from its definition: the cluster averages
    ybar_k = mean(y[k : k+m]) (k = 0 .. n-m), avar = sum_{k=0}^{n-2m} (ybar_{k+m} - ybar_k)^2
    / (2 (n - 2m + 1)).  Written with explicit windows (no cumulative sums); float64."""
    y = np.asarray(y, dtype=np.float64)
    ybar = np.lib.stride_tricks.sliding_window_view(y, m, axis=0).mean(axis=-1)
    diff = ybar[m:] - ybar[:-m]
    return np.sqrt(np.sum(diff**2, axis=0) / (2.0 * (len(y) - 2 * m + 1)))


def test_allan_deviation_matches_the_cluster_average_definition():
    """Short two-column series (n = 41), dt = 0.01 s (the Allan deviation of a rate does not
    depend on dt once tau is given in samples), every m from 1 to the largest allowed
    (2m < n: m = 20): equal to the definition to rounding (rtol 1e-12)."""
    rng = np.random.default_rng(11)
    n, dt = 41, 0.01
    y = np.column_stack([rng.standard_normal(n), 3.0 + np.cumsum(rng.standard_normal(n))])
    ms = np.arange(1, 21)
    adev = overlapping_allan_deviation(y, dt, ms * dt)
    assert adev.shape == (20, 2)
    np.testing.assert_allclose(adev, [reference_adev(y, m) for m in ms], rtol=1e-12, atol=0)
    # A 1-D series is one column.
    np.testing.assert_allclose(
        overlapping_allan_deviation(y[:, 1], dt, [0.05]), [reference_adev(y[:, 1:], 5)], rtol=1e-12, atol=0
    )


def test_allan_deviation_rejects_taus_outside_the_series():
    """tau must be at least one sample (m >= 1) and leave two full clusters (2m < n)."""
    y = np.random.default_rng(1).standard_normal(41)
    overlapping_allan_deviation(y, 0.5, [10.0])  # m = 20: 2m = 40 < 41, valid
    for tau in (10.5, 0.2):  # m = 21 (2m = 42 >= 41); m = 0
        with pytest.raises(ValueError, match="taus_s"):
            overlapping_allan_deviation(y, 0.5, [tau])


def test_allan_deviation_of_float32_data_is_computed_in_double():
    """A float32 rate log (e.g. a gyro on a rate table: mean 100x the noise) is analysed in
    double precision: the result equals the definition evaluated in float64 on the same
    float32 values to 1e-7 relative (float64 rounding of the running angle, ~2e6 x 1e-16,
    is ~1e-9 of the noise).  Cumulating in float32 instead is off by ~2e-4 here."""
    y32 = (100.0 + np.random.default_rng(3).standard_normal(20000)).astype(np.float32)
    ms = [1, 10, 100]
    adev = overlapping_allan_deviation(y32, 1.0, ms)
    np.testing.assert_allclose(adev[:, 0], [reference_adev(y32[:, None], m)[0] for m in ms], rtol=1e-7, atol=0)
