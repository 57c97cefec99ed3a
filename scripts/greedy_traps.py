"""Which maps trap a controller without memory, per robot? (issue 15: why the TurtleBot2 generalist fails mazes)

    .venv/bin/python scripts/greedy_traps.py [--maps heldout] [--robots turtlebot2,go2] [--episodes 256]
                                             [--seed 12345] [--deep 1.0] [--json OUT] [--outcomes EVAL_JSON ...]

For every map of ``--maps`` (a folder or glob of ROS map YAML files, or a committed benchmark suite: heldout, real)
and every robot, draws the fixed evaluation episodes that ``flashnav eval POLICY --maps ... --episodes N --seed S``
plays for that robot (its preset with geodesic goal sampling, as the command uses), and walks each
one with a **greedy walker**: from the start cell it steps to the 8-neighbour nearest (straight line) to the goal, among
the cells of the robot's configuration space (cell centres farther than its circumscribed radius from any wall, no
corner cutting), as long as that neighbour is strictly nearer; it succeeds when the goal is within the task's goal
threshold. A walker that stops first is in a dead end of the configuration space as seen from the goal: a place a
memoryless policy, however well it avoids walls, must back out of by going away from the goal. The fraction of
episodes that trap it is a property of the map, the robot's body and the episode distribution, not of any policy.
A trap's **depth** is the shortest path (through the configuration space) from where the walker stopped to the
nearest cell at least one cell nearer the goal than that point: the way a policy must go without getting nearer
before it can get nearer again. A wall jutting into the way costs a few tens of centimetres; a maze's dead end metres.
Prints one row per map and robot: the trapped fraction, the fraction trapped deeper than ``--deep`` metres, and the
trapped episodes' median depth.

``--outcomes EVAL_JSON``: the ``--json`` of ``flashnav eval POLICY --maps SUITE`` on the same episodes (same suite,
``--episodes`` and ``--seed``; its robot must be among ``--robots``), whose rows keep every episode's ending: prints
the policy's failure rate on the episodes with no trap, a shallow one and a deep one - does the policy fail where
the walker meets a deep dead end, and only there?
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np
from scipy.sparse.csgraph import dijkstra

from flashnav.eval_maps import fixed_episodes, suite_path
from flashnav.maps.bundled import resolve_maps
from flashnav.maps.fields import free_space
from flashnav.maps.graph import grid_graph
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.names import EVAL_SEED

STEPS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def trap_depths(graph, free: np.ndarray, traps: list[tuple[int, int]], goals: list[tuple[float, float]],
                resolution: float) -> np.ndarray:
    """[len(traps)] metres: for each trapped cell (row, col), the shortest free path to a cell whose centre is at
    least one cell nearer (straight line) to its goal (x, y metres); inf if none is reachable."""
    h, w = free.shape
    yy, xx = np.mgrid[0:h, 0:w]
    cx, cy = ((xx + 0.5) * resolution).ravel(), ((yy + 0.5) * resolution).ravel()
    out = np.full(len(traps), np.inf)
    for k0 in range(0, len(traps), 16):
        chunk = traps[k0:k0 + 16]
        dist = dijkstra(graph, indices=[r * w + c for r, c in chunk])
        for k, ((r, c), (gx, gy)) in enumerate(zip(chunk, goals[k0:k0 + 16])):
            here = math.hypot((c + 0.5) * resolution - gx, (r + 0.5) * resolution - gy)
            nearer = np.hypot(cx - gx, cy - gy) < here - resolution
            if nearer.any():
                out[k0 + k] = dist[k][nearer].min()
    return out


def greedy_walk(free: np.ndarray, start: tuple[int, int], goal_xy: tuple[float, float], resolution: float,
                threshold: float) -> tuple[bool, tuple[int, int]]:
    """Walk ``free`` [H, W] (row 0 = y 0, cell centres at (c + 0.5, r + 0.5) * resolution) from ``start`` (row,
    col) towards ``goal_xy`` (metres), always to the neighbour nearest the goal while it is strictly nearer.
    Returns (reached: within ``threshold`` metres of the goal, the cell where it stopped)."""
    h, w = free.shape
    gx, gy = goal_xy

    def dist(r: int, c: int) -> float:
        return math.hypot((c + 0.5) * resolution - gx, (r + 0.5) * resolution - gy)

    r, c = start
    d = dist(r, c)
    while d >= threshold:
        best, best_d = None, d
        for dr, dc in STEPS:
            nr, nc = r + dr, c + dc
            if not (0 <= nr < h and 0 <= nc < w and free[nr, nc]):
                continue
            if dr and dc and not (free[r + dr, c] and free[r, c + dc]):  # no corner cutting
                continue
            nd = dist(nr, nc)
            if nd < best_d - 1e-12:
                best, best_d = (nr, nc), nd
        if best is None:
            return False, (r, c)
        (r, c), d = best, best_d
    return True, (r, c)


def trap_rows(preset, grids, episodes: int, seed: int, deep: float) -> list[dict]:
    """One row per map of ``grids``: map, episodes, trapped and deep (fractions of the episodes: trapped at all,
    trapped deeper than ``deep`` metres), depth_median_m (of the trapped episodes; None if none), depths (per
    episode in the fixed order: None = not trapped, else the trap's depth in metres)."""
    radius = preset.footprint.circumscribed_radius
    env = NavVecEnv(evaluation_preset(preset), episodes * len(grids), grid=grids[0] if len(grids) == 1 else grids,
                    device="cpu", seed=seed)
    rows = []
    for m, grid in enumerate(grids):
        pose, goal = fixed_episodes(env, m, episodes, seed)
        ox, oy = grid.origin  # world metres -> metres from the map's lower-left corner
        free = free_space(grid, radius)
        traps, trap_goals, trapped_at = [], [], []
        for k in range(episodes):
            x, y = float(pose[k, 0]) - ox, float(pose[k, 1]) - oy
            gx, gy = float(goal[k, 0]) - ox, float(goal[k, 1]) - oy
            start = (min(max(int(y / grid.resolution), 0), free.shape[0] - 1),
                     min(max(int(x / grid.resolution), 0), free.shape[1] - 1))
            ok, stop = greedy_walk(free, start, (gx, gy), grid.resolution, preset.episode.goal_threshold)
            if not ok:
                traps.append(stop)
                trap_goals.append((gx, gy))
                trapped_at.append(k)
        depth = trap_depths(grid_graph(free, grid.resolution), free, traps, trap_goals, grid.resolution)
        depths: list[float | None] = [None] * episodes
        for k, d in zip(trapped_at, depth):
            depths[k] = float(d) if math.isfinite(d) else 1e9
        rows.append({"map": grid.name, "episodes": episodes, "trapped": len(traps) / episodes,
                     "deep": float((depth > deep).sum()) / episodes,
                     "depth_median_m": float(np.median(depth)) if traps else None, "depths": depths})
    return rows


def paired(report: dict, rows: list[dict], deep: float) -> dict[str, list[int]]:
    """{class: [failures, episodes]} over the maps of an eval report paired with ``rows`` by map name, for the
    classes none / shallow / deep (a trap deeper than ``deep`` metres)."""
    by_map = {r["map"]: r for r in rows}
    counts = {"none": [0, 0], "shallow": [0, 0], "deep": [0, 0]}
    for m in report["maps"]:
        row = by_map.get(m["map"])
        if row is None or "outcomes" not in m:
            raise ValueError(f"map {m['map']}: not among the walked maps, or its row has no per-episode outcomes "
                             f"(re-run flashnav eval --maps --json)")
        if len(m["outcomes"]) != len(row["depths"]):
            raise ValueError(f"map {m['map']}: {len(m['outcomes'])} episodes in the report, {len(row['depths'])} walked")
        for outcome, d in zip(m["outcomes"], row["depths"]):
            kind = "none" if d is None else "deep" if d > deep else "shallow"
            counts[kind][0] += outcome != "s"
            counts[kind][1] += 1
    return counts


def print_outcomes(path: str, out: dict, args) -> None:
    with open(path, encoding="utf-8") as f:
        report = json.load(f)
    robot = report.get("robot")
    if robot not in out:
        raise SystemExit(f"--outcomes {path}: robot {robot!r} is not among --robots {','.join(out)}")
    if (report.get("episodes_per_map"), report.get("seed")) != (args.episodes, args.seed):
        raise SystemExit(f"--outcomes {path}: {report.get('episodes_per_map')} episodes per map, seed "
                         f"{report.get('seed')}; walked {args.episodes} with seed {args.seed} (not the same episodes)")
    print(f"{report.get('label', path)} ({robot}): the policy's failures by the walker's trap on the same episodes")
    groups = {"all maps": report["maps"]}
    families = sorted({m["map"].rsplit("_", 1)[0] for m in report["maps"]})
    groups.update({f: [m for m in report["maps"] if m["map"].rsplit("_", 1)[0] == f] for f in families})
    for name, maps in groups.items():
        counts = paired({**report, "maps": maps}, out[robot], args.deep)
        cells = "  ".join(f"{kind}: {fail}/{n} = {fail / n:.1%}" if n else f"{kind}: -"
                          for kind, (fail, n) in counts.items())
        print(f"  {name:<12} {cells}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--maps", default="heldout")
    p.add_argument("--robots", default="turtlebot2,go2")
    p.add_argument("--episodes", type=int, default=256)
    p.add_argument("--seed", type=int, default=EVAL_SEED)
    p.add_argument("--deep", type=float, default=1.0, help="a trap deeper than this many metres counts as deep")
    p.add_argument("--json")
    p.add_argument("--outcomes", nargs="*", default=[], metavar="EVAL_JSON",
                   help="flashnav eval --maps --json reports of the same episodes: the policy's failures by trap")
    args = p.parse_args(argv)
    out = {}
    for robot in args.robots.split(","):
        preset = load_robot(robot, **{"episode.goal_sampling": "geodesic"})
        grids = resolve_maps(suite_path(args.maps), preset.map)
        out[robot] = trap_rows(preset, grids, args.episodes, args.seed, args.deep)
    robots = list(out)
    print(f"greedy walker: trapped / trapped deeper than {args.deep:g} m (fractions of {args.episodes} episodes per "
          f"map) and the trapped episodes' median depth")
    print(f"{'map':<22}" + "".join(f"{r:>28}" for r in robots))
    for i, row0 in enumerate(out[robots[0]]):
        cells = []
        for r in robots:
            row = out[r][i]
            depth = "-" if row["depth_median_m"] is None else f"{row['depth_median_m']:.2f} m"
            cells.append(f"{row['trapped']:>10.1%} {row['deep']:>7.1%} {depth:>9}")
        print(f"{row0['map']:<22}" + "".join(cells))
    for r in robots:
        print(f"{r}: mean trapped {np.mean([row['trapped'] for row in out[r]]):.1%}, "
              f"deeper than {args.deep:g} m {np.mean([row['deep'] for row in out[r]]):.1%}")
    for path in args.outcomes:
        print_outcomes(path, out, args)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"maps": args.maps, "episodes": args.episodes, "seed": args.seed, "deep_m": args.deep,
                       "robots": out}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
