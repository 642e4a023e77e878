"""Star identification (drake_att.star_identification) on frames made here from the Hipparcos
catalogue: true pixels of the stars on the detector (projected in the test by the polar form of
the pinhole), Gaussian centroid noise, false stars; the truth is the attitude and the catalogue
index of every centroid."""

import math

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.sky import load_hipparcos
from drake_att.star_camera import PinholeCamera
from drake_att.star_identification import REASONS, StarIdentifier

CAMERA = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024)
ARCMIN = math.pi / 180 / 60


@pytest.fixture(scope="module")
def catalog():
    return load_hipparcos().at_epoch(2026.0).brighter_than(6.5)


@pytest.fixture(scope="module")
def identifier(catalog):
    return StarIdentifier(CAMERA, catalog)


def sky_frame(catalog, q, rng, sigma_px, false_stars=0):
    """Centroids brightest first (true pixels + noise) and each one's catalogue index (-1 for a
    false star). Pixels from the angles: theta from the boresight, azimuth alpha, radius
    f tan(theta)."""
    d_S = rot.quat_rotate(rot.quat_conjugate(q), catalog.unit_I)
    theta = np.arccos(np.clip(d_S[:, 2], -1, 1))
    ahead = theta < math.radians(30)
    idx = np.flatnonzero(ahead)
    rho = CAMERA.focal_length_px * np.tan(theta[idx])
    alpha = np.arctan2(d_S[idx, 1], d_S[idx, 0])
    uv = CAMERA.principal_point_px + rho[:, None] * np.column_stack([np.cos(alpha), np.sin(alpha)])
    on = (uv[:, 0] >= 0) & (uv[:, 0] < 1024) & (uv[:, 1] >= 0) & (uv[:, 1] < 1024)
    idx, uv = idx[on], uv[on]
    order = np.argsort(catalog.magnitude[idx], kind="stable")
    idx, uv = idx[order], uv[order]
    z = uv + sigma_px * rng.normal(size=uv.shape)
    for _ in range(false_stars):
        pos = int(rng.integers(0, min(len(z), 10) + 1))
        z = np.insert(z, pos, rng.uniform(0, 1024, 2), axis=0)
        idx = np.insert(idx, pos, -1)
    return z, idx


def random_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def error_angle(q_hat, q):
    return np.linalg.norm(rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q_hat), q)))


def test_lost_in_space_identifies_and_never_reports_a_wrong_attitude(catalog, identifier):
    """200 random attitudes, 0.2 px, 0-3 false stars among the brightest: >= 98% confirmed; every
    confirmed frame's matches are the true stars and its error is within 5 sigma of its own
    covariance's largest axis."""
    rng = np.random.default_rng(11)
    valid = 0
    for _ in range(200):
        q = random_quaternion(rng)
        z, truth = sky_frame(catalog, q, rng, 0.2, int(rng.integers(0, 4)))
        frame = identifier.lost_in_space(z, 0.2)
        assert frame.mode == "lost_in_space"
        if not frame.valid:
            assert frame.reason in REASONS
            continue
        valid += 1
        assert np.array_equal(truth[frame.centroid_index], frame.catalog_index)
        sigma_max = math.sqrt(np.linalg.eigvalsh(frame.attitude.covariance_S)[-1])
        assert error_angle(frame.attitude.q_IS, q) < 5 * sigma_max
        assert frame.false_probability <= identifier.max_false_probability
    assert valid >= 196


def test_random_points_are_never_a_valid_frame(identifier):
    """Frames of false stars only (20-40 uniform points): never valid."""
    rng = np.random.default_rng(12)
    for _ in range(30):
        z = rng.uniform(0, 1024, size=(int(rng.integers(20, 41)), 2))
        frame = identifier.lost_in_space(z, 0.2)
        assert not frame.valid and frame.reason in REASONS and frame.attitude is None


def test_tracking_matches_from_a_close_prior_and_fails_from_a_far_one(catalog, identifier):
    """Prior 3 arcmin off: every frame confirmed with the true stars (most of them: close pairs
    within a gate are left out); 5 deg off: invalid, and identify() falls back to lost-in-space."""
    rng = np.random.default_rng(13)
    fraction = []
    for _ in range(50):
        q = random_quaternion(rng)
        z, truth = sky_frame(catalog, q, rng, 0.3, int(rng.integers(0, 4)))
        prior = rot.quat_multiply(q, rot.rotvec_to_quat(3 * ARCMIN * rng.normal(size=3)))
        frame = identifier.track(z, 0.3, prior, 3 * ARCMIN)
        assert frame.valid and frame.mode == "tracking" and frame.false_probability is None
        assert np.array_equal(truth[frame.centroid_index], frame.catalog_index)
        fraction.append(frame.attitude.num_stars / np.sum(truth >= 0))
        # a prior wrong by 5 deg with a 3-arcmin sigma: invalid with a reason; identify() falls back
        far = rot.quat_multiply(
            q, rot.rotvec_to_quat(math.radians(5) * rot.quat_normalize(rng.normal(size=3)[None])[0])
        )
        lost = identifier.track(z, 0.3, far, 3 * ARCMIN)
        assert not lost.valid and lost.reason in REASONS
        back = identifier.identify(z, 0.3, far, 3 * ARCMIN)
        assert back.valid and back.mode == "lost_in_space" and error_angle(back.attitude.q_IS, q) < 5 * ARCMIN
    assert np.median(fraction) > 0.85 and np.min(fraction) > 0.5


