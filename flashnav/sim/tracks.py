"""The opt-in agent tracks of the observation (``observation.agent_tracks``, issue 13).

A policy that sees only range scans cannot tell a pedestrian walking into its path from one walking
away; a robot among people usually runs a people tracker (a leg detector on the LiDAR, a camera
detector) that reports each person's position and velocity. With ``agent_tracks = M > 0`` every
observation ends with the M nearest agents the robot can see, as such a tracker would report them::

    [E + 6 j, E + 6 (j + 1))   track j = 0 .. M - 1, nearest first:
                               present (1 or 0), x, y (m, the agent's centre in the robot frame: x ahead,
                               y to the left), vx, vy (m/s, its velocity in the robot frame), radius (m)

with E = ``preset.history_end`` (the paper's observation and any scan history before them). Absent
tracks (fewer than M agents seen) are all zero. What the simulated tracker sees and reports:

- **seen**: an active agent whose centre lies inside the LiDAR's field of view, whose near edge is
  within ``lidar.max_range``, and whose centre beam (the beam nearest its bearing) reads at least its
  near-edge distance minus ``SEEN_TOLERANCE``: the beam reaches the agent, so no wall and no other
  agent stands in front of it. These are the agents a LiDAR leg tracker could pick out of the scan.
- **order**: by the distance from the robot's centre to the agent's edge, nearest first.
- **velocity**: the agent's displacement over the last control step divided by ``episode.dt`` (a
  tracker's two-frame estimate), and 0 for an agent that was not seen at the previous step (a new
  track has no velocity yet). A new episode starts with every velocity 0.
- positions, velocities and radii are exact (no tracker noise); the sensor's range noise and dropout
  (``lidar.noise_std``, ``lidar.dropout``) do not touch them.

Without agents (``agents.count`` 0) every track is absent. The robot side
(:mod:`flashnav.deploy.runtime`) takes the same tracks from the robot's tracker.
"""

from __future__ import annotations

import math

import torch

from flashnav.config import TRACK_FEATURES, RobotPreset
from flashnav.sim.motion import wrap_angle

#: metres: a centre beam that reads this much less than the agent's near edge is blocked by
#: something in front of it (float32 ranges of a 10 m scan agree with the geometry to ~1e-5 m; the
#: beam next to the bearing passes at most half a beam spacing off the centre, which only lengthens it)
SEEN_TOLERANCE = 0.01
#: columns per track
WIDTH = len(TRACK_FEATURES)


def track_scales(preset: RobotPreset) -> tuple[float, ...]:
    """Divisors of one track's columns inside the networks: 1, max_range, max_range, the robot's top
    forward speed (twice), the largest agent radius (1 m without agents)."""
    v = max(abs(b) for b in preset.motion.v_bounds)
    r = preset.agents.radius[1] if preset.agents.count else 1.0
    return (1.0, preset.lidar.max_range, preset.lidar.max_range, v, v, r)


def track_bounds(preset: RobotPreset) -> tuple[list[float], list[float]]:
    """(low, high) of one track's columns for the observation space."""
    rng = preset.lidar.max_range + (preset.agents.radius[1] if preset.agents.count else 0.0)
    v = preset.agents.speed[1] if preset.agents.count else 0.0
    r = preset.agents.radius[1] if preset.agents.count else 0.0
    return [0.0, -rng, -rng, -v, -v, 0.0], [1.0, rng, rng, v, v, r]


class AgentTracks:
    """The tracker state of N slots: each agent's position at the previous step and whether it was seen."""

    def __init__(self, preset: RobotPreset, num_envs: int, beam_angles: torch.Tensor, device: torch.device):
        self.tracks = preset.observation.agent_tracks
        if self.tracks < 1:
            raise ValueError(f"AgentTracks needs observation.agent_tracks >= 1, got {self.tracks}")
        self.dt = preset.episode.dt
        self.view = TrackerView(preset, beam_angles)
        self.prev = torch.zeros(num_envs, preset.agents.count, 2, device=device)  # agent centres at the previous step, m
        self.seen = torch.zeros(num_envs, preset.agents.count, dtype=torch.bool, device=device)  # seen at the previous step
        self.device = device

    @property
    def columns(self) -> int:
        return self.tracks * WIDTH

    def observe(self, sel, agents, pose: torch.Tensor, ranges: torch.Tensor, fresh: bool) -> torch.Tensor:
        """The tracks [k, M * 6] of slots ``sel`` (``ranges`` [k, B] m the noise-free scan at ``pose`` [k, 3]
        with the agents in it); ``fresh``: new episodes there, every velocity 0, else one step after
        the last call (the agents already moved)."""
        k = pose.shape[0]
        if agents is None:
            return torch.zeros(k, self.columns, device=pose.device)
        pos, radius, active = agents.pos[sel], agents.radius[sel], agents.active[sel]
        seen = self.seen_by(pose, pos, radius, active, ranges)
        velocity = torch.zeros_like(pos) if fresh else torch.where(
            (seen & self.seen[sel])[..., None], (pos - self.prev[sel]) / self.dt, torch.zeros_like(pos))
        self.prev[sel], self.seen[sel] = pos, seen
        return encode(pose, pos, velocity, radius, seen, self.tracks)

    def seen_by(self, pose, pos, radius, active, ranges) -> torch.Tensor:
        """[k, K] bool: the agents the robot sees (:meth:`TrackerView.seen_by`)."""
        return self.view.seen_by(pose, pos, radius, active, ranges)


