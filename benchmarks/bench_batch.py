#!/usr/bin/env python3
"""Where a campaign run's CPU goes, by batch size: ``simulate`` (or ``simulate_batch``) and the
default record, CPU seconds per run, in one process for every batch size asked::

    .venv/bin/python benchmarks/bench_batch.py                         # single, ten_hz, dual; batches 1, 10, 20
    .venv/bin/python benchmarks/bench_batch.py --case ten_hz --batch 1 5 10 --duration 1000

Cases are ``bench_campaign.py``'s (``single``, ``ten_hz``, ``dual``), at their shipped 5000 s
unless ``--duration``. Per case, each batch size runs seeds ``1 .. B`` once after a short warm-up
batch of the same size (compiled kernels, first calls); batch size 1 is a run alone
(``ScenarioDiagram.simulate``). A record is :func:`drake_att.analysis.run_records.default_record`
(the campaign's); before the timed runs of a case, one untimed run and record compute the
run's Cramér–Rao bound, which every timed record then reuses (the same truth, as in a campaign
after its first record): records are timed for the whole batch, divided by B. CPU is
``time.process_time`` of this process; compare figures of one run of the script only.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_campaign import CASES, SCENARIO  # noqa: E402


def scenario_of(case: str, duration: float | None):
    from drake_att.scenarios import config as cfg
    from drake_att.scenarios import library

    sets = list(CASES[case])
    if duration:
        sets += [f"duration_s={duration:g}", f"scoring.score_from_s={duration / 2:g}"]
    return cfg.apply_overrides(library.load(SCENARIO.get(case, "cubesat_dual_star_tracker")), sets)


def measure(case: str, batch: int, duration: float | None) -> tuple[float, float]:
    """``(simulate CPU s per run, record CPU s per run)`` of seeds 1..batch."""
    from drake_att.analysis.run_records import default_record
    from drake_att.scenarios.builder import ScenarioDiagram, diagram_for

    scenario = scenario_of(case, duration)
    sd = diagram_for(scenario) if batch == 1 else ScenarioDiagram(scenario, realizations=batch)
    warm = ["duration_s=20", "scoring.score_from_s=10"]
    seeds = list(range(1, batch + 1))
    if batch == 1:
        sd.simulate(1000, overrides=warm)
        c0 = time.process_time()
        runs = [sd.simulate(1)]
    else:
        sd.simulate_batch([s + 1000 for s in seeds], overrides=warm)
        c0 = time.process_time()
        runs = sd.simulate_batch(seeds)
    c1 = time.process_time()
    for run in runs:
        default_record(run)
    c2 = time.process_time()
    return (c1 - c0) / batch, (c2 - c1) / batch


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=(*CASES, "all"), default="all")
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 10, 20], help="batch sizes (1: a run alone)")
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds per run (default: 5000)")
    args = ap.parse_args(argv)
    if any(b < 1 for b in args.batch) or (args.duration is not None and not args.duration > 20):
        ap.error(f"--batch {args.batch}, --duration {args.duration}: need sizes >= 1 and a duration > 20 s")
    cases = list(CASES) if args.case == "all" else [args.case]
    print(f"{'case':<8} {'batch':>5} {'simulate s/run':>15} {'record s/run':>13} {'vs alone':>9}")
    for case in cases:
        from drake_att.analysis.run_records import default_record
        from drake_att.scenarios.builder import diagram_for

        default_record(diagram_for(scenario_of(case, args.duration)).simulate(999))  # the bound, untimed
        alone = None
        for batch in args.batch:
            sim, rec = measure(case, batch, args.duration)
            alone = sim + rec if batch == 1 else alone
            ratio = f"{alone / (sim + rec):8.2f}x" if alone else ""
            print(f"{case:<8} {batch:>5} {sim:>15.3f} {rec:>13.3f} {ratio:>9}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
