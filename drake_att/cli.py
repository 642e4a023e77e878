"""Command line: ``drake-att run [SCENARIO] [--seed N] [--out DIR] [--set path=value ...]``,
``drake-att score OUT_DIR [--out FILE]``, ``drake-att list``, ``drake-att montecarlo
SCENARIO --runs N ...`` (a Monte Carlo campaign on Dask) and ``drake-att compare
SCENARIO... --runs N ...`` (the estimator x scenario comparison matrix)."""

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


def _override_tag(items) -> str:
    """A short hash of ``--set``-like strings (empty for none): default folders of modified
    runs never land in (and replace) the unmodified ones."""
    if not items:
        return ""
    import hashlib

    return "_" + hashlib.sha1("\n".join(items).encode()).hexdigest()[:8]


def _estimator_list(text):
    return None if text is None else [n.strip() for n in text.split(",") if n.strip()]


def _campaign_failed(command: str, e) -> int:
    print(f"drake-att {command}: {e}", file=sys.stderr)
    return 2


def _saved_runs(out) -> int:
    runs = os.path.join(out, "runs") if out else None
    return len([f for f in os.listdir(runs) if f.endswith(".npz")]) if runs and os.path.isdir(runs) else 0


def _cmd_montecarlo(args) -> int:
    from drake_att.analysis import campaign_report
    from drake_att.analysis.montecarlo import (
        CampaignError,
        campaign_seeds,
        resolve_scenario,
        run_campaign,
    )
    from drake_att.scenarios.library import scenario_path
    from drake_att.scenarios.preflight import preflight_warnings

    def fail(e):
        return _campaign_failed("montecarlo", e)

    estimators = _estimator_list(args.estimators)
    try:
        campaign_seeds(args.runs, args.first_seed)
        scenario = resolve_scenario(scenario_path(args.scenario), args.set or (), estimators)
        scheduler = _scheduler_option(args)
    except (CampaignError, ConfigError, ValueError) as e:
        return fail(e)
    tag = _override_tag(list(args.set or []) + ([f"--estimators={args.estimators}"] if args.estimators else []))
    out = args.out or os.path.join("out", f"{scenario.name}_montecarlo{tag}")
    for message in preflight_warnings(scenario):
        print(f"drake-att: warning: {message}", file=sys.stderr)
    if scheduler == "serial" or (scheduler is None and args.workers == 1):
        where = "serially in this process"
    elif scheduler:
        where = f"on the Dask cluster at {scheduler}"
    else:
        where = f"on a local Dask cluster of {min(args.workers or os.cpu_count() or 1, args.runs)} worker processes"
    print(f"Monte Carlo: {scenario.name}, {args.runs} runs (seeds {args.first_seed}..{args.first_seed + args.runs - 1}) "
          f"{where} -> {out}/", file=sys.stderr)
    try:
        result = run_campaign(scenario, args.runs, args.first_seed, workers=args.workers, scheduler=scheduler, out=out,
                              resume=args.resume, progress=not args.quiet, connect_timeout_s=args.connect_timeout)
    except (CampaignError, ConfigError) as e:
        return fail(e)
    except KeyboardInterrupt:
        print(f"\ndrake-att montecarlo: interrupted; {_saved_runs(out)} of {args.runs} runs are saved in {out}/runs; "
              "the same command with --resume continues the campaign", file=sys.stderr)
        return 130
    print(campaign_report.format_campaign_table(result))
    for seed, message in result.failed.items():
        print(f"drake-att: warning: seed {seed} failed: {message}", file=sys.stderr)
    print(f"\n{result.ran} runs simulated, {result.reused} found complete in {out}/runs; {result.wall_time_s:.1f} s wall. "
          f"Wrote {out}/report.html, summary.json and {len([f for f in result.files if f.endswith('.png')])} figures")
    if args.screenshot:
        try:
            png = campaign_report.screenshot(os.path.join(out, "report.html"), args.screenshot)
        except (OSError, RuntimeError) as e:
            return fail(f"--screenshot {args.screenshot}: {e}")
        print(f"Screenshot of the report: {png}")
    return 0


