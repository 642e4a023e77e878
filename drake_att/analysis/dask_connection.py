"""Reaching Dask for a Monte Carlo campaign: the checks of ``--scheduler`` and
``--connect-timeout``, a local cluster of single-threaded worker processes, and the
connection to an existing scheduler in which every network wait has a deadline.

A campaign must neither hang on an address that is not a Dask scheduler nor leave a cluster
behind, and a user's mistake is a one-line :class:`CampaignError` naming the option. The
runner (:func:`drake_att.analysis.executor.map_runs`) and the campaigns on top of it get
their client here (:func:`_connect`) and close it here (:func:`_shut_down`); nothing here
imports the runner.
"""

from __future__ import annotations

import functools
import re
import sys
import threading
import time
import warnings

import numpy as np

from drake_att.validation import UserInputError, describe

DEFAULT_CONNECT_TIMEOUT_S = 10.0
MAX_CONNECT_TIMEOUT_S = 3600.0


class CampaignError(UserInputError):
    """Bad campaign input or a folder/cluster that cannot be used; the message names the
    option (``--runs``, ``--out``, ``--scheduler``, ...) and the value."""


# ----------------------------------------------------------------------------------------
# One-line messages: foreign text (paths, addresses, exceptions) inside them
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


# ----------------------------------------------------------------------------------------
# The options: --connect-timeout, --scheduler
# ----------------------------------------------------------------------------------------
def check_connect_timeout(value) -> float:
    """``--connect-timeout`` in seconds: a finite number > 0, at most
    :data:`MAX_CONNECT_TIMEOUT_S` (CampaignError naming the option otherwise)."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    seconds = float(value) if number else float("nan")
    if not (np.isfinite(seconds) and 0.0 < seconds <= MAX_CONNECT_TIMEOUT_S):
        raise CampaignError(
            f"--connect-timeout: got {describe(value)}; must be a finite number of seconds > 0 and at "
            f"most {MAX_CONNECT_TIMEOUT_S:g}"
        )
    return seconds


_SCHEDULER_ALLOWED = (
    "expected a Dask scheduler address tcp://HOST:PORT (e.g. tcp://10.0.0.5:8786, what "
    "`dask scheduler` prints), or 'serial'"
)
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
        hint = (
            " (tls:// needs certificates drake-att has no options for: reach a remote scheduler through an SSH "
            "tunnel to tcp://localhost:8786)"
            if scheme.lower() == "tls"
            else " (http:// is the scheduler's dashboard, not the scheduler)"
            if scheme.lower() in ("http", "https")
            else ""
        )
        raise CampaignError(
            f"--scheduler: got {describe(address)}; the scheme {_shown(scheme)}:// is not supported: "
            f"{_SCHEDULER_ALLOWED}{hint}"
        )
    host, _, port = rest.rpartition(":")
    if not _HOST_NAME.fullmatch(host) or not re.fullmatch(r"[0-9]{1,5}", port) or not 0 < int(port) < 65536:
        raise CampaignError(f"--scheduler: got {describe(address)}; {_SCHEDULER_ALLOWED}")
    return f"tcp://{host}:{int(port)}"


# ----------------------------------------------------------------------------------------
# A local cluster; a connection to a scheduler, with deadlines
# ----------------------------------------------------------------------------------------
def local_cluster(workers: int):
    """A Dask ``LocalCluster`` of ``workers`` single-threaded worker processes (pydrake
    systems are not thread-safe), its dashboard on a free port. Its workers ignore SIGINT: a
    terminal's Ctrl-C reaches the whole process group, and this process (the client) stops
    the campaign and closes the cluster; the workers would only print tracebacks."""
    import logging
    import signal

    from distributed import LocalCluster

    if _importing_the_main_script_for_a_worker():
        raise CampaignError(_MAIN_GUARD_HINT)
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None  # inherited by the spawned workers
    try:
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            silence_logs=logging.CRITICAL,
        )
    except Exception as e:  # a worker that could not start (e.g. it died importing the caller's script)
        raise CampaignError(
            f"a local Dask cluster of {workers} worker processes failed to start ({_one_line(e, 120)})"
            + (f"; {_MAIN_GUARD_HINT}" if _main_is_a_script() else "")
        ) from e
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)


_MAIN_GUARD_HINT = (
    "each worker process imports the main script again, so a script that starts a campaign with "
    'workers > 1 must do it under `if __name__ == "__main__":`'
)


def _importing_the_main_script_for_a_worker() -> bool:
    """True in a worker process while it imports the caller's main script (Python's spawn start
    method runs it as ``__mp_main__``): a campaign started there would start workers of its own."""
    return getattr(sys.modules.get("__main__"), "__name__", "") == "__mp_main__"


def _main_is_a_script() -> bool:
    """The main module is a file (``python script.py``), not an interactive session or ``-c``."""
    return bool(getattr(sys.modules.get("__main__"), "__file__", None))


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
        what = (
            "no TCP connection (the host name did not resolve, or no answer)"
            if stage == "tcp"
            else "something accepted the connection but no Dask scheduler answered"
        )
        raise CampaignError(f"{where}: cannot connect within {timeout_s:g} s ({what}); {advice}")
    if error is None:
        reply = box.get("reply")
        kind = reply.get("type") if isinstance(reply, dict) else None
        if kind == "Scheduler":
            return
        if isinstance(kind, str) and kind:
            raise CampaignError(
                f"{where}: is a Dask {_one_line(kind, 40)}, not a scheduler; give the address `dask scheduler` prints"
            )
        raise CampaignError(f"{where}: answers, but not as a Dask scheduler; give the address `dask scheduler` prints")
    if stage == "tcp" and isinstance(error, socket.gaierror):
        raise CampaignError(f"{where}: cannot connect: unknown host ({_error_text(error)}); {advice}")
    if stage == "tcp" and isinstance(error, ConnectionRefusedError):
        raise CampaignError(f"{where}: cannot connect: nothing listens there (connection refused); {advice}")
    if stage == "tcp" and isinstance(error, (TimeoutError, socket.timeout)):
        raise CampaignError(
            f"{where}: cannot connect within {timeout_s:g} s (no answer: host down, wrong address "
            f"or a firewall?); {advice}"
        )
    if stage == "tcp":
        raise CampaignError(f"{where}: cannot connect ({_error_text(error)}); {advice}")
    if isinstance(error, (TimeoutError, asyncio.TimeoutError)):
        raise CampaignError(
            f"{where}: cannot connect within {timeout_s:g} s: something accepts connections there "
            "but no Dask scheduler answered (another program on that port?); give the address "
            "`dask scheduler` prints"
        )
    raise CampaignError(
        f"{where}: cannot connect: something accepts connections there but does not speak Dask's "
        f"protocol ({_error_text(error)}); give the address `dask scheduler` prints"
    )


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
        for q, level in zip(quiet, levels, strict=True):
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
        raise CampaignError(
            f"{where}: cannot connect within {timeout_s:g} s (no answer from the scheduler); is "
            "`dask scheduler` running there and reachable?"
        ) from None
    except OSError as e:
        raise CampaignError(
            f"{where}: cannot connect within {timeout_s:g} s ({_error_text(e)}); is `dask scheduler` "
            "running there and reachable?"
        ) from None
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
            raise CampaignError(
                f"{where}: no workers connected within {timeout_s:g} s; start some with `dask worker {address}`"
            ) from None
        mine = _worker_versions()
        try:
            theirs = client.run(_worker_versions)
        except Exception as e:  # noqa: BLE001 - the worker's own error, reported with the address
            if fired.is_set():
                raise CampaignError(
                    f"{where}: the workers did not answer the version check within {timeout_s:g} s"
                ) from None
            raise CampaignError(
                f"{where}: a worker cannot run drake_att ({_error_text(e)}); install the same "
                "drake_att on every worker machine"
            ) from None
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
            warnings.warn(
                f"worker {worker} runs {versions}, this process {mine}: results may differ from a "
                "local run of the same seeds",
                stacklevel=3,
            )
    return client


# ----------------------------------------------------------------------------------------
# The runner's client: opened (a local cluster or a scheduler) and closed here
# ----------------------------------------------------------------------------------------
def _worker_versions() -> dict:
    """What a worker runs (checked against the client's before a cluster campaign)."""
    import pydrake

    import drake_att

    return {
        "drake_att": drake_att.__version__,
        "drake": getattr(pydrake, "__version__", "?"),
        "numpy": np.__version__,
        "python": sys.version.split()[0],
    }


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


def _shut_down(client, cluster, owned, futures) -> None:
    """Cancel what is left and close what this call opened, quietly (also after Ctrl-C)."""
    import logging

    quiet = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        for step in (
            [lambda: client.cancel([f for f in futures if not f.done()])]
            + ([client.close] if owned else [])
            + ([cluster.close] if owned and cluster is not None else [])
        ):
            try:
                step()
            except Exception:  # noqa: BLE001, S110 - shutting down after an error or Ctrl-C: the first error matters
                pass
    finally:
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)
