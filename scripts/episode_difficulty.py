"""Which evaluation episodes does a policy fail? Outcome by route length and detour (issue 16, item 3).

    .venv/bin/python scripts/episode_difficulty.py POLICY [--episodes 1024] [--seed 12345] [--json OUT] [--plot PNG]
        [--failures PNG]

Evaluates the exported POLICY on the fixed set that ``flashnav train`` evaluates on (``--episodes`` start/goal
pairs drawn with evaluation seed ``--seed``, the robot's bundled map), episode by episode
(:func:`flashnav.evaluate.evaluate_episodes`), and relates each outcome to the episode's geodesic route:
the shortest 8-connected grid path from start to goal through the cells where the footprint's circumscribed
disc is collision-free (the oracle's graph, :func:`flashnav.maps.graph.grid_graph`). Prints success / collision
/ timeout by route length and by detour ratio (route / straight line), and the time the route needs at top speed
against the horizon. The failed episodes are replayed alone (``set_state`` at their start and goal, the
deterministic policy gives the same path) to find each one's closest approach to its goal; how far it drove in
the second half of its horizon is the evaluation's own ``late_m``, and a timeout that drove under 0.5 m there
"stalled" (:func:`flashnav.evaluate.stalled`, as ``flashnav eval --maps`` counts it), the policy parked in front
of an obstacle; the other timeouts "wandered". ``--failures`` draws their paths on the
map, split into near misses (within 0.1 m of the goal radius) and the rest.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra

from failure_kinds import drive  # scripts/: the same replay from given starts and goals

from flashnav.evaluate import STALL_M, evaluate_episodes, stalled as stalled_episodes  # one reading of "stalled"
from flashnav.export import evaluated_robot, load_policy
from flashnav.sim.env import make_env
from flashnav.maps.graph import grid_graph
from flashnav.names import EVAL_EPISODES, EVAL_SEED

LENGTH_BINS = [0, 2, 3, 4, 5, 6, 8, math.inf]  # metres of route
DETOUR_BINS = [1.0, 1.1, 1.25, 1.5, 2.0, math.inf]
BEARING_BINS = [0, 45, 90, 135, 180.001]  # |deg| between the start heading and the goal


def route_lengths(grid, radius: float, start_xy: np.ndarray, goal_xy: np.ndarray) -> np.ndarray:
    """Geodesic route length (m) from each start to its goal on ``grid`` (world coordinates)."""
    graph = grid_graph(grid.free_space(radius), grid.resolution)
    h, w = grid.shape

    def cells(xy):
        j = np.clip(((xy[:, 0] - grid.origin[0]) / grid.resolution).astype(int), 0, w - 1)
        i = np.clip(((xy[:, 1] - grid.origin[1]) / grid.resolution).astype(int), 0, h - 1)
        return i * w + j

    goals, starts = cells(goal_xy), cells(start_xy)
    out = np.empty(len(goals))
    for k in range(0, len(goals), 64):
        field = dijkstra(graph, directed=False, indices=goals[k:k + 64])
        out[k:k + 64] = field[np.arange(len(field)), starts[k:k + 64]]
    return out


def replay_failures(policy, robot, start_pose: np.ndarray, goal: np.ndarray):
    """Replays episodes alone from ``start_pose [F, 3]`` / ``goal [F, 2]`` (world): their paths
    ``[T, F, 2]`` (NaN after the episode ended) and closest approach to the goal ``[F]`` (m)."""
    if len(goal) == 0:  # a policy that solved every episode: nothing to replay
        return np.zeros((0, 0, 2)), np.zeros(0)
    env = make_env(robot, len(goal), seed=0)
    env.reset(seed=0)
    _, _, paths = drive(env, policy, torch.as_tensor(start_pose), torch.as_tensor(goal))
    closest = np.nanmin(np.linalg.norm(paths - np.asarray(goal)[None], axis=2), axis=0)
    return paths, closest


def draw_failures(path: str, grid, paths: np.ndarray, goal: np.ndarray, near: np.ndarray, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    h, w = grid.shape
    extent = [grid.origin[0], grid.origin[0] + w * grid.resolution, grid.origin[1], grid.origin[1] + h * grid.resolution]
    fig, axes = plt.subplots(1, 2, figsize=(12, 6.3))
    for ax, sel, name in ((axes[0], near, "near misses: within 0.1 m of the goal radius, not inside"),
                          (axes[1], ~near, "never near the goal")):
        ax.imshow(grid.occupied, origin="lower", extent=extent, cmap="Greys")
        for j in np.nonzero(sel)[0]:
            line, = ax.plot(paths[:, j, 0], paths[:, j, 1], lw=0.9)
            ax.plot(paths[0, j, 0], paths[0, j, 1], "o", c=line.get_color(), ms=3)
            ax.plot(goal[j, 0], goal[j, 1], "*", c=line.get_color(), ms=10)
        ax.set_title(f"{name}: {int(sel.sum())}", fontsize=10)
        ax.set_aspect("equal")
    fig.suptitle(title + " (o start, * goal)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(name: str, values: np.ndarray, bins: list[float], outcome: np.ndarray) -> list[dict]:
    rows = []
    print(f"\nby {name}:\n  {'bin':>14} {'episodes':>9} {'success':>8} {'collision':>10} {'timeout':>8}")
    for lo, hi in zip(bins[:-1], bins[1:]):
        sel = (values >= lo) & (values < hi)
        n = int(sel.sum())
        if not n:
            continue
        rates = {k: float((outcome[sel] == k).mean()) for k in ("success", "collision", "timeout")}
        rows.append({"bin": [lo, hi], "episodes": n, **rates})
        print(f"  {f'[{lo:g}, {hi:g})':>14} {n:9d} {rates['success']:8.1%} {rates['collision']:10.1%} "
              f"{rates['timeout']:8.1%}")
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy")
    p.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    p.add_argument("--seed", type=int, default=EVAL_SEED, help="evaluation seed (flashnav train's eval.seed)")
    p.add_argument("--json", help="write every episode's route, detour and outcome here")
    p.add_argument("--plot", help="scatter of route length vs straight-line distance, coloured by outcome")
    p.add_argument("--failures", help="the failed episodes' paths on the map (near misses apart)")
    args = p.parse_args()
    policy, meta = load_policy(args.policy)
    # the policy's own preset (its observation options: scan history, pose trail), evaluated with the paper's reward
    preset = evaluated_robot(meta)
    env = make_env(preset, args.episodes, seed=args.seed)
    played = evaluate_episodes(policy, env, args.seed)
    e = {k: v.cpu().numpy() for k, v in played.items()}
    outcome = np.where(e["success"], "success", np.where(e["collision"], "collision", "timeout"))
    start, goal = e["start_pose"][:, :2], e["goal"]
    straight = np.linalg.norm(goal - start, axis=1)
    route = route_lengths(env.map, env.preset.footprint.circumscribed_radius, start, goal)
    detour = route / np.maximum(straight, 1e-9)
    # where the goal lies from the start heading, |deg|: 0 ahead, 180 right behind
    to_goal = np.arctan2(goal[:, 1] - start[:, 1], goal[:, 0] - start[:, 0]) - e["start_pose"][:, 2]
    bearing = np.degrees(np.abs((to_goal + np.pi) % (2 * np.pi) - np.pi))
    m, ep = env.preset.motion, env.preset.episode
    reach = max(m.v_bounds) * ep.horizon * ep.dt
    print(f"{args.policy}: {args.episodes} episodes (eval seed {args.seed}), success {np.mean(e['success']):.2%}; "
          f"route at top speed fits the horizon up to {reach:.1f} m; longest route {np.nanmax(route):.2f} m, "
          f"unreachable on the grid: {int(np.isinf(route).sum())}")
    out = {"by_route_length": table("route length (m)", route, LENGTH_BINS, outcome),
           "by_detour": table("detour ratio (route / straight line)", detour, DETOUR_BINS, outcome),
           "by_bearing": table("goal bearing from the start heading (|deg|)", bearing, BEARING_BINS, outcome)}
    failed = np.nonzero(outcome != "success")[0]
    paths, closest = replay_failures(policy, preset, e["start_pose"][failed], goal[failed])
    near = closest < ep.goal_threshold + 0.1
    # metres driven in the horizon's second half and "stalled" as flashnav eval reads them (near misses apart)
    late = e["late_m"][failed]
    stalled = stalled_episodes(played).cpu().numpy()[failed] & ~near
    print(f"\nfailed episodes ({len(failed)}; {int(near.sum())} came within 0.1 m of the {ep.goal_threshold:g} m "
          f"goal radius; {int(stalled.sum())} stalled: under {STALL_M:g} m driven in their last {ep.horizon // 2} "
          "steps): " + ", ".join(f"#{k} {outcome[k]} route {route[k]:.2f} m detour {detour[k]:.2f} "
                                 f"bearing {bearing[k]:.0f} deg closest {c:.2f} m late {m:.2f} m"
                                 for k, c, m in zip(failed[:40], closest, late)))
    out["failed"] = [{"index": int(k), "outcome": str(outcome[k]), "bearing_deg": float(bearing[k]),
                      "closest_m": float(c), "late_m": float(m),
                      "kind": "near miss" if n else "stalled" if st else "wandered" if outcome[k] == "timeout" else "collision"}
                     for k, c, m, n, st in zip(failed, closest, late, near, stalled)]
    if args.failures:
        draw_failures(args.failures, env.map, paths, goal[failed], near,
                      f"{len(failed)} failures of {args.policy} on {args.episodes} evaluation episodes")
        print(f"failures: {args.failures}")
    if args.json:
        out["episodes"] = [{"index": int(k), "outcome": str(outcome[k]), "straight_m": float(straight[k]),
                            "route_m": float(route[k]), "bearing_deg": float(bearing[k]),
                            "steps": float(e["episode_steps"][k])} for k in range(len(route))]
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=1)
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6, 4.5))
        for name, colour in (("success", "#9bbbd4"), ("timeout", "#e69f00"), ("collision", "#d62728")):
            sel = outcome == name
            ax.scatter(straight[sel], route[sel], s=6 if name == "success" else 22, c=colour,
                       label=f"{name} ({int(sel.sum())})")
        ax.axhline(reach, ls=":", c="k", lw=0.8, label=f"horizon at top speed ({reach:.0f} m)")
        ax.set_xlabel("straight-line start-goal distance (m)")
        ax.set_ylabel("geodesic route length (m)")
        ax.set_title(f"{meta['robot']}: {args.episodes} evaluation episodes, seed {args.seed}")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=130)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
