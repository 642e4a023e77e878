#!/usr/bin/env python3
"""The mission scenario's cost: CPU seconds per simulated hour, the environment's share of it, and
the peak memory of a run.

The environment's share is the CPU time spent inside the environment's computations, measured by
wrapping them with a clock (a few hundred ns per call, included in the share): the orbit
(``OrbitSource``: SGP4 and the LVLH frame), the Sun and the Moon (``SunMoonSource``), the IGRF field
(``MagneticFieldSource``), the trackers' exclusion causes and the sun sensors' shadow. The rest is
the truth, the sensors' noise, the estimators and the loggers. Each computation's time excludes
the others it triggers (a tracker's exclusion reading the orbit's port). One process per figure::

    .venv/bin/python benchmarks/bench_mission.py                  # 1 h simulated, after a warm-up
    .venv/bin/python benchmarks/bench_mission.py --hours 24       # the whole day (peak memory)
    .venv/bin/python benchmarks/bench_mission.py --hours 2 --default-logging   # without the logging policy
"""

from __future__ import annotations

import argparse
import resource
import time

_STACK: list = []  # per active wrapped call: [time spent in wrapped calls it made]


def _wrap(cls, name: str, totals: dict, key: str) -> None:
    """Time ``cls.name``'s calls into ``totals[key]``, exclusive of the wrapped calls it makes
    (a tracker's exclusion reads the orbit's port, which may propagate the orbit)."""
    original = getattr(cls, name)

    def timed(*args, **kwargs):
        _STACK.append([0.0])
        t0 = time.process_time()
        try:
            return original(*args, **kwargs)
        finally:
            spent = time.process_time() - t0
            children = _STACK.pop()[0]
            totals[key] = totals.get(key, 0.0) + spent - children
            if _STACK:
                _STACK[-1][0] += spent

    setattr(cls, name, timed)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--scenario", default="cubesat_sso_mission")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--default-logging", action="store_true", help="every signal at its own period (no logging: policy)"
    )
    args = ap.parse_args(argv)

    from drake_att.scenarios import library
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.systems.coarse_sensors import SunSensor
    from drake_att.systems.environment import MagneticFieldSource, SunMoonSource
    from drake_att.systems.orbit_source import OrbitSource
    from drake_att.systems.star_tracker import StarTracker

    totals: dict = {}
    _wrap(OrbitSource, "_state", totals, "orbit (SGP4, LVLH)")
    _wrap(SunMoonSource, "_positions", totals, "Sun and Moon")
    _wrap(MagneticFieldSource, "_field", totals, "IGRF field")
    _wrap(StarTracker, "_compute_causes", totals, "tracker exclusion")
    _wrap(SunSensor, "causes", totals, "sun sensor shadow and FOV")

    scenario = library.load(args.scenario)
    if args.default_logging:
        from drake_att.scenarios.config import LoggingConfig

        scenario.logging = LoggingConfig()
    t0 = time.process_time()
    sd = ScenarioDiagram(scenario)
    build = time.process_time() - t0
    short = ["scoring.score_from_s=0"]
    sd.simulate(args.seed, overrides=["duration_s=600", *short])  # warm-up: numba kernels, caches
    totals.clear()
    duration = args.hours * 3600.0
    t0 = time.process_time()
    run_log = sd.simulate(args.seed, overrides=[f"duration_s={duration:g}", *short])
    run = time.process_time() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    env = sum(totals.values())
    print(f"{args.scenario}: {args.hours:g} h simulated, seed {args.seed}")
    print(f"  build (once per diagram)          {build:8.2f} s CPU")
    print(f"  run                               {run:8.2f} s CPU = {run / args.hours:.1f} s CPU per simulated hour")
    print(f"  environment's share               {env:8.2f} s CPU = {100 * env / run:.1f} % of the run")
    for k, v in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"    {k:<32}{v:8.2f} s CPU ({100 * v / run:.1f} %)")
    print(f"  peak resident memory              {peak_mb:8.0f} MB (the process: imports, diagram, logs)")
    logged = sum(t.nbytes + x.nbytes for t, x in run_log.signals.values())
    print(f"  logged arrays                     {logged / duration / 1024:8.2f} KB per simulated second")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
