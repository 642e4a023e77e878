"""Command line: ``drake-att run [SCENARIO] [--seed N] [--out DIR] [--set path=value ...]``
and ``drake-att list``."""

from __future__ import annotations

import argparse
import os
import sys

from drake_att.scenarios.config import ConfigError, apply_overrides, load_scenario


def _cmd_list(args) -> int:
    from drake_att.scenarios.library import DEFAULT_SCENARIO, available_scenarios

    for name, path in available_scenarios().items():
        s = load_scenario(filename=path)
        mark = " (default)" if name == DEFAULT_SCENARIO else ""
        desc = " ".join(s.description.split())
        print(f"{name}{mark}\n    {desc}\n    estimators: {', '.join(e.name for e in s.estimators)}")
    return 0


def _cmd_run(args) -> int:
    from drake_att.analysis.metrics import compute_metrics, format_table
    from drake_att.analysis.report import write_results
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.library import scenario_path

    try:
        path = scenario_path(args.scenario)
        scenario = load_scenario(filename=path)
        overrides = list(args.set or [])
        if args.seed is not None:
            overrides.append(f"seed={args.seed}")
        if overrides:
            scenario = apply_overrides(scenario, overrides)
    except (ConfigError, ValueError) as e:
        print(f"drake-att: invalid scenario: {e}", file=sys.stderr)
        return 2
    out_dir = args.out or os.path.join("out", f"{scenario.name}_seed{scenario.seed}")
    print(f"Building {scenario.name} ({path}) ...", file=sys.stderr)
    sd = ScenarioDiagram(scenario)
    run = sd.simulate(scenario.seed, progress=not args.quiet)
    metrics = compute_metrics(run, sd.estimators)
    print(format_table(metrics))
    files = write_results(sd, run, metrics, out_dir, figures=not args.no_figures)
    print(f"\nWrote {len(files)} files to {out_dir}/: " + ", ".join(os.path.basename(f) for f in files))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="drake-att", description="Attitude-determination scenarios on Drake.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scenario (default: the project's default scenario)")
    p_run.add_argument("scenario", nargs="?", default=None, help="shipped scenario name or YAML path")
    p_run.add_argument("--seed", type=int, default=None, help="random seed (overrides the scenario's)")
    p_run.add_argument("--out", default=None, help="output folder (default out/<scenario>_seed<N>)")
    p_run.add_argument("--set", action="append", metavar="PATH=VALUE",
                       help="override a config value, e.g. --set duration_s=600 --set sensors.st1.period_s=1")
    p_run.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p_run.add_argument("--quiet", action="store_true", help="no progress line")
    p_run.set_defaults(func=_cmd_run)
    p_list = sub.add_parser("list", help="list the shipped scenarios")
    p_list.set_defaults(func=_cmd_list)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
