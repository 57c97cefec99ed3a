"""The plan's carrot (observation.wall_map_carrot, flashnav/maps/seen_plan.py carrot_points): on random grids the
grid's carrot is the centre of the first cell of the plan, walked from the robot (the Dijkstra walk of
tests/test_wall_plan.py), that lies the carrot's length of path away, seen from the robot and within that length of
it (the goal where the plan is shorter or there is none); the env puts its two columns after the pose trail and keeps
every other column; the robot's WallCells gives the grid's carrot; the networks scale it and the mirror flips it;
the metadata, the runtime and the settings name a bad value. kernel tests: tests/test_wall_plan.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_wall_plan import shortest_walk
from test_wall_visited import random_marked_grid, random_poses

from flashnav.maps.seen_plan import PLAN_MARGIN_M, carrot_points
from flashnav.presets import load_robot
from flashnav.sim.env import make_env

PLAN = {"observation.wall_map": 10, "observation.wall_map_cell": 0.4, "observation.wall_map_grid": 0.25,
        "observation.wall_map_plan": True, "observation.wall_map_plan_penalty": 2.0}


def reference_carrot(grid, slot: int, pose: np.ndarray, goal: np.ndarray, length: float) -> np.ndarray:
    """The carrot of one slot by hand: the Dijkstra walk of its plan (the grid's cells, checked there against scipy),
    the first cell at least ``length`` metres of path along it, its centre in the robot frame (else the goal), and
    brought within ``length`` metres."""
    h, w = grid.shape
    cell, org = grid.cell, grid.origin[slot].double().numpy()
    rc = [np.clip(np.floor((p[::-1] - org[::-1]) / cell).astype(int), 0, [h - 1, w - 1]) for p in (pose[:2], goal)]
    marks = grid.plan_cells(torch.tensor([slot]), torch.tensor(pose[None]), torch.tensor(goal[None]))[0][0, :-1]
    walk = shortest_walk(grid.known[slot, :-1].reshape(h, w).numpy(), tuple(rc[0]), tuple(rc[1]),
                         math.ceil(PLAN_MARGIN_M / cell - 1e-9), marks.numpy(), grid.plan_penalty)
    point = goal
    along = 0.0
    for a, b in zip(walk, walk[1:]):
        along += math.hypot(b[0] - a[0], b[1] - a[1]) * cell
        if along >= length - 1e-9:
            point = org + (np.array(b[::-1]) + 0.5) * cell
            break
    d = point - pose[:2]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    x, y = c * d[0] + s * d[1], -s * d[0] + c * d[1]
    return np.array([x, y]) * min(1.0, length / max(math.hypot(x, y), 1e-300))


@pytest.mark.parametrize("length", [0.6, 1.5])
def test_the_grids_carrot_is_the_walked_plans_cell_at_its_length_in_the_robot_frame(length):
    rng = np.random.default_rng(5)
    grid = random_marked_grid(rng, 16, (40, 40), plan=True, plan_penalty=2.0, carrot=length)
    pose, goal, idx = random_poses(rng, grid, (0.3, 0.7), 3.0, torch.float64)
    goal[:4] = pose[:4, :2] + 0.3  # goals nearer than the carrot's length of path: the carrot is the goal
    _, carrots = grid.plan_cells(idx, pose[idx], goal[idx])
    assert carrots.shape == (16, 2) and carrots.dtype == torch.float64
    kinds = set()
    for i, slot in enumerate(idx.tolist()):
        want = reference_carrot(grid, slot, pose[slot].numpy(), goal[slot].numpy(), length)
        np.testing.assert_allclose(carrots[i].numpy(), want, atol=1e-9)
        assert np.hypot(*carrots[i].numpy()) <= length + 1e-9
        d = goal[slot].numpy() - pose[slot, :2].numpy()
        kinds.add(bool(np.allclose(want, d @ np.array([[math.cos(pose[slot, 2]), -math.sin(pose[slot, 2])],
                                                       [math.sin(pose[slot, 2]), math.cos(pose[slot, 2])]]))))
    assert kinds == {True, False}  # some carrots at the goal itself, some along the plan


def test_carrot_points_take_the_goal_without_a_plan_and_bring_it_within_the_length():
    pose, goal = np.array([[1.0, 2.0, math.pi / 2]]), np.array([[1.0, 6.0]])  # the goal 4 m straight ahead
    for kind in (-1, 0):
        np.testing.assert_allclose(carrot_points([[5, 5, kind]], [[0.0, 0.0]], 0.25, pose, goal, 1.5), [[1.5, 0.0]],
                                   atol=1e-12)
    # kind 1: the cell's centre (row 9, column 5 of 0.25 m cells from the origin (-1, 0): (0.375, 2.375)), to the
    # right of a robot facing +y
    got = carrot_points([[9, 5, 1]], [[-1.0, 0.0]], 0.25, pose, goal, 1.5)
    np.testing.assert_allclose(got, [[0.375, 0.625]], atol=1e-12)


def test_the_env_puts_the_carrot_after_the_trail_and_keeps_every_other_column():
    n, seed = 6, 4
    plain_preset = load_robot("turtlebot2", **PLAN, **{"observation.pose_trail": 2})
    preset = load_robot("turtlebot2", **PLAN, **{"observation.pose_trail": 2, "observation.wall_map_carrot": 1.0})
    a, b = preset.trail_end, preset.carrot_end
    assert (b - a, preset.obs_dim) == (2, plain_preset.obs_dim + 2) and a == plain_preset.trail_end
    plain, env = make_env(plain_preset, n, seed=seed), make_env(preset, n, seed=seed)
    obs0, _ = plain.reset(seed=seed)
    obs1, _ = env.reset(seed=seed)
    gen = torch.Generator().manual_seed(seed)
    ends = 0
    for _ in range(30):
        assert torch.equal(torch.cat([obs1[:, :a], obs1[:, b:]], 1), obs0)
        for slot in range(n):  # (the env's grid holds this step's marks; the reference plans on them)
            want = reference_carrot(env.extras.walls, slot, env.pose[slot].double().numpy(),
                                    env.goal[slot].double().numpy(), 1.0)
            np.testing.assert_allclose(obs1[slot, a:b].numpy(), want, atol=2e-5)
        assert env.single_observation_space.contains(obs1[0].numpy())
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        obs0, r0, term0, trunc0, _ = plain.step(action)
        obs1, r1, term1, trunc1, _ = env.step(action)
        assert torch.equal(r0, r1) and torch.equal(term0, term1) and torch.equal(trunc0, trunc1)
        ends += int((term1 | trunc1).sum())
    assert ends >= 1


def test_the_robots_wall_cells_give_the_grids_carrot():
    """From the same marks, WallCells' carrot (odometry frame at the grid's origin) is the grid's."""
    from flashnav.deploy.memory import WallCells

    rng = np.random.default_rng(8)
    shape, g = (60, 60), 0.25
    grid = random_marked_grid(rng, 10, shape, plan=True, plan_penalty=2.0, carrot=1.0)
    grid.origin[:] = 0.0
    for slot in range(10):
        xy = rng.uniform(6.5, 8.5, 2)
        pose, goal = np.array([*xy, rng.uniform(-3, 3)]), xy + rng.uniform(-2.5, 2.5, 2)
        carrots = grid.plan_cells(torch.tensor([slot]), torch.tensor(pose[None]), torch.tensor(goal[None]))[1]
        robot = WallCells(12, 0.5, g, 8.0, plan=True, plan_penalty=2.0, carrot=1.0)
        at = torch.nonzero(grid.known[slot, :-1]).flatten().numpy()
        robot.known = np.stack([at % shape[1], at // shape[1]], 1)
        robot.step(pose, np.zeros(0), np.zeros(0), goal)
        np.testing.assert_allclose(robot.carrot_xy, carrots[0].numpy(), atol=1e-9)


def test_the_networks_scale_the_carrot_and_the_mirror_flips_its_y():
    from flashnav.learn.features import IPAPRec, ObsLayout
    from flashnav.learn.mirror import mirror_for

    preset = load_robot("turtlebot2", **PLAN, **{"observation.wall_map_carrot": 1.5})
    layout = ObsLayout.from_robot(preset, 14.0)
    assert layout.trail_end == preset.carrot_end and layout.memory_end == preset.memory_end
    assert layout.obs_dim == preset.obs_dim
    obs = torch.zeros(3, preset.obs_dim)
    obs[:, : preset.lidar.sectors] = 2.0
    obs[:, preset.trail_end: preset.carrot_end] = torch.tensor([[1.5, -0.75]] * 3)
    features = IPAPRec(layout)(obs)
    np.testing.assert_allclose(features[:, preset.trail_end: preset.carrot_end].detach().numpy(), [[1.0, -0.5]] * 3)
    flipped = mirror_for(preset, 1.0).obs(obs)
    assert flipped[0, preset.trail_end: preset.carrot_end].tolist() == [1.5, 0.75]


def test_the_setting_the_metadata_and_the_runtime_name_a_bad_carrot(tmp_path):
    import copy

    from test_export import random_actor

    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import export_policy

    with pytest.raises(ValueError, match=r"observation.wall_map_carrot=1 is a point along the plan, but "
                                         r"observation.wall_map_plan is false"):
        load_robot("turtlebot2", **{"observation.wall_map": 4, "observation.wall_map_carrot": 1.0})
    with pytest.raises(ValueError, match="wall_map_carrot"):
        load_robot("turtlebot2", **PLAN, **{"observation.wall_map_carrot": 4.0})  # past the plan's margin
    preset = load_robot("turtlebot2", **PLAN, **{"observation.wall_map_carrot": 1.0})
    rt = PolicyRuntime.load(export_policy(random_actor(preset, seed=2), preset, tmp_path)["onnx"])
    assert rt.carrot == 1.0 and rt.meta["observation"]["carrot"]["columns"] == [preset.trail_end, preset.carrot_end]
    controller = Controller(rt)
    assert controller.walls.carrot == 1.0
    sectors, pose, goal = np.full(preset.lidar.sectors, 3.0), (0.0, 0.0, 0.0), (3.0, 1.0)
    walls = controller.walls.step(pose, np.zeros(0), np.zeros(0), goal)
    obs = rt.observation(sectors, pose, goal, (0.0, 0.0), wall_map=walls, carrot=controller.walls.carrot_xy)
    assert obs.shape == (preset.obs_dim,)
    np.testing.assert_allclose(obs[preset.trail_end: preset.carrot_end], controller.walls.carrot_xy, atol=1e-6)
    with pytest.raises(ValueError, match=r"carrot must be 2 finite numbers .*wall_map_carrot 1 m\), got None"):
        rt.observation(sectors, pose, goal, (0.0, 0.0), wall_map=walls)
    meta = copy.deepcopy(rt.meta)
    for bad in (-1.0, "1", float("nan"), True):
        meta["observation"]["carrot"]["length_m"] = bad
        with pytest.raises(ValueError, match="policy.onnx: the policy's metadata records observation.carrot.length_m"):
            PolicyRuntime(rt.session, meta, "policy.onnx")
    plain = load_robot("turtlebot2", **PLAN)  # a policy without a carrot refuses one
    plain_rt = PolicyRuntime.load(export_policy(random_actor(plain, seed=2), plain, tmp_path / "plain")["onnx"])
    with pytest.raises(ValueError, match=r"carrot: the policy has no carrot \(observation.wall_map_carrot 0\), "
                                         r"got \[0.5, 0.0\]"):
        plain_rt.observation(sectors, pose, goal, (0.0, 0.0), wall_map=walls, carrot=[0.5, 0.0])
    meta["observation"]["carrot"] = None  # the preset's value is named where the metadata block is missing
    meta["preset"]["observation"]["wall_map_carrot"] = -2.0
    with pytest.raises(ValueError, match="records preset.observation.wall_map_carrot -2.0"):
        PolicyRuntime(rt.session, meta, "policy.onnx")
    # a policy exported before the carrot: none (the preset block has no such key either)
    del meta["observation"]["carrot"]
    del meta["preset"]["observation"]["wall_map_carrot"]
    with pytest.raises(ValueError, match="obs_dim"):  # its columns are there, so the layout no longer fits
        PolicyRuntime(rt.session, meta, "policy.onnx")


def test_a_run_with_the_carrot_trains_mirrored_and_shifted_and_exports_it(tmp_path):
    from flashnav import train
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import load_policy
    from flashnav.learn.artefacts import save_run
    from flashnav.observation_samples import sample_observations
    from tests.test_train import TINY, tiny

    over = {**TINY, "robot.observation.wall_map": 6, "robot.observation.wall_map_plan": True,
            "robot.observation.wall_map_carrot": 1.0, "algo.mirror": 0.5, "algo.wall_shift": 1}
    result = train(tiny(overrides=over), keep_replay=True)
    preset = result.spec.robot
    a, b = preset.trail_end, preset.carrot_end
    assert result.replay.obs.shape[-1] == b  # the vector columns, the carrot last; the squares kept as bits
    carrots = result.replay.obs[: result.replay.size // result.replay.num_envs][..., a:b]
    norms = carrots.reshape(-1, 2).norm(dim=-1)
    assert (norms <= 1.0 + 1e-5).all() and (norms > 0.5).float().mean() > 0.5  # most carrots 1 m along a plan
    out = save_run(result, tmp_path / "run")
    policy, meta = load_policy(out / "policy.onnx")
    assert meta["observation"]["carrot"] == {**meta["observation"]["carrot"], "length_m": 1.0, "columns": [a, b]}
    assert meta["observation"]["memory_scan"]["columns"] == [b, b]
    torch_policy, _ = load_policy(out / "policy.pt")
    obs = sample_observations(preset, 5, torch.Generator().manual_seed(0), 14.0)
    assert obs.shape[1] == preset.obs_dim and (obs[:, a:b].abs() <= 1.0).all()
    torch.testing.assert_close(torch.as_tensor(policy(obs)), torch_policy(obs), atol=1e-5, rtol=0)
    rt = PolicyRuntime.load(out / "policy.onnx")
    assert rt.carrot == 1.0 and rt.obs_dim == preset.obs_dim
