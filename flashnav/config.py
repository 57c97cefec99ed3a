"""Pydantic models for everything FlashNav is configured with (YAML in/out: :mod:`flashnav.yamlio`).

The paper's numbers do not live here: they live in ``flashnav/presets/*.yaml`` (the appendix as data).
These models only say what a valid value is, so that a negative radius or a field of view of 0 fails
with a message that names the field (their strict base and the reading of a validation error:
:mod:`flashnav.config_base`).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, model_validator

from flashnav.config_base import Strict
from flashnav.names import AGENT_BEHAVIOURS, GOAL_SAMPLINGS, PROGRESS_METRICS
from flashnav.policy_meta import wall_map_channel_names


class Footprint(Strict):
    """The robot's planar footprint, centred on the sensor."""

    kind: Literal["disc", "rectangle"]
    radius: float | None = Field(None, gt=0, description="disc radius, metres")
    length: float | None = Field(None, gt=0, description="rectangle extent along the heading, metres")
    width: float | None = Field(None, gt=0, description="rectangle extent across the heading, metres")

    @model_validator(mode="after")
    def _complete(self) -> "Footprint":
        if self.kind == "disc" and self.radius is None:
            raise ValueError("footprint.kind 'disc' needs footprint.radius (metres, > 0)")
        if self.kind == "rectangle" and (self.length is None or self.width is None):
            raise ValueError("footprint.kind 'rectangle' needs footprint.length and footprint.width (metres, > 0)")
        return self

    @property
    def inscribed_radius(self) -> float:
        """Radius of the largest disc inside the footprint (metres)."""
        return self.radius if self.kind == "disc" else 0.5 * min(self.length, self.width)

    @property
    def circumscribed_radius(self) -> float:
        """Radius of the smallest centred disc containing the footprint (metres)."""
        return self.radius if self.kind == "disc" else 0.5 * math.hypot(self.length, self.width)


#: the longest actuation latency a preset may ask for (motion.command_delay, control steps)
MAX_COMMAND_DELAY = 20


class Motion(Strict):
    """Action interface and kinematics. Actions in [-1, 1] map linearly onto [low, high]."""

    model: Literal["diff_drive"] = "diff_drive"  # the paper's model for both robots
    v_bounds: tuple[float, float] = Field(description="linear velocity command bounds (min, max), m/s")
    w_bounds: tuple[float, float] = Field(description="angular velocity command bounds (min, max), rad/s")
    max_linear_velocity: float = Field(gt=0, description="platform limit, m/s (commands are clamped to it)")
    max_angular_velocity: float = Field(gt=0, description="platform limit, rad/s (commands are clamped to it)")
    velocity_state_dims: Literal[2, 3] = Field(2, description="2: (v, w) in the observation; 3: (vx, vy, w)")
    command_delay: int = Field(0, ge=0, le=MAX_COMMAND_DELAY, description="actuation latency: control steps between "
                               "a command and its execution (the first ones of an episode execute (0, 0)); 0 = the "
                               "paper's, a command moves the robot in its own step")
    max_linear_accel: float | None = Field(None, gt=0, description="m/s^2: the executed linear velocity moves toward "
                                           "the command by at most this much per second; None = at once (the paper's)")
    max_angular_accel: float | None = Field(None, gt=0, description="rad/s^2: the same for the turn rate; None = at "
                                            "once (the paper's)")

    @property
    def instant(self) -> bool:
        """True when a command is executed at once and whole (the paper's motion, every preset's default)."""
        return self.command_delay == 0 and self.max_linear_accel is None and self.max_angular_accel is None

    @model_validator(mode="after")
    def _ordered(self) -> "Motion":
        for name in ("v_bounds", "w_bounds"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"motion.{name} must be (min, max) with min < max, got ({lo}, {hi})")
        return self


