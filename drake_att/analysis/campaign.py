"""Monte Carlo campaigns (``drake-att montecarlo``): :func:`run_campaign` over
:func:`~drake_att.analysis.executor.map_runs`, streamed to disk and resumable.

Seeds ``first_seed .. first_seed + runs - 1``; each finished run is written as it arrives
to ``<out>/runs/seed_<seed>.npz`` (temporary file + ``os.replace``: a file there is always
complete), so an interrupted campaign ``resume``\\ s without redoing or losing finished
runs; then ``summary.json`` (the ensemble statistics of :mod:`drake_att.analysis.ensemble`),
``report.html`` + PNGs (:mod:`drake_att.analysis.campaign_report`) and ``manifest.json``.
The folder itself is :mod:`drake_att.analysis.campaign_folder`.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drake_att import interrupts
from drake_att.analysis.campaign_folder import (
    CAMPAIGN_FILE,
    CONFIG_FILE,
    _create_folder,
    _inspect_folder,
    _load_existing,
    _record_check,
    _remove_created,
    _write_campaign_file,
    write_campaign_manifest,
)
from drake_att.analysis.campaign_records import (
    RUNS_DIR,
    _failed_path,
    _run_path,
    _valid_layout,
    record_layout,
    save_record,
    write_text_atomic,
)
from drake_att.analysis.dask_connection import (
    DEFAULT_CONNECT_TIMEOUT_S,
    CampaignError,
    _connect,
    _shown,
    _shut_down,
    check_connect_timeout,
)
from drake_att.analysis.executor import (
    DEFAULT_BATCH_SIZE,
    RunFailed,
    _check_workers,
    _is_serial,
    check_batch_size,
    executor_name,
    map_runs,
)
from drake_att.analysis.run_records import default_record
from drake_att.progress import Progress, format_duration
from drake_att.scenarios import config as cfg
from drake_att.scenarios.selection import with_estimators
from drake_att.validation import SEED_MAX


@dataclass
class CampaignResult:
    """What :func:`run_campaign` returns.

    Attributes:
        scenario: the resolved scenario that ran (overrides applied, estimators selected).
        seeds: the campaign's seeds.
        records: one per seed that did not fail, in seed order.
        failed: seed -> message of the runs that went non-finite.
        summary: the ensemble statistics (``summary.json``'s ``statistics``).
        out: the campaign folder (None: nothing written).
        ran: records simulated by this call (runs that completed).
        reused: records read from disk (``resume``): complete runs not redone.
        failed_reused: how many of ``failed`` were read from disk (a run that went
            non-finite is not redone: it would again). The counts partition the seeds:
            ``ran + reused + len(failed) == len(seeds)``; this call simulated
            ``ran + len(failed) - failed_reused`` runs.
        wall_time_s: this call's wall time.
        files: the files written at the top of ``out`` (report, figures, summary, ...).
    """

    scenario: cfg.Scenario
    seeds: list
    records: list
    failed: dict
    summary: dict | None
    out: str | None = None
    ran: int = 0
    reused: int = 0
    wall_time_s: float = 0.0
    files: list = field(default_factory=list)
    failed_reused: int = 0

    @property
    def simulated(self) -> int:
        """Runs simulated by this call (completed or failed)."""
        return self.ran + len(self.failed) - self.failed_reused


class CampaignProgress(Progress):
    """Runs done of a campaign, wall time and ETA (one rewritten line on a terminal; in a
    log one line per ~5 % of the runs). The ETA extrapolates this session's pace."""

    def __init__(self, total_runs: int, already_done: int = 0, label: str = "", **kwargs):
        super().__init__(float(total_runs), label, **kwargs)
        self.total_runs, self.already_done, self.done = int(total_runs), int(already_done), 0
        self._every = max(1, (total_runs - already_done) // 20)
        self._first_at = None

    def line(self, done: float) -> str:
        done = int(done)
        elapsed = self.clock() - self.start
        total_done = self.already_done + done
        left = self.total_runs - total_done
        if left <= 0:
            eta = "done"
        elif done > 1 and self._first_at is not None:
            # The pace since the first result: the start-up (cluster, imports, first diagram)
            # is not a cost every run pays again.
            eta = "ETA " + format_duration((self.clock() - self._first_at) / (done - 1) * left)
        elif done > 0:
            eta = "ETA " + format_duration(elapsed * left / done)
        else:
            eta = "ETA unknown"
        frac = total_done / self.total_runs if self.total_runs else 1.0
        prefix = f"  [{self.label}] " if self.label else "  "
        reused = f" ({self.already_done} from before)" if self.already_done else ""
        return (
            f"{prefix}{total_done} / {self.total_runs} runs{reused} ({frac:4.0%})  "
            f"{format_duration(elapsed)} wall  {eta}"
        )

    def run_done(self) -> None:
        self.done += 1
        if self._first_at is None:
            self._first_at = self.clock()
        if self.tty or self.done % self._every == 0 or self.already_done + self.done >= self.total_runs:
            self.update(self.done)


def campaign_seeds(runs: int, first_seed: int = 1) -> list[int]:
    """``first_seed .. first_seed + runs - 1``, checked (CampaignError naming the flag)."""
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1:
        raise CampaignError(f"--runs: got {runs!r}; must be a positive integer")
    if isinstance(first_seed, bool) or not isinstance(first_seed, (int, np.integer)) or not 0 <= first_seed <= SEED_MAX:
        raise CampaignError(f"--first-seed: got {first_seed!r}; must be an integer in [0, {SEED_MAX}]")
    if first_seed + runs - 1 > SEED_MAX:
        raise CampaignError(
            f"--runs: got {runs} from --first-seed {first_seed}; the last seed "
            f"{first_seed + runs - 1} exceeds {SEED_MAX} (Drake's 32-bit seed)"
        )
    return list(range(int(first_seed), int(first_seed) + int(runs)))


def select_estimators(scenario: cfg.Scenario, names) -> cfg.Scenario:
    """A copy of ``scenario`` with only the estimators ``names`` (in the scenario's order);
    ConfigError naming ``--estimators`` for an unknown name or a fusion without its sources.
    Dropping estimators changes no sensor's noise (the sensors' draws are keyed by seed and
    sensor name). A random estimator's (particle filters, the indoor star tracker) seed words
    come from the diagram's random sources in subsystem order, so its draws change when a random
    estimator listed before it is dropped: same statistics, another realization."""
    if names is None:
        return scenario
    out = with_estimators(scenario, names, field="--estimators", allow_empty=False)
    return cfg.load_scenario(text=cfg.dump_scenario(out))


def resolve_scenario(scenario, overrides=(), estimators=None) -> cfg.Scenario:
    """The scenario a campaign runs: a Scenario or a shipped name / YAML path, with the
    ``--set`` overrides applied and the estimators selected (ConfigError naming the field)."""
    if not isinstance(scenario, cfg.Scenario):
        from drake_att.scenarios.library import load

        scenario = load(scenario)
    if overrides:
        scenario = cfg.apply_overrides(scenario, list(overrides))
    return select_estimators(scenario, estimators)


def default_summarize(records, scenario, **kwargs) -> dict:
    """The ensemble statistics: :func:`drake_att.analysis.ensemble.summarize`."""
    from drake_att.analysis import ensemble

    return ensemble.summarize(records, scenario, **kwargs)


@interrupts.remembering
def run_campaign(
    scenario,
    runs: int,
    first_seed: int = 1,
    *,
    workers: int | None = None,
    scheduler=None,
    out: str | None = None,
    resume: bool = False,
    overrides=(),
    estimators=None,
    record: Callable | None = None,
    report: bool = True,
    progress: bool = True,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    stream=None,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> CampaignResult:
    """A Monte Carlo campaign: ``runs`` seeds from ``first_seed`` (``drake-att montecarlo``).

    Args:
        scenario: a Scenario, or a shipped scenario name / YAML path.
        runs, first_seed: the seeds ``first_seed .. first_seed + runs - 1``.
        workers, scheduler: where the runs go (:func:`map_runs`).
        out: the campaign folder (None: nothing is written, the records are returned).
            ``config.yaml`` (the resolved scenario) and ``campaign.json`` first, then each
            run as it finishes (``runs/seed_<seed>.npz``, or ``seed_<seed>.failed.txt``
            for a run that went non-finite), then ``summary.json``, ``report.html`` and its
            PNGs, and ``manifest.json`` last. Nothing is written before the cluster is
            connected, and a campaign that fails before saving a single run takes back what
            it created (a failed start leaves no campaign behind). A campaign folder of
            ours that holds no saved run starts afresh (with or without ``resume``).
        resume: continue the campaign in ``out``: seeds with a complete file there are
            read, not re-run; refused (CampaignError) if that campaign's resolved config
            differs. Without it an existing campaign in ``out`` is refused too (never
            overwritten by accident). A saved record is checked before it is reused (its
            layout against the campaign's, and the default record's documented structure,
            :func:`~drake_att.analysis.campaign_records.default_record_problem`); one that
            fails, or cannot be read, is reported in one line on ``stream`` and its run
            redone.
        overrides: ``--set``-style ``path=value`` strings applied to the scenario first.
        estimators: names of the estimators to run (default: all).
        record: ``RunLog -> dict of numpy arrays`` (default :func:`default_record`; with
            another one there are no ensemble statistics, ``summary`` is None). It returns
            the same keys, dtype kinds and ranks for every seed (keys ending in its
            ``optional_key_suffixes`` attribute may be absent).
        report: write the summary, report and manifest (with ``out``).
        progress: a progress line (runs done, wall time, ETA) on ``stream`` (stderr).
        connect_timeout_s: the deadline of the connection to ``scheduler``
            (:func:`~drake_att.analysis.dask_connection.connect_scheduler`).
        batch_size: the most seeds one simulation carries where the scenario allows batches
            (:func:`~drake_att.analysis.executor.map_runs`; the same records; 1: each run alone).

    Ctrl-C (KeyboardInterrupt) stops the campaign; every run finished so far is on disk.
    """
    record = default_record if record is None else record
    seeds = campaign_seeds(runs, first_seed)
    connect_timeout_s = check_connect_timeout(connect_timeout_s)
    batch_size = check_batch_size(batch_size)
    _check_workers(workers)
    resolved = resolve_scenario(scenario, overrides, estimators)
    yaml_text = cfg.dump_scenario(resolved)
    start = time.perf_counter()
    out = None if out is None else os.path.normpath(out)
    runs_so_far = _CampaignRuns(resolved, seeds, record, executor_name(workers, scheduler), out)
    if out is not None:
        runs_so_far.read_saved(out, yaml_text, resume, stream)
    _run_pending(runs_so_far, yaml_text, workers, scheduler, connect_timeout_s, progress, stream, batch_size)
    result = runs_so_far.result()
    interrupts.raise_if_interrupted()
    if report:
        result.summary = _campaign_summary(result, record, scenario, overrides)
    result.wall_time_s = time.perf_counter() - start
    if out is not None and report:
        _write_report_and_manifest(result, out, runs_so_far)
    return result


class _CampaignRuns:
    """The runs of one :func:`run_campaign` call as they are read from its folder ``out`` or
    arrive from the runner, each written to ``out`` as it arrives (None: kept in memory only).

    Attributes:
        records, failed: seed -> record, seed -> message of a run that went non-finite.
        reused, failed_reused: how many of them were read from ``out``.
        layout: the campaign's record layout (campaign.json's ``record_layout``; None: not known yet).
        ran: records that arrived from the runner.
        bar: the progress line a run that arrives advances (None: no progress line).
    """

    def __init__(self, resolved: cfg.Scenario, seeds: list, record: Callable, executor_text: str, out: str | None):
        self.resolved, self.seeds, self.record, self.out = resolved, seeds, record, out
        self.executor_text = executor_text  # campaign.json's and the report's
        self.optional = getattr(record, "optional_key_suffixes", ())
        self.records: dict = {}
        self.failed: dict = {}
        self.layout: dict | None = None
        self.ran = 0
        self.bar: CampaignProgress | None = None
        self.reused = self.failed_reused = 0

    def read_saved(self, out: str, yaml_text: str, resume: bool, stream) -> None:
        """The saved runs of the campaign in its folder ``out`` when it is resumed (the folder's
        checks: :func:`~drake_att.analysis.campaign_folder._inspect_folder`); a saved record that
        fails its check is reported in one line on ``stream`` and left out (its run is redone)."""
        mode, info = _inspect_folder(out, yaml_text, self.record, resume)
        if mode != "resume":
            return
        self.layout = _valid_layout((info or {}).get("record_layout"))
        if os.path.isdir(os.path.join(out, RUNS_DIR)):
            self.records, self.failed, bad = _load_existing(
                out, self.seeds, _record_check(self.record, self.resolved, self.layout)
            )
            for path, why in bad:
                print(f"drake-att: {_shown(path)}: {why}; its run is redone", file=stream or sys.stderr)
        self.reused, self.failed_reused = len(self.records), len(self.failed)

    def pending(self) -> list:
        """The seeds without a record or a failure, in seed order."""
        return [s for s in self.seeds if s not in self.records and s not in self.failed]

    def write_campaign_file(self) -> None:
        _write_campaign_file(self.out, self.resolved, self.seeds, self.record, self.executor_text, self.layout)

    def on_result(self, i, job, result) -> None:
        """The runner's callback: keep (and save) a run's record or failure."""
        seed = job[0]
        if isinstance(result, RunFailed):
            self.failed[seed] = result.message
            if self.out is not None:
                write_text_atomic(_failed_path(self.out, seed), result.message + "\n")
        else:
            if self.out is not None:
                save_record(self.out, seed, result)
                fresh = record_layout(result, self.optional)
                if fresh != self.layout:  # the first record (or a stale layout): the campaign's layout now
                    self.layout = fresh
                    self.write_campaign_file()
            self.records[seed] = result
            self.ran += 1
        if self.bar:
            self.bar.run_done()

    def result(self) -> CampaignResult:
        """The campaign's result without its summary and wall time (the counts checked)."""
        seeds = self.seeds
        ordered = [self.records[s] for s in seeds if s in self.records]
        result = CampaignResult(
            self.resolved,
            seeds,
            ordered,
            {s: self.failed[s] for s in seeds if s in self.failed},
            None,
            self.out,
            self.ran,
            self.reused,
            0.0,
            failed_reused=self.failed_reused,
        )
        if result.ran + result.reused + len(result.failed) != len(seeds):  # a bug, not a user's error
            raise RuntimeError(
                f"campaign counts do not add up: {result.ran} ran + {result.reused} reused + "
                f"{len(result.failed)} failed != {len(seeds)} seeds"
            )
        return result


def _run_pending(
    runs: _CampaignRuns,
    yaml_text: str,
    workers,
    scheduler,
    connect_timeout_s: float,
    progress: bool,
    stream,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> None:
    """Runs the pending seeds into ``runs`` (:func:`map_runs`), with the campaign folder created
    first; a failure takes back what the folder got from this call. The progress line (with
    ``progress``, on ``stream``) is closed and a cluster this call connected to shut down,
    whatever happens."""
    pending = runs.pending()
    # Connect first: an unreachable scheduler must not leave a campaign folder behind.
    executor = None
    if pending and not _is_serial(workers, scheduler) and (scheduler is None or isinstance(scheduler, str)):
        executor = _connect(min(workers or os.cpu_count() or 1, len(pending)), scheduler, connect_timeout_s)
    bar, created = None, []
    try:
        if runs.out is not None:
            created = _create_folder(runs.out, yaml_text)
            runs.write_campaign_file()
        bar = runs.bar = (
            CampaignProgress(len(runs.seeds), runs.reused + runs.failed_reused, f"{runs.resolved.name}", stream=stream)
            if progress
            else None
        )
        map_runs(
            runs.resolved,
            pending,
            runs.record,
            workers=workers,
            scheduler=executor[0] if executor else scheduler,
            on_result=runs.on_result,
            connect_timeout_s=connect_timeout_s,
            batch_size=batch_size,
        )
    except BaseException:
        if runs.out is not None:
            _remove_created(runs.out, created)
        raise
    finally:
        if bar:
            bar.close()
        if executor is not None:
            _shut_down(executor[0], executor[1], executor[2], [])


def _campaign_summary(result: CampaignResult, record: Callable, scenario, overrides) -> dict | None:
    """The ensemble statistics of the campaign's records: they read the default record; another
    record gets a report of the campaign alone (its caller reduces its own records)."""
    # The worst runs' re-run command: the campaign's resolved config.yaml says everything
    # (--set, --estimators); without a folder, the scenario and the overrides.
    out = result.out
    where = (
        {"scenario_arg": os.path.join(out, CONFIG_FILE)}
        if out is not None
        else {"scenario_arg": scenario if isinstance(scenario, str) else None, "overrides": list(overrides)}
    )
    return (
        default_summarize(result.records, result.scenario, **where)
        if result.records and record is default_record
        else None
    )


def _write_report_and_manifest(result: CampaignResult, out: str, runs: _CampaignRuns) -> None:
    """``report.html`` and its figures and ``summary.json`` in the campaign folder ``out`` (their
    names in ``result.files``), then ``manifest.json`` over every file of the campaign."""
    from drake_att.analysis import campaign_report

    seeds = result.seeds
    result.files = campaign_report.write_campaign_report(result, executor=runs.executor_text)
    run_files = [_run_path(out, s) for s in seeds if s in runs.records] + [_failed_path(out, s) for s in result.failed]
    interrupts.raise_if_interrupted()  # no manifest (the mark of a complete campaign) after a swallowed Ctrl-C
    write_campaign_manifest(
        out,
        [os.path.join(out, CONFIG_FILE), os.path.join(out, CAMPAIGN_FILE)] + result.files + run_files,
        result.scenario.name,
        seeds,
    )
