"""What the CLI prints and the report figures draw fit where they are read: the run, campaign
and comparison tables fit 100 columns without trailing spaces (names as long as the longest
shipped estimator's), a noise-free estimator's NEES carries a footnote that says why it means
nothing (decided from the config), the campaign report states the duration that ran next to the
scenario's description, and the figures' y-limits, legends, line styles and texts show every
curve inside the figure."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest

from drake_att.analysis import metrics
from drake_att.cli import main as cli_main
from drake_att.scenarios import library
from drake_att.scenarios.config import apply_overrides

WIDTH = 100


def _shipped():
    return {name: library.load(name) for name in library.available_scenarios()}


@pytest.fixture(scope="module")
def shipped():
    return _shipped()


@pytest.fixture(scope="module")
def longest_name(shipped):
    """The longest estimator name of the shipped scenarios."""
    return max((e.name for s in shipped.values() for e in s.estimators), key=len)


def _assert_fits(text: str) -> None:
    """Every line within ``WIDTH`` columns, in bytes too (``awk '{print length}'`` counts bytes
    in some awks), without trailing spaces."""
    for line in text.splitlines():
        assert len(line.encode()) <= WIDTH, (len(line.encode()), line)
        assert line == line.rstrip(), repr(line)


# ----------------------------------------------------------------------------------------
# The run table
# ----------------------------------------------------------------------------------------
def _record(second: str, nees):
    """One estimator's metrics with the widest numbers ``.3g`` prints (8 characters)."""
    return {
        "attitude_rmse_deg": [1.23e-05, 0.000123, 1.23e05],
        "attitude_mae_deg": [9.87e-05, 0.000987, 9.87e05],
        "attitude_rmse_total_deg": 1.23e-05,
        "bias_rmse_deg_per_h": [1.23e-05, 0.000123, 1.23e05] if second == "b" else None,
        "rate_rmse_deg_per_s": [4.56e-05, 0.000456, 4.56e05] if second == "w" else None,
        "convergence_time_s": 123456.7,
        "nees_mean": nees,
        "nees_dof": 6 if second else 3,
        "scored_from_s": 500.0,
        "samples_scored": 10,
        "measurements_used": 1234567,
        "measurements_skipped": 89012,
    }


def test_run_table_fits_100_columns_with_the_longest_shipped_name(longest_name):
    assert len(longest_name) >= 20  # the shipped names are not all short (the test is not vacuous)
    est = {longest_name: _record("b", 1.21e08), "mekf": _record("w", 6.05), "plain": _record("", None)}
    text = metrics.format_table(
        {
            "scenario": "cubesat_dual_star_tracker",
            "seed": 123,
            "duration_s": 5000.0,
            "wall_time_s": 22.9,
            "estimators": est,
        }
    )
    _assert_fits(text)
    for needed in ("1.23e-05", "0.000123", "1.23e+05", "9.87e-05", "4.56e-05", "123456.7", "1.21e+08", "1234567/89012"):
        assert needed in text  # every number is still printed
    assert "NEES dof: 3 (plain), 6 (" + longest_name + ", mekf)" in text.replace("\n ", " ")


def test_drake_att_run_prints_a_table_within_100_columns_and_explains_a_noise_free_nees(tmp_path, capsys):
    """``s2_indoor_static``: its camera has no centroid noise and no quantization, so the
    estimator's covariance is only its floor and the NEES (~1e8) is flagged with a footnote."""
    code = cli_main(["run", "s2_indoor_static", "--quiet", "--no-figures", "--out", str(tmp_path / "r")])
    out = capsys.readouterr().out
    assert code == 0
    table = out.split("\nWrote ")[0]
    _assert_fits(table)
    rows = [line for line in table.splitlines() if line.startswith("indoor_star_tracker ")]
    assert len(rows) == 2 and rows[1].split()[-2].endswith("*")  # the NEES, marked
    assert float(rows[1].split()[-2].rstrip("*")) > 1e6
    note = " ".join(line.strip() for line in table.splitlines() if line.startswith(("* ", " ")))
    assert "* noise-free measurements (indoor_star_tracker: camera)" in note
    assert "does not measure consistency" in note


def _metrics_of(scenario, nees=1.0e8):
    return {
        "scenario": scenario.name,
        "seed": 1,
        "duration_s": scenario.duration_s,
        "wall_time_s": 0.0,
        "estimators": {e.name: _record("w", nees) for e in scenario.estimators},
    }


