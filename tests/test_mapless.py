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
                              timeout=0.3, rate=None, guide=0.5)
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
