#!/usr/bin/env python3
"""Time paper S2's indoor star tracker: one tracking frame, one identification pass, one
particle-swarm initialization, and the whole ``s2_indoor_dynamic`` scenario.

    python benchmarks/bench_indoor_star_tracker.py            # ~1-2 min
    python benchmarks/bench_indoor_star_tracker.py --quick    # fewer frames and seeds, 60-s scenario

What is timed (``time.perf_counter``, one process, nothing else between the timed calls):

* **tracking frame**: ``IndoorStarTrackerSolver.solve(frame, A0)`` with ``A0`` = the previous
  frame's solution, on the default camera (:class:`ScreenCameraConfig`: 12 mm lens, 2048 px
  of 5.5 um; pattern seed 1) with 7 and 50 stars, 0.1 px centroid noise, frames at 5 Hz along
  the dynamic test's turn (0.05 / 0.10 / 0.01 deg/s from 2 / 3 / 0.5 deg), the estimator
  config's solver settings (tolerance 0.01 deg, <= 10 iterations); TRIAD and least squares.
  Identification + iteration, not the image (the frames are made before the clock starts).
* **identification pass**: ``AngleMatcher.identify`` of the centre-referenced directions (one
  pass of step 4; a frame runs it once per iteration).
* **PSO initialization**: ``solver.acquire`` (5 particles, +-10 deg about zero) on a 50-star
  frame at 2 / 3 / 0.5 deg, one seed per call (the seed drives the frame's noise and the swarm);
  median over the seeds, with the generations each took.
* **scenario**: ``ScenarioDiagram.simulate`` of ``s2_indoor_dynamic`` (140 s) on one diagram
  with ``estimators=[]`` (sensors only), the camera-alone estimator, the gyro-fused one, both
  (wall and process CPU time, one run each), and a cProfile of 30 s of the fused run.
* a cProfile top 10 (by own time) of tracking frames (50 stars, TRIAD).

No assertions: the figures depend on the machine; compare them as ratios within one run.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import platform
import pstats
import sys
import time
from dataclasses import replace

import numpy as np

from drake_att.contract import CameraCentroids
from drake_att.estimators.indoor_star_tracker_plugin import IndoorStarTrackerConfig
from drake_att.filters.indoor_star_tracker import (
    IndoorStarTrackerSolver,
    SwarmSettings,
    rotation_angle,
    rpy_deg_to_R_BI,
)
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.library import load
from drake_att.screen_geometry import directions_from_centroids
from drake_att.sensors.screen_camera_plugin import ScreenCameraConfig, camera_geometry
from drake_att.units import ARCSEC

NOISE_PX = 0.1
START_RPY = np.array([2.0, 3.0, 0.5])
RATE_RPY = np.array([0.05, 0.10, 0.01])  # deg/s, the dynamic test's turn
FRAME_S = 0.2


def make_solver(geometry, method: str) -> IndoorStarTrackerSolver:
    """The estimator config's solver settings (the dynamic scenario uses the defaults)."""
    c = IndoorStarTrackerConfig()
    swarm = SwarmSettings(
        c.pso_particles,
        c.pso_inertia,
        c.pso_c1,
        c.pso_c2,
        c.pso_v_max_deg,
        c.pso_max_generations,
        c.pso_search_range_deg,
        c.pso_stop_fraction,
    )
    return IndoorStarTrackerSolver(
        geometry,
        c.tolerance_deg,
        c.identification,
        method,
        c.max_iterations,
        c.convergence_tolerance_arcsec * ARCSEC,
        "given",
        swarm,
        c.max_lost_frames,
        c.sigma_floor_urad * 1e-6,
    )


def make_frames(geometry, count: int, seed: int, pitch: float):
    """``count`` frames along the turn, 0.1 px noise: (frames, true R_BI list)."""
    rng = np.random.default_rng(seed)
    frames, truths = [], []
    for k in range(count):
        R = rpy_deg_to_R_BI(START_RPY + RATE_RPY * FRAME_S * k)
        _, xy = geometry.project(R)
        xy = xy + NOISE_PX * pitch * rng.standard_normal(xy.shape)
        frames.append(CameraCentroids(k * FRAME_S, True, xy, geometry.focal_length_m, NOISE_PX * pitch))
        truths.append(R)
    return frames, truths


def track(solver, frames, truths):
    """Solve every frame from the previous solution; per-frame times and statistics."""
    A = truths[0]
    times, iters, ident, errs = [], [], [], []
    for frame, R in zip(frames, truths, strict=True):
        t0 = time.perf_counter()
        sol = solver.solve(frame, A)
        times.append(time.perf_counter() - t0)
        if sol.solved:
            A = sol.R_BI
        iters.append(sol.iterations)
        ident.append(sol.identified)
        errs.append(np.degrees(rotation_angle(sol.R_BI, R)))
    return np.array(times), np.array(iters), np.array(ident), np.array(errs)


