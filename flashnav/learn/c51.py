"""Categorical (C51) value distributions on a fixed support: projection and expected value.

The support is ``z_j = linspace(v_min, v_max, K)`` (reward units). All functions are vectorised over
any leading batch dimensions (e.g. ``[2, B, K]`` for the twin critics); no Python loops, no host sync.
"""

from __future__ import annotations

import torch


def support(v_min: float, v_max: float, num_atoms: int, device: torch.device | str | None = None) -> torch.Tensor:
    """``[K]`` float32 atom locations, reward units."""
    if not v_min < v_max or num_atoms < 2:
        raise ValueError(f"C51 support needs v_min < v_max and >= 2 atoms, got [{v_min}, {v_max}] x {num_atoms}")
    return torch.linspace(v_min, v_max, num_atoms, device=device, dtype=torch.float32)


def expected_value(probs: torch.Tensor, atoms: torch.Tensor) -> torch.Tensor:
    """``probs [..., K]``, ``atoms [K]`` -> ``[...]`` mean of each distribution."""
    return probs @ atoms


def project(probs: torch.Tensor, reward: torch.Tensor, bootstrap: torch.Tensor, gamma: float,
            atoms: torch.Tensor) -> torch.Tensor:
    """Project the distribution of ``r + b * gamma * Z`` back onto the support.

    ``probs [..., B, K]`` next-state probabilities (leading dims broadcast, e.g. twin critics
    ``[2, B, K]``); ``reward [B]``; ``bootstrap [B]`` (1 = not terminated, 0 = terminated; an n-step return's gamma^(n-1) (1 - terminated));
    ``atoms [K]`` evenly spaced. Returns ``[..., B, K]``; each row sums to the row's input mass.

    Shifted atoms are clamped to ``[v_min, v_max]`` (returns beyond the support pile up at its ends),
    then split linearly between their neighbours ``l = floor``, ``u = ceil``. An atom that lands
    exactly on a support point has ``l == u`` and both linear weights 0; moving ``u`` up one index
    (or ``l`` down one at the top end) gives that point weight 1, so no mass is lost.
    """
    # at least the support's precision (bf16 probabilities under autocast become float32 targets;
    # float32 or float64 input is returned as it is)
    probs = probs.to(torch.promote_types(probs.dtype, atoms.dtype))
    k = atoms.shape[0]
    v_min, v_max = atoms[0], atoms[-1]
    delta = (v_max - v_min) / (k - 1)
    shifted = reward.unsqueeze(-1) + (bootstrap * gamma).unsqueeze(-1) * atoms  # [B, K]
    pos = (shifted.clamp(v_min, v_max) - v_min) / delta                        # fractional index
    lower = pos.floor().long().clamp(0, k - 1)
    upper = pos.ceil().long().clamp(0, k - 1)
    exact = lower == upper
    upper = torch.where(exact & (upper < k - 1), upper + 1, upper)
    lower = torch.where(exact & (lower == upper), lower - 1, lower)   # only at the top end
    w_lower = upper.to(pos.dtype) - pos                                # [B, K]
    w_upper = pos - lower.to(pos.dtype)
    shape = probs.shape
    out = torch.zeros_like(probs)
    out.scatter_add_(-1, lower.expand(shape), probs * w_lower)
    out.scatter_add_(-1, upper.expand(shape), probs * w_upper)
    return out
