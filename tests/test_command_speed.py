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


def test_on_a_map_suite_the_unscaled_row_is_flashnav_eval_and_a_faster_cruise_changes_it(tmp_path, small_heldout_maps):
    import json

    from flashnav.cli import main as flashnav_main

    policy = str(Path(__file__).resolve().parent / "fixtures" / "deploy_policy" / "policy.onnx")
    maps = small_heldout_maps
    ref, out = tmp_path / "eval.json", tmp_path / "speed.json"
    assert flashnav_main(["eval", policy, "--maps", str(maps), "--episodes", "6", "--seed", "3",
                          "--json", str(ref)]) == 0
    command_speed.main([policy, "--maps", str(maps), "--episodes", "6", "--seed", "3", "--scales", "1,2",
                        "--json", str(out)])
    want = json.loads(ref.read_text())
    doc = json.loads(out.read_text())
    assert doc["maps"] == str(maps) and doc["episodes"] == 6
    (x1, x2), = [p["speed_scaled"] for p in doc["policies"].values()]
    assert x1["success"] == pytest.approx(want["aggregate"]["mean"]["success_rate"])
    assert x1["maps_under_95"] == [r["map"] for r in want["maps"] if r["success_rate"] < 0.95]
    assert x1["mean_steps"] == pytest.approx(sum(r["mean_steps"] for r in want["maps"]) / 2)
    assert x2["scale"] == 2 and x2 != {**x1, "scale": 2}  # twice the speed plays other episodes
