"""The comparison matrix (``drake-att compare``): every listed estimator on every listed
scenario, one campaign per scenario on one shared cluster, plus a timing run per estimator.

``SCENARIO:NAME`` copies an estimator's config into other scenarios and re-validates them,
so a cell that cannot run says why (:func:`comparison_plan`); :func:`run_comparison` runs
the plan and writes ``comparison.{json,md,png,html}``
(:mod:`drake_att.analysis.campaign_report`).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable
from dataclasses import dataclass, field

from drake_att import interrupts
from drake_att.analysis.campaign import campaign_seeds, run_campaign
from drake_att.analysis.dask_connection import (
    DEFAULT_CONNECT_TIMEOUT_S,
    CampaignError,
    _connect,
    _shut_down,
    check_connect_timeout,
)
from drake_att.analysis.executor import DEFAULT_BATCH_SIZE, _check_workers, _is_serial, check_batch_size, map_runs
from drake_att.analysis.run_records import timing_record
from drake_att.outputs import safe_component
from drake_att.scenarios import config as cfg
from drake_att.scenarios.selection import with_fused_sources
from drake_att.validation import SEED_MAX


@dataclass
class ComparisonPlan:
    """What :func:`run_comparison` runs.

    Attributes:
        scenarios: the resolved scenarios (overrides applied, estimators selected and
            transplanted), one campaign each.
        estimators: the matrix's columns (estimator names), in the order listed.
        cells: ``(scenario name, estimator)`` -> None (runs) or why it does not.
    """

    scenarios: list
    estimators: list
    cells: dict

    @property
    def skipped(self) -> list[str]:
        return [f"{s} x {e}: {why}" for (s, e), why in self.cells.items() if why is not None]


def _with_estimators(scenario: cfg.Scenario, estimator_configs, plugins=()) -> cfg.Scenario:
    out = copy.deepcopy(scenario)
    out.estimators = copy.deepcopy(list(estimator_configs))
    out.plugins = list(dict.fromkeys(list(scenario.plugins) + list(plugins)))
    return cfg.load_scenario(text=cfg.dump_scenario(out))


def comparison_plan(scenarios, estimators=None, overrides=()) -> ComparisonPlan:
    """Resolve ``drake-att compare``'s scenarios and ``--estimators`` entries.

    An entry ``NAME`` runs wherever a scenario defines an estimator of that name; an entry
    ``SOURCE:NAME`` takes estimator NAME's config from scenario SOURCE (a shipped name or a
    YAML path) and adds it to every listed scenario that lacks it (its sensors must exist
    there: the cell says why not). A fusion brings its sources along. ``None``: every
    scenario runs its own estimators. ConfigError names the option for bad input."""
    from drake_att.scenarios.library import load

    loaded = []
    for name in scenarios:
        s = load(name)
        if overrides:
            s = cfg.apply_overrides(s, list(overrides))
        if s.name in [x.name for x in loaded]:
            raise CampaignError(f"SCENARIO: {name!r} is listed twice (scenario {s.name!r})")
        loaded.append(s)
    if not loaded:
        raise CampaignError("SCENARIO: name at least one scenario")
    if estimators is None:
        columns = list(dict.fromkeys(e.name for s in loaded for e in s.estimators))
        entries = [(None, n) for n in columns]
    else:
        if not estimators:
            raise CampaignError("--estimators: got an empty list; name estimators (NAME or SCENARIO:NAME)")
        entries = []
        for item in estimators:
            source, _, name = item.rpartition(":") if ":" in item else (None, "", item)
            if not name:
                raise CampaignError(f"--estimators: got {item!r}; expected NAME or SCENARIO:NAME")
            entries.append((source, name))
        columns = list(dict.fromkeys(n for _, n in entries))
        if len(columns) != len(entries):
            raise CampaignError(f"--estimators: got {estimators!r}; each estimator name may appear once")
    transplants = {}
    for source, name in entries:
        if source is None:
            continue
        src = load(source)
        configs = {e.name: e for e in src.estimators}
        if name not in configs:
            raise CampaignError(
                f"--estimators {source}:{name}: scenario {src.name!r} has no estimator {name!r}; it has {list(configs)}"
            )
        bring = [configs[n] for n in with_fused_sources(configs, [name])]  # a fusion brings its sources
        transplants[name] = (bring[::-1], src.plugins)
    cells, resolved = {}, []
    for s in loaded:
        own = {e.name: e for e in s.estimators}
        keep = set()
        for _, name in entries:
            if name in own:
                keep.update(with_fused_sources(own, [name]))
                cells[(s.name, name)] = None
            elif name not in transplants:
                cells[(s.name, name)] = "not an estimator of this scenario (SOURCE:NAME adds one from another scenario)"
        configs = [e for e in s.estimators if e.name in keep]
        plugins = list(s.plugins)
        for name, (bring, src_plugins) in transplants.items():
            if name in own:
                continue
            extra = [b for b in bring if b.name not in {c.name for c in configs}]
            try:
                _with_estimators(s, configs + extra, plugins + list(src_plugins))
            except (cfg.ConfigError, ValueError) as e:
                cells[(s.name, name)] = f"cannot run here: {' '.join(str(e).split())}"
                continue
            configs += extra
            plugins += list(src_plugins)
            cells[(s.name, name)] = None
        if configs:
            resolved.append(_with_estimators(s, configs, plugins))
    if not any(why is None for why in cells.values()):
        raise CampaignError(
            "--estimators: no listed estimator runs on any listed scenario: "
            + "; ".join(f"{s} x {e}: {why}" for (s, e), why in cells.items())
        )
    return ComparisonPlan(resolved, columns, cells)


def _selection_with_sources(scenario: cfg.Scenario, name: str) -> tuple:
    """Estimator ``name`` and the estimators it fuses, in the scenario's order."""
    keep = set(with_fused_sources({e.name: e for e in scenario.estimators}, [name]))
    return tuple(e.name for e in scenario.estimators if e.name in keep)


