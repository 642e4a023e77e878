"""Ctrl-C is never lost: a SIGINT whose KeyboardInterrupt the interpreter swallows (raised
inside a weakref callback or a finalizer, which Python reports as "Exception ignored" and
drops) still stops a campaign at its next checkpoint."""

from __future__ import annotations

import os
import signal
import weakref

import pytest

from drake_att import interrupts
from drake_att.analysis import campaign
from drake_att.cli import main as cli_main

SCENARIO = "cubesat_single_star_tracker"


@pytest.fixture(autouse=True)
def default_sigint_handler():
    """Python's own SIGINT handler during each test (a test runner may have set another, e.g.
    SIG_IGN in a worker process), restored after."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


SHORT = ["duration_s=60", "scoring.score_from_s=20"]


def _swallowed_sigint() -> None:
    """A SIGINT delivered while the garbage collector runs a weakref callback: its
    KeyboardInterrupt is raised inside the callback, where the interpreter drops it."""

    class Box:
        pass

    box = Box()
    ref = weakref.ref(box, lambda _ref: signal.raise_signal(signal.SIGINT))
    del box  # the callback runs here; the KeyboardInterrupt it raises goes to sys.unraisablehook
    assert ref() is None


def test_python_drops_a_keyboard_interrupt_raised_in_a_weakref_callback(monkeypatch):
    """The window itself: without the mark, nothing after the swallowed Ctrl-C knows of it."""
    dropped = []
    monkeypatch.setattr("sys.unraisablehook", lambda u: dropped.append(u.exc_type))
    _swallowed_sigint()  # no exception here
    assert dropped == [KeyboardInterrupt]
    interrupts.raise_if_interrupted()  # nothing remembered outside the block


def test_a_swallowed_ctrl_c_is_raised_again_at_the_next_checkpoint(monkeypatch):
    monkeypatch.setattr("sys.unraisablehook", lambda u: None)
    with interrupts.remembered():
        assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        _swallowed_sigint()
        with pytest.raises(KeyboardInterrupt):
            interrupts.raise_if_interrupted()
        interrupts.raise_if_interrupted()  # raised once, then cleared
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


def test_a_delivered_ctrl_c_leaves_no_mark_behind():
    """A Ctrl-C that reached the code as usual is not raised a second time later."""
    with pytest.raises(KeyboardInterrupt), interrupts.remembered():
        signal.raise_signal(signal.SIGINT)
    with interrupts.remembered():
        interrupts.raise_if_interrupted()


def test_another_sigint_handler_is_left_alone():
    """A handler that is not Python's default (a user's own, a worker's SIG_IGN) stays in place."""
    seen = []
    previous = signal.signal(signal.SIGINT, lambda s, f: seen.append(s))
    try:
        with interrupts.remembered():
            assert signal.getsignal(signal.SIGINT) is not interrupts._on_sigint
            os.kill(os.getpid(), signal.SIGINT)
            interrupts.raise_if_interrupted()
        assert seen == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)


def _record_swallowing_a_ctrl_c_on_seed(seed_to_interrupt: int):
    default_record = campaign.default_record

    def record(run):
        if run.seed == seed_to_interrupt:
            _swallowed_sigint()
        return default_record(run)

    return record


def test_a_campaign_stops_at_the_run_during_which_a_ctrl_c_was_swallowed(tmp_path, monkeypatch):
    """Seed 2 of 3 swallows the Ctrl-C: seed 1 stays saved, seed 2 is not kept, seed 3 never
    runs, and no manifest marks the folder complete."""
    monkeypatch.setattr("sys.unraisablehook", lambda u: None)
    out = tmp_path / "mc"
    with pytest.raises(KeyboardInterrupt):
        campaign.run_campaign(
            SCENARIO,
            3,
            overrides=SHORT,
            workers=1,
            out=str(out),
            progress=False,
            record=_record_swallowing_a_ctrl_c_on_seed(2),
        )
    assert sorted(os.listdir(out / "runs")) == ["seed_1.npz"]
    assert not (out / "manifest.json").exists()


def test_the_cli_exits_130_after_a_swallowed_ctrl_c(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.unraisablehook", lambda u: None)
    monkeypatch.setattr(campaign, "default_record", _record_swallowing_a_ctrl_c_on_seed(2))
    out = tmp_path / "mc"
    argv = ["montecarlo", SCENARIO, "--runs", "3", "--workers", "1", "--quiet", "--out", str(out)]
    code = cli_main(argv + [a for s in SHORT for a in ("--set", s)])
    err = capsys.readouterr().err
    assert code == 130, err
    assert "interrupted; 1 of 3 runs are saved" in err, err


def test_a_result_folder_is_not_put_in_place_after_a_swallowed_ctrl_c(tmp_path, monkeypatch):
    """A Ctrl-C swallowed while a result folder is written (figures: matplotlib's weakrefs):
    the previous folder stays as it was, no staging folder is left behind."""
    from drake_att import outputs

    monkeypatch.setattr("sys.unraisablehook", lambda u: None)
    target = tmp_path / "run"
    outputs.replace_folder(str(target), lambda d: [open(os.path.join(d, "a.txt"), "w").write("old") and "a.txt"])

    def write(d):
        with open(os.path.join(d, "a.txt"), "w") as f:
            f.write("new")
        _swallowed_sigint()
        return ["a.txt"]

    with pytest.raises(KeyboardInterrupt), interrupts.remembered():
        outputs.replace_folder(str(target), write)
    assert (target / "a.txt").read_text() == "old"
    assert sorted(os.listdir(tmp_path)) == ["run"]


@pytest.mark.parametrize("where", ["after the runs", "while the report is written"])
def test_a_ctrl_c_swallowed_after_the_runs_leaves_no_manifest(tmp_path, monkeypatch, where):
    """Swallowed after the last run was kept (gathering the result) or while the report is
    written: the campaign raises before ``manifest.json``, the mark of a complete campaign;
    the runs stay on disk for ``--resume``."""
    from drake_att.analysis import campaign_report

    monkeypatch.setattr("sys.unraisablehook", lambda u: None)
    if where == "after the runs":
        result = campaign._CampaignRuns.result
        monkeypatch.setattr(campaign._CampaignRuns, "result", lambda self: (_swallowed_sigint(), result(self))[1])
    else:
        write = campaign_report.write_campaign_report
        monkeypatch.setattr(
            campaign_report, "write_campaign_report", lambda *a, **k: (write(*a, **k), _swallowed_sigint())[0]
        )
    out = tmp_path / "mc"
    with pytest.raises(KeyboardInterrupt):
        campaign.run_campaign(SCENARIO, 2, overrides=SHORT, workers=1, out=str(out), progress=False)
    assert sorted(os.listdir(out / "runs")) == ["seed_1.npz", "seed_2.npz"]
    assert not (out / "manifest.json").exists()
    assert (out / "report.html").exists() == (where == "while the report is written")
