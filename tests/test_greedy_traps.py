"""scripts/greedy_traps.py: the greedy walker and its trap depth (issue 15, why mazes defeat a memoryless policy)."""

from __future__ import annotations

import heapq
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import greedy_traps  # noqa: E402

RES = 0.1


def cup(depth_cells: int = 20) -> np.ndarray:
    """A 60 x 60 free grid with a U-shaped wall opening towards -x (rows = y): a walker heading +x inside the
    cup meets its bottom at column 40."""
    free = np.ones((60, 60), dtype=bool)
    free[20, 40 - depth_cells:41] = False  # lower arm
    free[40, 40 - depth_cells:41] = False  # upper arm
    free[20:41, 40] = False                # bottom
    return free


def test_the_walker_reaches_a_goal_in_the_open_and_stops_in_a_cup():
    free = np.ones((60, 60), dtype=bool)
    ok, stop = greedy_traps.greedy_walk(free, (30, 5), (5.5, 3.05), RES, 0.2)
    assert ok and math.hypot((stop[1] + 0.5) * RES - 5.5, (stop[0] + 0.5) * RES - 3.05) < 0.2
    ok, stop = greedy_traps.greedy_walk(cup(), (30, 25), (5.5, 3.05), RES, 0.2)
    assert not ok and stop == (30, 39)  # against the cup's bottom, on the straight line to the goal


def test_the_trap_depth_is_the_way_out_of_the_cup():
    """From the cup's bottom the nearest cell nearer the goal is round the arm's end: at least twice the arm's
    length back out (out along the arm and in again beyond the bottom), and more the deeper the cup."""
    depths = []
    for arm in (10, 20):
        free = cup(arm)
        graph = greedy_traps.grid_graph(free, RES)
        (d,) = greedy_traps.trap_depths(graph, free, [(30, 39)], [(5.5, 3.05)], RES)
        assert d > 2 * arm * RES * 0.9, (arm, d)
        depths.append(d)
    assert depths[1] > depths[0] + 1.5


def dijkstra_reference(free: np.ndarray, start: tuple[int, int]) -> dict[tuple[int, int], float]:
    """Plain Dijkstra over 8-neighbours of free cells, no corner cutting, metres."""
    h, w = free.shape
    dist = {start: 0.0}
    heap = [(0.0, start)]
    while heap:
        d, (r, c) = heapq.heappop(heap)
        if d > dist[(r, c)]:
            continue
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nr, nc = r + dr, c + dc
                if (dr, dc) == (0, 0) or not (0 <= nr < h and 0 <= nc < w and free[nr, nc]):
                    continue
                if dr and dc and not (free[r + dr, c] and free[r, c + dc]):
                    continue
                nd = d + RES * (math.sqrt(2) if dr and dc else 1.0)
                if nd < dist.get((nr, nc), math.inf) - 1e-12:
                    dist[(nr, nc)] = nd
                    heapq.heappush(heap, (nd, (nr, nc)))
    return dist


@pytest.mark.parametrize("seed", range(4))
def test_trap_depths_equal_a_plain_dijkstra_on_random_grids(seed):
    rng = np.random.default_rng(seed)
    free = rng.random((24, 31)) > 0.3
    cells = list(zip(*np.nonzero(free)))
    picks = [cells[i] for i in rng.choice(len(cells), 5, replace=False)]
    goals = [tuple(rng.uniform(0, 2.4, 2)) for _ in picks]
    got = greedy_traps.trap_depths(greedy_traps.grid_graph(free, RES), free, picks, goals, RES)
    for (r, c), (gx, gy), depth in zip(picks, goals, got):
        here = math.hypot((c + 0.5) * RES - gx, (r + 0.5) * RES - gy)
        reach = dijkstra_reference(free, (r, c))
        nearer = [d for (rr, cc), d in reach.items()
                  if math.hypot((cc + 0.5) * RES - gx, (rr + 0.5) * RES - gy) < here - RES]
        assert depth == pytest.approx(min(nearer) if nearer else math.inf)


def test_outcomes_pair_with_the_walked_episodes_by_map_and_order():
    rows = [{"map": "a", "depths": [None, 0.3, 2.0, None]}, {"map": "b", "depths": [1.5, None]}]
    report = {"maps": [{"map": "a", "outcomes": "sctt"}, {"map": "b", "outcomes": "ss"}]}
    assert greedy_traps.paired(report, rows, 1.0) == {"none": [1, 3], "shallow": [1, 1], "deep": [1, 2]}
    with pytest.raises(ValueError, match="per-episode outcomes"):
        greedy_traps.paired({"maps": [{"map": "a"}]}, rows, 1.0)
    with pytest.raises(ValueError, match="3 episodes in the report, 4 walked"):
        greedy_traps.paired({"maps": [{"map": "a", "outcomes": "sss"}]}, rows, 1.0)
