"""Monte Carlo campaigns: Dask equals serial bit for bit, an interrupted campaign
resumes to exactly N runs, bad input exits 2 naming the flag, report.html renders in a real
headless browser without console messages, and the comparison matrix runs every listed
estimator on every listed scenario."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from drake_att.analysis import campaign_report
from drake_att.analysis import montecarlo as mc
from drake_att.cli import main as cli_main
from drake_att.scenarios.config import dump_scenario, load_scenario

SCENARIO = "cubesat_single_star_tracker"
SHORT = ["duration_s=60", "scoring.score_from_s=20"]
ENV = dict(os.environ, MPLBACKEND="Agg")


def _comparable(record: dict) -> dict:
    """A record without its one non-deterministic number (the run's wall time)."""
    out = dict(record)
    metrics = json.loads(str(out.pop("metrics_json")))
    metrics.pop("wall_time_s")
    out["metrics"] = metrics
    return out


def _without_commands(summary: dict) -> dict:
    """A summary without the worst runs' re-run commands (they name the campaign's folder)."""
    out = json.loads(json.dumps(summary))
    for e in out["estimators"].values():
        for w in e["worst_runs"]:
            w.pop("command")
    return out


def assert_records_identical(a: list, b: list) -> None:
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        ra, rb = _comparable(ra), _comparable(rb)
        assert sorted(ra) == sorted(rb)
        assert ra.pop("metrics") == rb.pop("metrics")
        for key in ra:
            x, y = np.asarray(ra[key]), np.asarray(rb[key])
            assert x.dtype == y.dtype and x.shape == y.shape, key
            if x.dtype.kind in "fc":
                # bit for bit: the same bytes (NaN where NaN), not merely close
                assert x.tobytes() == y.tobytes(), key
            else:
                np.testing.assert_array_equal(x, y, err_msg=key)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A finished 4-run serial campaign with its report (shared by the report tests)."""
    out = str(tmp_path_factory.mktemp("campaign") / "c")
    result = mc.run_campaign(SCENARIO, 4, overrides=SHORT, workers=1, out=out, progress=False)
    return result


@pytest.mark.slow
def test_dask_local_cluster_equals_serial_bit_for_bit(tmp_path, campaign):
    """The same seeds on a 2-worker Dask LocalCluster (separate processes, each building the
    diagram once) give records identical to the serial in-process run, in memory and on disk."""
    from distributed import Client, LocalCluster

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        result = mc.run_campaign(
            SCENARIO, 4, overrides=SHORT, scheduler=client, out=str(tmp_path / "dask"), progress=False, report=False
        )
        stats = client.run(mc.worker_stats)
    assert_records_identical(result.records, campaign.records)
    on_disk = [mc.load_record(os.path.join(tmp_path, "dask", "runs", f"seed_{s}.npz")) for s in result.seeds]
    assert_records_identical(on_disk, campaign.records)
    # The runs happened in the workers, not here; each worker built the diagram once for all its seeds.
    assert sum(s["runs"] for s in stats.values()) == 4
    assert {s["pid"] for s in stats.values()}.isdisjoint({os.getpid()})
    assert all(s["diagrams_built"] <= 1 for s in stats.values())


def test_interrupted_campaign_resumes_to_exactly_n_runs(tmp_path, campaign):
    """Half a campaign, a half-written temporary file and a damaged run file (a crash), then
    --resume: exactly N runs, the same records and summary as the uninterrupted campaign;
    finished runs are read, not re-run."""
    out = str(tmp_path / "c")
    first = mc.run_campaign(SCENARIO, 2, overrides=SHORT, workers=1, out=out, progress=False, report=False)
    assert first.ran == 2 and sorted(os.listdir(os.path.join(out, "runs"))) == ["seed_1.npz", "seed_2.npz"]
    with open(os.path.join(out, "runs", ".seed_3.npz.tmp-12345"), "wb") as f:
        f.write(b"PK\x03\x04 half a zip")
    with open(os.path.join(out, "runs", "seed_2.npz"), "r+b") as f:
        f.truncate(100)
    with pytest.raises(mc.CampaignError, match="--resume"):
        mc.run_campaign(SCENARIO, 4, overrides=SHORT, workers=1, out=out, progress=False)
    with pytest.raises(mc.CampaignError, match="duration_s"):
        mc.run_campaign(
            SCENARIO,
            4,
            overrides=["duration_s=50", "scoring.score_from_s=20"],
            workers=1,
            out=out,
            resume=True,
            progress=False,
        )
    resumed = mc.run_campaign(SCENARIO, 4, overrides=SHORT, workers=1, out=out, resume=True, progress=False)
    assert (resumed.reused, resumed.ran) == (1, 3)  # seed 1 kept; the damaged seed 2 and seeds 3, 4 run
    assert sorted(os.listdir(os.path.join(out, "runs"))) == [f"seed_{s}.npz" for s in (1, 2, 3, 4)]
    assert_records_identical(resumed.records, campaign.records)
    assert _without_commands(resumed.summary) == _without_commands(campaign.summary)
    assert mc.check_campaign_manifest(out) == []
    again = mc.run_campaign(SCENARIO, 4, overrides=SHORT, workers=1, out=out, resume=True, progress=False, report=False)
    assert (again.reused, again.ran) == (4, 0)


@pytest.mark.slow
def test_ctrl_c_keeps_finished_runs_and_resume_completes(tmp_path):
    """SIGINT to the whole process group (as a terminal's Ctrl-C) of a Dask campaign: exit
    130, a message, no traceback, no worker left behind, only complete run files; the same
    command with --resume ends with exactly N runs."""
    n = 6
    args = [
        sys.executable,
        "-m",
        "drake_att.cli",
        "montecarlo",
        SCENARIO,
        "--runs",
        str(n),
        "--set",
        "duration_s=120",
        "--set",
        "scoring.score_from_s=20",
        "--out",
        "c",
        # one run per task, so that runs arrive one by one and the Ctrl-C falls between them (in
        # batches, each worker's runs arrive together: 6 runs on 2 workers can all be done first)
        "--batch-size",
        "1",
    ]
    proc = subprocess.Popen(
        args + ["--workers", "2"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # noqa: PLW1509
    runs = tmp_path / "c" / "runs"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if runs.is_dir() and len([f for f in os.listdir(runs) if f.endswith(".npz")]) >= 2:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    try:
        assert proc.returncode == 130, err[-3000:]
        assert "Traceback" not in err + out and "interrupted" in err, err[-3000:]
        done = sorted(f for f in os.listdir(runs))
        assert 2 <= len(done) < n and all(re.fullmatch(r"seed_\d+\.npz", f) for f in done), done
        for f in done:
            mc.load_record(os.path.join(runs, f))  # every file there is complete
        for _ in range(100):  # the workers went with the campaign
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            pytest.fail("worker processes outlived the interrupted campaign")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    r = subprocess.run(
        args + ["--workers", "1", "--resume", "--quiet"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=ENV,
        timeout=300,
        check=False,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"{n - len(done)} runs simulated, {len(done)} found complete" in r.stdout
    assert sorted(os.listdir(runs)) == sorted(f"seed_{s}.npz" for s in range(1, n + 1))
    assert mc.check_campaign_manifest(str(tmp_path / "c")) == []


def _write_campaign_folder(path, overrides):
    from drake_att.analysis.montecarlo import CONFIG_HEADER
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load

    os.makedirs(path / "runs")
    (path / "config.yaml").write_text(CONFIG_HEADER + dump_scenario(apply_overrides(load(SCENARIO), overrides)))
    (path / "runs" / "seed_1.failed.txt").write_text("went non-finite\n")  # one saved run: not an empty campaign


BAD = {
    # id: (CLI args, text the message must contain)
    "runs_zero": (["montecarlo", SCENARIO, "--runs", "0"], "--runs"),
    "negative_first_seed": (["montecarlo", SCENARIO, "--runs", "2", "--first-seed=-1"], "--first-seed"),
    "seeds_past_2_to_the_32": (["montecarlo", SCENARIO, "--runs", "2", "--first-seed", str(2**32 - 1)], "--runs"),
    "workers_zero": (["montecarlo", SCENARIO, "--runs", "2", "--workers", "0"], "--workers"),
    "unknown_scenario": (["montecarlo", "no_such_scenario", "--runs", "2"], "no_such_scenario"),
    "bad_set_value": (["montecarlo", SCENARIO, "--runs", "2", "--set", "duration_s=five"], "duration_s"),
    "unknown_estimator": (["montecarlo", SCENARIO, "--runs", "2", "--estimators", "nope"], "--estimators"),
    "malformed_scheduler": (["montecarlo", SCENARIO, "--runs", "2", "--scheduler", "not an address"], "--scheduler"),
    "workers_with_scheduler": (
        ["montecarlo", SCENARIO, "--runs", "2", "--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"],
        "--workers",
    ),
    "out_is_a_file": (["montecarlo", SCENARIO, "--runs", "2", "--out", "taken"], "--out taken"),
    "out_has_other_files": (["montecarlo", SCENARIO, "--runs", "2", "--out", "other"], "--out other"),
    "existing_campaign_without_resume": (
        [
            "montecarlo",
            SCENARIO,
            "--runs",
            "2",
            "--set",
            "duration_s=60",
            "--set",
            "scoring.score_from_s=20",
            "--out",
            "same",
        ],
        "--resume",
    ),
    "resume_another_config": (
        [
            "montecarlo",
            SCENARIO,
            "--runs",
            "2",
            "--set",
            "duration_s=70",
            "--set",
            "scoring.score_from_s=20",
            "--out",
            "same",
            "--resume",
        ],
        "duration_s: 60.0",
    ),
    "compare_runs_zero": (["compare", SCENARIO, "--runs", "0"], "--runs"),
    "compare_estimator_nowhere": (["compare", SCENARIO, "--runs", "2", "--estimators", "nope"], "--estimators"),
    "compare_source_lacks_it": (
        ["compare", SCENARIO, "--runs", "2", "--estimators", f"{SCENARIO}:joint"],
        f"{SCENARIO}:joint",
    ),
    "compare_same_scenario_twice": (["compare", SCENARIO, SCENARIO, "--runs", "2"], SCENARIO),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_campaign_input_exits_2_naming_it(tmp_path, monkeypatch, capsys, case):
    args, needle = BAD[case]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "taken").write_text("x")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    _write_campaign_folder(tmp_path / "same", SHORT)
    assert cli_main(args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines and lines[-1].startswith("drake-att") and needle in lines[-1], (case, lines)
    assert not (tmp_path / "out").exists()


def test_unreachable_scheduler_exits_2_without_traceback(tmp_path):
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
            "tcp://127.0.0.1:9",
            "--connect-timeout",
            "1",
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
    assert r.returncode == 2, r.stderr[-2000:]
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("drake-att montecarlo: --scheduler tcp://127.0.0.1:9: cannot connect"), last


def test_campaign_folder_holds_the_report_files(campaign):
    out = campaign.out
    names = set(os.listdir(out))
    assert {
        "config.yaml",
        "campaign.json",
        "summary.json",
        "report.html",
        "manifest.json",
        "runs",
        "rmse_vs_bound.png",
        "single_errors.png",
        "single_consistency.png",
    } <= names
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)  # strict JSON
    st = summary["statistics"]["estimators"]["single"]
    assert summary["campaign"]["completed"] == 4 and st["n_runs"] == 4
    assert st["bound"]["defined"] and st["anees"] is not None and "st1" in st["nis"]
    assert load_scenario(filename=os.path.join(out, "config.yaml")).duration_s == 60.0
    assert st["worst_runs"][0]["command"].startswith(f"drake-att run {os.path.join(out, 'config.yaml')} --seed ")
    assert mc.check_campaign_manifest(out) == []
    text = campaign_report.format_campaign_table(campaign)
    assert "single" in text and "RMSE" in text


def _self_contained(page: str) -> list[str]:
    """Addresses a page would fetch (src/href that are not data: URIs or in-page anchors)."""
    refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']*)["']""", page, flags=re.IGNORECASE)
    refs += re.findall(r"url\(([^)]*)\)", page)
    return [r for r in refs if not r.startswith("data:") and not r.startswith("#")]


CHROMIUM = campaign_report.find_chromium()
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no Chromium on PATH (Debian: apt-get install chromium; `make test` installs it as root)"
)


