"""What every raycaster shares: the :class:`Raycaster` interface and the floating-point constants of
the exact semantics (:mod:`flashnav.sim.raycast`), and the arrays the exact kernels read. A leaf module: the numba kernel
(:mod:`flashnav.sim.raycast_numba`) and the torch raycasters (:mod:`flashnav.sim.raycast_torch`)
both import it, and neither imports the other or the factory in :mod:`flashnav.sim.raycast`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from flashnav.maps.fields import PAD, cone_field
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.mapset import as_grids, check_map_index, map_table, pack

__all__ = ["AXIS_SNAP", "DELTA", "EPS", "JUMP_MIN_CELLS", "PAD", "Raycaster", "exact_kernel_arrays"]

EPS = 1e-9  # cells: "on a grid line" / "through a vertex" tolerance (see flashnav.sim.raycast)
DELTA = 1e-6  # cells: margin kept from the safe distance on every jump (>> EPS, << a cell)
AXIS_SNAP = 1e-12  # direction components below this are exactly 0
#: The numba kernel jumps through free space only where the field allows at least this many cells;
#: nearer to walls DDA steps (~2 ns each) are cheaper than a jump, which restarts the traversal
#: (float -> cell conversions) and loads a cell that is often not in cache. Measured on the 2-core
#: CPU: 3 to 8 are equally good, 1 is ~15 % slower.
JUMP_MIN_CELLS = 3.0


class Raycaster:
    """Callable ``(pose [N, 3] float32 (x m, y m, yaw rad), map_index [N] long or None) -> ranges
    [N, K] float32 metres``. Built on one map or on a sequence of M maps (:mod:`flashnav.sim.mapset`);
    with several, ``map_index`` names each pose's map (poses in that map's coordinates).

    Attributes: name, grids (the M maps), grid (the first), beam_angles ([K] float32 rad, relative to
    the heading, on ``device``), max_range (metres), device.
    """

    name = "base"

    def __init__(self, grid: OccupancyMap | Sequence[OccupancyMap], beam_angles: torch.Tensor, max_range: float,
                 device) -> None:
        if not (max_range > 0 and math.isfinite(max_range)):
            raise ValueError(f"max_range must be a positive number of metres, got {max_range}")
        self.grids = as_grids(grid)
        self.grid = self.grids[0]
        self.device = torch.device(device)
        self.beam_angles = torch.as_tensor(beam_angles, dtype=torch.float32).reshape(-1).to(self.device)
        self.max_range = float(max_range)

    def _check(self, pose: torch.Tensor, map_index=None) -> torch.Tensor | None:
        """Check ``pose``; return ``map_index`` as [N] long on the pose's device, or None for a single
        map (any map_index there must be all 0)."""
        if pose.ndim != 2 or pose.shape[1] != 3:
            raise ValueError(f"pose must be [N, 3] (x, y, yaw), got shape {tuple(pose.shape)}")
        if map_index is None:
            if len(self.grids) > 1:
                raise ValueError(f"this raycaster holds {len(self.grids)} maps: give map_index [N]")
            return None
        mi = check_map_index(map_index, pose.shape[0], len(self.grids), pose.device)
        return None if len(self.grids) == 1 else mi

    def __call__(self, pose: torch.Tensor, map_index=None) -> torch.Tensor:
        raise NotImplementedError

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(name={self.name!r}, beams={self.beam_angles.numel()}, "
                f"max_range={self.max_range}, device={self.device}, grid={self.grid!r})")


def exact_kernel_arrays(grids: Sequence[OccupancyMap], beam_angles: torch.Tensor) -> dict[str, np.ndarray]:
    """The arrays the exact kernels read (:func:`flashnav.sim.raycast_numba.cast_exact` and the CUDA kernel of
    :mod:`flashnav.sim.raycast_cuda`), in their argument order: ``cos_a``, ``sin_a``, ``angles`` [K] float64 (the
    beams); ``flat`` uint8 (every map's :func:`cone_field` flattened and concatenated); ``base0``, ``sectors``, ``h``,
    ``w``, ``hp``, ``wp`` [M] int64 and ``ox``, ``oy``, ``res`` [M] float64 (per map: :func:`map_table`)."""
    fields = [cone_field(g, PAD) for g in grids]
    flat, base0 = pack(fields)
    table = {key: value.numpy() for key, value in map_table(grids, "cpu", PAD).items()}  # int64 / float64
    a = beam_angles.cpu().double().numpy()
    return {"cos_a": np.cos(a), "sin_a": np.sin(a), "angles": a, "flat": flat, "base0": base0,
            "sectors": np.array([f.shape[0] for f in fields], dtype=np.int64),
            **{key: table[key] for key in ("h", "w", "hp", "wp", "ox", "oy", "res")}}
