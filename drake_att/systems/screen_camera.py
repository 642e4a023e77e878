"""The indoor star tracker's camera (paper S2): a pinhole camera on the air-bearing table
imaging the star screen above it, as a Drake ``LeafSystem``.

The image is the exact ray-plane forward model of :mod:`drake_att.screen_geometry` at the true
attitude (stars behind the camera or off the detector are not seen), plus optional
per-star centroid noise and centroid quantization:

``(X, Y) = round((X_true + sigma n) / q) q`` per axis (``n ~ N(0, 1)`` per star and frame;
``q = 0``: no rounding; ``sigma = q = 0``: the paper's "no extraction error"). A frame is
invalid during a configured outage window or, with the configured probability, at random.

Input ports:
    q_IB (4): true table attitude.
    seed_uniform (4, random uniform): seed.
Parameters: abstract parameter 0: the :class:`CameraNoise` (:meth:`set_noise`).
Output ports:
    camera_centroids (abstract :class:`~drake_att.contract.CameraCentroids`): the stars in
        view in raster order, with the frame time and validity.
    stars_in_view (1): how many stars the detector sees (noise-free geometry).
Discrete state: ``[seed words (4), frame index, t_frame, valid, noise numbers (2N, standard
    normals of every screen star), sigma (m), q (m), dropout probability, has outage windows]``;
    the draw for the next frame is made by the frame event (counter-based: a pure function
    of (seed, system name, frame index)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from drake_att import rotations as rot
from drake_att.contract import CameraCentroids
from drake_att.screen_geometry import ScreenCameraGeometry
from drake_att.systems.randomness import SEED_WORDS, SampledDrawEvents, counter_random, declare_seed_port
from drake_att.validation import check_nonnegative, check_positive, fail


@dataclass(frozen=True)
class CameraNoise:
    """Centroid noise 1-sigma and quantization step (m), drop-out probability and outage
    windows ``((start, end), ...)`` (s) of the camera (its abstract parameter)."""

    sigma_m: float
    quantization_m: float
    dropout_probability: float
    outage_windows_s: tuple

    @classmethod
    def make(
        cls,
        name: str,
        sigma_m: float = 0.0,
        quantization_m: float = 0.0,
        dropout_probability: float = 0.0,
        outage_windows_s=(),
    ) -> CameraNoise:
        check_nonnegative(f"{name}.centroid_noise", sigma_m)
        check_nonnegative(f"{name}.quantization", quantization_m)
        if not (0.0 <= dropout_probability < 1.0):
            fail(f"{name}.dropout_probability", dropout_probability, "must be in [0, 1)")
        windows = tuple((float(a), float(b)) for a, b in outage_windows_s)
        for a, b in windows:
            if not b > a:
                fail(f"{name}.outage_windows_s", (a, b), "each window needs end > start")
        return cls(float(sigma_m), float(quantization_m), float(dropout_probability), windows)


class ScreenCamera(SampledDrawEvents, LeafSystem):
    """The star-screen camera (see the module docstring for ports and state).

    Args:
        name: system name (noise stream name).
        period_s: frame period (s) > 0.
        geometry: the screen, its stars and the camera (:class:`ScreenCameraGeometry`).
        noise: the default :class:`CameraNoise`.
    """

    def __init__(self, name: str, period_s: float, geometry: ScreenCameraGeometry, noise: CameraNoise):
        LeafSystem.__init__(self)
        self.set_name(name)
        self.period_s = check_positive(f"{name}.period_s", period_s)
        self.geometry = geometry
        self.default_noise = noise
        self._n_noise = 2 * len(geometry.stars_I)
        self._noise_index = self.DeclareAbstractParameter(AbstractValue.Make(noise))
        self._q_port = self.DeclareVectorInputPort("q_IB", 4)
        self._seed_port = declare_seed_port(self)
        self._numbers_start = SEED_WORDS + 3 + self._n_noise
        state = np.concatenate([np.zeros(self._numbers_start), self._noise_numbers(noise)])
        self.DeclareDiscreteState(state)  # type: ignore[arg-type]  # pydrake stub
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_sample)
        deps = {self.xd_ticket(), self.all_input_ports_ticket()}
        self.DeclareAbstractOutputPort(
            "camera_centroids",
            lambda: AbstractValue.Make(CameraCentroids(0.0, False, np.zeros((0, 2)), geometry.focal_length_m, 0.0)),
            self._calc_centroids,
            deps,
        )
        self.DeclareVectorOutputPort("stars_in_view", 1, self._calc_count, {self.all_input_ports_ticket()})

    # -- parameters ---------------------------------------------------------------------
    def noise(self, context) -> CameraNoise:
        """The :class:`CameraNoise` in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._noise_index).get_value()

    def set_noise(self, context, noise: CameraNoise) -> None:
        """Give ``context`` (this system's) another :class:`CameraNoise` (from the next
        initialization on)."""
        context.get_mutable_abstract_parameter(self._noise_index).set_value(noise)

    @staticmethod
    def _noise_numbers(p: CameraNoise) -> np.ndarray:
        return np.array([p.sigma_m, p.quantization_m, p.dropout_probability, float(bool(p.outage_windows_s))])

    # -- events ---------------------------------------------------------------------------
    def _draw(self, context, numbers, words, index, t_frame):
        cr = counter_random(words, self.get_name())
        noise = cr.normals(index, self._n_noise)
        valid = cr.uniforms(index, 1)[0] >= numbers[2]
        if numbers[3] and any(a <= t_frame < b for a, b in self.noise(context).outage_windows_s):
            valid = False
        return noise, valid

    # -- outputs --------------------------------------------------------------------------
    def image(self, q_IB, normals, sigma_m: float, quantization_m: float):
        """``(star_ids, centroids_m)`` of one frame: the exact image of :meth:`ScreenCameraGeometry.project`
        plus ``sigma_m`` times the stars' ``normals`` (N, 2), rounded to ``quantization_m``."""
        ids, xy = self.geometry.project(rot.quat_to_rotmat(np.asarray(q_IB)).T)
        xy = xy + sigma_m * np.reshape(normals, (-1, 2))[ids]
        if quantization_m > 0.0:
            xy = np.round(xy / quantization_m) * quantization_m
        return ids, xy

    def _calc_centroids(self, context, output):
        x = context.get_discrete_state_vector().value()
        sigma, quant = float(x[self._numbers_start]), float(x[self._numbers_start + 1])
        _, xy = self.image(self._q_port.Eval(context), x[SEED_WORDS + 3 : self._numbers_start], sigma, quant)
        output.set_value(
            CameraCentroids(
                float(x[SEED_WORDS + 1]), bool(x[SEED_WORDS + 2] > 0.5), xy, self.geometry.focal_length_m, sigma, quant
            )
        )

    def _calc_count(self, context, output: BasicVector):
        ids, _ = self.geometry.project(rot.quat_to_rotmat(np.asarray(self._q_port.Eval(context))).T)
        output.SetFromVector([float(len(ids))])  # type: ignore[arg-type]  # pydrake stub
