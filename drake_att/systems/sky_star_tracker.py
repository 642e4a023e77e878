"""A star tracker that sees the sky: each frame rendered from the catalogue, centroided,
identified and solved (:mod:`drake_att.sky_tracker` does the work; this system is the Drake
wrapper).

Frame ``k`` is exposed around ``t_k = k T`` (mid-exposure). Its output is a direct function of the
truth at ``t_k`` (``q_IB``, and ``w_IB_B`` for the smear), of the frame's noise — a pure function
of (seed, system name, ``k``) — and of the tracker's memory of its earlier solutions, which its
periodic event writes at ``t_k`` from the very frame every consumer at ``t_k`` reads (all events
at an instant see the state from before it). So an estimator stepping at ``t_k`` reads frame
``k``, and frame ``k + 1`` is tracked from frame ``k``'s solution.

Input ports:
    q_IB (4): true attitude. w_IB_B (3, rad/s): true body rate (smear).
    seed_uniform (4, random uniform): seed.
    r_I, r_sun_I, r_moon_I (3 each, m, in I) (trackers with exclusion cones): the geometry.
Output ports:
    star_tracker_measurement (6): ``[t_frame (s), valid (1/0), q_IS_meas (4, wxyz)]``.
    covariance_S (9): the frame's attitude covariance (row-major 3x3, rad^2, sensor frame; the
        identity times 1 rad^2 for an invalid frame).
    frame_status (:data:`~drake_att.sky_tracker.FRAME_STATUS_NAMES`): what the frame saw and did.
    vector_observations (abstract :class:`~drake_att.contract.VectorObservations`) (trackers built
        with ``vector_observations``): the same frame
        as its identified stars' measured directions in S and catalogue directions in I, with the
        frame's RMS tangent sigma (no stars, invalid, when the frame is).
    exclusion (2) (trackers with cones): ``[t_frame, causes]`` (bit flags, :mod:`drake_att.exclusion`).
Discrete state: group 0 the seed words (4, read at initialization); group 1 the tracking memory
    (:class:`~drake_att.sky_tracker.TrackingMemory`, written by the periodic event).
Parameters: abstract parameter 0: the availability (``dropout_probability``, ``outage_windows_s``).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.contract import QUATERNION_MEASUREMENT_SIZE, VectorObservations, empty_vector_observations
from drake_att.exclusion import ExclusionCones, exclusion_causes, stray_light_factor
from drake_att.sky_tracker import FRAME_STATUS_NAMES, FrameResult, SkyTrackerModel, TrackingMemory
from drake_att.systems.randomness import SEED_WORDS, counter_random, declare_seed_port, read_seed_words
from drake_att.systems.value_cache import declare_value_cache
from drake_att.validation import check_availability, check_nonnegative


class SkyStarTracker(LeafSystem):
    """A star tracker whose frames come from the sky (see the module docstring).

    Args:
        name: system name (noise stream name).
        period_s: frame period (s) > 0.
        q_BS: mounting quaternion (4), body <- sensor.
        model: the :class:`~drake_att.sky_tracker.SkyTrackerModel` (camera, detector, catalogue,
            identification settings).
        dropout_probability: probability in [0, 1) that a frame is lost (not taken).
        outage_windows_s: ``[(start, end), ...]`` (s) with no frame.
        exclusion: Sun / Earth-limb / Moon cones (None: none).
        stray_light_e_per_px_per_s: stray light at a cone's edge (e-/s per pixel), falling off
            outside it (:func:`~drake_att.exclusion.stray_light_factor`); trackers with cones.
        vector_observations: declare the ``vector_observations`` output (the frames then carry
            their identified stars).
    """

    def __init__(
        self,
        name: str,
        period_s: float,
        q_BS,
        model: SkyTrackerModel,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
        exclusion: ExclusionCones | None = None,
        stray_light_e_per_px_per_s: float = 0.0,
        vector_observations: bool = False,
    ):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not (isinstance(period_s, (int, float)) and math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        q_BS = np.asarray(q_BS, dtype=float)
        if q_BS.shape != (4,) or not np.all(np.isfinite(q_BS)) or np.linalg.norm(q_BS) < 1e-9:
            raise ValueError(f"{name}.q_BS: got {q_BS.tolist()}; must be 4 finite numbers, not all zero")
        self.period_s = float(period_s)
        self.q_BS = rot.quat_normalize(q_BS)
        self.R_SB = rot.quat_to_rotmat(self.q_BS).T
        self.model = model
        self.exclusion = None if exclusion is None else exclusion.check(f"{name}.exclusion")
        self.stray_light_e_per_px_per_s = check_nonnegative(
            f"{name}.stray_light_e_per_px_per_s", stray_light_e_per_px_per_s
        )
        self._availability_index = self.DeclareAbstractParameter(
            AbstractValue.Make(check_availability(name, dropout_probability, outage_windows_s))
        )
        self._q_port = self.DeclareVectorInputPort("q_IB", 4)
        self._w_port = self.DeclareVectorInputPort("w_IB_B", 3)
        self._seed_port = declare_seed_port(self)
        self._seed_group = self.DeclareDiscreteState(np.zeros(SEED_WORDS))  # type: ignore[arg-type]  # pydrake stub
        self._memory_group = self.DeclareDiscreteState(TrackingMemory.empty().to_vector())  # type: ignore[arg-type]
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._remember)
        deps = {self.time_ticket(), self.xd_ticket(), self.all_input_ports_ticket(), self.all_parameters_ticket()}
        if self.exclusion is not None:
            self._geometry_ports = tuple(self.DeclareVectorInputPort(p, 3) for p in ("r_I", "r_sun_I", "r_moon_I"))
            self.DeclareVectorOutputPort("exclusion", 2, self._calc_exclusion, deps)
        self._frame = declare_value_cache(self, "frame", self._compute_frame, deps)
        self.DeclareVectorOutputPort(
            "star_tracker_measurement", QUATERNION_MEASUREMENT_SIZE, self._calc_measurement, deps
        )
        self.DeclareVectorOutputPort("covariance_S", 9, self._calc_covariance, deps)
        self.DeclareVectorOutputPort("frame_status", len(FRAME_STATUS_NAMES), self._calc_status, deps)
        self.vector_observations = bool(vector_observations)
        if self.vector_observations:
            self.DeclareAbstractOutputPort(
                "vector_observations", lambda: AbstractValue.Make(empty_vector_observations()), self._calc_vectors, deps
            )

    # -- parameters -----------------------------------------------------------------
    def availability(self, context) -> tuple:
        """``(dropout_probability, outage windows)`` in ``context`` (this system's)."""
        return context.get_abstract_parameter(self._availability_index).get_value()

    def set_availability(self, context, dropout_probability: float = 0.0, outage_windows_s=()) -> None:
        """Give ``context`` (this system's) another drop-out probability / outage windows."""
        value = check_availability(self.get_name(), dropout_probability, outage_windows_s)
        context.get_mutable_abstract_parameter(self._availability_index).set_value(value)

    # -- events ---------------------------------------------------------------------
    def _initialize(self, context, discrete_state):
        discrete_state.set_value(self._seed_group, read_seed_words(self, context, self._seed_port))
        return EventStatus.Succeeded()

    def _remember(self, context, discrete_state):
        """Frame ``k``'s solution becomes the tracking memory for frame ``k + 1``."""
        frame = self._frame(context)
        memory = TrackingMemory.from_vector(context.get_discrete_state(self._memory_group).value())
        discrete_state.set_value(self._memory_group, memory.after(frame).to_vector())
        return EventStatus.Succeeded()

    # -- the frame --------------------------------------------------------------------
    def frame_index(self, t: float) -> int:
        """The index ``k = max(0, ceil(t / T - 1e-9))`` of the frame an output at ``t`` carries."""
        return max(0, math.ceil(t / self.period_s - 1e-9))

    def _geometry(self, context):
        """``(boresight_I, r_I, r_sun_I, r_moon_I)`` as 3-lists (trackers with cones)."""
        r, r_sun, r_moon = (p.Eval(context).tolist() for p in self._geometry_ports)
        boresight = rot.quat_to_rotmat(rot.quat_multiply(self._q_port.Eval(context), self.q_BS))[:, 2]
        return boresight.tolist(), r, r_sun, r_moon

    def _causes(self, context) -> int:
        if self.exclusion is None:
            return 0
        b, r, r_sun, r_moon = self._geometry(context)
        return int(exclusion_causes(b, r, r_sun, r_moon, self.exclusion))

    def _stray_light(self, context) -> float:
        """Stray light on the detector (e-/s per pixel): ``stray_light_e_per_px_per_s`` times
        :func:`~drake_att.exclusion.stray_light_factor` (trackers with cones; else none)."""
        if self.exclusion is None or self.stray_light_e_per_px_per_s == 0.0:
            return 0.0
        b, r, r_sun, r_moon = self._geometry(context)
        return self.stray_light_e_per_px_per_s * stray_light_factor(b, r, r_sun, r_moon, self.exclusion)

    def _compute_frame(self, context) -> FrameResult:
        k = self.frame_index(context.get_time())
        t_k = k * self.period_s
        words = context.get_discrete_state(self._seed_group).value()
        rng = counter_random(words, self.get_name()).generator(k)
        dropout, windows = self.availability(context)
        taken = rng.random() >= dropout and not any(a <= t_k < b for a, b in windows)
        causes = self._causes(context)
        q_IB = np.asarray(self._q_port.Eval(context), dtype=float)
        w_IB_B = np.asarray(self._w_port.Eval(context), dtype=float)
        if not (taken and causes == 0):
            return FrameResult.not_taken(t_k)
        memory = TrackingMemory.from_vector(context.get_discrete_state(self._memory_group).value())
        q_IS = rot.quat_multiply(q_IB, self.q_BS)
        return self.model.frame(
            t_k, q_IS, self.R_SB @ w_IB_B, memory, rng, self._stray_light(context), self.vector_observations
        )

    # -- outputs ----------------------------------------------------------------------
    def _calc_measurement(self, context, output: BasicVector):
        f = self._frame(context)
        output.SetFromVector(np.array([f.time_s, 1.0 if f.valid else 0.0, *f.q_IS_meas]))  # type: ignore[arg-type]

    def _calc_covariance(self, context, output: BasicVector):
        output.SetFromVector(np.asarray(self._frame(context).covariance_S, dtype=float).ravel())  # type: ignore[arg-type]

    def _calc_status(self, context, output: BasicVector):
        output.SetFromVector(self._frame(context).status_vector())

    def _calc_vectors(self, context, output):
        f = self._frame(context)
        output.set_value(
            VectorObservations(f.time_s, f.valid, f.directions_S, f.references_I, f.vector_sigma_rad, self.q_BS)
        )

    def _calc_exclusion(self, context, output: BasicVector):
        t_k = self.frame_index(context.get_time()) * self.period_s
        output.SetFromVector(np.array([t_k, float(self._causes(context))]))  # type: ignore[arg-type]


__all__ = ["SkyStarTracker"]
