"""The configuration spine: what a user asks for (``TrainConfig``) -> ``resolve()`` -> what a run is
(``RunSpec``).

Every way of starting a run produces a :class:`TrainConfig`: ``flashnav train`` flags and
``key=value`` overrides and ``--config FILE`` (:func:`config_from_cli`), a sweep trial
(``services.sweep_schema.Sweep.train_config``), ``flashnav bench train``, or a Python call.
:func:`resolve` then turns it, once, into a frozen :class:`RunSpec`: the robot preset with its
overrides, the recipe's hyperparameters with theirs, the device, the map, the budget and evaluation
with the recipe's defaults filled in. ``train()`` takes the spec; ``TrainResult.spec`` carries it;
``config.yaml``, checkpoints, MLflow params and ``flashnav bench`` write :meth:`RunSpec.to_dict`
and read it back with :meth:`RunSpec.from_dict`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator

from flashnav.config import KnownKeys, RobotPreset, error_lines
from flashnav.finetune import InitSource, check_compatible, check_goal_scale, load_init_source
from flashnav.learn.hparams import MODELS, AnyHParams, load_hparams, override_section
from flashnav.machine import (MACHINE_KEYS, check_device_name, resolve_cuda_graph, resolve_device, resolve_overlap,
                              resolve_precision, resolve_recipe)
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.stream import GeneratedMaps, generate_set, generation_radius, parse_family_maps
from flashnav.maps.validation import check_eval_maps_value, check_not_benchmark, load_eval_maps
from flashnav.names import (ALGORITHMS, CUDA_GRAPH_MODES, DEFAULT_ROBOT, EVAL_EPISODES, EVAL_SEED, RAYCASTERS,
                            RECIPE_CHOICES, RECIPE_HELP, ROBOTS, check_robot)
from flashnav.presets import load_robot, with_recipe_setup
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
    seed: int = Field(EVAL_SEED, ge=0, description="fixed evaluation seed: same start/goal pairs for every evaluation and seed")
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
    seed: int = Field(0, ge=0, description="training seed")
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


# ---- building a TrainConfig ------------------------------------------------------------------------


def _mapping(data: Any, source: str) -> dict[str, Any]:
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
    try:
        return TrainConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"{source}: {'; '.join(error_lines(exc))}") from None


def run_request(data: dict[str, Any]) -> dict[str, Any] | None:
    """A run's ``config.yaml`` (with ``hparams``, ``robot_preset``) -> its request less MACHINE_KEYS; else None."""
    if not {"hparams", "robot_preset"} <= data.keys():
        return None
    return {k: v for k, v in data.items() if k in TrainConfig.model_fields and k not in MACHINE_KEYS}


def config_from_cli(config_file: str | None = None, flags: dict[str, Any] | None = None,
                    assignments: list[str] | tuple[str, ...] = ()) -> TrainConfig:
    """A TrainConfig from a YAML file (optional; a run's ``config.yaml`` gives its request), then flags (None = not
    given), then ``key=value`` assignments, each later winning. The path of ``flashnav train`` and ``bench train``."""
    data = _mapping(load_yaml(config_file), config_file) if config_file else {}
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


