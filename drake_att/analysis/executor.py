"""Where runs execute: :func:`map_runs`, the one runner over seeds, and the worker side.

:func:`map_runs` ships the scenario as YAML text plus seeds to worker processes (diagrams
and contexts do not pickle); each worker builds the scenario's diagram once
(:func:`drake_att.scenarios.builder.diagram_for`; pydrake 1.51 never frees a diagram) and
reuses it for every seed it gets, returning a *record* of each run
(:mod:`drake_att.analysis.run_records`). Where the work runs:

* ``scheduler=None`` (default): a Dask ``LocalCluster`` of ``workers`` processes (default:
  this machine's CPU count), one thread each (pydrake systems are not thread-safe);
* ``scheduler="tcp://host:8786"``: an existing Dask cluster, connected to within
  ``connect_timeout_s`` (:mod:`drake_att.analysis.dask_connection`); a
  ``distributed.Client`` works too (a notebook's);
* ``scheduler="serial"`` or ``workers=1``: in this process, one seed after the other (the
  reference the Dask runs are tested against bit for bit).

Where a scenario allows it (:func:`~drake_att.scenarios.builder.batch_problem`: a truth shared
by every seed, and sensors and estimators that carry several realizations), a worker runs up to
``batch_size`` seeds in one simulation of a batch diagram
(:meth:`~drake_att.scenarios.builder.ScenarioDiagram.simulate_batch`): the same runs, bit for
bit, for a fraction of the CPU (the truth, the per-step framework work and the Python calls are
shared by the batch).

:func:`run_seeds` is the paper scripts' view of the same runner (per-seed metrics and error
series).
"""

from __future__ import annotations

import functools
import os
import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drake_att.analysis.dask_connection import (
    DEFAULT_CONNECT_TIMEOUT_S,
    CampaignError,
    _connect,
    _shut_down,
    check_connect_timeout,
)
from drake_att.analysis.run_records import metrics_and_series_record, metrics_record
from drake_att.interrupts import raise_if_interrupted
from drake_att.scenarios import config as cfg
from drake_att.validation import describe

SERIAL = "serial"


@dataclass(frozen=True)
class RunFailed:
    """A run that raised :class:`~drake_att.scenarios.builder.NonFiniteRunError` (its
    truth or an estimate went non-finite): part of the campaign's result, not a crash."""

    seed: int
    message: str


_WORKER_DIAGRAMS: dict = {}
_WORKER_BATCH_DIAGRAMS: dict = {}
_WORKER_STATS = {"diagrams_built": 0, "batch_diagrams_built": 0, "runs": 0}
#: Seeds one simulation carries when the scenario allows batches (map_runs' ``batch_size``).
DEFAULT_BATCH_SIZE = 10
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


def _worker_batch_diagram(yaml_text: str, size: int):
    """This process's batch diagram of ``size`` realizations of the scenario ``yaml_text``
    (built on first use), or None where its estimators cannot carry several (the runs then
    take the single diagram: the same results)."""
    key = (yaml_text, size)
    if key not in _WORKER_BATCH_DIAGRAMS:
        from drake_att.scenarios.builder import ScenarioDiagram
        from drake_att.scenarios.preflight import DegenerateScenarioWarning

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DegenerateScenarioWarning)
            try:
                diagram = ScenarioDiagram(cfg.load_scenario(text=yaml_text), realizations=size)
            except ValueError:  # an estimator off the compiled step (EstimatorSystem says why)
                diagram = None
        _WORKER_BATCH_DIAGRAMS[key] = diagram
        _WORKER_STATS["batch_diagrams_built"] += diagram is not None
    return _WORKER_BATCH_DIAGRAMS[key]


def _run_jobs(yaml_text: str, jobs, record: Callable, batch: bool = False, emit: Callable | None = None) -> list:
    """Run ``jobs`` (``(seed, estimators or None)`` pairs) on this process's diagram of
    ``yaml_text`` (with ``batch``: jobs with the same estimators in one batch simulation);
    returns ``[(job, record(run) or RunFailed), ...]`` in job order, and passes each pair to
    ``emit`` as soon as its record is made (the serial runner keeps each finished run before
    the next record). The Dask task and the serial loop both call this, so both compute the
    very same thing."""
    with _WORKER_LOCK:
        return _run_jobs_locked(yaml_text, jobs, record, batch, emit)