def test_the_noise_free_footnote_follows_the_config_not_the_scenario_name(shipped):
    static = copy.deepcopy(shipped["s2_indoor_static"])
    assert metrics.noise_free_estimators(static) == {"indoor_star_tracker": ["camera"]}
    static.name = "my_bench"  # another name, the same config: still flagged
    assert "* noise-free measurements" in metrics.format_table(_metrics_of(static), static)
    for noisy in ("sensors.camera.centroid_noise_px=0.1", "sensors.camera.quantization_px=1"):
        s = apply_overrides(shipped["s2_indoor_static"], [noisy])
        assert metrics.noise_free_estimators(s) == {}
        text = metrics.format_table(_metrics_of(s), s)
        assert "noise-free" not in text and "*" not in text
    # the dynamic test's camera is noisy; made noise-free, both of its estimators are flagged
    dynamic = apply_overrides(shipped["s2_indoor_dynamic"], ["sensors.camera.centroid_noise_px=0"])
    assert shipped["s2_indoor_dynamic"].sensors[1].centroid_noise_px > 0
    assert metrics.noise_free_estimators(shipped["s2_indoor_dynamic"]) == {}
    assert set(metrics.noise_free_estimators(dynamic)) == {e.name for e in dynamic.estimators}
    # without the config, no footnote
    assert "noise-free" not in metrics.format_table(_metrics_of(static))


def test_no_shipped_scenario_but_s2_static_has_a_noise_free_estimator(shipped):
    """Star trackers (quaternion or vector mode) always have noise: a fusion of trackers
    (``centralized``, ``decentralized``) is never flagged."""
    flagged = {name: metrics.noise_free_estimators(s) for name, s in shipped.items()}
    assert {n: f for n, f in flagged.items() if f} == {"s2_indoor_static": {"indoor_star_tracker": ["camera"]}}


# ----------------------------------------------------------------------------------------
# The campaign and comparison tables
# ----------------------------------------------------------------------------------------
SCENARIO = "cubesat_single_star_tracker"
SHORT = ["duration_s=60", "scoring.score_from_s=20"]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory, longest_name):
    """A 3-run, 60-s campaign of the single-tracker scenario whose estimator is renamed to the
    longest shipped name, with its report."""
    from drake_att.analysis import montecarlo as mc

    out = str(tmp_path_factory.mktemp("campaign") / "c")
    overrides = [*SHORT, f"estimators.single.name={longest_name}"]
    return mc.run_campaign(SCENARIO, 3, overrides=overrides, workers=1, out=out, progress=False)


def test_campaign_table_fits_100_columns_and_keeps_its_numbers(campaign, longest_name):
    from drake_att.analysis import campaign_report

    text = campaign_report.format_campaign_table(campaign)
    _assert_fits(text)
    s = campaign.summary["estimators"][longest_name]
    rows = [line for line in text.splitlines() if line.startswith(longest_name + " ")]
    assert len(rows) == 2
    printed = " ".join(rows)
    for value in (
        s["attitude_rmse_total_deg"],
        *s["attitude_rmse_total_ci95_deg"],
        *s["attitude_rmse_deg"],
        s["bound"]["attitude_rmse_total_bound_deg"],
        *s["bound"]["ratio"],
        s["anees"],
    ):
        assert f"{value:.3g}" in printed, value
    assert f"{s['convergence']['n_converged']}/3" in printed


def _cell(scenario, estimator, **kw):
    cell = {
        "scenario": scenario,
        "estimator": estimator,
        "ran": True,
        "why": None,
        "runs": 1000,
        "attitude_rmse_total_deg": 0.000123,
        "attitude_rmse_total_ci95_deg": [0.000111, 0.000135],
        "attitude_rmse_deg": [0.000456, 0.000789, 1.23e-05],
        "anees": 123.0,
        "nees_dof": 6,
        "anees_band_95": [5.22, 6.82],
        "anees_in_band": False,
        "bound_total_deg": 0.000101,
        "ratio_to_bound_total": 1.22,
        "bound_reason": None,
        "converged": "1000/1000",
        "ms_per_step": 12.345,
    }
    cell.update(kw)
    return cell


