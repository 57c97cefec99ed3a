"""Start/goal sampling: the paper task's episodes pinned bit for bit; the euclidean band's fallbacks
counted and reported; geodesic goals inside the band by path length, against a plain Dijkstra."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from flashnav.config import RobotPreset
from flashnav.maps.grid import OccupancyMap
from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.sampling import EpisodeSampler

FIXTURES = Path(__file__).parent / "fixtures"


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_default_sampling_on_the_bundled_maps_is_unchanged(robot):
    # tests/fixtures/bundled_episodes.npz was written by main at 86fe09a (before goal_sampling existed):
    # env.reset(seed=3) with 256 slots, then sampler.sample(1000 / 7 / 1) from a generator seeded 0.
    saved = np.load(FIXTURES / "bundled_episodes.npz")
    env = make_env(robot, 256, seed=3)
    assert env.preset.episode.goal_sampling == "euclidean"
    env.reset(seed=3)
    np.testing.assert_array_equal(env.pose.numpy(), saved[f"{robot}_reset_pose"])
    np.testing.assert_array_equal(env.goal.numpy(), saved[f"{robot}_reset_goal"])
    gen = torch.Generator().manual_seed(0)
    for k, n in enumerate((1000, 7, 1)):
        pose, goal = env.sampler.sample(n, gen)
        np.testing.assert_array_equal(pose.numpy(), saved[f"{robot}_sample{k}_pose"])
        np.testing.assert_array_equal(goal.numpy(), saved[f"{robot}_sample{k}_goal"])
    assert int(env.sampler.out_of_band) == 0


# ---- helpers: maps and a reference geodesic distance ---------------------------------------------------


def robot(mode: str = "euclidean", **overrides) -> RobotPreset:
    return load_robot("turtlebot2", **{"episode.goal_sampling": mode, **overrides})


def walled(rows: int, cols: int, res: float, name: str) -> OccupancyMap:
    occ = np.zeros((rows, cols), dtype=bool)
    occ[:2], occ[-2:], occ[:, :2], occ[:, -2:] = True, True, True, True
    return OccupancyMap(occ, res, name=name)


def serpentine(res: float = 0.025) -> OccupancyMap:
    """8 x 6 m of parallel corridors joined at alternate ends, each just wide enough for the
    TurtleBot2 at its start clearance (0.72 m: a 0.3 m disc, the jitter margin and a few cells)."""
    corridor, wall = 0.72, 0.1
    grid = walled(round(6 / res), round(8 / res), res, "serpentine")
    occ = grid.occupied.copy()
    x, k = 0.05 + corridor, 0
    while x + wall < 8 - 0.05 - corridor:
        j0, j1 = round(x / res), round((x + wall) / res)
        if k % 2:
            occ[round((0.05 + corridor) / res):, j0:j1] = True  # open at the bottom
        else:
            occ[: round((6 - 0.05 - corridor) / res), j0:j1] = True  # open at the top
        x, k = x + wall + corridor, k + 1
    return OccupancyMap(occ, res, name="serpentine")


def reference_distances(free: np.ndarray, res: float, starts: np.ndarray, goals: np.ndarray, limit: float):
    """Plain Dijkstra over the 8-connected free cells (a diagonal step needs both cells beside it free),
    one start at a time: the geodesic distance (m) from each start cell to its goal cell [K]."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    h, w = free.shape
    src, dst, length = [], [], []
    rows, cols = np.nonzero(free)
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1), (0, -1), (-1, 0), (-1, -1), (-1, 1)):
        r2, c2 = rows + dr, cols + dc
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        ok[ok] = free[r2[ok], c2[ok]] & free[rows[ok], c2[ok]] & free[r2[ok], cols[ok]]
        src.append(rows[ok] * w + cols[ok]), dst.append(r2[ok] * w + c2[ok])
        length.append(np.full(ok.sum(), math.hypot(dr, dc) * res))
    graph = csr_matrix((np.concatenate(length), (np.concatenate(src), np.concatenate(dst))), shape=(h * w,) * 2)
    out = np.empty(len(starts))
    for k, (s, g) in enumerate(zip(starts, goals)):
        out[k] = dijkstra(graph, indices=int(s), limit=limit)[g]
    return out


def cells(grid: OccupancyMap, xy: np.ndarray) -> np.ndarray:
    """Flat indices [K] of the cells holding points xy [K, 2] (m)."""
    j = np.floor((xy[:, 0] - grid.origin[0]) / grid.resolution).astype(int)
    i = np.floor((xy[:, 1] - grid.origin[1]) / grid.resolution).astype(int)
    return i * grid.shape[1] + j


