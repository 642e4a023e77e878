"""Star tracker: attitude-quaternion output or unit-vector observations.

Sensor frame S is mounted on the body by ``R_BS`` (``q_BS``); the boresight is ``+z_S``.

* Quaternion mode: ``q_IS_meas = q_IB ⊗ q_BS ⊗ exp(delta_S)`` with
  ``delta_S ~ N(0, diag(s_c^2, s_c^2, s_b^2))`` - anisotropic noise, cross-boresight
  sigma ``s_c`` about x_S and y_S, boresight (roll) sigma ``s_b`` about z_S.
* Vector mode: observations of inertial reference directions ``r_i``:
  ``b_i = R_SI r_i + v_i`` with ``v_i ~ N(0, s^2 I3)`` (the additive model of papers S0
  and S4; not re-normalized, so the filter's measurement model is exact).

Every output carries its sample time and a validity flag.  A sample is invalid during a
configured outage window or, with the configured probability, at random (drop-outs), and,
with ``exclusion`` cones, when the Sun, the Earth's limb or the Moon is inside one
(:mod:`drake_att.exclusion`; then the input ports ``r_I``, ``r_sun_I`` and ``r_moon_I`` (m, in I)
give the geometry and the output port ``exclusion`` ``[t_sample, causes]`` says why, as bit flags).
With cones, a vector-mode sample also drops the reference stars the Earth and its atmosphere hide
(:func:`~drake_att.exclusion.star_occulted`): its number of directions varies, and a sample with
none left is invalid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.contract import QUATERNION_MEASUREMENT_SIZE, VectorObservations
from drake_att.exclusion import ExclusionCones, exclusion_causes, star_occulted
from drake_att.noise import CounterRandom
from drake_att.systems.randomness import (
    SEED_WORDS,
    NoiseCache,
    counter_random,
    declare_seed_port,
    read_seed_words,
)
from drake_att.systems.value_cache import declare_value_cache
from drake_att.validation import check_availability, check_nonnegative


def mounting_from_paper_s3_angles(psi_rad: float, phi_rad: float, theta_rad: float) -> np.ndarray:
    """``q_BS`` from paper S3's three mounting angles (its eq. 7).

    Eq. 7 gives a quaternion ``q7``; read as the attitude of the sensor relative to the
    body in the attitude-matrix sense, ``R(q7)`` maps body-frame vectors into the sensor
    frame: ``R_SB = R(q7)``, so ``q_BS = q7^-1``.  This is the reading under which the
    paper's two trackers, ``(-90, 45, -90)`` and ``(90, 45, 90)`` deg, have perpendicular
    boresights in the body x-y plane at +-45 deg from +y (tested).
    """
    c = lambda a: np.cos(0.5 * a)  # noqa: E731
    s = lambda a: np.sin(0.5 * a)  # noqa: E731
    th, ph, ps = theta_rad, phi_rad, psi_rad
    q7 = np.array(
        [
            c(th) * c(ph) * c(ps) - s(th) * s(ph) * s(ps),
            c(th) * s(ph) * c(ps) - s(th) * c(ph) * s(ps),
            s(th) * c(ph) * c(ps) + c(th) * s(ph) * s(ps),
            s(th) * s(ph) * c(ps) + c(th) * c(ph) * s(ps),
        ]
    )
    return rot.quat_conjugate(q7)


@dataclass(frozen=True)
class StarTrackerNoise:
    """A star tracker's noise and availability (its abstract parameter: any level per run).

    Attributes:
        sigmas_S: quaternion-mode rotation-vector sigmas ``[s_c, s_c, s_b]`` (rad).
        sigma_vector: vector-mode per-component sigma (rad).
        dropout_probability: in [0, 1). outage_windows_s: ``((start, end), ...)`` (s).
    """

    sigmas_S: np.ndarray
    sigma_vector: float
    dropout_probability: float
    outage_windows_s: tuple

    @classmethod
    def make(
        cls,
        name: str,
        sigma_cross_boresight_rad: float = 0.0,
        sigma_boresight_rad: float = 0.0,
        sigma_vector_rad: float = 0.0,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
    ) -> StarTrackerNoise:
        """Check the arguments of :class:`StarTracker` (ValueError naming the field)."""
        for field, v in (
            ("sigma_cross_boresight", sigma_cross_boresight_rad),
            ("sigma_boresight", sigma_boresight_rad),
            ("sigma_vector", sigma_vector_rad),
        ):
            check_nonnegative(f"{name}.{field}", v)
        dropout_probability, windows = check_availability(name, dropout_probability, outage_windows_s)
        return cls(
            np.array([sigma_cross_boresight_rad, sigma_cross_boresight_rad, sigma_boresight_rad]),
            float(sigma_vector_rad),
            float(dropout_probability),
            windows,
        )


class StarTracker(LeafSystem):
    """Star tracker with quaternion or vector output.

    Args:
        name: system name (noise stream name).
        period_s: sample period (s) > 0.
        q_BS: mounting quaternion (4), body <- sensor.
        mode: "quaternion" or "vectors".
        sigma_cross_boresight_rad, sigma_boresight_rad: quaternion-mode noise (rad) >= 0.
        references_I: (m, 3) inertial unit reference directions (vector mode).
        sigma_vector_rad: vector-mode per-component noise (rad) >= 0.
        dropout_probability: probability in [0, 1) that a sample is invalid.
        outage_windows_s: list of (start, end) times (s) with no valid sample.
        realizations: N independent trackers on the same truth (a batch of Monte Carlo runs in
            one diagram; quaternion mode without exclusion): ``seed_uniform`` and
            ``star_tracker_measurement`` carry N blocks, realization-major; realization ``i`` is
            drawn from the ``i``-th seed words exactly as a tracker alone would be.

    Input ports:
        q_IB (4): true attitude.
        seed_uniform (4, random uniform): seed.
        vector_noise (3m, vector mode, optional): the sample's additive noise (rad), replacing the
            tracker's own draw (a correlated-noise source, paper S1); unconnected: own noise.
    Parameters: abstract parameter 0: the :class:`StarTrackerNoise` (:meth:`set_noise`).
    Output ports (quaternion mode):
        star_tracker_measurement (6): ``[t_meas (s), valid (1/0), q_IS_meas (4, wxyz)]``.
    Output ports (vector mode):
        vector_observations (abstract :class:`VectorObservations`).
    Discrete state: the seed words (4, read at initialization); no per-sample event. Sample ``k`` is at ``t_k = k T``; an output evaluated at a time
        ``t`` in ``(t_(k-1), t_k]`` carries sample ``k`` (stamp ``t_k``, its validity and noise:
        ``q_BS ⊗ exp(delta_S)`` in quaternion mode, the ``3m`` vector errors in vector mode),
        drawn as a pure function of (seed, system name, ``k``) — the same numbers whenever and
        however often it is evaluated, and no Python call per sample unless an output is read.
    """

    def __init__(
        self,
        name: str,
        period_s: float,
        q_BS=(1.0, 0.0, 0.0, 0.0),
        mode: str = "quaternion",
        sigma_cross_boresight_rad: float = 0.0,
        sigma_boresight_rad: float = 0.0,
        references_I=None,
        sigma_vector_rad: float = 0.0,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
        exclusion: ExclusionCones | None = None,
        realizations: int = 1,
    ):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not (isinstance(realizations, int) and realizations >= 1):
            raise ValueError(f"{name}.realizations: got {realizations!r}; must be an integer >= 1")
        if realizations > 1 and (mode != "quaternion" or exclusion is not None):
            raise ValueError(
                f"{name}.realizations: got {realizations}; more than one needs mode 'quaternion' without exclusion"
            )
        self.realizations = N = realizations
        if not np.isfinite(period_s) or period_s <= 0:
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        if mode not in ("quaternion", "vectors"):
            raise ValueError(f"{name}.mode: got {mode!r}; allowed: 'quaternion', 'vectors'")
        self.default_noise = StarTrackerNoise.make(
            name,
            sigma_cross_boresight_rad,
            sigma_boresight_rad,
            sigma_vector_rad,
            dropout_probability,
            outage_windows_s,
        )
        q_BS = np.asarray(q_BS, dtype=float)
        if q_BS.shape != (4,) or not np.all(np.isfinite(q_BS)) or np.linalg.norm(q_BS) < 1e-9:
            raise ValueError(f"{name}.q_BS: got {q_BS.tolist()}; must be 4 finite numbers, not all zero")
        self.period_s = float(period_s)
        self.q_BS = rot.quat_normalize(q_BS)
        self.mode = mode
        if mode == "vectors":
            refs = np.asarray(references_I, dtype=float) if references_I is not None else np.zeros((0, 3))
            if refs.ndim != 2 or refs.shape[1] != 3 or refs.shape[0] < 1 or not np.all(np.isfinite(refs)):
                raise ValueError(f"{name}.references_I: got {references_I!r}; need (m>=1, 3) finite directions")
            norms = np.linalg.norm(refs, axis=1)
            if np.any(norms < 1e-9):
                raise ValueError(f"{name}.references_I: zero-length direction in {refs.tolist()}")
            self.references_I = refs / norms[:, None]
            n_noise = 3 * self.references_I.shape[0]
        else:
            self.references_I = None
            n_noise = 4
        self._n_noise = n_noise
        self._noise_index = self.DeclareAbstractParameter(AbstractValue.Make(self.default_noise))
        self._q_port = self.DeclareVectorInputPort("q_IB", 4)
        self._seed_port = declare_seed_port(self, N)
        # Vector mode, optional: the additive noise of this sample (3m) from a correlated-noise
        # source (paper S1, drake_att.systems.correlated_noise), used instead of the tracker's own.
        self._noise_port = self.DeclareVectorInputPort("vector_noise", n_noise) if mode == "vectors" else None
        # No per-sample event: sample k (time k T) is a pure function of (seed, name, k), drawn
        # when an output at a time in ((k-1) T, k T] is evaluated (one Python call per
        # evaluation instead of a per-sample event plus the evaluation). The state holds only
        # the seed words, read once at initialization (the seed port's value changes after t = 0).
        self.DeclareDiscreteState(np.zeros(SEED_WORDS * N))  # type: ignore[arg-type]  # pydrake stub
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        # The context's samples (a _TrackerSamples per realization, of its seed words and the
        # noise parameter, in a _TrackerBatch): one cache look-up per output evaluation.
        self._samples_cache = NoiseCache(
            self,
            "samples",
            self.noise,
            lambda words, noise: _TrackerBatch(
                tuple(_TrackerSamples(self, w, noise) for w in np.reshape(words, (N, SEED_WORDS)))
            ),
        )
        deps = {self.time_ticket(), self.xd_ticket(), self.all_input_ports_ticket(), self.all_parameters_ticket()}
        self.exclusion = None if exclusion is None else exclusion.check(f"{name}.exclusion")
        if self.exclusion is not None:
            self._geometry_ports = tuple(self.DeclareVectorInputPort(p, 3) for p in ("r_I", "r_sun_I", "r_moon_I"))
            self._causes = declare_value_cache(
                self, "causes", self._compute_causes, {self.time_ticket(), self.all_input_ports_ticket()}
            )
            self.DeclareVectorOutputPort("exclusion", 2, self._calc_exclusion, deps)
        if mode == "quaternion":
            self.DeclareVectorOutputPort(
                "star_tracker_measurement", QUATERNION_MEASUREMENT_SIZE * N, self._calc_quaternion, deps
            )
        else:
            self.DeclareAbstractOutputPort(
                "vector_observations", lambda: AbstractValue.Make(self._empty_observations()), self._calc_vectors, deps
            )

    def _empty_observations(self):
        return VectorObservations(0.0, False, np.zeros((0, 3)), np.zeros((0, 3)), 0.0, self.q_BS)

    # -- parameters -----------------------------------------------------------------
    def noise(self, context) -> StarTrackerNoise:
        """The :class:`StarTrackerNoise` in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._noise_index).get_value()

    def set_noise(
        self,
        context,
        sigma_cross_boresight_rad: float = 0.0,
        sigma_boresight_rad: float = 0.0,
        sigma_vector_rad: float = 0.0,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
    ) -> None:
        """Give ``context`` (this system's) other noise levels / availability (arguments as
        the constructor's); outputs evaluated afterwards use them."""
        noise = StarTrackerNoise.make(
            self.get_name(),
            sigma_cross_boresight_rad,
            sigma_boresight_rad,
            sigma_vector_rad,
            dropout_probability,
            outage_windows_s,
        )
        context.get_mutable_abstract_parameter(self._noise_index).set_value(noise)

    # -- noise ----------------------------------------------------------------------
    def _initialize(self, context, discrete_state):
        discrete_state.set_value(read_seed_words(self, context, self._seed_port))
        return EventStatus.Succeeded()

    def _samples(self, context) -> _TrackerSamples:
        """The samples of this context's seed words and noise parameter (cached; the first
        realization's)."""
        return self._samples_cache.get(context).realizations[0]

    def _sample_index(self, t: float) -> int:
        """The index ``k = max(0, ceil(t / T - 1e-9))`` of the sample an output at ``t``
        carries (``t`` on a sample instant, to round-off: that instant's)."""
        return max(0, math.ceil(t / self.period_s - 1e-9))

    def _sample(self, context):
        """``(t_sample, valid, draw, noise parameter)`` of the sample an output at this time
        carries: the pending one, index ``k = ceil(t / T)`` (``t`` on a sample instant: that
        instant's), stamped ``t_k = t_(k-1) + T`` (accumulated, as a sampling clock counts; 0 for
        ``k = 0``)."""
        samples = self._samples(context)
        block, r = divmod(self._sample_index(context.get_time()), CounterRandom.BLOCK)
        stamps, valid, draws = samples.block(block)
        return stamps[r], valid[r], draws[r], samples.noise

    # -- exclusion --------------------------------------------------------------------
    def causes(self, context) -> int:
        """The exclusion causes (bit flags, :mod:`drake_att.exclusion`) at this context's time:
        the boresight ``R_IB R_BS z`` against the Sun, the Earth's limb and the Moon (0 without cones)."""
        if self.exclusion is None:
            return 0
        return self._causes(context)

    def _compute_causes(self, context) -> int:
        r, r_sun, r_moon = (p.Eval(context) for p in self._geometry_ports)
        boresight = rot.quat_to_rotmat(rot.quat_multiply(self._q_port.Eval(context), self.q_BS))[:, 2]
        return int(exclusion_causes(boresight, r, r_sun, r_moon, self.exclusion))  # type: ignore[arg-type]  # set

    def _calc_exclusion(self, context, output: BasicVector):
        t_sample = self._sample(context)[0]
        output.SetFromVector(np.array([t_sample, float(self.causes(context))]))  # type: ignore[arg-type]

    # -- outputs ----------------------------------------------------------------------
    def _calc_quaternion(self, context, output: BasicVector):
        if self.realizations > 1:
            self._calc_quaternions(context, output)
            return
        t_sample, valid, noise, _ = self._sample(context)
        if valid and self.exclusion is not None:
            valid = self.causes(context) == 0
        q_IB = self._q_port.Eval(context).tolist()  # type: ignore[attr-defined]  # pydrake stub
        q_meas = _canonical_product(q_IB, noise)
        sample = np.array([t_sample, 1.0 if valid else 0.0, *q_meas])
        output.SetFromVector(sample)  # type: ignore[arg-type]  # pydrake stub

    def _calc_quaternions(self, context, output: BasicVector):
        """:meth:`_calc_quaternion` of every realization (no exclusion), realization-major."""
        block, r = divmod(self._sample_index(context.get_time()), CounterRandom.BLOCK)
        q_IB = self._q_port.Eval(context).tolist()  # type: ignore[attr-defined]  # pydrake stub
        values = []
        for stamps, valid, draws in self._samples_cache.get(context).blocks(block):
            values += [stamps[r], 1.0 if valid[r] else 0.0, *_canonical_product(q_IB, draws[r])]
        output.SetFromVector(np.array(values))  # type: ignore[arg-type]  # pydrake stub

    def _calc_vectors(self, context, output):
        t_sample, valid, noise, p = self._sample(context)
        if valid and self.exclusion is not None:
            valid = self.causes(context) == 0
        q_IS = rot.quat_multiply(self._q_port.Eval(context), self.q_BS)
        R_SI = rot.quat_to_rotmat(q_IS).T
        if self._noise_port.HasValue(context):
            noise = self._noise_port.Eval(context)
        dirs = self.references_I @ R_SI.T + np.reshape(noise, (-1, 3))
        refs = self.references_I
        if self.exclusion is not None:
            seen = ~star_occulted(refs, self._geometry_ports[0].Eval(context), self.exclusion.atmosphere_height_m)
            if not seen.all():
                dirs, refs = dirs[seen], refs[seen]
                valid = valid and bool(seen.any())
        output.set_value(VectorObservations(float(t_sample), bool(valid), dirs, refs, p.sigma_vector, self.q_BS))


