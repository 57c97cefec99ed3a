"""Observations spread over a robot's valid ranges, without a simulator: the inputs the export traces and checks a
policy with (:mod:`flashnav.export`), and tests' random inputs of the right layout."""

from __future__ import annotations

import math

import torch

from flashnav.config import TRACK_FEATURES, RobotPreset
from flashnav.sim.tracks import track_bounds
from flashnav.sim.trail import trail_bound


def sample_observations(preset: RobotPreset, n: int, generator: torch.Generator | None = None,
                        goal_distance_max: float | None = None) -> torch.Tensor:
    """``[n, D]`` float32 observations spread over the valid ranges (for export checks and tests).

    LiDAR readings (the current frame, any history frames and the memory scan) are uniform in [inscribed radius, max
    range] with about a tenth exactly at each end (the IPAPRec pole side and the no-return reading); goal distance in [0, goal_distance_max]
    (default: the diagonal of the preset's map size), goal
    angle in [-pi, pi), velocities inside the command bounds (vy = 0 for a 3-D velocity state); a wall map's
    squares 0 / 1 (:func:`_wall_map`).
    """
    s, lidar, m = preset.lidar.sectors, preset.lidar, preset.motion
    r_in, r_max = preset.footprint.inscribed_radius, lidar.max_range
    u = lambda *shape: torch.rand(*shape, generator=generator)  # noqa: E731
    ranges = _readings(n, s, r_in, r_max, u)
    dist = (goal_distance_max or math.hypot(*preset.map_size)) * u(n, 1)
    angle = math.pi * (2.0 * u(n, 1) - 1.0)
    v = m.v_bounds[0] + (m.v_bounds[1] - m.v_bounds[0]) * u(n, 1)
    w = m.w_bounds[0] + (m.w_bounds[1] - m.w_bounds[0]) * u(n, 1)
    velocity = [v, w] if m.velocity_state_dims == 2 else [v, torch.zeros_like(v), w]
    history = [_readings(n, s, r_in, r_max, u) for _ in range(preset.observation.scan_history)]
    bound = trail_bound(preset)
    trail = bound * (2.0 * u(n, 2 * preset.observation.pose_trail) - 1.0)
    carrot = preset.observation.wall_map_carrot  # within that many metres of the robot, each axis uniform
    carrot = [carrot * (2.0 * u(n, 2) - 1.0)] if carrot else []
    memory = [_readings(n, s, r_in, r_max, u)] if preset.observation.memory_frames else []
    return torch.cat([ranges, dist, angle, *velocity, *history, _tracks(preset, n, u), trail, *carrot, *memory,
                      _wall_map(preset, n, u)], dim=1)


def _wall_map(preset: RobotPreset, n: int, u) -> torch.Tensor:
    """``[n, 2 C^2]`` wall maps for :func:`sample_observations`: each square a wall with probability 1/5, the
    goal in one square (with ``observation.wall_map_visited``, then ``C^2`` visited squares, each with
    probability 1/10; with ``observation.wall_map_plan``, then ``C^2`` plan squares, each with probability 1/20)."""
    c = preset.observation.wall_map
    if not c:  # no draws: the other columns stay what they were before the wall map existed
        return torch.zeros(n, 0)
    walls = (u(n, c * c) < 0.2).float()
    goal = torch.zeros(n, c * c)
    goal[torch.arange(n), (u(n) * c * c).long().clamp(max=c * c - 1)] = 1.0
    visited = [(u(n, c * c) < 0.1).float()] if preset.observation.wall_map_visited else []
    plan = [(u(n, c * c) < 0.05).float()] if preset.observation.wall_map_plan else []
    return torch.cat([walls, goal, *visited, *plan], dim=1)


def _tracks(preset: RobotPreset, n: int, u) -> torch.Tensor:
    """``[n, 6 M]`` agent tracks for :func:`sample_observations`: each present with probability 1/2,
    features uniform within the observation bounds, absent ones zero."""
    m = preset.observation.agent_tracks
    lo, hi = (torch.tensor(b, dtype=torch.float32) for b in track_bounds(preset))
    feats = lo + (hi - lo) * u(n, m, len(TRACK_FEATURES))
    present = (u(n, m, 1) < 0.5).float()
    feats = torch.cat([present, feats[..., 1:]], dim=-1) * present
    return feats.flatten(1)


def _readings(n: int, s: int, r_in: float, r_max: float, u) -> torch.Tensor:
    """``[n, s]`` LiDAR readings for :func:`sample_observations` from the uniform draw ``u``."""
    ranges = r_in + (r_max - r_in) * u(n, s)
    pick = u(n, s)
    ranges = torch.where(pick < 0.1, torch.full_like(ranges, r_in), ranges)
    return torch.where(pick > 0.9, torch.full_like(ranges, r_max), ranges)
