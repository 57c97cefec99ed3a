"""The "exact-cuda" raycaster: the CPU kernel's exact traversal, compiled for a CUDA GPU by numba.cuda,
one GPU thread per ray and one launch per scan. Semantics: :mod:`flashnav.sim.raycast`.

Why: on a GPU the torch raycasters are bound by their launches (exact-torch: thousands of small
kernels per step; docs/benchmarks.md "GPU: the simulator's launches"). A ray's traversal is a short
loop with data-dependent exits, which a GPU thread runs as well as a CPU core does.

No second copy of the algorithm: the device functions are the very Python functions of
:mod:`flashnav.sim.raycast_numba` (``_span``, ``_touches``, ``_along_line``, ``_restart``,
``cast_ray``; their ``py_func``), rebound to each other's CUDA versions and compiled with
``numba.cuda.jit(device=True)``. Only the per-ray set-up (the CPU kernel's per-environment loop body,
without its beam-by-beam jump passes, which change no range) is written here. Compiled on first use
(a few seconds); launched on torch's current CUDA stream, so it orders with the collector's stream.

With ``NUMBA_ENABLE_CUDASIM=1`` numba runs the kernel in its CUDA simulator on the CPU (CPU tensors,
every thread in Python: slow, for tests on small scenes); without it, CPU poses are an error.
"""

from __future__ import annotations

import math
import types

import numpy as np
import torch

if not hasattr(np, "row_stack"):  # numba-cuda 0.30 registers an overload for it; numpy 2.5 removed it
    np.row_stack = np.vstack
from numba import cuda  # noqa: E402  a module global: numba's CUDA simulator swaps it in the kernel's globals

from flashnav.sim.raycast_base import AXIS_SNAP, JUMP_MIN_CELLS, PAD, Raycaster, exact_kernel_arrays

#: The CPU kernel's functions that run per ray, in an order in which each one's callees come first.
DEVICE_FUNCTIONS = ("_span", "_along_line", "_restart", "_touches", "cast_ray")
#: Threads per block (one ray each).
THREADS = 128

_KERNEL = None


def simulated() -> bool:
    """True when numba runs CUDA kernels in its CPU simulator (``NUMBA_ENABLE_CUDASIM=1``)."""
    from numba import config

    return bool(config.ENABLE_CUDASIM)


def kernel():
    """The compiled (lazily, once per process) CUDA kernel ``cast_rays[blocks, threads, stream](...)``."""
    global _KERNEL
    if _KERNEL is None:
        _KERNEL = _build()
    return _KERNEL


def _build():
    from flashnav.sim import raycast_numba as cpu

    scope = dict(vars(cpu))  # the CPU module's globals (math, EPS, DELTA, ...), the callees replaced below
    for name in DEVICE_FUNCTIONS:
        f = getattr(cpu, name).py_func
        scope[name] = cuda.jit(device=True)(types.FunctionType(f.__code__, scope, f.__name__, f.__defaults__, f.__closure__))
    touches, restart, cast_ray = scope["_touches"], scope["_restart"], scope["cast_ray"]

    @cuda.jit
    def cast_rays(pose, map_index, cos_a, sin_a, angles, flat, base0, sectors_of, hs, ws, hps, wps, ox_of, oy_of,
                  res_of, pad, max_range, jump_min, out):
        """out[n, k] = the exact range of beam k from pose n (on map map_index[n]); one thread per ray.
        Arguments as :func:`flashnav.sim.raycast_numba.cast_exact` (without its ``order``)."""
        r = cuda.grid(1)
        k_beam = cos_a.shape[0]
        if r >= pose.shape[0] * k_beam:
            return
        n = r // k_beam
        k = r - n * k_beam
        m = map_index[n]
        wp = wps[m]
        cell0 = base0[m] + pad * wp + pad
        res = res_of[m]
        inv = 1.0 / res
        u = (np.float64(pose[n, 0]) - ox_of[m]) * inv
        v = (np.float64(pose[n, 1]) - oy_of[m]) * inv
        yaw = np.float64(pose[n, 2])
        if not (u > 0.0 and u < ws[m] and v > 0.0 and v < hs[m]) or touches(flat, cell0, wp, u, v):
            out[n, k] = 0.0
            return
        cy = math.cos(yaw)
        sy = math.sin(yaw)
        dx = cy * cos_a[k] - sy * sin_a[k]
        dy = sy * cos_a[k] + cy * sin_a[k]
        dx = 0.0 if abs(dx) < AXIS_SNAP else dx
        dy = 0.0 if abs(dy) < AXIS_SNAP else dy
        ix = 1.0 / dx if dx != 0.0 else math.inf
        iy = 1.0 / dy if dy != 0.0 else math.inf
        two_pi = 2.0 * math.pi
        yn = yaw - two_pi * math.floor(yaw / two_pi)
        sectors = sectors_of[m]
        s = int(math.floor((yn + angles[k]) * (sectors / two_pi))) % sectors
        base = s * (hps[m] * wp) + cell0
        tmx, tmy, idx = restart(base, wp, u, v, dx, dy, ix, iy, 0.0)
        jump_byte = 1 + int(math.ceil(2.0 * jump_min))
        t = cast_ray(flat, base, wp, u, v, dx, dy, ix, iy, max_range * inv, jump_byte, 0.0, tmx, tmy, idx)
        out[n, k] = min(t * res, max_range)

    return cast_rays


class CudaExactRaycaster(Raycaster):
    """"exact-cuda": exact ranges from one numba.cuda launch per scan (see the module docstring).

    Poses and ranges live on a CUDA device; on the CPU only under numba's CUDA simulator (tests).
    """

    name = "exact-cuda"

    def __init__(self, grid, beam_angles, max_range, device="cuda") -> None:
        super().__init__(grid, beam_angles, max_range, device)
        if self.device.type != "cuda" and not simulated():
            raise ValueError(f"raycaster 'exact-cuda' runs on a CUDA device, not {self.device} "
                             "(use 'exact' there; tests may set NUMBA_ENABLE_CUDASIM=1)")
        # in the kernel's argument order; copied (np.array), since a single map's packed field is a read-only view
        self._arrays = {key: torch.from_numpy(np.array(value)).to(self.device)
                        for key, value in exact_kernel_arrays(self.grids, self.beam_angles).items()}
        self._zeros = torch.zeros(0, dtype=torch.int64, device=self.device)

    def __call__(self, pose: torch.Tensor, map_index=None) -> torch.Tensor:
        mi = self._check(pose, map_index)
        p = pose.detach().to(self.device, torch.float32).contiguous()
        n, k = p.shape[0], self._arrays["cos_a"].shape[0]
        if mi is None:
            if self._zeros.shape[0] < n:
                self._zeros = torch.zeros(n, dtype=torch.int64, device=self.device)
            mi = self._zeros[:n]
        out = torch.empty((n, k), dtype=torch.float32, device=self.device)
        if n == 0:
            return out
        args = [p, mi.to(self.device).contiguous(), *self._arrays.values(), PAD, self.max_range, JUMP_MIN_CELLS, out]
        blocks = (n * k + THREADS - 1) // THREADS
        if self.device.type == "cuda":
            stream = cuda.external_stream(torch.cuda.current_stream(self.device).cuda_stream)
            kernel()[blocks, THREADS, stream](*args)
        else:  # numba's CUDA simulator: numpy views of the CPU tensors
            kernel()[blocks, THREADS](*[x.numpy() if isinstance(x, torch.Tensor) else x for x in args])
        return out
