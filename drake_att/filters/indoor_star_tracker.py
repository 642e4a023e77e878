"""Paper S2's indoor star tracker solver: angle-matching star identification corrected for
the camera's offset, iterative TRIAD, particle-swarm initialization (plain numpy, no Drake).

Geometry and notation: :mod:`drake_att.screen_geometry` (``A = R_BI``, ``R0_B``, ``h``,
``alpha_i``).  Each frame (:class:`~drake_att.contract.CameraCentroids`) is solved from a guess
``A0``: centre-referenced directions from ``A0``, identification by inter-star angles, attitude,
repeated from the new attitude until it converges (or ``max_iterations``).

* :class:`IndoorStarTrackerSolver`: the solver as a :class:`drake_att.contract.FilterCore`
  (second quantity the body rate); :meth:`~IndoorStarTrackerSolver.solve` solves one frame.
* :class:`IndoorStarTrackerMekf`: beyond the paper, the solver fused with a table gyro in the MEKF.
* The steps: :class:`AngleMatcher`, :func:`triad`, :func:`triad_covariance`, :func:`svd_attitude`,
  :func:`particle_swarm_search` (:class:`SwarmSettings`).
* Calibration (:mod:`drake_att.filters.screen_calibration`): the attitude covariance's term for
  the uncertainty of the screen height and the camera offset, the angle-match tolerance from the
  centroid noise, self-calibration from tilted frames.

Conventions: attitudes are ``A = R_BI`` (the paper's) in the solver and ``q_IB`` (wxyz Hamilton)
in the state; roll/pitch/yaw in deg (x-y-z, as ``q_IB``); covariances in body axes (rad^2), the
project's ``dtheta_B``.

Derivation and paper notes: docs/derivations/indoor_star_tracker.md

Paper S2's pipeline (identification, iteration, swarm start) and its fusion: one core, one place.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import CameraCentroids, SecondQuantity, UpdateInfo
from drake_att.filters.screen_calibration import (
    FIXED_POINT_MAX_ITERATIONS,
    FIXED_POINT_TOLERANCE_RAD,
    JACOBIAN_RELATIVE_STEP,
    CalibrationFrame,
    CalibrationUncertainty,
    SelfCalibration,
    calibration_jacobian,
    calibration_vector,
    catalogue_directions,
    pair_angle_tolerance,
    self_calibrate,
)
from drake_att.screen_geometry import (
    ScreenCameraGeometry,
    camera_to_star_distances,
    centre_referenced_directions,
    directions_from_centroids,
)
from drake_att.validation import check_int, check_nonnegative, check_positive, fail

IDENTIFICATIONS = ("corrected", "naive")
ATTITUDE_METHODS = ("triad", "least_squares")
MIN_IDENTIFIED = 3  # a consistent triangle: the smallest identification angles can confirm


def rpy_deg_to_R_BI(rpy_deg) -> np.ndarray:
    """``A = R_BI`` of roll/pitch/yaw (deg; the project's x-y-z convention of ``q_IB``)."""
    return rot.quat_to_rotmat(rot.rpy_to_quat(np.radians(np.asarray(rpy_deg, dtype=float)))).T


def R_BI_to_rpy_deg(R_BI) -> np.ndarray:
    """Roll/pitch/yaw (deg) of ``A = R_BI`` (inverse of :func:`rpy_deg_to_R_BI`)."""
    return np.degrees(rot.quat_to_rpy(rot.rotmat_to_quat(np.asarray(R_BI).T)))


def rotation_angle(R_a, R_b) -> float:
    """The angle (rad) of ``R_a R_b^T``, accurate down to round-off (from the rotation
    vector, not ``arccos`` of the trace, which reads every angle below ~1e-8 rad as 0)."""
    return float(np.linalg.norm(rot.rotmat_to_rotvec(np.asarray(R_a) @ np.asarray(R_b).T)))


def _pair_angles(u, v) -> np.ndarray:
    return np.arccos(np.clip(np.einsum("ij,ij->i", u, v), -1.0, 1.0))


class AngleMatcher:
    """Star identification by inter-star angles against a catalogue
    (docs/derivations/indoor_star_tracker.md).

    Args:
        catalogue: (m, 3) catalogue unit directions (m >= 3).
        tolerance_rad: angle-match tolerance (rad) > 0.
    """

    def __init__(self, catalogue, tolerance_rad: float):
        c = np.asarray(catalogue, dtype=float)
        if c.ndim != 2 or c.shape[1] != 3 or len(c) < MIN_IDENTIFIED or not np.all(np.isfinite(c)):
            fail("catalogue", f"shape {c.shape}", f"need (m >= {MIN_IDENTIFIED}, 3) finite directions")
        self.tolerance_rad = check_positive("tolerance_rad", tolerance_rad)
        self.catalogue = c / np.linalg.norm(c, axis=1, keepdims=True)
        m = len(c)
        j, l = np.triu_indices(m, 1)
        phi = _pair_angles(self.catalogue[j], self.catalogue[l])
        order = np.argsort(phi, kind="stable")
        self._phi, self._j, self._l = phi[order], j[order], l[order]
        self._angles = np.arccos(np.clip(self.catalogue @ self.catalogue.T, -1.0, 1.0))

    def identify(self, directions, tolerance_rad: float | None = None) -> np.ndarray:
        """Catalogue index of each observed direction (n, 3), or -1 if not identified
        (``tolerance_rad``: this call's tolerance instead of the matcher's)."""
        u = np.asarray(directions, dtype=float)
        n, m = len(u), len(self.catalogue)
        tol = self.tolerance_rad if tolerance_rad is None else float(tolerance_rad)
        ids = np.full(n, -1)
        if n < MIN_IDENTIFIED:
            return ids
        i, k = np.triu_indices(n, 1)
        theta = _pair_angles(u[i], u[k])
        lo = np.searchsorted(self._phi, theta - tol, side="left")
        hi = np.searchsorted(self._phi, theta + tol, side="right")
        counts = hi - lo
        total = int(counts.sum())
        if total == 0:
            return ids
        pair = np.repeat(np.arange(len(theta)), counts)
        cat = np.repeat(lo - (np.cumsum(counts) - counts), counts) + np.arange(total)
        oi, ok, cj, cl = i[pair], k[pair], self._j[cat], self._l[cat]
        votes = np.bincount(
            np.concatenate([oi * m + cj, oi * m + cl, ok * m + cj, ok * m + cl]), minlength=n * m
        ).reshape(n, m)
        best = np.argmax(votes, axis=1)
        top = votes[np.arange(n), best]
        second = np.partition(votes, m - 2, axis=1)[:, m - 2] if m >= 2 else np.zeros(n)
        cand = np.flatnonzero((top >= 2) & (top > second))
        # A catalogue star claimed twice goes to the observed star with more votes (none on a tie).
        claim_max = np.zeros(m, dtype=votes.dtype)
        np.maximum.at(claim_max, best[cand], top[cand])
        at_max = top[cand] == claim_max[best[cand]]
        n_at_max = np.bincount(best[cand][at_max], minlength=m)
        cand = cand[at_max & (n_at_max[best[cand]] == 1)]
        if len(cand) < MIN_IDENTIFIED:
            return ids
        observed = np.arccos(np.clip(u[cand] @ u[cand].T, -1.0, 1.0))
        agree = np.abs(observed - self._angles[np.ix_(best[cand], best[cand])]) <= tol
        alive = np.ones(len(cand), dtype=bool)
        while True:
            sub = agree[np.ix_(alive, alive)]
            bad = (~sub).sum(axis=1)
            if bad.max(initial=0) == 0:
                break
            idx = np.flatnonzero(alive)
            worst = np.flatnonzero(bad == bad.max())
            drop = worst[np.argmin(top[cand[idx[worst]]])]
            alive[idx[drop]] = False
        if alive.sum() < MIN_IDENTIFIED:
            return ids
        ids[cand[alive]] = best[cand[alive]]
        return ids


def triad(b1, b2, r1, r2) -> np.ndarray:
    """TRIAD (paper eq.): ``A = M_obs M_ref^T`` with ``b1 = A r1`` exact (``A = R_BI``)."""

    def frame(v1, v2):
        t2 = np.cross(v1, v2)
        t2 = t2 / np.linalg.norm(t2)
        return np.column_stack([v1, t2, np.cross(v1, t2)])

    return frame(np.asarray(b1), np.asarray(b2)) @ frame(np.asarray(r1), np.asarray(r2)).T


def triad_covariance(b1, b2, sigma1: float, sigma2: float) -> np.ndarray:
    """Covariance (3x3, body axes, rad^2) of TRIAD's attitude error for direction noise
    ``sigma1``, ``sigma2`` (rad per axis normal to each direction).

    First-order error map (derived in the basis ``e1 = b1``, ``e3 = b1 x b2 / |.|``, ``e2 =
    e3 x e1``, with ``gamma`` the separation): the first vector fixes the two axes normal to
    it (variance ``sigma1^2`` each); the rotation about ``b1`` comes from the plane's normal,
    variance ``(sigma2^2 + cos^2 gamma sigma1^2) / sin^2 gamma``, correlated with the ``e2``
    error by ``cos gamma sigma1^2 / sin gamma``.
    """
    e1 = np.asarray(b1, dtype=float)
    e3 = np.cross(e1, b2)
    s = np.linalg.norm(e3)
    e3 = e3 / s
    e2 = np.cross(e3, e1)
    c = float(np.dot(e1, b2))
    s2, t2 = sigma1**2, sigma2**2
    P_e = np.array([[(t2 + c * c * s2) / (s * s), c * s2 / s, 0.0], [c * s2 / s, s2, 0.0], [0.0, 0.0, s2]])
    E = np.column_stack([e1, e2, e3])
    return E @ P_e @ E.T


def svd_attitude(b, r, sigmas) -> tuple[np.ndarray, np.ndarray]:
    """Wahba's problem by SVD (Markley): ``A = R_BI`` minimizing ``sum |b_i - A r_i|^2 /
    sigma_i^2``, and its covariance ``(sum sigma_i^-2 (I - b_i b_i^T))^-1`` (body axes)."""
    b, r = np.asarray(b, dtype=float), np.asarray(r, dtype=float)
    w = 1.0 / np.asarray(sigmas, dtype=float) ** 2
    B = (b * w[:, None]).T @ r
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    A = U @ np.diag([1.0, 1.0, d]) @ Vt
    F = np.einsum("i,ij,ik->jk", w, b, b)
    info = w.sum() * np.eye(3) - F
    return A, np.linalg.inv(info)


@dataclass(frozen=True)
class IterationRecord:
    """One iteration of :meth:`IndoorStarTrackerSolver.solve`: its attitude and stars identified."""

    R_BI: np.ndarray
    identified: int


@dataclass(frozen=True)
class Solution:
    """One frame's result.

    Attributes:
        solved: an attitude was found (>= 3 stars identified in the last iteration).
        R_BI: the attitude (the guess when not solved); covariance: (3, 3) body axes (rad^2).
        star_ids: catalogue index per observed centroid (-1 unidentified), last iteration.
        iterations: iterations run; history: one :class:`IterationRecord` per iteration.
    """

    solved: bool
    R_BI: np.ndarray
    covariance: np.ndarray
    star_ids: np.ndarray
    iterations: int
    history: tuple = ()

    @property
    def identified(self) -> int:
        return int(np.sum(self.star_ids >= 0))


@dataclass(frozen=True)
class SwarmResult:
    """:func:`particle_swarm_search`'s best attitude, its fitness (minus stars identified)
    and the generations run."""

    rpy_deg: np.ndarray
    fitness: float
    generations: int


@dataclass(frozen=True)
class SwarmSettings:
    """Particle swarm (paper S2): ``w = 0.8, c1 = 1.3, c2 = 1.7``, ``v_max = 5 deg``,
    ``G_max = 200``, 5 particles; positions are x-y-z angles (deg) within ``centre +-
    search_range_deg`` (clamped there), velocities clamped to ``+-v_max``. Stops at
    ``G_max`` or when the best particle identifies ``max(3, ceil(stop_fraction * n))`` of the
    ``n`` observed stars."""

    particles: int = 5
    inertia: float = 0.8
    c1: float = 1.3
    c2: float = 1.7
    v_max_deg: float = 5.0
    max_generations: int = 200
    search_range_deg: float = 10.0
    stop_fraction: float = 0.5

    def __post_init__(self):
        check_int("pso.particles", self.particles, 1)
        check_int("pso.max_generations", self.max_generations, 1)
        for f in ("inertia", "c1", "c2"):
            check_nonnegative(f"pso.{f}", getattr(self, f))
        check_positive("pso.v_max_deg", self.v_max_deg)
        check_positive("pso.search_range_deg", self.search_range_deg)
        if not 0.0 < self.stop_fraction <= 1.0:
            fail("pso.stop_fraction", self.stop_fraction, "must be in (0, 1]")


def particle_swarm_search(
    fitness, centre_rpy_deg, settings: SwarmSettings, n_observed: int, rng: np.random.Generator
) -> SwarmResult:
    """Minimize ``fitness(rpy_deg)`` (minus the stars identified from that ``A0``) by the
    paper's particle swarm (see :class:`SwarmSettings`)."""
    s = settings
    centre = np.asarray(centre_rpy_deg, dtype=float)
    lo, hi = centre - s.search_range_deg, centre + s.search_range_deg
    x = centre + rng.uniform(-s.search_range_deg, s.search_range_deg, (s.particles, 3))
    v = rng.uniform(-s.v_max_deg, s.v_max_deg, (s.particles, 3))
    f = np.array([fitness(p) for p in x])
    p_best, f_best = x.copy(), f.copy()
    g = int(np.argmin(f_best))
    stop = -max(MIN_IDENTIFIED, math.ceil(s.stop_fraction * n_observed))
    generation = 0
    while generation < s.max_generations and f_best[g] > stop:
        generation += 1
        r1, r2 = rng.random((s.particles, 3)), rng.random((s.particles, 3))
        v = s.inertia * v + s.c1 * r1 * (p_best - x) + s.c2 * r2 * (p_best[g] - x)
        v = np.clip(v, -s.v_max_deg, s.v_max_deg)
        x = np.clip(x + v, lo, hi)
        f = np.array([fitness(p) for p in x])
        better = f < f_best
        p_best[better], f_best[better] = x[better], f[better]
        g = int(np.argmin(f_best))
    return SwarmResult(p_best[g].copy(), float(f_best[g]), generation)


@dataclass(frozen=True)
class IndoorSolverState:
    """The solver's state between frames.

    Attributes:
        q_IB: last solution (or the initial guess); covariance: (6, 6) of ``[dtheta_B;
            w error]``; w_IB_B: body rate from the last two consecutive solutions (rad/s).
        t_solution: time of the last solution (s; -inf: none yet).
        held_s: time the solution has been held since (s): its attitude covariance grows by
            ``(w w^T + P_w) held_s^2`` (the table may have turned at the estimated rate).
        tracking: the last solution is usable as ``A0`` (reset after ``max_lost_frames``
            consecutive failures, which sends the next frame to the swarm search).
        failures: consecutive failed frames.
        diagnostics: ``[stars observed, stars identified, iterations, swarm generations,
            swarm searches so far, solved (1/0)]`` of the last frame.
    """

    q_IB: np.ndarray
    covariance: np.ndarray
    w_IB_B: np.ndarray
    t_solution: float = -math.inf
    held_s: float = 0.0
    tracking: bool = False
    failures: int = 0
    diagnostics: np.ndarray = field(default_factory=lambda: np.zeros(6))


DIAGNOSTIC_NAMES = ("stars_observed", "stars_identified", "iterations", "swarm_generations", "swarm_searches", "solved")
_UNKNOWN_RATE_SIGMA = math.radians(10.0)  # rad/s: the rate's 1-sigma before two consecutive solutions


class IndoorStarTrackerSolver:
    """The indoor star tracker as a filter core (:class:`drake_att.contract.FilterCore`):
    each camera frame (:class:`~drake_att.contract.CameraCentroids`) is solved on its own;
    ``predict`` holds the attitude (its covariance grows with the estimated rate). Second quantity: the body rate, differenced from the last
    two consecutive solutions.

    Args:
        geometry: the screen and camera the solver assumes (its catalogue is their view at
            zero attitude).
        tolerance_deg: angle-match tolerance (deg): fixed, or the floor of the adaptive one.
        tolerance_sigmas: None: the tolerance is ``tolerance_deg``; ``k`` > 0: per frame
            ``max(tolerance_deg, k sqrt(2) sigma_c / f)`` from the frame's centroid noise
            (:func:`~drake_att.filters.screen_calibration.pair_angle_tolerance`; the floor
            covers the ``A0`` and model errors the noise does not).
        identification: "corrected" (the paper) or "naive" (no ``alpha`` correction).
        attitude_method: "triad" (the paper) or "least_squares".
        max_iterations: iterations per frame (>= 1); convergence_tolerance_rad: stop when
            the attitude changes by less (rad, >= 0; 0: always run ``max_iterations``).
        initialization: "swarm" (the paper's PSO when no ``A0``) or "given" (the initial
            guess is ``A0`` of the first frame, as in the paper's Tables 1-2).
        swarm: :class:`SwarmSettings`; max_lost_frames: consecutive failures before the
            swarm search runs again (>= 1).
        sigma_floor_rad: floor of the direction noise in the covariance (rad, > 0).
        catalogue_centroids_m: the photo the catalogue is made from: focal-plane centroids
            (k, 2) of the real camera at zero attitude, converted with ``geometry`` (the
            solver's model of the layout). None: ``geometry``'s own noise-free view (a model
            that is exact). Differs from ``geometry``'s view when the model is miscalibrated.
        calibration: :class:`~drake_att.filters.screen_calibration.CalibrationUncertainty`, the
            1-sigma of ``geometry``'s ``h`` and ``R0_B``: a solution's covariance adds ``J
            Sigma_cal J^T``, ``J`` the derivative of the converged solution (identifications,
            TRIAD pair and star weights held) by central differences
            (:meth:`calibration_covariance`). None or zero sigmas: no term (nothing is computed).
    """

    second_quantity = SecondQuantity.BODY_RATE
    uses_gyro = False
    is_random = True
    state_size = 4 + 36 + 3 + 4 + len(DIAGNOSTIC_NAMES)
    diagnostic_names = DIAGNOSTIC_NAMES

    def __init__(
        self,
        geometry: ScreenCameraGeometry,
        tolerance_deg: float = 0.02,
        identification: str = "corrected",
        attitude_method: str = "triad",
        max_iterations: int = 10,
        convergence_tolerance_rad: float = 1e-9,
        initialization: str = "swarm",
        swarm: SwarmSettings = SwarmSettings(),
        max_lost_frames: int = 5,
        sigma_floor_rad: float = 1e-9,
        catalogue_centroids_m=None,
        tolerance_sigmas: float | None = None,
        calibration: CalibrationUncertainty | None = None,
    ):
        if identification not in IDENTIFICATIONS:
            fail("identification", identification, f"allowed: {list(IDENTIFICATIONS)}")
        if attitude_method not in ATTITUDE_METHODS:
            fail("attitude_method", attitude_method, f"allowed: {list(ATTITUDE_METHODS)}")
        if initialization not in ("swarm", "given"):
            fail("initialization", initialization, "allowed: ['swarm', 'given']")
        self.geometry = geometry
        self.identification = identification
        self.attitude_method = attitude_method
        self.max_iterations = check_int("max_iterations", max_iterations, 1)
        self.convergence_tolerance_rad = check_nonnegative("convergence_tolerance_rad", convergence_tolerance_rad)
        self.initialization = initialization
        self.swarm = swarm
        self.max_lost_frames = check_int("max_lost_frames", max_lost_frames, 1)
        self.sigma_floor_rad = check_positive("sigma_floor_rad", sigma_floor_rad)
        self.catalogue_ids, r_I, b0 = geometry.catalogue(catalogue_centroids_m)
        self.catalogue_photo_m = (
            geometry.project(np.eye(3))[1] if catalogue_centroids_m is None else np.asarray(catalogue_centroids_m)
        )
        if len(self.catalogue_ids) < MIN_IDENTIFIED:
            fail(
                "geometry",
                f"{len(self.catalogue_ids)} stars in view at zero attitude",
                f"the catalogue needs >= {MIN_IDENTIFIED}",
            )
        self.catalogue_b0 = b0
        self.catalogue_I = b0 if identification == "naive" else r_I
        self.matcher = AngleMatcher(self.catalogue_I, math.radians(check_positive("tolerance_deg", tolerance_deg)))
        self.tolerance_sigmas = (
            None if tolerance_sigmas is None else check_positive("tolerance_sigmas", tolerance_sigmas)
        )
        if calibration is not None and not isinstance(calibration, CalibrationUncertainty):
            fail("calibration", type(calibration).__name__, "need a CalibrationUncertainty or None")
        self.calibration = CalibrationUncertainty() if calibration is None else calibration

    # -- one frame ---------------------------------------------------------------------------
    def observed_directions(self, b_B, R_BI_guess, h_m: float | None = None, R0_B=None) -> np.ndarray:
        """The directions identification compares: ``r_i^B`` from ``A0`` (corrected) or ``b_i``
        (naive); ``h_m``, ``R0_B``: another model of the layout than ``geometry``'s."""
        if self.identification == "naive":
            return b_B
        h = self.geometry.h_m if h_m is None else h_m
        R0 = self.geometry.R0_B if R0_B is None else R0_B
        return centre_referenced_directions(b_B, camera_to_star_distances(R_BI_guess, b_B, R0, h), R0)

    def match_tolerance_rad(self, frame: CameraCentroids) -> float:
        """The angle-match tolerance (rad) of ``frame``: ``tolerance_deg``, or with
        ``tolerance_sigmas`` the larger of it and the frame's noise bound."""
        fixed = self.matcher.tolerance_rad
        if self.tolerance_sigmas is None:
            return fixed
        q = float(getattr(frame, "quantization_m", 0.0))
        noise = pair_angle_tolerance(float(frame.sigma_m), q, float(frame.focal_length_m), self.tolerance_sigmas)
        return max(fixed, noise)

    def count_identified(self, b_B, R_BI_guess, tolerance_rad: float | None = None) -> int:
        """Stars identified in one pass from the guess ``A0`` (the swarm's fitness is minus this)."""
        return int(np.sum(self.matcher.identify(self.observed_directions(b_B, R_BI_guess), tolerance_rad) >= 0))

    def _triad_pair(self, b, centroids_sel) -> tuple[int, int]:
        """TRIAD's pair: the identified pair with the largest separation, the star nearer the
        optical axis first (it is matched exactly)."""
        gram = np.abs(np.clip(b @ b.T, -1.0, 1.0))
        i, k = np.unravel_index(np.argmin(gram + 2.0 * np.eye(len(b))), gram.shape)
        radius = np.linalg.norm(np.asarray(centroids_sel), axis=1)
        if radius[k] < radius[i]:
            i, k = k, i
        return int(i), int(k)

    def _attitude(self, u, ids, sigmas, centroids, catalogue=None, pair=None):
        sel = np.flatnonzero(ids >= 0)
        cat = self.catalogue_I if catalogue is None else catalogue
        b, r, s = u[sel], cat[ids[sel]], sigmas[sel]
        if self.attitude_method == "least_squares":
            return svd_attitude(b, r, s)
        i, k = self._triad_pair(b, np.asarray(centroids)[sel]) if pair is None else pair
        return triad(b[i], b[k], r[i], r[k]), triad_covariance(b[i], b[k], s[i], s[k])

    def calibration_covariance(self, frame: CameraCentroids, ids, R_BI) -> np.ndarray:
        """``J Sigma_cal J^T`` (3, 3, body axes, rad^2) of a solution ``R_BI`` with
        identifications ``ids``: ``J`` (3, 4) is the derivative of the converged solution with
        respect to ``[h, R0_x, R0_y, R0_z]`` by central differences (step
        ``JACOBIAN_RELATIVE_STEP h``), each perturbed solution iterated from ``R_BI`` with the
        identifications, the TRIAD pair and the star weights held (the catalogue re-converted
        with the perturbed model)."""
        b = directions_from_centroids(frame.centroids_m, frame.focal_length_m)
        A = np.asarray(R_BI, dtype=float)
        sigmas = self.direction_sigmas(frame, b, A)
        sel = np.flatnonzero(ids >= 0)
        pair = None
        if self.attitude_method == "triad":
            u = self.observed_directions(b, A)
            pair = self._triad_pair(u[sel], np.asarray(frame.centroids_m)[sel])

        def solve_at(theta):
            h, R0 = float(theta[0]), theta[1:]
            cat = self.catalogue_I if self.identification == "naive" else catalogue_directions(self.catalogue_b0, h, R0)
            A_k = A
            for _ in range(FIXED_POINT_MAX_ITERATIONS):
                u = self.observed_directions(b, A_k, h, R0)
                A_new, _ = self._attitude(u, ids, sigmas, frame.centroids_m, cat, pair)
                change = rotation_angle(A_new, A_k)
                A_k = A_new
                if change < FIXED_POINT_TOLERANCE_RAD:
                    break
            return A_k

        g = self.geometry
        J = calibration_jacobian(solve_at, calibration_vector(g.h_m, g.R0_B), JACOBIAN_RELATIVE_STEP * g.h_m)
        return J @ self.calibration.covariance @ J.T

    def direction_sigmas(self, frame: CameraCentroids, b_B, R_BI) -> np.ndarray:
        """Per-star noise (rad) of the compared directions
        (docs/derivations/indoor_star_tracker.md)."""
        q = float(getattr(frame, "quantization_m", 0.0))
        sigma = max(
            math.sqrt(float(frame.sigma_m) ** 2 + q * q / 12.0) / float(frame.focal_length_m), self.sigma_floor_rad
        )
        if self.identification == "naive":
            return np.full(len(b_B), sigma)
        g = self.geometry
        alpha = camera_to_star_distances(R_BI, b_B, g.R0_B, g.h_m)
        beta = np.linalg.norm(g.R0_B + alpha[:, None] * b_B, axis=1)
        return sigma * alpha / beta

    def solve(self, frame: CameraCentroids, R_BI_guess) -> Solution:
        """Iterate identification + attitude from the guess ``A0``
        (docs/derivations/indoor_star_tracker.md)."""
        b = directions_from_centroids(frame.centroids_m, frame.focal_length_m)
        A = np.asarray(R_BI_guess, dtype=float)
        history: list[IterationRecord] = []
        ids = np.full(len(b), -1)
        P = np.full((3, 3), np.nan)
        tolerance = self.match_tolerance_rad(frame)
        for _ in range(self.max_iterations if self.identification == "corrected" else 1):
            u = self.observed_directions(b, A)
            ids = self.matcher.identify(u, tolerance)
            if np.sum(ids >= 0) < MIN_IDENTIFIED:
                return Solution(False, A, P, ids, len(history) + 1, tuple(history))
            A_new, P = self._attitude(u, ids, self.direction_sigmas(frame, b, A), frame.centroids_m)
            history.append(IterationRecord(A_new, int(np.sum(ids >= 0))))
            change = rotation_angle(A_new, A)
            A = A_new
            if change < self.convergence_tolerance_rad:
                break
        if self.calibration.active:
            P = P + self.calibration_covariance(frame, ids, A)
        return Solution(True, A, P, ids, len(history), tuple(history))

    def acquire(self, frame: CameraCentroids, centre_rpy_deg, rng: np.random.Generator) -> SwarmResult:
        """The swarm search for an ``A0`` around ``centre_rpy_deg``."""
        b = directions_from_centroids(frame.centroids_m, frame.focal_length_m)
        tolerance = self.match_tolerance_rad(frame)
        return particle_swarm_search(
            lambda x: -self.count_identified(b, rpy_deg_to_R_BI(x), tolerance), centre_rpy_deg, self.swarm, len(b), rng
        )

    # -- calibration ---------------------------------------------------------------------------
    def recalibrated(self, h_m: float, R0_B) -> IndoorStarTrackerSolver:
        """This solver with the layout ``(h_m, R0_B)`` (the same catalogue photo re-converted)."""
        new = copy.copy(self)
        new.geometry = self.geometry.with_layout(h_m, R0_B)
        _, r_I, b0 = new.geometry.catalogue(self.catalogue_photo_m)
        new.catalogue_b0 = b0
        new.catalogue_I = b0 if self.identification == "naive" else r_I
        new.matcher = AngleMatcher(new.catalogue_I, self.matcher.tolerance_rad)
        return new

    def self_calibrate(
        self, frames, R_BI_guesses, camera_to_screen_m: float, passes: int = 2
    ) -> tuple[SelfCalibration, list]:
        """Self-calibration from frames at several tilts
        (:func:`~drake_att.filters.screen_calibration.self_calibrate`): each frame is solved from
        its guess (e.g. the table's commanded tilt), the layout and the attitudes are estimated
        from the identified centroids, and the frames are identified again with the estimated
        layout (``passes`` times in all, >= 1; the Fisher information scaled by the first frame's
        centroid noise: one camera). The second pass matters: a miscalibrated model
        keeps the stars whose noise happens to agree with it, which biases the estimate towards
        the model; identified with the estimate, every star is kept.

        Returns:
            ``(the last pass's SelfCalibration, the last pass's catalogue ids per frame)``.
        """
        frames, guesses = list(frames), list(R_BI_guesses)
        if len(frames) != len(guesses) or not frames:
            fail("R_BI_guesses", f"{len(guesses)} guesses for {len(frames)} frames", "need one guess per frame, >= 1")
        check_int("passes", passes, 1)
        solver, result = self, None
        ids: list[np.ndarray] = []
        for _ in range(passes):
            cal_frames, ids = [], []
            for frame, guess in zip(frames, guesses, strict=True):
                sol = solver.solve(frame, guess)
                ids.append(sol.star_ids)
                cal_frames.append(CalibrationFrame(frame.centroids_m, sol.star_ids, sol.R_BI))
            sigma = math.hypot(
                float(frames[0].sigma_m), float(getattr(frames[0], "quantization_m", 0.0)) / math.sqrt(12)
            )
            result = self_calibrate(
                cal_frames,
                solver.catalogue_b0,
                float(frames[0].focal_length_m),
                camera_to_screen_m,
                solver.geometry.R0_B,
                max(sigma, self.sigma_floor_rad * float(frames[0].focal_length_m)),
            )
            solver = self.recalibrated(result.screen_height_m, result.camera_offset_B_m)
        assert result is not None
        return result, ids

    # -- the filter-core protocol --------------------------------------------------------------
    def initial_state(self, q_IB, attitude_sigma_rad: float) -> IndoorSolverState:
        """The guess before the first frame (``A0`` of the first frame with ``initialization:
        given``; the swarm's search centre otherwise)."""
        P = np.zeros((6, 6))
        P[:3, :3] = np.eye(3) * check_positive("attitude_sigma_rad", attitude_sigma_rad) ** 2
        P[3:, 3:] = np.eye(3) * _UNKNOWN_RATE_SIGMA**2
        return IndoorSolverState(
            rot.quat_canonical(rot.quat_normalize(np.asarray(q_IB, dtype=float))),
            P,
            np.zeros(3),
            tracking=self.initialization == "given",
        )

    def predict(self, state: IndoorSolverState, w_meas_B, dt: float, rng=None) -> IndoorSolverState:
        """Hold the last solution; its attitude covariance grows as the table may turn at the
        estimated rate: ``P_att(held) = P_att(solution) + (w w^T + P_w) held^2``."""
        if not (dt > 0.0 and math.isfinite(state.t_solution)):
            return state
        held = state.held_s + dt
        P = state.covariance.copy()
        P[:3, :3] += self._turn_covariance(state) * (held * held - state.held_s * state.held_s)
        return replace(state, covariance=P, held_s=held)

    @staticmethod
    def _turn_covariance(state: IndoorSolverState) -> np.ndarray:
        return np.outer(state.w_IB_B, state.w_IB_B) + state.covariance[3:, 3:]

    def update(
        self, state: IndoorSolverState, measurement, rng=None, guess_q_IB=None
    ) -> tuple[IndoorSolverState, UpdateInfo]:
        """Solve one frame: ``A0`` is ``guess_q_IB`` (a fused filter's prediction), else the
        held solution while tracking, else the swarm search around the held attitude."""
        if not isinstance(measurement, CameraCentroids):
            raise TypeError(
                f"IndoorStarTrackerSolver.update: got a {type(measurement).__name__}; allowed: CameraCentroids"
            )
        n_obs = len(np.asarray(measurement.centroids_m).reshape(-1, 2))
        searches = state.diagnostics[4]
        generations = 0
        if guess_q_IB is not None:
            R_guess = rot.quat_to_rotmat(guess_q_IB).T
        elif state.tracking:
            R_guess = rot.quat_to_rotmat(state.q_IB).T
        else:
            if rng is None:
                raise ValueError("IndoorStarTrackerSolver.update: the swarm search needs a random generator")
            found = self.acquire(measurement, np.degrees(rot.quat_to_rpy(state.q_IB)), rng)
            R_guess, generations, searches = rpy_deg_to_R_BI(found.rpy_deg), found.generations, searches + 1
        sol = self.solve(measurement, R_guess)
        diag = np.array([n_obs, sol.identified, sol.iterations, generations, searches, float(sol.solved)])
        if not sol.solved:
            failures = state.failures + 1
            tracking = state.tracking and failures < self.max_lost_frames
            return (
                replace(state, failures=failures, tracking=tracking, diagnostics=diag),
                UpdateInfo(None, None, float("nan"), False),
            )
        q = rot.quat_canonical(rot.rotmat_to_quat(sol.R_BI.T))
        t = float(measurement.time_s)
        P = np.zeros((6, 6))
        P[:3, :3] = 0.5 * (sol.covariance + sol.covariance.T)
        dt = t - state.t_solution
        if state.failures == 0 and math.isfinite(state.t_solution) and dt > 0:
            w = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(state.q_IB), q)) / dt
            P_previous = state.covariance[:3, :3] - self._turn_covariance(state) * state.held_s**2
            P[3:, 3:] = (P_previous + P[:3, :3]) / dt**2
        else:
            w = np.zeros(3)
            P[3:, 3:] = np.eye(3) * _UNKNOWN_RATE_SIGMA**2
        new = IndoorSolverState(q, P, w, t_solution=t, held_s=0.0, tracking=True, failures=0, diagnostics=diag)
        return new, UpdateInfo(None, None, float("nan"), True)

    @staticmethod
    def estimate(state: IndoorSolverState):
        return state.q_IB, state.w_IB_B, state.covariance

    @staticmethod
    def diagnostics(state: IndoorSolverState) -> np.ndarray:
        return np.asarray(state.diagnostics, dtype=float)

    @staticmethod
    def to_vector(state: IndoorSolverState) -> np.ndarray:
        """``[q_IB (4), covariance (36), w_IB_B (3), t_solution, tracking, failures, held_s,
        diagnostics (6)]``."""
        return np.concatenate(
            [
                state.q_IB,
                np.ravel(state.covariance),
                state.w_IB_B,
                [state.t_solution, float(state.tracking), float(state.failures), state.held_s],
                state.diagnostics,
            ]
        )

    @staticmethod
    def from_vector(vector) -> IndoorSolverState:
        v = np.asarray(vector, dtype=float)
        return IndoorSolverState(
            v[:4].copy(),
            v[4:40].reshape(6, 6).copy(),
            v[40:43].copy(),
            t_solution=float(v[43]),
            tracking=bool(v[44] > 0.5),
            failures=int(v[45]),
            held_s=float(v[46]),
            diagnostics=v[47:53].copy(),
        )


