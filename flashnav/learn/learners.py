"""One interface over FastTD3, FastSAC and FastDSAC, so one training loop drives all three.

```python
learner = make_learner("fastdsac", hp, layout, action_dim=2, num_envs=N, device="cpu", seed=0)
action = learner.act(obs)                 # [N, D] -> [N, A] exploration action in [-1, 1]
learner.on_episode_end(done)              # [N] bool: resample per-env exploration scales
learner.sync_collector()                  # every hp.env_steps_per_sync vector steps
batches = replay.sample(hp.batch_size, hp.updates_per_step)
for i in range(hp.updates_per_step):
    metrics = learner.update(batches.at(i))   # dict of detached 0-d / small device tensors
learner.policy                            # DeterministicActor: obs -> tanh(mu), for eval/export
```
The algorithm is data (a name selecting a module of functions), not a subclass.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import torch

from flashnav.learn import common, fastdsac, fastsac, fasttd3
from flashnav.learn.networks import DeterministicActor, ObsLayout
from flashnav.learn.replay import Transition

ALGORITHMS: dict[str, ModuleType] = {"fasttd3": fasttd3, "fastsac": fastsac, "fastdsac": fastdsac}


class Learner:
    """A learner state plus the functions of its algorithm. Build it with :func:`make_learner`."""

    def __init__(self, algorithm: str, state: common.LearnerState):
        self.algorithm = algorithm
        self.state = state
        self._ops = ALGORITHMS[algorithm]
        self.policy = DeterministicActor(state.actor)

    @property
    def hp(self):
        return self.state.hp

    @property
    def device(self) -> torch.device:
        return self.state.device

    @property
    def num_updates(self) -> int:
        """Critic updates performed so far."""
        return self.state.num_updates

    @torch.no_grad()
    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs [N, D]`` raw units -> exploration ``action [N, A]`` in [-1, 1] (collector weights)."""
        return self._ops.act(self.state, obs)

    def on_episode_end(self, done: torch.Tensor) -> None:
        """``done [N]`` bool (terminated | truncated): resample those envs' exploration scales."""
        self._ops.on_episode_end(self.state, done)

    def sync_collector(self) -> None:
        """Copy the trained actor's weights into the collector's copy."""
        common.copy_params_(self.state.collector, self.state.actor)

    def update(self, batch: Transition) -> dict[str, torch.Tensor]:
        """One critic update (+ actor/temperature on schedule) + Polyak on ``batch`` ``[B, ...]``."""
        return self._ops.update(self.state, batch)

    def state_dict(self) -> dict[str, Any]:
        return {"algorithm": self.algorithm, **common.state_to_dict(self.state)}

    def load_state_dict(self, data: dict[str, Any]) -> None:
        if data.get("algorithm") != self.algorithm:
            raise ValueError(f"state dict is for {data.get('algorithm')!r}, this learner is {self.algorithm!r}")
        common.load_state_from_dict(self.state, data)


def make_learner(algorithm: str, hp, layout: ObsLayout, action_dim: int, num_envs: int,
                 device: torch.device | str = "cpu", seed: int = 0) -> Learner:
    """Build a learner. ``hp`` is the algorithm's model from :func:`flashnav.learn.hparams.load_hparams`;
    ``num_envs`` sizes the per-env exploration state (it may differ from ``hp.num_envs``)."""
    if algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algorithm!r}: use one of {', '.join(ALGORITHMS)}")
    if getattr(hp, "algorithm", None) != algorithm:
        raise TypeError(f"hyperparameters are for {getattr(hp, 'algorithm', type(hp).__name__)!r}, not {algorithm!r}")
    if layout.obs_dim <= 0 or action_dim <= 0 or num_envs <= 0:
        raise ValueError("make_learner needs obs_dim, action_dim and num_envs > 0")
    state = ALGORITHMS[algorithm].init_state(hp, layout, action_dim, num_envs, torch.device(device), seed)
    return Learner(algorithm, state)
