"""Are a suite's episodes solvable within the horizon? The map-aware oracle on them (issue 15).

    .venv/bin/python scripts/oracle_maps.py MAP_YAML [MAP_YAML ...] [--robot turtlebot2] [--episodes 256] [--seed 12345]

For each ROS map, ``--episodes`` episodes drawn as ``flashnav eval --maps`` draws them (goals by path length,
``episode.goal_sampling=geodesic``) and driven by the oracle controller (:func:`flashnav.sim.oracle.run_oracle`:
it follows the shortest grid path with the map in hand). Success near 100 % means the policy's failures on that
map are the policy's, not the task's.
"""

from __future__ import annotations

import argparse

import torch

from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.oracle import run_oracle
from flashnav.names import EVAL_SEED


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("maps", nargs="+", metavar="MAP_YAML")
    ap.add_argument("--robot", default="turtlebot2")
    ap.add_argument("--episodes", type=int, default=256)
    ap.add_argument("--seed", type=int, default=EVAL_SEED)
    args = ap.parse_args()
    torch.set_num_threads(2)
    preset = load_robot(args.robot, **{"episode.goal_sampling": "geodesic"})
    for path in args.maps:
        env = make_env(preset, min(args.episodes, 256), map=path, seed=args.seed)
        r = run_oracle(env, episodes=args.episodes, seed=args.seed)
        print(f"{path}: oracle success {r['success']:.1%}, collision {r['collision']:.1%}, "
              f"timeout {r['timeout']:.1%} of {r['episodes']} episodes")


if __name__ == "__main__":
    main()
