"""The sky star tracker in a scenario (!SkyStarTrackerConfig): frames rendered from the catalogue,
identified (lost-in-space first, then tracking), solved with a covariance the MEKF uses.

Errors are computed here from the logged truth and measurement quaternions with scipy, not with
the library's metrics; the tracking memory's extrapolation against a constant-rate rotation
written here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drake_att.scenarios.builder import diagram_for
from drake_att.scenarios.config import load_scenario
from drake_att.sky_tracker import MODE_LOST_IN_SPACE, MODE_TRACKING, REASON_CODE, FrameResult, TrackingMemory
from drake_att.validation import ConfigError

ARCSEC = math.pi / 180 / 3600

SCENARIO = """
name: sky_small
duration_s: {duration}
seed: 1
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}}
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  initial_attitude_rpy_deg: [2.0, -2.0, 2.0]
  initial_rate_deg_per_s: [-0.5, 0.5, 0.5]
sensors:
- !GyroConfig {{name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.56, rrw_deg_per_h15: 123.75,
               initial_bias_deg_per_h: [12.0, 12.0, 12.0]}}
- !SkyStarTrackerConfig
  name: st1
  period_s: 0.1
  mounting: !PaperS3Eq7Mounting {{psi_phi_theta_deg: [-90.0, 45.0, -90.0]}}
  {extra}
estimators:
- !MekfConfig {{name: single, period_s: 1.0, gyro: gyro, star_trackers: [st1]}}
scoring: {{score_from_s: 10.0, convergence_threshold_deg: 0.05}}
"""


def scenario(duration=30.0, extra="detector: {exposure_s: 0.05}"):
    return load_scenario(SCENARIO.format(duration=duration, extra=extra))


def _last_per_time(t, x):
    t, x = np.asarray(t), np.asarray(x).reshape(len(t), -1)
    keep = np.r_[np.diff(t) > 1e-9, True]
    return t[keep], x[keep]


def _rotation(q_wxyz):
    return Rotation.from_quat(np.asarray(q_wxyz)[:, [1, 2, 3, 0]])


@pytest.fixture(scope="module")
def run():
    return diagram_for(scenario()).simulate(seed=1)


def _frames(run):
    t, status = _last_per_time(*run.signals["st1/frame_status"])
    _, meas = _last_per_time(*run.signals["st1/star_tracker_measurement"])
    _, cov = _last_per_time(*run.signals["st1/covariance_S"])
    t_q, q_true = _last_per_time(*run.signals[run.metadata["truth"]["attitude"]])
    idx = np.searchsorted(t_q, t - 1e-9)
    return t, status, meas, cov.reshape(-1, 3, 3), q_true[idx]


def test_frames_are_identified_first_lost_in_space_then_tracked_and_never_wrong(run):
    t, status, meas, _, _ = _frames(run)
    valid, mode, identified, wrong = status[:, 1], status[:, 2], status[:, 5], status[:, 6]
    np.testing.assert_allclose(status[:, 0], meas[:, 0])  # one frame, one time
    assert mode[0] == MODE_LOST_IN_SPACE and valid[0] == 1
    assert np.mean(mode[1:] == MODE_TRACKING) > 0.95
    assert np.mean(valid) > 0.99
    assert np.all(wrong == 0) and np.all(identified[valid == 1] >= 4)


def test_each_frame_is_the_truth_at_its_time_within_its_covariance(run):
    """Measurement ``q_IS`` against the truth ``q_IB (t_k) q_BS`` (q_BS from the logged first
    frame's geometry is not needed: the error is computed in S from the two rotations)."""
    from drake_att.sensors.star_tracker_plugin import PaperS3Eq7Mounting, star_tracker_mounting

    q_BS = star_tracker_mounting(
        type("C", (), {"mounting": PaperS3Eq7Mounting([-90.0, 45.0, -90.0])})()  # type: ignore[arg-type]
    )
    t, status, meas, cov, q_true = _frames(run)
    ok = status[:, 1] == 1
    R_IS_true = _rotation(q_true[ok]) * Rotation.from_quat(np.r_[q_BS[1:], q_BS[0]])
    e = (R_IS_true.inv() * _rotation(meas[ok, 2:6])).as_rotvec()  # error in S
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov[ok]), e)
    n = len(nees)
    assert n > 250
    # sanity of the size: cross-boresight arcsec-level, boresight tens of arcsec at most
    assert np.sqrt(np.mean(e[:, :2] ** 2)) < 5 * ARCSEC and np.sqrt(np.mean(e[:, 2] ** 2)) < 60 * ARCSEC
    # consistent: consecutive frames share stars and pixel phase, so use a wide band on the mean
    assert 1.0 < np.mean(nees) < 6.0, np.mean(nees)
    assert np.all(nees < 200)