class Lidar(Strict):
    """2D range sensor at the robot centre; beams pooled into sectors by the minimum."""

    beams: int = Field(gt=0, description="raw beams per scan")
    sectors: int = Field(gt=0, description="pooled sectors in the observation")
    fov_deg: float = Field(gt=0, le=360, description="field of view, degrees, centred on the heading")
    max_range: float = Field(gt=0, description="metres; readings are clipped to it")
    march_step: float = Field(gt=0, description="metres; step of the paper-literal 'march' raycaster")
    noise_std: float = Field(0.0, ge=0, description="Gaussian range noise, metres (0 = off)")
    noise_std_max: float | None = Field(None, ge=0, description="with it, each episode draws its range noise "
                                        "uniformly from [noise_std, noise_std_max] metres (for a policy that must "
                                        "work on sensors of unknown noise); None = noise_std in every episode")
    dropout: float = Field(0.0, ge=0, lt=1, description="probability a beam reads max_range (0 = off)")

    @model_validator(mode="after")
    def _pooling(self) -> "Lidar":
        if self.beams % self.sectors:
            raise ValueError(f"lidar.beams ({self.beams}) must be a multiple of lidar.sectors ({self.sectors})")
        if self.noise_std_max is not None and not self.noise_std_max > self.noise_std:
            raise ValueError(f"lidar.noise_std_max ({self.noise_std_max}) must be above lidar.noise_std "
                             f"({self.noise_std}), the range each episode's noise is drawn from")
        return self

    @property
    def beams_per_sector(self) -> int:
        return self.beams // self.sectors


class Episode(Strict):
    horizon: int = Field(gt=0, description="steps before truncation")
    dt: float = Field(gt=0, description="seconds per step")
    goal_threshold: float = Field(gt=0, description="goal reached when distance < this, metres")
    min_goal_distance: float = Field(ge=0, description="start-goal distance (see goal_sampling), lower bound, metres")
    max_goal_distance: float = Field(gt=0, description="start-goal distance (see goal_sampling), upper bound, metres")
    start_clearance: float = Field(ge=0, description="extra free margin around the footprint at start/goal, metres")
    goal_sampling: Literal[GOAL_SAMPLINGS] = Field(  # type: ignore[valid-type]
        "euclidean", description="goal distance band measured as the straight line (euclidean, the paper task) "
        "or as the path length through the free space (geodesic, capped by what the horizon allows)")
    retry_failed: float = Field(
        0.0, ge=0, le=1, description="chance that a slot whose episode ended without reaching the goal (a collision "
        "or a timeout) starts its next episode from the same start pose and goal, on the same map, instead of a fresh "
        "draw (a training curriculum that revisits the starts the policy fails; 0 = every episode drawn afresh, the "
        "paper). Evaluation is unchanged: it counts each slot's first episode")
    hard_share: float = Field(
        0.0, ge=0, le=1, description="training only: the share of new training episodes drawn as the longest "
        "detour (path length / straight line) of hard_candidates draws of the task's sampler (either goal_sampling, "
        "on one map or many: each slot's candidates on its own map), a curriculum that shows the policy the rare "
        "long routes round walls more often; 0 = the task's draws. Evaluations play the task's episodes")
    hard_candidates: int = Field(8, ge=2, le=64, description="draws per hard episode (episode.hard_share)")

    @model_validator(mode="after")
    def _band(self) -> "Episode":
        if not self.min_goal_distance < self.max_goal_distance:
            raise ValueError("episode.min_goal_distance must be < episode.max_goal_distance")
        return self


