"""The paper's observation of one batch of slots: the beams' directions, the optional sensor noise,
pooling into sectors, goal distance and angle, the velocity state, and the observation space's
bounds. The opt-in extras after it are :class:`flashnav.sim.extras.ObservationExtras` (:mod:`flashnav.sim.extras`).

Observation layout (``obs_dim`` = sectors + 2 + velocity dims; 34 for TurtleBot2, 35 for Go2):

    [0, S)      pooled LiDAR: minimum range over each sector's consecutive beams, metres, (0, max_range];
                sector 0 starts at -fov/2 (the robot's right) and sectors go counter-clockwise
    S           goal distance, metres
    S + 1       goal angle in the robot frame, radians, wrapped to [-pi, pi) (positive = to the left)
    S + 2 ...   velocity state: (v, w) for 2 dims; (vx, vy, w) for 3 dims (vy = 0 for diff-drive);
                m/s and rad/s, the command executed in the last step (0 after a reset)
    then, only with ``observation.scan_history`` k > 0, the k previous pooled scans, newest first
    (:mod:`flashnav.sim.history`; a new episode starts with its first scan repeated); obs_dim += k S
    then, only with ``observation.agent_tracks`` M > 0, the M nearest agents the robot sees as a people
    tracker reports them (present, x, y, vx, vy, radius in the robot frame; :mod:`flashnav.sim.tracks`);
    obs_dim += 6 M
    then, only with ``observation.pose_trail`` P > 0, the robot's own earlier positions, one every
    ``observation.trail_every`` steps, newest first (x, y in the robot frame; :mod:`flashnav.sim.trail`;
    a new episode starts with its start position repeated); obs_dim += 2 P
    then, only with ``observation.wall_map_carrot`` L > 0, the plan's carrot: the point L metres of path along
    the wall map's plan (x, y in the robot frame, within L metres; :func:`flashnav.maps.seen_plan.carrot_points`);
    obs_dim += 2
    then, only with ``observation.memory_frames`` F > 0, the memory scan: a 360-deg pooled scan of the wall
    points hit in the last F stored scans (:mod:`flashnav.sim.memory`); obs_dim += S
    then, only with ``observation.wall_map`` C > 0, the wall map: an egocentric image of C x C squares of
    ``observation.wall_map_cell`` metres, 1 where a wall hit this episode lies (kept per slot in a grid of
    ``observation.wall_map_grid`` metres: :class:`flashnav.sim.wall_grid.WallGrid`), then 1 in the goal's square
    (:func:`flashnav.sim.wall_image.wall_image`), then, with ``observation.wall_map_visited``, 1 in the squares the
    robot's centre has passed this episode; obs_dim += 2 C^2 (3 C^2 with the visited squares)
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flashnav.config import RobotPreset
from flashnav.sim.motion import wrap_angle
from flashnav.sim.tracks import track_bounds
from flashnav.sim.trail import trail_bound


def beam_angles(fov_deg: float, beams: int) -> torch.Tensor:
    """[beams] float32 radians relative to the heading: bin centres across the field of view, from
    -fov/2 (right) counter-clockwise. For 360 deg the beams are evenly spaced with no duplicate."""
    fov = math.radians(fov_deg)
    return torch.tensor([-0.5 * fov + (k + 0.5) * fov / beams for k in range(beams)], dtype=torch.float32)


def observation_bounds(preset: RobotPreset, goal_distance_max: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) [obs_dim] float32 of the observation space; history frames repeat the LiDAR bounds,
    agent tracks :func:`flashnav.sim.tracks.track_bounds`, pose-trail breadcrumbs
    +-:func:`flashnav.sim.trail.trail_bound`, the carrot +-``observation.wall_map_carrot``, the memory scan the LiDAR's, the wall map's squares [0, 1]."""
    s = preset.lidar.sectors
    (v_lo, v_hi), (w_lo, w_hi) = preset.motion.v_bounds, preset.motion.w_bounds
    vel_lo, vel_hi = ([v_lo, w_lo], [v_hi, w_hi]) if preset.motion.velocity_state_dims == 2 else (
        [v_lo, 0.0, w_lo], [v_hi, 0.0, w_hi])
    low = np.array([0.0] * s + [0.0, -math.pi] + vel_lo, dtype=np.float32)
    high = np.array([preset.lidar.max_range] * s + [goal_distance_max, math.pi] + vel_hi, dtype=np.float32)
    k, m = preset.observation.scan_history, preset.observation.agent_tracks
    t_lo, t_hi = track_bounds(preset)
    trail = np.full(2 * preset.observation.pose_trail, trail_bound(preset), dtype=np.float32)
    carrot = preset.observation.wall_map_carrot  # its two columns lie within that many metres of the robot
    trail = np.concatenate([trail, np.full(2 if carrot else 0, carrot, dtype=np.float32)])
    mem = int(preset.observation.memory_frames > 0)  # the memory scan: LiDAR bounds, one frame
    squares = preset.observation.wall_map_channels * preset.observation.wall_map ** 2
    return (np.concatenate([low, np.tile(low[:s], k), np.tile(np.array(t_lo, np.float32), m), -trail,
                            np.tile(low[:s], mem), np.zeros(squares, np.float32)]),
            np.concatenate([high, np.tile(high[:s], k), np.tile(np.array(t_hi, np.float32), m), trail,
                            np.tile(high[:s], mem), np.ones(squares, np.float32)]))


def apply_sensor(ranges: torch.Tensor, preset: RobotPreset, gen: torch.Generator,
                 noise_std: torch.Tensor | None = None) -> torch.Tensor:
    """``ranges`` with the optional range noise and beam dropout (off by default), drawn from ``gen``;
    ``noise_std`` [n]: each row's noise level (``lidar.noise_std_max``), else ``lidar.noise_std`` for all."""
    lidar = preset.lidar
    if noise_std is not None or lidar.noise_std > 0:
        std = lidar.noise_std if noise_std is None else noise_std[:, None]
        noise = torch.randn(ranges.shape, generator=gen, device=ranges.device) * std
        ranges = (ranges + noise).clamp(0.0, lidar.max_range)
    if lidar.dropout > 0:
        drop = torch.rand(ranges.shape, generator=gen, device=ranges.device) < lidar.dropout
        ranges = torch.where(drop, torch.full_like(ranges, lidar.max_range), ranges)
    return ranges


def observe(preset: RobotPreset, ranges: torch.Tensor, pose: torch.Tensor, goal: torch.Tensor,
            velocity: torch.Tensor, gen: torch.Generator, noise_std: torch.Tensor | None = None) -> torch.Tensor:
    """The paper's observations [n, base_obs_dim] from ranges [n, beams] (sensor effects applied here, each row's
    noise level ``noise_std`` [n] if given) and the state of n slots: pose [n, 3], goal [n, 2], velocity [n, 2]
    (the command sent: with the paper's instant motion, the one executed)."""
    lidar = preset.lidar
    pooled = apply_sensor(ranges, preset, gen, noise_std).view(-1, lidar.sectors, lidar.beams_per_sector).amin(dim=2)
    delta = goal - pose[:, :2]
    dist = torch.linalg.vector_norm(delta, dim=1)
    angle = wrap_angle(torch.atan2(delta[:, 1], delta[:, 0]) - pose[:, 2])
    if preset.motion.velocity_state_dims == 3:
        velocity = torch.stack([velocity[:, 0], torch.zeros_like(velocity[:, 0]), velocity[:, 1]], dim=1)
    return torch.cat([pooled, dist[:, None], angle[:, None], velocity], dim=1)
