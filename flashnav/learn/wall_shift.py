"""Random-shift augmentation of the wall map in replay batches (``algo.wall_shift``), as in DrQ and DrQ-v2.

DrQ (Kostrikov et al. 2020; Yarats et al. 2021) trains an image encoder with the critic's loss alone and keeps it
from fitting the few images it has seen by shifting every sampled image a few pixels at random (pad 4 of an 84 x 84
frame, then a random crop back to 84 x 84), the observation and the next observation each with its own draw. Here the
image is the egocentric wall map (:mod:`flashnav.learn.wall_map`, ``observation.wall_map`` squares of
``observation.wall_map_cell`` metres a side): each sampled row's map, every channel together (walls, goal and visited
squares, so the goal keeps its place among the walls), moves by (dr, dc) squares, each drawn uniformly from
``-k..k``, and the squares it uncovers are 0. Zero and not DrQ's replicated border: beyond the window nothing is
drawn, a 0 is what the map already says there, and a replicated goal square would smear into a line. With the map's
0.5 m squares and k = 1 the robot's place in its map moves by at most one square (DrQ's 4 of 84 pixels are about 1.1
of 24 squares); the scan and the goal's distance and angle, the rest of the observation, stay exact.

Rows of the map run across the robot, columns along its heading (:func:`flashnav.sim.wall_image.wall_image`); a shift
moves both. The actor step reads the same shifted squares as the critic (:func:`flashnav.learn.common.actor_view`
re-encodes the batch's own squares), as in DrQ-v2. ``tests/test_wall_shift.py`` checks the shift against a
square-by-square loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from flashnav.config import RobotPreset
from flashnav.learn.wall_map import WALL_MAP_CHANNELS


@dataclass(frozen=True)
class WallShift:
    """Shift the ``channels C^2`` wall-map columns starting at ``start`` (C = ``cells``) by up to ``reach`` squares."""

    start: int
    cells: int
    reach: int
    channels: int = WALL_MAP_CHANNELS

    @property
    def end(self) -> int:
        """One past the map's last column."""
        return self.start + self.channels * self.cells ** 2

    def shifted(self, obs: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """The squares of ``obs [..., D]``, each row's map moved by its own (dr, dc) drawn from ``generator``
        (rows' shifts first, then columns'): ``[..., channels C^2]``, 0 where a square came from beyond the map."""
        c, lead = self.cells, obs.shape[:-1]
        image = obs[..., self.start: self.end].reshape(-1, self.channels, c, c)
        n = image.shape[0]
        draw = dict(generator=generator, device=obs.device)
        dr = torch.randint(-self.reach, self.reach + 1, (n, 1), **draw)
        dc = torch.randint(-self.reach, self.reach + 1, (n, 1), **draw)
        span = torch.arange(c, device=obs.device)[None]
        src_r, src_c = span - dr, span - dc               # output square (i, j) reads input (i - dr, j - dc)
        inside = ((src_r >= 0) & (src_r < c))[:, :, None] & ((src_c >= 0) & (src_c < c))[:, None, :]
        rows = torch.arange(n, device=obs.device)[:, None, None, None]
        chans = torch.arange(self.channels, device=obs.device)[None, :, None, None]
        out = image[rows, chans, src_r.clamp(0, c - 1)[:, None, :, None], src_c.clamp(0, c - 1)[:, None, None, :]]
        return (out * inside[:, None].to(out.dtype)).reshape(*lead, -1)

    def apply(self, batch, generator: torch.Generator):
        """Shift the maps of every row of ``batch`` (a :class:`flashnav.learn.replay.Transition` of ``[..., D]``
        tensors) in place, ``obs``'s and ``next_obs``'s with separate draws (in that order). Returns ``batch``."""
        for obs in (batch.obs, batch.next_obs):
            obs[..., self.start: self.end].copy_(self.shifted(obs, generator))
        return batch


def wall_shift_for(preset: RobotPreset, reach: int) -> WallShift | None:
    """The :class:`WallShift` of ``preset``'s wall map, or None for ``reach`` 0. Raises ValueError naming the
    setting where there is no map to shift or the shift would move it off its window."""
    if reach < 0:
        raise ValueError(f"algo.wall_shift must be a number of squares >= 0, got {reach}")
    if reach == 0:
        return None
    cells = preset.observation.wall_map
    if not cells:
        raise ValueError(f"algo.wall_shift={reach} shifts the wall map, but {preset.name} has none "
                         "(set robot.observation.wall_map, or algo.wall_shift=0)")
    if reach >= cells:
        raise ValueError(f"algo.wall_shift={reach} would move {preset.name}'s {cells} x {cells} wall map off its "
                         f"window: at most {cells - 1} squares")
    return WallShift(start=preset.memory_end, cells=cells, reach=int(reach),
                     channels=preset.observation.wall_map_channels)
