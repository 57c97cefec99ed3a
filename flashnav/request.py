"""What a user asks for: :class:`TrainConfig` (with its :class:`Budget` and :class:`EvalSettings`), and the one
way each front door builds it from raw data (:func:`config_from_data`), from ``flashnav train``'s ``--config
FILE``, flags and ``key=value`` assignments (:func:`config_from_cli`), or from a run's ``config.yaml``
(:func:`run_request`).

:mod:`flashnav.spec` resolves it, once, into what a run is (``RunSpec``) and re-exports every name here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, StrictInt, ValidationError, ValidationInfo, field_validator, model_validator

from flashnav.config_base import KnownKeys, error_lines
from flashnav.learn.hparams import override_section
from flashnav.machine import MACHINE_KEYS, check_device_name
from flashnav.maps.stream import GeneratedMaps, parse_family_maps
from flashnav.maps.validation import check_eval_maps_value
from flashnav.names import (ALGORITHMS, CUDA_GRAPH_MODES, DEFAULT_ROBOT, EVAL_EPISODES, EVAL_SEED, MAX_SEED,
                            RAYCASTERS, RECIPE_CHOICES, RECIPE_HELP, ROBOTS, check_robot)
from flashnav.presets import with_recipe_setup
from flashnav.yamlio import load_yaml, parse_assignment, set_dotted

#: Prefixes of the keys in ``TrainConfig.overrides``: into the hyperparameters, into the robot preset.
OVERRIDE_PREFIXES = ("algo.", "robot.")


class Budget(KnownKeys):
    """When a training run stops (whichever comes first)."""

    max_train_seconds: float = Field(600.0, gt=0, description="training-clock budget, seconds")
    max_env_steps: int | None = Field(None, gt=0, description="None = the recipe's total env steps")
    stop_at_success: float | None = Field(1.0, ge=0, le=1, description="stop once an evaluation reaches this success rate")


class EvalSettings(KnownKeys):
    """The fixed evaluation set every evaluation of a run plays."""

    episodes: int = Field(EVAL_EPISODES, gt=0, description="evaluation episodes, run in parallel, deterministic policy")
    every: int | None = Field(None, gt=0, description="evaluate every k vector steps (None = the recipe's eval_every)")
    seed: StrictInt = Field(EVAL_SEED, ge=0, le=MAX_SEED, description="fixed evaluation seed: same start/goal pairs "
                            "for every "
                            "evaluation and seed")
    maps: str | list[str] | None = Field(
        None, description="evaluate on other maps than the training maps (None): a directory, glob or list of ROS map "
                          "YAML files, or 'validation' (generated, seeds from 800000; flashnav/maps/validation.py), "
                          "episodes spread over them in blocks; the benchmark suites (heldout, real) are refused")
    maps_per_family: int = Field(4, gt=0, description="with maps: validation, the suite's maps per family")
    training_episodes: int = Field(100, gt=0, description="the training-episode success beside each evaluation pools "
                                   "at least this many of the newest training episodes (a reading, never a stop)")

    @field_validator("maps")
    @classmethod
    def _not_benchmark(cls, value: Any) -> Any:
        return check_eval_maps_value(value)


class TrainConfig(KnownKeys):
    """One training run as asked for. Every field has a default: ``TrainConfig()`` trains FastDSAC on
    TurtleBot2. See docs/train-api.md."""

    robot: str = Field(DEFAULT_ROBOT, description=f"preset name ({', '.join(ROBOTS)}) or a preset YAML path")
    algorithm: Literal[ALGORITHMS] = Field("fastdsac", description="the learner")  # type: ignore[valid-type]
    recipe: Literal[RECIPE_CHOICES] = Field(  # type: ignore[valid-type]
        "auto", description="hyperparameter recipe: " + RECIPE_HELP)
    seed: StrictInt = Field(0, ge=0, le=MAX_SEED, description="training seed (an integer: `seed=yes` is not 1)")
    device: str = Field("auto", description="auto, cpu, cuda, cuda:N")
    map: str | None = Field(None, description="ROS map YAML path or bundled map name; None = the preset's map")
    maps: str | list[str] | GeneratedMaps | None = Field(
        None, description="train over many maps instead of one: a directory or glob pattern of ROS map YAML "
                          "files, or a list of maps as `map` takes; every slot draws a map when it resets; or "
                          "maps generated during training: {family, count, refresh_every, seed} "
                          "(flashnav/maps/stream.py; `family:rooms,offices` on the command line)")
    map_weights: list[float] | None = Field(None, description="with `maps` (a list): each map's relative "
                                                             "probability; None = uniform")
    init_from: str | None = Field(
        None, description="fine-tune: start from this run folder's (or checkpoint file's) learner state "
                          "(flashnav/finetune.py); the networks must match its shapes")
    init_replay: bool = Field(False, description="with init_from: start from its run's replay buffer too (replay.pt, "
                                                 "written by flashnav train --save-replay; same envs and layout)")
    raycaster: Literal[RAYCASTERS] | None = Field(  # type: ignore[valid-type]
        None, description="None = the simulator's default (exact)")
    overrides: dict[str, Any] = Field(
        default_factory=dict,
        description="dotted keys: 'algo.<hyperparameter>' (e.g. algo.batch_size) or 'robot.<preset path>' "
                    "(e.g. robot.lidar.noise_std)")
    budget: Budget = Field(default_factory=Budget)
    eval: EvalSettings = Field(default_factory=EvalSettings)
    threads: int | None = Field(None, gt=0, description="learner torch CPU threads (None = 1 beside an overlapped "
                                                        "collector thread on a CPU, else torch's count at train())")
    overlap: bool | Literal["auto"] = Field(
        "auto", description="overlap collection and learning (the collector in a second thread); False = the plain "
                            "sequential loop, the learner on every CPU core the process has; auto = on for cuda, "
                            "off for cpu (flashnav.machine.resolve_overlap)")
    cuda_graph: Literal[CUDA_GRAPH_MODES] = Field(  # type: ignore[valid-type]
        "auto", description="the U updates of a cycle on static batch buffers, captured as one CUDA graph on a "
                            "GPU (on a CPU: the same updates eagerly, capture skipped); auto = on for cuda, off for cpu")

    @model_validator(mode="before")
    @classmethod
    def _recipe_setup(cls, data: Any, info: ValidationInfo) -> Any:
        # a config read back (RunSpec.from_dict) already holds its setup as it was: not today's
        return data if (info.context or {}).get("resolved") else with_recipe_setup(data)

    @field_validator("robot")
    @classmethod
    def _robot(cls, value: str) -> str:
        return check_robot(value)

    @model_validator(mode="after")
    def _one_map_source(self) -> "TrainConfig":
        if self.map is not None and self.maps is not None:
            raise ValueError("give either map or maps, not both")
        if self.map_weights is not None and (self.maps is None or isinstance(self.maps, GeneratedMaps)):
            raise ValueError("map_weights needs maps (files or a list; generated maps are drawn uniformly)")
        if self.map_weights is not None and (min(self.map_weights, default=0) < 0 or not any(self.map_weights)):
            raise ValueError(f"map_weights must be >= 0 and not all 0 (relative probabilities), got {self.map_weights}")
        return self

    @field_validator("maps", mode="before")
    @classmethod
    def _family_maps(cls, value: Any) -> Any:
        return parse_family_maps(value)

    @field_validator("device")
    @classmethod
    def _device(cls, value: str) -> str:
        check_device_name(value)
        return value

    @field_validator("cuda_graph", mode="before")
    @classmethod
    def _yaml_switch(cls, value: Any) -> Any:
        """YAML reads a bare ``on`` / ``off`` (``cuda_graph=on``, ``cuda_graph: off``) as a boolean."""
        return {True: "on", False: "off"}.get(value, value) if isinstance(value, bool) else value

    @field_validator("overrides")
    @classmethod
    def _prefixed(cls, v: dict[str, Any]) -> dict[str, Any]:
        for key in v:
            if not key.startswith(OVERRIDE_PREFIXES) or key in OVERRIDE_PREFIXES:
                raise ValueError(f"override {key!r} must start with 'algo.' or 'robot.' and name a key after it")
        return v

    @classmethod
    def from_yaml(cls, path: str | Path) -> "TrainConfig":  # as `flashnav train --config` reads it (a run's too)
        return config_from_cli(str(path))

    def algo_overrides(self) -> dict[str, Any]:
        return {k[len("algo."):]: v for k, v in self.overrides.items() if k.startswith("algo.")}

    def robot_overrides(self) -> dict[str, Any]:
        return {k[len("robot."):]: v for k, v in self.overrides.items() if k.startswith("robot.")}


def as_mapping(data: Any, source: str) -> dict[str, Any]:
    """Raw config data as a mapping (None = empty); anything else is refused naming ``source``."""
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"{source}: a training config must be a mapping, got {type(data).__name__}")
    return data


def apply_override(data: dict[str, Any], key: str, value: Any) -> None:
    """Set one dotted ``key`` of raw TrainConfig data in place: ``algo.*`` / ``robot.*`` keys go to
    ``overrides`` (checked when resolved, against the recipe and the preset), any other key is a
    TrainConfig field path (``budget.max_train_seconds``), checked here."""
    if key.startswith(OVERRIDE_PREFIXES):
        overrides = data.setdefault("overrides", {})
        if not isinstance(overrides, dict):
            raise ValueError(f"overrides must be a mapping of dotted keys, got {overrides!r}")
        overrides[key] = value
    else:
        section = (head := key.split(".")[0]) not in TrainConfig.model_fields and override_section(head)  # lidar.x=1
        if section:
            raise ValueError(f"override {key!r}: not a training-config key; did you mean {section}.{key}?")
        set_dotted(data, key, value, known=TrainConfig, create=True,
                   other_sections=tuple(p.rstrip(".") for p in OVERRIDE_PREFIXES))


def config_from_data(data: dict[str, Any], source: str = "config") -> TrainConfig:
    """Validate raw data as a TrainConfig; a ValueError lists every problem with its key path."""
    if isinstance(data.get("algo"), dict):  # a section a config file cannot have: where its keys go instead
        raise ValueError(f"{source}: algo: not a section here; hyperparameters go under overrides as dotted keys: "
                         f"overrides: {{algo.{next(iter(data['algo']), 'batch_size')}: ...}}")
    if isinstance(data.get("robot"), dict):  # robot names a preset; its changes are overrides too
        first = _first_dotted(data["robot"]) or "lidar.noise_std"
        raise ValueError(f"{source}: robot: names a preset (turtlebot2, go2 or a preset YAML file), not a section; "
                         f"changes to it go under overrides as dotted keys: overrides: {{robot.{first}: ...}}")
    try:
        return TrainConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"{source}: {'; '.join(error_lines(exc))}") from None


def _first_dotted(section: dict) -> str | None:
    """The first key path of a nested mapping, dotted (``{lidar: {noise_std: 0.1}}`` -> ``lidar.noise_std``)."""
    for key, value in section.items():
        rest = _first_dotted(value) if isinstance(value, dict) and value else None
        return f"{key}.{rest}" if rest else str(key)
    return None


def run_request(data: dict[str, Any]) -> dict[str, Any] | None:
    """A run's ``config.yaml`` (with ``hparams``, ``robot_preset``) -> its request less MACHINE_KEYS; else None."""
    if not {"hparams", "robot_preset"} <= data.keys():
        return None
    return {k: v for k, v in data.items() if k in TrainConfig.model_fields and k not in MACHINE_KEYS}


