"""The wall map's visited channel (observation.wall_map_visited): the grid keeps the cell of every pose of a slot's
episode, against a pose-by-pose float64 reference, and nothing else changes (the walls' cells are those of a grid
without it); its image is :func:`wall_image` of the visited cells' centres, by either kernel; the env appends it
after the two channels it had, every other column bit for bit; a run trains with it, keeps it in the replay's uint8
columns and exports it so that the deploy runtime reads three channels; a bad setting or record names itself."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_wall_grid import random_grid, random_scans, step_pair

from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.wall_grid import HIT_BEYOND_M, WallGrid
from flashnav.sim.wall_image import wall_image
from flashnav.sim.observation import beam_angles

CPU = torch.device("cpu")


def pose_cells(pose: torch.Tensor, origin: torch.Tensor, cell: float, shape) -> list:
    """The (row, column) of each pose's centre, float64, None off the grid."""
    h, w = shape
    out = []
    for (x, y, _), (ox, oy) in zip(pose.double().tolist(), origin.double().tolist()):
        r, c = math.floor((y - oy) / cell), math.floor((x - ox) / cell)
        out.append((r, c) if 0 <= r < h and 0 <= c < w else None)
    return out


def visited_cells(grid: WallGrid, slot: int) -> set:
    return {divmod(int(f), grid.shape[1]) for f in torch.nonzero(grid.visited[slot, :-1]).flatten()}


def test_the_grid_keeps_the_cell_of_every_pose_of_each_slots_episode_and_the_same_walls():
    rng = np.random.default_rng(11)
    num, beams = 8, 72
    grid, angles = random_grid(rng, num)
    plain = WallGrid(num, grid.shape, grid.cell, grid.max_range, angles, CPU)
    grid = WallGrid(num, grid.shape, grid.cell, grid.max_range, angles, CPU, visited=True)
    origin = torch.as_tensor(rng.uniform(-3, 3, (num, 2)), dtype=torch.float32)
    want = [set() for _ in range(num)]
    every = torch.arange(num)
    for step in range(40):
        pose, ranges = random_scans(rng, grid, num, beams)
        # keep poses off the cells' edges, where float32 and float64 may differ: at most 0.4 of a cell from a centre
        cell_xy = torch.floor((pose[:, :2] - origin) / grid.cell)
        offset = torch.as_tensor(rng.uniform(0.1, 0.9, (num, 2)), dtype=torch.float32)
        pose[:, :2] = origin + (cell_xy + offset) * grid.cell
        if step % 10 == 0:  # a new episode in some slots: only their cells are forgotten
            idx = every[torch.as_tensor(rng.random(num) < 0.5)] if step else every
            for g in (grid, plain):
                g.start(idx, pose[idx], ranges[idx], origin[idx])
            for i in idx.tolist():
                want[i] = set()
            rest = torch.as_tensor([i for i in range(num) if i not in set(idx.tolist())], dtype=torch.long)
        else:
            rest = every
        if len(rest):
            for g in (grid, plain):
                g.push(rest, pose[rest], ranges[rest])
        for i, c in zip(every.tolist(), pose_cells(pose, origin, grid.cell, grid.shape)):
            if c is not None:
                want[i].add(c)
        for i in range(num):
            assert visited_cells(grid, i) == want[i]
        assert torch.equal(grid.known, plain.known)
    assert sum(len(w) for w in want) > 50
    with pytest.raises(ValueError, match="keeps no visited cells"):
        plain.centres(every, visited=True)


def random_marked_grid(rng: np.random.Generator, num: int, shape, **kwargs) -> WallGrid:
    """A grid of 0.25 m cells whose slots have random origins and a fifth of their cells marked (``kwargs``: the
    grid's ``visited`` / ``plan``)."""
    grid = WallGrid(num, shape, 0.25, 8.0, beam_angles(360.0, 8), CPU, **kwargs)
    grid.origin[:] = torch.as_tensor(rng.uniform(-3, 3, (num, 2)), dtype=torch.float32)
    grid.known[:, :-1] = torch.from_numpy(rng.random((num, shape[0] * shape[1])) < 0.2)
    return grid


