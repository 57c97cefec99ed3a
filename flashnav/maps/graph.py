"""The 8-connected grid graph of a map's free cells (scipy sparse), for shortest paths with
``scipy.sparse.csgraph.dijkstra``: the oracle's (:mod:`flashnav.sim.oracle`), the mapless planner's
(:mod:`flashnav.mapless`). numpy and scipy only."""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import csr_matrix

NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
#: the most a metre of path costs: beside a wall (:func:`wall_cost`)
MAX_WALL_COST = 5.0


def wall_cost(clearance: np.ndarray, radius: float, comfort: float) -> np.ndarray:
    """Per-cell cost of a metre of path [H, W]: 1 where the cell is at least ``radius + comfort`` metres
    from every wall (``clearance`` [H, W] metres), rising linearly to :data:`MAX_WALL_COST` at ``radius``:
    the planners' paths keep clear of walls where they can."""
    return 1.0 + (MAX_WALL_COST - 1.0) * np.clip((radius + comfort - clearance) / comfort, 0.0, 1.0)


def grid_graph(free: np.ndarray, resolution: float, cost: np.ndarray | None = None) -> csr_matrix:
    """8-connected graph over the free cells of ``free`` [H, W] (edge weights in metres, times the
    optional per-cell ``cost`` [H, W] >= 1 of the cell entered); a diagonal move needs both cells
    beside it free, so paths never cut an obstacle's corner."""
    h, w = free.shape
    idx = np.arange(h * w).reshape(h, w)
    pad = np.pad(free, 1, constant_values=False)

    def shifted(di: int, dj: int) -> np.ndarray:  # shifted(di, dj)[i, j] = free[i + di, j + dj]
        return pad[1 + di: 1 + di + h, 1 + dj: 1 + dj + w]

    rows, cols, weights = [], [], []
    for di, dj in NEIGHBOURS:
        ok = free & shifted(di, dj)
        if di and dj:  # no corner cutting
            ok &= shifted(di, 0) & shifted(0, dj)
        s = idx[ok]
        rows.append(s)
        cols.append(s + di * w + dj)
        step = np.full(s.size, resolution * math.hypot(di, dj))
        weights.append(step if cost is None else step * cost.reshape(-1)[s + di * w + dj])
    r, c, wt = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    return csr_matrix((wt, (r, c)), shape=(h * w, h * w))
