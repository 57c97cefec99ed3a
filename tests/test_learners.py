"""Learners (FastTD3, FastSAC, FastDSAC) through the common interface (their hyperparameters and options:
test_learner_options.py)."""

import math
import types
from pathlib import Path

import pytest
import torch

from flashnav.checkpoint import load_checkpoint
from flashnav.learn import c51, fastdsac, fastsac, fasttd3
from flashnav.learn.hparams import load_hparams
from flashnav.learn.learners import MODULES, make_learner
from flashnav.learn.networks import ObsLayout, gaussian_head
from flashnav.learn.protocol import AlgorithmModule, protocol_mismatches
from flashnav.learn.replay import Transition
from flashnav.names import ALGORITHMS

LEGACY = Path(__file__).parent / "fixtures" / "legacy_learners"
LAYOUT = ObsLayout(sectors=30, inscribed_radius=0.2, max_range=20.0, goal_scale=(15.0, math.pi),
                   velocity_scales=(0.5, math.pi / 4))
N, A, B = 8, 2, 32


def random_obs(n, gen):
    lidar = 0.2 + 19.8 * torch.rand(n, 30, generator=gen) ** 3
    goal = torch.stack([15 * torch.rand(n, generator=gen), (2 * torch.rand(n, generator=gen) - 1) * math.pi], -1)
    vel = torch.stack([0.5 * torch.rand(n, generator=gen), (2 * torch.rand(n, generator=gen) - 1) * math.pi / 4], -1)
    return torch.cat([lidar, goal, vel], -1)


def random_batch(seed=0, b=B, terminated=None):
    gen = torch.Generator().manual_seed(seed)
    term = (torch.rand(b, generator=gen) < 0.2).float() if terminated is None else torch.full((b,), float(terminated))
    return Transition(random_obs(b, gen), torch.rand(b, A, generator=gen) * 2 - 1, 3 * torch.randn(b, generator=gen),
                      1.0 - term, random_obs(b, gen))


def learner(algorithm, seed=0, envs=N, **overrides):
    hp = load_hparams(algorithm, "turtlebot2", "paper", overrides)
    return make_learner(algorithm, hp, LAYOUT, A, envs, "cpu", seed)


def params(module):
    return [p.detach().clone() for p in module.parameters()]


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_update_changes_parameters_and_returns_detached_tensors(algorithm):
    lrn = learner(algorithm)
    actor0, critic0 = params(lrn.state.actor), params(lrn.state.critic)
    keys = None
    for i in range(lrn.hp.policy_frequency):
        metrics = lrn.update(random_batch(i))
        assert all(isinstance(v, torch.Tensor) and not v.requires_grad for v in metrics.values())
        assert all(torch.isfinite(v).all() for v in metrics.values())
        assert keys is None or set(metrics) == keys
        keys = set(metrics)
    assert lrn.num_updates == lrn.hp.policy_frequency
    assert any(not torch.equal(a, b) for a, b in zip(actor0, params(lrn.state.actor)))
    assert any(not torch.equal(a, b) for a, b in zip(critic0, params(lrn.state.critic)))
    # the IPAPRec betas are trained too
    assert not torch.equal(critic0[0], lrn.state.critic.transform.rho)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_actor_updates_only_every_policy_frequency(algorithm):
    lrn = learner(algorithm, policy_frequency=3)
    actor0 = params(lrn.state.actor)
    lrn.update(random_batch(0))
    lrn.update(random_batch(1))
    assert all(torch.equal(a, b) for a, b in zip(actor0, params(lrn.state.actor)))
    lrn.update(random_batch(2))
    assert any(not torch.equal(a, b) for a, b in zip(actor0, params(lrn.state.actor)))


