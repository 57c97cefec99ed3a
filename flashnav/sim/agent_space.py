"""Where moving agents may be (issue 13): each map's clearance field (a lower bound on the distance to
any wall, :func:`~flashnav.maps.fields.safe_field`), the free cells new agents are placed in, and
whether a swept disc (a leg) stays clear of walls. Several maps share one flat clearance buffer with
per-map offsets; every lookup takes each point's map index. Used by :class:`flashnav.sim.agents.AgentWorld`
(the torch ops) and handed to the numba kernels of :mod:`flashnav.sim.agent_numba`."""

from __future__ import annotations

import numpy as np
import torch

from flashnav.maps.fields import PAD, safe_field
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.agent_draws import coarse_first
from flashnav.sim.mapset import map_table


class AgentSpace:
    """The maps as the agents see them: ``grids`` in their simulator frames, ``r_max`` the largest
    agent radius (free cells fit it everywhere), ``samples`` clearance samples per leg."""

    def __init__(self, grids: tuple[OccupancyMap, ...], r_max: float, samples: int, device: torch.device):
        self.device = device
        #: leg sample positions in [0, 1], coarse first (:func:`flashnav.sim.agent_draws.coarse_first`)
        self.samples = coarse_first(samples).to(device)
        flats, offsets, cells, first, count = [], [], [], [], []
        total = 0
        for g in grids:
            clear = safe_field(g).astype(np.float64) * g.resolution  # <0 on occupied cells
            offsets.append(total)
            flats.append(clear.reshape(-1))
            total += clear.size
            rows, cols = np.nonzero(clear[PAD:-PAD, PAD:-PAD] >= r_max)
            if rows.size == 0:
                raise ValueError(f"map {g.name!r}: no free cell for an agent of radius {r_max} m (agents.radius)")
            first.append(sum(len(c) for c in cells))
            count.append(rows.size)
            cells.append(np.stack([g.origin[0] + cols * g.resolution, g.origin[1] + rows * g.resolution], axis=1))
        dev = self.device
        self._clear = torch.from_numpy(np.concatenate(flats)).to(dev)
        self._offset = torch.tensor(offsets, dtype=torch.long, device=dev)
        table = map_table(grids, dev, PAD)
        self._wp, self._hp, self._res = table["wp"], table["hp"], table["res"]
        self._origin = torch.stack([table["ox"], table["oy"]], dim=1)  # [M, 2]
        self._cells = torch.from_numpy(np.concatenate(cells)).to(dev)  # [C, 2] lower-left corners, m
        self._cell_first = torch.tensor(first, dtype=torch.long, device=dev)
        self._cell_count = torch.tensor(count, dtype=torch.long, device=dev)
        g = grids[0]
        self._single = None if len(grids) > 1 else (g.origin[0], g.origin[1], g.resolution, g.shape[1] + 2 * PAD,
                                                    g.shape[0] + 2 * PAD)

    def clearance(self, points: torch.Tensor, maps: torch.Tensor) -> torch.Tensor:
        """A lower bound on the distance (m, float64) from ``points`` [..., 2] to any wall or the map
        boundary, negative on occupied cells and off the map; ``maps`` [...] long, each point's map."""
        p = points.double()
        if self._single is not None:  # one map: scalars instead of per-point gathers
            ox, oy, res, wp, hp = self._single
            j = (torch.floor((p[..., 0] - ox) / res).long() + PAD).clamp(0, wp - 1)
            i = (torch.floor((p[..., 1] - oy) / res).long() + PAD).clamp(0, hp - 1)
            return self._clear[i * wp + j]
        res, org = self._res[maps], self._origin[maps]
        j = (torch.floor((p[..., 0] - org[..., 0]) / res).long() + PAD).clamp(min=0)
        i = (torch.floor((p[..., 1] - org[..., 1]) / res).long() + PAD).clamp(min=0)
        wp, hp = self._wp[maps], self._hp[maps]
        j, i = torch.minimum(j, wp - 1), torch.minimum(i, hp - 1)
        return self._clear[self._offset[maps] + i * wp + j]

    def free_points(self, maps: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        """[...] map indices -> [..., 2] float32 points uniform over the cells whose every point has
        clearance >= the largest agent radius."""
        u = torch.rand(*maps.shape, 3, generator=gen, device=self.device, dtype=torch.float64)
        count = self._cell_count[maps]
        cell = self._cell_first[maps] + torch.minimum((u[..., 0] * count).long(), count - 1)
        # a hair inside the cell, so that float32 rounding cannot move a point into a neighbour
        inner = 1e-3 + u[..., 1:] * (1.0 - 2e-3)
        return (self._cells[cell] + inner * self._res[maps][..., None]).float()

    def segment_clear(self, a: torch.Tensor, b: torch.Tensor, radius: torch.Tensor, maps: torch.Tensor,
                      kernel: str | None = None) -> torch.Tensor:
        """[...] bool: a disc of ``radius`` swept from ``a`` to ``b`` ([..., 2] m) stays clear of walls
        (clearance >= radius + half the sample spacing at every sample of the segment). ``kernel``:
        "numba" (the CPU default: stops at a segment's first failing sample) or "torch"."""
        kernel = kernel or ("numba" if self.device.type == "cpu" else "torch")
        if kernel == "numba":
            from flashnav.sim.agent_numba import segments_clear

            shape = torch.broadcast_shapes(a.shape[:-1], b.shape[:-1], radius.shape, maps.shape)
            out = np.empty(shape.numel(), dtype=np.bool_)
            flat = lambda t, *tail: t.expand(*shape, *tail).reshape(-1, *tail).contiguous().numpy()  # noqa: E731
            segments_clear(flat(a, 2), flat(b, 2), flat(radius), flat(maps), self.samples.numpy(),
                           *self.numba_tables(), PAD, out)
            return torch.from_numpy(out).view(shape)
        a, b = a.double(), b.double()
        s = self.samples
        pts = a[..., None, :] + (b - a)[..., None, :] * s[:, None]  # [..., S, 2]
        spacing = torch.linalg.vector_norm(b - a, dim=-1) / (s.numel() - 1)
        need = radius.double() + 0.5 * spacing
        clear = self.clearance(pts, maps[..., None].expand(pts.shape[:-1]))
        return (clear >= need[..., None]).all(dim=-1)

    def numba_tables(self) -> tuple[np.ndarray, ...]:
        """The map tables as the numba kernels take them: clearance (flat), per-map offset, origin
        [M, 2], resolution, padded width and height."""
        return (self._clear.numpy(), self._offset.numpy(), self._origin.numpy(), self._res.numpy(),
                self._wp.numpy(), self._hp.numpy())
