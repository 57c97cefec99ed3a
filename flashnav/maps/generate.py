"""``python -m flashnav.maps.generate``: write generated maps as ROS map_server files.

One cluttered map of the bundled maps' kind (:mod:`flashnav.maps.clutter`)::

    python -m flashnav.maps.generate --width 10 --height 10 --seed 0 --robot-radius 0.3 --out map.yaml

or K maps of each of some families (:mod:`flashnav.maps.families`), with a contact sheet::

    python -m flashnav.maps.generate --family rooms,mazes --count 8 --seed 100 --out maps/ --sheet maps.png

Each file's YAML starts with the command that regenerates it bit for bit.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from flashnav.maps.clutter import BORDER_M, connect_free_space, generate_map  # noqa: F401 (the API of old)
from flashnav.maps.clutter import MAX_DENSITY, border_cells
from flashnav.maps.grid import OccupancyMap
from flashnav.names import seed_arg


# ---- command line ----------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> None:
    """``python -m flashnav.maps.generate``: generate maps and write them as ROS map YAML + image files.
    One cluttered map (``--width --height --out FILE.yaml``), or ``--count`` maps of each of
    ``--family`` (seeds ``--seed`` to ``--seed + count - 1``; ``--out DIR``)."""
    from flashnav.names import MAP_FAMILIES

    p = argparse.ArgumentParser(prog="python -m flashnav.maps.generate", description=main.__doc__)
    p.add_argument("--family", help=f"map family, a comma-separated list of them, or 'all': {', '.join(MAP_FAMILIES)}")
    p.add_argument("--count", type=int, default=None, help="with --family: maps per family (default 1)")
    p.add_argument("--sheet", type=Path, help="with --family: also draw the maps into this contact sheet PNG")
    p.add_argument("--width", type=float, help="map width, metres (with --family: drawn in 6-30 m if omitted)")
    p.add_argument("--height", type=float, help="map height, metres (with --family: drawn if omitted)")
    p.add_argument("--resolution", type=float,
                   help="metres per cell (default 0.05; with --family: drawn in 0.025-0.1 m if omitted)")
    p.add_argument("--seed", type=seed_arg, default=0, help="random seed (default 0)")
    p.add_argument("--robot-radius", type=float, default=0.3,
                   help="radius of the disc every passage must fit, metres: circumscribed radius + clearance")
    p.add_argument("--density", type=float,
                   help=f"without --family: target occupied fraction of the interior, in [0, {MAX_DENSITY:g}) "
                        "(default 0.16); the families draw their own")
    p.add_argument("--margin", type=float, default=0.1, help="extra passage width on each side of the disc, metres")
    p.add_argument("--format", choices=("pgm", "png"), default="pgm", help="image format (default pgm)")
    p.add_argument("--out", type=Path, required=True,
                   help="output YAML path, the image next to it (with --family: a directory)")
    a = p.parse_args(argv)
    try:
        _generate(p, a, MAP_FAMILIES)
    except ValueError as exc:  # a size, resolution or radius the generator cannot use: one line, exit 2
        p.error(str(exc))


def _check_numbers(p: argparse.ArgumentParser, a: argparse.Namespace) -> None:
    """The numeric flags, each named by its flag (the generators' own errors name their parameters)."""
    import math

    def bad(v: float | None, ok) -> bool:
        return v is not None and not (math.isfinite(v) and ok(v))

    for flag, v in (("--width", a.width), ("--height", a.height), ("--resolution", a.resolution)):
        if bad(v, lambda x: x > 0):
            p.error(f"{flag} {v:g}: must be a positive number of metres")
    if bad(a.robot_radius, lambda x: x > 0):
        p.error(f"--robot-radius {a.robot_radius:g}: must be a positive number of metres")
    if bad(a.margin, lambda x: x >= 0):
        p.error(f"--margin {a.margin:g}: must be >= 0 metres")
    if a.resolution is not None and a.resolution > a.robot_radius:
        p.error(f"--resolution {a.resolution:g}: a cell coarser than the robot's radius ({a.robot_radius:g} m, "
                "--robot-radius) cannot draw the passages it must fit; the families use 0.025-0.1 m")
    if a.density is not None:
        if a.family is not None:
            p.error("--density applies to the single cluttered map (without --family); each family draws its own")
        if bad(a.density, lambda x: 0 <= x < MAX_DENSITY):
            p.error(f"--density {a.density:g}: the occupied fraction must be in [0, {MAX_DENSITY:g})")


def _generate(p: argparse.ArgumentParser, a: argparse.Namespace, families: tuple[str, ...]) -> None:
    from flashnav.outputs import check_figure_file, check_output_dir, check_output_file

    _check_numbers(p, a)
    if a.family is None and a.count is not None:
        p.error(f"--count {a.count} goes with --family (maps per family); without it one map is written to --out")
    a.count = 1 if a.count is None else a.count

    # the paths first (ValueErrors naming the flag): a folder under a file, or a sheet matplotlib cannot write,
    # must not cost the maps
    if a.family is not None:
        check_output_dir(a.out, "--out")
        if a.sheet:
            a.sheet = check_figure_file(a.sheet, "--sheet")
    elif a.sheet:
        p.error("--sheet needs --family (a contact sheet of the family maps)")
    else:
        check_output_file(a.out, "--out")
    if a.family is not None:
        _write_families(p, a, families)
        return
    if a.width is None or a.height is None:
        p.error("--width and --height are required without --family")
    if a.out.suffix not in (".yaml", ".yml"):
        p.error(f"--out {a.out}: the map's YAML file (NAME.yaml; the image is written beside it)")
    a.resolution = 0.05 if a.resolution is None else a.resolution
    a.density = 0.16 if a.density is None else a.density
    grid = generate_map(a.width, a.height, a.resolution, a.seed, robot_radius=a.robot_radius,
                        density=a.density, margin=a.margin, name=a.out.stem)
    # Write the full command (defaults included) so the file can be regenerated bit for bit.
    command = shlex.join([
        "python", "-m", "flashnav.maps.generate", "--width", f"{a.width:g}", "--height", f"{a.height:g}",
        "--resolution", f"{a.resolution:g}", "--seed", str(a.seed), "--robot-radius", f"{a.robot_radius:g}",
        "--density", f"{a.density:g}", "--margin", f"{a.margin:g}", "--format", a.format, "--out", str(a.out),
    ])
    border = border_cells(a.resolution)
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
    from flashnav.names import parse_names

    try:
        families = parse_names("map family", a.family, known, "--family")
    except ValueError as exc:
        p.error(str(exc))
    if a.count < 1 or a.seed < 0:
        p.error(f"--count must be >= 1 and --seed >= 0, got {a.count} and {a.seed}")
    if (a.width is None) != (a.height is None):
        p.error("give both --width and --height, or neither")
    if a.out.suffix in (".yaml", ".yml"):
        p.error(f"--out {a.out}: with --family, --out is a directory")
    size = None if a.width is None else (a.width, a.height)

    def make(family: str, seed: int) -> OccupancyMap:
        return generate_family(family, seed, size=size, resolution=a.resolution, robot_radius=a.robot_radius,
                               margin=a.margin)

    # each family's first map before any is written: a size one family cannot draw leaves no folder and no maps
    first = {family: make(family, a.seed) for family in families}
    sheet: dict[str, list[OccupancyMap]] = {}
    for family in families:
        for seed in range(a.seed, a.seed + a.count):
            grid = first[family] if seed == a.seed else make(family, seed)
            args = ["python", "-m", "flashnav.maps.generate", "--family", family, "--seed", str(seed)]
            if size:
                args += ["--width", f"{a.width:g}", "--height", f"{a.height:g}"]
            if a.resolution is not None:
                args += ["--resolution", f"{a.resolution:g}"]
            args += ["--robot-radius", f"{a.robot_radius:g}", "--margin", f"{a.margin:g}", "--format", a.format,
                     "--out", str(a.out)]
            a.out.mkdir(parents=True, exist_ok=True)
            _save(grid, a.out / f"{grid.name}.yaml", a.format, a.robot_radius, shlex.join(args),
                  f"{grid.width_m:g} x {grid.height_m:g} m at {grid.resolution:g} m; occupied {grid.occupied.mean():.1%}")
            sheet.setdefault(family, []).append(grid)
    if a.sheet:
        from flashnav.viz import draw_map_sheet

        print(f"wrote {draw_map_sheet(sheet, a.sheet)}", file=sys.stderr)


if __name__ == "__main__":
    main()