def test_comparison_text_fits_100_columns_without_trailing_spaces(longest_name):
    from drake_att.analysis import campaign_report

    why = "not an estimator of this scenario (SOURCE:NAME adds one from another scenario)"
    reason = "the estimator reads no gyro: the bound is for gyro-driven attitude determination"
    cells = [
        _cell("cubesat_single_star_tracker", longest_name),
        {"scenario": "cubesat_single_star_tracker", "estimator": "joint", "ran": False, "why": why},
        _cell("s0_particle_filters_small_error", longest_name, ratio_to_bound_total=None, bound_reason=reason),
        _cell("s0_particle_filters_small_error", "mekf"),
    ]
    text = campaign_report.comparison_text(cells)
    _assert_fits(text)
    for needed in ("0.000123", "[0.000111, 0.000135]", "0.000456 / 0.000789 / 1.23e-05", "123 (6)", "[5.22, 6.82] OUT"):
        assert needed in text
    assert "1.22" in text and "12.345" in text and "1000/1000" in text
    lines = text.splitlines()
    # each reason once, numbered, and every cell it explains points to its number
    assert [line for line in lines if line.startswith("(1) ")] == [f"(1) {why}"]
    assert " ".join(ln.strip() for ln in lines[lines.index(next(ln for ln in lines if ln.startswith("(2) "))) :]) == (
        f"(2) {reason}"
    )
    assert sum(line.startswith("joint ") and "n/a (1)" in line for line in lines) == 2
    assert sum("no bound (2)" in line for line in lines) == 1
    assert sum(line == "scenario s0_particle_filters_small_error:" for line in lines) == 2


def test_a_negative_cost_points_to_the_timing_noise_note():
    """A per-step cost below zero (the difference of two noisy wall times) is printed as measured,
    with a numbered note that says what it means; a positive one gets no note."""
    from drake_att.analysis import campaign_report

    cells = [
        _cell("s", "fast", ms_per_step=-0.161),
        _cell("s", "slow", ms_per_step=0.5),
        _cell("s", "free", ms_per_step=0.0),
    ]
    lines = campaign_report.comparison_text(cells).splitlines()
    fast = [line for line in lines if line.startswith("fast ") and "-0.161" in line]
    assert len(fast) == 1 and "-0.161 (1)" in fast[0], lines
    assert not any("0.500 (" in line or "0.000 (" in line for line in lines), lines  # zero is not below zero
    note = " ".join(ln.strip() for ln in lines[lines.index(next(ln for ln in lines if ln.startswith("(1) "))) :])
    assert note == f"(1) {campaign_report.BELOW_TIMING_NOISE}"


def test_drake_att_compare_prints_within_100_columns(tmp_path, capsys):
    code = cli_main(
        ["compare", SCENARIO, "--estimators", "single,nope", "--runs", "1", "--workers", "1", "--quiet"]
        + ["--out", str(tmp_path / "cmp")]
        + [x for s in SHORT for x in ("--set", s)]
    )
    out = capsys.readouterr().out
    assert code == 0
    table = out.split("\nWrote ")[0]
    _assert_fits(table)
    rows = [line.split() for line in table.splitlines() if line.startswith("nope ")]
    # The note's number depends on which notes come first (a timing below the noise gets one
    # too, by the machine's load): read it from the note itself.
    notes = re.findall(r"^\((\d+)\) not an estimator of this scenario", table, flags=re.M)
    assert len(notes) == 1, table
    n = f"({notes[0]})"
    assert rows == [["nope", "–", "n/a", n], ["nope", "n/a", n]]  # accuracy, consistency


# ----------------------------------------------------------------------------------------
# The campaign report's description
# ----------------------------------------------------------------------------------------
def test_no_shipped_description_names_a_duration_that_set_can_change(shipped):
    import re

    for name, s in shipped.items():
        text = " ".join(s.description.split())
        assert not re.search(rf"(?<![\d.]){s.duration_s:g} s\b", text), (name, text)
        assert not re.search(r"\d+ orbits?\b", text), (name, text)


def test_campaign_report_states_the_duration_that_ran_next_to_the_description(campaign):
    import html
    import os
    import re

    with open(os.path.join(campaign.out, "report.html")) as f:
        page = html.unescape(f.read())
    row = re.search(r"<tr><td>description</td><td>(.*?)</td></tr>", page).group(1)
    description = " ".join(library.load(SCENARIO).description.split())
    assert row.startswith(description)
    assert "[as run: 60 s per run, scored from t ≥ 20 s;" in row


# ----------------------------------------------------------------------------------------
# The figures
# ----------------------------------------------------------------------------------------
NAME = "est"


