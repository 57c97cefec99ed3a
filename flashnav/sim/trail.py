"""The opt-in pose trail: where the robot has been (``observation.pose_trail``, issue 15).

A policy that sees one scan and the straight-line direction to its goal has no memory: in a maze it
walks back into the dead end it just left, or parks in front of a wall with the goal behind it, and
nothing in its input says it has been there for ten seconds. With ``pose_trail = P > 0`` every
observation ends with P breadcrumbs, the robot's own earlier positions in the robot frame of the
current pose::

    [T, T + 2 P)    breadcrumb j = (x, y) metres, x ahead, y to the left, j = 0 .. P - 1, newest first

with T = ``preset.tracks_end`` (after the paper's observation, the scan history and the agent tracks).
A breadcrumb is dropped every ``trail_every`` control steps: after the step that brings the episode's
step count to a multiple of ``trail_every``, that step's position becomes breadcrumb 0 and the oldest is
dropped. A new episode (a reset, sparse or full, and ``set_state``) fills every breadcrumb with its start
position, so at first they all read (0, 0) less the robot's own motion since. Any robot has this input
from its odometry (or localisation); :class:`flashnav.deploy.controller.Controller` keeps the same
breadcrumbs from its pose at the control rate, and a new goal restarts them.

The breadcrumbs are kept in the simulator frame [N, P, 2] and turned into the robot frame when observed;
like :class:`flashnav.sim.history.ScanHistory` they are a shift register.
"""

from __future__ import annotations

import torch


def trail_bound(preset) -> float:
    """Metres: no breadcrumb can be farther from the robot than the top speed allows over the whole
    trail (P * trail_every steps) - the observation bound and the network's divisor of these columns."""
    obs = preset.observation
    v_max = max(abs(b) for b in preset.motion.v_bounds)
    return max(v_max * preset.episode.dt * obs.pose_trail * obs.trail_every, 1e-3)


def to_robot_frame(points: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """``points [k, P, 2]`` (world or simulator frame) in the robot frame of ``pose [k, 3]``."""
    d = points - pose[:, None, :2]
    c, s = torch.cos(pose[:, 2])[:, None], torch.sin(pose[:, 2])[:, None]
    return torch.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], dim=-1)


class PoseTrail:
    """The last ``count`` breadcrumbs [N, count, 2] (simulator frame, metres) of each of N slots."""

    def __init__(self, num_envs: int, count: int, every: int, device: torch.device):
        if num_envs < 1 or count < 1 or every < 1:
            raise ValueError(f"PoseTrail needs num_envs, count and every >= 1, got {num_envs}, {count}, {every}")
        self.every = every
        self.crumbs = torch.zeros(num_envs, count, 2, device=device, dtype=torch.float32)

    @property
    def columns(self) -> int:
        """Observation columns the trail adds: 2 * count."""
        return 2 * self.crumbs.shape[1]

    def start(self, idx, pose: torch.Tensor) -> torch.Tensor:
        """New episodes in slots ``idx`` starting at ``pose [k, 3]``: every breadcrumb becomes the start
        position. Returns the trail's columns [k, 2 P] (all zero); other slots are untouched."""
        self.crumbs[idx] = pose[:, None, :2].expand(-1, self.crumbs.shape[1], -1)
        return torch.zeros(pose.shape[0], self.columns, device=pose.device)

    def push(self, idx, pose: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        """One step of slots ``idx`` now at ``pose [k, 3]`` after ``steps [k]`` steps of their episodes:
        where ``steps`` is a multiple of ``every`` the position becomes breadcrumb 0 (the oldest drops).
        Returns the trail's columns [k, 2 P] in the robot frame of ``pose``."""
        past = self.crumbs[idx]
        drop = (steps % self.every == 0)[:, None, None]
        shifted = torch.cat([pose[:, None, :2], past[:, :-1]], dim=1)
        now = torch.where(drop, shifted, past)
        self.crumbs[idx] = now
        return to_robot_frame(now, pose).flatten(1)
