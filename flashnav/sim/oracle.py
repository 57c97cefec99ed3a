"""An oracle controller: grid shortest paths + pure pursuit, with full knowledge of the map.

Evidence that every sampled episode is solvable within the horizon (so 100 % success is attainable),
and a baseline to compare learned policies against. Slow by design (host-side numpy/scipy).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra

from flashnav.maps.graph import NEIGHBOURS as _NEIGHBOURS, grid_graph, wall_cost
from flashnav.sim.env import NavVecEnv

class OracleController:
    """Follows the geodesic to each env's goal: the next waypoint is ``lookahead`` metres down the
    distance field; the heading error sets the turn rate, and forward speed falls off with it.

    With many maps (``env.num_maps > 1``) each slot plans on its own map: one graph per map, and each
    slot's distance field on its map's cells ([N, largest map's cells] float32 in all)."""

    def __init__(self, env: NavVecEnv, lookahead: float = 0.35, margin: float = 0.08, comfort: float = 0.3):
        self.env = env
        radius = env.preset.footprint.circumscribed_radius + margin
        self.graphs = []
        for grid in env.maps:
            free = grid.free_space(radius)
            # paths keep away from walls where they can: cells within `comfort` of the margin cost more
            cost = wall_cost(grid.clearance, radius, comfort)
            self.graphs.append(grid_graph(free, grid.resolution, cost))
        self.free = env.map.free_space(radius)  # the (first) map's, as before
        # per map: resolution, frame origin (the env's pose and goal are in each map's simulator
        # frame), shape and look-ahead in cells
        self._res = np.array([g.resolution for g in env.maps])
        self._origin = np.array([g.origin for g in env.frame_maps], dtype=np.float64)
        self._shape = np.array([g.shape for g in env.maps], dtype=np.int64)
        self._ahead = np.array([max(1, int(round(lookahead / g.resolution))) for g in env.maps])
        self.fields: np.ndarray | None = None

    def _cells(self, xy: np.ndarray, maps: np.ndarray) -> np.ndarray:
        """Flat cell index on each row's map of the points ``xy`` [n, 2] (clipped onto the map)."""
        res, origin, shape = self._res[maps], self._origin[maps], self._shape[maps]
        j = np.clip(((xy[:, 0] - origin[:, 0]) / res).astype(int), 0, shape[:, 1] - 1)
        i = np.clip(((xy[:, 1] - origin[:, 1]) / res).astype(int), 0, shape[:, 0] - 1)
        return i * shape[:, 1] + j

    def _maps(self, envs=None) -> np.ndarray:
        index = self.env.map_index if envs is None else self.env.map_index[torch.as_tensor(envs)]
        return index.cpu().numpy()

    def plan(self) -> None:
        """Distance-to-goal fields [N, cells] for the current goals (call after every reset)."""
        n = self.env.num_envs
        self.fields = np.full((n, int((self._shape[:, 0] * self._shape[:, 1]).max())), np.inf, dtype=np.float32)
        self.replan(np.arange(n))

    def replan(self, envs: np.ndarray) -> None:
        envs = np.asarray(envs)
        if not len(envs):
            return
        maps = self._maps(envs)
        goals = self._cells(self.env.goal[torch.as_tensor(envs)].cpu().numpy(), maps)
        for m in np.unique(maps):
            sel = envs[maps == m]
            cells = int(self._shape[m, 0] * self._shape[m, 1])
            for k in range(0, len(sel), 64):
                part = sel[k:k + 64]
                self.fields[part, :cells] = dijkstra(self.graphs[m], directed=True, indices=goals[maps == m][k:k + 64])

    def act(self) -> torch.Tensor:
        """Normalised actions [N, 2] for the env's current state."""
        pose = self.env.pose.cpu().numpy().astype(np.float64)
        goal = self.env.goal.cpu().numpy().astype(np.float64)
        maps = self._maps()
        h, w = self._shape[maps, 0], self._shape[maps, 1]
        res, origin, ahead = self._res[maps], self._origin[maps], self._ahead[maps]
        n = len(pose)
        cell = self._cells(pose[:, :2], maps)
        rows = np.arange(n)
        for step in range(int(ahead.max())):  # steepest descent of each env's own field
            i, j = cell // w, cell % w
            best, best_d = cell, self.fields[rows, cell]
            for di, dj in _NEIGHBOURS:
                ii, jj = np.clip(i + di, 0, h - 1), np.clip(j + dj, 0, w - 1)
                cand = ii * w + jj
                d = self.fields[rows, cand]
                better = (d < best_d) & (step < ahead)
                best, best_d = np.where(better, cand, best), np.where(better, d, best_d)
            cell = best
        tx = origin[:, 0] + (cell % w + 0.5) * res
        ty = origin[:, 1] + (cell // w + 0.5) * res
        target = np.stack([tx, ty], axis=1)
        near = np.linalg.norm(goal - pose[:, :2], axis=1) < ahead * res
        target[near] = goal[near]
        heading = np.arctan2(target[:, 1] - pose[:, 1], target[:, 0] - pose[:, 0])
        err = (heading - pose[:, 2] + math.pi) % (2 * math.pi) - math.pi
        m = self.env.preset.motion
        w_cmd = np.clip(2.5 * err, *m.w_bounds)
        v_cmd = np.where(np.abs(err) < 0.6, m.v_bounds[1] * np.cos(err) ** 2, 0.0)
        v_cmd = np.clip(v_cmd, *m.v_bounds)
        a_v = 2 * (v_cmd - m.v_bounds[0]) / (m.v_bounds[1] - m.v_bounds[0]) - 1
        a_w = 2 * (w_cmd - m.w_bounds[0]) / (m.w_bounds[1] - m.w_bounds[0]) - 1
        return torch.as_tensor(np.stack([a_v, a_w], axis=1), dtype=torch.float32, device=self.env.device)


def run_oracle(env: NavVecEnv, episodes: int, seed: int = 0) -> dict:
    """Run the oracle until ``episodes`` episodes have finished; returns success/collision/timeout
    rates over the first ``episodes`` finished episodes."""
    oracle = OracleController(env)
    env.reset(seed=seed)
    oracle.plan()
    outcomes: list[str] = []
    while len(outcomes) < episodes:
        _, _, terminated, truncated, info = env.step(oracle.act())
        done = (terminated | truncated).cpu().numpy()
        if done.any():
            idx = np.nonzero(done)[0]
            succ, coll = info["success"].cpu().numpy(), info["collision"].cpu().numpy()
            outcomes += ["success" if succ[i] else "collision" if coll[i] else "timeout" for i in idx]
            oracle.replan(idx)
    outcomes = outcomes[:episodes]
    return {k: outcomes.count(k) / episodes for k in ("success", "collision", "timeout")} | {"episodes": episodes}
