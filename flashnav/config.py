"""Pydantic models for everything FlashNav is configured with, and YAML in/out.

The paper's numbers do not live here: they live in ``flashnav/presets/*.yaml`` (the appendix as data).
These models only say what a valid value is, so that a negative radius or a field of view of 0 fails
with a message that names the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator


class Strict(BaseModel):
    """Base: unknown keys are errors (a misspelt key must not be silently ignored)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


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


class Motion(Strict):
    """Action interface and kinematics. Actions in [-1, 1] map linearly onto [low, high]."""

    model: Literal["diff_drive"] = "diff_drive"  # the paper's model for both robots
    v_bounds: tuple[float, float] = Field(description="linear velocity command bounds (min, max), m/s")
    w_bounds: tuple[float, float] = Field(description="angular velocity command bounds (min, max), rad/s")
    max_linear_velocity: float = Field(gt=0, description="platform limit, m/s (commands are clamped to it)")
    max_angular_velocity: float = Field(gt=0, description="platform limit, rad/s (commands are clamped to it)")
    velocity_state_dims: Literal[2, 3] = Field(2, description="2: (v, w) in the observation; 3: (vx, vy, w)")

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
    dropout: float = Field(0.0, ge=0, lt=1, description="probability a beam reads max_range (0 = off)")

    @model_validator(mode="after")
    def _pooling(self) -> "Lidar":
        if self.beams % self.sectors:
            raise ValueError(f"lidar.beams ({self.beams}) must be a multiple of lidar.sectors ({self.sectors})")
        return self

    @property
    def beams_per_sector(self) -> int:
        return self.beams // self.sectors


class Episode(Strict):
    horizon: int = Field(gt=0, description="steps before truncation")
    dt: float = Field(gt=0, description="seconds per step")
    goal_threshold: float = Field(gt=0, description="goal reached when distance < this, metres")
    min_goal_distance: float = Field(ge=0, description="start-goal straight-line distance, lower bound, metres")
    max_goal_distance: float = Field(gt=0, description="start-goal straight-line distance, upper bound, metres")
    start_clearance: float = Field(ge=0, description="extra free margin around the footprint at start/goal, metres")

    @model_validator(mode="after")
    def _band(self) -> "Episode":
        if not self.min_goal_distance < self.max_goal_distance:
            raise ValueError("episode.min_goal_distance must be < episode.max_goal_distance")
        return self


class Reward(Strict):
    goal: float = Field(description="terminal reward on reaching the goal")
    collision: float = Field(description="terminal reward on collision")
    progress: float = Field(description="coefficient c1 of the shaping term c1 * (d_old - d_new)")


class RobotPreset(Strict):
    """One embodiment: everything the simulator needs (paper appendix B)."""

    name: str
    footprint: Footprint
    motion: Motion
    lidar: Lidar
    episode: Episode
    reward: Reward
    map: str = Field(description="bundled map name (flashnav/maps/data/NAME.yaml) or a ROS map YAML path")
    map_size: tuple[float, float] = Field(description="the paper's map extent (x, y), metres, for reference")

    @property
    def obs_dim(self) -> int:
        return self.lidar.sectors + 2 + self.motion.velocity_state_dims


class DuplicateKeyError(yaml.YAMLError):
    """A mapping names the same key twice (plain YAML keeps the last one silently)."""


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate mapping keys: in a sweep or a config a repeated key
    is almost always an edit gone wrong, and the silent last-one-wins would run something else."""

    def construct_mapping(self, node, deep=False):
        first: dict[Any, yaml.Node] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<: *base' overrides by design
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                seen = first.setdefault(key, key_node)
            except TypeError:  # an unhashable key: the base class raises its own clear error
                continue
            if seen is not key_node:
                raise DuplicateKeyError(f"duplicate key {key!r} at line {key_node.start_mark.line + 1} "
                                        f"(first at line {seen.start_mark.line + 1})")
        return super().construct_mapping(node, deep)


def yaml_error_line(exc: yaml.YAMLError) -> str:
    """A YAML error as one line (PyYAML's own text spans several, with a caret drawing)."""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        return f"{exc.problem}{where}"
    return " ".join(str(exc).split())


def parse_yaml(text: str, source: str = "<string>") -> Any:
    """YAML text -> Python data with :class:`UniqueKeyLoader`; a ValueError names ``source``."""
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: not valid YAML: {yaml_error_line(exc)}") from None


def load_yaml(path: str | Path) -> Any:
    """Load YAML safely (a SafeLoader that refuses duplicate keys); a clear error names the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, not a YAML file") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    return parse_yaml(text, str(path))


def dump_yaml(data: Any, path: str | Path) -> None:
    with open(path, "w", encoding="utf-8") as f:
        yaml.safe_dump(data, f, sort_keys=False)
