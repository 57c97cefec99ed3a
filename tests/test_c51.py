"""C51 projection: mass conservation and agreement with a per-sample, per-atom loop."""

import math

import pytest
import torch

from flashnav.learn import c51


def brute_force_projection(probs, reward, bootstrap, gamma, atoms):
    """The textbook algorithm, one sample and one atom at a time (Python floats)."""
    k = len(atoms)
    v_min, v_max = float(atoms[0]), float(atoms[-1])
    delta = (v_max - v_min) / (k - 1)
    out = torch.zeros_like(probs)
    for i in range(probs.shape[0]):
        for j in range(k):
            shifted = float(reward[i]) + float(bootstrap[i]) * gamma * float(atoms[j])
            pos = (min(max(shifted, v_min), v_max) - v_min) / delta
            lo, hi = math.floor(pos), math.ceil(pos)
            if lo == hi:   # exactly on a support point: all mass there
                out[i, lo] += probs[i, j]
            else:
                out[i, lo] += probs[i, j] * (hi - pos)
                out[i, hi] += probs[i, j] * (pos - lo)
    return out


def random_probs(shape, seed):
    gen = torch.Generator().manual_seed(seed)
    return torch.softmax(3 * torch.randn(shape, generator=gen, dtype=torch.float64), dim=-1)


def test_matches_brute_force_with_exact_landings_and_out_of_range_returns():
    # integer support with unit spacing and gamma 0.5: many shifted atoms land exactly on support points
    atoms = torch.linspace(-8.0, 8.0, 17, dtype=torch.float64)
    reward = torch.tensor([0.0, 1.0, -3.0, 2.5, 8.0, -8.0, 30.0, -30.0, 7.5, 0.25], dtype=torch.float64)
    bootstrap = torch.tensor([1, 1, 0, 1, 0, 0, 1, 0, 1, 1], dtype=torch.float64)
    probs = random_probs((10, 17), seed=0)
    got = c51.project(probs, reward, bootstrap, 0.5, atoms)
    want = brute_force_projection(probs, reward, bootstrap, 0.5, atoms)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    torch.testing.assert_close(got.sum(-1), torch.ones(10, dtype=torch.float64), rtol=0, atol=1e-12)


def test_paper_support_random_rewards_match_and_conserve_mass():
    atoms = c51.support(-20.0, 20.0, 101)
    gen = torch.Generator().manual_seed(1)
    reward = 15 * torch.randn(64, generator=gen)             # many beyond [-20, 20] after shifting
    reward[:8] = torch.tensor([10.0, -10.0, 0.0, 20.0, -20.0, 0.4, 25.0, -25.0])  # terminal-like values
    bootstrap = (torch.rand(64, generator=gen) > 0.3).float()
    probs = random_probs((64, 101), seed=2).float()
    got = c51.project(probs, reward, bootstrap, 0.97, atoms)
    want = brute_force_projection(probs, reward, bootstrap, 0.97, atoms)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-5)
    torch.testing.assert_close(got.sum(-1), torch.ones(64), rtol=0, atol=1e-5)
    assert (got >= 0).all()


def test_terminated_projection_is_the_reward_within_the_support():
    atoms = c51.support(-10.0, 10.0, 101)
    reward = torch.tensor([-10.0, -3.3, 0.0, 0.05, 7.0, 10.0])
    probs = random_probs((6, 101), seed=3).float()
    projected = c51.project(probs, reward, torch.zeros(6), 0.97, atoms)
    torch.testing.assert_close(c51.expected_value(projected, atoms), reward, rtol=0, atol=1e-5)


def test_returns_beyond_the_support_pile_up_at_its_ends():
    atoms = c51.support(-10.0, 10.0, 11)
    probs = random_probs((2, 11), seed=4).float()
    projected = c51.project(probs, torch.tensor([100.0, -100.0]), torch.ones(2), 0.97, atoms)
    torch.testing.assert_close(projected[0, -1], torch.tensor(1.0))
    torch.testing.assert_close(projected[1, 0], torch.tensor(1.0))


def test_twin_leading_dimension_equals_per_critic_projection():
    atoms = c51.support(-20.0, 20.0, 101)
    gen = torch.Generator().manual_seed(5)
    reward, bootstrap = 5 * torch.randn(32, generator=gen), (torch.rand(32, generator=gen) > 0.5).float()
    probs = random_probs((2, 32, 101), seed=6).float()
    both = c51.project(probs, reward, bootstrap, 0.97, atoms)
    for k in range(2):
        torch.testing.assert_close(both[k], c51.project(probs[k], reward, bootstrap, 0.97, atoms))


def test_support_validation():
    with pytest.raises(ValueError):
        c51.support(1.0, -1.0, 51)
    assert c51.support(-10, 10, 101).shape == (101,)