def test_the_mekf_uses_each_frames_covariance_and_converges(run):
    meta = run.metadata["estimators"]["single"]["signals"]
    _, status = _last_per_time(*run.signals[meta["status"]])
    _, q_hat = _last_per_time(*run.signals[meta["attitude"]])
    t_q, q_true = _last_per_time(*run.signals[run.metadata["truth"]["attitude"]])
    t = status[:, 0]  # the estimate's own time
    idx = np.searchsorted(t_q, t - 1e-9)
    err = np.degrees((_rotation(q_true[idx]).inv() * _rotation(q_hat)).magnitude())
    assert err[t >= 20].max() < 0.01
    assert status[-1, 1] >= 29 and status[-1, 2] == 0  # used, skipped


def test_same_seed_same_frames_other_seed_other_frames(run):
    again = diagram_for(scenario()).simulate(seed=1)
    other = diagram_for(scenario()).simulate(seed=2)
    a = run.signals["st1/star_tracker_measurement"][1]
    np.testing.assert_array_equal(a, again.signals["st1/star_tracker_measurement"][1])
    assert not np.array_equal(a, other.signals["st1/star_tracker_measurement"][1])


def test_tracking_memory_extrapolates_a_constant_rate():
    w_S = np.radians([0.3, -0.2, 0.5])

    def q_at(t):  # a constant body-fixed rate: q(t) = q0 exp(w t), written with scipy
        r = Rotation.from_rotvec([0.1, 0.2, 0.3]) * Rotation.from_rotvec(w_S * t)
        x, y, z, w = r.as_quat()
        return np.array([w, x, y, z])

    frame = lambda t: FrameResult(t, True, q_at(t), np.eye(3) * 1e-12)  # noqa: E731
    memory = TrackingMemory.empty().after(frame(1.0)).after(frame(1.1))
    q, age = memory.prior(1.2, 1.0)
    assert age == pytest.approx(0.1)
    assert (_rotation(q[None]).inv() * _rotation(q_at(1.2)[None])).magnitude()[0] < 1e-12
    assert memory.prior(2.2, 1.0) is None  # older than the memory's age limit
    invalid = FrameResult.not_taken(1.2)
    assert memory.after(invalid) == memory
    assert invalid.reason == REASON_CODE["not_taken"]


@pytest.mark.parametrize(
    "extra, field",
    [
        ("identification: {magnitude_limit: -3.0}", "identification.magnitude_limit"),
        ("identification: {magnitude_limit: -1.8, render_magnitude_limit: -1.8}", "identification.magnitude_limit"),
        ("camera: {focal_length_mm: 2.0}", "camera.focal_length_mm"),  # a 130-deg field
        ("camera: {distortion_k1: 9.0}", "camera.distortion_k1, distortion_k2"),
        ("camera: {focal_length_mm: 5000.0}", "camera.focal_length_mm"),
        ("camera: {pixel_pitch_um: 0.1}", "camera.pixel_pitch_um"),
        ("detector: {exposure_s: 0.5}", "detector.exposure_s"),
        ("identification: {render_magnitude_limit: 6.0}", "identification.render_magnitude_limit"),
        ("identification: {max_stars: 3, min_stars: 5}", "identification.max_stars"),
        ("filter_covariance: diagonal", "filter_covariance"),
        ("mode: images", "mode"),
    ],
)
def test_bad_settings_are_refused_in_one_line_naming_the_field(extra, field):
    with pytest.raises(ConfigError) as e:
        diagram_for(scenario(extra=extra))
    message = str(e.value)
    assert "st1" in message and field in message and "\n" not in message, message


