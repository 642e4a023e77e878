"""The scenarios shipped with drake_att (YAML files next to this module)."""

from __future__ import annotations

import os

from drake_att.scenarios.config import ConfigError, Scenario, load_scenario
from drake_att.validation import describe

SCENARIO_DIR = os.path.dirname(os.path.abspath(__file__))
DEFAULT_SCENARIO = "cubesat_dual_star_tracker"


def available_scenarios() -> dict[str, str]:
    """Name -> path of every shipped scenario."""
    out = {}
    for fname in sorted(os.listdir(SCENARIO_DIR)):
        if fname.endswith(".yaml"):
            out[fname[:-5]] = os.path.join(SCENARIO_DIR, fname)
    return out


def scenario_path(name_or_path: str | None) -> str:
    """Resolve a shipped scenario name or a YAML path."""
    if name_or_path is None:
        name_or_path = DEFAULT_SCENARIO
    if os.path.isfile(name_or_path):
        return name_or_path
    shipped = available_scenarios()
    if name_or_path in shipped:
        return shipped[name_or_path]
    raise ConfigError(f"scenario: got {describe(name_or_path)}; not a file and not one of {sorted(shipped)}")


def load(name_or_path: str | None = None) -> Scenario:
    return load_scenario(filename=scenario_path(name_or_path))