def _run_jobs_locked(yaml_text: str, jobs, record: Callable, batch: bool = False, emit: Callable | None = None) -> list:
    from drake_att.scenarios.builder import NonFiniteRunError

    sd = _worker_diagram(yaml_text)
    results: dict = {}
    if batch:
        groups: dict = {}
        for job in jobs:
            groups.setdefault(job[1], []).append(job)
        for estimators, group in groups.items():
            batch_diagram = _worker_batch_diagram(yaml_text, len(group)) if len(group) > 1 else None
            if batch_diagram is None:
                continue
            runs = batch_diagram.simulate_batch(
                [int(seed) for seed, _ in group], estimators=None if estimators is None else list(estimators)
            )
            for job, run in zip(group, runs, strict=True):
                _WORKER_STATS["runs"] += 1
                failed = isinstance(run, NonFiniteRunError)
                results[job] = RunFailed(int(job[0]), str(run)) if failed else record(run)
                if emit is not None:
                    emit(job, results[job])
    out = []
    for job in jobs:
        if job not in results:
            seed, estimators = job
            _WORKER_STATS["runs"] += 1
            try:
                run = sd.simulate(int(seed), estimators=None if estimators is None else list(estimators))
                results[job] = record(run)
            except NonFiniteRunError as e:
                results[job] = RunFailed(int(seed), str(e))
            if emit is not None:
                emit(job, results[job])
        out.append((job, results[job]))
    return out


