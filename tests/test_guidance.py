"""Path guidance (flashnav/guidance.py): carrots on the shortest path, the goal itself once it is
within the lookahead, and a guided evaluation that equals the plain one when the carrot is always the
goal."""

from __future__ import annotations

import math

import pytest
import torch

from flashnav.eval_maps import evaluate_maps
from flashnav.guidance import PathGuide
from flashnav.sim.env import NavVecEnv
from test_goal_fields import blocked_room
from test_sampling import robot, serpentine


def placed(grid, poses, goals):
    env = NavVecEnv(robot("geodesic"), len(poses), grid=grid, seed=0)
    env.set_state(torch.tensor(poses, dtype=torch.float64), torch.tensor(goals, dtype=torch.float64))
    return env


def test_the_carrot_goes_round_the_wall_and_is_the_goal_once_near():
    grid = blocked_room(0.05)
    # left of the wall (x = 4 m, up to y = 5 m); goal across it at the same height, 4 m of path away
    env = placed(grid, [[3.0, 3.5, 0.0], [5.5, 3.5, 0.0]], [[5.0, 3.5], [5.0, 3.5]])
    guide = PathGuide(env, lookahead=1.0)
    carrot = guide.carrot(torch.arange(2))
    # slot 0: the straight line runs into the wall; the path goes up towards the wall's end
    assert carrot[0, 1] > 3.5 + 0.6 and carrot[0, 0] < 4.0
    assert math.dist(carrot[0].tolist(), [3.0, 3.5]) == pytest.approx(1.0, abs=0.15)
    # slot 1: the goal is 0.5 m away in the open: the carrot is the goal
    assert torch.equal(carrot[1], env.goal[1].float())


def test_carrots_descend_the_reference_path_length_by_the_lookahead():
    grid = serpentine(0.05)
    env = NavVecEnv(robot("geodesic"), 64, grid=grid, seed=3)
    env.reset(seed=3)
    guide = PathGuide(env, lookahead=1.0)
    idx = torch.arange(64)
    carrot = guide.carrot(idx)
    f = guide.fields
    ids = guide.field_of_slot
    d_robot, _ = f.nearest(env.pose[:, :2].float(), ids, None)
    d_carrot, _ = f.nearest(carrot, ids, None)
    far = d_robot > 1.0 + 0.2
    assert far.sum() > 10
    # the carrot is 1 m (+ one diagonal step) of path nearer the goal, measured on the field itself
    gained = d_robot[far] - d_carrot[far]
    assert (gained > 1.0 - 0.15).all() and (gained < 1.0 + 0.15).all()
    # (the fields themselves are the reference Dijkstra's: tests/test_goal_fields.py)


def test_a_guided_evaluation_with_the_goal_always_in_reach_is_the_plain_one():
    grid = serpentine(0.05)
    preset = robot("geodesic")
    gen = torch.Generator().manual_seed(0)
    weights = torch.randn(preset.base_obs_dim, 2, generator=gen) * 0.1

    def policy(obs):
        return torch.tanh(obs @ weights)

    kwargs = dict(goal_distance_scale=10.0)
    plain = evaluate_maps(policy, preset, [grid], 32, 7, **kwargs)
    far = evaluate_maps(policy, preset, [grid], 32, 7, guide=100.0, **kwargs)  # the carrot is always the goal
    assert plain == far
    near = evaluate_maps(policy, preset, [grid], 32, 7, guide=0.5, **kwargs)
    assert near != plain  # a different input changes at least one episode


def test_guidance_needs_a_positive_lookahead():
    env = placed(blocked_room(0.05), [[2.0, 1.5, 0.0]], [[6.0, 1.5]])
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="path guidance lookahead must be > 0 metres"):
            PathGuide(env, lookahead=bad)