def config_from_cli(config_file: str | None = None, flags: dict[str, Any] | None = None,
                    assignments: list[str] | tuple[str, ...] = ()) -> TrainConfig:
    """A TrainConfig from a YAML file (optional; a run's ``config.yaml`` gives its request), then flags (None = not
    given), then ``key=value`` assignments, each later winning. The path of ``flashnav train`` and ``bench train``."""
    data = as_mapping(load_yaml(config_file), config_file) if config_file else {}
    data = data if (request := run_request(data)) is None else request  # a run's config.yaml: its request only
    for name, value in (flags or {}).items():
        if value is not None:
            data[name] = value
    pairs = [parse_assignment(item) for item in assignments]
    # the recipe's setup before the assignments, so that maps.count=... finds the setup's maps; a map=
    # or maps= assignment replaces its maps and evaluation as --map / --maps do
    data = with_recipe_setup(data, own_maps=any(data.get(k) is not None for k in ("map", "maps"))
                             or any(key in ("map", "maps") for key, _ in pairs))
    if "maps" in data:  # `family:rooms` as the whole mapping, so maps.count=... overrides find their keys
        data["maps"] = parse_family_maps(data["maps"])
    for key, value in pairs:
        apply_override(data, key, value)
    return config_from_data(data, "training config")
