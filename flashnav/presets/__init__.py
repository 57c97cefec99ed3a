"""The paper's appendix as data: robot presets (appendix B) and algorithm presets (appendix A).

``load_robot("turtlebot2")`` returns a validated :class:`flashnav.config.RobotPreset`: the robot's
own file (its platform table) laid over ``simulator.yaml`` (the shared simulator table). The learners'
hyperparameters are read by :func:`flashnav.learn.hparams.load_hparams` from ``pipeline.yaml`` and
``<algorithm>.yaml`` in the same way (the order is written at the top of ``pipeline.yaml``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from flashnav.config import RobotPreset
from flashnav.config_base import error_lines
from flashnav.names import DEFAULT_ROBOT, RECIPES, ROBOTS, check_robot
from flashnav.yamlio import deep_merge, load_yaml, set_dotted


def preset_path(name: str) -> Path:
    """``flashnav/presets/<name>.yaml``."""
    return Path(str(resources.files(__package__) / f"{name}.yaml"))


def load_preset_file(name: str) -> dict[str, Any]:
    """A bundled preset file as a mapping (an empty file is an empty mapping)."""
    data = load_yaml(preset_path(name)) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{preset_path(name)}: a preset file must be a mapping")
    return data


def load_robot(robot: "str | RobotPreset", **overrides: Any) -> RobotPreset:
    """A robot preset by name (``turtlebot2``, ``go2``), a YAML path, or an existing preset.

    ``overrides``: dotted keys into the preset (``load_robot("go2", **{"lidar.noise_std": 0.01})``);
    an unknown key is a ValueError that names it and suggests the closest.
    """
    if isinstance(robot, RobotPreset):
        data, source = robot.model_dump(), robot.name
    elif check_robot(robot) in ROBOTS:  # check_robot: a bundled name or a preset YAML path, else raises
        data, source = deep_merge(load_preset_file("simulator"), load_preset_file(robot)), robot
    else:
        own = load_yaml(robot) or {}
        if not isinstance(own, dict):
            raise ValueError(f"{robot}: a robot preset must be a mapping")
        m = own.get("map")
        if isinstance(m, str) and m.lower().endswith((".yaml", ".yml")) and not Path(m).expanduser().is_absolute():
            own = {**own, "map": str(Path(robot).parent / m)}  # like a ROS map's image: beside its YAML
        data, source = deep_merge(load_preset_file("simulator"), own), str(robot)
    for key, value in overrides.items():
        set_dotted(data, key, value, known=RobotPreset, what="robot override")
    try:
        return RobotPreset.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(error_lines(exc, "robot"))
        raise ValueError(f"robot preset {source!r}"
                         + (f" with overrides {_shown(overrides)}" if overrides else "") + f": {problems}") from None


def with_recipe_setup(data: dict[str, Any], own_maps: bool | None = None) -> dict[str, Any]:
    """Raw TrainConfig ``data`` laid over its recipe's training setup (``setups.yaml``; recipes without
    one: ``data`` as it is). ``data`` wins key by key; when the run has maps of its own (``own_maps``;
    None: ``data`` has ``map`` or ``maps``) the setup's maps and training evaluation are left out. A
    recipe with a setup but none for the run's robot is an error."""
    recipe = data.get("recipe") if isinstance(data, dict) else None
    if recipe not in RECIPES:
        return data
    setups = load_preset_file("setups").get(recipe)
    if setups is None:
        return data
    robot = data.get("robot", DEFAULT_ROBOT)
    if robot not in setups:
        raise ValueError(f"recipe {recipe!r} has a training setup for {', '.join(setups)} only "
                         f"({preset_path('setups')}), not for robot {robot!r}")
    setup = dict(setups[robot])
    if own_maps is None:
        own_maps = data.get("map") is not None or data.get("maps") is not None
    if own_maps:
        setup.pop("maps", None)
        setup.pop("eval", None)
    return deep_merge(setup, data)


def _shown(overrides: dict[str, Any], most: int = 4) -> str:
    """The overrides for an error message: all of a few, else the first ``most`` and how many more (a scenario's
    agent settings are a dozen, and the failing key is named after them anyway)."""
    if len(overrides) <= most:
        return str(overrides)
    shown = ", ".join(f"{k!r}: {v!r}" for k, v in list(overrides.items())[:most])
    return f"{{{shown}, ... {len(overrides) - most} more}}"
