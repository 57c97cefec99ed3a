"""The batched episode sampler of a many-map env (MapSetSampler), against the per-map EpisodeSamplers
as the slow reference: the same per-map distributions (two-sample chi-square tests over many draws),
every sample valid by rules recomputed here (free cells, one component, the band or a counted
fallback), geodesic goals in the band by a plain Dijkstra on maps of different sizes and resolutions."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from scipy import ndimage
from scipy.stats import chi2_contingency

from flashnav.maps.generate import generate_map
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.env import make_env
from flashnav.sim.sampling import MIN_COMPONENT_CELLS, EpisodeSampler, MapSetSampler

from test_sampling import cells, reference_distances, robot, serpentine, walled

CPU = torch.device("cpu")
DRAWS = 20_000  # episodes per map and sampler for the distribution tests
P_MIN = 1e-3  # a feature's two-sample chi-square p-value below this fails (fixed seeds: deterministic)


def split_room() -> OccupancyMap:
    """8 x 4 m with a wall across the middle: two free components, goals never cross the wall."""
    grid = walled(80, 160, 0.05, "split")
    occ = grid.occupied.copy()
    occ[:, 78:82] = True
    return OccupancyMap(occ, 0.05, name="split")


@pytest.fixture(scope="module")
def euclid_maps() -> list[OccupancyMap]:
    """Maps of different sizes, resolutions and origins; "hall30" (30 m at 0.1 m) has many fallbacks."""
    b = generate_map(9.0, 7.0, 0.1, seed=2, name="b")
    return [split_room(), generate_map(6.0, 5.0, 0.05, seed=1, name="a"),
            OccupancyMap(b.occupied, b.resolution, (-3.25, 7.1), "b"),
            generate_map(4.0, 6.0, 0.025, seed=3, name="c"), walled(300, 300, 0.1, "hall30")]


def per_map_samplers(grids, preset) -> list[EpisodeSampler]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # hall30's fallback warning (tested in test_sampling)
        return [EpisodeSampler(g, preset, CPU) for g in grids]


def features(grid: OccupancyMap, pose: torch.Tensor, goal: torch.Tensor, band) -> dict[str, np.ndarray]:
    """Integer bins per episode: start and goal in 0.5 m blocks, the start's place inside its cell
    (the jitter), the straight-line distance (0.25 m), yaw (8 bins), and whether it is outside the band."""
    p, g = pose.double().numpy(), goal.double().numpy()
    ox, oy = grid.origin
    nx = math.ceil(grid.shape[1] * grid.resolution / 0.5)

    def block(xy):
        return np.floor((xy[:, 1] - oy) / 0.5).astype(int) * nx + np.floor((xy[:, 0] - ox) / 0.5).astype(int)

    frac = (p[:, 0] - ox) / grid.resolution
    d = np.linalg.norm(g - p[:, :2], axis=1)
    return {"start": block(p), "goal": block(g), "jitter": np.floor((frac - np.floor(frac)) * 8).astype(int),
            "distance": np.floor(d / 0.25).astype(int), "yaw": np.floor((p[:, 2] + math.pi) / (2 * math.pi) * 8).astype(int),
            "outside": ((d < band[0]) | (d > band[1])).astype(int)}


def same_distribution(a: np.ndarray, b: np.ndarray) -> float:
    """p-value of a two-sample chi-square test on integer samples (bins with < 10 in both dropped)."""
    lo = min(a.min(), b.min())
    ca, cb = np.bincount(a - lo), np.bincount(b - lo)
    size = max(len(ca), len(cb))
    table = np.stack([np.pad(ca, (0, size - len(ca))), np.pad(cb, (0, size - len(cb)))])
    table = table[:, table.sum(axis=0) >= 10]
    if table.shape[1] < 2:
        return 1.0
    return float(chi2_contingency(table)[1])


def batched_draws(sampler: MapSetSampler, num_maps: int, seed: int) -> tuple[torch.Tensor, ...]:
    """DRAWS episodes per map from the batched sampler, the maps interleaved in a shuffled order."""
    gen = torch.Generator().manual_seed(seed)
    maps = torch.arange(num_maps).repeat_interleave(DRAWS)
    maps = maps[torch.randperm(maps.numel(), generator=gen)]
    pose, goal = sampler.sample(maps, gen)
    return maps, pose, goal


@pytest.mark.parametrize("mode", ["euclidean", "geodesic"])
def test_batched_draws_follow_each_maps_own_sampler(euclid_maps, mode):
    grids = euclid_maps if mode == "euclidean" else euclid_maps[:4]  # geodesic: hall30's pairs are slow to build
    preset = robot(mode)
    reference = per_map_samplers(grids, preset)
    batched = MapSetSampler(per_map_samplers(grids, preset))
    maps, pose, goal = batched_draws(batched, len(grids), seed=11)
    band = (batched.d_min, batched.d_max)
    for m, (g, ref) in enumerate(zip(grids, reference)):
        sel = maps == m
        ours = features(g, pose[sel], goal[sel], band)
        theirs = features(g, *ref.sample(DRAWS, torch.Generator().manual_seed(100 + m)), band)
        for name in ours:
            p = same_distribution(ours[name], theirs[name])
            assert p > P_MIN, f"{mode}, map {g.name}: the {name} distribution differs from its sampler's (p = {p:.2g})"
    # the test can tell maps apart: map 1's draws against map 2's sampler fail it (guards against a vacuous test)
    other = features(grids[1], *reference[2].sample(DRAWS, torch.Generator().manual_seed(7)), band)
    assert same_distribution(features(grids[1], pose[maps == 1], goal[maps == 1], band)["distance"],
                             other["distance"]) < 1e-6


def free_components(grid: OccupancyMap, radius: float) -> np.ndarray:
    """[H, W] labels of the 4-connected components of the cells a start may use (0: none), recomputed
    here with the sampler's rule: centre clearance radius + the jitter margin, >= MIN_COMPONENT_CELLS."""
    labels, count = ndimage.label(grid.free_space(radius + grid.resolution * math.sqrt(0.5)))
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    keep = sizes >= MIN_COMPONENT_CELLS
    keep[0] = False
    return np.where(keep[labels], labels, 0)


