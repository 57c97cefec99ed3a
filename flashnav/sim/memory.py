"""The opt-in memory scan: the walls the robot has seen (``observation.memory_frames``, issues 15 and 16).

A policy that sees one scan and the straight-line direction to its goal forgets a wall the moment it
leaves the field of view or is hidden behind another: in a maze it walks back into the dead end it just
left, and Go2's last failures dither at a thin wall with the goal behind it (docs/benchmarks.md). The
pose trail (:mod:`flashnav.sim.trail`) remembers where the robot has been, not where the walls were.
With ``memory_frames = F > 0`` every observation ends with a second, 360-deg pooled scan of the wall
points the robot's LiDAR has hit in its last F stored frames::

    [M, M + S)    memory sector j: the distance, metres, from the robot to the nearest remembered wall
                  point whose bearing in the robot frame lies in [-pi + j w, -pi + (j + 1) w), w = 2 pi / S;
                  ``lidar.max_range`` where no remembered point lies (and no farther than it)

with M = ``preset.trail_end`` (after every other column) and S = ``lidar.sectors``. The columns are
LiDAR-like: the networks give them IPAPRec's ``1 / (l - beta)`` with the scan's beta. Sector 0 starts
straight behind (-pi) and sectors go counter-clockwise, so a mirror image reverses their order.

What is stored: a frame every ``memory_every`` control steps (the step that brings the episode's step
count to a multiple of it; a new episode stores its first scan as frame 0 and forgets the rest). A
frame is the scan's hits cut into ``points_per_frame(preset)`` groups of consecutive beams; each group
keeps its nearest hit (range below ``max_range``) as one point in the simulator frame, at that beam's
exact bearing. The memory scan is the minimum over every stored point, with no occlusion: the nearest
remembered point in a direction hides the ones behind it anyway. The points are kept in the simulator
frame and turned into the robot frame when observed; a robot keeps them in its odometry frame
(:class:`flashnav.deploy.controller.Controller`). With moving agents the memory also holds where they
were: it is a memory of hits, as a robot's own would be.
"""

from __future__ import annotations

import math

import torch

from flashnav.sim.trail import to_robot_frame

#: Stored points per pooled sector of the live scan: a frame keeps ``sectors * POINTS_PER_SECTOR`` points
#: (60 for both robots' 30 sectors; the groups' width is the nearest divisor of the sector's beams).
POINTS_PER_SECTOR = 2


