"""Noise models and reproducible, counter-based random numbers (no Drake).

* :class:`CounterRandom` - random numbers as a pure function of (key, sample index):
  the key comes from the diagram's ``RandomGenerator`` (via a random input port, see
  ``drake_att.systems.randomness``), the index is the sample's number computed from its
  time (``n = ceil(t / T)`` for a sensor of period ``T``).  Re-running with the same seed reproduces every draw; a sensor
  never depends on how often its outputs were evaluated.
* :class:`FarrenkopfGyroNoise` - the Farrenkopf gyro model (angle random walk
  ``sigma_v`` in rad/s^0.5, rate random walk ``sigma_u`` in rad/s^1.5) delivered as the
  **mean rate over an output interval** ``T``.  The exact joint statistics of the
  interval-mean noise and the end-of-interval bias are closed-form, so one draw per
  output replaces e.g. 300 draws of a 300 Hz gyro (see ``interval_covariance``).
"""

from __future__ import annotations

import zlib

import numpy as np

# Unit conversions used at config edges: their home is drake_att.units (re-exported here).
from drake_att.units import ARCSEC, ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15  # noqa: F401
from drake_att.validation import check_nonnegative, check_positive


def stream_key(seed_words, stream_name: str) -> np.ndarray:
    """128-bit Philox key derived from seed words and a stream (sensor) name."""
    words = [int(w) & 0xFFFFFFFF for w in np.atleast_1d(seed_words)]
    words.append(zlib.crc32(stream_name.encode("utf-8")))
    return np.random.SeedSequence(words).generate_state(2, np.uint64)


class CounterRandom:
    """Counter-based random numbers: every draw depends only on (key, sample index).

    ``normals(index, width)`` / ``uniforms(index, width)`` return the sample's row of a
    block of :attr:`BLOCK` samples generated at once (Philox counter = block number), so
    a per-sample draw costs well under a microsecond instead of building a generator.
    ``generator(index)`` gives a whole ``numpy.random.Generator`` for one sample (used by
    particle filters, which draw many numbers per step).

    Args:
        key: two uint64 words (see :func:`stream_key`).
    """

    BLOCK = 256

    def __init__(self, key):
        self._key = np.asarray(key, dtype=np.uint64)
        self._blocks: dict = {}

    def generator(self, index: int) -> np.random.Generator:
        """A fresh ``numpy.random.Generator`` for sample ``index`` (>= 0)."""
        counter = np.array([0, int(index), 0, 0], dtype=np.uint64)
        return np.random.Generator(np.random.Philox(key=self._key, counter=counter))

    def _block(self, kind: int, width: int, block: int) -> np.ndarray:
        k = (kind, width, block)
        arr = self._blocks.get(k)
        if arr is None:
            counter = np.array([0, block, width, 1 + kind], dtype=np.uint64)
            g = np.random.Generator(np.random.Philox(key=self._key, counter=counter))
            arr = g.standard_normal((self.BLOCK, width)) if kind == 0 else g.random((self.BLOCK, width))
            if len(self._blocks) > 8:
                self._blocks.clear()
            self._blocks[k] = arr
        return arr

    def normals_block(self, block: int, width: int) -> np.ndarray:
        """The ``(BLOCK, width)`` standard normals of samples ``block * BLOCK ...`` (row ``r`` is
        ``normals(block * BLOCK + r, width)``; read-only)."""
        return self._block(0, width, int(block))

    def uniforms_block(self, block: int, width: int) -> np.ndarray:
        """The ``(BLOCK, width)`` uniforms of samples ``block * BLOCK ...`` (read-only)."""
        return self._block(1, width, int(block))

    def normals(self, index: int, width: int) -> np.ndarray:
        """``width`` standard normals for sample ``index`` (>= 0)."""
        b, r = divmod(int(index), self.BLOCK)
        return self._block(0, width, b)[r]

    def uniforms(self, index: int, width: int) -> np.ndarray:
        """``width`` uniforms in [0, 1) for sample ``index`` (>= 0)."""
        b, r = divmod(int(index), self.BLOCK)
        return self._block(1, width, b)[r]


def seed_words_from_uniform(u) -> list[int]:
    """Integer seed words from uniform [0, 1) samples (one 32-bit word per sample)."""
    return [int(np.floor(float(x) * 4294967296.0)) & 0xFFFFFFFF for x in np.atleast_1d(u)]


