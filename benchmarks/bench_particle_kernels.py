#!/usr/bin/env python3
"""A/B of the S0 particle filters' steps: per-step and whole-run CPU time of an old checkout
against this one's library (the compiled kernels) and this one's numpy oracle
(``tests/particle_reference.py``, the ``Reference*`` cores), in one run, as ratios; plus numba's
first-compile and cache-load cost.

Usage::

    git worktree add /tmp/wt_pf_base <an older commit>
    .venv/bin/python benchmarks/bench_particle_kernels.py --old /tmp/wt_pf_base [--rounds 7]
        [--steps 100] [--particles 1000] [--duration 1000] [--no-oracle] [--no-scenario] [--no-compile]

**Per step.** Each measurement is a fresh interpreter with ``PYTHONPATH`` at one checkout: it
builds the filter with ``--particles`` particles on ``bench_particle_filters.py``'s synthetic
S0 data (1 s steps, two star vectors at 100 urad), runs 5 warm-up steps (numba loads or
compiles its kernels there), then times ``--steps`` predict + update pairs one by one with
``time.process_time`` (this process's CPU time: robust to other tenants of a shared VM). A
checkout with the pure cores (``drake_att.filters.particle.EkpfCore``) is driven through them
(``predict``/``update`` on a state, the tracker sample built before the timing); an older one
through its mutable filter objects; all draw the same random numbers in the same order.
Reported per filter: the best and the median step over all rounds, and the old / new ratio
of the bests and the median [range] of the per-round ratios of the median steps (above 1:
new is faster). The rounds alternate old, new oracle, new, so drifting load hits all
(``--no-oracle``: old and new only).

**Whole run.** ``s0_particle_filters_small_error`` with the EKPF only
(``ScenarioDiagram.simulate(seed, estimators=["ekpf"])``, ``--duration`` s): the CPU time of
``simulate(seed=2)`` after a 20-s warm-up run in the same process (diagram built once; the
oracle's variant builds it with ``ReferenceEkpfCore``).

**First compile.** Two fresh interpreters with ``NUMBA_CACHE_DIR`` at a new empty directory:
the first compiles every kernel (cold cache) and writes the cache, the second loads it.
Reported: the import of numba and of the kernel module, and the first call of the EKPF, the
bootstrap PF and the gyroless PF (each then compiles or loads its kernels).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))

# The filters of a checkout, as ``make(name, n, q0, s0, P0, rng, kw) -> stepper`` with
# ``stepper.predict(w_meas)`` and ``stepper.update(y)`` (y: (6,) body-frame vectors of REFS):
# the pure cores where the checkout has them, else its mutable filter objects.
FILTERS = r"""
import os, sys
import numpy as np
from drake_att.filters import particle as _particle
REFS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
PURE_CORES = hasattr(_particle, "EkpfCore")
sys.path.append(os.path.join(os.getcwd(), "tests"))  # the checkout's numpy oracle
if PURE_CORES:
    from drake_att.contract import VectorObservations
    from drake_att.filters.particle import BootstrapPfCore, EkpfCore, GyrolessPfCore, RandomWalkRoughening
    if sys.argv[1:2] == ["oracle"]:
        from particle_reference import ReferenceBootstrapPfCore as BootstrapPfCore
        from particle_reference import ReferenceEkpfCore as EkpfCore
        from particle_reference import ReferenceGyrolessPfCore as GyrolessPfCore

    class Stepper:
        def __init__(self, core, rng, sigma):
            self.core, self.rng, self.sigma = core, rng, sigma
            self.state = core.draw_initial_state(rng)

        def observation(self, y):
            return VectorObservations(0.0, True, np.reshape(y, (2, 3)), REFS, self.sigma, np.array([1.0, 0, 0, 0]))

        def predict(self, w):
            self.state = self.core.predict(self.state, w, 1.0, self.rng)

        def update_with(self, observation):
            self.state = self.core.update(self.state, observation, self.rng)[0]

        def update(self, y):
            self.update_with(self.observation(y))

    def make(name, n, q0, s0, P0, r, kw, sv=None, su=None, sigma=1e-4, extra=None):
        if name == "EKPF":
            core = EkpfCore(n, q0, s0, P0, sv, su, **kw)
        elif name == "bootstrap PF":
            core = BootstrapPfCore(n, q0, s0, P0, 2e-5, bias_roughening=RandomWalkRoughening(3e-7), **kw)
        else:
            inertia, torque, rate_sigma, attitude_sigma = extra
            core = GyrolessPfCore(n, q0, s0, P0, inertia, torque, rate_sigma, attitude_process_sigma=attitude_sigma,
                                  **kw)
        return Stepper(core, r, sigma)
