"""Monte Carlo campaigns over seeds, on Dask (a laptop's cores or a cluster) or serially.

One way to run many seeds: :func:`map_runs` ships the scenario as YAML text plus seeds to
worker processes (diagrams and contexts do not pickle); each worker builds the scenario's
diagram once (:func:`drake_att.scenarios.builder.diagram_for`; pydrake 1.51 never frees
a diagram) and reuses it for every seed it gets, turning each run into a small *record*
(a function of the :class:`~drake_att.scenarios.builder.RunLog`, computed where the run
is). Where the work runs:

* ``scheduler=None`` (default): a Dask ``LocalCluster`` of ``workers`` processes (default:
  this machine's CPU count), one thread each (pydrake systems are not thread-safe);
* ``scheduler="tcp://host:8786"``: an existing Dask cluster (``dask scheduler`` on one
  machine, ``dask worker tcp://host:8786`` on each machine, drake_att installed on all),
  connected to within ``connect_timeout_s`` (:func:`connect_scheduler`: every network wait
  has a deadline); a ``distributed.Client`` works too (a notebook's);
* ``scheduler="serial"`` or ``workers=1``: in this process, one seed after the other (the
  reference the Dask runs are tested against bit for bit).

:func:`run_campaign` is the campaign on top of it (``drake-att montecarlo``): seeds
``first_seed .. first_seed + runs - 1``; each finished run is written as it arrives to
``<out>/runs/seed_<seed>.npz`` (temporary file + ``os.replace``: a file there is always
complete), so an interrupted campaign ``resume``\\ s without redoing or losing finished
runs; then ``summary.json`` (the ensemble statistics of
:mod:`drake_att.analysis.ensemble`), ``report.html`` + PNGs
(:mod:`drake_att.analysis.campaign_report`) and ``manifest.json``.

:func:`run_comparison` (``drake-att compare``) runs one campaign per scenario with the
listed estimators and writes the comparison matrix. :func:`run_seeds` is the paper
scripts' view of the same runner (per-seed metrics and error series).

Reaching Dask (the ``--scheduler`` / ``--connect-timeout`` checks, the local cluster, the
connection with deadlines) is :mod:`drake_att.analysis.dask_connection`; what a saved run
is and how it is written, read and checked is :mod:`drake_att.analysis.campaign_records`.
Their public names are importable from here too.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import os
import sys
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drake_att.analysis.campaign_records import (  # noqa: F401  (MAX_RECORD_BYTES: re-exported)
    MAX_RECORD_BYTES,
    RUNS_DIR,
    _failed_path,
    _layout_problem,
    _run_path,
    _saved_run_files,
    _valid_layout,
    default_record_problem,
    load_record,
    record_layout,
    save_record,
    write_text_atomic,
)
from drake_att.analysis.dask_connection import (  # noqa: F401  (the public names are re-exported)
    CONNECT_STEP_MIN_S,
    DEFAULT_CONNECT_TIMEOUT_S,
    MAX_CONNECT_TIMEOUT_S,
    CampaignError,
    _connect,
    _error_text,
    _one_line,
    _shown,
    _shut_down,
    check_connect_timeout,
    check_scheduler_address,
    connect_scheduler,
    local_cluster,
)
from drake_att.progress import Progress, format_duration
from drake_att.outputs import safe_component
from drake_att.scenarios import config as cfg
from drake_att.validation import SEED_MAX, describe

SERIAL = "serial"
CONFIG_FILE = "config.yaml"
CAMPAIGN_FILE = "campaign.json"
SUMMARY_FILE = "summary.json"
MANIFEST_FILE = "manifest.json"
# Reading a campaign's small files (config.yaml, campaign.json, a failed run's message) is
# bounded too (saved records: MAX_RECORD_BYTES).
MAX_SIDE_FILE_BYTES = 2**20


@dataclass(frozen=True)
class RunFailed:
    """A run that raised :class:`~drake_att.scenarios.builder.NonFiniteRunError` (its
    truth or an estimate went non-finite): part of the campaign's result, not a crash."""

    seed: int
    message: str


# ----------------------------------------------------------------------------------------
# Records: what a worker returns for one run
# ----------------------------------------------------------------------------------------
def metrics_record(run) -> dict:
    """The smallest record: the run's metrics (:func:`compute_metrics`) as a JSON string
    under ``"metrics_json"``."""
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.analysis.report import strict_json

    return {"metrics_json": np.array(json.dumps(strict_json(compute_metrics(run))))}


def default_record(run) -> dict:
    """A campaign's record of one run: :func:`drake_att.analysis.ensemble.per_run_record`."""
    from drake_att.analysis import ensemble

    return ensemble.per_run_record(run)


default_record.optional_key_suffixes = ("__bound_sigma", "__bound_window_var")


def record_name(record: Callable) -> str:
    """``module:qualname`` of a record function (a ``functools.partial`` with its
    arguments): what a campaign folder remembers, so a resume uses the same one."""
    if isinstance(record, functools.partial):
        args = ", ".join([repr(a) for a in record.args] + [f"{k}={v!r}" for k, v in sorted(record.keywords.items())])
        return f"{record_name(record.func)}({args})"
    return f"{record.__module__}:{record.__qualname__}"


