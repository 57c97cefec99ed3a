"""The dense memory of hits (flashnav.sim.wall_grid.WallGrid): the cells it marks are those of every beam's hit,
against a beam-by-beam float64 reference (up to points within EDGE of a cell's edge, which float32 may put on
either side); its image is :func:`wall_image` of every marked cell's centre, drawn from a window; a start or a
push of some slots leaves the others bit-identical; fed from an env's scans, it marks walls."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_pose_trail import forward_actions  # seeded, forward-biased actions: episodes end, slots reset

from flashnav.maps import generate_map
from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.wall_grid import HIT_BEYOND_M, WallGrid
from flashnav.sim.wall_image import wall_image
from flashnav.sim.observation import beam_angles

#: metres: a hit this close to a cell's edge may fall in either cell in float32
EDGE = 1e-4
CPU = torch.device("cpu")


def reference_cells(pose, ranges, angles, origin, cell: float, shape, max_range: float, beyond: float = 0.0):
    """(every cell a hit certainly lies in, every cell a hit lies in or within EDGE of): beam by beam, float64."""
    sure, near = set(), set()
    h, w = shape
    for (x, y, yaw), row in zip(pose, ranges):
        for r, a in zip(row, angles):
            if not r < max_range:  # max range, inf and NaN: no hit
                continue
            px, py = x + (r + beyond) * math.cos(a + yaw), y + (r + beyond) * math.sin(a + yaw)
            fc, fr = (px - origin[0]) / cell, (py - origin[1]) / cell
            cols = {math.floor(fc + d) for d in (-EDGE / cell, 0.0, EDGE / cell)}
            rows = {math.floor(fr + d) for d in (-EDGE / cell, 0.0, EDGE / cell)}
            cells = {(i, j) for i in rows for j in cols if 0 <= i < h and 0 <= j < w}
            near |= cells
            if len(cols) == 1 and len(rows) == 1:
                sure |= cells
    return sure, near


def marked(grid: WallGrid, slot: int) -> set:
    h, w = grid.shape
    return {divmod(int(f), w) for f in torch.nonzero(grid.known[slot, :-1]).flatten()}


def random_grid(rng: np.random.Generator, num: int, shape=(24, 40), cell=0.25, beams=72, max_range=3.0,
                beyond=0.0):
    angles = beam_angles(360.0, beams)
    grid = WallGrid(num, shape, cell, max_range, angles, CPU, beyond)
    grid.origin[:] = torch.as_tensor(rng.uniform(-3, 3, (num, 2)), dtype=torch.float32)
    return grid, angles


def random_scans(rng: np.random.Generator, grid: WallGrid, k: int, beams: int):
    o = grid.origin[:k].numpy()
    h, w = grid.shape
    pose = np.stack([o[:, 0] + rng.uniform(-0.5, w * grid.cell + 0.5, k), o[:, 1] + rng.uniform(-0.5, h * grid.cell + 0.5, k),
                     rng.uniform(-math.pi, math.pi, k)], 1).astype(np.float32)
    ranges = rng.uniform(0.1, 1.3 * grid.max_range, (k, beams)).astype(np.float32)  # some beyond max range
    ranges[rng.random((k, beams)) < 0.05] = grid.max_range
    ranges[rng.random((k, beams)) < 0.05] = np.inf
    ranges[rng.random((k, beams)) < 0.05] = np.nan  # an invalid reading: no hit
    return torch.from_numpy(pose), torch.from_numpy(ranges)


@pytest.mark.parametrize("seed,beyond", [(0, 0.0), (1, 0.0), (2, 0.1)])
def test_the_grid_marks_the_cells_of_every_hit_against_a_beam_by_beam_reference(seed, beyond):
    rng = np.random.default_rng(seed)
    grid, angles = random_grid(rng, 5, beyond=beyond)
    pose, ranges = random_scans(rng, grid, 5, 72)
    grid.start(torch.arange(5), pose, ranges)
    more_pose, more_ranges = random_scans(rng, grid, 5, 72)
    idx = torch.tensor([3, 0])
    grid.push(idx, more_pose[:2], more_ranges[:2])
    total = 0
    for n in range(5):
        scans = [(pose[n], ranges[n])] + [(more_pose[i], more_ranges[i]) for i, s in enumerate(idx) if s == n]
        sure, near = set(), set()
        for p, r in scans:
            s, q = reference_cells(p[None].double().tolist(), r[None].double().tolist(), angles.double().tolist(),
                                   grid.origin[n].double().tolist(), grid.cell, grid.shape, grid.max_range, beyond)
            sure, near = sure | s, near | q
        got = marked(grid, n)
        assert sure <= got <= near, (n, sure - got, got - near)
        total += len(sure)
    assert total > 100  # the draw reaches the grid


@pytest.mark.parametrize("kernel", ["numba", "torch"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("cells,cell,grid_cell", [(24, 0.5, 0.25), (10, 0.3, 0.1), (6, 0.25, 0.5), (8, 0.5, 0.5)])
def test_the_image_draws_every_marked_cells_centre(dtype, cells, cell, grid_cell, kernel):
    """From a window of the grid, the same image as :func:`wall_image` of every marked centre, with the robot
    inside, at the edge of and off the grid (a window partly or wholly off it), by either kernel."""
    rng = np.random.default_rng(cells)
    num, shape = 6, (30, 45)
    grid = WallGrid(num, shape, grid_cell, 8.0, beam_angles(360.0, 8), CPU)
    assert grid.kernel == "numba"  # the CPU default
    grid.kernel = kernel
    grid.origin[:] = torch.as_tensor(rng.uniform(-2, 2, (num, 2)), dtype=torch.float32)
    grid.known[:, :-1] = torch.from_numpy(rng.random((num, shape[0] * shape[1])) < 0.3)
    grid.known[:, -1] = True  # the spare cell (where dropped hits go) is never drawn
    o = grid.origin.double().numpy()
    size = np.array([shape[1], shape[0]]) * grid_cell
    xy = o + rng.uniform(0.05, 0.95, (num, 2)) * size
    xy[0] = o[0] + size / 2  # the middle
    xy[1] = o[1] - 0.6 * cells * cell  # off the grid's corner, the image's corner on it
    xy[2, 0] = o[2, 0]  # on the grid's edge: half the window off it
    pose = torch.as_tensor(np.concatenate([xy, rng.uniform(-math.pi, math.pi, (num, 1))], 1), dtype=dtype)
    goal = torch.as_tensor(xy + rng.uniform(-6, 6, (num, 2)), dtype=dtype)
    idx = torch.tensor([0, 5, 1, 3, 2, 4])
    got = grid.image(idx, pose, goal, cells, cell)
    want = wall_image(grid.centres(idx).to(dtype), pose, goal, cells, cell)
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    assert got.dtype == dtype and got[:, 0].sum() > 10 and got[:, 1].sum((1, 2)).eq(1).all()
    with pytest.raises(ValueError, match="at least 2 cells"):
        grid.image(idx, pose, goal, 1, cell)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_numba_kernel_draws_the_torch_paths_squares_bit_for_bit(dtype):
    """Many random slots, poses (headings on the grid's axes too, where centres line up with squares' edges) and
    windows off the grid: the CPU kernel's image equals the torch path's exactly."""
    rng = np.random.default_rng(7)
    num, shape = 400, (50, 70)
    grid = WallGrid(num, shape, 0.25, 8.0, beam_angles(360.0, 8), CPU)
    grid.origin[:] = torch.as_tensor(rng.uniform(-3, 3, (num, 2)), dtype=torch.float32)
    grid.known[:, :-1] = torch.from_numpy(rng.random((num, shape[0] * shape[1])) < 0.2)
    o = grid.origin.double().numpy()
    xy = o + rng.uniform(-0.2, 1.2, (num, 2)) * np.array([shape[1], shape[0]]) * 0.25
    xy[::3] = np.round(xy[::3] * 8) / 8  # on cell edges and centres
    heading = rng.uniform(-math.pi, math.pi, num)
    heading[::2] = rng.integers(-2, 3, num // 2) * (math.pi / 2)
    pose = torch.as_tensor(np.concatenate([xy, heading[:, None]], 1), dtype=dtype)
    goal = torch.as_tensor(xy + rng.uniform(-9, 9, (num, 2)), dtype=dtype)
    idx = torch.from_numpy(rng.permutation(num))
    got = grid.image(idx, pose, goal, 24, 0.5)
    grid.kernel = "torch"
    want = grid.image(idx, pose, goal, 24, 0.5)
    assert torch.equal(got, want) and got[:, 0].sum() > 1000


def test_a_start_clears_its_slots_only_and_a_push_leaves_the_others_bit_identical():
    rng = np.random.default_rng(7)
    grid, _ = random_grid(rng, 4)
    pose, ranges = random_scans(rng, grid, 4, 72)
    grid.start(torch.arange(4), pose, ranges)
    for _ in range(3):
        p, r = random_scans(rng, grid, 4, 72)
        grid.push(torch.arange(4), p, r)
    before_known, before_origin = grid.known.clone(), grid.origin.clone()
    p, r = random_scans(rng, grid, 1, 72)
    grid.start(torch.tensor([2]), p, r, origin=torch.tensor([[10.0, -4.0]]))
    keep = torch.tensor([0, 1, 3])
    assert torch.equal(grid.known[keep], before_known[keep]) and torch.equal(grid.origin[keep], before_origin[keep])
    assert grid.origin[2].tolist() == [10.0, -4.0]
    fresh, _ = random_grid(rng, 1)
    fresh.origin[:] = grid.origin[2]
    fresh.start(torch.tensor([0]), p, r)
    assert torch.equal(grid.known[2, :-1], fresh.known[0, :-1])  # the old episode's marks are gone
    before = grid.known.clone()
    grid.push(torch.tensor([True, False, False, True]), *random_scans(rng, grid, 2, 72))  # a mask selects too
    assert torch.equal(grid.known[1:3], before[1:3]) and (grid.known[[0, 3]] >= before[[0, 3]]).all()


def test_covering_spans_the_map_and_bad_arguments_name_the_values():
    from flashnav.maps.grid import OccupancyMap

    geo = OccupancyMap(occupied=np.zeros((101, 60), dtype=bool), resolution=0.05, origin=(-1.0, 2.5))
    grid = WallGrid.covering(geo, 3, 0.25, 8.0, beam_angles(360.0, 8), CPU)
    assert grid.shape == (21, 12) and grid.origin.tolist() == [[-1.0, 2.5]] * 3  # 5.05 m x 3.0 m
    assert WallGrid.covering(geo, 1, 0.05, 8.0, beam_angles(360.0, 8), CPU).shape == (101, 60)
    for args, said in (((0, (2, 2), 0.1), "num_envs >= 1"), ((2, (0, 5), 0.1), "0 x 5"),
                       ((2, (3, 3), -0.1), "-0.1"), ((2, (3, 3), math.nan), "nan")):
        with pytest.raises(ValueError, match=said):
            WallGrid(*args, 8.0, beam_angles(360.0, 8), CPU)
    with pytest.raises(ValueError, match="beyond must be >= 0 metres, got -0.01"):
        WallGrid(2, (3, 3), 0.1, 8.0, beam_angles(360.0, 8), CPU, beyond=-0.01)


def test_fed_from_an_envs_scans_the_grid_marks_the_maps_walls():
    """An external check: at the map's own resolution and origin, every marked cell is a wall cell of the map or
    touches one (a beam stops on a wall cell's edge, which float32 puts in either cell), and marked half a cell
    beyond the hit, nine in ten or more are wall cells; many slots, forward-driving steps with resets."""
    preset = load_robot("turtlebot2")
    geo = generate_map(8.0, 8.0, 0.05, seed=3, robot_radius=0.3)
    env = make_env(preset, 8, map=geo, seed=0)
    env.reset(seed=0)
    grid, inside = (WallGrid.covering(env.frame_map, 8, geo.resolution, preset.lidar.max_range, env.beam_angles, CPU,
                                      beyond) for beyond in (0.0, geo.resolution / 2))
    every = torch.arange(8)
    grid.start(every, env.pose, env.scan())
    inside.start(every, env.pose, env.scan())
    gen = torch.Generator().manual_seed(1)
    for _ in range(12):
        env.step(forward_actions(gen, 8))
        grid.push(every, env.pose, env.scan())
        inside.push(every, env.pose, env.scan())
    occ = torch.from_numpy(np.array(env.frame_map.occupied, dtype=bool))
    near = torch.nn.functional.max_pool2d(occ[None, None].float(), 3, stride=1, padding=1)[0, 0].bool()
    known = grid.known[:, :-1].view(8, *grid.shape)
    assert known.sum() > 500
    assert not (known & ~near).any()
    assert (known & occ).sum() > 0.3 * known.sum()  # not all in the free cell before the wall
    walls = inside.known[:, :-1].view(8, *grid.shape)
    assert walls.sum() > 500 and (walls & occ).sum() > 0.9 * walls.sum()  # (a grazing beam may end beside one)


# ---- the wall map in the env's observation (observation.wall_map) ------------------------------------------------

WALL_CASES = {
    "tb2": ("turtlebot2", None, {}),
    "go2": ("go2", None, {}),
    "tb2-many-maps": ("turtlebot2", [(6.0, 6.0, 0.05, 1), (9.0, 5.0, 0.1, 2)], {}),
    "tb2-with-everything": ("turtlebot2", None, {"observation.memory_frames": 2, "observation.pose_trail": 2,
                                                 "observation.scan_history": 1, "agents.count": 2}),
}


def step_pair(plain, env, ref: WallGrid, gen: torch.Generator, origins) -> tuple[torch.Tensor, torch.Tensor, int]:
    """One step of ``plain`` and ``env`` (the same task, ``env`` with a wall map) with the same seeded actions, their
    rewards and ends equal; ``ref`` fed every slot's new pose and scan as the env's grid should be (a slot whose
    episode ended starts afresh on ``origins()``, its map's origin). Returns both observations and the ends."""
    every = torch.arange(env.num_envs)
    action = forward_actions(gen, env.num_envs)
    obs0, r0, term0, trunc0, _ = plain.step(action)
    obs1, r1, term1, trunc1, info1 = env.step(action)
    assert torch.equal(r0, r1) and torch.equal(term0, term1) and torch.equal(trunc0, trunc1)
    done = info1["_final_obs"]
    ref.push(every[~done], env.pose[~done], env.scan(every[~done]))
    if done.any():
        ref.start(every[done], env.pose[done], env.scan(every[done]), origins()[done])
    return obs0, obs1, int(done.sum())


@pytest.mark.parametrize("case", list(WALL_CASES))
def test_the_envs_wall_map_columns_draw_every_hit_of_each_slots_episode(case):
    """The wall map's columns are the image of a grid fed from outside with every scan of each slot's episode (the
    new episode's first scan alone after a reset), on the grid of the slot's own map; every earlier column is the
    env's without the map, bit for bit, and so are rewards and ends."""
    robot, maps, overrides = WALL_CASES[case]
    grids = [generate_map(w, h, r, seed=s, robot_radius=0.3, name=f"m{s}") for w, h, r, s in maps] if maps else None
    if grids:
        grids[1] = grids[1].shifted((-1.5, 0.7))  # its own origin: a slot's grid must be placed on its map
    n, seed, cells, cell = 6, 5, 10, 0.4
    plain_preset = load_robot(robot, **overrides)
    preset = load_robot(robot, **overrides, **{"observation.wall_map": cells, "observation.wall_map_cell": cell,
                                               "observation.wall_map_grid": 0.2})
    plain, env = (make_env(p, n, maps=grids, seed=seed) if grids else make_env(p, n, seed=seed)
                  for p in (plain_preset, preset))
    base = plain.obs_dim
    assert env.obs_dim == base + 2 * cells * cells == preset.obs_dim and preset.memory_end == base
    assert plain.extras.walls is None
    ref = WallGrid(n, env.extras.walls.shape, 0.2, preset.lidar.max_range, env.beam_angles, CPU, HIT_BEYOND_M)
    every = torch.arange(n)

    def origins() -> torch.Tensor:
        return torch.tensor([env.frame_maps[int(m)].origin for m in env.map_index], dtype=torch.float32)

    obs0, _ = plain.reset(seed=seed)
    obs1, _ = env.reset(seed=seed)
    ref.start(every, env.pose, env.scan(), origins())
    gen = torch.Generator().manual_seed(seed)
    resets = walls = 0
    for _ in range(30):
        assert torch.equal(obs1[:, :base], obs0)
        want = ref.image(every, env.pose, env.goal, cells, cell).reshape(n, -1)
        assert torch.equal(obs1[:, base:], want)
        assert env.single_observation_space.contains(obs1[0].numpy())
        walls += int(obs1[:, base: base + cells * cells].sum())
        obs0, obs1, ended = step_pair(plain, env, ref, gen, origins)
        resets += ended
    assert resets >= 2 and walls > 200
    if grids:
        assert len(set(env.map_index.tolist())) == 2 and env.extras.walls.shape == (30, 45)  # the larger map's
        assert env.frame_maps[1].origin == (1.5, -0.7)


def test_a_retried_slot_keeps_its_map_and_starts_its_wall_map_afresh():
    """``episode.retry_failed`` on many maps with the wall map (measured on the generalist, session 64): a failed
    slot restarts on the map it failed on, and its wall map holds its new first scan alone, not the walls it saw in
    the failed attempt - its observation is the episode's first one again, bit for bit."""
    grids = [generate_map(8.0, 8.0, 0.1, seed=1, robot_radius=0.3, name="a"),
             generate_map(10.0, 6.0, 0.1, seed=2, robot_radius=0.3, name="b")]
    preset = load_robot("turtlebot2", **{"episode.retry_failed": 1.0, "observation.wall_map": 8})
    env = make_env(preset, 6, maps=grids, seed=3)
    first, _ = env.reset(seed=3)
    maps = env.map_index.clone()
    slots = torch.stack([(maps == m).nonzero()[0, 0] for m in (0, 1)])   # one slot on each map
    gen = torch.Generator().manual_seed(0)
    known = env.extras.walls.known[slots].sum()
    for _ in range(3):
        env.step(forward_actions(gen, 6) * 0.2)
    assert (env.steps[slots] == 3).all() and env.extras.walls.known[slots].sum() > known   # the attempt saw more
    env.pose[slots, 0] = 100.0                            # off every map: both collide in the next step
    info = env.step(forward_actions(gen, 6) * 0.2)[4]
    assert info["collision"][slots].all()
    assert torch.equal(env.map_index[slots], maps[slots]) and (env.steps[slots] == 0).all()
    assert torch.equal(env.obs[slots], first[slots])


def test_a_partial_reset_keeps_the_other_slots_wall_grids_and_new_maps_rebuild_them():
    preset = load_robot("turtlebot2", **{"observation.wall_map": 8})
    env = make_env(preset, 4, seed=0)
    env.reset(seed=0)
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        env.step(forward_actions(gen, 4) * 0.2)
    before = env.extras.walls.known.clone()
    env.reset(options={"reset_mask": torch.tensor([False, True, False, False])})
    keep = torch.tensor([0, 2, 3])
    assert torch.equal(env.extras.walls.known[keep], before[keep])
    assert not torch.equal(env.extras.walls.known[1], before[1])
    big = generate_map(16.0, 12.0, 0.1, seed=4, robot_radius=0.3)
    obs, _ = env.replace_maps([big])
    assert env.extras.walls.shape == (48, 64) and obs[:, preset.memory_end:].reshape(4, 2, 8, 8)[:, 0].sum() > 0
    with pytest.raises(ValueError, match="observation.wall_map must be 0 .none. or at least 2 squares a side, got 1"):
        load_robot("turtlebot2", **{"observation.wall_map": 1})
    with pytest.raises(ValueError, match="wall_map_grid"):
        load_robot("turtlebot2", **{"observation.wall_map_grid": 0})