# ---- euclidean mode: honest about its band -------------------------------------------------------------


def test_euclidean_fallbacks_are_counted_and_reported_once_per_map():
    room = walled(1000, 1000, 0.1, "hall100")  # 100 x 100 m: most starts find no goal 1-5 m away
    with pytest.warns(RuntimeWarning, match=r"map 'hall100': \d+ of 4096 sampled episodes .* outside the band"):
        sampler = EpisodeSampler(room, robot(), torch.device("cpu"))
    pose, goal = sampler.sample(2048, torch.Generator().manual_seed(1))
    d = torch.linalg.vector_norm(goal - pose[:, :2], dim=1)
    outside = int(((d < 1.0) | (d > 5.0)).sum())
    assert int(sampler.out_of_band) == outside > 1000  # the straight-line recount, and it is most of them
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        EpisodeSampler(room, robot(), torch.device("cpu"))  # the same map again: no second warning


@pytest.mark.parametrize("mode", ["euclidean", "geodesic"])
def test_a_map_where_the_band_is_unreachable_is_refused_by_name(mode):
    closet = walled(30, 30, 0.05, "closet")  # 1.5 m square: the robot's centre has 0.5 m to move in
    with pytest.raises(ValueError, match=r"map 'closet': no (start found a goal|start-goal pair)"):
        EpisodeSampler(closet, robot(mode), torch.device("cpu"))


# ---- geodesic mode ---------------------------------------------------------------------------------------


def test_geodesic_goals_in_an_empty_100m_room_are_in_the_band():
    # no obstacle between any two cells: the grid geodesic is the octile distance, in closed form
    room = walled(1000, 1000, 0.1, "hall100")
    sampler = EpisodeSampler(room, robot("geodesic"), torch.device("cpu"))
    pose, goal = sampler.sample(4096, torch.Generator().manual_seed(0))
    a, b = cells(room, pose[:, :2].double().numpy()), cells(room, goal.double().numpy())
    di, dj = np.abs(a // 1000 - b // 1000), np.abs(a % 1000 - b % 1000)
    octile = (np.maximum(di, dj) + (math.sqrt(2) - 1) * np.minimum(di, dj)) * 0.1
    assert octile.min() >= 1.0 - 1e-9 and octile.max() <= 5.0 + 1e-9
    assert int(sampler.out_of_band) == 0
    # and they spread over the band, not only its ends
    assert np.histogram(octile, bins=4, range=(1, 5))[0].min() > 200


def geodesic_maps():
    from flashnav.maps.families import generate_family
    from flashnav.names import MAP_FAMILIES

    yield serpentine()
    for family in MAP_FAMILIES:
        yield generate_family(family, 3, size=(14.0, 11.0), resolution=0.05)


@pytest.mark.parametrize("grid", list(geodesic_maps()), ids=lambda g: g.name)
def test_geodesic_goals_are_in_the_band_by_a_reference_dijkstra(grid):
    preset = robot("geodesic")
    sampler = EpisodeSampler(grid, preset, torch.device("cpu"))
    pose, goal = sampler.sample(300, torch.Generator().manual_seed(2))
    free = grid.free_space(sampler.radius + grid.resolution * math.sqrt(0.5))
    a, b = cells(grid, pose[:, :2].double().numpy()), cells(grid, goal.double().numpy())
    assert free.reshape(-1)[a].all() and free.reshape(-1)[b].all()
    d = reference_distances(free, grid.resolution, a, b, limit=6.0)
    assert d.min() >= 1.0 - 1e-9 and d.max() <= 5.0 + 1e-9, (d.min(), d.max())


def test_geodesic_band_is_capped_by_what_the_horizon_allows():
    grid = serpentine(0.05)
    short = EpisodeSampler(grid, robot("geodesic", **{"episode.horizon": 60}), torch.device("cpu"))
    assert (short.d_min, short.d_max) == (1.0, pytest.approx(1.5))  # 0.5 x 60 steps x 0.1 s x 0.5 m/s
    with pytest.raises(ValueError, match=r"robot 'turtlebot2': episode.min_goal_distance 1 m .* horizon 30"):
        EpisodeSampler(grid, robot("geodesic", **{"episode.horizon": 30}), torch.device("cpu"))


def test_geodesic_sampling_is_reproducible():
    grid = serpentine(0.05)
    runs = [EpisodeSampler(grid, robot("geodesic"), torch.device("cpu")).sample(64, torch.Generator().manual_seed(s))
            for s in (4, 4, 5)]
    assert torch.equal(runs[0][0], runs[1][0]) and torch.equal(runs[0][1], runs[1][1])
    assert not torch.equal(runs[0][1], runs[2][1])
