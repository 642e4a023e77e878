"""The Monte Carlo campaign's edges (DESIGN.md "The edges"), each reproduced first as a
failing test: scheduler addresses and --connect-timeout are checked; every network wait
has a deadline (a program that is not a Dask scheduler, one that accepts and never
answers, a closed port); a failed start leaves no campaign folder behind and an empty
campaign of ours does not block a new start; a hostile --resume (edited run files,
campaign.json, config.yaml) is a one-line error or a redone run, never a traceback; the
counts add up."""

from __future__ import annotations

import http.server
import io
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drake_att.analysis import campaign, campaign_records, dask_connection
from drake_att.analysis import montecarlo as mc
from drake_att.cli import main as cli_main

SCENARIO = "cubesat_single_star_tracker"
SHORT = ["duration_s=60", "scoring.score_from_s=20"]
ENV = dict(os.environ, MPLBACKEND="Agg")
# The connection must fail within its timeout plus a few seconds; the old code waited for
# Dask's handshake without a deadline (580 s against an HTTP server).
TIMEOUT_S = 2.0
UPPER_BOUND_S = 15.0


def one_line(e) -> str:
    text = str(e)
    assert "\n" not in text and "\r" not in text and "Traceback" not in text, text
    return text


# ----------------------------------------------------------------------------------------
# 1, 2: --scheduler and --connect-timeout
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "address",
    [
        "http://127.0.0.1:8786",
        "https://example.org:443",
        "tls://10.0.0.5:8786",
        "ws://127.0.0.1:8786",
        "inproc://192.0.2.2/1/1",
        "ucx://127.0.0.1:8786",
        "tcp://127.0.0.1:8786/path",
        "tcp://127.0.0.1:0",
        "tcp://127.0.0.1:70000",
        "tcp://:8786",
        "not an address",
        "tcp://host name:8786",
        "tcp://127.0.0.1:８７",
        "tcp://a\nb:8786",
        8786,
        None,
    ],
)
def test_scheduler_other_than_tcp_is_refused_naming_the_value(address):
    with pytest.raises(mc.CampaignError) as e:
        mc.check_scheduler_address(address)
    text = one_line(e.value)
    assert text.startswith("--scheduler: got ") and "tcp://HOST:PORT" in text
    if isinstance(address, str) and "://" in address and not address.startswith("tcp"):
        assert f"the scheme {address.split('://')[0]}:// is not supported" in text


@pytest.mark.parametrize(
    "address, expected",
    [
        ("tcp://10.0.0.5:8786", "tcp://10.0.0.5:8786"),
        ("10.0.0.5:8786", "tcp://10.0.0.5:8786"),
        (" TCP://node-1.cluster:8786 ", "tcp://node-1.cluster:8786"),
        ("tcp://[::1]:8786", "tcp://[::1]:8786"),
    ],
)
def test_scheduler_tcp_addresses_are_accepted(address, expected):
    assert mc.check_scheduler_address(address) == expected


@pytest.mark.parametrize(
    "value", [-1, -1.0, 0, 0.0, float("nan"), float("inf"), -float("inf"), 3601, 1e300, True, "5", None, [5]]
)
def test_connect_timeout_is_refused_naming_the_option(value):
    with pytest.raises(mc.CampaignError) as e:
        mc.check_connect_timeout(value)
    assert one_line(e.value).startswith("--connect-timeout: got ")
    assert "finite number of seconds > 0" in str(e.value)


def test_connect_timeout_accepts_seconds():
    assert mc.check_connect_timeout(5) == 5.0 and mc.check_connect_timeout(0.25) == 0.25
    assert mc.check_connect_timeout(np.float32(3600.0)) == 3600.0


