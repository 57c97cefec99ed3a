"""Planning on what a robot's own scans have shown it: the optimistic mapless planner (issue 15).

A robot deployed in a building it has never seen is given the goal's position, not the map. What it
can know of the building is what its LiDAR has shown it so far. :class:`SeenWalls` keeps that per
environment slot - every beam's end marks its cell as a wall, and a mark stays until a later beam passes
through its cell (so a person who walked by leaves no trail; ``carve=False``: marks are never forgotten;
``memory=False``: only the current scan's) - and plans on it optimistically, through the space it has
not seen (unknown = free, as D* Lite and frontier navigation do): a shortest grid path to the goal
through the cells where the robot's disc (plus ``margin``) touches no known wall, with a cost that
grows within ``comfort`` metres of the walls (the oracle's, :class:`flashnav.sim.oracle.OracleController`).
It replans a slot when a newly seen wall lies on or beside its path.

Three controllers use it: ``scripts/mapless_planner.py`` steers with the oracle's pure pursuit along its
fields (the bound of what a controller without the map can do); :class:`flashnav.guidance.MaplessGuide`
hands a policy in the simulator, at every step, a point ``lookahead`` metres along its path as the goal
(``flashnav eval --maps ... --guide M --guide-from scans``); :class:`ScanGuide` does the same for one robot
from its LaserScan and odometry (``flashnav deploy ros --guide M``): a deployment mode that, unlike
:class:`flashnav.guidance.PathGuide`, needs no map. numpy, scipy and numba only (the deploy side has no
torch); the plans are :func:`flashnav.maps.grid_dijkstra.grid_distances`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from flashnav.maps.graph import MAX_WALL_COST, wall_cost
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.grid_dijkstra import grid_distances

SENSORS = ("raw", "pooled")
#: the 8-neighbourhood (row, column) and the centre
_MOVES = np.array([(0, 0), (-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)], dtype=np.int64)
#: beams on each side of a remembered cell's bearing that :meth:`SeenWalls._carve` tests against it
_CARVE_BEAMS = 4


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _nonzero(a: np.ndarray) -> tuple:
    """``np.nonzero`` of a sparse bool array, read 8 cells at a time (a remembered-walls memory is mostly
    empty, and a plain nonzero costs as much as the whole array)."""
    flat = np.ascontiguousarray(a).reshape(-1)
    pad = (-flat.size) % 8
    if pad:
        flat = np.concatenate([flat, np.zeros(pad, dtype=bool)])
    words = np.flatnonzero(flat.view(np.uint64))
    sub = np.nonzero(flat.reshape(-1, 8)[words])
    return np.unravel_index(words[sub[0]] * 8 + sub[1], a.shape)


class SeenWalls:
    """Per slot: the walls its scans have hit, on a grid of ``geometry``'s shape, resolution and origin
    (its occupancy is never read), and a distance field to the slot's goal over them.

    Inputs are arrays, so that the simulator (:class:`EnvScans`) and a robot
    (:class:`flashnav.deploy.controller.Controller`) feed it alike: poses [k, 3] (x, y, yaw) and goals
    [k, 2] in the grid's frame, ranges [k, B] metres along ``angles`` [B] (radians from the heading). A
    range below ``max_range`` is a return; ``max_range`` or more (``inf`` included) is a beam that met
    nothing within ``max_range``; NaN is a beam that says nothing (an invalid reading).

    Args:
        radius: metres; the plan's free space keeps the robot's centre this far from every known wall
            (the circumscribed radius plus a margin).
        comfort: metres beyond that in which cells cost more (paths keep clear of walls where they can).
        memory: remember walls across steps (False: plan on the current scan's walls alone).
        carve: with memory, forget a remembered wall when a later beam passes through its cell (free-space
            evidence: what moved away - a person, a door - stops blocking the plan). A cell is carved when
            a beam's line passes within half a cell of its centre and the beam's return (or its
            ``max_range``, for a beam that met nothing) lies more than a cell beyond it, and no return of
            the same scan ended in it or beside it (so the cells beside a wall the robot sees now stay, and
            a walking person's trail is carved a step behind them). False: marks are never forgotten.
    """

    def __init__(self, geometry: OccupancyMap, num: int, radius: float, comfort: float = 0.3, *, memory: bool = True,
                 carve: bool = True):
        if not (radius > 0 and comfort > 0):
            raise ValueError(f"mapless planner: radius and comfort must be > 0 metres, got {radius}, {comfort}")
        self.grid, self.radius, self.comfort, self.memory = geometry, float(radius), float(comfort), memory
        self.carve_walls = bool(carve and memory)
        h, w = geometry.shape
        self.known = np.zeros((num, h, w), dtype=bool)
        self.fields = np.full((num, h * w), np.inf, dtype=np.float32)
        self.goals = np.zeros((num, 2), dtype=np.float64)
        self.replans = np.zeros(num, dtype=np.int64)
        self.carved = np.zeros(num, dtype=np.int64)  # cells forgotten per slot, over its episodes
        # what the last mark() did, per row of the slots it marked: (row, i, j) of the cells it carved and of
        # the returns in cells it had not remembered (update() reads them), and how many slots it marked
        self._carved_at = self._new_at = (np.zeros(0, np.int64),) * 3
        self._marked = 0

    def cells(self, xy: np.ndarray) -> np.ndarray:
        """Flat cell index of the points ``xy`` [k, 2] (clipped onto the grid)."""
        i, j = self.grid.cell_of(xy, clip=True)
        return i * self.grid.shape[1] + j

    def _field(self, slot: int) -> np.ndarray:
        """Distance field (metres, inf where unreachable) to the slot's goal over its known walls."""
        g = self.grid
        seen = OccupancyMap(occupied=self.known[slot], resolution=g.resolution, origin=g.origin)
        free = seen.free_space(self.radius).copy()
        cost = wall_cost(seen.clearance, self.radius, self.comfort)
        goal = int(self.cells(self.goals[slot:slot + 1])[0])
        free.reshape(-1)[goal] = True  # the goal cell itself is never walled off by a margin
        self.replans[slot] += 1
        return grid_distances(free, g.resolution, cost, goal).astype(np.float32)

    def mark(self, slots: np.ndarray, pose: np.ndarray, ranges: np.ndarray, angles: np.ndarray,
             max_range: float) -> np.ndarray:
        """Marks the cells where the beams of ``slots`` end (ranges below ``max_range``) as walls, after
        carving (``carve``) the remembered ones that the beams pass through; returns [len(slots), H, W] the
        new ones (also in :attr:`last_carved`, the carved ones)."""
        self._mark(slots, pose, ranges, angles, max_range)
        return self._mask(self._new_at)

    def _mark(self, slots: np.ndarray, pose: np.ndarray, ranges: np.ndarray, angles: np.ndarray,
              max_range: float) -> None:
        """:meth:`mark` without the [k, H, W] mask: what it did is in ``_new_at`` / ``_carved_at`` as (row, i, j)
        (:meth:`update` reads those; a full-grid mask per step would cost as much as the memory)."""
        ends = self._ends(pose, ranges, angles, max_range)
        self._marked = len(pose)
        self._carved_at = (np.zeros(0, np.int64),) * 3
        if not self.memory:
            self._new_at = ends
            self.known[slots] = False
            self.known[slots[ends[0]], ends[1], ends[2]] = True
            return
        if self.carve_walls:
            self._carved_at = self._carve(slots, pose, ranges, angles, max_range, ends)
        fresh = ~self.known[slots[ends[0]], ends[1], ends[2]]  # returns in cells not remembered (yet)
        self._new_at = tuple(e[fresh] for e in ends)  # (row, i, j), a cell once per return that ended in it
        self.known[slots[self._new_at[0]], self._new_at[1], self._new_at[2]] = True

    @property
    def last_carved(self) -> np.ndarray:
        """[k, H, W]: the cells the last :meth:`mark` carved, per slot it marked."""
        return self._mask(self._carved_at)

    def _mask(self, at: tuple) -> np.ndarray:
        """[k, H, W] bool, True at the (row, i, j) ``at`` of the last :meth:`mark`'s k slots."""
        out = np.zeros((self._marked, *self.grid.shape), dtype=bool)
        out[at] = True
        return out

    def _ends(self, pose: np.ndarray, ranges: np.ndarray, angles: np.ndarray, max_range: float) -> tuple:
        """(row, i, j) of the cell where each return of the beams ends (rows: the scans' order)."""
        g = self.grid
        pose = np.asarray(pose, np.float64)
        ranges = np.asarray(ranges, np.float64)
        hit = np.isfinite(ranges) & (ranges < max_range - 1e-3)
        # a little beyond the surface, so the end lands in the wall's cell, not the free cell before it
        r = np.where(hit, ranges, 0.0) + 0.5 * g.resolution
        a = np.asarray(angles, np.float64)[None, :] + pose[:, 2:3]
        x, y = pose[:, :1] + r * np.cos(a), pose[:, 1:2] + r * np.sin(a)
        h, w = g.shape
        i, j = g.cell_of(np.stack((x, y), axis=-1))
        hit &= (i >= 0) & (i < h) & (j >= 0) & (j < w)  # ends off the grid are not remembered
        rows = np.broadcast_to(np.arange(len(pose))[:, None], hit.shape)
        return rows[hit], i[hit], j[hit]

    def _carve(self, slots: np.ndarray, pose: np.ndarray, ranges: np.ndarray, angles: np.ndarray,
               max_range: float, ends: tuple) -> tuple:
        """Forgets the remembered walls of ``slots`` that the beams pass through (see ``carve``), ``ends`` =
        (row, i, j) of this scan's returns; returns (row, i, j) of the cells forgotten. Each remembered cell
        is tested against the ``2 * _CARVE_BEAMS`` beams nearest its bearing, so the cost grows with the
        walls remembered, not with the beams."""
        g = self.grid
        res = g.resolution
        h, w = g.shape
        kk, ii, jj = _nonzero(self.known[slots])
        if not len(kk):
            return kk, ii, jj
        # no cell in or beside a return of this scan: the returns' 3 x 3 blocks, scattered (cheaper than a
        # dilation of the whole grid, which costs as much as the memory, not as the scan)
        near = np.zeros((len(slots), h, w), dtype=bool)
        sk, si, sj = ends
        for di, dj in _MOVES:
            near[sk, np.clip(si + di, 0, h - 1), np.clip(sj + dj, 0, w - 1)] = True
        keep = ~near[kk, ii, jj]
        kk, ii, jj = kk[keep], ii[keep], jj[keep]
        pose = np.asarray(pose, np.float64)
        dx = g.origin[0] + (jj + 0.5) * res - pose[kk, 0]
        dy = g.origin[1] + (ii + 0.5) * res - pose[kk, 1]
        dist = np.hypot(dx, dy)
        bearing = _wrap(np.arctan2(dy, dx) - pose[kk, 2])
        beam_angle = _wrap(np.asarray(angles, np.float64))
        order = np.argsort(beam_angle)
        ranges = np.asarray(ranges, np.float64)
        # how far each beam is known to be free: to its return, to max_range where it met nothing, nowhere if NaN
        free = np.where(np.isnan(ranges), -np.inf, np.minimum(ranges, max_range))
        at = np.searchsorted(beam_angle[order], bearing)
        hit = np.zeros(len(kk), dtype=bool)
        for offset in range(-_CARVE_BEAMS, _CARVE_BEAMS):
            b = order[(at + offset) % len(order)]
            delta = bearing - beam_angle[b]
            along, across = dist * np.cos(delta), np.abs(dist * np.sin(delta))
            hit |= (along > 0) & (across < 0.5 * res) & (along + res < free[kk, b])
        kk, ii, jj = kk[hit], ii[hit], jj[hit]
        self.known[slots[kk], ii, jj] = False
        self.carved[slots] += np.bincount(kk, minlength=len(slots))
        return kk, ii, jj

    def plan(self, slots: np.ndarray, goals: np.ndarray, scans: tuple) -> None:
        """New episodes of ``slots``: memories emptied, ``scans`` = (pose, ranges, angles, max_range)
        marked, then their fields to ``goals`` [k, 2]."""
        slots = np.asarray(slots)
        self.known[slots] = False
        self.goals[slots] = goals
        self._mark(slots, *scans)
        for slot in slots:
            self.fields[slot] = self._field(int(slot))

    def path_cells(self, slots: np.ndarray, xy: np.ndarray, steps: int = 400) -> np.ndarray:
        """[k, L] the cells (flat indices) of each slot's planned path from the points ``xy`` [k, 2]: the
        steepest descent of its field, all slots at once; a path that ends early repeats its last cell."""
        slots = np.asarray(slots)
        w = self.grid.shape[1]
        cell = self.cells(np.asarray(xy, np.float64).reshape(-1, 2))
        i, j = cell // w, cell % w
        value = self._values(slots, i[:, None], j[:, None])[:, 0]
        out = [i * w + j]
        for _ in range(steps):
            k, lowest = self._lowest(slots, i, j)
            move = lowest < value
            if not move.any():
                break
            i, j = np.where(move, i + _MOVES[k, 0], i), np.where(move, j + _MOVES[k, 1], j)
            value = np.where(move, lowest, value)
            out.append(i * w + j)
        return np.stack(out, axis=1)

    def update(self, slots: np.ndarray, scans: tuple) -> None:
        """After a step: ``scans`` = (pose, ranges, angles, max_range) of running ``slots`` marked (and
        carved); replanned are the slots whose path (from their pose) the new walls block or brush, and
        those where a carved wall may open a shorter way (:meth:`_opens`) or no path was known."""
        slots = np.asarray(slots)
        self._mark(slots, *scans)
        if not self.memory:
            for slot in slots:
                self.fields[slot] = self._field(int(slot))
            return
        pose = np.asarray(scans[0], np.float64)
        w = self.grid.shape[1]
        reach = self.radius / self.grid.resolution + 1.0  # cells: a wall this near a path cell blocks it
        nk, ni, nj = self._new_at
        walled = np.unique(nk)
        paths = self.path_cells(slots[walled], pose[walled, :2]) if len(walled) else None
        replan = np.zeros(len(slots), dtype=bool)
        for row, k in enumerate(walled):
            sel = nk == k
            walls = np.stack([ni[sel], nj[sel]], axis=1)
            path = paths[row]
            cells = np.stack([path // w, path % w], axis=1)
            gap = np.hypot(*(cells[:, None, :] - walls[None, :, :]).transpose(2, 0, 1)).min()
            replan[k] = gap <= reach or not np.isfinite(self.fields[slots[k]][path[0]])
        ck, ci, cj = self._carved_at
        for k in np.unique(ck):
            if not replan[k]:
                sel = ck == k
                replan[k] = self._opens(int(slots[k]), ci[sel], cj[sel], pose[k, :2])
        for slot in slots[replan]:
            self.fields[slot] = self._field(int(slot))

    def _opens(self, slot: int, ci: np.ndarray, cj: np.ndarray, xy: np.ndarray) -> bool:
        """Whether forgetting the cells (``ci``, ``cj``) may shorten the slot's path: no path was known
        from ``xy``, or around some carved cell two reachable cells differ in their path length by more
        than any way between them within the window (a radius and two cells a side) can cost - the wall
        stood between them."""
        h, w = self.grid.shape
        res = self.grid.resolution
        field = self.fields[slot].reshape(h, w)
        if not np.isfinite(field.reshape(-1)[self.cells(np.asarray(xy, np.float64).reshape(1, 2))[0]]):
            return True
        half = int(math.ceil(self.radius / res)) + 2
        i0, i1 = max(0, ci.min() - 2 * half), min(h, ci.max() + 2 * half + 1)
        j0, j1 = max(0, cj.min() - 2 * half), min(w, cj.max() + 2 * half + 1)
        box = field[i0:i1, j0:j1]
        finite = np.isfinite(box)
        if not finite.any():
            return False
        size = 2 * half + 1
        top = maximum_filter(np.where(finite, box, -np.inf), size=size, mode="constant", cval=-np.inf)
        low = minimum_filter(np.where(finite, box, np.inf), size=size, mode="constant", cval=np.inf)
        span = (top - low)[ci - i0, cj - j0]
        return bool((span > MAX_WALL_COST * math.sqrt(2.0) * (size - 1) * res).any())

    def _values(self, slots: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Field values of the slots' cells (i, j) [k, m]; off the grid: inf."""
        h, w = self.grid.shape
        inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
        v = self.fields[slots[:, None], np.clip(i, 0, h - 1) * w + np.clip(j, 0, w - 1)]
        return np.where(inside, v, np.inf)

    def _lowest(self, slots: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step of steepest descent for each slot's cell (i, j): the index into ``_MOVES`` of the lowest
        of the cell and its 8 neighbours (the first of equals, as a loop over them in order would take; 0 =
        stay) and its field value."""
        nb = self._values(slots, i[:, None] + _MOVES[:, 0], j[:, None] + _MOVES[:, 1])
        k = nb.argmin(axis=1)
        return k, nb[np.arange(len(slots)), k]

    def carrot(self, slots: np.ndarray, xy: np.ndarray, lookahead: float, escape: float = 0.3) -> np.ndarray:
        """[k, 2]: the point ``lookahead`` metres down each slot's field from ``xy`` [k, 2], or the slot's
        goal where the path to it is shorter than that or no path is known. Where ``xy`` lies in space the plan counts
        as blocked (closer than the radius to a seen wall), the descent starts from the lowest cell within
        ``escape`` metres."""
        g = self.grid
        slots = np.asarray(slots)
        w = g.shape[1]
        xy = np.asarray(xy, np.float64)
        goal = self.goals[slots]
        cell = self.cells(xy)
        i, j = cell // w, cell % w
        reach = max(1, int(math.ceil(escape / g.resolution)))
        di, dj = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1), indexing="ij")
        window = np.stack([di.ravel(), dj.ravel()], axis=1)
        around = self._values(slots, i[:, None] + window[:, 0], j[:, None] + window[:, 1])
        best = around.argmin(axis=1)
        here = self._values(slots, i[:, None], j[:, None])[:, 0]
        stuck = ~np.isfinite(here)
        i = np.where(stuck, i + window[best, 0], i)
        j = np.where(stuck, j + window[best, 1], j)
        value = np.where(stuck, around[np.arange(len(slots)), best], here)
        start = value.copy()  # the path still to go (metres, weighted by the wall cost: never below the length)
        step_m = np.where((_MOVES != 0).all(axis=1), math.sqrt(2.0), 1.0) * g.resolution
        travelled = np.zeros(len(slots))
        for _ in range(int(math.ceil(lookahead / g.resolution)) + 1):
            k, lowest = self._lowest(slots, i, j)
            move = np.isfinite(value) & (lowest < value) & (travelled < lookahead)
            if not move.any():
                break
            i, j = np.where(move, i + _MOVES[k, 0], i), np.where(move, j + _MOVES[k, 1], j)
            travelled += np.where(move, step_m[k], 0.0)
            value = np.where(move, lowest, value)
        point = np.stack([g.origin[0] + (j + 0.5) * g.resolution, g.origin[1] + (i + 0.5) * g.resolution], axis=1)
        # the goal itself once the path to it (not the straight line: a wall may stand between) is within the
        # lookahead, or where no path is known
        use_goal = ~np.isfinite(start) | (start <= lookahead) | (value <= 0)
        return np.where(use_goal[:, None], goal, point)


class ScanGuide:
    """:class:`SeenWalls` for one robot: each goal starts an empty memory on a square grid centred on
    the robot's pose at the goal's first control step (odometry frame; ``window`` metres a side, or
    2 x the goal's distance + 8 m where that is more), fed with every control step's scan. A plan
    costs ~0.1 s on a 16-m window at 5 cm (one core of the dev CPU); paths beyond the window are not
    considered.

    ``step(pose, angles, ranges, max_range)`` -> the carrot (x, y), odometry frame: ``angles`` [B]
    radians from the heading of the beams' directions and ``ranges`` [B] metres from the robot's centre
    (NaN: no return), as :meth:`flashnav.deploy.scan.ScanAdapter.beams` gives them.
    """

    def __init__(self, radius: float, lookahead: float = 0.5, resolution: float = 0.05, window: float = 16.0,
                 comfort: float = 0.3, escape: float = 0.3):
        if not (math.isfinite(lookahead) and lookahead > 0):
            raise ValueError(f"mapless guidance lookahead must be > 0 metres, got {lookahead}")
        if not (resolution > 0 and window > 0):
            raise ValueError(f"mapless guidance grid: resolution and window must be > 0 m, got {resolution}, {window}")
        self.radius, self.lookahead, self.resolution = float(radius), float(lookahead), float(resolution)
        self.window, self.comfort, self.escape = float(window), float(comfort), float(escape)
        self.goal: tuple[float, float] | None = None
        self.walls: SeenWalls | None = None

    def start(self, goal) -> None:
        """A new goal (odometry frame): the next :meth:`step` starts a new memory."""
        self.goal, self.walls = (float(goal[0]), float(goal[1])), None

    def step(self, pose, angles, ranges, max_range: float) -> tuple[float, float]:
        if self.goal is None:
            raise ValueError("ScanGuide.step before start(goal)")
        pose = np.asarray(pose, np.float64).reshape(1, 3)
        scans = (pose, np.asarray(ranges, np.float64).reshape(1, -1), np.asarray(angles, np.float64), float(max_range))
        if self.walls is None:
            side = max(self.window, 2.0 * math.dist(pose[0, :2], self.goal) + 8.0)
            cells = int(math.ceil(side / self.resolution))
            origin = (pose[0, 0] - 0.5 * cells * self.resolution, pose[0, 1] - 0.5 * cells * self.resolution)
            geometry = OccupancyMap(np.zeros((cells, cells), dtype=bool), self.resolution, origin=origin)
            self.walls = SeenWalls(geometry, 1, self.radius, self.comfort)
            self.walls.plan(np.zeros(1, np.int64), np.asarray([self.goal]), scans)
        else:
            self.walls.update(np.zeros(1, np.int64), scans)
        x, y = self.walls.carrot(np.zeros(1, np.int64), pose[:, :2], self.lookahead, self.escape)[0]
        return float(x), float(y)
