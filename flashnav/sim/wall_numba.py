"""The CPU kernel of the wall map's image (numba): :meth:`flashnav.sim.wall_grid.WallGrid.image` without the window's
unmarked cells.

The torch path turns every cell centre of a square window around the robot into the robot's frame (71 x 71 cells
for the 24 x 24 map of 0.5 m squares on the 0.25 m grid: 5,041 points a slot and step, a dozen full-size tensor ops
each) and drops the unmarked ones at the end; most cells of a window are unmarked. This kernel visits the same
window and does the arithmetic for the marked cells only, with the same float operations in the same order (the
cosine and sine of the heading, and the window's first cell, come from torch), so it draws the same squares bit for
bit (tests/test_wall_grid.py checks both paths against :func:`flashnav.sim.wall_image.wall_image` of every marked
centre). Serial, as :mod:`flashnav.sim.agent_numba` (a parallel launch measured slower on the 2-core CPU).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def mark_walls(known, rows, base, origin, pose, cos_h, sin_h, n, h, w, coord, consts, cells, out):
    """Set ``out[i, r * cells + c]`` to 1 for each square (r, c) of slot ``rows[i]``'s image that holds a marked
    cell's centre. ``known [N, h w + 1]`` bool; ``base [k, 2]`` the window's first (column, row); ``origin [k, 2]``,
    ``pose [k, 3]``, ``cos_h``/``sin_h [k]``, ``coord`` (0, 1, 2, ... as numbers: a cell's index) and ``consts`` = (grid cell, image
    half-width, image square, 0.5) all of the image's dtype; the window is ``n`` x ``n`` cells."""
    grid_cell, half, square, mid = consts[0], consts[1], consts[2], consts[3]
    for i in range(rows.shape[0]):
        slot = rows[i]
        px, py, c_, s_ = pose[i, 0], pose[i, 1], cos_h[i], sin_h[i]
        ox, oy = origin[i, 0], origin[i, 1]
        for a in range(n):
            r = base[i, 1] + a
            if r < 0 or r >= h:
                continue
            for b in range(n):
                c = base[i, 0] + b
                if c < 0 or c >= w or not known[slot, r * w + c]:
                    continue
                dx = (coord[c] + mid) * grid_cell + ox - px
                dy = (coord[r] + mid) * grid_cell + oy - py
                fwd = c_ * dx + s_ * dy
                left = -s_ * dx + c_ * dy
                row = math.floor((left + half) / square)
                col = math.floor((fwd + half) / square)
                if 0 <= row < cells and 0 <= col < cells:
                    out[i, row * cells + col] = 1.0


def wall_squares(known: np.ndarray, rows: np.ndarray, base: np.ndarray, origin: np.ndarray, pose: np.ndarray,
                 cos_h: np.ndarray, sin_h: np.ndarray, n: int, shape: tuple[int, int], grid_cell: float,
                 cells: int, square: float) -> np.ndarray:
    """The walls channel ``[k, cells, cells]`` (``pose``'s dtype) of :meth:`WallGrid.image`, or its visited channel
    given that grid as ``known``: see :func:`mark_walls`."""
    dtype = pose.dtype
    out = np.zeros((rows.shape[0], cells * cells), dtype=dtype)
    consts = np.array([grid_cell, cells * square / 2, square, 0.5], dtype=dtype)
    coord = np.arange(max(shape), dtype=dtype)
    mark_walls(known, rows, base, origin.astype(dtype), pose, cos_h.astype(dtype), sin_h.astype(dtype), n,
               shape[0], shape[1], coord, consts, cells, out)
    return out.reshape(-1, cells, cells)
