"""Networks: IPAPRec transform, batched twin critic, actor heads, deployable policy."""

import math

import pytest
import torch
from torch import nn

from flashnav import presets
from flashnav.learn import networks
from flashnav.learn.networks import (BETA_MARGIN, Actor, DeterministicActor, IPAPRec, ObsLayout, TwinCritic,
                                     bounded_log_std, dem_log_weights, gaussian_head, squashed_gaussian)

TB2 = ObsLayout(sectors=30, inscribed_radius=0.2, max_range=20.0, goal_scale=(15.0, math.pi),
                velocity_scales=(0.5, math.pi / 4))
GO2 = ObsLayout(sectors=30, inscribed_radius=0.205, max_range=20.0, goal_scale=15.0,
                velocity_scales=(0.5, 0.5, math.pi / 4))


def random_obs(layout, n, seed=0, lidar_low=None):
    gen = torch.Generator().manual_seed(seed)
    low = layout.inscribed_radius if lidar_low is None else lidar_low
    lidar = low + (layout.max_range - low) * torch.rand(n, layout.sectors, generator=gen) ** 3
    goal = torch.stack([15 * torch.rand(n, generator=gen), (2 * torch.rand(n, generator=gen) - 1) * math.pi], -1)
    vel = (2 * torch.rand(n, len(layout.velocity_scales), generator=gen) - 1) * torch.tensor(layout.velocity_scales)
    return torch.cat([lidar, goal, vel], -1)


def test_layout_dims_and_from_robot_presets():
    assert TB2.obs_dim == 34 and GO2.obs_dim == 35
    assert GO2.goal_scale == (15.0, math.pi)
    for name, dim, r_in in (("turtlebot2", 34, 0.2), ("go2", 35, 0.205)):
        layout = ObsLayout.from_robot(presets.load_robot(name), 14.0)
        assert layout.obs_dim == dim and layout.inscribed_radius == pytest.approx(r_in)
        assert layout.goal_scale == (14.0, math.pi)  # the map's diagonal, as given
        assert layout.velocity_scales[-1] == pytest.approx(math.pi / 4)
    with pytest.raises(ValueError):
        ObsLayout(30, 0.0, 20.0, 15.0, (0.5, 1.0))


def test_ipaprec_values_at_init():
    transform = IPAPRec(TB2)
    obs = random_obs(TB2, 8)
    beta = transform.beta().item()
    assert beta == pytest.approx(networks.BETA_INIT, abs=1e-6)
    out = transform(obs)
    torch.testing.assert_close(out[:, :30], 1.0 / (obs[:, :30] - beta))
    torch.testing.assert_close(out[:, 30], obs[:, 30] / 15.0)
    torch.testing.assert_close(out[:, 31], obs[:, 31] / math.pi)
    torch.testing.assert_close(out[:, 32:], obs[:, 32:] / torch.tensor([0.5, math.pi / 4]))


@pytest.mark.parametrize("layout", [TB2, GO2])
def test_beta_stays_below_inscribed_radius_after_large_steps(layout):
    transform = IPAPRec(layout)
    # pushing the features up drives beta towards the smallest reading, i.e. the pole
    opt = torch.optim.SGD(transform.parameters(), lr=1e4)
    at_radius = random_obs(layout, 16)
    at_radius[:, :layout.sectors] = layout.inscribed_radius
    for _ in range(50):
        opt.zero_grad()
        (-transform(at_radius).sum()).backward()
        opt.step()
        assert transform.beta().item() < layout.inscribed_radius
    with torch.no_grad():
        transform.rho.fill_(-1e6)          # softplus underflows to exactly 0 in float32
    assert transform.beta().item() <= layout.inscribed_radius - BETA_MARGIN + 1e-7
    out = transform(at_radius)
    assert torch.isfinite(out).all() and out[:, :layout.sectors].max() <= 1 / BETA_MARGIN * 1.001


def test_readings_inside_the_footprint_stay_finite():
    # a post-collision final observation may read below the inscribed radius (even 0)
    transform = IPAPRec(TB2)
    obs = random_obs(TB2, 4, lidar_low=0.0)
    obs[:, :5] = 0.0
    with torch.no_grad():
        transform.rho.fill_(-200.0)
    assert torch.isfinite(transform(obs)).all()
    assert torch.isfinite(IPAPRec(TB2, copies=2)(obs)).all()


