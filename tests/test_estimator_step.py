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


def test_tag_disposition_boundaries():
    t, tol, lag, period = 3.0, 0.125, 0.5, 2.0  # exactly representable: the boundaries are tested exactly

    def d(t_meas, t, tol, last, lag):
        return rules.tag_disposition(t_meas, t, tol, last, lag, period)

    assert d(NAN, t, tol, -INF, lag) == rules.NO_TIME
    assert d(-INF, t, tol, -INF, lag) == rules.NO_TIME
    assert d(3.0, t, tol, 3.0, lag) == rules.NOT_DUE  # handled already (a held sample seen again)
    assert d(2.75, t, tol, 2.875, lag) == rules.NOT_DUE  # older than the last handled one
    assert d(3.0625, t, tol, -INF, lag) == rules.DUE
    assert d(3.125, t, tol, -INF, lag) == rules.TOO_EARLY  # t + tol: not this instant's, nor the next step's
    assert d(4.3125, t, tol, -INF, lag) == rules.TOO_EARLY  # at the next step (5) later than the lag
    assert d(4.375, t, tol, -INF, lag) == rules.FUTURE  # t + period - lag - tol: the next step may carry it
    assert d(4.5, t, tol, -INF, lag) == rules.FUTURE
    assert d(4.8125, t, tol, -INF, 0.0) == rules.TOO_EARLY
    assert d(4.875, t, tol, -INF, 0.0) == rules.FUTURE  # within the tolerance of the next step: due then
    assert d(4.9375, t, tol, -INF, 0.0) == rules.FUTURE
    assert d(9.0, t, tol, -INF, lag) == rules.FUTURE  # a slower sensor's next sample
    assert d(2.875, t, tol, -INF, lag) == rules.LATE  # t - tol
    assert d(2.5, t, tol, -INF, lag) == rules.LATE  # t - lag: inside the lag
    assert d(2.4375, t, tol, -INF, lag) == rules.TOO_LATE
    assert d(2.875, t, tol, -INF, 0.0) == rules.TOO_LATE  # no lag: every late sample is rejected
    codes = {rules.NO_TIME, rules.NOT_DUE, rules.DUE, rules.FUTURE, rules.LATE, rules.TOO_LATE, rules.TOO_EARLY}
    assert len(codes) == 7


def test_sample_disposition_is_the_tag_disposition_without_a_lag_off_time_folded():
    for t_meas in (NAN, 1.0, 2.9, 3.0, 3.2, 5.0):
        for last in (-INF, 1.0, 3.0):
            full = rules.tag_disposition(t_meas, 3.0, 0.125, last, 0.0, 1.0)
            expected = full if full in (rules.NO_TIME, rules.NOT_DUE, rules.DUE) else rules.NOT_DUE
            assert rules.sample_disposition(t_meas, 3.0, 0.125, last) == expected


@pytest.mark.parametrize(
    "pending, last_used, t_meas, vanished",
    [
        (-INF, -INF, 5.0, False),  # nothing pending
        (10.05, 9.0, 11.05, True),  # a future-tagged sample replaced by the next one
        (10.05, 9.0, NAN, True),
        (10.05, 9.0, 10.05, False),  # still on the port (it may still become due)
        (20.0, 20.0, 30.0, False),  # handled when it became due
        (20.0, 25.0, 30.0, False),
    ],
)
def test_pending_vanished(pending, last_used, t_meas, vanished):
    assert rules.pending_vanished(pending, last_used, t_meas) is vanished


@pytest.mark.parametrize(
    "value, code",
    [(0.0, 0), (0.5, 0), (0.51, 1), (1.0, 1), (1.5, 1), (1.51, 2), (2.0, 2), (7.0, 2), (NAN, 0), (-1.0, 0), (INF, 2)],
)
def test_verdict_code(value, code):
    assert rules.verdict_code(value) == code
    assert (rules.NOT_ASSESSED, rules.CONFIRMED, rules.EXCLUDED) == (0, 1, 2)


def test_held_rate_variance_is_the_drift_variance_of_one_step():
    """Monte Carlo free: the drift of a Wiener rate error over [tau, tau + dt] written out as
    the double integral of q min(s, u) (midpoint rule on a fine grid)."""
    q, tau, dt = 2.5e-7, 3.0, 0.5
    n = 800
    s = tau + (np.arange(n) + 0.5) * dt / n
    expected = q * np.sum(np.minimum.outer(s, s)) * (dt / n) ** 2
    assert rules.held_rate_variance(q, tau, dt) == pytest.approx(expected, rel=1e-5)
    assert rules.held_rate_variance(q, 0.0, dt) == pytest.approx(q * dt**3 / 3, rel=1e-15)
    assert rules.held_rate_variance(q, -1.0, dt) == rules.held_rate_variance(q, 0.0, dt)
    assert rules.held_rate_variance(0.0, tau, dt) == 0.0
    assert rules.held_rate_variance(q, tau, 0.0) == 0.0
    assert rules.held_rate_variance(q, tau, -dt) == 0.0


def test_late_sample_variance():
    assert rules.late_sample_variance(4e-10, 0.05) == pytest.approx(4e-10 * 0.0025, rel=1e-15)
    assert rules.late_sample_variance(4e-10, 0.0) == 0.0


def test_carried_quaternion_is_the_sensor_attitude_after_the_bodys_rotation():
    """``R_IS(t) = R_IB(t_m) expm([w gap x]) R_BS``, written with rotation matrices (scipy)."""
    from scipy.linalg import expm
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    for _ in range(5):
        R_IB = Rotation.random(random_state=rng)
        R_BS = Rotation.random(random_state=rng)
        w, gap = rng.normal(0, 0.3, 3), 0.07
        q_IS = (R_IB * R_BS).as_quat(scalar_first=True)
        q_BS = R_BS.as_quat(scalar_first=True)
        x, y, z = w * gap
        turn = expm(np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]))
        expected = R_IB.as_matrix() @ turn @ R_BS.as_matrix()
        got = Rotation.from_quat(np.array(rules.carried_quaternion(q_IS, q_BS, *w, gap)), scalar_first=True)
        np.testing.assert_allclose(got.as_matrix(), expected, atol=1e-14)