# ---- resolving -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSpec:
    """One run, resolved: every value that decides what ``train()`` does, typed. Build with
    :func:`resolve`; serialise with :meth:`to_dict` (``config.yaml``), read back with :meth:`from_dict`."""

    config: TrainConfig           # as asked for (overrides kept as given)
    robot: RobotPreset            # the preset with its robot.* overrides applied
    hparams: AnyHParams           # the recipe with its algo.* overrides applied
    device: str                   # cpu, cuda, cuda:N (never auto)
    recipe: str                   # paper or cpu (never auto)
    goal_distance_max: float      # metres: the map's diagonal, the largest one over many maps, the largest
                                  # a generated map can have, or a fine-tuned checkpoint's run's
                                  # (observation bound, network scale; one fixed scale for all maps)
    grid: OccupancyMap | None = field(default=None, repr=False, compare=False)  # the loaded map (the first of many)
    grids: tuple[OccupancyMap, ...] | None = field(default=None, repr=False, compare=False)  # every loaded map
    cuda_graph: bool = False      # static-buffer updates, CUDA-graph captured on cuda (resolve_cuda_graph)
    overlap: bool = False         # collector thread beside the learner (resolve_overlap)
    init: InitSource | None = None  # fine-tuning: the checkpoint the learner starts from (config.init_from)
    eval_maps: dict[str, Any] | None = None  # config.eval.maps resolved: {"files": [...]} or the validation suite's
                                             # {"suite", "families", "seeds", "maps_per_family"}; None = training maps
    eval_grids: tuple[OccupancyMap, ...] | None = field(default=None, repr=False, compare=False)  # their maps

    def eval_env_maps(self) -> tuple[OccupancyMap, ...] | None:
        """The maps every evaluation plays when ``eval.maps`` is set (loaded or generated here for a spec
        read back from a file); None = the training maps (:meth:`env_maps`)."""
        if self.config.eval.maps is None:
            return None
        return self.eval_grids if self.eval_grids is not None else load_eval_maps(self.config, self.robot)[0]

    def env_maps(self) -> OccupancyMap | tuple[OccupancyMap, ...]:
        """What ``NavVecEnv(grid=...)`` takes for this run: the one map, or every map (loaded here
        for a spec read back from a file)."""
        grids = self.grids
        if grids is None:
            if self.config.maps is None and self.grid is not None:
                return self.grid
            grid, grids = _load_maps(self.config, self.robot)
            if grids is None:
                return grid
        return grids[0] if len(grids) == 1 else grids

    @property
    def algorithm(self) -> str:
        return self.config.algorithm

    @property
    def seed(self) -> int:
        return self.config.seed

    @property
    def budget(self) -> Budget:
        return self.config.budget

    @property
    def max_env_steps(self) -> int:
        """Budget in env steps: the config's, else the recipe's total."""
        return self.config.budget.max_env_steps or self.hparams.total_env_steps

    @property
    def eval_every(self) -> int:
        """Vector steps between evaluations: the config's, else the recipe's."""
        return self.config.eval.every or self.hparams.eval_every

    @property
    def threads(self) -> int | None:
        """Learner threads: the config's; on a CPU with overlap, 1 (the collector thread has the other
        core); else None (torch's, which ``train()`` holds at the count it had when called)."""
        return self.config.threads or (1 if self.overlap and self.device == "cpu" else None)

    @property
    def robot_name(self) -> str:
        return self.robot.name

    def to_dict(self) -> dict[str, Any]:
        """Plain data (YAML/JSON): the TrainConfig's fields with device, recipe, cuda_graph and overlap resolved,
        plus ``hparams``, ``robot_preset`` and ``goal_distance_max``."""
        data = self.config.model_dump(mode="json")
        data.update(device=self.device, recipe=self.recipe, cuda_graph="on" if self.cuda_graph else "off",
                    overlap=self.overlap, hparams=self.hparams.model_dump(mode="json"),
                    robot_preset=self.robot.model_dump(mode="json"), goal_distance_max=self.goal_distance_max)
        if self.init is not None:
            data["init_source"] = self.init.to_dict()
        if self.eval_maps is not None:
            data["eval_maps"] = self.eval_maps
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "run config") -> "RunSpec":
        """Read back :meth:`to_dict` (``config.yaml``, a checkpoint's config, an MLflow artifact).

        Configs written before ``goal_distance_max`` was recorded take the preset's map size."""
        data = _mapping(data, source)
        try:
            config = TrainConfig.model_validate({k: v for k, v in data.items() if k in TrainConfig.model_fields},
                                                context={"resolved": True})
            robot = RobotPreset.model_validate(data["robot_preset"])
            hparams = MODELS[config.algorithm].model_validate(data["hparams"])
        except KeyError as exc:
            raise ValueError(f"{source}: not a resolved run config (no {exc.args[0]!r})") from None
        except ValidationError as exc:
            raise ValueError(f"{source}: not a valid run config:\n{exc}") from None
        goal = data.get("goal_distance_max") or math.hypot(*robot.map_size)
        device = str(data.get("device", config.device))
        init = InitSource.from_dict(data["init_source"]) if data.get("init_source") else None
        return cls(config, robot, hparams, device, str(data.get("recipe", config.recipe)), float(goal),
                   cuda_graph=resolve_cuda_graph(config.cuda_graph, device, decaying_lr=hparams.lr_final_ratio < 1),
                   overlap=resolve_overlap(config.overlap, device), init=init,
                   eval_maps=data.get("eval_maps") if config.eval.maps is not None else None)