def _canonical_product(p, q) -> tuple:
    """``rot.quat_canonical(rot.quat_multiply(p, q))`` for two 4-sequences of Python floats
    (wxyz), the same operations in the same order as ``quat_multiply``'s scalar path, so the
    same bits, without building numpy arrays."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    w = pw * qw - px * qx - py * qy - pz * qz
    x = pw * qx + px * qw + py * qz - pz * qy
    y = pw * qy - px * qz + py * qw + pz * qx
    z = pw * qz + px * qy - py * qx + pz * qw
    return (-w, -x, -y, -z) if w < 0.0 else (w, x, y, z)


class _TrackerBatch:
    """The :class:`_TrackerSamples` of each realization, and the last block's rows of all of
    them (one look-up per output evaluation instead of one per realization). Immutable in
    effect (a memo), so a cloned context shares it."""

    def __init__(self, realizations: tuple):
        self.realizations = realizations
        self._last: tuple = (-1, [])

    def __deepcopy__(self, memo):
        return self

    def blocks(self, block: int) -> list:
        """``[samples.block(block) for each realization]``."""
        if self._last[0] != block:
            self._last = (block, [samples.block(block) for samples in self.realizations])
        return self._last[1]


class _TrackerSamples:
    """The samples of one tracker for one (seed words, :class:`StarTrackerNoise`): stamps,
    validity and draws by blocks of ``CounterRandom.BLOCK`` samples, a pure function of
    (seed words, the tracker's name, sample index) computed for a whole block at once and
    kept for the last few blocks.  Immutable in effect (a memo), so a cloned context shares
    it (``__deepcopy__``)."""

    def __init__(self, tracker: StarTracker, words, noise: StarTrackerNoise):
        self.noise = noise
        self._cr = counter_random(words, tracker.get_name())
        self._period_s = tracker.period_s
        self._q_BS = tracker.q_BS
        self._quaternion = tracker.mode == "quaternion"
        self._n_noise = tracker._n_noise
        self._blocks: dict = {}

    def __deepcopy__(self, memo):
        return self

    def block(self, block: int):
        """``(stamps, valid, draws)`` of samples ``block * BLOCK ...`` (``BLOCK`` of each;
        row ``r`` is sample ``k = block * BLOCK + r``): ``stamps[r] = t_k = t_(k-1) + T``
        (0 for ``k = 0``, s) and ``valid[r]`` (bool) as lists; ``draws[r]`` the noise:
        quaternion mode ``q_BS ⊗ exp(sigmas_S * normals(k, 3))`` as a list of 4 floats (the
        noise stored as one quaternion, so the output is one product), vector mode the row
        ``sigma_vector * normals(k, 3m)`` of an array.  Sample ``k`` is valid if
        ``uniforms(k, 1) >= dropout_probability`` and ``t_k`` is in no outage window."""
        hit = self._blocks.get(block)
        if hit is not None:
            return hit
        p, cr, n = self.noise, self._cr, CounterRandom.BLOCK
        if self._quaternion:
            phi = p.sigmas_S * cr.normals_block(block, 3)
            x, y, z = phi[:, 0], phi[:, 1], phi[:, 2]
            a = np.sqrt(x * x + y * y + z * z)  # rot.rotvec_to_quat's scalar formula, per row
            with np.errstate(invalid="ignore", divide="ignore"):
                k = np.where(a < rot._SMALL_ANGLE, 0.5 - a * a / 48.0, np.sin(0.5 * a) / a)
            dq = np.stack([np.cos(0.5 * a), k * x, k * y, k * z], axis=-1)
            draws = rot.quat_multiply(np.broadcast_to(self._q_BS, dq.shape), dq).tolist()
        else:
            draws = p.sigma_vector * cr.normals_block(block, self._n_noise)
        index = np.arange(block * n, (block + 1) * n)
        stamps = np.where(index > 0, (index - 1) * self._period_s + self._period_s, 0.0)
        valid = cr.uniforms_block(block, 1)[:, 0] >= p.dropout_probability
        for a, b in p.outage_windows_s:
            valid &= ~((a <= stamps) & (stamps < b))
        if len(self._blocks) > 8:
            self._blocks.clear()
        hit = self._blocks[block] = (stamps.tolist(), valid.tolist(), draws)
        return hit
