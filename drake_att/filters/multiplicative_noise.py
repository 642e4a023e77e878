"""Paper S1's multiplicative noise ``zeta_k`` and its correlation with the star-sensor noise:
the one model the CQE-MCNS filter (:mod:`drake_att.filters.cubature`) assumes and the truth
simulation draws from.  Plain numpy (no Drake).

``zeta_k ~ N(0, Q_zeta)`` (dimensionless, white) is a per-step gyro scale-factor error: over
step ``k`` (``[t_k, t_k + dt]``) the gyro reads ``w_meas_k = w_true_mean_k / (1 + kappa zeta_k)
+ b_k + e_k`` (rad/s).  It is correlated with each component of the star noise ``v_k`` of a
sample at ``t_k``, ``Cov(zeta_k, v_k) = rho sqrt(Q_zeta) sigma_v 1_{3m}`` (the joint covariance
is positive definite iff ``3 m rho^2 < 1``); the patent's ``S = 0.05`` is read as ``rho = 0.158``.

* :class:`MultiplicativeNoiseModel`: ``(Q_zeta, rho, kappa)``; the joint covariance, ``(zeta, v)``
  from standard normals, Lemma 1's conditional moments ``(M, U)``, the patent's ``Phi``.
* :func:`reference_step`, :func:`simulate_reference` (:class:`ReferenceStep`,
  :class:`ReferenceRun`): the reference truth a Drake gyro / star tracker must reproduce bit
  for bit, from one row of ``7 + 3m`` standard normals per gyro step (:func:`normals_per_step`);
  :func:`star_directions`: the noise-free tracker directions.

Conventions: :mod:`drake_att.rotations` (``q_IB`` wxyz, Hamilton, ``v_I = R(q_IB) v_B``); the
tracker is mounted by ``q_BS`` (``R_SB = R(q_BS)'``): ``d_i = R_SB R(q_k)' r_i + v_i``.

Derivation and paper notes: docs/derivations/cubature_and_mcns.md
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att import rotations as rot
from drake_att.noise import FarrenkopfGyroNoise
from drake_att.validation import (
    check_array,
    check_finite,
    check_int,
    check_nonnegative,
    check_positive,
    fail,
)

# The seed's (patent's) numbers: variance of zeta and its "cross-covariance" with the star noise.
PAPER_ZETA_VARIANCE = 0.1
PAPER_CROSS_COVARIANCE = 0.05
# rho = S / sqrt(Q_zeta * 1): S read as Cov(zeta, v / sigma_v)
# (docs/derivations/cubature_and_mcns.md).
PAPER_CORRELATION = PAPER_CROSS_COVARIANCE / math.sqrt(PAPER_ZETA_VARIANCE)
# kappa: the patent gives no Phi. 1e-2 makes the zeta-driven attitude noise over one 10 s star
# interval (kappa sqrt(Q_zeta) n dt sqrt(10) ~ 2.3 arcsec at the orbit rate n) comparable to the
# 2 arcsec star noise: the regime where the multiplicative noise matters (tests/test_cubature.py).
DEFAULT_SCALE_PER_ZETA = 1e-2

GYRO_NORMALS = 6  # z_k[0:6]
ZETA_INDEX = 6  # z_k[6]
STAR_OFFSET = 7  # z_k[7:7+3m]


def normals_per_step(num_stars: int) -> int:
    """Length of the per-step row of standard normals ``z_k``: ``7 + 3 m``."""
    return STAR_OFFSET + 3 * check_int("num_stars", num_stars, 0)


@dataclass(frozen=True)
class MultiplicativeNoiseModel:
    """``zeta_k`` (a per-step gyro scale-factor error) and its correlation with the star noise.

    The equations: docs/derivations/cubature_and_mcns.md. Build with :meth:`make` (checked) or
    :meth:`paper` (the seed's numbers).

    Attributes:
        zeta_variance: ``Q_zeta`` (dimensionless) >= 0.
        correlation: ``rho``, the correlation of ``zeta_k`` with each component of the star
            noise ``v_k`` of the same step, in (-1, 1).
        scale_per_zeta: ``kappa`` >= 0, scale-factor error per unit ``zeta``.
    """

    zeta_variance: float
    correlation: float
    scale_per_zeta: float

    @classmethod
    def make(
        cls,
        zeta_variance: float = PAPER_ZETA_VARIANCE,
        correlation: float = PAPER_CORRELATION,
        scale_per_zeta: float = DEFAULT_SCALE_PER_ZETA,
    ) -> MultiplicativeNoiseModel:
        """Checked constructor (ValueError naming the field)."""
        q = check_nonnegative("zeta_variance", zeta_variance)
        rho = check_finite("correlation", correlation)
        if not -1.0 < rho < 1.0:
            fail("correlation", correlation, "must be in (-1, 1)")
        kappa = check_nonnegative("scale_per_zeta", scale_per_zeta)
        if kappa * math.sqrt(q) >= 0.1:
            fail(
                "scale_per_zeta",
                scale_per_zeta,
                f"kappa sqrt(zeta_variance) must be < 0.1 (1 + kappa zeta > 0 with certainty; zeta_variance = {q})",
            )
        return cls(q, rho, kappa)

    @classmethod
    def paper(cls, scale_per_zeta: float = DEFAULT_SCALE_PER_ZETA) -> MultiplicativeNoiseModel:
        """The seed's ``Q_zeta = 0.1``, ``S = 0.05`` read as ``rho = 0.05 / sqrt(0.1) = 0.158``."""
        return cls.make(PAPER_ZETA_VARIANCE, PAPER_CORRELATION, scale_per_zeta)

    @property
    def zeta_sigma(self) -> float:
        return math.sqrt(self.zeta_variance)

    def max_stars(self) -> int:
        """Largest ``m`` with a positive-definite joint covariance (``3 m rho^2 < 1``)."""
        r2 = self.correlation**2
        if r2 == 0.0:
            return 10**9
        m = math.floor(1.0 / (3.0 * r2))
        return m - 1 if 3.0 * m * r2 >= 1.0 else m

    def admits(self, num_stars: int) -> bool:
        """True if ``m`` stars give a positive-definite joint covariance."""
        return 3.0 * num_stars * self.correlation**2 < 1.0

    def _check_stars(self, num_stars) -> int:
        m = check_int("num_stars", num_stars, 1)
        if not self.admits(m):
            fail("num_stars", num_stars, f"needs 3 m rho^2 < 1 (rho = {self.correlation:.6g}: m <= {self.max_stars()})")
        return m

    def cross_covariance(self, star_sigma_rad: float, num_stars: int) -> np.ndarray:
        """``S = Cov(zeta_k, v_k) = rho sqrt(Q_zeta) sigma_v 1_{3m}`` (3m,)."""
        m = self._check_stars(num_stars)
        s = check_nonnegative("star_sigma_rad", star_sigma_rad)
        return np.full(3 * m, self.correlation * self.zeta_sigma * s)

    def joint_covariance(self, star_sigma_rad: float, num_stars: int) -> np.ndarray:
        """Covariance of ``(zeta_k, v_k)`` for a step with ``m`` star vectors, (1+3m, 1+3m)."""
        S = self.cross_covariance(star_sigma_rad, num_stars)
        n = S.size
        C = np.zeros((n + 1, n + 1))
        C[0, 0] = self.zeta_variance
        C[0, 1:] = C[1:, 0] = S
        C[1:, 1:] = float(star_sigma_rad) ** 2 * np.eye(n)
        return C

    def from_normals(self, z, star_sigma_rad: float) -> tuple[np.ndarray, np.ndarray]:
        """``(zeta, v)`` from standard normals ``z`` of shape ``(..., 1 + 3m)``.

        ``z[..., 0]`` gives ``zeta``, ``z[..., 1:]`` the star noise
        (docs/derivations/cubature_and_mcns.md):
        ``v_j = sigma_v (z_j + c_m sum_l z_l + rho z_0)``. Returns ``zeta`` of shape ``(...)``
        and ``v`` of shape ``(..., m, 3)``. ``m = 0`` (``z`` of length 1) gives only ``zeta``.
        """
        z = np.asarray(z, dtype=float)
        n = z.shape[-1] - 1
        if n < 0 or n % 3:
            fail("z", z, "last dimension must be 1 + 3m")
        zeta = self.zeta_sigma * z[..., 0]
        m = n // 3
        if m == 0:
            return zeta, np.zeros(z.shape[:-1] + (0, 3))
        self._check_stars(m)
        rho = self.correlation
        c = (math.sqrt(1.0 - n * rho * rho) - 1.0) / n
        w = z[..., 1:]
        v = float(star_sigma_rad) * (w + (c * np.sum(w, axis=-1) + rho * z[..., 0])[..., None])
        return zeta, v.reshape(z.shape[:-1] + (m, 3))

    def conditional_moments(self, innovation, innovation_covariance, star_sigma_rad: float) -> tuple[float, float]:
        """Lemma 1: ``(M, U) = (S' P_yy^-1 nu, Q_zeta - S' P_yy^-1 S)`` of an update with
        innovation ``nu`` (3m,) and covariance ``P_yy`` (3m, 3m)."""
        nu = np.asarray(innovation, dtype=float)
        S = self.cross_covariance(star_sigma_rad, nu.size // 3)
        w = np.linalg.solve(np.asarray(innovation_covariance, dtype=float), S)
        return float(w @ nu), float(self.zeta_variance - w @ S)

    def increment_matrix(self, grp_a: float = 1.0, grp_f: float = 4.0) -> np.ndarray:
        """The patent's ``Phi`` for the GRP error state: ``c kappa [I_3; 0_3]`` (6, 3),
        ``c = f / (2 (1 + a))``, applied to the one-step increment ``u = (w_meas - beta) dt``."""
        out = np.zeros((6, 3))
        out[:3] = grp_f / (2.0 * (1.0 + grp_a)) * self.scale_per_zeta * np.eye(3)
        return out


@dataclass(frozen=True)
class ReferenceStep:
    """One gyro step of the reference truth (docs/derivations/cubature_and_mcns.md).

    Attributes:
        w_meas_B: gyro output for the step (3, rad/s), time stamp ``t_k + dt``.
        directions_S: star directions (m, 3) at ``t_k``, or None without a star sample.
        zeta: ``zeta_k``.
        q_IB_next, bias_next: truth at ``t_k + dt``.
    """

    w_meas_B: np.ndarray
    directions_S: np.ndarray | None
    zeta: float
    q_IB_next: np.ndarray
    bias_next: np.ndarray


def star_directions(q_IB, references_I, q_BS=(1.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """Noise-free sensor-frame directions ``R_SB R(q_IB)' r_i`` (m, 3) (batched over ``q_IB``)."""
    R_IS = rot.quat_to_rotmat(rot.quat_multiply(q_IB, rot.quat_normalize(q_BS)))
    return np.einsum("...ji,mj->...mi", R_IS, np.asarray(references_I, dtype=float))


def reference_step(
    q_IB,
    bias_B,
    w_mean_B,
    dt: float,
    z,
    gyro_noise: FarrenkopfGyroNoise,
    model: MultiplicativeNoiseModel,
    references_I=None,
    star_sigma_rad: float = 0.0,
    q_BS=(1.0, 0.0, 0.0, 0.0),
    star_sample: bool = False,
) -> ReferenceStep:
    """One step of the reference truth, from the row of normals ``z`` (length ``7 + 3m``).

    Args:
        q_IB, bias_B: truth at ``t_k``. w_mean_B: the body's mean rate over the step (rad/s).
        dt: step (s); must equal ``gyro_noise.interval_s``.
        z: standard normals, ordered as in docs/derivations/cubature_and_mcns.md.
        references_I: (m, 3) unit reference directions; star_sigma_rad: ``sigma_v`` (rad);
        q_BS: tracker mounting; star_sample: a star sample is taken at ``t_k``.
    """
    z = np.asarray(z, dtype=float)
    m = 0 if references_I is None else np.asarray(references_I).shape[0]
    if z.shape != (normals_per_step(m),):
        fail("z", z, f"must have shape ({normals_per_step(m)},) for m = {m} stars")
    e, db = gyro_noise.from_normals(z[:GYRO_NORMALS].reshape(2, 3))
    zeta_array, v = model.from_normals(z[ZETA_INDEX:], star_sigma_rad)
    zeta = float(zeta_array)
    w_mean_B = np.asarray(w_mean_B, dtype=float)
    bias_B = np.asarray(bias_B, dtype=float)
    w_meas = w_mean_B / (1.0 + model.scale_per_zeta * zeta) + bias_B + e
    dirs = star_directions(q_IB, references_I, q_BS) + v if (star_sample and m) else None
    q_next = rot.quat_normalize(rot.quat_propagate(q_IB, w_mean_B, dt))
    return ReferenceStep(w_meas, dirs, zeta, q_next, bias_B + db)


@dataclass(frozen=True)
class ReferenceRun:
    """A whole reference run (:func:`simulate_reference`), ``N`` gyro steps.

    Attributes:
        t: (N + 1,) times ``t_k = k dt`` (s). q_IB: (N + 1, 4) truth. bias_B: (N + 1, 3) truth.
        w_meas_B: (N, 3) gyro output of step k (interval ``[t_k, t_{k+1}]``).
        zeta: (N,). star_steps: (K,) indices k with a star sample at ``t_k``.
        directions_S: (K, m, 3) the samples. references_I: (m, 3). q_BS: (4,). star_sigma_rad.
    """

    t: np.ndarray
    q_IB: np.ndarray
    bias_B: np.ndarray
    w_meas_B: np.ndarray
    zeta: np.ndarray
    star_steps: np.ndarray
    directions_S: np.ndarray
    references_I: np.ndarray
    q_BS: np.ndarray
    star_sigma_rad: float


def simulate_reference(
    q_IB,
    w_mean_B,
    dt: float,
    normals,
    gyro_noise: FarrenkopfGyroNoise,
    model: MultiplicativeNoiseModel,
    bias0_B,
    references_I,
    star_sigma_rad: float,
    star_every: int,
    q_BS=(1.0, 0.0, 0.0, 0.0),
) -> ReferenceRun:
    """A whole run of :func:`reference_step`, vectorized (the same numbers).

    Args:
        q_IB: (N + 1, 4) true attitude at ``t_k`` (the body's motion is an input).
        w_mean_B: (N, 3) the body's mean rate over each step (rad/s).
        dt: gyro step (s) = ``gyro_noise.interval_s``.
        normals: (N, 7 + 3m) standard normals, row k = ``z_k``.
        bias0_B: true bias at ``t_0`` (3, rad/s).
        references_I: (m, 3) unit reference directions. star_sigma_rad: ``sigma_v`` (rad).
        star_every: a star sample at every ``star_every``-th step (k = 0, s, 2s, ...).
    """
    q_IB = np.asarray(q_IB, dtype=float)
    w_mean_B = np.asarray(w_mean_B, dtype=float)
    n = w_mean_B.shape[0]
    refs = np.asarray(references_I, dtype=float)
    m = refs.shape[0]
    check_array("q_IB", q_IB, (n + 1, 4))
    check_array("normals", normals, (n, normals_per_step(m)))
    check_int("star_every", star_every, 1)
    check_positive("dt", dt)
    if not math.isclose(dt, gyro_noise.interval_s, rel_tol=1e-12):
        fail("dt", dt, f"must equal gyro_noise.interval_s = {gyro_noise.interval_s}")
    z = np.asarray(normals, dtype=float)
    e, db = gyro_noise.from_normals(np.moveaxis(z[:, :GYRO_NORMALS].reshape(n, 2, 3), 1, 0))
    zeta, v = model.from_normals(z[:, ZETA_INDEX:], star_sigma_rad)
    # b_{k+1} = b_k + db_k, summed in that order (bit-identical to stepping).
    bias = np.cumsum(np.vstack([np.asarray(bias0_B, dtype=float)[None, :], db]), axis=0)
    w_meas = w_mean_B / (1.0 + model.scale_per_zeta * zeta)[:, None] + bias[:-1] + e
    steps = np.arange(0, n, star_every)
    dirs = star_directions(q_IB[steps], refs, q_BS) + v[steps]
    t = dt * np.arange(n + 1)
    return ReferenceRun(t, q_IB, bias, w_meas, zeta, steps, dirs, refs, rot.quat_normalize(q_BS), float(star_sigma_rad))


__all__ = [
    "MultiplicativeNoiseModel",
    "ReferenceStep",
    "ReferenceRun",
    "reference_step",
    "simulate_reference",
    "star_directions",
    "normals_per_step",
    "PAPER_ZETA_VARIANCE",
    "PAPER_CROSS_COVARIANCE",
    "PAPER_CORRELATION",
    "DEFAULT_SCALE_PER_ZETA",
]
