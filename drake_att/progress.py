"""Progress of a simulation for people: simulated time, wall time so far and an ETA.

On a terminal the updates rewrite one line (``\\r``); anywhere else (a log file, CI, a
captured stream) each update is its own line, so a log holds a readable history instead of
twenty updates glued together by carriage returns.
"""

from __future__ import annotations

import sys
import time


def format_duration(seconds: float) -> str:
    """``12.3 s``, ``4 min 05 s``, ``2 h 03 min``."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    s = round(seconds)
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Progress:
    """Prints one update per call of :meth:`update` for a run of ``total_s`` simulated seconds.

    Each update names ``label``, the simulated time, the fraction done, the elapsed wall time
    and the estimated wall time remaining (ETA, extrapolated linearly from the fraction done;
    the last update says ``done``). ``stream`` defaults to ``sys.stderr``; ``tty`` (default:
    ``stream.isatty()``) selects rewriting one line with ``\\r`` over newline-separated
    lines. ``start`` is the wall-clock origin (``clock()`` value; default: now), ``clock`` the
    wall clock (seconds)."""

    def __init__(
        self,
        total_s: float,
        label: str = "",
        stream=None,
        tty: bool | None = None,
        start: float | None = None,
        clock=time.perf_counter,
    ):
        self.total_s = float(total_s)
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        if tty is None:
            isatty = getattr(self.stream, "isatty", None)
            tty = bool(isatty()) if callable(isatty) else False
        self.tty = tty
        self.clock = clock
        self.start = clock() if start is None else start
        self._width = 0  # length of the line on screen (tty): a shorter update pads it out

    def line(self, t_s: float) -> str:
        """The text of the update at simulated time ``t_s`` (no line ending)."""
        elapsed = self.clock() - self.start
        frac = min(max(t_s / self.total_s, 0.0), 1.0) if self.total_s > 0 else 1.0
        if frac >= 1.0:
            eta = "done"
        elif frac > 0.0:
            eta = "ETA " + format_duration(elapsed * (1.0 - frac) / frac)
        else:
            eta = "ETA unknown"
        prefix = f"  [{self.label}] " if self.label else "  "
        return f"{prefix}t = {t_s:8.1f} / {self.total_s:.1f} s ({frac:4.0%})  {format_duration(elapsed)} wall  {eta}"

    def update(self, t_s: float) -> None:
        text = self.line(t_s)
        if self.tty:
            self.stream.write("\r" + text.ljust(self._width))
            self._width = max(self._width, len(text))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        """Ends the rewritten line (tty); nothing otherwise."""
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0
