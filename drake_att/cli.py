"""Command line: ``drake-att run [SCENARIO] [--seed N] [--out DIR] [--set path=value ...]``,
``drake-att score OUT_DIR [--out FILE]``, ``drake-att list``, ``drake-att montecarlo
SCENARIO --runs N ...`` (a Monte Carlo campaign on Dask) and ``drake-att compare
SCENARIO... --runs N ...`` (the estimator x scenario comparison matrix), ``drake-att
check SCENARIO`` (validate without simulating) and ``drake-att view OUT_DIR`` (a run in 3-D).

Every refusal of user input (a file, a field, an option, a folder) is one line on stderr
naming it and exit code 2; an unexpected internal error is one line and exit code 1, with
the traceback only under ``--debug``; Ctrl-C is exit code 130.

Seven subcommands behind one guard (exit codes, messages, the writer lock); a parser helper each.
"""

from __future__ import annotations

import argparse
import os
import sys

from drake_att import interrupts
from drake_att.scenarios.config import ConfigError, apply_overrides, load_scenario
from drake_att.validation import UserInputError

# No line the CLI prints about an error is longer than this (values are cut, not the rule).
MAX_MESSAGE_CHARS = 1000
REPORT_WIDTH = 100  # the printed tables' width too (drake_att.analysis.metrics.format_table)


def _report(heading: str, items: str) -> None:
    """Print on stdout, after a blank line, ``heading`` and then ``items`` indented and wrapped
    at :data:`REPORT_WIDTH` (a name longer than a line stays whole)."""
    import textwrap

    print("\n" + heading)
    print(textwrap.fill(items, REPORT_WIDTH, initial_indent="  ", subsequent_indent="  ", break_long_words=False))


def _say(text: str) -> None:
    """Print one error line on stderr, on one line and at most :data:`MAX_MESSAGE_CHARS`."""
    line = " ".join(str(text).split())
    if len(line) > MAX_MESSAGE_CHARS:
        line = line[: MAX_MESSAGE_CHARS - 3] + "..."
    print(line, file=sys.stderr)


def _cmd_list(args) -> int:
    from drake_att.scenarios.library import DEFAULT_SCENARIO, available_scenarios

    for name, path in available_scenarios().items():
        s = load_scenario(filename=path)
        mark = " (default)" if name == DEFAULT_SCENARIO else ""
        desc = " ".join(s.description.split())
        print(f"{name}{mark}\n    {desc}\n    estimators: {', '.join(e.name for e in s.estimators)}")
    return 0


def _load_with_overrides(scenario_arg, overrides, seed=None):
    from drake_att.scenarios.library import scenario_path

    path = scenario_path(scenario_arg)
    scenario = load_scenario(filename=path)
    overrides = list(overrides or [])
    if seed is not None:
        overrides.append(f"seed={seed}")
    if overrides:
        scenario = apply_overrides(scenario, overrides)
    return path, scenario


def _preflight(scenario, processes: int = 1) -> None:
    """Refuse what cannot run here (memory, with ``processes`` runs at once on this
    machine), then print the warnings of a valid scenario."""
    from drake_att.scenarios import preflight

    preflight.check_memory(scenario, processes=processes)
    for message in preflight.preflight_warnings(scenario):
        _say(f"drake-att: warning: {message}")


def _local_processes(args) -> int:
    """Runs at once on this machine for a campaign's options (a remote cluster's memory is
    its own: one, for the client's check)."""
    if args.scheduler is not None:
        return 1
    return max(1, min(args.workers or os.cpu_count() or 1, args.runs))


def _result_bytes(scenario) -> int:
    from drake_att.scenarios.preflight import result_bytes

    return int(result_bytes(scenario))


def _cmd_check(args) -> int:
    path, scenario = _load_with_overrides(args.scenario, args.set, args.seed)
    _preflight(scenario)
    import warnings

    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.preflight import DegenerateScenarioWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateScenarioWarning)  # printed above, as one line each
        ScenarioDiagram(scenario)  # what only the built diagram knows: e.g. the logging policy's signals
    print(
        f"{path}: valid ({scenario.name}: {len(scenario.sensors)} sensors, {len(scenario.estimators)} "
        f"estimators, {scenario.duration_s:g} s, seed {scenario.seed})"
    )
    return 0


