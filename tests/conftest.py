"""Test-suite configuration.

Hypothesis runs derandomized (examples are a fixed function of each test), so the suite is
reproducible like every run of the library: a failure seen once is seen every time.
Set ``HYPOTHESIS_PROFILE=explore`` to search with fresh random examples.
"""

import os

from hypothesis import settings

settings.register_profile("reproducible", derandomize=True, database=None, deadline=None)
settings.register_profile("explore", deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))
