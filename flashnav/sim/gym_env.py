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

from flashnav.names import DEFAULT_ROBOT
from flashnav.sim.env import make_env

class NavEnv(gym.Env):
    """One navigation environment (numpy in, numpy out) on top of a one-slot NavVecEnv.

    The episode ends at termination or truncation; ``reset`` starts the next one (a ``step`` before it is a
    RuntimeError: the slot was reset inside, and its new start was never returned). ``info`` holds the
    batched env's step info for this slot: ``success``, ``collision``, ``collision_static``, ``collision_agent``,
    ``episode_steps``, ``episode_return`` (where the episode ended) and ``final_pose`` (x, y, yaw).
    No render mode: draw episodes with ``flashnav render`` or :func:`flashnav.rollout.rollout` and
    :func:`flashnav.viz.draw_trajectories`.
    """

    metadata = {"render_modes": []}
    _FLAGS = ("success", "collision", "collision_static", "collision_agent")

    def __init__(self, robot: str = DEFAULT_ROBOT, map=None, raycaster: str | None = None, seed: int = 0,
                 render_mode: str | None = None):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r}: this env has no render mode; draw episodes with "
                             "`flashnav render POLICY --out PNG [--gif]` or flashnav.rollout + flashnav.viz")
        self._vec = make_env(robot, 1, map=map, device="cpu", seed=seed, raycaster=raycaster)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space
        self._ended = False

    @property
    def map(self):
        return self._vec.map

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, _ = self._vec.reset(seed=seed)
        self._ended = False
        return obs[0].numpy(), {}

    def step(self, action):
        if self._ended:
            raise RuntimeError("the episode ended (terminated or truncated): call reset() before step()")
        action = np.asarray(action, dtype=np.float32)
        if action.shape != (2,):
            raise ValueError(f"action must have shape [2] (linear, angular in [-1, 1]), got {list(action.shape)}")
        _, reward, terminated, truncated, info = self._vec.step(torch.from_numpy(action).reshape(1, 2))
        obs = info["final_obs"][0].numpy()  # the observation before any automatic reset
        extra = {key: bool(info[key][0]) for key in self._FLAGS}
        extra.update(episode_steps=int(info["episode_steps"][0]), episode_return=float(info["episode_return"][0]),
                     final_pose=info["final_pose"][0].numpy().astype(np.float64))
        self._ended = bool(terminated[0]) or bool(truncated[0])
        return obs, float(reward[0]), bool(terminated[0]), bool(truncated[0]), extra

    def render(self):
        raise NotImplementedError("NavEnv has no render mode: draw episodes with `flashnav render POLICY --out PNG "
                                  "[--gif]`, or flashnav.rollout.rollout and flashnav.viz.draw_trajectories")


def make_vec_env(num_envs: int = 1, robot: str = DEFAULT_ROBOT, **kwargs):
    return make_env(robot, num_envs, **kwargs)

