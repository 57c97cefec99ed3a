"""The Optuna search space of a sweep: distributions, start points, the objective.

``search:`` in a sweep YAML. services.optuna_search turns it into an Optuna sampler for Ray Tune.
"""

from __future__ import annotations

import builtins
from typing import Any

from pydantic import Field, field_validator, model_validator

from services.schema_base import OBJECTIVES, Strict, known_algorithms

DISTRIBUTIONS = ("choice", "int", "logint", "loguniform", "uniform")


class Distribution(Strict):
    """One search distribution, written ``{int: [2, 16]}`` (bounds inclusive), ``{choice: [...]}``, ..."""

    # builtins.int: a field named `int` shadows the builtin inside the class body.
    choice: list[Any] | None = None
    int: tuple[builtins.int, builtins.int] | None = None
    logint: tuple[builtins.int, builtins.int] | None = None
    uniform: tuple[float, float] | None = None
    loguniform: tuple[float, float] | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> "Distribution":
        given = [name for name in DISTRIBUTIONS if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one distribution; allowed: {', '.join(DISTRIBUTIONS)}")
        kind = given[0]
        value = getattr(self, kind)
        if kind == "choice" and not value:
            raise ValueError("choice needs at least one value")
        if kind != "choice" and not value[0] < value[1]:
            raise ValueError(f"{kind} bounds must be [low, high] with low < high, got {list(value)}")
        if kind.startswith("log") and value[0] <= 0:
            raise ValueError(f"{kind} bounds must be > 0, got {list(value)}")
        return self

    @property
    def kind(self) -> str:
        return next(name for name in DISTRIBUTIONS if getattr(self, name) is not None)

    def contains(self, value: Any) -> bool:
        """Whether ``value`` is a possible sample (bounds inclusive)."""
        if self.kind == "choice":
            return value in self.choice
        if isinstance(value, bool) or not isinstance(value, (builtins.int, float)):
            return False
        if self.kind in ("int", "logint") and not isinstance(value, builtins.int):
            return False
        low, high = self.args
        return low <= value <= high

    @property
    def args(self) -> Any:
        return getattr(self, self.kind)

    def extremes(self) -> list[Any]:
        """The values that bound what a trial may draw: every choice, or both ends of a range, and for a
        uniform range one value inside it that is not a whole number (what the driver checks before anything
        runs: ``uniform: [2, 16]`` for an integer key passed at both ends, 2.0 and 16.0, and failed every trial)."""
        if self.kind == "choice":
            return list(self.choice)
        low, high = self.args
        if self.kind in ("int", "logint"):
            return [low, high]
        inside = low + 0.381966 * (high - low)  # (the golden section: not a whole number for whole-number ends)
        return [low, high, inside if self.kind == "uniform" else low * (high / low) ** 0.381966]


class Search(Strict):
    """Optuna search: one study per (robot, algorithm); each trial runs ``seeds_per_trial`` seeds."""

    n_trials: int = Field(gt=0, description="trials per (robot, algorithm) study")
    objective: str = Field("time_to_90", description="per-seed metric averaged over the trial's seeds")
    seeds_per_trial: int = Field(1, gt=0, description="the first k of the sweep's seeds, the same for every trial")
    unreached_penalty: float = Field(0.0, ge=0, description="added to a censored objective where not reached")
    study_name: str | None = Field(None, description="default: <sweep>-<robot>-<algorithm>-<invocation stamp>")
    storage: str | None = Field(None, description="Optuna RDB URL; default sqlite:///<runs>/optuna.db")
    sampler_seed: int | None = Field(None, ge=0, le=2**32 - 1, description="the TPE sampler's seed (numpy's range)")
    startup_trials: int | None = Field(
        None, gt=0, description="trials (start points included) drawn at random before TPE models the results "
        "(Optuna's n_startup_trials; default: Optuna's 10): a study of no more trials than this is a seeded random "
        "search, whatever the results")
    best_seeds: int = Field(10, gt=0, description="seeds of the best-config sweep YAML written at the end")
    parameters: dict[str, Distribution] = Field(default_factory=dict, description="config path -> distribution")
    algorithm_parameters: dict[str, dict[str, Distribution]] = Field(default_factory=dict)
    start_points: list[dict[str, Any]] = Field(
        default_factory=list, description="trials run first, in order (e.g. the current recipe, a baseline "
        "inside the study): config path -> value, each inside its distribution; unnamed paths are sampled")

    @field_validator("storage")
    @classmethod
    def _storage(cls, value: str | None) -> str | None:
        if value is None:
            return value
        from sqlalchemy.engine import make_url
        from sqlalchemy.exc import ArgumentError

        try:  # what optuna's RDB storage parses, only once Ray is up
            make_url(value)
        except ArgumentError:
            raise ValueError(f"{value!r} is not a database URL (e.g. sqlite:///runs/optuna.db, "
                             f"postgresql://user@host/db)") from None
        return value

    @field_validator("objective")
    @classmethod
    def _objective(cls, value: str) -> str:
        if value not in OBJECTIVES:
            raise ValueError(f"unknown objective {value!r}; allowed: {', '.join(OBJECTIVES)}")
        return value

    @field_validator("algorithm_parameters")
    @classmethod
    def _algorithms(cls, value: dict) -> dict:
        return known_algorithms(value)

    @model_validator(mode="after")
    def _start_points_in_space(self) -> "Search":
        known = dict(self.parameters)
        for space in self.algorithm_parameters.values():
            known.update(space)
        for i, point in enumerate(self.start_points):
            for path, value in point.items():
                if path not in known:
                    raise ValueError(f"start_points[{i}]: {path!r} is not a searched parameter; "
                                     f"searched: {', '.join(known) or 'none'}")
                if not known[path].contains(value):
                    raise ValueError(f"start_points[{i}]: {path}={value!r} lies outside its distribution "
                                     f"{{{known[path].kind}: {list(known[path].args)}}}")
        return self

    @property
    def mode(self) -> str:
        return OBJECTIVES[self.objective]

    def space_for(self, algorithm: str) -> dict[str, Distribution]:
        """The distributions that apply to ``algorithm`` (shared ones plus its own)."""
        return {**self.parameters, **self.algorithm_parameters.get(algorithm, {})}