class Reward(Strict):
    goal: float = Field(description="terminal reward on reaching the goal")
    collision: float = Field(description="terminal reward on collision")
    progress: float = Field(description="coefficient c1 of the shaping term c1 * (d_old - d_new)")
    agent_proximity: float = Field(0.0, ge=0, description="with agents: penalty per step and metre by which the "
                                   "robot is nearer an agent than agent_proximity_distance (0 = off, the paper's "
                                   "reward)")
    agent_proximity_distance: float = Field(0.5, gt=0, description="metres of gap (footprint to agent disc) "
                                            "below which agent_proximity applies")
    progress_metric: Literal[PROGRESS_METRICS] = Field(  # type: ignore[valid-type]
        "euclidean", description="the distance d of the shaping term: the straight line (euclidean, the "
        "paper's) or the path length through the free space (geodesic: training only; on many maps it needs "
        "episode.goal_sampling=geodesic; flashnav.sim.goal_fields)")
    progress_discount: float = Field(1.0, ge=0, le=1, description="c in the shaping term progress * (d_old - "
                                     "c * d_new): 1 = the paper's; the learner's discount gamma makes it "
                                     "potential-based (Ng et al. 1999: the shaping changes no policy's ranking, "
                                     "so it cannot favour a longer route that gains ground sooner)")
    step_cost: float = Field(0.0, ge=0, le=1, description="paid (subtracted) on every step that ends in neither "
                             "goal nor collision: a price on time, against a robot that parks short of its goal "
                             "(0 = the paper's reward; training only, an evaluation plays without it)")


class Agents(Strict):
    """Moving disc obstacles (pedestrians) in every environment slot; ``count`` 0 is the static
    simulator, unchanged. See :mod:`flashnav.sim.agents` for the behaviours."""

    count: int = Field(0, ge=0, le=64, description="agents per environment slot (K); 0 = none")
    radius: tuple[float, float] = Field((0.2, 0.3), description="disc radius range (min, max), metres; "
                                        "each agent draws its own uniformly")
    speed: tuple[float, float] = Field((0.2, 0.5), description="walking speed range (min, max), m/s")
    mix: dict[str, float] = Field(default_factory=lambda: {"waypoints": 0.5, "bounce": 0.5},
                                  description="relative weight of each behaviour (waypoints, bounce, crossing)")
    reactive: float = Field(0.0, ge=0, le=1, description="probability that an agent is reactive: it slows "
                            "down and stops for a robot ahead of it")
    reactive_distance: float = Field(1.0, gt=0, description="metres of gap at which a reactive agent starts to slow")
    spawn_clearance: float = Field(0.5, ge=0, description="metres of free gap between a new agent and the robot's "
                                   "footprint at its start and at its goal")
    crossing_offset: tuple[float, float] = Field((1.0, 2.0), description="metres from the route at which a "
                                                 "crossing agent appears (min, max)")

    @model_validator(mode="after")
    def _ranges(self) -> "Agents":
        for name, low in (("radius", 0.0), ("speed", 0.0), ("crossing_offset", 0.0)):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and low < lo <= hi):
                raise ValueError(f"agents.{name} must be (min, max) with 0 < min <= max, got ({lo}, {hi})")
        for key, weight in self.mix.items():
            if key not in AGENT_BEHAVIOURS:
                raise ValueError(f"agents.mix: unknown behaviour {key!r}; allowed: {', '.join(AGENT_BEHAVIOURS)}")
            if not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"agents.mix.{key} must be a finite weight >= 0, got {weight}")
        if self.count and sum(self.mix.values()) <= 0:
            raise ValueError(f"agents.mix needs a positive weight for some behaviour, got {self.mix}")
        return self


#: Largest ``observation.scan_history``: each frame adds ``lidar.sectors`` columns to every network's input.
MAX_SCAN_HISTORY = 16
#: Largest ``observation.agent_tracks``: each track adds TRACK_FEATURES (6) columns.
MAX_AGENT_TRACKS = 16
#: Columns of one agent track (:mod:`flashnav.sim.tracks`).
TRACK_FEATURES = ("present", "x", "y", "vx", "vy", "radius")
#: Largest ``observation.pose_trail``: each breadcrumb adds 2 columns (x, y in the robot frame).
MAX_POSE_TRAIL = 32
#: Largest ``observation.memory_frames``: the memory scan's cost per step grows with the frames kept.
MAX_MEMORY_FRAMES = 64
#: Largest ``observation.wall_map`` (squares a side): the map adds 2 (one more with each of ``wall_map_visited`` and
#: ``wall_map_plan``) x wall_map^2 columns.
MAX_WALL_MAP = 48
#: Largest ``observation.wall_map_carrot``, metres: within the plan's margin (seen_plan.PLAN_MARGIN_M).
MAX_WALL_MAP_CARROT = 3.0


