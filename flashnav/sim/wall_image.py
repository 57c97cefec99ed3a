"""The egocentric wall image (issue 15): wall points seen from the robot as squares of a grid turned with its heading.

:func:`wall_image` draws it from any set of points (the stored points of :class:`flashnav.sim.memory.WallMemory`, the
marked cells of :class:`flashnav.sim.wall_grid.WallGrid`, issue 15's behaviour-cloning probe); :func:`goal_square`
draws its goal channel and :func:`cell_index` flattens rows and columns onto a grid, for the dense grid's own kernel.
Torch only, in the inputs' dtype, on their device, with no host sync.
"""

from __future__ import annotations

import math

import torch

from flashnav.sim.trail import to_robot_frame

def check_wall_image(cells: int, cell: float) -> None:
    """Raise ValueError unless a :func:`wall_image` of ``cells`` x ``cells`` squares of ``cell`` metres can be drawn."""
    if cells < 2 or not (math.isfinite(cell) and cell > 0):
        raise ValueError(f"a wall image needs at least 2 cells a side of > 0 metres, got {cells} x {cell}")


def cell_index(r: torch.Tensor, c: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Flat index ``r * w + c`` (long) of rows ``r`` and columns ``c`` (whole numbers, float or integer) on an
    ``h`` x ``w`` grid, -1 off it (NaN and inf are off it: they compare False); the same ops whatever the values."""
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    return torch.where(inside, torch.where(inside, r, 0).long() * w + torch.where(inside, c, 0).long(), -1)


def wall_image(points: torch.Tensor, pose: torch.Tensor, goal: torch.Tensor, cells: int, cell: float,
               visited: torch.Tensor | None = None, plan: torch.Tensor | None = None) -> torch.Tensor:
    """An egocentric image [k, 2, cells, cells] of wall ``points [k, Q, 2]`` (simulator frame, metres; a point
    with a non-finite coordinate is none) seen from ``pose [k, 3]``, with the goal ``goal [k, 2]``: squares of
    ``cell`` metres centred on the robot and turned with its heading, row = left (row 0 rightmost), column =
    forward (column 0 behind); channel 0 is 1 where a point falls in the square, channel 1 is 1 in the goal's
    square (clipped onto the image's edge when farther). Unknown reads as free. With ``visited [k, V, 2]`` (points
    the robot has been at, drawn as the walls are) a third channel [k, 3, cells, cells]; with ``plan [k, L, 2]`` (the
    cells of the plan, :mod:`flashnav.maps.seen_plan`, drawn likewise) one more, last. Computed in the inputs'
    dtype, on their device, with no host sync (the same ops whatever the points).

    The input of issue 15's behaviour-cloning probe (``scripts/bc_memory_probe.py --wall-map``): drawn from a
    slot's stored points (:meth:`WallMemory.image`) or from any other set of wall points."""
    check_wall_image(cells, cell)
    channels = [_point_squares(points, pose, cells, cell), goal_square(goal, pose, cells, cell, points.dtype)]
    if visited is not None:
        channels.append(_point_squares(visited.to(points.dtype), pose, cells, cell))
    if plan is not None:
        channels.append(_point_squares(plan.to(points.dtype), pose, cells, cell))
    return torch.stack(channels, dim=1)


def _point_squares(points: torch.Tensor, pose: torch.Tensor, cells: int, cell: float) -> torch.Tensor:
    """[k, cells, cells]: 1 in each of :func:`wall_image`'s squares that holds one of ``points [k, Q, 2]``."""
    k = points.shape[0]
    square = cell_index(*_squares(points, pose, cells, cell), cells, cells)
    inside = torch.isfinite(points).all(-1) & (square >= 0)
    at = torch.arange(k, device=pose.device)[:, None] * (cells * cells) + square
    at = torch.where(inside, at, k * cells * cells)  # outside: one spare square, dropped
    marks = torch.zeros(k * cells * cells + 1, device=pose.device, dtype=points.dtype)
    return marks.index_fill_(0, at.reshape(-1), 1.0)[:-1].view(k, cells, cells)


def _squares(xy: torch.Tensor, pose: torch.Tensor, cells: int, cell: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(row, column) of :func:`wall_image`'s squares, unclipped, as floats, of ``xy [k, Q, 2]`` seen from ``pose``."""
    fwd, left = to_robot_frame(xy, pose).unbind(-1)
    half = cells * cell / 2
    return torch.floor((left + half) / cell), torch.floor((fwd + half) / cell)


def goal_square(goal: torch.Tensor, pose: torch.Tensor, cells: int, cell: float, dtype) -> torch.Tensor:
    """:func:`wall_image`'s goal channel [k, cells, cells]: 1 in the goal's square, clipped onto the edge."""
    k = goal.shape[0]
    r, c = (v[:, 0].clamp(0, cells - 1).long() for v in _squares(goal[:, None], pose, cells, cell))
    target = torch.zeros(k, cells, cells, device=pose.device, dtype=dtype)
    target[torch.arange(k, device=pose.device), r, c] = 1.0
    return target
