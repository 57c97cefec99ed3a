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

with M = ``preset.carrot_end`` (after every column but the wall map's) and S = ``lidar.sectors``. The columns are
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

The same points can also be drawn as an egocentric image (:meth:`WallMemory.image`, drawn by
:func:`flashnav.sim.wall_image.wall_image`). The dense form of the same memory, every beam's hit kept as the cells of a
coarse grid (the observation's wall map), is :class:`flashnav.sim.wall_grid.WallGrid`.
"""

from __future__ import annotations

import math

import torch

from flashnav.sim.wall_image import wall_image

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
    """The last ``frames`` stored frames of wall points [N, frames, 2, P] (x and y rows, simulator frame,
    metres; ``inf`` where a group of beams hit nothing) of each of N slots, and the memory scan of ``sectors``
    they give. x and y are separate rows so that every elementwise op reads runs of contiguous memory (atan2
    on interleaved pairs is ten times slower on a CPU).

    The frames are a ring: the frame stored after episode step t (a multiple of ``every``) goes to row
    ``(t // every) % frames``, overwriting the oldest; the order does not matter to a minimum, and one
    write per stored frame costs less than shifting every frame at every step."""

    def __init__(self, num_envs: int, frames: int, every: int, sectors: int, max_range: float,
                 beam_angles: torch.Tensor, points: int, device: torch.device):
        beams = beam_angles.numel()
        if num_envs < 1 or frames < 1 or every < 1 or sectors < 1 or points < 1 or beams % points:
            raise ValueError(f"WallMemory needs num_envs, frames, every, sectors, points >= 1 and points dividing "
                             f"the {beams} beams, got {num_envs}, {frames}, {every}, {sectors}, {points}")
        self.every, self.sectors, self.max_range = every, sectors, float(max_range)
        self.group_angles = beam_angles.to(device=device, dtype=torch.float32).view(points, beams // points)
        self.points = torch.full((num_envs, frames, 2, points), math.inf, device=device, dtype=torch.float32)
        self.rows = torch.arange(num_envs, device=device)

    @classmethod
    def from_preset(cls, preset, num_envs: int, beam_angles: torch.Tensor, device: torch.device) -> "WallMemory":
        o = preset.observation
        return cls(num_envs, o.memory_frames, o.memory_every, preset.lidar.sectors, preset.lidar.max_range,
                   beam_angles, points_per_frame(preset), device)

    @property
    def columns(self) -> int:
        """Observation columns the memory adds: the sectors."""
        return self.sectors

    @property
    def valid(self) -> torch.Tensor:
        """[N, frames, P] bool: the stored points that are hits."""
        return torch.isfinite(self.points[:, :, 0])

    def image(self, idx, pose: torch.Tensor, goal: torch.Tensor, cells: int, cell: float) -> torch.Tensor:
        """:func:`wall_image` [k, 2, cells, cells] of slots ``idx``'s stored points, seen from ``pose [k, 3]``
        with goals ``goal [k, 2]``."""
        pts = self.points[idx]  # [k, F, 2, P]
        return wall_image(pts.transpose(2, 3).reshape(pts.shape[0], -1, 2), pose, goal, cells, cell)

    def frame(self, pose: torch.Tensor, ranges: torch.Tensor) -> torch.Tensor:
        """One frame of ``k`` scans: points [k, 2, P] (x and y planes) in the frame of ``pose [k, 3]``, the
        nearest hit of each group of beams at its beam's bearing, ``inf`` where the group's nearest range is
        max range."""
        k, (p, g) = ranges.shape[0], self.group_angles.shape
        near, arg = ranges.reshape(k, p, g).min(dim=2)
        bearing = torch.gather(self.group_angles.expand(k, -1, -1), 2, arg[..., None])[..., 0] + pose[:, 2:3]
        near = torch.where(near < self.max_range, near, torch.full_like(near, math.inf))
        return pose[:, :2, None] + near[:, None] * torch.stack([torch.cos(bearing), torch.sin(bearing)], dim=1)

    def scan(self, points: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """The memory scan [k, S] of stored ``points [k, F, 2, P]`` (``inf`` = none) seen from ``pose [k, 3]``:
        the bearing is taken in the simulator frame and turned by the heading, the distance needs no turn."""
        k = pose.shape[0]
        dx = points[:, :, 0].reshape(k, -1) - pose[:, 0:1]
        dy = points[:, :, 1].reshape(k, -1) - pose[:, 1:2]
        dist = torch.hypot(dx, dy).clamp(max=self.max_range)  # inf (no hit) -> max range
        turn = torch.atan2(dy, dx) - pose[:, 2:3] + math.pi
        width = 2.0 * math.pi / self.sectors
        sector = (torch.remainder(turn, 2.0 * math.pi) / width).long().clamp(0, self.sectors - 1)
        out = torch.full((k, self.sectors), self.max_range, device=pose.device, dtype=torch.float32)
        return out.scatter_reduce(1, sector, dist, reduce="amin")

    def start(self, idx, pose: torch.Tensor, ranges: torch.Tensor) -> torch.Tensor:
        """New episodes in slots ``idx`` at ``pose [k, 3]`` with first scans ``ranges [k, beams]``: row 0
        holds that scan's points, every other row is forgotten. Returns the memory scan [k, S]."""
        points = torch.full((pose.shape[0], *self.points.shape[1:]), math.inf, device=pose.device,
                            dtype=torch.float32)
        points[:, 0] = self.frame(pose, ranges)
        self.points[idx] = points
        return self.scan(points, pose)

    def push(self, idx, pose: torch.Tensor, ranges: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        """One step of slots ``idx`` now at ``pose [k, 3]`` with scans ``ranges [k, beams]`` after
        ``steps [k]`` steps of their episodes: where ``steps`` is a multiple of ``every`` this scan replaces
        the oldest stored one. Returns the memory scan [k, S] from ``pose``."""
        rows = self.rows[idx]
        ring = (steps // self.every) % self.points.shape[1]
        store = (steps % self.every == 0)[:, None, None]  # no host sync: the same ops every step
        old = self.points[rows, ring]  # [k, 2, P]
        self.points[rows, ring] = torch.where(store, self.frame(pose, ranges), old)
        return self.scan(self.points[idx], pose)
