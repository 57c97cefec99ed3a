"""Footprint collision against the occupancy grid, exact to the grid, batched in torch (any device).

A pose (x, y, yaw) collides when its footprint - a disc of radius r, or a length x width rectangle
centred on (x, y) with its length along the heading - overlaps an occupied cell square with positive
area, or any part of it lies outside the map rectangle:

- disc: the distance from (x, y) to some occupied closed square is < r (touching is not a
  collision), or x - r < xmin, x + r > xmax, y - r < ymin or y + r > ymax;
- rectangle: strict overlap on all four separating axes (the grid's x and y, and the rectangle's
  own two axes) with some occupied square (for convex polygons that is exactly a positive-area
  intersection), or a corner outside the map rectangle.

The outside of the map is occupied for the LiDAR too (:mod:`flashnav.sim.raycast`): a robot can
never stand where its own scan reports a wall.

Method: each footprint's axis-aligned bounding box covers at most B x B cells (B from the
circumscribed radius); those cells are gathered from a padded occupancy tensor and tested exactly,
as [N, B, B] tensors. With ``prefilter`` (the default on CPU) poses whose cell is at least the
circumscribed radius from every obstacle (:func:`flashnav.maps.fields.clear_cells`) skip the window
test, and only the occupied cells of the remaining windows are tested (sparse). Measured on the
2-core CPU, 1,024 poses on a cluttered 10 x 10 m map: disc 0.55 -> 0.10 ms, Go2 rectangle
2-12 ms -> ~1.5 ms. Without it (the default on CUDA, where data-dependent shapes cost a host sync)
the whole windows are tested densely.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Callable

import torch

from flashnav.config import Footprint
from flashnav.maps.fields import PAD, clear_cells
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.mapset import as_grids, check_map_index, map_table, pack


class CollisionChecker:
    """Callable ``(pose [N, 3] (x m, y m, yaw rad), map_index [N] long or None) -> [N] bool`` (True =
    collision), see the module docstring. Built on one map or a sequence of M maps (each pose on its
    map, in that map's coordinates; every map's padded grid in one flat buffer). Computations are
    float64 on ``device``."""

    def __init__(self, footprint: Footprint, grid: OccupancyMap | Sequence[OccupancyMap],
                 device: torch.device | str = "cpu", prefilter: bool | None = None) -> None:
        self.footprint = footprint
        self.grids = as_grids(grid)
        self.grid = self.grids[0]
        self.device = torch.device(device)
        # on CUDA the filter's data-dependent shapes cost a host sync; measure before enabling there
        self.prefilter = (self.device.type == "cpu") if prefilter is None else bool(prefilter)
        self._rc = footprint.circumscribed_radius
        # the bounding box [x - rc, x + rc] spans at most ceil(2 rc / res) + 1 cells from floor();
        # with several maps, the finest map's window (a larger window is still exact)
        self._b = max(math.ceil(2 * self._rc / g.resolution) + 2 for g in self.grids)
        self._pad = self._b
        occ, occ_base = pack([g.padded(self._pad) for g in self.grids])
        self._occ = torch.from_numpy(occ.copy()).to(self.device)
        g = self.grid
        self._hp, self._wp = g.shape[0] + 2 * self._pad, g.shape[1] + 2 * self._pad
        self._ar = torch.arange(self._b, device=self.device)
        if self.prefilter:  # shared per map and radius with every other checker of this map
            clear, clear_base = pack([clear_cells(m, self._rc) for m in self.grids])
            self._clear = torch.from_numpy(clear.copy()).to(self.device)
            self._clear_w = g.shape[1] + 2 * PAD
        # one map: Python numbers (the single-map ops, unchanged); several: [M] values gathered per pose
        self._maps = None
        if len(self.grids) > 1:
            table = map_table(self.grids, self.device, self._pad)
            self._maps = {key: table[key] for key in ("ox", "oy", "res", "xmax", "ymax", "h", "w")}
            self._maps["occ_base"] = torch.as_tensor(occ_base, device=self.device, dtype=torch.long)
            if self.prefilter:
                self._maps["clear_base"] = torch.as_tensor(clear_base, device=self.device, dtype=torch.long)

    def _geometry(self, map_index: torch.Tensor | None) -> dict:
        """Each pose's map: origin, resolution, upper bounds (m), shape (cells), padded width and
        flat offsets. Python numbers for one map, else [n] tensors."""
        if map_index is None:
            g = self.grid
            geo = {"ox": g.origin[0], "oy": g.origin[1], "res": g.resolution, "xmax": g.bounds[2],
                   "ymax": g.bounds[3], "h": g.shape[0], "w": g.shape[1], "occ_base": 0, "clear_base": 0}
        else:
            geo = {key: value[map_index] for key, value in self._maps.items()}
        geo["wp"], geo["hp"] = geo["w"] + 2 * self._pad, geo["h"] + 2 * self._pad
        return geo

    def __call__(self, pose: torch.Tensor, map_index=None) -> torch.Tensor:
        if pose.ndim != 2 or pose.shape[1] != 3:
            raise ValueError(f"pose must be [N, 3] (x, y, yaw), got shape {tuple(pose.shape)}")
        if map_index is None and len(self.grids) > 1:
            raise ValueError(f"this collision checker holds {len(self.grids)} maps: give map_index [N]")
        mi = None if map_index is None else check_map_index(map_index, pose.shape[0], len(self.grids), self.device)
        mi = None if len(self.grids) == 1 else mi
        geo = self._geometry(mi)
        p = pose.to(self.device, torch.float64)
        x, y, yaw = p[:, 0], p[:, 1], p[:, 2]
        out = self._outside(x, y, yaw, geo)
        if self.prefilter:
            j = torch.floor((x - geo["ox"]) / geo["res"])
            i = torch.floor((y - geo["oy"]) / geo["res"])
            h, w = geo["h"], geo["w"]
            inside = (j >= 0) & (j < w) & (i >= 0) & (i < h)
            if mi is None:
                idx = ((i.clamp(0, h - 1).long() + PAD) * self._clear_w + j.clamp(0, w - 1).long() + PAD)
            else:
                row = torch.minimum(i.clamp(min=0).long(), h - 1) + PAD
                col = torch.minimum(j.clamp(min=0).long(), w - 1) + PAD
                idx = geo["clear_base"] + row * (w + 2 * PAD) + col
            todo = torch.nonzero(~out & ~(inside & self._clear[idx])).squeeze(1)
            if todo.numel():
                part = geo if mi is None else {key: value[todo] for key, value in geo.items()}
                out[todo] = self._overlap(x[todo], y[todo], yaw[todo], part)
            return out
        return out | self._overlap(x, y, yaw, geo)

    def _outside(self, x, y, yaw, geo: dict) -> torch.Tensor:
        """[N] bool: some part of the footprint lies outside the map rectangle."""
        xmin, ymin, xmax, ymax = geo["ox"], geo["oy"], geo["xmax"], geo["ymax"]
        fp = self.footprint
        if fp.kind == "disc":
            hx = hy = torch.full_like(x, fp.radius)
        else:  # the rotated rectangle's exact axis-aligned half extents
            c, s = torch.cos(yaw).abs(), torch.sin(yaw).abs()
            hx = 0.5 * fp.length * c + 0.5 * fp.width * s
            hy = 0.5 * fp.length * s + 0.5 * fp.width * c
        return (x - hx < xmin) | (x + hx > xmax) | (y - hy < ymin) | (y + hy > ymax)

    def _overlap(self, x, y, yaw, geo: dict) -> torch.Tensor:
        """[n] bool: the footprint overlaps an occupied cell square (positive area)."""
        res, b, single = geo["res"], self._b, not isinstance(geo["res"], torch.Tensor)
        ox, oy, hp, wp = geo["ox"], geo["oy"], geo["hp"], geo["wp"]
        # first cell of each window, in padded indices; clamped so off-map poses index safely
        j0 = torch.floor((x - self._rc - ox) / res).long() + self._pad
        i0 = torch.floor((y - self._rc - oy) / res).long() + self._pad
        if single:
            j0, i0 = j0.clamp(0, wp - b), i0.clamp(0, hp - b)
        else:
            j0, i0 = torch.minimum(j0.clamp(min=0), wp - b), torch.minimum(i0.clamp(min=0), hp - b)
        cols = j0[:, None] + self._ar  # [n, B]
        rows = i0[:, None] + self._ar
        if single:
            occ = self._occ[rows[:, :, None] * wp + cols[:, None, :]]  # [n, B(rows), B(cols)]
        else:
            occ = self._occ[geo["occ_base"][:, None, None] + rows[:, :, None] * wp[:, None, None] + cols[:, None, :]]
            ox, oy, res = ox[:, None, None], oy[:, None, None], res[:, None, None]
        if self.prefilter:  # sparse: test only the occupied cells of the windows (few, on CPU)
            k, r, q = torch.nonzero(occ, as_tuple=True)
            cell = (ox, oy, res) if single else (ox[k, 0, 0], oy[k, 0, 0], res[k, 0, 0])
            k = k[self._touch(x[k], y[k], yaw[k], rows[k, r], cols[k, q], *cell)]
            return torch.zeros_like(x, dtype=torch.bool).index_fill_(0, k, True)
        x, y, yaw = x[:, None, None], y[:, None, None], yaw[:, None, None]
        touch = self._touch(x, y, yaw, rows[:, :, None], cols[:, None, :], ox, oy, res)
        return (occ & touch).flatten(1).any(1)

    def _touch(self, x, y, yaw, rows, cols, ox, oy, res) -> torch.Tensor:
        """Positive-area overlap of the footprint at (x, y, yaw) with cell (rows, cols) in padded
        indices of a map with origin (ox, oy) and resolution res (broadcasting tensors or numbers)."""
        fp = self.footprint
        # offsets from the footprint centre to the cell centres, metres
        ddx = ox + (cols - self._pad + 0.5) * res - x
        ddy = oy + (rows - self._pad + 0.5) * res - y
        half = 0.5 * res
        if fp.kind == "disc":
            gx = (ddx.abs() - half).clamp(min=0.0)
            gy = (ddy.abs() - half).clamp(min=0.0)
            return gx * gx + gy * gy < fp.radius * fp.radius
        c, s = torch.cos(yaw), torch.sin(yaw)
        ac, as_ = c.abs(), s.abs()
        hl, hw = 0.5 * fp.length, 0.5 * fp.width
        # separating axes: grid x, grid y (the rectangle's half extents there), then the rectangle's
        # own axes (the square's half extent there is half * (|c| + |s|))
        sq = half * (ac + as_)
        return ((ddx.abs() < hl * ac + hw * as_ + half) & (ddy.abs() < hl * as_ + hw * ac + half)
                & ((ddx * c + ddy * s).abs() < hl + sq) & ((ddy * c - ddx * s).abs() < hw + sq))


def make_collision_checker(footprint: Footprint, grid: OccupancyMap | Sequence[OccupancyMap], device: torch.device | str = "cpu",
                           prefilter: bool | None = None) -> Callable[[torch.Tensor], torch.Tensor]:
    """A :class:`CollisionChecker`: ``(pose [N, 3] float (x m, y m, yaw rad), map_index [N] or None)
    -> [N] bool``; ``grid`` one map or a sequence of maps (then ``map_index`` is required).

    ``prefilter`` (default: on for CPU, off for CUDA) skips the window test for poses whose cell is
    at least the circumscribed radius from every obstacle.
    """
    return CollisionChecker(footprint, grid, device, prefilter)
