"""Footprint collision against a brute-force geometric reference over every occupied square.

The reference is formulated independently of the implementation's separating-axis / clamped
distance tests: the disc overlaps a square if its centre is strictly inside it, a corner is strictly
within r, or an edge passes strictly within r with its foot inside the edge; the rectangle overlaps
a square if a corner of either lies strictly inside the other (orientation signs), two edges cross
properly, or a centre lies strictly inside the other. (For positive-area overlap this misses only
exactly collinear edge configurations, which random poses never produce.)"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.config import Footprint
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.collision import make_collision_checker

DISC = Footprint(kind="disc", radius=0.2)
RECT = Footprint(kind="rectangle", length=0.8, width=0.41)


def squares(grid):
    rows, cols = np.nonzero(grid.occupied)
    x0 = grid.origin[0] + cols * grid.resolution
    y0 = grid.origin[1] + rows * grid.resolution
    return x0, y0, x0 + grid.resolution, y0 + grid.resolution


def ref_disc(grid, pose, r):
    x0, y0, x1, y1 = squares(grid)
    px, py = pose[:, 0:1], pose[:, 1:2]
    inside = (px > x0) & (px < x1) & (py > y0) & (py < y1)
    corner = np.zeros_like(inside)
    for cx in (x0, x1):
        for cy in (y0, y1):
            corner |= (px - cx) ** 2 + (py - cy) ** 2 < r * r
    # edges: the foot of the perpendicular within the edge's open span, distance < r
    edge = ((px > x0) & (px < x1) & ((np.abs(py - y0) < r) | (np.abs(py - y1) < r)))
    edge |= ((py > y0) & (py < y1) & ((np.abs(px - x0) < r) | (np.abs(px - x1) < r)))
    hit = (inside | corner | edge).any(1) if x0.size else np.zeros(len(pose), bool)
    xmin, ymin, xmax, ymax = grid.bounds
    out = (pose[:, 0] - r < xmin) | (pose[:, 0] + r > xmax) | (pose[:, 1] - r < ymin) | (pose[:, 1] + r > ymax)
    return hit | out


def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def _strictly_in_ccw(poly, qx, qy):
    """poly: list of 4 CCW corners (each (x, y) arrays broadcastable); q strictly inside."""
    ok = True
    for k in range(4):
        (ax, ay), (bx, by) = poly[k], poly[(k + 1) % 4]
        ok = ok & (_orient(ax, ay, bx, by, qx, qy) > 0)
    return ok


def ref_rect(grid, pose, length, width):
    x0, y0, x1, y1 = squares(grid)
    n = len(pose)
    px, py, th = pose[:, 0:1], pose[:, 1:2], pose[:, 2:3]
    c, s = np.cos(th), np.sin(th)
    hl, hw = length / 2, width / 2
    rect = [(px + c * ex - s * ey, py + s * ex + c * ey) for ex, ey in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]
    sq = [(x1, y0), (x1, y1), (x0, y1), (x0, y0)]  # CCW
    hit = np.zeros((n, x0.size), bool)
    for qx, qy in sq:
        hit |= _strictly_in_ccw(rect, qx, qy)
    for rx, ry in rect:
        hit |= _strictly_in_ccw(sq, rx, ry)
    hit |= _strictly_in_ccw(rect, (x0 + x1) / 2, (y0 + y1) / 2)
    hit |= _strictly_in_ccw(sq, px, py)
    for k in range(4):
        (ax, ay), (bx, by) = rect[k], rect[(k + 1) % 4]
        for m in range(4):
            (cx, cy), (dx, dy) = sq[m], sq[(m + 1) % 4]
            hit |= ((_orient(ax, ay, bx, by, cx, cy) * _orient(ax, ay, bx, by, dx, dy) < 0)
                    & (_orient(cx, cy, dx, dy, ax, ay) * _orient(cx, cy, dx, dy, bx, by) < 0))
    xmin, ymin, xmax, ymax = grid.bounds
    xs = np.concatenate([r[0] for r in rect], 1)
    ys = np.concatenate([r[1] for r in rect], 1)
    out = (xs.min(1) < xmin) | (xs.max(1) > xmax) | (ys.min(1) < ymin) | (ys.max(1) > ymax)
    return hit.any(1) | out


def clutter(seed, shape=(60, 70), res=0.05, origin=(0.4, -0.7)):
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < 0.002
    for _ in range(6):
        i, j = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        occ[i : i + rng.integers(1, 6), j : j + rng.integers(1, 6)] = True
    return OccupancyMap(occ, res, origin)


def poses_near_walls(grid, n, rng, spread):
    """Half near occupied cells (within `spread` metres), a quarter uniform over the map, a quarter
    around the map boundary (some entirely off the map)."""
    rows, cols = np.nonzero(grid.occupied)
    k = rng.integers(0, rows.size, n // 2)
    cx, cy = grid.cell_centres(rows[k], cols[k])
    near = np.stack([cx + rng.uniform(-spread, spread, k.size), cy + rng.uniform(-spread, spread, k.size)], 1)
    xmin, ymin, xmax, ymax = grid.bounds
    uni = np.stack([rng.uniform(xmin, xmax, n // 4), rng.uniform(ymin, ymax, n // 4)], 1)
    m = n - near.shape[0] - uni.shape[0]
    edge_y = rng.choice([ymin, ymax], m) + rng.uniform(-0.6, 0.6, m)
    edge = np.stack([rng.uniform(xmin - 0.5, xmax + 0.5, m), edge_y], 1)
    xy = np.concatenate([near, uni, edge])
    return np.concatenate([xy, rng.uniform(-math.pi, math.pi, (n, 1))], 1)


@pytest.mark.parametrize("prefilter", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_disc_matches_reference(seed, prefilter):
    grid = clutter(seed)
    rng = np.random.default_rng(10 + seed)
    pose = poses_near_walls(grid, 3000, rng, spread=0.3)
    pose32 = torch.tensor(pose, dtype=torch.float32)
    ref = ref_disc(grid, pose32.double().numpy(), DISC.radius)
    got = make_collision_checker(DISC, grid, "cpu", prefilter=prefilter)(pose32).numpy()
    assert 0.2 < ref.mean() < 0.8
    bad = np.nonzero(got != ref)[0]
    assert bad.size == 0, f"{bad.size} mismatches, e.g. pose {pose32[bad[0]].tolist()}: got {got[bad[0]]}"


@pytest.mark.parametrize("prefilter", [True, False])
@pytest.mark.parametrize("seed", [2, 3])
def test_rectangle_matches_reference(seed, prefilter):
    grid = clutter(seed)
    rng = np.random.default_rng(20 + seed)
    pose = poses_near_walls(grid, 2000, rng, spread=0.5)
    pose32 = torch.tensor(pose, dtype=torch.float32)
    ref = ref_rect(grid, pose32.double().numpy(), RECT.length, RECT.width)
    got = make_collision_checker(RECT, grid, "cpu", prefilter=prefilter)(pose32).numpy()
    assert 0.2 < ref.mean() < 0.95
    bad = np.nonzero(got != ref)[0]
    assert bad.size == 0, f"{bad.size} mismatches, e.g. pose {pose32[bad[0]].tolist()}: got {got[bad[0]]}"


def test_touching_is_not_a_collision_and_any_overlap_is():
    # binary-exact geometry: one occupied cell [1.0, 1.25] x [1.0, 1.25] in a 4 x 4 m map
    occ = np.zeros((16, 16), bool)
    occ[4, 4] = True
    grid = OccupancyMap(occ, 0.25, (0.0, 0.0))
    disc = make_collision_checker(Footprint(kind="disc", radius=0.5), grid)
    p = torch.tensor([[0.5, 1.125, 0.0],  # touches the cell's left edge
                      [0.5 + 1e-6, 1.125, 0.0],  # overlaps by 1e-6
                      [1.125, 2.0, 1.0],  # touches the top edge from above (any yaw)
                      [0.5, 2.0, 0.0],  # near the corner (1.0, 1.25): distance 0.901
                      [3.5, 2.0, 0.0],  # touches the map's right boundary
                      [3.5 + 1e-6, 2.0, 0.0]], dtype=torch.float64)
    assert disc(p).tolist() == [False, True, False, False, False, True]
    rect = make_collision_checker(Footprint(kind="rectangle", length=1.0, width=0.5), grid)
    q = torch.tensor([[0.5, 1.125, 0.0],  # front edge x = 1.0 touches the cell
                      [0.5 + 1e-6, 1.125, 0.0],
                      [1.125, 0.5, math.pi / 2],  # along +y, front edge at y = 1.0
                      [1.125, 0.5 + 1e-6, math.pi / 2],
                      [0.5, 0.25, 0.0],  # bottom edge on the map boundary: inside
                      [0.5, 0.25 - 1e-6, 0.0],
                      [20.0, 20.0, 0.3]], dtype=torch.float64)  # far off the map
    assert rect(q).tolist() == [False, True, False, True, False, True, True]


def test_free_map_and_shapes():
    grid = OccupancyMap(np.zeros((40, 40), bool), 0.05, (0.0, 0.0))
    pose = torch.tensor([[1.0, 1.0, 0.3], [0.1, 1.0, 0.0], [1.0, 1.79, 1.57]])
    for fp in (DISC, RECT):
        out = make_collision_checker(fp, grid)(pose)
        assert out.dtype == torch.bool and out.shape == (3,)
        assert out[0].item() is False and out[1].item() is True
    assert make_collision_checker(RECT, grid)(torch.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError):
        make_collision_checker(DISC, grid)(torch.zeros(3))