def test_run_campaign_map_runs_and_comparison_check_the_timeout(tmp_path):
    out = tmp_path / "c"
    with pytest.raises(mc.CampaignError, match="--connect-timeout"):
        mc.run_campaign(
            SCENARIO, 1, overrides=SHORT, workers=1, out=str(out), progress=False, connect_timeout_s=float("nan")
        )
    with pytest.raises(mc.CampaignError, match="--connect-timeout"):
        mc.map_runs(mc.resolve_scenario(SCENARIO, SHORT), [1], workers=1, connect_timeout_s=-1)
    plan = mc.comparison_plan([SCENARIO], overrides=SHORT)
    with pytest.raises(mc.CampaignError, match="--connect-timeout"):
        mc.run_comparison(plan, 1, workers=1, out=str(tmp_path / "cmp"), progress=False, connect_timeout_s=0)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--scheduler", "http://127.0.0.1:8786"], "--scheduler: got 'http://127.0.0.1:8786'; the scheme http://"),
        (["--connect-timeout", "nan"], "--connect-timeout: got nan"),
        (["--connect-timeout", "-1"], "--connect-timeout: got -1"),
        (["--connect-timeout", "inf"], "--connect-timeout: got inf"),
        (["--connect-timeout", "0"], "--connect-timeout: got 0"),
    ],
)
def test_cli_refuses_scheduler_scheme_and_timeout_with_exit_2(tmp_path, monkeypatch, capsys, args, needle):
    monkeypatch.chdir(tmp_path)
    for command in (["montecarlo", SCENARIO], ["compare", SCENARIO]):
        assert cli_main(command + ["--runs", "1", "--out", "c"] + args) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0], lines
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------------------
# 3: every network wait has a deadline
# ----------------------------------------------------------------------------------------
class _QuietHandler(http.server.BaseHTTPRequestHandler):
    def log_message(self, *args):  # no lines on stderr
        pass


@pytest.fixture(scope="module")
def hostile_servers():
    """On 127.0.0.1, ephemeral ports, daemon threads: a plain HTTP server, a TCP server that
    accepts and never answers, and a port where nothing listens."""
    http_server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _QuietHandler)
    http_server.daemon_threads = True
    threading.Thread(target=http_server.serve_forever, daemon=True).start()
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(16)
    held = []

    def accept_forever():
        while True:
            try:
                conn, _ = silent.accept()
            except OSError:
                return
            held.append(conn)

    threading.Thread(target=accept_forever, daemon=True).start()
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    closed_port = probe.getsockname()[1]
    probe.close()
    yield {
        "http": f"tcp://127.0.0.1:{http_server.server_address[1]}",
        "silent": f"tcp://127.0.0.1:{silent.getsockname()[1]}",
        "closed": f"tcp://127.0.0.1:{closed_port}",
    }
    http_server.shutdown()
    http_server.server_close()
    silent.close()
    for conn in held:
        conn.close()


def _connect_fails(address: str, timeout_s: float = TIMEOUT_S) -> tuple[str, float]:
    """map_runs on the scheduler at ``address`` (the path of every campaign): its one-line
    CampaignError and how long it took."""
    scenario = mc.resolve_scenario(SCENARIO, SHORT)
    start = time.monotonic()
    with pytest.raises(mc.CampaignError) as e:
        mc.map_runs(scenario, [1], scheduler=address, connect_timeout_s=timeout_s)
    return one_line(e.value), time.monotonic() - start


@pytest.mark.parametrize("server", ["http", "silent"])
def test_a_program_that_is_not_a_dask_scheduler_fails_within_the_timeout(hostile_servers, server):
    address = hostile_servers[server]
    text, elapsed = _connect_fails(address)
    assert elapsed < UPPER_BOUND_S, elapsed
    assert elapsed >= TIMEOUT_S * 0.5  # it did wait for an answer, not give up at once
    assert text.startswith(f"--scheduler {address}: cannot connect within 2 s") and "Dask scheduler" in text, text


def test_the_client_start_has_a_deadline_too(hostile_servers, monkeypatch):
    """The second line of defence: without the probe, the Client's own start (connection,
    handshake) is cancelled at the deadline."""
    monkeypatch.setattr(dask_connection, "_probe_scheduler", lambda *args: None)
    text, elapsed = _connect_fails(hostile_servers["silent"])
    assert elapsed < UPPER_BOUND_S and "cannot connect within 2 s" in text, (elapsed, text)


def test_a_closed_port_fails_at_once(hostile_servers):
    text, elapsed = _connect_fails(hostile_servers["closed"], timeout_s=10.0)
    assert elapsed < 5.0, elapsed  # not the 10-s timeout: a refused connection is final
    assert "nothing listens there (connection refused)" in text


