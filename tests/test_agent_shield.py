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


def test_memory_and_growth_predict_more_and_why_sorts_every_agent_collision():
    torch.set_num_threads(1)
    p = scenario_preset("turtlebot2", "wander-8")
    seen = agent_shield.run(drive_at_goal, p, 24, 5, 2.0, "seen", why=True)
    why = seen.pop("why")
    assert why["hits"] == round(seen["agent_collision_rate"] * 24) == sum(why["kinds"].values()) > 0
    assert seen == run_scenario(drive_at_goal, make_env(p, 24, seed=5), 5, shield=PeopleShield(p, 2.0))
    # discs that grow with the look-ahead and agents remembered out of view: the shield takes over more often
    grown = agent_shield.run(drive_at_goal, p, 24, 5, 2.0, "seen", growth=0.3)
    kept = agent_shield.run(drive_at_goal, p, 24, 5, 2.0, "seen", memory=2.0)
    assert grown["shield_overruled"] > seen["shield_overruled"] and kept["shield_overruled"] >= seen["shield_overruled"]
    with pytest.raises(ValueError, match="--tracker future"):
        agent_shield.run(drive_at_goal, p, 4, 0, 2.0, "future", memory=1.0)
    with pytest.raises(ValueError, match=">= 0"):
        agent_shield.run(drive_at_goal, p, 4, 0, 2.0, "seen", growth=-0.1)


def test_radii_per_predicted_step_are_the_shields_discs_step_by_step():
    from flashnav.shield import People

    gen = torch.Generator().manual_seed(1)
    shield = PeopleShield(scenario_preset("turtlebot2", "wander-8"), lookahead=1.0)
    e, c, m, steps = 8, 5, 2, shield.steps
    pose = torch.cat([torch.rand(e, 2, generator=gen), torch.zeros(e, 1)], 1)
    actions = 2 * torch.rand(e, c, 2, generator=gen) - 1
    centres = pose[:, None, None, :2] + 3 * (torch.rand(e, steps, m, 2, generator=gen) - 0.5)
    radius = 0.1 + 0.2 * torch.rand(e, steps, m, generator=gen)
    on = torch.ones(e, m, dtype=torch.bool)
    got = shield.first_contact(pose, actions, People(centres, None, radius, on))
    # the reference: at each step l the rollouts against that step's discs alone; the first l that touches
    hits = torch.stack([shield_hits_at(shield, pose, actions, People(centres[:, l:l + 1], None, radius[:, l], on), l)
                        for l in range(steps)])   # [L, E, C]
    ref = torch.where(hits, torch.arange(steps)[:, None, None], steps).amin(0)
    assert torch.equal(got, ref) and 0 < int((ref < steps).sum()) < e * c


def shield_hits_at(shield, pose, actions, people, step):
    """[E, C] bool: the rollouts' footprint at ``step`` touches one of ``people``'s discs (fixed over the steps)."""
    from flashnav.sim.agent_geometry import footprint_hits_discs
    from flashnav.sim.motion import action_to_velocity, integrate

    e, c = actions.shape[:2]
    v, w = action_to_velocity(actions.reshape(-1, 2), shield.preset.motion)
    x = pose.repeat_interleave(c, 0)
    for _ in range(step + 1):
        x = integrate(x, v, w, shield.dt)
    r = (people.radius + shield.margin).repeat_interleave(c, 0)
    return footprint_hits_discs(x, shield.preset.footprint, people.centres[:, 0].repeat_interleave(c, 0), r,
                                people.present.repeat_interleave(c, 0)).reshape(e, c)


def test_shield_in_loop_collects_every_step_behind_the_shield_and_charges_its_take_overs(tmp_path, monkeypatch, capsys):
    import json

    import shield_in_loop

    import flashnav.learn.loop as loop

    # the runner wraps the loop's env class and learner factory for its process: restored after the test
    monkeypatch.setattr(loop, "NavVecEnv", loop.NavVecEnv)
    monkeypatch.setattr(loop, "run_learner", loop.run_learner)
    out = tmp_path / "run"
    rc = shield_in_loop.main(["--lookahead", "2", "--penalty", "0.5", "--", "train", "--device", "cpu", "--recipe",
                              "paper", "--seed", "0", "--out", str(out), "robot.agents.count=4", "algo.num_envs=32",
                              "algo.learning_start=64", "budget.max_env_steps=256", "eval.episodes=4", "threads=1"])
    printed = capsys.readouterr().out
    assert rc == 0 and json.loads((out / "metrics.json").read_text())["env_steps"] == 256
    assert "of the 256 collected steps" in printed   # every collected step went through the shield
    state = shield_in_loop._Shielded(2.0, 0.5)
    # the charge: P on the steps it took over, nothing elsewhere
    from flashnav.shield import SimShield

    p = scenario_preset("turtlebot2", "wander-8")
    state.attach(make_env(p, 3, seed=1))
    guard = state.guard
    assert isinstance(guard, SimShield) and guard.env is state.env
    guard.seen[:], guard.prev[:] = True, 0.0
    state.took_over = torch.tensor([True, False, True])
    reward = state.after_step(torch.tensor([1.0, 1.0, -10.0]), torch.tensor([False, False, True]))
    assert torch.equal(reward, torch.tensor([0.5, 1.0, -10.5]))
    # the ended slot starts afresh: no velocity from its old agents; the others keep their tracks
    assert not guard.seen[2].any() and guard.seen[0].all() and torch.equal(guard.prev[2], state.env.agents.pos[2])
    assert not guard.prev[0].any()


def test_shield_in_loop_refuses_bad_arguments_by_name():
    import shield_in_loop

    for argv, words in ((["train"], "usage"), (["--penalty", "-1", "--", "train"], "--penalty"),
                        (["--", "eval", "x"], "starting with 'train'")):
        with pytest.raises(SystemExit, match=words):
            shield_in_loop.main(argv)
