"""FastSAC: tanh-squashed Gaussian actor, twin C51 critics, learned entropy temperature.

Reference behaviour (notes): the entropy bonus is folded into the reward, each critic regresses to
its *own* target critic's projected distribution (no min), the actor maximises the mean of the two
critics, and the temperature is stepped after every critic update.
Functions over a :class:`flashnav.learn.common.LearnerState` whose ``algo`` is a :class:`SACState`.
Shapes: N envs, B batch, A actions, K atoms.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from flashnav.learn import c51
from flashnav.learn.common import (LearnerState, Temperature, actor_view, build_state, collection_noise, finish_update,
                                   make_temperature, optimizer_step)
from flashnav.learn.hparams import FastSACHParams
from flashnav.learn.networks import ObsLayout, bounded_log_std, squashed_gaussian, with_headroom
from flashnav.learn.replay import Transition


@dataclass
class SACState:
    """FastSAC's own state. ``atoms [K]``: the C51 support (return units). ``temperature``: the
    learned entropy temperature alpha (target entropy ``-ratio * A``)."""

    atoms: torch.Tensor
    temperature: Temperature


def init_state(hp: FastSACHParams, layout: ObsLayout, action_dim: int, num_envs: int,
               device: torch.device | str, seed: int) -> LearnerState:
    """Networks, optimisers, the C51 support, and alpha with target entropy ``-ratio * A``."""
    state = build_state(hp, layout, action_dim, actor_heads=2, critic_out=hp.num_atoms, num_envs=num_envs,
                        device=device, seed=seed)
    state.algo = SACState(atoms=c51.support(hp.v_min, hp.v_max, hp.num_atoms, state.device),
                          temperature=make_temperature(state, hp.alpha_init, hp.alpha_lr,
                                                       -hp.target_entropy_ratio * action_dim))
    zero = torch.zeros((), device=state.device)
    state.last_actor_metrics = {"actor_loss": zero, "actor_grad_norm": zero}
    return state


def policy_log_std(raw: torch.Tensor, hp: FastSACHParams) -> tuple[torch.Tensor, torch.Tensor]:
    """Actor output ``[B, 2A]`` -> (mu ``[B, A]``, log sigma ``[B, A]`` bounded to [log_std_min, log_std_max])."""
    mu, raw_log_std = raw.chunk(2, dim=-1)
    return mu, bounded_log_std(raw_log_std, hp.log_std_min, hp.log_std_max)


def sample(actor: torch.nn.Module, obs: torch.Tensor, hp: FastSACHParams,
           gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """``obs [B, D]`` -> reparameterised ``action [B, A]`` in (-1, 1) and ``log_prob [B]``."""
    mu, log_std = policy_log_std(actor(obs), hp)
    noise = torch.randn(mu.shape, generator=gen, device=mu.device)
    return squashed_gaussian(mu, log_std, noise, hp.action_headroom)


def act(state: LearnerState, obs: torch.Tensor) -> torch.Tensor:
    """Exploration action ``[N, A]`` sampled from the collector's copy of the policy (standard-normal
    draws white or coloured: ``hp.noise_color``)."""
    mu, log_std = policy_log_std(state.collector(obs), state.hp)
    action, _ = squashed_gaussian(mu, log_std, collection_noise(state, mu.shape, mu.device),
                                  state.hp.action_headroom)
    return action.clamp(-1.0, 1.0)


def on_episode_end(state: LearnerState, done: torch.Tensor) -> None:
    """FastSAC keeps no per-env exploration state."""


@torch.no_grad()
def compute_target(state: LearnerState, batch: Transition) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-critic target distributions ``[2, B, K]`` and the next-action ``log_prob [B]``.

    ``a' ~ pi(.|s')`` from the current actor; the soft reward ``r - gamma b alpha log pi(a'|s')``
    shifts the support with ``r + b gamma z``, and each target critic's distribution is projected.
    """
    hp = state.hp
    bootstrap = batch.bootstrap
    next_action, next_log_prob = sample(state.actor, batch.next_obs, hp, state.update_gen)
    soft_reward = batch.reward - hp.gamma * bootstrap * state.algo.temperature.alpha * next_log_prob
    next_probs = F.softmax(state.critic_target(batch.next_obs, next_action), dim=-1)
    return c51.project(next_probs, soft_reward, bootstrap, hp.gamma, state.algo.atoms), next_log_prob


def update_critic(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """Critic k minimises cross-entropy to target critic k's projection; then one temperature step
    with ``-alpha (log pi(a'|s') + H_target)`` (reusing the target's next-action log-probs)."""
    target, next_log_prob = compute_target(state, batch)
    logits = state.critic(batch.obs, batch.action)
    loss = -(target * F.log_softmax(logits, dim=-1)).sum(-1).mean(-1).sum()
    grad_norm = optimizer_step(loss, state.critic_opt, state.critic_params, state.hp.max_grad_norm)
    alpha_loss = state.algo.temperature.step(next_log_prob)
    q = c51.expected_value(F.softmax(logits.detach(), dim=-1), state.algo.atoms)
    return {"critic_loss": loss.detach(), "q_mean": q.mean(), "critic_grad_norm": grad_norm,
            "alpha": state.algo.temperature.alpha, "alpha_loss": alpha_loss,
            "entropy": -next_log_prob.mean()}


def update_actor(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """Minimise ``alpha log pi(a|s) - mean(Q1, Q2)`` at reparameterised ``a ~ pi(.|s)``, minus
    ``hp.mean_action_q`` times the same value at the deterministic action ``tanh(mu)``."""
    hp = state.hp
    mu, log_std = policy_log_std(state.actor(batch.obs), hp)
    action, log_prob = squashed_gaussian(mu, log_std, torch.randn(mu.shape, generator=state.update_gen,
                                                                  device=mu.device), hp.action_headroom)

    def value(a: torch.Tensor) -> torch.Tensor:                                               # [B]
        logits = state.critic(batch.obs, a, detach_params=True)
        return c51.expected_value(F.softmax(logits, dim=-1), state.algo.atoms).mean(dim=0)

    loss = (state.algo.temperature.alpha * log_prob - value(action)).mean()
    if hp.mean_action_q > 0:  # the evaluated (deterministic) action's value too
        loss = loss - hp.mean_action_q * value(with_headroom(torch.tanh(mu), hp.action_headroom)).mean()
    grad_norm = optimizer_step(loss, state.actor_opt, state.actor_params, hp.max_grad_norm)
    return {"actor_loss": loss.detach(), "actor_grad_norm": grad_norm}


def update(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """One critic + temperature update (+ actor every ``policy_frequency``-th) + Polyak."""
    return finish_update(state, update_critic(state, batch), lambda s: update_actor(s, actor_view(s, batch)))
