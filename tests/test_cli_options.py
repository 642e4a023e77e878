"""What a user of the ``drake-att`` command sees, in process (drake_att/cli.py): the options'
parsed values and defaults, ``--help`` naming each option with its placeholder, default and
unit; ``list``'s lines; ``run``'s warnings and its "Wrote ... (replacing ...)" line;
``montecarlo``'s progress line, failed-run count, ``--scheduler serial`` and its Ctrl-C
message (saved runs counted); ``compare``'s notes on skipped cells and its "Wrote" line;
error lines cut at ``MAX_MESSAGE_CHARS``; SIGTERM (exit 143) and a call from another thread.

Short scenarios (30 s of simulated time, one run per campaign) keep the file fast."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import signal
import threading

import pytest

from drake_att import cli
from drake_att.scenarios.config import load_scenario

SCENARIO = "cubesat_single_star_tracker"
SHORT = ["--set", "duration_s=30", "--set", "scoring.score_from_s=10"]
SCENARIO_DIR = os.path.join(os.path.dirname(cli.__file__), "scenarios")


def _cli(argv):
    """``drake-att argv`` in this process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _one_line(text: str) -> str:
    return " ".join(text.split())


# ----------------------------------------------------------------------------------------
# Parsed values and defaults
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["montecarlo", "compare"])
def test_campaign_options_parse_to_their_documented_defaults_and_types(command):
    args = cli._parser().parse_args([command, SCENARIO, "--runs", "3"])
    assert args.runs == 3 and isinstance(args.runs, int)
    assert args.first_seed == 1 and isinstance(args.first_seed, int)
    assert args.workers is None and args.scheduler is None and args.set is None and args.out is None
    assert args.connect_timeout == 10.0 and isinstance(args.connect_timeout, float)
    assert args.resume is False and args.quiet is False and args.estimators is None
    assert args.batch_size is None  # the executor's default (10), set by the command
    given = cli._parser().parse_args(
        [
            command,
            SCENARIO,
            "--runs",
            "4",
            "--first-seed",
            "7",
            "--workers",
            "2",
            "--connect-timeout",
            "2.5",
            "--set",
            "a=1",
            "--set",
            "b=2",
            "--out",
            "o",
            "--resume",
            "--quiet",
            "--estimators",
            "x,y",
            "--batch-size",
            "3",
        ]
    )
    assert (given.runs, given.first_seed, given.workers, given.connect_timeout) == (4, 7, 2, 2.5)
    assert given.set == ["a=1", "b=2"] and given.out == "o" and given.resume and given.quiet
    assert given.estimators == "x,y"
    assert given.batch_size == 3 and isinstance(given.batch_size, int)