def test_a_catalogue_that_fails_to_load_is_refused_in_one_line(tmp_path, monkeypatch):
    from drake_att import sky
    from drake_att.sensors import sky_star_tracker_plugin as plugin

    broken = tmp_path / "hip2.dat"
    broken.write_text("not a catalogue\n")
    monkeypatch.setattr(sky, "hipparcos_path", lambda: broken)
    plugin._hipparcos.cache_clear()
    try:
        with pytest.raises(ConfigError) as e:
            diagram_for(scenario())
    finally:
        plugin._hipparcos.cache_clear()
    message = str(e.value)
    assert "st1" in message and "catalog" in message and str(broken) in message and "\n" not in message, message


def test_stray_light_factor_is_the_sum_of_the_bodies_power_laws():
    """Each body's term written here with arccos: (cone / angle)^3 outside its cone, 1 at its edge;
    a body the Earth hides adds nothing."""
    from drake_att.exclusion import ExclusionCones, stray_light_factor

    cones = ExclusionCones(40.0, 20.0, 10.0, 100e3)
    r = np.array([7.0e6, 0.0, 0.0])
    b = np.array([0.0, 1.0, 0.0])  # 90 deg from nadir
    sun = r + 1.5e11 * np.array([0.0, math.cos(math.radians(60)), math.sin(math.radians(60))])  # 60 deg off
    moon = r + 3.8e8 * np.array([0.0, math.cos(math.radians(25)), -math.sin(math.radians(25))])  # 25 deg off

    def angle(a, c):
        return math.acos(np.dot(a, c) / np.linalg.norm(a) / np.linalg.norm(c))

    limb = math.asin((6378137.0 + 100e3) / 7.0e6)
    expected = (
        (40 / 60) ** 3 + (math.radians(20) / (angle(b, -r) - limb)) ** 3 + (10 / math.degrees(angle(b, moon - r))) ** 3
    )
    assert stray_light_factor(b.tolist(), r.tolist(), sun.tolist(), moon.tolist(), cones) == pytest.approx(expected)
    # the Moon behind the Earth adds nothing; a body inside its cone counts as at its edge
    hidden = (r + 3.8e8 * np.array([-1.0, 0.0, 0.0])).tolist()
    assert stray_light_factor(b.tolist(), r.tolist(), sun.tolist(), hidden, cones) == pytest.approx(
        expected - (10 / math.degrees(angle(b, moon - r))) ** 3
    )
    near = (r + 1.5e11 * b).tolist()
    at_edge = stray_light_factor(b.tolist(), r.tolist(), near, hidden, cones)
    assert at_edge == pytest.approx(1.0 + (math.radians(20) / (angle(b, -r) - limb)) ** 3)


def test_stray_light_costs_stars_and_accuracy():
    """The same attitudes with and without 2e4 e-/s per pixel of stray light: fewer stars, larger
    sigmas."""
    from drake_att import rotations as rot
    from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model

    model = sky_tracker_model(SkyStarTrackerConfig(), 2026.0)
    rng = np.random.default_rng(3)
    stars, sigmas = {0.0: [], 2e4: []}, {0.0: [], 2e4: []}
    for _ in range(30):
        q = rot.quat_normalize(rng.standard_normal(4))
        for stray in stars:  # lost-in-space: every star in the field is rendered
            f = model.frame(0.0, q, np.zeros(3), TrackingMemory.empty(), np.random.default_rng(7), stray)
            stars[stray].append(f.stars_detected)
            if f.valid:
                sigmas[stray].append(math.sqrt(f.covariance_S[0, 0]))
    assert np.mean(stars[2e4]) < 0.7 * np.mean(stars[0.0])
    assert len(sigmas[2e4]) > 20 and np.median(sigmas[2e4]) > 1.3 * np.median(sigmas[0.0])


