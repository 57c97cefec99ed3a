"""Geodesic progress (``reward.progress_metric: geodesic``): the shaping term measured along the path.

The paper's shaping term is ``progress x (d_old - d_new)`` with ``d`` the straight-line distance to the
goal. In a maze or behind a wall that distance points through the wall: the robot is paid for walking
into a dead end that looks towards the goal and charged for the detour that leads there. With
``progress_metric: geodesic``, ``d`` is the path length
through the free space of the robot's disc instead: a potential-based change of the shaping (the
returns of two policies that reach the goal differ only by discounting) that uses the map during
training only. The observation stays the paper's (the policy still sees the straight-line distance and
angle), and so does every evaluation (:func:`evaluation_preset`).

How: the geodesic sampler's pairs already start from a few source cells per map
(:mod:`flashnav.maps.geodesic`); with this metric every episode's goal is a source (the pair is played
from its other end), and each source keeps the path lengths to the window of cells around it
(the top of the geodesic goal band, ``EpisodeSampler.d_max``, + :data:`MARGIN_M`; the bounded Dijkstra of
:mod:`flashnav.maps.geodesic_numba`, float16 metres, cached on the map like every derived field). A position's distance is the smallest
``field[c] + |position - centre(c)|`` over the 3 x 3 cells around it (continuous, and defined beside
walls where the robot's own cell is not free), capped at the window's bound: beyond it progress is 0.
The fields use the free space of the footprint's circumscribed disc; where a footprint that is not a
disc stands with no such cell around it, the step earns no progress (:meth:`GoalFields.distance`).
Cost: about 8-40 MB of fields per generated map plus 8 bytes per map cell (the cell -> source table),
and 18 gathers per slot and step.

With the paper's straight-line goal sampling (``episode.goal_sampling: euclidean``, one map: the paper's
task, whose episodes stay exactly the paper's draws) the goals fall anywhere, so
:class:`EpisodeGoalFields` computes each new episode's field when it starts instead: the path lengths
from the goal's cell to the whole map (a bounded Dijkstra, about a millisecond per episode on the
bundled maps), 4 bytes per map cell and slot (150 MB for 1,024 slots on the 13.5 x 13.5 m Go2 map).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from flashnav.config import RobotPreset
from flashnav.maps.fields import _radius_key, cached, free_space
from flashnav.maps.grid import OccupancyMap

MARGIN_M = 2.0  # metres of path beyond the farthest goal that each field still measures
_OFFSETS = torch.tensor([(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)])  # [9, 2] rows, cols


def drive_bound(preset: RobotPreset) -> float:
    """Metres: the farthest path an episode can drive (horizon x dt x top speed) + :data:`MARGIN_M`, the
    bound of the path lengths measured on the paper's straight-line episodes (:class:`EpisodeGoalFields`,
    ``episode.hard_share``)."""
    ep = preset.episode
    return ep.horizon * ep.dt * preset.motion.v_bounds[1] + MARGIN_M


def evaluation_preset(preset: RobotPreset) -> RobotPreset:
    """``preset`` with the paper's reward (straight-line progress, ``progress_discount`` 1, no ``step_cost``) and the
    task's own episode draws: what an evaluation plays. The reward does not change what is measured (its returns
    read as the paper's), but the geodesic metric plays every pair from its source end, and ``episode.hard_share``
    re-weights the draws, which would change the episodes; evaluations keep the task's."""
    paper = preset.reward.model_copy(update={"progress_metric": "euclidean", "progress_discount": 1.0,
                                             "step_cost": 0.0})
    if paper == preset.reward and preset.episode.hard_share == 0:
        return preset
    return preset.model_copy(update={"reward": paper, "episode": preset.episode.model_copy(update={"hard_share": 0.0})})