def _cmd_run(args) -> int:
    from drake_att import outputs
    from drake_att.analysis.metrics import compute_metrics, format_table
    from drake_att.analysis.report import write_results
    from drake_att.scenarios.builder import NonFiniteRunError, ScenarioDiagram

    try:
        path, scenario = _load_with_overrides(args.scenario, args.set, args.seed)
    except ConfigError as e:
        _say(f"drake-att: invalid scenario: {e}")
        return 2
    # The default folder names the scenario and seed, and the overrides too (a short hash of
    # them): a run with --set never lands in (and replaces) the unmodified run's folder.
    out_dir = args.out if args.out is not None else default_out("run", scenario, args.set)
    _preflight(scenario)
    out_dir = outputs.check_target(out_dir, option="--out", need_bytes=_result_bytes(scenario))
    with outputs.writer_lock(out_dir):
        print(f"Building {scenario.name} ({path}) ...", file=sys.stderr)
        import warnings

        from drake_att.scenarios.preflight import DegenerateScenarioWarning, run_warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DegenerateScenarioWarning)  # printed above, as one line each
            sd = ScenarioDiagram(scenario)
        try:
            run = sd.simulate(scenario.seed, progress=not args.quiet)
        except NonFiniteRunError as e:
            _say(f"drake-att: the run failed: {e}")
            return 2
        metrics = compute_metrics(run)
        print(format_table(metrics, scenario))
        for message in run_warnings(metrics):
            _say(f"drake-att: warning: {message}")
        replaced = os.path.isdir(out_dir)
        try:
            files = write_results(sd, run, metrics, out_dir, figures=not args.no_figures)
        except OSError as e:
            _say(
                f"drake-att: --out {out_dir}: cannot write the results ({e.strerror or e}); nothing was written "
                "or replaced"
            )
            return 2
    _report(
        f"Wrote {len(files)} files to {out_dir}/"
        + (" (replacing the previous results there)" if replaced else "")
        + ":",
        ", ".join(os.path.basename(f) for f in files),
    )
    return 0


def _cmd_score(args) -> int:
    import zipfile

    from drake_att.analysis.metrics import compute_metrics, format_table
    from drake_att.analysis.report import write_metrics_json
    from drake_att.scenarios.builder import RunLog

    def fail(msg):
        _say(f"drake-att score: {msg}")
        return 2

    out_dir = args.out_dir
    if not os.path.isdir(out_dir):
        return fail(f"{out_dir}: no such result folder")
    npz_path, config_path = os.path.join(out_dir, "log.npz"), os.path.join(out_dir, "config.yaml")
    for path in (npz_path, config_path):
        if not os.path.isfile(path):
            return fail(f"{path}: missing (a result folder of `drake-att run` holds log.npz and config.yaml)")
    out = args.out if args.out is not None else os.path.join(out_dir, "metrics.json")
    if not out.strip():
        return fail(f"--out: got {out!r}; name a file for the metrics")
    previous = _previous_metrics(out)
    try:
        scenario = load_scenario(filename=config_path, new_plugins=args.allow_plugins)
    except ConfigError as e:
        return fail(f"{config_path}: not a valid scenario: {e}")
    try:
        run = RunLog.load(npz_path, scenario)
    except (OSError, ValueError, EOFError, KeyError, TypeError, zipfile.BadZipFile) as e:
        return fail(f"{npz_path}: cannot be scored: {type(e).__name__}: {e}")
    try:
        metrics = compute_metrics(run)
    except (ValueError, KeyError, IndexError, TypeError) as e:
        return fail(f"{npz_path}: cannot be scored: {type(e).__name__}: {e}")
    print(format_table(metrics, scenario))
    try:
        write_metrics_json(metrics, out)
        with open(out, "rb") as f:
            now = f.read()
    except OSError as e:
        return fail(f"{out}: cannot write ({e.strerror or e}); the file is unchanged")
    same = (
        ""
        if previous is None
        else (" (identical to the file it replaced)" if previous == now else " (differs from the file it replaced)")
    )
    print(f"\nWrote {out}{same}")
    return 0


