"""scripts/command_speed.py: a policy's forward command and its evaluation driven faster (issue 16, S19)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import command_speed  # noqa: E402

from flashnav.presets import load_robot
from flashnav.sim.env import make_env


def cruise(obs):  # forward action 0.6 (0.4 m/s of the TurtleBot2's 0.5), no turn
    return torch.tensor([[0.6, 0.0]]).expand(len(obs), 2)


def test_speed_scaling_multiplies_the_speed_and_stops_at_the_bound():
    obs = torch.zeros(3, 34)
    torch.testing.assert_close(command_speed.faster(cruise, 1.0, 0.0)(obs), cruise(obs))
    # speed (a + 1) / 2 * v_max: 0.8 of top speed, x1.1 -> 0.88 (action 0.76); x1.5 -> 1.2, clamped at the bound
    np.testing.assert_allclose(command_speed.faster(cruise, 1.1, 0.0)(obs)[:, 0].numpy(), 0.76, atol=1e-6)
    assert torch.equal(command_speed.faster(cruise, 1.5, 0.0)(obs)[:, 0], torch.ones(3))
    assert torch.equal(command_speed.faster(cruise, 1.5, 0.0)(obs)[:, 1], torch.zeros(3))  # the turn untouched
    with pytest.raises(ValueError, match="lower speed bound"):
        command_speed.faster(cruise, 1.1, -0.2)


def test_forward_commands_are_read_while_each_episode_runs():
    env = make_env(load_robot("turtlebot2"), 6, seed=3)
    a_v, evaluation = command_speed.forward_commands(cruise, env, 3)
    assert len(evaluation["episode_steps"]) == 6
    # one reading per slot and step until that slot's first episode ends: at least one per slot, at most the horizon
    assert 6 <= len(a_v) <= 6 * env.preset.episode.horizon and np.all(a_v == np.float32(0.6))