class Observation(Strict):
    """What the policy sees besides the paper's layout; the default is the paper's observation."""

    scan_history: int = Field(0, ge=0, le=MAX_SCAN_HISTORY, description="previous pooled scans appended "
                              "after the paper's observation, newest first (0 = the paper's observation); "
                              "one frame per control step, a new episode starts with its first scan repeated")
    agent_tracks: int = Field(0, ge=0, le=MAX_AGENT_TRACKS, description="the M nearest agents the robot can see, "
                              "as a people tracker on the robot reports them (present, x, y, vx, vy, radius in "
                              "the robot frame; flashnav.sim.tracks), appended after the scan history; 0 = none, "
                              "the paper's "
                              "observation")
    pose_trail: int = Field(0, ge=0, le=MAX_POSE_TRAIL, description="the robot's own earlier positions (x, y in "
                            "the robot frame of the current pose; flashnav.sim.trail), one every trail_every "
                            "control steps, newest first, appended after the agent tracks: a memory of where it "
                            "has been that odometry gives any robot; 0 = none, the paper's observation")
    trail_every: int = Field(10, ge=1, le=1000, description="control steps between two breadcrumbs of the pose "
                             "trail (the trail covers pose_trail * trail_every steps)")
    memory_frames: int = Field(0, ge=0, le=MAX_MEMORY_FRAMES, description="the memory scan (flashnav.sim.memory): "
                               "a 360-deg pooled scan of lidar.sectors columns of the wall points the LiDAR hit in "
                               "the last memory_frames stored scans, appended before the wall map: a memory of "
                               "walls; 0 = none, the paper's observation")
    memory_every: int = Field(10, ge=1, le=1000, description="control steps between two stored scans of the memory "
                              "scan (it remembers memory_frames * memory_every steps)")
    wall_map: int = Field(0, ge=0, le=MAX_WALL_MAP, description="the wall map (flashnav.sim.wall_grid.WallGrid): an "
                          "egocentric image of wall_map x wall_map squares of wall_map_cell metres around the robot, "
                          "turned with it, 1 where a wall its LiDAR hit this episode lies and, in a second channel, "
                          "1 in the goal's square; 2 x wall_map^2 columns appended after everything else; 0 = none, "
                          "the paper's observation")
    wall_map_cell: float = Field(0.5, gt=0, le=2.0, description="the wall map's square, metres")
    wall_map_grid: float = Field(0.25, gt=0, le=1.0, description="the cell, metres, of the per-slot grid in which "
                                 "the wall map remembers hits (the map is drawn at the marked cells' centres)")
    wall_map_visited: bool = Field(False, description="a third channel of the wall map: 1 where the robot's centre "
                                   "has been this episode (the grid cells it passed, kept like the hits; on a robot "
                                   "from odometry), so that a policy can tell a dead end it has seen from one it has "
                                   "not; wall_map^2 more columns; needs wall_map > 0")
    wall_map_plan: bool = Field(False, description="a last channel of the wall map: 1 in the squares of the shortest "
                                "way from the robot to its goal over the grid cells its LiDAR has not marked as walls "
                                "(unknown = free; flashnav.maps.seen_plan), recomputed every step from the wall "
                                "memory alone, no map; wall_map^2 more columns; needs wall_map > 0")
    wall_map_plan_penalty: float = Field(0.0, ge=0, le=100.0, description="with wall_map_plan: the plan is the "
                                         "cheapest way, not the shortest, where a move into a cell beside a marked "
                                         "cell costs its length times 1 + this (a costmap's inflation, one cell "
                                         "wide), so that it keeps off the walls where there is room; 0 = the "
                                         "shortest way")
    wall_map_carrot: float = Field(0.0, ge=0, le=MAX_WALL_MAP_CARROT, description="with wall_map_plan: two more "
                                   "columns after the pose trail, the point this many metres of path along the plan "
                                   "from the robot's grid cell (the goal where the plan is shorter or there is none), "
                                   "x and y in the robot frame, brought within this many metres of the robot "
                                   "(flashnav.maps.seen_plan.carrot_points): the plan's direction as numbers; 0 = "
                                   "none")

    @model_validator(mode="after")
    def _one_square_is_no_image(self):
        if self.wall_map == 1:
            raise ValueError("observation.wall_map must be 0 (none) or at least 2 squares a side, got 1")
        for key in ("wall_map_visited", "wall_map_plan"):
            if getattr(self, key) and not self.wall_map:
                raise ValueError(f"observation.{key}=true adds a channel to the wall map, but "
                                 "observation.wall_map is 0 (none): set observation.wall_map to at least 2")
        if self.wall_map_carrot and not self.wall_map_plan:
            raise ValueError(f"observation.wall_map_carrot={self.wall_map_carrot:g} is a point along the plan, but "
                             "observation.wall_map_plan is false: set it true, or the carrot 0")
        if self.wall_map_plan_penalty and not self.wall_map_plan:
            raise ValueError(f"observation.wall_map_plan_penalty={self.wall_map_plan_penalty:g} prices the plan "
                             "channel's cells, but observation.wall_map_plan is false: set it true, or the penalty 0")
        return self

    @property
    def wall_map_channels(self) -> int:
        """The wall map's channels: 0 without one, else walls and goal, then the visited squares with
        ``wall_map_visited``, then the plan's with ``wall_map_plan``."""
        return len(wall_map_channel_names(self.wall_map, self.wall_map_visited, self.wall_map_plan))


