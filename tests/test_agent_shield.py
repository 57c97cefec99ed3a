"""scripts/agent_shield.py: the shield with other predictions. Its "seen" tracker must be flashnav eval's shield,
episode for episode, or its other rows say nothing about the shield that ships."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import agent_shield  # noqa: E402

from flashnav.scenarios import run_scenario, scenario_preset  # noqa: E402
from flashnav.shield import PeopleShield  # noqa: E402
from flashnav.sim.env import make_env  # noqa: E402
from tests.test_shield import drive_at_goal  # noqa: E402


def test_the_seen_tracker_is_the_evaluations_shield_and_the_future_bound_runs():
    torch.set_num_threads(1)
    p = scenario_preset("turtlebot2", "wander-8")
    seen = agent_shield.run(drive_at_goal, p, 24, 5, 2.0, "seen")
    assert seen == run_scenario(drive_at_goal, make_env(p, 24, seed=5), 5, shield=PeopleShield(p, 2.0))
    future = agent_shield.run(drive_at_goal, p, 24, 5, 2.0, "future")
    assert future["agent_collision_rate"] <= seen["agent_collision_rate"] and future["scored"] == 24


def test_the_tracks_prediction_needs_a_policy_with_tracks():
    with pytest.raises(ValueError, match="agent_tracks"):
        agent_shield.run(drive_at_goal, scenario_preset("turtlebot2", "wander-8"), 4, 0, 2.0, "tracks")
