"""Path guidance: a global planner in front of the policy (``flashnav eval --guide M``), on the map it knows
(:class:`PathGuide`) or on the walls its own scans have shown (:class:`MaplessGuide`, ``--guide-from scans``;
:mod:`flashnav.mapless`).

A robot in a building it has a map of does not aim its local controller at a goal behind walls: a global
planner hands it a point a little way along the shortest path (the "carrot" of pure-pursuit controllers
such as Nav2's regulated pure pursuit), and the LiDAR policy steers there around what it sees. The
paper's task is the unguided one (the policy gets the goal); guidance is a deployment mode, measured
and reported as its own column, never mixed with the zero-shot numbers.

:class:`PathGuide` does this for the episodes placed in an environment: one bounded Dijkstra per
episode from its goal cell through the free space of the robot's circumscribed disc (the fields of
:class:`flashnav.sim.goal_fields.WindowFields`, out to the goal band's top + ``margin`` metres of path),
and at every step, for each slot, the point ``lookahead`` metres of path along steepest descent from
the robot (cell by cell, 8-connected). The policy sees that point in the observation's goal columns
(distance and angle, as the environment computes them for a goal); success, collisions and the reward
are still the environment's, about the real goal. Where the robot is beyond the field (farther than
the bound, or no free cell around it) the policy gets the real goal.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flashnav.mapless import SENSORS, SeenWalls
from flashnav.sim.goal_fields import WindowFields
from flashnav.sim.motion import wrap_angle

LOOKAHEAD_M = 1.5  # the default carrot distance along the path, metres
MARGIN_M = 3.0  # path beyond the goal band's top that each episode's field still covers, metres


class PathGuide:
    """Carrots along the shortest paths to the goals of the episodes now in ``env`` (call after
    ``set_state`` or ``reset``, before stepping); :meth:`observe` puts them in observations."""

    def __init__(self, env, lookahead: float = LOOKAHEAD_M, margin: float = MARGIN_M):
        if not (math.isfinite(lookahead) and lookahead > 0):
            raise ValueError(f"path guidance lookahead must be > 0 metres, got {lookahead}")
        self.env, self.lookahead = env, float(lookahead)
        maps = env.map_index.cpu().numpy()
        goal = env.goal.detach().cpu().double().numpy()  # the simulator frame, as the frame maps
        cells, order = [], []
        for m, grid in enumerate(env.frame_maps):
            slots = np.flatnonzero(maps == m)
            row, col = grid.cell_of(goal[slots], clip=True)
            cells.append(row * grid.shape[1] + col)
            order.append(slots)
        bound = max(s.d_max for s in env.samplers) + margin if env.sampler.mode == "geodesic" else (
            env.preset.episode.max_goal_distance + margin)
        self.fields = WindowFields(env.frame_maps, cells, env.preset.footprint.circumscribed_radius, bound,
                                   env.device)
        field_of_slot = np.empty(env.num_envs, dtype=np.int64)
        field_of_slot[np.concatenate(order)] = np.arange(env.num_envs)
        self.field_of_slot = torch.as_tensor(field_of_slot, device=env.device)
        self.max_moves = int(math.ceil(self.lookahead / float(self.fields.res.min()))) + 1
        diagonal = (self.fields.offsets != 0).all(dim=1)
        self.step_cells = torch.where(diagonal, math.sqrt(2.0), 1.0)  # [9] step length, cells (0 for "stay")
        self.step_cells[(self.fields.offsets == 0).all(dim=1)] = 0.0

    def carrot(self, idx: torch.Tensor) -> torch.Tensor:
        """[k, 2] metres (simulator frame): the point ``lookahead`` metres of path from slots ``idx`` [k]
        towards their goals, or the goal itself where the path is shorter or unknown."""
        env, f = self.env, self.fields
        ids, m = self.field_of_slot[idx], env.map_index[idx]
        pos, goal = env.pose[idx, :2].float(), env.goal[idx].float()
        d, cell = f.nearest(pos, ids, m)
        value = torch.where(torch.isfinite(d), f.values(cell[:, None, :], ids)[:, 0], torch.full_like(d, math.inf))
        travelled = torch.zeros_like(d)
        step_m = self.step_cells[None, :] * f.res[m][:, None]  # [k, 9]
        for _ in range(self.max_moves):
            around = cell[:, None, :] + f.offsets  # [k, 9, 2]
            lowest, j = f.values(around, ids).min(dim=1)
            move = torch.isfinite(value) & (lowest < value) & (travelled < self.lookahead)
            if not bool(move.any()):
                break
            pick = around[torch.arange(len(j), device=j.device), j]
            cell = torch.where(move[:, None], pick, cell)
            travelled = travelled + torch.where(move, step_m.gather(1, j[:, None])[:, 0], torch.zeros_like(d))
            value = torch.where(move, lowest, value)
        point = f.centres(cell[:, None, :], m)[:, 0]
        at_goal = ~torch.isfinite(d) | (d <= self.lookahead) | (value <= 0)  # unknown, or the goal is the carrot
        return torch.where(at_goal[:, None], goal, point)

    def observe(self, obs: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        """Observations [k, D] of slots ``idx`` [k] with their goal columns (distance, angle) pointing at
        their carrots instead of their goals."""
        return aim(self.env, obs, idx, self.carrot(idx))


def aim(env, obs: torch.Tensor, idx: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Observations ``obs`` [k, D] of slots ``idx`` [k] with their goal columns (distance, angle, as the
    environment computes them for a goal) pointing at ``points`` [k, 2] (simulator frame) instead."""
    col = env.preset.lidar.sectors
    pose = env.pose[idx]
    delta = points.double() - pose[:, :2].double()
    out = obs.clone()
    out[:, col] = torch.linalg.vector_norm(delta, dim=1).to(obs.dtype)
    out[:, col + 1] = wrap_angle(torch.atan2(delta[:, 1], delta[:, 0]) - pose[:, 2].double()).to(obs.dtype)
    return out


