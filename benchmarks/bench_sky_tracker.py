#!/usr/bin/env python3
"""A sky star tracker's cost: one frame in tracking mode (windowed rendering, centroids, match
and solution), one lost-in-space frame, and a whole S3 run with two 10 Hz sky trackers as a ratio
to the same run with the paper's Gaussian trackers (both in this process, one after the
other)::

    .venv/bin/python benchmarks/bench_sky_tracker.py                    # frames + 5000-s runs
    .venv/bin/python benchmarks/bench_sky_tracker.py --duration 500     # shorter runs
    .venv/bin/python benchmarks/bench_sky_tracker.py --duration 0       # frames only

Frames: the default tracker (``!SkyStarTrackerConfig``) at random attitudes turning at 0.87 deg/s
(S3's body rate), each sequence first identified lost-in-space and then tracked; the first call of
each compiled kernel is made before timing (numba's compile or cache load is not a frame's cost).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from drake_att import rotations as rot
from drake_att.sensors.sky_star_tracker_plugin import SkyStarTrackerConfig, sky_tracker_model
from drake_att.sky_tracker import MODE_LOST_IN_SPACE, MODE_TRACKING, TrackingMemory


def frame_costs(sequences: int, frames: int, rate_deg_per_s: float) -> dict:
    config = SkyStarTrackerConfig()
    t0 = time.perf_counter()
    model = sky_tracker_model(config, 2026.0)
    build_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    warm = rot.quat_normalize(rng.standard_normal(4))
    model.frame(0.0, warm, np.zeros(3), TrackingMemory.empty(), rng)  # compile / load the kernels
    model.frame(0.1, warm, np.zeros(3), TrackingMemory(0.0, warm, math.nan, warm), rng)
    times = {MODE_TRACKING: [], MODE_LOST_IN_SPACE: []}
    for _ in range(sequences):
        q0 = rot.quat_normalize(rng.standard_normal(4))
        axis = rng.standard_normal(3)
        w = math.radians(rate_deg_per_s) * axis / np.linalg.norm(axis)
        memory = TrackingMemory.empty()
        for k in range(frames):
            q = rot.quat_multiply(q0, rot.rotvec_to_quat(w * 0.1 * k))
            t1 = time.perf_counter()
            f = model.frame(0.1 * k, q, w, memory, rng)
            dt = time.perf_counter() - t1
            memory = memory.after(f)
            if f.mode in times and f.valid:
                times[f.mode].append(dt)
    return {"build_s": build_s, "tracking": np.array(times[MODE_TRACKING]), "lis": np.array(times[MODE_LOST_IN_SPACE])}


def run_cost(name: str, duration_s: float) -> float:
    from drake_att.scenarios.builder import diagram_for
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load

    def shortened(d):
        return apply_overrides(load(name), [f"duration_s={d}", f"scoring.score_from_s={d / 2}"])

    diagram_for(shortened(2.0)).simulate(seed=1)  # kernels compiled or loaded, sky model built
    diagram = diagram_for(shortened(duration_s))
    t0 = time.process_time()
    diagram.simulate(seed=2)
    return time.process_time() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequences", type=int, default=50)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--rate", type=float, default=0.87, help="body rate (deg/s)")
    ap.add_argument("--duration", type=float, default=5000.0, help="S3 run length (s); 0: no runs")
    args = ap.parse_args(argv)
    c = frame_costs(args.sequences, args.frames, args.rate)
    tr, lis = c["tracking"] * 1e6, c["lis"] * 1e3
    print(f"model built (catalogue, index, identifier) in {c['build_s']:.2f} s")
    print(
        f"tracking frame: median {np.median(tr):.0f} us, 95th percentile {np.percentile(tr, 95):.0f} us "
        f"over {len(tr)} frames at {args.rate:g} deg/s"
    )
    print(
        f"lost-in-space frame: median {np.median(lis):.1f} ms, 95th percentile {np.percentile(lis, 95):.1f} ms "
        f"over {len(lis)} frames"
    )
    if args.duration > 0:
        gaussian = run_cost("cubesat_dual_star_tracker", args.duration)
        sky = run_cost("cubesat_dual_sky_tracker", args.duration)
        print(
            f"S3 run, {args.duration:g} s, two 10 Hz trackers (process CPU): Gaussian {gaussian:.1f} s, "
            f"sky {sky:.1f} s, ratio {sky / gaussian:.1f}x"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