def test_a_tracker_with_exclusion_cones_loses_the_frames_inside_them():
    text = SCENARIO.format(
        duration=20.0,
        extra="exclusion: {sun_deg: 45.0, earth_limb_deg: 25.0, moon_deg: 12.0}\n  detector: {exposure_s: 0.05}",
    ).replace(
        "plant: !RigidBodyConfig",
        'orbit: !KeplerOrbitConfig {epoch_utc: "2026-06-21T00:00:00Z", semi_major_axis_km: 6928.137,\n'
        "                           eccentricity: 0.001, inclination_deg: 97.5}\nplant: !RigidBodyConfig",
    )
    run = diagram_for(load_scenario(text)).simulate(seed=1)
    _, status = _last_per_time(*run.signals["st1/frame_status"])
    _, excl = _last_per_time(*run.signals["st1/exclusion"])
    blinded = excl[:, 1] != 0
    np.testing.assert_array_equal(status[blinded, 7], REASON_CODE["not_taken"])
    assert np.all(status[blinded, 1] == 0)
    assert np.all(status[~blinded, 1] == 1) or np.mean(status[~blinded, 1]) > 0.95


def test_faults_corrupt_a_sky_tracker_like_any_quaternion_sensor():
    """NaN samples at 10 and 20 s and an outage over [14, 17) s: the MEKF skips exactly those
    steps (counted), the tracker itself keeps its frames."""
    text = SCENARIO.format(duration=25.0, extra="detector: {exposure_s: 0.05}").replace(
        "estimators:",
        "- !SensorFaultsConfig {name: st1_faults, sensor: st1, nan_times_s: [10.0, 20.0],\n"
        "                       outage_windows_s: [[14.0, 17.0]]}\nestimators:",
    )
    run = diagram_for(load_scenario(text)).simulate(seed=1)
    meta = run.metadata["estimators"]["single"]["signals"]
    _, status = _last_per_time(*run.signals[meta["status"]])
    skipped = np.diff(status[:, 2], prepend=0.0)
    t = status[:, 0]
    hit = {10.0, 14.0, 15.0, 16.0, 20.0}
    assert {float(x) for x in t[skipped > 0]} == hit
    _, frames = _last_per_time(*run.signals["st1/frame_status"])
    assert np.mean(frames[:, 1]) > 0.99


def test_the_double_star_cut_from_its_definition():
    """Stars placed here: a pair 1 px apart of equal brightness (both cut), a star with a neighbour
    3 mag fainter at 1 px (kept; the faint one has a bright neighbour: cut), a star alone (kept),
    and a pair 10 px apart (kept)."""
    from drake_att.sky import StarCatalog
    from drake_att.sky_tracker import DOUBLE_STAR_MAGNITUDE_GAP, without_close_pairs

    px = 5.5e-6 / 0.016  # one pixel (rad)

    def at(x_px, y_px):
        d = np.array([x_px * px, y_px * px, 1.0])
        return d / np.linalg.norm(d)

    unit = np.array([at(0, 0), at(1, 0), at(100, 0), at(101, 0), at(-200, 50), at(300, 300), at(310, 300)])
    mag = np.array([5.0, 5.0, 4.0, 7.0, 5.0, 5.0, 5.0])
    hip = np.arange(1, 8)
    sky = StarCatalog(hip, unit, np.zeros_like(unit), mag, np.zeros(7), 2026.0)
    kept = without_close_pairs(sky, sky, 3 * px, DOUBLE_STAR_MAGNITUDE_GAP)
    assert kept.hip.tolist() == [3, 5, 6, 7]
    np.testing.assert_array_equal(kept.unit_I, unit[[2, 4, 5, 6]])
    np.testing.assert_array_equal(kept.magnitude, mag[[2, 4, 5, 6]])
    assert kept.b_minus_v.shape == (4,) and kept.epoch_jyear == 2026.0
    # identification stars only (the bright ones) against every rendered neighbour
    bright = StarCatalog(hip[mag < 6], unit[mag < 6], np.zeros((6, 3)), mag[mag < 6], np.zeros(6), 2026.0)
    assert without_close_pairs(bright, sky, 3 * px, DOUBLE_STAR_MAGNITUDE_GAP).hip.tolist() == [3, 5, 6, 7]
    assert without_close_pairs(sky, sky, 0.0, DOUBLE_STAR_MAGNITUDE_GAP) is sky  # no cut


