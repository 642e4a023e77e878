"""Coarse attitude sensors: a sun sensor and a three-axis magnetometer.

Both deliver one unit-vector observation per sample (:class:`~drake_att.contract.VectorObservations`
with ``m = 1``), so any vector-observation filter reads them like a vector-mode star tracker.
Sample ``k`` is at ``t_k = k T``; as for :class:`~drake_att.systems.star_tracker.StarTracker`, an
output evaluated at a time in ``(t_(k-1), t_k]`` carries sample ``k`` (stamp ``t_k``), its noise and
availability drawn as a pure function of (seed, system name, ``k``) (no per-sample event), and the
truth read at the evaluation time (the estimator reads it at ``t_k``).

**Sun sensor** (:class:`SunSensor`): one two-axis cosine-detector head (photodiodes behind a mask,
the usual CubeSat coarse sun sensor), boresight ``+z_S``, field of view a cone of half-angle
``fov_half_angle`` (default 60 deg, ours). The measured direction is the true Sun direction seen
from the spacecraft, ``s_S = R_SI unit(r_sun_I - r_I)``, plus a tangent-plane error of per-axis
standard deviation ``sigma(theta) = sigma_boresight / cos(theta)`` (``theta`` the Sun's angle from the
boresight): a cosine detector's signal falls as ``cos(theta)`` while its noise does not, so the angle
error grows as ``1 / cos(theta)`` (a model of ours, the shape of the published photodiode error
curves). The measured direction is re-normalized. The observation's ``sigma_rad`` is
``sigma_boresight / cos(theta_measured)`` (what the sensor itself can compute).

A sample is invalid (its cause logged on ``sun_sensor_status`` as bit flags) when

* :data:`ECLIPSE`: less than ``min_sun_fraction`` (default 0.5) of the solar disk is visible
  (:func:`drake_att.ephemeris.shadow_fraction`, conical shadow with penumbra). With 0.5 the
  transitions fall at the middle of the penumbra, where the Sun's centre crosses the Earth's limb: the
  cylindrical shadow's boundary to within the Sun's parallax (< 0.1 s in LEO);
* :data:`OUT_OF_FOV`: the Sun is more than ``fov_half_angle`` from the boresight;
* a configured drop-out (probability per sample) or outage window (no cause bit).

**Albedo** (``albedo``, default 0): the Earth's reflected sunlight reaches the detectors as a second,
unmodelled source. Approximation (ours): the Earth seen as a point source at nadir whose irradiance,
relative to the Sun's, is ``albedo * (R_E / |r|)^2 * max(0, r_hat . s_hat)`` - the view factor of a
sphere from a plate facing it times the illumination of the sub-satellite point. The head adds it to
the Sun's light, ``s_S + e_S`` with ``e_S`` along the nadir direction, re-normalized, only while the
Earth's disk overlaps the field of view (nadir within ``fov_half_angle`` plus the Earth's angular
radius of the boresight). The reference stays the true Sun direction: albedo is a bias the filters do
not model.

**Magnetometer** (:class:`Magnetometer`): ``B_S = (I + S + M) R_SI B_I + bias_S + n``, ``n ~ N(0,
sigma^2 I3)``, with ``B_I`` the IGRF field at the true position (input port, from
:class:`~drake_att.systems.environment.MagneticFieldSource`), ``S`` the per-axis scale-factor errors
and ``M`` the axis misalignment (zero diagonal) of the sensor's own axes. The observation is the
direction ``B_S / |B_S|`` with reference ``B_I / |B_I|`` and ``sigma_rad = sigma / |B_S|``: the
linearization of the normalization, exact to first order in ``sigma / |B|`` (100 nT in a 20-60 uT
field: 2-5 mrad). The bias, scale factor and misalignment are not modelled by the filters; they bias the
direction.

Units: SI (rad, m, tesla) inside; the magnetometer's logged ``magnetic_field`` port is in nT, the
sensor's native unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.contract import VectorObservations
from drake_att.ephemeris import shadow_fraction
from drake_att.noise import CounterRandom
from drake_att.orbit import EARTH_RADIUS_M
from drake_att.systems.randomness import SEED_WORDS, NoiseCache, counter_random, declare_seed_port, read_seed_words
from drake_att.systems.value_cache import declare_value_cache
from drake_att.validation import check_availability

ECLIPSE = 1
"""Sun-sensor cause bit: less than ``min_sun_fraction`` of the solar disk visible."""
OUT_OF_FOV = 2
"""Sun-sensor cause bit: the Sun outside the field of view."""

DEFAULT_FOV_HALF_ANGLE_RAD = math.radians(60.0)
DEFAULT_MIN_SUN_FRACTION = 0.5
TESLA_PER_NANOTESLA = 1e-9


def _nonnegative(name: str, value: float) -> float:
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{name}: got {value}; must be finite and >= 0")
    return float(value)


@dataclass(frozen=True)
class SunSensorNoise:
    """A sun sensor's noise, albedo and availability (its abstract parameter).

    Attributes:
        sigma_boresight_rad: per-axis direction noise on the boresight (rad).
        albedo: the Earth's albedo seen by the head, in [0, 1] (0: none).
        dropout_probability: in [0, 1). outage_windows_s: ``((start, end), ...)`` (s).
    """

    sigma_boresight_rad: float
    albedo: float = 0.0
    dropout_probability: float = 0.0
    outage_windows_s: tuple = ()

    @classmethod
    def make(cls, name, sigma_boresight_rad, albedo=0.0, dropout_probability=0.0, outage_windows_s=()):
        """Checked (ValueError naming the field)."""
        sigma = _nonnegative(f"{name}.sigma_boresight", sigma_boresight_rad)
        if not (math.isfinite(albedo) and 0.0 <= albedo <= 1.0):
            raise ValueError(f"{name}.albedo: got {albedo}; must be in [0, 1]")
        return cls(sigma, float(albedo), *check_availability(name, dropout_probability, outage_windows_s))


@dataclass(frozen=True)
class MagnetometerNoise:
    """A magnetometer's noise and errors (its abstract parameter), SI.

    Attributes:
        sigma_T: per-axis white noise (T). bias_S_T: constant bias in S (3, T).
        sensor_matrix: ``I + S + M`` (3, 3): scale factors and misalignment of the sensor's axes.
        dropout_probability: in [0, 1). outage_windows_s: ``((start, end), ...)`` (s).
    """

    sigma_T: float
    bias_S_T: np.ndarray
    sensor_matrix: np.ndarray
    dropout_probability: float = 0.0
    outage_windows_s: tuple = ()

    @classmethod
    def make(
        cls,
        name,
        sigma_T,
        bias_S_T=(0.0, 0.0, 0.0),
        scale_factor_error=(0.0, 0.0, 0.0),
        misalignment=None,
        dropout_probability=0.0,
        outage_windows_s=(),
    ):
        """Checked (ValueError naming the field); ``misalignment`` (3, 3) with zero diagonal (rad)."""
        sigma = _nonnegative(f"{name}.sigma", sigma_T)
        bias = np.asarray(bias_S_T, dtype=float)
        sf = np.asarray(scale_factor_error, dtype=float)
        M = np.zeros((3, 3)) if misalignment is None else np.asarray(misalignment, dtype=float)
        for field, v, shape in (("bias", bias, (3,)), ("scale_factor_error", sf, (3,)), ("misalignment", M, (3, 3))):
            if v.shape != shape or not np.all(np.isfinite(v)):
                raise ValueError(f"{name}.{field}: got {v.tolist()}; must be finite with shape {shape}")
        if np.any(np.diag(M) != 0.0):
            raise ValueError(f"{name}.misalignment: got {M.tolist()}; the diagonal must be zero (scale factors apart)")
        return cls(
            sigma, bias, np.eye(3) + np.diag(sf) + M, *check_availability(name, dropout_probability, outage_windows_s)
        )


class _Samples:
    """Stamps, validity (drop-outs, outages) and standard normals of one sensor's samples for one
    (seed words, noise parameter), by blocks of ``CounterRandom.BLOCK`` samples: a pure function of
    (seed words, the sensor's name, sample index). Immutable in effect (a memo): a cloned context
    shares it."""

    def __init__(self, sensor: _CoarseSensor, words, noise):
        self.noise = noise
        self._cr = counter_random(words, sensor.get_name())
        self._period_s = sensor.period_s
        self._width = sensor.noise_width
        self._blocks: dict = {}

    def __deepcopy__(self, memo):
        return self

    def sample(self, k: int):
        """``(t_k, valid, normals (width,))`` of sample ``k``: ``t_k = t_(k-1) + T`` (0 for k = 0);
        valid if ``uniforms(k, 1) >= dropout_probability`` and ``t_k`` is in no outage window."""
        block, r = divmod(k, CounterRandom.BLOCK)
        hit = self._blocks.get(block)
        if hit is None:
            n = CounterRandom.BLOCK
            index = np.arange(block * n, (block + 1) * n)
            stamps = np.where(index > 0, (index - 1) * self._period_s + self._period_s, 0.0)
            valid = self._cr.uniforms_block(block, 1)[:, 0] >= self.noise.dropout_probability
            for a, b in self.noise.outage_windows_s:
                valid &= ~((a <= stamps) & (stamps < b))
            if len(self._blocks) > 8:
                self._blocks.clear()
            hit = self._blocks[block] = (stamps, valid, self._cr.normals_block(block, self._width))
        return float(hit[0][r]), bool(hit[1][r]), hit[2][r]


class _CoarseSensor(LeafSystem):
    """What both sensors share: name, period, mounting, the ``q_IB`` and seed ports, the seed words
    (discrete state, read at initialization), the noise parameter and the sample of a time."""

    noise_width = 3

    def __init__(self, name: str, period_s: float, q_BS, noise):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not (isinstance(period_s, (int, float)) and math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        q = np.asarray(q_BS, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
            raise ValueError(f"{name}.q_BS: got {q.tolist()}; must be 4 finite numbers, not all zero")
        self.period_s = float(period_s)
        self.q_BS = rot.quat_normalize(q)
        self.default_noise = noise
        self._noise_index = self.DeclareAbstractParameter(AbstractValue.Make(noise))
        self._q_port = self.DeclareVectorInputPort("q_IB", 4)
        self._seed_port = declare_seed_port(self)
        self.DeclareDiscreteState(np.zeros(SEED_WORDS))  # type: ignore[arg-type]  # pydrake stub
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self._samples_cache = NoiseCache(self, "samples", self.noise, lambda words, p: _Samples(self, words, p))
        self._deps = {self.time_ticket(), self.xd_ticket(), self.all_input_ports_ticket(), self.all_parameters_ticket()}
        # This time's sample, computed once for all the output ports that show it.
        self._measure = declare_value_cache(self, "sample", self._compute_sample, self._deps)

    def _compute_sample(self, context) -> tuple:
        """This time's sample (each sensor's own)."""
        raise NotImplementedError

    def noise(self, context):
        """The noise parameter in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._noise_index).get_value()

    def _set_noise(self, context, noise) -> None:
        context.get_mutable_abstract_parameter(self._noise_index).set_value(noise)

    def _initialize(self, context, discrete_state):
        discrete_state.set_value(read_seed_words(self, context, self._seed_port))
        return EventStatus.Succeeded()

    def _sample(self, context):
        """``(t_k, valid, normals, noise)`` of the sample an output at this time carries,
        ``k = max(0, ceil(t / T - 1e-9))``."""
        samples = self._samples_cache.get(context)
        k = max(0, math.ceil(context.get_time() / self.period_s - 1e-9))
        return (*samples.sample(k), samples.noise)

    def _R_SI(self, context) -> np.ndarray:
        return rot.quat_to_rotmat(rot.quat_multiply(self._q_port.Eval(context), self.q_BS)).T

    def _empty_observations(self):
        return VectorObservations(0.0, False, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), 1.0, self.q_BS)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


