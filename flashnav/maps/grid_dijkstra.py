"""Shortest path lengths from one cell over a map's 8-connected free cells, in numba: the same numbers as
``scipy.sparse.csgraph.dijkstra(grid_graph(free, resolution, cost), indices=source)``
(:func:`flashnav.maps.graph.grid_graph`; tests compare them on random maps) without building the sparse
graph, which took more than half of each replan of the mapless planner (:mod:`flashnav.mapless`).

A move from cell u to a neighbour n costs ``resolution * |(di, dj)| * cost[n]`` (the cell entered); both
cells must be free, and a diagonal move needs both cells beside it free (no corner cutting). Final
distances do not depend on the order in which equal keys leave the heap, so they equal scipy's bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_DI = np.array([-1, -1, -1, 0, 0, 1, 1, 1], dtype=np.int64)
_DJ = np.array([-1, 0, 1, -1, 1, -1, 0, 1], dtype=np.int64)


@njit(cache=True)
def _push(keys, nodes, size, key, node):
    i = size
    keys[i], nodes[i] = key, node
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= keys[i]:
            break
        keys[parent], keys[i] = keys[i], keys[parent]
        nodes[parent], nodes[i] = nodes[i], nodes[parent]
        i = parent
    return size + 1


@njit(cache=True)
def _pop(keys, nodes, size):
    key, node = keys[0], nodes[0]
    size -= 1
    keys[0], nodes[0] = keys[size], nodes[size]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= size:
            break
        child = left
        if left + 1 < size and keys[left + 1] < keys[left]:
            child = left + 1
        if keys[i] <= keys[child]:
            break
        keys[child], keys[i] = keys[i], keys[child]
        nodes[child], nodes[i] = nodes[i], nodes[child]
        i = child
    return key, node, size


@njit(cache=True)
def _distances(free, step, cost, source, di, dj):
    h, w = free.shape
    dist = np.full(h * w, np.inf)
    done = np.zeros(h * w, dtype=np.bool_)
    cap = 8 * h * w + 1  # each cell is pushed at most once per neighbour, plus the source
    keys = np.empty(cap, dtype=np.float64)
    nodes = np.empty(cap, dtype=np.int64)
    dist[source] = 0.0
    size = _push(keys, nodes, 0, 0.0, source)
    while size > 0:
        d, u, size = _pop(keys, nodes, size)
        if done[u]:
            continue
        done[u] = True
        i, j = u // w, u % w
        if not free[i, j]:
            continue
        for k in range(8):
            ii, jj = i + di[k], j + dj[k]
            if ii < 0 or ii >= h or jj < 0 or jj >= w or not free[ii, jj]:
                continue
            if di[k] != 0 and dj[k] != 0 and not (free[ii, j] and free[i, jj]):
                continue
            n = ii * w + jj
            nd = d + step[k] * cost[ii, jj]
            if nd < dist[n]:
                dist[n] = nd
                size = _push(keys, nodes, size, nd, n)
    return dist


def grid_distances(free: np.ndarray, resolution: float, cost: np.ndarray | None, source: int) -> np.ndarray:
    """[H * W] float64: the length (metres, each move times the ``cost`` [H, W] of the cell it enters; None:
    1) of the shortest 8-connected path from the flat cell ``source`` to every cell over ``free`` [H, W]
    (a diagonal move needs both cells beside it free); inf where unreachable. A source that is not free
    reaches nothing but itself."""
    free = np.ascontiguousarray(free, dtype=np.bool_)
    h, w = free.shape
    if not 0 <= source < h * w:
        raise ValueError(f"source cell {source} is outside the {h} x {w} grid")
    cost = np.ones((h, w)) if cost is None else np.ascontiguousarray(cost, dtype=np.float64)
    if cost.shape != free.shape:
        raise ValueError(f"cost has shape {cost.shape}, the grid {free.shape}")
    step = np.array([resolution * math.hypot(a, b) for a, b in zip(_DI, _DJ)], dtype=np.float64)
    return _distances(free, step, cost, int(source), _DI, _DJ)
