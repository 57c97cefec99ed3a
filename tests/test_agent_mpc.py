"""scripts/agent_mpc.py: the constant-velocity MPC behind issue 13's "what do the tracks allow" figure.

Its figure only says something about the tracks if the controller sees what the policy sees (the track columns,
turned back into the simulator frame, are the agents the robot sees, where they are and how fast they moved),
predicts and moves as the simulator moves, and is scored by the simulator alone.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import agent_mpc  # noqa: E402

from flashnav.presets import load_robot  # noqa: E402
from flashnav.scenarios import scenario_preset  # noqa: E402
from flashnav.sim.env import make_env  # noqa: E402


def test_decoded_tracks_are_the_seen_agents_in_the_simulator_frame():
    preset = load_robot("turtlebot2", **{"agents.count": 6, "observation.agent_tracks": 6})
    env = make_env(preset, 16, seed=3)
    obs, _ = env.reset(seed=3)
    idx = torch.arange(16)
    checked = 0
    for _ in range(12):
        before = env.agents.pos.clone()
        r = env.step_slots(idx, torch.tensor([[0.5, 0.2]]).expand(16, 2))
        obs = r["obs"]
        centres, velocity, radii, present = agent_mpc.tracked_agents(obs, env.pose, 6)
        for i in range(16):
            if r["terminated"][i] or r["truncated"][i]:
                continue  # a new episode: its tracks start again
            got = centres[i][present[i]]
            for j, c in enumerate(got):
                k = int(torch.linalg.vector_norm(env.agents.pos[i] - c, dim=1).argmin())
                assert torch.allclose(c, env.agents.pos[i, k], atol=1e-4)
                assert float(radii[i][present[i]][j]) == pytest.approx(float(env.agents.radius[i, k]), abs=1e-6)
                v = velocity[i][present[i]][j]
                moved = (env.agents.pos[i, k] - before[i, k]) / preset.episode.dt
                # seen at both steps: the last step's displacement; seen first now: 0
                assert torch.allclose(v, moved, atol=1e-3) or float(v.abs().max()) == 0.0
                checked += 1
    assert checked > 50  # the robots saw agents


def test_on_the_static_map_it_drives_to_the_goal_and_never_touches_a_wall():
    torch.set_num_threads(1)
    rates = agent_mpc.run_mpc(scenario_preset("turtlebot2", "static"), 8, seed=11)
    assert rates["wall_collision_rate"] == 0.0  # its rollouts use the simulator's motion and collision checker
    assert rates["success_rate"] >= 0.75 and rates["mean_speed"] > 0.2


def test_knowing_the_agents_future_avoids_them_better_than_guessing_it():
    torch.set_num_threads(1)
    preset = scenario_preset("turtlebot2", "wander-8")
    future = agent_mpc.run_mpc(preset, 24, seed=5, tracker="future")
    blind = agent_mpc.run_mpc(load_robot(preset, **{"agents.count": 8}), 24, seed=5, tracker="lidar", margin=-10.0)
    # a margin of -10 m shrinks every predicted agent to nothing: the controller ignores them and is hit
    assert future["agent_collision_rate"] < blind["agent_collision_rate"]
    assert future["scored"] == blind["scored"] == 24


def test_bad_trackers_and_reactive_agents_are_refused_by_name():
    with pytest.raises(ValueError, match="tracker"):
        agent_mpc.run_mpc(scenario_preset("turtlebot2", "wander-4"), 2, seed=0, tracker="psychic")
    preset = load_robot("turtlebot2", **{"agents.count": 2, "agents.reactive": 0.5})
    with pytest.raises(ValueError, match="agents.reactive"):
        agent_mpc.run_mpc(preset, 2, seed=0, tracker="future")
