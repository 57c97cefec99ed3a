"""Flags and reward of one step (flashnav.sim.reward): the paper's order, checked on hand-made cases, and
the env's transitions against them."""

import torch

from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.reward import Shaping, outcome

P = load_robot("turtlebot2")
T = torch.tensor


def test_goal_first_then_collision_then_shaping():
    thr, h = P.episode.goal_threshold, P.episode.horizon
    dist = T([thr / 2, thr / 2, 2.0, 2.0, 2.0, 2.0])
    static = T([True, False, True, False, False, False])
    agent = T([True, True, False, True, False, False])
    steps = T([1, h, 5, 5, 5, h])
    shaping = T([0.1, 0.2, 0.3, 0.4, 0.5, -0.6])
    out = outcome(P, dist, static, agent, steps, shaping)
    assert out["success"].tolist() == [True, True, False, False, False, False]
    # a step that reaches the goal is no collision, whatever touched it
    assert out["collision_static"].tolist() == [False, False, True, False, False, False]
    assert out["collision_agent"].tolist() == [False, False, False, True, False, False]
    assert out["collision"].tolist() == [False, False, True, True, False, False]
    assert out["terminated"].tolist() == [True, True, True, True, False, False]
    # the horizon truncates only an episode that did not end otherwise
    assert out["truncated"].tolist() == [False, False, False, False, False, True]
    g, c = P.reward.goal, P.reward.collision
    assert torch.allclose(out["reward"], T([g, g, c, c, 0.5, -0.6]))


def test_straight_line_shaping_is_the_distance_closed():
    s = Shaping(P, [], [], 3, torch.device("cpu"))
    assert s.fields is None
    gain = s.step(slice(None), torch.zeros(3, 2), T([3.0, 2.0, 1.0]), T([2.5, 2.5, 1.0]), None)
    assert torch.allclose(gain, P.reward.progress * T([0.5, -0.5, 0.0]))


def test_env_steps_agree_with_outcome():
    """Random driving on the bundled map: slots still running earned the shaping term; slots that ended
    were paid the goal or the collision reward, never both flags at once."""
    env = make_env("turtlebot2", 64, seed=3)
    env.reset(seed=3)
    gen = torch.Generator().manual_seed(0)
    ended_total = 0
    for _ in range(60):
        before = env.goal_distance.clone()
        _, reward, term, trunc, info = env.step(torch.rand(64, 2, generator=gen) * 2 - 1)
        live = ~(term | trunc)
        assert torch.allclose(reward[live], P.reward.progress * (before - env.goal_distance)[live])
        assert (reward[info["success"]] == P.reward.goal).all()
        assert (reward[info["collision"]] == P.reward.collision).all()
        assert not (info["success"] & info["collision"]).any()
        assert torch.equal(term, info["success"] | info["collision"])
        ended_total += int(term.sum())
    assert ended_total > 0  # the random walk did end episodes, so the checks above bit
