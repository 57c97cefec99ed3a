"""scripts/mapless_planner.py: a planner that knows only the walls its scans have hit (issue 15)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import mapless_planner  # noqa: E402

from flashnav.maps import generate_map, save_ros_map  # noqa: E402
from flashnav.presets import load_robot  # noqa: E402
from flashnav.sim.env import make_env  # noqa: E402

TB2 = load_robot("turtlebot2", **{"episode.goal_sampling": "geodesic"})


@pytest.fixture(scope="module")
def maze(tmp_path_factory):
    from flashnav.maps.families import generate_family

    grid = generate_family("mazes", 7, size=(6.0, 6.0), resolution=0.05)
    return save_ros_map(grid, tmp_path_factory.mktemp("maze") / "maze.yaml")


def test_the_planner_plans_on_its_seen_walls(maze):
    """The script's planner steers on the fields of flashnav.mapless.SeenWalls (tests/test_mapless.py)."""
    env = make_env(TB2, 4, map=str(maze), seed=0)
    env.reset(seed=1)
    planner = mapless_planner.MaplessPlanner(env)
    assert not planner.walls.known.any() and planner.fields is planner.walls.fields
    planner.plan_all()
    assert planner.walls.known.any(axis=(1, 2)).all() and (planner.replans == 1).all()
    assert planner.act().shape == (4, 2)


def test_memory_solves_the_maze_and_forgetting_costs(maze):
    """The same 8 episodes: with memory the planner reaches every goal as the full-map oracle does; the
    forgetful planner (current scan only, replanned every step) plans far more often."""
    with_memory = mapless_planner.run_map(TB2, str(maze), 8, 12345)
    assert with_memory["oracle"]["success"] == 1.0
    assert with_memory["mapless"]["success"] >= 0.875 and with_memory["mapless"]["collision"] == 0.0
    forgetful = mapless_planner.run_map(TB2, str(maze), 8, 12345, memory=False)
    assert forgetful["mapless"]["replans_mean"] > 3 * with_memory["mapless"]["replans_mean"]
    assert len(forgetful["mapless"]["per_episode"]) == 8


def test_the_script_writes_its_table(maze, tmp_path, monkeypatch, capsys):
    out = tmp_path / "mapless.json"
    monkeypatch.setattr(sys, "argv", ["mapless_planner.py", str(maze), "--episodes", "2", "--sensor", "pooled",
                                      "--json", str(out)])
    torch.manual_seed(0)
    mapless_planner.main()
    result = json.loads(out.read_text())
    assert result["sensor"] == "pooled" and result["memory"] is True and result["maps"][0]["map"] == "maze"
    assert "mapless planner" in capsys.readouterr().out
