"""Threshold metrics of training runs: first crossings, censored times, aggregates over seeds.

Pure functions over plain Python sequences and numpy arrays (no torch, no services), in the spirit
of rliable's ``metrics.py``. Every caller that turns success rates into time-to-threshold numbers
uses these: the training loop's :class:`flashnav.evaluate.ThresholdTracker`, the Tune trainable's
final metrics and search objective, ``flashnav bench train``, and the report's tables.

Data contract
-------------
* A *curve* is one run's evaluations in the order they happened: ``success`` ``[E]`` success rates,
  fractions in [0, 1], and ``x`` ``[E]`` where each evaluation happened on some monotone axis
  (training seconds or env steps). ``E`` may be 0.
* A *threshold* is a success-rate fraction in [0, 1] (:data:`THRESHOLDS`); its *tag* is the percent
  as a string (:data:`THRESHOLD_TAGS`), used in metric names (``time_to_90``, ``reached_95``...).
* An evaluation *reaches* a threshold when ``success >= threshold - TOLERANCE``: success rates are
  means over episodes, so 0.99999999 (float noise) counts as 100 %. NaN never reaches.
* The *first crossing* is ``x`` at the first evaluation that reaches; later dips do not undo it
  (curves need not be monotone). None when no evaluation reaches.
* A *censored* time is the first crossing where reached, else the run's total (its last ``x``
  unless given): never None or NaN, always paired with a ``reached`` flag.
* *Over seeds*: one value per seed (float seconds / steps; None or NaN = not reached), optionally
  with explicit reached flags (1.0 / True = reached; 0, NaN or None = not). Best = min and mean =
  exactly rounded mean (``math.fsum``) over the reached seeds only, ``k`` of ``n`` seeds reached,
  and a 95 % percentile-bootstrap interval of that mean (None when k < 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from flashnav.names import THRESHOLD_TAGS, THRESHOLDS  # defined once, with the other names users choose

TOLERANCE = 1e-9
"""A success rate this far below a threshold still reaches it (float noise of a mean)."""
BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0


def tag_of(threshold: float) -> str:
    """0.95 -> ``"95"``; raises ValueError naming a threshold that is not one of THRESHOLDS."""
    for t, tag in zip(THRESHOLDS, THRESHOLD_TAGS):
        if math.isclose(float(threshold), t):
            return tag
    raise ValueError(f"threshold {threshold!r} is not one of {THRESHOLDS}")


def threshold_of(tag: str) -> float:
    """``"95"`` -> 0.95; raises ValueError naming a tag that is not one of THRESHOLD_TAGS."""
    try:
        return THRESHOLDS[THRESHOLD_TAGS.index(str(tag))]
    except ValueError:
        raise ValueError(f"threshold tag {tag!r} is not one of {THRESHOLD_TAGS}") from None


def reaches(success_rate: float, threshold: float) -> bool:
    """Whether one evaluation's success rate (fraction) reaches ``threshold`` (fraction)."""
    return bool(success_rate >= threshold - TOLERANCE)


def _check_threshold(threshold: float) -> None:
    if not 0.0 <= threshold <= 1.0:
        raise ValueError(f"threshold must be a success-rate fraction in [0, 1], got {threshold!r}")


def plain_number(value):
    """numpy scalar -> Python number, so callers get what a list of floats would give them."""
    return value.item() if hasattr(value, "item") else value


def first_crossing(success: Sequence[float], x: Sequence[float], threshold: float):
    """``x`` [same unit as x] at the first evaluation whose success reaches ``threshold``, or None.

    success: ``[E]`` success rates (fractions); x: ``[E]`` seconds or env steps of each evaluation.
    """
    _check_threshold(threshold)
    if len(success) != len(x):
        raise ValueError(f"success ({len(success)} evaluations) and x ({len(x)}) differ in length")
    for rate, where in zip(success, x):
        if reaches(rate, threshold):
            return plain_number(where)
    return None


def censor(first: float | None, total: float) -> tuple[float, bool]:
    """(first crossing, True) where reached, else (the run's total, False). NaN counts as not reached."""
    if first is None or (isinstance(first, float) and math.isnan(first)):
        return float(total), False
    return float(first), True