# ----------------------------------------------------------------------------------------
# The worker side
# ----------------------------------------------------------------------------------------
_WORKER_DIAGRAMS: dict = {}
_WORKER_STATS = {"diagrams_built": 0, "runs": 0}
# One simulation at a time per process: a Dask worker started with several threads
# (``dask worker --nthreads 4``) would otherwise run pydrake systems concurrently.
_WORKER_LOCK = threading.Lock()


def worker_stats() -> dict:
    """This process's pid, diagrams built and runs simulated by :func:`map_runs` (e.g.
    ``client.run(worker_stats)`` on a Dask cluster: one diagram per worker, many runs)."""
    return {"pid": os.getpid(), **_WORKER_STATS}


def _worker_diagram(yaml_text: str):
    """This process's diagram of the scenario ``yaml_text`` (built on first use)."""
    sd = _WORKER_DIAGRAMS.get(yaml_text)
    if sd is None:
        from drake_att.scenarios.builder import diagram_for
        from drake_att.scenarios.preflight import DegenerateScenarioWarning

        with warnings.catch_warnings():
            # The client prints a scenario's preflight warnings once, not once per worker.
            warnings.simplefilter("ignore", DegenerateScenarioWarning)
            sd = _WORKER_DIAGRAMS[yaml_text] = diagram_for(cfg.load_scenario(text=yaml_text))
        _WORKER_STATS["diagrams_built"] += 1
    return sd


def _run_jobs(yaml_text: str, jobs, record: Callable) -> list:
    """Run ``jobs`` (``(seed, estimators or None)`` pairs) on this process's diagram of
    ``yaml_text``; returns ``[(job, record(run) or RunFailed), ...]``. The Dask task and the
    serial loop both call this, so both compute the very same thing."""
    with _WORKER_LOCK:
        return _run_jobs_locked(yaml_text, jobs, record)


def _run_jobs_locked(yaml_text: str, jobs, record: Callable) -> list:
    from drake_att.scenarios.builder import NonFiniteRunError

    sd = _worker_diagram(yaml_text)
    out = []
    for seed, estimators in jobs:
        _WORKER_STATS["runs"] += 1
        try:
            run = sd.simulate(int(seed), estimators=None if estimators is None else list(estimators))
        except NonFiniteRunError as e:
            out.append(((seed, estimators), RunFailed(int(seed), str(e))))
            continue
        out.append(((seed, estimators), record(run)))
    return out


# ----------------------------------------------------------------------------------------
# The one runner
# ----------------------------------------------------------------------------------------
def map_runs(scenario, jobs, record: Callable = metrics_record, *, workers: int | None = None, scheduler=None,
             chunk_size: int = 1, on_result: Callable | None = None, raise_failures: bool = False,
             connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S) -> list:
    """Run ``scenario`` for every job and return the records in job order.

    Args:
        scenario: a validated :class:`~drake_att.scenarios.config.Scenario`.
        jobs: seeds, or ``(seed, estimators)`` pairs (``estimators``: the names to run, as
            :meth:`ScenarioDiagram.simulate`'s; None = all).
        record: ``RunLog -> object``, a module-level function (or a ``functools.partial`` of
            one): workers import it by name.
        workers: processes of the local cluster (default: the CPU count, at most one per
            task); 1 runs serially in this process.
        scheduler: None (local cluster), ``"serial"``, a scheduler address or a
            ``distributed.Client``.
        chunk_size: jobs per task (1: every run is streamed back as it finishes).
        on_result: called as ``on_result(index, job, result)`` in this process as each run
            arrives (in completion order).

    A run whose truth or estimates go non-finite gives a :class:`RunFailed` (with
    ``raise_failures``: raises its ``NonFiniteRunError``); any other exception stops the map
    (the results already passed to ``on_result`` stay delivered). A scheduler address is
    connected to within ``connect_timeout_s`` (:func:`connect_scheduler`).
    """
    connect_timeout_s = check_connect_timeout(connect_timeout_s)
    jobs = [(int(j), None) if isinstance(j, (int, np.integer)) else (int(j[0]), None if j[1] is None else tuple(j[1]))
            for j in jobs]
    yaml_text = cfg.dump_scenario(scenario)
    index = {}
    for i, job in enumerate(jobs):
        index.setdefault(job, []).append(i)
    results = [None] * len(jobs)

    def deliver(pairs):
        for job, result in pairs:
            if raise_failures and isinstance(result, RunFailed):
                from drake_att.scenarios.builder import NonFiniteRunError

                raise NonFiniteRunError(result.message)
            for i in index[job]:
                results[i] = result
                if on_result is not None:
                    on_result(i, job, result)

    unique = list(index)
    if not unique:
        return results
    if workers is not None and workers < 1:
        raise CampaignError(f"--workers: got {workers}; must be a positive integer")
    serial = scheduler == SERIAL or (scheduler is None and workers == 1)
    if serial:
        for k in range(0, len(unique), max(1, chunk_size)):
            deliver(_run_jobs(yaml_text, unique[k:k + chunk_size], record))
        return results
    chunks = [unique[k:k + chunk_size] for k in range(0, len(unique), max(1, chunk_size))]
    n_workers = min(workers or os.cpu_count() or 1, len(chunks))
    from distributed import as_completed

    client, cluster, owned = _connect(n_workers, scheduler, connect_timeout_s)
    futures = []
    try:
        futures = [client.submit(_run_jobs, yaml_text, chunk, record, pure=False) for chunk in chunks]
        for future in as_completed(futures):
            deliver(future.result())
            future.release()
    finally:
        _shut_down(client, cluster, owned, futures)
    return results

