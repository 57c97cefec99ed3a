"""Raycasters against a slow, obviously-correct reference: exact ray-vs-closed-square intersection
(slab method, float64, metres) over every occupied square, plus the exit through the map boundary."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.maps.fields import cone_field, safe_field
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.raycast import RAYCASTERS, error_stats, make_raycaster, random_free_poses
from flashnav.sim.raycast_torch import MarchRaycaster, TorchExactRaycaster

TOL = 1e-9  # metres, 'touching' tolerance of the reference (the kernels use 1e-9 cells)


def reference_ranges(grid: OccupancyMap, pose: np.ndarray, angles: np.ndarray, max_range: float) -> np.ndarray:
    """[N, K] float64 metres: the first t >= 0 at which each ray meets a closed occupied square or
    leaves the open map rectangle, clipped to max_range."""
    res, (ox, oy) = grid.resolution, grid.origin
    rows, cols = np.nonzero(grid.occupied)
    x0, y0 = ox + cols * res, oy + rows * res
    x1, y1 = x0 + res, y0 + res
    px = np.repeat(pose[:, 0].astype(np.float64), len(angles))
    py = np.repeat(pose[:, 1].astype(np.float64), len(angles))
    th = (pose[:, 2:3].astype(np.float64) + angles[None, :].astype(np.float64)).reshape(-1)
    dx, dy = np.cos(th), np.sin(th)
    dx[np.abs(dx) < 1e-12] = 0.0  # the documented axis snap
    dy[np.abs(dy) < 1e-12] = 0.0
    out = np.full(px.shape, float(max_range))
    xmin, ymin, xmax, ymax = grid.bounds

    def slab(p, d, lo, hi):  # [R, S] entry/exit of the slab lo <= p + t d <= hi
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (lo - p) / d, (hi - p) / d
        enter, leave = np.minimum(ta, tb), np.maximum(ta, tb)
        par = d == 0
        within = (lo - TOL <= p) & (p <= hi + TOL)
        enter = np.where(par, np.where(within, -np.inf, np.inf), enter)
        leave = np.where(par, np.where(within, np.inf, -np.inf), leave)
        return enter, leave

    chunk = max(1, 2_000_000 // max(1, x0.size))
    for s in range(0, px.size, chunk):
        sl = slice(s, s + chunk)
        p_x, p_y, d_x, d_y = px[sl, None], py[sl, None], dx[sl, None], dy[sl, None]
        if x0.size:
            ex, lx = slab(p_x, d_x, x0[None], x1[None])
            ey, ly = slab(p_y, d_y, y0[None], y1[None])
            enter, leave = np.maximum(ex, ey), np.minimum(lx, ly)
            touched = (enter <= leave + TOL) & (leave >= -TOL)
            hit = np.where(touched, np.maximum(enter, 0.0), np.inf).min(1)
            out[sl] = np.minimum(out[sl], hit)
        # the map boundary: leaving the open rectangle (0 if the origin is not strictly inside)
        _, lx = slab(p_x, d_x, np.array([[xmin]]), np.array([[xmax]]))
        _, ly = slab(p_y, d_y, np.array([[ymin]]), np.array([[ymax]]))
        inside = (p_x > xmin) & (p_x < xmax) & (p_y > ymin) & (p_y < ymax)
        exit_t = np.where(inside, np.minimum(lx, ly), 0.0)[:, 0]
        out[sl] = np.minimum(out[sl], exit_t)
    return out.reshape(len(pose), len(angles))


def cluttered_map(seed: int, shape=(48, 64), res=0.05, origin=(0.0, 0.0), boxes=12, discs=6, noise=0.02):
    rng = np.random.default_rng(seed)
    h, w = shape
    occ = rng.random(shape) < noise
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = rng.random() < 0.5  # sometimes no border wall
    for _ in range(boxes):
        i, j = rng.integers(0, h), rng.integers(0, w)
        occ[i : i + rng.integers(1, 8), j : j + rng.integers(1, 8)] = True
    ii, jj = np.mgrid[:h, :w]
    for _ in range(discs):
        ci, cj, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(1, 5)
        occ |= (ii - ci) ** 2 + (jj - cj) ** 2 < r * r
    return OccupancyMap(occ, res, origin)


def run_all_exact(grid, pose, angles, max_range):
    a = torch.as_tensor(angles, dtype=torch.float32)
    p = torch.as_tensor(pose, dtype=torch.float32)
    ref = reference_ranges(grid, p.double().numpy(), a.double().numpy(), max_range)
    got = {name: make_raycaster(name, grid, a, max_range)(p).double().numpy() for name in ("exact", "exact-torch")}
    return ref, got


def assert_close(ref, got, what):
    for name, r in got.items():
        err = np.abs(r - ref)
        worst = np.unravel_index(err.argmax(), err.shape)
        assert err.max() < 1e-4, f"{what}/{name}: max error {err.max():.3g} m at {worst}: {r[worst]} vs {ref[worst]}"


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_exact_matches_reference_on_random_maps(seed):
    # res 0.05 is not exact in binary and the origin is arbitrary: the generic float path
    grid = cluttered_map(seed, origin=(-1.3 + seed, 0.7))
    rng = np.random.default_rng(100 + seed)
    xmin, ymin, xmax, ymax = grid.bounds
    n = 80  # uniform over (a bit beyond) the map: some origins in walls or off the map
    pose = np.stack([rng.uniform(xmin - 0.1, xmax + 0.1, n), rng.uniform(ymin - 0.1, ymax + 0.1, n),
                     rng.uniform(-math.pi, math.pi, n)], 1)
    angles = np.sort(rng.uniform(-math.pi, math.pi, 40))
    ref, got = run_all_exact(grid, pose, angles, max_range=2.5)
    assert ref.size >= 3200 and (ref == 0).any() and (ref > 0).mean() > 0.5
    assert_close(ref, got, f"seed {seed}")


def test_grid_lines_vertices_and_diagonal_corners():
    # res 0.125 and origin exact in binary: poses exactly on grid lines and vertices, beams exactly
    # along the lines and at 45 degrees through vertices
    rng = np.random.default_rng(7)
    occ = rng.random((32, 32)) < 0.12
    occ[10:12, 5:20] = True
    occ[::4, ::4] = True  # isolated cells: many diagonal corner pairs
    grid = OccupancyMap(occ, 0.125, (-2.0, 1.0))
    ij = rng.integers(1, 32, size=(600, 2)).astype(np.float64)
    frac = rng.choice([0.0, 0.5], size=(600, 2))  # on vertices, on lines, or mid-cell
    x = grid.origin[0] + (ij[:, 1] + frac[:, 1]) * 0.125
    y = grid.origin[1] + (ij[:, 0] + frac[:, 0]) * 0.125
    yaw = rng.integers(0, 4, 600) * (math.pi / 2)
    pose = np.stack([x, y, yaw], 1)
    angles = np.arange(8) * (math.pi / 4)
    ref, got = run_all_exact(grid, pose, angles, max_range=3.0)
    assert_close(ref, got, "grid lines")


def test_diagonal_corner_does_not_leak_and_line_rays_touch_both_sides():
    occ = np.zeros((8, 8), bool)
    occ[3, 3] = occ[4, 4] = True  # diagonal pair sharing the vertex (4, 4) in cells
    occ[6, 1] = True  # a cell just left of the grid line x = 2 cells
    grid = OccupancyMap(occ, 0.25, (0.0, 0.0))
    # from (7, 1) cells going up-left at 135 deg, between the pair through their shared vertex (4, 4)
    pose = torch.tensor([[1.75, 0.25, 3 * math.pi / 4], [0.5, 0.25, math.pi / 2]], dtype=torch.float32)
    for name in ("exact", "exact-torch"):
        r = make_raycaster(name, grid, torch.zeros(1), 10.0)(pose)[:, 0]
        assert r[0] == pytest.approx(math.sqrt(2) * 0.75, abs=1e-5), name
        # along x = 2 cells (0.5 m) upward: touches cell (6, 1) on its left at y = 6 cells
        assert r[1] == pytest.approx(1.5 - 0.25, abs=1e-6), name


def test_origin_inside_on_or_outside_gives_zero():
    occ = np.zeros((10, 10), bool)
    occ[5, 5] = True
    grid = OccupancyMap(occ, 0.1, (1.0, 1.0))
    pose = torch.tensor([[1.55, 1.55, 0.3],  # inside the occupied cell
                         [1.5, 1.52, 2.0],  # on its left edge
                         [1.0, 1.5, 0.0],  # on the map boundary, facing in
                         [0.5, 1.5, 0.0],  # off the map, facing it
                         [5.0, 9.0, 1.0]], dtype=torch.float32)
    for name in ("exact", "exact-torch"):
        r = make_raycaster(name, grid, torch.tensor([0.0, 1.0, -2.0]), 5.0)(pose)
        assert torch.all(r == 0), (name, r)


def test_max_range_on_open_map():
    grid = OccupancyMap(np.zeros((200, 200), bool), 0.25, (0.0, 0.0))  # 50 x 50 m, no obstacles
    rng = np.random.default_rng(3)
    pose = np.stack([rng.uniform(15, 35, 40), rng.uniform(15, 35, 40), rng.uniform(-3, 3, 40)], 1)
    angles = np.linspace(-math.pi, math.pi, 60, endpoint=False)
    ref, got = run_all_exact(grid, pose, angles, max_range=8.0)
    assert (ref == 8.0).all()
    assert_close(ref, got, "open map")
    # and the boundary when max range exceeds the map
    ref, got = run_all_exact(grid, pose, angles, max_range=100.0)
    assert (ref < 100).all()
    assert_close(ref, got, "open map, long range")


def test_exact_torch_equals_exact_on_many_rays():
    grid = cluttered_map(11, shape=(100, 120))
    pose = random_free_poses(grid, 64, 5)
    angles = torch.linspace(-math.pi, math.pi, 361)[:-1]
    a = make_raycaster("exact", grid, angles, 20.0)(pose)
    b = make_raycaster("exact-torch", grid, angles, 20.0)(pose)
    # few lines per round and small batches: many rounds and batch boundaries
    c = TorchExactRaycaster(grid, angles, 20.0, chunk_lines=3, max_batch_rays=5000)(pose)
    assert (a - b).abs().max() < 1e-5 and (a - c).abs().max() < 1e-5


def test_march_within_one_step_of_exact():
    grid = cluttered_map(21, shape=(100, 100), noise=0.0)
    pose = random_free_poses(grid, 64, 2, min_clearance=0.05)
    angles = torch.linspace(-math.pi, math.pi, 361)[:-1]
    exact = make_raycaster("exact", grid, angles, 20.0)(pose)
    march = make_raycaster("march", grid, angles, 20.0, march_step=0.03)(pose)
    diff = march.double() - exact.double()
    # every march sample before the exact range is in free space: it can only overshoot (float32)
    assert diff.min() > -1e-4
    # it overshoots by less than a step unless the ray clips a corner for less than a step, which
    # these maps (1-cell-thin walls, staircase disc edges) make ~1.3 % of beams; measured 98.7 %
    assert (diff < 0.03 + 1e-4).double().mean() > 0.97
    stats = error_stats(march, exact)
    assert 0.005 < stats["mean"] < 0.06 and stats["frac_over_5cm"] < 0.03 and stats["max"] <= 20.0


def one_sample_march(grid: OccupancyMap, pose: torch.Tensor, angles: torch.Tensor, max_range: float,
                     step: float) -> torch.Tensor:
    """The paper's march one sample at a time over all rays (float32, the kernel's arithmetic):
    t = k step for k = 1, 2, ...; the first sample in an occupied cell or off the map gives t."""
    occ = torch.from_numpy(grid.occupied)
    h, w = occ.shape
    ang = pose[:, 2:3] + angles
    c, s = torch.cos(ang).reshape(-1), torch.sin(ang).reshape(-1)
    x = pose[:, 0:1].expand_as(ang).reshape(-1)
    y = pose[:, 1:2].expand_as(ang).reshape(-1)
    out = torch.full_like(x, max_range)
    open_ = torch.ones_like(x, dtype=torch.bool)
    for k in range(1, math.ceil(max_range / step - 1e-9) + 1):
        t = torch.tensor([float(k)]) * step
        col = torch.floor((x + t * c - grid.origin[0]) * (1.0 / grid.resolution)).long()
        row = torch.floor((y + t * s - grid.origin[1]) * (1.0 / grid.resolution)).long()
        off = (col < 0) | (col >= w) | (row < 0) | (row >= h)
        blocked = off | occ[row.clamp(0, h - 1), col.clamp(0, w - 1)]
        new = open_ & blocked
        out[new] = torch.clamp(t, max=max_range).expand_as(out)[new]
        open_ &= ~blocked
    return out.reshape(pose.shape[0], -1)


@pytest.mark.parametrize("chunk_steps,max_batch_rays,growth", [(1, None, 2), (5, 777, 2), (32, None, 1), (32, None, 2),
                                                               (32, 300, 3), (200, None, 1)])
@pytest.mark.parametrize("device", ["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
def test_march_chunking_never_changes_a_range(chunk_steps, max_batch_rays, growth, device):
    grid = cluttered_map(23, shape=(80, 90), noise=0.02)
    pose = torch.cat([random_free_poses(grid, 24, 3),  # and poses off the map and inside walls
                      torch.tensor([[-1.0, 2.0, 0.3], [2.0, 2.0, 1.0], [100.0, 1.0, -2.0]])])
    angles = torch.linspace(-math.pi, math.pi, 91)[:-1]
    ref = one_sample_march(grid, pose, angles, 1.5, 0.03)
    if device != "cpu":  # the device's own cos / sin: its march one sample at a time is the reference
        ref = MarchRaycaster(grid, angles, 1.5, device, step=0.03, chunk_steps=1, chunk_growth=1)(pose.to(device)).cpu()
    march = MarchRaycaster(grid, angles, 1.5, device, step=0.03, chunk_steps=chunk_steps, max_batch_rays=max_batch_rays,
                           chunk_growth=growth)
    assert torch.equal(march(pose.to(device)).cpu(), ref)
    assert (ref < 1.5).any() and (ref == 1.5).any() and (ref <= 0.03).any()


def test_error_stats_on_fixed_data():
    exact = torch.tensor([[1.0, 2.0, 3.0, 4.0]])
    ranges = torch.tensor([[1.0, 2.1, 3.0, 3.96]])
    s = error_stats(ranges, exact)
    assert s["mean"] == pytest.approx(0.035, abs=1e-6)
    assert s["max"] == pytest.approx(0.1, abs=1e-6)
    assert s["frac_over_5cm"] == pytest.approx(0.25)
    assert 0.04 < s["p99"] <= 0.1
    with pytest.raises(ValueError):
        error_stats(ranges, exact[:, :2])


def test_random_free_poses_and_factory():
    grid = cluttered_map(5)
    pose = random_free_poses(grid, 500, 9, min_clearance=0.1)
    assert pose.shape == (500, 3) and pose.dtype == torch.float32
    assert torch.equal(pose, random_free_poses(grid, 500, 9, min_clearance=0.1))
    assert pose[:, 2].abs().max() <= math.pi
    r = make_raycaster("exact", grid, torch.linspace(-math.pi, math.pi, 90), 20.0)(pose)
    assert r.min() >= 0.1 - 1e-5
    with pytest.raises(ValueError, match="exact-torch"):
        make_raycaster("nope", grid, torch.zeros(1), 1.0)
    assert RAYCASTERS == ("exact", "exact-torch", "march", "exact-cuda")
    field = safe_field(grid)
    assert field.shape == (grid.shape[0] + 4, grid.shape[1] + 4)


def test_safe_field_is_a_lower_bound():
    grid = cluttered_map(8, shape=(30, 40))
    field = safe_field(grid)[2:-2, 2:-2].astype(np.float64) * grid.resolution
    pose = random_free_poses(grid, 300, 4).double().numpy()
    rng = np.random.default_rng(0)
    angles = rng.uniform(-math.pi, math.pi, 64)
    ref = reference_ranges(grid, pose, angles, 100.0).min(1)  # ~ distance to the nearest obstacle
    j = np.floor((pose[:, 0] - grid.origin[0]) / grid.resolution).astype(int)
    i = np.floor((pose[:, 1] - grid.origin[1]) / grid.resolution).astype(int)
    assert (field[i, j] <= ref + 1e-9).all()


def test_isotropic_fallback_for_large_maps(monkeypatch):
    # maps over MAX_CONE_CELLS use one sector (the isotropic field): same exact results
    from flashnav.maps import fields

    monkeypatch.setattr(fields, "MAX_CONE_CELLS", 1)
    grid = cluttered_map(31, origin=(0.3, 0.1))
    assert cone_field(grid, 2).shape[0] == 1
    rng = np.random.default_rng(31)
    pose = random_free_poses(grid, 40, 8).double().numpy()
    angles = rng.uniform(-math.pi, math.pi, 50)
    ref, got = run_all_exact(grid, pose, angles, max_range=4.0)
    assert_close(ref, got, "isotropic")


def test_directional_field_is_a_lower_bound():
    # from any point of a cell, a ray in sector s travels at least the field's value before a hit
    grid = cluttered_map(41, shape=(40, 50))
    field = cone_field(grid, 2)
    sectors = field.shape[0]
    rng = np.random.default_rng(41)
    rows, cols = np.nonzero(~grid.occupied)
    k = rng.integers(0, rows.size, 3000)
    frac = rng.random((3000, 2))
    x = grid.origin[0] + (cols[k] + frac[:, 1]) * grid.resolution
    y = grid.origin[1] + (rows[k] + frac[:, 0]) * grid.resolution
    theta = rng.uniform(0, 2 * math.pi, 3000)
    s = np.minimum((theta * sectors / (2 * math.pi)).astype(int), sectors - 1)
    bound = (field[s, rows[k] + 2, cols[k] + 2].astype(np.float64) - 1) * 0.5 * grid.resolution
    assert (field[s, rows[k] + 2, cols[k] + 2] > 0).all() and bound.max() > 0.3
    ref = np.array([reference_ranges(grid, np.array([[xi, yi, ti]]), np.zeros(1), 100.0)[0, 0]
                    for xi, yi, ti in zip(x, y, theta)])
    assert (ref >= bound - 1e-9).all()
    # and it is directional: on average well above the isotropic bound
    iso = safe_field(grid)[rows[k] + 2, cols[k] + 2].astype(np.float64) * grid.resolution
    assert bound.mean() > 1.5 * iso.mean()