def _previous_metrics(path: str):
    """The bytes of the metrics file ``score`` is about to replace (None: there is none).
    Only a metrics file of ours is replaced: anything else at ``path`` is refused."""
    import json

    from drake_att.outputs import OutputError

    if not os.path.lexists(path):
        return None
    if os.path.islink(path) or not os.path.isfile(path):
        raise OutputError(f"--out {path}: is not a regular file; name a new file or a metrics.json of drake-att")
    with open(path, "rb") as f:
        data = f.read(2**26)
    try:
        ours = isinstance(json.loads(data.decode("utf-8")).get("estimators"), dict)
    except (ValueError, AttributeError):
        ours = False
    if not ours:
        raise OutputError(f"--out {path}: exists and is not a metrics.json written by drake-att; name a new file")
    return data


def default_out(command: str, scenario, overrides=None, estimators=None, scenarios=()) -> str:
    """The default output folder of ``command`` (one safe path component under ``out/``):

    * ``run``: ``<name>_seed<seed>`` plus ``_<hash of the --set strings>`` when there are any;
    * ``montecarlo``: ``<name>_montecarlo`` plus the hash of the ``--set`` strings and
      ``--estimators=<list>`` when given (the seeds are not in it: a campaign grows by
      ``--resume``);
    * ``compare``: ``compare`` plus the hash of the scenario arguments, the ``--set`` strings
      and the ``--estimators`` text.

    A modified run never lands in (and replaces) the unmodified one's folder."""
    from drake_att import outputs

    sets = list(overrides or [])
    if command == "run":
        name = f"{scenario.name}_seed{scenario.seed}{_override_tag(sets)}"
    elif command == "montecarlo":
        name = (
            f"{scenario.name}_montecarlo{_override_tag(sets + ([f'--estimators={estimators}'] if estimators else []))}"
        )
    else:
        name = f"compare{_override_tag(list(scenarios) + sets + [estimators or ''])}"
    return os.path.join("out", outputs.safe_component(name))


def _override_tag(items) -> str:
    """A short hash of ``--set``-like strings (empty for none): default folders of modified
    runs never land in (and replace) the unmodified ones."""
    if not items:
        return ""
    import hashlib

    return "_" + hashlib.sha1("\n".join(items).encode("utf-8", "surrogateescape")).hexdigest()[:8]


def _estimator_list(text):
    """``--estimators A,B``: the names, each once (None: all)."""
    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names or len(set(names)) != len(names):
        raise UserInputError(
            f"--estimators: got {text[:200]!r}; a comma-separated list of estimator names, each listed once"
        )
    return names


def _campaign_failed(command: str, e) -> int:
    _say(f"drake-att {command}: {e}")
    return 2


def _saved_runs(out) -> int:
    runs = os.path.join(out, "runs") if out else None
    return len([f for f in os.listdir(runs) if f.endswith(".npz")]) if runs and os.path.isdir(runs) else 0


def _kept_runs(out: str, runs: int) -> str:
    """What an interrupted campaign in ``out`` kept, in words."""
    saved = _saved_runs(out)
    return (
        f"{saved} of {runs} runs are saved in {out}/runs; the same command with --resume continues the campaign"
        if saved
        else "no run had finished, so nothing was kept"
    )


def _run_holding_lock(command: str, run, target, args, scheduler, out: str, kept):
    """``run(target, ...)`` (:func:`~drake_att.analysis.campaign.run_campaign` or
    :func:`~drake_att.analysis.comparison.run_comparison`) with the command line's campaign
    options, holding ``out``'s writer lock. Returns ``(result, None)``, or ``(None, exit code)``:
    2 for a user's error (its message on stderr), 130 for Ctrl-C (``kept()``, what was kept, on stderr)."""
    from drake_att import outputs

    try:
        with outputs.writer_lock(out):
            return run(
                target,
                args.runs,
                args.first_seed,
                workers=args.workers,
                scheduler=scheduler,
                out=out,
                resume=args.resume,
                progress=not args.quiet,
                connect_timeout_s=args.connect_timeout,
                batch_size=args.batch_size,
            ), None
    except UserInputError as e:
        return None, _campaign_failed(command, e)
    except KeyboardInterrupt:
        print(f"\ndrake-att {command}: interrupted; {kept()}", file=sys.stderr)
        return None, 130


