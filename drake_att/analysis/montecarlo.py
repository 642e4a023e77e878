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
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import os
import re
import sys
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drake_att.analysis.progress import Progress, format_duration
from drake_att.outputs import safe_component
from drake_att.scenarios import config as cfg
from drake_att.validation import SEED_MAX, UserInputError, describe

SERIAL = "serial"
RUNS_DIR = "runs"
CONFIG_FILE = "config.yaml"
CAMPAIGN_FILE = "campaign.json"
SUMMARY_FILE = "summary.json"
MANIFEST_FILE = "manifest.json"
DEFAULT_CONNECT_TIMEOUT_S = 10.0
MAX_CONNECT_TIMEOUT_S = 3600.0
# Reading a campaign folder is bounded: a saved record expands to at most this many bytes
# (a 5000-s, 1-Hz run is ~0.5 MB per estimator), the campaign's small files to the other.
MAX_RECORD_BYTES = 2**30
MAX_SIDE_FILE_BYTES = 2**20


class CampaignError(UserInputError):
    """Bad campaign input or a folder/cluster that cannot be used; the message names the
    option (``--runs``, ``--out``, ``--scheduler``, ...) and the value."""


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


def _worker_versions() -> dict:
    """What a worker runs (checked against the client's before a cluster campaign)."""
    import pydrake

    import drake_att

    return {"drake_att": drake_att.__version__, "drake": getattr(pydrake, "__version__", "?"),
            "numpy": np.__version__, "python": sys.version.split()[0]}


# ----------------------------------------------------------------------------------------
# The one runner
# ----------------------------------------------------------------------------------------
def _one_line(text, limit: int = 300) -> str:
    """``text`` on one line (whitespace runs folded), at most ``limit`` characters: foreign
    text (an exception's message, a line of a file) inside a one-line message."""
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[:limit] + "..."


def _shown(path) -> str:
    """A path or address as a message shows it: as is when printable, else its repr (a name
    with a newline must not break the one-line message)."""
    text = str(path)
    return text if text.isprintable() and len(text) <= 300 else repr(text[:300])


def _error_text(e: BaseException) -> str:
    return _one_line(f"{type(e).__name__}: {e}" if str(e) else type(e).__name__, 200)


def check_connect_timeout(value) -> float:
    """``--connect-timeout`` in seconds: a finite number > 0, at most
    :data:`MAX_CONNECT_TIMEOUT_S` (CampaignError naming the option otherwise)."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    seconds = float(value) if number else float("nan")
    if not (np.isfinite(seconds) and 0.0 < seconds <= MAX_CONNECT_TIMEOUT_S):
        raise CampaignError(f"--connect-timeout: got {describe(value)}; must be a finite number of seconds > 0 and at "
                            f"most {MAX_CONNECT_TIMEOUT_S:g}")
    return seconds


_SCHEDULER_ALLOWED = ("expected a Dask scheduler address tcp://HOST:PORT (e.g. tcp://10.0.0.5:8786, what "
                      "`dask scheduler` prints), or 'serial'")
_HOST_NAME = re.compile(r"[A-Za-z0-9_](?:[A-Za-z0-9_.-]{0,252})|\[[0-9A-Fa-f:.]{2,45}\]")


def check_scheduler_address(address: str) -> str:
    """A Dask scheduler address ``[tcp://]HOST:PORT``, returned as ``tcp://HOST:PORT``
    (CampaignError naming ``--scheduler`` otherwise).

    Only ``tcp://``: Dask's other schemes are refused with the value and what is allowed
    (``tls://`` needs a CA, a certificate and a key in Dask's configuration, which drake-att
    has no options for and does not test; ``ws://``, ``ucx://``, ``inproc://`` are not for a
    campaign's cluster; ``http://`` is the dashboard, not the scheduler)."""
    if not isinstance(address, str):
        raise CampaignError(f"--scheduler: got {describe(address)}; {_SCHEDULER_ALLOWED}")
    text = address.strip()
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "tcp", text
    if scheme.lower() != "tcp":
        hint = (" (tls:// needs certificates drake-att has no options for: reach a remote scheduler through an SSH "
                "tunnel to tcp://localhost:8786)" if scheme.lower() == "tls" else
                " (http:// is the scheduler's dashboard, not the scheduler)" if scheme.lower() in ("http", "https")
                else "")
        raise CampaignError(f"--scheduler: got {describe(address)}; the scheme {_shown(scheme)}:// is not supported: "
                            f"{_SCHEDULER_ALLOWED}{hint}")
    host, _, port = rest.rpartition(":")
    if not _HOST_NAME.fullmatch(host) or not re.fullmatch(r"[0-9]{1,5}", port) or not 0 < int(port) < 65536:
        raise CampaignError(f"--scheduler: got {describe(address)}; {_SCHEDULER_ALLOWED}")
    return f"tcp://{host}:{int(port)}"


def local_cluster(workers: int):
    """A Dask ``LocalCluster`` of ``workers`` single-threaded worker processes (pydrake
    systems are not thread-safe), its dashboard on a free port. Its workers ignore SIGINT: a
    terminal's Ctrl-C reaches the whole process group, and this process (the client) stops
    the campaign and closes the cluster; the workers would only print tracebacks."""
    import logging
    import signal

    from distributed import LocalCluster

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None  # inherited by the spawned workers
    try:
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                            silence_logs=logging.CRITICAL)
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)


