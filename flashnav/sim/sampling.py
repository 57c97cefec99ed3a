"""Start/goal sampling that keeps every episode solvable.

Starts and goals are drawn from the *free configuration space*: cells whose centre (plus the jitter
inside the cell) stays farther than the footprint's circumscribed radius + ``start_clearance`` from any
obstacle, so the robot is collision-free there at any heading. The goal lies in the same 4-connected
component of that space as the start (so a path exists along which the whole footprint stays clear),
at a straight-line distance within [min_goal_distance, max_goal_distance].

Sampling is a handful of batched tensor ops with a ``torch.Generator``: no host synchronisation,
same seed -> same episodes, on any device.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flashnav.config import RobotPreset
from flashnav.maps.fields import component_cells
from flashnav.maps.grid import OccupancyMap

GOAL_CANDIDATES = 32  # goal candidates drawn per start; the first inside the distance band wins
MIN_COMPONENT_CELLS = 16  # smaller pockets of free space are never used for starts


class EpisodeSampler:
    """Draws (pose [n, 3], goal [n, 2]) pairs for ``n`` environment slots, in ``grid``'s
    coordinates (the environment passes its re-centred map, so they are in the simulator's frame)."""

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
        self.comp_first = torch.tensor(per_cell_first, device=device, dtype=torch.long)  # [M]
        self.comp_count = torch.tensor(per_cell_count, device=device, dtype=torch.float32)  # [M]
        self.num_cells = len(rows)
        self.resolution = grid.resolution
        self.d_min, self.d_max = ep.min_goal_distance, ep.max_goal_distance
        self.device = device

    def _jitter(self, n: int, gen: torch.Generator) -> torch.Tensor:
        return (torch.rand(n, 2, generator=gen, device=self.device) - 0.5) * self.resolution

    def sample(self, n: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns pose [n, 3] (x, y m, yaw rad in [-pi, pi)) and goal [n, 2] (m)."""
        dev = self.device
        start_idx = torch.randint(self.num_cells, (n,), generator=gen, device=dev)
        start = self.centres[start_idx] + self._jitter(n, gen)
        yaw = (torch.rand(n, generator=gen, device=dev) * 2.0 - 1.0) * math.pi
        # goal candidates uniform over the start's component
        u = torch.rand(n, GOAL_CANDIDATES, generator=gen, device=dev)
        offset = (u * self.comp_count[start_idx, None]).long()
        offset = torch.minimum(offset, self.comp_count[start_idx, None].long() - 1)
        cand = self.centres[self.comp_first[start_idx, None] + offset]  # [n, C, 2]
        cand = cand + self._jitter(n * GOAL_CANDIDATES, gen).view(n, GOAL_CANDIDATES, 2)
        dist = torch.linalg.vector_norm(cand - start[:, None, :], dim=-1)  # [n, C]
        # distance outside the band: 0 inside it; the first zero (else the nearest) wins
        miss = (self.d_min - dist).clamp(min=0) + (dist - self.d_max).clamp(min=0)
        index = torch.arange(GOAL_CANDIDATES, device=dev, dtype=torch.float32)
        score = miss * 1e3 + index * 1e-3
        pick = score.argmin(dim=1)
        goal = cand[torch.arange(n, device=dev), pick]
        return torch.cat([start, yaw[:, None]], dim=1), goal
