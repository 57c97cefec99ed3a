"""The opt-in columns after the paper's observation (:mod:`flashnav.sim.env`'s layout): the scan history
(:mod:`flashnav.sim.history`), the agent tracks (:mod:`flashnav.sim.tracks`), the pose trail
(:mod:`flashnav.sim.trail`), the plan's carrot, the memory scan (:mod:`flashnav.sim.memory`) and the wall map
(:mod:`flashnav.sim.wall_grid`), in that order.
Each is None where its option is 0: then the step is exactly the paper's."""

from __future__ import annotations

import torch

from flashnav.config import RobotPreset
from flashnav.sim.history import ScanHistory
from flashnav.sim.memory import WallMemory
from flashnav.sim.wall_grid import HIT_BEYOND_M, WallGrid, grid_shape
from flashnav.sim.tracks import AgentTracks
from flashnav.sim.trail import PoseTrail


class ObservationExtras:
    """Per-slot state of the opt-in observation columns of ``n`` env slots."""

    def __init__(self, preset: RobotPreset, n: int, beam_angles: torch.Tensor, device: torch.device):
        o = preset.observation
        self.history = ScanHistory(n, o.scan_history, preset.lidar.sectors, device) if o.scan_history else None
        self.tracks = AgentTracks(preset, n, beam_angles, device) if o.agent_tracks else None
        self.trail = PoseTrail(n, o.pose_trail, o.trail_every, device) if o.pose_trail else None
        self.memory = WallMemory.from_preset(preset, n, beam_angles, device) if o.memory_frames else None
        self.preset, self.n, self.beam_angles, self.device = preset, n, beam_angles, device
        self.walls: WallGrid | None = None  # the wall map's grids: built on the env's maps (use_maps)
        self._origins: torch.Tensor | None = None

    def use_maps(self, maps) -> None:
        """The env's maps (simulator frame) changed: the wall map's grids span the largest of them, each slot's
        grid set at its map's origin when its next episode starts (every slot starts one after a change)."""
        o = self.preset.observation
        if not o.wall_map:
            return
        self.walls = WallGrid(self.n, grid_shape(maps, o.wall_map_grid), o.wall_map_grid, self.preset.lidar.max_range,
                              self.beam_angles, self.device, HIT_BEYOND_M, o.wall_map_visited, o.wall_map_plan,
                              o.wall_map_plan_penalty, o.wall_map_carrot)
        self._origins = torch.tensor([g.origin for g in maps], dtype=torch.float32, device=self.device)

    def append(self, obs: torch.Tensor, sel, agents, pose: torch.Tensor, ranges: torch.Tensor, start: bool,
               steps: torch.Tensor | None = None, goal: torch.Tensor | None = None,
               maps: torch.Tensor | None = None) -> torch.Tensor:
        """The paper's observations ``obs`` [k, D] of slots ``sel`` with the extras after them: the scan
        history (a new episode, ``start``, fills it; a step gives the frames before it, then this scan joins
        them), the ``agents`` seen, as a tracker reports them, the pose trail, the memory scan (``steps``
        [k]: the slots' episode steps after this step; not needed at a start) and the wall map (``goal`` [k, 2]
        the slots' goals; ``maps`` [k] their map indices, None with one map; the carrot is the wall map's)."""
        if self.history is not None:
            obs = (self.history.start if start else self.history.push)(sel, obs)
        if self.tracks is not None:
            obs = torch.cat([obs, self.tracks.observe(sel, agents, pose, ranges, fresh=start)], dim=1)
        if self.trail is not None:
            obs = torch.cat([obs, self.trail.start(sel, pose) if start else self.trail.push(sel, pose, steps)], dim=1)
        image = None
        if self.walls is not None:
            o = self.preset.observation
            if start:
                origin = self._origins[0 if maps is None else maps]
                self.walls.start(sel, pose, ranges, origin.expand(pose.shape[0], 2))
            else:
                self.walls.push(sel, pose, ranges)
            plan, carrots = self.walls.plan_cells(sel, pose, goal) if self.walls.plan else (None, None)
            image = self.walls.image(sel, pose, goal, o.wall_map, o.wall_map_cell, plan).reshape(pose.shape[0], -1)
            if carrots is not None:
                obs = torch.cat([obs, carrots.to(obs.dtype)], dim=1)
        if self.memory is not None:
            m = self.memory
            obs = torch.cat([obs, m.start(sel, pose, ranges) if start else m.push(sel, pose, ranges, steps)], dim=1)
        if image is not None:
            obs = torch.cat([obs, image], dim=1)
        return obs
