"""scripts/episode_difficulty.py: replaying the failed evaluation episodes (issue 16)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import episode_difficulty  # noqa: E402


def test_a_policy_without_failures_replays_nothing():
    # a policy that solved all 1,024 episodes has no failure to replay (this raised "num_envs must be >= 1")
    paths, closest = episode_difficulty.replay_failures(None, "turtlebot2", np.zeros((0, 3)), np.zeros((0, 2)))
    assert paths.shape[1] == 0 and closest.shape == (0,)


def test_failures_are_replayed_from_their_start():
    # a robot that stands still times out where it started: its closest approach is the start-goal distance
    start, goal = np.array([[3.0, 3.0, 0.0], [4.0, 6.0, 1.0]]), np.array([[5.0, 3.0], [4.0, 8.5]])

    def still(obs):
        return torch.tensor([[-1.0, 0.0]]).expand(len(obs), 2)

    paths, closest = episode_difficulty.replay_failures(still, "turtlebot2", start, goal)
    assert np.allclose(closest, [2.0, 2.5], atol=1e-4)
    assert np.nanmax(np.abs(paths - paths[:1])) < 1e-5  # it never moved (NaN after its episode ended)
