"""Learner hyperparameters and options: the presets hold the paper's appendix A numbers, overrides are
validated by name, and each optional departure (policy averaging, learning-rate decay, late batch, the goal's
sine and cosine, action headroom, FastDSAC's risk-averse actor) does what its documentation says and nothing when
off."""

import math

import pytest
import torch

from flashnav.learn import common, fastdsac
from flashnav.learn.networks import gaussian_head
from flashnav.learn.hparams import load_hparams
from flashnav.names import ALGORITHMS
from tests.test_learners import A, B, LAYOUT, N, learner, params, random_batch, random_obs

# --- hyperparameters: the presets hold the paper's appendix A numbers -------------------------------

SHARED = dict(batch_size=1024, gamma=0.97, actor_lr=3e-4, critic_lr=3e-4, weight_decay=0.001,
              actor_hidden=(100,) * 4, critic_hidden=(100,) * 4)
PAPER = {
    ("fastdsac", "turtlebot2"): dict(total_env_steps=200_704, env_steps_per_sync=1, policy_frequency=2),
    ("fastdsac", "go2"): dict(total_env_steps=401_408, env_steps_per_sync=2, policy_frequency=2),
    ("fastsac", "turtlebot2"): dict(total_env_steps=200_704, env_steps_per_sync=1, policy_frequency=1),
    ("fastsac", "go2"): dict(total_env_steps=501_760, env_steps_per_sync=2, policy_frequency=2),
    ("fasttd3", "turtlebot2"): dict(total_env_steps=200_704, env_steps_per_sync=1, policy_frequency=2),
    ("fasttd3", "go2"): dict(total_env_steps=602_112, env_steps_per_sync=2, policy_frequency=2),
}
PER_ALGORITHM = {
    "fastdsac": dict(num_envs=1024, updates_per_step=40, learning_start=8192, tau=0.1, std_ema=0.005,
                     reward_scale=0.4, temperature=2.0, scale_range=(0.5, 2.0), cdq=True, log_std_max=0.0,
                     log_std_min=-5.0, huber_delta=50.0, betas=(0.9, 0.95)),
    "fastsac": dict(num_envs=1024, updates_per_step=40, learning_start=8192, tau=0.1, alpha_lr=3e-4,
                    alpha_init=0.001, target_entropy_ratio=0.5, num_atoms=101, v_min=-20.0, v_max=20.0,
                    betas=(0.9, 0.95)),
    "fasttd3": dict(num_envs=512, updates_per_step=56, learning_start=16_384, tau=0.01, target_noise=0.1,
                    noise_clip=0.2, max_grad_norm=10.0, collection_noise=(0.05, 0.25), num_atoms=101,
                    v_min=-10.0, v_max=10.0),
}


@pytest.mark.parametrize("algorithm,robot", sorted(PAPER))
def test_paper_presets_hold_appendix_a(algorithm, robot):
    hp = load_hparams(algorithm, robot, "paper")
    for key, value in {**SHARED, **PER_ALGORITHM[algorithm], **PAPER[(algorithm, robot)]}.items():
        assert getattr(hp, key) == pytest.approx(value), key
    cpu = load_hparams(algorithm, robot, "cpu")
    assert cpu.algorithm == algorithm and cpu.num_envs <= 256


def test_overrides_and_validation_messages():
    hp = load_hparams("fastdsac", "go2", "paper", {"batch_size": 256, "betas": [0.9, 0.99]})
    assert hp.batch_size == 256 and hp.betas == (0.9, 0.99)
    with pytest.raises(ValueError, match="batch_size"):
        load_hparams("fastdsac", "go2", "paper", {"batch_sise": 256})
    with pytest.raises(ValueError, match="greater than 0"):
        load_hparams("fasttd3", "go2", "paper", {"num_envs": 0})
    with pytest.raises(ValueError, match="v_min"):
        load_hparams("fastsac", "turtlebot2", "paper", {"v_min": 30.0})
    with pytest.raises(ValueError, match="recipe"):
        load_hparams("fastsac", "turtlebot2", "auto")
    with pytest.raises(ValueError, match="robot"):
        load_hparams("fastsac", "jackal", "paper")
    with pytest.raises(ValueError):
        type(hp).model_validate({**hp.model_dump(), "unknown_key": 1})


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_policy_averaging_evaluates_a_polyak_average_of_the_actor(algorithm):
    rate = 0.25
    lrn = learner(algorithm, policy_averaging=rate, obs_norm=True)
    expected = params(lrn.state.actor)
    for i in range(3 * lrn.hp.policy_frequency):
        lrn.update(random_batch(i))
        if lrn.num_updates % lrn.hp.policy_frequency == 0:  # an actor step: the average moves
            expected = [(1 - rate) * e + rate * p for e, p in zip(expected, params(lrn.state.actor))]
    got = params(lrn.state.averaged_actor)
    assert all(torch.allclose(e, g, rtol=1e-5, atol=1e-6) for e, g in zip(expected, got))
    assert any(not torch.equal(a, g) for a, g in zip(params(lrn.state.actor), got))
    assert torch.equal(lrn.state.averaged_actor.transform.feat_mean, lrn.state.actor.transform.feat_mean)
    obs = random_obs(N, torch.Generator().manual_seed(4))
    with torch.no_grad():
        assert torch.equal(lrn.policy(obs), torch.tanh(lrn.state.averaged_actor(obs)[:, :A]))
    copy = learner(algorithm, seed=5, policy_averaging=rate, obs_norm=True)
    copy.load_state_dict(lrn.state_dict())
    assert all(torch.equal(a, b) for a, b in zip(got, params(copy.state.averaged_actor)))
    assert learner(algorithm).state.averaged_actor is None  # off: the policy is the trained actor
    # averaging moves only the evaluated copy: the same batches train the same actor without it
    plain = learner(algorithm, obs_norm=True)
    for i in range(3 * plain.hp.policy_frequency):
        plain.update(random_batch(i))
    assert all(torch.equal(a, b) for a, b in zip(params(plain.state.actor), params(lrn.state.actor)))


