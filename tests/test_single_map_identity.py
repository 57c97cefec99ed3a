"""The single-map environment is bit-identical to the code before many-map support (issue 15).

``tests/fixtures/single_map_trajectory.npz`` holds a seeded rollout of every robot x CPU raycaster
recorded with main at 86fe09a (before ``make_env(maps=...)``); rerun this file as a script with that
version of flashnav to rewrite it (``python tests/test_single_map_identity.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from flashnav.sim.env import make_env

FIXTURE = Path(__file__).parent / "fixtures" / "single_map_trajectory.npz"
CASES = [(robot, rc) for robot in ("turtlebot2", "go2") for rc in ("exact", "exact-torch", "march")]


def rollout(robot: str, raycaster: str, steps: int = 40, n: int = 6, seed: int = 3, **env_kwargs) -> dict:
    """Seeded random actions (biased forward, so that episodes end and slots reset): every output."""
    env = make_env(robot, n, seed=seed, raycaster=raycaster, **env_kwargs)
    obs, _ = env.reset(seed=seed)
    gen = torch.Generator().manual_seed(seed)
    out: dict[str, list] = {"obs": [obs], "reward": [], "terminated": [], "truncated": [], "final_obs_done": []}
    for _ in range(steps):
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        action[:, 0] = action[:, 0] * 0.5 + 0.5
        obs, reward, terminated, truncated, info = env.step(action)
        out["obs"].append(obs)
        out["reward"].append(reward)
        out["terminated"].append(terminated)
        out["truncated"].append(truncated)
        out["final_obs_done"].append(info["final_obs"][terminated | truncated])
    return {k: torch.cat(v).numpy() if k == "final_obs_done" else torch.stack(v).numpy() for k, v in out.items()}


@pytest.mark.parametrize("robot,raycaster", CASES)
@pytest.mark.parametrize("as_list", [False, True], ids=["map", "maps=[one]"])
def test_single_map_matches_saved_trajectory(robot, raycaster, as_list):
    saved = np.load(FIXTURE)
    kwargs = {"maps": [robot]} if as_list else {}
    got = rollout(robot, raycaster, **kwargs)
    assert saved[f"{robot}/{raycaster}/terminated"].any(), "the fixture must exercise resets"
    for key, value in got.items():
        ref = saved[f"{robot}/{raycaster}/{key}"]
        assert value.shape == ref.shape and value.dtype == ref.dtype, key
        assert np.array_equal(value, ref), f"{robot}/{raycaster}: {key} differs from the saved trajectory"


if __name__ == "__main__":
    torch.set_num_threads(1)
    data = {f"{robot}/{rc}/{k}": v for robot, rc in CASES for k, v in rollout(robot, rc).items()}
    np.savez_compressed(FIXTURE, **data)
    print(f"wrote {FIXTURE}")