def hand_actor_loss(algorithm, lrn, batch, weight):
    """The actor objective written out: alpha log pi(a|s) - Q(s, a) at a reparameterised sample (the critics'
    min of means for FastDSAC with CDQ, the mean of the C51 expectations for FastSAC), minus ``weight`` times
    Q(s, tanh(mu)); the sample's noise is the next draw of ``update_gen``."""
    st, hp = lrn.state, lrn.hp
    eps = torch.randn((batch.obs.shape[0], A), generator=st.update_gen)
    raw = st.actor(batch.obs)
    if algorithm == "fastdsac":
        mu, log_std = fastdsac.policy_log_std(raw, hp)
        value = lambda a: gaussian_head(st.critic(batch.obs, a))[0].min(dim=0).values  # noqa: E731
    else:
        mu, raw_log_std = raw.chunk(2, dim=-1)
        log_std = fastsac.bounded_log_std(raw_log_std, hp.log_std_min, hp.log_std_max)
        value = lambda a: c51.expected_value(torch.softmax(st.critic(batch.obs, a), -1), st.algo.atoms).mean(0)  # noqa: E731
    pre = mu + log_std.exp() * eps
    action = torch.tanh(pre)
    log_prob = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)
                - torch.log(1 - action.pow(2) + 1e-6)).sum(-1)
    loss = (st.algo.temperature.alpha * log_prob - value(action)).mean()
    return loss - weight * value(torch.tanh(mu)).mean()


@pytest.mark.parametrize("algorithm", ["fastdsac", "fastsac"])
@pytest.mark.parametrize("weight", [0.0, 0.7])
def test_the_actor_climbs_the_sampled_and_optionally_the_deterministic_actions_value(algorithm, weight):
    lrn = learner(algorithm, mean_action_q=weight)
    batch = random_batch(4)
    rng = lrn.state.update_gen.get_state()
    with torch.no_grad():
        expected = hand_actor_loss(algorithm, lrn, batch, weight)
    lrn.state.update_gen.set_state(rng)
    update_actor = fastdsac.update_actor if algorithm == "fastdsac" else fastsac.update_actor
    got = update_actor(lrn.state, batch)["actor_loss"]
    assert torch.allclose(got, expected, rtol=1e-5, atol=1e-6), (float(got), float(expected))


