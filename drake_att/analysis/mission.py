"""What a mission day asks of the estimators: tracker availability, the gaps when every star
tracker is blinded, and each estimator's error over the day and inside the worst gap.

:func:`mission_record` reduces one run (a :class:`~drake_att.scenarios.builder.RunLog`) to numbers;
it is the record function the Monte Carlo runner (:func:`~drake_att.analysis.executor.map_runs`)
calls in each worker. :func:`summarize_mission` pools the records of many seeds: every figure as
the mean over seeds with its 95% Student-t interval ``mean -+ t(0.975, n-1) s / sqrt(n)``, and the
average NEES with the chi-square band of a consistent filter.

Definitions:

* a tracker is *out* at a sample whose logged validity flag is 0 (exclusion, drop-out, outage);
  *all out* where every star tracker with exclusion cones is out at the same sample time;
* a *gap* is a maximal run of consecutive all-out samples, lasting from its first sample to one
  tracker period past its last (the time without a tracker sample); the *worst* gap the longest
  of those that start in the scored part of the run (``scoring.score_from_s``: after the
  estimators' convergence);
* an estimator's *error in the gap* is over its estimates timed inside ``[start, end)``.
"""

from __future__ import annotations

import math

import numpy as np

from drake_att.analysis.ensemble import anees_band, t_q
from drake_att.analysis.metrics import compute_metrics, estimator_errors

DEG = math.pi / 180.0


def outage_runs(times, out) -> list[tuple[float, float]]:
    """``[(start, end), ...]`` of the maximal runs of consecutive samples with ``out`` true, each
    from its first sample's time to one sample period past its last (uniform sampling; the period
    of a single sample is unknown: 0)."""
    t = np.asarray(times, dtype=float)
    o = np.asarray(out, dtype=bool)
    if t.shape != o.shape or t.ndim != 1:
        raise ValueError(f"outage_runs: times {t.shape} and flags {o.shape} must be equal 1-D shapes")
    if t.size == 0:
        return []
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    edges = np.diff(np.r_[0, o.astype(np.int8), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b]) + dt) for a, b in zip(starts, ends, strict=True)]


def worst_gap(gaps, score_from_s: float) -> tuple[float, float] | None:
    """The longest of ``gaps`` (``(start, end)``) that starts at or after ``score_from_s`` (the
    first of equals), or None."""
    scored = [g for g in gaps if g[0] >= score_from_s]
    return max(scored, key=lambda g: g[1] - g[0]) if scored else None


def star_trackers_with_cones(run) -> list[str]:
    """The star trackers of the run that log an ``exclusion`` port (in the scenario's order)."""
    return [s.name for s in run.scenario.sensors if f"{s.name}/exclusion" in run.signals]


