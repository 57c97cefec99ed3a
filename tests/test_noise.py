"""Coloured collection noise (``algo.noise_color``, flashnav/learn/noise.py): the sequences' law, and
what each learner's collection does with it."""

import functools
import math

import numpy as np
import pytest
import torch

from flashnav.learn import fastdsac, fastsac
from flashnav.learn.hparams import load_hparams
from flashnav.learn.noise import NOISE_STEPS, ColoredNoise, powerlaw_noise
from flashnav.names import ALGORITHMS
from tests import test_learners
from tests.test_learners import random_obs

N, A = 64, 2
learner = functools.partial(test_learners.learner, envs=N)  # the learners' test fixture, with more envs


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def slow_periodogram(x: np.ndarray) -> np.ndarray:
    """|DFT|^2 / n of each row at k = 1 .. n // 2, summed term by term (the obvious definition)."""
    n = x.shape[-1]
    t = np.arange(n)
    out = []
    for k in range(1, n // 2 + 1):
        c = (x * np.cos(2 * np.pi * k * t / n)).sum(-1)
        s = (x * np.sin(2 * np.pi * k * t / n)).sum(-1)
        out.append((c ** 2 + s ** 2) / n)
    return np.stack(out, -1)


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0])
@pytest.mark.parametrize("steps", [128, 127])
def test_sequences_have_unit_variance_zero_mean_and_a_1_over_f_beta_spectrum(beta, steps):
    x = powerlaw_noise((3000,), beta, steps, gen(1), "cpu")
    assert x.shape == (3000, steps) and x.dtype == torch.float32
    assert x.mean(-1).abs().max() < 1e-5                     # every sequence's mean is removed
    assert abs(float(x.var()) - 1.0) < 0.05                   # unit variance on average ...
    per_step = x.var(dim=0)                                   # ... at every step alike (a stationary law)
    assert float((per_step - 1).abs().mean()) < 0.1
    power = slow_periodogram(x.double().numpy()).mean(0)      # the spectrum, averaged over sequences
    k = np.arange(1, steps // 2 + 1)
    keep = k < steps // 2                                     # the Nyquist bin of an even length has its own law
    slope = np.polyfit(np.log(k[keep]), np.log(power[keep]), 1)[0]
    assert abs(slope + beta) < 0.1, slope
    assert np.allclose(power[keep] / power[keep].mean(), k[keep] ** -beta / (k[keep] ** -beta).mean(), rtol=0.25)


def test_colour_correlates_successive_draws():
    lag1 = []
    for beta in (0.0, 0.5, 1.0, 2.0):
        x = powerlaw_noise((2000,), beta, NOISE_STEPS, gen(2), "cpu")
        lag1.append(float((x[:, 1:] * x[:, :-1]).mean() / x.pow(2).mean()))
    assert abs(lag1[0]) < 0.02 and lag1 == sorted(lag1) and lag1[2] > 0.5 and lag1[3] > 0.9


def test_too_short_a_sequence_is_refused():
    with pytest.raises(ValueError, match="at least 2 steps"):
        powerlaw_noise((4,), 1.0, 1, gen(), "cpu")


def test_draws_walk_through_a_block_then_draw_a_fresh_one():
    g = gen(3)
    noise = ColoredNoise.create(1.0, N, A, g, "cpu", steps=16)
    first = noise.block.clone()
    for t in range(16):
        assert torch.equal(noise.draw(g), first[..., t])
    fresh = noise.draw(g)
    assert noise.step == 1 and not torch.equal(noise.block, first) and torch.equal(fresh, noise.block[..., 0])
    again = ColoredNoise.create(1.0, N, A, gen(3), "cpu", steps=16)   # the same generator state, the same block
    assert torch.equal(again.block, first)


def test_one_exponent_per_action_colours_each_action_alone():
    x = powerlaw_noise((2000, 3), (0.0, 1.0, 2.0), NOISE_STEPS, gen(7), "cpu")
    lag1 = (x[..., 1:] * x[..., :-1]).mean((0, 2)) / x.pow(2).mean((0, 2))
    assert abs(float(lag1[0])) < 0.02 and 0.5 < float(lag1[1]) < 0.9 and float(lag1[2]) > 0.9
    assert (x.var((0, 2)) - 1).abs().max() < 0.05                       # unit variance for every exponent
    # the Gaussian draws are the same as for one exponent: equal exponents give the same sequences bit for bit,
    # and each action's sequences are those of its exponent alone
    assert torch.equal(powerlaw_noise((50, 2), (1.0, 1.0), 64, gen(8), "cpu"), powerlaw_noise((50, 2), 1.0, 64, gen(8), "cpu"))
    mixed = powerlaw_noise((50, 2), (0.0, 2.0), 64, gen(8), "cpu")
    assert torch.allclose(mixed[:, 0], powerlaw_noise((50, 2), 0.0, 64, gen(8), "cpu")[:, 0], atol=1e-6)
    assert torch.allclose(mixed[:, 1], powerlaw_noise((50, 2), 2.0, 64, gen(8), "cpu")[:, 1], atol=1e-6)
    with pytest.raises(ValueError, match="3 exponents"):
        powerlaw_noise((50, 2), (0.0, 1.0, 2.0), 64, gen(8), "cpu")


def action_lag1(lrn, steps=120, per_action=False):
    """Lag-1 autocorrelation of the exploration actions on a fixed observation (each env's mean removed),
    over all actions or ``[A]`` per action."""
    obs = random_obs(N, gen(4))
    actions = torch.stack([lrn.act(obs) for _ in range(steps)], -1)          # [N, A, T]
    centred = actions - actions.mean(-1, keepdim=True)
    dims = (0, 2) if per_action else (0, 1, 2)
    return (centred[..., 1:] * centred[..., :-1]).mean(dims) / centred.pow(2).mean(dims)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_each_learner_collects_with_correlated_draws_only_when_asked(algorithm):
    white, pink = learner(algorithm), learner(algorithm, noise_color=1.0)
    assert white.state.noise is None and pink.state.noise is not None
    assert abs(float(action_lag1(white))) < 0.1
    assert float(action_lag1(pink)) > 0.4


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_a_list_of_exponents_colours_the_actions_one_by_one(algorithm):
    turn_only = learner(algorithm, noise_color=[0, 1])      # the TurtleBot2: forward speed white, turn rate pink
    assert turn_only.state.noise.beta == (0.0, 1.0)
    forward, turn = action_lag1(turn_only, per_action=True).tolist()
    assert abs(forward) < 0.1 and turn > 0.4
    assert learner(algorithm, noise_color=[0, 0]).state.noise is None   # every exponent 0: white, from collect_gen
    with pytest.raises(ValueError, match=r"algo.noise_color has 3 exponents .* \(2 for this robot\)"):
        learner(algorithm, noise_color=[0, 1, 1])


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_white_noise_is_the_collection_generator_drawn_step_by_step(algorithm):
    # noise_color 0 (every recipe): the exploration draw is torch.randn from collect_gen, as before the option
    lrn = learner(algorithm)
    obs = random_obs(N, gen(5))
    saved = lrn.state.collect_gen.get_state()
    action = lrn.act(obs)
    lrn.state.collect_gen.set_state(saved)
    eps = torch.randn((N, A), generator=lrn.state.collect_gen)
    with torch.no_grad():
        raw = lrn.state.collector(obs)
        if algorithm == "fasttd3":
            expected = (torch.tanh(raw) + lrn.state.algo.noise_std * eps).clamp(-1, 1)
        elif algorithm == "fastsac":
            mu, log_std = fastsac.policy_log_std(raw, lrn.hp)
            expected = torch.tanh(mu + log_std.exp() * eps)
        else:
            mu, log_std = fastdsac.policy_log_std(raw, lrn.hp, lrn.state.algo.dem_scale)
            expected = torch.tanh(mu + log_std.exp() * eps)
    assert torch.equal(action, expected.clamp(-1, 1))


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_the_noise_block_and_its_position_travel_with_the_learner_state(algorithm):
    a = learner(algorithm, noise_color=1.0)
    obs = random_obs(N, gen(6))
    for _ in range(NOISE_STEPS - 3):      # near the end of the first block: the next block is drawn after the load
        a.act(obs)
    b = learner(algorithm, seed=9, noise_color=1.0)
    b.load_state_dict(a.state_dict())
    assert b.state.noise.step == a.state.noise.step
    for _ in range(6):
        assert torch.equal(a.act(obs), b.act(obs))
    milder = learner(algorithm, noise_color=[0.5, 0.5])   # the exponent is configuration: a loaded state keeps it
    milder.load_state_dict(a.state_dict())
    assert milder.state.noise.beta == (0.5, 0.5) and milder.state.noise.step == a.state.noise.step
    white = learner(algorithm).state_dict()              # a coloured run may start from a white one's state
    c = learner(algorithm, noise_color=1.0)
    block = c.state.noise.block.clone()
    c.load_state_dict(white)
    assert torch.equal(c.state.noise.block, block) and c.state.noise.step == 0


def test_a_colour_outside_0_to_2_is_named():
    with pytest.raises(ValueError, match="noise_color"):
        load_hparams("fastdsac", "turtlebot2", "paper", {"noise_color": 3})
    with pytest.raises(ValueError, match="noise_color"):
        load_hparams("fasttd3", "turtlebot2", "paper", {"noise_color": -0.5})
    assert math.isclose(load_hparams("fastsac", "go2", "cpu", {"noise_color": 1}).noise_color, 1.0)
    with pytest.raises(ValueError, match="noise_color"):
        load_hparams("fastdsac", "turtlebot2", "paper", {"noise_color": [0, 2.5]})
    with pytest.raises(ValueError, match="noise_color"):
        load_hparams("fastdsac", "turtlebot2", "paper", {"noise_color": []})
    assert load_hparams("fastdsac", "go2", "paper", {"noise_color": [0, 1]}).noise_color == (0.0, 1.0)