def test_no_probe_outlives_its_deadline_and_distributed_still_works(hostile_servers):
    """After the failures above, no probe thread is left and distributed's event loop still
    connects to a real scheduler (in this process): no broken state for later tests."""
    from distributed import LocalCluster

    _connect_fails(hostile_servers["silent"])
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and any(t.name == "drake-att-scheduler-probe" for t in threading.enumerate()):
        time.sleep(0.05)
    assert not any(t.name == "drake-att-scheduler-probe" for t in threading.enumerate())
    with LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=":0") as cluster:
        text, elapsed = _connect_fails(cluster.scheduler_address)
        assert "no workers connected within 2 s" in text and elapsed < UPPER_BOUND_S
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", dashboard_address=":0"
    ) as cluster:
        client = mc.connect_scheduler(cluster.scheduler_address, 10)
        try:
            workers = client.run(mc.worker_stats)
            assert len(workers) == 1
        finally:
            client.close()
        text, _ = _connect_fails(next(iter(workers)))  # a worker's address: Dask, but not the scheduler
        assert "is a Dask Worker, not a scheduler" in text, text


@pytest.mark.slow
def test_cli_against_an_http_server_exits_2_within_the_timeout_and_writes_nothing(tmp_path, hostile_servers):
    start = time.monotonic()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "drake_att.cli",
            "montecarlo",
            SCENARIO,
            "--runs",
            "2",
            "--scheduler",
            hostile_servers["http"],
            "--connect-timeout",
            "2",
            "--out",
            "c",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=ENV,
        timeout=120,
        check=False,
    )
    elapsed = time.monotonic() - start
    assert r.returncode == 2, r.stderr[-2000:]
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith(f"drake-att montecarlo: --scheduler {hostile_servers['http']}: cannot connect"), last
    assert elapsed < 60, elapsed  # the interpreter and pydrake start-up included
    assert not (tmp_path / "c").exists()


# ----------------------------------------------------------------------------------------
# 4: a failed start leaves no campaign folder behind
# ----------------------------------------------------------------------------------------
def test_unreachable_scheduler_creates_nothing_and_the_next_try_is_the_same(tmp_path, hostile_servers):
    out = tmp_path / "deep" / "er" / "c"
    (tmp_path / "empty").mkdir()
    for target in (out, tmp_path / "empty"):
        for _ in range(2):  # the second try fails the same way, not with "holds a campaign already"
            with pytest.raises(mc.CampaignError, match="cannot connect") as e:
                mc.run_campaign(
                    SCENARIO,
                    2,
                    overrides=SHORT,
                    scheduler=hostile_servers["closed"],
                    out=str(target),
                    progress=False,
                    connect_timeout_s=TIMEOUT_S,
                )
            one_line(e.value)
    assert sorted(os.listdir(tmp_path)) == ["empty"] and os.listdir(tmp_path / "empty") == []
    plan = mc.comparison_plan([SCENARIO], overrides=SHORT)
    with pytest.raises(mc.CampaignError, match="cannot connect"):
        mc.run_comparison(
            plan,
            1,
            scheduler=hostile_servers["closed"],
            out=str(tmp_path / "cmp"),
            progress=False,
            connect_timeout_s=TIMEOUT_S,
        )
    assert sorted(os.listdir(tmp_path)) == ["empty"]


def _fake_map_runs(saved: int, error: BaseException):
    """A map_runs that delivers ``saved`` results and then fails like a cluster or Ctrl-C."""

    def fake(scenario, jobs, record, *, on_result=None, **kwargs):
        for i, seed in enumerate(jobs[:saved]):
            on_result(i, (seed, None), {"x": np.arange(3.0)})
        raise error

    return fake


@pytest.mark.parametrize("error", [KeyboardInterrupt(), RuntimeError("a worker died")])
def test_a_start_that_fails_before_its_first_run_takes_back_what_it_created(tmp_path, monkeypatch, error):
    keep = tmp_path / "existing"
    keep.mkdir()
    monkeypatch.setattr(campaign, "map_runs", _fake_map_runs(0, error))  # the runner run_campaign calls
    for out in (tmp_path / "new" / "c", keep):
        with pytest.raises(type(error)):
            mc.run_campaign(SCENARIO, 2, overrides=SHORT, workers=1, out=str(out), progress=False)
    assert sorted(os.listdir(tmp_path)) == ["existing"] and os.listdir(keep) == []  # the folder that was there stays
    # ...but a campaign that saved a run keeps everything (it resumes)
    monkeypatch.setattr(campaign, "map_runs", _fake_map_runs(1, error))
    with pytest.raises(type(error)):
        mc.run_campaign(
            SCENARIO, 2, overrides=SHORT, workers=1, out=str(keep), progress=False, record=mc.metrics_record
        )
    assert sorted(os.listdir(keep)) == ["campaign.json", "config.yaml", "runs"]
    assert os.listdir(keep / "runs") == ["seed_1.npz"]


