"""flashnav/mapless.py: planning on the walls a robot's own scans have shown it, and the mapless guide
(``flashnav eval --maps ... --guide M --guide-from scans``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_dilation

from flashnav.eval_maps import evaluate_maps, fixed_episodes
from flashnav.evaluate import play_episodes
from flashnav.guidance import EnvScans, MaplessGuide
from flashnav.mapless import SeenWalls
from flashnav.maps.families import generate_family
from flashnav.sim.env import NavVecEnv, make_env
from test_goal_fields import blocked_room
from test_sampling import robot

TB2 = robot("geodesic")


def placed(grid, poses, goals):
    env = NavVecEnv(TB2, len(poses), grid=grid, seed=0)
    env.set_state(torch.tensor(poses, dtype=torch.float64), torch.tensor(goals, dtype=torch.float64))
    return env


def goal_seeker(env):
    """A policy that drives straight at whatever its goal columns point to (turns on the spot first)."""
    col = env.preset.lidar.sectors

    def policy(obs):
        angle = obs[:, col + 1]
        a_w = torch.clamp(2.0 * angle, -1.0, 1.0)
        a_v = torch.where(angle.abs() < 0.3, torch.ones_like(angle), -torch.ones_like(angle))
        return torch.stack([a_v, a_w], dim=1)
    return policy


def test_seen_walls_mark_only_walls_and_start_knowing_nothing():
    """It starts with an empty map, and every cell it marks is a wall of the true map or touches one (a
    beam's end is pushed half a cell past the surface, into the wall it hit; a grazing beam can end in the
    free cell beside it)."""
    grid = generate_family("mazes", 7, size=(6.0, 6.0), resolution=0.05)
    env = make_env(TB2, 4, map=grid, seed=0)
    env.reset(seed=1)
    source = EnvScans(env)
    walls = source.walls()
    assert not walls.known.any()
    new = walls.mark(np.arange(4), *source.scans(np.arange(4)))
    truth = env.frame_maps[0].occupied
    marked = new.any(axis=0)
    assert new.any(axis=(1, 2)).all() and truth[marked].mean() > 0.95
    assert binary_dilation(truth, structure=np.ones((3, 3), bool))[marked].all()
    assert not walls.mark(np.arange(4), *source.scans(np.arange(4))).any()  # the same scans: nothing new
    # elsewhere (new poses, same slots): the walls seen before stay known; forgetful, only the new scan's
    before = walls.known.copy()
    forgetful = source.walls(memory=False)
    forgetful.mark(np.arange(4), *source.scans(np.arange(4)))
    env.set_state(env.world_pose().flip(0), env.world_goal())
    walls.mark(np.arange(4), *source.scans(np.arange(4)))
    assert (walls.known >= before).all() and (walls.known > before).any()
    forgetful.mark(np.arange(4), *source.scans(np.arange(4)))
    assert not (forgetful.known >= before).all() and forgetful.known.any()
    with pytest.raises(ValueError, match="sensor must be one of"):
        EnvScans(env, sensor="camera")
    with pytest.raises(ValueError, match="one map per env, got 2 maps"):
        EnvScans(make_env(TB2, 2, maps=[grid, blocked_room(0.05)], seed=0))
    with pytest.raises(ValueError, match="radius and comfort must be > 0"):
        SeenWalls(grid, 1, 0.0)


def test_the_guide_goes_round_the_wall_it_sees_and_never_reads_the_rest():
    grid = blocked_room(0.05)
    # left of the wall (x = 4 m, up to y = 5 m), facing it; goal across it at the same height
    env = placed(grid, [[3.0, 3.5, 0.0], [5.5, 3.5, 0.0], [3.6, 3.5, 0.0]], [[5.0, 3.5], [5.0, 3.5], [4.4, 3.5]])
    guide = MaplessGuide(env, lookahead=1.0)
    obs = guide.observe(env.obs.clone(), torch.arange(3))
    carrot = torch.as_tensor(guide.carrot(np.arange(3)))
    # slot 2: the goal 0.8 m away in a straight line, but behind the wall: the carrot is on the path round it
    assert carrot[2, 1] > 3.5 + 0.6 and carrot[2, 0] < 4.0
    # slot 0: the wall it sees blocks the straight line: the path goes up towards the wall's end
    assert carrot[0, 1] > 3.5 + 0.6 and carrot[0, 0] < 4.0
    assert math.dist(carrot[0].tolist(), [3.0, 3.5]) == pytest.approx(1.0, abs=0.15)
    assert float(obs[0, env.preset.lidar.sectors]) == pytest.approx(math.dist(carrot[0].tolist(), [3.0, 3.5]), abs=1e-5)
    # slot 1: the goal is 0.5 m away in the open: the carrot is the goal, the observation unchanged
    assert torch.equal(carrot[1], env.goal[1].double())
    torch.testing.assert_close(obs[1], env.obs[1])
    # the right-hand outer wall (x = 8 m) is behind the middle wall for slot 0: never seen, never known
    w = grid.shape[1]
    assert walls_right_of(guide.walls.known[0], w, 0.75) == 0 and guide.walls.known[0].any()


def walls_right_of(known: np.ndarray, width: int, fraction: float) -> int:
    return int(known[:, int(fraction * width):].sum())


def test_a_goal_seeker_behind_a_wall_arrives_only_with_the_guide():
    """The same episode twice: steered straight at the goal the robot drives into the wall; steered at
    the mapless guide's carrots it finds the way round the wall's end, learnt from its scans."""
    grid = blocked_room(0.05)
    outcome = {}
    for guided in (False, True):
        env = placed(grid, [[3.0, 3.5, 0.0]], [[5.0, 3.5]])
        e = play_episodes(goal_seeker(env), env, env.obs.clone(), guide=MaplessGuide(env, lookahead=0.5) if guided
                          else None)
        outcome[guided] = (bool(e["success"][0]), bool(e["collision"][0]))
    assert outcome == {False: (False, True), True: (True, False)}


def test_scans_guided_evaluation_plays_each_maps_fixed_episodes(monkeypatch):
    """Map by map and in blocks of slots (a small cell budget forces 3 blocks), the same episodes as the
    unguided evaluation, a row per map; a goal seeker does better guided on the blocked room."""
    import flashnav.eval_maps as eval_maps

    grids = [blocked_room(0.05), generate_family("mazes", 3, size=(6.0, 6.0), resolution=0.05)]
    env = NavVecEnv(TB2, 6, grid=grids[0], seed=0)
    seen = []
    real = eval_maps.play_episodes

    def spy(policy, env, obs, guide=None):
        seen.append((env.world_pose().clone(), type(guide).__name__))
        return real(policy, env, obs, guide=guide)
    monkeypatch.setattr(eval_maps, "play_episodes", spy)
    monkeypatch.setattr(eval_maps, "SCANS_GUIDE_CELLS", grids[0].shape[0] * grids[0].shape[1] * 2)
    out = evaluate_maps(goal_seeker(env), TB2, grids, 5, 7, goal_distance_scale=20.0, guide=0.5, guide_from="scans")
    assert [r["episodes"] for r in out["maps"]] == [5, 5] and len(seen) == 6  # 3 blocks (2 + 2 + 1) per map
    assert {name for _, name in seen} == {"MaplessGuide"}
    start, _ = fixed_episodes(NavVecEnv(TB2, 5, grid=grids[0], seed=7), 0, 5, 7)
    torch.testing.assert_close(torch.cat([p for p, _ in seen[:3]]), start, atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="guide_from must be one of"):
        evaluate_maps(goal_seeker(env), TB2, grids, 2, 7, goal_distance_scale=20.0, guide=0.5, guide_from="slam")


def test_the_deploy_controller_with_a_scan_guide_finds_the_way_round_the_wall():
    """The robot stack without a map: the simulator's scans and poses through a ROS-shaped Controller whose
    runtime steers straight at whatever its observation's goal columns point to. Aimed at the goal it
    drives into the wall; with a ScanGuide it goes round, and the goal radius is still the goal's."""
    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.deploy.scan import simulator_scan_fields
    from flashnav.mapless import ScanGuide
    from test_deploy_runtime import POLICY

    grid = blocked_room(0.05)
    outcome = {}
    for guided in (False, True):
        env = placed(grid, [[3.0, 3.5, 0.0]], [[5.0, 3.5]])
        rt = PolicyRuntime.load(POLICY)
        seek = goal_seeker(env)

        def act(obs, seek=seek, rt=rt):  # the goal seeker in place of the network, the runtime's units
            a = seek(torch.as_tensor(obs)[None])[0].numpy()
            lo_v, hi_v = env.preset.motion.v_bounds
            lo_w, hi_w = env.preset.motion.w_bounds
            return a, lo_v + (a[0] + 1) * 0.5 * (hi_v - lo_v), lo_w + (a[1] + 1) * 0.5 * (hi_w - lo_w)
        rt.act = act
        guide = ScanGuide(env.preset.footprint.circumscribed_radius, lookahead=0.5) if guided else None
        ctl = Controller(rt, timeout=1.0, guide=guide)
        scan = simulator_scan_fields(env.preset.lidar)
        t, dt, result = 0.0, env.preset.episode.dt, None
        ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
        for _ in range(env.preset.episode.horizon):
            ctl.on_odom(*env.world_pose()[0].tolist(), now=t)
            command = ctl.on_scan(ranges=env.scan()[0].numpy(), stamp=t, now=t, **scan)
            if command.state == "reached":
                result = "reached"
                break
            if guided:  # the carrot: within the lookahead of the robot, off the straight line at first
                assert math.dist(ctl.carrot, env.world_pose()[0, :2].tolist()) <= 0.5 + 0.3 + 1e-6
            _, _, terminated, truncated, info = env.step(torch.tensor([ctl.last_action], dtype=torch.float32))
            t += dt
            if bool(terminated[0] | truncated[0]):
                result = "success" if bool(info["success"][0]) else "collision" if bool(info["collision"][0]) else "timeout"
                break
        outcome[guided] = result
        assert ctl.status(t)["carrot"] is None if not guided else ctl.status(t)["carrot"] is not None
    # the env ends an episode inside the goal radius; the controller says reached at the same radius
    assert outcome[False] == "collision" and outcome[True] in ("success", "reached")
    with pytest.raises(ValueError, match="lookahead must be > 0"):
        ScanGuide(0.2, lookahead=0.0)


