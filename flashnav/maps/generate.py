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
randomness). Command line (writes a ROS map YAML + image)::

    python -m flashnav.maps.generate --width 10 --height 10 --seed 0 --robot-radius 0.3 --out map.yaml
"""

from __future__ import annotations

import argparse
import math
import numbers
import shlex
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

from flashnav.maps.grid import OccupancyMap

BORDER_M = 0.15  # border wall thickness, metres (3 cells at 0.05 m)
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
    if not 0 <= density < 0.5:
        raise ValueError(f"density must be in [0, 0.5), got {density}")
    rows, cols = round(height_m / resolution), round(width_m / resolution)
    border = max(2, round(BORDER_M / resolution))
    # Centre-to-centre cell distance between two obstacles: the free gap between the cell squares
    # (distance - 1 cell) must hold 2 * (radius + margin); one more cell absorbs grid rounding.
    spacing = math.ceil(2 * (robot_radius + margin) / resolution) + 2
    if min(rows, cols) < 2 * border + spacing + 1:
        raise ValueError(
            f"a {width_m} x {height_m} m map is too small for a robot of radius {robot_radius} m "
            f"(needs at least {(2 * border + spacing + 1) * resolution:.2f} m per side)"
        )
    occupied = np.zeros((rows, cols), dtype=bool)
    occupied[:border], occupied[-border:], occupied[:, :border], occupied[:, -border:] = True, True, True, True
    blocked = _grow(occupied, spacing)  # cells where no new obstacle cell may go

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
        occupied[window] |= shape
        filled += int(shape.sum())
        # Update `blocked` only near the new obstacle: farther cells are >= spacing away from it.
        pad = spacing + 1
        big = (slice(max(r0 - pad, 0), min(r0 + h + pad, rows)), slice(max(c0 - pad, 0), min(c0 + w + pad, cols)))
        local = np.zeros((big[0].stop - big[0].start, big[1].stop - big[1].start), dtype=bool)
        local[r0 - big[0].start : r0 - big[0].start + h, c0 - big[1].start : c0 - big[1].start + w] = shape
        blocked[big] |= _grow(local, spacing)

    occupied = connect_free_space(occupied, resolution, robot_radius)
    return OccupancyMap(occupied, resolution, (0.0, 0.0), name or f"generated_{width_m:g}x{height_m:g}_seed{seed}")


def _grow(mask: np.ndarray, cells: int) -> np.ndarray:
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


# ---- command line ----------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> None:
    """``python -m flashnav.maps.generate``: generate maps and write them as ROS map YAML + image files.
    One cluttered map (``--width --height --out FILE.yaml``), or ``--count`` maps of each of
    ``--family`` (seeds ``--seed`` to ``--seed + count - 1``; ``--out DIR``)."""
    from flashnav.names import MAP_FAMILIES

    p = argparse.ArgumentParser(prog="python -m flashnav.maps.generate", description=main.__doc__)
    p.add_argument("--family", help=f"map family, a comma-separated list of them, or 'all': {', '.join(MAP_FAMILIES)}")
    p.add_argument("--count", type=int, default=1, help="maps per family (default 1)")
    p.add_argument("--sheet", type=Path, help="with --family: also draw the maps into this contact sheet PNG")
    p.add_argument("--width", type=float, help="map width, metres (with --family: drawn in 6-30 m if omitted)")
    p.add_argument("--height", type=float, help="map height, metres (with --family: drawn if omitted)")
    p.add_argument("--resolution", type=float,
                   help="metres per cell (default 0.05; with --family: drawn in 0.025-0.1 m if omitted)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--robot-radius", type=float, default=0.3,
                   help="radius of the disc every passage must fit, metres: circumscribed radius + clearance")
    p.add_argument("--density", type=float, default=0.16, help="target occupied fraction of the interior")
    p.add_argument("--margin", type=float, default=0.1, help="extra passage width on each side of the disc, metres")
    p.add_argument("--format", choices=("pgm", "png"), default="pgm", help="image format (default pgm)")
    p.add_argument("--out", type=Path, required=True,
                   help="output YAML path, the image next to it (with --family: a directory)")
    a = p.parse_args(argv)
    if a.family:
        _write_families(p, a, MAP_FAMILIES)
        return
    if a.width is None or a.height is None:
        p.error("--width and --height are required without --family")
    a.resolution = 0.05 if a.resolution is None else a.resolution
    grid = generate_map(a.width, a.height, a.resolution, a.seed, robot_radius=a.robot_radius,
                        density=a.density, margin=a.margin, name=a.out.stem)
    # Write the full command (defaults included) so the file can be regenerated bit for bit.
    command = shlex.join([
        "python", "-m", "flashnav.maps.generate", "--width", f"{a.width:g}", "--height", f"{a.height:g}",
        "--resolution", f"{a.resolution:g}", "--seed", str(a.seed), "--robot-radius", f"{a.robot_radius:g}",
        "--density", f"{a.density:g}", "--margin", f"{a.margin:g}", "--format", a.format, "--out", str(a.out),
    ])
    border = max(2, round(BORDER_M / a.resolution))
    interior = grid.occupied[border:-border, border:-border].mean()
    _save(grid, a.out, a.format, a.robot_radius, command,
          f"occupied {grid.occupied.mean():.1%} (interior inside the border walls: {interior:.1%})")


def _save(grid: OccupancyMap, out: Path, fmt: str, robot_radius: float, command: str, occupied: str) -> None:
    from flashnav.maps.ros import save_ros_map

    labels, count = grid.components(robot_radius)
    comment = (
        f"Generated by FlashNav's seeded map generator (flashnav/maps/generate.py):\n  {command}\n"
        f"{grid.shape[1]} x {grid.shape[0]} cells; {occupied};\nfree space for a {robot_radius:g} m disc: "
        f"{(labels > 0).mean():.1%} of the cells, in {count} connected component(s)."
    )
    path = save_ros_map(grid, out, fmt, comment=comment)
    print(f"wrote {path} ({grid!r})", file=sys.stderr)


def _write_families(p: argparse.ArgumentParser, a: argparse.Namespace, known: tuple[str, ...]) -> None:
    """``--family``: ``--count`` maps per family into the directory ``--out``, named <family>_<seed>."""
    from flashnav.maps.families import generate_family
    from flashnav.names import check_name

    families = list(known) if a.family == "all" else [f.strip() for f in a.family.split(",")]
    try:
        for f in families:
            check_name("map family", f, known)
    except ValueError as exc:
        p.error(str(exc))
    if a.count < 1 or a.seed < 0:
        p.error(f"--count must be >= 1 and --seed >= 0, got {a.count} and {a.seed}")
    if (a.width is None) != (a.height is None):
        p.error("give both --width and --height, or neither")
    if a.out.suffix in (".yaml", ".yml"):
        p.error(f"--out {a.out}: with --family, --out is a directory")
    a.out.mkdir(parents=True, exist_ok=True)
    size = None if a.width is None else (a.width, a.height)
    sheet: dict[str, list[OccupancyMap]] = {}
    for family in families:
        for seed in range(a.seed, a.seed + a.count):
            grid = generate_family(family, seed, size=size, resolution=a.resolution, robot_radius=a.robot_radius,
                                   margin=a.margin)
            args = ["python", "-m", "flashnav.maps.generate", "--family", family, "--seed", str(seed)]
            if size:
                args += ["--width", f"{a.width:g}", "--height", f"{a.height:g}"]
            if a.resolution is not None:
                args += ["--resolution", f"{a.resolution:g}"]
            args += ["--robot-radius", f"{a.robot_radius:g}", "--margin", f"{a.margin:g}", "--format", a.format,
                     "--out", str(a.out)]
            _save(grid, a.out / f"{grid.name}.yaml", a.format, a.robot_radius, shlex.join(args),
                  f"{grid.width_m:g} x {grid.height_m:g} m at {grid.resolution:g} m; occupied {grid.occupied.mean():.1%}")
            sheet.setdefault(family, []).append(grid)
    if a.sheet:
        from flashnav.viz import draw_map_sheet

        print(f"wrote {draw_map_sheet(sheet, a.sheet)}", file=sys.stderr)


if __name__ == "__main__":
    main()