def test_lr_decay_is_a_cosine_from_the_recipe_rates_to_their_final_fraction():
    assert common.lr_factor(0.1, 0.0) == 1.0 and common.lr_factor(0.1, 1.0) == pytest.approx(0.1)
    assert common.lr_factor(0.1, 0.5) == pytest.approx(0.55)  # half way between, at half the budget
    assert common.lr_factor(0.1, 2.0) == pytest.approx(0.1) and common.lr_factor(0.1, -1.0) == 1.0  # clamped
    steps = [common.lr_factor(0.0, p / 10) for p in range(11)]
    assert steps == sorted(steps, reverse=True) and steps[-1] == pytest.approx(0.0, abs=1e-12)
    lrn = learner("fastdsac", lr_final_ratio=0.25, actor_lr=1e-3, critic_lr=2e-3)
    alpha_lr = lrn.state.algo.temperature.opt.param_groups[0]["lr"]
    lrn.schedule(1.0)
    assert [g["lr"] for g in lrn.state.actor_opt.param_groups] == [pytest.approx(2.5e-4)]
    assert [g["lr"] for g in lrn.state.critic_opt.param_groups] == [pytest.approx(5e-4)]
    assert lrn.state.algo.temperature.opt.param_groups[0]["lr"] == alpha_lr  # the temperature keeps its rate
    lrn.schedule(0.0)
    assert lrn.state.actor_opt.param_groups[0]["lr"] == pytest.approx(1e-3)
    constant = learner("fastdsac")  # every recipe: ratio 1, the rates never touched
    assert constant.hp.lr_final_ratio == 1.0
    constant.state.actor_opt.param_groups[0]["lr"] = 0.123
    constant.schedule(1.0)
    assert constant.state.actor_opt.param_groups[0]["lr"] == 0.123
    with pytest.raises(ValueError, match="lr_final_ratio"):
        learner("fastdsac", lr_final_ratio=1.5)