def separate_critic(twin: TwinCritic, k: int) -> tuple[IPAPRec, nn.Sequential]:
    """Critic k of the twin as an ordinary IPAPRec + nn.Linear stack with the same weights."""
    transform = IPAPRec(TB2)
    with torch.no_grad():
        transform.rho.copy_(twin.transform.rho[k])
    layers = []
    for i, (w, b) in enumerate(zip(twin.weights, twin.biases)):
        linear = nn.Linear(w.shape[1], w.shape[2])
        with torch.no_grad():
            linear.weight.copy_(w[k].T)
            linear.bias.copy_(b[k, 0])
        layers.append(linear)
        if i < len(twin.weights) - 1:
            if twin.layer_norm:
                norm = nn.LayerNorm(w.shape[2])
                with torch.no_grad():
                    norm.weight.copy_(twin.norm_gains[i][k, 0])
                    norm.bias.copy_(twin.norm_biases[i][k, 0])
                layers.append(norm)
            layers.append(nn.LeakyReLU())
    return transform, nn.Sequential(*layers)


@pytest.mark.parametrize("out_dim,layer_norm", [(101, False), (2, False), (101, True), (2, True)])
def test_batched_twin_critic_equals_two_separate_mlps(out_dim, layer_norm):
    twin = TwinCritic(TB2, 2, (100, 100, 100, 100), out_dim, torch.Generator().manual_seed(0),
                      layer_norm=layer_norm)
    with torch.no_grad():
        twin.transform.rho.copy_(torch.tensor([-1.0, 0.7]))   # different betas per critic
        for p in [*getattr(twin, "norm_gains", []), *getattr(twin, "norm_biases", [])]:
            p.add_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))
    obs, action = random_obs(TB2, 64), torch.rand(64, 2) * 2 - 1
    out = twin(obs, action)
    assert out.shape == (2, 64, out_dim)
    for k in range(2):
        transform, mlp = separate_critic(twin, k)
        torch.testing.assert_close(out[k], mlp(torch.cat([transform(obs), action], -1)), rtol=1e-5, atol=1e-5)


def test_twin_init_draws_like_two_linear_stacks():
    twin = TwinCritic(TB2, 2, (100, 100), 101, torch.Generator().manual_seed(0))
    for w in twin.weights:
        bound = 1 / math.sqrt(w.shape[1])
        assert w.abs().max() <= bound and w.std() > bound / 3
    assert not torch.equal(twin.weights[0][0], twin.weights[0][1])


def test_layer_norm_keeps_the_linear_draws_and_normalises_each_hidden_layer():
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    plain, normed = TwinCritic(TB2, 2, (100, 100), 2, gen()), TwinCritic(TB2, 2, (100, 100), 2, gen(), layer_norm=True)
    assert all(torch.equal(a, b) for a, b in zip(plain.weights, normed.weights))
    actor_plain, actor_normed = Actor(TB2, 2, (100, 100), 3, gen()), Actor(TB2, 2, (100, 100), 3, gen(), layer_norm=True)
    linears = lambda a: [m.weight for m in a.mlp.net if isinstance(m, nn.Linear)]  # noqa: E731
    assert all(torch.equal(a, b) for a, b in zip(linears(actor_plain), linears(actor_normed)))
    norms = [m for m in actor_normed.mlp.net if isinstance(m, nn.LayerNorm)]
    assert [n.normalized_shape for n in norms] == [(100,), (100,)]
    # the first hidden layer's activations, before LeakyReLU, have zero mean and unit variance per sample
    obs = random_obs(TB2, 32)
    pre = actor_normed.mlp.net[1](actor_normed.mlp.net[0](actor_normed.transform(obs)))
    torch.testing.assert_close(pre.mean(-1), torch.zeros(32), atol=1e-5, rtol=0)
    torch.testing.assert_close(pre.var(-1, unbiased=False), torch.ones(32), atol=1e-3, rtol=0)


