"""Behaviour preservation: every shipped scenario (shortened) gives exactly the metrics
recorded from the reference commit's code (tests/data/shipped_metrics_pre_redesign.json,
written by tests/regression/shipped_metrics.py from a git worktree of that commit).

The runs are pure functions of config + seed, so the comparison is exact for every count
and to ``FLOAT_RTOL`` (1e-9 relative) for every real number: a refactor that changes a noise
draw, a counter or an estimate fails here and must say why. The tolerance admits only
round-off: the compiled filter kernels (issue 13) sum their 6x6 products in another order
than numpy's BLAS, which moves metrics by ~1e-15 relative; a changed draw or model moves
them by many orders of magnitude more.
"""

import json
import math
import os

import pytest

from regression.shipped_metrics import OVERRIDES, SEEDS, shipped_metrics

FLOAT_RTOL = 1e-9

RECORD = os.path.join(os.path.dirname(__file__), "data", "shipped_metrics_pre_redesign.json")


def _diff(a, b, path=""):
    """First difference between two JSON trees, as 'path: a != b' (None when equal)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{path}/{k}: present in only one"
            d = _diff(a[k], b[k], f"{path}/{k}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            d = _diff(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if isinstance(a, float) and isinstance(b, float) and math.isclose(a, b, rel_tol=FLOAT_RTOL, abs_tol=0.0):
        return None  # round-off (see the module docstring); ints and strings compare exactly
    return None if a == b else f"{path}: {a!r} != {b!r}"


@pytest.fixture(scope="module")
def record():
    with open(RECORD) as f:
        return json.load(f)


def test_record_covers_every_scenario_shipped_before_the_redesign(record):
    """Every scenario of the reference commit is recorded and still shipped (scenarios added
    since, e.g. paper S4's, have no pre-redesign numbers)."""
    from drake_att.scenarios.library import available_scenarios

    assert set(record["metrics"]) == set(OVERRIDES) <= set(available_scenarios())
    assert record["seeds"] == list(SEEDS) and record["overrides"] == OVERRIDES


@pytest.mark.parametrize("name", sorted(OVERRIDES))
def test_shipped_scenario_metrics_are_unchanged(record, name):
    now = shipped_metrics([name])[name]
    diff = _diff(record["metrics"][name], now)
    assert diff is None, f"{name} differs from commit {record['recorded_from_commit'][:10]}: {diff}"


def test_the_comparison_admits_round_off_only():
    assert _diff({"x": [1.0, 2]}, {"x": [1.0 + 1e-14, 2]}) is None
    assert _diff({"x": [1.0, 2]}, {"x": [1.0 + 1e-8, 2]}) == "/x[0]: 1.0 != 1.00000001"
    assert _diff({"n": 2}, {"n": 3}) == "/n: 2 != 3"
    assert _diff({"x": 0.0}, {"x": 1e-300}) is not None