def _cmd_montecarlo(args) -> int:
    from drake_att import outputs
    from drake_att.analysis import campaign_report
    from drake_att.analysis.campaign import campaign_seeds, resolve_scenario, run_campaign
    from drake_att.analysis.executor import executor_phrase
    from drake_att.scenarios.library import scenario_path

    def fail(e):
        return _campaign_failed("montecarlo", e)

    estimators = _estimator_list(args.estimators)
    try:
        campaign_seeds(args.runs, args.first_seed)
        scenario = resolve_scenario(scenario_path(args.scenario), args.set or (), estimators)
        scheduler = _scheduler_option(args)
    except UserInputError as e:
        return fail(e)
    out = args.out if args.out is not None else default_out("montecarlo", scenario, args.set, args.estimators)
    _preflight(scenario, _local_processes(args))
    out = outputs.check_target(out, option="--out", kinds=("empty", "campaign"))
    where = executor_phrase(args.workers, scheduler, args.runs)
    print(
        f"Monte Carlo: {scenario.name}, {args.runs} runs (seeds {args.first_seed}..{args.first_seed + args.runs - 1}) "
        f"{where} -> {out}/",
        file=sys.stderr,
    )
    result, code = _run_holding_lock(
        "montecarlo", run_campaign, scenario, args, scheduler, out, lambda: _kept_runs(out, args.runs)
    )
    if code is not None:
        return code
    print(campaign_report.format_campaign_table(result))
    for seed, message in result.failed.items():
        _say(f"drake-att: warning: seed {seed} failed: {message}")
    failed = f", {len(result.failed)} failed" if result.failed else ""
    print(
        f"\n{result.ran} runs simulated, {result.reused} found complete in {out}/runs{failed}; "
        f"{result.wall_time_s:.1f} s wall.\n"
        f"Wrote {out}/report.html, summary.json and {len([f for f in result.files if f.endswith('.png')])} figures"
    )
    if args.screenshot:
        try:
            png = campaign_report.screenshot(os.path.join(out, "report.html"), args.screenshot)
        except (OSError, RuntimeError) as e:
            return fail(f"--screenshot {args.screenshot}: {e}")
        print(f"Screenshot of the report: {png}")
    return 0


def _scheduler_option(args):
    from drake_att.analysis.dask_connection import CampaignError, check_connect_timeout, check_scheduler_address

    if args.workers is not None and not 1 <= args.workers <= 1024:
        raise CampaignError(f"--workers: got {args.workers}; must be an integer in [1, 1024]")
    if args.batch_size is None:
        from drake_att.analysis.executor import DEFAULT_BATCH_SIZE

        args.batch_size = DEFAULT_BATCH_SIZE
    elif not 1 <= args.batch_size <= 1000:
        raise CampaignError(f"--batch-size: got {args.batch_size}; must be an integer in [1, 1000]")
    args.connect_timeout = check_connect_timeout(args.connect_timeout)
    if args.scheduler is None:
        return None
    if args.scheduler == "serial":
        return "serial"
    if args.workers is not None:
        raise CampaignError(
            f"--workers {args.workers} with --scheduler {args.scheduler}: the cluster's own workers "
            "run the campaign; give one of the two"
        )
    return check_scheduler_address(args.scheduler)


