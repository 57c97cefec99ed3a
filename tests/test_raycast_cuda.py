"""The "exact-cuda" raycaster (numba.cuda, one thread per ray) against the numba CPU kernel and the
slab reference of test_raycast.py.

Without a GPU the kernel runs in numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, which numba reads
when ``numba.cuda`` is first imported, so in a subprocess): the kernel's own code (per-ray set-up,
indexing, the rebinding of the CPU kernel's functions) in Python, on small scenes, to the bit. With a
GPU the compiled kernel runs too, on larger scenes."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from test_raycast import cluttered_map, reference_ranges  # noqa: E402

from flashnav.maps.grid import OccupancyMap  # noqa: E402
from flashnav.sim.raycast import make_raycaster, random_free_poses  # noqa: E402


def scenes(n: int):
    """(name, maps, pose [N, 3], map_index or None, beam angles, max_range): random cluttered maps with
    origins anywhere (some in walls, some off the map), poses on grid lines and vertices with beams along
    the lines and through vertices, and a batch over two maps of different sizes and resolutions."""
    out = []
    for seed in (0, 1):
        grid = cluttered_map(seed, origin=(-1.3 + seed, 0.7))
        rng = np.random.default_rng(100 + seed)
        xmin, ymin, xmax, ymax = grid.bounds
        pose = np.stack([rng.uniform(xmin - 0.1, xmax + 0.1, n), rng.uniform(ymin - 0.1, ymax + 0.1, n),
                         rng.uniform(-math.pi, math.pi, n)], 1)
        out.append((f"random map {seed}", [grid], pose, None, np.sort(rng.uniform(-math.pi, math.pi, 40)), 2.5))
    rng = np.random.default_rng(7)
    occ = rng.random((32, 32)) < 0.12
    occ[::4, ::4] = True  # isolated cells: diagonal corner pairs
    grid = OccupancyMap(occ, 0.125, (-2.0, 1.0))
    ij = rng.integers(1, 32, size=(n, 2)).astype(np.float64)
    frac = rng.choice([0.0, 0.5], size=(n, 2))  # on vertices, on lines, or mid-cell
    pose = np.stack([grid.origin[0] + (ij[:, 1] + frac[:, 1]) * 0.125, grid.origin[1] + (ij[:, 0] + frac[:, 0]) * 0.125,
                     rng.integers(0, 4, n) * (math.pi / 2)], 1)
    out.append(("grid lines", [grid], pose, None, np.arange(8) * (math.pi / 4), 3.0))
    maps = [cluttered_map(3, shape=(40, 30), res=0.1, origin=(0.3, -2.0)), cluttered_map(4, shape=(64, 48))]
    index = rng.integers(0, 2, n)
    pose = np.concatenate([random_free_poses(maps[i], 1, 11 + k).numpy() for k, i in enumerate(index)])
    out.append(("two maps", maps, pose, index, np.linspace(-math.pi, math.pi, 30, endpoint=False), 4.0))
    return out


def compare(device: str, n: int, tol_cpu: float) -> list[str]:
    """Failures of exact-cuda against the CPU kernel (within tol_cpu metres) and the slab reference."""
    failures = []
    for name, maps, pose, index, angles, max_range in scenes(n):
        a = torch.tensor(angles, dtype=torch.float32)
        p = torch.tensor(pose, dtype=torch.float32)
        mi = None if index is None else torch.as_tensor(index)
        cpu = make_raycaster("exact", maps, a, max_range)(p, mi)
        ray = make_raycaster("exact-cuda", maps, a, max_range, device=device)
        got = ray(p.to(device), None if mi is None else mi.to(device)).cpu()
        err = (got - cpu).abs().max().item()
        if not (got.shape == cpu.shape and err <= tol_cpu):
            failures.append(f"{name}: exact-cuda differs from exact by {err:.3g} m")
        for m, grid in enumerate(maps):
            rows = np.arange(len(pose)) if index is None else np.nonzero(index == m)[0]
            ref = reference_ranges(grid, p[rows].double().numpy(), a.double().numpy(), max_range)
            slab = np.abs(got[rows].double().numpy() - ref).max()
            if slab > 1e-4:
                failures.append(f"{name}, map {m}: {slab:.3g} m from the slab reference")
    return failures


def test_exact_cuda_in_the_cuda_simulator_equals_the_cpu_kernel():
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    run = subprocess.run([sys.executable, __file__, "simulator"], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "4 scenes, equal" in run.stdout


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (the simulator test runs the kernel's code on CPU)")
def test_exact_cuda_on_a_gpu_equals_the_cpu_kernel():
    # the GPU may fuse a multiply and an add (one rounding less): equal to well under a micrometre
    assert compare("cuda", 256, 1e-6) == []
    # a stepped environment's scan, on torch's current stream (a side stream, as the collector's)
    grid = cluttered_map(11, shape=(100, 120))
    pose = random_free_poses(grid, 2048, 5)
    angles = torch.linspace(-math.pi, math.pi, 1081)[:-1]
    want = make_raycaster("exact", grid, angles, 20.0)(pose)
    ray = make_raycaster("exact-cuda", grid, angles, 20.0, device="cuda")
    stream = torch.cuda.Stream()
    with torch.cuda.stream(stream):
        got = ray(pose.cuda())
    stream.synchronize()
    assert (got.cpu() - want).abs().max().item() <= 1e-6


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_exact_on_a_gpu_is_the_cuda_kernel_and_falls_back_to_torch_with_a_warning(monkeypatch):
    from flashnav.sim import raycast_cuda
    from flashnav.sim.raycast_torch import TorchExactRaycaster

    grid, angles = cluttered_map(2), torch.linspace(-math.pi, math.pi, 64)
    ray = make_raycaster("exact", grid, angles, 5.0, device="cuda")
    assert isinstance(ray, raycast_cuda.CudaExactRaycaster) and ray.name == "exact"

    def broken(*args, **kwargs):
        raise ImportError("libNVVM cannot be found")

    monkeypatch.setattr(raycast_cuda, "CudaExactRaycaster", broken)
    with pytest.warns(RuntimeWarning, match="numba.cuda unusable .*libNVVM.*using exact-torch"):
        ray = make_raycaster("exact", grid, angles, 5.0, device="cuda")
    assert isinstance(ray, TorchExactRaycaster) and ray.name == "exact"


def test_exact_cuda_refuses_a_cpu_device_outside_the_simulator():
    code = ("import torch; from flashnav.sim.raycast import make_raycaster; from test_raycast import cluttered_map\n"
            "make_raycaster('exact-cuda', cluttered_map(0), torch.zeros(4), 5.0, device='cpu')")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    run = subprocess.run([sys.executable, "-c", code], env=env, cwd=Path(__file__).parent, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode != 0 and "raycaster 'exact-cuda' runs on a CUDA device, not cpu" in run.stderr


if __name__ == "__main__" and sys.argv[1:] == ["simulator"]:
    from flashnav.sim.raycast_cuda import simulated

    assert simulated(), "NUMBA_ENABLE_CUDASIM=1 was not seen"
    problems = compare("cpu", 24, 0.0)  # the same float64 operations in the same order: to the bit
    print("\n".join(problems) if problems else f"{len(scenes(2))} scenes, equal")
    sys.exit(1 if problems else 0)
