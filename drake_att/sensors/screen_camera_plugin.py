"""Sensor plug-in: paper S2's indoor star tracker camera and star screen
(:class:`drake_att.systems.screen_camera.ScreenCamera`). YAML tag ``!ScreenCameraConfig``.

The layout is the paper's: a square screen of side ``screen_size_mm`` (1200) at ``h_mm``
(2000) above the table's rotation centre, the camera ``camera_to_screen_mm`` (1800) from the
screen, i.e. ``R0_B = [0, 0, -(h - h1)]`` = 200 mm towards the screen, looking along ``-z_B``.
``star_count`` stars are placed uniformly at random on the screen by ``pattern_seed`` (the
screen is hardware: it does not change with the run's seed).

**The camera (the paper gives none; documented choice).** A 2048 x 2048 px, 5.5 um machine
-vision sensor (CMV4000 class, 11.26 mm square) behind a 12 mm lens: 50.3 deg field of view
per side (67 deg diagonal), so from 1.8 m it sees the whole screen (36.9 deg per side) with
about 6.7 deg of margin per side; one pixel is 0.026 deg. Centroid noise
``centroid_noise_px`` and quantization ``quantization_px`` default to 0 (the paper's "no
extraction error"). Output kind "camera" (:class:`~drake_att.contract.CameraCentroids`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import numpy as np

from drake_att import validation
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import SensorOutput, register_sensor
from drake_att.screen_geometry import ScreenCameraGeometry, random_star_pattern
from drake_att.systems.screen_camera import CameraNoise, ScreenCamera


@dataclass
class ScreenCameraConfig:
    """The star screen and the camera that images it (lengths in mm, pixel pitch in um)."""

    name: str = "camera"
    period_s: float = 0.2
    star_count: int = 50
    pattern_seed: int = 1
    screen_size_mm: float = 1200.0
    h_mm: float = 2000.0
    camera_to_screen_mm: float = 1800.0
    focal_length_mm: float = 12.0
    pixels: List[int] = field(default_factory=lambda: [2048, 2048])
    pixel_pitch_um: float = 5.5
    centroid_noise_px: float = 0.0
    quantization_px: float = 0.0
    dropout_probability: float = 0.0
    outage_windows_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (k, 2) [start, end]


def camera_geometry(c: ScreenCameraConfig) -> ScreenCameraGeometry:
    """The :class:`ScreenCameraGeometry` of a (validated) config, SI units."""
    h = c.h_mm * 1e-3
    pitch = c.pixel_pitch_um * 1e-6
    return ScreenCameraGeometry(
        random_star_pattern(int(c.star_count), c.screen_size_mm * 1e-3, h, int(c.pattern_seed)),
        h,
        np.array([0.0, 0.0, -(c.h_mm - c.camera_to_screen_mm) * 1e-3]),
        c.focal_length_mm * 1e-3,
        (c.pixels[0] * pitch, c.pixels[1] * pitch),
        pitch,
    )


def camera_noise(c: ScreenCameraConfig) -> CameraNoise:
    pitch = c.pixel_pitch_um * 1e-6
    return CameraNoise.make(
        c.name,
        c.centroid_noise_px * pitch,
        c.quantization_px * pitch,
        c.dropout_probability,
        [tuple(w) for w in np.reshape(c.outage_windows_s, (-1, 2))],
    )


def validate_screen_camera(path: str, c: ScreenCameraConfig, checks) -> None:
    cfg.check_positive(f"{path}.period_s", c.period_s)
    validation.check_int(f"{path}.star_count", c.star_count, 1, cfg.ConfigError)
    validation.check_seed(f"{path}.pattern_seed", c.pattern_seed, cfg.ConfigError)
    for f in ("screen_size_mm", "h_mm", "camera_to_screen_mm", "focal_length_mm", "pixel_pitch_um"):
        cfg.check_positive(f"{path}.{f}", getattr(c, f))
    if not c.camera_to_screen_mm < c.h_mm:
        cfg.fail(
            f"{path}.camera_to_screen_mm",
            c.camera_to_screen_mm,
            f"must be < h_mm = {c.h_mm} (the camera sits between the rotation centre and the screen)",
        )
    if not (isinstance(c.pixels, list) and len(c.pixels) == 2):
        cfg.fail(f"{path}.pixels", c.pixels, "need [columns, rows]")
    for i, v in enumerate(c.pixels):
        validation.check_int(f"{path}.pixels[{i}]", v, 1, cfg.ConfigError)
    cfg.check_nonnegative(f"{path}.centroid_noise_px", c.centroid_noise_px)
    cfg.check_nonnegative(f"{path}.quantization_px", c.quantization_px)
    cfg.check_finite(f"{path}.dropout_probability", c.dropout_probability)
    if not 0.0 <= c.dropout_probability < 1.0:
        cfg.fail(f"{path}.dropout_probability", c.dropout_probability, "must be in [0, 1)")
    if np.size(c.outage_windows_s) and np.ndim(c.outage_windows_s) != 2:
        cfg.fail(f"{path}.outage_windows_s", c.outage_windows_s, "must be a list of [start, end] (s)")
    for j, w in enumerate(np.reshape(c.outage_windows_s, (-1, 2))):
        if not (np.all(np.isfinite(w)) and w[1] > w[0]):
            cfg.fail(f"{path}.outage_windows_s[{j}]", w, "must be [start, end] (s) with end > start")


def configure_screen_camera(ctx, c: ScreenCameraConfig, camera, context) -> None:
    camera.set_noise(context, camera_noise(c))


@register_sensor(
    ScreenCameraConfig,
    output=lambda c, sensors: SensorOutput("camera", "camera_centroids", c.period_s),
    validate=validate_screen_camera,
    logged_ports=lambda c: [("stars_in_view", c.period_s)],
    parameters=("centroid_noise_px", "quantization_px", "dropout_probability", "outage_windows_s"),
    configure=configure_screen_camera,
)
def build_screen_camera(ctx, c: ScreenCameraConfig):
    camera = ctx.builder.AddSystem(ScreenCamera(c.name, c.period_s, camera_geometry(c), camera_noise(c)))
    ctx.builder.Connect(ctx.truth.GetOutputPort("q_IB"), camera.GetInputPort("q_IB"))
    return camera