def test_a_frame_without_enough_stars_is_invalid_with_its_reason():
    from drake_att import rotations as rot
    from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model
    from drake_att.sky_tracker import IdentificationSettings, SkyTrackerModel

    base = sky_tracker_model(SkyStarTrackerConfig(), 2026.0)
    catalog = base.render_catalog  # already at the epoch
    model = SkyTrackerModel(base.camera, base.detector, catalog, IdentificationSettings(min_stars=500, max_stars=500))
    q = rot.quat_normalize(np.array([0.3, -0.2, 0.5, 0.7]))
    for memory in (TrackingMemory.empty(), TrackingMemory(0.0, q, math.nan, rot.quat_identity())):
        f = model.frame(0.1, q, np.zeros(3), memory, np.random.default_rng(1))
        assert not f.valid and f.reason == REASON_CODE["too_few_stars"] and f.mode == MODE_LOST_IN_SPACE
        np.testing.assert_array_equal(f.q_IS_meas, [1.0, 0.0, 0.0, 0.0])
        np.testing.assert_array_equal(f.covariance_S, np.eye(3))
        assert f.stars_detected > 4 and f.stars_identified == 0
        np.testing.assert_array_equal(f.status_vector()[[0, 1, 2, 7]], [0.1, 0.0, MODE_LOST_IN_SPACE, f.reason])


@pytest.mark.parametrize(
    "settings, field",
    [
        (dict(magnitude_limit=6.5, render_magnitude_limit=6.0), "st9.render_magnitude_limit"),
        (dict(min_stars=6, max_stars=5), "st9.max_stars"),
        (dict(prior_sigma_rad=0.0), "st9.prior_sigma_rad"),
        (dict(max_track_age_s=-1.0), "st9.max_track_age_s"),
    ],
)
def test_model_settings_are_checked_in_one_line(settings, field):
    from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model
    from drake_att.sky_tracker import IdentificationSettings, SkyTrackerModel

    base = sky_tracker_model(SkyStarTrackerConfig(), 2026.0)
    with pytest.raises(ValueError) as e:
        SkyTrackerModel(base.camera, base.detector, base.render_catalog, IdentificationSettings(**settings), name="st9")
    assert str(e.value).startswith(field + ":") and "\n" not in str(e.value)