@dataclass
class ComparisonResult:
    """What :func:`run_comparison` returns: the plan, each scenario's
    :class:`CampaignResult`, and per (scenario, estimator) the timing
    (``{"ms_per_step", "selection", "steps", "wall_s", "baseline_wall_s"}``)."""

    plan: ComparisonPlan
    campaigns: dict
    timing: dict
    out: str | None = None
    files: list = field(default_factory=list)


@interrupts.remembering
def run_comparison(
    plan: ComparisonPlan,
    runs: int,
    first_seed: int = 1,
    *,
    workers: int | None = None,
    scheduler=None,
    out: str | None = None,
    resume: bool = False,
    progress: bool = True,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    batch_size: int = DEFAULT_BATCH_SIZE,
    record: Callable | None = None,
    timing_repeats: int = 3,
    stream=None,
) -> ComparisonResult:
    """Run :func:`comparison_plan`'s scenarios (``drake-att compare``): one campaign each
    (``<out>/<scenario>/``, resumable), then per scenario one timing run per estimator
    (that estimator and its sources alone, minus the sensors-only run; the fastest of
    ``timing_repeats`` runs, seeds ``first_seed, first_seed + 1, ...``, each run alone, never in a
    batch) and the matrix
    (``comparison.{json,md,png,html}``). One Dask cluster serves all: a local one, or the
    scheduler's, connected to before anything is written
    (:func:`~drake_att.analysis.dask_connection.connect_scheduler`); a
    comparison that fails before any campaign saved a run leaves no folder behind."""
    campaign_seeds(runs, first_seed)
    connect_timeout_s = check_connect_timeout(connect_timeout_s)
    check_batch_size(batch_size)
    _check_workers(workers)
    owned = None
    if not _is_serial(workers, scheduler) and (scheduler is None or isinstance(scheduler, str)):
        owned = _connect(workers or os.cpu_count() or 1, scheduler, connect_timeout_s)
        scheduler = owned[0]
    campaigns, timing, created = {}, {}, []
    try:
        if out is not None:
            created = _missing_folders(out)
            os.makedirs(out, exist_ok=True)
        for scenario in plan.scenarios:
            sub = None if out is None else os.path.join(out, safe_component(scenario.name))
            campaigns[scenario.name] = run_campaign(
                scenario,
                runs,
                first_seed,
                workers=workers,
                scheduler=scheduler,
                out=sub,
                resume=resume,
                record=record,
                progress=progress,
                connect_timeout_s=connect_timeout_s,
                batch_size=batch_size,
                stream=stream,
            )
            timing.update(
                _time_estimators(plan, scenario, first_seed, timing_repeats, workers, scheduler, connect_timeout_s)
            )
    except BaseException:
        _remove_empty_folders(created)
        raise
    finally:
        if owned is not None:
            _shut_down(owned[0], owned[1], owned[2], [])
    result = ComparisonResult(plan, campaigns, timing, out)
    interrupts.raise_if_interrupted()
    if out is not None:
        from drake_att.analysis import campaign_report

        result.files = campaign_report.write_comparison(result)
    return result


def _missing_folders(out: str) -> list:
    """The folders creating ``out`` would add, deepest first (taken back if nothing is saved)."""
    created = []
    path = os.path.normpath(out)
    while not os.path.isdir(path):
        created.append(path)
        if os.path.dirname(path) in ("", path):
            break
        path = os.path.dirname(path)
    return created


def _remove_empty_folders(created: list) -> None:
    """Remove the folders in ``created`` (deepest first) while they are empty: a campaign that
    saved runs keeps them."""
    for path in created:
        try:
            os.rmdir(path)
        except OSError:
            break


def _time_estimators(plan, scenario, first_seed, timing_repeats, workers, scheduler, connect_timeout_s) -> dict:
    """Per (scenario, estimator) with a matrix cell, the timing entry: the fastest of
    ``timing_repeats`` runs of that estimator and its sources, minus the fastest sensors-only run."""
    names = [e for e in plan.estimators if plan.cells.get((scenario.name, e), "") is None]
    selections = [()] + [_selection_with_sources(scenario, e) for e in names]
    seeds = [min(first_seed + k, SEED_MAX) for k in range(timing_repeats)]
    jobs = [(seed, sel) for sel in selections for seed in seeds]
    # Each timed run alone: a batch's wall time is shared by its runs, not one estimator's cost.
    walls = map_runs(
        scenario,
        jobs,
        timing_record,
        workers=workers,
        scheduler=scheduler,
        connect_timeout_s=connect_timeout_s,
        batch_size=1,
    )
    fastest = [
        min(walls[k * len(seeds) : (k + 1) * len(seeds)], key=lambda w: w["wall_time_s"])
        for k in range(len(selections))
    ]
    base = fastest[0]["wall_time_s"]
    timing = {}
    for e, sel, w in zip(names, selections[1:], fastest[1:], strict=True):
        steps = w["steps"][e]
        timing[(scenario.name, e)] = {
            "selection": list(sel),
            "steps": steps,
            "wall_s": w["wall_time_s"],
            "baseline_wall_s": base,
            "repeats": len(seeds),
            "ms_per_step": 1e3 * (w["wall_time_s"] - base) / max(steps, 1),
        }
    return timing
