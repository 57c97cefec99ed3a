"""The sweep YAML: a strict pydantic schema and ``--set`` overrides.

A sweep names robots x algorithms x seeds, the TrainConfig fields every trial shares (``base``, a
partial :class:`flashnav.spec.TrainConfig`; ``overrides``; ``budget``, TrainConfig's own Budget), the Ray resources of one trial, and optionally an Optuna ``search``
(services.search_space).
Unknown keys are errors whose message names the key's full path and the allowed names, so that a
misspelt ``budjet`` fails at load time, not after an hour of sweeping.

Paths in a sweep (MLflow tracking store, Optuna storage, Ray storage) are made absolute by
services.paths, in the driver: the driver of a Ray job runs in a temporary copy of the working dir and
each trial in its own directory, so a relative path would silently land in a folder that is thrown away.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

import yaml
from pydantic import Field, StrictInt, ValidationError, field_serializer, field_validator, model_validator
from pydantic_core import PydanticCustomError

from flashnav.config_base import problems
from flashnav.names import check_robot
from flashnav.spec import Budget, TrainConfig
from flashnav.yamlio import load_yaml, parse_assignment, set_dotted
from services.schema_base import Strict, SweepError, known_algorithms
from services.search_space import Search

# Maps whose keys are themselves dotted config paths: `--set` treats the rest of a path as one key.
_DOTTED_MAPS = ("overrides", "parameters")
_PER_ALGORITHM_MAPS = ("algorithm_overrides", "algorithm_parameters")


# TrainConfig fields a sweep sets elsewhere, and where.
_SET_BY_SWEEP = {"robot": "robots", "algorithm": "algorithms", "seed": "seeds", "device": "resources.gpu",
                 "budget": "budget (top level)", "overrides": "overrides (top level)"}


def _base_keys(data: Any) -> Any:
    """``base`` is a partial TrainConfig: its own fields only, minus those the sweep sets elsewhere."""
    if isinstance(data, dict):
        allowed = sorted(set(TrainConfig.model_fields) - set(_SET_BY_SWEEP))
        for key in data:
            if key in _SET_BY_SWEEP:
                raise PydanticCustomError("unknown_key", "set by the sweep's {where}, not in base",
                                          {"key": str(key), "where": _SET_BY_SWEEP[key]})
            if key not in allowed:
                raise PydanticCustomError("unknown_key", "unknown key; allowed: {allowed}",
                                          {"key": str(key), "allowed": ", ".join(allowed)})
    return data


class Resources(Strict):
    cpu: float = Field(1.0, gt=0, description="CPUs per trial")
    gpu: float = Field(0.0, ge=0, description="GPUs per trial; 0 = the trial trains on CPU even on a GPU host")


class Tracking(Strict):
    experiment: str | None = Field(None, description="MLflow experiment; default: the sweep's name")
    tracking_uri: str | None = Field(None, description="default: $MLFLOW_TRACKING_URI, else sqlite:///<runs>/mlflow.db")


class Retry(Strict):
    max_failures: int = Field(1, ge=0, description="retries of a trial that raised (Tune FailureConfig)")


def _once(names: list[str], key: str) -> list[str]:
    """``names`` unless one repeats (every seed would train twice and the report pool them as separate seeds)."""
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ValueError(f"{key} repeat: {', '.join(twice)} (each would run every seed twice)")
    return names


class Sweep(Strict):
    """A sweep file (see sweeps/*.yaml)."""

    name: str = Field(description="letters, digits, '.', '_', '-'")
    description: str = ""
    robots: list[str] = Field(min_length=1)
    algorithms: list[str] = Field(min_length=1)
    seeds: StrictInt | list[StrictInt] = Field(description="n (= seeds 0..n-1) or an explicit list")
    base: TrainConfig = Field(default_factory=TrainConfig,
                              description="TrainConfig fields every trial shares (recipe, map, eval, raycaster, ...)")
    overrides: dict[str, Any] = Field(default_factory=dict, description="TrainConfig.overrides for every trial")
    algorithm_overrides: dict[str, dict[str, Any]] = Field(default_factory=dict)
    budget: Budget = Budget()
    search: Search | None = None
    resources: Resources = Resources()
    max_concurrent_trials: int | None = Field(None, gt=0)
    tracking: Tracking = Tracking()
    storage: str | None = Field(None, min_length=1, description="Ray storage path; default <runs>/ray")
    retry: Retry = Retry()
    export_policy: bool = Field(True, description="write each run's policy.pt (TorchScript) as an MLflow artifact")

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", value):
            raise ValueError(f"{value!r} must be letters, digits, '.', '_', '-' (it names folders and studies)")
        return value

    @field_validator("base", mode="before")
    @classmethod
    def _base(cls, value: Any) -> Any:
        # base as written: a recipe's training setup (setups.yaml) belongs to each trial's robot and is laid
        # under the trial's own TrainConfig (train_config); laid under base here, it would be the default
        # robot's, and its overrides and budget would come back as base keys the sweep sets elsewhere
        if isinstance(_base_keys(value), dict):
            return TrainConfig.model_validate(value, context={"resolved": True})
        return value

    @field_serializer("base")
    def _dump_base(self, base: TrainConfig, info) -> dict[str, Any]:
        # only what the sweep set: the trials' robot, algorithm, seed... come from the sweep itself
        return base.model_dump(mode=info.mode, exclude_unset=True, exclude_defaults=info.exclude_defaults)

    @field_validator("robots")
    @classmethod
    def _robots(cls, value: list[str]) -> list[str]:
        for name in value:
            check_robot(name)
        return _once(value, "robots")

    @field_validator("algorithms")
    @classmethod
    def _algorithms(cls, value: list[str]) -> list[str]:
        return _once(known_algorithms(value), "algorithms")

    @field_validator("algorithm_overrides")
    @classmethod
    def _override_algorithms(cls, value: dict) -> dict:
        return known_algorithms(value)

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, value: int | list[int]) -> list[int]:
        seeds = list(range(value)) if isinstance(value, int) else list(value)
        if not seeds:
            raise ValueError("need at least one seed")
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds repeat: {seeds}")
        negative = [seed for seed in seeds if seed < 0]
        if negative:  # a training seed is >= 0 (flashnav.spec); the dry run resolves only the first seed
            raise ValueError(f"seeds must be >= 0, got {negative}")
        return seeds

    @model_validator(mode="after")
    def _overrides_apply(self) -> "Sweep":
        unused = sorted(set(self.algorithm_overrides) - set(self.algorithms))
        if unused:  # they would never reach a trial
            raise ValueError(f"algorithm_overrides for {', '.join(unused)}, which the sweep does not run "
                             f"(algorithms: {', '.join(self.algorithms)}); remove them or add the algorithm")
        return self

    @model_validator(mode="after")
    def _search_fits(self) -> "Sweep":
        if self.search is None:
            return self
        if self.search.seeds_per_trial > len(self.seed_list):
            raise ValueError(f"search.seeds_per_trial ({self.search.seeds_per_trial}) exceeds the {len(self.seed_list)} seeds")
        for algorithm in self.algorithms:
            space = self.search.space_for(algorithm)
            if not space:
                raise ValueError(f"search has no parameters for algorithm {algorithm!r}")
            clash = sorted(set(space) & set(self.overrides_for(algorithm)))
            if clash:
                raise ValueError(f"{', '.join(clash)}: both searched and fixed in overrides; remove one")
        return self

    @property
    def seed_list(self) -> list[int]:
        return list(self.seeds)  # normalised to a list by the validator

    @property
    def experiment(self) -> str:
        return self.tracking.experiment or self.name

    def overrides_for(self, algorithm: str) -> dict[str, Any]:
        """TrainConfig.overrides of ``algorithm``'s trials before any searched value."""
        return {**self.overrides, **self.algorithm_overrides.get(algorithm, {})}

    def train_config(self, robot: str, algorithm: str, seed: int, device: str, extra: dict | None = None) -> dict:
        """The TrainConfig of one training run, as the plain dict ``TrainConfig.model_validate`` takes."""
        return {
            **self.base.model_dump(mode="json", exclude_unset=True),
            "robot": robot,
            "algorithm": algorithm,
            "seed": int(seed),
            "device": device,
            "overrides": {**self.overrides_for(algorithm), **(extra or {})},
            "budget": self.budget.model_dump(),
        }


# ---------------------------------------------------------------- loading


def format_errors(error: ValidationError, source: str, sets: dict[tuple[str, ...], str] | None = None) -> str:
    """One line per problem: ``<file>: <key.path>: <message>``, with ``(from --set K=V)`` where the key, or a
    section holding it, was given by that ``--set`` (``sets``: the parts of each --set's path -> the assignment)."""
    found = problems(error)
    lines = [f"{source}: invalid sweep ({len(found)} problem{'s' * (len(found) > 1)})"]
    for loc, item in found:
        message = item["msg"].removeprefix("Value error, ")
        # A dotted config key (``algo.batch_size``) is bracketed so the path stays unambiguous.
        path = "".join(f"[{part}]" if "." in part else f".{part}" for part in loc).lstrip(".")
        lines.append(f"  {path or '<top>'}: {message}{_set_note(tuple(map(str, loc)), sets or {})}")
    return "\n".join(lines)


def _set_note(loc: tuple[str, ...], sets: dict[tuple[str, ...], str]) -> str:
    """`` (from --set K=V)`` where the problem's key is (or lies under) the last --set of it, `` (the section of
    --set K=V, --set ...)`` naming every --set whose key lies under the problem's section; else nothing."""
    given = [a for parts, a in sets.items() if loc[:len(parts)] == parts]
    if given:
        return f" (from --set {given[-1]})"
    within = [a for parts, a in sets.items() if loc and parts[:len(loc)] == loc]  # (which of them: not known)
    return f" (the section of {', '.join(f'--set {a}' for a in within)})" if within else ""


def _set_parts(path: str) -> list[str]:
    """A --set key's path as the sweep's keys: under ``overrides`` / ``search.parameters`` (and their per-algorithm
    maps) the rest of the path is one dotted config key."""
    parts = path.split(".")
    for i, part in enumerate(parts[:-1]):
        if part in _DOTTED_MAPS or (i > 0 and parts[i - 1] in _PER_ALGORITHM_MAPS):
            return parts[: i + 1] + [".".join(parts[i + 1:])]
    return parts


def set_flags(assignments: list[str] | None) -> str:
    """The ``--set`` flags of a command line that repeats ``assignments`` (`` --set K=V`` each, shell-quoted)."""
    return "".join(f" --set {shlex.quote(item)}" for item in assignments or [])


def apply_sets(data: dict, assignments: list[str]) -> dict[tuple[str, ...], str]:
    """Apply ``KEY.PATH=VALUE`` overrides (VALUE parsed as YAML) to raw sweep data, in place, through
    the project's one dotted setter (:func:`flashnav.yamlio.set_dotted`).

    Under ``overrides`` / ``search.parameters`` (and their per-algorithm maps) the rest of the path is
    one dotted config key: ``overrides.algo.batch_size=512`` sets the key ``algo.batch_size``.
    Returns the parts of each assignment's path -> the assignment (for :func:`format_errors`).
    """
    given = {}
    for assignment in assignments:
        try:
            path, value = parse_assignment(assignment, "--set")
            parts = _set_parts(path)
            set_dotted(data, parts, value, create=True, what="--set")
        except ValueError as exc:
            raise SweepError(str(exc)) from None
        given.pop(tuple(parts), None)  # (the last assignment of a key is the one in force: last in the dict)
        given[tuple(parts)] = assignment
    return given


def load_sweep(path: str | Path, sets: list[str] | None = None) -> Sweep:
    """Read, override and validate a sweep file; raises :class:`SweepError` with every problem."""
    path = Path(path)
    try:
        # flashnav's loader refuses duplicate keys: with plain safe_load the last `seeds:` would win silently
        data = load_yaml(path)
    except FileNotFoundError:
        raise SweepError(f"{path}: no such sweep file") from None
    except ValueError as exc:  # "<path>: not valid YAML: ..." (or a folder, or not UTF-8)
        raise SweepError(str(exc)) from None
    if not isinstance(data, dict):
        raise SweepError(f"{path}: a sweep is a mapping of keys, got {type(data).__name__}")
    given = apply_sets(data, sets or [])
    return parse_sweep(data, str(path), given)


def parse_sweep(data: dict, source: str = "<sweep>", sets: dict[tuple[str, ...], str] | None = None) -> Sweep:
    try:
        return Sweep.model_validate(data)
    except ValidationError as exc:
        raise SweepError(format_errors(exc, source, sets)) from None


def sweep_to_yaml(sweep: Sweep) -> str:
    """The sweep as YAML that :func:`load_sweep` reads back (defaults left out)."""
    data = sweep.model_dump(mode="json", exclude_defaults=True)
    data["seeds"] = sweep.seed_list
    return yaml.safe_dump(data, sort_keys=False)
