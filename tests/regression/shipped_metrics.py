"""Metrics of every shipped scenario, shortened, for seeds 1-3: the behaviour-preservation
record for refactors (a refactor must reproduce these numbers).

Run as a script to (re)record them from the library that is on ``sys.path``::

    PYTHONPATH=<checkout of the reference commit> .venv/bin/python \\
        tests/regression/shipped_metrics.py tests/data/shipped_metrics_pre_redesign.json

Recording from a ``git worktree`` of the reference commit (not from the working tree)
makes the record a measurement of that commit's code, never typed in. The test
``tests/test_regression.py`` recomputes the same numbers with the current library and
compares them exactly (the runs are pure functions of config + seed).

Each scenario is shortened (``duration_s``, ``scoring.score_from_s``) so that the check
costs seconds, while every estimator, sensor and the metrics layer run as shipped.
"""

from __future__ import annotations

import json
import subprocess
import sys

SEEDS = (1, 2, 3)

# Shortened runs: long enough to pass every estimator's start-up (first updates, first
# resampling, shadow switches in the large-error case) and to score a stable stage.
OVERRIDES = {
    "cubesat_dual_star_tracker": ["duration_s=120", "scoring.score_from_s=40"],
    "cubesat_single_star_tracker": ["duration_s=120", "scoring.score_from_s=40"],
    "s0_particle_filters_small_error": ["duration_s=60", "scoring.score_from_s=20"],
    "s0_particle_filters_large_error": ["duration_s=60", "scoring.score_from_s=20"],
    "s0_gyroless_pf": ["duration_s=60", "scoring.score_from_s=20"],
}

# Not a function of config + seed.
VOLATILE_KEYS = ("wall_time_s",)


def gate_off(scenario) -> list[str]:
    """Overrides that switch off the default innovation gate (added after the record: the
    record guards everything else bit for bit; the gate has its own tests)."""
    return [
        f"estimators.{e.name}.innovation_gate_probability=0.0"
        for e in scenario.estimators
        if hasattr(e, "innovation_gate_probability")
    ]


def shipped_metrics(names=None) -> dict:
    """``{scenario: {seed: metrics}}`` for the shipped scenarios (one diagram per scenario)."""
    from drake_att.analysis.metrics import compute_metrics
    from drake_att.scenarios.builder import ScenarioDiagram
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load

    out = {}
    for name in names or sorted(OVERRIDES):
        scenario = load(name)
        sd = ScenarioDiagram(apply_overrides(scenario, OVERRIDES[name] + gate_off(scenario)))
        out[name] = {}
        for seed in SEEDS:
            run = sd.simulate(seed)
            # Commits before runs carried their metadata took the systems as well.
            m = compute_metrics(run) if getattr(run, "metadata", None) else compute_metrics(run, sd.estimators)
            for k in VOLATILE_KEYS:
                m.pop(k, None)
            # Through JSON, exactly as metrics.json stores them (floats round-trip exactly).
            out[name][str(seed)] = json.loads(json.dumps(m))
    return out


def main(path: str) -> None:
    import drake_att

    commit = subprocess.run(
        ["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=drake_att.__path__[0]
    ).stdout.strip()
    record = {
        "recorded_from_commit": commit,
        "seeds": list(SEEDS),
        "overrides": OVERRIDES,
        "metrics": shipped_metrics(),
    }
    with open(path, "w") as f:
        json.dump(record, f, indent=1, sort_keys=True)
        f.write("\n")
    print(f"recorded {len(record['metrics'])} scenarios x {len(SEEDS)} seeds from {commit} -> {path}")


if __name__ == "__main__":
    main(sys.argv[1])