def random_poses(rng: np.random.Generator, grid: WallGrid, span: tuple[float, float], reach: float, dtype):
    """Poses [N, 3] at fractions ``span`` of each slot's grid, goals within ``reach`` metres per axis of them, and
    the slots in a random order."""
    h, w = grid.shape
    num = grid.origin.shape[0]
    xy = grid.origin.double().numpy() + rng.uniform(*span, (num, 2)) * np.array([w, h]) * grid.cell
    pose = torch.as_tensor(np.concatenate([xy, rng.uniform(-math.pi, math.pi, (num, 1))], 1), dtype=dtype)
    goal = torch.as_tensor(xy + rng.uniform(-reach, reach, (num, 2)), dtype=dtype)
    return pose, goal, torch.from_numpy(rng.permutation(num))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_visited_channel_is_the_image_of_every_visited_centre_by_either_kernel(dtype):
    rng = np.random.default_rng(5)
    num, shape, cells, cell = 60, (40, 50), 12, 0.5
    grid = random_marked_grid(rng, num, shape, visited=True)
    grid.visited[:, :-1] = torch.from_numpy(rng.random((num, shape[0] * shape[1])) < 0.1)
    grid.visited[:, -1] = True  # the spare cell is never drawn
    pose, goal, idx = random_poses(rng, grid, (-0.2, 1.2), 9.0, dtype)
    got = grid.image(idx, pose, goal, cells, cell)
    grid.kernel = "torch"
    assert torch.equal(grid.image(idx, pose, goal, cells, cell), got)
    want = wall_image(grid.centres(idx).to(dtype), pose, goal, cells, cell,
                      visited=grid.centres(idx, visited=True).to(dtype))
    assert got.shape == (num, 3, cells, cells) and got.dtype == dtype
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    assert got[:, 2].sum() > 300 and not torch.equal(got[:, 2], got[:, 0])


def env_third_channel(key: str, extra: dict | None = None, **grid_kwargs) -> tuple[int, int]:
    """Steps a 2-channel wall-map env beside one with the wall map's extra channel ``key`` (an observation key; more
    robot keys in ``extra``) and a reference grid (``grid_kwargs``: that channel on) fed each slot's scans and poses
    from outside, through resets:
    every earlier column of the env is the 2-channel env's, bit for bit (and so are rewards and ends), the last
    channel the reference's. Returns (episodes ended, squares drawn in the channel)."""
    n, seed, cells, cell = 6, 3, 10, 0.4
    over = {"observation.wall_map": cells, "observation.wall_map_cell": cell, "observation.wall_map_grid": 0.2}
    plain_preset = load_robot("turtlebot2", **over)
    preset = load_robot("turtlebot2", **over, **{key: True}, **(extra or {}))
    assert preset.obs_dim == plain_preset.obs_dim + cells * cells and preset.observation.wall_map_channels == 3
    plain, env = make_env(plain_preset, n, seed=seed), make_env(preset, n, seed=seed)
    d = plain.obs_dim
    ref = WallGrid(n, env.extras.walls.shape, 0.2, preset.lidar.max_range, env.beam_angles, CPU, HIT_BEYOND_M,
                   **grid_kwargs)
    origin = torch.tensor([env.frame_map.origin], dtype=torch.float32).expand(n, 2)
    every = torch.arange(n)
    obs0, _ = plain.reset(seed=seed)
    obs1, _ = env.reset(seed=seed)
    ref.start(every, env.pose, env.scan(), origin)
    gen = torch.Generator().manual_seed(seed)
    resets = drawn = 0
    for _ in range(40):
        assert torch.equal(obs1[:, :d], obs0)
        want = ref.image(every, env.pose, env.goal, cells, cell)[:, 2].reshape(n, -1)
        assert torch.equal(obs1[:, d:], want)
        assert env.single_observation_space.contains(obs1[0].numpy())
        drawn += int(obs1[:, d:].sum())
        obs0, obs1, ended = step_pair(plain, env, ref, gen, lambda: origin)
        resets += ended
    return resets, drawn


def test_the_env_appends_the_visited_squares_and_keeps_every_other_column():
    """The env's wall map with the visited channel: its first two channels and every earlier column are the
    2-channel env's, bit for bit (and so are rewards and ends); the third is the image of a grid fed each slot's
    poses from outside, through resets."""
    resets, been = env_third_channel("observation.wall_map_visited", visited=True)
    assert resets >= 2 and been > 200


def test_the_setting_needs_a_wall_map_and_names_itself():
    with pytest.raises(ValueError, match="observation.wall_map_visited=true .*observation.wall_map is 0"):
        load_robot("turtlebot2", **{"observation.wall_map_visited": True})
    assert load_robot("turtlebot2", **{"observation.wall_map": 4}).observation.wall_map_channels == 2
    assert load_robot("turtlebot2").observation.wall_map_channels == 0


