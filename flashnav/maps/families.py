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
- ``clutter``: the bundled maps' kind (:func:`flashnav.maps.generate.generate_map`).

Sizes are drawn in [6, 30] m per side and resolutions from ``RESOLUTIONS`` (0.025-0.1 m) unless
given. Every passage (door, corridor, aisle, gap) is at least ``2 (robot_radius + margin)`` wide plus
two cells for rasterisation; loose furniture keeps that distance from everything else, so it never
closes a passage; and a final pass fills any pocket of free space that a disc of ``robot_radius``
cannot reach from the largest region (:func:`flashnav.maps.generate.connect_free_space`), so the free
space for the robot is one connected region. Same arguments -> bit-identical map (numpy's PCG64,
seeded by the seed and the family's name). The layouts live in :mod:`flashnav.maps.family_layouts`.
"""

from __future__ import annotations

import math
import numbers
import zlib

import numpy as np
from scipy import ndimage

from flashnav.maps.grid import OccupancyMap
from flashnav.names import MAP_FAMILIES, check_name

SIZE_RANGE = (6.0, 30.0)  # metres per side, drawn uniformly (rounded to 0.1 m) unless given
RESOLUTIONS = (0.025, 0.05, 0.075, 0.1)  # metres per cell, drawn uniformly unless given
WALL = (0.1, 0.2)  # wall thickness range, metres
BORDER_M = 0.15  # outer walls, metres (at least 2 cells)


class Canvas:
    """An occupancy grid drawn in metres (x right, y up, origin at the lower-left corner).

    Obstacles cover every cell their shape overlaps, and openings free only the cells inside them,
    so a drawn gap is at most two cells narrower than asked: ``gap()`` adds them back.
    """

    def __init__(self, width_m: float, height_m: float, res: float, robot_radius: float, margin: float):
        self.res = res
        self.rows, self.cols = round(height_m / res), round(width_m / res)
        self.width, self.height = self.cols * res, self.rows * res
        self.occupied = np.zeros((self.rows, self.cols), dtype=bool)
        self.half_gap = robot_radius + margin  # half the narrowest passage, metres
        self.border = max(2, round(BORDER_M / res)) * res
        b = round(self.border / res)
        self.occupied[:b], self.occupied[-b:], self.occupied[:, :b], self.occupied[:, -b:] = True, True, True, True

    def gap(self, extra: float = 0.0) -> float:
        """The narrowest passage width, metres (plus ``extra``), with the rasterisation cells added."""
        return 2 * self.half_gap + 2 * self.res + extra

    def _span(self, lo: float, hi: float, size: int, inner: bool) -> slice:
        if inner:  # cells entirely inside [lo, hi]
            a, b = math.ceil(lo / self.res - 1e-9), math.floor(hi / self.res + 1e-9)
        else:  # cells overlapping it, at least one
            a, b = math.floor(lo / self.res + 1e-9), math.ceil(hi / self.res - 1e-9)
            b = max(b, a + 1)
        return slice(min(max(a, 0), size), min(max(b, 0), size))

    def rect(self, x0: float, y0: float, x1: float, y1: float, value: bool = True) -> None:
        """Fill (``value`` True: every overlapped cell) or clear (False: every cell inside) a rectangle."""
        inner = not value
        self.occupied[self._span(y0, y1, self.rows, inner), self._span(x0, x1, self.cols, inner)] = value

    def _disc_cells(self, cx: float, cy: float, radius: float) -> tuple[slice, slice, np.ndarray]:
        """The cells a disc overlaps (approximately: centre within r + res/sqrt2): (rows, cols, mask)."""
        r = radius + self.res * math.sqrt(0.5)
        rows = self._span(cy - r, cy + r, self.rows, False)
        cols = self._span(cx - r, cx + r, self.cols, False)
        yy = (np.arange(rows.start, rows.stop) + 0.5) * self.res - cy
        xx = (np.arange(cols.start, cols.stop) + 0.5) * self.res - cx
        return rows, cols, yy[:, None] ** 2 + xx[None, :] ** 2 <= r * r

    def disc(self, cx: float, cy: float, radius: float) -> None:
        """Fill every cell the disc overlaps."""
        rows, cols, mask = self._disc_cells(cx, cy, radius)
        self.occupied[rows, cols] |= mask

    def scatter(self, rng: np.random.Generator, count: int, box: tuple[float, float] = (0.4, 1.2),
                disc: tuple[float, float] = (0.15, 0.5), p_disc: float = 0.3, attempts: int = 400,
                region: tuple[float, float, float, float] | None = None) -> int:
        """Place up to ``count`` loose boxes (side in ``box``) and discs (radius in ``disc``), each at
        least a passage width from every other obstacle, so none closes a passage; inside ``region``
        (x0, y0, x1, y1) if given. Returns how many were placed."""
        spacing = math.ceil(self.gap() / self.res)
        blocked = ndimage.distance_transform_edt(~self.occupied) < spacing
        x0, y0, x1, y1 = region or (0.0, 0.0, self.width, self.height)
        placed = 0
        for _ in range(attempts):
            if placed >= count:
                break
            if rng.random() < p_disc:
                r = rng.uniform(*disc)
                rows, cols, mask = self._disc_cells(rng.uniform(x0 + r, max(x1 - r, x0 + r)),
                                                    rng.uniform(y0 + r, max(y1 - r, y0 + r)), r)
            else:
                w, h = rng.uniform(*box), rng.uniform(*box)
                bx, by = rng.uniform(x0, max(x1 - w, x0)), rng.uniform(y0, max(y1 - h, y0))
                rows, cols = self._span(by, by + h, self.rows, False), self._span(bx, bx + w, self.cols, False)
                mask = np.ones((rows.stop - rows.start, cols.stop - cols.start), dtype=bool)
            if not mask.any() or (blocked[rows, cols] & mask).any():
                continue
            self.occupied[rows, cols] |= mask
            # farther cells are more than `spacing` away from the new obstacle: update near it only
            big = (slice(max(rows.start - spacing - 1, 0), min(rows.stop + spacing + 1, self.rows)),
                   slice(max(cols.start - spacing - 1, 0), min(cols.stop + spacing + 1, self.cols)))
            local = np.zeros((big[0].stop - big[0].start, big[1].stop - big[1].start), dtype=bool)
            local[rows.start - big[0].start: rows.stop - big[0].start,
                  cols.start - big[1].start: cols.stop - big[1].start] = mask
            blocked[big] |= ndimage.distance_transform_edt(~local) < spacing
            placed += 1
        return placed


def generate_family(family: str, seed: int, *, size: tuple[float, float] | None = None,
                    resolution: float | None = None, robot_radius: float = 0.3, margin: float = 0.1,
                    name: str | None = None) -> OccupancyMap:
    """A map of ``family``, reproducibly.

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
    from flashnav.maps import family_layouts
    from flashnav.maps.generate import connect_free_space, generate_map

    check_name("map family", family, MAP_FAMILIES)
    if not (isinstance(seed, numbers.Integral) and seed >= 0):
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