def source_fields(grid: OccupancyMap, sources: np.ndarray, radius: float, bound_m: float) -> tuple[np.ndarray, int]:
    """Path lengths (metres, float16; inf where farther than ``bound_m``, not free or unreachable) from
    each source cell (flat indices [P] into ``grid``) through the free space of a disc of ``radius`` to
    the cells of the window around it: ([P, 2 reach + 1, 2 reach + 1], reach). Cached on the map."""
    sources = np.ascontiguousarray(sources, dtype=np.int64)
    key = ("goal_fields", _radius_key(radius), round(float(bound_m), 9), sources.tobytes())

    def build():
        from flashnav.maps import geodesic_numba  # the first import may JIT-compile

        bound = bound_m / grid.resolution
        reach = int(math.ceil(bound)) + 1
        cells = geodesic_numba.window_fields(free_space(grid, radius), sources, reach, bound)
        return (cells * grid.resolution).astype(np.float16), reach

    return cached(grid, key, build)


class WindowFields:
    """Path-length fields of a batch of cells on a set of maps, on ``device``: field ``i`` holds the path
    lengths from cell ``cells[m][j]`` of map ``m`` (fields numbered map by map) to the window around
    it, through the free space of a disc of ``radius``, up to ``bound`` metres (:func:`source_fields`,
    cached on each map). :meth:`distance` reads them at positions; :mod:`flashnav.guidance` walks them."""

    def __init__(self, grids: Sequence[OccupancyMap], cells: Sequence[np.ndarray], radius: float, bound: float,
                 device: torch.device | str):
        self.device, self.radius, self.bound = torch.device(device), float(radius), float(bound)
        fields, side, corner, res, shape, first = [], [], [], [], [], [0]
        for grid, flat in zip(grids, cells):
            h, w = grid.shape
            flat = np.asarray(flat, dtype=np.int64)
            table, reach = source_fields(grid, flat, self.radius, self.bound)
            fields.append(torch.from_numpy(table.reshape(-1).copy()))
            side.append(np.full(len(flat), 2 * reach + 1))
            corner.append(np.stack([flat // w - reach, flat % w - reach], axis=1))
            res.append(grid.resolution)
            shape.append((h, w, grid.origin[0], grid.origin[1]))
            first.append(first[-1] + h * w)
        sizes = [s * s for s in np.concatenate(side)]
        self.field = torch.cat(fields).to(self.device)  # every window, flat, float16 metres
        self.offset = torch.tensor([0, *np.cumsum(sizes)[:-1]], dtype=torch.long, device=self.device)  # [P]
        self.side = torch.as_tensor(np.concatenate(side), device=self.device)  # [P] window side, cells
        self.window = torch.as_tensor(np.concatenate(corner), device=self.device)  # [P, 2] its corner (row, col)
        self.cell_first = torch.tensor(first[:-1], dtype=torch.long, device=self.device)  # [M]
        self.res = torch.tensor(res, dtype=torch.float32, device=self.device)  # [M]
        self.hw = torch.tensor([(h, w) for h, w, _, _ in shape], dtype=torch.long, device=self.device)  # [M, 2]
        self.origin = torch.tensor([(ox, oy) for _, _, ox, oy in shape], dtype=torch.float32, device=self.device)
        self.offsets = _OFFSETS.to(self.device)

    def _maps(self, maps: torch.Tensor | None, n: int) -> torch.Tensor:
        return torch.zeros(n, dtype=torch.long, device=self.device) if maps is None else maps

    def _around(self, pos: torch.Tensor, m: torch.Tensor):
        """The 3 x 3 cells around the cell centre nearest each position [k, 2]: (rc [k, 9, 2] row, col;
        their centres [k, 9, 2] x, y in metres)."""
        res, origin = self.res[m][:, None], self.origin[m]
        near = torch.round((pos - origin) / res - 0.5).long()  # [k, 2] col, row of the nearest centre
        rc = torch.stack([near[:, 1], near[:, 0]], dim=1)[:, None, :] + self.offsets  # [k, 9, 2] row, col
        return rc, self.centres(rc, m)

    def centres(self, rc: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
        """Cell centres [k, n, 2] (x, y m) of cells rc [k, n, 2] (row, col) of maps m [k]."""
        return self.origin[m][:, None, :] + (rc.flip(2).float() + 0.5) * self.res[m][:, None, None]

    def values(self, rc: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        """[k, n] float32 metres: field ``ids`` [k] at cells rc [k, n, 2] (row, col), inf outside its window."""
        local = rc - self.window[ids][:, None, :]
        side = self.side[ids][:, None]
        inside = ((local >= 0) & (local < side[..., None])).all(dim=2)
        flat = self.offset[ids][:, None] + local[..., 0].clamp(min=0) * side + local[..., 1].clamp(min=0)
        flat = torch.where(inside, flat, torch.zeros_like(flat))
        return torch.where(inside, self.field[flat].float(), torch.full_like(flat, math.inf, dtype=torch.float32))

    def nearest(self, pos: torch.Tensor, ids: torch.Tensor, maps: torch.Tensor | None):
        """(d [k] metres, rc [k, 2]): the smallest ``field[c] + |position - centre(c)|`` over the 3 x 3 cells
        c around each position [k, 2] (continuous, and defined beside walls where the position's own cell
        is not free; inf where none is reachable) and the cell that gives it."""
        m = self._maps(maps, pos.shape[0])
        rc, centre = self._around(pos, m)
        total = self.values(rc, ids) + torch.linalg.vector_norm(pos[:, None, :] - centre, dim=2)
        d, best = total.min(dim=1)
        return d, rc[torch.arange(rc.shape[0], device=rc.device), best]

    def distance(self, pos: torch.Tensor, ids: torch.Tensor, maps: torch.Tensor | None,
                 fallback: torch.Tensor, unknown: torch.Tensor | None = None) -> torch.Tensor:
        """[k] float32 metres: the path length from positions [k, 2] (m, the map's frame) to the cells of
        fields ``ids`` [k], at most the bound; ``fallback`` [k] where ``ids`` is -1; ``unknown`` [k]
        (default: the bound) where no cell around the position is in the free space of the disc the
        fields were built for (a footprint that is not a disc may stand there): the env passes the
        previous distance, so such a step earns no progress instead of a jump to the bound."""
        has = ids >= 0
        d, _ = self.nearest(pos, ids.clamp(min=0), maps)
        if unknown is not None:
            d = torch.where(torch.isfinite(d), d, unknown)
        return torch.where(has, d.clamp(max=self.bound), fallback)


class GoalFields(WindowFields):
    """The per-source fields of a set of maps (the environment's frame maps and their samplers, in
    order), on ``device``: which source a goal sits on (:meth:`ids`), and the path length from
    positions to it (:meth:`distance`)."""

    def __init__(self, grids: Sequence[OccupancyMap], samplers, preset: RobotPreset, device: torch.device):
        if any(s.mode != "geodesic" for s in samplers):
            raise ValueError("geodesic progress needs the geodesic episode sampler (episode.goal_sampling=geodesic), "
                             f"got goal_sampling {[s.mode for s in samplers]}")
        cells, lookup, count = [], [], 0
        for grid, sampler in zip(grids, samplers):
            h, w = grid.shape
            centres = sampler.centres[torch.unique(sampler.pair_start)].cpu().numpy()
            rows, cols = grid.cell_of(centres)
            cells.append(rows * w + cols)
            cell_to_source = np.full(h * w, -1, dtype=np.int64)
            cell_to_source[rows * w + cols] = count + np.arange(len(rows))
            lookup.append(torch.as_tensor(cell_to_source))
            count += len(rows)
        super().__init__(grids, cells, preset.footprint.circumscribed_radius, samplers[0].d_max + MARGIN_M, device)
        self.lookup = torch.cat(lookup).to(self.device)  # [sum H W] cell -> source id, -1 elsewhere

    def start(self, idx: torch.Tensor, goal: torch.Tensor, maps: torch.Tensor | None) -> torch.Tensor:
        """New episodes in slots ``idx`` [k] with goals [k, 2]: their fields' ids (:meth:`ids`)."""
        return self.ids(goal, maps)

    def ids(self, goal: torch.Tensor, maps: torch.Tensor | None) -> torch.Tensor:
        """[k] long: the source whose cell holds each goal [k, 2] (m, the map's frame), -1 where none does
        (a goal placed by ``set_state`` off the sources: its slot keeps straight-line progress). The
        nearest source centre among the 3 x 3 cells around the goal, so float32 rounding at a cell's
        edge cannot lose it (the sampler keeps these goals inside their cells: GOAL_INSIDE)."""
        m = self._maps(maps, goal.shape[0])
        rc, centre = self._around(goal, m)
        hw = self.hw[m][:, None, :]
        inside = ((rc >= 0) & (rc < hw)).all(dim=2)  # [k, 9]
        flat = self.cell_first[m][:, None] + rc[..., 0].clamp(min=0) * hw[..., 1] + rc[..., 1].clamp(min=0)
        src = torch.where(inside, self.lookup[torch.where(inside, flat, torch.zeros_like(flat))],
                          torch.full_like(flat, -1))
        half = 0.5 * self.res[m][:, None] * (1 + 1e-4)  # within its cell (and float rounding)
        gap = (goal[:, None, :] - centre).abs().amax(dim=2)  # [k, 9] Chebyshev distance to each centre
        gap = torch.where((src >= 0) & (gap <= half), gap, torch.full_like(gap, math.inf))
        best = gap.argmin(dim=1, keepdim=True)
        found = torch.isfinite(gap.gather(1, best)).squeeze(1)
        return torch.where(found, src.gather(1, best).squeeze(1), torch.full_like(found, -1, dtype=torch.long))


class EpisodeGoalFields(WindowFields):
    """Geodesic progress with the straight-line goal sampler on one map: slot ``i``'s field holds the path
    lengths from its episode's goal cell to every cell of the map (metres, float32; inf where farther
    than the bound, not free or unreachable), computed by :meth:`start` when the episode starts. The
    bound is the farthest path an episode can drive (horizon x dt x top speed) + :data:`MARGIN_M`.
    Field ids are slot indices; a goal whose cell is not in the free space of the footprint's
    circumscribed disc gets id -1 (its slot keeps straight-line progress)."""

    def __init__(self, grid: OccupancyMap, preset: RobotPreset, num_envs: int, device: torch.device | str):
        self.device, self.radius = torch.device(device), float(preset.footprint.circumscribed_radius)
        self.bound = drive_bound(preset)
        self.free = free_space(grid, self.radius)
        self.grid = grid
        self.h, self.w = grid.shape
        self.grid_res = grid.resolution
        self.res = torch.tensor([grid.resolution], dtype=torch.float32, device=self.device)
        self.origin = torch.tensor([grid.origin], dtype=torch.float32, device=self.device)
        self.hw = torch.tensor([[self.h, self.w]], dtype=torch.long, device=self.device)
        self.offsets = _OFFSETS.to(self.device)
        self.field = torch.full((num_envs, self.h * self.w), math.inf, dtype=torch.float32, device=self.device)

    def start(self, idx: torch.Tensor, goal: torch.Tensor, maps: torch.Tensor | None) -> torch.Tensor:
        """New episodes in slots ``idx`` [k] with goals [k, 2] (m): compute their fields; returns the
        ids [k] (the slots, -1 where the goal's cell is not free)."""
        from flashnav.maps import geodesic_numba  # the first import may JIT-compile

        if idx.numel() == 0:
            return torch.empty(0, dtype=torch.long, device=self.device)
        row, col = self.grid.cell_of(goal)
        inside = (row >= 0) & (row < self.h) & (col >= 0) & (col < self.w)
        flat = np.where(inside, row * self.w + col, 0)
        ok = inside & self.free.reshape(-1)[flat]
        if ok.any():
            cells = geodesic_numba.map_fields(self.free, np.ascontiguousarray(flat[ok]), self.bound / self.grid_res)
            rows = idx[torch.as_tensor(ok, device=idx.device)]
            self.field[rows] = torch.from_numpy(cells * np.float32(self.grid_res)).to(self.device)
        return torch.where(torch.as_tensor(ok, device=self.device), idx.to(self.device), -1)

    def values(self, rc: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        """[k, n] float32 metres: slot ``ids`` [k]'s field at cells rc [k, n, 2] (row, col), inf off the map."""
        inside = (rc[..., 0] >= 0) & (rc[..., 0] < self.h) & (rc[..., 1] >= 0) & (rc[..., 1] < self.w)
        flat = torch.where(inside, rc[..., 0] * self.w + rc[..., 1], torch.zeros_like(rc[..., 0]))
        got = self.field[ids[:, None], flat]
        return torch.where(inside, got, torch.full_like(got, math.inf))
