"""Copy a public ROS map_server map into a benchmark suite: read it as FlashNav reads it, coarsen it, write
it small.

    .venv/bin/python scripts/import_ros_map.py SRC.yaml OUT.yaml [--factor K] [--note TEXT]

The map is read with :func:`flashnav.maps.load_ros_map` under its own YAML's thresholds (so the copy holds
exactly the cells FlashNav would simulate on the original: unknown counts as an obstacle), coarsened by
``--factor`` K (a coarse cell is occupied when any of its K x K fine cells is, so no wall thins or opens;
the right and top edges are padded with obstacle), and written as a trinary PNG map
(:func:`flashnav.maps.save_ros_map`) with ``--note`` (source, commit, licence) as YAML comment lines.
Used for ``flashnav/maps/data/benchmark/real`` (its README lists the commands).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from flashnav.maps import OccupancyMap, load_ros_map, save_ros_map


def coarsen(grid: OccupancyMap, factor: int) -> OccupancyMap:
    """``grid`` with cells ``factor`` times larger: [ceil(H/K), ceil(W/K)], occupied where any fine cell
    is (cells past the right/top edge count as occupied), same origin, resolution x K."""
    if factor < 1:
        raise ValueError(f"--factor must be >= 1, got {factor}")
    if factor == 1:
        return grid
    h, w = grid.shape
    hh, ww = -(-h // factor), -(-w // factor)
    padded = np.ones((hh * factor, ww * factor), dtype=bool)
    padded[:h, :w] = grid.occupied
    occ = padded.reshape(hh, factor, ww, factor).any(axis=(1, 3))
    return OccupancyMap(occ, grid.resolution * factor, grid.origin, grid.name)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src", type=Path, help="the original map's YAML")
    p.add_argument("out", type=Path, help="the copy's YAML (a PNG is written next to it)")
    p.add_argument("--factor", type=int, default=1, help="coarsening factor (default 1: cells as they are)")
    p.add_argument("--note", default="", help="text for the YAML's comment lines (source, commit, licence)")
    a = p.parse_args(argv)
    src = load_ros_map(a.src)
    grid = coarsen(src, a.factor)
    note = (f"{a.note}\n" if a.note else "") + (
        f"Read by flashnav.maps.load_ros_map under the original YAML's thresholds ({src.shape[1]} x "
        f"{src.shape[0]} cells at {src.resolution:g} m)" + (f", coarsened {a.factor}x (a cell is occupied where "
        f"any of its {a.factor}x{a.factor} original cells is)" if a.factor > 1 else "") + ".")
    out = save_ros_map(grid, a.out, "png", comment=note)
    print(f"wrote {out} ({grid!r}, {grid.width_m:g} x {grid.height_m:g} m)", file=sys.stderr)


if __name__ == "__main__":
    main()