def test_tracking_rejects_an_ambiguous_centroid(catalog, identifier):
    """A false star placed 1 px from a true star's centroid: neither is matched (two centroids
    claim one prediction), the rest of the frame is."""
    rng = np.random.default_rng(14)
    q = random_quaternion(rng)
    z, truth = sky_frame(catalog, q, rng, 0.1)
    z = np.vstack([z, z[5] + [1.0, 0.0]])
    frame = identifier.track(z, 0.1, q, 1 * ARCMIN)
    assert frame.valid
    assert 5 not in frame.centroid_index and len(z) - 1 not in frame.centroid_index


def test_too_few_stars_is_invalid_with_its_reason(catalog, identifier):
    rng = np.random.default_rng(15)
    q = random_quaternion(rng)
    z, _ = sky_frame(catalog, q, rng, 0.2)
    for frame in (identifier.lost_in_space(z[:3], 0.2), identifier.track(z[:3], 0.2, q, ARCMIN)):
        assert not frame.valid and frame.reason == "too_few_stars"


def test_a_probability_above_the_threshold_is_low_probability(catalog):
    """tetra3rs's match accepted by it but not by a stricter threshold: invalid, its attitude kept
    as tetra3rs's own (and right)."""
    strict = StarIdentifier(CAMERA, catalog, max_false_probability=1e-300)
    rng = np.random.default_rng(16)
    q = random_quaternion(rng)
    z, _ = sky_frame(catalog, q, rng, 0.2)
    frame = strict.lost_in_space(z[:10], 0.2)  # 10 stars: tetra3rs says ~1e-27 (60 stars: ~1e-308)
    assert not frame.valid and frame.reason == "low_probability" and frame.attitude is None
    assert frame.false_probability > 1e-300 and error_angle(frame.tetra3rs_q_IS, q) < 5 * ARCMIN


def test_database_is_built_from_our_catalogue_and_cached(catalog, identifier):
    db = identifier.database
    assert db.num_stars == len(catalog)
    assert StarIdentifier(CAMERA, catalog).database is db
    star = db.get_star_by_id(100)
    u = catalog.unit_I[100]
    assert star.ra_deg == pytest.approx(math.degrees(math.atan2(u[1], u[0])) % 360, abs=1e-6)  # stored in float32
    assert star.dec_deg == pytest.approx(math.degrees(math.asin(u[2])), abs=1e-6)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"min_stars": 2}, "min_stars"),
        ({"max_false_probability": 0.0}, "max_false_probability"),
        ({"residual_p_value": 0.7}, "residual_p_value"),
        ({"gate_sigmas": 50.0}, "gate_sigmas"),
        ({"solve_timeout_ms": -1.0}, "solve_timeout_ms"),
    ],
)
def test_bad_config_is_a_one_line_error(catalog, kwargs, field):
    with pytest.raises(ValueError, match=field) as e:
        StarIdentifier(CAMERA, catalog, **kwargs)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "call, field",
    [
        (lambda i: i.lost_in_space(np.zeros((5, 3)), 0.2), "centroids_px"),
        (lambda i: i.lost_in_space(np.zeros((5, 2)), 0.0), "centroid_cov_px2"),
        (lambda i: i.track(np.zeros((5, 2)), 0.2, [0, 0, 0, 0], 1e-3), "q_IS_prior"),
        (lambda i: i.track(np.zeros((5, 2)), 0.2, [1, 0, 0, 0], 1.0), "prior_sigma_rad"),
    ],
)
def test_bad_inputs_are_one_line_errors(identifier, call, field):
    with pytest.raises(ValueError, match=field) as e:
        call(identifier)
    assert "\n" not in str(e.value)


def test_edges_refused_elsewhere(catalog):
    with pytest.raises(ValueError, match="magnitude_limit"):
        catalog.brighter_than(-5.0)
    with pytest.raises(ValueError, match="focal_length_m"):
        PinholeCamera.make(0.002, 5.5e-6, 1024, 1024)