def test_a_tracking_frame_reads_the_windows_of_the_brightest_predicted_stars():
    """The window rule written here over the whole identification catalogue (no sky index): the
    ``max_stars`` brightest stars (ties by catalogue order) predicted at the prior with their
    whole window on the detector, seen where the true image centre is within ``h - 1`` px of
    the prediction; priors from 0 to ~6 px off, some stars lost."""
    from drake_att import rotations as rot
    from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model

    model = sky_tracker_model(SkyStarTrackerConfig(), 2026.0)
    cam, h = model.camera, model.detector.window_half_size_px
    ident = model._identified_sky.catalog
    render_of = {hip: k for k, hip in enumerate(model.render_catalog.hip.tolist())}
    rng = np.random.default_rng(12)
    pixel = cam.pixel_pitch_m / cam.focal_length_m
    lost = 0
    for trial in range(40):
        q_true = rot.quat_normalize(rng.standard_normal(4))
        q_prior = rot.quat_multiply(q_true, rot.rotvec_to_quat(rng.normal(0.0, (trial % 4) * pixel, size=3)))
        R_true, R_prior = rot.quat_to_rotmat(q_true), rot.quat_to_rotmat(q_prior)
        uv_pred, front = cam.project(ident.unit_I @ R_prior)
        with np.errstate(invalid="ignore"):
            inside = (
                (ident.unit_I @ R_prior[:, 2] > 0)
                & (uv_pred[:, 0] >= h + 1)
                & (uv_pred[:, 0] <= cam.width_px - h - 1)
                & (uv_pred[:, 1] >= h + 1)
                & (uv_pred[:, 1] <= cam.height_px - h - 1)
            )
        candidates = np.flatnonzero(inside)
        chosen = candidates[np.lexsort((candidates, ident.magnitude[candidates]))][: model.settings.max_stars]
        want_index, want_uv = [], []
        for j in chosen:
            r = render_of[int(ident.hip[j])]
            uv_true = cam.project(model.render_catalog.unit_I[r] @ R_true)[0][0]
            if np.all(np.abs(uv_true - uv_pred[j]) <= h - 1):
                want_index.append(r)
                want_uv.append(uv_true)
        lost += len(chosen) - len(want_index)
        index, uv = model.tracked_windows(q_prior, R_true)
        assert index.tolist() == want_index, trial
        np.testing.assert_allclose(uv, np.reshape(want_uv, (-1, 2)), atol=1e-9)
    assert lost > 0  # the rule's second half was exercised


def test_the_detector_config_exposes_every_checked_detector_field_with_its_range():
    import dataclasses

    from drake_att.sensors.sky_star_tracker_plugin import SkyDetectorConfig
    from drake_att.star_image import DetectorModel

    model_fields = set(DetectorModel.RANGES) | set(DetectorModel.INT_RANGES)
    config_fields = {f.name for f in dataclasses.fields(SkyDetectorConfig)} - {"hot_pixel_seed"}
    assert config_fields == model_fields == set(SkyDetectorConfig.RANGES) - {"hot_pixel_seed"}
    for key, (lo, hi, unit, _, _) in DetectorModel.RANGES.items():
        if key != "zero_point_photons_per_m2_s":  # 0 is the config's "default"
            assert SkyDetectorConfig.RANGES[key][:3] == (lo, hi, unit)
        assert getattr(SkyDetectorConfig(), key) == getattr(DetectorModel(), key) or key.startswith("zero_point")


