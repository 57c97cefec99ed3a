"""The paper's appendix as data: robot presets (appendix B) and algorithm presets (appendix A).

``load_robot("turtlebot2")`` returns a validated :class:`flashnav.config.RobotPreset`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from flashnav.config import RobotPreset, load_yaml

ROBOTS = ("turtlebot2", "go2")


def preset_path(name: str) -> Path:
    return Path(str(resources.files(__package__) / f"{name}.yaml"))


def load_robot(robot: "str | RobotPreset", **overrides) -> RobotPreset:
    """A robot preset by name (``turtlebot2``, ``go2``), a YAML path, or an existing preset."""
    if isinstance(robot, RobotPreset):
        data = robot.model_dump()
    elif robot in ROBOTS:
        data = load_yaml(preset_path(robot))
    elif str(robot).endswith((".yaml", ".yml")):
        data = load_yaml(robot)
    else:
        raise ValueError(f"unknown robot {robot!r}: use one of {', '.join(ROBOTS)} or a preset YAML path")
    for key, value in overrides.items():
        _set_path(data, key, value)
    return RobotPreset.model_validate(data)


def _set_path(data: dict, dotted: str, value) -> None:
    *parents, leaf = dotted.split(".")
    node = data
    for part in parents:
        if not isinstance(node.get(part), dict):
            raise KeyError(f"no section {part!r} in override {dotted!r}")
        node = node[part]
    node[leaf] = value