def map_runs(
    scenario,
    jobs,
    record: Callable = metrics_record,
    *,
    workers: int | None = None,
    scheduler=None,
    chunk_size: int = 1,
    on_result: Callable | None = None,
    raise_failures: bool = False,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> list:
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
        batch_size: seeds one simulation carries where the scenario allows batches (see the
            module docstring; 1: every run alone). Tasks then hold up to this many jobs each
            (at most an even share per worker), whatever ``chunk_size``.

    A run whose truth or estimates go non-finite gives a :class:`RunFailed` (with
    ``raise_failures``: raises its ``NonFiniteRunError``); any other exception stops the map
    (the results already passed to ``on_result`` stay delivered). A scheduler address is
    connected to within ``connect_timeout_s``
    (:func:`~drake_att.analysis.dask_connection.connect_scheduler`).
    """
    connect_timeout_s = check_connect_timeout(connect_timeout_s)
    jobs = [
        (int(j), None) if isinstance(j, (int, np.integer)) else (int(j[0]), None if j[1] is None else tuple(j[1]))
        for j in jobs
    ]
    yaml_text = cfg.dump_scenario(scenario)
    index = {}
    for i, job in enumerate(jobs):
        index.setdefault(job, []).append(i)
    results = [None] * len(jobs)

    def deliver(pairs):
        raise_if_interrupted()  # a Ctrl-C swallowed during the runs stops here, before they are kept
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
    check_batch_size(batch_size)
    from drake_att.scenarios.builder import batch_problem

    serial = _is_serial(workers, scheduler)
    batch = batch_size > 1 and len(unique) > 1 and batch_problem(scenario) is None
    if batch:
        processes = 1 if serial else (workers or os.cpu_count() or 1)
        size = batch_chunk_size(len(unique), processes, int(batch_size), _batch_fit(scenario, processes))
        batch = size > 1
        chunk_size = size if batch else chunk_size
    chunk_size = max(1, chunk_size)
    chunks = [unique[k : k + chunk_size] for k in range(0, len(unique), chunk_size)]
    if serial:
        for chunk in chunks:
            _run_jobs(yaml_text, chunk, record, batch, emit=lambda job, result: deliver([(job, result)]))
        return results
    n_workers = min(workers or os.cpu_count() or 1, len(chunks))
    from distributed import as_completed

    client, cluster, owned = _connect(n_workers, scheduler, connect_timeout_s)
    futures = []
    try:
        futures = [client.submit(_run_jobs, yaml_text, chunk, record, batch, pure=False) for chunk in chunks]
        for future in as_completed(futures):
            deliver(future.result())
            future.release()
    finally:
        _shut_down(client, cluster, owned, futures)
    return results


def check_batch_size(batch_size) -> int:
    """``batch_size`` if it is an integer >= 1, else CampaignError naming it."""
    if isinstance(batch_size, bool) or not (isinstance(batch_size, (int, np.integer)) and batch_size >= 1):
        raise CampaignError(f"batch_size: got {describe(batch_size)}; must be an integer >= 1")
    return int(batch_size)


def batch_chunk_size(jobs: int, processes: int, batch_size: int, fit: int) -> int:
    """The seeds per task when ``jobs`` runs can be batched: at most ``batch_size``, at most
    ``fit`` (what memory holds), and at most an even share per process (``ceil(jobs /
    processes)``: a batch must not leave a worker idle). Below 2: no batches."""
    return min(batch_size, -(-jobs // processes), fit)


def _batch_fit(scenario, processes: int) -> int:
    """The most runs a batch may carry with ``processes`` batches at once in this machine's
    available memory: a batch holds its realizations' logs and then their per-run copies,
    twice a run's estimate (:func:`~drake_att.scenarios.preflight.memory_estimate`) each."""
    from drake_att.scenarios.preflight import available_memory_bytes, memory_estimate

    available = available_memory_bytes()
    if available is None:
        return 1
    per_run = max(1.0, float(memory_estimate(scenario).total_bytes))
    return int(available // (2.0 * per_run * max(1, processes)))


def run_seeds(scenario, seeds, workers: int | None = None, keep_series_for=(), scheduler=None) -> list[dict]:
    """Per-seed ``{"metrics": ..., "series": ...}``
    (:func:`~drake_att.analysis.run_records.metrics_and_series_record`) of ``scenario`` over
    ``seeds``, through :func:`map_runs` (``workers=1``: in this process).
    A run that goes non-finite raises its ``NonFiniteRunError``."""
    record = functools.partial(metrics_and_series_record, keep_series_for=frozenset(int(s) for s in keep_series_for))
    return map_runs(
        scenario, [int(s) for s in seeds], record, workers=workers, scheduler=scheduler, raise_failures=True
    )


def metric_mean_std(results: list[dict], key: str, estimator: str) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (ddof 1) over :func:`run_seeds` results of a per-axis
    metric (None entries dropped)."""
    vals = [r["metrics"]["estimators"][estimator][key] for r in results]
    vals = np.array([v for v in vals if v is not None], dtype=float)
    return vals.mean(axis=0), vals.std(axis=0, ddof=1) if len(vals) > 1 else np.zeros_like(vals[0])


def _is_serial(workers, scheduler) -> bool:
    return (isinstance(scheduler, str) and scheduler == SERIAL) or (scheduler is None and workers == 1)


def _check_workers(workers) -> None:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1):
        raise CampaignError(f"--workers: got {describe(workers)}; must be a positive integer")


def where_runs_go(workers, scheduler, tasks: int | None = None) -> tuple[str, object]:
    """Where :func:`map_runs` runs with these arguments: ``("serial", None)``,
    ``("local", worker processes)`` (for ``tasks`` tasks: at most one each; None: as many as
    asked for) or ``("cluster", scheduler address)``."""
    if _is_serial(workers, scheduler):
        return "serial", None
    if scheduler is None:
        n = workers or os.cpu_count()
        return "local", n if tasks is None else min(n or 1, tasks)
    if not isinstance(scheduler, str):  # a distributed.Client
        return "cluster", getattr(getattr(scheduler, "scheduler", None), "address", "?")
    return "cluster", scheduler


def executor_name(workers, scheduler) -> str:
    """Where the runs go, as ``campaign.json`` and the campaign's report name it."""
    kind, detail = where_runs_go(workers, scheduler)
    if kind == "serial":
        return "serial (this process)"
    if kind == "local":
        return f"Dask LocalCluster, {detail} worker processes"
    return f"Dask cluster at {detail}"


def executor_phrase(workers, scheduler, runs: int) -> str:
    """Where ``runs`` runs go, as ``drake-att montecarlo`` announces them."""
    kind, detail = where_runs_go(workers, scheduler, runs)
    if kind == "serial":
        return "serially in this process"
    if kind == "local":
        return f"on a local Dask cluster of {detail} worker processes"
    return f"on the Dask cluster at {detail}"