def test_actor_output_init_small_by_default_and_uniform_at_zero():
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    small, uniform = Actor(TB2, 2, (100, 100), 3, gen()), Actor(TB2, 2, (100, 100), 3, gen(), out_init_std=0.0)
    out_small, out_uniform = small.mlp.net[-1], uniform.mlp.net[-1]
    assert out_small.weight.std().item() == pytest.approx(networks.ACTOR_OUT_INIT_STD, rel=0.2)
    assert torch.count_nonzero(out_small.bias) == 0
    bound = 1 / math.sqrt(100)  # the uniform draw every other layer gets (PyTorch's nn.Linear default)
    assert out_uniform.weight.abs().max() <= bound and out_uniform.weight.std() > bound / 3
    assert torch.count_nonzero(out_uniform.bias) > 0
    hidden = lambda a: [m.weight for m in a.mlp.net[:-1] if isinstance(m, nn.Linear)]  # noqa: E731
    assert all(torch.equal(a, b) for a, b in zip(hidden(small), hidden(uniform)))  # same hidden draws
    # the DEM logits (third head) vary with the state only with the uniform draw
    obs = random_obs(TB2, 256)
    logits_small, logits_uniform = small(obs)[:, 4:], uniform(obs)[:, 4:]
    assert logits_uniform.std(0).mean() > 5 * logits_small.std(0).mean()


@pytest.mark.parametrize("layer_norm", [False, True])
def test_detached_critic_trains_the_action_only(layer_norm):
    twin = TwinCritic(TB2, 2, (100, 100), 2, torch.Generator().manual_seed(0), layer_norm=layer_norm)
    action = torch.zeros(8, 2, requires_grad=True)
    twin(random_obs(TB2, 8), action, detach_params=True).sum().backward()
    assert action.grad is not None and action.grad.abs().sum() > 0
    assert all(p.grad is None for p in twin.parameters())


@pytest.mark.parametrize("heads", [1, 2, 3])
def test_actor_heads_and_deterministic_policy(heads):
    actor = Actor(GO2, 2, (100, 100, 100, 100), heads, torch.Generator().manual_seed(0))
    obs = random_obs(GO2, 16)
    raw = actor(obs)
    assert raw.shape == (16, 2 * heads)
    policy = DeterministicActor(actor)
    action = policy(obs)
    torch.testing.assert_close(action, torch.tanh(raw[:, :2]))
    assert action.abs().max() <= 1.0


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch.jit.trace: TorchScript is deprecated upstream
def test_deterministic_policy_exports():
    policy = DeterministicActor(Actor(TB2, 2, (100, 100, 100, 100), 3, torch.Generator().manual_seed(0)))
    obs = random_obs(TB2, 5)
    exported = torch.export.export(policy, (obs,))
    torch.testing.assert_close(exported.module()(obs), policy(obs))
    traced = torch.jit.trace(policy, obs)
    torch.testing.assert_close(traced(random_obs(TB2, 7, seed=1)), policy(random_obs(TB2, 7, seed=1)))


def test_squashed_gaussian_log_prob_matches_torch_distributions():
    gen = torch.Generator().manual_seed(0)
    mu, log_std = 0.5 * torch.randn(256, 2, generator=gen), -1.0 + 0.5 * torch.randn(256, 2, generator=gen)
    noise = torch.randn(256, 2, generator=gen)
    action, log_prob = squashed_gaussian(mu, log_std, noise)
    dist = torch.distributions.TransformedDistribution(
        torch.distributions.Normal(mu, log_std.exp()), [torch.distributions.TanhTransform()])
    torch.testing.assert_close(log_prob, dist.log_prob(action).sum(-1), rtol=1e-3, atol=2e-3)
    assert action.abs().max() < 1.0


def test_log_std_bounds_and_dem_weights():
    raw = torch.linspace(-50, 50, 101)
    log_std = bounded_log_std(raw, -5.0, 0.0)
    assert log_std.min() >= -5.0 and log_std.max() <= 0.0
    logits = torch.tensor([[3.0, -1.0], [1e4, -1e4], [0.0, 0.0]])
    weights = dem_log_weights(logits, temperature=2.0).exp()
    torch.testing.assert_close(weights.sum(-1), torch.full((3,), 2.0))
    torch.testing.assert_close(weights[2], torch.ones(2))
    assert torch.isfinite(dem_log_weights(logits, 2.0, scale=torch.full((3, 1), 2.0))).all()
    sharp = dem_log_weights(logits[:1], 2.0, scale=2.0).exp()
    flat = dem_log_weights(logits[:1], 2.0, scale=0.5).exp()
    assert sharp.max() > weights[0].max() > flat.max()