def time_to_threshold(success: Sequence[float], x: Sequence[float], threshold: float,
                      total: float | None = None) -> tuple[float, bool]:
    """Censored time to ``threshold``: (first crossing, True), else (``total``, False).

    ``total`` defaults to the last evaluation's ``x`` (the time spent so far, a lower bound of the
    run's total); an empty curve needs it.
    """
    if total is None:
        if len(x) == 0:
            raise ValueError("time_to_threshold of an empty curve needs the run's total")
        total = x[-1]
    return censor(first_crossing(success, x, threshold), plain_number(total))


@dataclass(frozen=True)
class SeedStats:
    """One threshold over seeds: best / mean over the k reached seeds of n, and the mean's interval."""

    best: float | None
    mean: float | None
    k: int
    n: int
    ci: tuple[float, float] | None


def _flag(value) -> bool:
    """A reached flag: 1.0 / True reached; 0, NaN, None not."""
    return value is not None and float(value) >= 1.0


def reached_values(values: Sequence[float | None], reached: Sequence | None = None) -> list[float]:
    """The finite values of the seeds that reached, in input order (see the module's contract)."""
    if reached is not None and len(reached) != len(values):
        raise ValueError(f"values ({len(values)} seeds) and reached ({len(reached)}) differ in length")
    flags = [True] * len(values) if reached is None else [_flag(f) for f in reached]
    return [float(v) for v, f in zip(values, flags)
            if f and v is not None and math.isfinite(float(v))]


def over_seeds(values: Sequence[float | None], reached: Sequence | None = None,
               interval: bool = True) -> SeedStats:
    """Best / mean / k-of-n (and, with ``interval``, the 95 % bootstrap interval) over seeds.

    values: ``[n]`` seconds or env steps per seed (censored or None where not reached); reached:
    ``[n]`` flags, else a seed reached where its value is not None / NaN.
    """
    hit = reached_values(values, reached)
    return SeedStats(best=min(hit) if hit else None,
                     mean=math.fsum(hit) / len(hit) if hit else None,
                     k=len(hit), n=len(values),
                     ci=bootstrap_mean_ci(hit) if interval else None)


def bootstrap_mean_ci(values, confidence: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES,
                      seed: int = BOOTSTRAP_SEED) -> tuple[float, float] | None:
    """Percentile-bootstrap interval of the mean over seeds, e.g. seconds -> (low, high) seconds.

    Deterministic: a fixed-seed generator over the *sorted* values, so seed order does not matter.
    Non-finite values are dropped. None when fewer than 2 values (an interval from one seed means
    nothing).
    """
    x = np.sort(np.asarray(values, dtype=float))
    x = x[np.isfinite(x)]
    if x.size < 2:
        return None
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    alpha = (1.0 - confidence) / 2.0
    low, high = np.percentile(means, [100 * alpha, 100 * (1 - alpha)])
    return float(low), float(high)


__all__ = ["THRESHOLDS", "THRESHOLD_TAGS", "TOLERANCE", "BOOTSTRAP_RESAMPLES", "BOOTSTRAP_SEED", "SeedStats",
           "tag_of", "threshold_of", "reaches", "first_crossing", "censor", "time_to_threshold",
           "reached_values", "over_seeds", "bootstrap_mean_ci"]


def within_budget(values: Sequence[float | None], budget: float | None, reached: Sequence | None = None) -> int:
    """How many runs reached a threshold at or below ``budget`` (env steps or seconds); ``values`` and
    ``reached`` as for :func:`over_seeds`. 0 when there is no budget."""
    if budget is None:
        return 0
    return sum(1 for v in reached_values(values, reached) if v <= budget)


#: Run-config keys (dotted) that take a run off the paper's task: other maps to train on or to be scored on.
OFF_TASK_KEYS = ("map", "maps", "eval.maps")


def _is_set(value) -> bool:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return str(value) not in ("None", "", "nan", "<NA>")


def on_paper_task(config: Mapping[str, Any]) -> bool:
    """Whether a run trained and was scored on its robot's bundled map, the task the paper's env-step budget
    (:func:`within_budget`) is for. ``config``: the run's config as dotted keys (``maps.family``; MLflow's
    params, where a null reads "None"): off the task when ``map``, ``maps`` (or a ``maps.*`` key) or
    ``eval.maps`` is set - a generalist is scored on generated validation maps, a fine-tuning on one building."""
    return not any(_is_set(v) for k, v in config.items() if k in OFF_TASK_KEYS or k.startswith("maps."))
