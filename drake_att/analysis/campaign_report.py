"""The report of a Monte Carlo campaign and of a comparison matrix.

:func:`write_campaign_report` writes into a campaign folder (:func:`drake_att.analysis.campaign.run_campaign`):

* ``summary.json``: ``{"campaign": {...}, "statistics": ensemble.summarize(...)}`` - every
  number of the report (strict JSON: ``null``, never NaN);
* PNGs (matplotlib, Agg): per estimator ``<E>_errors.png`` (each run's attitude error per
  axis as a thin line, the filters' mean +-3 sigma, the ensemble's +-3 RMS and, when
  defined, the Cramer-Rao bound's +-3 sigma; top row the whole run, bottom row the scoring
  window) and ``<E>_consistency.png`` (ANEES per instant with its 95% band; NIS / dof per
  input in time bins with each bin's 95% band); ``rmse_vs_bound.png`` (window RMSE per
  axis with 95% CI next to the bound; RMSE per instant over runs vs the bound);
* ``report.html``: one self-contained page (the PNGs embedded as ``data:`` URIs, inline
  CSS, no script, no external address): the campaign, the tables, the figures, the
  methods, the worst runs with the command that repeats each, the resolved config.

:func:`write_comparison` writes the comparison matrix of ``drake-att compare``
(``comparison.{json,md,png,html}``). :func:`screenshot` renders a page in headless
Chromium and fails on any console message (the report has no script: a message means a
broken page).

The summary file, the figures and the self-contained HTML page of one campaign, in the page's order.
"""

from __future__ import annotations

import base64
import html
import json
import os
import shutil
import subprocess
import tempfile

import numpy as np

from drake_att.analysis.ensemble import common_times
from drake_att.analysis.plot_lines import axes_width_px, line_points
from drake_att.units import DEG

AXES = ["x (roll)", "y (pitch)", "z (yaw)"]
MAX_RUNS_DRAWN = 50
NIS_BINS = 60
FIGURE_DPI = 100  # the saved PNGs' resolution


# ----------------------------------------------------------------------------------------
# Small helpers
# ----------------------------------------------------------------------------------------
def _g(x, fmt=".3g") -> str:
    return "–" if x is None else format(x, fmt)


def _ci(ci, fmt=".3g") -> str:
    return "–" if ci is None or ci[0] is None else f"[{ci[0]:{fmt}}, {ci[1]:{fmt}}]"


def _save(fig, path: str) -> str:
    from drake_att.analysis.campaign_records import _atomic_write

    _atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=FIGURE_DPI))
    return path


def _name(record, key) -> str:
    return str(np.asarray(record[key]))


def _stack(records, key, idx):
    return np.array([np.asarray(r[key], dtype=float)[i] for r, i in zip(records, idx, strict=True)])


def _moving_mean(x, k: int):
    """Centered moving mean of ``x`` (n, ...) along axis 0 over ``k`` samples (shorter at
    the ends)."""
    x = np.asarray(x, dtype=float)
    if k <= 1 or len(x) < 2:
        return x
    kernel = np.ones(k)
    flat = x.reshape(len(x), -1)
    num = np.stack([np.convolve(np.nan_to_num(c), kernel, mode="same") for c in flat.T], axis=1)
    den = np.convolve(np.ones(len(x)), kernel, mode="same")[:, None]
    return (num / den).reshape(x.shape)


