"""The maps of one batched environment: one map, or M maps of any sizes and resolutions.

Every environment slot holds a map index (``NavVecEnv.map_index`` [N] long); a slot draws its map
when it resets, uniformly or by the set's weights, with the environment's torch generator (same seed,
same maps). The raycasters and the collision checker read all M maps from *one flat buffer with
per-map offsets* (:func:`pack`): each map keeps its own shape, resolution and padding, so memory is
the sum of the maps' fields, not M times the largest. A stack padded to a common shape ran at the
same speed within noise and took 2.2x the memory for 64 maps of 6-20 m (docs/benchmarks.md, "Many
maps in one env"). Per-map values that the kernels need (offsets, shapes, origins, resolutions) are
small [M] arrays, gathered per slot.

Frames: each map is simulated in its own frame (:func:`sim_frame`), world coordinates minus the frame's origin
(float64): (0, 0) - world coordinates as they are - for maps within ``FRAME_LIMIT_M`` of the world origin (every
bundled map), else the map's origin, so a map at UTM coordinates (500000, 4000000) or at 1e12 m simulates exactly like
the same map at (0, 0) instead of losing the float32 precision of its coordinates. A slot's pose and goal are in its
map's frame (:func:`world_to_frame`, :func:`frame_to_world`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from flashnav.maps.grid import OccupancyMap


def as_grids(grid: OccupancyMap | Sequence[OccupancyMap]) -> tuple[OccupancyMap, ...]:
    """One map or a non-empty sequence of maps -> a tuple of maps (TypeError / ValueError otherwise)."""
    grids = (grid,) if isinstance(grid, OccupancyMap) else tuple(grid)
    if not grids:
        raise ValueError("a map set needs at least one map, got none")
    for i, g in enumerate(grids):
        if not isinstance(g, OccupancyMap):
            raise TypeError(f"maps[{i}] must be an OccupancyMap, got {type(g).__name__}")
    return grids


def pack(arrays: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Flatten and concatenate per-map arrays: (flat [sum of sizes], offsets [M] int64 where each
    map's array starts). One array is returned as a view, without a copy."""
    sizes = np.array([a.size for a in arrays], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    flat = arrays[0].reshape(-1) if len(arrays) == 1 else np.concatenate([a.reshape(-1) for a in arrays])
    return flat, offsets


def map_table(grids: Sequence[OccupancyMap], device: torch.device | str, pad: int,
              dtype: torch.dtype = torch.float64) -> dict[str, torch.Tensor]:
    """The [M] per-map values that the many-map kernels gather per slot (raycasters, collision,
    agents): ``ox``, ``oy`` (origin), ``res``, ``inv`` (1 / res, divided in float64), ``xmax``, ``ymax``
    (upper bounds), metres, in ``dtype``; ``h``, ``w`` (shape) and ``hp``, ``wp`` (shape padded by
    ``pad`` cells on each side), cells, long. Built in float64 and then cast, so each float32 value
    is the nearest to the map's (as the single-map ops' Python numbers give)."""
    f64 = dict(device=device, dtype=torch.float64)
    long = dict(device=device, dtype=torch.long)
    floats = {
        "ox": torch.tensor([g.origin[0] for g in grids], **f64),
        "oy": torch.tensor([g.origin[1] for g in grids], **f64),
        "res": torch.tensor([g.resolution for g in grids], **f64),
        "inv": torch.tensor([1.0 / g.resolution for g in grids], **f64),
        "xmax": torch.tensor([g.bounds[2] for g in grids], **f64),
        "ymax": torch.tensor([g.bounds[3] for g in grids], **f64),
    }
    table = {key: value.to(dtype) for key, value in floats.items()}
    table["h"] = torch.tensor([g.shape[0] for g in grids], **long)
    table["w"] = torch.tensor([g.shape[1] for g in grids], **long)
    table["hp"], table["wp"] = table["h"] + 2 * pad, table["w"] + 2 * pad
    return table


def check_map_index(map_index, n: int, num_maps: int, device: torch.device) -> torch.Tensor:
    """``map_index`` as a [n] long tensor on ``device``; a ValueError for another shape or dtype, and
    (on the CPU, where it costs no device sync) for an index outside [0, num_maps)."""
    mi = torch.as_tensor(map_index, device=device)
    if mi.shape != (n,) or mi.dtype.is_floating_point or mi.dtype == torch.bool or mi.is_complex():
        raise ValueError(f"map_index must be a 1-D integer tensor of shape [N] = [{n}], got {mi.dtype} {list(mi.shape)}")
    mi = mi.long()
    if device.type == "cpu" and n and (int(mi.min()) < 0 or int(mi.max()) >= num_maps):
        bad = mi[(mi < 0) | (mi >= num_maps)]
        raise ValueError(f"map_index holds {int(bad[0])}, outside [0, {num_maps}) ({num_maps} maps)")
    return mi


def outside_maps(grids: Sequence[OccupancyMap], points: torch.Tensor, map_index: torch.Tensor) -> torch.Tensor:
    """[N] bool: ``points`` [N, 2] (m, world, float64: goals, or robot positions) lie outside the extent of their
    map ``grids[map_index]``, by more than one cell (float32 goals on a map's edge may round a hair outside it).
    Indices out of range count as inside (checked elsewhere)."""
    dev = points.device
    bounds = torch.tensor([g.bounds for g in grids], dtype=torch.float64, device=dev)
    tol = torch.tensor([g.resolution for g in grids], dtype=torch.float64, device=dev)
    mi = map_index.clamp(0, len(grids) - 1)
    b, t = bounds[mi], tol[mi]
    x, y = points[:, 0], points[:, 1]
    return (x < b[:, 0] - t) | (x > b[:, 2] + t) | (y < b[:, 1] - t) | (y > b[:, 3] + t)


class MapDraw:
    """Draws map indices for resetting slots: uniform over M maps, or proportional to ``weights``."""

    def __init__(self, num_maps: int, weights: Sequence[float] | None, device: torch.device):
        self.num_maps = num_maps
        self.weights = None
        if weights is not None:
            w = [float(x) for x in weights]
            if len(w) != num_maps:
                raise ValueError(f"map_weights has {len(w)} entries for {num_maps} maps")
            if any(not (math.isfinite(x) and x >= 0) for x in w) or sum(w) <= 0:
                raise ValueError(f"map_weights must be finite, >= 0 and not all 0, got {w}")
            self.weights = torch.tensor(w, dtype=torch.float64, device=device)

    def __call__(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """[n] long map indices."""
        device = gen.device
        if self.weights is None:
            return torch.randint(self.num_maps, (n,), generator=gen, device=device)
        return torch.multinomial(self.weights, n, replacement=True, generator=gen)


#: Maps whose coordinates all stay below this (metres, in magnitude) are simulated in world
#: coordinates: float32 spacing there is at most 2**-13 m (0.12 mm, 1/400 of a 5 cm cell), and
#: existing maps keep their bit-exact trajectories. Farther maps are re-centred on their origin.
FRAME_LIMIT_M = 1024.0


def sim_frame(grid: OccupancyMap) -> tuple[float, float]:
    """The world (x, y) of the simulator frame's origin, metres float64 (module docstring, "Frames")."""
    if max(abs(b) for b in grid.bounds) <= FRAME_LIMIT_M:
        return (0.0, 0.0)
    return grid.origin


def world_to_frame(pose: torch.Tensor, goal: torch.Tensor, origins: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World float64 pose [N, 3] and goal [N, 2] -> each slot's map frame, ``origins`` [N, 2] float64 its frame's
    origin (still float64)."""
    return torch.cat([pose[:, :2] - origins, pose[:, 2:]], dim=1), goal - origins


def frame_to_world(state: torch.Tensor, origins: torch.Tensor) -> torch.Tensor:
    """A pose [N, 3] (x, y, yaw) or a point [N, 2] in each slot's map frame -> world coordinates, float64."""
    xy = state[:, :2].double() + origins
    return torch.cat([xy, state[:, 2:].double()], dim=1)


def check_map_scale(grid: OccupancyMap, preset) -> None:
    """Refuse a map so fine for the robot that the collision grid (padded by the footprint's size in
    cells, as collision.py does) would exceed the map size limit: a clear error, not a huge allocation."""
    from flashnav.maps import grid as grid_module

    pad = math.ceil(2 * preset.footprint.circumscribed_radius / grid.resolution) + 2
    h, w = grid.shape
    cells = (h + 2 * pad) * (w + 2 * pad)
    if cells > grid_module.MAX_CELLS:
        raise ValueError(f"map {grid.name!r}: resolution {grid.resolution} m is too fine for {preset.name}'s "
                         f"{preset.footprint.circumscribed_radius} m footprint: its collision grid would need "
                         f"{cells:.3g} cells (limit {grid_module.MAX_CELLS})")


def sample_on_maps(sampler, draw: MapDraw, n: int,
                   gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """New episodes for ``n`` resetting slots of a many-map env: each slot draws its map (``draw``),
    then ``sampler`` (a :class:`flashnav.sim.sampling.MapSetSampler` over all the maps) draws every
    slot's episode on its map in one batch, without a host sync. Returns ``map_index [n]`` (long),
    ``pose [n, 3]`` and ``goal [n, 2]`` in each map's own frame."""
    maps = draw(n, gen)
    pose, goal = sampler.sample(maps, gen)
    return maps, pose, goal
