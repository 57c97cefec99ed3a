"""The wall map's plan channel (``observation.wall_map_plan``, issue 15): the cells of the shortest way from the
robot to its goal over the cells that its scans have not marked as walls.

The imitation probes of issue 15 (docs/benchmarks.md, "Can a recurrent network learn the mazes ...") put the
remembering mapless planner at 99.4 % of the validation mazes and the best network that reads the wall map at
92.6 %: the network does not compute the plan that the map allows. This channel hands it that plan, computed from
nothing but the policy's own wall memory (no map): unknown cells are free, as :mod:`flashnav.mapless` plans (the
optimistic plan of frontier navigation), so the path runs into unseen space and bends as walls are seen.

The plan, per slot: an 8-connected shortest path (moves of 1 and sqrt 2 cells; a diagonal move needs both cells
beside it free, so a diagonal line of wall cells blocks it) from the goal's cell over the cells not marked,
the robot's and the goal's cells always free, within the box around both cells widened by ``margin`` cells on
every side (clipped onto the grid): the episodes' goals lie a few metres away by path length, and the box bounds the
cost whatever the map's size. The path is traced back from the robot's cell through the neighbour that lies on a
shortest way (the least distance plus the move; the first of equals in a fixed order; steepest descent alone can cut
onto a diagonal that is not one), marked cell by cell from the robot's cell to the goal's; no cell is marked
when the goal cannot be reached inside the box. The plan ignores the robot's body (a gap of one free cell counts
as open): it is a direction, and the policy keeps to the walls it sees. ``observation.wall_map_plan_penalty``
(``penalty`` here) makes a cell beside a marked one dearer, as a costmap's inflation does: the plan then runs down
the middle of a corridor and through the wider of two gaps, and takes a narrow gap only where it is the way.
``observation.wall_map_carrot`` (L metres) hands the policy the plan's direction as two columns too: the point L
metres of path along it from the robot (:func:`plan_route`'s carrot, :func:`carrot_points`), the pure-pursuit
carrot of :mod:`flashnav.guidance` computed from the policy's own wall memory.

numpy and numba only (the deploy side has no torch): the simulator's :class:`flashnav.sim.wall_grid.WallGrid` and a
robot's :class:`flashnav.deploy.memory.WallCells` call the same kernel.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from flashnav.maps.grid_dijkstra import _DI, _DJ, _pop, _push

#: Metres around the box of the robot's and the goal's cells within which the plan runs (``margin`` in cells is
#: this over the grid's cell): room for detours round the walls between them.
PLAN_MARGIN_M = 3.0


@njit(cache=True)
def _free(known, slot, w, r, c, sr, sc, gr, gc):
    return (not known[slot, r * w + c]) or (r == sr and c == sc) or (r == gr and c == gc)


@njit(cache=True)
def _cost(known, slot, w, r, c, sr, sc, gr, gc, r0, r1, c0, c1, penalty):
    """What entering cell (r, c) costs a move's length times: 1, or 1 + ``penalty`` beside a marked cell of the box."""
    if penalty == 0.0:
        return 1.0
    for k in range(8):
        ii, jj = r + _DI[k], c + _DJ[k]
        if r0 <= ii <= r1 and c0 <= jj <= c1 and not _free(known, slot, w, ii, jj, sr, sc, gr, gc):
            return 1.0 + penalty
    return 1.0