def _scheduler_option(args):
    from drake_att.analysis.montecarlo import CampaignError, check_scheduler_address

    if args.workers is not None and args.workers < 1:
        raise CampaignError(f"--workers: got {args.workers}; must be a positive integer")
    if args.scheduler is None:
        return None
    if args.scheduler == "serial":
        return "serial"
    if args.workers is not None:
        raise CampaignError(f"--workers {args.workers} with --scheduler {args.scheduler}: the cluster's own workers "
                            "run the campaign; give one of the two")
    return check_scheduler_address(args.scheduler)


def _cmd_compare(args) -> int:
    from drake_att.analysis import campaign_report
    from drake_att.analysis.montecarlo import (
        CampaignError,
        campaign_seeds,
        comparison_plan,
        run_comparison,
    )

    def fail(e):
        return _campaign_failed("compare", e)

    try:
        campaign_seeds(args.runs, args.first_seed)
        plan = comparison_plan(args.scenarios, _estimator_list(args.estimators), args.set or ())
        scheduler = _scheduler_option(args)
    except (CampaignError, ConfigError, ValueError) as e:
        return fail(e)
    tag = _override_tag(list(args.scenarios) + list(args.set or []) + [args.estimators or ""])
    out = args.out or os.path.join("out", f"compare{tag}")
    for cell in plan.skipped:
        print(f"drake-att compare: note: {cell}", file=sys.stderr)
    try:
        result = run_comparison(plan, args.runs, args.first_seed, workers=args.workers, scheduler=scheduler, out=out,
                                resume=args.resume, progress=not args.quiet, connect_timeout_s=args.connect_timeout)
    except (CampaignError, ConfigError) as e:
        return fail(e)
    except KeyboardInterrupt:
        print(f"\ndrake-att compare: interrupted; the finished runs are saved under {out}/; the same command with "
              "--resume continues", file=sys.stderr)
        return 130
    print(campaign_report.format_comparison_table(result))
    print(f"\nWrote {out}/comparison.html, comparison.json, comparison.md and comparison.png "
          f"(one campaign folder per scenario under {out}/)")
    return 0


def _add_campaign_options(p, what: str) -> None:
    p.add_argument("--runs", type=int, required=True, metavar="N", help="runs (seeds) per scenario")
    p.add_argument("--first-seed", type=int, default=1, metavar="S", help="seeds S .. S+N-1 (default 1)")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help="worker processes of the local Dask cluster (default: the CPU count); 1 = serial, in this process")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster (tcp://HOST:8786, started with `dask scheduler` and "
                        "`dask worker tcp://HOST:8786`), or 'serial'")
    p.add_argument("--connect-timeout", type=float, default=10.0, metavar="SECONDS",
                   help="how long to wait for --scheduler and its first worker (default 10)")
    p.add_argument("--set", action="append", metavar="PATH=VALUE", help="override a config value (as for run)")
    p.add_argument("--out", default=None, metavar="DIR", help=f"{what} folder")
    p.add_argument("--resume", action="store_true",
                   help="continue the campaign in --out: finished runs are kept, the others run (the config must match)")
    p.add_argument("--quiet", action="store_true", help="no progress line")


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
    p_mc = sub.add_parser("montecarlo", help="Monte Carlo campaign over seeds (Dask), with report.html")
    p_mc.add_argument("scenario", nargs="?", default=None, metavar="SCENARIO",
                      help="shipped scenario name or YAML path (default: the project's default scenario)")
    _add_campaign_options(p_mc, "campaign (default out/<scenario>_montecarlo, plus a hash of --set/--estimators)")
    p_mc.add_argument("--estimators", default=None, metavar="A,B", help="run only these estimators (default: all)")
    p_mc.add_argument("--screenshot", default=None, metavar="PNG",
                      help="also render report.html in headless Chromium into this PNG")
    p_mc.set_defaults(func=_cmd_montecarlo)
    p_cmp = sub.add_parser("compare", help="every listed estimator on every listed scenario: the comparison matrix")
    p_cmp.add_argument("scenarios", nargs="+", metavar="SCENARIO", help="shipped scenario names or YAML paths")
    p_cmp.add_argument("--estimators", default=None, metavar="A,B,SCENARIO:C",
                       help="estimator names (default: each scenario's own); SCENARIO:NAME takes NAME's config "
                            "from SCENARIO and adds it to every listed scenario that lacks it")
    _add_campaign_options(p_cmp, "comparison (default out/compare_<hash>)")
    p_cmp.set_defaults(func=_cmd_compare)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("\ndrake-att: interrupted; no result folder was written or changed", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
