"""Monte Carlo over seeds: one diagram per worker process, reseeded for every run.

Diagrams and contexts do not pickle, so workers receive the scenario as YAML text plus
seeds, build the diagram once (pydrake 1.51 does not garbage-collect Python systems) and
return plain dictionaries.
"""

from __future__ import annotations

import multiprocessing as mp
import os

import numpy as np

from drake_att.analysis.metrics import compute_metrics, estimator_errors
from drake_att.scenarios.config import dump_scenario, load_scenario

_WORKER = {}


def _init_worker(yaml_text: str):
    from drake_att.scenarios.builder import diagram_for

    _WORKER["sd"] = diagram_for(load_scenario(text=yaml_text))


def _run_seed(args):
    seed, keep_series = args
    sd = _WORKER["sd"]
    run = sd.simulate(seed)
    out = {"metrics": compute_metrics(run)}
    if keep_series:
        series = {}
        for name in run.metadata["estimators"]:
            err = estimator_errors(run, name)
            series[name] = {"t": err["t"], "dtheta": err["dtheta"], "second_err": err["second_err"],
                              "sigma": np.sqrt(np.maximum(np.einsum("nii->ni", err["P"]), 0.0))}
        out["series"] = series
    return out


def run_monte_carlo(scenario, seeds, workers: int | None = None, keep_series_for=()) -> list[dict]:
    """Run ``scenario`` for every seed; returns per-seed ``{"metrics": ..., "series": ...}``.

    Args:
        scenario: a validated :class:`~drake_att.scenarios.config.Scenario`.
        seeds: iterable of ints.
        workers: processes (default: number of CPUs, at most the number of seeds).
        keep_series_for: seeds whose error time series are returned (for figures).
    """
    seeds = [int(s) for s in seeds]
    yaml_text = dump_scenario(scenario)
    workers = min(workers or os.cpu_count() or 1, len(seeds))
    jobs = [(s, s in set(keep_series_for)) for s in seeds]
    if workers <= 1:
        _init_worker(yaml_text)
        return [_run_seed(j) for j in jobs]
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers, initializer=_init_worker, initargs=(yaml_text,)) as pool:
        return pool.map(_run_seed, jobs)


def summarize(results: list[dict], key: str, estimator: str) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation over seeds of a per-axis metric (None entries dropped)."""
    vals = [r["metrics"]["estimators"][estimator][key] for r in results]
    vals = np.array([v for v in vals if v is not None], dtype=float)
    return vals.mean(axis=0), vals.std(axis=0, ddof=1) if len(vals) > 1 else np.zeros_like(vals[0])
