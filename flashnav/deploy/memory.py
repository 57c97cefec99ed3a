"""The memory scan on the robot (numpy, no torch): :mod:`flashnav.sim.memory` from a real scanner's beams.

A policy trained with ``observation.memory_frames`` F > 0 ends its observation with a 360-deg pooled scan
of the wall hits stored in the last F stored scans. The simulator cuts its own beams into groups of
consecutive beams; a robot's scanner has other beams, so here a stored scan is cut by angle into the same
``points_per_frame`` equal wedges across the policy's field of view (the simulator's groups exactly, for
its own beams): each wedge keeps its nearest hit at that beam's bearing, in the odometry frame. The
controller (:class:`flashnav.deploy.controller.Controller`) stores the first control step's scan after a
goal and then one every ``every`` control steps, as the simulator's episode steps; a new goal forgets.
"""

from __future__ import annotations

import math

import numpy as np

from flashnav.deploy.runtime import robot_frame
from flashnav.maps.seen_plan import PLAN_MARGIN_M, carrot_points, check_carrot, plan_route

#: Metres along each axis from the robot within which :meth:`WallCells.plan_centres` takes the goal (a farther one is
#: brought onto that square's edge): the largest generated map's side, which bounds the simulator's plans.
PLAN_REACH_M = 30.0