else:
    from drake_att.filters.particle import (BootstrapParticleFilter, ExtendedKalmanParticleFilter,
                                            GyrolessParticleFilter)

    class Stepper:
        def __init__(self, pf, rng, sigma, gyroless):
            self.pf, self.rng, self.sigma, self.gyroless = pf, rng, sigma, gyroless

        def observation(self, y):
            return y

        def predict(self, w):
            self.pf.predict(1.0, self.rng) if self.gyroless else self.pf.predict(1.0, w, self.rng)

        def update_with(self, y):
            self.pf.update(y, REFS, self.sigma, self.rng)

        def update(self, y):
            self.update_with(y)

    def make(name, n, q0, s0, P0, r, kw, sv=None, su=None, sigma=1e-4, extra=None):
        if name == "EKPF":
            return Stepper(ExtendedKalmanParticleFilter(n, q0, s0, P0, sv, su, r, **kw), r, sigma, False)
        if name == "bootstrap PF":
            return Stepper(BootstrapParticleFilter(n, q0, s0, P0, 2e-5, r, bias_roughening_sigma=3e-7, **kw), r,
                           sigma, False)
        inertia, torque, rate_sigma, attitude_sigma = extra
        return Stepper(GyrolessParticleFilter(n, q0, s0, P0, inertia, torque, rate_sigma, r,
                                              attitude_process_sigma=attitude_sigma, **kw), r, sigma, True)
"""

STEP_CHILD = (
    FILTERS
    + r"""
import json, sys, time
from drake_att import rotations as rot
try:  # the measurement model: the library's where it has one, else the oracle's
    from drake_att.filters.mrp_ekf import vector_measurement_model
except ImportError:
    from particle_reference import vector_measurement_model
n, steps = int(sys.argv[2]), int(sys.argv[3])
kw = {}
DEG, HOUR = np.pi / 180.0, 3600.0
SV, SU, SIG = 0.2 * DEG / HOUR, 0.02 * DEG / HOUR / np.sqrt(HOUR), 100e-6
rng = np.random.default_rng(0)
w, b, q = np.array([1e-3, -5e-4, 2e-4]), np.full(3, DEG / HOUR), np.array([1.0, 0.0, 0.0, 0.0])
ys, wms = [], []
for _ in range(steps + 6):
    ys.append(vector_measurement_model(rot.quat_to_mrp(q), REFS) + SIG * rng.standard_normal(6))
    wms.append(w + b + SV * rng.standard_normal(3))
    b = b + SU * rng.standard_normal(3)
    q = rot.quat_propagate(q, w, 1.0)
q0 = rot.rpy_to_quat(np.array([1.0, 1.0, 1.0]) * DEG)
b0 = np.full(3, 2 * DEG / HOUR)
P0 = np.diag([DEG**2] * 3 + [(DEG / HOUR) ** 2] * 3)
P0g = np.diag([DEG**2] * 3 + [(0.001 * DEG) ** 2] * 3)
out = {}
for name in ("EKPF", "bootstrap PF", "gyroless PF"):
    r = np.random.default_rng(3)
    if name == "gyroless PF":
        f = make(name, n, q0, np.full(3, 0.001 * DEG), P0g, r, kw, sigma=SIG,
                 extra=(np.diag([100.0, 200.0, 200.0]), np.full(3, 1e-5), 1e-6, 3e-5))
    else:
        f = make(name, n, q0, b0, P0, r, kw, SV, SU, sigma=SIG)
    obs = [f.observation(y) for y in ys]
    t0 = time.process_time()
    f.update_with(obs[0])
    first = time.process_time() - t0
    for k in range(5):
        f.predict(wms[k])
        f.update_with(obs[k + 1])
    times = []
    for k in range(5, 5 + steps):
        t0 = time.process_time()
        f.predict(wms[k])
        f.update_with(obs[k + 1])
        times.append(time.process_time() - t0)
    out[name] = {"times": times, "first_update_s": first}
