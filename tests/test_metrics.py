"""Golden tests for flashnav/metrics.py: fixed curves and seed values, expected numbers by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flashnav.evaluate import ThresholdTracker
from flashnav.metrics import (THRESHOLD_TAGS, THRESHOLDS, SeedStats, bootstrap_mean_ci, censor, first_crossing,
                              over_seeds, reaches, tag_of, threshold_of, time_to_threshold)

SECONDS = [0.0, 10.0, 20.0, 30.0, 40.0]


def test_thresholds_and_tags_pair_up():
    assert THRESHOLDS == (0.9, 0.95, 1.0) and THRESHOLD_TAGS == ("90", "95", "100")
    assert [tag_of(t) for t in THRESHOLDS] == list(THRESHOLD_TAGS)
    assert [threshold_of(tag) for tag in THRESHOLD_TAGS] == list(THRESHOLDS)
    assert threshold_of("95") == 95 / 100                   # what the search objective used to compute
    with pytest.raises(ValueError, match="'80'"):
        threshold_of("80")
    with pytest.raises(ValueError, match="0.8"):
        tag_of(0.8)


@pytest.mark.parametrize("success, threshold, want", [
    ([0.1, 0.5, 0.8, 0.85, 0.89], 0.9, None),               # never reached
    ([0.95, 0.2, 0.3, 0.4, 0.5], 0.9, 0.0),                 # at the first evaluation
    ([0.1, 0.92, 0.5, 0.97, 0.6], 0.9, 10.0),               # non-monotone: the first crossing stands
    ([0.1, 0.92, 0.5, 0.97, 0.6], 0.95, 30.0),
    ([0.1, 0.89, 0.9, 0.95, 1.0], 0.9, 20.0),               # a tie at exactly the threshold reaches
    ([0.1, 0.3, 0.99999999, 0.7, 1.0], 1.0, 40.0),          # 1e-8 below 1.0 is more than the 1e-9 tolerance
    ([0.1, 0.3, 1.0 - 1e-10, 0.7, 1.0], 1.0, 20.0),         # float noise 1e-10 below 1.0 counts as 100 %
])
def test_first_crossing(success, threshold, want):
    got = first_crossing(success, SECONDS, threshold)
    assert got == want


def test_first_crossing_tolerance_edge():
    # 0.99999999 is 1e-8 below 1.0, more than the 1e-9 tolerance: 100 % is first met at 40 s
    assert first_crossing([0.99999999, 0.99999999, 0.5, 0.5, 1.0], SECONDS, 1.0) == 40.0
    assert reaches(1.0 - 5e-10, 1.0) and not reaches(1.0 - 2e-9, 1.0)
    assert not reaches(float("nan"), 0.9)


def test_first_crossing_numpy_and_steps():
    steps = np.array([0, 4096, 8192, 12288])
    got = first_crossing(np.array([0.0, 0.5, 0.96, 0.99]), steps, 0.95)
    assert got == 8192 and type(got) is int                 # a plain Python number, in x's unit


def test_first_crossing_rejects_bad_input():
    with pytest.raises(ValueError, match=r"success \(2 evaluations\) and x \(3\)"):
        first_crossing([0.1, 0.2], [0.0, 1.0, 2.0], 0.9)
    with pytest.raises(ValueError, match="90"):
        first_crossing([0.1], [0.0], 90)                    # a percent where a fraction belongs
    assert first_crossing([], [], 0.9) is None


def test_censored_time_to_threshold():
    success = [0.1, 0.92, 0.5, 0.97, 0.6]
    assert time_to_threshold(success, SECONDS, 0.9) == (10.0, True)
    assert time_to_threshold(success, SECONDS, 1.0) == (40.0, False)           # the last evaluation
    assert time_to_threshold(success, SECONDS, 1.0, total=55.5) == (55.5, False)  # the run's total
    assert time_to_threshold([], [], 0.9, total=3.0) == (3.0, False)
    with pytest.raises(ValueError, match="empty curve"):
        time_to_threshold([], [], 0.9)
    assert censor(None, 60.0) == (60.0, False) and censor(float("nan"), 60.0) == (60.0, False)
    assert censor(12.0, 60.0) == (12.0, True)


def test_over_seeds_values_with_none():
    # seeds 10, 30 reached; one did not: best 10, mean 20, k/n = 2/3
    stats = over_seeds([10.0, None, 30.0])
    assert (stats.best, stats.mean, stats.k, stats.n) == (10.0, 20.0, 2, 3)
    # two seeds: resampled means are 10, 20 or 30 with p = 1/4, 1/2, 1/4 -> 2.5 / 97.5 % = 10, 30
    assert stats.ci == (10.0, 30.0)
    assert over_seeds([10.0, None, 30.0], interval=False).ci is None


def test_over_seeds_censored_values_with_flags():
    # censored times of 4 seeds; the flags say which were reached (NaN flag = not logged = not reached)
    stats = over_seeds([12.0, 120.0, 18.0, 9.0], reached=[1.0, 0.0, 1.0, float("nan")])
    assert (stats.best, stats.mean, stats.k, stats.n) == (12.0, 15.0, 2, 4)
    assert over_seeds([5.0, 6.0], reached=[True, False]) == SeedStats(5.0, 5.0, 1, 2, None)  # k = 1: no interval


def test_over_seeds_none_reached_and_empty():
    assert over_seeds([None, None, float("nan")]) == SeedStats(None, None, 0, 3, None)
    assert over_seeds([]) == SeedStats(None, None, 0, 0, None)
    with pytest.raises(ValueError, match=r"values \(2 seeds\) and reached \(1\)"):
        over_seeds([1.0, 2.0], reached=[1.0])


def test_over_seeds_mean_is_exactly_rounded():
    values = [0.1] * 10                                      # naive left-to-right summation gives 0.0999...
    assert over_seeds(values).mean == math.fsum(values) / 10 == 0.1


def test_bootstrap_interval_golden():
    assert bootstrap_mean_ci([9.0, 17.0]) == (9.0, 17.0)
    assert bootstrap_mean_ci([5.0, 5.0, 5.0]) == (5.0, 5.0)
    assert bootstrap_mean_ci([1.0]) is None and bootstrap_mean_ci([]) is None
    assert bootstrap_mean_ci([1.0, float("nan")]) is None   # non-finite values dropped first
    a = bootstrap_mean_ci([3.0, 1.0, 2.0, 8.0, 4.0])
    assert a == bootstrap_mean_ci([8.0, 4.0, 2.0, 1.0, 3.0])  # seeded over sorted values: order-free
    assert 1.0 < a[0] < 3.6 < a[1] < 8.0


def test_threshold_tracker_is_the_incremental_first_crossing():
    success = [0.1, 0.92, 0.5, 0.99999999, 1.0]
    steps = [0, 100, 200, 300, 400]
    tracker = ThresholdTracker()
    new = [tracker.update(s, t, e) for s, t, e in zip(success, SECONDS, steps)]
    assert new == [[], [0.9], [], [0.95], [1.0]]
    for t in THRESHOLDS:
        assert tracker.seconds[t] == first_crossing(success, SECONDS, t)
        assert tracker.env_steps[t] == first_crossing(success, steps, t)


def test_within_budget_counts_reached_runs_at_or_below_the_budget():
    from flashnav.metrics import within_budget

    steps = [120_000.0, 200_704.0, 250_000.0, None, float("nan")]
    assert within_budget(steps, 200_704) == 2  # at the budget counts
    assert within_budget(steps, None) == 0
    # censored values (the run's total where not reached) never count, whatever their size
    assert within_budget([150_000.0, 100_000.0], 200_704, reached=[1, 0]) == 1


def test_paper_budget_is_the_paper_recipes_total():
    from flashnav.learn.hparams import paper_budget

    assert paper_budget("fastdsac", "turtlebot2") == 200_704
    assert paper_budget("fastdsac", "go2") == 401_408
    assert paper_budget("fasttd3", "go2") == 602_112
    assert paper_budget("fastdsac", "jackal") is None
