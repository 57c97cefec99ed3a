"""The wall map's plan channel (observation.wall_map_plan, flashnav/maps/seen_plan.py): on random grids the kernel's
path is a shortest 8-connected path (no corner cut) from the robot's cell to the goal's over the unmarked cells of its
box, checked step by step against scipy's Dijkstra on that box, and nothing is marked when the goal is walled off;
the grid draws it by either kernel as wall_image draws its cells' centres; the env appends it last, every other
column bit for bit; the robot's WallCells plans the same cells from its own marks; a bad setting names itself;
tests/test_wall_visited.py trains and exports a run with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.sparse.csgraph import dijkstra
from test_wall_visited import env_third_channel, random_marked_grid, random_poses

from flashnav.maps.graph import grid_graph
from flashnav.maps.seen_plan import PLAN_MARGIN_M, plan_cells, plan_route
from flashnav.presets import load_robot
from flashnav.sim.wall_grid import WallGrid
from flashnav.sim.wall_image import wall_image

MOVES = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj]


def check_shortest(known: np.ndarray, start, goal, margin: int, marks: np.ndarray, penalty: float = 0.0) -> int:
    """The number of cells of :func:`shortest_walk` (its checks made)."""
    return len(shortest_walk(known, start, goal, margin, marks, penalty))


def shortest_walk(known: np.ndarray, start, goal, margin: int, marks: np.ndarray, penalty: float = 0.0) -> list:
    """Asserts that ``marks`` [H W] (one slot's plan on the grid ``known`` [H, W]) is exactly the cells of a shortest
    8-connected path (no corner cut) from ``start`` to ``goal`` over the unmarked cells of the box around both
    (the two cells always free), by scipy's Dijkstra on the box - the cheapest, with a cell beside a marked cell of
    the box costing 1 + ``penalty`` times a move into it; returns the path's cells from the robot's to the goal's,
    none where scipy finds none."""
    h, w = known.shape
    (sr, sc), (gr, gc) = start, goal
    r0, r1 = max(0, min(sr, gr) - margin), min(h - 1, max(sr, gr) + margin)
    c0, c1 = max(0, min(sc, gc) - margin), min(w - 1, max(sc, gc) + margin)
    free = ~known[r0:r1 + 1, c0:c1 + 1]
    free[sr - r0, sc - c0] = free[gr - r0, gc - c0] = True
    bw = c1 - c0 + 1
    walls = np.pad(~free, 1, constant_values=False)  # a cell beside a marked cell of the box, by brute force
    near = np.zeros_like(free)
    for di, dj in MOVES:
        near |= walls[1 + di: 1 + di + free.shape[0], 1 + dj: 1 + dj + free.shape[1]]
    cost = 1.0 + penalty * near
    dist = dijkstra(grid_graph(free, 1.0, cost), indices=(gr - r0) * bw + (gc - c0)).reshape(free.shape)
    marked = {divmod(int(f), w) for f in np.flatnonzero(marks)}
    if not np.isfinite(dist[sr - r0, sc - c0]):
        assert not marked
        return []
    assert all(r0 <= r <= r1 and c0 <= c <= c1 and free[r - r0, c - c0] for r, c in marked)
    at, walked = (sr, sc), [(sr, sc)]
    while at != (gr, gc):  # the next cell: a marked neighbour one step of a cheapest way nearer the goal
        here = dist[at[0] - r0, at[1] - c0]
        steps = [(dist[at[0] + di - r0, at[1] + dj - c0], di, dj) for di, dj in MOVES
                 if (at[0] + di, at[1] + dj) in marked and (at[0] + di, at[1] + dj) not in walked
                 and (not (di and dj) or (free[at[0] + di - r0, at[1] - c0] and free[at[0] - r0, at[1] + dj - c0]))
                 and math.isclose(here - dist[at[0] + di - r0, at[1] + dj - c0],
                                  math.hypot(di, dj) * cost[at[0] - r0, at[1] - c0], abs_tol=1e-9)]
        assert steps, f"the plan breaks off at {at}"
        _, di, dj = min(steps)
        at = (at[0] + di, at[1] + dj)
        walked.append(at)
    assert set(walked) == marked
    return walked


@pytest.mark.parametrize("penalty", [0.0, 2.0])
@pytest.mark.parametrize("density", [0.15, 0.3, 0.45])
def test_the_plan_is_a_shortest_path_over_the_unmarked_cells_of_its_box_against_scipy(density, penalty):
    rng = np.random.default_rng(int(density * 100))
    num, (h, w) = 40, (30, 45)
    known = np.zeros((num, h * w + 1), dtype=bool)
    known[:, :-1] = rng.random((num, h * w)) < density
    known[:, -1] = True  # the spare cell: never read
    rows = rng.permutation(num)[:30]
    start = np.stack([rng.integers(0, h, 30), rng.integers(0, w, 30)], 1)
    goal = np.clip(start + rng.integers(-12, 13, (30, 2)), 0, [h - 1, w - 1])
    margin = int(rng.integers(0, 6))
    out = plan_cells(known, rows, start, goal, (h, w), margin, penalty)
    assert out.shape == (30, h * w + 1) and not out[:, -1].any()
    lengths = [check_shortest(known[r, :-1].reshape(h, w), start[i], goal[i], margin, out[i, :-1], penalty)
               for i, r in enumerate(rows)]
    assert sum(n > 0 for n in lengths) >= 5 and max(lengths) > 8  # paths found, some long


@pytest.mark.parametrize("penalty", [0.0, 2.0])
def test_the_carrot_is_the_first_cell_of_the_walked_plan_at_its_path_length(penalty):
    rng = np.random.default_rng(11)
    num, (h, w) = 30, (25, 35)
    known = np.zeros((num, h * w + 1), dtype=bool)
    known[:, :-1] = rng.random((num, h * w)) < 0.3
    rows = rng.permutation(num)[:24]
    start = np.stack([rng.integers(0, h, 24), rng.integers(0, w, 24)], 1)
    goal = np.clip(start + rng.integers(-10, 11, (24, 2)), 0, [h - 1, w - 1])
    kinds = set()
    for carrot in (0.0, 1.0, 4.0, 5.5):
        cells, carrots = plan_route(known, rows, start, goal, (h, w), 3, penalty, carrot)
        assert np.array_equal(cells, plan_cells(known, rows, start, goal, (h, w), 3, penalty))
        for i, r in enumerate(rows):
            walk = shortest_walk(known[r, :-1].reshape(h, w), start[i], goal[i], 3, cells[i, :-1], penalty)
            if not walk or carrot == 0.0:
                assert tuple(carrots[i]) == (-1, -1, -1)
                continue
            along = np.cumsum([0.0] + [math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(walk, walk[1:])])
            at = np.flatnonzero(along >= carrot - 1e-9)
            want = (*walk[at[0]], 1) if len(at) else (*walk[-1], 0)
            assert tuple(carrots[i]) == want
            kinds.add(want[2])
    assert kinds == {0, 1}  # both kinds met: along the plan, and the goal's cell of a shorter plan
    with pytest.raises(ValueError, match=r"carrot must be a finite number of cells >= 0, got -1"):
        plan_route(known, rows, start, goal, (h, w), 3, penalty, -1.0)


def test_a_walled_off_goal_gets_no_plan_and_an_open_grid_the_straight_way():
    h = w = 20
    known = np.zeros((2, h * w + 1), dtype=bool)
    ring = np.zeros((h, w), dtype=bool)
    ring[8:13, 8:13] = True
    ring[9:12, 9:12] = False
    known[1, :-1] = ring.reshape(-1)  # slot 1: the goal (10, 10) inside a closed ring
    out = plan_cells(known, np.array([0, 1]), np.array([[2, 3], [2, 3]]), np.array([[10, 10], [10, 10]]), (h, w), 3)
    assert not out[1].any()
    cells = {divmod(int(f), w) for f in np.flatnonzero(out[0])}
    assert (2, 3) in cells and (10, 10) in cells and len(cells) == 9  # 7 diagonal moves and 1 straight one
    # a goal or a start off the grid is brought onto its edge; so is a margin past the grid
    out = plan_cells(known[:1], np.array([0]), np.array([[-5, 3]]), np.array([[50, 3]]), (h, w), 100)
    assert {divmod(int(f), w) for f in np.flatnonzero(out[0])} == {(r, 3) for r in range(h)}
    with pytest.raises(ValueError, match="known must be \\[N, 401\\] for a 20 x 20 grid"):
        plan_cells(known[:, :-1], np.array([0]), np.array([[0, 0]]), np.array([[1, 1]]), (h, w), 1)


def test_a_penalty_keeps_the_plan_off_the_walls_where_there_is_room_and_through_the_only_gap():
    h, w = 9, 30
    corridor = np.zeros((h, w), dtype=bool)
    corridor[0, :] = corridor[-1, :] = True  # walls along rows 0 and 8: rows 2-6 are beside none
    crossed = corridor.copy()
    crossed[:4, 15] = crossed[5:, 15] = True  # slot 1: a wall across column 15 but for one cell, (4, 15)
    known = np.stack([np.append(g.reshape(-1), False) for g in (corridor, crossed)])
    start, goal = np.array([[1, 1], [1, 1]]), np.array([[1, 28], [1, 28]])  # both beside the wall of row 0

    def cells(penalty):
        out = plan_cells(known, np.array([0, 1]), start, goal, (h, w), 3, penalty)[:, :-1].reshape(2, h, w)
        return [{tuple(int(v) for v in rc) for rc in np.argwhere(o)} for o in out]

    (plain, plain_gap), (dear, dear_gap) = cells(0.0), cells(2.0)
    assert plain == {(1, c) for c in range(1, 29)}  # the straight way, every cell beside the wall
    assert {r for r, _ in dear} == {1, 2} and sum(r == 1 for r, _ in dear) == 2  # one row off it, but its ends
    assert (4, 15) in plain_gap and (4, 15) in dear_gap  # the only gap (inside the box, rows 0-4): both pass it
    with pytest.raises(ValueError, match="penalty must be a finite number >= 0, got -1.0"):
        plan_cells(known, np.array([0]), start[:1], goal[:1], (h, w), 3, -1.0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_plan_channel_is_the_image_of_the_plans_centres_by_either_kernel(dtype):
    rng = np.random.default_rng(7)
    num, shape, cells, cell = 50, (40, 50), 12, 0.5
    grid = random_marked_grid(rng, num, shape, plan=True)
    pose, goal, idx = random_poses(rng, grid, (0.1, 0.9), 4.0, dtype)
    got = grid.image(idx, pose, goal, cells, cell)
    grid.kernel = "torch"
    assert torch.equal(grid.image(idx, pose, goal, cells, cell), got)
    marks = grid.plan_cells(idx, pose, goal)[0]
    for kernel in ("torch", "numba"):  # the plan handed in (as the simulator's extras do) draws the same image
        grid.kernel = kernel
        assert torch.equal(grid.image(idx, pose, goal, cells, cell, marks), got)
    h, w = shape
    r, c = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    centres = (torch.stack([c, r], -1).reshape(-1, 2).double() + 0.5) * 0.25 + grid.origin[idx].double()[:, None]
    plan = torch.where(marks[:, :-1, None], centres, math.inf).to(dtype)
    want = wall_image(grid.centres(idx).to(dtype), pose, goal, cells, cell, plan=plan)
    assert got.shape == (num, 3, cells, cells) and got.dtype == dtype
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    assert got[:, 2].sum() > 200 and torch.equal(got[:, :2], WallGrid.image(
        _without_plan(grid), idx, pose, goal, cells, cell))
    # the plan's own cells: a shortest path on each slot's grid (the cells of pose and goal, as the grid takes them)
    org = grid.origin[idx].to(dtype)
    for i in range(0, num, 7):
        rc = [tuple(torch.floor((p[[1, 0]] - org[i, [1, 0]]) / 0.25).long().clamp(0, max(shape) - 1).tolist())
              for p in (pose[i, :2], goal[i])]
        rc = [(min(a, h - 1), min(b, w - 1)) for a, b in rc]
        check_shortest(grid.known[idx[i], :-1].reshape(h, w).numpy(), rc[0], rc[1],
                       math.ceil(PLAN_MARGIN_M / 0.25 - 1e-9), marks[i, :-1].numpy())


def _without_plan(grid: WallGrid) -> WallGrid:
    grid.plan = False
    return grid


def test_the_env_appends_the_plan_squares_last_and_keeps_every_other_column():
    """The env's wall map with the plan channel: every earlier column (the wall map's first two channels included)
    is the 2-channel env's, bit for bit (and so are rewards and ends); the last is the plan of a grid fed each slot's
    scans from outside, through resets, to the env's goals."""
    resets, drawn = env_third_channel("observation.wall_map_plan", plan=True)
    assert resets >= 2 and drawn > 200
    # the penalty reaches the env's grid: its plan is a reference grid's at the same penalty
    resets, drawn = env_third_channel("observation.wall_map_plan", {"observation.wall_map_plan_penalty": 2.0},
                                      plan=True, plan_penalty=2.0)
    assert resets >= 2 and drawn > 200


