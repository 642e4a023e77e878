"""Records: what a worker returns for one run (a function of its
:class:`~drake_att.scenarios.builder.RunLog`, computed where the run is), and the name a
campaign folder keeps of the record function."""

from __future__ import annotations

import functools
import json
from collections.abc import Callable

import numpy as np

# The name campaign folders store for the records defined here (``campaign.json``'s
# ``record``): their public module, so a folder resumes whichever module defines them.
PUBLIC_MODULE = "drake_att.analysis.montecarlo"


def metrics_record(run) -> dict:
    """The smallest record: the run's metrics (:func:`~drake_att.analysis.metrics.compute_metrics`) as a JSON string
    under ``"metrics_json"``."""
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.analysis.report import strict_json

    return {"metrics_json": np.array(json.dumps(strict_json(compute_metrics(run))))}


def default_record(run) -> dict:
    """A campaign's record of one run: :func:`drake_att.analysis.ensemble.per_run_record`."""
    from drake_att.analysis import ensemble

    return ensemble.per_run_record(run)


default_record.optional_key_suffixes = ("__bound_sigma", "__bound_window_var")


def metrics_and_series_record(run, keep_series_for=()) -> dict:
    """``{"metrics": compute_metrics(run)}`` plus, for a seed in ``keep_series_for``,
    ``"series"``: estimator -> ``t``, ``dtheta`` (rad), ``second_err`` (SI or None) and
    ``sigma`` (the covariance's 6 standard deviations)."""
    from drake_att.analysis.metrics import compute_metrics, estimator_errors

    out = {"metrics": compute_metrics(run)}
    if run.seed in keep_series_for:
        series = {}
        for name in run.metadata["estimators"]:
            err = estimator_errors(run, name)
            series[name] = {
                "t": err["t"],
                "dtheta": err["dtheta"],
                "second_err": err["second_err"],
                "sigma": np.sqrt(np.maximum(np.einsum("nii->ni", err["P"]), 0.0)),
            }
        out["series"] = series
    return out


def timing_record(run) -> dict:
    """Wall time of a run and the steps each of its estimators took (the timing runs of
    :func:`drake_att.analysis.comparison.run_comparison`)."""
    steps = {}
    for name, spec in run.metadata["estimators"].items():
        status = run.values(spec["signals"]["status"])
        steps[name] = len(np.unique(status[np.isfinite(status[:, 0]), 0]))
    return {"wall_time_s": float(run.wall_time_s), "steps": steps}


def record_name(record: Callable) -> str:
    """``module:qualname`` of a record function (a ``functools.partial`` with its
    arguments): what a campaign folder remembers, so a resume uses the same one."""
    if isinstance(record, functools.partial):
        args = ", ".join([repr(a) for a in record.args] + [f"{k}={v!r}" for k, v in sorted(record.keywords.items())])
        return f"{record_name(record.func)}({args})"
    module = PUBLIC_MODULE if record.__module__ == __name__ else record.__module__
    return f"{module}:{record.__qualname__}"
