"""Write a run's results: metrics.json, log.npz, config.yaml, figures, diagram graph."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import numpy as np

from drake_att.analysis import metrics as met
from drake_att.analysis.plot_lines import PRINT_DPI, axes_width_px, line_points
from drake_att.noise import DEG, DEG_PER_H
from drake_att.scenarios.config import dump_scenario

FIGURE_DPI = 110  # the saved PNGs' resolution


def _error_ylim(err, three_sigma, floor):
    """Symmetric y-limit of an error plot over its whole run: every finite error sample is
    inside (the initial transient too, never clipped), and the +-3 sigma lines as well unless
    they exceed 3x the largest error (then they run off the plot, the error stays readable;
    an error that is exactly zero shows the whole +-3 sigma)."""

    def peak(x):
        x = np.abs(np.asarray(x, dtype=float))
        x = x[np.isfinite(x)]
        return float(x.max()) if x.size else 0.0

    e = peak(err)
    s = peak(three_sigma)
    return 1.05 * max(e, min(s, 3.0 * e) if e > 0 else s, floor)


def estimator_figures(run, name, score_from_s=0.0) -> dict:
    """The error figures of estimator ``name``: ``{"full": Figure, "stable": Figure}``
    (``"stable"`` only when ``score_from_s > 0`` and there are samples from then on).

    Each shows the per-axis attitude error with its +-3 sigma bounds (top row) and the bias or
    rate error (bottom row, when its truth is known), titled with the scenario, the seed and
    the estimator. The full figure's y-limits hold the whole error trajectory, initial
    transient included (see :func:`_error_ylim`); the stable figure (t >= ``score_from_s``)
    is zoomed on the scored stage. Plain matplotlib ``Figure`` objects (no pyplot, no
    backend switch): save them with ``fig.savefig``."""
    from matplotlib.figure import Figure

    e = met.estimator_errors(run, name)
    is_bias = e["second_kind"] == "gyro_bias"
    t = e["t"]
    sig = np.sqrt(np.maximum(np.einsum("nii->ni", e["P"]), 0.0))
    figures = {}
    axes_names = ["x (roll)", "y (pitch)", "z (yaw)"]
    for stage, sel in (("full", np.ones_like(t, dtype=bool)), ("stable", t >= score_from_s)):
        if stage == "stable" and (score_from_s <= 0 or not np.any(sel)):
            continue
        nrows = 2 if e["second_err"] is not None else 1
        fig = Figure(figsize=(14, 3.4 * nrows + 0.4), layout="constrained")
        ax = fig.subplots(nrows, 3, squeeze=False, sharex=True)
        width = axes_width_px(fig, 3, PRINT_DPI)  # the caller saves it
        for i in range(3):
            a = ax[0, i]
            a.plot(*line_points(t[sel], e["dtheta"][sel, i] / DEG, width), lw=0.7, label="error")
            a.plot(*line_points(t[sel], 3 * sig[sel, i] / DEG, width), "r--", lw=0.7, label="±3σ")
            a.plot(*line_points(t[sel], -3 * sig[sel, i] / DEG, width), "r--", lw=0.7)
            a.set_title(f"attitude error {axes_names[i]}")
            a.set_ylabel("deg")
            a.grid(True, alpha=0.3)
            if stage == "full":
                lim = _error_ylim(e["dtheta"][:, i] / DEG, 3 * sig[:, i] / DEG, 1e-6)
                a.set_ylim(-lim, lim)
            if e["second_err"] is not None:
                b = ax[1, i]
                scale, unit = (DEG_PER_H, "deg/h") if is_bias else (DEG, "deg/s")
                label = "bias error" if is_bias else "rate error"
                b.plot(*line_points(t[sel], e["second_err"][sel, i] / scale, width), lw=0.7)
                b.plot(*line_points(t[sel], 3 * sig[sel, 3 + i] / scale, width), "r--", lw=0.7)
                b.plot(*line_points(t[sel], -3 * sig[sel, 3 + i] / scale, width), "r--", lw=0.7)
                b.set_title(f"{label} {axes_names[i]}")
                b.set_ylabel(unit)
                b.grid(True, alpha=0.3)
                if stage == "full":
                    lim = _error_ylim(e["second_err"][:, i] / scale, 3 * sig[:, 3 + i] / scale, 1e-9)
                    b.set_ylim(-lim, lim)
        for a in ax[-1]:
            a.set_xlabel("time (s)")
        fig.legend(*ax[0, 0].get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=8)
        what = "whole run" if stage == "full" else f"stable stage, t >= {score_from_s:g} s"
        fig.suptitle(f"{run.scenario.name}, seed {run.seed}: estimator {name} ({what})")
        figures[stage] = fig
    return figures


def plot_estimator(run, name, out_dir, score_from_s=0.0) -> list[str]:
    """Save :func:`estimator_figures` as ``<name>_errors_{full,stable}.png`` in ``out_dir``;
    returns the files."""
    files = []
    for stage, fig in estimator_figures(run, name, score_from_s).items():
        path = os.path.join(out_dir, f"{name}_errors_{stage}.png")
        fig.savefig(path, dpi=FIGURE_DPI)
        files.append(path)
    return files


AXIS_NAMES = ["roll (x)", "pitch (y)", "yaw (z)"]


def plot_error_grid(
    series: dict,
    names,
    path: str,
    title: str,
    second_scale: float = DEG,
    second_unit: str = "deg/s",
    second_label: str = "gyro bias error",
    t_range=None,
    att_ylim=None,
    sec_ylim=None,
) -> str:
    """Paper-style figure comparing estimators: per-axis attitude error (top row, deg) and
    bias or rate error (bottom row, ``second_unit`` = SI / ``second_scale``) versus time.

    ``series[name]`` holds ``t`` (n,), ``dtheta`` (n, 3, rad) and ``second_err`` (n, 3, SI
    or None), e.g. from :func:`drake_att.analysis.metrics.estimator_errors`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(15, 7), sharex=True, layout="constrained")
    width = axes_width_px(fig, 3, FIGURE_DPI)
    for name in names:
        s = series[name]
        m = np.ones(len(s["t"]), dtype=bool) if t_range is None else (s["t"] >= t_range[0]) & (s["t"] <= t_range[1])
        for i in range(3):
            ax[0, i].plot(*line_points(s["t"][m], s["dtheta"][m, i] / DEG, width), lw=0.7, label=name)
            if s["second_err"] is not None:
                ax[1, i].plot(*line_points(s["t"][m], s["second_err"][m, i] / second_scale, width), lw=0.7, label=name)
    for i in range(3):
        ax[0, i].set_title(f"attitude error {AXIS_NAMES[i]}")
        ax[0, i].set_ylabel("deg")
        ax[1, i].set_title(f"{second_label} {AXIS_NAMES[i]}")
        ax[1, i].set_ylabel(second_unit)
        ax[1, i].set_xlabel("time (s)")
        if att_ylim:
            ax[0, i].set_ylim(*att_ylim)
        if sec_ylim:
            ax[1, i].set_ylim(*sec_ylim)
        for a in ax[:, i]:
            a.grid(True, alpha=0.3)
    fig.legend(*ax[0, 0].get_legend_handles_labels(), loc="outside lower center", ncols=len(names), fontsize=8)
    fig.suptitle(title)
    fig.savefig(path, dpi=FIGURE_DPI)
    plt.close(fig)
    return path


