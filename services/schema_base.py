"""Building blocks shared by the sweep schema, its search space, tracking and the report: names, metric names,
the strict model, the error.

A module of its own so that services.search_space and services.sweep_schema both build on it without
importing each other.
"""

from __future__ import annotations

from flashnav.config_base import Strict  # noqa: F401  (the sweep schema's base: one strict model for the project)
from flashnav.names import ALGORITHMS, THRESHOLD_TAGS

#: what a trial's final report carries to MLflow (services.tracking logs them; services.report reads them)
FINAL_METRICS = tuple(f"{kind}_{tag}" for tag in THRESHOLD_TAGS for kind in ("time_to", "env_steps_to", "reached")) + (
    "final_success_rate", "best_success_rate", "train_seconds_total", "env_steps_total",
    "cycle_collector_ms", "cycle_learner_ms", "cycle_effective_ms")
#: what each evaluation report carries, logged at the step of its ``env_steps``
CURVE_METRICS = ("success_rate", "mean_return", "train_seconds", "env_steps")

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
