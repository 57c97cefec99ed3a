"""The maps a training run evaluates on when they are not its training maps (``eval.maps``).

``eval.maps`` takes what ``maps`` takes for files (a directory, a glob pattern or a list of ROS map YAML
files, loaded by :func:`flashnav.maps.bundled.resolve_maps`), or ``validation``: the generated
validation suite, ``K`` maps per family (``eval.maps_per_family``), map ``j`` of family ``f`` being
``generate_family(f, VALIDATION_SEEDS[0] + j)`` (seeds 800000 .. 800000 + K - 1 for every family; the
family's name also seeds the generator, so no two maps are alike). They are exactly the maps of the
command that the benchmark README gives for the validation suite
(``python -m flashnav.maps.generate --family all --count K --seed 800000``), for the TurtleBot2 (whose
passages are drawn for its 0.3 m disc; another robot's suite is drawn for its own disc, as its training
maps are). A larger ``K`` keeps the first maps of a smaller one. The families are the training stream's
(``maps.family``, each once, in its order) when the run trains on generated maps, else all of
:data:`flashnav.names.MAP_FAMILIES`; the same for every run and trial of a configuration, so their
results compare.

The benchmark suites stay untouched until the final measurement (``flashnav/maps/data/benchmark/README.md``:
nothing is tuned on them, and a run's best policy is picked by these evaluations): ``eval.maps`` refuses the
committed ``heldout`` and ``real`` folders (by name or by path) and any map named ``<family>_<seed>`` with a
held-out seed (``>= HELDOUT_SEEDS_FROM``), wherever the file lies.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from typing import Any

from flashnav.maps.families import generate_family
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.stream import GeneratedMaps, generation_radius
from flashnav.names import BENCHMARK_SUITES, HELDOUT_SEEDS_FROM, MAP_FAMILIES, VALIDATION_SEEDS

#: ``eval.maps: validation``: the generated validation suite.
VALIDATION = "validation"
#: Most maps per family the validation seed range holds.
MAX_PER_FAMILY = VALIDATION_SEEDS[1] - VALIDATION_SEEDS[0] + 1
_GENERATED_NAME = re.compile(rf"({'|'.join(MAP_FAMILIES)})_(\d+)")


def benchmark_dir() -> Path:
    """The folder of the committed benchmark suites (``flashnav/maps/data/benchmark``)."""
    return Path(str(resources.files("flashnav") / "maps" / "data" / "benchmark"))


def check_eval_maps_value(value: Any) -> Any:
    """``eval.maps`` as given, unless it names a benchmark suite (a ValueError naming ``eval.maps``)."""
    for item in [value] if isinstance(value, str) else (value or []):
        if isinstance(item, str) and item.strip() in BENCHMARK_SUITES:
            raise ValueError(f"eval.maps: {item.strip()!r} is a benchmark suite, kept for the final measurement "
                             f"(flashnav eval POLICY --maps {item.strip()}); evaluate during training on "
                             f"{VALIDATION!r} or on map files of your own")
    if isinstance(value, list) and not value:
        raise ValueError("eval.maps: an empty list names no map (None = the training maps)")
    return value


def spread_episodes(episodes: int, num_maps: int) -> list[int]:
    """Episodes per map when ``episodes`` slots are spread over ``num_maps`` maps: ``episodes // num_maps``
    each, and one more for each of the first ``episodes % num_maps`` maps (in the maps' order). A ValueError
    naming ``eval.episodes`` when there are fewer episodes than maps (every map gets one)."""
    if episodes < num_maps:
        raise ValueError(f"eval.episodes = {episodes} is fewer than the {num_maps} evaluation maps (eval.maps): "
                         "every map needs an episode")
    base, extra = divmod(episodes, num_maps)
    return [base + (m < extra) for m in range(num_maps)]


def validation_seeds(families: list[str] | tuple[str, ...], per_family: int) -> list[tuple[str, int]]:
    """(family, seed) of every map of the validation suite, family by family (see the module docstring)."""
    if not 0 < per_family <= MAX_PER_FAMILY:
        raise ValueError(f"eval.maps_per_family must be in [1, {MAX_PER_FAMILY}], got {per_family}")
    return [(f, VALIDATION_SEEDS[0] + j) for f in families for j in range(per_family)]


def validation_families(training_families: list[str] | None) -> list[str]:
    """The suite's families: the training stream's, each once in its order; all families without one."""
    return list(dict.fromkeys(training_families)) if training_families else list(MAP_FAMILIES)


def _benchmark_suite_of(path: Path) -> str | None:
    """The benchmark suite whose committed folder holds ``path``, if any."""
    try:
        rel = path.resolve().relative_to(benchmark_dir().resolve())
    except ValueError:
        return None
    return rel.parts[0] if rel.parts and rel.parts[0] in BENCHMARK_SUITES else None


def check_not_benchmark(grids: list[OccupancyMap], key: str = "eval.maps") -> None:
    """A ValueError naming ``key`` (``eval.maps``, or the training ``maps``) and the map when one of
    ``grids`` is a benchmark suite's map or a generated map with a held-out seed."""
    instead = ("evaluate during training on 'validation' or on maps of your own" if key == "eval.maps" else
               "train on generated maps (family:...) or on maps of your own")
    for g in grids:
        suite = _benchmark_suite_of(Path(g.source)) if g.source else None
        if suite is not None:
            raise ValueError(f"{key}: {g.source} is a map of the {suite!r} benchmark suite, kept for the final "
                             f"measurement; {instead}")
        match = _GENERATED_NAME.fullmatch(g.name)
        if match and int(match.group(2)) >= HELDOUT_SEEDS_FROM:
            raise ValueError(f"{key}: map {g.name!r} ({g.source or 'no file'}) has a held-out seed "
                             f"(>= {HELDOUT_SEEDS_FROM}), kept for the final measurement; validation maps take "
                             f"seeds {VALIDATION_SEEDS[0]}-{VALIDATION_SEEDS[1]}")


def resolve_eval_maps(value: str | list[str], per_family: int, training_families: list[str] | None,
                      robot_radius: float, default_map: str) -> tuple[tuple[OccupancyMap, ...], dict[str, Any]]:
    """The evaluation maps ``eval.maps = value`` names, and their record for ``config.yaml``.

    Args:
        value: ``validation``, or what :func:`flashnav.maps.bundled.resolve_maps` takes (files).
        per_family: ``eval.maps_per_family`` (the validation suite's K).
        training_families: ``maps.family`` of a run on generated maps, else None.
        robot_radius: the disc the validation maps' passages fit (metres; ``generation_radius(robot)``).
        default_map: the preset's bundled map (what resolve_maps takes for a None entry).

    Returns:
        ``(grids, record)``: the maps in order, and ``{"suite": "validation", "families", "seeds",
        "maps_per_family"}`` or ``{"files": [...]}``.

    Raises:
        ValueError naming ``eval.maps`` (a benchmark suite's map, a held-out seed, a bad path).
    """
    from flashnav.maps.bundled import resolve_maps

    check_eval_maps_value(value)
    if value == VALIDATION:
        families = validation_families(training_families)
        pairs = validation_seeds(families, per_family)
        grids = tuple(generate_family(f, seed, robot_radius=robot_radius) for f, seed in pairs)
        record = {"suite": VALIDATION, "families": families, "maps_per_family": per_family,
                  "seeds": sorted({seed for _, seed in pairs})}
        return grids, record
    try:
        grids = tuple(resolve_maps(value, default_map))
    except (ValueError, FileNotFoundError, TypeError) as exc:
        raise ValueError(f"eval.maps = {value!r}: {exc}") from None
    check_not_benchmark(list(grids))
    return grids, {"files": [str(g.source) if g.source else g.name for g in grids]}


__all__ = ["VALIDATION", "benchmark_dir", "check_eval_maps_value", "check_not_benchmark", "load_eval_maps", "resolve_eval_maps",
           "spread_episodes", "validation_families", "validation_seeds"]


def load_eval_maps(config, robot) -> tuple[tuple[OccupancyMap, ...] | None, dict[str, Any] | None]:
    """A TrainConfig's ``eval.maps`` resolved for ``robot`` (its preset) with :func:`resolve_eval_maps`:
    (maps, record), checked to give every map an episode; (None, None) for the training maps."""
    default = type(config.eval).model_fields["maps_per_family"].default  # a stored config.yaml holds the default
    if config.eval.maps_per_family != default and config.eval.maps != "validation":  # ignored: say so, not drop it
        raise ValueError(f"eval.maps_per_family={config.eval.maps_per_family} goes with eval.maps: validation "
                         f"(--eval-maps validation); eval.maps is {config.eval.maps!r}")
    if config.eval.maps is None:
        return None, None
    families = config.maps.family if isinstance(config.maps, GeneratedMaps) else None
    grids, record = resolve_eval_maps(config.eval.maps, config.eval.maps_per_family, families,
                                      generation_radius(robot), robot.map)
    spread_episodes(config.eval.episodes, len(grids))  # every evaluation map gets an episode
    return grids, record

