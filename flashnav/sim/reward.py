"""What a step ends in and what it pays (paper section 2.2), for the slots of one transition.

In the paper's order: the goal is reached when the goal distance is below ``episode.goal_threshold``
(+goal, terminated); otherwise a footprint that touches a wall or the map's edge (``collision_static``)
or a moving agent (``collision_agent``) ends the episode with the collision reward; otherwise the step
earns the shaping term ``progress x (d_old - c d_new)``, ``c = reward.progress_discount`` (1, the paper's; the
learner's discount gamma makes the term potential-based, Ng, Harada and Russell 1999). Reaching the horizon
without a terminal event is a truncation. ``d`` is the straight-line goal distance (the paper's), or with
``reward.progress_metric: geodesic`` the path length to the goal through the robot's free space (:class:`Shaping`,
:mod:`flashnav.sim.goal_fields`). With agents and ``reward.agent_proximity > 0`` (off by default) the
shaping term also pays ``agent_proximity`` per metre by which the robot is nearer an agent than
``agent_proximity_distance``. With ``reward.step_cost`` > 0 (0 by default, the paper's) every step that ends in
neither goal nor collision pays that much on top (a price on time: a robot parked short of its goal earns 0 a step
otherwise).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from flashnav.config import RobotPreset
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.goal_fields import EpisodeGoalFields, GoalFields


class Shaping:
    """The ``d`` of the shaping term per slot. With the paper's straight line it keeps no state of its
    own (the environment's ``goal_distance`` is ``d``; ``fields``, ``source`` and ``distance`` are None); with
    geodesic progress, each slot's goal source (``source`` [N]) and path length (``distance`` [N], metres) in
    its map's :class:`GoalFields`."""

    def __init__(self, preset: RobotPreset, frame_maps: Sequence[OccupancyMap], samplers, num_envs: int,
                 device: torch.device):
        self.weight, self.discount = preset.reward.progress, preset.reward.progress_discount
        self.fields = self.distance = self.source = None
        if preset.reward.progress_metric == "geodesic":
            if preset.episode.goal_sampling == "geodesic":
                self.fields = GoalFields(frame_maps, samplers, preset, device)
            elif len(frame_maps) == 1:
                self.fields = EpisodeGoalFields(frame_maps[0], preset, num_envs, device)
            else:
                raise ValueError("reward.progress_metric=geodesic with episode.goal_sampling=euclidean computes each "
                                 f"episode's field on its one map; this env has {len(frame_maps)} maps: set "
                                 "episode.goal_sampling=geodesic with many maps")
            self.distance = torch.zeros(num_envs, device=device)
            self.source = torch.full((num_envs,), -1, dtype=torch.long, device=device)

    def start(self, idx: torch.Tensor, xy: torch.Tensor, goal: torch.Tensor, straight: torch.Tensor,
              maps: torch.Tensor | None) -> None:
        """New episodes in slots ``idx`` [k]: the robots at ``xy`` [k, 2], goals [k, 2], straight-line
        distances [k], on ``maps`` [k] (None with one map)."""
        if self.fields is not None:
            self.source[idx] = source = self.fields.start(idx, goal, maps)
            self.distance[idx] = self.fields.distance(xy, source, maps, straight)

    def step(self, sel, xy: torch.Tensor, straight_old: torch.Tensor, straight: torch.Tensor,
             maps: torch.Tensor | None) -> torch.Tensor:
        """The shaping term [k] of slots ``sel`` moving to ``xy`` [k, 2] (straight-line distance from
        ``straight_old`` to ``straight``); geodesic progress updates its distances."""
        if self.fields is None:
            return self.weight * (straight_old - self.discount * straight)
        d = self.fields.distance(xy, self.source[sel], maps, straight, unknown=self.distance[sel])
        gain = self.weight * (self.distance[sel] - self.discount * d)
        self.distance[sel] = d
        return gain


def outcome(preset: RobotPreset, dist: torch.Tensor, static: torch.Tensor, agent: torch.Tensor,
            steps: torch.Tensor, shaping: torch.Tensor) -> dict[str, torch.Tensor]:
    """Flags and reward [k] of one step: ``dist`` the goal distance after it, ``static`` / ``agent`` the
    footprint's raw hits, ``steps`` the episode's step count after it, ``shaping`` the step's shaping
    term (``reward.step_cost`` is subtracted from it). The goal is checked first: a step that reaches it is no
    collision."""
    success = dist < preset.episode.goal_threshold
    static, agent = static & ~success, agent & ~success
    collision = static | agent
    terminated = success | collision
    truncated = (steps >= preset.episode.horizon) & ~terminated
    live = shaping - preset.reward.step_cost if preset.reward.step_cost else shaping
    reward = torch.where(success, preset.reward.goal, torch.where(collision, preset.reward.collision, live))
    return {"reward": reward, "terminated": terminated, "truncated": truncated, "success": success,
            "collision": collision, "collision_static": static, "collision_agent": agent}
