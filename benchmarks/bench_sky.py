#!/usr/bin/env python3
"""The sky's cost: loading the Hipparcos catalogue, moving it to an epoch, building the cone
index, and one cone search (the stars a tracker's field of view holds), per call::

    .venv/bin/python benchmarks/bench_sky.py                       # 20 deg field, 6.5 mag
    .venv/bin/python benchmarks/bench_sky.py --fov-deg 10 --magnitude-limit 7.5
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from drake_att.sky import SkyIndex, load_hipparcos


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fov-deg", type=float, default=20.0, help="full field of view (deg)")
    ap.add_argument("--magnitude-limit", type=float, default=6.5)
    ap.add_argument("--queries", type=int, default=20000)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    catalog = load_hipparcos()
    t1 = time.perf_counter()
    bright = catalog.at_epoch(2026.0).brighter_than(args.magnitude_limit)
    t2 = time.perf_counter()
    index = SkyIndex(bright)
    t3 = time.perf_counter()
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(args.queries, 3))
    half = math.radians(0.5 * args.fov_deg) * math.sqrt(2.0)  # the circle around a square field
    counts = np.empty(args.queries, dtype=int)
    t4 = time.perf_counter()
    for k, d in enumerate(directions):
        counts[k] = len(index.cone(d, half))
    t5 = time.perf_counter()
    print(f"catalogue: {len(catalog)} stars read in {t1 - t0:.2f} s")
    print(f"to epoch 2026.0 and cut at {args.magnitude_limit:g} mag: {len(bright)} stars in {1e3 * (t2 - t1):.1f} ms")
    print(f"index built in {1e3 * (t3 - t2):.1f} ms")
    print(
        f"cone search ({args.fov_deg:g} deg field, circle of {math.degrees(half):.1f} deg): "
        f"{1e6 * (t5 - t4) / args.queries:.1f} us per query over {args.queries} random directions; "
        f"stars per cone min / median / max {counts.min()} / {int(np.median(counts))} / {counts.max()}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
