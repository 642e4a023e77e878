"""Test-suite configuration.

Hypothesis runs derandomized (examples are a fixed function of each test), so the suite is
reproducible like every run of the library: a failure seen once is seen every time.
Set ``HYPOTHESIS_PROFILE=explore`` to search with fresh random examples
(``mutation``: fewer examples, for mutation runs).
"""

import os

from hypothesis import settings

settings.register_profile("reproducible", derandomize=True, database=None, deadline=None)
settings.register_profile("explore", deadline=None)
# Mutation runs (tests/mutation_run.py) execute the covering tests once per mutant: fewer,
# still derandomized examples keep a run of ~5000 mutants within about an hour on 2 cores.
settings.register_profile("mutation", derandomize=True, database=None, deadline=None, max_examples=15)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))


import subprocess  # noqa: E402
import sys  # noqa: E402

import pytest  # noqa: E402


@pytest.fixture
def diagram_builds(monkeypatch):
    """The names of the scenarios whose ``ScenarioDiagram`` is constructed during the test
    (the process cache of ``builder.diagram_for`` starts empty): a script that changes
    contexts instead of diagrams appends each scenario once."""
    from drake_att.scenarios import builder

    built = []
    original = builder.ScenarioDiagram.__init__

    def counting(self, scenario):
        built.append(scenario.name)
        original(self, scenario)

    monkeypatch.setattr(builder.ScenarioDiagram, "__init__", counting)
    monkeypatch.setattr(builder, "_DIAGRAMS", {})
    return built


@pytest.fixture
def load_script():
    """``load_script(name)``: the module ``diagrams/<name>.py`` (the reproduction scripts)."""
    import importlib.util

    def load(name):
        path = os.path.join(os.path.dirname(__file__), "..", "diagrams", f"{name}.py")
        spec = importlib.util.spec_from_file_location(f"_script_{name}", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


@pytest.fixture
def drake_att_cli():
    """``drake_att_cli(*args)``: ``drake-att`` in a fresh interpreter (CompletedProcess)."""

    def run(*args):
        return subprocess.run(
            [sys.executable, "-m", "drake_att.cli", *args],
            capture_output=True,
            text=True,
            env=dict(os.environ, MPLBACKEND="Agg"),
        )

    return run


def pytest_configure(config):
    """Under mutmut (``MUTANT_UNDER_TEST`` in the environment, also while it collects its
    stats) the estimator loop's rules are mutmut's trampolines, which numba cannot compile:
    the estimators then run the Python loop, which calls the same rules
    (``tests/test_compiled_step.py`` compares the two loops outside mutation runs)."""
    if "MUTANT_UNDER_TEST" in os.environ:
        from drake_att.systems.estimator_system import EstimatorSystem

        EstimatorSystem.use_compiled_step = False
