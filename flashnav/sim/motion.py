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


class Actuation:
    """The robot's actuation between the command and the motion, when a preset asks for more than the paper's
    instant execution (``motion.command_delay``, ``motion.max_linear_accel`` / ``max_angular_accel``):

    * latency: a command is executed ``command_delay`` control steps after it is given (a queue per slot; an
      episode starts with the queue at (0, 0), the robot at rest);
    * acceleration limits: the executed (v, w) moves from the last executed velocity toward the due command by at
      most ``max_*_accel * dt`` per step.

    Batched over the slots ``sel`` of an env (``slice(None)`` or [k] indices); pure torch on the env's device."""

    def __init__(self, motion: Motion, num_envs: int, dt: float, device: torch.device):
        self.delay = motion.command_delay
        self.queue = torch.zeros(num_envs, self.delay, 2, device=device) if self.delay else None
        limits = [motion.max_linear_accel, motion.max_angular_accel]
        self.step_limit = (None if all(a is None for a in limits) else
                           torch.tensor([math.inf if a is None else a * dt for a in limits], device=device))

    def reset(self, idx: torch.Tensor) -> None:
        """Slots ``idx`` start an episode: nothing pending (their executed velocity is the env's, zeroed)."""
        if self.queue is not None:
            self.queue[idx] = 0.0

    def execute(self, sel, command: torch.Tensor, velocity: torch.Tensor) -> torch.Tensor:
        """[k, 2] the (v, w) the slots ``sel`` execute this step, given this step's ``command`` [k, 2] and their
        last executed ``velocity`` [k, 2]; the command joins the slots' queues."""
        if self.queue is not None:
            pending = self.queue[sel]
            due = pending[:, 0].clone()  # a copy: the queue is rewritten below
            self.queue[sel] = torch.cat([pending[:, 1:], command[:, None]], dim=1)
            command = due
        if self.step_limit is not None:
            command = velocity + torch.clamp(command - velocity, -self.step_limit, self.step_limit)
        return command
