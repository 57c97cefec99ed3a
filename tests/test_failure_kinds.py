"""scripts/failure_kinds.py: how a policy fails on a set of maps, beside the oracle's time on the same routes
(issue 15)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import failure_kinds  # noqa: E402

from flashnav.maps import generate_map, save_ros_map  # noqa: E402
from flashnav.presets import load_robot  # noqa: E402
from flashnav.sim.env import make_env  # noqa: E402
from flashnav.sim.oracle import OracleController  # noqa: E402

TB2 = load_robot("turtlebot2", **{"episode.goal_sampling": "geodesic"})


@pytest.mark.parametrize("args, kind", [
    (("collision", 0.0, 5.0, 50, True), "collision"),          # a collision is one, however close it came
    (("timeout", 0.25, 0.1, 50, True), "near miss"),           # within 0.1 m of the 0.2 m goal radius
    (("timeout", 1.0, 0.3, 50, True), "stalled"),              # under 0.5 m in the second half
    (("timeout", 1.0, 3.0, 160, True), "long route"),          # the oracle needed 80 % of the horizon
    (("timeout", 1.0, 3.0, 200, False), "long route"),         # ... or failed
    (("timeout", 1.0, 3.0, 149, True), "wandered"),            # time enough, driving elsewhere
])
def test_each_failure_gets_its_kind(args, kind):
    assert failure_kinds.classify(*args, TB2) == kind


def test_drive_plays_each_slot_once_from_the_given_starts():
    """The oracle from fixed starts: every slot's first episode, its steps and a path that starts at the start
    pose and ends (NaN after) where the episode ended; a standing robot times out at the horizon."""
    env = make_env(TB2, 6, seed=0)
    env.reset(seed=3)
    start, goal = env.world_pose().clone(), env.world_goal().clone()
    oracle = OracleController(env)
    env.set_state(start, goal)
    oracle.plan()
    ok, steps, path = failure_kinds.drive(env, lambda _obs: oracle.act(), start, goal)
    assert ok.all() and (steps < TB2.episode.horizon).all()
    assert np.allclose(path[0], start[:, :2].numpy(), atol=1e-5)
    for j, k in enumerate(steps):
        assert not np.isnan(path[k - 1, j]).any() and np.isnan(path[k:, j]).all()
    still = make_env(TB2, 6, seed=0)
    still.reset(seed=0)
    ok, steps, path = failure_kinds.drive(still, lambda obs: torch.tensor([[-1.0, 0.0]]).expand(len(obs), 2), start, goal)
    assert not ok.any() and (steps == TB2.episode.horizon).all()
    assert np.allclose(path[-2], start[:, :2].numpy(), atol=1e-5)


def test_the_script_counts_a_standing_policys_timeouts_as_stalls(tmp_path, monkeypatch):
    """End to end on a generated map: a policy that never moves fails every episode, each one stalled, while
    the oracle solves them; the JSON carries the counts and every failure."""
    grid = generate_map(6.0, 6.0, 0.05, seed=4, robot_radius=0.3, name="small")
    map_yaml = save_ros_map(grid, tmp_path / "small.yaml")

    def standing(obs):
        return torch.tensor([[-1.0, 0.0]]).expand(len(obs), 2)

    monkeypatch.setattr(failure_kinds, "load_policy", lambda path: (standing, {"robot": "turtlebot2"}))
    out = tmp_path / "kinds.json"
    monkeypatch.setattr(sys, "argv", ["failure_kinds.py", "any.onnx", str(map_yaml), "--episodes", "6",
                                      "--json", str(out)])
    failure_kinds.main()
    result = json.loads(out.read_text())
    row = result["maps"][0]
    assert row["success"] == 0 and row["stalled"] == 6 and len(row["failures"]) == 6
    assert row["oracle_success"] == 1.0 and result["total"]["stalled"] == 6