def test_campaign_json_names_the_library_records_by_their_public_module():
    """campaign.json's ``record`` is what a resume compares: the library's record functions
    keep the names ``drake_att.analysis.montecarlo:<name>`` whichever module defines them;
    any other function is named by its own module."""
    import functools

    assert mc.record_name(mc.default_record) == "drake_att.analysis.montecarlo:default_record"
    assert mc.record_name(functools.partial(mc.metrics_record)) == "drake_att.analysis.montecarlo:metrics_record()"
    assert mc.record_name(one_line) == f"{one_line.__module__}:one_line"


def test_an_empty_campaign_of_ours_does_not_block_a_new_start(tmp_path):
    """A campaign folder that saved no run (a start killed before its first run, or its runs
    removed) starts afresh without --resume, whatever configuration it had; a folder with a
    config.yaml that is not ours (no campaign.json) is still refused and left alone."""
    out = tmp_path / "c"
    mc.run_campaign(
        SCENARIO,
        1,
        overrides=["duration_s=50", "scoring.score_from_s=20"],
        workers=1,
        out=str(out),
        progress=False,
        report=False,
    )
    os.remove(out / "runs" / "seed_1.npz")
    result = mc.run_campaign(SCENARIO, 2, overrides=SHORT, workers=1, out=str(out), progress=False, report=False)
    assert (result.ran, result.reused) == (2, 0)
    assert "duration_s: 60.0" in (out / "config.yaml").read_text()
    with pytest.raises(mc.CampaignError) as e:  # now it holds runs: refused without --resume
        mc.run_campaign(SCENARIO, 2, overrides=SHORT, workers=1, out=str(out), progress=False, report=False)
    assert one_line(e.value) == (
        f"--out {out}: holds a campaign already (2 runs); add --resume to continue it, or name another folder"
    )
    theirs = tmp_path / "theirs"
    (theirs / "runs").mkdir(parents=True)
    (theirs / "config.yaml").write_text("my: own file\n")
    with pytest.raises(mc.CampaignError, match="holds a campaign already"):
        mc.run_campaign(SCENARIO, 1, overrides=SHORT, workers=1, out=str(theirs), progress=False)
    assert (theirs / "config.yaml").read_text() == "my: own file\n"


# ----------------------------------------------------------------------------------------
# 5: a hostile --resume
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def base_campaign(tmp_path_factory):
    """A finished 3-run campaign (no report) to copy and damage."""
    out = tmp_path_factory.mktemp("base") / "c"
    result = mc.run_campaign(SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), progress=False, report=False)
    assert result.ran == 3
    return out


def _copy(base, tmp_path):
    out = tmp_path / "c"
    shutil.copytree(base, out)
    return out


def _edit(path, change):
    record = mc.load_record(str(path))
    change(record)
    np.savez(str(path), **record)


def _set(key, value):
    return lambda r: r.__setitem__(key, value)


EDITS = {
    "extra_key": _set("surprise", np.zeros(3)),
    "missing_key": lambda r: r.pop("single__nees"),
    "missing_nis_triple": lambda r: [r.pop(f"single__nis0__{k}") for k in ("t", "value", "dof")],
    "string_array_for_floats": lambda r: r.__setitem__("single__dtheta", np.array(["a", "b"])),
    "scalar_for_vector": _set("single__t", np.array(1.0)),
    "vector_for_scalar": _set("single__window_n", np.arange(3)),
    "wrong_columns": lambda r: r.__setitem__("single__sigma", r["single__sigma"][:, :4]),
    "second_window_size": lambda r: r.__setitem__("single__window_ms_second", r["single__window_ms_second"][:2]),
    "fewer_samples": lambda r: r.__setitem__("single__dtheta", r["single__dtheta"][:-1]),
    "unsorted_times": lambda r: r.__setitem__("single__t", r["single__t"][::-1].copy()),
    "bytes_for_text": _set("single__bound_json", np.array(b"{}")),
    "bad_json": _set("metrics_json", np.array("{not json")),
    "another_seed": _set("seed", np.array(7)),
    "another_scenario": _set("scenario", np.array("other")),
    "estimators_differ": _set("estimators", np.array(["single", "ghost"])),
}