class SunSensor(_CoarseSensor):
    """Cosine-detector sun sensor head (model: see the module).

    Args:
        name: system name (noise stream name).
        period_s: sample period (s) > 0.
        q_BS: mounting (4, body <- sensor); boresight ``+z_S``.
        sigma_boresight_rad: per-axis direction noise on the boresight (rad) >= 0.
        fov_half_angle_rad: field-of-view half-angle in (0, pi/2).
        min_sun_fraction: the visible fraction of the solar disk below which a sample is invalid, in (0, 1].
        albedo: in [0, 1] (0: no Earth albedo).
        dropout_probability: in [0, 1). outage_windows_s: ``[(start, end), ...]`` (s).

    Input ports:
        q_IB (4): true attitude. r_I (3, m): position (GCRS). r_sun_I (3, m): the Sun, geocentric.
        seed_uniform (4, random uniform): seed.
    Output ports:
        vector_observations (abstract :class:`VectorObservations`, one direction): the measured Sun
            direction in S, reference the true unit Sun direction from the spacecraft.
        sun_sensor_measurement (5): ``[t_k (s), valid (1/0), s_S_meas (3)]``.
        sun_sensor_status (2): ``[t_k (s), causes]`` (bit flags :data:`ECLIPSE`, :data:`OUT_OF_FOV`).
    Parameters: abstract parameter 0: the :class:`SunSensorNoise` (:meth:`set_noise`).
    Discrete state: the seed words (4, read at initialization); no per-sample event.
    """

    def __init__(
        self,
        name: str,
        period_s: float,
        q_BS=(1.0, 0.0, 0.0, 0.0),
        sigma_boresight_rad: float = 0.0,
        fov_half_angle_rad: float = DEFAULT_FOV_HALF_ANGLE_RAD,
        min_sun_fraction: float = DEFAULT_MIN_SUN_FRACTION,
        albedo: float = 0.0,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
    ):
        if not (math.isfinite(fov_half_angle_rad) and 0.0 < fov_half_angle_rad < 0.5 * math.pi):
            raise ValueError(f"{name}.fov_half_angle: got {fov_half_angle_rad} rad; must be in (0, pi/2)")
        if not (math.isfinite(min_sun_fraction) and 0.0 < min_sun_fraction <= 1.0):
            raise ValueError(f"{name}.min_sun_fraction: got {min_sun_fraction}; must be in (0, 1]")
        noise = SunSensorNoise.make(name, sigma_boresight_rad, albedo, dropout_probability, outage_windows_s)
        super().__init__(name, period_s, q_BS, noise)
        self.fov_half_angle_rad = float(fov_half_angle_rad)
        self.min_sun_fraction = float(min_sun_fraction)
        self._cos_fov = math.cos(self.fov_half_angle_rad)
        self._r_port = self.DeclareVectorInputPort("r_I", 3)
        self._sun_port = self.DeclareVectorInputPort("r_sun_I", 3)
        self.DeclareAbstractOutputPort(
            "vector_observations",
            lambda: AbstractValue.Make(self._empty_observations()),
            self._calc_vectors,
            self._deps,
        )
        self.DeclareVectorOutputPort("sun_sensor_measurement", 5, self._calc_measurement, self._deps)
        self.DeclareVectorOutputPort("sun_sensor_status", 2, self._calc_status, self._deps)

    def set_noise(self, context, sigma_boresight_rad, albedo=0.0, dropout_probability=0.0, outage_windows_s=()):
        """Give ``context`` (this system's) other noise levels, albedo and availability."""
        self._set_noise(
            context,
            SunSensorNoise.make(self.get_name(), sigma_boresight_rad, albedo, dropout_probability, outage_windows_s),
        )

    def _geometry(self, context) -> tuple[np.ndarray, np.ndarray]:
        """``(r_I, r_sun_I)`` (m) on the input ports."""
        return np.asarray(self._r_port.Eval(context), dtype=float), np.asarray(
            self._sun_port.Eval(context), dtype=float
        )

    def causes(self, context) -> int:
        """The bit flags of why this time's sample is unusable (0: the Sun is seen)."""
        r, r_sun = self._geometry(context)
        s_S = self._R_SI(context) @ _unit(r_sun - r)
        causes = 0
        if float(shadow_fraction(r, r_sun)) < self.min_sun_fraction:
            causes |= ECLIPSE
        if s_S[2] < self._cos_fov:
            causes |= OUT_OF_FOV
        return causes

    def albedo_irradiance_I(self, r_I: np.ndarray, s_I: np.ndarray, albedo: float) -> np.ndarray:
        """The Earth's reflected light relative to the Sun's, as a vector toward nadir (the module's
        approximation), before the field-of-view test."""
        rn = float(np.linalg.norm(r_I))
        r_hat = r_I / rn
        return -albedo * (EARTH_RADIUS_M / rn) ** 2 * max(0.0, float(r_hat @ s_I)) * r_hat

    def _compute_sample(self, context):
        """``(t_k, valid, s_S_meas (3), s_I (3), sigma_rad, causes)`` of this time's sample."""
        t_k, valid, z, p = self._sample(context)
        r, r_sun = self._geometry(context)
        R_SI = self._R_SI(context)
        s_I = _unit(r_sun - r)
        s_S = R_SI @ s_I
        causes = self.causes(context)
        light = s_S
        if p.albedo > 0.0:
            nadir_S = -R_SI @ _unit(r)
            earth_half_angle = math.asin(min(1.0, EARTH_RADIUS_M / float(np.linalg.norm(r))))
            if math.acos(max(-1.0, min(1.0, float(nadir_S[2])))) < self.fov_half_angle_rad + earth_half_angle:
                light = _unit(s_S + R_SI @ self.albedo_irradiance_I(r, s_I, p.albedo))
        sigma = p.sigma_boresight_rad / max(float(light[2]), self._cos_fov)
        error = sigma * (z - float(z @ light) * light)  # tangent-plane error, per-axis sigma
        measured = _unit(light + error)
        sigma_rad = p.sigma_boresight_rad / max(float(measured[2]), self._cos_fov)
        return t_k, valid and causes == 0, measured, s_I, sigma_rad, causes

    def _calc_vectors(self, context, output):
        t_k, valid, s_S, s_I, sigma, _ = self._measure(context)
        output.set_value(VectorObservations(t_k, valid, s_S[None, :], s_I[None, :], sigma, self.q_BS))

    def _calc_measurement(self, context, output: BasicVector):
        t_k, valid, s_S, _, _, _ = self._measure(context)
        output.SetFromVector(np.array([t_k, 1.0 if valid else 0.0, *s_S]))  # type: ignore[arg-type]

    def _calc_status(self, context, output: BasicVector):
        t_k, _, _, _, _, causes = self._measure(context)
        output.SetFromVector(np.array([t_k, float(causes)]))  # type: ignore[arg-type]