def test_report_is_self_contained_with_valid_embedded_pngs(campaign):
    import base64

    with open(os.path.join(campaign.out, "report.html")) as f:
        page = f.read()
    assert _self_contained(page) == []
    assert "<script" not in page.lower()
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    pngs = [f for f in os.listdir(campaign.out) if f.endswith(".png")]
    assert len(images) == len(pngs) == 3
    for data in images:
        assert base64.b64decode(data).startswith(b"\x89PNG\r\n\x1a\n")


@needs_chromium
def test_report_renders_in_headless_chromium_without_console_messages(campaign, tmp_path):
    """report.html in a real headless browser: screenshot taken, no console message; the
    same check catches a page with a script error (the detector works)."""
    png = str(tmp_path / "report.png")
    console = campaign_report.render_in_browser(os.path.join(campaign.out, "report.html"), png)
    assert console == []
    from PIL import Image

    with Image.open(png) as im:
        assert im.size == (1400, 3000)
        gray = np.asarray(im.convert("L"), dtype=float)
    assert gray.std() > 20  # text, tables and figures, not a blank page
    assert (gray < 128).mean() > 0.02
    with open(os.path.join(campaign.out, "report.html")) as f:
        page = f.read()
    broken = tmp_path / "broken.html"
    broken.write_text(page.replace("</body>", "<script>undefinedFunction();</script></body>"))
    with pytest.raises(RuntimeError, match="console message.*undefinedFunction"):
        campaign_report.screenshot(str(broken), str(tmp_path / "broken.png"))