class FarrenkopfGyroNoise:
    """Exact interval statistics of the Farrenkopf gyro model.

    Continuous model per axis: ``w_meas = w + b + n_v``, ``b_dot = n_u`` with white
    ``n_v`` (PSD ``sigma_v^2``) and ``n_u`` (PSD ``sigma_u^2``).  A gyro that samples at a
    high rate and delivers the **mean of its samples over an interval T** (equivalently,
    delta-angle / T) outputs ``mean(w) + b_k + e_k`` where, given the bias ``b_k`` at the
    start of the interval, the pair ``(e_k, b_{k+1} - b_k)`` is zero-mean Gaussian with

    ``var(e) = sigma_v^2 / T + sigma_u^2 T / 3``, ``cov(e, db) = sigma_u^2 T / 2``,
    ``var(db) = sigma_u^2 T``.

    This equals the mean of the paper-S3 discrete model sampled at any rate
    (``W_om ~ N(0, N^2/Ts + K^2 Ts/12)``, bias averaged over each sample), because that
    discrete model is the exact discretization of the continuous one.

    Args:
        arw: angle random walk ``sigma_v`` (rad/s^0.5), >= 0.
        rrw: rate random walk ``sigma_u`` (rad/s^1.5), >= 0.
        interval_s: output interval T (s), > 0.
    """

    def __init__(self, arw: float, rrw: float, interval_s: float):
        self.arw = check_nonnegative("arw", arw)  # rad/s^0.5
        self.rrw = check_nonnegative("rrw", rrw)  # rad/s^1.5
        check_positive("interval_s", interval_s)  # s
        self.interval_s = float(interval_s)
        cov = self.interval_covariance()
        # Cholesky of the 2x2 (e, db) covariance; handle rrw == 0 (singular).
        var_e, cov_ed, var_d = cov[0, 0], cov[0, 1], cov[1, 1]
        l11 = np.sqrt(var_e)
        l21 = cov_ed / l11 if l11 > 0 else 0.0
        l22 = np.sqrt(max(var_d - l21 * l21, 0.0))
        self._chol = np.array([[l11, 0.0], [l21, l22]])

    def interval_covariance(self) -> np.ndarray:
        """2x2 covariance of (mean-rate noise e, bias increment db) per axis."""
        T = self.interval_s
        su2 = self.rrw**2
        return np.array([[self.arw**2 / T + su2 * T / 3.0, su2 * T / 2.0], [su2 * T / 2.0, su2 * T]])

    def draw(self, rng: np.random.Generator, shape=(3,)) -> tuple[np.ndarray, np.ndarray]:
        """One interval: returns ``(e, db)``, each of ``shape`` (independent axes)."""
        return self.from_normals(rng.standard_normal((2,) + tuple(shape)))

    def from_normals(self, z) -> tuple[np.ndarray, np.ndarray]:
        """``(e, db)`` from standard normals ``z`` of shape ``(2, ...)``."""
        z = np.asarray(z)
        e = self._chol[0, 0] * z[0]
        db = self._chol[1, 0] * z[0] + self._chol[1, 1] * z[1]
        return e, db

    def simulate_static(self, n: int, rng: np.random.Generator, bias0=0.0) -> np.ndarray:
        """``n`` consecutive mean-rate outputs of a static gyro, shape ``(n, 3)``.

        Vectorized: used by Allan-variance analyses and tests.
        """
        z = rng.standard_normal((n, 2, 3))
        e = self._chol[0, 0] * z[:, 0]
        db = self._chol[1, 0] * z[:, 0] + self._chol[1, 1] * z[:, 1]
        bias = np.asarray(bias0, dtype=float) + np.vstack([np.zeros((1, 3)), np.cumsum(db, axis=0)[:-1]])
        return bias + e


def overlapping_allan_deviation(rate: np.ndarray, dt: float, taus_s) -> np.ndarray:
    """Overlapping Allan deviation of a rate series (IEEE Std 952), per column.

    Args:
        rate: ``(n,)`` or ``(n, k)`` rate samples (each the mean over ``dt``).
        dt: sample interval (s).
        taus_s: averaging times (s), multiples of ``dt``.

    Returns:
        ``(len(taus), k)`` Allan deviations (same units as ``rate``).
    """
    rate = np.asarray(rate, dtype=float)
    if rate.ndim == 1:
        rate = rate[:, None]
    theta = np.vstack([np.zeros((1, rate.shape[1])), np.cumsum(rate, axis=0) * dt])
    n = rate.shape[0]
    out = []
    for tau in np.atleast_1d(taus_s):
        m = int(round(tau / dt))
        if m < 1 or 2 * m >= n:
            raise ValueError(f"taus_s: tau={tau} s needs 1 <= m and 2m < n={n} samples")
        d = theta[2 * m :] - 2.0 * theta[m:-m] + theta[: -2 * m]
        avar = np.sum(d * d, axis=0) / (2.0 * (m * dt) ** 2 * (n - 2 * m + 1))
        out.append(np.sqrt(avar))
    return np.array(out)
