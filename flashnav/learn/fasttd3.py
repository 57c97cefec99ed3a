"""FastTD3: deterministic tanh actor, twin C51 critics, clipped double Q, target policy smoothing.

Functions over a :class:`flashnav.learn.common.LearnerState` whose ``algo`` is a :class:`TD3State`
(the module satisfies :class:`flashnav.learn.protocol.AlgorithmModule`); :func:`flashnav.learn.learners.make_learner`
wraps them in the common learner interface. Shapes: N envs, B batch, A actions, K atoms.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from flashnav.learn import c51
from flashnav.learn.common import (LearnerState, actor_view, build_state, collection_noise, finish_update,
                                   optimizer_step, resample_where, uniform)
from flashnav.learn.hparams import FastTD3HParams
from flashnav.learn.networks import ObsLayout, with_headroom
from flashnav.learn.replay import Transition


@dataclass
class TD3State:
    """FastTD3's own state. ``atoms [K]``: the C51 support (return units). ``noise_std [N, 1]``:
    each env's exploration std sigma_e (action units), resampled when its episode ends."""

    atoms: torch.Tensor
    noise_std: torch.Tensor


def init_state(hp: FastTD3HParams, layout: ObsLayout, action_dim: int, num_envs: int,
               device: torch.device | str, seed: int) -> LearnerState:
    """Networks, optimisers, the C51 support and each env's exploration std sigma_e ``[N, 1]``."""
    state = build_state(hp, layout, action_dim, actor_heads=1, critic_out=hp.num_atoms, num_envs=num_envs,
                        device=device, seed=seed)
    state.algo = TD3State(atoms=c51.support(hp.v_min, hp.v_max, hp.num_atoms, state.device),
                          noise_std=uniform((num_envs, 1), *hp.collection_noise, state.collect_gen, state.device))
    zero = torch.zeros((), device=state.device)
    state.last_actor_metrics = {"actor_loss": zero, "actor_grad_norm": zero}
    return state


def act(state: LearnerState, obs: torch.Tensor) -> torch.Tensor:
    """Exploration action ``[N, A]``: ``clamp(tanh(mu(obs)) + sigma_e * eps, -1, 1)``, from the
    collector's weight copy (``tanh(mu)`` with the action headroom: :func:`~flashnav.learn.networks.with_headroom`)."""
    mean = with_headroom(torch.tanh(state.collector(obs)), state.hp.action_headroom)
    noise = collection_noise(state, mean.shape, mean.device)  # white or coloured (hp.noise_color)
    return (mean + state.algo.noise_std * noise).clamp(-1.0, 1.0)


def on_episode_end(state: LearnerState, done: torch.Tensor) -> None:
    """Resample sigma_e ~ U[collection_noise] for the envs whose episode ended (``done [N]`` bool)."""
    resample_where(state.algo.noise_std, done, *state.hp.collection_noise, state.collect_gen)


@torch.no_grad()
def compute_target(state: LearnerState, batch: Transition) -> tuple[torch.Tensor, torch.Tensor]:
    """Target distribution ``[B, K]`` and its expected value ``[B]``.

    Smoothed target action from the *current* actor, ``a' = clamp(tanh(mu(s')) + clip(sigma eps), -1, 1)``;
    both target critics' next-state distributions are projected through ``r + bootstrap gamma z``;
    per sample, the one with the smaller expected value is the target of both critics (clipped double Q).
    """
    hp = state.hp
    bootstrap = batch.bootstrap
    noise = torch.randn(batch.action.shape, generator=state.update_gen, device=batch.action.device)
    noise = (noise * hp.target_noise).clamp(-hp.noise_clip, hp.noise_clip)
    next_action = (with_headroom(torch.tanh(state.actor(batch.next_obs)), hp.action_headroom) + noise).clamp(-1.0, 1.0)
    next_probs = F.softmax(state.critic_target(batch.next_obs, next_action), dim=-1)      # [2, B, K]
    projected = c51.project(next_probs, batch.reward, bootstrap, hp.gamma, state.algo.atoms)   # [2, B, K]
    values = c51.expected_value(projected, state.algo.atoms)                                    # [2, B]
    first = (values[0] <= values[1]).unsqueeze(-1)
    return torch.where(first, projected[0], projected[1]), values.min(dim=0).values


def update_critic(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """Both critics minimise cross-entropy to the clipped-double-Q target distribution."""
    target, target_value = compute_target(state, batch)
    logits = state.critic(batch.obs, batch.action)                                         # [2, B, K]
    loss = -(target * F.log_softmax(logits, dim=-1)).sum(-1).mean(-1).sum()
    grad_norm = optimizer_step(loss, state.critic_opt, state.critic_params, state.hp.max_grad_norm)
    q = c51.expected_value(F.softmax(logits.detach(), dim=-1), state.algo.atoms)
    return {"critic_loss": loss.detach(), "q_mean": q.mean(), "target_q_mean": target_value.mean(),
            "critic_grad_norm": grad_norm}


def update_actor(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """Maximise min(Q1, Q2) (expected values) at ``tanh(mu(s))``; critic weights are not trained here."""
    action = with_headroom(torch.tanh(state.actor(batch.obs)), state.hp.action_headroom)
    logits = state.critic(batch.obs, action, detach_params=True)
    q = c51.expected_value(F.softmax(logits, dim=-1), state.algo.atoms)                          # [2, B]
    loss = -q.min(dim=0).values.mean()
    grad_norm = optimizer_step(loss, state.actor_opt, state.actor_params, state.hp.max_grad_norm)
    return {"actor_loss": loss.detach(), "actor_grad_norm": grad_norm}


def update(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """One critic update (+ actor every ``policy_frequency``-th) + Polyak. ``batch``: ``[B, ...]``."""
    return finish_update(state, update_critic(state, batch), lambda s: update_actor(s, actor_view(s, batch)))