def _cmd_compare(args) -> int:
    from drake_att import outputs
    from drake_att.analysis import campaign_report
    from drake_att.analysis.campaign import campaign_seeds
    from drake_att.analysis.comparison import comparison_plan, run_comparison

    def fail(e):
        return _campaign_failed("compare", e)

    try:
        campaign_seeds(args.runs, args.first_seed)
        plan = comparison_plan(args.scenarios, _estimator_list(args.estimators), args.set or ())
        scheduler = _scheduler_option(args)
    except UserInputError as e:
        return fail(e)
    out = args.out if args.out is not None else default_out("compare", None, args.set, args.estimators, args.scenarios)
    for scenario in plan.scenarios:
        _preflight(scenario, _local_processes(args))
    out = outputs.check_target(out, option="--out", kinds=("empty", "comparison"))
    for cell in plan.skipped:
        print(f"drake-att compare: note: {cell}", file=sys.stderr)
    result, code = _run_holding_lock(
        "compare",
        run_comparison,
        plan,
        args,
        scheduler,
        out,
        lambda: f"the finished runs are saved under {out}/; the same command with --resume continues",
    )
    if code is not None:
        return code
    print(campaign_report.format_comparison_table(result))
    print(
        f"\nWrote {out}/comparison.html, comparison.json, comparison.md and comparison.png\n"
        f"(one campaign folder per scenario under {out}/)"
    )
    return 0


def _add_campaign_options(p, what: str) -> None:
    p.add_argument("--runs", type=int, required=True, metavar="N", help="runs (seeds) per scenario")
    p.add_argument("--first-seed", type=int, default=1, metavar="S", help="seeds S .. S+N-1 (default 1)")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="K",
        help="worker processes of the local Dask cluster (default: the CPU count); 1 = serial, in this process",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on an existing Dask cluster (tcp://HOST:8786, started with `dask scheduler` and "
        "`dask worker tcp://HOST:8786`), or 'serial'",
    )
    p.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="deadline in seconds (> 0, at most 3600) for reaching --scheduler: the connection, Dask's "
        "handshake, the first worker and its version check, plus a few seconds (default 10)",
    )
    p.add_argument(
        "--batch-size",
        type=int,
        default=None,
        metavar="B",
        help="the most seeds one simulation carries where the scenario allows it (one truth shared by "
        "every seed; the same records, for less CPU); 1 = every run alone (default 10)",
    )
    p.add_argument("--set", action="append", metavar="PATH=VALUE", help="override a config value (as for run)")
    p.add_argument("--out", default=None, metavar="DIR", help=f"{what} folder")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the campaign in --out: finished runs are kept, the others run (the config must match)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``drake-att: <message>``, exit 2) instead of a usage
    block, so every refusal looks alike."""

    def error(self, message):
        raise _UsageError(f"{self.prog}: {message} (see {self.prog} --help)")


class _UsageError(UserInputError):
    pass


def _parser() -> argparse.ArgumentParser:
    """The ``drake-att`` command line: the shared ``--debug`` option and one ``_add_*_command`` per subcommand."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--debug", action="store_true", help="show the full traceback of an unexpected error (for bug reports)"
    )
    parser = _Parser(prog="drake-att", description="Attitude-determination scenarios on Drake.", parents=[common])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for add_command in (
        _add_run_command,
        _add_check_command,
        _add_score_command,
        _add_list_command,
        _add_montecarlo_command,
        _add_compare_command,
        _add_view_command,
    ):
        add_command(sub, common)
    return parser


def _add_run_command(sub, common) -> None:
    """``drake-att run``: simulate one scenario into a result folder."""
    p_run = sub.add_parser("run", parents=[common], help="run a scenario (default: the project's default scenario)")
    p_run.add_argument("scenario", nargs="?", default=None, help="shipped scenario name or YAML path")
    p_run.add_argument("--seed", type=int, default=None, help="random seed (overrides the scenario's)")
    p_run.add_argument(
        "--out",
        default=None,
        help="output folder (default out/<scenario>_seed<N>, plus a hash of "
        "the --set overrides if any); replaced as a whole, atomically, and only if it is empty or "
        "a result folder of drake-att",
    )
    p_run.add_argument(
        "--set",
        action="append",
        metavar="PATH=VALUE",
        help="override a config value, e.g. --set duration_s=600 --set sensors.st1.period_s=1",
    )
    p_run.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p_run.add_argument("--quiet", action="store_true", help="no progress line")
    p_run.set_defaults(func=_cmd_run)


