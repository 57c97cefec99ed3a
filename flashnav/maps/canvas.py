"""A canvas for the map families' layouts (:mod:`flashnav.maps.family_layouts`): an occupancy grid
drawn in metres, with walls, openings and loose furniture that keeps clear of passages."""

from __future__ import annotations

import math

import numpy as np

from flashnav.maps.clutter import border_cells, bordered, grow, place

WALL = (0.1, 0.2)  # wall thickness range, metres


class Canvas:
    """An occupancy grid drawn in metres (x right, y up, origin at the lower-left corner).

    Obstacles cover every cell their shape overlaps, and openings free only the cells inside them,
    so a drawn gap is at most two cells narrower than asked: ``gap()`` adds them back.
    """

    def __init__(self, width_m: float, height_m: float, res: float, robot_radius: float, margin: float):
        self.res = res
        self.rows, self.cols = round(height_m / res), round(width_m / res)
        self.width, self.height = self.cols * res, self.rows * res
        self.half_gap = robot_radius + margin  # half the narrowest passage, metres
        self.border = border_cells(res) * res  # outer walls, metres
        self.occupied = bordered(self.rows, self.cols, border_cells(res))

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
        blocked = grow(self.occupied, spacing)
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
            place(self.occupied, blocked, (rows, cols), mask, spacing)
            placed += 1
        return placed