# Connecting to a scheduler: every wait has a deadline. distributed's own connect() bounds
# the TCP connection but not Dask's handshake after it: a program that accepts the
# connection and never answers like a scheduler (an HTTP server, a port forwarder to
# nothing) holds a plain ``Client(address, timeout=...)`` forever. So the address is first
# probed on an event loop of its own, in a daemon thread the caller stops waiting for at
# the deadline; then the Client's start, the wait for a worker and the version check each
# get what is left of the same deadline (at least CONNECT_STEP_MIN_S).
CONNECT_STEP_MIN_S = 1.0


def _host_port(address: str) -> tuple[str, int]:
    host, _, port = address.split("://", 1)[1].rpartition(":")
    return host.strip("[]"), int(port)


async def _dask_identity(address: str, timeout_s: float):
    """Dask's handshake with ``address`` and the reply of its ``identity`` handler."""
    from distributed.comm import connect

    comm = await connect(address, timeout=timeout_s)
    try:
        await comm.write({"op": "identity", "reply": True})
        return await comm.read()
    finally:
        comm.abort()


def _probe_scheduler(address: str, timeout_s: float, shown: str) -> None:
    """Within ``timeout_s`` (plus a fraction of a second): ``address`` (``tcp://HOST:PORT``)
    accepts a TCP connection, speaks Dask's protocol and its ``identity`` says it is a Dask
    *scheduler*; CampaignError naming ``--scheduler`` and the address otherwise. Nothing is
    left waiting: the probe's event loop, in a daemon thread, cancels itself at the deadline."""
    import asyncio
    import socket

    box = {"stage": "tcp"}
    start = time.monotonic()

    def left() -> float:
        return max(0.05, timeout_s - (time.monotonic() - start))

    def probe() -> None:
        try:
            host, port = _host_port(address)
            with socket.create_connection((host, port), timeout=left()) as sock:
                peer = sock.getpeername()[0]
            box["stage"] = "dask"
            peer_address = f"tcp://[{peer}]:{port}" if ":" in peer else f"tcp://{peer}:{port}"
            box["reply"] = asyncio.run(asyncio.wait_for(_dask_identity(peer_address, left()), left()))
        except BaseException as e:  # noqa: BLE001 - reported by the caller, with the stage it happened in
            box["error"] = e

    thread = threading.Thread(target=probe, name="drake-att-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout_s + 0.5)
    where = f"--scheduler {shown}"
    advice = "is `dask scheduler` running there and reachable?"
    stage, error = box["stage"], box.get("error")
    if thread.is_alive():
        what = ("no TCP connection (the host name did not resolve, or no answer)" if stage == "tcp" else
                "something accepted the connection but no Dask scheduler answered")
        raise CampaignError(f"{where}: cannot connect within {timeout_s:g} s ({what}); {advice}")
    if error is None:
        reply = box.get("reply")
        kind = reply.get("type") if isinstance(reply, dict) else None
        if kind == "Scheduler":
            return
        if isinstance(kind, str) and kind:
            raise CampaignError(f"{where}: is a Dask {_one_line(kind, 40)}, not a scheduler; give the address "
                                "`dask scheduler` prints")
        raise CampaignError(f"{where}: answers, but not as a Dask scheduler; give the address `dask scheduler` prints")
    if stage == "tcp" and isinstance(error, socket.gaierror):
        raise CampaignError(f"{where}: cannot connect: unknown host ({_error_text(error)}); {advice}")
    if stage == "tcp" and isinstance(error, ConnectionRefusedError):
        raise CampaignError(f"{where}: cannot connect: nothing listens there (connection refused); {advice}")
    if stage == "tcp" and isinstance(error, (TimeoutError, socket.timeout)):
        raise CampaignError(f"{where}: cannot connect within {timeout_s:g} s (no answer: host down, wrong address "
                            f"or a firewall?); {advice}")
    if stage == "tcp":
        raise CampaignError(f"{where}: cannot connect ({_error_text(error)}); {advice}")
    if isinstance(error, (TimeoutError, asyncio.TimeoutError)):
        raise CampaignError(f"{where}: cannot connect within {timeout_s:g} s: something accepts connections there "
                            "but no Dask scheduler answered (another program on that port?); give the address "
                            "`dask scheduler` prints")
    raise CampaignError(f"{where}: cannot connect: something accepts connections there but does not speak Dask's "
                        f"protocol ({_error_text(error)}); give the address `dask scheduler` prints")


@functools.cache
def _deadline_client_class():
    """``distributed.Client`` whose start (connection, handshake, registration) is cancelled
    at its ``timeout`` (``Client.start`` passes ``callback_timeout`` to
    ``distributed.utils.sync``); a start that timed out closes the half-made client."""
    from distributed import Client

    class DeadlineClient(Client):
        def start(self, **kwargs):
            timeout = kwargs.get("timeout")
            if isinstance(timeout, (int, float)):
                kwargs.setdefault("callback_timeout", timeout)
            try:
                return super().start(**kwargs)
            except BaseException:
                _close_quietly(self)
                raise

    return DeadlineClient


def _close_quietly(client, timeout_s: float = 5.0) -> None:
    import logging

    quiet = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        client.close(timeout=timeout_s)
    except Exception:  # noqa: BLE001, S110 - closing after a failure: the failure is what is reported
        pass
    finally:
        for q, level in zip(quiet, levels):
            q.setLevel(level)


def connect_scheduler(address: str, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S):
    """A ``distributed.Client`` of the Dask scheduler at ``address`` with at least one worker
    that runs this drake_att, within ``connect_timeout_s`` plus at most ~5 s: the TCP
    connection, Dask's handshake, the first worker and the version check. Every failure is a
    one-line CampaignError naming ``--scheduler`` and the address (a port where nothing
    listens fails at once; a program there that is not a Dask scheduler within the timeout).
    The caller closes the client."""
    timeout_s = check_connect_timeout(connect_timeout_s)
    shown = _shown(address)
    address = check_scheduler_address(address)
    deadline = time.monotonic() + timeout_s
    _probe_scheduler(address, timeout_s, shown)

    def left() -> float:
        return max(CONNECT_STEP_MIN_S, deadline - time.monotonic())

    where = f"--scheduler {shown}"
    try:
        client = _deadline_client_class()(address, timeout=left(), set_as_default=False)
    except TimeoutError:
        raise CampaignError(f"{where}: cannot connect within {timeout_s:g} s (no answer from the scheduler); is "
                            "`dask scheduler` running there and reachable?") from None
    except OSError as e:
        raise CampaignError(f"{where}: cannot connect within {timeout_s:g} s ({_error_text(e)}); is `dask scheduler` "
                            "running there and reachable?") from None
    except Exception as e:  # noqa: BLE001 - e.g. the scheduler refused this client (versions): reported, one line
        raise CampaignError(f"{where}: the scheduler refused the connection ({_error_text(e)})") from None
    # What follows talks to a scheduler that answered; a watchdog still closes the client
    # (which ends any wait on it) if it stops answering.
    fired = threading.Event()

    def stop() -> None:
        fired.set()
        _close_quietly(client, 2.0)

    watchdog = threading.Timer(left() + CONNECT_STEP_MIN_S, stop)
    watchdog.daemon = True
    watchdog.start()
    try:
        try:
            client.wait_for_workers(1, timeout=left())
        except Exception:  # noqa: BLE001 - TimeoutError, or the watchdog closed the client
            raise CampaignError(f"{where}: no workers connected within {timeout_s:g} s; start some with "
                                f"`dask worker {address}`") from None
        mine = _worker_versions()
        try:
            theirs = client.run(_worker_versions)
        except Exception as e:  # noqa: BLE001 - the worker's own error, reported with the address
            if fired.is_set():
                raise CampaignError(f"{where}: the workers did not answer the version check within {timeout_s:g} s"
                                    ) from None
            raise CampaignError(f"{where}: a worker cannot run drake_att ({_error_text(e)}); install the same "
                                "drake_att on every worker machine") from None
        if fired.is_set():
            raise CampaignError(f"{where}: the scheduler stopped answering within {timeout_s:g} s")
    except BaseException:
        watchdog.cancel()
        _close_quietly(client, 2.0)
        raise
    watchdog.cancel()
    if fired.is_set():
        raise CampaignError(f"{where}: the scheduler stopped answering within {timeout_s:g} s")
    for worker, versions in theirs.items():
        if versions != mine:
            warnings.warn(f"worker {worker} runs {versions}, this process {mine}: results may differ from a "
                          "local run of the same seeds", stacklevel=3)
    return client


def _connect(workers, scheduler, connect_timeout_s):
    """``(client, cluster, owned)`` for a Dask run (``owned``: this call opened the client,
    and the cluster when not None, so its caller closes them)."""
    from distributed import Client

    if scheduler is None:
        cluster = local_cluster(workers)
        return Client(cluster), cluster, True
    if isinstance(scheduler, Client):
        return scheduler, None, False
    return connect_scheduler(scheduler, connect_timeout_s), None, True


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


def _shut_down(client, cluster, owned, futures) -> None:
    """Cancel what is left and close what this call opened, quietly (also after Ctrl-C)."""
    import logging

    quiet = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        for step in ([lambda: client.cancel([f for f in futures if not f.done()])]
                     + ([client.close] if owned else [])
                     + ([cluster.close] if owned and cluster is not None else [])):
            try:
                step()
            except Exception:  # noqa: BLE001, S110 - shutting down after an error or Ctrl-C: the first error matters
                pass
    finally:
        for q, level in zip(quiet, levels):
            q.setLevel(level)


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


def _run_path(out: str, seed: int) -> str:
    return os.path.join(out, RUNS_DIR, f"seed_{seed}.npz")


def _failed_path(out: str, seed: int) -> str:
    return os.path.join(out, RUNS_DIR, f"seed_{seed}.failed.txt")


def _atomic_write(path: str, write: Callable) -> None:
    """``write(file)`` into a temporary sibling, flushed to disk, then renamed to ``path``:
    ``path`` is complete or absent, never half written."""
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def write_text_atomic(path: str, text: str) -> str:
    _atomic_write(path, lambda f: f.write(text.encode()))
    return path


def _npz_arrays(record, seed: int) -> dict:
    if not isinstance(record, dict):
        raise TypeError(f"seed {seed}: a campaign record must be a dict of numpy arrays, got {type(record).__name__}")
    arrays = {}
    for key, value in record.items():
        a = np.asarray(value)
        if a.dtype == object:
            raise TypeError(f"seed {seed}: record entry {key!r} is not a plain numpy array (dtype object); "
                            "records are saved without pickles")
        arrays[key] = a
    return arrays


def save_record(out: str, seed: int, record) -> str:
    """``<out>/runs/seed_<seed>.npz``, atomically (``np.savez``, no pickles)."""
    path = _run_path(out, seed)
    arrays = _npz_arrays(record, seed)
    _atomic_write(path, lambda f: np.savez(f, **arrays))
    return path


def load_record(path: str) -> dict:
    """A saved record: ``np.load`` without pickles, every array read (a damaged file raises
    here). ValueError for a file that is not an ``.npz`` archive, an entry that is not a
    numpy array or an archive that expands beyond :data:`MAX_RECORD_BYTES`."""
    loaded = np.load(path, allow_pickle=False)
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ValueError("a single .npy array, not an .npz archive of a record")
    with loaded as npz:
        size = sum(info.file_size for info in npz.zip.infolist())
        if size > MAX_RECORD_BYTES:
            raise ValueError(f"expands to {size} bytes, more than {MAX_RECORD_BYTES} (a record is a few MB)")
        record = {}
        for key in npz.files:
            value = npz[key]
            if not isinstance(value, np.ndarray):
                raise ValueError(f"entry {_one_line(repr(key), 80)} is not a numpy array")
            record[key] = value
    return record


# ----------------------------------------------------------------------------------------
# Is a saved record one of this campaign's? (checked before a resume reuses it)
# ----------------------------------------------------------------------------------------
# Two checks, so that a file edited by hand (or by another program) is redone rather than
# reused and crashing the summary later:
#
# * the *layout* every record of the campaign shares: its keys and, per key, the dtype kind,
#   the number of dimensions and every dimension but the first (the first is the number of
#   samples, which may differ from seed to seed). campaign.json keeps the layout of the
#   campaign's first fresh record ("record_layout"); a record function may declare keys
#   that some runs lack (``optional_key_suffixes``: the default record's bound arrays,
#   absent when a run has no bound). A record computed later with another layout replaces
#   it (records just computed are the reference, never a file);
# * for the default record, its documented structure (drake_att.analysis.ensemble),
#   derived from the scenario without a simulation: the keys of each estimator, shapes
#   consistent within the record (n estimate samples in t, dtheta, sigma, ...), the seed,
#   scenario and estimators it names, its JSON texts.
_KIND_NAMES = {"f": "float", "i": "int", "u": "unsigned int", "U": "str", "S": "bytes", "b": "bool", "c": "complex"}


def record_layout(record, optional_suffixes=()) -> dict:
    """``{key: [dtype kind, ndim, [every dimension but the first]]}`` of a record's arrays
    (keys ending in one of ``optional_suffixes`` left out)."""
    out = {}
    for key in sorted(record):
        if optional_suffixes and key.endswith(tuple(optional_suffixes)):
            continue
        a = np.asarray(record[key])
        out[key] = [a.dtype.kind, a.ndim, [int(d) for d in a.shape[1:]]]
    return out


def _valid_layout(value) -> dict | None:
    """A layout read from campaign.json, or None when it is absent or malformed (then the
    next fresh record sets it again)."""
    if not isinstance(value, dict) or not value:
        return None
    for key, entry in value.items():
        if not (isinstance(key, str) and isinstance(entry, list) and len(entry) == 3 and isinstance(entry[0], str)
                and isinstance(entry[1], int) and not isinstance(entry[1], bool) and 0 <= entry[1] <= 32
                and isinstance(entry[2], list) and len(entry[2]) == max(entry[1] - 1, 0)
                and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in entry[2])):
            return None
    return value


