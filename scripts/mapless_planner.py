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
from scipy.sparse.csgraph import dijkstra

from flashnav.maps.grid import OccupancyMap
from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.sim.oracle import OracleController, grid_graph


class MaplessPlanner(OracleController):
    """The oracle's steering over distance fields planned on what each slot has seen (one map per env)."""

    def __init__(self, env, lookahead: float = 0.35, margin: float = 0.08, comfort: float = 0.3, *,
                 sensor: str = "raw", memory: bool = True):
        if sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {SENSORS}, got {sensor!r}")
        super().__init__(env, lookahead, margin, comfort)
        self.sensor, self.memory = sensor, memory
        if env.num_maps != 1:
            raise ValueError("MaplessPlanner plans on one map per env (give one map at a time)")
        self.radius = env.preset.footprint.circumscribed_radius + margin
        self.comfort = comfort
        grid = env.frame_maps[0]
        self.grid = grid
        self.known = np.zeros((env.num_envs, *grid.shape), dtype=bool)  # walls seen, per slot
        self.replans = np.zeros(env.num_envs, dtype=np.int64)

    def _field(self, slot: int) -> np.ndarray:
        """Distance field (metres, inf where unreachable) to the slot's goal over its known walls."""
        g = self.grid
        seen = OccupancyMap(occupied=self.known[slot], resolution=g.resolution, origin=g.origin)
        free = seen.free_space(self.radius).copy()
        cost = 1.0 + 4.0 * np.clip((self.radius + self.comfort - seen.clearance) / self.comfort, 0.0, 1.0)
        goal = int(self._cells(self.env.goal[slot:slot + 1].cpu().numpy(), np.zeros(1, dtype=np.int64))[0])
        free.reshape(-1)[goal] = True  # the goal cell itself is never walled off by a margin
        self.replans[slot] += 1
        return dijkstra(grid_graph(free, g.resolution, cost), directed=True, indices=goal).astype(np.float32)

    def observe(self, slots: np.ndarray) -> np.ndarray:
        """Marks the walls the current scans of ``slots`` hit; returns [len(slots), H, W] the new ones."""
        g, env = self.grid, self.env
        ranges = env.scan()[torch.as_tensor(slots)].cpu().numpy()
        if self.sensor == "pooled":  # what the policy's observation keeps: each sector's minimum, across its arc
            lidar = env.preset.lidar
            pooled = ranges.reshape(len(slots), lidar.sectors, lidar.beams_per_sector).min(axis=2)
            ranges = np.repeat(pooled, lidar.beams_per_sector, axis=1)
        pose = env.pose[torch.as_tensor(slots)].cpu().numpy().astype(np.float64)
        angles = env.beam_angles.cpu().numpy()[None, :] + pose[:, 2:3]
        hit = ranges < env.preset.lidar.max_range - 1e-3
        # a little beyond the surface, so the end lands in the wall's cell, not the free cell before it
        r = ranges + 0.5 * g.resolution
        x, y = pose[:, :1] + r * np.cos(angles), pose[:, 1:2] + r * np.sin(angles)
        h, w = g.shape
        j = np.clip(((x - g.origin[0]) / g.resolution).astype(int), 0, w - 1)
        i = np.clip(((y - g.origin[1]) / g.resolution).astype(int), 0, h - 1)
        new = np.zeros((len(slots), h, w), dtype=bool)
        rows = np.broadcast_to(np.arange(len(slots))[:, None], hit.shape)
        new[rows[hit], i[hit], j[hit]] = True
        if not self.memory:  # only this scan's walls: every step plans afresh
            self.known[slots] = new
            return new
        new &= ~self.known[slots]
        self.known[slots] |= new
        return new

    def plan_all(self) -> None:
        n = self.env.num_envs
        self.fields = np.full((n, self.grid.shape[0] * self.grid.shape[1]), np.inf, dtype=np.float32)
        self.observe(np.arange(n))
        for k in range(n):
            self.fields[k] = self._field(k)

    def path_cells(self, slot: int, steps: int = 400) -> np.ndarray:
        """The cells of the slot's planned path from the robot (steepest descent of its field)."""
        h, w = self.grid.shape
        field = self.fields[slot]
        cell = int(self._cells(self.env.pose[slot:slot + 1, :2].cpu().numpy(), np.zeros(1, dtype=np.int64))[0])
        out = [cell]
        for _ in range(steps):
            i, j = divmod(cell, w)
            best, best_d = cell, field[cell]
            for di, dj in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
                ii, jj = i + di, j + dj
                if 0 <= ii < h and 0 <= jj < w and field[ii * w + jj] < best_d:
                    best, best_d = ii * w + jj, field[ii * w + jj]
            if best == cell:
                break
            cell = best
            out.append(cell)
        return np.array(out)

    def update(self, slots: np.ndarray) -> None:
        """After a step: new walls of running ``slots``; replan those whose path they block or brush."""
        new = self.observe(slots)
        w = self.grid.shape[1]
        reach = self.radius / self.grid.resolution + 1.0  # cells: a wall this near a path cell blocks it
        for k, slot in enumerate(slots):
            if not self.memory:
                self.fields[slot] = self._field(int(slot))
                continue
            walls = np.argwhere(new[k])
            if not len(walls):
                continue
            path = self.path_cells(int(slot))
            cells = np.stack([path // w, path % w], axis=1)
            gap = np.hypot(*(cells[:, None, :] - walls[None, :, :]).transpose(2, 0, 1)).min()
            if gap <= reach or not np.isfinite(self.fields[slot][path[0]]):
                self.fields[slot] = self._field(int(slot))


SENSORS = ("raw", "pooled")


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
    p.add_argument("--seed", type=int, default=12345)
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