class TrackerView:
    """What the simulated tracker can see with the preset's LiDAR (field of view, range, beams)."""

    def __init__(self, preset: RobotPreset, beam_angles: torch.Tensor):
        self.max_range = preset.lidar.max_range
        self.half_fov = math.radians(preset.lidar.fov_deg) / 2.0
        self.full_circle = preset.lidar.fov_deg >= 360.0
        a = torch.as_tensor(beam_angles, dtype=torch.float32).reshape(-1)
        self.beams = a.numel()
        self._a0 = float(a[0])
        self._a_step = float(a[-1] - a[0]) / (self.beams - 1) if self.beams > 1 else 1.0

    def seen_by(self, pose, pos, radius, active, ranges) -> torch.Tensor:
        """[k, K] bool: the agents (centres ``pos`` [k, K, 2], ``radius`` [k, K], ``active`` [k, K]) that
        the robot at ``pose`` [k, 3] sees in ``ranges`` [k, B] (module docstring)."""
        rel = pos - pose[:, None, :2]
        dist = torch.linalg.vector_norm(rel, dim=-1)
        bearing = wrap_angle(torch.atan2(rel[..., 1], rel[..., 0]) - pose[:, 2:3])
        near = dist - radius
        beam = torch.round((bearing - self._a0) / self._a_step).long()
        if self.full_circle:
            beam = beam.remainder(self.beams)
            inside = torch.ones_like(active)
        else:
            inside = bearing.abs() <= self.half_fov
            beam = beam.clamp(0, self.beams - 1)
        reading = torch.gather(ranges, 1, beam)
        return active & inside & (near <= self.max_range) & (reading >= near - SEEN_TOLERANCE)


def seen_world_rows(view: TrackerView, agents, pose: torch.Tensor, ranges: torch.Tensor, previous, dt: float,
                    origin=(0.0, 0.0)):
    """Slot 0's tracker output as a robot's people tracker publishes it (``flashnav deploy sim-robot``):
    rows of (x, y, vx, vy, radius) in the world frame (the simulator frame + ``origin``) of the agents
    ``view`` sees from ``pose`` [1, 3] in ``ranges`` [1, B], nobody without agents. ``previous`` is what
    the last call returned second (None at an episode's start): the velocity is the displacement since
    then over ``dt`` for an agent seen both times, else 0, as in the observation. Returns (rows, state)."""
    if agents is None:
        return [], None
    pos, radius, active = agents.pos[:1], agents.radius[:1], agents.active[:1]
    seen = view.seen_by(pose, pos, radius, active, ranges)[0]
    velocity = torch.zeros_like(pos[0])
    if previous is not None:
        before, was_seen = previous
        velocity = torch.where((seen & was_seen)[:, None], (pos[0] - before) / dt, velocity)
    rows = [[float(pos[0, j, 0]) + origin[0], float(pos[0, j, 1]) + origin[1], *velocity[j].tolist(),
             float(radius[0, j])] for j in torch.nonzero(seen).flatten().tolist()]
    return rows, (pos[0].clone(), seen)


def encode(pose: torch.Tensor, pos: torch.Tensor, velocity: torch.Tensor, radius: torch.Tensor, seen: torch.Tensor,
           tracks: int) -> torch.Tensor:
    """[k, tracks * 6]: the ``tracks`` nearest seen agents (by edge distance) as (1, x, y, vx, vy, radius) in
    the robot frame of ``pose`` [k, 3]; world-frame ``pos``, ``velocity`` [k, K, 2], ``radius`` [k, K],
    ``seen`` [k, K]; absent tracks all zero."""
    k, count = seen.shape
    c, s = torch.cos(pose[:, 2:3]), torch.sin(pose[:, 2:3])
    rel = pos - pose[:, None, :2]
    x, y = c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]
    vx, vy = c * velocity[..., 0] + s * velocity[..., 1], -s * velocity[..., 0] + c * velocity[..., 1]
    feats = torch.stack([torch.ones_like(x), x, y, vx, vy, radius], dim=-1) * seen[..., None]
    order = torch.linalg.vector_norm(rel, dim=-1) - radius
    order = torch.where(seen, order, torch.full_like(order, math.inf))
    m = min(tracks, count)
    pick = torch.topk(order, m, dim=1, largest=False).indices  # nearest first (ties: any order)
    out = torch.gather(feats, 1, pick[..., None].expand(-1, -1, WIDTH)).flatten(1)
    if m < tracks:
        out = torch.cat([out, out.new_zeros(k, (tracks - m) * WIDTH)], dim=1)
    return out