def test_deploy_guide_flag_builds_the_scan_guide_or_names_the_bad_value():
    import argparse

    from flashnav.deploy.cli import make_controller
    from test_deploy_runtime import POLICY

    args = argparse.Namespace(policy=str(POLICY), lidar_pose=[0.0, 0.0, 0.0], lidar_flipped=False, fill=None,
                              timeout=0.3, rate=None, guide=0.5, shield=None)
    ctl = make_controller(args)
    assert ctl.guide is not None and ctl.guide.lookahead == 0.5 and ctl.guide.radius == pytest.approx(0.2)
    assert make_controller(argparse.Namespace(**{**vars(args), "guide": None})).guide is None
    with pytest.raises(ValueError, match="--guide must be > 0 metres, got -1"):
        make_controller(argparse.Namespace(**{**vars(args), "guide": -1.0}))


def test_sim_robot_episodes_take_the_goal_sampling_asked_for():
    from flashnav.deploy.sim_robot import episodes_of
    from flashnav.sim.goal_fields import evaluation_preset

    grid = generate_family("mazes", 5, size=(6.0, 6.0), resolution=0.05)
    euclid = episodes_of("turtlebot2", grid, 8, 3)
    geo = episodes_of("turtlebot2", grid, 8, 3, "geodesic")
    assert not np.allclose(euclid[1], geo[1])
    env = NavVecEnv(evaluation_preset(TB2), 8, grid=grid, seed=3)  # what flashnav eval --maps plays
    pose, goal = fixed_episodes(env, 0, 8, 3)
    np.testing.assert_allclose(geo[0], pose.numpy(), atol=1e-5)
    np.testing.assert_allclose(geo[1], goal.numpy(), atol=1e-5)