class EnvScans:
    """What :class:`SeenWalls` is fed in the simulator: the scans, poses and goals of an env's slots
    (one map per env: the walls live on its grid). ``sensor``: ``raw`` (every beam) or ``pooled`` (only
    what the policy's observation keeps: each sector's minimum range, across the sector's arc)."""

    def __init__(self, env, sensor: str = "raw"):
        if sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {SENSORS}, got {sensor!r}")
        if env.num_maps != 1:
            raise ValueError(f"the mapless planner plans on one map per env, got {env.num_maps} maps "
                             "(evaluate them one at a time)")
        self.env, self.sensor = env, sensor

    def walls(self, margin: float = 0.08, comfort: float = 0.3, memory: bool = True, carve: bool = True) -> SeenWalls:
        """A :class:`SeenWalls` for the env's slots on its map's grid (the simulator frame)."""
        env = self.env
        return SeenWalls(env.frame_maps[0], env.num_envs, env.preset.footprint.circumscribed_radius + margin,
                         comfort, memory=memory, carve=carve)

    def scans(self, slots: np.ndarray) -> tuple:
        """(pose [k, 3], ranges [k, B], angles [B], max_range) of ``slots`` now."""
        env = self.env
        sel = torch.as_tensor(slots, device=env.device)
        ranges = env.scan(sel).cpu().numpy()
        lidar = env.preset.lidar
        if self.sensor == "pooled":
            pooled = ranges.reshape(len(slots), lidar.sectors, lidar.beams_per_sector).min(axis=2)
            ranges = np.repeat(pooled, lidar.beams_per_sector, axis=1)
        return (env.pose[sel].cpu().numpy().astype(np.float64), ranges, env.beam_angles.cpu().numpy(),
                lidar.max_range)

    def goals(self, slots: np.ndarray) -> np.ndarray:
        return self.env.goal[torch.as_tensor(slots, device=self.env.device)].cpu().numpy().astype(np.float64)

    def positions(self, slots: np.ndarray) -> np.ndarray:
        return self.env.pose[torch.as_tensor(slots, device=self.env.device), :2].cpu().numpy().astype(np.float64)


class MaplessGuide:
    """Carrots on paths planned over each slot's own scans (no map): the interface of
    :class:`flashnav.guidance.PathGuide` (:meth:`observe`), for one-map envs. A slot's memory starts
    empty at the first :meth:`observe` of its episode (call ``reset``/``set_state`` first, then observe
    before every step, as :func:`flashnav.evaluate.play_episodes` does). See :meth:`SeenWalls.carrot`;
    ``carve=False``: wall marks are never forgotten (moving agents leave trails of walls)."""

    def __init__(self, env, lookahead: float = LOOKAHEAD_M, margin: float = 0.0, comfort: float = 0.3,
                 escape: float = 0.3, carve: bool = True):
        if not (math.isfinite(lookahead) and lookahead > 0):
            raise ValueError(f"mapless guidance lookahead must be > 0 metres, got {lookahead}")
        self.env, self.lookahead, self.escape = env, float(lookahead), float(escape)
        self.source = EnvScans(env)
        self.walls = self.source.walls(margin, comfort, carve=carve)
        self.planned = np.zeros(env.num_envs, dtype=bool)

    def carrot(self, slots: np.ndarray) -> np.ndarray:
        """[k, 2] metres (simulator frame) for ``slots`` at their current positions."""
        return self.walls.carrot(slots, self.source.positions(slots), self.lookahead, self.escape)

    def observe(self, obs: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        """Observations [k, D] of slots ``idx`` [k] with their goal columns pointing at their carrots;
        first updates the slots' memories with their current scans (and replans where needed)."""
        slots = idx.cpu().numpy()
        fresh = ~self.planned[slots]
        first, later = slots[fresh], slots[~fresh]
        if len(first):
            self.walls.plan(first, self.source.goals(first), self.source.scans(first))
            self.planned[first] = True
        if len(later):
            self.walls.update(later, self.source.scans(later))
        points = torch.as_tensor(self.carrot(slots), device=self.env.device)
        return aim(self.env, obs, idx, points)