def test_the_deterministic_actions_value_moves_the_actor():
    plain, both = learner("fastdsac"), learner("fastdsac", mean_action_q=1.0)
    batch = random_batch(5)
    fastdsac.update_actor(plain.state, batch)
    fastdsac.update_actor(both.state, batch)
    assert any(not torch.equal(a, b) for a, b in zip(params(plain.state.actor), params(both.state.actor)))
    with pytest.raises(ValueError, match="mean_action_q"):
        learner("fastdsac", mean_action_q=-1.0)
    with pytest.raises(ValueError, match="mean_action_q"):
        learner("fasttd3", mean_action_q=1.0)   # FastTD3's actor is deterministic already: no such key


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_target_critic_is_a_polyak_average(algorithm):
    lrn = learner(algorithm)
    lrn.update(random_batch(0))            # targets and critics now differ
    target0 = params(lrn.state.critic_target)
    lrn.update(random_batch(1))
    tau = lrn.hp.tau
    for old, new, online in zip(target0, params(lrn.state.critic_target), params(lrn.state.critic)):
        torch.testing.assert_close(new, (1 - tau) * old + tau * online, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_act_stays_in_bounds_and_uses_the_collector_copy(algorithm):
    lrn = learner(algorithm)
    obs = random_obs(N, torch.Generator().manual_seed(3))
    for _ in range(5):
        action = lrn.act(obs)
        assert action.shape == (N, A) and action.abs().max() <= 1.0 and not action.requires_grad
    for i in range(4):
        lrn.update(random_batch(i))
    collector = params(lrn.state.collector)
    assert any(not torch.equal(a, b) for a, b in zip(collector, params(lrn.state.actor)))
    lrn.sync_collector()
    assert all(torch.equal(a, b) for a, b in zip(params(lrn.state.collector), params(lrn.state.actor)))


@pytest.mark.parametrize("algorithm,key,field", [("fasttd3", "collection_noise", "noise_std"),
                                                 ("fastdsac", "scale_range", "dem_scale")])
def test_episode_end_resamples_only_finished_envs(algorithm, key, field):
    lrn = learner(algorithm)
    before = getattr(lrn.state.algo, field).clone()
    done = torch.tensor([True, False, True, False, False, False, False, True])
    lrn.on_episode_end(done)
    after = getattr(lrn.state.algo, field)
    lo, hi = getattr(lrn.hp, key)
    assert torch.equal(after[~done], before[~done]) and not torch.equal(after[done], before[done])
    assert after.min() >= lo and after.max() <= hi


def test_fastsac_episode_end_is_a_no_op():
    learner("fastsac").on_episode_end(torch.ones(N, dtype=torch.bool))


def test_terminated_transitions_do_not_bootstrap():
    batch = random_batch(0, terminated=1)
    batch = batch._replace(reward=torch.linspace(-9, 9, B))
    lrn = learner("fasttd3")
    target, value = fasttd3.compute_target(lrn.state, batch)
    torch.testing.assert_close(c51.expected_value(target, lrn.state.algo.atoms), batch.reward, rtol=0, atol=1e-4)
    lrn = learner("fastsac")
    target, _ = fastsac.compute_target(lrn.state, batch)
    for k in range(2):
        torch.testing.assert_close(c51.expected_value(target[k], lrn.state.algo.atoms), batch.reward, rtol=0, atol=1e-4)
    lrn = learner("fastdsac")
    y, y_hat = fastdsac.compute_target(lrn.state, batch)
    torch.testing.assert_close(y, 0.4 * batch.reward)
    torch.testing.assert_close(y_hat, 0.4 * batch.reward)


def test_truncated_transitions_bootstrap_from_the_stored_next_obs():
    batch = random_batch(0, terminated=0)
    batch = batch._replace(reward=torch.zeros(B))
    lrn = learner("fasttd3")
    _, value = fasttd3.compute_target(lrn.state, batch)
    assert value.abs().min() > 0
    lrn = learner("fastdsac")
    state, hp = lrn.state, lrn.hp
    saved = state.update_gen.get_state()
    y, y_hat = fastdsac.compute_target(state, batch)
    # recompute by hand from the same random draws: y = 0.4 r + gamma (min_k mu'_k - alpha log pi')
    state.update_gen.set_state(saved)
    with torch.no_grad():
        action, log_prob = fastdsac.sample(state.actor, batch.next_obs, hp, state.update_gen)
        mu, std = gaussian_head(state.critic_target(batch.next_obs, action))
        zeta = torch.randn(mu.shape, generator=state.update_gen).clamp(-3, 3)
    k = mu.argmin(dim=0, keepdim=True)
    alpha = hp.alpha_init
    torch.testing.assert_close(y, hp.gamma * (mu.gather(0, k)[0] - alpha * log_prob))
    torch.testing.assert_close(y_hat, hp.gamma * ((mu + zeta * std).gather(0, k)[0] - alpha * log_prob))


def test_dsac_critic_loss_gradient_signs():
    """dL/dmu = w Huber'(mu - y): the mean moves towards y. dL/dsigma = w (s^2 - Huber(mu - y^)) / s:
    in the quadratic zone sigma grows when |mu - y^| > sqrt(2) sigma and shrinks when smaller."""
    mu = torch.tensor([[0.0, 0.0, 0.0, 0.0, 100.0]], requires_grad=True)
    std = torch.ones(1, 5, requires_grad=True)
    y = torch.tensor([2.0, -2.0, 0.0, 0.0, 0.0])
    y_hat = torch.tensor([0.0, 0.0, 3.0, 0.5, 0.0])
    m = torch.tensor([1.0])   # running std = sigma: weight 1
    fastdsac.critic_loss(mu, std, y, y_hat, m, huber_delta=50.0).backward()
    g_mu, g_std = mu.grad[0] * 5, std.grad[0] * 5           # undo the batch mean
    assert g_mu[0] < 0 and g_mu[1] > 0                      # descent moves mu up to 2 / down to -2
    torch.testing.assert_close(g_mu[:4], torch.tensor([-2.0, 2.0, 0.0, 0.0]), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(g_mu[4], torch.tensor(50.0))  # Huber: gradient capped at delta
    assert g_std[2] < 0                                     # |mu - y^| = 3 > sqrt(2): sigma grows
    assert g_std[3] > 0                                     # |mu - y^| = 0.5 < sqrt(2): sigma shrinks
    torch.testing.assert_close(g_std[:4], torch.tensor([1.0, 1.0, 1 - 4.5, 1 - 0.125]), rtol=1e-4, atol=1e-4)


def test_dsac_loss_weight_uses_running_std():
    mu, std = torch.zeros(1, 2, requires_grad=True), torch.tensor([[0.1, 10.0]])
    y = torch.tensor([1.0, 1.0])
    fastdsac.critic_loss(mu, std, y, torch.zeros(2), torch.tensor([1.0]), 50.0).backward()
    # weights clamp(1 / s^2, 0.1, 10): 10 for the confident sample, 0.1 for the uncertain one
    torch.testing.assert_close(mu.grad[0] * 2, torch.tensor([-10.0, -0.1]), rtol=1e-4, atol=1e-6)


def test_dsac_running_std_initialised_from_first_batch_then_ema():
    # obs_norm off: with it the update first moves the feature statistics, so the critic's std read here
    # before the update would not be the one the update sees
    lrn = learner("fastdsac", obs_norm=False)
    assert (lrn.state.algo.running_std < 0).all()
    batch = random_batch(0)
    with torch.no_grad():
        _, std = gaussian_head(lrn.state.critic(batch.obs, batch.action))
    lrn.update(batch)
    torch.testing.assert_close(lrn.state.algo.running_std, std.mean(-1))
    first = lrn.state.algo.running_std.clone()
    batch2 = random_batch(1)
    with torch.no_grad():
        _, std2 = gaussian_head(lrn.state.critic(batch2.obs, batch2.action))
    lrn.update(batch2)
    torch.testing.assert_close(lrn.state.algo.running_std, 0.995 * first + 0.005 * std2.mean(-1))


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_same_seed_same_parameters(algorithm):
    runs = []
    for seed in (0, 0, 1):
        lrn = learner(algorithm, seed=seed)
        obs = random_obs(N, torch.Generator().manual_seed(9))
        for i in range(3):
            lrn.act(obs)
            lrn.update(random_batch(i))
        runs.append(params(lrn.state.actor) + params(lrn.state.critic) + [lrn.act(obs)])
    assert all(torch.equal(a, b) for a, b in zip(runs[0], runs[1]))
    assert any(not torch.equal(a, b) for a, b in zip(runs[0], runs[2]))


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_obs_norm_feeds_every_network_the_replay_statistics(algorithm):
    lrn = learner(algorithm, obs_norm=True, layer_norm=True)
    nets = (lrn.state.actor, lrn.state.critic, lrn.state.critic_target)
    seen = {id(net): [] for net in nets}  # each network's features of each batch, with its beta of that moment
    for i in range(3):
        batch = random_batch(i)
        for net in nets:
            seen[id(net)].append(net.transform.features(batch.obs).detach())
        lrn.update(batch)
    for net in nets:
        feats = torch.cat(seen[id(net)], dim=-2)
        assert float(net.transform.feat_count) == 3 * B
        torch.testing.assert_close(net.transform.feat_mean, feats.mean(-2, keepdim=net is not lrn.state.actor),
                                   rtol=1e-4, atol=1e-4)
    assert float(lrn.state.collector.transform.feat_count) == 0  # the collector gets them with the weights
    lrn.sync_collector()
    assert torch.equal(lrn.state.collector.transform.feat_mean, lrn.state.actor.transform.feat_mean)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("norms", [{}, {"obs_norm": True, "layer_norm": True}])
def test_state_dict_round_trip_continues_identically(algorithm, norms):
    a = learner(algorithm, seed=0, **norms)
    for i in range(3):
        a.update(random_batch(i))
    b = learner(algorithm, seed=123, **norms)
    b.load_state_dict(a.state_dict())
    ma, mb = a.update(random_batch(7)), b.update(random_batch(7))
    assert all(torch.equal(ma[k], mb[k]) for k in ma)
    assert all(torch.equal(x, y) for x, y in zip(params(a.state.critic), params(b.state.critic)))
    obs = random_obs(N, torch.Generator().manual_seed(2))
    assert torch.equal(a.act(obs), b.act(obs))
    with pytest.raises(ValueError):
        learner("fastsac").load_state_dict(learner("fasttd3").state_dict())


def test_state_dict_groups_the_algorithm_state_and_names_what_is_missing():
    data = learner("fastdsac").state_dict()
    assert set(data["algo"]) == {"temperature", "running_std", "dem_scale"}
    assert set(data["algo"]["temperature"]) == {"log_alpha", "opt", "target_entropy"}
    assert not {"log_alpha", "running_std", "explore_scale"} & set(data)  # nothing left flat
    del data["algo"]["temperature"]["opt"]
    with pytest.raises(KeyError, match=r"\['algo'\]\['temperature'\] lacks opt"):
        learner("fastdsac").load_state_dict(data)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_checkpoint_of_the_flat_layout_loads_and_continues_identically(algorithm):
    """A checkpoint written by the code before ``state.algo`` (tests/fixtures/legacy_learners/make.py):
    the loaded learner acts and updates as the old learner did next. To float rounding, not bit for bit:
    the fixture was written on one CPU and torch's kernels round differently on another (AVX-512 or
    not); a state loaded into the wrong place differs by orders of magnitude more."""
    payload = load_checkpoint(LEGACY / f"{algorithm}.pt")
    saved, probe = payload["learner"], payload["extra"]["probe"]
    assert "algo" not in saved and {"atoms", "log_alpha"} & set(saved)  # the old, flat layout indeed
    # the recipe's later options, off as they were when the fixture was written (the goal sine and cosine widen the input)
    written_with = {"goal_sincos": False, "action_headroom": 1.0, **probe["overrides"]}
    hp = load_hparams(algorithm, "turtlebot2", "cpu", written_with)
    lrn = make_learner(algorithm, hp, LAYOUT, A, 4, "cpu", seed=99)
    lrn.load_state_dict(saved)
    assert lrn.num_updates == 3
    torch.testing.assert_close(lrn.act(probe["obs"]), probe["action"], rtol=1e-5, atol=1e-6)
    obs, action, reward, terminated, next_obs = probe["batch"]   # stored when the 4th field was `terminated`
    metrics = lrn.update(Transition(obs, action, reward, 1.0 - terminated, next_obs))
    assert set(metrics) == set(probe["metrics"])
    for key, value in probe["metrics"].items():
        torch.testing.assert_close(metrics[key], value, rtol=1e-4, atol=1e-6, msg=key)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_each_algorithm_module_satisfies_the_protocol(algorithm):
    module = MODULES[algorithm]
    assert module.__name__ == f"flashnav.learn.{algorithm}"
    assert isinstance(module, AlgorithmModule) and protocol_mismatches(module) == []


def test_protocol_check_fails_for_a_missing_or_misnamed_function():
    partial = types.ModuleType("partial")
    partial.init_state, partial.act, partial.update = fasttd3.init_state, fasttd3.act, fasttd3.update
    assert not isinstance(partial, AlgorithmModule)
    assert protocol_mismatches(partial) == ["on_episode_end: missing"]
    partial.on_episode_end = lambda state, dones: None
    assert protocol_mismatches(partial) == ["on_episode_end: parameters ['state', 'dones'], "
                                            "expected ['state', 'done']"]


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_policy_is_deterministic_tanh_mean(algorithm):
    lrn = learner(algorithm)
    obs = random_obs(N, torch.Generator().manual_seed(4))
    action = lrn.policy(obs)
    assert torch.equal(action, lrn.policy(obs)) and action.abs().max() <= 1
    torch.testing.assert_close(action, torch.tanh(lrn.state.actor(obs)[:, :A]))


def test_make_learner_rejects_mismatched_hparams():
    with pytest.raises(TypeError):
        make_learner("fastsac", load_hparams("fasttd3", "go2"), LAYOUT, A, N)
    with pytest.raises(ValueError):
        make_learner("ppo", load_hparams("fasttd3", "go2"), LAYOUT, A, N)
