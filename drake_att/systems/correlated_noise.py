"""Paper S1's multiplicative noise in the diagram: one source of the per-step gyro
scale-factor error ``zeta_k`` and of the star-sensor noise correlated with it.

The model is :class:`drake_att.filters.multiplicative_noise.MultiplicativeNoiseModel` — the
one the CQE-MCNS filter assumes — drawn here so that every estimator can run on such data:
the gyro divides the interval's true mean rate by ``1 + kappa zeta_k`` (its ``scale_error``
input) and a vector-mode star tracker adds the correlated noise ``v_k`` of its sample at
``t_k`` (its ``vector_noise`` input) instead of its own.

Timing (no hidden lag, one event per gyro step ``T``): step ``k`` is ``[t_k, t_k + T]``;
``zeta_k`` scales that interval and is correlated with the star noise ``v_k`` of a sample
taken at ``t_k``. At ``t_k`` (before the events of ``t_k``) the source holds ``zeta_{k-1}``
(the interval the gyro reports at ``t_k``) and ``(zeta_k, v_k)``; its event at ``t_k`` draws
``(zeta_{k+1}, v_{k+1})``. Draws are counter-based: ``z_k`` = normals ``(k, 1 + 3m)`` of
``counter_random(seed words, system name)``, ``(zeta_k, v_k) = model.from_normals(z_k,
sigma_v)`` (``v_k`` is drawn every step; a tracker uses it only at its own samples).

Input ports:
    seed_uniform (4, random uniform).
Output ports:
    scale_error (1): ``kappa zeta_{k-1}`` at ``t_k`` (0 at ``t_0``) -> the gyro's ``scale_error``.
    vector_noise (3m): ``v_k`` (rad, star-major) -> the tracker's ``vector_noise``.
    zeta (1): ``zeta_{k-1}`` (the truth of the interval ending now; logged).
Parameters:
    abstract parameter 0: ``(MultiplicativeNoiseModel, sigma_v)`` (:meth:`set_model`).
Discrete state: ``[seed words (4), k, zeta_{k-1}, zeta_k, v_k (3m)]``.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att.filters.multiplicative_noise import MultiplicativeNoiseModel
from drake_att.systems.randomness import SEED_WORDS, counter_random, declare_seed_port, read_seed_words
from drake_att.validation import check_int, check_nonnegative, check_positive

_K, _ZETA_PREV, _ZETA_NEXT, _V = SEED_WORDS, SEED_WORDS + 1, SEED_WORDS + 2, SEED_WORDS + 3


class ScaleFactorStarNoiseSource(LeafSystem):
    """Source of ``(zeta_k, v_k)`` (see the module docstring).

    Args:
        name: system name (also the random stream name).
        period_s: the gyro step ``T`` (s) > 0.
        model: the multiplicative-noise model (``Q_zeta``, ``rho``, ``kappa``).
        star_sigma_rad: the tracker's per-component noise ``sigma_v`` (rad) >= 0.
        num_stars: ``m`` >= 1, the tracker's reference directions (``3 m rho^2 < 1``).
    """

    def __init__(
        self, name: str, period_s: float, model: MultiplicativeNoiseModel, star_sigma_rad: float, num_stars: int
    ):
        LeafSystem.__init__(self)
        self.set_name(name)
        self.period_s = check_positive(f"{name}.period_s", period_s)
        self.num_stars = check_int(f"{name}.num_stars", num_stars, 1)
        self._check(model, star_sigma_rad)
        self._model_index = self.DeclareAbstractParameter(AbstractValue.Make((model, float(star_sigma_rad))))
        self._seed_port = declare_seed_port(self)
        n = 3 * self.num_stars
        self.DeclareDiscreteState(_V + n)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._on_step)
        ticket = {self.xd_ticket(), self.all_parameters_ticket()}
        self.DeclareVectorOutputPort("scale_error", 1, self._calc_scale, ticket)
        self.DeclareVectorOutputPort("vector_noise", n, self._calc_noise, ticket)
        self.DeclareVectorOutputPort("zeta", 1, self._calc_zeta, ticket)

    def _check(self, model, star_sigma_rad):
        if not isinstance(model, MultiplicativeNoiseModel):
            raise TypeError(f"{self.get_name()}.model: got {type(model).__name__}; need a MultiplicativeNoiseModel")
        check_nonnegative(f"{self.get_name()}.star_sigma_rad", star_sigma_rad)
        model.cross_covariance(star_sigma_rad, self.num_stars)  # refuses 3 m rho^2 >= 1, naming num_stars

    def model(self, context) -> tuple[MultiplicativeNoiseModel, float]:
        """``(model, sigma_v)`` in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._model_index).get_value()

    def set_model(self, context, model: MultiplicativeNoiseModel, star_sigma_rad: float) -> None:
        """Another model / star sigma for ``context``; takes effect at the next initialization."""
        self._check(model, star_sigma_rad)
        context.get_mutable_abstract_parameter(self._model_index).set_value((model, float(star_sigma_rad)))

    # -- events -------------------------------------------------------------------
    def _draw(self, context, words, k):
        model, sigma_v = self.model(context)
        z = counter_random(words, self.get_name()).normals(k, 1 + 3 * self.num_stars)
        zeta, v = model.from_normals(z, sigma_v)
        return float(zeta), v.ravel()

    def _initialize(self, context, discrete_state):
        words = read_seed_words(self, context, self._seed_port)
        zeta0, v0 = self._draw(context, words, 0)
        discrete_state.set_value(np.concatenate([words, [0.0, 0.0, zeta0], v0]))
        return EventStatus.Succeeded()

    def _on_step(self, context, discrete_state):
        x = context.get_discrete_state_vector().value()
        k = int(x[_K]) + 1
        zeta, v = self._draw(context, x[:SEED_WORDS], k)
        new = x.copy()
        new[_K], new[_ZETA_PREV], new[_ZETA_NEXT], new[_V:] = k, x[_ZETA_NEXT], zeta, v
        discrete_state.set_value(new)
        return EventStatus.Succeeded()

    # -- outputs ------------------------------------------------------------------
    def _calc_scale(self, context, output: BasicVector):
        x = context.get_discrete_state_vector().value()
        output.SetAtIndex(0, self.model(context)[0].scale_per_zeta * x[_ZETA_PREV])

    def _calc_noise(self, context, output: BasicVector):
        output.SetFromVector(context.get_discrete_state_vector().value()[_V:])

    def _calc_zeta(self, context, output: BasicVector):
        output.SetAtIndex(0, context.get_discrete_state_vector().value()[_ZETA_PREV])
