"""The star camera's geometry (drake_att.star_camera) against an independent projection written
here in polar form: a direction at angle theta from the boresight and azimuth alpha images at
radius f (tan theta)(1 + k1 tan^2 theta + k2 tan^4 theta) from the principal point, at azimuth alpha."""

import math

import numpy as np
import pytest

from drake_att.star_camera import PinholeCamera


def polar_projection(camera, d):
    d = d / np.linalg.norm(d)
    theta = math.acos(d[2])
    alpha = math.atan2(d[1], d[0])
    t = math.tan(theta)
    rho = camera.focal_length_m / camera.pixel_pitch_m * t * (1 + camera.k1 * t**2 + camera.k2 * t**4)
    return np.array([camera.width_px / 2 + rho * math.cos(alpha), camera.height_px / 2 + rho * math.sin(alpha)])


CAMERAS = [
    PinholeCamera.make(0.025, 5.5e-6, 1024, 1024),
    PinholeCamera.make(0.016, 4.8e-6, 1280, 1024, k1=0.05, k2=-0.01),
    PinholeCamera.make(0.05, 6.5e-6, 2048, 1536, k1=-0.08),
]


@pytest.mark.parametrize("camera", CAMERAS)
def test_projection_matches_the_polar_form_and_unproject_inverts_it(camera):
    rng = np.random.default_rng(3)
    half = camera.half_diagonal_fov_rad
    for _ in range(200):
        theta = half * math.sqrt(rng.uniform())
        alpha = rng.uniform(-math.pi, math.pi)
        d = np.array([math.sin(theta) * math.cos(alpha), math.sin(theta) * math.sin(alpha), math.cos(theta)])
        uv, on = camera.project(3.7 * d[None])
        np.testing.assert_allclose(uv[0], polar_projection(camera, d), atol=1e-9)
        np.testing.assert_allclose(camera.unproject(uv)[0], d, atol=1e-13)


@pytest.mark.parametrize("camera", CAMERAS)
def test_corners_are_at_the_half_diagonal_field_and_detector_bounds_hold(camera):
    corner = camera.unproject([[0.0, 0.0]])[0]
    assert math.acos(corner[2]) == pytest.approx(camera.half_diagonal_fov_rad, abs=1e-12)
    w, h = camera.width_px, camera.height_px
    uv = np.array([[1e-9, 1e-9], [w - 1e-9, h - 1e-9], [w + 1e-6, h / 2], [w / 2, -1e-6]])
    _, on = camera.project(camera.unproject(uv))
    assert on.tolist() == [True, True, False, False]
    _, on = camera.project([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert on.tolist() == [False, True]
    fx, fy = camera.fov_rad
    edge = camera.unproject([[w, h / 2]])[0]
    assert 2 * math.atan2(edge[0], edge[2]) == pytest.approx(fx, abs=1e-12)
    assert fy <= fx + 1e-12 if h <= w else fy > fx


@pytest.mark.parametrize("camera", CAMERAS)
def test_projection_jacobian_matches_finite_differences(camera):
    rng = np.random.default_rng(5)
    d = camera.unproject(rng.uniform([0, 0], [camera.width_px, camera.height_px], size=(20, 2)))
    J = camera.projection_jacobian(d)
    eps = 1e-7
    for k in range(3):
        phi = np.zeros(3)
        phi[k] = eps
        c, s = math.cos(eps), math.sin(eps)
        R = np.eye(3) * c + s * np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]]) / eps
        R += (1 - c) * np.outer(phi, phi) / eps**2
        up, _ = camera.project(d @ R.T)
        um, _ = camera.project(d @ R)
        np.testing.assert_allclose((up - um) / (2 * eps), J[:, :, k], rtol=1e-5, atol=1e-3)
    # rotation about the direction itself does not move the star
    np.testing.assert_allclose(np.einsum("nij,nj->ni", J, d), 0.0, atol=1e-6)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(focal_length_m=0.0), "focal_length_m"),
        (dict(focal_length_m=2.0), "focal_length_m"),
        (dict(focal_length_m=0.002), "focal_length_m"),  # 130 deg field
        (dict(pixel_pitch_m=1e-3), "pixel_pitch_m"),
        (dict(width_px=8), "width_px"),
        (dict(height_px=1.5), "height_px"),
        (dict(k1=20.0), "k1, k2"),
        (dict(k1=float("nan")), "k1"),
    ],
)
def test_bad_intrinsics_are_refused_in_one_line_naming_the_field(kwargs, field):
    args = dict(focal_length_m=0.025, pixel_pitch_m=5.5e-6, width_px=1024, height_px=1024)
    args.update(kwargs)
    with pytest.raises(ValueError) as e:
        PinholeCamera.make(**args, name="st1")
    assert str(e.value).startswith(f"st1.{field}:") and "\n" not in str(e.value)
    if kwargs == dict(focal_length_m=0.002):
        assert "diagonal field of view" in str(e.value)