class Magnetometer(_CoarseSensor):
    """Three-axis magnetometer (model: see the module).

    Args:
        name: system name (noise stream name).
        period_s: sample period (s) > 0.
        q_BS: mounting (4, body <- sensor).
        sigma_T: per-axis white noise (T) >= 0.
        bias_S_T: constant bias (3, T, sensor axes).
        scale_factor_error: (3,) dimensionless. misalignment: (3, 3) zero diagonal (rad), None: none.
        dropout_probability: in [0, 1). outage_windows_s: ``[(start, end), ...]`` (s).

    Input ports:
        q_IB (4): true attitude. B_I (3, T): the field at the spacecraft, in I.
        seed_uniform (4, random uniform): seed.
    Output ports:
        magnetic_field (5): ``[t_k (s), valid (1/0), B_S_meas (3, nT)]``.
        vector_observations (abstract :class:`VectorObservations`, one direction): ``B_S / |B_S|``,
            reference ``B_I / |B_I|``, ``sigma_rad = sigma / |B_S|``.
    Parameters: abstract parameter 0: the :class:`MagnetometerNoise` (:meth:`set_noise`).
    Discrete state: the seed words (4, read at initialization); no per-sample event.
    """

    def __init__(
        self,
        name: str,
        period_s: float,
        q_BS=(1.0, 0.0, 0.0, 0.0),
        sigma_T: float = 0.0,
        bias_S_T=(0.0, 0.0, 0.0),
        scale_factor_error=(0.0, 0.0, 0.0),
        misalignment=None,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
    ):
        noise = MagnetometerNoise.make(
            name, sigma_T, bias_S_T, scale_factor_error, misalignment, dropout_probability, outage_windows_s
        )
        super().__init__(name, period_s, q_BS, noise)
        self._field_port = self.DeclareVectorInputPort("B_I", 3)
        self.DeclareVectorOutputPort("magnetic_field", 5, self._calc_field, self._deps)
        self.DeclareAbstractOutputPort(
            "vector_observations",
            lambda: AbstractValue.Make(self._empty_observations()),
            self._calc_vectors,
            self._deps,
        )

    def set_noise(
        self,
        context,
        sigma_T,
        bias_S_T=(0.0, 0.0, 0.0),
        scale_factor_error=(0.0, 0.0, 0.0),
        misalignment=None,
        dropout_probability=0.0,
        outage_windows_s=(),
    ):
        """Give ``context`` (this system's) other noise and errors (arguments as the constructor's)."""
        self._set_noise(
            context,
            MagnetometerNoise.make(
                self.get_name(),
                sigma_T,
                bias_S_T,
                scale_factor_error,
                misalignment,
                dropout_probability,
                outage_windows_s,
            ),
        )

    def _compute_sample(self, context):
        """``(t_k, valid, B_S_meas (3, T), B_I (3, T), sigma (T))``."""
        t_k, valid, z, p = self._sample(context)
        B_I = np.asarray(self._field_port.Eval(context), dtype=float)
        B_S = p.sensor_matrix @ (self._R_SI(context) @ B_I) + p.bias_S_T + p.sigma_T * z
        return t_k, valid, B_S, B_I, p.sigma_T

    def _calc_field(self, context, output: BasicVector):
        t_k, valid, B_S, _, _ = self._measure(context)
        output.SetFromVector(np.array([t_k, 1.0 if valid else 0.0, *(B_S / TESLA_PER_NANOTESLA)]))  # type: ignore[arg-type]

    def _calc_vectors(self, context, output):
        t_k, valid, B_S, B_I, sigma = self._measure(context)
        magnitude = float(np.linalg.norm(B_S))
        reference = float(np.linalg.norm(B_I))
        usable = valid and magnitude > 0.0 and reference > 0.0
        direction = B_S / magnitude if magnitude > 0.0 else np.array([0.0, 0.0, 1.0])
        reference_I = B_I / reference if reference > 0.0 else np.array([0.0, 0.0, 1.0])
        output.set_value(
            VectorObservations(
                t_k, usable, direction[None, :], reference_I[None, :], sigma / max(magnitude, 1e-300), self.q_BS
            )
        )