def tracker_validity(run, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(times, valid)`` of star tracker ``name``'s samples: the measurement's own flag."""
    t, x = run.signals[f"{name}/star_tracker_measurement"]
    return np.asarray(t, dtype=float), np.asarray(x, dtype=float)[:, 1] > 0.5


def all_out(run) -> tuple[np.ndarray, np.ndarray]:
    """``(times, flags)``: every star tracker with cones out at the same sample (their common
    sample times)."""
    names = star_trackers_with_cones(run)
    if not names:
        raise ValueError(f"{run.scenario.name}: no star tracker with exclusion cones to find gaps in")
    t, out = None, None
    for name in names:
        tn, valid = tracker_validity(run, name)
        if t is None:
            t, out = tn, ~valid
            continue
        common, i, j = np.intersect1d(np.round(t, 9), np.round(tn, 9), return_indices=True)
        t, out = t[i], out[i] & ~valid[j]
    assert t is not None and out is not None
    return t, out


def _error_deg(errors: dict, mask) -> tuple[float | None, float | None]:
    """``(RMS, max)`` of the attitude error's magnitude (deg) over the masked estimates."""
    d = np.linalg.norm(errors["dtheta"][mask], axis=1) / DEG
    if d.size == 0:
        return None, None
    return float(np.sqrt(np.mean(d * d))), float(np.max(d))


SERIES_STEP_S = 60.0  # the error history a record keeps: one estimate per minute


def mission_record(run) -> dict:
    """One run's mission figures (see the module). Keys: ``seed``; ``availability`` (per tracker,
    per cause, as :func:`~drake_att.analysis.metrics.tracker_availability`); ``all_out_fraction``,
    ``gaps`` (how many), ``worst_gap`` ``{start_s, end_s, duration_s}``; per estimator: attitude
    RMSE over the scored day, the 50th/95th percentile and maximum of the error's magnitude, its
    RMS and maximum in the worst gap, and the run's mean NEES with its dof; ``series``: per
    estimator its error's magnitude (deg) at its first estimate of every :data:`SERIES_STEP_S`,
    and every gap ``[start, end]`` (for a figure of the day)."""
    metrics = compute_metrics(run)
    t, out = all_out(run)
    gaps = outage_runs(t, out)
    score_from = run.scenario.scoring.score_from_s
    worst = worst_gap(gaps, score_from)
    estimators, series = {}, {}
    for name, m in metrics["estimators"].items():
        e = estimator_errors(run, name)
        grid = np.unique(np.searchsorted(e["t"], np.arange(0.0, e["t"][-1] + 1e-9, SERIES_STEP_S)))
        grid = grid[grid < len(e["t"])]
        series[name] = {
            "t_s": e["t"][grid].tolist(),
            "error_deg": (np.linalg.norm(e["dtheta"][grid], axis=1) / DEG).tolist(),
        }
        scored = e["t"] >= score_from
        d = np.linalg.norm(e["dtheta"][scored], axis=1) / DEG
        gap_rms, gap_max = (None, None)
        if worst is not None:
            gap_rms, gap_max = _error_deg(e, (e["t"] >= worst[0]) & (e["t"] < worst[1]))
        estimators[name] = {
            "rmse_deg": m["attitude_rmse_total_deg"],
            "p50_deg": float(np.percentile(d, 50)),
            "p95_deg": float(np.percentile(d, 95)),
            "max_deg": float(np.max(d)),
            "gap_rms_deg": gap_rms,
            "gap_max_deg": gap_max,
            "nees_mean": m["nees_mean"],
            "nees_dof": m["nees_dof"],
        }
    return {
        "seed": int(run.seed),
        "availability": {k: v["availability"] for k, v in metrics.get("sensors", {}).items()},
        "all_out_fraction": float(np.mean(out)) if out.size else 0.0,
        "gaps": len(gaps),
        "worst_gap": None
        if worst is None
        else {"start_s": worst[0], "end_s": worst[1], "duration_s": worst[1] - worst[0]},
        "estimators": estimators,
        "series": {"estimators": series, "gaps_s": [list(g) for g in gaps]},
    }


def interval(values, probability: float = 0.95) -> dict:
    """``{"mean", "lo", "hi", "n"}``: the mean of ``values`` (None entries dropped; every figure
    here is >= 0) with its Student-t interval, the lower end clipped at 0; ``lo``/``hi`` None
    below 2 values."""
    x = np.array([v for v in values if v is not None], dtype=float)
    if x.size == 0:
        return {"mean": None, "lo": None, "hi": None, "n": 0}
    mean = float(np.mean(x))
    if x.size < 2:
        return {"mean": mean, "lo": None, "hi": None, "n": 1}
    half = t_q(0.5 + 0.5 * probability, x.size - 1) * float(np.std(x, ddof=1)) / math.sqrt(x.size)
    return {"mean": mean, "lo": max(0.0, mean - half), "hi": mean + half, "n": int(x.size)}


def summarize_mission(records: list[dict]) -> dict:
    """Pool :func:`mission_record` outputs of several seeds (see the module)."""
    if not records:
        raise ValueError("summarize_mission: got no records")
    trackers = list(records[0]["availability"])
    causes = list(records[0]["availability"][trackers[0]]) if trackers else []
    summary: dict = {
        "seeds": [r["seed"] for r in records],
        "availability": {
            tr: {c: interval([r["availability"][tr][c] for r in records]) for c in causes} for tr in trackers
        },
        "all_out_fraction": interval([r["all_out_fraction"] for r in records]),
        "gaps": interval([r["gaps"] for r in records]),
        "worst_gap_s": interval([(r["worst_gap"] or {}).get("duration_s") for r in records]),
        "estimators": {},
    }
    for name, first in records[0]["estimators"].items():
        rows = [r["estimators"][name] for r in records]
        keys = ("rmse_deg", "p50_deg", "p95_deg", "max_deg", "gap_rms_deg", "gap_max_deg", "nees_mean")
        entry = {k: interval([row[k] for row in rows]) for k in keys}
        entry["nees_dof"] = first["nees_dof"]
        entry["anees_band"] = anees_band(len(rows), first["nees_dof"])
        summary["estimators"][name] = entry
    return summary


def _ci(x: dict, scale: float = 1.0, digits: int = 3) -> str:
    if x["mean"] is None:
        return "—"
    if x["lo"] is None:
        return f"{x['mean'] * scale:.{digits}g}"
    return f"{x['mean'] * scale:.{digits}g} [{x['lo'] * scale:.{digits}g}, {x['hi'] * scale:.{digits}g}]"


def format_mission_tables(summary: dict) -> str:  # pragma: no mutate block (presentation)
    """The summary as Markdown tables (availability; errors and consistency per estimator)."""
    n = len(summary["seeds"])
    lines = [
        f"Mean over {n} seeds with its 95% Student-t interval.",
        "",
        "| tracker | available (%) | Sun (%) | Earth limb (%) | Moon (%) |",
        "|---|---|---|---|---|",
    ]
    for tr, a in summary["availability"].items():
        lines.append(
            f"| {tr} | {_ci(a['available'], 100)} | {_ci(a['sun'], 100)} | {_ci(a['earth'], 100)} | {_ci(a['moon'], 100)} |"
        )
    lines += [
        "",
        f"All trackers out: {_ci(summary['all_out_fraction'], 100)} % of the day, in "
        f"{_ci(summary['gaps'])} gaps; the worst lasts {_ci(summary['worst_gap_s'])} s.",
        "",
        "| estimator | RMSE (deg) | median (deg) | 95th pct (deg) | max (deg) | worst gap RMS (deg) "
        "| worst gap max (deg) | ANEES (consistent band) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, e in summary["estimators"].items():
        lo, hi = e["anees_band"]
        lines.append(
            f"| {name} | {_ci(e['rmse_deg'])} | {_ci(e['p50_deg'])} | {_ci(e['p95_deg'])} | {_ci(e['max_deg'])} "
            f"| {_ci(e['gap_rms_deg'])} | {_ci(e['gap_max_deg'])} | {_ci(e['nees_mean'])} "
            f"({e['nees_dof']} dof: {lo:.2f}–{hi:.2f}) |"
        )
    return "\n".join(lines) + "\n"
