"""``lidar.noise_std_max``: each episode draws its range-noise level from [noise_std, noise_std_max]; off (None),
no level exists and nothing is drawn (the default step is untouched); a sparse reset draws only its slots' levels;
a slot's noise has its own level."""

from __future__ import annotations

import pytest
import torch

from flashnav.presets import load_robot
from flashnav.sim.env import make_env

N = 64


def _env(**lidar):
    return make_env(load_robot("turtlebot2", **{f"lidar.{k}": v for k, v in lidar.items()}), N, seed=2)


def test_levels_are_drawn_per_episode_within_the_range_and_only_for_reset_slots():
    assert _env().noise_std is None and _env(noise_std=0.02).noise_std is None
    env = _env(noise_std=0.02, noise_std_max=0.1)
    env.reset(seed=4)
    levels = env.noise_std.clone()
    assert ((levels >= 0.02) & (levels <= 0.1)).all() and levels.std() > 0.01
    env.reset(options={"reset_mask": torch.arange(N) < 8})
    assert not torch.equal(env.noise_std[:8], levels[:8]) and torch.equal(env.noise_std[8:], levels[8:])


def test_each_slot_is_noisy_at_its_own_level():
    """Slots at level 0 see the clean scan exactly; slots at 0.2 m do not (same poses, same map)."""
    clean, noisy = _env(), _env(noise_std=0.0, noise_std_max=0.2)
    clean.reset(seed=4)
    noisy.reset(seed=4)
    noisy.noise_std[: N // 2] = 0.0
    noisy.noise_std[N // 2:] = 0.2
    still = torch.tensor([-1.0, 0.0]).expand(N, 2)  # stand still: both envs keep the reset's poses
    a, *_ = clean.step(still)
    b, *_ = noisy.step(still)
    assert torch.equal(clean.pose, noisy.pose)
    s = clean.preset.lidar.sectors
    assert torch.equal(a[: N // 2, :s], b[: N // 2, :s])
    assert (a[N // 2:, :s] != b[N // 2:, :s]).float().mean() > 0.5


def test_a_range_that_is_no_range_is_named():
    with pytest.raises(ValueError, match="noise_std_max"):
        load_robot("turtlebot2", **{"lidar.noise_std": 0.05, "lidar.noise_std_max": 0.05})