def _load_maps(config: TrainConfig, robot: RobotPreset) -> tuple[OccupancyMap, tuple[OccupancyMap, ...] | None]:
    """The maps ``config`` asks for: ``(the map, None)`` for one map (``map``, else the preset's);
    ``(the first, all of them)`` for ``maps`` (files, a list, or generated maps' set 0)."""
    from flashnav.maps.bundled import resolve_map, resolve_maps

    if config.maps is None:  # one map: a benchmark map is allowed (fine-tuning on one building, issue 15)
        return resolve_map(config.map, robot.map), None
    if isinstance(config.maps, GeneratedMaps):
        grids = generate_set(config.maps, 0, generation_radius(robot))
    else:
        grids = tuple(resolve_maps(config.maps, robot.map))
        check_not_benchmark(list(grids), "maps")  # a generalist trained on the benchmark would measure nothing
    return grids[0], grids


def resolve(config: TrainConfig | None = None) -> RunSpec:
    """The one place a run's configuration is resolved: device, recipe, preset, hyperparameters, map.

    Raises ValueError naming the bad input (an unknown override key, a missing map, no CUDA, ...).
    """
    config = config or TrainConfig()
    device = resolve_device(config.device)
    recipe = resolve_recipe(config.recipe, device)
    robot = load_robot(config.robot, **config.robot_overrides())
    hparams = load_hparams(config.algorithm, robot.name, recipe, config.algo_overrides())
    if hparams.precision == "auto":  # what this device runs, recorded as such in the run's config
        hparams = hparams.model_copy(update={"precision": resolve_precision(hparams.precision, device)})
    cuda_graph = resolve_cuda_graph(config.cuda_graph, device, decaying_lr=hparams.lr_final_ratio < 1)
    if cuda_graph and device.startswith("cuda") and hparams.lr_final_ratio < 1:
        # a captured optimiser step replays the learning rate it was recorded with
        raise ValueError(f"algo.lr_final_ratio={hparams.lr_final_ratio} (a decaying learning rate) cannot run with "
                         "cuda_graph=on on a GPU: the captured updates keep the rate of the capture; "
                         "use cuda_graph=off or algo.lr_final_ratio=1")
    overlap = resolve_overlap(config.overlap, device)
    init = checkpoint = None
    if config.init_from is not None or config.init_replay:  # before the maps: a mismatch is refused before any loads
        init, checkpoint = load_init_source(config.init_from, RunSpec.from_dict, replay=config.init_replay)
        check_compatible(checkpoint, config.algorithm, hparams, robot, config.init_from)
    if isinstance(config.maps, GeneratedMaps):  # before drawing set 0: every set's seeds must be valid
        config.maps.check_seeds(math.ceil((config.budget.max_env_steps or hparams.total_env_steps) / hparams.num_envs))
    eval_grids, eval_maps = load_eval_maps(config, robot)  # before the training maps: a bad path fails fast
    grid, grids = _load_maps(config, robot)
    if grids is None:
        scale = grid.diagonal_m
    elif isinstance(config.maps, GeneratedMaps):
        scale = config.maps.goal_distance_max  # the largest a generated map can be
    else:
        if config.map_weights is not None and len(config.map_weights) != len(grids):
            raise ValueError(f"map_weights has {len(config.map_weights)} entries for the {len(grids)} maps of "
                             f"maps = {config.maps!r}")
        # one fixed goal-distance scale for every map: the largest diagonal
        scale = max(g.diagonal_m for g in grids)
    if checkpoint is not None:
        # the network keeps the scale it was trained with, whatever the new maps' size
        scale = checkpoint.goal_distance_max
        check_goal_scale(scale, robot, config.init_from)
    return RunSpec(config, robot, hparams, device, recipe, scale, grid, grids, cuda_graph=cuda_graph,
                   overlap=overlap, init=init, eval_maps=eval_maps, eval_grids=eval_grids)
