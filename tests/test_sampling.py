"""Start/goal sampling: the paper task's episodes pinned bit for bit; the euclidean band's fallbacks
counted and reported; geodesic goals inside the band by path length, against a plain Dijkstra."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

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
