"""How often does a map's task ask for a long way round? Share of long detours per map (issue 16, Go2's map).

    .venv/bin/python scripts/map_detours.py MAP [MAP ...] [--robot go2] [--episodes 8192] [--seed 0] [--json OUT]

For each MAP (a bundled map name or a ROS map YAML), draws ``--episodes`` start/goal pairs with the robot's
episode sampler (the task's straight-line draws, :class:`flashnav.sim.sampling.EpisodeSampler`) and measures each
one's detour, path length / straight line (:meth:`EpisodeSampler.detour`: the path through the free space of the
footprint's circumscribed disc). Prints the occupied share of the map and the share of episodes whose detour
exceeds 1.25 and 1.5 (and those with no path within the horizon's reach). The maps' generated siblings can be
compared this way before training on them, without looking at any training result.
"""

from __future__ import annotations

import argparse
import json

import torch

from flashnav.maps.bundled import resolve_map
from flashnav.presets import load_robot
from flashnav.sim.sampling import EpisodeSampler

THRESHOLDS = (1.25, 1.5)


def map_detours(grid, preset, episodes: int, seed: int) -> dict:
    """Occupied share and detour shares of ``episodes`` draws of ``preset``'s sampler on ``grid``."""
    sampler = EpisodeSampler(grid, preset, torch.device("cpu"))
    pose, goal = sampler.sample(episodes, torch.Generator().manual_seed(seed))
    ratio = sampler.detour(pose[:, :2], goal)
    out = {"map": grid.name, "occupied": float(grid.occupied.mean()), "episodes": episodes,
           "no_path": float((ratio == 0).float().mean())}
    for t in THRESHOLDS:
        out[f"detour_over_{t:g}"] = float((ratio > t).float().mean())
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("maps", nargs="+", metavar="MAP", help="bundled map name or ROS map YAML")
    ap.add_argument("--robot", default="go2", help="robot preset (its footprint, sampler and horizon)")
    ap.add_argument("--episodes", type=int, default=8192)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {args.episodes}")
    preset = load_robot(args.robot)
    rows = [map_detours(resolve_map(m, preset.map), preset, args.episodes, args.seed) for m in args.maps]
    for r in rows:
        print(f"{r['map']}: occupied {100 * r['occupied']:.1f} %, detour > 1.25: {100 * r['detour_over_1.25']:.2f} %, "
              f"> 1.5: {100 * r['detour_over_1.5']:.2f} %, no path within reach: {100 * r['no_path']:.2f} % "
              f"({r['episodes']} episodes)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
