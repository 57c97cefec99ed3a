"""What can a robot that knows only what its LiDAR has shown it do on a map set? (issue 15)

    .venv/bin/python scripts/mapless_planner.py MAP_YAML [MAP_YAML ...] [--episodes 32] [--seed 12345]
        [--robot turtlebot2] [--json OUT]

The bar for a zero-shot policy on unseen buildings is a mapless one: the paper's robot is given the goal's
position, not the map. A learned policy with no memory is one such controller; the best a controller can do
with memory is bounded by a planner that remembers every wall its scans have hit and plans optimistically
through the space it has not seen (unknown = free, as D* Lite / frontier navigation do): the
**optimistic mapless planner** here. Per episode it starts with an empty map; at every control step the
true scan of the simulator (the policy's 270-deg, 20-m LiDAR, raw beams) marks the cell of each beam's end
occupied; when a newly seen wall cell lies on or beside the planned path, it replans: shortest grid path to
the goal through the cells where the robot's disc (plus the oracle's margin) touches no known wall, with
the oracle's wall cost, and the oracle's pure pursuit along it
(:class:`flashnav.sim.oracle.OracleController`, which does the same with the whole map in hand). Same fixed
episodes as ``flashnav eval --maps`` (goals by path length), same horizon and motion limits. If this planner
misses a map's 95 %, no policy without the map can be expected to make it; where it makes it and a policy
does not, memory is what the policy lacks.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from flashnav.guidance import EnvScans
from flashnav.mapless import SENSORS
from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.sim.oracle import OracleController
from flashnav.names import EVAL_SEED


class MaplessPlanner(OracleController):
    """The oracle's steering over distance fields planned on what each slot has seen
    (:class:`flashnav.mapless.SeenWalls`; one map per env)."""

    def __init__(self, env, lookahead: float = 0.35, margin: float = 0.08, comfort: float = 0.3, *,
                 sensor: str = "raw", memory: bool = True):
        self.source = EnvScans(env, sensor)
        self.walls = self.source.walls(margin, comfort, memory)
        super().__init__(env, lookahead, margin, comfort)
        self.fields = self.walls.fields  # what the oracle's steering descends

    @property
    def replans(self) -> np.ndarray:
        return self.walls.replans

    def plan_all(self) -> None:
        slots = np.arange(self.env.num_envs)
        self.walls.plan(slots, self.source.goals(slots), self.source.scans(slots))

    def update(self, slots: np.ndarray) -> None:
        """After a step: new walls of running ``slots``; replan those whose path they block or brush."""
        self.walls.update(slots, self.source.scans(slots))


def run_map(preset, map_path: str, episodes: int, seed: int, sensor: str = "raw", memory: bool = True) -> dict:
    """The planner and the full-map oracle on one map's fixed episodes."""
    from flashnav.eval_maps import fixed_episodes

    env = make_env(preset, episodes, map=map_path, seed=0)
    start, goal = fixed_episodes(env, 0, episodes, seed)
    out = {}
    for name in ("mapless", "oracle"):
        env.reset(seed=0)
        env.set_state(start.float(), goal.float())
        ctl = MaplessPlanner(env, sensor=sensor, memory=memory) if name == "mapless" else OracleController(env)
        if name == "mapless":
            ctl.plan_all()
        else:
            ctl.plan()
        done = np.zeros(episodes, dtype=bool)
        success, steps = np.zeros(episodes, dtype=bool), np.full(episodes, preset.episode.horizon)
        collision = np.zeros(episodes, dtype=bool)
        for t in range(preset.episode.horizon):
            _, _, terminated, truncated, info = env.step(ctl.act())
            end = (terminated | truncated).numpy() & ~done
            success[end], collision[end], steps[end] = info["success"].numpy()[end], info["collision"].numpy()[end], t + 1
            done |= end
            if done.all():
                break
            if name == "mapless":
                ctl.update(np.nonzero(~done)[0])
        out[name] = {"success": float(success.mean()), "collision": float(collision.mean()),
                     "timeout": float((~success & ~collision).mean()),
                     "steps_mean": float(steps[success].mean()) if success.any() else None,
                     "per_episode": [{"success": bool(s), "collision": bool(c), "steps": int(k)}
                                     for s, c, k in zip(success, collision, steps)]}
        if name == "mapless":
            out[name]["replans_mean"] = float(ctl.replans.mean())
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("maps", nargs="+", metavar="MAP_YAML")
    p.add_argument("--episodes", type=int, default=32, help="episodes per map (flashnav eval --maps's first ones)")
    p.add_argument("--seed", type=int, default=EVAL_SEED)
    p.add_argument("--robot", default="turtlebot2")
    p.add_argument("--sensor", choices=SENSORS, default="raw",
                   help="raw: every beam's end is a wall; pooled: only what the policy's observation keeps, each "
                        "sector's minimum range, taken as a wall across the sector's arc")
    p.add_argument("--no-memory", action="store_true",
                   help="plan on the current scan's walls alone, afresh every step (what a memory-less controller "
                        "can know)")
    p.add_argument("--json", help="write the per-map results here")
    args = p.parse_args()
    torch.set_num_threads(1)
    preset = evaluation_preset(load_robot(args.robot, **{"episode.goal_sampling": "geodesic"}))
    rows = []
    for map_path in args.maps:
        t0 = time.perf_counter()
        r = run_map(preset, map_path, args.episodes, args.seed, args.sensor, not args.no_memory)
        m, o = r["mapless"], r["oracle"]
        print(f"{Path(map_path).stem}: mapless planner {m['success']:.1%} (collision {m['collision']:.1%}, timeout "
              f"{m['timeout']:.1%}, {m['steps_mean'] or 0:.0f} steps, {m['replans_mean']:.1f} plans/episode) | "
              f"full-map oracle {o['success']:.1%} ({o['steps_mean'] or 0:.0f} steps) | {time.perf_counter() - t0:.0f} s",
              flush=True)
        rows.append({"map": Path(map_path).stem, **r})
    mean = {k: float(np.mean([r[k]["success"] for r in rows])) for k in ("mapless", "oracle")}
    print(f"mean over {len(rows)} maps: mapless planner {mean['mapless']:.1%}, full-map oracle {mean['oracle']:.1%}; "
          f"worst map: mapless {min(r['mapless']['success'] for r in rows):.1%}")
    if args.json:
        Path(args.json).write_text(json.dumps({"robot": args.robot, "episodes": args.episodes, "seed": args.seed,
                                               "sensor": args.sensor, "memory": not args.no_memory,
                                               "maps": rows, "mean": mean}, indent=1), encoding="utf-8")
        print(f"json: {args.json}")


if __name__ == "__main__":
    main()
