"""Every sampled episode is solvable within the horizon: a map-aware oracle reaches (almost) all."""

import pytest

from flashnav.sim.env import make_env
from flashnav.sim.oracle import run_oracle


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_oracle_reaches_at_least_99_percent_of_sampled_goals(robot):
    env = make_env(robot, 256, seed=5)  # the preset's bundled map
    result = run_oracle(env, episodes=512, seed=5)
    assert result["success"] >= 0.99, result