@pytest.mark.parametrize("cells, visited", [(0, False), (4, False), (4, True)])
def test_the_preset_the_networks_and_the_export_count_the_same_channels(cells, visited):
    from flashnav.export import policy_metadata
    from flashnav.learn.features import ObsLayout

    given = {"observation.wall_map": cells, "observation.wall_map_visited": visited}
    preset = load_robot("turtlebot2", **given)
    names = policy_metadata(preset)["observation"]["wall_map"]["channels"]
    n = {(0, False): 0, (4, False): 2, (4, True): 3}[cells, visited]
    assert names == ["walls", "goal", "visited"][:n]
    assert preset.observation.wall_map_channels == ObsLayout.from_robot(preset, 14.0).wall_channels == n


@pytest.mark.parametrize("channel", ["visited", "plan"])
def test_a_run_with_a_third_channel_trains_keeps_it_as_bits_and_exports_three_channels(tmp_path, channel):
    """With the visited channel or the plan's (tests/test_wall_plan.py)."""
    from flashnav import train
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import load_policy
    from flashnav.learn.artefacts import save_run
    from flashnav.observation_samples import sample_observations
    from tests.test_train import TINY, tiny

    over = {**TINY, "robot.observation.wall_map": 6, f"robot.observation.wall_map_{channel}": True,
            "algo.mirror": 0.5, "algo.wall_shift": 1}
    result = train(tiny(overrides=over), keep_replay=True)
    walls = result.learner.state.actor.walls
    assert walls.channels == 3 and walls.squares == 108 and walls.conv_weights[0].shape[1] == 3
    bits = result.replay.obs_bits  # all three channels' 108 squares as uint8, the robot's own path (or plan) among them
    assert bits.dtype == torch.uint8 and bits.shape[-1] == 108 and result.replay.obs.shape[-1] == 34
    rows = bits[: result.replay.size // result.replay.num_envs]
    assert set(rows.unique().tolist()) == {0, 1} and rows[..., 72:].sum() > 0
    out = save_run(result, tmp_path / "run")
    policy, meta = load_policy(out / "policy.onnx")
    wm = meta["observation"]["wall_map"]
    assert wm["channels"] == ["walls", "goal", channel] and wm["columns"] == [34, 34 + 108]
    assert meta["obs_dim"] == 34 + 108
    torch_policy, _ = load_policy(out / "policy.pt")
    obs = sample_observations(result.spec.robot, 5, torch.Generator().manual_seed(0), 14.0)
    assert obs.shape[1] == 142
    torch.testing.assert_close(torch.as_tensor(policy(obs)), torch_policy(obs), atol=1e-5, rtol=0)
    rt = PolicyRuntime.load(out / "policy.onnx")
    assert rt.wall_channels == 3 and rt.wall_channel_names == ("walls", "goal", channel)
    sectors, pose, goal, vel = np.full(30, 2.0, np.float32), (0.0, 0.0, 0.0), (1.0, 0.0), (0.0, 0.0)
    assert rt.observation(sectors, pose, goal, vel, wall_map=np.zeros(108)).shape == (142,)
    with pytest.raises(ValueError, match="wall_map must be 108 squares of 0 or 1 .*got 72"):
        rt.observation(sectors, pose, goal, vel, wall_map=np.zeros(72))


def test_the_metadata_reader_counts_the_channels_and_names_a_bad_list():
    from flashnav.export import policy_metadata
    from flashnav.policy_meta import wall_map_channels

    assert wall_map_channels(policy_metadata(load_robot("turtlebot2"))) == 0
    two = policy_metadata(load_robot("turtlebot2", **{"observation.wall_map": 4}))
    three = policy_metadata(load_robot("turtlebot2", **{"observation.wall_map": 4,
                                                        "observation.wall_map_visited": True}))
    assert (wall_map_channels(two), wall_map_channels(three)) == (2, 3)
    del two["observation"]["wall_map"]["channels"]  # a file written before the list: walls and goal
    assert wall_map_channels(two) == 2
    three["observation"]["wall_map"]["channels"] = ["walls", "visited", "goal"]
    with pytest.raises(ValueError, match="policy.onnx: .*wall-map channels \\['walls', 'visited', 'goal'\\]"):
        wall_map_channels(three, "policy.onnx")
