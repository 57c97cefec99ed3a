"""Start/goal sampling that keeps every episode solvable.

Starts and goals are drawn from the *free configuration space*: cells whose centre (plus the jitter
inside the cell) stays farther than the footprint's circumscribed radius + ``start_clearance`` from any
obstacle, so the robot is collision-free there at any heading. The goal lies in the same 4-connected
component of that space as the start (so a path exists along which the whole footprint stays clear).
``episode.goal_sampling`` says how far:

- ``euclidean`` (default; the paper task on the bundled maps, whose episodes stay bit-identical): a
  straight-line distance within [min_goal_distance, max_goal_distance]. Of ``GOAL_CANDIDATES``
  candidates the first inside the band wins; when none is, the nearest one outside it does. Such a
  fallback is counted (``out_of_band``, on the device) and, when a probe at construction finds any,
  reported once per map with a warning; a map where the probe finds no episode in the band at all is
  refused.
- ``geodesic``: a path length through that space (:mod:`flashnav.maps.geodesic`) within
  [min_goal_distance, min(max_goal_distance, HORIZON_PATH_FRACTION x horizon x dt x top speed)],
  so every goal is reachable in time by construction, on any map; a map with no such pair is refused.

Sampling is a handful of batched tensor ops with a ``torch.Generator``: no host synchronisation,
same seed -> same episodes, on any device.
"""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
import torch

from flashnav.config import RobotPreset
from flashnav.maps.fields import component_cells, free_space
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.goal_fields import drive_bound

GOAL_CANDIDATES = 32  # goal candidates drawn per start; the first inside the distance band wins
MIN_COMPONENT_CELLS = 16  # smaller pockets of free space are never used for starts
#: Geodesic goals are at most this fraction of the horizon's path at top speed away: the rest of the
#: horizon is for turning (a half turn takes 40 steps at pi/4 rad/s) and slowing down around corners.
HORIZON_PATH_FRACTION = 0.5
PROBE_EPISODES = 4096  # euclidean mode: episodes drawn at construction to find fallbacks
GOAL_INSIDE = 0.998  # geodesic progress: goal jitter as a share of the cell, inside it by 0.1 % a side
_warned: set[tuple] = set()  # (map, band, radius) already reported: warn once per map and process


