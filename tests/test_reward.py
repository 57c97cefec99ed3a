"""Flags and reward of one step (flashnav.sim.reward): the paper's order, checked on hand-made cases, and
the env's transitions against them."""

import pytest
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


def test_a_progress_discount_makes_the_shaping_potential_based():
    """With c = gamma the shaping is gamma Phi(s') - Phi(s), Phi = -progress d: its discounted sum over any run of
    live steps telescopes to progress (d_0 - gamma^T d_T), whatever the route (Ng et al. 1999); c = 1 is the
    paper's term exactly."""
    gamma = 0.99
    pbrs = load_robot("turtlebot2", **{"reward.progress_discount": gamma})
    assert P.reward.progress_discount == 1.0
    env = make_env(pbrs, 64, seed=5)
    paper = make_env("turtlebot2", 64, seed=5)
    env.reset(seed=5)
    paper.reset(seed=5)
    d0 = env.goal_distance.clone()
    total, weight = torch.zeros(64, dtype=torch.float64), 1.0
    alive = torch.ones(64, dtype=torch.bool)
    gen = torch.Generator().manual_seed(1)
    steps = 40
    for _ in range(steps):
        before = env.goal_distance.clone()
        action = torch.rand(64, 2, generator=gen) * 2 - 1
        _, reward, term, trunc, _ = env.step(action)
        _, paper_reward, *_ = paper.step(action)
        live = ~(term | trunc)
        # the same transitions as the paper's env; only the live steps' shaping differs, by (1 - c) d_new
        d = env.goal_distance
        assert torch.allclose(reward[live], pbrs.reward.progress * (before - gamma * d)[live])
        assert torch.allclose((reward - paper_reward)[live], (pbrs.reward.progress * (1 - gamma) * d)[live])
        assert torch.equal(reward[~live], paper_reward[~live])
        alive &= live
        total += weight * reward.double() * alive
        weight *= gamma
        if alive.any():
            d_alive = d.clone()
    expected = pbrs.reward.progress * (d0.double() - gamma ** steps * d_alive.double())
    assert alive.sum() > 5  # some slots drove every step, so the telescoping sum is checked
    assert torch.allclose(total[alive], expected[alive], atol=1e-4)
    with pytest.raises(ValueError, match="progress_discount"):
        load_robot("turtlebot2", **{"reward.progress_discount": 1.5})


def test_a_step_cost_is_paid_on_every_live_step_and_never_on_an_ending_one():
    """``reward.step_cost`` k: a live step pays its shaping term minus k, truncation included; a goal or a collision
    pays its terminal reward alone; k = 0 is the paper's reward; an evaluation plays without it."""
    from flashnav.sim.goal_fields import evaluation_preset

    assert P.reward.step_cost == 0.0
    k = 0.05
    priced = load_robot("turtlebot2", **{"reward.step_cost": k})
    thr, h = P.episode.goal_threshold, P.episode.horizon
    dist, steps = T([thr / 2, 2.0, 2.0, 2.0]), T([3, 3, 3, h])
    static, agent = T([False, True, False, False]), T([False, False, False, False])
    shaping = T([0.1, 0.2, 0.0, 0.3])
    out = outcome(priced, dist, static, agent, steps, shaping)
    assert torch.allclose(out["reward"], T([P.reward.goal, P.reward.collision, -k, 0.3 - k]))
    assert out["truncated"].tolist() == [False, False, False, True]
    env, paper = make_env(priced, 64, seed=4), make_env("turtlebot2", 64, seed=4)
    env.reset(seed=4)
    paper.reset(seed=4)
    gen = torch.Generator().manual_seed(2)
    for _ in range(30):  # the same transitions; only the live steps' rewards differ, by exactly k
        action = torch.rand(64, 2, generator=gen) * 2 - 1
        _, reward, term, trunc, _ = env.step(action)
        _, paper_reward, paper_term, *_ = paper.step(action)
        assert torch.equal(term, paper_term)
        assert torch.allclose(reward[~term], paper_reward[~term] - k)
        assert torch.equal(reward[term], paper_reward[term])
    assert evaluation_preset(priced).reward == P.reward
    for bad in (-0.1, 2.0):
        with pytest.raises(ValueError, match="step_cost"):
            load_robot("turtlebot2", **{"reward.step_cost": bad})
