"""Long lines reduced for drawing (drake_att.analysis.plot_lines): every pixel column keeps the
extremes of its samples, gaps stay gaps, short lines are untouched, and the drawn ink is the
same column by column. Expected values come from the definition (columns of equal time width),
not from the library."""

import numpy as np
import pytest

from drake_att.analysis.plot_lines import BUCKETS_PER_PIXEL, line_points


def _columns(t, t0, t1, width):
    """Pixel column of each time: ``width`` equal columns over ``[t0, t1]``."""
    return np.minimum(((t - t0) / (t1 - t0) * width).astype(int), width - 1)


def _walk(n, seed):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 5000.0, n))  # no sample on a column edge
    return t, np.cumsum(rng.standard_normal(n)) + 5.0 * rng.standard_normal(n)


@pytest.mark.parametrize("width", [37, 100, 431.5])
def test_every_column_keeps_its_samples_extremes_and_the_line_its_ends(width):
    t, y = _walk(40_000, seed=int(width))
    tr, yr = line_points(t, y, width)
    columns = int(np.ceil(width))
    assert len(tr) <= 4 * BUCKETS_PER_PIXEL * columns < len(t)
    assert np.all(np.diff(tr) >= 0)
    index = np.searchsorted(t, tr)  # every kept point is one of the samples, in order
    np.testing.assert_array_equal(t[index], tr)
    np.testing.assert_array_equal(y[index], yr)
    assert (tr[0], yr[0], tr[-1], yr[-1]) == (t[0], y[0], t[-1], y[-1])
    full, kept = _columns(t, t[0], t[-1], columns), _columns(tr, t[0], t[-1], columns)
    for c in range(columns):
        column = y[full == c]
        assert column.max() == yr[kept == c].max() and column.min() == yr[kept == c].min(), c


def test_a_gap_stays_a_gap_and_only_where_it_was():
    t, y = _walk(30_000, seed=4)
    y[10_000:10_400] = np.nan  # ~67 s: wider than a column at 100 px over 5000 s
    tr, yr = line_points(t, y, 100)
    full, kept = _columns(t, t[0], t[-1], 100), _columns(tr, t[0], t[-1], 100)
    for c in range(100):
        assert np.isnan(y[full == c]).any() == np.isnan(yr[kept == c]).any(), c
        finite = y[full == c][np.isfinite(y[full == c])]
        if finite.size:  # a column partly in the gap keeps its finite extremes
            assert np.nanmax(yr[kept == c]) == finite.max() and np.nanmin(yr[kept == c]) == finite.min()


def test_a_line_short_enough_is_drawn_as_it_is():
    t, y = _walk(4 * BUCKETS_PER_PIXEL * 50, seed=5)
    tr, yr = line_points(t, y, 50)
    np.testing.assert_array_equal(tr, t)
    np.testing.assert_array_equal(yr, y)


@pytest.mark.parametrize(
    "args, words",
    [
        ((np.arange(3.0), np.arange(3.0), 0.0), ["width_px", "0.0", "> 0"]),
        ((np.arange(3.0), np.arange(3.0), float("nan")), ["width_px", "nan"]),
        ((np.arange(3.0), np.arange(4.0), 10.0), ["(3,)", "(4,)", "1-D"]),
        ((np.array([0.0, 2.0, 1.0]), np.arange(3.0), 10.0), ["t:", "nondecreasing"]),
        ((np.array([0.0, np.nan, 1.0]), np.arange(3.0), 10.0), ["t:", "finite"]),
    ],
)
def test_bad_input_is_named(args, words):
    with pytest.raises(ValueError) as err:
        line_points(*args)
    for w in words:
        assert w in str(err.value)