def test_late_batch_options_are_validated_by_name():
    for bad in ({"late_from": 1.5}, {"late_from": -0.1}, {"late_batch_size": -1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            learner("fastdsac", **bad)
    hp = learner("fastdsac", batch_size=64).hp
    assert hp.late_batch_size == 0 and hp.batch_size_at(0.99) == 64  # off: the same batch all run long


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_goal_sincos_learners_update_and_act_on_the_plain_observation(algorithm):
    """``algo.goal_sincos`` widens every network's input by one (the angle's sine and cosine); the learner
    still takes and stores the observation as it is, and an update moves its weights."""
    lrn = learner(algorithm, goal_sincos=True)
    assert lrn.state.actor.transform.goal_sincos and lrn.state.critic.transform.goal_sincos
    assert lrn.state.actor.mlp.net[0].in_features == LAYOUT.obs_dim + 1
    before = params(lrn.state.critic)
    for i in range(lrn.hp.policy_frequency):
        lrn.update(random_batch(i))
    assert any(not torch.equal(a, b) for a, b in zip(before, params(lrn.state.critic)))
    assert lrn.policy(random_batch(9).obs).shape == (B, A)
    assert not learner(algorithm).state.actor.transform.goal_sincos  # off by default (the paper's feature)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_action_headroom_scales_and_clamps_every_action_the_robot_gets(algorithm):
    """``algo.action_headroom`` k: the evaluated policy is clamp(k tanh(mu), -1, 1), the collection actions stay in
    [-1, 1] and reach the bounds for a large mean; k = 1 (every recipe) is the paper's tanh(mu), update for update."""
    base, roomy = learner(algorithm, seed=3), learner(algorithm, seed=3, action_headroom=1.25)
    obs = random_batch(4).obs
    with torch.no_grad():
        squashed = torch.tanh(base.state.actor(obs)[:, :A])
        torch.testing.assert_close(base.policy(obs), squashed, rtol=0, atol=0)
        torch.testing.assert_close(roomy.policy(obs), (1.25 * squashed).clamp(-1, 1), rtol=0, atol=0)
        out = roomy.state.actor.mlp.net[-1]
        out.bias[:A] = 2.0  # tanh(mu) ~ 0.96 in every state: beyond 1 / k, so the action sits on the bound
        assert torch.equal(roomy.policy(obs), torch.ones(B, A))
        roomy.state.collector.load_state_dict(roomy.state.actor.state_dict())
        acted = roomy.act(obs[:N])
    assert acted.abs().max() <= 1.0 and (acted == 1.0).float().mean() > 0.3
    for i in range(4):  # updates run and stay finite with actions on the bound
        assert all(torch.isfinite(v).all() for v in roomy.update(random_batch(10 + i)).values())
    with pytest.raises(ValueError, match="action_headroom"):
        learner(algorithm, action_headroom=0.9)


def test_action_headroom_one_is_todays_learner_step_for_step():
    """The default (k = 1) and an explicit k = 1 train to the same weights bit for bit."""
    a, b = learner("fastdsac", seed=2), learner("fastdsac", seed=2, action_headroom=1.0)
    for i in range(4):
        a.update(random_batch(i)), b.update(random_batch(i))
        a.act(random_batch(i).obs[:N]), b.act(random_batch(i).obs[:N])
    assert all(torch.equal(x, y) for x, y in zip(params(a.state.actor), params(b.state.actor)))


# --- FastDSAC: a risk-averse actor (algo.risk_cvar, docs/learners.md S24) ----------------------------

def test_cvar_factor_is_the_mean_of_the_worst_share_of_a_gaussian():
    """k against a brute-force reference: the mean of the lowest ``level`` share of 2e6 N(0, 1) draws is -k."""
    draws = torch.randn(2_000_000, generator=torch.Generator().manual_seed(0), dtype=torch.float64).sort().values
    for level in (0.05, 0.25, 0.5, 0.9):
        tail = draws[: int(level * draws.numel())].mean().item()
        assert fastdsac.cvar_std_factor(level) == pytest.approx(-tail, abs=5e-3), level
    assert fastdsac.cvar_std_factor(1.0) == 0.0
    with pytest.raises(ValueError, match="risk_cvar"):
        fastdsac.cvar_std_factor(0.0)


@pytest.mark.parametrize("level", [1.0, 0.25])
def test_the_risk_averse_actor_climbs_each_critics_cvar(level):
    """The actor loss with ``risk_cvar`` written out: alpha log pi - min_k (mu_k - k(level) sigma_k); at level 1
    exactly today's loss (the mean)."""
    lrn = learner("fastdsac", risk_cvar=level)
    batch = random_batch(6)
    st, hp = lrn.state, lrn.hp
    rng = st.update_gen.get_state()
    with torch.no_grad():
        eps = torch.randn((batch.obs.shape[0], A), generator=st.update_gen)
        mu, log_std = fastdsac.policy_log_std(st.actor(batch.obs), hp)
        action = torch.tanh(mu + log_std.exp() * eps)
        log_prob = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)
                    - torch.log(1 - action.pow(2) + 1e-6)).sum(-1)
        q_mu, q_std = gaussian_head(st.critic(batch.obs, action))
        k = {1.0: 0.0, 0.25: 1.2711}[level]
        expected = (st.algo.temperature.alpha * log_prob - (q_mu - k * q_std).min(dim=0).values).mean()
    st.update_gen.set_state(rng)
    got = fastdsac.update_actor(st, batch)["actor_loss"]
    assert torch.allclose(got, expected, rtol=1e-4, atol=1e-5), (float(got), float(expected))
    if level < 1.0:
        assert k * q_std.mean() > 1e-3     # the critics' std is not ~0, so this test tells the two losses apart
    with pytest.raises(ValueError, match="risk_cvar"):
        learner("fastdsac", risk_cvar=1.5)
    with pytest.raises(ValueError, match="risk_cvar"):
        learner("fastsac", risk_cvar=0.5)   # FastSAC's critic is C51, no Gaussian: no such key
