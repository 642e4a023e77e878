"""Monte Carlo over seeds: the public names of the modules that do it, in one place.

* :mod:`~drake_att.analysis.executor`: where runs execute (:func:`map_runs`, the worker
  side, serial or Dask) and the paper scripts' :func:`run_seeds`;
* :mod:`~drake_att.analysis.run_records`: what a worker returns for one run;
* :mod:`~drake_att.analysis.campaign`: :func:`run_campaign` (``drake-att montecarlo``);
* :mod:`~drake_att.analysis.campaign_folder`: the campaign folder, written and read back;
* :mod:`~drake_att.analysis.comparison`: :func:`run_comparison` (``drake-att compare``);
* :mod:`~drake_att.analysis.dask_connection` (reaching Dask) and
  :mod:`~drake_att.analysis.campaign_records` (a saved run).
"""

from __future__ import annotations

from drake_att.analysis.campaign import (
    CampaignProgress,
    CampaignResult,
    campaign_seeds,
    default_summarize,
    resolve_scenario,
    run_campaign,
    select_estimators,
)
from drake_att.analysis.campaign_folder import (
    CAMPAIGN_FILE,
    CONFIG_FILE,
    CONFIG_HEADER,
    MANIFEST_FILE,
    MAX_SIDE_FILE_BYTES,
    SUMMARY_FILE,
    check_campaign_manifest,
    write_campaign_manifest,
)
from drake_att.analysis.campaign_records import (
    MAX_RECORD_BYTES,
    RUNS_DIR,
    default_record_problem,
    load_record,
    record_layout,
    save_record,
    write_text_atomic,
)
from drake_att.analysis.comparison import ComparisonPlan, ComparisonResult, comparison_plan, run_comparison
from drake_att.analysis.dask_connection import (
    CONNECT_STEP_MIN_S,
    DEFAULT_CONNECT_TIMEOUT_S,
    MAX_CONNECT_TIMEOUT_S,
    CampaignError,
    check_connect_timeout,
    check_scheduler_address,
    connect_scheduler,
    local_cluster,
)
from drake_att.analysis.executor import SERIAL, RunFailed, map_runs, metric_mean_std, run_seeds, worker_stats
from drake_att.analysis.run_records import (
    default_record,
    metrics_and_series_record,
    metrics_record,
    record_name,
    timing_record,
)

__all__ = [
    "CAMPAIGN_FILE",
    "CONFIG_FILE",
    "CONFIG_HEADER",
    "CONNECT_STEP_MIN_S",
    "DEFAULT_CONNECT_TIMEOUT_S",
    "MANIFEST_FILE",
    "MAX_CONNECT_TIMEOUT_S",
    "MAX_RECORD_BYTES",
    "MAX_SIDE_FILE_BYTES",
    "RUNS_DIR",
    "SERIAL",
    "SUMMARY_FILE",
    "CampaignError",
    "CampaignProgress",
    "CampaignResult",
    "ComparisonPlan",
    "ComparisonResult",
    "RunFailed",
    "campaign_seeds",
    "check_campaign_manifest",
    "check_connect_timeout",
    "check_scheduler_address",
    "comparison_plan",
    "connect_scheduler",
    "default_record",
    "default_record_problem",
    "default_summarize",
    "load_record",
    "local_cluster",
    "map_runs",
    "metric_mean_std",
    "metrics_and_series_record",
    "metrics_record",
    "record_layout",
    "record_name",
    "resolve_scenario",
    "run_campaign",
    "run_comparison",
    "run_seeds",
    "save_record",
    "select_estimators",
    "timing_record",
    "worker_stats",
    "write_campaign_manifest",
    "write_text_atomic",
]
