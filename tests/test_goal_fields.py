"""Geodesic progress (reward.progress_metric = geodesic, flashnav.sim.goal_fields): the fields against a
reference Dijkstra, goals on the sources, the reward's telescoping sum, walls, and the paper's path
left alone."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.maps.fields import free_space
from flashnav.maps.grid import OccupancyMap
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv
from flashnav.maps.geodesic_numba import map_fields
from flashnav.sim.goal_fields import MARGIN_M, EpisodeGoalFields, evaluation_preset, source_fields
from flashnav.sim.sampling import GOAL_INSIDE, EpisodeSampler
from test_sampling import cells, reference_distances, robot, serpentine, walled

GEO = {"reward.progress_metric": "geodesic"}


def geo_robot(**overrides):
    return robot("geodesic", **GEO, **overrides)


def blocked_room(res: float = 0.05) -> OccupancyMap:
    """8 x 6 m with a wall across the middle (x = 4 m) from the bottom up to y = 5 m: the only way from
    the left half to the right is round its top end."""
    grid = walled(round(6 / res), round(8 / res), res, "blocked")
    occ = grid.occupied.copy()
    occ[: round(5 / res), round(3.95 / res): round(4.05 / res)] = True
    return OccupancyMap(occ, res, name="blocked")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_source_fields_equal_a_reference_dijkstra_on_random_maps(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((40, 50)) < 0.25
    grid = OccupancyMap(occ, 0.1, name=f"random{seed}")
    radius = 0.04  # below half a cell: the free space is the map's free cells
    free = free_space(grid, radius)
    sources = rng.choice(np.flatnonzero(free), size=4, replace=False)
    table, reach = source_fields(grid, sources, radius, bound_m=1.5)
    side = 2 * reach + 1
    assert table.shape == (4, side, side) and table.dtype == np.float16
    h, w = grid.shape
    for k, s in enumerate(sources):
        si, sj = divmod(int(s), w)
        for i in range(side):
            for j in range(side):
                r, c = si - reach + i, sj - reach + j
                if not (0 <= r < h and 0 <= c < w):
                    assert math.isinf(table[k, i, j])
                    continue
                ref = reference_distances(free, 0.1, np.array([s]), np.array([r * w + c]), limit=np.inf)[0]
                want = ref if ref <= 1.5 + 1e-9 else math.inf
                got = float(table[k, i, j])
                assert (math.isinf(got) and math.isinf(want)) or abs(got - want) < 2e-3, (k, i, j, got, want)


def test_every_geodesic_goal_sits_on_a_source_and_keeps_the_band():
    grid = serpentine(0.05)
    env = NavVecEnv(geo_robot(), 256, grid=grid, seed=3)
    env.reset(seed=3)
    assert (env.shaping.source >= 0).all()
    # the straight-line sampler's pairs played from their source end: still in the band by path length
    sampler = env.sampler
    free = grid.free_space(sampler.radius + grid.resolution * math.sqrt(0.5))
    a, b = cells(grid, env.pose[:, :2].double().numpy()), cells(grid, env.goal.double().numpy())
    d = reference_distances(free, grid.resolution, a, b, limit=6.0)
    assert d.min() >= 1.0 - 1e-9 and d.max() <= 5.0 + 1e-9
    # and the field's distance at the start is that path length (through the disc's free space, which
    # is wider than the start cells' space, so never longer), up to the start's jitter in its cell
    start = env.shaping.distance
    assert (start <= torch.as_tensor(d, dtype=torch.float32) + grid.resolution).all()
    assert (start >= torch.as_tensor(d, dtype=torch.float32) - 0.1 * torch.as_tensor(d) - grid.resolution).all()
    assert (start >= env.goal_distance - grid.resolution).all()  # the goal too is jittered in its cell


def test_multimap_slots_get_their_own_maps_sources():
    grids = [serpentine(0.05), blocked_room(0.05)]
    env = NavVecEnv(geo_robot(), 128, grid=grids, seed=1)
    env.reset(seed=1)
    fields = env.shaping.fields
    src = env.shaping.source
    assert (src >= 0).all()
    first_of_second = int((fields.lookup[: grids[0].shape[0] * grids[0].shape[1]] >= 0).sum())
    on_second = env.map_index == 1
    assert on_second.any() and (~on_second).any()
    assert (src[on_second] >= first_of_second).all() and (src[~on_second] < first_of_second).all()


def test_a_wall_between_robot_and_goal_counts_the_way_round():
    grid = blocked_room(0.05)
    env = NavVecEnv(geo_robot(), 1, grid=grid, seed=0)
    fields = env.shaping.fields
    # a goal source left of the wall and low down; the point across the wall at its height
    centres = env.sampler.centres[torch.unique(env.sampler.pair_start)]
    low_left = (centres[:, 0] > 2.5) & (centres[:, 0] < 3.6) & (centres[:, 1] > 1.0) & (centres[:, 1] < 3.0)
    assert low_left.any()
    goal = centres[low_left][0]
    source = fields.ids(goal[None], None)
    assert int(source) >= 0
    near = fields.distance(goal[None] + torch.tensor([[0.0, 0.5]]), source, None, torch.zeros(1))
    assert float(near) == pytest.approx(0.5, abs=0.03)  # open floor: the straight line
    x, y = float(goal[0]), float(goal[1])
    across = torch.tensor([[8.0 - x, y]])
    straight = 8.0 - 2 * x
    d = float(fields.distance(across, source, None, torch.zeros(1)))
    over_the_end = 2 * math.hypot(4.0 - x, 5.0 - y)  # no path is shorter than over the wall's end at y = 5 m
    assert d >= min(over_the_end, fields.bound) - 0.05 and d > straight + 2.0
    # the environment pays the detour: the same step towards the wall (and the goal behind it) earns the
    # straight-line reward its full closing distance and the geodesic one at most what it gains on the
    # way round the wall's end
    pose = torch.tensor([[8.0 - x + 0.3, y, math.pi]], dtype=torch.float64)
    action = torch.tensor([[1.0, 0.0]])  # full speed towards the wall
    rewards = []
    for preset in (geo_robot(), robot("geodesic")):
        e = NavVecEnv(preset, 1, grid=grid, seed=0)
        e.set_state(pose, goal[None].double())
        assert e.shaping.fields is None or int(e.shaping.source[0]) == int(source)
        _, reward, term, _, _ = e.step(action)
        assert not bool(term)
        rewards.append(float(reward))
    geodesic, straight_line = rewards
    gained = 0.3 - float(e.goal_distance[0] - (8.0 - 2 * x))  # straight-line distance closed by the step
    assert straight_line == pytest.approx(e.preset.reward.progress * gained, rel=1e-3) and straight_line > 0.05
    assert geodesic < 0.5 * straight_line


@pytest.mark.parametrize("c", [1.0, 0.9])
def test_progress_rewards_telescope_to_the_path_length_gained(c):
    """c = reward.progress_discount: the discounted sum telescopes to progress (d_0 - c^T d_T) (c = 1: the path
    length gained)."""
    grid = blocked_room(0.05)
    env = NavVecEnv(geo_robot(**{"reward.progress_discount": c}), 64, grid=grid, seed=5)
    env.reset(seed=5)
    d0 = env.shaping.distance.clone()
    total = torch.zeros(64)
    alive = torch.ones(64, dtype=torch.bool)
    gen = torch.Generator().manual_seed(0)
    for t in range(30):
        actions = torch.rand(64, 2, generator=gen) * 2 - 1
        _, reward, term, trunc, info = env.step(actions)
        ended = term | trunc
        total += torch.where(alive & ~ended, reward * c ** t, torch.zeros(64))
        d_last = torch.where(alive & ~ended, env.shaping.distance, torch.zeros(64))
        alive &= ~ended
        if alive.any():
            d_alive = env.shaping.distance
    assert alive.sum() > 10
    k = env.preset.reward.progress
    assert torch.allclose(total[alive], k * (d0[alive] - c ** 30 * d_alive[alive]), atol=1e-3)
    assert (env.shaping.distance <= MARGIN_M + env.sampler.d_max + 1e-5).all()
    del d_last


def test_geodesic_progress_with_straight_line_sampling_needs_one_map_and_evaluations_play_the_task():
    with pytest.raises(ValueError, match=r"euclidean computes each episode's field on its one map; this env has 2 maps"):
        NavVecEnv(robot("euclidean", **GEO), 8, grid=[serpentine(0.05), blocked_room(0.05)], seed=0)
    preset = geo_robot()
    plain = robot("geodesic")
    assert evaluation_preset(preset).reward == plain.reward and evaluation_preset(plain) is plain
    assert evaluation_preset(geo_robot(**{"reward.progress_discount": 0.99})).reward == plain.reward
    # the evaluation preset draws exactly the episodes of the plain geodesic task
    grid = serpentine(0.05)
    a = EpisodeSampler(grid, evaluation_preset(preset), torch.device("cpu")).sample(64, torch.Generator().manual_seed(7))
    b = EpisodeSampler(grid, plain, torch.device("cpu")).sample(64, torch.Generator().manual_seed(7))
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_the_default_reward_is_the_papers_straight_line():
    env = NavVecEnv(robot("geodesic"), 32, grid=serpentine(0.05), seed=2)
    assert env.shaping.fields is None
    env.reset(seed=2)
    before = env.goal_distance.clone()
    _, reward, term, _, _ = env.step(torch.zeros(32, 2))
    live = ~term
    assert torch.allclose(reward[live], 2.0 * (before[live] - env.goal_distance[live]))


def test_fixed_evaluation_sets_play_the_tasks_episodes_with_the_papers_reward():
    from flashnav.eval_maps import EvalSet

    grids = [serpentine(0.05), blocked_room(0.05)]
    trained = EvalSet(geo_robot(), grids, 32, seed=3)
    plain = EvalSet(robot("geodesic"), grids, 32, seed=3)
    assert trained.env.shaping.fields is None and trained.env.preset.reward == plain.env.preset.reward
    assert torch.equal(trained.pose, plain.pose) and torch.equal(trained.goal, plain.goal)


def test_replacing_the_maps_rebuilds_the_fields_for_the_new_maps():
    env = NavVecEnv(geo_robot(), 32, grid=serpentine(0.05), seed=4)
    env.reset(seed=4)
    first = env.shaping.fields
    env.replace_maps(blocked_room(0.05))
    assert env.shaping.fields is not first and (env.shaping.source >= 0).all()
    expect = env.shaping.fields.distance(env.pose[:, :2].float(), env.shaping.source, None, env.goal_distance)
    assert torch.allclose(env.shaping.distance, expect)
    assert (env.shaping.distance >= env.goal_distance - 0.05).all()  # a path is never shorter than the line


def test_flashnav_eval_plays_a_geodesic_progress_policy_on_the_task_with_the_papers_reward(tmp_path):
    import argparse

    from test_export import random_actor

    from flashnav.export import export_policy
    from flashnav.policy_cli import load_policy_for

    trained = load_robot("turtlebot2", **{"episode.goal_sampling": "geodesic", "reward.progress_metric": "geodesic"})
    paths = export_policy(random_actor(trained), trained, tmp_path / "policy", onnx=False)
    args = argparse.Namespace(policy=str(paths["torchscript"]), robot=None, episodes=4)
    _, meta, robot, _ = load_policy_for(args)
    assert meta["preset"]["reward"]["progress_metric"] == "geodesic"  # the export records what it trained with
    assert robot.reward.progress_metric == "euclidean" and robot.episode.goal_sampling == "geodesic"


def test_goals_near_their_cells_edges_find_their_source_and_walls_earn_no_progress():
    grid = blocked_room(0.05)
    env = NavVecEnv(geo_robot(), 1, grid=grid, seed=0)
    fields = env.shaping.fields
    centres = env.sampler.centres[torch.unique(env.sampler.pair_start)]
    ids = fields.ids(centres, None)
    assert (ids >= 0).all() and len(set(ids.tolist())) == len(ids)
    inside = 0.5 * GOAL_INSIDE  # the farthest from its centre that the sampler puts a goal
    for corner in ([inside, inside], [-inside, -inside], [inside, -inside], [inside, 0.0]):
        assert torch.equal(fields.ids(centres + torch.tensor(corner) * 0.05, None), ids)
    assert (fields.ids(centres + torch.tensor([0.6, 0.0]) * 0.05, None) != ids).any()  # past the edge: not it
    # inside the wall (x = 4 m) no cell around is free for the disc: the caller's value, not the bound
    pos = torch.tensor([[4.0, 2.0]])
    assert float(fields.distance(pos, ids[:1], None, torch.zeros(1))) == pytest.approx(fields.bound)
    assert float(fields.distance(pos, ids[:1], None, torch.zeros(1), unknown=torch.tensor([1.25]))) == 1.25


# --- geodesic progress on the paper's straight-line episodes (EpisodeGoalFields) ---------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_map_fields_equal_a_reference_dijkstra_on_random_maps(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((30, 40)) < 0.25
    free = ~occ
    sources = rng.choice(np.flatnonzero(free), size=3, replace=False)
    bound = 12.0  # cells
    table = map_fields(free, sources, bound)
    assert table.shape == (3, 30 * 40) and table.dtype == np.float32
    for k, s in enumerate(sources):
        ref = reference_distances(free, 1.0, np.full(free.size, s), np.arange(free.size), limit=np.inf)
        want = np.where(ref <= bound + 1e-9, ref, np.inf)
        assert np.array_equal(np.isinf(table[k]), np.isinf(want))
        fin = np.isfinite(want)
        assert np.abs(table[k][fin] - want[fin]).max() < 1e-4


def euclid_geo(**overrides):
    return robot("euclidean", **GEO, **overrides)


def test_straight_line_episodes_are_the_papers_draws_and_start_at_their_path_length():
    grid = blocked_room(0.05)
    env = NavVecEnv(euclid_geo(), 128, grid=grid, seed=3)
    plain = NavVecEnv(robot("euclidean"), 128, grid=grid, seed=3)
    env.reset(seed=3), plain.reset(seed=3)
    assert isinstance(env.shaping.fields, EpisodeGoalFields)
    assert torch.equal(env.pose, plain.pose) and torch.equal(env.goal, plain.goal)  # the same episodes
    src = env.shaping.source
    assert (src == torch.arange(128)).sum() >= 120  # ids are the slots (a goal off the disc's space: -1)
    free = free_space(grid, env.preset.footprint.circumscribed_radius)
    ok = src >= 0
    a, b = cells(grid, env.pose[ok, :2].double().numpy()), cells(grid, env.goal[ok].double().numpy())
    ref = torch.as_tensor(reference_distances(free, grid.resolution, b, a, limit=np.inf), dtype=torch.float32)
    known = torch.isfinite(ref)
    d = env.shaping.distance[ok]
    # the path length from the goal's cell, read at the start's position (3 x 3 cells, continuous)
    assert known.sum() > 100
    assert (d[known] <= ref[known] + 2 * grid.resolution).all() and (d[known] >= ref[known] - 2 * grid.resolution).all()
    assert (d >= env.goal_distance[ok] - 2 * grid.resolution).all()  # never shorter than the straight line
    # the bound: the farthest an episode can drive, plus the margin
    ep = env.preset.episode
    assert env.shaping.fields.bound == pytest.approx(ep.horizon * ep.dt * env.preset.motion.v_bounds[1] + MARGIN_M)


def test_straight_line_episodes_pay_the_way_round_the_wall_and_telescope():
    grid = blocked_room(0.05)
    x, y = 3.3, 2.0  # left of the wall, low down; across it at the same height
    goal = torch.tensor([[x, y]], dtype=torch.float64)
    pose = torch.tensor([[8.0 - x + 0.3, y, math.pi]], dtype=torch.float64)
    rewards = []
    for preset in (euclid_geo(), robot("euclidean")):
        e = NavVecEnv(preset, 1, grid=grid, seed=0)
        e.set_state(pose, goal)
        _, reward, term, _, _ = e.step(torch.tensor([[1.0, 0.0]]))
        assert not bool(term)
        rewards.append(float(reward))
    geodesic, straight_line = rewards
    assert straight_line > 0.05 and geodesic < 0.5 * straight_line
    # over random steps the shaping sums to the path length gained
    env = NavVecEnv(euclid_geo(), 64, grid=grid, seed=5)
    env.reset(seed=5)
    d0 = env.shaping.distance.clone()
    total, alive = torch.zeros(64), torch.ones(64, dtype=torch.bool)
    gen = torch.Generator().manual_seed(0)
    for _ in range(30):
        _, reward, term, trunc, _ = env.step(torch.rand(64, 2, generator=gen) * 2 - 1)
        ended = term | trunc
        total += torch.where(alive & ~ended, reward, torch.zeros(64))
        alive &= ~ended
    assert alive.sum() > 10
    c = env.preset.reward.progress
    assert torch.allclose(total[alive], c * (d0[alive] - env.shaping.distance[alive]), atol=1e-3)


def test_a_reset_slot_gets_its_new_goals_field_and_the_others_keep_theirs():
    env = NavVecEnv(euclid_geo(), 16, grid=blocked_room(0.05), seed=2)
    env.reset(seed=2)
    fields = env.shaping.fields
    before = fields.field.clone()
    idx = torch.tensor([3, 7])
    goal = torch.tensor([[1.0, 1.0], [6.5, 4.0]])
    got = fields.start(idx, goal, None)
    assert torch.equal(got, idx)
    rest = torch.ones(16, dtype=torch.bool)
    rest[idx] = False
    assert torch.equal(fields.field[rest], before[rest])
    # zero at the goal's own cell, and what a fresh computation for those goals gives
    d = fields.distance(goal, got, None, torch.zeros(2))
    assert (d < 0.05).all()
    fresh = EpisodeGoalFields(blocked_room(0.05), env.preset, 2, "cpu")
    fresh.start(torch.arange(2), goal, None)
    assert torch.equal(fresh.field, fields.field[idx])
    # a goal inside a wall: no field, the slot keeps the straight line
    assert int(fields.start(torch.tensor([5]), torch.tensor([[4.0, 1.0]]), None)) == -1
