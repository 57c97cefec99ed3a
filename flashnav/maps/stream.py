"""Fresh generated maps during training: ``maps: {family: rooms|[rooms, offices], count: K,
refresh_every: C, seed: S}`` in a config, ``--maps family:rooms,offices`` on the command line.

Set ``i`` (0, 1, 2, ...) holds K maps: map ``j`` of it is family ``families[j % F]`` drawn with seed
``S + i K + j`` (:func:`flashnav.maps.families.generate_family`), so no seed, hence no map, comes back
within a run. Set 0 is the run's first map set (and its fixed evaluation set); every C cycles
(vector steps) the training env swaps to the next set (:meth:`flashnav.sim.env.NavVecEnv.replace_maps`).
Seeds at or above :data:`flashnav.maps.families.RESERVED_SEED_START` are reserved for validation and
held-out benchmark suites: a configuration whose run could reach one is refused before it starts.

Generating a set takes seconds (a 30 x 30 m map at 0.025 m: 0.3-0.7 s to draw and 0.2-1.2 s for the
sampler's fields on the loaded 2-core machine; K maps per set), so :class:`MapStream` draws the next
set, and computes the fields the env will read (cached on each map), on a background thread while
training runs on the current one.
"""

from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable

from pydantic import Field, field_validator

from flashnav.config_base import KnownKeys
from flashnav.maps.families import RESERVED_SEED_START, SIZE_RANGE, check_training_seed, generate_family
from flashnav.machine import numba_threads
from flashnav.maps.grid import OccupancyMap
from flashnav.names import MAP_FAMILIES, parse_names

#: ``--maps family:rooms,offices``: the command line's form of generated maps.
FAMILY_PREFIX = "family:"


class GeneratedMaps(KnownKeys):
    """Maps generated during training instead of loaded from files (see the module docstring)."""

    family: list[str] = Field(description=f"map families ({', '.join(MAP_FAMILIES)}): a list, a comma list, or 'all'; "
                                          "a family named twice is drawn twice as often (mazes,mazes,rooms: 2 mazes "
                                          "to 1 rooms map in a set)")
    count: int = Field(16, gt=0, description="maps per set: the env's slots draw among them when they reset")
    refresh_every: int | None = Field(None, gt=0, description="cycles (vector steps) between new sets "
                                                              "(None = the first set for the whole run)")
    seed: int = Field(0, ge=0, description=f"seed of the first map; seeds stay below {RESERVED_SEED_START} "
                                           "(reserved for held-out suites)")

    @field_validator("family", mode="before")
    @classmethod
    def _families(cls, value: Any) -> Any:
        # anything but a string or a list is left to pydantic's type error
        return parse_names("map family", value, MAP_FAMILIES) if isinstance(value, (str, list)) else value

    def seeds(self, index: int) -> list[tuple[str, int]]:
        """(family, seed) of every map of set ``index``."""
        return [(self.family[j % len(self.family)], self.seed + index * self.count + j) for j in range(self.count)]

    def sets_needed(self, cycles: int) -> int:
        """Sets a run of ``cycles`` cycles draws (the first, then one every ``refresh_every``)."""
        return 1 if not self.refresh_every else 1 + (max(cycles, 1) - 1) // self.refresh_every

    def check_seeds(self, cycles: int) -> None:
        """A ValueError naming ``maps.seed`` when a run of ``cycles`` cycles would reach a held-out seed."""
        last = self.seed + self.sets_needed(cycles) * self.count - 1
        if last >= RESERVED_SEED_START:
            raise ValueError(
                f"maps.seed: a run of {cycles:,} cycles draws {self.sets_needed(cycles)} sets of {self.count} maps, "
                f"seeds {self.seed}-{last}; seeds from {RESERVED_SEED_START} up are reserved for validation and "
                "held-out suites (lower maps.seed, maps.count or the budget, or raise maps.refresh_every)")

    @property
    def goal_distance_max(self) -> float:
        """The largest diagonal a generated map can have (metres): one fixed scale for every set."""
        return math.hypot(SIZE_RANGE[1], SIZE_RANGE[1])


def parse_family_maps(value: Any) -> Any:
    """``"family:rooms,offices"`` -> the plain data of :class:`GeneratedMaps` (defaults filled, so
    ``maps.count=...`` overrides find their keys; validated with the rest of the config); anything
    else is returned as it is."""
    if isinstance(value, str) and value.startswith(FAMILY_PREFIX):
        defaults = {name: f.default for name, f in GeneratedMaps.model_fields.items() if name != "family"}
        return {"family": value[len(FAMILY_PREFIX):], **defaults}  # the comma list: GeneratedMaps parses it
    return value


def generation_radius(robot) -> float:
    """The disc every passage of a generated map fits (metres): circumscribed radius + start clearance."""
    return robot.footprint.circumscribed_radius + robot.episode.start_clearance


def generate_set(maps: GeneratedMaps, index: int, robot_radius: float) -> tuple[OccupancyMap, ...]:
    """The K maps of set ``index`` (bit-identical for the same arguments)."""
    out = []
    for family, seed in maps.seeds(index):
        check_training_seed(seed)
        out.append(generate_family(family, seed, robot_radius=robot_radius))
    return tuple(out)


class MapStream:
    """Sets 1, 2, ... of ``maps`` (set 0 is the run's first set, built when the run is resolved), each
    drawn on a background thread while the previous one trains. ``warm(grids)``, optional, runs on
    that thread after drawing: e.g. build a throwaway env so the fields the training env reads are
    computed (they are cached on each map) before the swap. ``sets``: how many sets the run uses
    (set 0 included; :meth:`GeneratedMaps.sets_needed`), so none is drawn past the last; None = no end."""

    def __init__(self, maps: GeneratedMaps, robot_radius: float,
                 warm: Callable[[tuple[OccupancyMap, ...]], Any] | None = None, background: bool = True,
                 sets: int | None = None):
        if not maps.refresh_every:
            raise ValueError("a MapStream needs maps.refresh_every (cycles between sets)")
        self.maps, self.robot_radius, self.warm, self.sets = maps, robot_radius, warm, sets
        self.index = 0  # the set in use
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="maps") if background else None
        self._next: Future | None = None
        self._prefetch()

    def due(self, cycle: int) -> bool:
        """Whether cycle ``cycle`` (1-based) starts on a new set: cycles 1 + C, 1 + 2C, ..."""
        return cycle > 1 and (cycle - 1) % self.maps.refresh_every == 0

    def _build(self, index: int) -> tuple[OccupancyMap, ...]:
        if self._pool is None:
            return self._generate(index)
        with numba_threads(1):  # the collector and learner own the cores
            return self._generate(index)

    def _generate(self, index: int) -> tuple[OccupancyMap, ...]:
        grids = generate_set(self.maps, index, self.robot_radius)
        if self.warm is not None:
            self.warm(grids)
        return grids

    def _prefetch(self) -> None:
        self._next = None
        if self._pool is not None and (self.sets is None or self.index + 1 < self.sets):
            self._next = self._pool.submit(self._build, self.index + 1)

    def take(self) -> tuple[OccupancyMap, ...]:
        """The next set (waiting for its thread if it is not ready yet); starts drawing the one after."""
        grids = self._next.result() if self._next is not None else self._build(self.index + 1)
        self.index += 1
        self._prefetch()
        return grids

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)  # a set being drawn finishes on its own