print(json.dumps(out))
"""
)

SCENARIO_CHILD = r"""
import json, os, sys, time
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import apply_overrides
from drake_att.scenarios.library import load
variant, duration = sys.argv[1], float(sys.argv[2])
if variant == "oracle":
    sys.path.append(os.path.join(os.getcwd(), "tests"))
    from particle_reference import ReferenceEkpfCore
    from drake_att.systems import filter_setups
    filter_setups.EkpfCore = ReferenceEkpfCore
s = apply_overrides(load("s0_particle_filters_small_error"),
                    [f"duration_s={duration}", f"scoring.score_from_s={duration / 10}"])
sd = ScenarioDiagram(s)
t0 = time.process_time()
sd.simulate(1, estimators=["ekpf"], overrides=["duration_s=20", "scoring.score_from_s=2"])
warm = time.process_time() - t0
t0 = time.process_time()
sd.simulate(2, estimators=["ekpf"])
print(json.dumps({"cpu_s": time.process_time() - t0, "warm_up_s": warm}))
"""

COMPILE_CHILD = (
    r"""
import json, time
t0 = time.perf_counter()
import numba
t_numba = time.perf_counter() - t0
t0 = time.perf_counter()
from drake_att.filters import particle_kernels
t_module = time.perf_counter() - t0
"""
    + FILTERS
    + r"""
P0 = np.diag([1e-4] * 3 + [1e-10] * 3)
y = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
out = {"import numba": t_numba, "import particle_kernels": t_module, "caching": particle_kernels.CACHING}
r = np.random.default_rng(0)
for name in ("EKPF", "bootstrap PF", "gyroless PF"):
    f = make(name, 10, [1, 0, 0, 0], np.zeros(3), P0, r, {}, 1e-6, 1e-9, 1e-4,
             extra=(np.eye(3), np.zeros(3), 1e-6, 1e-6))
    t0 = time.perf_counter()
    f.predict(np.zeros(3))
    f.update(y)
    out[f"first step, {name}"] = time.perf_counter() - t0
