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