def test_every_batched_euclidean_episode_is_valid_and_fallbacks_are_counted_per_map(euclid_maps):
    preset = robot()
    batched = MapSetSampler(per_map_samplers(euclid_maps, preset))
    maps, pose, goal = batched_draws(batched, len(euclid_maps), seed=3)
    for m, g in enumerate(euclid_maps):
        sel = maps == m
        labels = free_components(g, preset.footprint.circumscribed_radius + preset.episode.start_clearance)
        a = cells(g, pose[sel, :2].double().numpy())
        b = cells(g, goal[sel].double().numpy())
        la, lb = labels.reshape(-1)[a], labels.reshape(-1)[b]
        assert (la > 0).all() and (lb > 0).all(), f"map {g.name}: a start or goal outside the free space"
        assert (la == lb).all(), f"map {g.name}: a goal in another component than its start"
        d = torch.linalg.vector_norm(goal[sel] - pose[sel, :2], dim=1)
        outside = int(((d < batched.d_min) | (d > batched.d_max)).sum())
        assert int(batched.out_of_band[m]) == outside, f"map {g.name}: fallbacks miscounted"
        assert (pose[sel, 2] >= -math.pi).all() and (pose[sel, 2] < math.pi).all()
    assert int(batched.out_of_band[4]) > DRAWS // 50 and int(batched.out_of_band[:4].sum()) < DRAWS // 100
    # the split room: both sides are used, and no episode crosses the wall
    sel = maps == 0
    left = pose[sel, 0] < 3.9
    assert 0.3 < float(left.float().mean()) < 0.7
    assert torch.equal(left, goal[sel, 0] < 3.9)