def test_a_record_of_each_nis_source_is_accepted(base_campaign):
    """'status' is a valid NIS source as much as 'innovations' (the check accepts exactly the
    three sources a record can carry); anything else is a problem naming the key."""
    from drake_att.analysis.montecarlo import resolve_scenario

    scenario = resolve_scenario(SCENARIO, SHORT)
    record = mc.load_record(str(base_campaign / "runs" / "seed_2.npz"))
    assert mc.default_record_problem(record, scenario, 2) is None
    record["single__nis_source"] = np.array("status")
    assert mc.default_record_problem(record, scenario, 2) is None
    record["single__nis_source"] = np.array("guess")
    assert "nis_source" in mc.default_record_problem(record, scenario, 2)


@pytest.mark.parametrize("case", sorted(EDITS))
def test_an_edited_run_file_is_reported_and_redone(base_campaign, tmp_path, case):
    out = _copy(base_campaign, tmp_path)
    _edit(out / "runs" / "seed_2.npz", EDITS[case])
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False, stream=err
    )
    lines = err.getvalue().splitlines()
    assert (
        len(lines) == 1
        and lines[0].startswith(f"drake-att: {out / 'runs' / 'seed_2.npz'}: not a record of this campaign (")
        and lines[0].endswith("its run is redone")
    ), lines
    assert (result.ran, result.reused, len(result.failed)) == (1, 2, 0)
    mc.default_summarize(result.records, result.scenario)  # no traceback
    again = mc.run_campaign(
        SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False, stream=err
    )
    assert (again.ran, again.reused) == (0, 3)  # the redone run was saved and is reused now


@pytest.mark.parametrize("content", [b"not a zip at all", b"PK\x03\x04 half a zip", "npy", "pickle", "bomb"])
def test_an_unreadable_run_file_is_reported_and_redone(base_campaign, tmp_path, monkeypatch, content):
    out = _copy(base_campaign, tmp_path)
    path = out / "runs" / "seed_3.npz"
    if content == "npy":
        with open(path, "wb") as f:
            np.save(f, np.arange(3.0))
    elif content == "pickle":
        np.savez(str(path), x=np.array([{"a": 1}], dtype=object))
    elif content == "bomb":  # a few KB that expand past the limit (lowered here: the real one is 1 GiB)
        monkeypatch.setattr(campaign_records, "MAX_RECORD_BYTES", 8 * 2**20)
        assert max(os.path.getsize(out / "runs" / f"seed_{s}.npz") for s in (1, 2)) < 2**20
        np.savez_compressed(str(path), x=np.zeros(2**21))
        assert os.path.getsize(path) < 2**16
    else:
        path.write_bytes(content)
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False, stream=err
    )
    lines = err.getvalue().splitlines()
    assert len(lines) == 1 and "seed_3.npz: unreadable (" in lines[0] and "redone" in lines[0], lines
    assert (result.ran, result.reused) == (1, 2)