def points_per_frame(preset) -> int:
    """Points one stored frame keeps: ``lidar.beams`` cut into equal groups of consecutive beams, the
    widest group at most ``beams_per_sector / POINTS_PER_SECTOR`` beams that divides a sector's beams."""
    bps = preset.lidar.beams_per_sector
    cap = max(1, bps // POINTS_PER_SECTOR)
    group = max(d for d in range(1, cap + 1) if bps % d == 0)
    return preset.lidar.beams // group


class WallMemory:
    """The last ``frames`` stored frames of wall points [N, frames, P, 2] (simulator frame, metres) of
    each of N slots, their validity [N, frames, P], and the memory scan of ``sectors`` they give."""

    def __init__(self, num_envs: int, frames: int, every: int, sectors: int, max_range: float,
                 beam_angles: torch.Tensor, points: int, device: torch.device):
        beams = beam_angles.numel()
        if num_envs < 1 or frames < 1 or every < 1 or sectors < 1 or points < 1 or beams % points:
            raise ValueError(f"WallMemory needs num_envs, frames, every, sectors, points >= 1 and points dividing "
                             f"the {beams} beams, got {num_envs}, {frames}, {every}, {sectors}, {points}")
        self.every, self.sectors, self.max_range = every, sectors, float(max_range)
        self.group_angles = beam_angles.to(device=device, dtype=torch.float32).view(points, beams // points)
        self.points = torch.zeros(num_envs, frames, points, 2, device=device, dtype=torch.float32)
        self.valid = torch.zeros(num_envs, frames, points, device=device, dtype=torch.bool)

    @classmethod
    def from_preset(cls, preset, num_envs: int, beam_angles: torch.Tensor, device: torch.device) -> "WallMemory":
        o = preset.observation
        return cls(num_envs, o.memory_frames, o.memory_every, preset.lidar.sectors, preset.lidar.max_range,
                   beam_angles, points_per_frame(preset), device)

    @property
    def columns(self) -> int:
        """Observation columns the memory adds: the sectors."""
        return self.sectors

    def frame(self, pose: torch.Tensor, ranges: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One frame of ``k`` scans: points [k, P, 2] in the frame of ``pose [k, 3]`` (the nearest hit of
        each group of beams at its beam's bearing) and their validity [k, P] (a hit: below max range)."""
        k, (p, g) = ranges.shape[0], self.group_angles.shape
        near, arg = ranges.reshape(k, p, g).min(dim=2)
        bearing = torch.gather(self.group_angles.expand(k, -1, -1), 2, arg[..., None])[..., 0] + pose[:, 2:3]
        pts = pose[:, None, :2] + near[..., None] * torch.stack([torch.cos(bearing), torch.sin(bearing)], dim=-1)
        return pts, near < self.max_range

    def scan(self, points: torch.Tensor, valid: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """The memory scan [k, S] of stored ``points [k, F, P, 2]`` (``valid [k, F, P]``) seen from ``pose [k, 3]``."""
        k = pose.shape[0]
        rel = to_robot_frame(points.reshape(k, -1, 2), pose)
        dist = torch.linalg.vector_norm(rel, dim=-1).clamp(max=self.max_range)
        dist = torch.where(valid.reshape(k, -1), dist, torch.full_like(dist, self.max_range))
        width = 2.0 * math.pi / self.sectors
        sector = ((torch.atan2(rel[..., 1], rel[..., 0]) + math.pi) / width).long().clamp(0, self.sectors - 1)
        out = torch.full((k, self.sectors), self.max_range, device=pose.device, dtype=torch.float32)
        return out.scatter_reduce(1, sector, dist, reduce="amin")

    def start(self, idx, pose: torch.Tensor, ranges: torch.Tensor) -> torch.Tensor:
        """New episodes in slots ``idx`` at ``pose [k, 3]`` with first scans ``ranges [k, beams]``: frame 0
        holds that scan's points, every other frame is forgotten. Returns the memory scan [k, S]."""
        pts, ok = self.frame(pose, ranges)
        points = torch.zeros((pose.shape[0], *self.points.shape[1:]), device=pose.device, dtype=torch.float32)
        valid = torch.zeros((pose.shape[0], *self.valid.shape[1:]), device=pose.device, dtype=torch.bool)
        points[:, 0], valid[:, 0] = pts, ok
        self.points[idx], self.valid[idx] = points, valid
        return self.scan(points, valid, pose)

    def push(self, idx, pose: torch.Tensor, ranges: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        """One step of slots ``idx`` now at ``pose [k, 3]`` with scans ``ranges [k, beams]`` after
        ``steps [k]`` steps of their episodes: where ``steps`` is a multiple of ``every`` this scan becomes
        frame 0 (the oldest is dropped). Returns the memory scan [k, S] from ``pose``."""
        points, valid = self.points[idx], self.valid[idx]
        store = steps % self.every == 0  # no host sync: the same ops every step (CUDA graphs, no branch)
        pts, ok = self.frame(pose, ranges)
        points = torch.where(store[:, None, None, None], torch.cat([pts[:, None], points[:, :-1]], dim=1), points)
        valid = torch.where(store[:, None, None], torch.cat([ok[:, None], valid[:, :-1]], dim=1), valid)
        self.points[idx], self.valid[idx] = points, valid
        return self.scan(points, valid, pose)
