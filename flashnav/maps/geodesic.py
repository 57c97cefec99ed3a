"""Start-goal pairs by path length in the free configuration space, computed once per map.

The geodesic distance between two cells is the length of the shortest 8-connected path between
their centres through the cells of :func:`flashnav.maps.fields.component_cells` (the cells the
episode sampler starts from), a diagonal step needing both cells beside it free (no corner
cutting). A Dijkstra from every start would cost seconds per reset on a large map; instead, a
seeded set of source cells (uniform over the cells) each keeps up to ``PAIRS / sources`` cells,
chosen at random, whose distance lies in the band. Each source's search visits about
pi (hi / resolution)^2 cells, so the number of sources is what ``VISIT_BUDGET`` affords (between
``MIN_SOURCES`` and ``MAX_SOURCES``): 256 at 0.05 m cells and a 5 m band, 64 at 0.025 m. A pair serves in both directions (the
distance is symmetric), so starts are the sources and their goals (with geodesic progress, goals are
the sources: :mod:`flashnav.sim.goal_fields`). Sampling is then an index into
a table on the device; building the table is one bounded Dijkstra per source (numba, parallel over
sources; :mod:`flashnav.maps.geodesic_numba`), cached on the map like every derived field.
"""

from __future__ import annotations

import math

import numpy as np

from flashnav.maps.fields import _radius_key, cached, component_cells

PAIRS = 32768  # pairs kept per map (each serves both ways)
VISIT_BUDGET = 8_000_000  # cells visited by all the sources' searches together
MIN_SOURCES, MAX_SOURCES = 32, 256
MAX_TRIES = 8  # sources tried, in multiples of the sources kept, before giving up on a map


def geodesic_pairs(grid, radius: float, min_cells: int, band: tuple[float, float],
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of cells of ``component_cells(grid, radius, min_cells)`` whose geodesic distance is in
    ``band`` = (lo, hi) metres.

    Returns:
        (start [K], goal [K]) int64 indices into the rows/cols of ``component_cells`` (K >= 1).

    Raises:
        ValueError naming the map when no pair exists among the sources tried (every cell, on maps
        with at most ``MAX_TRIES`` x sources cells, so then no pair exists at all).
    """
    lo, hi = float(band[0]), float(band[1])
    key = ("geodesic_pairs", _radius_key(radius), int(min_cells), round(lo, 9), round(hi, 9), int(seed))
    return cached(grid, key, lambda: _build(grid, radius, min_cells, lo, hi, seed))


def _build(grid, radius, min_cells, lo, hi, seed):
    from flashnav.maps import geodesic_numba  # the first import may JIT-compile

    rows, cols, _, _ = component_cells(grid, radius, min_cells)
    h, w = grid.shape
    free = np.zeros((h, w), dtype=bool)
    free[rows, cols] = True
    flat = rows * w + cols
    index = np.full(h * w, -1, dtype=np.int64)  # flat cell -> its index in component_cells
    index[flat] = np.arange(flat.size)
    res = grid.resolution
    ball = math.pi * (hi / res) ** 2
    sources = int(np.clip(VISIT_BUDGET / ball, MIN_SOURCES, MAX_SOURCES))
    per_source = math.ceil(PAIRS / sources)
    order = np.random.default_rng(seed).permutation(flat.size)
    tries = min(flat.size, MAX_TRIES * sources)
    starts, goals, found, tried = [], [], 0, 0
    while found < sources and tried < tries:
        batch = order[tried: min(tried + sources, tries)]
        tried += batch.size
        got, counts = geodesic_numba.band_pairs(free, flat[batch], lo / res, hi / res, per_source, seed)
        keep = np.nonzero(counts > 0)[0][: sources - found]
        found += keep.size
        for k in keep:
            starts.append(np.full(counts[k], batch[k], dtype=np.int64))
            goals.append(index[got[k, : counts[k]]])
    if not found:
        where = f"{grid.source}" if grid.source else f"map {grid.name!r}"
        scope = "from any cell" if tried == flat.size else f"from {tried} of its {flat.size} cells"
        raise ValueError(
            f"{where}: no start-goal pair with a path of {lo:g}-{hi:g} m through the free space of a "
            f"{radius:.3f} m disc {scope} (map {w} x {h} cells at {res} m); the map is too small or "
            f"too cluttered for this band: change episode.min_goal_distance / max_goal_distance")
    return np.concatenate(starts), np.concatenate(goals)