def test_a_custom_record_is_checked_against_the_campaign_layout(tmp_path):
    out = tmp_path / "c"
    mc.run_campaign(SCENARIO, 2, overrides=SHORT, workers=1, out=str(out), progress=False, record=mc.metrics_record)
    with open(out / "campaign.json") as f:
        assert json.load(f)["record_layout"] == {"metrics_json": ["U", 0, []]}
    _edit(out / "runs" / "seed_2.npz", _set("metrics_json", np.array(["a", "b"])))
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO,
        2,
        overrides=SHORT,
        workers=1,
        out=str(out),
        resume=True,
        progress=False,
        record=mc.metrics_record,
        stream=err,
    )
    assert "seed_2.npz: not a record of this campaign ('metrics_json': got a str array of shape (n)" in err.getvalue()
    assert (result.ran, result.reused) == (1, 1)


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"{not json", "not JSON"),
        (b"[1, 2, 3]", "got a JSON list"),
        (b"\xff\xfe\x00\x01binary", "a binary file"),
        (b"\xc3\x28 latin", "not UTF-8 text"),
        ("huge", "larger than"),
    ],
)
def test_a_hostile_campaign_json_is_one_line_naming_the_file(base_campaign, tmp_path, content, needle):
    out = _copy(base_campaign, tmp_path)
    if content == "huge":
        content = b" " * (mc.MAX_SIDE_FILE_BYTES + 1)
    (out / "campaign.json").write_bytes(content)
    for resume in (True, False):
        with pytest.raises(mc.CampaignError) as e:
            mc.run_campaign(
                SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=resume, progress=False, report=False
            )
        assert one_line(e.value).startswith(f"{out / 'campaign.json'}: {needle}"), str(e.value)
    assert (out / "campaign.json").read_bytes() == content  # left as it was


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"\x00\x01\x02binary", "a binary file"),
        (b"name: \xff\xfe", "not UTF-8 text"),
        (b"- just\n- a list\n", "is not a scenario"),
        (b"hello: [unclosed\n", "is not a scenario"),
        (b"no_such_field: 1\n", "is not a scenario"),
    ],
)
def test_a_hostile_config_yaml_is_one_line_naming_the_file(base_campaign, tmp_path, content, needle):
    out = _copy(base_campaign, tmp_path)
    (out / "config.yaml").write_bytes(content)
    with pytest.raises(mc.CampaignError) as e:
        mc.run_campaign(
            SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False
        )
    text = one_line(e.value)
    assert str(out / "config.yaml") in text and needle in text, text
    assert (out / "config.yaml").read_bytes() == content


@pytest.mark.slow
def test_counts_add_up_after_resume(base_campaign, tmp_path):
    """ran + reused + failed == seeds, printed and stored: seed 3 failed before (not redone:
    it would fail again), seed 2's file is damaged (redone), seeds 4 and 5 are new."""
    out = _copy(base_campaign, tmp_path)
    os.remove(out / "runs" / "seed_3.npz")
    (out / "runs" / "seed_3.failed.txt").write_text("truth went non-finite at t = 12 s\n")
    (out / "runs" / "seed_2.npz").write_bytes(b"damaged")
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO, 5, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, stream=err
    )
    assert (result.ran, result.reused, len(result.failed), result.failed_reused) == (3, 1, 1, 1)
    assert result.ran + result.reused + len(result.failed) == len(result.seeds) == 5
    assert result.simulated == 3
    with open(out / "summary.json") as f:
        campaign = json.load(f)["campaign"]
    assert campaign["completed"] + len(campaign["failed"]) == campaign["runs"] == 5
    assert mc.check_campaign_manifest(str(out)) == []


def test_a_binary_failed_run_message_is_redone_not_a_traceback(base_campaign, tmp_path):
    out = _copy(base_campaign, tmp_path)
    os.remove(out / "runs" / "seed_1.npz")
    (out / "runs" / "seed_1.failed.txt").write_bytes(b"\xff\x00\x01")
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False, stream=err
    )
    assert "seed_1.failed.txt: unreadable" in err.getvalue() and (result.ran, result.reused) == (1, 2)


# ----------------------------------------------------------------------------------------
# 6: one line
# ----------------------------------------------------------------------------------------
def test_messages_naming_hostile_paths_stay_one_line(tmp_path):
    odd = tmp_path / "a\nb"
    odd.write_text("x")
    with pytest.raises(mc.CampaignError) as e:
        mc.run_campaign(SCENARIO, 1, overrides=SHORT, workers=1, out=str(odd), progress=False)
    assert "is an existing file" in one_line(e.value)
    with pytest.raises(mc.CampaignError) as e:
        mc.check_scheduler_address("tcp://a\nb:1")
    one_line(e.value)


def test_a_hostile_manifest_is_a_problem_not_a_traceback(base_campaign, tmp_path):
    out = _copy(base_campaign, tmp_path)
    (out / "manifest.json").write_bytes(b"\xff\xfe")
    assert "unreadable" in mc.check_campaign_manifest(str(out))[0]
    (out / "manifest.json").write_text("[]")
    assert "not a manifest" in mc.check_campaign_manifest(str(out))[0]


