"""``flashnav demo``: drive the simulator with the oracle controller and draw what happened."""

from __future__ import annotations

import argparse
import time

import numpy as np

from flashnav.names import DEFAULT_ROBOT, ROBOT_HELP, seed_arg


def register_cli(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the simulator with the map-aware oracle controller and draw trajectories")
    p.add_argument("--robot", default=DEFAULT_ROBOT, help=ROBOT_HELP)
    p.add_argument("--map", default=None, help="ROS map YAML (default: the preset's bundled map)")
    p.add_argument("--envs", type=int, default=16, help="parallel environments (one episode each)")
    p.add_argument("--seed", type=seed_arg, default=0)
    p.add_argument("--out", default="runs/demo.png",
                   help="the trajectories picture (PNG; .pdf, .svg, ... by its suffix; .png added without one)")
    p.set_defaults(func=run_demo)


def run_demo(args) -> int:
    from flashnav.sim.env import make_env
    from flashnav.sim.oracle import OracleController
    from flashnav.outputs import check_figure_file
    from flashnav.viz import draw_trajectories

    out = check_figure_file(args.out, "--out")  # before any work: a bad path costs nothing
    if args.envs < 1:
        raise ValueError(f"--envs must be >= 1 (robots driven at once), got {args.envs}")
    env = make_env(args.robot, args.envs, map=args.map, seed=args.seed)
    print(f"{env}  map {env.map}")
    env.reset(seed=args.seed)
    oracle = OracleController(env)
    oracle.plan()
    goals = env.goal.numpy().copy()
    paths = [[p] for p in env.pose[:, :2].numpy().copy()]
    outcome = ["timeout"] * args.envs
    running = np.ones(args.envs, dtype=bool)
    start = time.perf_counter()
    for _ in range(env.preset.episode.horizon):
        _, _, terminated, truncated, info = env.step(oracle.act())
        final_pose = env.pose.numpy()  # for finished slots this is already the next episode's start
        done = (terminated | truncated).numpy()
        for i in np.nonzero(running)[0]:
            if not done[i]:
                paths[i].append(final_pose[i, :2].copy())
            else:
                running[i] = False
                outcome[i] = "success" if info["success"][i] else "collision" if info["collision"][i] else "timeout"
        if not running.any():
            break
    seconds = time.perf_counter() - start
    counts = {k: outcome.count(k) for k in ("success", "collision", "timeout")}
    print(f"oracle: {counts} over {args.envs} episodes ({seconds:.1f} s, planning included)")
    out = draw_trajectories(env.frame_map, [np.array(p) for p in paths], goals, outcome, out,
                            title=f"{env.preset.name}: oracle controller, {counts['success']}/{args.envs} reached")
    print(f"trajectories: {out}")
    return 0
