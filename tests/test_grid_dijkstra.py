"""flashnav/maps/grid_dijkstra.py: the numba grid Dijkstra against scipy's on the sparse grid graph."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from flashnav.maps.graph import grid_graph
from flashnav.maps.grid_dijkstra import grid_distances


@pytest.mark.parametrize("seed", range(6))
def test_grid_distances_equal_scipy_on_the_grid_graph(seed):
    """Random maps (open, cluttered, nearly closed), random wall costs (float32, as the planners pass them)
    or none, random sources (free or not): the same distances to the bit, unreachable cells inf."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(5, 60, 2)
    free = rng.random((h, w)) > [0.05, 0.3, 0.5, 0.2, 0.4, 0.0][seed]
    cost = None if seed % 3 == 0 else (1.0 + 4.0 * rng.random((h, w))).astype(np.float32)
    res = float(rng.choice([0.025, 0.05, 0.1]))
    for source in rng.integers(0, h * w, 4):
        got = grid_distances(free, res, cost, int(source))
        want = dijkstra(grid_graph(free, res, cost), directed=True, indices=int(source))
        np.testing.assert_array_equal(got, want)
        assert got[source] == 0.0 and (np.isinf(got).any() or free.all())


def test_grid_distances_name_a_bad_source_or_cost():
    free = np.ones((4, 5), bool)
    with pytest.raises(ValueError, match="source cell 20 is outside the 4 x 5 grid"):
        grid_distances(free, 0.1, None, 20)
    with pytest.raises(ValueError, match=r"cost has shape \(5, 4\), the grid \(4, 5\)"):
        grid_distances(free, 0.1, np.ones((5, 4)), 0)


def test_bench_plan_times_both_ways_and_checks_they_agree(capsys):
    from flashnav.cli import main

    assert main(["bench", "plan", "turtlebot2", "--goals", "2", "--repeats", "1"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "numba grid_distances" in out and "same distances both ways" in out
    assert main(["bench", "plan", "turtlebot2", "--goals", "0"]) == 2
    assert "--goals and --repeats must be >= 1" in capsys.readouterr().err
