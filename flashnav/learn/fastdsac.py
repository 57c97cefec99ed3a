"""FastDSAC: Gaussian distributional twin critics, DEM actor, learned entropy temperature.

Critic k outputs mean mu_k and std sigma_k = softplus(raw). Targets come from the target critics at
``a' ~ pi(.|s')`` (current actor): the mean target uses the target mean (expected-value
substitution), the sample target a clamped sample ``mu' + clamp(zeta, -3, 3) sigma'``; with CDQ
both use the target critic with the smaller mean. Rewards are scaled by ``reward_scale``. The loss
is the variance-based gradient adjustment of DSAC-T (see :func:`critic_loss`).
Functions over a :class:`flashnav.learn.common.LearnerState` whose ``algo`` is a :class:`DSACState`.
Shapes: N envs, B batch, A actions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import torch
import torch.nn.functional as F

from flashnav.learn.common import (LearnerState, Temperature, actor_view, build_state, collection_noise, finish_update,
                                   make_temperature, optimizer_step, resample_where, uniform)
from flashnav.learn.hparams import FastDSACHParams
from flashnav.learn.networks import (ObsLayout, bounded_log_std, dem_log_weights, gaussian_head, squashed_gaussian,
                                     with_headroom)
from flashnav.learn.replay import Transition

#: zeta ~ N(0, 1) is clamped to +-ZETA_CLIP before scaling the target std.
ZETA_CLIP = 3.0
#: Keeps the 1/sigma factors finite when a critic's std collapses.
STD_EPS = 1e-6


@dataclass
class DSACState:
    """FastDSAC's own state. ``temperature``: the learned entropy temperature alpha.
    ``running_std [2]``: per-critic EMA m_k of the batch-mean critic std (scaled-return units;
    -1 until the first update). ``dem_scale [N, 1]``: each env's DEM collection scale s_e,
    resampled when its episode ends."""

    temperature: Temperature
    running_std: torch.Tensor
    dem_scale: torch.Tensor


def init_state(hp: FastDSACHParams, layout: ObsLayout, action_dim: int, num_envs: int,
               device: torch.device | str, seed: int) -> LearnerState:
    """Networks, optimisers, alpha (target entropy ``-ratio * A``), running std ``[2]`` (-1 = unset),
    and each env's DEM collection scale s_e ``[N, 1]``."""
    state = build_state(hp, layout, action_dim, actor_heads=3, critic_out=2, num_envs=num_envs,
                        device=device, seed=seed)
    temperature = make_temperature(state, hp.alpha_init, hp.alpha_lr, -hp.target_entropy_ratio * action_dim)
    state.algo = DSACState(temperature=temperature, running_std=torch.full((2,), -1.0, device=state.device),
                           dem_scale=uniform((num_envs, 1), *hp.scale_range, state.collect_gen, state.device))
    zero = torch.zeros((), device=state.device)
    state.last_actor_metrics = {"actor_loss": zero, "actor_grad_norm": zero, "alpha_loss": zero,
                                "entropy": zero}
    return state


def policy_log_std(raw: torch.Tensor, hp: FastDSACHParams, scale: torch.Tensor | float = 1.0):
    """Actor output ``[B, 3A]`` -> (mu ``[B, A]``, log sigma_eff ``[B, A]``).

    ``sigma_eff = w * exp(log sigma)``, ``w = A * softmax(scale * clamp(l / T, -20, 20))``."""
    mu, raw_log_std, logits = raw.chunk(3, dim=-1)
    log_std = bounded_log_std(raw_log_std, hp.log_std_min, hp.log_std_max)
    return mu, log_std + dem_log_weights(logits, hp.temperature, scale)


