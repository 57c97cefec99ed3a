"""The training run's configuration (pydantic; loadable from YAML). See docs/train-api.md."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from flashnav.config import load_yaml

THRESHOLDS = (0.9, 0.95, 1.0)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Budget(_Strict):
    max_train_seconds: float = Field(600.0, gt=0, description="training-clock budget, seconds")
    max_env_steps: int | None = Field(None, gt=0, description="None = the recipe's total env steps")
    stop_at_success: float | None = Field(1.0, ge=0, le=1, description="stop once an evaluation reaches this success rate")


class EvalSettings(_Strict):
    episodes: int = Field(1024, gt=0, description="evaluation episodes, run in parallel, deterministic policy")
    every: int | None = Field(None, gt=0, description="evaluate every k vector steps (None = the recipe's eval_every)")
    seed: int = Field(12345, description="fixed evaluation seed: same start/goal pairs for every evaluation and seed")


class TrainConfig(_Strict):
    """One training run. Every field has a default: ``TrainConfig()`` trains FastDSAC on TurtleBot2."""

    robot: str = Field("turtlebot2", description="preset name (turtlebot2, go2) or a preset YAML path")
    algorithm: Literal["fastdsac", "fastsac", "fasttd3"] = Field("fastdsac", description="the learner")
    recipe: Literal["auto", "paper", "cpu"] = Field(
        "auto", description="hyperparameter recipe: paper (appendix A, GPU), cpu (2 CPU cores), auto by device")
    seed: int = Field(0, description="training seed")
    device: str = Field("auto", description="auto, cpu, cuda, cuda:N")
    map: str | None = Field(None, description="ROS map YAML path or bundled map name; None = the preset's map")
    raycaster: str | None = Field(None, description="None = the simulator's default (exact)")
    overrides: dict[str, Any] = Field(
        default_factory=dict,
        description="dotted keys: 'algo.<hyperparameter>' (e.g. algo.batch_size) or 'robot.<preset path>' "
                    "(e.g. robot.lidar.noise_std)")
    budget: Budget = Field(default_factory=Budget)
    eval: EvalSettings = Field(default_factory=EvalSettings)
    threads: int | None = Field(None, gt=0, description="torch CPU threads (None = torch's default)")
    overlap: bool = Field(True, description="overlap collection and learning (False = the plain sequential loop)")

    @field_validator("overrides")
    @classmethod
    def _prefixed(cls, v: dict[str, Any]) -> dict[str, Any]:
        for key in v:
            if not (key.startswith("algo.") or key.startswith("robot.")):
                raise ValueError(f"override {key!r} must start with 'algo.' or 'robot.'")
        return v

    @classmethod
    def from_yaml(cls, path: str | Path) -> "TrainConfig":
        data = load_yaml(path) or {}
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a training config must be a mapping")
        return cls.model_validate(data)

    def algo_overrides(self) -> dict[str, Any]:
        return {k[len("algo."):]: v for k, v in self.overrides.items() if k.startswith("algo.")}

    def robot_overrides(self) -> dict[str, Any]:
        return {k[len("robot."):]: v for k, v in self.overrides.items() if k.startswith("robot.")}


#: the device names a run accepts (``cuda:N`` picks the N-th GPU)
DEVICE_NAMES = "auto, cpu, cuda, cuda:N"
_DEVICE = re.compile(r"auto|cpu|cuda(:\d+)?")


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` where a GPU is visible, else ``cpu``; other names are checked here, before
    any folder or tensor is made, so a typo or a missing GPU fails at once with a clear ValueError."""
    import torch

    if not isinstance(device, str) or not _DEVICE.fullmatch(device):
        raise ValueError(f"device {device!r} is not one of {DEVICE_NAMES}")
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise ValueError(f"device {device!r} requested but CUDA is not available on this machine "
                             f"(torch {torch.__version__} sees no GPU); use cpu")
        index, count = int(device.partition(":")[2] or 0), torch.cuda.device_count()
        if index >= count:
            raise ValueError(f"device {device!r} requested but this machine has {count} GPU(s) "
                             f"(cuda:0 .. cuda:{count - 1})")
    return device


def resolve_recipe(recipe: str, device: str) -> str:
    if recipe != "auto":
        return recipe
    return "paper" if device.startswith("cuda") else "cpu"
