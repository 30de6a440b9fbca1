"""Shared pytest setup: hypothesis profiles.

``ci`` bounds the number of examples and drops the deadline (shared CI machines
are slow and torch's first call is slow anywhere); it is loaded when the ``CI``
environment variable is set. ``dev`` (the default otherwise) keeps hypothesis's
example count but also has no deadline. ``stress`` (``HYPOTHESIS_PROFILE=stress``)
draws ten times more, for a long search after an engine change. None writes an
example database into the work tree.
"""

import os

from hypothesis import HealthCheck, settings

_COMMON = {"deadline": None, "database": None, "suppress_health_check": [HealthCheck.too_slow]}
settings.register_profile("ci", max_examples=30, derandomize=True, **_COMMON)
settings.register_profile("dev", max_examples=100, **_COMMON)
settings.register_profile("stress", max_examples=1000, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))
