"""Every sampled episode is solvable within the horizon: a map-aware oracle reaches (almost) all."""

import pytest

from flashnav.maps.families import generate_family
from flashnav.names import MAP_FAMILIES
from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.oracle import run_oracle


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_oracle_reaches_at_least_99_percent_of_sampled_goals(robot):
    env = make_env(robot, 256, seed=5)  # the preset's bundled map
    result = run_oracle(env, episodes=512, seed=5)
    assert result["success"] >= 0.99, result


@pytest.mark.slow
@pytest.mark.parametrize("robot, radius, family", [("turtlebot2", 0.3, f) for f in MAP_FAMILIES]
                         + [("go2", 0.55, "rooms"), ("go2", 0.55, "mazes")])
def test_oracle_solves_geodesic_episodes_on_every_generated_family(robot, radius, family):
    # radius: the robot's circumscribed radius + start clearance, which every passage must fit
    grid = generate_family(family, 11, size=(11.0, 9.0), resolution=0.05, robot_radius=radius)
    env = make_env(load_robot(robot, **{"episode.goal_sampling": "geodesic"}), 64, map=grid, seed=11)
    result = run_oracle(env, episodes=128, seed=11)
    assert result["success"] >= 0.99, (grid.name, result)
