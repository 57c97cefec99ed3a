"""Device-resident circular replay buffer for vectorised off-policy learning.

Layout: time-major per-env slabs ``[T, N, ...]`` (T = rows per env, N = envs). Every ``add`` writes
one contiguous slab ``[N, ...]`` at the write position, so storage viewed flat is ``[T * N, ...]``
with row ``t * N + e`` = env ``e`` at slot ``t``. Rows ``[0, size)`` are valid (all rows once the
buffer has wrapped); sampling draws rows uniformly with replacement. Bookkeeping (write position,
size) is plain host integers advanced by ``add``: reading ``size`` never synchronises with the device.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch


class Transition(NamedTuple):
    """A batch of transitions. From ``sample``: ``[U, B, ...]``; one update's batch: ``[B, ...]``.

    ``obs [.., D]`` raw units; ``action [.., A]`` executed, in [-1, 1]; ``reward [..]``;
    ``terminated [..]`` float32 0/1 (1 = no bootstrap); ``next_obs [.., D]`` (the final observation
    where the env reset in that step).
    """

    obs: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    terminated: torch.Tensor
    next_obs: torch.Tensor

    def at(self, i: int) -> "Transition":
        """The i-th of the U batches: ``[B, ...]`` views, no copy."""
        return Transition(*(x[i] for x in self))


class Replay:
    """Circular buffer of ``capacity`` transitions (rounded up to a multiple of ``num_envs``).

    ``obs_dim`` D, ``action_dim`` A; tensors live on ``device``; ``seed`` drives a private
    ``torch.Generator`` so sampling is reproducible and independent of the global RNG.
    """

    def __init__(self, num_envs: int, obs_dim: int, action_dim: int, capacity: int,
                 device: torch.device | str = "cpu", seed: int = 0):
        if num_envs <= 0 or capacity <= 0:
            raise ValueError(f"Replay needs num_envs > 0 and capacity > 0, got {num_envs}, {capacity}")
        self.num_envs = num_envs
        self.rows_per_env = math.ceil(capacity / num_envs)
        self.device = torch.device(device)
        t, n = self.rows_per_env, num_envs
        f32 = dict(dtype=torch.float32, device=self.device)
        self.obs = torch.zeros(t, n, obs_dim, **f32)
        self.action = torch.zeros(t, n, action_dim, **f32)
        self.reward = torch.zeros(t, n, **f32)
        self.terminated = torch.zeros(t, n, **f32)
        self.next_obs = torch.zeros(t, n, obs_dim, **f32)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed)
        self._pos = 0          # next slot to write
        self._filled = 0       # slots written, at most rows_per_env

    @property
    def capacity(self) -> int:
        """Transitions the buffer holds when full."""
        return self.rows_per_env * self.num_envs

    @property
    def size(self) -> int:
        """Transitions currently stored (host integer; no device sync)."""
        return self._filled * self.num_envs

    def add(self, obs: torch.Tensor, action: torch.Tensor, reward: torch.Tensor,
            terminated: torch.Tensor, next_obs: torch.Tensor) -> None:
        """Store one vector step: ``obs [N, D]``, ``action [N, A]`` (clamped here to [-1, 1], the
        action the env executed), ``reward [N]``, ``terminated [N]`` bool or 0/1, ``next_obs [N, D]``
        already merged with the final observation where the env reset."""
        if obs.shape != self.obs.shape[1:] or next_obs.shape != self.obs.shape[1:]:
            raise ValueError(f"obs/next_obs must be {tuple(self.obs.shape[1:])}, got "
                             f"{tuple(obs.shape)} and {tuple(next_obs.shape)}")
        if action.shape != self.action.shape[1:]:
            raise ValueError(f"action must be {tuple(self.action.shape[1:])}, got {tuple(action.shape)}")
        t = self._pos
        self.obs[t].copy_(obs)
        torch.clamp(action, -1.0, 1.0, out=self.action[t])
        self.reward[t].copy_(reward.reshape(self.num_envs))
        self.terminated[t].copy_(terminated.reshape(self.num_envs))
        self.next_obs[t].copy_(next_obs)
        self._pos = (t + 1) % self.rows_per_env
        self._filled = min(self._filled + 1, self.rows_per_env)

    def sample(self, batch_size: int, n_batches: int = 1, out: Transition | None = None) -> Transition:
        """``n_batches`` (U) batches of ``batch_size`` (B) transitions at once: ``Transition`` of
        ``[U, B, ...]`` tensors, rows drawn uniformly with replacement from the stored ones.

        ``out``: static ``[U, B, ...]`` tensors (float32, on this buffer's device) to gather into
        and return, e.g. the batch buffers a CUDA graph reads (:mod:`flashnav.learn.cuda_graph`);
        the same rows, the same values and the same generator draws as without it."""
        if self._filled == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        if out is not None:
            self._check_out(out, batch_size, n_batches)
        rows = torch.randint(self.size, (n_batches, batch_size), generator=self.generator, device=self.device)
        flat = lambda x: x.view(self.capacity, *x.shape[2:])  # noqa: E731 - [T, N, ...] -> [T*N, ...]
        stored = (self.obs, self.action, self.reward, self.terminated, self.next_obs)
        if out is None:
            return Transition(*(flat(x)[rows] for x in stored))
        for src, dst in zip(stored, out):
            torch.index_select(flat(src), 0, rows.view(-1), out=dst.view(-1, *dst.shape[2:]))
        return out

    def _check_out(self, out: Transition, batch_size: int, n_batches: int) -> None:
        """A ValueError naming the first field of ``out`` that cannot take a ``[U, B, ...]`` sample."""
        for name, src, dst in zip(Transition._fields, (self.obs, self.action, self.reward, self.terminated,
                                                       self.next_obs), out):
            want = (n_batches, batch_size, *src.shape[2:])
            if tuple(dst.shape) != want or dst.dtype != src.dtype or dst.device != self.device \
                    or not dst.is_contiguous():
                raise ValueError(f"sample(out=...): {name} must be a contiguous {src.dtype} tensor of shape "
                                 f"{want} on {self.device}, got {dst.dtype} {tuple(dst.shape)} on {dst.device}")

    def clear(self) -> None:
        """Forget all transitions (storage is kept)."""
        self._pos = 0
        self._filled = 0
