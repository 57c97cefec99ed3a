"""Fields derived from an occupancy map: computed once per map, cached on it, read by everyone.

LiDAR (:mod:`flashnav.sim.raycast`, ``raycast_numba``, ``raycast_torch``), collision
(:mod:`flashnav.sim.collision`), start/goal sampling (:mod:`flashnav.sim.sampling`) and the oracle
(:mod:`flashnav.sim.oracle`) all read their distance fields, free configuration spaces and connected
components from here, so two consumers of one map share one computation.

Every field depends only on the occupancy and the resolution, never on the origin: a map and its
re-centred copy (:meth:`~flashnav.maps.grid.OccupancyMap.shifted`) share one cache. Cached arrays
are read-only. Keys that depend on a footprint take its radius in metres (rounded to 1e-9 m so that
float noise does not split a cache entry).

Padded fields are [H + 2 pad, W + 2 pad]: the map inside ``pad`` occupied cells, so a kernel near
the boundary needs no bounds checks.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from scipy import ndimage

#: Occupied cells around the map in the padded fields; >= 2 so that a float64 landing point a hair
#: outside the map (after a jump that ends on the boundary) still indexes an occupied pad cell.
PAD = 2
SECTORS = 32  # directions of the directional safe-distance field (cone_field)
REACH = 63  # cells: the cone field's cap; larger gained nothing measurable and costs build time
#: maps with more padded cells than this get the isotropic cone field (one sector, built by an EDT):
#: the directional one would take S bytes per cell and seconds to build
MAX_CONE_CELLS = 1 << 18


def cached(grid, key: tuple, build: Callable[[], Any]) -> Any:
    """``grid``'s cached value for ``key``, built by ``build()`` on first use (numpy results are
    made read-only: callers share them)."""
    cache = grid._cache
    if key not in cache:
        value = build()
        for part in value if isinstance(value, tuple) else (value,):
            if isinstance(part, np.ndarray):
                part.setflags(write=False)
        cache[key] = value
    return cache[key]


def _radius_key(radius: float) -> float:
    return round(float(radius), 9)


# ---- isotropic distances ---------------------------------------------------------------------------
def centre_distance(grid) -> np.ndarray:
    """[H, W] float64 metres: Euclidean distance from each cell centre to the nearest occupied
    cell centre, the outside of the map counting as occupied (0 on occupied cells)."""

    def build():
        free = np.pad(~grid.occupied, 1, constant_values=False)
        return ndimage.distance_transform_edt(free)[1:-1, 1:-1] * grid.resolution

    return cached(grid, ("centre_distance",), build)


def clearance(grid) -> np.ndarray:
    """[H, W] float64 metres: a lower bound on the distance from each cell centre to the nearest
    occupied cell square (or the map boundary); exact to within (sqrt(2) - 1) / 2 cells."""

    def build():
        c = np.maximum(centre_distance(grid) - grid.resolution * math.sqrt(0.5), 0.0)
        c[grid.occupied] = 0.0
        return c

    return cached(grid, ("clearance",), build)


def free_space(grid, radius: float) -> np.ndarray:
    """[H, W] bool: cells whose centre is farther than ``radius`` metres from any obstacle (the
    configuration space of a disc of that radius, sampled at cell centres)."""
    return cached(grid, ("free_space", _radius_key(radius)), lambda: clearance(grid) > radius)


def components(grid, radius: float) -> tuple[np.ndarray, int]:
    """4-connected components of ``free_space(radius)``: (labels [H, W] int32, count); label 0 is
    'not free'."""

    def build():
        labels, count = ndimage.label(free_space(grid, radius))
        return labels.astype(np.int32), int(count)

    return cached(grid, ("components", _radius_key(radius)), build)


def component_cells(grid, radius: float, min_cells: int) -> tuple[np.ndarray, ...]:
    """The cells of the components of ``free_space(radius)`` with at least ``min_cells`` cells (all
    of the largest ones if none has), grouped by component: (rows [M], cols [M] int64, first [M]
    (index of the first cell of the cell's component), count [M] (cells in it))."""

    def build():
        labels, count = components(grid, radius)
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        sizes[0] = 0
        keep = sizes >= min_cells
        if not keep.any():
            keep = sizes == sizes.max()
        rows, cols = np.nonzero(keep[labels])
        comp = labels[rows, cols]
        order = np.argsort(comp, kind="stable")  # cells of one component are contiguous
        rows, cols, comp = rows[order], cols[order], comp[order]
        _, first, counts = np.unique(comp, return_index=True, return_counts=True)
        return rows, cols, np.repeat(first, counts), np.repeat(counts, counts)

    return cached(grid, ("component_cells", _radius_key(radius), int(min_cells)), build)


# ---- padded fields for the raycasters and collision ------------------------------------------------
def iso_field(occ: np.ndarray) -> np.ndarray:
    """[H, W] float64 cells for a padded occupancy grid: the exact distance between each closed cell
    square and the nearest occupied one (0 next to or on obstacles). With cell centres on the integer
    lattice, the distance between squares c and q is the distance from centre c to ``q + [-1, 1]^2``,
    whose nearest point to a lattice point is a lattice point (the centre of one of the 3 x 3 cells
    around q): so it is the EDT of the complement of the 8-neighbour dilation of the occupied set."""
    dilated = ndimage.binary_dilation(occ, structure=np.ones((3, 3), bool), border_value=1)
    return ndimage.distance_transform_edt(~dilated)


def square_distance(grid, pad: int = PAD) -> np.ndarray:
    """[H + 2 pad, W + 2 pad] float64 cells: :func:`iso_field` of ``grid.padded(pad)``."""
    return cached(grid, ("square_distance", pad), lambda: iso_field(grid.padded(pad)))


def safe_field(grid) -> np.ndarray:
    """[H + 2 PAD, W + 2 PAD] float32, cells: -1 on occupied cells (the pad included), else S(c), the
    exact distance from the closed cell square c to the nearest occupied square or the map boundary,
    i.e. a lower bound on the clearance of any point in c. It is tighter than
    ``centre_distance - sqrt(2) res`` by up to 0.41 cells next to axis-aligned walls. Rounded *down*
    to float32 so that it stays a lower bound."""

    def build():
        occ = grid.padded(PAD)
        s64 = square_distance(grid, PAD)
        s32 = s64.astype(np.float32)
        s32 = np.where(s32 > s64, np.nextafter(s32, np.float32(0)), s32).astype(np.float32)
        s32[occ] = -1.0
        return s32

    return cached(grid, ("safe_field",), build)


def clear_cells(grid, radius: float) -> np.ndarray:
    """[H + 2 PAD, W + 2 PAD] bool: cells every point of which is at least ``radius`` metres from
    any occupied square and the map boundary (``safe_field * resolution >= radius``), so a footprint
    of circumscribed radius ``radius`` centred there collides with nothing."""
    return cached(grid, ("clear_cells", _radius_key(radius)),
                  lambda: safe_field(grid).astype(np.float64) * grid.resolution >= radius)


def cone_field(grid, pad: int = PAD, sectors: int = SECTORS, reach: int = REACH) -> np.ndarray:
    """[S, H + 2 pad, W + 2 pad] uint8: the directional safe-distance field the exact raycasters
    jump by (0 = occupied, else 1 + floor(2 D) half cells, D capped at ``reach`` cells; see
    :mod:`flashnav.maps.fields_numba`). S = 1, the isotropic bound from :func:`square_distance`, for
    maps over MAX_CONE_CELLS padded cells. Built by numba, imported only when first needed."""
    occ = grid.padded(pad)
    if occ.size > MAX_CONE_CELLS:
        sectors = 1

    def build():
        iso = square_distance(grid, pad)
        if sectors == 1:
            field = (1 + np.minimum(np.floor(2.0 * iso), 2 * reach)).astype(np.uint8)[None]
            field[0][occ] = 0
            return field
        from flashnav.maps import fields_numba  # the first import may JIT-compile

        return fields_numba.build_cone_field(occ, iso, sectors, reach)

    return cached(grid, ("cone_field", pad, sectors, reach), build)
