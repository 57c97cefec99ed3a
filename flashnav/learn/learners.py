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
The algorithm is data (a name from :data:`flashnav.names.ALGORITHMS` selecting the module
``flashnav.learn.<name>``, which satisfies :class:`~flashnav.learn.protocol.AlgorithmModule`), not a
subclass. ``learner.state`` is the shared core (:class:`~flashnav.learn.common.LearnerState`);
``learner.state.algo`` the algorithm's own state (e.g. :class:`~flashnav.learn.fastdsac.DSACState`).
"""

from __future__ import annotations

import importlib
from typing import Any

import torch

from flashnav.learn import common
from flashnav.learn.networks import DeterministicActor, ObsLayout
from flashnav.learn.protocol import AlgorithmModule
from flashnav.learn.replay import Transition
from flashnav.learn.wall_map import encode_wall_maps
from flashnav.names import ALGORITHMS

#: name -> algorithm module, for every name in :data:`flashnav.names.ALGORITHMS`.
MODULES: dict[str, AlgorithmModule] = {name: importlib.import_module(f"flashnav.learn.{name}") for name in ALGORITHMS}

#: Checkpoints written before the per-algorithm state existed (no ``"algo"`` key) kept the
#: algorithm's fields flat beside the core's: old key -> path inside ``state_dict()["algo"]``.
_LEGACY_ALGO_KEYS: dict[str, dict[str, tuple[str, ...]]] = {
    "fasttd3": {"atoms": ("atoms",), "explore_scale": ("noise_std",)},
    "fastsac": {"atoms": ("atoms",), "log_alpha": ("temperature", "log_alpha"), "alpha_opt": ("temperature", "opt"),
                "target_entropy": ("temperature", "target_entropy")},
    "fastdsac": {"log_alpha": ("temperature", "log_alpha"), "alpha_opt": ("temperature", "opt"),
                 "target_entropy": ("temperature", "target_entropy"), "running_std": ("running_std",),
                 "explore_scale": ("dem_scale",)},
}


class Learner:
    """A learner state plus the functions of its algorithm. Build it with :func:`make_learner`."""

    def __init__(self, algorithm: str, state: common.LearnerState):
        self.algorithm = algorithm
        self.state = state
        self._ops = MODULES[algorithm]
        # the evaluated and exported policy: the trained actor, or its Polyak average (hp.policy_averaging)
        self.policy = DeterministicActor(state.actor if state.averaged_actor is None else state.averaged_actor)
        # the collector's deterministic action, for the slots that collect without exploring (hp.deterministic_envs)
        self._collector_policy = DeterministicActor(state.collector)

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
        """``obs [N, D]`` raw units -> exploration ``action [N, A]`` in [-1, 1] (collector weights). With
        ``hp.deterministic_envs`` above 0, the last ``deterministic_slots(N)`` slots take the collector's
        deterministic action instead (their exploration draws are made and dropped, so the others' are unchanged)."""
        action = self._ops.act(self.state, obs)
        k = deterministic_slots(self.state.hp.deterministic_envs, obs.shape[0])
        if k:
            action[-k:] = self._collector_policy(obs[-k:])
        return action

    def on_episode_end(self, done: torch.Tensor) -> None:
        """``done [N]`` bool (terminated | truncated): resample those envs' exploration scales."""
        self._ops.on_episode_end(self.state, done)

    def sync_collector(self) -> None:
        """Copy the trained actor's weights into the collector's copy."""
        common.copy_params_(self.state.collector, self.state.actor)

    def schedule(self, progress: float) -> None:
        """Set the learning rates for ``progress`` (the fraction of the run's env-step budget done):
        ``hp.lr_final_ratio``'s cosine decay; a no-op at the recipes' constant rate (ratio 1)."""
        if self.state.hp.lr_final_ratio < 1:
            common.set_learning_rates(self.state, common.lr_factor(self.state.hp.lr_final_ratio, progress))

    def update(self, batch: Transition) -> dict[str, torch.Tensor]:
        """One critic update (+ actor/temperature on schedule) + Polyak on ``batch`` ``[B, ...]``
        (with ``hp.obs_norm``, the batch's observations first update the running feature statistics; with a wall
        map, its squares are encoded once for the whole update: :func:`flashnav.learn.wall_map.encode_wall_maps`)."""
        if self.state.hp.obs_norm:
            common.update_obs_stats(self.state, batch.obs)
        if self.state.critic.walls is not None:
            batch = encode_wall_maps(batch, self.state.critic, self.state.critic_target)
        return self._ops.update(self.state, batch)

    def state_dict(self) -> dict[str, Any]:
        """``{"algorithm", <core fields>, "algo": {<algorithm fields>}}``: modules and optimisers as
        state dicts, tensors, RNG states; plain data only (see :func:`flashnav.checkpoint.save_checkpoint`)."""
        return {"algorithm": self.algorithm, **common.state_to_dict(self.state)}

    def load_state_dict(self, data: dict[str, Any]) -> None:
        """Inverse of :meth:`state_dict`, in place; also reads the flat layout of older checkpoints."""
        if data.get("algorithm") != self.algorithm:
            raise ValueError(f"state dict is for {data.get('algorithm')!r}, this learner is {self.algorithm!r}")
        common.load_state_from_dict(self.state, upgrade_state_dict(data))


def deterministic_slots(share: float, num_envs: int) -> int:
    """How many of ``num_envs`` slots collect with the deterministic action for ``hp.deterministic_envs`` =
    ``share``: ``round(share * num_envs)``, at least one for any share above 0."""
    return max(1, round(share * num_envs)) if share > 0 else 0


def upgrade_state_dict(data: dict[str, Any]) -> dict[str, Any]:
    """A learner state dict in the current layout: one from before the per-algorithm state (its
    algorithm's fields flat beside the core's, see ``_LEGACY_ALGO_KEYS``) is regrouped under
    ``"algo"``; a current one is returned as it is. Fields the algorithm never used (e.g. FastTD3's
    ``target_entropy``) are dropped."""
    if "algo" in data:
        return data
    legacy_keys = {key for keys in _LEGACY_ALGO_KEYS.values() for key in keys}
    out = {k: v for k, v in data.items() if k not in legacy_keys}
    algo: dict[str, Any] = {}
    for old, path in _LEGACY_ALGO_KEYS.get(data.get("algorithm"), {}).items():
        if old in data:
            node = algo
            for key in path[:-1]:
                node = node.setdefault(key, {})
            node[path[-1]] = data[old]
    out["algo"] = algo
    return out


def make_learner(algorithm: str, hp, layout: ObsLayout, action_dim: int, num_envs: int,
                 device: torch.device | str = "cpu", seed: int = 0) -> Learner:
    """Build a learner. ``hp`` is the algorithm's model from :func:`flashnav.learn.hparams.load_hparams`;
    ``num_envs`` sizes the per-env exploration state (it may differ from ``hp.num_envs``)."""
    if algorithm not in MODULES:
        raise ValueError(f"unknown algorithm {algorithm!r}: use one of {', '.join(ALGORITHMS)}")
    if getattr(hp, "algorithm", None) != algorithm:
        raise TypeError(f"hyperparameters are for {getattr(hp, 'algorithm', type(hp).__name__)!r}, not {algorithm!r}")
    if layout.obs_dim <= 0 or action_dim <= 0 or num_envs <= 0:
        raise ValueError("make_learner needs obs_dim, action_dim and num_envs > 0")
    state = MODULES[algorithm].init_state(hp, layout, action_dim, num_envs, torch.device(device), seed)
    return Learner(algorithm, state)