def descend_one_by_one(field: np.ndarray, shape: tuple, cell: int, steps: int = 400) -> list[int]:
    """The obviously-correct descent: from ``cell``, step to the first of the 8 neighbours (in the planner's
    order) that is lower than every other and than the cell itself, until none is."""
    h, w = shape
    moves = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
    out = [cell]
    for _ in range(steps):
        i, j = divmod(cell, w)
        best, best_d = cell, field[cell]
        for di, dj in moves:
            ii, jj = i + di, j + dj
            if 0 <= ii < h and 0 <= jj < w and field[ii * w + jj] < best_d:
                best, best_d = ii * w + jj, field[ii * w + jj]
        if best == cell:
            break
        cell = best
        out.append(cell)
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_path_cells_descend_all_slots_at_once_as_one_by_one(seed):
    """The batched descent equals a loop over each slot's neighbours, on planned fields (a maze's walls) and
    on random ones with ties and unreachable cells; a path that ends early repeats its last cell."""
    rng = np.random.default_rng(seed)
    grid = generate_family("mazes", seed, size=(6.0, 6.0), resolution=0.1)
    h, w = grid.shape
    walls = SeenWalls(grid, 6, 0.15)
    walls.known[:3] = grid.occupied
    free = np.flatnonzero(grid.free_space(0.15))
    goal = rng.choice(free, 3)
    walls.goals[:3] = np.stack([(goal % w + 0.5) * grid.resolution, (goal // w + 0.5) * grid.resolution], axis=1)
    for slot in range(3):
        walls.fields[slot] = walls._field(slot)
    noise = np.round(rng.random((3, h * w)) * 20.0)  # rounded: many equal neighbours
    walls.fields[3:] = np.where(rng.random((3, h * w)) < 0.1, np.inf, noise)
    xy = rng.uniform(0.0, 6.0, (6, 2))
    for slot in range(3):  # planned fields: start where the goal is reachable
        c = rng.choice(np.flatnonzero(np.isfinite(walls.fields[slot])))
        xy[slot] = (c % w + 0.5) * grid.resolution, (c // w + 0.5) * grid.resolution
    got = walls.path_cells(np.arange(6), xy, steps=50)
    assert got.shape[0] == 6
    for k in range(6):
        ref = descend_one_by_one(walls.fields[k], (h, w), int(walls.cells(xy[k:k + 1])[0]), steps=50)
        assert got[k, :len(ref)].tolist() == ref and (got[k, len(ref):] == ref[-1]).all()
    assert max(len(descend_one_by_one(walls.fields[k], (h, w), int(walls.cells(xy[k:k + 1])[0]))) for k in range(3)) > 5


def beams_pass_through(walls: SeenWalls, candidate: np.ndarray, pose, ranges, angles, max_range) -> np.ndarray:
    """The obviously-correct carving rule, every beam against every candidate cell: a beam whose line passes
    within half a cell of the cell's centre and whose free part (to its return, or max_range) reaches a cell
    beyond it."""
    g, res = walls.grid, walls.grid.resolution
    out = np.zeros_like(candidate)
    for k, i, j in zip(*np.nonzero(candidate)):
        dx, dy = g.origin[0] + (j + 0.5) * res - pose[k, 0], g.origin[1] + (i + 0.5) * res - pose[k, 1]
        delta = math.atan2(dy, dx) - pose[k, 2] - angles
        dist = math.hypot(dx, dy)
        free = np.where(np.isnan(ranges[k]), -np.inf, np.minimum(ranges[k], max_range))
        out[k, i, j] = ((dist * np.cos(delta) > 0) & (np.abs(dist * np.sin(delta)) < 0.5 * res)
                        & (dist * np.cos(delta) + res < free)).any()
    return out


def test_carving_forgets_the_agents_trails_and_never_a_wall():
    """Eight wandering agents walk through the scans of eight robots: remembered for good (``carve=False``),
    their trails pile up as walls; carved by the beams that later pass through them, fewer stay (the rest
    lie behind the field of view or behind what the scan hit) - and no cell of the true map's walls is ever
    carved, so both memories hold the same true walls. Each step's carving is a subset of what a check of
    every beam against every remembered cell would carve, and most of it."""
    from flashnav.scenarios import scenario_preset

    grid = generate_family("offices", 3, size=(10.0, 10.0), resolution=0.05)
    env = make_env(scenario_preset(TB2, "wander-8"), 8, map=grid, seed=0)
    env.reset(seed=2)
    source = EnvScans(env)
    kept, carved = source.walls(carve=False), source.walls()
    slots = np.arange(8)
    ever_carved = np.zeros_like(carved.known)
    gen = torch.Generator().manual_seed(0)
    for step in range(40):
        scans = source.scans(slots)
        kept.mark(slots, *scans)
        before = carved.known.copy()
        carved.mark(slots, *scans)
        ever_carved |= carved.last_carved
        if step in (20, 39):
            seen = np.zeros_like(before)
            seen[carved._ends(*scans)] = True
            candidate = before & ~binary_dilation(seen, structure=np.ones((1, 3, 3), bool))
            reference = beams_pass_through(carved, candidate, *scans)
            assert (carved.last_carved <= reference).all() and carved.last_carved.sum() >= 0.9 * reference.sum()
        env.step(torch.rand(8, 2, generator=gen) * 2 - 1)  # slots that end restart elsewhere on the same map
    occupied = env.frame_maps[0].occupied
    assert ever_carved.sum() > 100 and not (ever_carved & occupied).any()
    assert (carved.known <= kept.known).all()
    assert ((carved.known & occupied) == (kept.known & occupied)).all()
    beside_walls = binary_dilation(occupied, structure=np.ones((3, 3), bool))
    trails_kept, trails_carved = (kept.known & ~beside_walls).sum(), (carved.known & ~beside_walls).sum()
    assert trails_kept > 100 and trails_carved < 0.7 * trails_kept
    assert carved.carved.sum() >= ever_carved.sum() and not kept.carved.any()  # a cell can be carved twice


def test_sparse_nonzero_equals_numpy():
    from flashnav.mapless import _nonzero

    rng = np.random.default_rng(0)
    for shape in [(3, 17, 29), (1, 8, 8), (2, 5, 3)]:
        for p in (0.0, 0.01, 0.3, 1.0):
            a = rng.random(shape) < p
            for got, want in zip(_nonzero(a), np.nonzero(a)):
                np.testing.assert_array_equal(got, want)


def test_a_person_in_the_only_gap_blocks_the_plan_until_a_beam_passes_through():
    """The blocked room's only way round is the gap above its middle wall. A person stood in it (their disc
    marked as walls): no path. Seen empty from the left, the marks are carved and the slot replanned; with
    ``carve=False`` the person stays a wall for good."""
    grid = blocked_room(0.05)
    env = placed(grid, [[3.0, 5.5, 0.0]], [[5.0, 3.5]])
    source = EnvScans(env)
    res = grid.resolution
    yy, xx = np.mgrid[0:grid.shape[0], 0:grid.shape[1]]
    person = np.hypot((xx + 0.5) * res - 4.0, (yy + 0.5) * res - 5.5) < 0.25
    person &= ~grid.occupied
    cell = int(source.walls().cells(np.array([[3.0, 5.5]]))[0])
    for carve in (True, False):
        walls = source.walls(carve=carve)
        walls.plan(np.zeros(1, np.int64), source.goals(np.zeros(1, np.int64)), source.scans(np.zeros(1, np.int64)))
        assert np.isfinite(walls.fields[0, cell])
        walls.known[0] |= person
        walls.fields[0] = walls._field(0)
        assert not np.isfinite(walls.fields[0, cell])  # no way round: the carrot is the goal itself
        np.testing.assert_allclose(walls.carrot(np.zeros(1, np.int64), np.array([[3.0, 5.5]]), 0.5), [[5.0, 3.5]])
        walls.update(np.zeros(1, np.int64), source.scans(np.zeros(1, np.int64)))
        assert np.isfinite(walls.fields[0, cell]) == carve
        assert (walls.known[0] & person).sum() == (0 if carve else person.sum())


def test_deploy_beams_say_which_beams_met_nothing_and_which_said_nothing():
    from flashnav.deploy.scan import ScanAdapter, SectorLayout

    adapter = ScanAdapter(SectorLayout(sectors=30, fov_deg=270.0, max_range=20.0))
    ranges = np.full(1080, 3.0)
    ranges[[0, 1, 2, 3]] = [np.inf, np.nan, 99.0, 0.001]  # no return, invalid, beyond range_max, below range_min
    fov = math.radians(270.0)
    angles, r = adapter.beams(-fov / 2 + fov / 1080 / 2, fov / 1080, ranges, 0.05, 20.0)
    assert r[0] == np.inf and np.isnan(r[1]) and r[2] == np.inf and np.isnan(r[3]) and (r[4:] == 3.0).all()
    assert len(angles) == 1080
