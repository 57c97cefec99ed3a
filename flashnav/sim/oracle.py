"""An oracle controller: grid shortest paths + pure pursuit, with full knowledge of the map.

Evidence that every sampled episode is solvable within the horizon (so 100 % success is attainable),
and a baseline to compare learned policies against. Slow by design (host-side numpy/scipy).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from flashnav.sim.env import NavVecEnv

_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def grid_graph(free: np.ndarray, resolution: float, cost: np.ndarray | None = None) -> csr_matrix:
    """8-connected graph over the free cells of ``free`` [H, W] (edge weights in metres, times the
    optional per-cell ``cost`` [H, W] >= 1 of the cell entered); a diagonal move needs both cells
    beside it free, so paths never cut an obstacle's corner."""
    h, w = free.shape
    idx = np.arange(h * w).reshape(h, w)
    pad = np.pad(free, 1, constant_values=False)

    def shifted(di: int, dj: int) -> np.ndarray:  # shifted(di, dj)[i, j] = free[i + di, j + dj]
        return pad[1 + di: 1 + di + h, 1 + dj: 1 + dj + w]

    rows, cols, weights = [], [], []
    for di, dj in _NEIGHBOURS:
        ok = free & shifted(di, dj)
        if di and dj:  # no corner cutting
            ok &= shifted(di, 0) & shifted(0, dj)
        s = idx[ok]
        rows.append(s)
        cols.append(s + di * w + dj)
        step = np.full(s.size, resolution * math.hypot(di, dj))
        weights.append(step if cost is None else step * cost.reshape(-1)[s + di * w + dj])
    r, c, wt = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    return csr_matrix((wt, (r, c)), shape=(h * w, h * w))


class OracleController:
    """Follows the geodesic to each env's goal: the next waypoint is ``lookahead`` metres down the
    distance field; the heading error sets the turn rate, and forward speed falls off with it."""

    def __init__(self, env: NavVecEnv, lookahead: float = 0.35, margin: float = 0.08, comfort: float = 0.3):
        self.env = env
        grid = env.map
        radius = env.preset.footprint.circumscribed_radius + margin
        self.free = grid.free_space(radius)
        # paths keep away from walls where they can: cells within `comfort` of the margin cost more
        cost = 1.0 + 4.0 * np.clip((radius + comfort - grid.clearance) / comfort, 0.0, 1.0)
        self.graph = grid_graph(self.free, grid.resolution, cost)
        # the env's pose and goal are in its simulator frame: index cells with that frame's origin
        self.res, self.origin, self.shape = grid.resolution, env.frame_map.origin, grid.shape
        self.steps_ahead = max(1, int(round(lookahead / grid.resolution)))
        self.fields: np.ndarray | None = None

    def _cells(self, xy: np.ndarray) -> np.ndarray:
        j = np.clip(((xy[:, 0] - self.origin[0]) / self.res).astype(int), 0, self.shape[1] - 1)
        i = np.clip(((xy[:, 1] - self.origin[1]) / self.res).astype(int), 0, self.shape[0] - 1)
        return i * self.shape[1] + j

    def plan(self) -> None:
        """Distance-to-goal fields [N, H*W] for the current goals (call after every reset)."""
        goals = self._cells(self.env.goal.cpu().numpy())
        fields = np.empty((len(goals), self.shape[0] * self.shape[1]), dtype=np.float32)
        for k in range(0, len(goals), 64):
            fields[k:k + 64] = dijkstra(self.graph, directed=True, indices=goals[k:k + 64])
        self.fields = fields

    def replan(self, envs: np.ndarray) -> None:
        if len(envs):
            goals = self._cells(self.env.goal[torch.as_tensor(envs)].cpu().numpy())
            self.fields[envs] = dijkstra(self.graph, directed=True, indices=goals)

    def act(self) -> torch.Tensor:
        """Normalised actions [N, 2] for the env's current state."""
        pose = self.env.pose.cpu().numpy().astype(np.float64)
        goal = self.env.goal.cpu().numpy().astype(np.float64)
        n, w = len(pose), self.shape[1]
        cell = self._cells(pose[:, :2])
        rows = np.arange(n)
        for _ in range(self.steps_ahead):  # steepest descent of each env's own field
            i, j = cell // w, cell % w
            best, best_d = cell, self.fields[rows, cell]
            for di, dj in _NEIGHBOURS:
                ii, jj = np.clip(i + di, 0, self.shape[0] - 1), np.clip(j + dj, 0, w - 1)
                cand = ii * w + jj
                d = self.fields[rows, cand]
                better = d < best_d
                best, best_d = np.where(better, cand, best), np.where(better, d, best_d)
            cell = best
        tx = self.origin[0] + (cell % w + 0.5) * self.res
        ty = self.origin[1] + (cell // w + 0.5) * self.res
        target = np.stack([tx, ty], axis=1)
        near = np.linalg.norm(goal - pose[:, :2], axis=1) < self.steps_ahead * self.res
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