def machine_line() -> str:
    import os

    import pydrake

    try:
        from importlib.metadata import version

        drake_version = version("drake")
    except Exception:  # pragma: no cover - presentation only
        drake_version = getattr(pydrake, "__version__", "?")
    load_avg = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (
        f"{platform.machine()} '{platform.processor()}', {os.cpu_count()} CPUs, Python {platform.python_version()}, "
        f"drake {drake_version}, numpy {np.__version__}; 1-min load average at start {load_avg:.2f}"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer frames and seeds, a 60-s scenario")
    ap.add_argument("--frames", type=int, default=None, help="tracking frames per case (default 300; quick 100)")
    ap.add_argument("--seeds", type=int, default=None, help="PSO seeds (default 30; quick 10)")
    args = ap.parse_args(argv)
    n_frames = args.frames or (100 if args.quick else 300)
    n_seeds = args.seeds or (10 if args.quick else 30)
    print(machine_line())
    base = ScreenCameraConfig()
    pitch = base.pixel_pitch_um * 1e-6

    # -- tracking frames and identification passes --------------------------------------------
    print(
        f"\nTracking: {n_frames} frames at {FRAME_S:g} s along the turn, {NOISE_PX:g} px noise, A0 = previous "
        "solution (times per frame: identification + iteration)"
    )
    print(
        f"{'stars':>5} {'in view':>8} {'method':<14} {'median ms':>9} {'mean ms':>8} {'iterations':>10} "
        f"{'ms/iter':>8} {'identified':>10} {'err RMS (deg)':>13}"
    )
    identify_rows = []
    for stars in (7, 50):
        geometry = camera_geometry(replace(base, star_count=stars))
        frames, truths = make_frames(geometry, n_frames, 7, pitch)
        for method in ("triad", "least_squares"):
            solver = make_solver(geometry, method)
            track(solver, frames[:10], truths[:10])  # warm-up
            t, it, ident, err = track(solver, frames, truths)
            view = np.mean([len(f.centroids_m) for f in frames])
            print(
                f"{stars:5d} {view:8.1f} {method:<14} {1e3 * np.median(t):9.3f} {1e3 * t.mean():8.3f} "
                f"{it.mean():10.2f} {1e3 * t.sum() / it.sum():8.3f} {ident.mean():10.1f} "
                f"{np.sqrt(np.mean(err**2)):13.5f}"
            )
        # one identification pass (centre-referenced directions at the true attitude)
        solver = make_solver(geometry, "triad")
        bs = [directions_from_centroids(f.centroids_m, f.focal_length_m) for f in frames]
        us = [solver.observed_directions(b, R) for b, R in zip(bs, truths, strict=True)]
        for u in us[:10]:
            solver.matcher.identify(u)
        reps = max(1, 2000 // len(us))
        t0 = time.perf_counter()
        for _ in range(reps):
            for u in us:
                solver.matcher.identify(u)
        per = (time.perf_counter() - t0) / (reps * len(us))
        t0 = time.perf_counter()
        for _ in range(reps):
            for b, R in zip(bs, truths, strict=True):
                solver.count_identified(b, R)
        per_fit = (time.perf_counter() - t0) / (reps * len(us))
        identify_rows.append((stars, np.mean([len(u) for u in us]), per, per_fit))
    print(
        "\nOne identification pass (AngleMatcher.identify), and one swarm fitness evaluation "
        "(directions + alpha correction + identify):"
    )
    for stars, view, per, per_fit in identify_rows:
        print(f"  {stars:2d} stars ({view:.1f} in view): identify {1e6 * per:7.1f} us; fitness {1e6 * per_fit:7.1f} us")

    # -- PSO initialization ----------------------------------------------------------------------
    geometry = camera_geometry(replace(base, star_count=50))
    solver = make_solver(geometry, "triad")
    R0 = rpy_deg_to_R_BI(START_RPY)
    _, xy0 = geometry.project(R0)
    times, gens, found = [], [], []
    for seed in range(n_seeds):
        rng = np.random.default_rng(seed)
        xy = xy0 + NOISE_PX * pitch * rng.standard_normal(xy0.shape)
        frame = CameraCentroids(0.0, True, xy, geometry.focal_length_m, NOISE_PX * pitch)
        t0 = time.perf_counter()
        res = solver.acquire(frame, np.zeros(3), rng)
        times.append(time.perf_counter() - t0)
        gens.append(res.generations)
        found.append(-res.fitness)
    times, gens = np.array(times), np.array(gens)
    evals = solver.swarm.particles * (1 + gens)
    print(
        f"\nPSO initialization ({solver.swarm.particles} particles, 50 stars, truth {START_RPY.tolist()} deg, "
        f"+-{solver.swarm.search_range_deg:g} deg about 0), {n_seeds} seeds:"
    )
    print(
        f"  median {1e3 * np.median(times):.1f} ms (range {1e3 * times.min():.1f}-{1e3 * times.max():.1f} ms); "
        f"generations median {np.median(gens):g} (range {gens.min()}-{gens.max()}, {np.mean(gens == 0):.0%} none); "
        f"{1e6 * times.sum() / evals.sum():.0f} us per fitness evaluation; best particle identified "
        f"{min(found):g}-{max(found):g} stars"
    )

    # -- scenario ----------------------------------------------------------------------------------
    scenario = load("s2_indoor_dynamic")
    if args.quick:
        scenario.duration_s = 60.0
    sd = ScenarioDiagram(scenario)
    names = [e.name for e in scenario.estimators]
    print(f"\n{scenario.name}: {scenario.duration_s:g} s simulated, one diagram, seed 1 (estimators {names}):")
    walls, cpus = {}, {}
    for label, sel in (
        ("sensors only (estimators=[])", []),
        ("camera alone", ["indoor_star_tracker"]),
        ("camera + gyro (MEKF)", ["indoor_star_tracker_gyro"]),
        ("both (the scenario)", None),
    ):
        t0, c0 = time.perf_counter(), time.process_time()
        run = sd.simulate(seed=1, estimators=sel)
        walls[label], cpus[label] = time.perf_counter() - t0, time.process_time() - c0
        print(
            f"  {label:<30} {walls[label]:6.2f} s wall, {cpus[label]:6.2f} s CPU "
            f"({scenario.duration_s / walls[label]:5.1f} sim-s / wall-s)"
        )
    for label in ("camera alone", "camera + gyro (MEKF)"):
        print(
            f"  {label}: the estimator's share {walls[label] - walls['sensors only (estimators=[])']:5.2f} s wall, "
            f"{cpus[label] - cpus['sensors only (estimators=[])']:5.2f} s CPU over the sensors-only run"
        )
    del run

    # where the fused run's time goes (30 s of it, under cProfile)
    prof = cProfile.Profile()
    prof.enable()
    sd.simulate(seed=1, overrides=["duration_s=30.0"], estimators=["indoor_star_tracker_gyro"])
    prof.disable()
    entries = pstats.Stats(prof).stats
    total = sum(v[2] for v in entries.values())

    def cumulative(name, file_part):
        hits = [v for k, v in entries.items() if k[2] == name and file_part in k[0]]
        return sum(v[1] for v in hits), sum(v[3] for v in hits)

    print(f"  camera + gyro, 30 s under cProfile ({total:.2f} s of own time in all functions); cumulative:")
    for label, name, part in (
        ("estimator steps (_on_step)", "_on_step", "systems/estimator_system.py"),
        ("  frame solves (IndoorStarTrackerSolver.solve)", "solve", "filters/indoor_star_tracker.py"),
        ("  camera port evaluations (ScreenCamera._calc_centroids)", "_calc_centroids", "systems/screen_camera.py"),
        ("  MEKF predictions (MultiplicativeEKF.predict)", "predict", "filters/mekf.py"),
    ):
        calls, cum = cumulative(name, part)
        print(f"    {label:<58} {calls:6d} calls {cum:6.2f} s ({cum / total:5.1%})")

    # -- the pieces of one iteration, without the profiler ----------------------------------------
    geometry = camera_geometry(replace(base, star_count=50))
    frames, truths = make_frames(geometry, min(n_frames, 200), 7, pitch)
    solver = make_solver(geometry, "triad")
    frame, R = frames[len(frames) // 2], truths[len(frames) // 2]
    b = directions_from_centroids(frame.centroids_m, frame.focal_length_m)
    u = solver.observed_directions(b, R)
    ids = solver.matcher.identify(u)
    sigmas = solver.direction_sigmas(frame, b, R)
    lsq = make_solver(geometry, "least_squares")
    pieces = (
        ("directions from centroids", lambda: directions_from_centroids(frame.centroids_m, frame.focal_length_m)),
        ("alpha + centre-referenced directions", lambda: solver.observed_directions(b, R)),
        ("identification (AngleMatcher.identify)", lambda: solver.matcher.identify(u)),
        ("direction sigmas (for the covariance)", lambda: solver.direction_sigmas(frame, b, R)),
        ("TRIAD + its covariance (pair choice incl.)", lambda: solver._attitude(u, ids, sigmas, frame.centroids_m)),
        ("least squares (SVD) + covariance", lambda: lsq._attitude(u, ids, sigmas, frame.centroids_m)),
        ("rotation_angle (the stop test)", lambda: rotation_angle(R, R)),
    )
    print(f"\nOne iteration's pieces, 50 stars ({len(b)} in view), us per call (best of 5 x 200 calls, no profiler):")
    for label, fn in pieces:
        best = np.inf
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(200):
                fn()
            best = min(best, (time.perf_counter() - t0) / 200)
        print(f"  {label:<44} {1e6 * best:8.1f}")

    # -- profile -----------------------------------------------------------------------------------
    prof = cProfile.Profile()
    prof.enable()
    track(solver, frames, truths)
    prof.disable()
    out = io.StringIO()
    stats = pstats.Stats(prof, stream=out)
    print(
        f"\ncProfile of {len(frames)} tracking frames (50 stars, TRIAD), top 10 by own time "
        f"(total {stats.total_tt:.3f} s under the profiler):"
    )
    stats.sort_stats("tottime").print_stats(10)
    text = out.getvalue()
    start = text.find("   ncalls")
    print(text[start:].rstrip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