@njit(cache=True)
def _plan_paths(known, rows, start, goal, h, w, margin, penalty, out, carrot, carrots):
    step = np.empty(8)
    for k in range(8):
        step[k] = np.sqrt(float(_DI[k] * _DI[k] + _DJ[k] * _DJ[k]))
    dist = np.full(h * w, np.inf)
    done = np.zeros(h * w, dtype=np.bool_)
    cap = 8 * h * w + 1
    keys = np.empty(cap, dtype=np.float64)
    nodes = np.empty(cap, dtype=np.int64)
    for i in range(rows.shape[0]):
        slot = rows[i]
        sr, sc, gr, gc = start[i, 0], start[i, 1], goal[i, 0], goal[i, 1]
        r0, r1 = max(0, min(sr, gr) - margin), min(h - 1, max(sr, gr) + margin)
        c0, c1 = max(0, min(sc, gc) - margin), min(w - 1, max(sc, gc) + margin)
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                dist[r * w + c] = np.inf
                done[r * w + c] = False
        source = gr * w + gc
        dist[source] = 0.0
        size = _push(keys, nodes, 0, 0.0, source)
        target = sr * w + sc
        while size > 0:
            d, u, size = _pop(keys, nodes, size)
            if done[u]:
                continue
            done[u] = True
            if u == target:
                break  # every cell of the descent from the robot's cell is settled by now
            ui, uj = u // w, u % w
            for k in range(8):
                ii, jj = ui + _DI[k], uj + _DJ[k]
                if ii < r0 or ii > r1 or jj < c0 or jj > c1 or not _free(known, slot, w, ii, jj, sr, sc, gr, gc):
                    continue
                if _DI[k] != 0 and _DJ[k] != 0 and not (_free(known, slot, w, ii, uj, sr, sc, gr, gc)
                                                         and _free(known, slot, w, ui, jj, sr, sc, gr, gc)):
                    continue
                n = ii * w + jj
                nd = d + step[k] * _cost(known, slot, w, ii, jj, sr, sc, gr, gc, r0, r1, c0, c1, penalty)
                if nd < dist[n]:
                    dist[n] = nd
                    size = _push(keys, nodes, size, nd, n)
        if not done[target]:
            continue
        r, c = sr, sc
        out[i, r * w + c] = True
        here = dist[target]
        walked = 0.0  # cells of path length from the robot's cell
        while here > 0.0:
            best, bi, bj = np.inf, -1, -1
            entered = _cost(known, slot, w, r, c, sr, sc, gr, gc, r0, r1, c0, c1, penalty)  # this cell's, from each
            for k in range(8):
                ii, jj = r + _DI[k], c + _DJ[k]
                if ii < r0 or ii > r1 or jj < c0 or jj > c1 or not done[ii * w + jj]:
                    continue
                if _DI[k] != 0 and _DJ[k] != 0 and not (_free(known, slot, w, ii, c, sr, sc, gr, gc)
                                                         and _free(known, slot, w, r, jj, sr, sc, gr, gc)):
                    continue
                through = dist[ii * w + jj] + step[k] * entered
                if dist[ii * w + jj] < here and through < best:
                    best, bi, bj = through, ii, jj
            if bi < 0:
                break
            walked += np.sqrt(float((bi - r) * (bi - r) + (bj - c) * (bj - c)))
            r, c, here = bi, bj, dist[bi * w + bj]
            out[i, r * w + c] = True
            if carrot > 0.0 and carrots[i, 2] < 0 and walked >= carrot - 1e-9:
                carrots[i, 0], carrots[i, 1], carrots[i, 2] = r, c, 1
        if carrot > 0.0 and carrots[i, 2] < 0:  # the plan ends nearer than the carrot: its end, the goal's cell
            carrots[i, 0], carrots[i, 1], carrots[i, 2] = r, c, 0


def check_carrot(owner: str, carrot: float, plan: bool, plan_name: str = "plan") -> float:
    """``carrot`` (metres along the plan) as a float: 0, or a finite number > 0 with the plan on; else a ValueError
    naming ``owner`` and both settings (``plan_name``: what the owner calls its plan switch)."""
    if not (math.isfinite(carrot) and carrot >= 0) or (carrot and not plan):
        raise ValueError(f"{owner}: carrot must be 0 or, with {plan_name}, metres > 0, got carrot={carrot!r} with "
                         f"{plan_name}={plan}")
    return float(carrot)


def plan_cells(known: np.ndarray, rows: np.ndarray, start: np.ndarray, goal: np.ndarray, shape: tuple[int, int],
               margin: int, penalty: float = 0.0) -> np.ndarray:
    """[k, H W + 1] bool: the cells of the plan (the module's docstring) of each slot ``rows[i]`` of the grids
    ``known [N, H W + 1]`` (bool, row-major cells of ``shape`` (H, W); the last column a spare, never read, never
    marked), from the robot's cell ``start[i]`` to the goal's ``goal[i]`` ((row, column) on the grid; clipped onto
    it), within ``margin`` cells around both. With ``penalty`` > 0 the way is the cheapest, not the shortest: a
    move into a cell beside a marked cell of the box (8-neighbourhood) costs its length times 1 + ``penalty`` (the
    inflation cost of a costmap, one cell wide), so the plan keeps off the walls where there is room and still
    passes every gap the plain plan passes."""
    return plan_route(known, rows, start, goal, shape, margin, penalty)[0]


