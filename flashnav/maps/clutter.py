"""A seeded generator of cluttered indoor maps that a navigation policy can master.

The map is a rectangle of border walls holding random axis-aligned boxes, discs and straight wall
segments. Every obstacle is kept at least ``2 * (robot_radius + margin)`` metres of free space away
from every other obstacle and from the border walls. Obstacles are convex and never touch, so the
free configuration space of a disc of ``robot_radius`` (the complement of the obstacles grown by the
radius, which stay disjoint) is one connected region: any start can reach any goal, along a path that
only bends around single convex obstacles of at most ~2 m -- no corridors, no dead ends, no mazes.
A final pass fills any pocket the grid discretisation could still cut off (none in practice).

Obstacles are placed by random sequential placement with rejection until the interior (inside the
border walls) reaches the requested occupied fraction ``density`` or the attempts run out; with large
radii the spacing rule may saturate below ``density``.

Same arguments -> bit-identical map (numpy's PCG64 ``default_rng(seed)``; no other source of
randomness). The command line is :mod:`flashnav.maps.generate`::

    python -m flashnav.maps.generate --width 10 --height 10 --seed 0 --robot-radius 0.3 --out map.yaml
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from scipy import ndimage

from flashnav.maps.grid import OccupancyMap

BORDER_M = 0.15  # border wall thickness, metres (3 cells at 0.05 m; at least 2 cells: border_cells)
MAX_DENSITY = 0.5  # the occupied fraction a generated map stays below (``density`` in [0, MAX_DENSITY))
MAX_ATTEMPTS = 4000  # candidate obstacles tried before giving up on reaching ``density``
# Shape mix and sizes, metres, for a passage half-width (robot_radius + margin) of REFERENCE_HALF_GAP;
# sizes grow with the square root of the half-width so that wider passages still leave clutter. They
# stay small enough (<= ~2.5 m) that detours around any one obstacle stay short.
REFERENCE_HALF_GAP = 0.4
SHAPE_PROBS = {"box": 0.5, "disc": 0.3, "wall": 0.2}
BOX_SIDE = (0.5, 2.0)
DISC_RADIUS = (0.3, 0.9)
WALL_LENGTH = (1.0, 2.5)
WALL_THICKNESS = 0.2
# After SMALL_AFTER of the attempts, candidates shrink by SMALL_SCALE: small pillars fill the holes
# that big obstacles no longer fit into (random sequential placement saturates early otherwise).
SMALL_AFTER, SMALL_SCALE = 0.5, 0.5


def generate_map(
    width_m: float,
    height_m: float,
    resolution: float = 0.05,
    seed: int = 0,
    *,
    robot_radius: float = 0.3,
    density: float = 0.16,
    margin: float = 0.1,
    name: str | None = None,
) -> OccupancyMap:
    """Generate a cluttered indoor map, reproducibly.

    Args:
        width_m, height_m: map extent, metres (rounded to whole cells).
        resolution: metres per cell.
        seed: random seed; the same arguments give a bit-identical map.
        robot_radius: radius (metres) of the disc that must pass every passage; use the robot's
            circumscribed radius plus the start clearance.
        density: target occupied fraction of the interior (inside the border walls), in [0, 0.5).
        margin: extra free width (metres) on each side of the disc in the narrowest passage.
        name: the map's name (default ``generated_<W>x<H>_seed<seed>``).

    Returns:
        An ``OccupancyMap`` of ``[round(height_m / resolution), round(width_m / resolution)]`` cells,
        origin (0, 0), whose free space for ``robot_radius`` is one connected component.
    """
    for label, v in (("width_m", width_m), ("height_m", height_m), ("resolution", resolution)):
        if not (isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
            raise ValueError(f"{label} must be a positive number of metres, got {v!r}")
    if not (robot_radius >= 0 and margin >= 0):
        raise ValueError(f"robot_radius and margin must be >= 0 metres, got {robot_radius}, {margin}")
    if not 0 <= density < MAX_DENSITY:
        raise ValueError(f"density must be in [0, {MAX_DENSITY:g}), got {density}")
    rows, cols = round(height_m / resolution), round(width_m / resolution)
    border = border_cells(resolution)
    # Centre-to-centre cell distance between two obstacles: the free gap between the cell squares
    # (distance - 1 cell) must hold 2 * (radius + margin); one more cell absorbs grid rounding.
    spacing = math.ceil(2 * (robot_radius + margin) / resolution) + 2
    if min(rows, cols) < 2 * border + spacing + 1:
        raise ValueError(
            f"a {width_m} x {height_m} m map is too small for a robot of radius {robot_radius} m "
            f"(needs at least {(2 * border + spacing + 1) * resolution:.2f} m per side)"
        )
    occupied = bordered(rows, cols, border)
    blocked = grow(occupied, spacing)  # cells where no new obstacle cell may go

    rng = np.random.default_rng(seed)
    interior = (rows - 2 * border) * (cols - 2 * border)
    target = density * interior
    filled = 0
    kinds, probs = list(SHAPE_PROBS), np.array(list(SHAPE_PROBS.values()))
    size_scale = max(1.0, (robot_radius + margin) / REFERENCE_HALF_GAP) ** 0.5
    for attempt in range(MAX_ATTEMPTS):
        if filled >= target:
            break
        kind = kinds[rng.choice(len(kinds), p=probs)]
        scale = size_scale * (SMALL_SCALE if attempt >= SMALL_AFTER * MAX_ATTEMPTS else 1.0)
        r0, c0, shape = _shape(kind, rng, rows, cols, resolution / scale, resolution)
        h, w = shape.shape
        if r0 < 0 or c0 < 0 or r0 + h > rows or c0 + w > cols:
            continue
        window = (slice(r0, r0 + h), slice(c0, c0 + w))
        if (blocked[window] & shape).any():
            continue
        place(occupied, blocked, window, shape, spacing)
        filled += int(shape.sum())

    occupied = connect_free_space(occupied, resolution, robot_radius)
    return OccupancyMap(occupied, resolution, (0.0, 0.0), name or f"generated_{width_m:g}x{height_m:g}_seed{seed}")


def border_cells(resolution: float) -> int:
    """The border walls' thickness in cells: ``BORDER_M`` at ``resolution`` (metres per cell), at least 2."""
    return max(2, round(BORDER_M / resolution))


