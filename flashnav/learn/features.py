"""The networks' input transform: the observation layout (:class:`ObsLayout`) and IPAPRec (paper eq. 2).

LiDAR readings become ``1 / (l - beta)`` with a trainable ``beta = r_in - margin - softplus(rho)`` that
always stays below the inscribed radius ``r_in``; the other features are divided by their known bounds
(the goal angle optionally as its sine and cosine). :mod:`flashnav.learn.networks` builds the actor and
critics on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from flashnav.learn.hparams import WALL_MAP_CONVS
from flashnav.learn.wall_map import WALL_MAP_FEATURES
from flashnav.maps.seen_plan import check_carrot
from flashnav.policy_meta import wall_map_channel_names
from flashnav.sim.tracks import track_scales
from flashnav.sim.trail import trail_bound

#: Floor on ``r_in - beta`` (metres). softplus(rho) underflows to exactly 0 in float32 for rho below
#: about -104, which would put beta on the inscribed radius and the feature at infinity; the margin
#: caps the LiDAR feature at 1 / margin = 100 whatever the optimiser does to rho.
BETA_MARGIN = 0.01
#: beta at initialisation (metres): the plain reciprocal 1 / l.
BETA_INIT = 0.0
#: added to the running variance before the square root of the optional feature normalisation.
NORM_EPS = 1e-8


@dataclass(frozen=True)
class ObsLayout:
    """Where each feature sits in the observation and the bounds used to scale it.

    ``sectors``: number of pooled LiDAR sectors S (columns 0..S-1).
    ``inscribed_radius``: smallest reading a collision-free robot can see, metres.
    ``max_range``: LiDAR maximum range, metres.
    ``goal_scale``: ``(distance, angle)`` divisors, metres and radians (a float = distance, angle pi).
    ``velocity_scales``: one divisor per velocity column (m/s or rad/s), e.g. ``(0.5, pi/4)``.
    ``scan_history``: previous pooled scans k after those columns (k * S more LiDAR columns; 0 = none).
    ``agent_tracks``: tracked agents M after the history (M * len(track_scales) columns; 0 = none).
    ``track_scales``: the divisors of one track's columns (:func:`flashnav.sim.tracks.track_scales`).
    ``pose_trail``: breadcrumbs P after the tracks (2 P columns, x and y; 0 = none).
    ``trail_scale``: the divisor of every breadcrumb column, metres (:func:`flashnav.sim.trail.trail_bound`).
    ``carrot``: the plan's carrot after the trail (2 columns, x and y in metres, each divided by this many metres, its
    bound; 0 = none; needs ``wall_plan``; :func:`flashnav.maps.seen_plan.carrot_points`).
    ``memory_sectors``: the memory scan's columns after the carrot (LiDAR-like, :mod:`flashnav.sim.memory`; 0 = none).
    ``wall_map``: the wall map's squares a side C after the memory scan (2 C^2 columns of 0 / 1, an image read by
    :class:`flashnav.learn.wall_map.WallMapEncoder`, not by IPAPRec; 0 = none).
    ``wall_visited``: the wall map has a third channel, the squares the robot has been in (3 C^2 columns).
    ``wall_plan``: the wall map has a last channel, the squares of the plan (:mod:`flashnav.maps.seen_plan`).
    ``wall_convs``: the wall-map encoder's convolutions, ``(out channels, stride)`` each (the learners set it from
    their ``wall_map_convs``).
    ``goal_sincos``: the networks see the goal angle as (sin, cos) instead of angle / pi (one feature more than
    the observation's columns: :attr:`feature_dim`); the observation itself is unchanged.
    """

    sectors: int
    inscribed_radius: float
    max_range: float
    goal_scale: tuple[float, float]
    velocity_scales: tuple[float, ...]
    scan_history: int = 0
    agent_tracks: int = 0
    track_scales: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    pose_trail: int = 0
    trail_scale: float = 1.0
    carrot: float = 0.0
    memory_sectors: int = 0
    goal_sincos: bool = False
    wall_map: int = 0
    wall_visited: bool = False
    wall_plan: bool = False
    wall_convs: tuple[tuple[int, int], ...] = WALL_MAP_CONVS

    def __post_init__(self) -> None:
        goal = self.goal_scale
        if isinstance(goal, (int, float)):
            object.__setattr__(self, "goal_scale", (float(goal), math.pi))
        object.__setattr__(self, "velocity_scales", tuple(float(v) for v in self.velocity_scales))
        object.__setattr__(self, "track_scales", tuple(float(v) for v in self.track_scales))
        if self.sectors <= 0:
            raise ValueError(f"ObsLayout.sectors must be > 0, got {self.sectors}")
        if not 0 < self.inscribed_radius < self.max_range:
            raise ValueError("ObsLayout needs 0 < inscribed_radius < max_range (metres), got "
                             f"{self.inscribed_radius} and {self.max_range}")
        if BETA_INIT >= self.inscribed_radius - BETA_MARGIN:
            raise ValueError(f"inscribed_radius {self.inscribed_radius} m is too small for beta init {BETA_INIT}")
        if min(self.goal_scale) <= 0 or any(v <= 0 for v in (*self.velocity_scales, *self.track_scales,
                                                              self.trail_scale)):
            raise ValueError("ObsLayout scales must all be > 0")
        if not isinstance(self.scan_history, int) or self.scan_history < 0:
            raise ValueError(f"ObsLayout.scan_history must be an integer >= 0, got {self.scan_history!r}")
        if not isinstance(self.agent_tracks, int) or self.agent_tracks < 0:
            raise ValueError(f"ObsLayout.agent_tracks must be an integer >= 0, got {self.agent_tracks!r}")
        if not isinstance(self.pose_trail, int) or self.pose_trail < 0:
            raise ValueError(f"ObsLayout.pose_trail must be an integer >= 0, got {self.pose_trail!r}")
        if not isinstance(self.memory_sectors, int) or self.memory_sectors < 0:
            raise ValueError(f"ObsLayout.memory_sectors must be an integer >= 0, got {self.memory_sectors!r}")
        if not isinstance(self.wall_map, int) or self.wall_map < 0 or self.wall_map == 1:
            raise ValueError(f"ObsLayout.wall_map must be 0 or an integer >= 2, got {self.wall_map!r}")
        if (self.wall_visited or self.wall_plan) and not self.wall_map:
            raise ValueError("ObsLayout.wall_visited and wall_plan need a wall map (wall_map >= 2)")
        check_carrot("ObsLayout", self.carrot, self.wall_plan, "wall_plan")

    @property
    def base_dim(self) -> int:
        """B = sectors + 2 goal features + velocity features: the paper's observation."""
        return self.sectors + 2 + len(self.velocity_scales)

    @property
    def history_end(self) -> int:
        """B + scan_history * sectors: the end of the LiDAR history, where the agent tracks start."""
        return self.base_dim + self.scan_history * self.sectors

    @property
    def trail_end(self) -> int:
        """The end of the agent tracks, the pose trail and the carrot (the scaled columns), where the memory scan
        starts: :attr:`flashnav.config.RobotPreset.carrot_end`, not its ``trail_end`` (which is before the carrot)."""
        return (self.history_end + self.agent_tracks * len(self.track_scales) + 2 * self.pose_trail
                + (2 if self.carrot else 0))

    @property
    def memory_end(self) -> int:
        """The end of the memory scan: the columns IPAPRec reads end here, where the wall map starts."""
        return self.trail_end + self.memory_sectors

    @property
    def obs_dim(self) -> int:
        """D = B + scan_history * sectors + agent_tracks * len(track_scales) + 2 * pose_trail (+ 2 with a carrot)
        + memory_sectors + wall_channels * wall_map^2."""
        return self.memory_end + self.wall_channels * self.wall_map ** 2

    @property
    def wall_channels(self) -> int:
        """The wall map's channels: 0 without one, else 2 (walls, goal), one more with each of ``wall_visited`` and
        ``wall_plan``."""
        return len(wall_map_channel_names(self.wall_map, self.wall_visited, self.wall_plan))

    @property
    def vector_feature_dim(self) -> int:
        """IPAPRec's output width: the columns before the wall map, + 1 with ``goal_sincos`` (the angle's sine and
        cosine)."""
        return self.memory_end + int(self.goal_sincos)

    @property
    def feature_dim(self) -> int:
        """The networks' MLP input width: IPAPRec's features, then the wall-map encoder's
        (:data:`flashnav.learn.wall_map.WALL_MAP_FEATURES`) with a wall map."""
        return self.vector_feature_dim + (WALL_MAP_FEATURES if self.wall_map else 0)

    def feature_scales(self) -> torch.Tensor:
        """Divisors for the scaled columns: goal distance, angle, velocities, then the agent tracks', the
        pose trail's and the carrot's."""
        return torch.tensor((*self.goal_scale, *self.velocity_scales, *self.track_scales * self.agent_tracks,
                             *(self.trail_scale,) * (2 * self.pose_trail), *(self.carrot,) * (2 if self.carrot else 0)),
                            dtype=torch.float32)

    @classmethod
    def from_robot(cls, preset, goal_distance_max: float) -> "ObsLayout":
        """Layout for a :class:`flashnav.config.RobotPreset` on a map whose diagonal is
        ``goal_distance_max`` metres (``OccupancyMap.diagonal_m``, the environment's observation bound;
        ``RunSpec.goal_distance_max`` in training).

        The goal distance is scaled by that bound; velocities by the action bounds (the velocity state
        follows the commanded velocity); ``vy`` (always 0 on Go2) reuses the v bound.
        """
        v_max = max(abs(b) for b in preset.motion.v_bounds)
        w_max = max(abs(b) for b in preset.motion.w_bounds)
        velocity = (v_max, w_max) if preset.motion.velocity_state_dims == 2 else (v_max, v_max, w_max)
        return cls(sectors=preset.lidar.sectors, inscribed_radius=preset.footprint.inscribed_radius,
                   max_range=preset.lidar.max_range, goal_scale=(float(goal_distance_max), math.pi),
                   velocity_scales=velocity, scan_history=preset.observation.scan_history,
                   agent_tracks=preset.observation.agent_tracks, track_scales=track_scales(preset),
                   pose_trail=preset.observation.pose_trail, trail_scale=trail_bound(preset),
                   carrot=preset.observation.wall_map_carrot,
                   memory_sectors=preset.lidar.sectors if preset.observation.memory_frames else 0,
                   wall_map=preset.observation.wall_map, wall_visited=preset.observation.wall_map_visited,
                   wall_plan=preset.observation.wall_map_plan)


class IPAPRec(nn.Module):
    """``obs [..., D]`` -> features ``[..., D]``: LiDAR ``1 / (l - beta)``, other columns / bounds.

    ``copies=0``: one transform (scalar rho), any leading shape. ``copies=C``: C independent
    transforms (rho ``[C]``) for a batched ensemble; input ``[B, D]``, output ``[C, B, D]``.
    Readings are clamped to ``[inscribed_radius, max_range]`` first: a post-collision final
    observation can read inside the footprint, and must not reach the pole of the reciprocal.
    ``normalize``: the features are then centred and scaled by running statistics (buffers, updated
    only by :meth:`update_stats`), like the reference code's empirical observation normaliser.
    History frames (columns from ``layout.base_dim`` on) get the same ``1 / (l - beta)`` with the same
    beta: one reading means the same distance whenever it was taken, and sharing keeps one parameter
    per transform; agent tracks (the last columns) are divided by their bounds like the goal and
    velocity columns, and so are the pose trail's breadcrumbs and the carrot after them; the memory scan (next) is
    LiDAR-like:
    ``1 / (l - beta)`` with the same beta; a wall map's columns (after it) are not read here
    (:class:`flashnav.learn.wall_map.WallMapEncoder` reads them). The output keeps the input's
    column order; with ``layout.goal_sincos`` the goal angle's column holds sin(angle) and cos(angle) follows it
    (``layout.feature_dim`` columns: sin and cos are continuous where the angle jumps from pi to -pi, the goal
    straight behind; docs/learners.md S18).
    """

    def __init__(self, layout: ObsLayout, copies: int = 0, normalize: bool = False):
        super().__init__()
        self.sectors = layout.sectors
        self.r_in = float(layout.inscribed_radius)
        self.max_range = float(layout.max_range)
        self.copies = copies
        self.base_dim, self.history_end, self.trail_end = layout.base_dim, layout.history_end, layout.trail_end
        # Python bools: tracing records one path
        self.history = layout.history_end > layout.base_dim
        self.tracks = layout.trail_end > layout.history_end  # agent tracks, the pose trail and / or the carrot
        self.memory = layout.memory_end > layout.trail_end
        self.vector_end = layout.memory_end  # the wall map's columns after it are the encoder's, not IPAPRec's
        self.wall_map = layout.wall_map > 0
        self.scaled_base = layout.base_dim - layout.sectors  # goal and velocity columns
        self.goal_sincos = bool(layout.goal_sincos)
        # softplus(rho0) = r_in - margin - BETA_INIT puts beta at BETA_INIT
        gap = self.r_in - BETA_MARGIN - BETA_INIT
        rho0 = gap + math.log(-math.expm1(-gap))
        self.rho = nn.Parameter(torch.full((copies,) if copies else (), rho0))
        self.register_buffer("inv_scale", 1.0 / layout.feature_scales())
        self.normalize = normalize
        if normalize:  # running statistics of the transformed features (identity until the first update)
            shape = (copies, 1, layout.vector_feature_dim) if copies else (layout.vector_feature_dim,)
            self.register_buffer("feat_mean", torch.zeros(shape))
            self.register_buffer("feat_var", torch.ones(shape))
            self.register_buffer("feat_count", torch.zeros((), dtype=torch.float64))

    def beta(self, detach: bool = False) -> torch.Tensor:
        """Pole position, metres: ``[]`` or ``[C]``, always <= r_in - margin."""
        rho = self.rho.detach() if detach else self.rho
        return self.r_in - BETA_MARGIN - F.softplus(rho)

    def forward(self, obs: torch.Tensor, detach_rho: bool = False) -> torch.Tensor:
        x = self.features(obs, detach_rho)
        if self.normalize:
            x = (x - self.feat_mean) * torch.rsqrt(self.feat_var + NORM_EPS)
        return x

    @torch.no_grad()
    def update_stats(self, obs: torch.Tensor) -> None:
        """Merge the batch ``obs [B, D]``'s transformed features into the running mean and variance
        (Chan et al.'s parallel update; per copy for a batched transform). Only with ``normalize``."""
        x = self.features(obs, detach_rho=True)
        n = x.shape[-2]
        keep = self.copies > 0
        mean, var = x.mean(-2, keepdim=keep), x.var(-2, unbiased=False, keepdim=keep)
        count = self.feat_count
        total = count + n
        delta = mean - self.feat_mean
        m2 = self.feat_var * count + var * n + delta.square() * (count * n / total)
        self.feat_mean.add_(delta * (n / total))
        self.feat_var.copy_(m2 / total)
        self.feat_count.copy_(total)

    def features(self, obs: torch.Tensor, detach_rho: bool = False) -> torch.Tensor:
        """The transform before any normalisation: LiDAR ``1 / (l - beta)``, the rest / bounds (the goal
        angle as its sine and cosine with ``goal_sincos``)."""
        x = self._features(obs, detach_rho)
        if not self.goal_sincos:
            return x
        angle = obs[..., self.sectors + 1: self.sectors + 2]
        if self.copies > 0:
            angle = angle.unsqueeze(0).expand(self.copies, -1, -1)
        return torch.cat([x[..., : self.sectors + 1], torch.sin(angle), torch.cos(angle),
                          x[..., self.sectors + 2:]], dim=-1)

    def _features(self, obs: torch.Tensor, detach_rho: bool) -> torch.Tensor:
        if self.wall_map:
            obs = obs[..., : self.vector_end]
        beta = self.beta(detach_rho)
        if self.copies > 0:
            beta = beta.view(-1, 1, 1)
        if not self.history and not self.tracks and not self.memory:
            return torch.cat([self._reciprocal(obs[..., : self.sectors], beta),
                              self._scaled(obs[..., self.sectors:])], dim=-1)
        parts = [self._reciprocal(obs[..., : self.sectors], beta)]
        parts.append(self._scaled(obs[..., self.sectors: self.base_dim], 0, self.scaled_base))
        if self.history:
            parts.append(self._reciprocal(obs[..., self.base_dim: self.history_end], beta))
        if self.tracks:
            parts.append(self._scaled(obs[..., self.history_end: self.trail_end], self.scaled_base, None))
        if self.memory:
            parts.append(self._reciprocal(obs[..., self.trail_end:], beta))
        return torch.cat(parts, dim=-1)

    def _reciprocal(self, lidar: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
        """LiDAR columns ``[B, L]`` -> ``1 / (clamp(l) - beta)``, ``[B, L]`` or ``[C, B, L]``."""
        lidar = lidar.clamp(min=self.r_in, max=self.max_range)
        return torch.reciprocal((lidar.unsqueeze(0) if self.copies > 0 else lidar) - beta)

    def _scaled(self, rest: torch.Tensor, start: int = 0, stop: int | None = None) -> torch.Tensor:
        """Goal and velocity columns (and agent tracks) divided by their bounds ``inv_scale[start:stop]``,
        expanded over copies."""
        rest = rest * (self.inv_scale if start == 0 and stop is None else self.inv_scale[start:stop])
        return rest.unsqueeze(0).expand(self.copies, -1, -1) if self.copies > 0 else rest