def _ink_extent(t, y, xlim, ylim, width_px=200, height_px=120):
    """Topmost and bottommost dark pixel row of each pixel column of the line drawn by Agg."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_px / 100, height_px / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.plot(t, y, color="k", lw=1.0)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    fig.canvas.draw()
    dark = np.asarray(fig.canvas.buffer_rgba())[:, :, 0] < 128
    rows = np.arange(dark.shape[0])[:, None]
    top = np.where(dark.any(axis=0), np.where(dark, rows, 10**6).min(axis=0), -1)
    bottom = np.where(dark.any(axis=0), np.where(dark, rows, -1).max(axis=0), -1)
    return top, bottom


def _over_neighbours(v, pick):
    """``pick`` of each column and its two neighbours."""
    padded = np.r_[v[0], v, v[-1]]
    return pick(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)


@pytest.mark.parametrize("seed", [6, 7, 8])
def test_the_drawn_line_reaches_the_same_pixels_within_a_column(seed):
    """Each rendering's topmost and bottommost ink of a pixel column is reached by the other
    rendering in that column or a neighbour, to one pixel: a 1-px antialiased line spreads
    the strokes next to a column's edge into the neighbouring column, more darkly the more
    strokes the full line packs there, so the comparison is one column wide."""
    t, y = _walk(50_000, seed=seed)
    xlim, ylim = (t[0], t[-1]), (np.min(y) - 5, np.max(y) + 5)
    full = _ink_extent(t, y, xlim, ylim)
    reduced = _ink_extent(*line_points(t, y, 200), xlim, ylim)
    for a, b in ((full, reduced), (reduced, full)):
        assert np.all(a[0] >= _over_neighbours(b[0], np.min) - 1)  # top rows
        assert np.all(a[1] <= _over_neighbours(b[1], np.max) + 1)  # bottom rows


def _buckets(t, width):
    """Bucket of each time: ``BUCKETS_PER_PIXEL`` equal buckets per pixel column."""
    return _columns(t, t[0], t[-1], BUCKETS_PER_PIXEL * int(np.ceil(width)))


def test_every_bucket_keeps_its_first_and_last_sample_and_at_most_four():
    """The first and last sample of a bucket carry the line across the bucket's edges; ties
    (a quantized signal) keep one minimum and one maximum each."""
    t, y = _walk(30_000, seed=9)
    y = np.round(y / 20.0)  # long runs of equal values
    tr, yr = line_points(t, y, 80)
    b, br = _buckets(t, 80), _buckets(tr, 80)
    for k in range(BUCKETS_PER_PIXEL * 80):
        inside = np.flatnonzero(b == k)
        kept = tr[br == k]
        assert t[inside[0]] in kept and t[inside[-1]] in kept, k
        assert len(kept) <= 4, (k, len(kept))
        assert yr[br == k].max() == y[inside].max() and yr[br == k].min() == y[inside].min()


def test_the_samples_on_both_sides_of_a_gap_are_kept():
    t, y = _walk(30_000, seed=10)
    y[7_003:7_011] = np.nan
    y[20_000:20_500] = np.inf  # matplotlib does not draw inf either
    tr, _ = line_points(t, y, 100)
    for i in (7_002, 7_003, 7_010, 7_011, 19_999, 20_000, 20_499, 20_500):
        assert t[i] in tr, i


@pytest.mark.parametrize(
    "t",
    [
        np.r_[np.linspace(0.0, 1.0, 3997), 1000.0, 1001.0, 1002.0, 1003.0],  # samples bunched in one bucket
        np.linspace(0.0, 0.5, 20_000),  # half a second
        np.repeat(np.linspace(0.0, 100.0, 5_000), 4),  # every time four times
    ],
)
def test_any_line_with_more_than_four_samples_per_bucket_is_reduced(t):
    y = np.sin(np.arange(t.size) * 0.7)
    tr, yr = line_points(t, y, 500)  # 1000 buckets: room for 4000 samples
    assert len(tr) < len(t)
    assert np.max(yr) == np.max(y) and np.min(yr) == np.min(y)


@pytest.mark.parametrize(
    "t, y",
    [
        (np.array([]), np.array([])),
        (np.full(10_000, 3.0), np.arange(10_000.0)),  # one instant: nothing to reduce
    ],
)
def test_an_empty_line_or_a_single_instant_is_drawn_as_it_is(t, y):
    tr, yr = line_points(t, y, 10)
    np.testing.assert_array_equal(tr, t)
    np.testing.assert_array_equal(yr, y)


def test_lists_of_integers_and_a_narrow_axes_are_accepted():
    tr, yr = line_points(list(range(10_000)), [k % 7 for k in range(10_000)], 0.5)
    assert tr.dtype == yr.dtype == np.float64
    assert len(tr) <= 4 * BUCKETS_PER_PIXEL and (yr.min(), yr.max()) == (0.0, 6.0)


def test_an_axes_width_is_the_figure_width_at_the_dpi_over_the_columns():
    from matplotlib.figure import Figure

    from drake_att.analysis.plot_lines import axes_width_px

    assert axes_width_px(Figure(figsize=(15, 4)), 3, 110.0) == pytest.approx(15 * 110 / 3)
