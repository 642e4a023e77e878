#!/usr/bin/env python3
"""Star identification's cost per frame (us): lost-in-space (tetra3rs + our confirmation),
tracking from a prior, and the attitude solve alone, on the default tracker (20 deg field,
6.5 mag) over random attitudes with 0.2 px centroid noise; also the tetra3rs database build::

    .venv/bin/python benchmarks/bench_star_identification.py
    .venv/bin/python benchmarks/bench_star_identification.py --frames 200 --stars 15

``--stars N`` keeps only the N brightest stars of each frame (a tracker that reports N).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from drake_att import rotations as rot
from drake_att.sky import SkyIndex, load_hipparcos
from drake_att.star_attitude import solve_star_attitude
from drake_att.star_camera import PinholeCamera
from drake_att.star_identification import StarIdentifier, tetra3rs_database


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--stars", type=int, default=0, help="brightest stars kept per frame (0: all)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    camera = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024)
    catalog = load_hipparcos().at_epoch(2026.0).brighter_than(6.5)
    index = SkyIndex(catalog)
    t = time.perf_counter()
    tetra3rs_database(catalog, math.degrees(camera.fov_rad[0]))
    build = time.perf_counter() - t
    identifier = StarIdentifier(camera, catalog)
    rng = np.random.default_rng(args.seed)
    frames = []
    for _ in range(args.frames):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R = rot.quat_to_rotmat(q)
        near = index.cone(R[:, 2], camera.half_diagonal_fov_rad)
        uv, on = camera.project(catalog.unit_I[near] @ R)
        order = np.argsort(catalog.magnitude[near[on]], kind="stable")
        keep = order if args.stars <= 0 else order[: args.stars]
        z = uv[on][keep] + 0.2 * rng.normal(size=(len(keep), 2))
        prior = rot.quat_multiply(q, rot.rotvec_to_quat(rng.normal(size=3) * math.radians(1 / 60)))
        frames.append((z, prior, near[on][keep]))
    identifier.track(frames[0][0], 0.2, frames[0][1], math.radians(1 / 60))  # compile / warm up
    times = {"lost_in_space": [], "tracking": [], "solve": []}
    valid = {"lost_in_space": 0, "tracking": 0}
    for z, prior, ids in frames:
        t = time.perf_counter()
        valid["lost_in_space"] += identifier.lost_in_space(z, 0.2).valid
        times["lost_in_space"].append(time.perf_counter() - t)
        t = time.perf_counter()
        valid["tracking"] += identifier.track(z, 0.2, prior, math.radians(1 / 60)).valid
        times["tracking"].append(time.perf_counter() - t)
        t = time.perf_counter()
        solve_star_attitude(camera, z, catalog.unit_I[ids], 0.2)
        times["solve"].append(time.perf_counter() - t)
    n = [len(f[0]) for f in frames]
    print(f"tetra3rs database from our catalogue ({len(catalog)} stars): built in {build:.2f} s")
    print(f"{args.frames} frames, stars per frame min/median/max {min(n)}/{int(np.median(n))}/{max(n)}, 0.2 px")
    print(f"{'per frame':<16}{'median us':>10}{'p95 us':>10}{'valid':>8}")
    for name, ts in times.items():
        v = f"{valid[name]}" if name in valid else ""
        print(f"{name:<16}{np.median(ts) * 1e6:>10.0f}{np.percentile(ts, 95) * 1e6:>10.0f}{v:>8}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
