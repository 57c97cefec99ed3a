"""Mirror augmentation of replay batches (``algo.mirror``): the left-right reflection of a transition.

The navigation MDP is symmetric about the robot's heading: both robots' footprints (a disc, a rectangle
centred on the robot) and fields of view (centred on the heading, beams at symmetric angles:
:func:`flashnav.sim.observation.beam_angles`) are mirror images of themselves, and the motion model turns
left as it turns right. So a transition seen in a map has a twin in the mirror image of that map: the
scan read from right to left, the goal and every robot-frame y on the other side, every turn rate
negated, the same reward and the same ending. A learner that is fed a share of its batches mirrored sees
both sides of every situation it met (a goal behind-left teaches behind-right too) for the cost of a
gather, without another environment step.

The observation columns (:attr:`flashnav.config.RobotPreset.obs_dim`) and what the mirror does to each:

- pooled sectors, current and each frame of ``observation.scan_history``: reversed in order (sector s,
  counted from -fov/2 on the right, becomes sector S - 1 - s);
- goal distance: kept; goal angle: negated;
- velocity state (v, w) or (vx, vy, w): v and vx kept, vy and w negated;
- agent tracks (present, x, y, vx, vy, radius): y and vy negated;
- pose-trail breadcrumbs (x, y): y negated;
- the plan's carrot (x, y): y negated;
- the memory scan (360 deg from straight behind): reversed in order;
- the wall map's squares, every channel (walls, goal, visited): rows (across the robot, row 0 rightmost)
  reversed, columns kept.

Actions (v, w), normalised: w negated, which is the mirrored command because ``motion.w_bounds`` are
symmetric about 0 (a preset whose bounds are not cannot be mirrored: :func:`mirror_for` says so).
``tests/test_mirror.py`` checks all of it against the simulator itself: a mirrored pose on a mirrored
map gives the mirrored observation, reward and ending.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from flashnav.config import TRACK_FEATURES, RobotPreset


@dataclass(frozen=True)
class Mirror:
    """``obs_index [D]`` / ``obs_sign [D]``: mirrored obs = ``obs[..., obs_index] * obs_sign``;
    ``action_sign [A]``: mirrored action = ``action * action_sign``; ``fraction``: the share of each
    sampled batch's rows mirrored (each row independently, with that probability)."""

    obs_index: torch.Tensor
    obs_sign: torch.Tensor
    action_sign: torch.Tensor
    fraction: float

    def obs(self, obs: torch.Tensor) -> torch.Tensor:
        return obs[..., self.obs_index] * self.obs_sign

    def action(self, action: torch.Tensor) -> torch.Tensor:
        return action * self.action_sign

    def apply(self, batch, generator: torch.Generator):
        """Mirror a random ``fraction`` of the rows of ``batch`` (a :class:`flashnav.learn.replay.Transition`
        of ``[..., D]`` tensors), in place; rewards and bootstrap weights are the twin's own. Draws one
        uniform number per row from ``generator``. Returns ``batch``."""
        rows = batch.reward.shape
        pick = torch.rand(rows, generator=generator, device=batch.reward.device) < self.fraction
        flip = pick[..., None]
        batch.obs.copy_(torch.where(flip, self.obs(batch.obs), batch.obs))
        batch.next_obs.copy_(torch.where(flip, self.obs(batch.next_obs), batch.next_obs))
        batch.action.copy_(torch.where(flip, self.action(batch.action), batch.action))
        return batch


def mirror_for(preset: RobotPreset, fraction: float, device: torch.device | str = "cpu") -> Mirror | None:
    """The :class:`Mirror` of ``preset``'s observation and action layout, or None for ``fraction`` 0.
    Raises ValueError naming the setting where the robot is not left-right symmetric."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"algo.mirror must be a fraction in [0, 1], got {fraction}")
    if fraction == 0.0:
        return None
    lo, hi = preset.motion.w_bounds
    if abs(lo + hi) > 1e-9 * max(abs(lo), abs(hi), 1.0):
        raise ValueError(f"algo.mirror needs turn-rate bounds symmetric about 0 ({preset.name}: motion.w_bounds "
                         f"= ({lo}, {hi})): a mirrored turn would not be a command the robot can take")
    s = preset.lidar.sectors
    index = list(range(s))[::-1]
    sign = [1.0] * s
    index += [s, s + 1]  # goal distance, goal angle
    sign += [1.0, -1.0]
    vel = list(range(s + 2, preset.base_obs_dim))
    index += vel
    sign += [1.0] * (len(vel) - 1) + [-1.0]  # the turn rate is the last velocity column
    if preset.motion.velocity_state_dims == 3:
        sign[s + 3] = -1.0  # vy
    for frame in range(preset.observation.scan_history):
        start = preset.base_obs_dim + frame * s
        index += list(range(start, start + s))[::-1]
        sign += [1.0] * s
    width = len(TRACK_FEATURES)
    flipped = {TRACK_FEATURES.index("y"), TRACK_FEATURES.index("vy")}
    for track in range(preset.observation.agent_tracks):
        start = preset.history_end + track * width
        index += list(range(start, start + width))
        sign += [-1.0 if c in flipped else 1.0 for c in range(width)]
    for crumb in range(preset.observation.pose_trail):
        start = preset.tracks_end + 2 * crumb
        index += [start, start + 1]
        sign += [1.0, -1.0]
    if preset.observation.wall_map_carrot:
        index += [preset.trail_end, preset.trail_end + 1]
        sign += [1.0, -1.0]
    if preset.observation.memory_frames:  # 360 deg from straight behind: a mirror image reverses the sectors
        index += list(range(preset.carrot_end, preset.carrot_end + s))[::-1]
        sign += [1.0] * s
    cells = preset.observation.wall_map
    # rows run across the robot (row 0 rightmost): a mirror reverses them
    for channel in range(preset.observation.wall_map_channels):
        start = preset.memory_end + channel * cells * cells
        index += [start + (cells - 1 - r) * cells + c for r in range(cells) for c in range(cells)]
        sign += [1.0] * (cells * cells)
    if len(index) != preset.obs_dim:  # a column this module does not know: refuse rather than guess
        raise ValueError(f"algo.mirror: {preset.name}'s observation has {preset.obs_dim} columns, the mirror "
                         f"knows {len(index)}")
    f32 = dict(dtype=torch.float32, device=device)
    return Mirror(obs_index=torch.tensor(index, dtype=torch.long, device=device), obs_sign=torch.tensor(sign, **f32),
                  action_sign=torch.tensor([1.0, -1.0], **f32), fraction=float(fraction))