def write_diagram_graph(diagram, out_dir) -> list[str]:
    """``diagram.dot`` always; ``diagram.svg`` when Graphviz ``dot`` is installed."""
    dot_path = os.path.join(out_dir, "diagram.dot")
    with open(dot_path, "w") as f:
        f.write(diagram.GetGraphvizString(max_depth=1))
    files = [dot_path]
    dot = shutil.which("dot")
    if dot:
        svg_path = os.path.join(out_dir, "diagram.svg")
        subprocess.run([dot, "-Tsvg", dot_path, "-o", svg_path], check=True)
        files.append(svg_path)
    return files


def strict_json(value):
    """``value`` with every non-finite float replaced by ``None`` (strict JSON: ``null``,
    never ``NaN``/``Infinity``, which JSON does not have)."""
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_metrics_json(metrics: dict, path: str) -> str:
    """``metrics.json`` as :func:`write_results` writes it (``drake-att score`` rewrites it
    byte for byte); strict JSON (a non-finite number is written as ``null``)."""
    from drake_att.outputs import write_file_atomic

    return write_file_atomic(path, json.dumps(strict_json(metrics), indent=2, allow_nan=False).encode())


def write_results(scenario_diagram, run, metrics: dict, out_dir: str, figures: bool = True) -> list[str]:
    """Write every result file of one run into ``out_dir``, atomically; returns the paths.

    The files are written into a fresh sibling folder that then replaces ``out_dir`` in one
    rename (:func:`drake_att.outputs.replace_folder`): ``out_dir`` is complete or absent (an
    interruption or a failure leaves the previous results untouched), never a mix of two
    runs (a run without figures removes the previous run's PNGs). An existing ``out_dir`` is
    replaced only when it is empty or one of our run folders
    (:func:`drake_att.outputs.check_target`; :class:`~drake_att.outputs.OutputError`
    otherwise). ``log.npz`` holds the signals and the run's metadata, so ``metrics.json`` can
    be recomputed from ``log.npz`` + ``config.yaml`` alone (``drake-att score``)."""
    from drake_att import outputs

    if os.path.lexists(out_dir):
        outputs.check_target(out_dir)
    return outputs.replace_folder(
        out_dir,
        lambda staging: [
            os.path.basename(f) for f in _write_results_into(scenario_diagram, run, metrics, staging, figures)
        ],
    )