class ScanMemory:
    """The stored wall points of one robot (odometry frame) and the memory scan they give."""

    def __init__(self, frames: int, every: int, sectors: int, points: int, fov_deg: float, max_range: float):
        if frames < 1 or every < 1 or sectors < 1 or points < 1 or not 0 < fov_deg <= 360 or not max_range > 0:
            raise ValueError(f"ScanMemory needs frames, every, sectors, points >= 1, fov in (0, 360] deg and a "
                             f"positive max range, got {frames}, {every}, {sectors}, {points}, {fov_deg}, {max_range}")
        self.frames, self.every, self.sectors, self.points = frames, every, sectors, points
        self.fov, self.max_range = math.radians(fov_deg), float(max_range)
        self.stored: list[np.ndarray] = []  # frames of hit points [h, 2], newest first

    def forget(self) -> None:
        """A new goal: nothing is remembered."""
        self.stored = []

    def frame(self, pose, angles: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        """The hit points [h, 2] (odometry frame) of one scan: beams at ``angles`` [B] (radians from the
        heading) with ``ranges`` [B] (m; inf = no return, NaN = invalid) seen from ``pose`` (x, y, yaw):
        the nearest hit below max range in each of ``points`` equal wedges across the field of view."""
        angles, ranges = np.asarray(angles, np.float64), np.asarray(ranges, np.float64)
        rel = angles + 0.5 * self.fov
        if self.fov >= 2 * math.pi:
            rel = np.mod(rel, 2 * math.pi)
        wedge = np.floor(rel / (self.fov / self.points)).astype(np.int64)
        hit = np.isfinite(ranges) & (ranges < self.max_range) & (wedge >= 0) & (wedge < self.points)
        best = np.full(self.points, np.inf)
        np.minimum.at(best, wedge[hit], ranges[hit])
        out = []
        for j in np.flatnonzero(np.isfinite(best)):  # the first beam of the wedge at its minimum
            k = np.flatnonzero(hit & (wedge == j) & (ranges == best[j]))[0]
            bearing = float(pose[2]) + angles[k]
            out.append((float(pose[0]) + best[j] * math.cos(bearing), float(pose[1]) + best[j] * math.sin(bearing)))
        return np.asarray(out, np.float64).reshape(-1, 2)

    def step(self, pose, angles, ranges, goal_steps: int) -> np.ndarray:
        """The memory scan [sectors] float32 m for the control step ``goal_steps`` (0 = the goal's first)
        at ``pose``: its scan is stored first when ``goal_steps`` is 0 or a multiple of ``every``."""
        if not self.stored or goal_steps % self.every == 0:
            self.stored = [self.frame(pose, angles, ranges), *self.stored][: self.frames]
        return self.scan(pose)

    def scan(self, pose) -> np.ndarray:
        """[sectors] float32: the distance to the nearest stored point per 360-deg sector of the robot frame
        of ``pose`` (sector 0 from straight behind, counter-clockwise); max range where none lies."""
        out = np.full(self.sectors, self.max_range)
        pts = np.concatenate(self.stored) if self.stored else np.zeros((0, 2))
        if len(pts):
            dx, dy = pts[:, 0] - float(pose[0]), pts[:, 1] - float(pose[1])
            c, s = math.cos(float(pose[2])), math.sin(float(pose[2]))
            x, y = c * dx + s * dy, -s * dx + c * dy
            sector = np.clip(np.floor((np.arctan2(y, x) + math.pi) / (2 * math.pi / self.sectors)).astype(np.int64),
                             0, self.sectors - 1)
            np.minimum.at(out, sector, np.minimum(np.hypot(x, y), self.max_range))
        return out.astype(np.float32)


def wall_image(points: np.ndarray, pose, goal, cells: int, cell: float,
               visited: np.ndarray | None = None, plan: np.ndarray | None = None) -> np.ndarray:
    """[2, cells, cells] float32: :func:`flashnav.sim.wall_image.wall_image` of one robot in numpy (float64), the
    wall ``points`` [Q, 2] and ``goal`` (x, y) in the frame of ``pose`` (x, y, yaw): channel 0 is 1 in each square
    a point falls in, channel 1 in the goal's square (clipped onto the edge); row = left (row 0 rightmost),
    column = forward (column 0 behind). With ``visited`` [V, 2] (where the robot has been) a third channel
    [3, cells, cells], drawn as the walls are; with ``plan`` [L, 2] (the plan's cells' centres) one more channel,
    last."""
    half = cells * cell / 2

    def squares(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fwd, left = robot_frame(xy, pose).T
        return np.floor((left + half) / cell), np.floor((fwd + half) / cell)

    def mark(channel: np.ndarray, points: np.ndarray) -> None:
        pts = np.asarray(points, np.float64).reshape(-1, 2)
        pts = pts[np.isfinite(pts).all(1)]  # a point at infinity lies in no square (and would turn into nan)
        r, col = squares(pts)
        inside = (r >= 0) & (r < cells) & (col >= 0) & (col < cells)
        channel[r[inside].astype(np.int64), col[inside].astype(np.int64)] = 1.0

    out = np.zeros((2 + (visited is not None) + (plan is not None), cells, cells), np.float32)
    mark(out[0], points)
    r, col = squares(np.asarray(goal, np.float64).reshape(1, 2))
    out[1, int(np.clip(r[0], 0, cells - 1)), int(np.clip(col[0], 0, cells - 1))] = 1.0
    if visited is not None:
        mark(out[2], visited)
    if plan is not None:
        mark(out[-1], plan)
    return out


class WallCells:
    """The wall map on the robot (:class:`flashnav.sim.wall_grid.WallGrid`'s): the cells of a grid of ``grid``
    metres in the odometry frame (cell (0, 0) from its origin) in which a beam ended, ``beyond`` metres past its
    return, since the goal; drawn as the policy's ``cells`` x ``cells`` squares of ``cell`` metres at the marked
    cells' centres. The simulator's grid starts at its map's corner, the robot's at the odometry origin: the
    same kind of grid, placed elsewhere against the walls. With ``visited`` it also keeps the cells the robot's
    odometry pose has been in at each control step since the goal, drawn as a third channel. With ``plan`` the
    plan's cells (:meth:`plan_centres`) are drawn as the last channel; with ``carrot`` (metres) every :meth:`step`
    also leaves the plan's carrot in :attr:`carrot_xy` (as the simulator's grid does:
    :func:`flashnav.maps.seen_plan.carrot_points`)."""

    def __init__(self, cells: int, cell: float, grid: float, max_range: float, beyond: float = 0.0,
                 visited: bool = False, plan: bool = False, plan_penalty: float = 0.0, carrot: float = 0.0):
        if cells < 2 or not (cell > 0 and grid > 0 and max_range > 0 and beyond >= 0):
            raise ValueError(f"WallCells needs >= 2 squares a side, cells and grid > 0 m, max_range > 0 and beyond "
                             f">= 0, got {cells}, {cell}, {grid}, {max_range}, {beyond}")
        self.cells, self.cell, self.grid = int(cells), float(cell), float(grid)
        self.max_range, self.beyond = float(max_range), float(beyond)
        self.known = np.zeros((0, 2), np.int64)  # marked (column, row) pairs, each once
        self.visited = np.zeros((0, 2), np.int64) if visited else None  # the cells the robot has been in
        self.plan = bool(plan)
        self.plan_penalty = float(plan_penalty)  # seen_plan.plan_cells' penalty: the policy's, from its metadata
        self.carrot = check_carrot("WallCells", carrot, plan)
        #: [2] the carrot (x, y m in the robot frame) of the last :meth:`step`, None without ``carrot``
        self.carrot_xy: np.ndarray | None = None

    def forget(self) -> None:
        """A new goal: no wall is known (and the robot has been nowhere)."""
        self.known = np.zeros((0, 2), np.int64)
        if self.visited is not None:
            self.visited = np.zeros((0, 2), np.int64)

    def mark(self, pose, angles: np.ndarray, ranges: np.ndarray) -> None:
        """Marks the cells where the beams at ``angles`` [B] (radians from the heading) with ``ranges`` [B] (m; inf =
        no return, NaN = invalid) from ``pose`` (x, y, yaw) end: returns below max range only."""
        angles, ranges = np.asarray(angles, np.float64), np.asarray(ranges, np.float64)
        hit = np.isfinite(ranges) & (ranges < self.max_range)
        r, bearing = ranges[hit] + self.beyond, angles[hit] + float(pose[2])
        x, y = float(pose[0]) + r * np.cos(bearing), float(pose[1]) + r * np.sin(bearing)
        new = np.stack([np.floor(x / self.grid), np.floor(y / self.grid)], axis=1).astype(np.int64)
        self.known = np.unique(np.concatenate([self.known, new]), axis=0)

    def plan_centres(self, pose, goal) -> np.ndarray:
        """[L, 2] the centres of the plan's cells from the cell of ``pose`` to the cell of ``goal`` (odometry frame):
        :func:`flashnav.maps.seen_plan.plan_cells` on the marked cells of the box it searches (the simulator's grid
        also clips that box onto its map; here a goal farther than :data:`PLAN_REACH_M` along an axis is first
        brought within it, so that the box stays bounded). With :attr:`carrot`, sets :attr:`carrot_xy`."""
        g = self.grid
        start = np.floor(np.array([float(pose[1]), float(pose[0])]) / g).astype(np.int64)  # (row, column)
        reach = int(math.ceil(PLAN_REACH_M / g))
        goal_rc = np.floor(np.array([float(goal[1]), float(goal[0])]) / g)
        goal_rc = np.clip(np.nan_to_num(goal_rc, nan=0.0), start - reach, start + reach).astype(np.int64)
        margin = int(math.ceil(PLAN_MARGIN_M / g - 1e-9))
        lo, hi = np.minimum(start, goal_rc) - margin, np.maximum(start, goal_rc) + margin
        h, w = (int(v) for v in hi - lo + 1)
        known = np.zeros((1, h * w + 1), dtype=bool)
        r, c = self.known[:, 1] - lo[0], self.known[:, 0] - lo[1]
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        known[0, r[inside] * w + c[inside]] = True
        out, carrots = plan_route(known, np.zeros(1, np.int64), (start - lo)[None], (goal_rc - lo)[None], (h, w),
                                  margin, self.plan_penalty, self.carrot / g)
        if self.carrot:
            self.carrot_xy = carrot_points(carrots, lo[::-1][None] * g, g, np.asarray(pose, np.float64)[None],
                                           np.asarray(goal, np.float64)[None], self.carrot)[0]
        at = np.flatnonzero(out[0, :-1])
        return (np.stack([at % w + lo[1], at // w + lo[0]], axis=1) + 0.5) * g

    def step(self, pose, angles, ranges, goal) -> np.ndarray:
        """The wall map's columns [2 cells^2] float32 (one more channel of cells^2 with each of ``visited`` and
        ``plan``) at ``pose`` after marking this scan (and the pose's cell), with ``goal`` (x, y)."""
        self.mark(pose, angles, ranges)
        visited = None
        if self.visited is not None:
            here = np.floor(np.array([[float(pose[0]), float(pose[1])]]) / self.grid).astype(np.int64)
            self.visited = np.unique(np.concatenate([self.visited, here]), axis=0)
            visited = (self.visited + 0.5) * self.grid
        centres = (self.known + 0.5) * self.grid
        plan = self.plan_centres(pose, goal) if self.plan else None
        return wall_image(centres, pose, goal, self.cells, self.cell, visited, plan).reshape(-1)