@pytest.mark.parametrize("command", ["montecarlo", "compare"])
def test_a_campaign_without_runs_is_refused_by_the_parser_naming_the_option(command, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli([command, SCENARIO, "--workers", "1", "--quiet", *SHORT])
    assert code == 2, err[-2000:]
    assert f"drake-att {command}: the following arguments are required: --runs" in err, err[-2000:]
    assert os.listdir(tmp_path) == []  # nothing ran, nothing written


def test_run_options_parse_to_their_defaults():
    args = cli._parser().parse_args(["run"])
    assert args.scenario is None and args.seed is None and args.out is None and args.set is None
    assert args.no_figures is False and args.quiet is False
    args = cli._parser().parse_args(["run", SCENARIO, "--seed", "5", "--no-figures", "--quiet"])
    assert args.seed == 5 and args.no_figures and args.quiet


# ----------------------------------------------------------------------------------------
# --help: every option named with its placeholder; defaults and units stated
# ----------------------------------------------------------------------------------------
def _help_entries(command, monkeypatch, capsys) -> dict:
    """``drake-att COMMAND --help`` as {invocation (lower case): its description (one line,
    lower case)}: e.g. ``{"--first-seed s": "seeds s .. s+n-1 (default 1)"}``."""
    monkeypatch.setenv("COLUMNS", "200")
    assert cli.main([command, "--help"]) == 0
    text = capsys.readouterr().out
    entries, current = {}, None
    for line in text.splitlines():
        entry = re.match(r"^  (\S.*?)(?:\s{2,}(\S.*))?$", line)
        if entry:
            current = entry.group(1).lower()
            entries[current] = (entry.group(2) or "").lower()
        elif current is not None and line.startswith("   ") and line.strip():
            entries[current] = _one_line(entries[current] + " " + line.lower())
        else:
            current = None
    return entries


def _says(description: str, *phrases) -> bool:
    """Each phrase appears as whole words (a garbled ``XXword`` does not count)."""
    return all(re.search(r"(?<![\w])" + re.escape(p.lower()) + r"(?![\w])", description) for p in phrases)


@pytest.mark.parametrize("command", ["montecarlo", "compare"])
def test_campaign_help_names_each_option_with_its_placeholder_default_and_unit(command, monkeypatch, capsys):
    entries = _help_entries(command, monkeypatch, capsys)
    assert _says(entries["--runs n"], "runs", "per scenario")
    assert _says(entries["--first-seed s"], "seeds s .. s+n-1", "default 1")
    assert _says(entries["--workers k"], "worker processes", "default: the cpu count", "1 = serial")
    assert _says(entries["--scheduler address"], "dask cluster", "serial")
    assert _says(entries["--connect-timeout seconds"], "seconds", "at most 3600", "default 10")
    from drake_att.analysis.executor import DEFAULT_BATCH_SIZE

    batch = entries["--batch-size b"]
    assert _says(batch, "seeds one simulation carries", "1 = every run alone", f"default {DEFAULT_BATCH_SIZE}")
    assert _says(entries["--set path=value"], "override a config value")
    assert _says(entries["--resume"], "continue the campaign")
    assert _says(entries["--quiet"], "no progress line")


def test_montecarlo_help_states_the_defaults_of_scenario_out_and_estimators(monkeypatch, capsys):
    entries = _help_entries("montecarlo", monkeypatch, capsys)
    assert _says(entries["scenario"], "shipped scenario name or yaml path", "default: the project's default scenario")
    assert _says(entries["--out dir"], "campaign", "default out/<scenario>_montecarlo", "folder")
    assert _says(entries["--estimators a,b"], "run only these estimators", "default: all")
    assert _says(entries["--screenshot png"], "report.html")


def test_compare_help_states_the_estimator_syntax_and_the_default_folder(monkeypatch, capsys):
    entries = _help_entries("compare", monkeypatch, capsys)
    assert _says(entries["scenario"], "shipped scenario names or yaml paths")
    assert _says(
        entries["--estimators a,b,scenario:c"], "estimator names", "default: each scenario's own", "scenario:name"
    )
    assert _says(entries["--out dir"], "comparison", "default out/compare_<hash>", "folder")


def test_run_help_names_seed_out_set_and_figures(monkeypatch, capsys):
    entries = _help_entries("run", monkeypatch, capsys)
    assert _says(entries["scenario"], "shipped scenario name or yaml path")
    assert _says(entries["--seed seed"], "random seed", "overrides the scenario's")
    assert _says(entries["--out out"], "output folder", "default out/<scenario>_seed<n>")
    assert _says(entries["--set path=value"], "override a config value")
    assert _says(entries["--no-figures"], "skip the png figures")
    assert _says(entries["--quiet"], "no progress line")


# ----------------------------------------------------------------------------------------
# Error lines
# ----------------------------------------------------------------------------------------
def test_an_error_line_of_exactly_the_limit_is_printed_whole_and_a_longer_one_is_cut(capsys):
    limit = cli.MAX_MESSAGE_CHARS
    cli._say("x" * limit)
    assert capsys.readouterr().err == "x" * limit + "\n"
    cli._say("y" * (limit + 1))
    assert capsys.readouterr().err == "y" * (limit - 3) + "...\n"


# ----------------------------------------------------------------------------------------
# list
# ----------------------------------------------------------------------------------------
def test_list_prints_every_shipped_scenario_its_description_and_estimators(capsys):
    assert cli.main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = sorted(f[:-5] for f in os.listdir(SCENARIO_DIR) if f.endswith(".yaml"))
    assert len(lines) == 3 * len(names)
    for i, name in enumerate(names):
        s = load_scenario(filename=os.path.join(SCENARIO_DIR, f"{name}.yaml"))
        head, desc, est = lines[3 * i : 3 * i + 3]
        assert head == (f"{name} (default)" if name == "cubesat_dual_star_tracker" else name)
        assert desc == "    " + _one_line(s.description)
        assert est == "    estimators: " + ", ".join(e.name for e in s.estimators)


# ----------------------------------------------------------------------------------------
# run
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """``run`` into ``r`` with the tracker out for the whole run, then again into ``r``
    without the outage: [(code, stdout, stderr)] x 2 and the folder."""
    where = tmp_path_factory.mktemp("runs")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(where)
        first = _cli(
            [
                "run",
                SCENARIO,
                "--out",
                "r",
                "--no-figures",
                "--quiet",
                *SHORT,
                "--set",
                "sensors.st1.outage_windows_s=[[-1.0, 100.0]]",
            ]
        )
        second = _cli(["run", SCENARIO, "--out", "r", "--no-figures", "--quiet", *SHORT])
    return first, second, where / "r"


def test_run_warns_of_an_estimator_that_used_no_measurement(two_runs):
    (code, _, err), (code2, _, err2), _ = two_runs
    assert code == 0 and code2 == 0, err[-2000:] + err2[-2000:]
    warning = [line for line in err.splitlines() if line.startswith("drake-att: warning:")]
    assert len(warning) == 1, err[-2000:]
    assert warning[0].startswith("drake-att: warning: estimator 'single' used no measurement in the whole run")
    assert "drake-att: warning" not in err2  # the tracker is in: no warning


def test_run_lists_the_files_it_wrote_and_says_when_it_replaced_a_folder(two_runs):
    (_, out, _), (_, out2, _), folder = two_runs
    files = sorted(os.listdir(folder))
    for text, tail in ((out, ": "), (out2, " (replacing the previous results there): ")):
        paragraph = text.rstrip("\n").split("\n\n")[-1].splitlines()  # the names wrapped at 100 columns
        assert all(len(line) <= 100 for line in paragraph), paragraph
        assert all(line.startswith("  ") for line in paragraph[1:]), paragraph
        listed = " ".join(line.strip() for line in paragraph[1:]).split(", ")
        assert paragraph[0] == f"Wrote {len(listed)} files to r/{tail.rstrip()}", paragraph
        assert sorted(listed) == files
    assert "replacing" not in out


# ----------------------------------------------------------------------------------------
# montecarlo
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """``montecarlo --runs 1 --scheduler serial`` into ``c`` (progress shown), then seed 2
    recorded as failed and the campaign resumed to 2 runs with ``--quiet``."""
    where = tmp_path_factory.mktemp("campaign")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(where)
        first = _cli(["montecarlo", SCENARIO, "--runs", "1", "--scheduler", "serial", "--out", "c", *SHORT])
        resumed = (None, "", "")
        if first[0] == 0:  # (each test checks the first exit code)
            (where / "c" / "runs" / "seed_2.failed.txt").write_text("truth went non-finite at t = 12 s\n")
            resumed = _cli(
                [
                    "montecarlo",
                    SCENARIO,
                    "--runs",
                    "2",
                    "--scheduler",
                    "serial",
                    "--out",
                    "c",
                    "--resume",
                    "--quiet",
                    *SHORT,
                ]
            )
    return first, resumed, where


def test_montecarlo_runs_serially_with_scheduler_serial_and_shows_progress_unless_quiet(campaign):
    (code, out, err), (code2, out2, err2), where = campaign
    assert code == 0, err[-2000:]
    assert "serially in this process" in err.splitlines()[0]
    assert re.search(r"\b1 / 1 runs\b", err), err[-2000:]  # the progress line
    assert (where / "c" / "runs" / "seed_1.npz").is_file()
    assert code2 == 0, err2[-2000:]
    assert not re.search(r"\d+ / 2 runs", err2), err2[-2000:]  # --quiet: no progress line
    assert "1 runs simulated, 0 found complete in c/runs;" in out


def test_montecarlo_counts_the_failed_runs_in_its_last_line(campaign):
    (code1, _, err1), (code, out, err), _ = campaign
    assert code1 == 0 and code == 0, err1[-2000:] + err[-2000:]
    assert "drake-att: warning: seed 2 failed: truth went non-finite at t = 12 s" in err
    assert "0 runs simulated, 1 found complete in c/runs, 1 failed; " in out, out[-2000:]
    first = campaign[0][1]
    assert "failed" not in first.splitlines()[-1]


def _interrupted(monkeypatch):
    """Ctrl-C while the campaign runs (run_campaign raises KeyboardInterrupt)."""
    from drake_att.analysis import campaign as campaign_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(campaign_module, "run_campaign", interrupted)


def test_an_interrupted_campaign_counts_its_saved_runs_and_suggests_resume(campaign, tmp_path, monkeypatch):
    (code, _, err), _, where = campaign
    assert code == 0, err[-2000:]
    shutil.copytree(where / "c", tmp_path / "c")  # seed 1 saved (seed 2 failed: not a saved run)
    monkeypatch.chdir(tmp_path)
    _interrupted(monkeypatch)
    code, _, err = _cli(["montecarlo", SCENARIO, "--runs", "3", "--workers", "1", "--out", "c", "--resume", *SHORT])
    assert code == 130, err[-2000:]
    assert (
        "drake-att montecarlo: interrupted; 1 of 3 runs are saved in c/runs; the same command with --resume "
        "continues the campaign"
    ) in err, err[-2000:]


def test_an_interrupted_campaign_without_a_finished_run_says_nothing_was_kept(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _interrupted(monkeypatch)
    code, _, err = _cli(["montecarlo", SCENARIO, "--runs", "2", "--workers", "1", "--out", "c", *SHORT])
    assert code == 130, err[-2000:]
    assert "drake-att montecarlo: interrupted; no run had finished, so nothing was kept" in err, err[-2000:]


# ----------------------------------------------------------------------------------------
# compare
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def comparison(tmp_path_factory):
    """``compare SCENARIO --estimators single,nope --runs 1`` into ``cmp``: ``nope`` is a
    skipped cell."""
    where = tmp_path_factory.mktemp("compare")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(where)
        result = _cli(
            [
                "compare",
                SCENARIO,
                "--estimators",
                "single,nope",
                "--runs",
                "1",
                "--workers",
                "1",
                "--quiet",
                "--out",
                "cmp",
                *SHORT,
            ]
        )
    return result, where / "cmp"


def test_compare_notes_each_skipped_cell_on_stderr(comparison):
    (code, _, err), _ = comparison
    assert code == 0, err[-2000:]
    notes = [line for line in err.splitlines() if line.startswith("drake-att compare: note:")]
    assert notes == [
        f"drake-att compare: note: {SCENARIO} x nope: not an estimator of this scenario (SOURCE:NAME "
        "adds one from another scenario)"
    ], err[-2000:]


def test_compare_names_the_files_it_wrote(comparison):
    (code, out, err), folder = comparison
    assert code == 0, err[-2000:]
    paragraph = out.rstrip("\n").split("\n\n")[-1].splitlines()
    assert all(len(line) <= 100 for line in paragraph), paragraph
    assert " ".join(paragraph) == (
        "Wrote cmp/comparison.html, comparison.json, comparison.md and comparison.png "
        "(one campaign folder per scenario under cmp/)"
    )
    for name in ("comparison.html", "comparison.json", "comparison.md", "comparison.png"):
        assert (folder / name).is_file(), name


# ----------------------------------------------------------------------------------------
# SIGTERM and threads
# ----------------------------------------------------------------------------------------
def test_sigterm_during_a_command_exits_143_and_restores_the_previous_handler(monkeypatch, capsys):
    from drake_att.scenarios import library

    received = []

    def sentinel(signum, frame):
        received.append(signum)

    def terminated_while_listing():
        os.kill(os.getpid(), signal.SIGTERM)
        return {}

    monkeypatch.setattr(library, "available_scenarios", terminated_while_listing)
    previous = signal.signal(signal.SIGTERM, sentinel)
    try:
        code = cli.main(["list"])
        assert signal.getsignal(signal.SIGTERM) is sentinel  # put back after the command
    finally:
        signal.signal(signal.SIGTERM, previous)
    err = capsys.readouterr().err
    assert code == 143 and received == [], err
    assert "drake-att: terminated (SIGTERM); no result folder was written or changed" in err


def test_main_called_from_another_thread_runs_the_command(capsys):
    """A GUI or a notebook kernel may call main() off the main thread (no signal handler can
    be installed there): the command still runs."""
    outcome = {}

    def call():
        try:
            outcome["code"] = cli.main(["list"])
        except BaseException as e:  # reported by the assertion below
            outcome["error"] = e

    thread = threading.Thread(target=call)
    thread.start()
    thread.join()
    assert outcome == {"code": 0}, outcome
    assert f"{SCENARIO}\n" in capsys.readouterr().out