# ----------------------------------------------------------------------------------------
# The paper scripts' view: per-seed metrics and error series
# ----------------------------------------------------------------------------------------
def metrics_and_series_record(run, keep_series_for=()) -> dict:
    """``{"metrics": compute_metrics(run)}`` plus, for a seed in ``keep_series_for``,
    ``"series"``: estimator -> ``t``, ``dtheta`` (rad), ``second_err`` (SI or None) and
    ``sigma`` (the covariance's 6 standard deviations)."""
    from drake_att.analysis.metrics import compute_metrics, estimator_errors

    out = {"metrics": compute_metrics(run)}
    if run.seed in keep_series_for:
        series = {}
        for name in run.metadata["estimators"]:
            err = estimator_errors(run, name)
            series[name] = {"t": err["t"], "dtheta": err["dtheta"], "second_err": err["second_err"],
                            "sigma": np.sqrt(np.maximum(np.einsum("nii->ni", err["P"]), 0.0))}
        out["series"] = series
    return out


def run_seeds(scenario, seeds, workers: int | None = None, keep_series_for=(), scheduler=None) -> list[dict]:
    """Per-seed ``{"metrics": ..., "series": ...}`` (:func:`metrics_and_series_record`) of
    ``scenario`` over ``seeds``, through :func:`map_runs` (``workers=1``: in this process).
    A run that goes non-finite raises its ``NonFiniteRunError``."""
    record = functools.partial(metrics_and_series_record, keep_series_for=frozenset(int(s) for s in keep_series_for))
    return map_runs(scenario, [int(s) for s in seeds], record, workers=workers, scheduler=scheduler,
                    raise_failures=True)


def metric_mean_std(results: list[dict], key: str, estimator: str) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (ddof 1) over :func:`run_seeds` results of a per-axis
    metric (None entries dropped)."""
    vals = [r["metrics"]["estimators"][estimator][key] for r in results]
    vals = np.array([v for v in vals if v is not None], dtype=float)
    return vals.mean(axis=0), vals.std(axis=0, ddof=1) if len(vals) > 1 else np.zeros_like(vals[0])


# ----------------------------------------------------------------------------------------
# Campaigns: streamed to disk, resumable, reported
# ----------------------------------------------------------------------------------------
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
        return (f"{prefix}{total_done} / {self.total_runs} runs{reused} ({frac:4.0%})  "
                f"{format_duration(elapsed)} wall  {eta}")

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
        raise CampaignError(f"--runs: got {runs} from --first-seed {first_seed}; the last seed "
                            f"{first_seed + runs - 1} exceeds {SEED_MAX} (Drake's 32-bit seed)")
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
    from drake_att.scenarios.builder import with_estimators

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


# ----------------------------------------------------------------------------------------
# Reading a campaign folder back (--resume): its records' checks, its small files, its runs
# ----------------------------------------------------------------------------------------
def _record_check(record_fn: Callable, scenario: cfg.Scenario, layout: dict | None):
    """``check(record, seed) -> why not, or None`` for the records of a campaign."""
    optional = getattr(record_fn, "optional_key_suffixes", ())

    def check(record, seed):
        if record_fn is default_record:
            why = default_record_problem(record, scenario, seed)
            if why:
                return why
        return None if layout is None else _layout_problem(record, layout, optional)

    return check


def _small_file_text(path: str, limit: int = MAX_SIDE_FILE_BYTES) -> str:
    """The UTF-8 text of one of the campaign's own small files (config.yaml, campaign.json,
    a failed run's message): :func:`drake_att.scenarios.config.read_text_bounded`."""
    return cfg.read_text_bounded(path, limit)


def _read_small_file(path: str, what: str, limit: int = MAX_SIDE_FILE_BYTES) -> str:
    """:func:`_small_file_text`, or CampaignError ``<path>: <why>; <what>``."""
    try:
        return _small_file_text(path, limit)
    except ValueError as e:
        raise CampaignError(f"{_shown(path)}: {e}; {what}") from None


def _read_campaign_file(path: str) -> dict:
    """campaign.json as a dict; CampaignError naming the file when it is not the JSON
    object drake-att writes."""
    what = "it should be the JSON object drake-att writes there; name another --out"
    text = _read_small_file(path, what)
    try:
        info = json.loads(text)
    except ValueError as e:
        raise CampaignError(f"{_shown(path)}: not JSON ({_one_line(e, 120)}); {what}") from None
    if not isinstance(info, dict):
        raise CampaignError(f"{_shown(path)}: got a JSON {type(info).__name__}; {what}")
    return info


