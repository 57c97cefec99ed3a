"""Families of generated maps: buildings of several kinds, seeded and reproducible.

``generate_family(name, seed)`` draws a map of one family (:data:`flashnav.names.MAP_FAMILIES`):

- ``rooms``: rows of rooms on both sides of corridors, a spine corridor joining them, a door from
  every room onto its corridor (and now and then one into the next room), a little furniture;
- ``offices``: an open-plan floor of desk islands between aisles, a row of closed offices with doors
  along one wall, plants and cabinets;
- ``halls``: an open hall with a regular grid of pillars (square or round; a few missing) and some
  benches;
- ``warehouses``: parallel rows of shelving racks with aisles and cross aisles, a loading area
  cluttered with pallets and boxes;
- ``mazes``: a maze of narrow corridors (a random spanning tree of a grid of cells, with a few loops);
- ``clutter``: the bundled maps' kind (:func:`flashnav.maps.clutter.generate_map`).

Sizes are drawn in [6, 30] m per side and resolutions from ``RESOLUTIONS`` (0.025-0.1 m) unless
given. Every passage (door, corridor, aisle, gap) is at least ``2 (robot_radius + margin)`` wide plus
two cells for rasterisation; loose furniture keeps that distance from everything else, so it never
closes a passage; and a final pass fills any pocket of free space that a disc of ``robot_radius``
cannot reach from the largest region (:func:`flashnav.maps.clutter.connect_free_space`), so the free
space for the robot is one connected region. Same arguments -> bit-identical map (numpy's PCG64,
seeded by the seed and the family's name). The layouts live in :mod:`flashnav.maps.family_layouts`,
drawn on a :class:`~flashnav.maps.canvas.Canvas`.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import zlib

import numpy as np

from flashnav.maps import family_layouts
from flashnav.maps.canvas import Canvas
from flashnav.maps.clutter import BORDER_M, connect_free_space, generate_map
from flashnav.maps.grid import MAX_CELLS, OccupancyMap
from flashnav.names import MAP_FAMILIES, VALIDATION_SEEDS, check_name

SIZE_RANGE = (6.0, 30.0)  # metres per side, drawn uniformly (rounded to 0.1 m) unless given
RESOLUTIONS = (0.025, 0.05, 0.075, 0.1)  # metres per cell, drawn uniformly unless given
#: Seeds from here up are reserved for validation and held-out benchmark suites: training never
#: draws them (:func:`check_training_seed`; ``maps: {family: ...}`` in a training config). The ranges
#: themselves are defined once in :mod:`flashnav.names`.
RESERVED_SEED_START = VALIDATION_SEEDS[0]


def check_training_seed(seed: int) -> int:
    """``seed`` if a training run may generate a map with it, else a ValueError naming it."""
    if seed >= RESERVED_SEED_START:
        raise ValueError(f"map seed {seed} is reserved for validation and held-out suites (seeds >= "
                         f"{RESERVED_SEED_START}); training maps use lower seeds")
    return seed


#: within :func:`reuse_generated_maps`: the maps made so far, by their arguments (None outside it)
_REUSED: dict[tuple, OccupancyMap] | None = None


@contextlib.contextmanager
def reuse_generated_maps():
    """Within this block :func:`generate_family` gives the same map object again for the same arguments instead of
    drawing it anew (an :class:`OccupancyMap` is immutable, its derived fields cached read-only), so a caller that
    resolves one map set several times - a sweep checking each searched point's training config before Ray starts
    - pays for each map once. Outside it every call draws its map. Nested blocks share the outer one's maps."""
    global _REUSED
    outer = _REUSED
    _REUSED = {} if outer is None else outer
    try:
        yield
    finally:
        _REUSED = outer


def generate_family(family: str, seed: int, *, size: tuple[float, float] | None = None,
                    resolution: float | None = None, robot_radius: float = 0.3, margin: float = 0.1,
                    name: str | None = None) -> OccupancyMap:
    """A map of ``family``, reproducibly (the same object again for the same arguments inside
    :func:`reuse_generated_maps`).

    Args:
        family: one of :data:`flashnav.names.MAP_FAMILIES`.
        seed: random seed (>= 0); the same arguments give a bit-identical map.
        size: (width, height) metres; drawn in ``SIZE_RANGE`` per side if None.
        resolution: metres per cell; drawn from ``RESOLUTIONS`` if None.
        robot_radius: radius (metres) of the disc every passage must fit: the robot's circumscribed
            radius plus the start clearance (0.3 for the TurtleBot2, 0.55 for the Go2).
        margin: extra free width (metres) on each side of that disc in the narrowest passage.
        name: the map's name (default ``<family>_<seed>``).

    Returns:
        An ``OccupancyMap`` (origin (0, 0)) whose free space for ``robot_radius`` is one connected region.
    """
    if _REUSED is None:
        return _draw_family(family, seed, size, resolution, robot_radius, margin, name)
    key = (family, seed, None if size is None else tuple(size), resolution, robot_radius, margin, name)
    if key not in _REUSED:
        _REUSED[key] = _draw_family(family, seed, size, resolution, robot_radius, margin, name)
    return _REUSED[key]


def _draw_family(family: str, seed: int, size, resolution, robot_radius: float, margin: float,
                 name: str | None) -> OccupancyMap:
    """:func:`generate_family`'s map, drawn."""
    check_name("map family", family, MAP_FAMILIES)
    if isinstance(seed, bool) or not (isinstance(seed, numbers.Integral) and seed >= 0):
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not (robot_radius > 0 and margin >= 0):
        raise ValueError(f"robot_radius must be > 0 and margin >= 0 metres, got {robot_radius}, {margin}")
    rng = np.random.default_rng([int(seed), zlib.crc32(family.encode())])
    if size is None:
        size = tuple(round(float(rng.uniform(*SIZE_RANGE)), 1) for _ in range(2))
    if resolution is None:
        resolution = float(rng.choice(RESOLUTIONS))
    width, height = size
    for label, v in (("width", width), ("height", height), ("resolution", resolution)):
        if not (isinstance(v, numbers.Real) and math.isfinite(v) and v > 0):
            raise ValueError(f"{label} must be a positive number of metres, got {v!r}")
    if (width / resolution) * (height / resolution) > MAX_CELLS:  # before the canvas is allocated
        raise ValueError(f"a {width:g} x {height:g} m map at {resolution:g} m a cell has more than {MAX_CELLS:,} "
                         f"cells; the families use 0.025-0.1 m")
    name = name or f"{family}_{seed}"
    need = 2 * BORDER_M + 2 * (2 * (robot_radius + margin) + 2 * resolution)
    if min(width, height) < need:
        raise ValueError(f"a {width:g} x {height:g} m {family} map is too small for a robot of radius "
                         f"{robot_radius} m (needs at least {need:.2f} m per side)")
    if family == "clutter":
        return generate_map(width, height, resolution, int(rng.integers(2**31)), robot_radius=robot_radius,
                            density=float(rng.uniform(0.1, 0.2)), margin=margin, name=name)
    canvas = Canvas(width, height, resolution, robot_radius, margin)
    getattr(family_layouts, family)(canvas, rng)
    occupied = connect_free_space(canvas.occupied, resolution, robot_radius)
    grid = OccupancyMap(occupied, resolution, (0.0, 0.0), name)
    grid.check_free_space(robot_radius, what=f"a {robot_radius} m disc")
    return grid
