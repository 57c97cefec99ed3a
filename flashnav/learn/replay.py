"""Device-resident circular replay buffer for vectorised off-policy learning.

Layout: time-major per-env slabs ``[T, N, ...]`` (T = rows per env, N = envs). Every ``add`` writes
one contiguous slab ``[N, ...]`` at the write position, so storage viewed flat is ``[T * N, ...]``
with row ``t * N + e`` = env ``e`` at slot ``t``. Rows ``[0, size)`` are valid (all rows once the
buffer has wrapped); sampling draws rows uniformly with replacement. Bookkeeping (write position,
size) is plain host integers advanced by ``add``: reading ``size`` never synchronises with the device.

n-step returns (``n_step > 1``): a sampled row ``t`` of env ``e`` sums the discounted rewards of rows
``t, t+1, ...`` of the same env until its episode ends (terminated or truncated), ``n_step`` rewards
are summed or the newest stored row is reached, and bootstraps from the last summed row's next
observation; ``n_step = 1`` is the one-step transition, gathered exactly as stored.

Binary columns (``binary_columns`` B > 0): the observation's last B columns hold only 0 and 1 (the wall map's
squares, 2 C^2 of them with ``observation.wall_map`` C, 3 C^2 with its visited channel) and are kept as uint8
beside the float32 rest (``obs_bits``, ``next_obs_bits``): a quarter of their memory, joined back into float32 rows
when sampled, so a batch is the same as from an all-float buffer.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import torch

if TYPE_CHECKING:
    from flashnav.learn.mirror import Mirror
    from flashnav.learn.wall_shift import WallShift


class Transition(NamedTuple):
    """A batch of transitions. From ``sample``: ``[U, B, ...]``; one update's batch: ``[B, ...]``.

    ``obs [.., D]`` raw units; ``action [.., A]`` executed, in [-1, 1]; ``reward [..]`` (with n-step
    returns, the discounted sum ``r_t + gamma r_t+1 + ... + gamma^(m-1) r_t+m-1`` of the m rewards
    summed); ``bootstrap [..]`` float32, the weight of ``gamma * V(next_obs)`` in the target: ``1 -
    terminated`` for a one-step transition (0 = the episode terminated, nothing to bootstrap),
    ``gamma^(m-1) (1 - terminated)`` for an m-step one, so that every learner's ``gamma * bootstrap`` is
    the return's discount; ``next_obs [.., D]`` (the final observation where the env reset in that
    step; with n-step returns, that of the last summed step).
    """

    obs: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    bootstrap: torch.Tensor
    next_obs: torch.Tensor

    def at(self, i: int) -> "Transition":
        """The i-th of the U batches: ``[B, ...]`` views, no copy."""
        return Transition(*(x[i] for x in self))


class Replay:
    """Circular buffer of ``capacity`` transitions (rounded up to a multiple of ``num_envs``).

    ``obs_dim`` D, ``action_dim`` A; tensors live on ``device``; ``seed`` drives a private
    ``torch.Generator`` so sampling is reproducible and independent of the global RNG. ``n_step`` > 1
    samples n-step returns discounted by ``gamma`` (module docstring); ``add`` then needs ``ended``.
    ``mirror``: a :class:`flashnav.learn.mirror.Mirror` that reflects a share of every sampled batch's
    rows left-right (``algo.mirror``; its draws come from the same generator, after the rows').
    ``wall_shift``: a :class:`flashnav.learn.wall_shift.WallShift` that moves every sampled row's wall map by a
    few squares (``algo.wall_shift``; its draws come from the same generator, after the mirror's).
    ``binary_columns``: the observation's last columns that hold only 0 / 1, kept as uint8 (module docstring;
    another value in them would be truncated: the caller says which columns are binary).
    """

    def __init__(self, num_envs: int, obs_dim: int, action_dim: int, capacity: int,
                 device: torch.device | str = "cpu", seed: int = 0, n_step: int = 1, gamma: float | None = None,
                 mirror: "Mirror | None" = None, wall_shift: "WallShift | None" = None, binary_columns: int = 0):
        if num_envs <= 0 or capacity <= 0:
            raise ValueError(f"Replay needs num_envs > 0 and capacity > 0, got {num_envs}, {capacity}")
        if not isinstance(n_step, int) or n_step < 1:
            raise ValueError(f"Replay n_step must be an integer >= 1, got {n_step!r}")
        if n_step > 1 and (gamma is None or not 0 < gamma <= 1):
            raise ValueError(f"Replay with n_step={n_step} needs the discount gamma in (0, 1], got {gamma!r}")
        self.n_step, self.gamma = n_step, gamma
        if mirror is not None and (mirror.obs_index.numel() != obs_dim or mirror.action_sign.numel() != action_dim):
            raise ValueError(f"Replay mirror is for {mirror.obs_index.numel()} observation and {mirror.action_sign.numel()} "
                             f"action columns, the buffer holds {obs_dim} and {action_dim}")
        self.mirror = mirror
        if wall_shift is not None and wall_shift.end > obs_dim:
            raise ValueError(f"Replay wall_shift reads columns up to {wall_shift.end}, the buffer holds {obs_dim}")
        self.wall_shift = wall_shift
        if not isinstance(binary_columns, int) or not 0 <= binary_columns <= obs_dim:
            raise ValueError(f"Replay binary_columns must be an integer in [0, obs_dim={obs_dim}], "
                             f"got {binary_columns!r}")
        self.obs_dim, self.binary_columns = obs_dim, binary_columns
        self._split = obs_dim - binary_columns  # float32 columns before the binary ones
        self.num_envs = num_envs
        self.rows_per_env = math.ceil(capacity / num_envs)
        self.device = torch.device(device)
        t, n = self.rows_per_env, num_envs
        f32 = dict(dtype=torch.float32, device=self.device)
        bits = dict(dtype=torch.uint8, device=self.device)
        self.obs = torch.zeros(t, n, self._split, **f32)
        self.obs_bits = torch.zeros(t, n, binary_columns, **bits) if binary_columns else None
        self.action = torch.zeros(t, n, action_dim, **f32)
        self.reward = torch.zeros(t, n, **f32)
        self.terminated = torch.zeros(t, n, **f32)
        self.next_obs = torch.zeros(t, n, self._split, **f32)
        self.next_obs_bits = torch.zeros(t, n, binary_columns, **bits) if binary_columns else None
        # episode ended in that step (terminated or truncated): where an n-step return stops summing
        self.ended = torch.zeros(t, n, dtype=torch.bool, device=self.device) if n_step > 1 else None
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
            terminated: torch.Tensor, next_obs: torch.Tensor, ended: torch.Tensor | None = None) -> None:
        """Store one vector step: ``obs [N, D]``, ``action [N, A]`` (clamped here to [-1, 1], the
        action the env executed), ``reward [N]``, ``terminated [N]`` bool or 0/1, ``next_obs [N, D]``
        already merged with the final observation where the env reset; ``ended [N]`` bool (terminated
        or truncated), needed with n-step returns, ignored without."""
        want = (self.num_envs, self.obs_dim)
        if obs.shape != want or next_obs.shape != want:
            raise ValueError(f"obs/next_obs must be {want}, got {tuple(obs.shape)} and {tuple(next_obs.shape)}")
        if action.shape != self.action.shape[1:]:
            raise ValueError(f"action must be {tuple(self.action.shape[1:])}, got {tuple(action.shape)}")
        if self.ended is not None and ended is None:
            raise ValueError(f"Replay with n_step={self.n_step} needs add(..., ended=terminated | truncated): "
                             "an n-step return must stop where an episode ended")
        t = self._pos
        if self.ended is not None:
            self.ended[t].copy_(ended.reshape(self.num_envs))
        self._store(t, obs, self.obs, self.obs_bits)
        torch.clamp(action, -1.0, 1.0, out=self.action[t])
        self.reward[t].copy_(reward.reshape(self.num_envs))
        self.terminated[t].copy_(terminated.reshape(self.num_envs))
        self._store(t, next_obs, self.next_obs, self.next_obs_bits)
        self._pos = (t + 1) % self.rows_per_env
        self._filled = min(self._filled + 1, self.rows_per_env)

    def _store(self, t: int, obs: torch.Tensor, floats: torch.Tensor, bits: torch.Tensor | None) -> None:
        """Write observations ``[N, D]`` into slot ``t``: the float columns, and the binary ones as uint8."""
        floats[t].copy_(obs[:, : self._split])
        if bits is not None:
            bits[t].copy_(obs[:, self._split:])

    def _rows(self, floats: torch.Tensor, bits: torch.Tensor | None, rows: torch.Tensor,
              out: torch.Tensor | None = None) -> torch.Tensor:
        """The float32 rows ``[R, ...]`` of a stored field at flat ``rows`` (into ``out`` where given); for the
        observations with ``bits``: the float columns, then the binary ones converted as they are copied in."""
        if bits is None:
            return self._take(floats, rows, out)
        if out is None:
            out = torch.empty(rows.numel(), self.obs_dim, dtype=floats.dtype, device=floats.device)
        out[:, : self._split] = self._take(floats, rows)
        out[:, self._split:] = self._take(bits, rows)
        return out

    def sample(self, batch_size: int, n_batches: int = 1, out: Transition | None = None) -> Transition:
        """``n_batches`` (U) batches of ``batch_size`` (B) transitions at once: ``Transition`` of
        ``[U, B, ...]`` tensors, rows drawn uniformly with replacement from the stored ones (n-step
        returns: each from its row on, module docstring).

        ``out``: static ``[U, B, ...]`` tensors (float32, on this buffer's device) to gather into
        and return, e.g. the batch buffers a CUDA graph reads (:mod:`flashnav.learn.cuda_graph`);
        the same rows, the same values and the same generator draws as without it."""
        if self._filled == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        if out is not None:
            self._check_out(out, batch_size, n_batches)
        rows = torch.randint(self.size, (n_batches, batch_size), generator=self.generator, device=self.device)
        batch = self._gather(rows, n_batches, batch_size, out)
        if self.mirror is not None:
            batch = self.mirror.apply(batch, self.generator)
        return batch if self.wall_shift is None else self.wall_shift.apply(batch, self.generator)

    def _gather(self, rows: torch.Tensor, n_batches: int, batch_size: int, out: Transition | None) -> Transition:
        """The transitions of ``rows`` [U, B] (into ``out`` where given)."""
        if self.n_step > 1:
            fields = self._n_step_fields(rows.view(-1), out)
            if out is None:
                return Transition(*(x.view(n_batches, batch_size, *x.shape[1:]) for x in fields))
            out.reward.view(-1).copy_(fields.reward)  # obs, action and next obs went straight into out
            out.bootstrap.view(-1).copy_(fields.bootstrap)
            return out
        r = rows.view(-1)
        stored = ((self.obs, self.obs_bits), (self.action, None), (self.reward, None), (self.terminated, None),
                  (self.next_obs, self.next_obs_bits))
        if out is None:
            taken = (self._rows(x, bits, r) for x, bits in stored)
            batch = Transition(*(x.view(n_batches, batch_size, *x.shape[1:]) for x in taken))
            return batch._replace(bootstrap=1.0 - batch.bootstrap)
        for (src, bits), dst in zip(stored, out):  # straight into the static buffers
            self._rows(src, bits, r, out=dst.view(-1, *dst.shape[2:]))
        torch.sub(1.0, out.bootstrap, out=out.bootstrap)
        return out

    def _take(self, x: torch.Tensor, rows: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """The flat ``rows`` of a stored tensor (into ``out`` where given), gathered with ``index_select`` (a draw of
        the generalist's 9 x 512 wall-map rows 1.09x the speed of ``[rows]`` indexing on the 2-core CPU;
        docs/benchmarks.md "The replay's wall map as uint8")."""
        flat = self._flat(x)
        return torch.index_select(flat, 0, rows) if out is None else torch.index_select(flat, 0, rows, out=out)

    def _flat(self, x: torch.Tensor) -> torch.Tensor:
        """A stored ``[T, N, ...]`` tensor viewed as ``[T * N, ...]`` rows (no copy)."""
        return x.view(self.capacity, *x.shape[2:])

    def _n_step_fields(self, rows: torch.Tensor, out: Transition | None = None) -> Transition:
        """``(obs, action, reward, bootstrap, next_obs)`` of the n-step transitions from flat ``rows``; with ``out``
        the gathered fields (obs, action, next obs) are written into its buffers, reward and bootstrap returned."""
        n, rows_per_env = self.num_envs, self.rows_per_env
        slot, env = rows // n, rows % n
        newest = (self._pos - 1) % rows_per_env
        ahead = (newest - slot) % rows_per_env        # stored rows of this env after this one
        take = self._take
        reward = take(self.reward, rows)
        last = rows.clone()
        summing = ~take(self.ended, rows)              # the episode goes on after the first step
        weight = torch.ones_like(reward)              # gamma^(m-1) of the last summed reward
        for k in range(1, self.n_step):
            adds = summing & (ahead >= k)
            row_k = ((slot + k) % rows_per_env) * n + env
            weight = torch.where(adds, weight * self.gamma, weight)
            reward = torch.where(adds, reward + weight * take(self.reward, row_k), reward)
            last = torch.where(adds, row_k, last)
            summing = adds & ~take(self.ended, row_k)
        bootstrap = weight * (1.0 - take(self.terminated, last))
        obs, action, next_obs = (None,) * 3 if out is None else (
            x.view(-1, *x.shape[2:]) for x in (out.obs, out.action, out.next_obs))
        return Transition(self._rows(self.obs, self.obs_bits, rows, obs), take(self.action, rows, action), reward,
                          bootstrap, self._rows(self.next_obs, self.next_obs_bits, last, next_obs))

    def _check_out(self, out: Transition, batch_size: int, n_batches: int) -> None:
        """A ValueError naming the first field of ``out`` that cannot take a ``[U, B, ...]`` sample."""
        u_b, f32, device = (n_batches, batch_size), torch.float32, self.obs.device  # "cuda:0", not "cuda"
        wants = (u_b + (self.obs_dim,), u_b + tuple(self.action.shape[2:]), u_b, u_b, u_b + (self.obs_dim,))
        for name, want, dst in zip(Transition._fields, wants, out):
            if tuple(dst.shape) != want or dst.dtype != f32 or dst.device != device or not dst.is_contiguous():
                raise ValueError(f"sample(out=...): {name} must be a contiguous {f32} tensor of shape "
                                 f"{want} on {device}, got {dst.dtype} {tuple(dst.shape)} on {dst.device}")

    def clear(self) -> None:
        """Forget all transitions (storage is kept)."""
        self._pos = 0
        self._filled = 0

    #: The per-row tensors a state dict carries (``ended`` only with n-step returns, the ``*_bits`` only with
    #: binary columns).
    _STORED = ("obs", "obs_bits", "action", "reward", "terminated", "next_obs", "next_obs_bits", "ended")
    #: :meth:`state_dict`'s layout: 2 added ``binary_columns`` (1: every observation column float32; still read).
    FORMAT = 2

    def state_dict(self) -> dict:
        """What :meth:`load_state_dict` restores (``flashnav train --save-replay`` writes it as ``replay.pt``): the
        stored rows oldest first (``[S, N, ...]``, S = rows written, at most ``rows_per_env``; a copy, the buffer
        keeps its own; the binary columns as uint8), the layout they need (envs, observation and action width,
        the binary columns, whether episode ends are kept) and the sampler's generator state with its device
        type. Tensors on the CPU; loads with ``torch.load(weights_only=True)``."""
        order = torch.arange(self._filled, device=self.device)
        if self._filled == self.rows_per_env:  # wrapped: the oldest row is the next one to be written
            order = (order + self._pos) % self.rows_per_env
        rows = {name: getattr(self, name)[order].cpu() for name in self._STORED if getattr(self, name) is not None}
        return {"format": self.FORMAT, "num_envs": self.num_envs, "obs_dim": self.obs_dim,
                "binary_columns": self.binary_columns, "action_dim": self.action.shape[-1], "rows": rows,
                "generator": self.generator.get_state(), "generator_device": self.device.type}

    def load_state_dict(self, state: dict, source: str = "replay state") -> None:
        """Restore :meth:`state_dict`'s rows into this buffer (its own capacity: where it holds fewer rows per
        env than were saved, the newest are kept) and its generator state (saved on the same kind of device: a
        CPU's and a GPU's generators differ, and across them this buffer keeps its own seeded one). The newest
        row of every env is marked as an episode end, so an n-step return never sums across into the rows this
        buffer adds next (a new episode). ValueError naming ``source`` where the layout differs: another env
        count, observation or action width, or saved without episode ends for a buffer with n-step returns."""
        if not isinstance(state.get("format"), int) or state["format"] > self.FORMAT:
            raise ValueError(f"{source}: replay layout format {state.get('format')!r}, this FlashNav reads up to "
                             f"{self.FORMAT} (written by a newer FlashNav?)")
        want = {"num_envs": self.num_envs, "obs_dim": self.obs_dim, "action_dim": self.action.shape[-1]}
        for key, value in want.items():
            if state.get(key) != value:
                raise ValueError(f"{source}: saved with {key} {state.get(key)}, this run's replay has {value} "
                                 "(a replay continues only with the same envs and observation layout)")
        rows = state["rows"]
        if self.ended is not None and "ended" not in rows:
            raise ValueError(f"{source}: saved without episode ends (n_step 1); this run's n_step {self.n_step} needs "
                             "them to stop its returns where episodes ended")
        count = min(rows["obs"].shape[0], self.rows_per_env)
        saved_bits = state.get("binary_columns", 0)  # format 1: none
        newest = {name: value[value.shape[0] - count:] for name, value in rows.items()}
        for name in ("obs", "next_obs"):
            if saved_bits != self.binary_columns:  # split as this buffer splits: join the saved row, split it anew
                floats, bits = newest.pop(name), newest.pop(f"{name}_bits", None)
                joined = floats if bits is None else torch.cat((floats, bits.to(floats.dtype)), dim=-1)
                newest[name], newest[f"{name}_bits"] = joined[..., : self._split], joined[..., self._split:]
        for name in self._STORED:
            if getattr(self, name) is not None:
                getattr(self, name)[:count].copy_(newest[name])
        if self.ended is not None and count:
            self.ended[count - 1] = True
        self._filled, self._pos = count, count % self.rows_per_env
        if state.get("generator_device") == self.device.type:
            self.generator.set_state(state["generator"])
