"""Unit tests of the estimator contract module (drake_att/contract.py): the packed estimate
layout, the measurement types read from ports, and the one validity rule. The system-level
contract (skipping, counting, seeds) is tested over every estimator in test_plugins.py."""

import math

import numpy as np
import pytest

from drake_att import contract as c


def _estimate():
    P = np.arange(36, dtype=float).reshape(6, 6) + 100.0
    return c.Estimate(np.array([0.5, 0.5, 0.5, 0.5]), np.array([7.0, 8.0, 9.0]), P, 12.5, 3, 4, 2.25)


def test_pack_places_every_field_in_its_named_slice():
    e = _estimate()
    v = e.pack()
    assert v.shape == (c.ESTIMATE_SIZE,) and c.ESTIMATE_SIZE == 4 + 3 + 36 + c.STATUS_SIZE
    np.testing.assert_array_equal(v[c.Q_IB], e.q_IB)
    np.testing.assert_array_equal(v[c.SECOND], e.second)
    np.testing.assert_array_equal(v[c.COVARIANCE].reshape(6, 6), e.covariance)  # row-major
    status = v[c.STATUS]
    assert status[c.STATUS_T_ESTIMATE] == 12.5 and status[c.STATUS_USED] == 3
    assert status[c.STATUS_SKIPPED] == 4 and status[c.STATUS_LAST_NIS] == 2.25


def test_unpack_inverts_pack_with_typed_fields_and_copies():
    e = _estimate()
    v = e.pack()
    u = c.Estimate.unpack(v)
    np.testing.assert_array_equal(u.q_IB, e.q_IB)
    np.testing.assert_array_equal(u.second, e.second)
    np.testing.assert_array_equal(u.covariance, e.covariance)
    assert u.covariance.shape == (6, 6)
    assert (u.t_estimate, u.used, u.skipped, u.last_nis) == (12.5, 3, 4, 2.25)
    assert isinstance(u.used, int) and isinstance(u.skipped, int) and isinstance(u.last_nis, float)
    v[:] = -1.0  # the unpacked estimate owns its arrays
    assert u.q_IB[0] == 0.5 and u.second[0] == 7.0 and u.covariance[0, 0] == 100.0
    nan_nis = c.Estimate.unpack(np.r_[e.pack()[:-1], np.nan])
    assert math.isnan(nan_nis.last_nis)
    # Integer input (e.g. a logged int array) is read as floats.
    ints = c.Estimate.unpack(np.arange(c.ESTIMATE_SIZE))
    assert ints.q_IB.dtype == float and ints.t_estimate == 43.0


def test_unpack_rejects_a_vector_of_the_wrong_size():
    with pytest.raises(ValueError, match="size 46; need 47"):
        c.Estimate.unpack(np.zeros(46))


def test_second_quantity_names_its_port_and_parses_it_back():
    for q in c.SecondQuantity:
        assert c.SecondQuantity.from_port_name(q.port_name) is q
    assert c.SecondQuantity.GYRO_BIAS.port_name == "bias_B_hat"
    assert c.SecondQuantity.BODY_RATE.port_name == "w_IB_B_hat"
    with pytest.raises(ValueError, match="w_hat.*allowed.*bias_B_hat"):
        c.SecondQuantity.from_port_name("w_hat")


@pytest.mark.parametrize(
    "flag, expected",
    [
        (1.0, True),
        (True, True),
        (0.51, True),
        (0.5, False),
        (0.0, False),
        (False, False),
        (-1.0, False),
        (np.nan, False),
        (np.inf, False),
    ],
)
def test_validity_flag_is_true_only_for_a_finite_value_above_one_half(flag, expected):
    assert c.flag_is_true(flag) is expected


def test_gyro_sample_reads_time_flag_and_exactly_three_rates():
    g = c.GyroSample.from_port([2.0, 1.0, 0.1, 0.2, 0.3, 99.0])
    assert g.time_s == 2.0 and g.valid is True
    np.testing.assert_array_equal(g.w_meas_B, [0.1, 0.2, 0.3])
    assert g.w_meas_B.dtype == float
    assert c.GyroSample.from_port([2.0, np.nan, 0.1, 0.2, 0.3]).valid is False
    assert c.GyroSample.from_port([2.0, 0.0, 0.1, 0.2, 0.3]).valid is False


def test_empty_vector_observations_is_an_unusable_sample_with_identity_mounting():
    e = c.empty_vector_observations()
    assert e.time_s == 0.0 and e.valid is False and e.sigma_rad == 0.0
    assert e.directions_S.shape == (0, 3) and e.references_I.shape == (0, 3)
    np.testing.assert_array_equal(e.q_BS, [1.0, 0.0, 0.0, 0.0])
    assert not c.is_usable(e)


def _vectors(**kw):
    base = dict(
        time_s=1.0,
        valid=True,
        directions_S=np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
        references_I=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
        sigma_rad=1e-4,
        q_BS=np.array([1.0, 0.0, 0.0, 0.0]),
    )
    base.update(kw)
    return c.VectorObservations(**base)


def test_is_usable_for_vector_observations():
    assert c.is_usable(_vectors())
    # A valid-looking sample with no stars carries no information.
    assert not c.is_usable(_vectors(directions_S=np.zeros((0, 3)), references_I=np.zeros((0, 3))))
    assert not c.is_usable(_vectors(valid=False))
    assert not c.is_usable(_vectors(valid=np.nan))
    assert not c.is_usable(_vectors(time_s=np.nan))
    assert not c.is_usable(_vectors(directions_S=np.array([[1.0, 0.0, np.nan], [0.0, 1.0, 0.0]])))
    assert not c.is_usable(_vectors(references_I=np.array([[0.0, 0.0, 1.0]])))  # one reference for two stars
    assert not c.is_usable(_vectors(sigma_rad=0.0)) and not c.is_usable(_vectors(sigma_rad=np.inf))
    assert not c.is_usable(_vectors(references_I=np.array([[0.0, 0.0, np.inf], [1.0, 0.0, 0.0]])))
    # A reference given with a missing entry reads as NaN (unusable), never a TypeError.
    assert not c.is_usable(_vectors(references_I=[[0.0, 0.0, None], [1.0, 0.0, 0.0]]))
    # Reference directions must be non-zero: the documented floor is a norm of 1e-9.
    assert not c.is_usable(_vectors(references_I=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])))
    assert c.is_usable(_vectors(references_I=np.array([[1e-9, 0.0, 0.0], [1.0, 0.0, 0.0]])))


def test_is_usable_for_quaternion_samples_and_centroids():
    q = dict(
        time_s=1.0,
        valid=True,
        q_IS_meas=np.array([1.0, 0.0, 0.0, 0.0]),
        q_BS=np.array([1.0, 0, 0, 0]),
        covariance_S=np.eye(3) * 1e-10,
    )
    assert c.is_usable(c.QuaternionSample(**q))
    assert not c.is_usable(c.QuaternionSample(**{**q, "q_IS_meas": np.array([0.4, 0.0, 0.0, 0.0])}))
    assert not c.is_usable(c.QuaternionSample(**{**q, "q_IS_meas": np.array([1.0, np.nan, 0.0, 0.0])}))
    assert not c.is_usable(c.QuaternionSample(**{**q, "valid": False}))
    one_star = c.CameraCentroids(1.0, True, np.array([[1e-3, -2e-3]]), 0.02, 1e-6)
    assert c.is_usable(one_star)
    assert not c.is_usable(c.CameraCentroids(1.0, True, np.zeros((0, 2)), 0.02, 1e-6))
