"""Gymnasium adapters: a single-environment view with numpy observations (ids registered by
``import flashnav``).

``gymnasium.make("flashnav/TurtleBot2-v0")`` (after ``import flashnav``) gives :class:`NavEnv`;
``gymnasium.make_vec("flashnav/TurtleBot2-v0", num_envs=N, vectorization_mode="vector_entry_point")``
gives the batched :class:`flashnav.sim.env.NavVecEnv` with torch tensors.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from flashnav.sim.env import make_env

class NavEnv(gym.Env):
    """One navigation environment (numpy in, numpy out) on top of a one-slot NavVecEnv.

    The episode ends at termination or truncation; ``reset`` starts the next one.
    """

    metadata = {"render_modes": []}

    def __init__(self, robot: str = "turtlebot2", map=None, raycaster: str | None = None, seed: int = 0):
        self._vec = make_env(robot, 1, map=map, device="cpu", seed=seed, raycaster=raycaster)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space

    @property
    def map(self):
        return self._vec.map

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, _ = self._vec.reset(seed=seed)
        return obs[0].numpy(), {}

    def step(self, action):
        action = torch.as_tensor(np.asarray(action, dtype=np.float32)).reshape(1, 2)
        _, reward, terminated, truncated, info = self._vec.step(action)
        obs = info["final_obs"][0].numpy()  # the observation before any automatic reset
        extra = {"success": bool(info["success"][0]), "collision": bool(info["collision"][0])}
        return obs, float(reward[0]), bool(terminated[0]), bool(truncated[0]), extra


def make_vec_env(num_envs: int = 1, robot: str = "turtlebot2", **kwargs):
    return make_env(robot, num_envs, **kwargs)