def test_gaussian_head_std_positive():
    mean, std = gaussian_head(torch.tensor([[1.0, -30.0], [2.0, 3.0]]))
    torch.testing.assert_close(mean, torch.tensor([1.0, 2.0]))
    assert (std > 0).all()


@pytest.mark.parametrize("copies", [0, 2])
def test_running_feature_statistics_equal_those_of_all_batches_together(copies):
    transform = IPAPRec(TB2, copies=copies, normalize=True)
    with torch.no_grad():
        transform.rho.copy_(torch.tensor([-1.0, 0.7]) if copies else torch.tensor(0.3))
    batches = [random_obs(TB2, n, seed=n) for n in (5, 64, 1, 300)]
    for obs in batches:
        transform.update_stats(obs)
    feats = transform.features(torch.cat(batches))  # [N, D] or [C, N, D]
    expected_mean = feats.mean(-2, keepdim=bool(copies))
    expected_var = feats.var(-2, unbiased=False, keepdim=bool(copies))
    torch.testing.assert_close(transform.feat_mean, expected_mean, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(transform.feat_var, expected_var, rtol=1e-4, atol=1e-5)
    assert float(transform.feat_count) == 370
    obs = random_obs(TB2, 7, seed=99)
    torch.testing.assert_close(transform(obs), (transform.features(obs) - expected_mean) / (expected_var + 1e-8).sqrt(),
                               rtol=1e-4, atol=1e-4)


def test_normalisation_is_the_identity_before_any_statistics():
    plain, normed = IPAPRec(TB2), IPAPRec(TB2, normalize=True)
    obs = random_obs(TB2, 9)
    torch.testing.assert_close(normed(obs), plain(obs), rtol=0, atol=1e-6)


@pytest.mark.parametrize("copies", [0, 2])
def test_goal_sincos_puts_the_angles_sine_and_cosine_where_the_angle_was(copies):
    """``goal_sincos``: one feature more (cos after sin, in the angle's place), every other column as without it;
    the goal straight behind reads the same from either side of the wrap (pi and -pi), unlike angle / pi."""
    import dataclasses

    sincos = dataclasses.replace(TB2, goal_sincos=True)
    assert sincos.obs_dim == TB2.obs_dim == 34 and sincos.feature_dim == 35 and TB2.feature_dim == 34
    plain, both = IPAPRec(TB2, copies=copies), IPAPRec(sincos, copies=copies)
    obs = random_obs(TB2, 16)
    a, b = plain(obs), both(obs)
    assert b.shape[-1] == 35
    torch.testing.assert_close(b[..., :31], a[..., :31])
    torch.testing.assert_close(b[..., 33:], a[..., 32:])
    angle = obs[:, 31].expand(b.shape[:-1])
    torch.testing.assert_close(b[..., 31], torch.sin(angle))
    torch.testing.assert_close(b[..., 32], torch.cos(angle))
    behind = obs[:2].clone()
    behind[0, 31], behind[1, 31] = math.pi - 1e-4, -math.pi
    behind[1, :31], behind[1, 32:] = behind[0, :31], behind[0, 32:]
    out, raw = both(behind), plain(behind)
    assert (out[..., 0, :] - out[..., 1, :]).abs().max() < 1e-3
    assert (raw[..., 0, 31] - raw[..., 1, 31]).abs().min() > 1.99


@pytest.mark.parametrize("obs_norm", [False, True])
def test_goal_sincos_networks_take_the_observation_and_widen_their_input(obs_norm):
    import dataclasses

    sincos = dataclasses.replace(TB2, goal_sincos=True)
    actor = Actor(sincos, 2, (32, 32), 3, torch.Generator().manual_seed(0), obs_norm=obs_norm)
    critic = TwinCritic(sincos, 2, (32, 32), 11, torch.Generator().manual_seed(0), obs_norm=obs_norm)
    obs = random_obs(TB2, 5)
    assert actor.mlp.net[0].in_features == 35 and critic.weights[0].shape[1] == 35 + 2
    assert actor(obs).shape == (5, 6) and critic(obs, torch.zeros(5, 2)).shape == (2, 5, 11)
    if obs_norm:
        actor.transform.update_stats(obs)
        assert actor.transform.feat_mean.shape == (35,)
        torch.testing.assert_close(actor.transform.feat_mean[32], torch.cos(obs[:, 31]).mean())