def test_a_run_file_that_is_a_folder_or_a_fifo_is_not_read(base_campaign, tmp_path):
    """A FIFO would block np.load forever: it is not read, its run is redone (the new file
    replaces it); a folder in a run file's place would make the save fail mid-campaign: the
    resume is refused first, naming it."""
    out = _copy(base_campaign, tmp_path)
    os.remove(out / "runs" / "seed_2.npz")
    os.mkfifo(out / "runs" / "seed_2.npz")
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False, stream=err
    )
    assert "seed_2.npz: unreadable (not a regular file)" in err.getvalue() and (result.ran, result.reused) == (1, 2)
    assert os.path.isfile(out / "runs" / "seed_2.npz")
    os.remove(out / "runs" / "seed_3.npz")
    os.mkdir(out / "runs" / "seed_3.npz")
    with pytest.raises(mc.CampaignError) as e:
        mc.run_campaign(SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False)
    assert "seed_3.npz is a folder, not a run file" in one_line(e.value)


@pytest.mark.parametrize(
    "entry, valid",
    [
        (["f", 0, []], True),
        (["f", 1, []], True),
        (["f", 2, [3]], True),
        (["f", 2, [0]], True),  # a zero-size dimension is a shape numpy can hold
        (["f", 32, [1] * 31], True),  # the most dimensions a stored layout may name
        (["f", 33, [1] * 32], False),
        (["f", -1, []], False),
        (["f", 2, [-1]], False),
        (["f", 2, []], False),  # rest must list every dimension but the first
        (["f", 1, [3]], False),
        (["f", True, []], False),
        (["f", 2, [True]], False),
        (["f", 2, [3.0]], False),
        ([1, 0, []], False),
        (["f", 0], False),
    ],
)
def test_a_stored_layout_entry_at_its_bounds(entry, valid):
    """A layout read back from campaign.json: dimensions 0..32, each size a non-negative int,
    one size per dimension after the first; anything else is dropped (None), not trusted."""
    layout = {"a": entry}
    assert (campaign_records._valid_layout(layout) == layout) is valid
    assert (campaign_records._valid_layout({"ok": ["f", 0, []], **layout}) is not None) is valid


PER_SAMPLE = ["t", "dtheta", "sigma", "nees", "second_err", "bound_sigma"]


@pytest.mark.parametrize("suffix", PER_SAMPLE)
def test_a_record_with_one_truncated_per_sample_array_is_redone(base_campaign, tmp_path, suffix):
    """Each per-sample array of a record (``(n, ...)`` in the record schema) cut by one sample
    in turn: the resume reports the file and redoes its run, and the summary of the result
    holds (a length check that skips one array lets the summary fail on every later resume)."""
    out = _copy(base_campaign, tmp_path)
    path = out / "runs" / "seed_2.npz"
    record = mc.load_record(str(path))
    key = f"single__{suffix}"
    assert key in record and len(record[key]) == len(record["single__t"]) > 1
    _edit(path, lambda r: r.__setitem__(key, r[key][:-1]))
    err = io.StringIO()
    result = mc.run_campaign(
        SCENARIO, 3, overrides=SHORT, workers=1, out=str(out), resume=True, progress=False, report=False, stream=err
    )
    assert "seed_2.npz: not a record of this campaign" in err.getvalue(), err.getvalue()
    assert (result.ran, result.reused, len(result.failed)) == (1, 2, 0)
    mc.default_summarize(result.records, result.scenario)