def plan_route(known: np.ndarray, rows: np.ndarray, start: np.ndarray, goal: np.ndarray, shape: tuple[int, int],
               margin: int, penalty: float = 0.0, carrot: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`plan_cells` (``cells``) and, per slot, its carrot (``carrots [k, 3]`` int64: row, column, kind): with
    ``carrot`` > 0 (cells of path length), the first cell of the plan, walked from the robot's cell, at least
    ``carrot`` cells of path (moves of 1 and sqrt 2) from it, kind 1; where the whole plan is shorter, its last
    cell (the goal's), kind 0; where there is no plan (or ``carrot`` is 0), (-1, -1, -1)."""
    penalty, carrot = float(penalty), float(carrot)
    if not (np.isfinite(penalty) and penalty >= 0.0):
        raise ValueError(f"plan_cells: penalty must be a finite number >= 0, got {penalty}")
    if not (np.isfinite(carrot) and carrot >= 0.0):
        raise ValueError(f"plan_route: carrot must be a finite number of cells >= 0, got {carrot}")
    h, w = (int(v) for v in shape)
    known = np.ascontiguousarray(known, dtype=np.bool_)
    if known.ndim != 2 or known.shape[1] != h * w + 1:
        raise ValueError(f"plan_cells: known must be [N, {h * w + 1}] for a {h} x {w} grid, got {known.shape}")
    rows = np.ascontiguousarray(rows, dtype=np.int64).reshape(-1)
    k = rows.shape[0]
    lim = np.array([h - 1, w - 1], dtype=np.int64)
    start = np.clip(np.asarray(start, dtype=np.int64).reshape(k, 2), 0, lim)
    goal = np.clip(np.asarray(goal, dtype=np.int64).reshape(k, 2), 0, lim)
    out = np.zeros((k, h * w + 1), dtype=np.bool_)
    carrots = np.full((k, 3), -1, dtype=np.int64)
    if k:
        _plan_paths(known, rows, start, goal, h, w, max(0, int(margin)), penalty, out, carrot, carrots)
    return out, carrots


def carrot_points(carrots: np.ndarray, origin: np.ndarray, cell: float, pose: np.ndarray, goal: np.ndarray,
                  length: float) -> np.ndarray:
    """[k, 2] float64: each slot's carrot (``observation.wall_map_carrot``) in its robot's frame (x ahead, y to the
    left), metres: the centre of its carrot cell (``carrots`` of :func:`plan_route`, kind 1: row and column on a
    grid of ``cell`` metres whose cell (0, 0) has its corner at ``origin [k, 2]``), else (a shorter plan, or none)
    the goal ``goal [k, 2]``; seen from ``pose [k, 3]`` and brought within ``length`` metres of the robot along its
    bearing (a goal with no plan to it is a direction)."""
    carrots = np.asarray(carrots, dtype=np.int64).reshape(-1, 3)
    origin, pose = np.asarray(origin, np.float64).reshape(-1, 2), np.asarray(pose, np.float64).reshape(-1, 3)
    goal = np.asarray(goal, np.float64).reshape(-1, 2)
    centre = np.stack([(carrots[:, 1] + 0.5) * cell + origin[:, 0], (carrots[:, 0] + 0.5) * cell + origin[:, 1]], 1)
    d = np.where(carrots[:, 2:3] == 1, centre, goal) - pose[:, :2]
    cos, sin = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    x, y = cos * d[:, 0] + sin * d[:, 1], cos * d[:, 1] - sin * d[:, 0]
    norm = np.hypot(x, y)
    shrink = np.where(norm > length, length / np.maximum(norm, 1e-300), 1.0)
    return np.stack([x * shrink, y * shrink], axis=1)