@pytest.mark.parametrize("penalty", [0.0, 2.0])
def test_the_robots_wall_cells_plan_the_grids_cells(penalty):
    """The deploy side (flashnav/deploy/memory.py): from the same marks, WallCells plans the cells the simulator's grid
    plans (the grid at the odometry origin, robot and goal away from its edges, where the grid clips the box)."""
    from flashnav.deploy.memory import WallCells

    rng = np.random.default_rng(3)
    shape, g = (60, 60), 0.25
    grid = random_marked_grid(rng, 12, shape, plan=True, plan_penalty=penalty)
    grid.origin[:] = 0.0
    found = 0
    for slot in range(12):
        xy = rng.uniform(6.5, 8.5, 2)
        pose, goal = np.array([*xy, 0.3]), xy + rng.uniform(-2.5, 2.5, 2)
        marks = grid.plan_cells(torch.tensor([slot]), torch.tensor(pose[None]), torch.tensor(goal[None]))[0][0, :-1]
        want = {(int(f) % shape[1], int(f) // shape[1]) for f in torch.nonzero(marks).flatten()}
        robot = WallCells(12, 0.5, g, 8.0, plan=True, plan_penalty=penalty)
        at = torch.nonzero(grid.known[slot, :-1]).flatten().numpy()
        robot.known = np.stack([at % shape[1], at // shape[1]], 1)
        got = {tuple(int(v) for v in np.floor(c / g)) for c in robot.plan_centres(pose, goal)}
        assert got == want
        found += bool(want)
        image = robot.step(pose, np.zeros(0), np.zeros(0), goal).reshape(3, 12, 12)
        assert image[2].sum() >= 1 if want else image[2].sum() == 0
    assert found >= 6


def test_the_setting_needs_a_wall_map_and_the_metadata_lists_the_plan():
    from flashnav.export import policy_metadata
    from flashnav.learn.features import ObsLayout
    from flashnav.policy_meta import wall_map_channel_list, wall_map_channels

    with pytest.raises(ValueError, match="observation.wall_map_plan=true .*observation.wall_map is 0"):
        load_robot("turtlebot2", **{"observation.wall_map_plan": True})
    with pytest.raises(ValueError, match="observation.wall_map_plan_penalty=2 .*observation.wall_map_plan is false"):
        load_robot("turtlebot2", **{"observation.wall_map": 4, "observation.wall_map_plan_penalty": 2.0})
    for visited, names in ((False, ["walls", "goal", "plan"]), (True, ["walls", "goal", "visited", "plan"])):
        preset = load_robot("turtlebot2", **{"observation.wall_map": 4, "observation.wall_map_visited": visited,
                                             "observation.wall_map_plan": True})
        meta = policy_metadata(preset)
        assert meta["observation"]["wall_map"]["channels"] == names
        assert meta["observation"]["wall_map"]["plan_margin_m"] == PLAN_MARGIN_M
        assert meta["observation"]["wall_map"]["plan_penalty"] == 0.0
        assert wall_map_channel_list(meta) == tuple(names) and wall_map_channels(meta) == len(names)
        assert preset.observation.wall_map_channels == ObsLayout.from_robot(preset, 14.0).wall_channels == len(names)
    meta["observation"]["wall_map"]["channels"] = ["walls", "goal", "plan", "visited"]
    with pytest.raises(ValueError, match="policy.onnx: .*wall-map channels \\['walls', 'goal', 'plan', 'visited'\\]"):
        wall_map_channels(meta, "policy.onnx")



def test_the_runtime_refuses_a_plan_drawn_within_another_margin(tmp_path):
    import copy

    from test_export import random_actor

    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import export_policy

    preset = load_robot("turtlebot2", **{"observation.wall_map": 6, "observation.wall_map_plan": True})
    rt = PolicyRuntime.load(export_policy(random_actor(preset, seed=1), preset, tmp_path)["onnx"])
    assert rt.wall_channel_names == ("walls", "goal", "plan")
    meta = copy.deepcopy(rt.meta)
    meta["observation"]["wall_map"]["plan_margin_m"] = 5.0
    with pytest.raises(ValueError, match="policy.onnx: the policy's plan channel was drawn within plan_margin_m 5.0 "
                                         "of the robot and the goal; this runtime plans within 3.0 m"):
        PolicyRuntime(rt.session, meta, "policy.onnx")


def test_the_runtime_plans_at_the_policys_penalty_and_names_a_bad_one(tmp_path):
    import copy

    from test_export import random_actor

    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import export_policy

    preset = load_robot("turtlebot2", **{"observation.wall_map": 6, "observation.wall_map_plan": True,
                                         "observation.wall_map_plan_penalty": 1.5})
    rt = PolicyRuntime.load(export_policy(random_actor(preset, seed=1), preset, tmp_path)["onnx"])
    assert rt.plan_penalty == 1.5 and Controller(rt).walls.plan_penalty == 1.5
    meta = copy.deepcopy(rt.meta)
    del meta["observation"]["wall_map"]["plan_penalty"]  # a policy exported before the key: the shortest way
    assert PolicyRuntime(rt.session, meta, "policy.onnx").plan_penalty == 0.0
    for bad in (-1.0, "2", float("nan"), True):
        meta["observation"]["wall_map"]["plan_penalty"] = bad
        with pytest.raises(ValueError, match="policy.onnx: observation.wall_map.plan_penalty must be a number >= 0"):
            PolicyRuntime(rt.session, meta, "policy.onnx")