print(json.dumps(out))
"""
)


def child(checkout: str, code: str, args, env_extra=None) -> dict:
    env = dict(os.environ, PYTHONPATH=os.path.abspath(checkout), MPLBACKEND="Agg", **(env_extra or {}))
    out = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)],
        check=False,
        env=env,
        capture_output=True,
        text=True,
        cwd=os.path.abspath(checkout),
    )
    if out.returncode != 0:
        raise SystemExit(f"{checkout} {args}: failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def median(v):
    return statistics.median(v)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="checkout of an older commit (git worktree)")
    ap.add_argument("--new", default=os.path.join(HERE, os.pardir))
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--steps", type=int, default=100, help="timed steps per filter and child")
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=1000.0, help="simulated seconds of the S0 run")
    ap.add_argument("--no-oracle", action="store_true", help="time old and new only, not the numpy oracle")
    ap.add_argument("--no-scenario", action="store_true", help="skip the whole-run A/B")
    ap.add_argument("--no-compile", action="store_true", help="skip the first-compile measurement")
    args = ap.parse_args(argv)
    variants = [("old", args.old, "library"), ("new oracle", args.new, "oracle"), ("new", args.new, "library")]
    if args.no_oracle:
        del variants[1]
    print(
        f"old: {os.path.abspath(args.old)}\nnew: {os.path.abspath(args.new)}\n"
        f"{args.rounds} rounds ({', '.join(v for v, _, _ in variants)} in turn); N = {args.particles}; CPU time "
        f"(time.process_time); 1-min load average {os.getloadavg()[0]:.2f} at start, {os.cpu_count()} CPUs"
    )
    step_table(variants, args)
    if not args.no_scenario:
        run_table(variants, args)
    if not args.no_compile:
        compile_table(args)


def step_table(variants, args) -> None:
    """Per step: each variant's best and median, and old / variant ratios."""
    steps = {v: [] for v, _, _ in variants}  # per round: {filter: times}
    for _ in range(args.rounds):
        for v, tree, kind in variants:
            steps[v].append(child(tree, STEP_CHILD, [kind, args.particles, args.steps]))
    filters = list(steps["old"][0])
    others = [v for v, _, _ in variants if v != "old"]
    print(f"\nPer step (predict + update), ms of CPU; {args.steps} steps x {args.rounds} rounds per cell")
    print(
        "| filter | "
        + " | ".join(f"{v} best / median" for v, _, _ in variants)
        + " | "
        + " | ".join(f"old / {v}, best/best | old / {v}, median of per-round median ratios [range]" for v in others)
        + " |"
    )
    print("|---|" + "---|" * (len(variants) + 2 * len(others)))
    for f in filters:
        cell, med_round = {}, {}
        for v, _, _ in variants:
            all_t = [t for r in steps[v] for t in r[f]["times"]]
            cell[v] = (1e3 * min(all_t), 1e3 * median(all_t))
            med_round[v] = [median(r[f]["times"]) for r in steps[v]]
        row = [f"{cell[v][0]:.3f} / {cell[v][1]:.3f}" for v, _, _ in variants]
        for v in others:
            ratio = sorted(o / n for o, n in zip(med_round["old"], med_round[v], strict=True))
            row += [f"{cell['old'][0] / cell[v][0]:.2f}", f"{median(ratio):.2f} [{ratio[0]:.2f}, {ratio[-1]:.2f}]"]
        print(f"| {f} | " + " | ".join(row) + " |")


def run_table(variants, args) -> None:
    """Whole run: each variant's best and median CPU time of ``simulate()``, old / variant."""
    runs = {v: [] for v, _, _ in variants}
    for _ in range(args.rounds):
        for v, tree, kind in variants:
            runs[v].append(child(tree, SCENARIO_CHILD, [kind, args.duration]))
    print(
        f"\nWhole run: s0_particle_filters_small_error, EKPF only, {args.duration:.0f} s simulated, CPU s of simulate()"
    )
    print("| variant | best | median | old / variant, best/best | old / variant, median of per-round ratios [range] |")
    print("|---|---|---|---|---|")
    for v, _, _ in variants:
        t = [r["cpu_s"] for r in runs[v]]
        rr = sorted(o["cpu_s"] / n["cpu_s"] for o, n in zip(runs["old"], runs[v], strict=True))
        print(
            f"| {v} | {min(t):.2f} | {median(t):.2f} | {min(r['cpu_s'] for r in runs['old']) / min(t):.2f} | "
            f"{median(rr):.2f} [{rr[0]:.2f}, {rr[-1]:.2f}] |"
        )


def compile_table(args) -> None:
    """numba's first compile (a new empty cache) and the load from that cache, of the new checkout."""
    with tempfile.TemporaryDirectory(prefix="numba_cache_") as cache:
        env = {"NUMBA_CACHE_DIR": cache}
        cold = child(args.new, COMPILE_CHILD, [], env)
        warm = child(args.new, COMPILE_CHILD, [], env)
        size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(cache) for f in fs)
    print(f"\nFirst compile (NUMBA_CACHE_DIR = a new empty directory; wall s; cache written: {size / 1e6:.1f} MB)")
    print("| | cold cache (compiles) | warm cache (loads) |")
    print("|---|---|---|")
    for k in cold:
        if k == "caching":
            continue
        print(f"| {k} | {cold[k]:.2f} | {warm[k]:.2f} |")


if __name__ == "__main__":
    main()