def _add_check_command(sub, common) -> None:
    """``drake-att check``: validate a scenario without simulating."""
    p_check = sub.add_parser(
        "check",
        parents=[common],
        help="validate a scenario (with --set) without simulating: field ranges, memory, warnings",
    )
    p_check.add_argument("scenario", nargs="?", default=None, help="shipped scenario name or YAML path")
    p_check.add_argument("--seed", type=int, default=None, help="random seed (overrides the scenario's)")
    p_check.add_argument("--set", action="append", metavar="PATH=VALUE", help="override a config value (as for run)")
    p_check.set_defaults(func=_cmd_check)


def _add_score_command(sub, common) -> None:
    """``drake-att score``: recompute a result folder's metrics."""
    p_score = sub.add_parser(
        "score", parents=[common], help="recompute a result folder's metrics.json from its log.npz + config.yaml"
    )
    p_score.add_argument("out_dir", metavar="OUT_DIR", help="result folder written by `drake-att run`")
    p_score.add_argument(
        "--out", default=None, metavar="FILE", help="write the metrics here (default OUT_DIR/metrics.json)"
    )
    p_score.add_argument(
        "--allow-plugins",
        action="store_true",
        help="import the plug-in modules the folder's config.yaml names (runs their code: only for "
        "folders you trust); without it such a folder is refused",
    )
    p_score.set_defaults(func=_cmd_score)


def _add_list_command(sub, common) -> None:
    """``drake-att list``: the shipped scenarios."""
    p_list = sub.add_parser("list", parents=[common], help="list the shipped scenarios")
    p_list.set_defaults(func=_cmd_list)


def _add_montecarlo_command(sub, common) -> None:
    """``drake-att montecarlo``: a Monte Carlo campaign over seeds."""
    p_mc = sub.add_parser(
        "montecarlo", parents=[common], help="Monte Carlo campaign over seeds (Dask), with report.html"
    )
    p_mc.add_argument(
        "scenario",
        nargs="?",
        default=None,
        metavar="SCENARIO",
        help="shipped scenario name or YAML path (default: the project's default scenario)",
    )
    _add_campaign_options(p_mc, "campaign (default out/<scenario>_montecarlo, plus a hash of --set/--estimators)")
    p_mc.add_argument("--estimators", default=None, metavar="A,B", help="run only these estimators (default: all)")
    p_mc.add_argument(
        "--screenshot", default=None, metavar="PNG", help="also render report.html in headless Chromium into this PNG"
    )
    p_mc.set_defaults(func=_cmd_montecarlo)


def _add_compare_command(sub, common) -> None:
    """``drake-att compare``: the estimator x scenario comparison matrix."""
    p_cmp = sub.add_parser(
        "compare", parents=[common], help="every listed estimator on every listed scenario: the comparison matrix"
    )
    p_cmp.add_argument("scenarios", nargs="+", metavar="SCENARIO", help="shipped scenario names or YAML paths")
    p_cmp.add_argument(
        "--estimators",
        default=None,
        metavar="A,B,SCENARIO:C",
        help="estimator names (default: each scenario's own); SCENARIO:NAME takes NAME's config "
        "from SCENARIO and adds it to every listed scenario that lacks it",
    )
    _add_campaign_options(p_cmp, "comparison (default out/compare_<hash>)")
    p_cmp.set_defaults(func=_cmd_compare)