def sample(actor: torch.nn.Module, obs: torch.Tensor, hp: FastDSACHParams, gen: torch.Generator,
           scale: torch.Tensor | float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """``obs [B, D]`` -> reparameterised ``action [B, A]`` in (-1, 1) and ``log_prob [B]``."""
    mu, log_std = policy_log_std(actor(obs), hp, scale)
    noise = torch.randn(mu.shape, generator=gen, device=mu.device)
    return squashed_gaussian(mu, log_std, noise, hp.action_headroom)


def act(state: LearnerState, obs: torch.Tensor) -> torch.Tensor:
    """Exploration action ``[N, A]`` from the collector's copy, DEM allocation sharpened/flattened
    by each env's scale s_e; the standard-normal draws white or coloured (``hp.noise_color``)."""
    mu, log_std = policy_log_std(state.collector(obs), state.hp, state.algo.dem_scale)
    action, _ = squashed_gaussian(mu, log_std, collection_noise(state, mu.shape, mu.device),
                                  state.hp.action_headroom)
    return action.clamp(-1.0, 1.0)


def on_episode_end(state: LearnerState, done: torch.Tensor) -> None:
    """Resample s_e ~ U[scale_range] for the envs whose episode ended (``done [N]`` bool)."""
    resample_where(state.algo.dem_scale, done, *state.hp.scale_range, state.collect_gen)


@torch.no_grad()
def compute_target(state: LearnerState, batch: Transition) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean target ``y [B]`` and sample target ``y_hat [B]`` (scaled-reward units).

    ``y = c r + b gamma (mu'_k* - alpha log pi')``, ``y_hat = c r + b gamma (q'_k* - alpha log pi')``,
    ``q'_k = mu'_k + clamp(zeta, -3, 3) sigma'_k``, ``k* = argmin_k mu'_k`` (CDQ) or the mean of both.
    """
    hp = state.hp
    bootstrap = batch.bootstrap
    next_action, next_log_prob = sample(state.actor, batch.next_obs, hp, state.update_gen)
    next_mu, next_std = gaussian_head(state.critic_target(batch.next_obs, next_action))    # [2, B]
    zeta = torch.randn(next_mu.shape, generator=state.update_gen, device=next_mu.device)
    next_sample = next_mu + zeta.clamp(-ZETA_CLIP, ZETA_CLIP) * next_std
    if hp.cdq:
        first = next_mu[0] <= next_mu[1]
        mean_q = torch.where(first, next_mu[0], next_mu[1])
        sample_q = torch.where(first, next_sample[0], next_sample[1])
    else:
        mean_q, sample_q = next_mu.mean(dim=0), next_sample.mean(dim=0)
    reward = hp.reward_scale * batch.reward
    entropy = state.algo.temperature.alpha * next_log_prob
    discount = hp.gamma * bootstrap
    return reward + discount * (mean_q - entropy), reward + discount * (sample_q - entropy)


def critic_loss(mu: torch.Tensor, std: torch.Tensor, target: torch.Tensor, target_sample: torch.Tensor,
                running_std: torch.Tensor, huber_delta: float) -> torch.Tensor:
    """Variance-based gradient adjustment loss, summed over critics, mean over the batch.

    ``mu, std [2, B]`` critic outputs; ``target, target_sample [B]``; ``running_std [2]`` (m_k).
    With s = stopgrad(std) and ``w = clamp(m^2 / (s^2 + eps), 0.1, 10)``:
    ``L = mean w [Huber(mu - y) + std (s^2 - Huber(stopgrad(mu) - y_hat)) / (s + eps)]``.
    The mean is pulled towards y (dL/dmu = w Huber'(mu - y)); the std grows when the sampled TD
    error is large against it (Huber(mu - y_hat) > s^2) and shrinks otherwise (dL/dstd =
    w (s^2 - Huber) / s). w rescales each sample's step by the std it is measured in.
    """
    s = std.detach()
    weight = (running_std.unsqueeze(-1).pow(2) / (s.pow(2) + STD_EPS)).clamp(0.1, 10.0)
    mean_term = F.huber_loss(mu, target.expand_as(mu), reduction="none", delta=huber_delta)
    sample_err = F.huber_loss(mu.detach(), target_sample.expand_as(mu), reduction="none", delta=huber_delta)
    std_term = std * (s.pow(2) - sample_err) / (s + STD_EPS)
    return (weight * (mean_term + std_term)).mean(dim=-1).sum()


def update_critic(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """One critic step: running-std EMA (initialised from the first batch), then :func:`critic_loss`."""
    hp = state.hp
    target, target_sample = compute_target(state, batch)
    mu, std = gaussian_head(state.critic(batch.obs, batch.action))                         # [2, B]
    with torch.no_grad():
        batch_std = std.float().mean(dim=-1)  # float32 state, also under bf16 autocast (no-op otherwise)
        running_std = state.algo.running_std
        ema = torch.lerp(running_std, batch_std, hp.std_ema)
        running_std.copy_(torch.where(running_std < 0, batch_std, ema))
    loss = critic_loss(mu, std, target, target_sample, running_std, hp.huber_delta)
    grad_norm = optimizer_step(loss, state.critic_opt, state.critic_params, hp.max_grad_norm)
    return {"critic_loss": loss.detach(), "q_mean": mu.detach().mean(), "q_std_mean": std.detach().mean(),
            "target_q_mean": target.mean(), "running_std": running_std.clone(), "critic_grad_norm": grad_norm}


@lru_cache(maxsize=None)
def cvar_std_factor(level: float) -> float:
    """k with ``CVaR_level(N(mu, sigma^2)) = mu - k sigma`` (the mean of the worst ``level`` share of the
    returns): ``k = pdf(Phi^-1(level)) / level``; 0 at level 1 (the mean), 0.80 at 0.5, 1.27 at 0.25. Cached:
    every actor update asks for the run's one level."""
    if not 0.0 < level <= 1.0:
        raise ValueError(f"risk_cvar must be in (0, 1], got {level}")
    if level == 1.0:
        return 0.0
    normal = NormalDist()
    return normal.pdf(normal.inv_cdf(level)) / level


def update_actor(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """Actor: minimise ``alpha log pi - min(mu_1, mu_2)`` (mean of both without CDQ) at ``a ~ pi(.|s)``, minus
    ``hp.mean_action_q`` times the same value at the deterministic action ``tanh(mu)``; then one temperature
    step with ``-alpha (log pi + H_target)``. With ``hp.risk_cvar`` < 1 each critic's value is the CVaR of its
    Gaussian, ``mu_k - k sigma_k`` (:func:`cvar_std_factor`), before the min."""
    hp = state.hp
    mu, log_std = policy_log_std(state.actor(batch.obs), hp)
    action, log_prob = squashed_gaussian(mu, log_std, torch.randn(mu.shape, generator=state.update_gen,
                                                                  device=mu.device), hp.action_headroom)

    risk = cvar_std_factor(hp.risk_cvar)

    def value(a: torch.Tensor) -> torch.Tensor:                                               # [B]
        q_mu, q_std = gaussian_head(state.critic(batch.obs, a, detach_params=True))          # [2, B]
        q = q_mu - risk * q_std if risk > 0 else q_mu
        return q.min(dim=0).values if hp.cdq else q.mean(dim=0)

    loss = (state.algo.temperature.alpha * log_prob - value(action)).mean()
    if hp.mean_action_q > 0:  # the evaluated (deterministic) action's value too
        loss = loss - hp.mean_action_q * value(with_headroom(torch.tanh(mu), hp.action_headroom)).mean()
    grad_norm = optimizer_step(loss, state.actor_opt, state.actor_params, hp.max_grad_norm)
    alpha_loss = state.algo.temperature.step(log_prob)
    return {"actor_loss": loss.detach(), "actor_grad_norm": grad_norm, "alpha_loss": alpha_loss,
            "entropy": -log_prob.detach().mean()}


def update(state: LearnerState, batch: Transition) -> dict[str, torch.Tensor]:
    """One critic update (+ actor and temperature every ``policy_frequency``-th) + Polyak."""
    metrics = finish_update(state, update_critic(state, batch), lambda s: update_actor(s, actor_view(s, batch)))
    metrics["alpha"] = state.algo.temperature.alpha
    return metrics
