"""Long time series drawn at the resolution of their figure.

A 5000-s run logged at 10 Hz is 50,000 samples per line; an axes a few hundred pixels wide shows
at most a few points per pixel column. Rasterizing every segment is most of a report's CPU
(Agg draws each one). :func:`line_points` keeps, for every time bucket narrower than half a
pixel, the samples that decide what the column shows: the first, the smallest, the largest and
the last (M4 aggregation: U. Jugel et al., "M4: a visualization-oriented time series data
aggregation", PVLDB 7(10), 2014). Where the buckets split the axes' columns evenly, each
column's drawn line spans exactly the values of the full series'; otherwise a bucket that
straddles a column edge may lend its extreme to the neighbouring column, half a pixel away at
most. Gaps (NaN) stay gaps, with the finite samples on both sides of each kept (written here:
``tsdownsample``'s NaN-aware M4 keeps a NaN instead of a bucket's finite extremes).
"""

from __future__ import annotations

import math

import numpy as np

#: Time buckets per pixel of the width given: buckets at most half a pixel wide (callers pass an
#: upper bound of the axes' width, so the real columns hold two buckets or more).
BUCKETS_PER_PIXEL = 2


def line_points(t, y, width_px: float) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` reduced for a line drawn ``width_px`` pixels wide.

    Args:
        t: sample times, finite and nondecreasing (n,).
        y: values (n,); NaN (or inf, which matplotlib does not draw either) marks a gap.
        width_px: the width of the axes the line is drawn in (pixels, > 0).

    Returns:
        The samples kept, in time order: the first, minimum, maximum and last of each of
        ``BUCKETS_PER_PIXEL * ceil(width_px)`` equal time buckets over ``[t[0], t[-1]]`` (the
        extremes over the bucket's finite values), and the samples on both sides of every
        change between finite and not; ``t`` and ``y`` themselves when they have no more than
        four samples per bucket.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if not (math.isfinite(width_px) and width_px > 0):
        raise ValueError(f"width_px: got {width_px!r}; must be a finite number of pixels > 0")
    if t.shape != y.shape or t.ndim != 1:
        raise ValueError(f"t, y: got shapes {t.shape} and {y.shape}; need two equal 1-D shapes")
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0)):
        raise ValueError("t: got times that are not finite and nondecreasing; need sample times in order")
    buckets = BUCKETS_PER_PIXEL * math.ceil(width_px)
    span = t[-1] - t[0] if t.size else 0.0
    if t.size <= 4 * buckets or not span > 0:
        return t, y
    bucket = np.minimum(((t - t[0]) * (buckets / span)).astype(np.int64), buckets - 1)
    keep = np.zeros(t.size, dtype=bool)
    starts = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
    keep[starts] = True  # each bucket's first sample
    keep[np.r_[starts[1:] - 1, t.size - 1]] = True  # and its last
    finite = np.isfinite(y)
    for fill, extreme in ((np.inf, np.minimum), (-np.inf, np.maximum)):
        values = np.where(finite, y, fill)
        per_bucket = np.repeat(extreme.reduceat(values, starts), np.diff(np.r_[starts, t.size]))
        hits = np.flatnonzero((values == per_bucket) & finite)
        keep[hits[np.r_[True, bucket[hits][1:] != bucket[hits][:-1]]]] = True  # one per bucket
    gap_edges = finite != np.r_[finite[1:], finite[-1]]  # the last sample before a change ...
    keep[gap_edges] = True
    keep[1:][gap_edges[:-1]] = True  # ... and the first after it
    return t[keep], y[keep]


#: The resolution a figure handed to users is reduced for (they may save it at any dpi).
PRINT_DPI = 300.0


def axes_width_px(fig, columns: int, dpi: float) -> float:
    """An upper bound on the width in pixels of one of ``columns`` side-by-side axes filling
    ``fig`` when it is rendered at ``dpi`` (its width over the columns)."""
    return fig.get_figwidth() * dpi / columns


__all__ = ["BUCKETS_PER_PIXEL", "PRINT_DPI", "axes_width_px", "line_points"]
