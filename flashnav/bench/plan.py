"""``flashnav bench plan``: one replan of the mapless planner (:mod:`flashnav.mapless`), scipy against numba.

A replan is a shortest-path field from the goal over the cells where the robot's disc touches no known wall.
It ran as ``scipy.sparse.csgraph.dijkstra`` on a sparse graph built for every replan
(:func:`flashnav.maps.graph.grid_graph`); :func:`flashnav.maps.grid_dijkstra.grid_distances` runs the same
search in numba on the grid itself. Both are timed here on the same map and goals, interleaved, and must give
the same distances to the bit; the table says whether they did.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from flashnav.names import DEFAULT_ROBOT, seed_arg


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("plan", help="one mapless-planner replan on a map: scipy graph + Dijkstra vs the numba grid Dijkstra")
    p.add_argument("map", metavar="MAP", help="ROS map YAML or bundled map name (its walls stand for the known ones)")
    p.add_argument("--radius", type=float, default=0.28, help="metres kept from every wall (TurtleBot2 + margin)")
    p.add_argument("--goals", type=int, default=8, help="goals, random free cells (seeded)")
    p.add_argument("--repeats", type=int, default=3, help="timed rounds over the goals, the two ways interleaved")
    p.add_argument("--seed", type=seed_arg, default=0)
    p.set_defaults(func=run_bench_plan)


def run_bench_plan(args) -> int:
    from scipy.sparse.csgraph import dijkstra

    from flashnav.machine import machine_name
    from flashnav.maps.bundled import resolve_map
    from flashnav.maps.graph import grid_graph, wall_cost
    from flashnav.maps.grid_dijkstra import grid_distances

    if args.goals < 1 or args.repeats < 1 or not args.radius > 0:
        raise ValueError(f"--goals and --repeats must be >= 1 and --radius > 0, got {args.goals}, {args.repeats}, "
                         f"{args.radius}")
    grid = resolve_map(args.map, DEFAULT_ROBOT)
    free = grid.free_space(args.radius).copy()
    cells = np.flatnonzero(free)
    if not len(cells):
        raise ValueError(f"map {grid.name!r} has no cell {args.radius} m from every wall")
    cost = wall_cost(grid.clearance, args.radius, 0.3)  # the planner's (flashnav.mapless.SeenWalls, comfort 0.3)
    goals = np.random.default_rng(args.seed).choice(cells, args.goals)
    ways = {
        "scipy (graph + dijkstra)": lambda g: dijkstra(grid_graph(free, grid.resolution, cost), directed=True, indices=g),
        "numba grid_distances": lambda g: grid_distances(free, grid.resolution, cost, int(g)),
    }
    out = {name: [way(g) for g in goals[:1]] for name, way in ways.items()}  # warm-up (JIT)
    seconds: dict[str, list[float]] = {name: [] for name in ways}
    for _ in range(args.repeats):
        for name, way in ways.items():
            start = time.perf_counter()
            out[name] = [way(g) for g in goals]
            seconds[name].append((time.perf_counter() - start) / len(goals))
    first, second = out.values()
    same = all(np.array_equal(a, b) for a, b in zip(first, second))
    t = Table(title=f"flashnav bench plan: {grid.name} {grid.shape[0]} x {grid.shape[1]} cells at {grid.resolution} m, "
                    f"{args.goals} goals x {args.repeats} interleaved rounds, {machine_name('cpu')}")
    for col in ("way", "ms per plan (min / median round)", "x scipy"):
        t.add_column(col, justify="right")
    base = min(next(iter(seconds.values())))
    for name, s in seconds.items():
        t.add_row(name, f"{1e3 * min(s):.1f} / {1e3 * statistics.median(s):.1f}", f"{base / min(s):.1f}x")
    console = Console()
    console.print(t)
    console.print("same distances both ways" if same else "[red]the two ways disagree[/]")
    return 0 if same else 1
