"""The numba kernel behind :func:`flashnav.maps.geodesic.geodesic_pairs` (nothing else should call
this module): from each source cell, a Dijkstra bounded by a path length over a window of the grid,
and a seeded choice of the cells whose path length falls in a band.

Distances are in cells along the 8-connected grid (steps of 1 and sqrt(2)); a diagonal step needs
both cells beside it free, so paths never cut a corner. A cell farther than ``hi`` cells along any
path is also farther than ``hi`` cells in a straight line, so each source's search only needs the
window of ``2 ceil(hi) + 1`` cells around it; its cost grows with the band, not with the map.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_SQRT2 = math.sqrt(2.0)


@njit(cache=True)
def _splitmix(state):
    """(next state, a pseudo-random uint64): splitmix64, so the choice of goals depends only on the
    seed and the source, never on threads."""
    state = (state + np.uint64(0x9E3779B97F4A7C15)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = state
    z = ((z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = ((z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    return state, z ^ (z >> np.uint64(31))


@njit(cache=True)
def _append(buf, size, val):
    """Append ``val`` to ``buf`` holding ``size`` entries, doubling it when full; returns buf."""
    if size == buf.size:
        grown = np.empty(2 * buf.size, np.int64)
        grown[:size] = buf[:size]
        buf = grown
    buf[size] = val
    return buf


@njit(cache=True)
def _relax(free, dist, c, d, bound, i0, j0, wh, ww, bufs, sizes):
    """Dijkstra's relaxation of the 8 neighbours of window cell ``c`` (settled at distance ``d`` cells)
    in the window (rows i0.., cols j0.., wh x ww) of ``free``: a neighbour reached shorter, within
    ``bound``, gets its distance and joins bucket int(distance) % 3 of ``bufs`` / ``sizes``."""
    ci, cj = c // ww, c % ww
    for di in range(-1, 2):
        for dj in range(-1, 2):
            if di == 0 and dj == 0:
                continue
            ni, nj = ci + di, cj + dj
            if ni < 0 or nj < 0 or ni >= wh or nj >= ww or not free[ni + i0, nj + j0]:
                continue
            step = 1.0
            if di != 0 and dj != 0:
                if not (free[ci + di + i0, cj + j0] and free[ci + i0, cj + dj + j0]):
                    continue  # no corner cutting
                step = _SQRT2
            nd = d + step
            n = ni * ww + nj
            if nd <= bound and nd < dist[n]:
                dist[n] = nd
                b = int(nd) % 3
                bufs[b] = _append(bufs[b], sizes[b], n)
                sizes[b] += 1


@njit(cache=True)
def _dijkstra(free, src, reach, bound, lo, band):
    """Dijkstra (Dinitz's buckets) from cell ``src`` (flat index into ``free`` [H, W] bool) over the part
    inside the map of the window of ``2 reach + 1`` cells centred on it, bounded at ``bound`` cells.
    Returns (dist [wh * ww] cells, inf where farther, not free or unreachable; i0, j0, wh, ww: the
    window part's corner and size; nband): the flat map indices of the settled cells with distance
    >= ``lo`` are written to ``band``, in the order they settle, and counted by nband."""
    h, w = free.shape
    si, sj = src // w, src % w
    i0, j0 = max(si - reach, 0), max(sj - reach, 0)
    wh, ww = min(si + reach + 1, h) - i0, min(sj + reach + 1, w) - j0
    dist = np.full(wh * ww, np.inf)
    settled = np.zeros(wh * ww, np.bool_)
    # Dinitz's bucket queue: bucket k holds cells first reached at a distance in [k, k + 1). No step
    # is shorter than 1, so cells of one bucket cannot shorten each other's paths: each is final when
    # its bucket comes up (an exact Dijkstra without a heap). Steps are < 2, so a cell of bucket k
    # only reaches buckets k + 1 and k + 2: three rotating buffers hold them all.
    bufs = [np.empty(256, np.int64), np.empty(256, np.int64), np.empty(256, np.int64)]
    sizes = np.zeros(3, np.int64)
    start = (si - i0) * ww + (sj - j0)
    dist[start] = 0.0
    bufs[0] = _append(bufs[0], 0, start)
    sizes[0] = 1
    nband = 0
    for k in range(int(bound) + 1):
        cur = k % 3
        todo = bufs[cur]
        for e in range(sizes[cur]):
            c = todo[e]
            d = dist[c]
            if settled[c] or d >= k + 1:
                continue  # a stale entry: the cell was reached closer since (same or earlier bucket)
            settled[c] = True
            if d >= lo:
                band[nband] = (c // ww + i0) * w + (c % ww + j0)
                nband += 1
            _relax(free, dist, c, d, bound, i0, j0, wh, ww, bufs, sizes)
        sizes[cur] = 0
    return dist, i0, j0, wh, ww, nband


@njit(cache=True)
def _band_cells(free, src, lo, hi, max_goals, seed, out):
    """Up to ``max_goals`` cells whose path length from cell ``src`` (flat index into ``free`` [H, W]
    bool) lies in [lo, hi] cells (all of them if fewer), drawn by a seeded shuffle: writes their flat
    indices to ``out`` and returns how many."""
    reach = int(math.ceil(hi)) + 1
    band = np.empty((2 * reach + 1) ** 2, np.int64)
    nband = _dijkstra(free, src, reach, hi, lo, band)[5]
    # a seeded partial Fisher-Yates shuffle picks the goals
    state = np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(src)
    take = min(nband, max_goals)
    for k in range(take):
        state, r = _splitmix(state)
        pick = k + int(r % np.uint64(nband - k))
        band[k], band[pick] = band[pick], band[k]
        out[k] = band[k]
    return take


@njit(parallel=True, cache=True)
def band_pairs(free, sources, lo, hi, max_goals, seed):
    """For each source cell (flat indices [P] into ``free`` [H, W] bool), up to ``max_goals`` cells
    whose grid path length from it lies in [lo, hi] cells: (goals [P, max_goals] int64 flat indices,
    counts [P] int64)."""
    p = sources.size
    goals = np.full((p, max_goals), -1, np.int64)
    counts = np.zeros(p, np.int64)
    for k in prange(p):
        counts[k] = _band_cells(free, sources[k], lo, hi, max_goals, seed, goals[k])
    return goals, counts


@njit(cache=True)
def _window_field(free, src, reach, bound, out):
    """The path length in cells from cell ``src`` (flat index into ``free`` [H, W] bool) to every cell of
    the window of ``2 reach + 1`` cells centred on it, written to ``out`` [2 reach + 1, 2 reach + 1]
    float32 (:func:`_dijkstra`, bounded at ``bound`` cells); cells farther, not free, unreachable or
    outside the map stay inf."""
    w = free.shape[1]
    si, sj = src // w, src % w
    dist, i0, j0, wh, ww, _ = _dijkstra(free, src, reach, bound, np.inf, np.empty(0, np.int64))
    out[:, :] = np.inf
    oi, oj = i0 - (si - reach), j0 - (sj - reach)  # where the map part sits in the full window
    for i in range(wh):
        for j in range(ww):
            out[oi + i, oj + j] = dist[i * ww + j]


@njit(parallel=True, cache=True)
def window_fields(free, sources, reach, bound):
    """For each source cell (flat indices [P] into ``free`` [H, W] bool), the path lengths in cells to the
    window of ``2 reach + 1`` cells centred on it, bounded at ``bound`` cells (inf beyond):
    [P, 2 reach + 1, 2 reach + 1] float32."""
    p = sources.size
    side = 2 * reach + 1
    out = np.empty((p, side, side), np.float32)
    for k in prange(p):
        _window_field(free, sources[k], reach, bound, out[k])
    return out


@njit(cache=True)
def _whole_map(free, src, bound):
    """[H * W] path lengths in cells from cell ``src`` to every cell of the map, bounded at ``bound`` cells
    (:func:`_dijkstra` with a window that covers the whole map)."""
    h, w = free.shape
    return _dijkstra(free, src, max(h, w), bound, np.inf, np.empty(0, np.int64))[0]


@njit(parallel=True, cache=True)
def map_fields(free, sources, bound):
    """For each source cell (flat indices [P] into ``free`` [H, W] bool), the path lengths in cells to every
    cell of the map, bounded at ``bound`` cells (inf beyond, where not free or unreachable): [P, H * W]
    float32 (:func:`_whole_map`)."""
    p = sources.size
    h, w = free.shape
    out = np.empty((p, h * w), np.float32)
    for k in prange(p):
        out[k, :] = _whole_map(free, sources[k], bound)
    return out


@njit(parallel=True, cache=True)
def pair_lengths(free, sources, targets, bound):
    """For each pair k, the path length in cells from cell ``sources[k]`` to cell ``targets[k]`` (flat
    indices into ``free`` [H, W] bool), bounded at ``bound`` cells: [P] float64, inf where farther, not
    free or unreachable (:func:`_whole_map`)."""
    p = sources.size
    out = np.empty(p, np.float64)
    for k in prange(p):
        out[k] = _whole_map(free, sources[k], bound)[targets[k]]
    return out