@dataclass(frozen=True)
class IndoorMekfState:
    """:class:`IndoorStarTrackerMekf`'s state: the MEKF's and the solver's."""

    mekf: object
    solver: IndoorSolverState


class IndoorStarTrackerMekf:
    """Beyond the paper: the indoor star tracker fused with a table gyro in the MEKF
    (:class:`drake_att.filters.mekf.MultiplicativeEKF`), as a filter core.

    The gyro drives the MEKF's prediction between frames; each frame is solved by the
    :class:`IndoorStarTrackerSolver` with ``A0`` = the MEKF's prediction (the paper's "A0 from
    another sensor on the table") once a first solution exists (before it, or after
    ``max_lost_frames`` failures, the swarm search), and the solution enters the MEKF as a
    quaternion measurement with the solver's covariance. A frame the solver cannot solve is
    skipped (the gyro carries the attitude through it). Second quantity: the gyro bias.
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True
    is_random = True
    diagnostic_names = DIAGNOSTIC_NAMES

    def __init__(self, solver: IndoorStarTrackerSolver, mekf):
        self.solver, self.mekf = solver, mekf
        self.state_size = mekf.state_size + solver.state_size

    def initial_state(self, mekf_state, solver_state: IndoorSolverState) -> IndoorMekfState:
        return IndoorMekfState(mekf_state, replace(solver_state, tracking=self.solver.initialization == "given"))

    def predict(self, state: IndoorMekfState, w_meas_B, dt: float, rng=None) -> IndoorMekfState:
        return IndoorMekfState(self.mekf.predict(state.mekf, w_meas_B, dt), state.solver)

    def update(self, state: IndoorMekfState, measurement, rng=None) -> tuple[IndoorMekfState, UpdateInfo]:
        guess = self.mekf.estimate(state.mekf)[0] if state.solver.tracking else None
        solver_state, info = self.solver.update(state.solver, measurement, rng, guess_q_IB=guess)
        if not info.accepted:
            return IndoorMekfState(state.mekf, solver_state), info
        P = solver_state.covariance[:3, :3]
        mekf_state, info = self.mekf.update_quaternion(state.mekf, solver_state.q_IB, np.array([1.0, 0.0, 0.0, 0.0]), P)
        return IndoorMekfState(mekf_state, solver_state), info

    def reacquire(self, state: IndoorMekfState, info) -> IndoorMekfState:
        """The MEKF's covariance inflated after repeated gate rejections (its own rule)."""
        return IndoorMekfState(self.mekf.reacquire(state.mekf, info), state.solver)

    def ungated(self) -> IndoorStarTrackerMekf:
        """This core with its MEKF's gate off (the gate is the MEKF's)."""
        return IndoorStarTrackerMekf(self.solver, self.mekf.ungated())

    def estimate(self, state: IndoorMekfState):
        return self.mekf.estimate(state.mekf)

    def diagnostics(self, state: IndoorMekfState) -> np.ndarray:
        return self.solver.diagnostics(state.solver)

    def to_vector(self, state: IndoorMekfState) -> np.ndarray:
        return np.concatenate([self.mekf.to_vector(state.mekf), self.solver.to_vector(state.solver)])

    def from_vector(self, vector) -> IndoorMekfState:
        v = np.asarray(vector, dtype=float)
        n = self.mekf.state_size
        return IndoorMekfState(self.mekf.from_vector(v[:n]), self.solver.from_vector(v[n:]))


__all__ = [
    "IDENTIFICATIONS",
    "ATTITUDE_METHODS",
    "MIN_IDENTIFIED",
    "rpy_deg_to_R_BI",
    "R_BI_to_rpy_deg",
    "rotation_angle",
    "AngleMatcher",
    "triad",
    "triad_covariance",
    "svd_attitude",
    "IterationRecord",
    "Solution",
    "SwarmResult",
    "SwarmSettings",
    "particle_swarm_search",
    "IndoorSolverState",
    "DIAGNOSTIC_NAMES",
    "IndoorStarTrackerSolver",
    "IndoorMekfState",
    "IndoorStarTrackerMekf",
]
