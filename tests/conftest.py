"""Test-suite settings.

Hypothesis runs derandomized by default (the same examples on every run), so that CI on a
clean clone gives the same verdict as the run before the commit; explore new examples with
``HYPOTHESIS_PROFILE=explore python -m pytest`` (random seeds, as hypothesis does by default)
and add any failure it finds as an ``@example``.
"""

import os

from hypothesis import settings

settings.register_profile("bikeid", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "bikeid"))
