"""``flashnav eval POLICY robot.KEY=VALUE`` (and ``render``): the policy played on a changed robot - a robustness
check such as sensor noise - is the library's evaluation on that preset; what an evaluation cannot change is named."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from flashnav.cli import main as cli_main
from flashnav.evaluate import evaluate
from flashnav.export import evaluated_robot, load_policy
from flashnav.sim.env import make_env

POLICY = str(Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx")


def _cli_rates(tmp_path, *extra) -> dict:
    out = tmp_path / "e.json"
    assert cli_main(["eval", POLICY, "--episodes", "48", "--seed", "7", "--json", str(out), *extra]) == 0
    return json.loads(out.read_text())


def test_an_override_is_the_evaluation_on_the_changed_preset(tmp_path):
    noisy = _cli_rates(tmp_path, "robot.lidar.noise_std=0.3")
    plain = _cli_rates(tmp_path)
    assert noisy["robot_overrides"] == {"lidar.noise_std": 0.3} and plain["robot_overrides"] == {}
    policy, meta = load_policy(POLICY)
    preset = evaluated_robot(meta, **{"lidar.noise_std": 0.3})
    want = evaluate(policy, make_env(preset, 48, seed=7), seed=7)
    assert noisy["success_rate"] == want["success_rate"] and noisy["mean_steps"] == pytest.approx(want["mean_steps"])
    assert (noisy["success_rate"], noisy["mean_steps"]) != (plain["success_rate"], plain["mean_steps"])


@pytest.mark.parametrize("bad, says", [
    ("algo.batch_size=3", "flashnav eval takes robot.KEY=VALUE"),
    ("robot.agents.count=4", "--scenario NAME [--agents KEY=VALUE]"),
    ("robot.reward.collision=-5", "the reward does not enter it"),
    ("robot.lidar.nois=0.1", "did you mean noise_std"),
    ("robot.lidar.sectors=20", "the policy expects 34"),
])
def test_what_an_evaluation_cannot_change_is_named(bad, says, capsys):
    assert cli_main(["eval", POLICY, "--episodes", "4", bad]) == 2
    assert says in capsys.readouterr().err


def test_render_and_scenarios_take_them_too(tmp_path, capsys):
    out = tmp_path / "r.png"
    assert cli_main(["render", POLICY, "--episodes", "2", "--out", str(out), "robot.lidar.noise_std=0.02"]) == 0
    assert out.stat().st_size > 0
    report = tmp_path / "s.json"
    assert cli_main(["eval", POLICY, "--scenario", "wander-4", "--episodes", "8", "--json", str(report),
                     "robot.lidar.max_range=4"]) == 0
    assert json.loads(report.read_text())["robot_overrides"] == {"lidar.max_range": 4}
    assert "with robot.lidar.max_range=4" in capsys.readouterr().out


def test_the_maps_report_carries_them(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert cli_main(["eval", POLICY, "--maps", "turtlebot2", "--episodes", "4", "--json", str(out),
                     "robot.lidar.noise_std=0.05"]) == 0
    assert json.loads(out.read_text())["robot_overrides"] == {"lidar.noise_std": 0.05}
    assert "robot.lidar.noise_std=0.05" in capsys.readouterr().out