class EpisodeSampler:
    """Draws (pose [n, 3], goal [n, 2]) pairs for ``n`` environment slots, in ``grid``'s
    coordinates (the environment passes its re-centred map, so they are in the simulator's frame).

    Attributes:
        d_min, d_max: the goal distance band, metres (geodesic: after the horizon cap).
        out_of_band: [] int64 on the device: euclidean episodes sampled so far whose goal lies outside
            the band (the nearest candidate was taken); always 0 in geodesic mode.
    """

    def __init__(self, grid: OccupancyMap, preset: RobotPreset, device: torch.device):
        ep = preset.episode
        jitter_margin = grid.resolution * math.sqrt(0.5)
        self.radius = preset.footprint.circumscribed_radius + ep.start_clearance
        grid.check_free_space(self.radius + jitter_margin, what=f"the {preset.name} footprint at its start clearance")
        rows, cols, per_cell_first, per_cell_count = component_cells(
            grid, self.radius + jitter_margin, MIN_COMPONENT_CELLS)
        cx, cy = grid.cell_centres(rows, cols)
        f32 = dict(device=device, dtype=torch.float32)
        self.centres = torch.as_tensor(np.stack([cx, cy], axis=1), **f32)  # [M, 2] metres
        self.num_cells = len(rows)
        self.resolution = grid.resolution
        self.mode = ep.goal_sampling
        self.device = device
        self.out_of_band = torch.zeros((), dtype=torch.long, device=device)
        # geodesic progress (flashnav.sim.goal_fields) needs every goal on a pair's source cell
        self.goal_at_source = preset.reward.progress_metric == "geodesic" and ep.goal_sampling == "geodesic"
        # ... and strictly inside it, so that float32 rounding never puts a goal on a neighbour's edge
        self.goal_jitter = GOAL_INSIDE if self.goal_at_source else 1.0
        if self.mode == "geodesic":
            from flashnav.maps.geodesic import geodesic_pairs

            self.d_min, self.d_max = geodesic_band(preset)
            starts, goals = geodesic_pairs(grid, self.radius + jitter_margin, MIN_COMPONENT_CELLS,
                                           (self.d_min, self.d_max))
            self.pair_start = torch.tensor(starts, device=device)  # [K] indices into centres
            self.pair_goal = torch.tensor(goals, device=device)
        else:
            self.comp_first = torch.tensor(per_cell_first, device=device, dtype=torch.long)  # [M]
            self.comp_count = torch.tensor(per_cell_count, device=device, dtype=torch.float32)  # [M]
            self.d_min, self.d_max = ep.min_goal_distance, ep.max_goal_distance
            self._probe(grid)
        # episode.hard_share: some training episodes are the longest detour of several draws (detour)
        self.hard_share, self.hard_candidates = ep.hard_share, ep.hard_candidates
        self._grid, self._path_radius, self.path_free = grid, preset.footprint.circumscribed_radius, None
        self.path_bound = drive_bound(preset) / grid.resolution  # cells

    def _jitter(self, n: int, gen: torch.Generator) -> torch.Tensor:
        return (torch.rand(n, 2, generator=gen, device=self.device) - 0.5) * self.resolution

    def sample(self, n: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns pose [n, 3] (x, y m, yaw rad in [-pi, pi)) and goal [n, 2] (m)."""
        pose, goal, outside = self._draws(n, gen)
        if self.hard_share > 0:
            harden(pose, goal, outside, self.hard_share, self.hard_candidates, gen,
                   draw=lambda slots, c: self._draws(slots.numel() * c, gen),
                   detour=lambda slots, start, end: self.detour(start, end))
        if outside is not None:
            self.out_of_band += outside.sum()
        return pose, goal

    def _draws(self, n: int, gen: torch.Generator):
        """(pose [n, 3], goal [n, 2], outside [n] bool or None): the task's draws, ``outside`` the euclidean
        fallbacks (None in geodesic mode, whose draws are all in the band)."""
        if self.mode == "geodesic":
            return (*self._sample_geodesic(n, gen), None)
        return self._sample_euclidean(n, gen)

    def detour(self, start: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """[k] float32: path length / straight line from each start [k, 2] to its goal [k, 2] (m), the path
        through the free space of the footprint's circumscribed disc (8-connected cells); 0 where no path
        is within :func:`~flashnav.sim.goal_fields.drive_bound` or the straight line is 0."""
        from flashnav.maps.geodesic_numba import pair_lengths  # the first import may JIT-compile

        if self.path_free is None:  # built on first use (cached on the map)
            self.path_free = free_space(self._grid, self._path_radius)
        w = self.path_free.shape[1]

        def flat(xy):
            row, col = self._grid.cell_of(xy, clip=True)
            return row * w + col

        cells = pair_lengths(self.path_free, flat(goal), flat(start), self.path_bound)
        path = torch.as_tensor(cells * self.resolution, dtype=torch.float32, device=self.device)
        straight = torch.linalg.vector_norm(goal - start, dim=1)
        ratio = path / straight.clamp(min=1e-6)
        return torch.where(torch.isfinite(ratio), ratio, torch.zeros_like(ratio))

    def _sample_euclidean(self, n: int, gen: torch.Generator):
        """(pose [n, 3], goal [n, 2], outside [n] bool: no candidate was in the band)."""
        dev = self.device
        start_idx = torch.randint(self.num_cells, (n,), generator=gen, device=dev)
        start = self.centres[start_idx] + self._jitter(n, gen)
        yaw = (torch.rand(n, generator=gen, device=dev) * 2.0 - 1.0) * math.pi
        # goal candidates uniform over the start's component
        u = torch.rand(n, GOAL_CANDIDATES, generator=gen, device=dev)
        offset = floor_index(u, self.comp_count[start_idx, None])
        cand = self.centres[self.comp_first[start_idx, None] + offset]  # [n, C, 2]
        cand = cand + self._jitter(n * GOAL_CANDIDATES, gen).view(n, GOAL_CANDIDATES, 2)
        goal, outside = first_in_band(cand, start, self.d_min, self.d_max)
        return torch.cat([start, yaw[:, None]], dim=1), goal, outside

    def _sample_geodesic(self, n: int, gen: torch.Generator):
        dev = self.device
        pair = torch.randint(self.pair_start.numel(), (n,), generator=gen, device=dev)
        swap = (torch.rand(n, generator=gen, device=dev) < 0.5) | self.goal_at_source  # a pair serves both ways
        a, b = self.pair_start[pair], self.pair_goal[pair]
        start_idx, goal_idx = torch.where(swap, b, a), torch.where(swap, a, b)
        start = self.centres[start_idx] + self._jitter(n, gen)
        goal = self.centres[goal_idx] + self._jitter(n, gen) * self.goal_jitter
        yaw = (torch.rand(n, generator=gen, device=dev) * 2.0 - 1.0) * math.pi
        return torch.cat([start, yaw[:, None]], dim=1), goal

    def _probe(self, grid: OccupancyMap) -> None:
        """Euclidean mode: draw PROBE_EPISODES with a private generator (the caller's stream is not
        touched); refuse the map if none is in the band, warn once if some fall outside it."""
        gen = torch.Generator(device=self.device).manual_seed(0)
        _, _, outside = self._sample_euclidean(PROBE_EPISODES, gen)
        count = int(outside.sum())
        if count == 0:
            return
        where = f"{grid.source}" if grid.source else f"map {grid.name!r}"
        band = f"{self.d_min:g}-{self.d_max:g} m"
        if count == PROBE_EPISODES:
            raise ValueError(
                f"{where}: no start found a goal {band} away (straight line) in its free-space component "
                f"({PROBE_EPISODES} starts, {GOAL_CANDIDATES} candidates each): the band is unreachable "
                f"on this map; change episode.min_goal_distance / max_goal_distance")
        key = (grid.name, str(grid.source), grid.shape, self.d_min, self.d_max, self.radius)
        if key not in _warned:
            _warned.add(key)
            warnings.warn(
                f"{where}: {count} of {PROBE_EPISODES} sampled episodes ({count / PROBE_EPISODES:.2%}) find no goal "
                f"{band} away (straight line) and take "
                f"the nearest candidate outside the band (counted in EpisodeSampler.out_of_band); "
                f"episode.goal_sampling=geodesic keeps every goal in the band by path length", RuntimeWarning,
                stacklevel=3)


def geodesic_band(preset: RobotPreset) -> tuple[float, float]:
    """The geodesic goal band (lo, hi), metres: the preset's, its top capped at HORIZON_PATH_FRACTION
    of the path the horizon allows at top speed (horizon x dt x v_max)."""
    ep = preset.episode
    reach = HORIZON_PATH_FRACTION * ep.horizon * ep.dt * preset.motion.v_bounds[1]
    hi = min(ep.max_goal_distance, reach)
    if not ep.min_goal_distance < hi:
        raise ValueError(
            f"robot {preset.name!r}: episode.min_goal_distance {ep.min_goal_distance:g} m is not below the "
            f"geodesic band's top {hi:g} m (max_goal_distance {ep.max_goal_distance:g} m, or "
            f"{HORIZON_PATH_FRACTION:g} x horizon {ep.horizon} x dt {ep.dt:g} s x top speed "
            f"{preset.motion.v_bounds[1]:g} m/s)")
    return ep.min_goal_distance, hi


def floor_index(u: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """Uniform indices ``floor(u * count)`` (long) for ``u`` in [0, 1), clamped below ``count`` (rounding
    of ``u * count`` can reach it)."""
    return torch.minimum((u * count).long(), count.long() - 1)


def first_in_band(cand: torch.Tensor, start: torch.Tensor, d_min: float, d_max: float):
    """Of the goal candidates ``cand`` [n, C, 2] of starts ``start`` [n, 2]: the first whose straight-line
    distance is in [d_min, d_max], else the nearest to the band; returns (goal [n, 2], outside [n] bool)."""
    dist = torch.linalg.vector_norm(cand - start[:, None, :], dim=-1)  # [n, C]
    # distance outside the band: 0 inside it; the first zero (else the nearest) wins
    miss = (d_min - dist).clamp(min=0) + (dist - d_max).clamp(min=0)
    index = torch.arange(cand.shape[1], device=cand.device, dtype=torch.float32)
    pick = (miss * 1e3 + index * 1e-3).argmin(dim=1)
    rows = torch.arange(cand.shape[0], device=cand.device)
    return cand[rows, pick], miss[rows, pick] > 0


class MapSetSampler:
    """Draws episodes for slots spread over M maps in one chain of batched ops, whatever the number
    of maps: every map's candidate-cell tables (its :class:`EpisodeSampler`'s cell centres, per-cell
    component ranges, geodesic pairs) are concatenated, with per-map offsets into them.

    Each slot's episode has its map's own sampler's distribution (the same validity rules: cells,
    distance band, nearest-candidate fallback, geodesic pairs; the per-map samplers' construction
    already refused impossible maps and warned of fallbacks). Only the uniform index over a map's
    cells or pairs is drawn as ``floor(u * count)`` from a float64 ``u`` instead of
    ``torch.randint(count)`` (each of up to 2**31 entries within 2**-22 relative of 1 / count), and
    the generator's stream is consumed in another order, so the draws are not those of the per-map
    loop. The per-map samplers' tables become views of the concatenated ones (no second copy).

    Attributes:
        out_of_band: [M] int64 on the device: euclidean fallbacks per map, shared with the per-map
            samplers (``samplers[m].out_of_band`` is a view of entry m), so either path counts there.
    """

    def __init__(self, samplers: list[EpisodeSampler]):
        if not samplers:
            raise ValueError("MapSetSampler needs at least one map's EpisodeSampler, got none")
        first = samplers[0]
        for m, s in enumerate(samplers):
            if (s.mode, s.d_min, s.d_max, s.device, s.goal_at_source, s.hard_share, s.hard_candidates) != (
                    first.mode, first.d_min, first.d_max, first.device, first.goal_at_source, first.hard_share,
                    first.hard_candidates):
                raise ValueError(f"samplers[{m}] has mode {s.mode!r}, band {s.d_min:g}-{s.d_max:g} m on {s.device}, "
                                 f"goals at sources {s.goal_at_source}; samplers[0] has {first.mode!r}, "
                                 f"{first.d_min:g}-{first.d_max:g} m on {first.device}, goals at sources "
                                 f"{first.goal_at_source}: one map set samples with one episode preset")
        self.mode, self.d_min, self.d_max, self.device = first.mode, first.d_min, first.d_max, first.device
        self.goal_at_source, self.goal_jitter = first.goal_at_source, first.goal_jitter
        # episode.hard_share: each map's own sampler measures the detours of its candidates
        self.samplers, self.hard_share, self.hard_candidates = samplers, first.hard_share, first.hard_candidates
        dev = self.device
        # per-map tables concatenated; indices inside them stay local to their map (+ cell_first[m])
        self.centres = _concat(samplers, "centres")  # [sum of cells, 2] metres
        cells = [s.num_cells for s in samplers]
        self.cell_first = torch.tensor(_starts(cells), dtype=torch.long, device=dev)  # [M]
        self.num_cells = torch.tensor(cells, dtype=torch.float64, device=dev)  # [M]
        self.resolution = torch.tensor([s.resolution for s in samplers], dtype=torch.float32, device=dev)  # [M]
        self.out_of_band = _concat(samplers, "out_of_band", lambda t: t.reshape(1))  # [M]
        if self.mode == "geodesic":
            pairs = [s.pair_start.numel() for s in samplers]
            self.pair_first = torch.tensor(_starts(pairs), dtype=torch.long, device=dev)  # [M]
            self.num_pairs = torch.tensor(pairs, dtype=torch.float64, device=dev)  # [M]
            self.pair_start, self.pair_goal = _concat(samplers, "pair_start"), _concat(samplers, "pair_goal")
        else:
            self.comp_first, self.comp_count = _concat(samplers, "comp_first"), _concat(samplers, "comp_count")

    @staticmethod
    def _pick(u: torch.Tensor, first: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
        """Uniform indices: entry ``first + floor(u * count)`` (float64 ``u`` in [0, 1), so every one of up
        to 2**31 entries has probability 1 / count within 2**-22 relative), clamped into the range."""
        return first + floor_index(u, count)

    def sample(self, maps: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Episodes for slots on maps ``maps`` [n] (long, in [0, M)): pose [n, 3] (x, y m in each map's
        frame, yaw rad in [-pi, pi)) and goal [n, 2] (m)."""
        pose, goal, outside = self._draws(maps, gen)
        if self.hard_share > 0:  # each slot's candidates drawn on its own map, their detours measured there
            harden(pose, goal, outside, self.hard_share, self.hard_candidates, gen,
                   draw=lambda slots, c: self._draws(maps[slots].repeat_interleave(c), gen),
                   detour=lambda slots, start, end: self._detours(maps[slots], start, end))
        if outside is not None:
            self.out_of_band.index_add_(0, maps, outside.long())
        return pose, goal

    def _draws(self, maps: torch.Tensor, gen: torch.Generator):
        """As :meth:`EpisodeSampler._draws`, per slot on its map ``maps`` [n]."""
        if self.mode == "geodesic":
            return (*self._sample_geodesic(maps, gen), None)
        return self._sample_euclidean(maps, gen)

    def _detours(self, maps: torch.Tensor, start: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """[k] :meth:`EpisodeSampler.detour` of each start [k, 2] / goal [k, 2] on its map ``maps`` [k], measured by
        that map's own sampler."""
        ratio = torch.empty(maps.numel(), dtype=torch.float32, device=self.device)
        for m in torch.unique(maps).tolist():
            on = (maps == m).nonzero().squeeze(1)
            ratio[on] = self.samplers[m].detour(start[on], goal[on])
        return ratio

    def _jitter(self, maps: torch.Tensor, k: int, gen: torch.Generator) -> torch.Tensor:
        """[n, k, 2] offsets uniform within each slot's map cell (m)."""
        n = maps.numel()
        u = torch.rand(n, k, 2, generator=gen, device=self.device)
        return (u - 0.5) * self.resolution[maps][:, None, None]

    def _sample_euclidean(self, maps: torch.Tensor, gen: torch.Generator):
        """As EpisodeSampler._sample_euclidean, per slot on its map: (pose, goal, outside [n] bool)."""
        dev, n = self.device, maps.numel()
        first = self.cell_first[maps]
        u = torch.rand(n, generator=gen, device=dev, dtype=torch.float64)
        start_idx = self._pick(u, first, self.num_cells[maps])
        start = self.centres[start_idx] + self._jitter(maps, 1, gen)[:, 0]
        yaw = (torch.rand(n, generator=gen, device=dev) * 2.0 - 1.0) * math.pi
        count = self.comp_count[start_idx, None]  # float32, exactly as the per-map sampler computes it
        offset = floor_index(torch.rand(n, GOAL_CANDIDATES, generator=gen, device=dev), count)
        cand = self.centres[(first + self.comp_first[start_idx])[:, None] + offset]
        cand = cand + self._jitter(maps, GOAL_CANDIDATES, gen)
        goal, outside = first_in_band(cand, start, self.d_min, self.d_max)
        return torch.cat([start, yaw[:, None]], dim=1), goal, outside

    def _sample_geodesic(self, maps: torch.Tensor, gen: torch.Generator):
        dev, n = self.device, maps.numel()
        u = torch.rand(n, generator=gen, device=dev, dtype=torch.float64)
        pair = self._pick(u, self.pair_first[maps], self.num_pairs[maps])
        swap = (torch.rand(n, generator=gen, device=dev) < 0.5) | self.goal_at_source  # a pair serves both ways
        first = self.cell_first[maps]
        a, b = first + self.pair_start[pair], first + self.pair_goal[pair]
        start_idx, goal_idx = torch.where(swap, b, a), torch.where(swap, a, b)
        jitter = self._jitter(maps, 2, gen)
        start = self.centres[start_idx] + jitter[:, 0]
        goal = self.centres[goal_idx] + jitter[:, 1] * self.goal_jitter
        yaw = (torch.rand(n, generator=gen, device=dev) * 2.0 - 1.0) * math.pi
        return torch.cat([start, yaw[:, None]], dim=1), goal


def harden(pose: torch.Tensor, goal: torch.Tensor, outside: torch.Tensor | None, share: float, candidates: int,
           gen: torch.Generator, draw, detour) -> None:
    """episode.hard_share, in place: each slot, with chance ``share``, takes the episode with the longest detour (path
    length / straight line) of ``candidates`` fresh draws of the task's sampler. ``draw(slots, c)`` -> (pose, goal,
    outside or None) of c candidates for each slot index in ``slots``, slot by slot; ``detour(slots, start, goal)``
    -> [k] their ratios (``slots`` repeated per candidate). ``outside`` (euclidean fallbacks) follows the pick."""
    slots = (torch.rand(pose.shape[0], generator=gen, device=pose.device) < share).nonzero().squeeze(1)
    if slots.numel() == 0:
        return
    cand_pose, cand_goal, cand_out = draw(slots, candidates)
    ratio = detour(slots.repeat_interleave(candidates), cand_pose[:, :2], cand_goal)
    pick = torch.arange(slots.numel(), device=pose.device) * candidates + ratio.view(-1, candidates).argmax(dim=1)
    pose[slots], goal[slots] = cand_pose[pick], cand_goal[pick]
    if outside is not None:
        outside[slots] = cand_out[pick]


def _starts(sizes: list[int]) -> list[int]:
    """Where each of consecutive blocks of ``sizes`` starts."""
    return [0, *itertools.accumulate(sizes)][:-1]


def _concat(samplers: list[EpisodeSampler], name: str, shape=lambda t: t) -> torch.Tensor:
    """The samplers' tensors ``name`` concatenated along dim 0; each sampler's attribute then becomes
    its view into the result (its values unchanged), so the table is held once."""
    parts = [shape(getattr(s, name)) for s in samplers]
    whole = torch.cat(parts)
    start = 0
    for s, part in zip(samplers, parts):
        setattr(s, name, whole[start:start + part.shape[0]].view(getattr(s, name).shape))
        start += part.shape[0]
    return whole
