"""What every raycaster shares: the :class:`Raycaster` interface and the floating-point constants of
the exact semantics (:mod:`flashnav.sim.raycast`). A leaf module: the numba kernel
(:mod:`flashnav.sim.raycast_numba`) and the torch raycasters (:mod:`flashnav.sim.raycast_torch`)
both import it, and neither imports the other or the factory in :mod:`flashnav.sim.raycast`.
"""

from __future__ import annotations

import math

import torch

from flashnav.maps.fields import PAD
from flashnav.maps.grid import OccupancyMap

__all__ = ["AXIS_SNAP", "DELTA", "EPS", "JUMP_MIN_CELLS", "PAD", "Raycaster"]

EPS = 1e-9  # cells: "on a grid line" / "through a vertex" tolerance (see flashnav.sim.raycast)
DELTA = 1e-6  # cells: margin kept from the safe distance on every jump (>> EPS, << a cell)
AXIS_SNAP = 1e-12  # direction components below this are exactly 0
#: The numba kernel jumps through free space only where the field allows at least this many cells;
#: nearer to walls DDA steps (~2 ns each) are cheaper than a jump, which restarts the traversal
#: (float -> cell conversions) and loads a cell that is often not in cache. Measured on the 2-core
#: CPU: 3 to 8 are equally good, 1 is ~15 % slower.
JUMP_MIN_CELLS = 3.0


class Raycaster:
    """Callable ``pose [N, 3] float32 (x m, y m, yaw rad) -> ranges [N, K] float32 metres``.

    Attributes: name, grid, beam_angles ([K] float32 rad, relative to the heading, on ``device``),
    max_range (metres), device.
    """

    name = "base"

    def __init__(self, grid: OccupancyMap, beam_angles: torch.Tensor, max_range: float, device) -> None:
        if not (max_range > 0 and math.isfinite(max_range)):
            raise ValueError(f"max_range must be a positive number of metres, got {max_range}")
        self.grid = grid
        self.device = torch.device(device)
        self.beam_angles = torch.as_tensor(beam_angles, dtype=torch.float32).reshape(-1).to(self.device)
        self.max_range = float(max_range)

    def _check(self, pose: torch.Tensor) -> None:
        if pose.ndim != 2 or pose.shape[1] != 3:
            raise ValueError(f"pose must be [N, 3] (x, y, yaw), got shape {tuple(pose.shape)}")

    def __call__(self, pose: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(name={self.name!r}, beams={self.beam_angles.numel()}, "
                f"max_range={self.max_range}, device={self.device}, grid={self.grid!r})")