def smoothing_window(n_runs: int, n_samples: int) -> int:
    """Samples per moving window for ensemble statistics per instant: about 100 squared
    errors per point (runs x window), at most 2% of the run."""
    return int(max(1, min(np.ceil(100 / max(n_runs, 1)), max(1, n_samples // 50))))


def _y_scale(ax, span_factor: float = 20.0, values=None) -> None:
    """A log y-axis (ticks 1, 2, 5 x 10^k written as plain numbers) when the plotted data
    (``values``, default: the axes' lines) span more than ``span_factor`` (a transient NEES
    of 1e4 next to a steady 6), else linear."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    if values is None:
        # data lines only (not axhline / axvline, whose coordinates are partly axes fractions)
        values = np.concatenate(
            [
                np.asarray(line.get_ydata(), dtype=float)
                for line in ax.get_lines()
                if line.get_transform() == ax.transData
            ]
            or [np.zeros(0)]
        )
    y = np.array([np.nan if v is None else v for v in np.ravel(np.asarray(values, dtype=object))], dtype=float)
    y = y[np.isfinite(y) & (y > 0)]
    if y.size and y.max() / y.min() > span_factor:
        ax.set_yscale("log")
        decades = np.log10(y.max() / y.min())
        ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0) if decades <= 2.5 else (1.0,), numticks=10))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(NullFormatter())


def _peak(values) -> float:
    """The largest finite ``|value|`` (0 when there is none)."""
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    return float(v.max()) if v.size else 0.0


def error_axis_limit(data, envelopes, floor: float, reach: float = 3.0) -> tuple[float, list]:
    """Symmetric y-limit of an error plot and the envelopes it clips.

    Every finite value of ``data`` (the errors and the ensemble's +-3 RMS) is inside; so is each
    envelope (``(label, values)``: the filter's +-3 sigma, the bound's) unless it reaches past
    ``reach`` times the data's peak (an initial sigma of degrees next to arcsecond errors):
    then the limit stops there and ``clipped`` lists ``(label, its peak)``, for the figure to
    say. Returns ``(limit, clipped)``."""
    data_peak = max(max((_peak(d) for d in data), default=0.0), floor)
    lim = data_peak
    for _, values in envelopes:
        lim = max(lim, min(_peak(values), reach * data_peak))
    lim *= 1.08
    return lim, [(label, _peak(values)) for label, values in envelopes if _peak(values) > lim]


def _agg_figure(**kwargs):
    """A matplotlib ``Figure`` with constrained layout on an Agg canvas (no pyplot, no backend
    switch): texts can be measured (:func:`fit_titles`) and the figure saved."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(layout="constrained", **kwargs)
    FigureCanvasAgg(fig)
    return fig


def _with_legend_band(fig, rows: int, plots_height_in: float, at: str = "bottom"):
    """Split ``fig`` into the plots' subfigure and a band for the legend (``rows`` lines of
    entries) below or above them, so that no legend covers data. Returns ``(plots, band)``."""
    band_in = 0.3 + 0.22 * rows
    fig.set_figheight(plots_height_in + band_in + 0.5)
    if at == "top":
        band, plots = fig.subfigures(2, 1, height_ratios=[band_in, plots_height_in])
    else:
        plots, band = fig.subfigures(2, 1, height_ratios=[plots_height_in, band_in])
    return plots, band


def _band_legend(band, handles, labels, ncol: int, **kwargs):
    return band.legend(handles, labels, loc="center", ncol=ncol, fontsize=8, frameon=False, **kwargs)


def _wrap_to(text_artist, width_px: float) -> None:
    """Re-wrap ``text_artist``'s text onto more lines until it is at most ``width_px`` wide."""
    import textwrap

    lines = text_artist.get_text().split("\n")  # explicit line breaks are kept
    chars = max(len(line) for line in lines)
    renderer = text_artist.figure.canvas.get_renderer()
    while chars > 12 and text_artist.get_window_extent(renderer).width > width_px:
        chars = int(chars * 0.9)
        text_artist.set_text("\n".join(textwrap.fill(line, chars) for line in lines))


def fit_titles(fig):
    """Wrap every axes title wider than its axes, and the figure's title wider than the
    figure, onto more lines (constrained layout then makes room for them); returns ``fig``.
    The layout is computed without rasterizing (``draw_without_rendering``): the figure is
    drawn once, when it is saved."""
    fig.draw_without_rendering()
    for ax in fig.axes:
        if ax.get_title():
            _wrap_to(ax.title, ax.get_window_extent().width)
    for f in [fig, *fig.subfigs]:
        if getattr(f, "_suptitle", None) is not None:
            _wrap_to(f._suptitle, 0.98 * fig.bbox.width)
    return fig


# ----------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------
FILTER_STYLE = {"color": "tab:red", "ls": "--", "lw": 1.1, "zorder": 4}  # the filters' own +-3 sigma
BOUND_STYLE = {"color": "tab:green", "ls": "-", "lw": 3.5, "alpha": 0.45, "zorder": 2}  # under it: seen when equal
ENSEMBLE_STYLE = {"color": "k", "ls": "-", "lw": 1.0, "zorder": 3}


def error_ensemble_figure(records, name: str, score_from_s: float, title: str):
    """Each run's attitude error per axis (deg) with the +-3 sigma envelopes; top row the
    whole run, bottom row ``t >= score_from_s``.

    The filters' +-3 sigma (red, dashed) and the Cramér–Rao bound's (wide, pale green, drawn
    under it) differ in color, style and width, so both show where they coincide; the legend
    sits in a band below the plots; the y-limits hold every run's error and the ensemble's
    +-3 RMS, and the envelopes up to 3x that (:func:`error_axis_limit`; a title says which
    envelope runs off and its peak). Long lines are reduced to what the PNG's pixels show at
    :data:`FIGURE_DPI` (:func:`~drake_att.analysis.plot_lines.line_points`)."""
    t, idx = common_times(records, name)
    d = _stack(records, f"{name}__dtheta", idx) / DEG  # (N, n, 3)
    sig = _stack(records, f"{name}__sigma", idx)[:, :, :3] / DEG
    filt3 = 3 * np.sqrt(np.mean(sig**2, axis=0))  # the filters' RMS sigma over runs
    k = smoothing_window(len(records), len(t))
    ens3 = 3 * np.sqrt(_moving_mean(np.mean(d**2, axis=0), k))  # the ensemble's RMS error
    bound3 = None
    if all(f"{name}__bound_sigma" in r for r in records):
        b = _stack(records, f"{name}__bound_sigma", idx)[:, :, :3] / DEG
        bound3 = 3 * np.sqrt(np.mean(b**2, axis=0))
    N = len(records)
    drawn = min(N, MAX_RUNS_DRAWN)
    window = t >= score_from_s - 1e-6
    rows = [("whole run", np.ones_like(t, dtype=bool))] + (
        [(f"t ≥ {score_from_s:g} s (scored)", window)] if score_from_s > 0 and np.any(window) else []
    )
    fig = _agg_figure(figsize=(15, 3.6 * len(rows)))
    plots, band = _with_legend_band(fig, 1, 3.6 * len(rows))
    ax = plots.subplots(len(rows), 3, squeeze=False)
    labels = {
        "error": f"error, {drawn} of {N} runs",
        "filter": "filter ±3σ (RMS over runs)",
        "ensemble": f"ensemble ±3·RMS error (runs x {k} samples)",
        "bound": "Cramér–Rao bound ±3σ",
    }
    width = axes_width_px(fig, 3, FIGURE_DPI)
    for r, (label, sel) in enumerate(rows):
        for i in range(3):
            a = ax[r, i]
            for j in range(drawn):
                a.plot(
                    *line_points(t[sel], d[j, sel, i], width),
                    lw=0.5,
                    alpha=0.45,
                    color="tab:blue",
                    label=labels["error"] if j == 0 else None,
                )
            for sign in (1, -1):
                first = sign > 0
                for v, style, key in (
                    (filt3, FILTER_STYLE, "filter"),
                    (ens3, ENSEMBLE_STYLE, "ensemble"),
                    (bound3, BOUND_STYLE, "bound"),
                ):
                    if v is not None:
                        a.plot(
                            *line_points(t[sel], sign * v[sel, i], width), **style, label=labels[key] if first else None
                        )
            envelopes = [("filter ±3σ", filt3[sel, i])] + (
                [("bound ±3σ", bound3[sel, i])] if bound3 is not None else []
            )
            lim, clipped = error_axis_limit([d[:, sel, i], ens3[sel, i]], envelopes, 1e-9)
            a.set_ylim(-lim, lim)
            off = "; ".join(f"{what} runs off (peak {peak:.3g} deg)" for what, peak in clipped)
            a.set_title(f"attitude error {AXES[i]} — {label}" + (f"\n{off}" if off else ""), fontsize=10)
            a.set_ylabel("deg")
            a.set_xlabel("time (s)")
            a.grid(True, alpha=0.3)
    handles, texts = ax[0, 0].get_legend_handles_labels()
    _band_legend(band, handles, texts, ncol=len(handles))
    fig.suptitle(title)
    return fit_titles(fig)


def _nis_bins(records, name, i, t_end, bins=NIS_BINS):
    """Mean NIS / dof per time bin over runs and its 95% band per bin."""
    from drake_att.analysis.ensemble import chi2_q

    t = np.concatenate([np.asarray(r[f"{name}__nis{i}__t"], dtype=float) for r in records])
    v = np.concatenate([np.asarray(r[f"{name}__nis{i}__value"], dtype=float) for r in records])
    d = np.concatenate([np.asarray(r[f"{name}__nis{i}__dof"], dtype=float) for r in records])
    edges = np.linspace(0.0, max(t_end, float(t.max()) if t.size else 1.0) + 1e-9, bins + 1)
    k = np.clip(np.digitize(t, edges) - 1, 0, bins - 1)
    centers, mean, lo, hi = [], [], [], []
    for b in range(bins):
        m = k == b
        if not np.any(m):
            continue
        D = float(np.sum(d[m]))
        centers.append(0.5 * (edges[b] + edges[b + 1]))
        mean.append(float(np.sum(v[m]) / D))
        lo.append(chi2_q(0.025, D) / D)
        hi.append(chi2_q(0.975, D) / D)
    return np.array(centers), np.array(mean), np.array(lo), np.array(hi)


def consistency_figure(records, name: str, stats: dict, title: str):
    """ANEES per instant with its 95% band (top) and NIS / dof per input (bottom); each
    legend to the right of its plot."""
    h = stats["history"]
    inputs = [str(x) for x in np.atleast_1d(records[0][f"{name}__inputs"])]
    nis_inputs = [(i, n) for i, n in enumerate(inputs) if f"{name}__nis{i}__t" in records[0]]
    nrows = 1 + (1 if nis_inputs else 0)
    fig = _agg_figure(figsize=(13, 3.6 * nrows + 0.6))
    ax = fig.subplots(nrows, 1, squeeze=False)[:, 0]
    a = ax[0]
    t = np.array(h["t"], dtype=float)
    anees = np.array([np.nan if v is None else v for v in h["anees"]], dtype=float)
    dof = stats["nees_dof"]
    band = stats["anees_band_95"]
    a.plot(
        *line_points(t, anees, axes_width_px(fig, 1, FIGURE_DPI)),
        lw=0.8,
        label=f"ANEES over {stats['n_runs']} runs (dof {dof})",
    )
    if band[0] is not None:
        a.fill_between(
            t,
            band[0],
            band[1],
            color="tab:green",
            alpha=0.2,
            label=f"95% band at one instant [{band[0]:.3g}, {band[1]:.3g}]",
        )
    a.axhline(dof, color="k", lw=0.8, ls="--", label=f"consistent: {dof}")
    if stats.get("anees") is not None:
        a.axhline(
            stats["anees"],
            color="tab:red",
            lw=0.8,
            ls=":",
            label=f"window ANEES {stats['anees']:.3g}"
            + (
                f", window band [{stats['anees_window_band_95'][0]:.3g}, {stats['anees_window_band_95'][1]:.3g}]"
                if stats.get("anees_window_band_95")
                else ""
            ),
        )
    a.axvline(float(records[0]["score_from_s"]), color="gray", lw=0.8)
    _y_scale(a, 20.0, np.r_[anees, [v for v in band if v is not None], dof])
    a.set_ylabel("ANEES")
    a.set_xlabel("time (s)")
    a.set_title("average NEES per instant (the gray line starts the scoring window)", fontsize=10)
    a.grid(True, which="major", alpha=0.3)
    a.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    if nis_inputs:
        b = ax[1]
        t_end = float(records[0]["duration_s"])
        spans = [1.0]
        for i, n in nis_inputs:
            c, m, lo, hi = _nis_bins(records, name, i, t_end)
            spans += [*m, *lo, *hi]
            line = b.plot(c, m, ".-", lw=0.8, ms=3, label=f"{n}: mean NIS / dof per bin")[0]
            b.fill_between(c, lo, hi, color=line.get_color(), alpha=0.15, label=f"{n}: 95% band per bin")
        b.axhline(1.0, color="k", lw=0.8, ls="--")
        b.axvline(float(records[0]["score_from_s"]), color="gray", lw=0.8)
        b.set_ylabel("NIS / dof")
        b.set_xlabel("time (s)")
        b.set_title(f"normalized innovation squared per input ({NIS_BINS} time bins, all runs)", fontsize=10)
        b.grid(True, which="major", alpha=0.3)
        _y_scale(b, 20.0, spans)
        b.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.suptitle(title)
    return fit_titles(fig)


def rmse_vs_bound_figure(summary: dict, title: str):
    """Window RMSE per axis and total with 95% CI next to the bound (left); RMSE per instant
    over runs vs the bound (right: a wide pale line in the estimator's color); one legend in
    a band below the plots."""
    ests = summary["estimators"]
    names = list(ests)
    from matplotlib.lines import Line2D

    fig = _agg_figure(figsize=(15, 5.2))
    plots, band = _with_legend_band(fig, -(-(len(names) + 2) // 6), 4.7)
    a, b = plots.subplots(1, 2, width_ratios=[1.1, 1])
    groups = AXES + ["total"]
    width = 0.8 / max(len(names), 1)
    for j, n in enumerate(names):
        s = ests[n]
        vals = list(s["attitude_rmse_deg"]) + [s["attitude_rmse_total_deg"]]
        cis = list(s["attitude_rmse_ci95_deg"]) + [s["attitude_rmse_total_ci95_deg"]]
        x = np.arange(4) + (j - (len(names) - 1) / 2) * width
        v = np.array([np.nan if q is None else q for q in vals])
        err = np.array(
            [[v[k] - c[0], c[1] - v[k]] if c is not None and c[0] is not None else [0, 0] for k, c in enumerate(cis)]
        ).T
        a.bar(x, v, width, yerr=err, capsize=2, label=n)
        bd = s["bound"]
        if bd["defined"] and bd["attitude_rmse_bound_deg"] is not None:
            bv = list(bd["attitude_rmse_bound_deg"]) + [bd["attitude_rmse_total_bound_deg"]]
            a.scatter(
                x,
                bv,
                marker="D",
                s=22,
                facecolor="white",
                edgecolor="k",
                zorder=3,
                label="left: the Cramér–Rao bound (diamonds)" if j == 0 else None,
            )
    _y_scale(
        a,
        20.0,
        [
            q
            for n in names
            for q in list(ests[n]["attitude_rmse_deg"])
            + [ests[n]["attitude_rmse_total_deg"]]
            + list(ests[n]["bound"]["attitude_rmse_bound_deg"] or [])
        ],
    )
    a.set_xticks(np.arange(4), groups)
    a.set_ylabel("RMSE over the scoring window (deg)")
    a.set_title("window RMSE with 95% CI; diamonds: the bound", fontsize=10)
    a.grid(True, axis="y", alpha=0.3)
    width_b = axes_width_px(fig, 2, FIGURE_DPI)
    for n in names:
        h = ests[n]["history"]
        t = np.array(h["t"], dtype=float)
        r = np.array([[np.nan if q is None else q for q in row] for row in h["attitude_rmse_deg"]], dtype=float)
        k = smoothing_window(ests[n]["n_runs"], len(t))
        line = b.plot(*line_points(t, np.sqrt(_moving_mean(np.sum(r**2, axis=1), k)), width_b), lw=0.9, label=n)[0]
        if h.get("bound_attitude_sigma_deg") is not None:
            bs = np.array(
                [[np.nan if q is None else q for q in row] for row in h["bound_attitude_sigma_deg"]], dtype=float
            )
            b.plot(
                *line_points(t, np.sqrt(np.sum(bs**2, axis=1)), width_b), **{**BOUND_STYLE, "color": line.get_color()}
            )
    b.axvline(summary["score_from_s"], color="gray", lw=0.8)
    b.set_xlabel("time (s)")
    b.set_ylabel("total attitude error (deg)")
    b.set_title(
        "RMS of |dθ| over runs (and a moving window of "
        f"{smoothing_window(summary['n_runs'], len(ests[names[0]]['history']['t']))} points) vs the bound's "
        "total σ",
        fontsize=10,
    )
    b.grid(True, which="major", alpha=0.3)
    _y_scale(b, 5.0)
    handles, labels = a.get_legend_handles_labels()
    if any(ests[n]["history"].get("bound_attitude_sigma_deg") is not None for n in names):
        handles.append(Line2D([], [], **{**BOUND_STYLE, "color": "gray"}))
        labels.append("right: each estimator's bound (wide pale line, its color)")
    _band_legend(band, handles, labels, ncol=min(len(handles), 6))
    fig.suptitle(title)
    return fit_titles(fig)


# ----------------------------------------------------------------------------------------
# Tables
# ----------------------------------------------------------------------------------------
TABLE_COLUMNS = [
    "estimator",
    "RMSE x / y / z (deg)",
    "95% CI total",
    "RMSE total (deg)",
    "bias RMSE x/y/z (deg/h)",
    "ANEES (dof)",
    "95% band (window)",
    "NIS mean / dof per input",
    "converged",
    "median conv. (s)",
    "bound total (deg)",
    "RMSE / bound x / y / z",
    "worst seeds",
]


def summary_rows(summary: dict) -> list[list[str]]:
    """One row of strings per estimator (columns :data:`TABLE_COLUMNS`)."""
    rows = []
    for n, s in summary["estimators"].items():
        second = s["bias_rmse_deg_per_h"] if s["second_kind"] == "gyro_bias" else None
        band = s.get("anees_window_band_95") or s["anees_band_95"]
        ok = s.get("anees_in_window_band") if s.get("anees_window_band_95") else s.get("anees_in_band")
        nis = (
            "; ".join(
                f"{k} {_g(v['mean'])}/{_g(v['mean_dof'], '.0f')}" + ("" if v["in_band"] else " (out of band)")
                for k, v in s["nis"].items()
            )
            or "–"
        )
        conv = s["convergence"]
        bd = s["bound"]
        rows.append(
            [
                n,
                " / ".join(_g(v) for v in s["attitude_rmse_deg"]),
                _ci(s["attitude_rmse_total_ci95_deg"]),
                _g(s["attitude_rmse_total_deg"]),
                "–" if second is None else " / ".join(_g(v) for v in second),
                f"{_g(s['anees'])} ({s['nees_dof']})",
                _ci(band) + ("" if ok is None else (" in" if ok else " OUT")),
                nis,
                f"{conv['n_converged']}/{s['n_runs']}",
                "–" if conv["time_s"] is None else _g(conv["time_s"]["median"]),
                _g(bd["attitude_rmse_total_bound_deg"]) if bd["defined"] else "none",
                " / ".join(_g(v) for v in bd["ratio"]) if bd["defined"] and bd["ratio"] else "–",
                ", ".join(str(w["seed"]) for w in s["worst_runs"][:3]),
            ]
        )
    return rows


TEXT_WIDTH = 100  # the printed tables' lines fit 100 columns (names up to 24 characters)


def _text_table(header, rows) -> list[str]:
    """Left-aligned columns two spaces apart under a dash line, no trailing spaces; a row
    given as a string is printed whole (a section heading) and does not widen the columns."""
    cells = [header] + [r for r in rows if not isinstance(r, str)]
    widths = [max(len(r[c]) for r in cells) for c in range(len(header))]

    def line(row):
        return "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()

    return [line(header), "  ".join("-" * w for w in widths)] + [r if isinstance(r, str) else line(r) for r in rows]


def _wrapped(text: str) -> list[str]:
    """``text`` wrapped to :data:`TEXT_WIDTH` columns, continuation lines indented by one."""
    import textwrap

    return textwrap.wrap(text, TEXT_WIDTH, subsequent_indent=" ", break_long_words=False, break_on_hyphens=False)


CAMPAIGN_TEXT_BLOCKS = (
    # (column of summary_rows, its header in the printed table)
    ((0, "estimator"), (3, "RMSE tot"), (2, "95% CI"), (10, "bound tot"), (1, "RMSE x / y / z")),
    ((0, "estimator"), (5, "ANEES (dof)"), (6, "95% band"), (8, "converged"), (11, "RMSE / bound x / y / z")),
)


def format_campaign_table(result) -> str:
    """The campaign's table as text (what ``drake-att montecarlo`` prints): the accuracy
    block (RMSE, its CI, the bound) and the consistency block (ANEES, convergence, RMSE /
    bound per axis), then what the columns mean; every line fits :data:`TEXT_WIDTH`."""
    head = (
        f"Monte Carlo {result.scenario.name}: {len(result.records)} runs"
        + (f" ({len(result.failed)} failed)" if result.failed else "")
        + f", seeds {result.seeds[0]}..{result.seeds[-1]}"
    )
    if not result.summary:
        return head + "\n(no completed run)"
    rows = summary_rows(result.summary)
    lines = [head]
    for block in CAMPAIGN_TEXT_BLOCKS:
        lines += _text_table([h for _, h in block], [[row[k] for k, _ in block] for row in rows]) + [""]
    lines.pop()
    lines += _wrapped(
        f"(deg; window t >= {result.summary['score_from_s']:g} s; 95% CI: of the total RMSE; bound: posterior "
        "Cramer-Rao, total RMS over the window; ANEES band: 95% of the window average, 'in'/'OUT')"
    )
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------
# HTML
# ----------------------------------------------------------------------------------------
CSS = """
body{font-family:-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:24px auto;max-width:1500px;color:#222;
line-height:1.4;padding:0 16px}
h1{font-size:1.6em;margin-bottom:.2em}h2{font-size:1.25em;border-bottom:1px solid #ccc;margin-top:1.6em}
table{border-collapse:collapse;font-size:.85em;margin:.6em 0}th,td{border:1px solid #ccc;padding:3px 7px;
text-align:left;vertical-align:top}th{background:#f0f3f7}tr:nth-child(even) td{background:#fafafa}
td.num{text-align:right;font-variant-numeric:tabular-nums}.out{color:#b00;font-weight:bold}
img{max-width:100%;border:1px solid #ddd;margin:.4em 0}figure{margin:1em 0}figcaption{font-size:.85em;color:#555}
pre{background:#f6f8fa;padding:8px;overflow-x:auto;font-size:.8em}code{background:#f6f8fa;padding:0 3px}
.facts td:first-child{font-weight:bold;background:#f0f3f7}
"""


def _png_uri(path: str) -> str:
    with open(path, "rb") as f:
        return "data:image/png;base64," + base64.b64encode(f.read()).decode("ascii")


def _table_html(header, rows) -> str:
    def cell(c):
        cls = ' class="out"' if " OUT" in c or "out of band" in c else ""
        return f"<td{cls}>{html.escape(c)}</td>"

    return (
        "<table><tr>"
        + "".join(f"<th>{html.escape(h)}</th>" for h in header)
        + "</tr>"
        + "".join("<tr>" + "".join(cell(c) for c in r) + "</tr>" for r in rows)
        + "</table>"
    )


def _figure_html(path: str, caption: str) -> str:
    return (
        f'<figure><img src="{_png_uri(path)}" alt="{html.escape(os.path.basename(path))}">'
        f"<figcaption>{html.escape(os.path.basename(path))}: {html.escape(caption)}</figcaption></figure>"
    )


def _page(title: str, body: str) -> str:
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{CSS}</style></head><body>\n{body}\n</body></html>\n"
    )


def write_campaign_report(result, executor: str = "") -> list[str]:
    """``summary.json``, the PNGs and ``report.html`` of a finished campaign in
    ``result.out``; returns the paths (summary first, report last)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from drake_att.analysis.campaign_folder import SUMMARY_FILE
    from drake_att.analysis.campaign_records import write_text_atomic
    from drake_att.analysis.report import strict_json
    from drake_att.scenarios.config import dump_scenario

    out = result.out
    scenario = result.scenario
    campaign = {
        "scenario": scenario.name,
        "runs": len(result.seeds),
        "completed": len(result.records),
        "failed": {str(s): m for s, m in result.failed.items()},
        "first_seed": result.seeds[0],
        "last_seed": result.seeds[-1],
        "executor": executor,
        "runs_simulated_by_last_call": result.simulated,
        "runs_reused_from_disk": result.reused,
        "wall_time_s_of_last_call": round(result.wall_time_s, 3),
        "duration_s": scenario.duration_s,
        "config": "config.yaml",
        "runs_folder": "runs/",
    }
    files = [
        write_text_atomic(
            os.path.join(out, SUMMARY_FILE),
            json.dumps(strict_json({"campaign": campaign, "statistics": result.summary}), indent=1, allow_nan=False)
            + "\n",
        )
    ]
    figures = []
    summary, records = result.summary, result.records
    if summary:
        sf = summary["score_from_s"]
        figures.append(
            (
                _save(
                    rmse_vs_bound_figure(
                        summary, f"{scenario.name}: RMSE vs the Cramér–Rao bound ({len(records)} runs)"
                    ),
                    os.path.join(out, "rmse_vs_bound.png"),
                ),
                "window RMSE with 95% CI per axis and total, with the bound; RMSE per instant vs the bound.",
            )
        )
        for n, s in summary["estimators"].items():
            figures.append(
                (
                    _save(
                        error_ensemble_figure(
                            records, n, sf, f"{scenario.name}: {n}, attitude error of {len(records)} runs"
                        ),
                        os.path.join(out, f"{n}_errors.png"),
                    ),
                    (
                        f"{n}: each run's attitude error per axis (thin lines), the filter's own ±3σ (RMS over "
                        "runs, red dashes), the ensemble's ±3·RMS error (black) and the Cramér–Rao bound's ±3σ "
                        "(wide pale green, under the red dashes; when defined); top: the whole run, bottom: the "
                        "scoring window."
                    ),
                )
            )
            figures.append(
                (
                    _save(
                        consistency_figure(records, n, s, f"{scenario.name}: {n}, consistency"),
                        os.path.join(out, f"{n}_consistency.png"),
                    ),
                    f"{n}: ANEES per instant over the runs with its 95% band, and NIS / dof per input.",
                )
            )
    files += [p for p, _ in figures]
    page = _campaign_html(result, campaign, figures, dump_scenario(scenario))
    files.append(write_text_atomic(os.path.join(out, "report.html"), page))
    return files


def _campaign_html(result, campaign, figures, yaml_text) -> str:
    """The campaign's report page: facts, failed runs, the summary sections (when any run
    finished), the file list and the resolved configuration."""
    s = result.summary
    title = f"Monte Carlo: {result.scenario.name}, {len(result.records)} runs"
    body = [
        f"<h1>{html.escape(title)}</h1>",
        "<table class='facts'>"
        + "".join(
            f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in _campaign_facts(result, campaign)
        )
        + "</table>",
    ]
    if result.failed:
        body.append(
            "<h2>Failed runs</h2><ul>"
            + "".join(f"<li>seed {s_}: {html.escape(m)}</li>" for s_, m in result.failed.items())
            + "</ul>"
        )
    if s:
        body += _summary_sections(s, figures)
    body.append(
        "<h2>Files</h2><p><code>summary.json</code> (every number above), <code>config.yaml</code> (the "
        "resolved configuration), <code>runs/seed_&lt;seed&gt;.npz</code> (one record per run: "
        "<code>drake_att.analysis.ensemble</code>), the PNGs, <code>manifest.json</code>.</p>"
    )
    body.append(f"<h2>Resolved configuration</h2><pre>{html.escape(yaml_text)}</pre>")
    return _page(title, "\n".join(body))


def _description_as_run(scenario) -> str:
    """The scenario's description followed by what ran: its text comes from the scenario file
    and may name values a ``--set`` changed, so the duration and the scoring window of the
    resolved config stand next to it."""
    return (
        " ".join(scenario.description.split())
        + f" [as run: {scenario.duration_s:g} s per run, scored from t ≥ {scenario.scoring.score_from_s:g} s; "
        "the resolved configuration at the end of this page is what ran]"
    )


def _campaign_facts(result, campaign) -> list:
    """The (label, text) rows of the page's facts table."""
    return [
        ("scenario", result.scenario.name),
        ("description", _description_as_run(result.scenario)),
        (
            "runs",
            f"{campaign['completed']} completed of {campaign['runs']} (seeds {campaign['first_seed']}.."
            f"{campaign['last_seed']})" + (f", {len(result.failed)} failed" if result.failed else ""),
        ),
        ("simulated time per run", f"{result.scenario.duration_s:g} s"),
        ("scoring window", f"t ≥ {result.scenario.scoring.score_from_s:g} s"),
        ("executed on", campaign["executor"] or "–"),
        (
            "last call",
            (
                f"{result.simulated} runs simulated, {result.reused + result.failed_reused} read from "
                "runs/, "
                f"{result.wall_time_s:.1f} s wall"
            ),
        ),
    ]


def _summary_sections(s, figures) -> list:
    """The HTML sections built from the summary ``s``: the table, figures, the bound, the
    worst runs and the methods."""
    return [
        "<h2>Summary</h2>" + _table_html(TABLE_COLUMNS, summary_rows(s)),
        "<p>RMSE over the scoring window pooled over runs; the 95% CI is for the total. ANEES: mean NEES "
        "over runs and window samples, with the 95% band of a window average of a consistent filter "
        "(‘OUT’: outside it). NIS: mean NIS per update attempt in the window / its mean dimension. "
        "Bound: the posterior Cramér–Rao bound on each run's true trajectory with the true sensor noise; "
        "RMSE / bound ≥ 1 for any estimator up to sampling error.</p>",
        "<h2>Figures</h2>" + "".join(_figure_html(p, c) for p, c in figures),
        _bound_section(s),
        _worst_runs_section(s),
        "<h2>Methods</h2><ul>"
        + "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in s["methods"].items())
        + "</ul>",
    ]


def _bound_section(s) -> str:
    """The Cramér–Rao bound table: per estimator whether it is defined, its RMS and the ratios."""
    rows = []
    for n, e in s["estimators"].items():
        bd = e["bound"]
        rows.append(
            [
                n,
                "yes" if bd["defined"] else f"no: {bd['reason']}",
                " / ".join(_g(v) for v in bd["attitude_rmse_bound_deg"]) if bd["attitude_rmse_bound_deg"] else "–",
                "; ".join(_ci(c) for c in bd["ratio_ci95"]) if bd["ratio_ci95"] else "–",
                " / ".join(_g(v) for v in bd["bias_ratio"]) if bd["bias_ratio"] else "–",
                _g(bd["prior_sensitivity"]),
            ]
        )
    return "<h2>The Cramér–Rao bound</h2>" + _table_html(
        [
            "estimator",
            "defined",
            "bound RMS x / y / z (deg)",
            "RMSE / bound 95% CI x; y; z",
            "bias RMSE / bound",
            "prior sensitivity",
        ],
        rows,
    )


def _worst_runs_section(s) -> str:
    """The worst runs per estimator, each with the command that repeats it."""
    rows = [
        [n, str(w["seed"]), _g(w["attitude_rmse_total_deg"]), w["command"]]
        for n, e in s["estimators"].items()
        for w in e["worst_runs"]
    ]
    return (
        "<h2>Worst runs</h2><p>Largest total attitude RMSE per estimator; the command repeats the run "
        "bit for bit (the campaign's resolved config).</p>"
        + _table_html(["estimator", "seed", "RMSE total (deg)", "repeat it"], rows)
    )


# ----------------------------------------------------------------------------------------
# The comparison matrix
# ----------------------------------------------------------------------------------------
def comparison_cells(result) -> list[dict]:
    """One dict per (scenario, estimator): RMSE (total, CI, per axis), ANEES (band, in),
    ratio to the bound, ms per step - or ``why`` it did not run."""
    cells = []
    names = {sc.name for sc in result.plan.scenarios}
    for (scen, est), why in result.plan.cells.items():
        cell = {"scenario": scen, "estimator": est, "ran": why is None and scen in names, "why": why}
        c = result.campaigns.get(scen)
        st = c.summary["estimators"].get(est) if c is not None and c.summary and why is None else None
        if st is not None:
            bd = st["bound"]
            band = st.get("anees_window_band_95") or st["anees_band_95"]
            cell.update(
                {
                    "runs": st["n_runs"],
                    "attitude_rmse_total_deg": st["attitude_rmse_total_deg"],
                    "attitude_rmse_total_ci95_deg": st["attitude_rmse_total_ci95_deg"],
                    "attitude_rmse_deg": st["attitude_rmse_deg"],
                    "anees": st["anees"],
                    "nees_dof": st["nees_dof"],
                    "anees_band_95": band,
                    "anees_in_band": bool(band[0] <= st["anees"] <= band[1])
                    if st["anees"] is not None and band and band[0] is not None
                    else None,
                    "bound_total_deg": bd["attitude_rmse_total_bound_deg"],
                    "ratio_to_bound_total": bd["ratio_total"],
                    "bound_reason": bd["reason"],
                    "converged": f"{st['convergence']['n_converged']}/{st['n_runs']}",
                }
            )
        tm = result.timing.get((scen, est))
        if tm is not None:
            cell["ms_per_step"] = tm["ms_per_step"]
            cell["timing"] = tm
        cells.append(cell)
    return cells


COMPARISON_COLUMNS = [
    "scenario",
    "estimator",
    "runs",
    "RMSE total (deg)",
    "95% CI",
    "RMSE x / y / z (deg)",
    "ANEES (dof)",
    "95% band",
    "RMSE / bound",
    "ms / step",
    "converged",
    "note",
]


def comparison_rows(cells) -> list[list[str]]:
    rows = []
    for c in cells:
        if "attitude_rmse_total_deg" not in c:
            rows.append(
                [c["scenario"], c["estimator"], "–", "n/a", "", "", "", "", "", "", "", c["why"] or "no completed run"]
            )
            continue
        rows.append(
            [
                c["scenario"],
                c["estimator"],
                str(c["runs"]),
                _g(c["attitude_rmse_total_deg"]),
                _ci(c["attitude_rmse_total_ci95_deg"]),
                " / ".join(_g(v) for v in c["attitude_rmse_deg"]),
                f"{_g(c['anees'])} ({c['nees_dof']})",
                _ci(c["anees_band_95"])
                + ("" if c["anees_in_band"] is None else (" in" if c["anees_in_band"] else " OUT")),
                _g(c["ratio_to_bound_total"]) if c["ratio_to_bound_total"] is not None else "no bound",
                _g(c.get("ms_per_step"), ".3f") if c.get("ms_per_step") is not None else "–",
                c["converged"],
                "" if c["ratio_to_bound_total"] is not None else (c.get("bound_reason") or ""),
            ]
        )
    return rows


def _footnote(notes: dict, text: str) -> str:
    """`` (k)``: ``text``'s number in ``notes`` (text -> number, numbered as first seen)."""
    return f" ({notes.setdefault(text, len(notes) + 1)})"


def _comparison_text_rows(cells, notes: dict) -> tuple[list, list]:
    """The accuracy and the consistency rows of :func:`format_comparison_table`: a heading
    per scenario, then one row per estimator; a cell that did not run, or has no bound, points
    to its reason in ``notes``."""
    accuracy, consistency, current = [], [], None
    for c in cells:
        if c["scenario"] != current:
            current = c["scenario"]
            accuracy.append(f"scenario {current}:")
            consistency.append(f"scenario {current}:")
        est = c["estimator"]
        if "attitude_rmse_total_deg" not in c:
            why = "n/a" + _footnote(notes, c["why"] or "no completed run")
            accuracy.append([est, "–", why, "", ""])
            consistency.append([est, why, "", "", "", ""])
            continue
        accuracy.append(
            [
                est,
                str(c["runs"]),
                _g(c["attitude_rmse_total_deg"]),
                _ci(c["attitude_rmse_total_ci95_deg"]),
                " / ".join(_g(v) for v in c["attitude_rmse_deg"]),
            ]
        )
        ratio = c["ratio_to_bound_total"]
        consistency.append(
            [
                est,
                f"{_g(c['anees'])} ({c['nees_dof']})",
                _ci(c["anees_band_95"])
                + ("" if c["anees_in_band"] is None else (" in" if c["anees_in_band"] else " OUT")),
                _g(ratio)
                if ratio is not None
                else "no bound" + (_footnote(notes, c["bound_reason"]) if c.get("bound_reason") else ""),
                _cost_text(c.get("ms_per_step"), notes),
                c["converged"],
            ]
        )
    return accuracy, consistency


BELOW_TIMING_NOISE = (
    "a negative cost is below the timing noise: the fastest run with this estimator was faster than the "
    "fastest sensors-only run it is measured against"
)


def _cost_text(ms_per_step, notes: dict) -> str:
    """A cell's ms/step as printed; a negative one points to :data:`BELOW_TIMING_NOISE` in ``notes``."""
    if ms_per_step is None:
        return "–"
    return _g(ms_per_step, ".3f") + (_footnote(notes, BELOW_TIMING_NOISE) if ms_per_step < 0 else "")


def format_comparison_table(result) -> str:
    """The comparison as text (what ``drake-att compare`` prints): :func:`comparison_text`."""
    return comparison_text(comparison_cells(result))


def comparison_text(cells) -> str:
    """The :func:`comparison_cells` as text: an accuracy block and a consistency-and-cost
    block, each with a heading line per scenario, then what the columns mean and the numbered
    reasons of the cells that did not run or have no bound; every line fits
    :data:`TEXT_WIDTH` for names up to 24 characters."""
    notes: dict = {}
    accuracy, consistency = _comparison_text_rows(cells, notes)
    lines = _text_table(["estimator", "runs", "RMSE tot", "95% CI", "RMSE x / y / z"], accuracy)
    lines += [""] + _text_table(
        ["estimator", "ANEES (dof)", "95% band", "RMSE / bound", "ms / step", "converged"], consistency
    )
    lines += _wrapped(
        "(RMSE in deg over each scenario's scoring window, pooled over runs; 95% CI: of the total RMSE; ANEES band: "
        "95% of a window average, 'in'/'OUT'; RMSE / bound: total RMSE / the posterior Cramer-Rao bound; ms / step: "
        "time per estimator step)"
    )
    for text, k in notes.items():
        lines += _wrapped(f"({k}) {text}")
    return "\n".join(lines)


def comparison_figure(cells, title: str):
    """RMSE with CI and the bound, ANEES / dof with its band, RMSE / bound and time per step
    of every cell that ran; bars colored by scenario, the legend in a band above the plots,
    long titles wrapped (:func:`fit_titles`)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ran = [c for c in cells if "attitude_rmse_total_deg" in c]
    x = np.arange(len(ran))
    scenarios = list(dict.fromkeys(c["scenario"] for c in ran))
    fig = _agg_figure(figsize=(max(11, 0.9 * len(ran) + 6), 9))
    plots, band = _with_legend_band(fig, -(-(len(scenarios) + 2) // 3), 8.4, at="top")
    ax = plots.subplots(2, 2)
    scen_colors = {}
    colors = [f"C{scen_colors.setdefault(c['scenario'], len(scen_colors)) % 10}" for c in ran]
    a = ax[0, 0]
    v = np.array([c["attitude_rmse_total_deg"] or np.nan for c in ran])
    err = np.array(
        [
            [
                c["attitude_rmse_total_deg"] - c["attitude_rmse_total_ci95_deg"][0],
                c["attitude_rmse_total_ci95_deg"][1] - c["attitude_rmse_total_deg"],
            ]
            if c["attitude_rmse_total_ci95_deg"]
            else [0, 0]
            for c in ran
        ]
    ).T.reshape(2, -1)
    a.bar(x, v, yerr=err, capsize=3, color=colors)
    bound = [c["bound_total_deg"] if c["bound_total_deg"] is not None else np.nan for c in ran]
    a.scatter(x, bound, marker="D", s=28, facecolor="white", edgecolor="k", zorder=3)
    _y_scale(a, 10.0, np.r_[v, bound])
    a.set_ylabel("total attitude RMSE (deg)")
    a.set_title("RMSE over the scoring window (95% CI); diamonds: the Cramér–Rao bound", fontsize=10)
    a = ax[0, 1]
    v = np.array([(c["anees"] if c["anees"] is not None else np.nan) / c["nees_dof"] for c in ran])
    a.bar(x, v, color=colors)
    for k, c in enumerate(ran):
        if c["anees_band_95"] and c["anees_band_95"][0] is not None:
            a.plot([k - 0.4, k + 0.4], [c["anees_band_95"][0] / c["nees_dof"]] * 2, "k-", lw=0.8)
            a.plot([k - 0.4, k + 0.4], [c["anees_band_95"][1] / c["nees_dof"]] * 2, "k-", lw=0.8)
    a.axhline(1.0, color="k", ls="--", lw=0.8)
    _y_scale(a, 10.0, np.r_[v, 1.0])
    a.set_ylabel("ANEES / dof")
    a.set_title("consistency: ANEES / dof (1 = consistent; black lines: 95% band)", fontsize=10)
    a = ax[1, 0]
    a.bar(
        x, [c["ratio_to_bound_total"] if c["ratio_to_bound_total"] is not None else np.nan for c in ran], color=colors
    )
    a.axhline(1.0, color="k", ls="--", lw=0.8)
    a.set_ylabel("RMSE / bound")
    a.set_title("ratio to the Cramér–Rao bound (1 = efficient; no bar: no bound)", fontsize=10)
    a = ax[1, 1]
    a.bar(x, [c.get("ms_per_step") if c.get("ms_per_step") is not None else np.nan for c in ran], color=colors)
    a.set_ylabel("ms per estimator step")
    a.set_title("time per step (run with it alone minus the sensors-only run; min of 3)", fontsize=10)
    for a in ax.ravel():
        a.set_xticks(x, [c["estimator"] for c in ran], fontsize=8, rotation=20, ha="right")
        a.grid(True, axis="y", which="both", alpha=0.3)
    handles = [Patch(color=f"C{i % 10}") for i in scen_colors.values()] + [
        Line2D([], [], ls="", marker="D", markerfacecolor="white", markeredgecolor="k"),
        Line2D([], [], color="k", lw=0.8),
    ]
    labels = [f"scenario {n}" for n in scen_colors] + ["Cramér–Rao bound", "ANEES 95% band"]
    _band_legend(band, handles, labels, ncol=min(3, len(handles)))
    fig.suptitle(title)
    return fit_titles(fig)


def write_comparison(result) -> list[str]:
    """``comparison.json``, ``comparison.md``, ``comparison.png`` and ``comparison.html`` in
    ``result.out``; returns the paths."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from drake_att.analysis.campaign_records import write_text_atomic
    from drake_att.analysis.report import strict_json

    out = result.out
    cells = comparison_cells(result)
    runs = max((c.summary["n_runs"] for c in result.campaigns.values() if c.summary), default=0)
    title = (
        f"Comparison: {len(result.plan.scenarios)} scenarios x {len(result.plan.estimators)} estimators, {runs} runs"
    )
    files = [
        write_text_atomic(
            os.path.join(out, "comparison.json"),
            json.dumps(
                strict_json(
                    {
                        "scenarios": [s.name for s in result.plan.scenarios],
                        "estimators": result.plan.estimators,
                        "cells": cells,
                        "campaign_folders": {n: n + "/" for n in result.campaigns},
                    }
                ),
                indent=1,
                allow_nan=False,
            )
            + "\n",
        )
    ]
    rows = comparison_rows(cells)
    md = ["| " + " | ".join(COMPARISON_COLUMNS) + " |", "|" + "---|" * len(COMPARISON_COLUMNS)]
    md += ["| " + " | ".join(r) + " |" for r in rows]
    files.append(write_text_atomic(os.path.join(out, "comparison.md"), f"# {title}\n\n" + "\n".join(md) + "\n"))
    png = _save(comparison_figure(cells, title), os.path.join(out, "comparison.png"))
    files.append(png)
    body = [
        f"<h1>{html.escape(title)}</h1>",
        (
            "<p>Every listed estimator on every listed scenario: the estimators of one scenario run in one diagram "
            "per seed, on the same truth and the same sensor noise. RMSE over each scenario's scoring window, "
            "pooled over runs (95% CI); ANEES with the 95% band of a window average; RMSE / the posterior "
            "Cramér–Rao bound; time per estimator step from one run with that estimator alone (and its sources) "
            "minus the sensors-only run. Each scenario's own report: <code>&lt;scenario&gt;/report.html</code>.</p>"
        ),
        _table_html(COMPARISON_COLUMNS, rows),
        _figure_html(png, title),
    ]
    files.append(write_text_atomic(os.path.join(out, "comparison.html"), _page(title, "\n".join(body))))
    return files


# ----------------------------------------------------------------------------------------
# Headless browser
# ----------------------------------------------------------------------------------------
CHROMIUM_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """A Chromium (or Chrome) executable on PATH, or None."""
    for name in CHROMIUM_CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


def run_headless_chromium(chromium: str, html_path: str, args, timeout_s: float) -> subprocess.CompletedProcess:
    """Headless ``chromium`` on the local page ``html_path`` with extra ``args`` (a screenshot,
    ``--dump-dom``, ...), in a throw-away profile, no network services, the page's console on
    stderr (``:CONSOLE`` lines). Raises ``subprocess.TimeoutExpired`` after ``timeout_s``."""
    with tempfile.TemporaryDirectory(prefix="drake-att-chromium-") as profile:
        cmd = [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            f"--user-data-dir={profile}",
            "--enable-logging=stderr",
            "--v=0",
            *args,
            "file://" + os.path.abspath(html_path),
        ]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)


def render_in_browser(
    html_path: str,
    png_path: str,
    width: int = 1400,
    height: int = 3000,
    chromium: str | None = None,
    timeout_s: float = 120.0,
) -> list[str]:
    """Render ``html_path`` in headless Chromium, screenshot it to ``png_path`` and return
    the page's console messages (Chromium's ``CONSOLE`` log lines: script errors,
    ``console.*`` calls). RuntimeError when Chromium is missing or fails."""
    chromium = chromium or find_chromium()
    if chromium is None:
        raise RuntimeError("no Chromium found (Debian: apt-get install chromium)")
    html_path, png_path = os.path.abspath(html_path), os.path.abspath(png_path)
    try:
        p = run_headless_chromium(
            chromium, html_path, [f"--screenshot={png_path}", f"--window-size={width},{height}"], timeout_s
        )
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"Chromium did not finish within {timeout_s:g} s") from None
    if p.returncode != 0 or not os.path.isfile(png_path):
        raise RuntimeError(f"Chromium failed (exit {p.returncode}): {p.stderr.strip()[-500:]}")
    return [line for line in p.stderr.splitlines() if ":CONSOLE" in line]


def screenshot(html_path: str, png_path: str, **kwargs) -> str:
    """:func:`render_in_browser`, failing (RuntimeError) on any console message; returns
    ``png_path``."""
    console = render_in_browser(html_path, png_path, **kwargs)
    if console:
        raise RuntimeError(f"{html_path}: the page logged {len(console)} console message(s): {console[0][-300:]}")
    return png_path
