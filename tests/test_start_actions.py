"""scripts/start_actions.py: a policy's first action on each episode of the fixed evaluation set (issue 16)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import start_actions  # noqa: E402

from flashnav.presets import load_robot

GOAL_ANGLE = 30 + 1  # TurtleBot2: 30 pooled sectors, then goal distance, then goal angle


def turns_when_goal_behind(obs):
    """Top speed towards a goal ahead, on the spot (a_v = -1) towards one behind, turning by the angle's sign."""
    angle = obs[:, GOAL_ANGLE]
    behind = angle.abs() >= math.pi / 2
    return torch.stack([torch.where(behind, -1.0, 1.0), torch.sign(angle)], dim=1)


def test_the_first_action_is_read_from_each_episodes_first_observation():
    r = start_actions.start_actions(turns_when_goal_behind, load_robot("turtlebot2"), 64, 5)
    ahead, behind = r["goal ahead"], r["goal behind"]
    assert r["all"]["starts"] == 64 == ahead["starts"] + behind["starts"] and ahead["starts"] > 0 < behind["starts"]
    # the split by start pose and goal agrees with the goal angle the policy saw in its first observation
    assert ahead["top_speed"] == 1.0 and ahead["turn_on_spot"] == 0.0
    assert behind["turn_on_spot"] == 1.0 and behind["top_speed"] == 0.0
    assert r["all"]["turn_on_spot"] == pytest.approx(behind["starts"] / 64)
    assert r["all"]["mean_abs_turn"] == pytest.approx(1.0)
    # every forward command is at a bound (+-1); so is every turn command but for a goal dead ahead (sign 0)
    assert r["all"]["saturated_v"] == 1.0 and r["all"]["saturated_w"] == pytest.approx(1.0, abs=1 / 64)


def test_saturation_counts_only_commands_at_a_bound():
    half = lambda obs: torch.full((obs.shape[0], 2), 0.5)  # noqa: E731
    r = start_actions.start_actions(half, load_robot("turtlebot2"), 16, 5)
    assert r["all"]["saturated_v"] == 0.0 == r["all"]["saturated_w"]