def _load_existing(out: str, seeds, check: Callable | None = None) -> tuple[dict, dict, list]:
    """Complete runs of ``seeds`` already in ``out/runs``: (records, failed, bad) with
    ``bad`` a list of ``(path, why)``: files that cannot be read, or whose record ``check``
    refuses (``check(record, seed) -> why or None``); their runs are redone."""
    records, failed, bad = {}, {}, []
    runs = os.path.join(out, RUNS_DIR)
    try:
        names = os.listdir(runs)
    except OSError as e:
        raise CampaignError(f"--resume {_shown(out)}: its {RUNS_DIR} folder cannot be read "
                            f"({_one_line(e.strerror or e, 80)})") from None
    for name in names:
        if name.startswith(".") and ".tmp-" in name:  # a write that was interrupted
            try:
                os.remove(os.path.join(runs, name))
            except OSError:
                pass
    for seed in seeds:
        path, fpath = _run_path(out, seed), _failed_path(out, seed)
        for p in (path, fpath):
            if os.path.isdir(p) and not os.path.islink(p):  # a run's result could not be written there
                raise CampaignError(f"--resume {_shown(out)}: {_shown(p)} is a folder, not a run file; move it "
                                    "away, or name another --out")
        if os.path.lexists(path):
            if not os.path.isfile(path):  # a link to nothing, a FIFO (reading it would block), a device
                bad.append((path, "unreadable (not a regular file)"))
                continue
            try:
                record = load_record(path)
            except Exception as e:  # noqa: BLE001 - any failure to read a file is a damaged file: its run is redone
                bad.append((path, f"unreadable ({_error_text(e)})"))
                continue
            why = None if check is None else check(record, seed)
            if why is None:
                records[seed] = record
            else:
                bad.append((path, f"not a record of this campaign ({why})"))
            continue
        if os.path.lexists(fpath):
            try:
                failed[seed] = _one_line(_small_file_text(fpath), 2000)
            except ValueError as e:
                bad.append((fpath, f"unreadable ({e})"))
    return records, failed, bad


def _campaign_identity(yaml_text: str, record: Callable) -> dict:
    return {"config_sha256": hashlib.sha256(yaml_text.encode()).hexdigest(), "record": record_name(record)}


def _first_difference(old: str, new: str) -> str:
    import difflib

    a, b = old.splitlines(), new.splitlines()
    for tag, i1, i2, j1, j2 in difflib.SequenceMatcher(None, a, b).get_opcodes():
        if tag != "equal":
            was = _one_line(a[i1].strip(), 100) if i1 < i2 else "(nothing)"
            now = _one_line(b[j1].strip(), 100) if j1 < j2 else "(nothing)"
            return f"line {i1 + 1}: the campaign has '{was}', this request '{now}'"
    return "(same text)"


CONFIG_HEADER = "# Resolved configuration of this Monte Carlo campaign (every run; seed per run).\n"


def _inspect_folder(out: str, yaml_text: str, record: Callable, resume: bool) -> tuple[str, dict | None]:
    """What ``out`` is for this campaign, read only (nothing is written before the cluster
    is connected): ``("new", None)`` (absent or empty, or a campaign of ours that saved no
    run: nothing to resume, it starts afresh), or ``("resume", campaign.json or None)``.
    CampaignError (one line, naming the folder or file) for anything else."""
    shown = _shown(out)
    if os.path.lexists(out) and not os.path.isdir(out):
        raise CampaignError(f"--out {shown}: is an existing file, not a folder; name a folder for the campaign")
    if not os.path.isdir(out):
        return "new", None
    config_path, cpath, runs = (os.path.join(out, n) for n in (CONFIG_FILE, CAMPAIGN_FILE, RUNS_DIR))
    has_config, has_campaign = os.path.lexists(config_path), os.path.lexists(cpath)
    try:
        entries = os.listdir(out)
    except OSError as e:
        raise CampaignError(f"--out {shown}: cannot be read ({_one_line(e.strerror or e, 80)}); name another "
                            "folder") from None
    if not has_config and not has_campaign:
        if [n for n in entries if not n.startswith(".")]:
            raise CampaignError(f"--out {shown}: is a folder with other files in it (no {CONFIG_FILE} of a campaign); "
                                "name a new or empty folder")
        return "new", None
    info = _read_campaign_file(cpath) if has_campaign else None
    if os.path.lexists(runs) and not os.path.isdir(runs):
        raise CampaignError(f"--out {shown}: its {RUNS_DIR} is not a folder; name another --out")
    saved = _saved_run_files(runs)
    if not saved and info is not None and "config_sha256" in info and "record" in info:
        # A campaign of ours that saved no run (its start failed, or it was stopped before
        # the first run finished): nothing to keep or resume; it starts afresh, with or
        # without --resume, whatever configuration it had.
        try:
            ours = not has_config or _small_file_text(config_path).startswith(CONFIG_HEADER.split("(")[0])
        except ValueError:
            ours = False  # refused below, naming the file (--resume) or as a campaign already there
        if ours:
            return "new", info
    if not resume:
        n_failed = len([n for n in saved if n.endswith(".failed.txt")])
        runs_text = f"{len(saved) - n_failed} runs" + (f", {n_failed} failed" if n_failed else "")
        raise CampaignError(f"--out {shown}: holds a campaign already ({runs_text}); add --resume to continue it, or "
                            "name another folder")
    if not has_config:
        raise CampaignError(f"--resume {shown}: {CONFIG_FILE} is missing, so the configuration of its runs is unknown; "
                            "name another --out")
    old = _read_small_file(config_path, "the campaign's configuration (YAML written by drake-att); name another --out")
    old_yaml = old.split("\n", 1)[1] if old.startswith("#") else old
    if old_yaml != yaml_text:
        try:
            cfg._preparse(old_yaml, _shown(config_path))  # parse only: imports nothing the file names
        except Exception as e:  # noqa: BLE001 - any failure to parse it says the file is not a scenario
            raise CampaignError(f"--resume {shown}: {_shown(config_path)} is not a scenario ({_one_line(e, 160)}); "
                                "name another --out") from None
        raise CampaignError(f"--resume {shown}: the campaign there ran another configuration "
                            f"({_first_difference(old_yaml, yaml_text)}, in {_shown(config_path)}); give the same "
                            "scenario, --set and --estimators, or another --out")
    if info is not None and info.get("record") != record_name(record):
        raise CampaignError(f"--resume {shown}: the campaign there saved records of "
                            f"{_one_line(repr(info.get('record')), 120)}, this request {record_name(record)}")
    return "resume", info


