"""Batched 2D LiDAR raycasting on an :class:`~flashnav.maps.grid.OccupancyMap`.

Exact semantics (what the "exact" raycasters compute)
-----------------------------------------------------
A beam from pose (x, y, yaw) at beam angle a is the ray ``p + t * (cos(yaw + a), sin(yaw + a))``.
Its range is the smallest ``t >= 0`` at which the ray *touches* a closed occupied cell square or the
map boundary (everything outside the open map rectangle counts as occupied), clipped to
``max_range``. Consequences:

- a ray passing exactly through the shared corner of two diagonal occupied cells stops at the corner
  (nothing leaks between diagonal neighbours);
- a ray running exactly along a grid line touches the cells on both sides of the line;
- an origin inside or on an occupied cell, on the map boundary or outside the map gives 0.

Floating-point conventions (in grid units, i.e. cells): a direction component smaller than 1e-12 in
magnitude is taken as exactly 0, so beams meant to be axis-aligned (yaw + a a multiple of pi/2,
whose float cosine is ~6e-17) are; a point within 1e-9 cells of a grid line is on the line, and a
ray passing within 1e-9 cells of a grid vertex passes through it. Arithmetic is float64 internally.

Raycasters (:data:`RAYCASTERS`)
-------------------------------
- ``"exact"``: CPU tensors run a numba kernel (parallel over environments on all cores; exact
  Amanatides-Woo DDA with skipping through free space by a directional distance field, see
  :mod:`flashnav.sim.raycast_numba`); CUDA tensors run ``"exact-cuda"`` (``"exact-torch"`` where
  numba's CUDA target is missing, with a warning).
- ``"exact-torch"``: the same semantics as batched torch ops on any device (the GPU path).
- ``"exact-cuda"``: the numba kernel's traversal compiled for a CUDA GPU by numba.cuda, one thread
  per ray, one launch per scan (:mod:`flashnav.sim.raycast_cuda`); CUDA devices only.
- ``"march"``: the paper's algorithm literally (appendix B): fixed steps of ``march_step`` metres
  from ``t = step``; the first sample point whose cell (``floor``) is occupied or off the map gives
  the range. Approximate (it can step over a corner); the fidelity baseline of the benchmark.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np
import torch

from flashnav.maps.fields import safe_field
from flashnav.maps.grid import OccupancyMap
from flashnav.names import RAYCASTERS  # defined once; re-exported here
from flashnav.sim import raycast_torch
from flashnav.sim.raycast_base import JUMP_MIN_CELLS, PAD, Raycaster, exact_kernel_arrays

__all__ = ["RAYCASTERS", "NumbaExactRaycaster", "Raycaster", "error_stats", "make_raycaster",
           "random_free_poses"]


class NumbaExactRaycaster(Raycaster):
    """"exact" on CPU: the numba kernel (every map's field in one flat buffer); CUDA inputs go to the
    torch implementation."""

    name = "exact"

    def __init__(self, grid, beam_angles, max_range, device="cpu") -> None:
        super().__init__(grid, beam_angles, max_range, device)
        from flashnav.sim import raycast_numba  # imported lazily: the first import may JIT-compile

        self._kernel = raycast_numba.cast_exact
        a = exact_kernel_arrays(self.grids, self.beam_angles)
        self._angles, self._cos_a, self._sin_a = a["angles"], a["cos_a"], a["sin_a"]
        self._field, self._base0, self._sectors = a["flat"], a["base0"], a["sectors"]
        self._hs, self._ws, self._hps, self._wps = a["h"], a["w"], a["hp"], a["wp"]
        self._ox, self._oy, self._res = a["ox"], a["oy"], a["res"]
        # map_index and cast order of a single map, grown on demand
        self._zeros, self._order = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        self._torch = None

    def __call__(self, pose: torch.Tensor, map_index=None) -> torch.Tensor:
        mi = self._check(pose, map_index)
        if pose.device.type != "cpu":
            if self._torch is None:
                self._torch = gpu_exact(self.grids, self.beam_angles, self.max_range, pose.device)
            return self._torch(pose, mi)
        # float32 contiguous CPU poses reach the kernel as a zero-copy numpy view
        p = pose.detach().to(torch.float32).contiguous().numpy()
        if mi is None:
            if self._zeros.shape[0] < p.shape[0]:
                self._zeros, self._order = np.zeros(p.shape[0], dtype=np.int64), np.arange(p.shape[0], dtype=np.int64)
            m, order = self._zeros[: p.shape[0]], self._order[: p.shape[0]]
        else:
            # cast the poses grouped by map, so the threads read one map's field at a time: slot
            # order took 1.17x as long with 64 maps (docs/benchmarks.md, "Many maps in one env")
            m = mi.contiguous().numpy()
            order = np.argsort(m, kind="stable")
        out = torch.empty((p.shape[0], self._cos_a.shape[0]), dtype=torch.float32)
        self._kernel(p, m, order, self._cos_a, self._sin_a, self._angles, self._field, self._base0, self._sectors,
                     self._hs, self._ws, self._hps, self._wps, self._ox, self._oy, self._res, PAD, self.max_range, JUMP_MIN_CELLS,
                     out.numpy())
        return out


def make_raycaster(name: str, grid: OccupancyMap | Sequence[OccupancyMap], beam_angles: torch.Tensor, max_range: float,
                   device: torch.device | str = "cpu", march_step: float = 0.03) -> Raycaster:
    """Build a raycaster by name (one of :data:`RAYCASTERS`); see the module docstring.

    Args:
        grid: the occupancy map, or a sequence of maps (then call it with ``map_index`` [N]).
        beam_angles: [K] radians relative to the heading.
        max_range: metres; ranges are clipped to it.
        device: where poses and ranges live.
        march_step: metres, only for ``"march"``.
    """
    device = torch.device(device)
    if name == "exact":
        if device.type == "cpu":
            return NumbaExactRaycaster(grid, beam_angles, max_range, device)
        return gpu_exact(grid, beam_angles, max_range, device)
    if name == "exact-torch":
        return raycast_torch.TorchExactRaycaster(grid, beam_angles, max_range, device)
    if name == "march":
        return raycast_torch.MarchRaycaster(grid, beam_angles, max_range, device, step=march_step)
    if name == "exact-cuda":
        from flashnav.sim.raycast_cuda import CudaExactRaycaster  # numba.cuda is imported only when asked for

        return CudaExactRaycaster(grid, beam_angles, max_range, device)
    raise ValueError(f"unknown raycaster {name!r}; valid names: {', '.join(RAYCASTERS)}")


def gpu_exact(grid, beam_angles, max_range, device) -> Raycaster:
    """"exact" off the CPU: the numba.cuda kernel on a CUDA device (10-30x the march on an H100, one
    launch per scan; docs/benchmarks.md "GPU: the exact raycaster as one kernel"), else exact-torch - also
    where numba's CUDA target cannot be loaded or compiled, with a warning that says why."""
    if torch.device(device).type == "cuda":
        try:
            from flashnav.sim.raycast_cuda import CudaExactRaycaster

            ray = CudaExactRaycaster(grid, beam_angles, max_range, device)
            ray.name = "exact"
            # one cast compiles the kernel now, so that a missing CUDA toolchain shows here, not mid-training
            ray(torch.zeros((1, 3), device=device), torch.zeros(1, dtype=torch.long, device=device))
            return ray
        except Exception as exc:  # noqa: BLE001  any failure of numba's CUDA target: the torch path is exact too
            warnings.warn(f"raycaster 'exact' on {device}: numba.cuda unusable ({type(exc).__name__}: {exc}); "
                          "using exact-torch (exact, slower)", RuntimeWarning, stacklevel=2)
    return raycast_torch.TorchExactRaycaster(grid, beam_angles, max_range, device, name="exact")


def error_stats(ranges: torch.Tensor, exact: torch.Tensor) -> dict[str, float]:
    """Absolute error of ``ranges`` against ``exact`` (same shape, metres): mean, p99 and max in
    metres, and ``frac_over_5cm``, the share of beams off by more than 0.05 m."""
    if ranges.shape != exact.shape:
        raise ValueError(f"shape mismatch: {tuple(ranges.shape)} vs {tuple(exact.shape)}")
    err = (ranges.double() - exact.double()).abs().reshape(-1)
    if err.numel() == 0:
        raise ValueError("error_stats needs at least one beam")
    return {
        "mean": float(err.mean()),
        "p99": float(torch.quantile(err.cpu(), 0.99)) if err.numel() <= 16_000_000 else float(
            err.cpu().kthvalue(max(1, math.ceil(0.99 * err.numel()))).values),
        "max": float(err.max()),
        "frac_over_5cm": float((err > 0.05).double().mean()),
    }


def random_free_poses(grid: OccupancyMap, n: int, generator: torch.Generator | int | None = None,
                      min_clearance: float = 0.0, device: torch.device | str = "cpu", *,
                      seed: int | None = None) -> torch.Tensor:
    """[n, 3] float32 poses (x m, y m, yaw rad in [-pi, pi]): positions uniform over the free cells
    whose every point is at least ``min_clearance`` metres from any occupied square and the map
    boundary (cells with ``safe_field * resolution >= min_clearance``), uniform yaw.

    ``generator`` is a ``torch.Generator``, an int seed, or None; ``seed=`` is the same as an int
    generator. With neither, the draw is unseeded.
    """
    if seed is not None:
        if generator is not None:
            raise ValueError("give either generator or seed, not both")
        generator = int(seed)
    if isinstance(generator, int) or generator is None:
        seed = generator
        generator = torch.Generator()
        if seed is None:
            generator.seed()
        else:
            generator.manual_seed(seed)
    field = safe_field(grid)[PAD:-PAD, PAD:-PAD]
    ok = (field >= 0) & (field.astype(np.float64) * grid.resolution >= min_clearance)
    rows, cols = np.nonzero(ok)
    if rows.size == 0:
        raise ValueError(f"map {grid.name!r}: no free cell with clearance >= {min_clearance} m")
    pick = torch.randint(0, rows.size, (n,), generator=generator).numpy()
    u = torch.rand((n, 3), generator=generator, dtype=torch.float64).numpy()
    # keep a hair inside the cell so float32 rounding cannot move a point into a neighbour
    u[:, :2] = 1e-3 + u[:, :2] * (1.0 - 2e-3)
    ox, oy = grid.origin
    x = ox + (cols[pick] + u[:, 0]) * grid.resolution
    y = oy + (rows[pick] + u[:, 1]) * grid.resolution
    yaw = (u[:, 2] * 2.0 - 1.0) * math.pi
    return torch.from_numpy(np.stack([x, y, yaw], axis=1).astype(np.float32)).to(device)
