"""How long a control step of the mapless guide takes on a robot (``flashnav deploy ros --guide M``).

    .venv/bin/python scripts/scan_guide_steps.py [MAP_YAML] [--episodes 8] [--steps 60]

Plays the first episodes of ``flashnav eval --maps MAP`` (goals by path length, seed 12345) one robot at a time:
every control step feeds the simulator's scan and pose to a :class:`flashnav.mapless.ScanGuide` (as the node's
Controller does) and steers a goal seeker at its carrot. Each step's ScanGuide time is recorded, with the replans
computed by scipy's Dijkstra on the grid graph (the planner before 2026-11-26) and by the numba grid Dijkstra (now),
the same episodes both ways: mean, 95th percentile and worst per way (the worst steps are the replans).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra

import flashnav.mapless as mapless
from flashnav.eval_maps import fixed_episodes
from flashnav.maps.bundled import resolve_map
from flashnav.maps.graph import grid_graph
from flashnav.names import EVAL_SEED
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv


def scipy_distances(free, resolution, cost, source):
    return dijkstra(grid_graph(free, resolution, cost), directed=True, indices=source)


def play(grid, preset, episodes: int, steps: int) -> list[float]:
    env = NavVecEnv(preset, 1, grid=grid, seed=0)
    pose, goal = fixed_episodes(NavVecEnv(preset, 1, grid=grid, seed=EVAL_SEED), 0, episodes, EVAL_SEED)
    angles = env.beam_angles.numpy()
    times = []
    for e in range(episodes):
        env.set_state(pose[e:e + 1], goal[e:e + 1])
        guide = mapless.ScanGuide(preset.footprint.circumscribed_radius, lookahead=0.5)  # as the node builds it
        guide.start(env.world_goal()[0].tolist())
        for _ in range(steps):
            p = env.world_pose()[0].numpy()
            start = time.perf_counter()
            carrot = guide.step(p, angles, env.scan()[0].numpy(), preset.lidar.max_range)
            times.append(time.perf_counter() - start)
            d = np.asarray(carrot) - p[:2]
            err = (np.arctan2(d[1], d[0]) - p[2] + np.pi) % (2 * np.pi) - np.pi
            _, _, terminated, truncated, _ = env.step(torch.tensor([[1.0 if abs(err) < 0.3 else -1.0,
                                                                      float(np.clip(2 * err, -1, 1))]]))
            if bool(terminated[0] | truncated[0]):
                break
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", nargs="?", default=str(Path(__file__).resolve().parents[1]
                                                 / "flashnav/maps/data/benchmark/heldout/mazes_900002.yaml"))
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--steps", type=int, default=60)
    args = ap.parse_args(argv)
    preset = load_robot("turtlebot2", **{"episode.goal_sampling": "geodesic"})
    grid = resolve_map(args.map, "turtlebot2")
    numba_distances = mapless.grid_distances
    ways = {"scipy": scipy_distances, "numba": numba_distances}
    out = {}
    for round_ in range(2):  # the first round warms both up (numba's JIT, the map's fields)
        for name, way in ways.items():
            mapless.grid_distances = way
            out[name] = play(grid, preset, args.episodes, args.steps)
    mapless.grid_distances = numba_distances
    for name, times in out.items():
        t = 1e3 * np.asarray(times)
        print(f"{name}: mean {t.mean():.1f} ms, p95 {np.percentile(t, 95):.1f} ms, worst {t.max():.1f} ms "
              f"over {len(t)} control steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