def _cmd_view(args) -> int:
    """``drake-att view``: the run in Meshcat (served until Ctrl-C unless ``--no-serve``), the static page with ``--html``."""
    from drake_att.analysis import view3d

    try:
        meshcat, geometry = view3d.view_run(
            args.out_dir,
            html_path=args.html,
            frames=args.frames,
            box_m=args.box_m,
            playback_s=args.playback_s,
            error_scale=args.error_scale,
            still_time_s=args.at,
            allow_plugins=args.allow_plugins,
        )
    except view3d.ViewError as e:
        _say(f"drake-att view: {e}")
        return 2
    print("\nLegend:")
    for line in view3d.legend(geometry, args.playback_s, args.error_scale):
        print(f"  {line}")
    if args.html:
        print(f"\nWrote {args.html} (the scene and its animation; opens without a server or network)")
    if args.no_serve:
        return 0
    import time

    print(f"\nMeshcat: {meshcat.web_url()} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("\ndrake-att view: stopped", file=sys.stderr)
    return 0


def _add_view_command(sub, common) -> None:
    """``drake-att view``: a saved run in 3-D (Meshcat)."""
    from drake_att.analysis import view3d

    p = sub.add_parser(
        "view",
        parents=[common],
        help="replay a result folder in 3-D in Meshcat (spacecraft, trackers' cones, Sun/Earth/Moon, estimates)",
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="result folder written by `drake-att run`")
    p.add_argument("--html", default=None, metavar="FILE", help="also write the view as one self-contained HTML page")
    p.add_argument("--no-serve", action="store_true", help="do not keep serving Meshcat (with --html: just write it)")
    p.add_argument(
        "--frames",
        type=int,
        default=view3d.DEFAULT_FRAMES,
        metavar="N",
        help=f"frames of the replay, spread evenly over the run (default {view3d.DEFAULT_FRAMES}, "
        f"at most {view3d.MAX_FRAMES})",
    )
    p.add_argument(
        "--playback-s",
        type=float,
        default=view3d.DEFAULT_PLAYBACK_S,
        metavar="S",
        help=f"the animation plays the whole run in S seconds (default {view3d.DEFAULT_PLAYBACK_S:g})",
    )
    p.add_argument(
        "--box-m",
        type=float,
        nargs=3,
        default=None,
        metavar=("X", "Y", "Z"),
        help="the spacecraft box's edges in m (default: a uniform box of "
        f"{view3d.DEFAULT_DENSITY_KG_M3:g} kg/m^3 with the plant's inertia)",
    )
    p.add_argument(
        "--error-scale",
        type=float,
        default=1.0,
        metavar="K",
        help="magnify each estimate's attitude error K times (default 1: as estimated)",
    )
    p.add_argument("--at", type=float, default=None, metavar="T", help="run time (s) the still scene shows (default 0)")
    p.add_argument(
        "--allow-plugins",
        action="store_true",
        help="import the plug-in modules the folder's config.yaml names (as for score)",
    )
    p.set_defaults(func=_cmd_view)


def main(argv=None) -> int:
    """The ``drake-att`` command: returns the exit code (0 done, 2 refused input, 1 an
    unexpected error, 130 interrupted); never raises, except with ``--debug``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
    import signal
    import threading

    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        args = _parser().parse_args(argv)
        with interrupts.remembered():
            return args.func(args)
    except _Terminated:
        print("\ndrake-att: terminated (SIGTERM); no result folder was written or changed", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("\ndrake-att: interrupted; no result folder was written or changed", file=sys.stderr)
        return 130
    except UserInputError as e:  # the user's input, not a bug: one line also under --debug
        text = str(e)
        _say(text if text.startswith("drake-att") else f"drake-att: {text}")
        return 2
    except SystemExit as e:  # --help, or a library call that exits
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except MemoryError:
        if debug:
            raise
        _say(
            "drake-att: out of memory; the run needs more memory than this machine has (fewer particles, a "
            "shorter duration or longer sensor periods?)"
        )
        return 1
    except Exception as e:  # noqa: BLE001 - the one guard: a user sees one line, a developer uses --debug
        if debug:
            raise
        where = ""
        tb = e.__traceback__
        while tb is not None:
            where = f" at {os.path.basename(tb.tb_frame.f_code.co_filename)}:{tb.tb_lineno}"
            tb = tb.tb_next
        _say(
            f"drake-att: internal error: {type(e).__name__}: {e}{where}; please report it with the output of "
            "the same command with --debug"
        )
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that every ``finally`` runs (staging folders
    and locks are removed, a Dask cluster is closed) before the process exits 143."""


def _terminate(signum, frame):
    raise _Terminated()


if __name__ == "__main__":
    sys.exit(main())
