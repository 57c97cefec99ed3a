"""Building blocks shared by the sweep schema and its search space: names, the strict model, the error.

A module of its own so that services.search_space and services.sweep_schema both build on it without
importing each other.
"""

from __future__ import annotations

from flashnav.config import Strict  # noqa: F401  (the sweep schema's base: one strict model for the project)
from flashnav.names import ALGORITHMS, THRESHOLD_TAGS

# Objective name -> Optuna direction. Time/steps are censored (the run's total where not reached).
OBJECTIVES = {
    **{f"{kind}_{tag}": "min" for kind in ("time_to", "env_steps_to") for tag in THRESHOLD_TAGS},
    "final_success_rate": "max", "best_success_rate": "max",
}


def known_algorithms(names):
    """``names`` (a list, or a dict keyed by algorithm) unchanged, or a clear error."""
    for name in names:
        if name not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {name!r}; allowed: {', '.join(ALGORITHMS)}")
    return names


class SweepError(ValueError):
    """A sweep file that cannot be used; the message lists every problem with its key path."""