def test_geodesic_goals_of_the_batched_sampler_are_in_the_band_by_a_reference_dijkstra():
    grids = [serpentine(0.025), walled(90, 120, 0.1, "room12x9"), generate_map(7.0, 6.0, 0.05, seed=5, name="g5")]
    preset = robot("geodesic")
    batched = MapSetSampler(per_map_samplers(grids, preset))
    gen = torch.Generator().manual_seed(2)
    maps = torch.randint(len(grids), (600,), generator=gen)
    pose, goal = batched.sample(maps, gen)
    radius = preset.footprint.circumscribed_radius + preset.episode.start_clearance
    for m, g in enumerate(grids):
        sel = maps == m
        free = g.free_space(radius + g.resolution * math.sqrt(0.5))
        a, b = cells(g, pose[sel, :2].double().numpy()), cells(g, goal[sel].double().numpy())
        assert free.reshape(-1)[a].all() and free.reshape(-1)[b].all(), f"map {g.name}: a cell outside the free space"
        d = reference_distances(free, g.resolution, a, b, limit=6.0)
        assert d.min() >= batched.d_min - 1e-9 and d.max() <= batched.d_max + 1e-9, (g.name, d.min(), d.max())
    assert int(batched.out_of_band.sum()) == 0


def test_per_map_samplers_count_into_the_batched_counter(euclid_maps):
    samplers = per_map_samplers(euclid_maps[-2:], robot())
    batched = MapSetSampler(samplers)
    gen = torch.Generator().manual_seed(0)
    batched.sample(torch.ones(500, dtype=torch.long), gen)
    before = int(batched.out_of_band[1])
    assert before > 0 and int(samplers[1].out_of_band) == before
    samplers[1].sample(100, gen)  # the per-map path (eval_maps' fixed episodes) counts in the same place
    assert int(batched.out_of_band[1]) == int(samplers[1].out_of_band) > before


def test_samplers_of_different_episode_presets_are_refused(euclid_maps):
    a = per_map_samplers(euclid_maps[1:2], robot())[0]
    b = per_map_samplers(euclid_maps[1:2], robot("euclidean", **{"episode.max_goal_distance": 4.0}))[0]
    with pytest.raises(ValueError, match=r"samplers\[1\] has mode 'euclidean', band 1-4 m"):
        MapSetSampler([a, b])
    with pytest.raises(ValueError, match="got none"):
        MapSetSampler([])


def test_many_map_env_resets_through_the_batched_sampler(euclid_maps):
    env = make_env("turtlebot2", 256, maps=euclid_maps[1:4], seed=5)
    env.reset(seed=5)
    again = make_env("turtlebot2", 256, maps=euclid_maps[1:4], seed=5)
    again.reset(seed=5)
    assert torch.equal(env.pose, again.pose) and torch.equal(env.goal, again.goal)  # seeded
    for m, g in enumerate(env.frame_maps):
        sel = env.map_index == m
        labels = free_components(g, env.samplers[m].radius)
        a = cells(g, env.pose[sel, :2].double().numpy())
        b = cells(g, env.goal[sel].double().numpy())
        assert (labels.reshape(-1)[a] > 0).all() and (labels.reshape(-1)[a] == labels.reshape(-1)[b]).all()


@pytest.mark.parametrize("mode", ["euclidean", "geodesic"])
def test_per_map_samplers_draw_the_same_episodes_once_their_tables_are_shared(euclid_maps, mode):
    # eval_maps' fixed episodes come from the per-map samplers: viewing their tables inside the
    # concatenated ones must leave their draws bit for bit as they were
    samplers = per_map_samplers(euclid_maps[1:4], robot(mode))
    before = [s.sample(300, torch.Generator().manual_seed(m)) for m, s in enumerate(samplers)]
    batched = MapSetSampler(samplers)
    for m, s in enumerate(samplers):
        pose, goal = s.sample(300, torch.Generator().manual_seed(m))
        assert torch.equal(pose, before[m][0]) and torch.equal(goal, before[m][1])
        assert s.centres.untyped_storage().data_ptr() == batched.centres.untyped_storage().data_ptr()