def _records(n_runs=3, n=600, amplitude_deg=0.01, sigma_deg=0.001, sigma0_deg=None, bound=True, seed=0):
    """Synthetic campaign records: every error sample is +-``amplitude_deg`` (random signs), so
    the ensemble's RMS is ``amplitude_deg`` at every instant and its +-3 RMS three times the
    largest error; the filters' sigma is ``sigma_deg`` (``sigma0_deg`` at t = 0)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    out = []
    for _ in range(n_runs):
        d = amplitude_deg * np.deg2rad(1.0) * rng.choice([-1.0, 1.0], size=(n, 3))
        sig = np.full((n, 6), np.deg2rad(sigma_deg))
        if sigma0_deg is not None:
            sig[0, :3] = np.deg2rad(sigma0_deg)
        rec = {f"{NAME}__t": t, f"{NAME}__dtheta": d, f"{NAME}__sigma": sig}
        if bound:
            rec[f"{NAME}__bound_sigma"] = 1.0001 * sig  # the bound equals the filter's sigma
        out.append(rec)
    return out


def _lines(fig, label):
    return [line for ax in fig.axes for line in ax.get_lines() if line.get_label() == label]


def _legend_texts(fig):
    from matplotlib.legend import Legend

    return [t.get_text() for leg in fig.findobj(Legend) for t in leg.get_texts()]


def test_error_figure_y_limits_hold_the_ensemble_three_rms_with_few_runs():
    from drake_att.analysis import campaign_report

    records = _records(n_runs=3)
    fig = campaign_report.error_ensemble_figure(records, NAME, 300.0, "t")
    three_rms = 3 * np.sqrt(np.mean([np.rad2deg(r[f"{NAME}__dtheta"]) ** 2 for r in records], axis=0)).max()
    assert three_rms == pytest.approx(0.03)  # three times every error sample
    axes = [ax for ax in fig.axes if ax.get_lines()]
    assert len(axes) == 6
    for ax in axes:
        lo, hi = ax.get_ylim()
        assert lo <= -three_rms and hi >= three_rms, (ax.get_title(), lo, hi)
        for line in ax.get_lines():  # every plotted curve is inside
            y = np.asarray(line.get_ydata(), dtype=float)
            assert lo <= y.min() and y.max() <= hi, (ax.get_title(), line.get_label())


def test_error_figure_names_an_envelope_that_runs_off():
    """An initial sigma of 10 deg next to 0.01-deg errors: the whole-run plots stop at 3x the
    data and their titles say the filter's (and bound's) +-3 sigma runs off, with its peak."""
    from drake_att.analysis import campaign_report

    fig = campaign_report.error_ensemble_figure(_records(sigma0_deg=10.0), NAME, 300.0, "t")
    whole = [ax for ax in fig.axes if "whole run" in ax.get_title()]
    scored = [ax for ax in fig.axes if "scored" in ax.get_title()]
    assert len(whole) == len(scored) == 3
    for ax in whole:
        title = " ".join(ax.get_title().split())
        assert "filter ±3σ runs off (peak 30 deg)" in title and "bound ±3σ runs off" in title
        assert ax.get_ylim()[1] < 30.0
    for ax in scored:
        assert "runs off" not in ax.get_title()


def test_filter_sigma_and_bound_lines_differ_in_color_and_style_and_each_has_a_legend_entry():
    from matplotlib.colors import to_rgba

    from drake_att.analysis import campaign_report

    fig = campaign_report.error_ensemble_figure(_records(), NAME, 300.0, "t")
    filt = _lines(fig, "filter ±3σ (RMS over runs)")
    bound = _lines(fig, "Cramér–Rao bound ±3σ")
    assert filt and bound
    f, b = filt[0], bound[0]
    assert to_rgba(f.get_color())[:3] != to_rgba(b.get_color())[:3]
    assert f.get_linestyle() != b.get_linestyle()
    assert f.get_zorder() > b.get_zorder() and b.get_linewidth() > 2 * f.get_linewidth()  # both show when equal
    texts = _legend_texts(fig)
    assert "filter ±3σ (RMS over runs)" in texts and "Cramér–Rao bound ±3σ" in texts


def _inside(extent, box) -> bool:
    return box.x0 - 1 <= extent.x0 and extent.x1 <= box.x1 + 1 and box.y0 - 1 <= extent.y0 and extent.y1 <= box.y1 + 1


def _assert_laid_out(fig):
    """After drawing: every visible text (titles, axis labels, legend entries) lies inside the
    figure, so do the drawn tick labels (each axes' tight box), and no legend overlaps a plot."""
    from matplotlib.legend import Legend
    from matplotlib.text import Text

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    ticks = {
        id(label)
        for ax in fig.axes
        for axis in (ax.xaxis, ax.yaxis)
        for tick in axis.get_major_ticks() + axis.get_minor_ticks()
        for label in (tick.label1, tick.label2)
    }
    texts = [t for t in fig.findobj(Text) if id(t) not in ticks and t.get_visible() and t.get_text().strip()]
    assert any(t is fig._suptitle for t in texts)
    for t in texts:
        assert _inside(t.get_window_extent(renderer), box), (t.get_text()[:60], t.get_window_extent(renderer))
    for ax in fig.axes:
        assert _inside(ax.get_tightbbox(renderer), box), ax.get_title()[:60]
    legends = fig.findobj(Legend)
    assert legends
    for leg in legends:
        e = leg.get_window_extent(renderer)
        for ax in fig.axes:
            assert not e.overlaps(ax.get_window_extent(renderer)), (ax.get_title()[:60], e)


def _cells(n=8):
    names = ["indoor_star_tracker_gyro", "lie_group_paper_literal", "bootstrap_pf_roughened", "mekf"]
    return [
        _cell(
            ["cubesat_single_star_tracker", "s0_particle_filters_small_error"][k % 2],
            names[k % len(names)],
            attitude_rmse_total_deg=10.0 ** -(k % 5),
            attitude_rmse_total_ci95_deg=[0.9 * 10.0 ** -(k % 5), 1.1 * 10.0 ** -(k % 5)],
            bound_total_deg=0.5 * 10.0 ** -(k % 5),
            anees=6.0 * 10.0 ** (k % 4),
            ms_per_step=0.01 * 10.0 ** (k % 3),
        )
        for k in range(n)
    ]


@pytest.mark.parametrize("n", [2, 8])
def test_comparison_figure_keeps_labels_titles_and_legend_inside_and_off_the_plots(n):
    from drake_att.analysis import campaign_report

    fig = campaign_report.comparison_figure(_cells(n), "Comparison: 2 scenarios x 4 estimators, 1000 runs")
    _assert_laid_out(fig)
    assert [ax.get_legend() for ax in fig.axes] == [None] * 4  # the legend is the band's, above the plots


def test_campaign_figures_keep_texts_inside_and_legends_off_the_plots(campaign, longest_name):
    from drake_att.analysis import campaign_report

    s = campaign.summary
    figures = {
        "errors": campaign_report.error_ensemble_figure(campaign.records, longest_name, 20.0, "errors"),
        "consistency": campaign_report.consistency_figure(
            campaign.records, longest_name, s["estimators"][longest_name], "consistency"
        ),
        "rmse_vs_bound": campaign_report.rmse_vs_bound_figure(s, "rmse vs bound"),
    }
    for fig in figures.values():
        _assert_laid_out(fig)


def test_a_runs_error_figures_keep_texts_inside_and_the_legend_off_the_plots():
    """``drake-att run``'s per-estimator figures (whole run and stable stage)."""
    from drake_att.analysis.report import estimator_figures
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load

    scenario = apply_overrides(load(SCENARIO), SHORT)
    run = ScenarioDiagram(scenario).simulate(1)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    figures = estimator_figures(run, "single", scenario.scoring.score_from_s)
    assert set(figures) == {"full", "stable"}
    for fig in figures.values():
        FigureCanvasAgg(fig)  # what savefig uses
        _assert_laid_out(fig)
        assert [ax.get_legend() for ax in fig.axes] == [None] * len(fig.axes)  # the figure's legend, below


def test_error_figure_lines_keep_every_pixel_columns_extremes():
    """Long runs are drawn reduced (drake_att.analysis.plot_lines): in the saved figure's pixel
    columns each run's drawn line reaches the run's largest and smallest error of that column,
    to the half pixel a bucket may straddle, and holds far fewer points than the run."""
    from drake_att.analysis import campaign_report

    rng = np.random.default_rng(11)
    n = 20_000
    t = np.arange(n) * 0.25
    records = []
    for _ in range(3):
        d = np.deg2rad(1e-3) * np.cumsum(rng.standard_normal((n, 3)), axis=0)
        sig = np.full((n, 6), np.deg2rad(0.05))
        records.append({f"{NAME}__t": t, f"{NAME}__dtheta": d, f"{NAME}__sigma": sig})
    fig = campaign_report.error_ensemble_figure(records, NAME, 0.0, "t")
    fig.set_dpi(campaign_report.FIGURE_DPI)
    fig.draw_without_rendering()
    runs = _lines(fig, f"error, {len(records)} of {len(records)} runs")
    assert len(runs) == 3  # the label is on each axis' first run
    for ax in fig.axes:
        lines = [line for line in ax.get_lines() if line.get_color() == "tab:blue"]
        if not lines:
            continue
        i = [k for k, name in enumerate(campaign_report.AXES) if name in ax.get_title()][0]
        x0, x1 = ax.transData.transform([[t[0], 0.0], [t[-1], 0.0]])[:, 0]
        for j, line in enumerate(lines):
            drawn_t, drawn_y = np.asarray(line.get_xdata()), np.asarray(line.get_ydata())
            assert len(drawn_t) < n / 4
            full_y = np.rad2deg(records[j][f"{NAME}__dtheta"][:, i])
            columns = int(np.ceil(x1 - x0))

            def column(times, x0=x0, x1=x1, columns=columns):
                return np.minimum(((times - t[0]) / (t[-1] - t[0]) * (x1 - x0)).astype(int), columns - 1)

            full_c, drawn_c = column(t), column(drawn_t)
            hi = np.full(columns, -np.inf)
            lo = np.full(columns, np.inf)
            drawn_hi, drawn_lo = hi.copy(), lo.copy()
            np.maximum.at(hi, full_c, full_y)
            np.minimum.at(lo, full_c, full_y)
            np.maximum.at(drawn_hi, drawn_c, drawn_y)
            np.minimum.at(drawn_lo, drawn_c, drawn_y)
            near = lambda v, pick: pick(np.stack([np.r_[v[:1], v[:-1]], v, np.r_[v[1:], v[-1:]]]), axis=0)  # noqa: E731
            eps = 1e-12 * np.max(np.abs(full_y))  # deg from rad: the figure divides, this test multiplies
            assert np.all(near(drawn_hi, np.max) >= hi - eps) and np.all(drawn_hi <= near(hi, np.max) + eps)
            assert np.all(near(drawn_lo, np.min) <= lo + eps) and np.all(drawn_lo >= near(lo, np.min) - eps)


def test_error_figure_envelopes_are_plus_and_minus_three_sigma():
    """Each panel's filter and bound envelopes are drawn at +3 sigma and at -3 sigma (the
    records' sigma is 0.001 deg everywhere, the bound's 1.0001 times it)."""
    from drake_att.analysis import campaign_report

    fig = campaign_report.error_ensemble_figure(_records(n=6000), NAME, 300.0, "t")
    for ax in [ax for ax in fig.axes if ax.get_lines()]:
        for style, value in ((campaign_report.FILTER_STYLE, 0.003), (campaign_report.BOUND_STYLE, 0.0030003)):
            ys = [np.asarray(ln.get_ydata()) for ln in ax.get_lines() if ln.get_linewidth() == style["lw"]]
            assert len(ys) == 2, ax.get_title()
            np.testing.assert_allclose(sorted(float(np.mean(y)) for y in ys), [-value, value], rtol=1e-9)


def test_consistency_and_rmse_history_lines_hold_every_point_of_a_short_history(campaign, longest_name):
    """A history shorter than a few points per pixel is drawn as it is: the ANEES line and the
    RMS-over-runs line hold every instant of the summary's history."""
    from drake_att.analysis import campaign_report

    stats = campaign.summary["estimators"][longest_name]
    n = len(stats["history"]["t"])
    consistency = campaign_report.consistency_figure(campaign.records, longest_name, stats, "c")
    anees = _lines(consistency, f"ANEES over {stats['n_runs']} runs (dof {stats['nees_dof']})")
    rmse = _lines(campaign_report.rmse_vs_bound_figure(campaign.summary, "r"), longest_name)
    assert n > 8 * 2 and len(anees) == 1 and len(rmse) == 1
    np.testing.assert_array_equal(anees[0].get_xdata(), np.asarray(stats["history"]["t"], dtype=float))
    assert len(rmse[0].get_xdata()) == n