def _create_folder(out: str, yaml_text: str) -> list[str]:
    """Create ``out/runs`` and write ``config.yaml``; returns what this created (files, then
    folders deepest first): what :func:`_remove_created` may take back."""
    runs = os.path.join(out, RUNS_DIR)
    missing, path = [], runs
    while not os.path.isdir(path):
        missing.append(path)
        parent = os.path.dirname(path)
        if not parent or parent == path:
            break
        path = parent
    config_path, cpath = os.path.join(out, CONFIG_FILE), os.path.join(out, CAMPAIGN_FILE)
    new_files = [p for p in (config_path, cpath) if not os.path.lexists(p)]
    os.makedirs(runs, exist_ok=True)
    write_text_atomic(config_path, CONFIG_HEADER + yaml_text)
    return new_files + missing


def _remove_created(out: str, created: list[str]) -> None:
    """Take back what :func:`_create_folder` created, when the campaign saved no run: a
    failed start leaves nothing behind. Files first, then folders only when empty; nothing
    that existed before is touched."""
    if _saved_run_files(os.path.join(out, RUNS_DIR)):
        return
    for path in created:
        try:
            if os.path.isdir(path) and not os.path.islink(path):
                os.rmdir(path)  # only an empty folder
            else:
                os.remove(path)
        except OSError:
            pass


def _write_campaign_file(out, scenario, seeds, record, workers, scheduler, layout=None) -> str:
    import drake_att

    info = {"scenario": scenario.name, "first_seed": seeds[0], "runs": len(seeds), "seeds": [seeds[0], seeds[-1]],
            **_campaign_identity(cfg.dump_scenario(scenario), record), "drake_att": drake_att.__version__,
            "executor": _executor_name(workers, scheduler)}
    if layout is not None:
        info["record_layout"] = layout
    return write_text_atomic(os.path.join(out, CAMPAIGN_FILE), json.dumps(info, indent=1) + "\n")


def _executor_name(workers, scheduler) -> str:
    if scheduler == SERIAL or (scheduler is None and workers == 1):
        return "serial (this process)"
    if scheduler is None:
        return f"Dask LocalCluster, {workers or os.cpu_count()} worker processes"
    if not isinstance(scheduler, str):  # a distributed.Client
        return f"Dask cluster at {getattr(getattr(scheduler, 'scheduler', None), 'address', '?')}"
    return f"Dask cluster at {scheduler}"


def write_campaign_manifest(out: str, files, scenario_name: str, seeds) -> str:
    """``manifest.json`` (as :func:`drake_att.analysis.report.write_manifest`, with paths
    relative to ``out`` so the runs in ``runs/`` are listed too), written last."""
    from drake_att.analysis.report import manifest_entries

    text = json.dumps({"scenario": scenario_name, "seeds": [seeds[0], seeds[-1]], "runs": len(seeds),
                       "files": manifest_entries(out, files)}, indent=1)
    return write_text_atomic(os.path.join(out, MANIFEST_FILE), text)


def check_campaign_manifest(out: str) -> list[str]:
    """Problems of a campaign folder against its manifest (empty: complete, unmodified)."""
    from drake_att.analysis.report import manifest_problems

    path = os.path.join(out, MANIFEST_FILE)
    if not os.path.isfile(path):
        return [f"{out}: no {MANIFEST_FILE} (the campaign did not finish)"]
    try:
        manifest = json.loads(_read_small_file(path, "it should be the manifest drake-att writes", 2**24))
    except (CampaignError, ValueError) as e:
        return [f"{_shown(path)}: unreadable ({_one_line(e, 200)})"]
    if not isinstance(manifest, dict) or not isinstance(manifest.get("files"), list):
        return [f"{_shown(path)}: not a manifest of drake-att (no list of files)"]
    return manifest_problems(out, manifest["files"])


def default_summarize(records, scenario, **kwargs) -> dict:
    """The ensemble statistics: :func:`drake_att.analysis.ensemble.summarize`."""
    from drake_att.analysis import ensemble

    return ensemble.summarize(records, scenario, **kwargs)


