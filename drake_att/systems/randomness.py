"""Seeding Python systems from the diagram's ``RandomGenerator``.

Python ``LeafSystem`` s cannot override ``SetRandomState``.  The Drake idiom used here:
each stochastic system declares a random input port ``seed_uniform`` (uniform [0, 1),
size :data:`SEED_WORDS`); the scenario builder calls
``pydrake.systems.primitives.AddRandomInputs`` so a C++ ``RandomSource`` (whose state
``Diagram.SetRandomContext(context, RandomGenerator(seed))`` randomizes) feeds it.  At
initialization the system copies the port value into its discrete state as integer seed
words; its draws are then counter-based (:class:`drake_att.noise.CounterRandom`): a pure
function of (seed words, system name, sample index).

Consequences: the scenario seed fixes every draw; two systems never share a stream; a
system's noise does not depend on how often its outputs are evaluated or on which other
systems are in the diagram.
"""

from __future__ import annotations

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, ValueProducer

from drake_att.noise import CounterRandom, seed_words_from_uniform, stream_key

SEED_WORDS = 4
RANDOM_SOURCE_SAMPLING_INTERVAL_S = 1e12  # the seed is drawn once per run


def declare_seed_port(system, realizations: int = 1):
    """Declare the ``seed_uniform`` random input port on ``system`` and return it
    (:data:`SEED_WORDS` per realization, realization-major)."""
    return system.DeclareVectorInputPort("seed_uniform", SEED_WORDS * realizations, RandomDistribution.kUniform)


def read_seed_words(system, context, port) -> np.ndarray:
    """Seed words (as floats, exact integers < 2^32) from ``port`` (or zeros if unwired)."""
    if port.HasValue(context):
        return np.array(seed_words_from_uniform(port.Eval(context)), dtype=float)
    return np.zeros(port.size())


_CACHE: dict = {}


class NoiseCache:
    """A sensor's noise tables for its context's seed words and noise parameter, as a Drake
    cache entry: one look-up per output evaluation, recomputed only when the seed words (the
    system's discrete state) or its parameters change, and memoized across contexts (a Monte
    Carlo's runs with one seed share them; a few entries are kept).

    Args:
        system: the sensor (a ``LeafSystem`` whose discrete state is its seed words).
        name: the cache entry's name.
        read_parameter: ``context -> parameter`` (the noise model the tables depend on).
        build: ``(seed words, parameter) -> tables`` (treated as immutable).
    """

    MEMO_SIZE = 8

    def __init__(self, system, name: str, read_parameter, build):
        self._read_parameter, self._build = read_parameter, build
        self._memo: dict = {}  # (seed words bytes, id(parameter)) -> (parameter, tables)
        self._entry = system.DeclareCacheEntry(
            name,
            ValueProducer(allocate=lambda: AbstractValue.Make(None), calc=self._calc),
            {system.xd_ticket(), system.all_parameters_ticket()},
        )

    def _calc(self, context, value):
        words = context.get_discrete_state_vector().value()
        parameter = self._read_parameter(context)
        key = (words.tobytes(), id(parameter))
        hit = self._memo.get(key)
        if hit is None or hit[0] is not parameter:  # (the memo keeps parameter alive)
            if len(self._memo) >= self.MEMO_SIZE:
                self._memo.clear()
            hit = self._memo[key] = (parameter, self._build(words.copy(), parameter))
        value.set_value(hit[1])

    def get(self, context):
        """The tables of ``context`` (the system's own context)."""
        return self._entry.EvalAbstract(context).get_value()


def counter_random(seed_words, stream: str) -> CounterRandom:
    """Cached :class:`CounterRandom` for (seed words, stream name)."""
    words = np.asarray(seed_words, dtype=float)
    key = (words.tobytes(), stream)
    cr = _CACHE.get(key)
    if cr is None:
        if len(_CACHE) > 4096:
            _CACHE.clear()
        cr = _CACHE[key] = CounterRandom(stream_key([int(w) for w in words], stream))
    return cr


class SampledDrawEvents:
    """The initialization and per-sample events of a sensor whose discrete state is
    ``[seed words (SEED_WORDS), sample index, t_sample, valid, draw (n), numbers (k)]`` (the
    star tracker, the screen camera): the event at ``t`` draws the sample of ``t + period``
    (a pure function of seed, system name and sample index), so an output at ``t`` reads
    only the state. The system provides ``period_s``, ``_seed_port``, ``_numbers_start``
    (index of the numbers), ``noise(context)`` (its abstract parameter),
    ``_noise_numbers(parameter)`` (the numbers copied into the state at initialization) and
    ``_draw(context, numbers, seed_words, index, t_sample) -> (draw, valid)``."""

    def _initialize(self, context, discrete_state):
        words = read_seed_words(self, context, self._seed_port)
        t = context.get_time()
        numbers = self._noise_numbers(self.noise(context))
        draw, valid = self._draw(context, numbers, words, 0, t)
        discrete_state.set_value(np.concatenate([words, [0.0, t, float(valid)], draw, numbers]))
        return EventStatus.Succeeded()

    def _on_sample(self, context, discrete_state):
        x = context.get_discrete_state_vector().value()
        index = int(x[SEED_WORDS]) + 1
        t_next = context.get_time() + self.period_s
        draw, valid = self._draw(context, x[self._numbers_start :], x[:SEED_WORDS], index, t_next)
        new = x.copy()
        new[SEED_WORDS : SEED_WORDS + 3] = [index, t_next, float(valid)]
        new[SEED_WORDS + 3 : self._numbers_start] = draw
        discrete_state.set_value(new)
        return EventStatus.Succeeded()