def test_vector_observations_are_the_identified_stars_within_their_sigma():
    """Over 300 frames at random attitudes turning at S3's rate: each identified direction
    against its catalogue reference seen from the true attitude (scipy), the tangent error
    (the cross product) squared and summed, over 2 x the stars x the frame's sigma^2, is 1
    within 10% (~4000 stars; the sigma is each frame's RMS, so the sum is the definition);
    the references are the catalogue's directions of the stars identified."""
    from drake_att import rotations as rot
    from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model

    model = sky_tracker_model(SkyStarTrackerConfig(), 2026.0)
    ident = model._identified_sky.catalog
    rng = np.random.default_rng(31)
    ratio_sum, stars, frames = 0.0, 0, 0
    for _ in range(300):
        q = rot.quat_normalize(rng.standard_normal(4))
        axis = rng.standard_normal(3)
        w = math.radians(0.87) * axis / np.linalg.norm(axis)
        f = model.frame(0.1, q, w, TrackingMemory(0.0, q, math.nan, q), rng, vectors=True)
        if not f.valid:
            assert f.directions_S.shape == (0, 3) and f.references_I.shape == (0, 3)
            continue
        frames += 1
        m = f.stars_identified
        assert f.directions_S.shape == f.references_I.shape == (m, 3)
        np.testing.assert_allclose(np.linalg.norm(f.directions_S, axis=1), 1.0, atol=1e-12)
        # every reference is a catalogue star's direction
        assert all(np.any(np.all(ident.unit_I == r, axis=1)) for r in f.references_I)
        seen = Rotation.from_quat(np.r_[q[1:], q[0]]).inv().apply(f.references_I)  # in S
        tangent = np.linalg.norm(np.cross(f.directions_S, seen), axis=1)
        ratio_sum += float(np.sum(tangent**2)) / (2.0 * f.vector_sigma_rad**2)
        stars += m
        assert 0.5 * ARCSEC < f.vector_sigma_rad < 30 * ARCSEC
    assert frames > 280 and stars > 3000
    assert 0.9 < ratio_sum / stars < 1.1, ratio_sum / stars
    # without asking, a frame carries no stars, and nothing else changes
    q = rot.quat_normalize(rng.standard_normal(4))
    with_vectors = model.frame(
        0.1, q, np.zeros(3), TrackingMemory(0.0, q, math.nan, q), np.random.default_rng(2), 0.0, True
    )
    plain = model.frame(0.1, q, np.zeros(3), TrackingMemory(0.0, q, math.nan, q), np.random.default_rng(2))
    assert with_vectors.valid and plain.directions_S.shape == (0, 3) and plain.vector_sigma_rad == 0.0
    np.testing.assert_array_equal(plain.q_IS_meas, with_vectors.q_IS_meas)
    np.testing.assert_array_equal(plain.covariance_S, with_vectors.covariance_S)


def test_a_vectors_mode_tracker_feeds_an_mekf_its_stars():
    scenario_v = scenario(duration=30.0, extra="mode: vectors")
    run = diagram_for(scenario_v).simulate(seed=1)
    meta = run.metadata["estimators"]["single"]["signals"]
    _, status = _last_per_time(*run.signals[meta["status"]])
    _, q_hat = _last_per_time(*run.signals[meta["attitude"]])
    t_q, q_true = _last_per_time(*run.signals[run.metadata["truth"]["attitude"]])
    t = status[:, 0]
    idx = np.searchsorted(t_q, t - 1e-9)
    err = np.degrees((_rotation(q_true[idx]).inv() * _rotation(q_hat)).magnitude())
    assert err[t >= 20].max() < 0.01
    _, frames = _last_per_time(*run.signals["st1/frame_status"])
    at_steps = frames[np.isin(np.round(frames[:, 0], 6), np.round(t, 6))]
    # every frame an estimator step reads is used or skipped and counted (the gate rejects the
    # first few: the initial attitude error is thousands of the stars' sigmas)
    assert np.all(at_steps[:, 1] == 1)
    assert status[-1, 1] + status[-1, 2] == len(at_steps) and status[-1, 1] >= len(at_steps) - 5


def test_the_rate_sweeps_interval_is_students_t_over_the_sequences():
    import sys
    from pathlib import Path

    from scipy import stats

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "diagrams"))
    from sky_rate_sweep import over_sequences

    x = np.array([1.0, 0.9, 0.7, 1.0, 0.6, 0.95, 0.8, 1.0])
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=x.std(ddof=1) / math.sqrt(len(x)))
    assert over_sequences(x) == pytest.approx((lo, min(hi, 1.0)), rel=1e-4)
    assert over_sequences([1.0, 1.0, 1.0]) == (1.0, 1.0)
    assert over_sequences([0.0, 0.0, 0.1]) == pytest.approx((0.0, 0.1 / 3 + stats.t.ppf(0.975, 2) * 0.1 / 3), rel=1e-3)
    assert over_sequences([0.5]) == (0.0, 1.0)  # one sequence: no spread to estimate