def bordered(rows: int, cols: int, border: int) -> np.ndarray:
    """[rows, cols] bool: free but for ``border`` cells of wall along every edge."""
    occupied = np.zeros((rows, cols), dtype=bool)
    occupied[:border], occupied[-border:], occupied[:, :border], occupied[:, -border:] = True, True, True, True
    return occupied


def place(occupied: np.ndarray, blocked: np.ndarray, window: tuple[slice, slice], mask: np.ndarray,
          spacing: int) -> None:
    """Add an obstacle, in place: ``mask`` ([h, w] bool) into ``occupied[window]``, and to ``blocked``
    (the [H, W] cells where no new obstacle cell may go) every cell closer than ``spacing`` cells to
    it. Only cells near the obstacle are recomputed: farther ones are >= spacing away from it."""
    rows, cols = window
    pad = spacing + 1
    big = (slice(max(rows.start - pad, 0), min(rows.stop + pad, occupied.shape[0])),
           slice(max(cols.start - pad, 0), min(cols.stop + pad, occupied.shape[1])))
    occupied[window] |= mask
    local = np.zeros((big[0].stop - big[0].start, big[1].stop - big[1].start), dtype=bool)
    local[rows.start - big[0].start: rows.stop - big[0].start,
          cols.start - big[1].start: cols.stop - big[1].start] = mask
    blocked[big] |= grow(local, spacing)


def grow(mask: np.ndarray, cells: int) -> np.ndarray:
    """[H, W] bool: cells whose centre is closer than ``cells`` cell widths to a True cell of ``mask``."""
    if not mask.any():
        return np.zeros_like(mask)
    return ndimage.distance_transform_edt(~mask) < cells


def _shape(
    kind: str, rng: np.random.Generator, rows: int, cols: int, res: float, cell: float
) -> tuple[int, int, np.ndarray]:
    """A random obstacle: (row, col) of its bounding box's lower-left cell and its [h, w] bool mask.
    Sizes are drawn in metres and divided by ``res`` (the cell size over the size scale); the wall
    thickness is not scaled, so it uses the true cell size ``cell``."""
    if kind == "box":
        h = max(1, round(rng.uniform(*BOX_SIDE) / res))
        w = max(1, round(rng.uniform(*BOX_SIDE) / res))
        mask = np.ones((h, w), dtype=bool)
    elif kind == "disc":
        radius = rng.uniform(*DISC_RADIUS) / res  # in cells
        n = 2 * math.ceil(radius)
        centres = np.arange(n) - (n - 1) / 2.0
        mask = centres[:, None] ** 2 + centres[None, :] ** 2 <= radius**2
    else:  # straight wall segment, horizontal or vertical
        length = max(1, round(rng.uniform(*WALL_LENGTH) / res))
        thick = max(1, round(WALL_THICKNESS / cell))
        mask = np.ones((thick, length) if rng.random() < 0.5 else (length, thick), dtype=bool)
    h, w = mask.shape
    r0 = int(rng.integers(0, rows - h + 1)) if rows >= h else -1
    c0 = int(rng.integers(0, cols - w + 1)) if cols >= w else -1
    return r0, c0, mask


def connect_free_space(occupied: np.ndarray, resolution: float, robot_radius: float) -> np.ndarray:
    """Fill every pocket of free space that a disc of ``robot_radius`` cannot reach from the largest
    free-space component, so that any two free poses are joined.

    Args:
        occupied: [H, W] bool grid (row 0 = lowest y).
        resolution: metres per cell.
        robot_radius: disc radius, metres.

    Returns:
        [H, W] bool, a copy of ``occupied`` with the unreachable pockets filled; cells within reach
        of the largest component are untouched, so that component keeps its shape.
    """
    occupied = occupied.copy()
    for _ in range(3):
        # OccupancyMap freezes the array it is given: hand it a copy, we keep filling ours.
        labels, count = OccupancyMap(occupied.copy(), resolution).components(robot_radius)
        if count <= 1:
            break
        sizes = np.bincount(labels.ravel(), minlength=count + 1)[1:]
        main = labels == 1 + int(np.argmax(sizes))
        pockets = (labels > 0) & ~main
        # What the disc touches from the main component stays free; a pocket and the free cells its
        # disc would touch are filled. Spare one extra cell around the main reach for the clearance
        # bound's rounding.
        reach = ndimage.distance_transform_edt(~main) * resolution <= robot_radius + 2 * resolution
        pocket_reach = ndimage.distance_transform_edt(~pockets) * resolution <= robot_radius + resolution
        fill = pocket_reach & ~reach
        if not fill.any():
            fill = pockets  # a pocket right against the main reach: fill its own cells
        occupied |= fill
    return occupied
