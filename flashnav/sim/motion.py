"""Motion models: normalised actions -> velocity commands -> planar pose update.

All functions are batched over N environments and device-agnostic (pure torch).
"""

from __future__ import annotations

import math

import torch

from flashnav.config import Motion


def action_to_velocity(action: torch.Tensor, motion: Motion) -> tuple[torch.Tensor, torch.Tensor]:
    """Map actions [N, 2] in [-1, 1] linearly onto the preset's bounds.

    Returns (v [N] m/s, w [N] rad/s), clamped to the platform limits. Out-of-range actions are
    clamped to [-1, 1] first (the action actually executed).
    """
    a = action.clamp(-1.0, 1.0)
    (v_lo, v_hi), (w_lo, w_hi) = motion.v_bounds, motion.w_bounds
    v = v_lo + (a[:, 0] + 1.0) * (0.5 * (v_hi - v_lo))
    w = w_lo + (a[:, 1] + 1.0) * (0.5 * (w_hi - w_lo))
    v = v.clamp(-motion.max_linear_velocity, motion.max_linear_velocity)
    w = w.clamp(-motion.max_angular_velocity, motion.max_angular_velocity)
    return v, w


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    """Wrap radians to [-pi, pi)."""
    return torch.remainder(a + math.pi, 2.0 * math.pi) - math.pi


def integrate(pose: torch.Tensor, v: torch.Tensor, w: torch.Tensor, dt: float) -> torch.Tensor:
    """One differential-drive step; returns the new pose [N, 3] (x, y metres, yaw radians).

    Unicycle kinematics integrated with the midpoint rule (translate along the heading rotated by
    half a step), so a constant (v, w) traces the true arc to second order in dt.
    """
    x, y, yaw = pose.unbind(-1)
    mid = yaw + 0.5 * dt * w
    x = x + dt * v * torch.cos(mid)
    y = y + dt * v * torch.sin(mid)
    yaw = wrap_angle(yaw + dt * w)
    return torch.stack((x, y, yaw), dim=-1)
