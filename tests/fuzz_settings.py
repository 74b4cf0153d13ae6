"""Hypothesis settings shared by the fuzz tests (a helper module, not a test file).

Two profiles, chosen with ``$LETSPI_FUZZ_PROFILE``:

* ``ci`` (default): derandomised (every run, CI or local, draws the same examples: a failure
  reproduces, and the suite never turns red on an unrelated change), no example database,
  no deadline (shared 2-core machines).
* ``explore``: random examples, ten times as many, with the example database, to hunt for new
  failures (``LETSPI_FUZZ_PROFILE=explore pytest tests/test_llm_fuzz.py``). Found failures are
  printed with a reproduction blob; add them as explicit ``@example``s.

The example counts are per test; the totals are listed in notes/robustness.md.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

PROFILE = os.environ.get("LETSPI_FUZZ_PROFILE", "ci")
if PROFILE not in ("ci", "explore"):
    raise ValueError(f"LETSPI_FUZZ_PROFILE must be 'ci' or 'explore', got {PROFILE!r}")


def fuzz(max_examples: int) -> settings:
    """Settings for a fuzz test drawing ``max_examples`` examples in the ``ci`` profile."""
    explore = PROFILE == "explore"
    common = {
        "deadline": None,
        "print_blob": True,
        "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    }
    if explore:
        return settings(max_examples=10 * max_examples, **common)  # type: ignore[arg-type]
    return settings(max_examples=max_examples, derandomize=True, database=None, **common)  # type: ignore[arg-type]