def _layout_text(entry) -> str:
    kind, ndim, rest = entry
    name = _KIND_NAMES.get(kind, f"dtype kind {kind!r}")
    return f"{name} scalar" if ndim == 0 else f"{name} array of shape ({', '.join(['n'] + [str(d) for d in rest])})"


def _layout_problem(record: dict, layout: dict, optional_suffixes=()) -> str | None:
    mine = record_layout(record, optional_suffixes)
    missing, extra = sorted(set(layout) - set(mine)), sorted(set(mine) - set(layout))
    more = lambda keys: f" (and {len(keys) - 1} more)" if len(keys) > 1 else ""  # noqa: E731
    if missing:
        return f"key {_one_line(repr(missing[0]), 80)} is missing{more(missing)}"
    if extra:
        return f"unexpected key {_one_line(repr(extra[0]), 80)}{more(extra)}"
    for key, entry in layout.items():
        if mine[key] != entry:
            return f"{key!r}: got a {_layout_text(mine[key])}; the campaign's records hold a {_layout_text(entry)}"
    return None


def _is_kind(a, kinds: str, ndim: int) -> bool:
    return isinstance(a, np.ndarray) and a.dtype.kind in kinds and a.ndim == ndim


def default_record_problem(record: dict, scenario: cfg.Scenario, seed: int) -> str | None:
    """Why ``record`` is not :func:`default_record` of run ``seed`` of ``scenario`` (None:
    it has the documented structure, :mod:`drake_att.analysis.ensemble`). Checks keys,
    dtype kinds and shapes, shapes consistent within the record, the seed, scenario,
    estimators and scoring it names, and that its JSON texts are JSON objects; derived from
    the scenario, no simulation needed."""
    from drake_att.analysis.ensemble import RECORD_SCHEMA

    FLOAT, INT, STR = "f", "iu", "U"

    def text(key):
        return str(record[key])

    def json_object(key):
        try:
            return isinstance(json.loads(text(key)), dict)
        except ValueError:
            return False

    names = [e.name for e in scenario.estimators]
    scalars = {"schema": INT, "scenario": STR, "seed": INT, "duration_s": FLOAT, "score_from_s": FLOAT,
               "convergence_threshold_deg": FLOAT, "metrics_json": STR}
    expected = set(scalars) | {"estimators"}
    for key, kinds in scalars.items():
        if key not in record:
            return f"key {key!r} is missing"
        if not _is_kind(record[key], kinds, 0):
            return f"{key!r}: got {_layout_text(record_layout({key: record[key]})[key])}; expected a scalar"
    if int(record["schema"]) != RECORD_SCHEMA:
        return f"record schema {int(record['schema'])}, this drake_att writes {RECORD_SCHEMA}"
    if int(record["seed"]) != seed:
        return f"it holds seed {int(record['seed'])}, not {seed}"
    if text("scenario") != scenario.name:
        return f"it holds scenario {_one_line(repr(text('scenario')), 80)}, not {scenario.name!r}"
    for key, value in (("duration_s", scenario.duration_s), ("score_from_s", scenario.scoring.score_from_s),
                       ("convergence_threshold_deg", scenario.scoring.convergence_threshold_deg)):
        if not abs(float(record[key]) - float(value)) <= 1e-9 * max(1.0, abs(float(value))):
            return f"{key} {float(record[key])!r}, the campaign's configuration has {float(value)!r}"
    if not json_object("metrics_json"):
        return "'metrics_json' is not a JSON object"
    if "estimators" not in record or not _is_kind(record["estimators"], STR, 1):
        return "'estimators' is missing or not an array of names"
    if [str(x) for x in record["estimators"]] != names:
        return f"it holds estimators {_one_line([str(x) for x in record['estimators']], 120)}, not {names}"
    per = {"t": (FLOAT, 1, None), "dtheta": (FLOAT, 2, 3), "sigma": (FLOAT, 2, 6), "nees": (FLOAT, 1, None),
           "second_kind": (STR, 0, None), "nees_dof": (INT, 0, None), "window_n": (INT, 0, None),
           "window_ms": (FLOAT, 1, None), "window_ms_second": (FLOAT, 1, None), "window_nees_sum": (FLOAT, 0, None),
           "window_nees_n": (INT, 0, None), "convergence_time_s": (FLOAT, 0, None), "inputs": (STR, 1, None),
           "nis_source": (STR, 0, None), "bound_json": (STR, 0, None)}
    optional = {"second_err": (FLOAT, 2, 3), "bound_sigma": (FLOAT, 2, 6), "bound_window_var": (FLOAT, 1, None)}
    for name in names:
        p = f"{name}__"
        for suffix, (kinds, ndim, cols) in list(per.items()) + list(optional.items()):
            key = p + suffix
            if key not in record:
                if suffix in optional:
                    continue
                return f"key {key!r} is missing"
            a = record[key]
            if not _is_kind(a, kinds, ndim) or (cols is not None and a.shape[1] != cols):
                want = ("str" if kinds == STR else "int" if kinds == INT else "float")
                want += " scalar" if ndim == 0 else f" array of shape (n{', ' + str(cols) if cols else ''})"
                return f"{key!r}: got a {_layout_text(record_layout({key: a})[key])}; expected a {want}"
            expected.add(key)
        t = record[p + "t"]
        n = len(t)
        for suffix in ("dtheta", "sigma", "nees", "second_err", "bound_sigma"):
            if p + suffix in record and len(record[p + suffix]) != n:
                return f"'{p}{suffix}' has {len(record[p + suffix])} samples, '{p}t' {n}"
        for suffix, size in (("window_ms", 3), ("window_ms_second", 3), ("bound_window_var", 6)):
            if p + suffix in record and record[p + suffix].shape != (size,):
                return f"'{p}{suffix}': got shape {record[p + suffix].shape}; expected ({size},)"
        if not (np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0)):
            return f"'{p}t' is not a finite, increasing time series"
        if text(p + "second_kind") not in ("gyro_bias", "body_rate"):
            return f"'{p}second_kind' is {_one_line(repr(text(p + 'second_kind')), 60)}, not gyro_bias or body_rate"
        if int(record[p + "nees_dof"]) < 1:
            return f"'{p}nees_dof' is {int(record[p + 'nees_dof'])}; a NEES has at least 1 degree of freedom"
        source = text(p + "nis_source")
        if source not in ("innovations", "status", "none"):
            return f"'{p}nis_source' is {_one_line(repr(source), 60)}, not innovations, status or none"
        if not json_object(p + "bound_json"):
            return f"'{p}bound_json' is not a JSON object"
        # NIS samples: one (t, value, dof) triple per input, of equal lengths (none: "none")
        inputs = 0 if source == "none" else len(record[p + "inputs"])
        for i in range(inputs):
            keys = [f"{p}nis{i}__{k}" for k in ("t", "value", "dof")]
            for key, kinds in zip(keys, (FLOAT, FLOAT, INT)):
                if key not in record:
                    return f"key {key!r} is missing"
                if not _is_kind(record[key], kinds, 1):
                    got = _layout_text(record_layout({key: record[key]})[key])
                    return f"{key!r}: got a {got}; expected a 1-d array"
                expected.add(key)
            if len({len(record[k]) for k in keys}) != 1:
                return f"'{p}nis{i}__t', '__value' and '__dof' differ in length"
    extra = sorted(set(record) - expected)
    if extra:
        return f"unexpected key {_one_line(repr(extra[0]), 80)}" + (f" (and {len(extra) - 1} more)" if len(extra) > 1
                                                                   else "")
    return None


default_record.optional_key_suffixes = ("__bound_sigma", "__bound_window_var")


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
    a failed run's message), at most ``limit`` bytes; ValueError saying why not (not a
    file, unreadable, too large, binary, not UTF-8), without the path."""
    if not os.path.isfile(path):
        raise ValueError("is not a regular file")
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as e:
        raise ValueError(f"cannot be read ({_one_line(e.strerror or e, 80)})") from None
    if len(data) > limit:
        raise ValueError(f"larger than {limit} bytes")
    if b"\x00" in data:
        raise ValueError("a binary file (it holds NUL bytes)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"not UTF-8 text (byte 0x{data[e.start]:02x} at offset {e.start})") from None


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


def _saved_run_files(runs: str) -> list[str]:
    """The run files (``seed_<n>.npz``, ``seed_<n>.failed.txt``) in ``runs``."""
    try:
        names = os.listdir(runs)
    except OSError:
        return []
    return [n for n in names if re.fullmatch(r"seed_[0-9]+\.(npz|failed\.txt)", n)]


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
