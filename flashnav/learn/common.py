"""Helpers shared by the three learners: optimisers, Polyak averaging, seeding, checkpoint state."""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any, Iterable, Sequence

import numpy as np
import torch
from torch import nn

from flashnav.learn.networks import Actor, TwinCritic
from flashnav.learn.noise import ColoredNoise, exponents
from flashnav.learn.wall_map import with_features


def adamw(params: Iterable[torch.Tensor], lr: float, betas: Sequence[float], weight_decay: float) -> torch.optim.AdamW:
    """AdamW, fused (one kernel for all parameters) where this torch/device supports it, else foreach."""
    params = list(params)
    try:
        return torch.optim.AdamW(params, lr=lr, betas=tuple(betas), weight_decay=weight_decay, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.AdamW(params, lr=lr, betas=tuple(betas), weight_decay=weight_decay, foreach=True)


@torch.no_grad()
def polyak_(target: Sequence[torch.Tensor], source: Sequence[torch.Tensor], tau: float) -> None:
    """``target <- (1 - tau) * target + tau * source`` for every pair, as one foreach op."""
    torch._foreach_lerp_(list(target), list(source), tau)


@torch.no_grad()
def copy_params_(target: nn.Module, source: nn.Module) -> None:
    """Copy ``source``'s parameters and buffers into ``target`` (same architecture), foreach."""
    dst = list(target.parameters()) + list(target.buffers())
    src = list(source.parameters()) + list(source.buffers())
    torch._foreach_copy_(dst, src)


def frozen_copy(module: nn.Module) -> nn.Module:
    """A deep copy with gradients off: target critics, the collector's actor."""
    clone = copy.deepcopy(module)
    clone.requires_grad_(False)
    return clone


def optimizers(state: Any) -> list[torch.optim.Optimizer]:
    """Every optimiser of a learner state (dataclass fields, nested dataclasses such as the
    temperature included), in field order."""
    found: list[torch.optim.Optimizer] = []
    for field in dataclasses.fields(state):
        value = getattr(state, field.name)
        if isinstance(value, torch.optim.Optimizer):
            found.append(value)
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            found.extend(optimizers(value))
    return found


def optimizer_step(loss: torch.Tensor, optimizer: torch.optim.Optimizer, params: Sequence[torch.Tensor],
                   max_grad_norm: float) -> torch.Tensor:
    """zero_grad, backward, optional global-norm clip (``max_grad_norm`` > 0), step.

    Returns the pre-clip gradient norm (a device tensor; zeros when clipping is off, to avoid the
    extra reduction)."""
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if max_grad_norm > 0:
        norm = torch.nn.utils.clip_grad_norm_(params, max_grad_norm, foreach=True)
    else:
        norm = torch.zeros((), device=loss.device)
    optimizer.step()
    return norm.detach()


def lr_factor(final_ratio: float, progress: float) -> float:
    """The learning-rate multiplier of ``hp.lr_final_ratio``'s cosine decay at ``progress`` (the
    fraction of the run's env-step budget done, clamped to [0, 1]): 1 at the start, ``final_ratio``
    at the end, ``final_ratio + (1 - final_ratio) (1 + cos(pi p)) / 2`` between."""
    p = min(max(float(progress), 0.0), 1.0)
    return final_ratio + (1.0 - final_ratio) * 0.5 * (1.0 + math.cos(math.pi * p))


def set_learning_rates(state: "LearnerState", factor: float) -> None:
    """Actor and critic optimisers at ``factor`` x their recipe rates (``hp.actor_lr``, ``hp.critic_lr``);
    the temperature's rate is left as it is."""
    for opt, base in ((state.actor_opt, state.hp.actor_lr), (state.critic_opt, state.hp.critic_lr)):
        for group in opt.param_groups:
            group["lr"] = base * factor


def derive_seeds(seed: int, n: int) -> list[int]:
    """``n`` independent 63-bit seeds from one training seed (init, collection, update streams)."""
    return [int(s) >> 1 for s in np.random.SeedSequence(seed).generate_state(n, dtype=np.uint64)]


def generator(device: torch.device, seed: int) -> torch.Generator:
    gen = torch.Generator(device=device)
    gen.manual_seed(seed)
    return gen


def uniform(shape: Sequence[int], low: float, high: float, gen: torch.Generator, device: torch.device) -> torch.Tensor:
    return torch.rand(shape, generator=gen, device=device) * (high - low) + low


def state_to_dict(state: Any) -> dict[str, Any]:
    """Checkpointable snapshot of a learner state dataclass: modules and optimisers as state dicts,
    tensors cloned, generators as their RNG state, plain numbers as they are, nested dataclasses
    (the per-algorithm state, its temperature) as nested dicts. Lists and dicts (cached parameter
    lists, last metrics) are derived data and are skipped. Everything is copied:
    ``Optimizer.load_state_dict`` keeps the given tensors when dtype and device match, so an
    uncopied in-memory round trip would leave two learners sharing Adam moments."""
    out: dict[str, Any] = {}
    for field in dataclasses.fields(state):
        value = getattr(state, field.name)
        if isinstance(value, (nn.Module, torch.optim.Optimizer)):
            out[field.name] = copy.deepcopy(value.state_dict())
        elif isinstance(value, torch.Tensor):
            out[field.name] = value.detach().clone()
        elif isinstance(value, torch.Generator):
            out[field.name] = value.get_state()
        elif isinstance(value, (int, float, bool)):
            out[field.name] = value
        elif dataclasses.is_dataclass(value):
            out[field.name] = state_to_dict(value)
    return out


def _required(value: Any) -> bool:
    return isinstance(value, (nn.Module, torch.optim.Optimizer, torch.Tensor)) or dataclasses.is_dataclass(value)


def load_state_from_dict(state: Any, data: dict[str, Any], where: str = "learner state dict") -> None:
    """Inverse of :func:`state_to_dict`, in place (parameters keep their identity, so optimisers and
    cached parameter lists stay valid). A missing module, optimiser, tensor or nested state is a
    KeyError naming it (``where`` prefixes the message)."""
    missing = [f.name for f in dataclasses.fields(state)
               if f.name not in data and _required(getattr(state, f.name)) and not f.metadata.get("optional")]
    if missing:
        raise KeyError(f"{where} lacks {', '.join(missing)}")
    for field in dataclasses.fields(state):
        if field.name not in data:
            continue
        value, saved = getattr(state, field.name), data[field.name]
        if isinstance(value, (nn.Module, torch.optim.Optimizer)):
            value.load_state_dict(saved)
        elif isinstance(value, torch.Tensor):
            with torch.no_grad():
                value.copy_(saved)
        elif isinstance(value, torch.Generator):
            value.set_state(saved)
        elif isinstance(value, (int, float, bool)):
            setattr(state, field.name, type(value)(saved))
        elif dataclasses.is_dataclass(value):
            load_state_from_dict(value, saved, f"{where}[{field.name!r}]")


@dataclasses.dataclass
class LearnerState:
    """The core every learner owns; ``algo`` holds its algorithm's own state (a dataclass of the
    algorithm module, e.g. :class:`flashnav.learn.fasttd3.TD3State`).

    ``collector``: the actor's weight copy used for collection (synced by the loop).
    ``averaged_actor``: with ``hp.policy_averaging > 0``, a Polyak average of the actor's weights
    (updated after every actor step): the policy that is evaluated and exported. None otherwise.
    ``critic`` / ``critic_target``: twin critics, one batched network each.
    ``collect_gen`` / ``update_gen``: RNG streams of collection (exploration noise, per-env scales)
    and of updates (target and actor samples), on the learner's device.
    ``num_updates``: critic updates so far (host int: the actor schedule is decided without
    reading the device). ``*_params`` / ``*_buffers``: cached parameter and buffer lists (foreach Polyak, grad clipping, the averaged policy).
    ``last_actor_metrics``: the last actor step's metrics, repeated between actor steps.
    ``noise``: with a ``hp.noise_color`` above 0, the coloured collection noise (:mod:`flashnav.learn.noise`);
    None for white noise, drawn step by step from ``collect_gen``.
    """

    hp: Any
    actor: nn.Module
    collector: nn.Module
    critic: nn.Module
    critic_target: nn.Module
    actor_opt: torch.optim.Optimizer
    critic_opt: torch.optim.Optimizer
    collect_gen: torch.Generator
    update_gen: torch.Generator
    algo: Any = None
    averaged_actor: nn.Module | None = None
    num_updates: int = 0
    critic_params: list = dataclasses.field(default_factory=list)
    target_params: list = dataclasses.field(default_factory=list)
    actor_params: list = dataclasses.field(default_factory=list)
    averaged_params: list = dataclasses.field(default_factory=list)
    averaged_buffers: list = dataclasses.field(default_factory=list)
    actor_buffers: list = dataclasses.field(default_factory=list)
    last_actor_metrics: dict = dataclasses.field(default_factory=dict)
    # optional in a saved state: a run with coloured noise may start from one without (fresh sequences)
    noise: ColoredNoise | None = dataclasses.field(default=None, metadata={"optional": True})

    @property
    def device(self) -> torch.device:
        return self.collect_gen.device


@dataclasses.dataclass
class Temperature:
    """A learned entropy temperature (FastSAC, FastDSAC): ``log_alpha []`` (requires grad), its
    optimiser, and the target entropy (nats; e.g. ``-0.5 A``)."""

    log_alpha: torch.Tensor
    opt: torch.optim.Optimizer
    target_entropy: float

    @property
    def alpha(self) -> torch.Tensor:
        """``[]`` detached ``exp(log_alpha)``."""
        return self.log_alpha.detach().exp()

    def step(self, log_prob: torch.Tensor) -> torch.Tensor:
        """One step on ``-alpha (log pi + H_target)`` for ``log_prob [B]`` (detached here);
        returns the detached loss."""
        loss = -(self.log_alpha.exp() * (log_prob.detach() + self.target_entropy)).mean()
        optimizer_step(loss, self.opt, [self.log_alpha], 0.0)
        return loss.detach()


def build_state(hp: Any, layout: Any, action_dim: int, actor_heads: int, critic_out: int, num_envs: int,
                device: torch.device | str, seed: int) -> LearnerState:
    """Actor, collector copy, twin critic and its target, optimisers, RNG streams and, with
    a ``hp.noise_color`` above 0, the coloured collection noise of ``num_envs`` envs.

    Weights are drawn on the CPU from a generator seeded by ``seed``, then moved: the same seed gives
    the same initial network on every device."""
    device = torch.device(device)
    init_seed, collect_seed, update_seed = derive_seeds(seed, 3)
    init_gen = torch.Generator().manual_seed(init_seed)
    norms = dict(layer_norm=hp.layer_norm, obs_norm=hp.obs_norm)
    layout = dataclasses.replace(layout, goal_sincos=hp.goal_sincos, wall_convs=hp.wall_map_convs)
    actor = Actor(layout, action_dim, hp.actor_hidden, actor_heads, init_gen, out_init_std=hp.actor_out_init_std,
                  headroom=hp.action_headroom, **norms).to(device)
    # a wall map's one encoder (drawn after the actor's layers) is the critics', shared with the actor: the critic
    # loss trains it, the actor step reads its features detached (flashnav.learn.wall_map)
    critic = TwinCritic(layout, action_dim, hp.critic_hidden, critic_out, init_gen, walls=actor.walls,
                        **norms).to(device)
    critic_target = frozen_copy(critic)
    averaged = None
    if hp.policy_averaging > 0:
        averaged = frozen_copy(actor)
        averaged.walls = actor.walls  # the average reads the live encoder; its own layers are averaged
    collect_gen = generator(device, collect_seed)
    return LearnerState(
        hp=hp, actor=actor, collector=frozen_copy(actor), critic=critic, critic_target=critic_target,
        actor_opt=adamw(actor_own_params(actor), hp.actor_lr, hp.betas, hp.weight_decay),
        critic_opt=adamw(critic.parameters(), hp.critic_lr, hp.betas, hp.weight_decay),
        collect_gen=collect_gen, update_gen=generator(device, update_seed),
        critic_params=list(critic.parameters()), target_params=list(critic_target.parameters()),
        actor_params=actor_own_params(actor),
        averaged_actor=averaged,
        averaged_params=[] if averaged is None else actor_own_params(averaged),
        averaged_buffers=[] if averaged is None else list(averaged.buffers()),
        actor_buffers=list(actor.buffers()),
        noise=collection_colour(hp.noise_color, num_envs, action_dim, collect_gen, device),
    )


def actor_own_params(actor: nn.Module) -> list[nn.Parameter]:
    """The parameters the actor loss trains: all of ``actor``'s but a wall-map encoder's (the critics', shared)."""
    shared = set() if actor.walls is None else {id(p) for p in actor.walls.parameters()}
    return [p for p in actor.parameters() if id(p) not in shared]


def actor_view(state: LearnerState, batch: Any) -> Any:
    """The actor step's batch. With a wall map (a batch from
    :func:`flashnav.learn.wall_map.encode_wall_maps`) the features are computed again by the encoder as the critic
    step left it, without gradients: the actor loss trains the actor only, as in the pixel-based references (SAC-AE,
    DrQ). Without one the observations are the replay's own tensors: the same batch."""
    if state.critic.walls is None:
        return batch
    with torch.no_grad():
        return batch._replace(obs=with_features(batch.obs, state.critic.walls, state.critic.vector_end))


def collection_colour(beta: float | Sequence[float], num_envs: int, action_dim: int, gen: torch.Generator,
                      device: torch.device) -> ColoredNoise | None:
    """The coloured collection noise of ``algo.noise_color`` (one exponent, or one per action), or None for white
    noise (every exponent 0: the draws come step by step from ``collect_gen``, as in every recipe)."""
    betas = exponents(beta)
    if len(betas) not in (1, action_dim):
        raise ValueError(f"algo.noise_color has {len(betas)} exponents {list(betas)}; give one, or one per action "
                         f"({action_dim} for this robot)")
    if all(b == 0 for b in betas):
        return None
    return ColoredNoise.create(betas, num_envs, action_dim, gen, device)


def collection_noise(state: LearnerState, shape: Sequence[int], device: torch.device) -> torch.Tensor:
    """Standard-normal exploration draws ``shape`` (= ``[N, A]``) for one collection step: white from
    ``collect_gen``, or the next step of the coloured sequences (``hp.noise_color`` above 0)."""
    if state.noise is None:
        return torch.randn(shape, generator=state.collect_gen, device=device)
    return state.noise.draw(state.collect_gen)


@torch.no_grad()
def update_obs_stats(state: LearnerState, obs: torch.Tensor) -> None:
    """With ``hp.obs_norm``: merge a replay batch's observations ``[B, D]`` into the running feature
    statistics of the actor, the critics and the target critics (each on its own transform; the
    collector's copy receives them with the weights)."""
    for net in (state.actor, state.critic, state.critic_target):
        net.transform.update_stats(obs)


def make_temperature(state: LearnerState, alpha_init: float, alpha_lr: float, target_entropy: float) -> Temperature:
    """Learned entropy temperature: ``log_alpha`` from ``alpha_init``, its own AdamW (no weight
    decay: decay would pull log alpha towards 0, i.e. alpha towards 1)."""
    log_alpha = torch.tensor(float(np.log(alpha_init)), device=state.device, requires_grad=True)
    return Temperature(log_alpha, adamw([log_alpha], alpha_lr, state.hp.betas, 0.0), float(target_entropy))


def finish_update(state: LearnerState, critic_metrics: dict, actor_step) -> dict:
    """After a critic step: count it, run ``actor_step(state)`` every ``policy_frequency``-th update
    (the 2nd, 4th, ... for 2), Polyak-average the target critics. Returns the merged metrics; actor
    metrics repeat the last actor step's values between actor steps, so the keys never change."""
    state.num_updates += 1
    if state.num_updates % state.hp.policy_frequency == 0:
        state.last_actor_metrics = actor_step(state)
        if state.averaged_actor is not None:
            average_actor_(state)
    polyak_(state.target_params, state.critic_params, state.hp.tau)
    return {**critic_metrics, **state.last_actor_metrics}


@torch.no_grad()
def average_actor_(state: LearnerState) -> None:
    """``averaged <- (1 - rate) averaged + rate actor`` for the weights (``hp.policy_averaging``);
    buffers (running feature statistics) are copied, not averaged."""
    polyak_(state.averaged_params, state.actor_params, state.hp.policy_averaging)
    if state.averaged_buffers:
        torch._foreach_copy_(state.averaged_buffers, state.actor_buffers)


def resample_where(scale: torch.Tensor, done: torch.Tensor, low: float, high: float, gen: torch.Generator) -> None:
    """``scale [N, 1]``: draw U[low, high] afresh where ``done [N]`` is true, in place, no host sync."""
    fresh = uniform(scale.shape, low, high, gen, scale.device)
    scale.copy_(torch.where(done.reshape(-1, 1).bool(), fresh, scale))
