"""Command line: ``drake-att run [SCENARIO] [--seed N] [--out DIR] [--set path=value ...]``,
``drake-att score OUT_DIR [--out FILE]`` and ``drake-att list``."""

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
    from drake_att.scenarios.builder import NonFiniteRunError, ScenarioDiagram
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
    # The default folder names the scenario and seed, and the overrides too (a short hash of
    # them): a run with --set never lands in (and replaces) the unmodified run's folder.
    tag = ""
    if args.set:
        import hashlib

        tag = "_" + hashlib.sha1("\n".join(args.set).encode()).hexdigest()[:8]
    out_dir = args.out or os.path.join("out", f"{scenario.name}_seed{scenario.seed}{tag}")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        print(f"drake-att: --out {out_dir}: is an existing file, not a folder; name a folder for the results",
              file=sys.stderr)
        return 2
    from drake_att.scenarios.preflight import preflight_warnings, run_warnings

    for message in preflight_warnings(scenario):
        print(f"drake-att: warning: {message}", file=sys.stderr)
    print(f"Building {scenario.name} ({path}) ...", file=sys.stderr)
    import warnings

    from drake_att.scenarios.preflight import DegenerateScenarioWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateScenarioWarning)  # printed above, as one line each
        sd = ScenarioDiagram(scenario)
    try:
        run = sd.simulate(scenario.seed, progress=not args.quiet)
    except NonFiniteRunError as e:
        print(f"drake-att: the run failed: {e}", file=sys.stderr)
        return 2
    metrics = compute_metrics(run)
    print(format_table(metrics))
    for message in run_warnings(metrics):
        print(f"drake-att: warning: {message}", file=sys.stderr)
    replaced = os.path.isdir(out_dir)
    files = write_results(sd, run, metrics, out_dir, figures=not args.no_figures)
    print(f"\nWrote {len(files)} files to {out_dir}/" + (" (replacing the previous results there)" if replaced else "")
          + ": " + ", ".join(os.path.basename(f) for f in files))
    return 0


def _cmd_score(args) -> int:
    import zipfile

    from drake_att.analysis.metrics import compute_metrics, format_table
    from drake_att.analysis.report import write_metrics_json
    from drake_att.scenarios.builder import RunLog

    def fail(msg):
        print(f"drake-att score: {msg}", file=sys.stderr)
        return 2

    out_dir = args.out_dir
    if not os.path.isdir(out_dir):
        return fail(f"{out_dir}: no such result folder")
    npz_path, config_path = os.path.join(out_dir, "log.npz"), os.path.join(out_dir, "config.yaml")
    for path in (npz_path, config_path):
        if not os.path.isfile(path):
            return fail(f"{path}: missing (a result folder of `drake-att run` holds log.npz and config.yaml)")
    try:
        scenario = load_scenario(filename=config_path)
    except (ConfigError, ValueError, OSError) as e:
        return fail(f"{config_path}: not a valid scenario: {e}")
    try:
        run = RunLog.load(npz_path, scenario)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        return fail(f"{npz_path}: cannot be scored: {e}")
    try:
        metrics = compute_metrics(run)
    except (ValueError, KeyError, IndexError) as e:
        return fail(f"{npz_path}: cannot be scored: {e}")
    print(format_table(metrics))
    out = args.out or os.path.join(out_dir, "metrics.json")
    previous = None
    if os.path.isfile(out):
        with open(out, "rb") as f:
            previous = f.read()
    try:
        write_metrics_json(metrics, out)
        with open(out, "rb") as f:
            now = f.read()
    except OSError as e:
        return fail(f"{out}: cannot write: {e}")
    same = "" if previous is None else (" (identical to the file it replaced)" if previous == now
                                        else " (differs from the file it replaced)")
    print(f"\nWrote {out}{same}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="drake-att", description="Attitude-determination scenarios on Drake.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scenario (default: the project's default scenario)")
    p_run.add_argument("scenario", nargs="?", default=None, help="shipped scenario name or YAML path")
    p_run.add_argument("--seed", type=int, default=None, help="random seed (overrides the scenario's)")
    p_run.add_argument("--out", default=None, help="output folder (default out/<scenario>_seed<N>, plus a hash of "
                       "the --set overrides if any); replaced as a whole, atomically")
    p_run.add_argument("--set", action="append", metavar="PATH=VALUE",
                       help="override a config value, e.g. --set duration_s=600 --set sensors.st1.period_s=1")
    p_run.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p_run.add_argument("--quiet", action="store_true", help="no progress line")
    p_run.set_defaults(func=_cmd_run)
    p_score = sub.add_parser("score", help="recompute a result folder's metrics.json from its log.npz + config.yaml")
    p_score.add_argument("out_dir", metavar="OUT_DIR", help="result folder written by `drake-att run`")
    p_score.add_argument("--out", default=None, metavar="FILE",
                         help="write the metrics here (default OUT_DIR/metrics.json)")
    p_score.set_defaults(func=_cmd_score)
    p_list = sub.add_parser("list", help="list the shipped scenarios")
    p_list.set_defaults(func=_cmd_list)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("\ndrake-att: interrupted; no result folder was written or changed", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