def _write_results_into(scenario_diagram, run, metrics: dict, out_dir: str, figures: bool) -> list[str]:
    files = [write_metrics_json(metrics, os.path.join(out_dir, "metrics.json"))]
    path = os.path.join(out_dir, "config.yaml")
    with open(path, "w") as f:
        f.write(f"# Resolved configuration of this run (seed {run.seed}).\n")
        f.write(dump_scenario(run.scenario))
    files.append(path)
    path = os.path.join(out_dir, "log.npz")
    # stored, not deflated: zlib cost ~20% of a 10 Hz run's process CPU for a 1.7x smaller file
    # (benchmarks/bench_log_writer.py); np.load reads either
    np.savez(path, **run.to_npz_dict())
    files.append(path)
    if figures:
        for name in run.metadata["estimators"]:
            files += plot_estimator(run, name, out_dir, run.scenario.scoring.score_from_s)
    files += write_diagram_graph(scenario_diagram.diagram, out_dir)
    files.append(write_manifest(out_dir, files, run))
    return files


MANIFEST = "manifest.json"


def manifest_entries(out_dir: str, files) -> list[dict]:
    """``{"file", "bytes", "sha256"}`` of each file, named relative to ``out_dir`` (the one
    home of the manifest format: run folders and Monte Carlo campaign folders)."""
    import hashlib

    entries = []
    for path in files:
        with open(path, "rb") as f:
            data = f.read()
        entries.append(
            {"file": os.path.relpath(path, out_dir), "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        )
    return entries


def manifest_problems(out_dir: str, entries) -> list[str]:
    """The entries whose file is missing or differs from its recorded size and SHA-256."""
    import hashlib

    problems = []
    for e in entries:
        p = os.path.join(out_dir, e["file"])
        if not os.path.isfile(p):
            problems.append(f"{e['file']}: missing")
            continue
        with open(p, "rb") as f:
            data = f.read()
        if len(data) != e["bytes"] or hashlib.sha256(data).hexdigest() != e["sha256"]:
            problems.append(f"{e['file']}: changed since it was written")
    return problems


def write_manifest(out_dir: str, files, run) -> str:
    """``manifest.json``: every file written (name, bytes, SHA-256), the scenario and seed —
    written last, so a folder with a manifest that matches its files is a complete result."""
    path = os.path.join(out_dir, MANIFEST)
    with open(path, "w") as f:
        json.dump(
            {"scenario": run.scenario.name, "seed": run.seed, "files": manifest_entries(out_dir, files)}, f, indent=1
        )
    return path


def check_manifest(out_dir: str) -> list[str]:
    """Problems of a result folder against its manifest (empty: complete and unmodified)."""
    path = os.path.join(out_dir, MANIFEST)
    if not os.path.isfile(path):
        return [f"{out_dir}: no {MANIFEST} (not a complete result folder)"]
    with open(path) as f:
        manifest = json.load(f)
    problems = manifest_problems(out_dir, manifest["files"])
    listed = {e["file"] for e in manifest["files"]} | {MANIFEST}
    problems += [f"{n}: not written by this run" for n in sorted(set(os.listdir(out_dir)) - listed)]
    return problems