class RobotPreset(Strict):
    """One embodiment: everything the simulator needs (paper appendix B)."""

    name: str
    footprint: Footprint
    motion: Motion
    lidar: Lidar
    episode: Episode
    reward: Reward
    map: str = Field(description="bundled map name (flashnav/maps/data/NAME.yaml) or a ROS map YAML path (a relative "
                                 "one from a preset file is relative to that file's folder)")
    map_size: tuple[float, float] = Field(description="the paper's map extent (x, y), metres, for reference")
    agents: Agents = Field(default_factory=Agents, description="moving obstacles (none by default)")
    observation: Observation = Field(default_factory=Observation, description="opt-in observation extras")

    @property
    def base_obs_dim(self) -> int:
        """The paper's observation: sectors + goal (distance, angle) + velocity state."""
        return self.lidar.sectors + 2 + self.motion.velocity_state_dims

    @property
    def history_end(self) -> int:
        """End column of the scan history (= base_obs_dim without one): where the agent tracks start."""
        return self.base_obs_dim + self.observation.scan_history * self.lidar.sectors

    @property
    def tracks_end(self) -> int:
        """End column of the agent tracks: where the pose trail starts."""
        return self.history_end + self.observation.agent_tracks * len(TRACK_FEATURES)

    @property
    def trail_end(self) -> int:
        """End column of the pose trail: where the carrot starts."""
        return self.tracks_end + 2 * self.observation.pose_trail

    @property
    def carrot_end(self) -> int:
        """End column of the carrot (``observation.wall_map_carrot``: 2 columns, else none): where the memory scan
        starts."""
        return self.trail_end + (2 if self.observation.wall_map_carrot else 0)

    @property
    def memory_end(self) -> int:
        """End column of the memory scan: where the wall map starts."""
        return self.carrot_end + (self.lidar.sectors if self.observation.memory_frames else 0)

    @property
    def obs_dim(self) -> int:
        """The paper's observation, then ``observation.scan_history`` previous frames of ``sectors`` each,
        then ``observation.agent_tracks`` tracks of ``len(TRACK_FEATURES)`` columns each, then
        ``observation.pose_trail`` breadcrumbs of 2 columns each, then the carrot's 2 with
        ``observation.wall_map_carrot`` > 0, then the memory scan's ``sectors`` columns
        with ``observation.memory_frames`` > 0, then the wall map's ``observation.wall_map_channels`` x
        ``observation.wall_map``^2 columns (the walls' squares row by row, then the goal's, then the visited ones)."""
        return self.memory_end + self.observation.wall_map_channels * self.observation.wall_map ** 2
