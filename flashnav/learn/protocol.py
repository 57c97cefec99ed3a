"""What an algorithm module provides: the contract between the training loop and a learner.

Each learner (``flashnav/learn/<name>.py`` for every name in :data:`flashnav.names.ALGORITHMS`) is a
module of functions over a :class:`~flashnav.learn.common.LearnerState`, whose ``algo`` field holds
the algorithm's own dataclass. :func:`flashnav.learn.learners.make_learner` selects the module by
name; nothing subclasses anything. Shapes: N envs, B batch, D observation, A action dims.
"""

from __future__ import annotations

import inspect
from typing import Any, Protocol, runtime_checkable

import torch

from flashnav.learn.common import LearnerState
from flashnav.learn.networks import ObsLayout
from flashnav.learn.replay import Transition


@runtime_checkable
class AlgorithmModule(Protocol):
    """The functions every algorithm module defines (``isinstance(module, AlgorithmModule)`` checks
    that they exist; :func:`protocol_mismatches` also checks their parameter names)."""

    def init_state(self, hp: Any, layout: ObsLayout, action_dim: int, num_envs: int,
                   device: torch.device | str, seed: int) -> LearnerState:
        """Networks, optimisers, RNG streams (same seed -> same weights on every device) and the
        algorithm's own state in ``state.algo``, sized for ``num_envs`` collecting envs."""

    def act(self, state: LearnerState, obs: torch.Tensor) -> torch.Tensor:
        """``obs [N, D]`` raw units -> exploration ``action [N, A]`` in [-1, 1], from the collector
        copy and ``state.collect_gen``."""

    def on_episode_end(self, state: LearnerState, done: torch.Tensor) -> None:
        """``done [N]`` bool (terminated | truncated): reset those envs' exploration state."""

    def update(self, state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
        """One critic update (+ actor/temperature on schedule) + Polyak on ``batch [B, ...]``;
        returns detached device tensors with the same keys at every call."""


def protocol_mismatches(module: Any) -> list[str]:
    """What keeps ``module`` from satisfying :class:`AlgorithmModule`: each missing or non-callable
    function, and each function whose parameter names differ from the protocol's. Empty if none."""
    problems = []
    for name in ("init_state", "act", "on_episode_end", "update"):
        wanted = list(inspect.signature(getattr(AlgorithmModule, name)).parameters)[1:]  # drop self
        func = getattr(module, name, None)
        if not callable(func):
            problems.append(f"{name}: missing")
            continue
        got = list(inspect.signature(func).parameters)
        if got != wanted:
            problems.append(f"{name}: parameters {got}, expected {wanted}")
    return problems
