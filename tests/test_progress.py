"""Simulation progress for people (drake_att.progress): newline-separated updates
with the elapsed wall time and an ETA when the stream is not a terminal (logs, CI), one
rewritten line on a terminal."""

import io
import itertools
import re

from drake_att.progress import Progress, format_duration


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class TtyStream(io.StringIO):
    def isatty(self):
        return True


def test_format_duration():
    assert format_duration(0.0) == "0.0 s"
    assert format_duration(12.34) == "12.3 s"
    assert format_duration(65.0) == "1 min 05 s"
    assert format_duration(3599.4) == "59 min 59 s"
    assert format_duration(7380.0) == "2 h 03 min"


def test_not_a_terminal_gives_one_line_per_update_with_elapsed_time_and_eta():
    clock, out = FakeClock(), io.StringIO()
    bar = Progress(200.0, "demo seed 3", stream=out, clock=clock)
    assert bar.tty is False  # StringIO is not a terminal
    for t, wall in ((50.0, 10.0), (100.0, 20.0), (200.0, 45.0)):
        clock.now = 100.0 + wall
        bar.update(t)
    bar.close()
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert len(lines) == 3 and text.endswith("\n")
    # a quarter done after 10 s: 30 s to go; half after 20 s: 20 s to go; then done
    assert re.fullmatch(r"  \[demo seed 3\] t = +50\.0 / 200\.0 s \( 25%\)  10\.0 s wall  ETA 30\.0 s", lines[0])
    assert lines[1].endswith("( 50%)  20.0 s wall  ETA 20.0 s"), lines[1]
    assert lines[2].endswith("(100%)  45.0 s wall  done"), lines[2]


def test_terminal_rewrites_one_line_and_ends_it_on_close():
    clock, out = FakeClock(), TtyStream()
    bar = Progress(10.0, "x", stream=out, clock=clock)
    assert bar.tty is True
    for k in range(1, 11):
        clock.now += 1.0
        bar.update(float(k))
    bar.close()
    text = out.getvalue()
    assert text.count("\r") == 10 and text.count("\n") == 1 and text.endswith("\n")
    assert text.rstrip().endswith("done")  # the last update, padded over the longer one before it
    shown = [s for s in text.rstrip("\n").split("\r") if s]
    assert len(shown) == 10
    # a shorter update is padded with spaces over the longer one before it (no stale tail)
    assert all(len(b) >= len(a) for a, b in itertools.pairwise(shown))


def test_cli_progress_in_a_captured_stream_is_newline_separated_with_an_eta(drake_att_cli, tmp_path):
    """``drake-att run`` with stderr captured (not a terminal, as in a log or CI): several
    progress lines, each with the wall time so far and an ETA (the last one says done), and
    no carriage return."""
    r = drake_att_cli(
        "run",
        "cubesat_single_star_tracker",
        "--set",
        "duration_s=50",
        "--set",
        "scoring.score_from_s=10",
        "--no-figures",
        "--out",
        str(tmp_path / "out"),
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "\r" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "[cubesat_single_star_tracker seed" in ln]
    assert len(lines) == 20, r.stderr  # the 20 chunks of the simulation, one line each
    pattern = (
        r"  \[cubesat_single_star_tracker seed \d+\] t = +([\d.]+) / 50\.0 s \( *\d+%\)  [\d.]+ s wall  (ETA .+|done)"
    )
    times = []
    for ln in lines:
        m = re.fullmatch(pattern, ln)
        assert m, ln
        times.append(float(m.group(1)))
    assert times == [2.5 * k for k in range(1, 21)]
    assert all("ETA " in ln for ln in lines[:-1]) and lines[-1].endswith("done")
