#!/usr/bin/env python3
"""A star tracker frame's image cost: windowed rendering (PSF, smear, noise, hot pixels, ADC)
plus centre-of-mass centroids, per frame, for 5, 10 and 20 stars, still and smeared::

    .venv/bin/python benchmarks/bench_star_image.py
    .venv/bin/python benchmarks/bench_star_image.py --frames 5000 --rate-deg-per-s 1.0

The default camera and detector: 16 mm, 5.5 um, 1024x1024 (~20 deg), drake_att.star_image's
DetectorModel defaults; stars of magnitude 2-6.5 at random positions; the smeared case turns the
sensor at ``--rate-deg-per-s`` about an axis across the boresight.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from drake_att.star_camera import PinholeCamera
from drake_att.star_image import DetectorModel, draw_hot_pixels, pixel_velocity, simulate_frame


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--rate-deg-per-s", type=float, default=1.0, help="body rate of the smeared case")
    args = ap.parse_args(argv)
    camera = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024)
    detector = DetectorModel.make()
    hot = draw_hot_pixels(detector, camera, seed=1)
    rng = np.random.default_rng(0)
    w = np.array([math.radians(args.rate_deg_per_s), 0.0, 0.0])
    print(f"{'stars':>5} {'rate deg/s':>10} {'smear px':>8} {'us/frame':>9}")
    for n in (5, 10, 20):
        uv = rng.uniform(20.0, 1000.0, size=(n, 2))
        flux = detector.electron_rate(rng.uniform(2.0, 6.5, size=n))
        d = camera.unproject(uv)
        for rate in (0.0, args.rate_deg_per_s):
            uv_rate = pixel_velocity(camera, d, w * (rate / args.rate_deg_per_s if args.rate_deg_per_s else 0.0))
            smear = float(np.max(np.hypot(*uv_rate.T))) * detector.exposure_s
            for _ in range(50):  # warm-up
                simulate_frame(camera, detector, uv, uv_rate, flux, rng, hot)
            t0 = time.perf_counter()
            for _ in range(args.frames):
                simulate_frame(camera, detector, uv, uv_rate, flux, rng, hot)
            us = (time.perf_counter() - t0) / args.frames * 1e6
            print(f"{n:5d} {rate:10.2f} {smear:8.2f} {us:9.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
