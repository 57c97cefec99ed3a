"""Evaluation scenarios with moving agents: presets, the name checks, scoring, and the rollout the
render draws."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from flashnav.presets import load_robot
from flashnav.rollout import agent_tracks, rollout, write_gif
from flashnav.scenarios import run_scenario, scenario_names, scenario_preset
from flashnav.sim.env import make_env
from flashnav.viz import draw_trajectories


def stand_still(obs: torch.Tensor) -> torch.Tensor:
    """v = 0, w = 0: a robot that never moves can only be hit by agents, never reach a wall."""
    action = torch.zeros(obs.shape[0], 2)
    action[:, 0] = -1.0
    return action


def test_scenario_presets_and_names():
    assert scenario_preset("turtlebot2", "static").agents.count == 0
    assert scenario_preset("turtlebot2", "wander-8").agents.count == 8
    crossing = scenario_preset("go2", "crossing").agents
    assert crossing.count == 1 and crossing.mix == {"crossing": 1.0}
    assert scenario_names("all") == ["static", "wander-4", "wander-8", "crossing"]
    with pytest.raises(ValueError, match="wander-8"):
        scenario_names("wander8")


def test_scenario_agents_are_fixed_whatever_the_policy_trained_with(tmp_path):
    from flashnav.policy_cli import _scenario_env
    from flashnav.yamlio import dump_yaml

    trained = load_robot("turtlebot2", **{"agents.count": 8, "agents.reactive": 0.5, "agents.speed": [0.6, 0.7],
                                          "observation.agent_tracks": 4})
    plain = scenario_preset("turtlebot2", "wander-8")
    fixed = scenario_preset(trained, "wander-8")
    assert fixed.agents == plain.agents and fixed.agents.reactive == 0.0 and fixed.agents.speed == (0.2, 0.5)
    assert fixed.observation.agent_tracks == 4  # the rest of the policy's preset stays
    own = scenario_preset(trained, "crossing", own_agents=True).agents
    assert own.reactive == 0.5 and own.speed == (0.6, 0.7) and own.count == 1 and own.mix == {"crossing": 1.0}
    # the CLI: the recorded preset gets the fixed agents; a preset named with --robot keeps its own
    path = tmp_path / "reactive.yaml"
    dump_yaml(load_robot("turtlebot2", **{"agents.reactive": 0.5}).model_dump(mode="json"), path)
    args = SimpleNamespace(robot=None, episodes=4, map=None, seed=0)
    assert _scenario_env(args, trained, "wander-4", "cpu").preset.agents.reactive == 0.0
    args.robot = str(path)
    assert _scenario_env(args, load_robot(str(path)), "wander-4", "cpu").preset.agents.reactive == 0.5


def test_a_standing_robot_is_hit_by_agents_and_never_by_walls():
    env = make_env(scenario_preset("turtlebot2", "wander-8"), 48, seed=3)
    r = run_scenario(stand_still, env, seed=3)
    assert r["scored"] == r["episodes"] == 48
    assert r["success_rate"] == 0.0 and r["wall_collision_rate"] == 0.0
    assert r["agent_collision_rate"] > 0.1
    assert r["agent_collision_rate"] + r["timeout_rate"] == pytest.approx(1.0)
    # the same episodes stepped densely, counting each slot's first episode
    env.reset(seed=3)
    first = torch.full((48,), -1)
    for _ in range(env.preset.episode.horizon):
        _, _, terminated, truncated, info = env.step(stand_still(env.obs))
        new = (terminated | truncated) & (first < 0)
        first[new] = torch.where(info["collision_agent"][new], 2, 0)
    assert float((first == 2).float().mean()) == pytest.approx(r["agent_collision_rate"])


def test_crossing_scores_only_episodes_with_a_crossing_agent():
    env = make_env(scenario_preset("turtlebot2", "crossing"), 64, seed=4)
    env.reset(seed=4)
    placed = int(env.agents.placed.any(dim=1).sum())
    r = run_scenario(stand_still, env, seed=4)
    assert r["scored"] == placed and 0 < placed < 64


def test_render_rollout_tracks_agents(tmp_path):
    env = make_env(scenario_preset("turtlebot2", "wander-4"), 3, seed=5)
    result = rollout(stand_still, env, seed=5)
    steps = result["poses"].shape[0]
    assert result["agents"].shape == (steps, 3, 4, 2) and result["agent_active"].shape == (steps, 3, 4)
    tracks = agent_tracks(result)
    assert len(tracks) >= 6 and all(t.shape[1] == 2 and 0.2 <= r <= 0.3 for t, r in tracks)
    moved = max(float(np.linalg.norm(t[-1] - t[0])) for t, _ in tracks)
    assert moved > 0.5
    paths = [result["poses"][: result["length"][i], i, :2] for i in range(3)]
    out = draw_trajectories(env.frame_map, paths, result["goals"], result["outcomes"], tmp_path / "a.png", agents=tracks)
    assert out.stat().st_size > 10_000
    gif = write_gif(env.frame_map, result, 0.2, str(tmp_path / "a.gif"))  # a str path too (it needed a Path)
    assert gif.stat().st_size > 1_000


def test_eval_scenario_command_writes_a_row_per_scenario(tmp_path):
    import json

    from test_export import random_actor, run_cli

    from flashnav.export import export_policy
    from flashnav.presets import load_robot

    paths = export_policy(random_actor(load_robot("turtlebot2")), load_robot("turtlebot2"), tmp_path / "policy")
    out = tmp_path / "scenarios.json"
    assert run_cli("eval", str(paths["torchscript"]), "--scenario", "static,wander-4", "--episodes", "8",
                   "--json", str(out)) == 0
    report = json.loads(out.read_text())
    assert list(report["scenarios"]) == ["static", "wander-4"]
    for r in report["scenarios"].values():
        total = sum(r[k] for k in ("success_rate", "agent_collision_rate", "wall_collision_rate", "timeout_rate"))
        assert total == pytest.approx(1.0) and r["episodes"] == 8
    assert report["scenarios"]["static"]["agent_collision_rate"] == 0.0
    with pytest.raises(ValueError, match="unknown scenario"):
        run_cli("eval", str(paths["torchscript"]), "--scenario", "rush-hour", "--episodes", "2")


def test_eval_scenario_with_a_guide_records_it_and_refuses_bad_guides(tmp_path, monkeypatch):
    """``--scenario`` with ``--guide``: every scenario's env gets the guide asked for (mapless from the scans,
    carving unless ``--guide-keep-walls``), the report and title say so; bad combinations are named."""
    import json

    import flashnav.guidance as guidance
    from test_export import random_actor, run_cli

    from flashnav.export import export_policy
    from flashnav.presets import load_robot

    made = []
    real = guidance.MaplessGuide

    def spy(env, **kw):
        made.append((env.num_envs, env.agents is not None, kw))
        return real(env, **kw)
    monkeypatch.setattr(guidance, "MaplessGuide", spy)
    paths = export_policy(random_actor(load_robot("turtlebot2")), load_robot("turtlebot2"), tmp_path / "policy")
    policy = str(paths["torchscript"])
    out = tmp_path / "guided.json"
    assert run_cli("eval", policy, "--scenario", "static,wander-4", "--episodes", "4", "--guide", "0.5",
                   "--guide-from", "scans", "--guide-keep-walls", "--json", str(out)) == 0
    assert made == [(4, False, {"lookahead": 0.5, "carve": False}), (4, True, {"lookahead": 0.5, "carve": False})]
    report = json.loads(out.read_text())
    assert (report["guide_lookahead_m"], report["guide_from"], report["guide_keep_walls"]) == (0.5, "scans", True)
    with pytest.raises(ValueError, match="--guide-keep-walls goes with --guide LOOKAHEAD_M --guide-from scans"):
        run_cli("eval", policy, "--scenario", "static", "--episodes", "2", "--guide", "0.5", "--guide-keep-walls")
    with pytest.raises(ValueError, match="--guide must be > 0 metres, got 0.0"):
        run_cli("eval", policy, "--scenario", "static", "--episodes", "2", "--guide", "0")
    with pytest.raises(ValueError, match="--guide goes with --maps or --scenario"):
        run_cli("eval", policy, "--episodes", "2", "--guide", "0.5")


def test_eval_agents_option_changes_the_scenario_agents_and_names_bad_input(tmp_path):
    import json

    from test_export import run_cli

    from flashnav.policy_cli import _scenario_env, agent_overrides

    policy = "tests/fixtures/deploy_policy/policy.onnx"
    out = tmp_path / "s.json"
    assert run_cli("eval", policy, "--scenario", "wander-4", "--episodes", "6", "--agents", "reactive=0.5",
                   "--agents", "speed=[0.3, 0.4]", "--json", str(out)) == 0
    report = json.loads(out.read_text())
    assert report["agents"] == {"reactive": 0.5, "speed": [0.3, 0.4]} and report["scenarios"]["wander-4"]["episodes"] == 6
    args = SimpleNamespace(robot=None, episodes=4, map=None, seed=0, scenario="wander-4", agents=["reactive=0.5"])
    env = _scenario_env(args, load_robot("turtlebot2"), "wander-8", "cpu")
    assert env.preset.agents.reactive == 0.5 and env.preset.agents.count == 8  # the scenario's count stays
    with pytest.raises(ValueError, match="agents.reactiv"):
        run_cli("eval", policy, "--scenario", "wander-4", "--episodes", "2", "--agents", "reactiv=0.5")
    with pytest.raises(ValueError, match="reactive"):
        run_cli("eval", policy, "--scenario", "wander-4", "--episodes", "2", "--agents", "reactive=2")
    with pytest.raises(ValueError, match="--agents 'reactive' is not key=value"):
        run_cli("eval", policy, "--scenario", "wander-4", "--episodes", "2", "--agents", "reactive")
    with pytest.raises(ValueError, match="--scenario"):
        run_cli("eval", policy, "--episodes", "2", "--agents", "reactive=0.5")
    with pytest.raises(ValueError, match="--scenario"):
        run_cli("render", policy, "--episodes", "2", "--out", str(tmp_path / "r.png"), "--agents", "reactive=0.5")
    assert not (tmp_path / "r.png").exists()
    assert run_cli("render", policy, "--scenario", "wander-4", "--episodes", "2", "--out", str(tmp_path / "w.png"),
                   "--agents", "reactive=1") == 0 and (tmp_path / "w.png").stat().st_size > 0
    assert agent_overrides(SimpleNamespace(scenario=None, agents=None)) == {}