def _is_serial(workers, scheduler) -> bool:
    return (isinstance(scheduler, str) and scheduler == SERIAL) or (scheduler is None and workers == 1)


def _check_workers(workers) -> None:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or workers < 1):
        raise CampaignError(f"--workers: got {describe(workers)}; must be a positive integer")


def run_campaign(scenario, runs: int, first_seed: int = 1, *, workers: int | None = None, scheduler=None,
                 out: str | None = None, resume: bool = False, overrides=(), estimators=None,
                 record: Callable | None = None, report: bool = True, progress: bool = True,
                 connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S, stream=None) -> CampaignResult:
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
            :func:`default_record_problem`); one that fails, or cannot be read, is reported
            in one line on ``stream`` and its run redone.
        overrides: ``--set``-style ``path=value`` strings applied to the scenario first.
        estimators: names of the estimators to run (default: all).
        record: ``RunLog -> dict of numpy arrays`` (default :func:`default_record`; with
            another one there are no ensemble statistics, ``summary`` is None). It returns
            the same keys, dtype kinds and ranks for every seed (keys ending in its
            ``optional_key_suffixes`` attribute may be absent).
        report: write the summary, report and manifest (with ``out``).
        progress: a progress line (runs done, wall time, ETA) on ``stream`` (stderr).
        connect_timeout_s: the deadline of the connection to ``scheduler``
            (:func:`connect_scheduler`).

    Ctrl-C (KeyboardInterrupt) stops the campaign; every run finished so far is on disk.
    """
    record = default_record if record is None else record
    seeds = campaign_seeds(runs, first_seed)
    connect_timeout_s = check_connect_timeout(connect_timeout_s)
    _check_workers(workers)
    resolved = resolve_scenario(scenario, overrides, estimators)
    yaml_text = cfg.dump_scenario(resolved)
    start = time.perf_counter()
    records, failed, layout, mode, ran = {}, {}, None, "new", 0
    optional = getattr(record, "optional_key_suffixes", ())
    if out is not None:
        out = os.path.normpath(out)
        mode, info = _inspect_folder(out, yaml_text, record, resume)
        if mode == "resume":
            layout = _valid_layout((info or {}).get("record_layout"))
            if os.path.isdir(os.path.join(out, RUNS_DIR)):
                records, failed, bad = _load_existing(out, seeds, _record_check(record, resolved, layout))
                for path, why in bad:
                    print(f"drake-att: {_shown(path)}: {why}; its run is redone", file=stream or sys.stderr)
    reused, failed_reused = len(records), len(failed)
    pending = [s for s in seeds if s not in records and s not in failed]
    # Connect first: an unreachable scheduler must not leave a campaign folder behind.
    executor = None
    if pending and not _is_serial(workers, scheduler) and (scheduler is None or isinstance(scheduler, str)):
        executor = _connect(min(workers or os.cpu_count() or 1, len(pending)), scheduler, connect_timeout_s)
    bar, created = None, []
    try:
        if out is not None:
            created = _create_folder(out, yaml_text)
            _write_campaign_file(out, resolved, seeds, record, workers, scheduler, layout)

        def on_result(i, job, result):
            nonlocal ran, layout
            seed = job[0]
            if isinstance(result, RunFailed):
                failed[seed] = result.message
                if out is not None:
                    write_text_atomic(_failed_path(out, seed), result.message + "\n")
            else:
                if out is not None:
                    save_record(out, seed, result)
                    fresh = record_layout(result, optional)
                    if fresh != layout:  # the first record (or a stale layout): the campaign's layout now
                        layout = fresh
                        _write_campaign_file(out, resolved, seeds, record, workers, scheduler, layout)
                records[seed] = result
                ran += 1
            if bar:
                bar.run_done()

        bar = CampaignProgress(len(seeds), reused + failed_reused, f"{resolved.name}", stream=stream) \
            if progress else None
        map_runs(resolved, pending, record, workers=workers, scheduler=executor[0] if executor else scheduler,
                 on_result=on_result, connect_timeout_s=connect_timeout_s)
    except BaseException:
        if out is not None:
            _remove_created(out, created)
        raise
    finally:
        if bar:
            bar.close()
        if executor is not None:
            _shut_down(executor[0], executor[1], executor[2], [])
    ordered = [records[s] for s in seeds if s in records]
    result = CampaignResult(resolved, seeds, ordered, {s: failed[s] for s in seeds if s in failed}, None, out, ran,
                            reused, 0.0, failed_reused=failed_reused)
    if result.ran + result.reused + len(result.failed) != len(seeds):  # a bug, not a user's error
        raise RuntimeError(f"campaign counts do not add up: {result.ran} ran + {result.reused} reused + "
                           f"{len(result.failed)} failed != {len(seeds)} seeds")
    if report:
        # The ensemble statistics read the default record; another record gets a report of
        # the campaign alone (its caller reduces its own records).
        # The worst runs' re-run command: the campaign's resolved config.yaml says everything
        # (--set, --estimators); without a folder, the scenario and the overrides.
        where = ({"scenario_arg": os.path.join(out, CONFIG_FILE)} if out is not None else
                 {"scenario_arg": scenario if isinstance(scenario, str) else None, "overrides": list(overrides)})
        result.summary = (default_summarize(ordered, resolved, **where)
                          if ordered and record is default_record else None)
    result.wall_time_s = time.perf_counter() - start
    if out is not None and report:
        from drake_att.analysis import campaign_report

        result.files = campaign_report.write_campaign_report(result, executor=_executor_name(workers, scheduler))
        run_files = [_run_path(out, s) for s in seeds if s in records] + [_failed_path(out, s) for s in result.failed]
        write_campaign_manifest(out, [os.path.join(out, CONFIG_FILE), os.path.join(out, CAMPAIGN_FILE)]
                                + result.files + run_files, resolved.name, seeds)
    return result


# ----------------------------------------------------------------------------------------
# The comparison matrix: every listed estimator on every listed scenario
# ----------------------------------------------------------------------------------------
@dataclass
class ComparisonPlan:
    """What :func:`run_comparison` runs.

    Attributes:
        scenarios: the resolved scenarios (overrides applied, estimators selected and
            transplanted), one campaign each.
        estimators: the matrix's columns (estimator names), in the order listed.
        cells: ``(scenario name, estimator)`` -> None (runs) or why it does not.
    """

    scenarios: list
    estimators: list
    cells: dict

    @property
    def skipped(self) -> list[str]:
        return [f"{s} x {e}: {why}" for (s, e), why in self.cells.items() if why is not None]


def _with_estimators(scenario: cfg.Scenario, estimator_configs, plugins=()) -> cfg.Scenario:
    out = copy.deepcopy(scenario)
    out.estimators = copy.deepcopy(list(estimator_configs))
    out.plugins = list(dict.fromkeys(list(scenario.plugins) + list(plugins)))
    return cfg.load_scenario(text=cfg.dump_scenario(out))


def comparison_plan(scenarios, estimators=None, overrides=()) -> ComparisonPlan:
    """Resolve ``drake-att compare``'s scenarios and ``--estimators`` entries.

    An entry ``NAME`` runs wherever a scenario defines an estimator of that name; an entry
    ``SOURCE:NAME`` takes estimator NAME's config from scenario SOURCE (a shipped name or a
    YAML path) and adds it to every listed scenario that lacks it (its sensors must exist
    there: the cell says why not). A fusion brings its sources along. ``None``: every
    scenario runs its own estimators. ConfigError names the option for bad input."""
    from drake_att.scenarios.library import load

    loaded = []
    for name in scenarios:
        s = load(name)
        if overrides:
            s = cfg.apply_overrides(s, list(overrides))
        if s.name in [x.name for x in loaded]:
            raise CampaignError(f"SCENARIO: {name!r} is listed twice (scenario {s.name!r})")
        loaded.append(s)
    if not loaded:
        raise CampaignError("SCENARIO: name at least one scenario")
    if estimators is None:
        columns = list(dict.fromkeys(e.name for s in loaded for e in s.estimators))
        entries = [(None, n) for n in columns]
    else:
        if not estimators:
            raise CampaignError("--estimators: got an empty list; name estimators (NAME or SCENARIO:NAME)")
        entries = []
        for item in estimators:
            source, _, name = item.rpartition(":") if ":" in item else (None, "", item)
            if not name:
                raise CampaignError(f"--estimators: got {item!r}; expected NAME or SCENARIO:NAME")
            entries.append((source, name))
        columns = list(dict.fromkeys(n for _, n in entries))
        if len(columns) != len(entries):
            raise CampaignError(f"--estimators: got {estimators!r}; each estimator name may appear once")
    transplants = {}
    for source, name in entries:
        if source is None:
            continue
        src = load(source)
        configs = {e.name: e for e in src.estimators}
        if name not in configs:
            raise CampaignError(f"--estimators {source}:{name}: scenario {src.name!r} has no estimator {name!r}; "
                                f"it has {list(configs)}")
        bring = [configs[name]]
        i = 0
        while i < len(bring):  # a fusion brings its sources
            bring += [configs[s] for s in getattr(bring[i], "sources", []) if configs[s] not in bring]
            i += 1
        transplants[name] = (bring[::-1], src.plugins)
    cells, resolved = {}, []
    for s in loaded:
        own = {e.name: e for e in s.estimators}
        keep = set()
        for _, name in entries:
            if name in own:
                stack = [name]
                while stack:
                    n = stack.pop()
                    keep.add(n)
                    stack += list(getattr(own[n], "sources", []))
                cells[(s.name, name)] = None
            elif name not in transplants:
                cells[(s.name, name)] = "not an estimator of this scenario (SOURCE:NAME adds one from another scenario)"
        configs = [e for e in s.estimators if e.name in keep]
        plugins = list(s.plugins)
        for name, (bring, src_plugins) in transplants.items():
            if name in own:
                continue
            extra = [b for b in bring if b.name not in {c.name for c in configs}]
            try:
                _with_estimators(s, configs + extra, plugins + list(src_plugins))
            except (cfg.ConfigError, ValueError) as e:
                cells[(s.name, name)] = f"cannot run here: {' '.join(str(e).split())}"
                continue
            configs += extra
            plugins += list(src_plugins)
            cells[(s.name, name)] = None
        if configs:
            resolved.append(_with_estimators(s, configs, plugins))
    if not any(why is None for why in cells.values()):
        raise CampaignError("--estimators: no listed estimator runs on any listed scenario: "
                            + "; ".join(f"{s} x {e}: {why}" for (s, e), why in cells.items()))
    return ComparisonPlan(resolved, columns, cells)


def timing_record(run) -> dict:
    """Wall time of a run and the steps each of its estimators took (the timing runs of
    :func:`run_comparison`)."""
    steps = {}
    for name, spec in run.metadata["estimators"].items():
        status = run.values(spec["signals"]["status"])
        steps[name] = len(np.unique(status[np.isfinite(status[:, 0]), 0]))
    return {"wall_time_s": float(run.wall_time_s), "steps": steps}


def _selection_with_sources(scenario: cfg.Scenario, name: str) -> tuple:
    own = {e.name: e for e in scenario.estimators}
    keep, stack = set(), [name]
    while stack:
        n = stack.pop()
        keep.add(n)
        stack += list(getattr(own[n], "sources", []))
    return tuple(e.name for e in scenario.estimators if e.name in keep)


@dataclass
class ComparisonResult:
    """What :func:`run_comparison` returns: the plan, each scenario's
    :class:`CampaignResult`, and per (scenario, estimator) the timing
    (``{"ms_per_step", "selection", "steps", "wall_s", "baseline_wall_s"}``)."""

    plan: ComparisonPlan
    campaigns: dict
    timing: dict
    out: str | None = None
    files: list = field(default_factory=list)


def run_comparison(plan: ComparisonPlan, runs: int, first_seed: int = 1, *, workers: int | None = None,
                   scheduler=None, out: str | None = None, resume: bool = False, progress: bool = True,
                   connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S, record: Callable | None = None,
                   timing_repeats: int = 3, stream=None) -> ComparisonResult:
    """Run :func:`comparison_plan`'s scenarios (``drake-att compare``): one campaign each
    (``<out>/<scenario>/``, resumable), then per scenario one timing run per estimator
    (that estimator and its sources alone, minus the sensors-only run; the fastest of
    ``timing_repeats`` runs, seeds ``first_seed, first_seed + 1, ...``) and the matrix
    (``comparison.{json,md,png,html}``). One Dask cluster serves all: a local one, or the
    scheduler's, connected to before anything is written (:func:`connect_scheduler`); a
    comparison that fails before any campaign saved a run leaves no folder behind."""
    campaign_seeds(runs, first_seed)
    connect_timeout_s = check_connect_timeout(connect_timeout_s)
    _check_workers(workers)
    owned = None
    if not _is_serial(workers, scheduler) and (scheduler is None or isinstance(scheduler, str)):
        owned = _connect(workers or os.cpu_count() or 1, scheduler, connect_timeout_s)
        scheduler = owned[0]
    campaigns, timing, created = {}, {}, []
    try:
        if out is not None:
            path = os.path.normpath(out)
            while not os.path.isdir(path):  # what this call creates (taken back if nothing is saved)
                created.append(path)
                if os.path.dirname(path) in ("", path):
                    break
                path = os.path.dirname(path)
            os.makedirs(out, exist_ok=True)
        for scenario in plan.scenarios:
            sub = None if out is None else os.path.join(out, safe_component(scenario.name))
            campaigns[scenario.name] = run_campaign(
                scenario, runs, first_seed, workers=workers, scheduler=scheduler, out=sub, resume=resume,
                record=record, progress=progress, connect_timeout_s=connect_timeout_s, stream=stream)
            names = [e for e in plan.estimators if plan.cells.get((scenario.name, e), "") is None]
            selections = [()] + [_selection_with_sources(scenario, e) for e in names]
            seeds = [min(first_seed + k, SEED_MAX) for k in range(timing_repeats)]
            jobs = [(seed, sel) for sel in selections for seed in seeds]
            walls = map_runs(scenario, jobs, timing_record, workers=workers, scheduler=scheduler,
                             connect_timeout_s=connect_timeout_s)
            fastest = [min(walls[k * len(seeds):(k + 1) * len(seeds)], key=lambda w: w["wall_time_s"])
                       for k in range(len(selections))]
            base = fastest[0]["wall_time_s"]
            for e, sel, w in zip(names, selections[1:], fastest[1:]):
                steps = w["steps"][e]
                timing[(scenario.name, e)] = {"selection": list(sel), "steps": steps, "wall_s": w["wall_time_s"],
                                              "baseline_wall_s": base, "repeats": len(seeds),
                                              "ms_per_step": 1e3 * (w["wall_time_s"] - base) / max(steps, 1)}
    except BaseException:
        for path in created:  # empty folders only: a campaign that saved runs keeps them
            try:
                os.rmdir(path)
            except OSError:
                break
        raise
    finally:
        if owned is not None:
            _shut_down(owned[0], owned[1], owned[2], [])
    result = ComparisonResult(plan, campaigns, timing, out)
    if out is not None:
        from drake_att.analysis import campaign_report

        result.files = campaign_report.write_comparison(result)
    return result
