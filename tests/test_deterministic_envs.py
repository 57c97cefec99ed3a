"""``algo.deterministic_envs``: a share of the slots collects with the evaluated policy's action, tanh(mu), and
nothing else changes (docs/learners.md S25)."""

from __future__ import annotations

import pytest
import torch

from flashnav import train
from flashnav.learn.hparams import load_hparams
from flashnav.learn.learners import deterministic_slots
from flashnav.learn.networks import DeterministicActor
from flashnav.names import ALGORITHMS
from tests.test_learners import learner, random_obs
from tests.test_train import TINY, tiny


@pytest.mark.parametrize("share,envs,slots", [(0.0, 1024, 0), (0.125, 1024, 128), (0.1, 1024, 102),
                                              (0.01, 8, 1), (0.5, 7, 4), (0.9, 8, 7)])
def test_deterministic_slots_rounds_and_keeps_one_for_any_share(share, envs, slots):
    assert deterministic_slots(share, envs) == slots


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_the_last_slots_take_tanh_mu_and_the_others_their_exploration_draw(algorithm):
    obs = random_obs(8, torch.Generator().manual_seed(3))
    for _ in range(2):   # the second step after an update-free sync: the collector is the actor's copy
        plain, mixed = learner(algorithm, seed=4), learner(algorithm, seed=4, deterministic_envs=0.25)
        a, b = plain.act(obs), mixed.act(obs)
        assert torch.equal(a[:6], b[:6])                                     # the same exploration draws
        expected = DeterministicActor(mixed.state.collector)(obs[6:])
        assert torch.equal(b[6:], expected) and not torch.equal(a[6:], b[6:])
        # and the draws stay in step: the next call of each explores the first six slots alike
        assert torch.equal(plain.act(obs)[:6], mixed.act(obs)[:6])


def test_the_deterministic_action_carries_the_headroom():
    lrn = learner("fastdsac", seed=1, deterministic_envs=0.5, action_headroom=1.5)
    with torch.no_grad():   # push tanh(mu) towards the bounds so the clamp shows
        lrn.state.collector.mlp.net[-1].bias.fill_(2.0)
    b = lrn.act(random_obs(8, torch.Generator().manual_seed(0)))
    assert torch.all(b[4:, :2] == 1.0)


def test_shares_outside_zero_to_one_are_refused_by_name():
    for bad in (-0.1, 1.0):
        with pytest.raises(ValueError, match="deterministic_envs"):
            load_hparams("fastdsac", "turtlebot2", "paper", {"deterministic_envs": bad})


def test_a_run_with_deterministic_slots_trains_and_differs_from_one_without():
    plain = train(tiny())
    mixed = train(tiny(overrides={**TINY, "algo.deterministic_envs": 0.25}))
    assert mixed.learner.hp.deterministic_envs == 0.25
    assert [c["env_steps"] for c in plain.curve] == [c["env_steps"] for c in mixed.curve]
    flat = [torch.cat([p.flatten() for p in r.learner.state.actor.parameters()]) for r in (plain, mixed)]
    assert not torch.equal(*flat)
