"""scripts/agent_oracle.py: the clairvoyant planner behind issue 13's feasibility figure.

Its figure is only honest if a plan found by the search is a plan the simulator accepts: the recorded agent
tracks must be the tracks the replay meets (non-reactive agents ignore the robot), and the search must move
and collide exactly as the simulator does. So: every plan found succeeds when replayed, and nothing else does.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import agent_oracle  # noqa: E402

from flashnav.presets import load_robot  # noqa: E402
from flashnav.scenarios import scenario_preset  # noqa: E402


def test_every_plan_found_succeeds_in_the_simulator_and_nothing_else_does():
    torch.set_num_threads(1)
    preset = scenario_preset("turtlebot2", "wander-8")
    episodes = 6
    result, plans = agent_oracle.clairvoyant(preset, episodes, seed=7, beam=300, v_levels=3, w_levels=5)
    found = sum(p is not None for p in plans)
    assert result["plans_found"] == found and found >= 3  # the search is not empty-handed on easy episodes
    assert result["scored"] == episodes
    assert result["success_rate"] == pytest.approx(found / episodes)  # each plan replays to the goal
    for p in plans:
        if p is not None:
            assert p.shape[1] == 2 and len(p) <= preset.episode.horizon
            assert bool((p.abs() <= 1.0).all())


def test_agent_tracks_do_not_depend_on_the_robot():
    preset = scenario_preset("turtlebot2", "wander-4")
    still = agent_oracle.stand_still(preset)
    pos_a, act_a = agent_oracle.agent_tracks(preset, 4, 3, still)
    pos_b, act_b = agent_oracle.agent_tracks(preset, 4, 3, torch.tensor([[1.0, 0.3]]))  # driving instead
    assert torch.equal(pos_a, pos_b) and torch.equal(act_a, act_b)


def test_reactive_agents_are_refused_by_name():
    preset = load_robot("turtlebot2", **{"agents.count": 2, "agents.reactive": 0.5})
    with pytest.raises(ValueError, match="agents.reactive"):
        agent_oracle.clairvoyant(preset, 2, seed=0, beam=10)