def test_a_record_problem_names_the_key_and_the_expected_shape(base_campaign):
    """What the resume prints about an edited record: the unexpected key by name (and how many
    more), the expected dtype and shape of a mis-shaped array (``(n)`` for a per-sample
    vector, ``(n, 3)`` for a per-sample 3-vector)."""
    scenario = mc.resolve_scenario(SCENARIO, SHORT)
    base = mc.load_record(str(base_campaign / "runs" / "seed_2.npz"))

    def problem(**changes):
        record = dict(base, **changes)
        return mc.default_record_problem(record, scenario, 2)

    one = problem(surprise=np.zeros(3))
    assert one == "unexpected key 'surprise'", one
    two = problem(surprise=np.zeros(3), another=np.zeros(1))
    assert two == "unexpected key 'another' (and 1 more)", two
    t2d = problem(single__t=np.zeros((3, 2)))
    assert "single__t" in t2d and t2d.endswith("expected a float array of shape (n)"), t2d
    text = problem(single__dtheta=np.array(["a", "b"]))
    assert "single__dtheta" in text and "expected a float array of shape (n, 3)" in text, text
    ints = problem(single__dtheta=np.zeros((4, 3), dtype=np.int64))
    assert "expected a float array of shape (n, 3)" in ints, ints
    floats = problem(single__window_n=np.array(2.5))
    assert "single__window_n" in floats and "expected a int scalar" in floats, floats
    number = problem(single__second_kind=np.array(3))
    assert "'single__second_kind'" in number and number.endswith("expected a str scalar"), number


def test_a_record_problem_quotes_foreign_names_on_one_short_line(base_campaign):
    """A record's own names inside the resume's message: the scenario it holds (and the
    campaign's), its estimator list and an unexpected key, each folded onto one line and cut
    at its stated length (80, 120, 80 characters) with "..." -- a hostile record cannot flood
    the terminal or break the one-line message."""
    scenario = mc.resolve_scenario(SCENARIO, SHORT)
    base = mc.load_record(str(base_campaign / "runs" / "seed_2.npz"))

    def problem(**changes):
        return mc.default_record_problem(dict(base, **changes), scenario, 2)

    def cut(text, limit):
        line = " ".join(str(text).split())
        return line if len(line) <= limit else line[:limit] + "..."

    other = problem(scenario=np.array("elsewhere"))
    assert other == f"it holds scenario 'elsewhere', not {scenario.name!r}", other
    long_name = "x\n" * 100
    flood = problem(scenario=np.array(long_name))
    assert flood == f"it holds scenario {cut(repr(long_name), 80)}, not {scenario.name!r}", flood
    names = [f"estimator_{i}" for i in range(40)]
    listed = problem(estimators=np.array(names))
    expect = f"it holds estimators {cut(names, 120)}, not {[e.name for e in scenario.estimators]}"
    assert listed == expect and "\n" not in listed, listed
    key = "k" * 200
    extra = problem(**{key: np.zeros(1)})
    assert extra == f"unexpected key {cut(repr(key), 80)}", extra


def _documented_run_campaign_snippet() -> str:
    """The ``run_campaign`` example of the README or the docs (the first Python block that calls it with workers)."""
    import re

    root = Path(__file__).resolve().parents[1]
    for path in [root / "README.md", *sorted((root / "docs").rglob("*.md"))]:
        for block in re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S):
            if "run_campaign(" in block and "workers=2" in block:
                return block
    raise AssertionError("no run_campaign example with workers=2 in README.md or docs/")


@pytest.mark.slow
def test_the_documented_run_campaign_snippet_runs_as_a_script_with_two_workers(tmp_path):
    """The documented snippet saved as a file and run: it completes its campaign with a
    2-worker local cluster. The same code without its ``__main__`` guard (each spawned worker
    re-imports the script) fails at once with one line that names the guard, and leaves no
    campaign folder that would block the corrected retry."""
    import textwrap

    snippet = _documented_run_campaign_snippet().replace("runs=20", "runs=3")
    assert 'if __name__ == "__main__":' in snippet, snippet
    (tmp_path / "guarded.py").write_text(snippet)
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run(
        [sys.executable, "guarded.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "out" / "mc" / "manifest.json").is_file()
    rmse = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(rmse) == 3 and all(0 < x < 0.1 for x in rmse), rmse

    head, _, body = snippet.partition('if __name__ == "__main__":')
    unguarded = head + textwrap.dedent(body.split("\n", 1)[1]).replace('"out/mc"', '"out/mc2"')
    (tmp_path / "unguarded.py").write_text(unguarded)
    failed = subprocess.run(
        [sys.executable, "unguarded.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env
    )
    last = failed.stderr.strip().splitlines()[-1]
    assert failed.returncode != 0
    assert last.startswith("drake_att.analysis.dask_connection.CampaignError: a local Dask cluster of 2 worker"), last
    assert 'under `if __name__ == "__main__":`' in last, last
    assert not (tmp_path / "out" / "mc2").exists()
