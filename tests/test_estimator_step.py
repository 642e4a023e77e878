"""The estimator loop's rules (drake_att.systems.estimator_step), each against its definition.

The Python loop and the compiled MEKF step call the same rule functions, so the test that
compares the two loops (tests/test_compiled_step.py) cannot see a change to a rule: these
tests pin each rule's boundaries (strict or not, NaN, the exact codes) and the bookkeeping
layout, written out here from the module's documented definitions.
"""

import math

import numpy as np
import pytest

from drake_att.contract import TIME_TOLERANCE_S
from drake_att.systems import estimator_step as rules
from drake_att.systems.estimator_step import Bookkeeping
from drake_att.systems.randomness import SEED_WORDS

NAN, INF = math.nan, math.inf


@pytest.mark.parametrize(
    "valid, rate, usable",
    [
        (1.0, (0.1, -0.2, 0.3), True),
        (0.5, (0.0, 0.0, 0.0), False),  # a flag is true only above 0.5
        (0.5000001, (0.0, 0.0, 0.0), True),
        (NAN, (0.0, 0.0, 0.0), False),
        (INF, (0.0, 0.0, 0.0), False),
        (1.0, (NAN, 0.0, 0.0), False),
        (1.0, (0.0, INF, 0.0), False),
        (1.0, (0.0, 0.0, -INF), False),
    ],
)
def test_rate_usable(valid, rate, usable):
    assert rules.rate_usable(valid, *rate) is usable


def test_gyro_sample_usable_needs_this_steps_time_tag_strictly_within_the_tolerance():
    t, tol = 2.0, 0.5  # exactly representable: |t_g - t| == tol is tested exactly
    assert rules.gyro_sample_usable(t, tol, 2.25, 1.0, 0.0, 0.0, 0.0)
    assert not rules.gyro_sample_usable(t, tol, 2.5, 1.0, 0.0, 0.0, 0.0)  # on the boundary: not this step's
    assert not rules.gyro_sample_usable(t, tol, 1.5, 1.0, 0.0, 0.0, 0.0)
    assert not rules.gyro_sample_usable(t, tol, NAN, 1.0, 0.0, 0.0, 0.0)
    assert not rules.gyro_sample_usable(t, tol, 2.0, 0.0, 0.0, 0.0, 0.0)  # on time but invalid
    assert not rules.gyro_sample_usable(t, tol, 2.0, 1.0, 0.0, NAN, 0.0)


def test_sample_disposition():
    t, tol = 3.0, 0.5
    assert rules.sample_disposition(NAN, t, tol, -INF) == rules.NO_TIME
    assert rules.sample_disposition(INF, t, tol, -INF) == rules.NO_TIME
    assert rules.sample_disposition(3.25, t, tol, -INF) == rules.DUE
    assert rules.sample_disposition(3.5, t, tol, -INF) == rules.NOT_DUE  # |t_meas - t| == tol: another instant
    assert rules.sample_disposition(2.0, t, tol, -INF) == rules.NOT_DUE  # an old sample still on the port
    assert rules.sample_disposition(3.0, t, tol, 3.0) == rules.NOT_DUE  # used already (equal time)
    assert rules.sample_disposition(3.0, t, tol, 2.9) == rules.DUE
    assert rules.sample_disposition(2.0, t, tol, 5.0) == rules.NOT_DUE  # neither this instant's nor new
    assert len({rules.NO_TIME, rules.NOT_DUE, rules.DUE}) == 3


def test_the_runner_uses_the_contracts_time_tolerance():
    assert rules.TIME_TOLERANCE_S == TIME_TOLERANCE_S == 1e-6


@pytest.mark.parametrize(
    "flag, n_subsets, slot",
    [
        (1.0, 0, 0),
        (3.0, 0, 0),
        (NAN, 0, 0),  # no flag-dependent covariances: always the sensor's own
        (1.0, 4, 0),
        (1.5, 4, 0),  # flag <= 1.5: all inputs formed the sample
        (2.0, 4, 1),
        (3.0, 4, 2),
        (4.0, 4, 3),
        (2.4, 4, 1),  # flag 1 + mask, rounded
        (5.0, 4, -1),
        (9.0, 4, -1),  # a mask beyond the table
        (2.0, 1, -1),  # a table of one entry (mask 0 only) has no subset 1
        (NAN, 4, 0),  # NaN > 1.5 is false: the own covariance (the flag itself is invalid anyway)
        (INF, 4, -1),
    ],
)
def test_covariance_slot(flag, n_subsets, slot):
    assert rules.covariance_slot(flag, n_subsets) == slot


@pytest.mark.parametrize(
    "accepted, nis, counts",
    [
        (False, 30.0, True),
        (False, 0.0, True),
        (False, INF, True),  # the gate's rejection (a NIS)
        (False, NAN, False),  # no NIS: a singular innovation covariance, not the gate
        (True, 3.0, False),
        (True, NAN, False),
    ],
)
def test_is_gate_rejection(accepted, nis, counts):
    assert rules.is_gate_rejection(accepted, nis) is counts


@pytest.mark.parametrize("n_inputs, particles", [(0, None), (2, None), (3, 500)])
def test_bookkeeping_layout_and_initial_values(n_inputs, particles):
    b = Bookkeeping(n_inputs)
    last = 9 + SEED_WORDS
    assert (b.T_LAST, b.W_LAST, b.STEP, b.SEED) == (0, slice(1, 4), 4, slice(5, 5 + SEED_WORDS))
    assert (b.N_RESAMPLES, b.ESS, b.N_DEGENERATE, b.T_GYRO_GOOD, b.LAST_SAMPLE) == (
        5 + SEED_WORDS,
        6 + SEED_WORDS,
        7 + SEED_WORDS,
        8 + SEED_WORDS,
        last,
    )
    assert b.pending == last + n_inputs and b.rejections == last + 2 * n_inputs and b.size == last + 3 * n_inputs
    book = b.initial(particles)
    expected = np.zeros(last + 3 * n_inputs)
    expected[0] = -INF  # no step yet
    expected[6 + SEED_WORDS] = NAN if particles is None else float(particles)  # N_eff before any update: N
    expected[8 + SEED_WORDS] = -INF  # no usable gyro sample yet
    expected[last : last + 2 * n_inputs] = -INF  # no sample handled, none pending
    np.testing.assert_array_equal(book, expected)
    assert book.dtype == np.float64
