"""The configuration spine: what a user asks for (``TrainConfig``) -> ``resolve()`` -> what a run is
(``RunSpec``).

Every way of starting a run produces a :class:`TrainConfig` (built in :mod:`flashnav.request`,
re-exported here): ``flashnav train`` flags and ``key=value`` overrides and ``--config FILE``
(:func:`config_from_cli`), a sweep trial (``services.sweep_schema.Sweep.train_config``),
``flashnav bench train``, or a Python call.
:func:`resolve` then turns it, once, into a frozen :class:`RunSpec`: the robot preset with its
overrides, the recipe's hyperparameters with theirs, the device, the map, the budget and evaluation
with the recipe's defaults filled in. ``train()`` takes the spec; ``TrainResult.spec`` carries it;
``config.yaml``, checkpoints, MLflow params and ``flashnav bench`` write :meth:`RunSpec.to_dict`
and read it back with :meth:`RunSpec.from_dict`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

from flashnav.config import RobotPreset
from flashnav.finetune import InitSource, check_compatible, check_goal_scale, load_init_source
from flashnav.learn.hparams import MODELS, AnyHParams, load_hparams
from flashnav.machine import resolve_cuda_graph, resolve_device, resolve_overlap, resolve_precision, resolve_recipe
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.stream import GeneratedMaps, generate_set, generation_radius
from flashnav.maps.validation import check_not_benchmark, load_eval_maps
from flashnav.presets import load_robot
from flashnav.request import (OVERRIDE_PREFIXES, Budget, EvalSettings, TrainConfig, as_mapping, apply_override,
                              config_from_cli, config_from_data, run_request)

__all__ = ["OVERRIDE_PREFIXES", "Budget", "EvalSettings", "TrainConfig", "apply_override", "config_from_cli",
           "config_from_data", "run_request", "RunSpec", "resolve"]


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
        data = as_mapping(data, source)
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
        check_compatible(checkpoint, config.algorithm, hparams, robot, config.init_from, recipe)
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