@pytest.mark.slow
def test_compare_runs_every_listed_estimator_on_every_listed_scenario(tmp_path, capsys):
    """Two scenarios sharing the plant and sensors; `single` in both, `joint` transplanted from
    the dual-tracker scenario (it cannot run on one tracker: the cell says why). The shared
    sensors give `single` the same noise, hence the same numbers, in both scenarios."""
    out = str(tmp_path / "cmp")
    code = cli_main(
        [
            "compare",
            SCENARIO,
            "cubesat_dual_star_tracker",
            "--estimators",
            "single,cubesat_dual_star_tracker:joint",
            "--runs",
            "2",
            "--workers",
            "1",
            "--quiet",
            "--set",
            "duration_s=60",
            "--set",
            "scoring.score_from_s=20",
            "--out",
            out,
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err[-3000:]
    with open(os.path.join(out, "comparison.json")) as f:
        cmp = json.load(f)
    cells = {(c["scenario"], c["estimator"]): c for c in cmp["cells"]}
    assert set(cells) == {(s, e) for s in (SCENARIO, "cubesat_dual_star_tracker") for e in ("single", "joint")}
    a, b = cells[(SCENARIO, "single")], cells[("cubesat_dual_star_tracker", "single")]
    assert a["ran"] and b["ran"] and a["attitude_rmse_deg"] == b["attitude_rmse_deg"]
    assert not cells[(SCENARIO, "joint")]["ran"] and "st2" in cells[(SCENARIO, "joint")]["why"]
    joint = cells[("cubesat_dual_star_tracker", "joint")]
    assert joint["ran"] and joint["ratio_to_bound_total"] is not None and joint["ms_per_step"] is not None
    assert joint["attitude_rmse_total_deg"] < b["attitude_rmse_total_deg"]  # two trackers beat one
    for name in ("comparison.md", "comparison.png", "comparison.html"):
        assert os.path.isfile(os.path.join(out, name))
    with open(os.path.join(out, "comparison.html")) as f:
        assert _self_contained(f.read()) == []
    assert "joint" in captured.out and "st2" in captured.out
