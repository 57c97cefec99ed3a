"""The opt-in pose trail (observation.pose_trail, flashnav/sim/trail.py): the paper's columns and every
other opt-in column are unchanged, and the breadcrumbs equal a slow reference (a Python list of past
positions per slot, turned into the robot frame one point at a time with math.cos / math.sin) through
sparse resets, with agents, a scan history, agent tracks and many maps; a slot's reset or a partial step
leaves the other slots' trails bit-identical; the observation stays inside its bounds; the networks
divide the breadcrumbs by their bound; the export records the trail and the deploy controller rebuilds
the env's observations from odometry alone."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.learn.networks import IPAPRec, ObsLayout
from flashnav.maps import generate_map
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv, make_env
from flashnav.sim.trail import trail_bound


def forward_actions(gen: torch.Generator, n: int) -> torch.Tensor:
    """Seeded random actions biased forward (episodes end in collisions and at goals: resets happen)."""
    action = torch.rand(n, 2, generator=gen) * 2 - 1
    action[:, 0] = action[:, 0] * 0.5 + 0.5
    return action


def reference_columns(crumbs: list[tuple[float, float]], pose: torch.Tensor) -> torch.Tensor:
    """The breadcrumbs (simulator frame) seen from ``pose`` (x, y, yaw), point by point."""
    x, y, yaw = (float(v) for v in pose)
    out = []
    for cx, cy in crumbs:
        dx, dy = cx - x, cy - y
        out += [math.cos(yaw) * dx + math.sin(yaw) * dy, -math.sin(yaw) * dx + math.cos(yaw) * dy]
    return torch.tensor(out, dtype=torch.float64)


CASES = {
    "tb2": ("turtlebot2", 4, 3, {}),
    "go2-every1": ("go2", 2, 1, {}),
    "tb2-with-everything": ("turtlebot2", 3, 5, {"agents.count": 4, "observation.agent_tracks": 2,
                                                 "observation.scan_history": 2, "lidar.noise_std": 0.05}),
    "tb2-many-maps": ("turtlebot2", 5, 2, {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_trail_columns_equal_a_list_of_past_positions_per_slot(case):
    robot, m, every, overrides = CASES[case]
    maps = [generate_map(6.0, 6.0, 0.05, seed=s, robot_radius=0.3, name=f"m{s}") for s in (1, 2)] \
        if case == "tb2-many-maps" else None
    n, seed = 6, 13

    def env(trail):
        preset = load_robot(robot, **overrides, **{"observation.pose_trail": trail, "observation.trail_every": every})
        return NavVecEnv(preset, n, grid=maps or make_env(preset).map, seed=seed)

    plain, trail = env(0), env(m)
    base = plain.obs_dim
    assert plain.extras.trail is None and trail.obs_dim == base + 2 * m
    assert trail.single_observation_space.shape == (base + 2 * m,)
    bound = trail_bound(trail.preset)
    assert bound == pytest.approx(max(abs(b) for b in trail.preset.motion.v_bounds) * trail.preset.episode.dt * m * every)
    assert np.allclose(trail.single_observation_space.high[base:], bound)
    assert np.allclose(trail.single_observation_space.low[base:], -bound)

    obs0, _ = plain.reset(seed=seed)
    obs1, _ = trail.reset(seed=seed)
    crumbs = [[tuple(trail.pose[i, :2].tolist())] * m for i in range(n)]  # the reference, newest first
    steps = [0] * n
    gen = torch.Generator().manual_seed(seed)
    resets = 0
    for step in range(70):
        for i in range(n):
            assert torch.equal(obs1[i, :base], obs0[i]), (step, i)
            want = reference_columns(crumbs[i], trail.pose[i])
            assert torch.allclose(obs1[i, base:].double(), want, atol=1e-5), (step, i)
        assert trail.single_observation_space.contains(obs1[0].numpy())
        action = forward_actions(gen, n)
        obs0, r0, term0, trunc0, info0 = plain.step(action)
        obs1, r1, term1, trunc1, info1 = trail.step(action)
        assert torch.equal(r0, r1) and torch.equal(term0, term1) and torch.equal(trunc0, trunc1)
        assert torch.equal(info1["final_obs"][:, :base], info0["final_obs"])
        for i in range(n):
            steps[i] += 1
            done = bool(info0["_final_obs"][i])
            if not done and steps[i] % every == 0:
                crumbs[i] = [tuple(trail.pose[i, :2].tolist()), *crumbs[i][:-1]]
            if done:  # a new episode: its start, M times
                assert torch.isfinite(info1["final_obs"][i, base:]).all()
                crumbs[i] = [tuple(trail.pose[i, :2].tolist())] * m
                steps[i] = 0
                resets += 1
    assert resets >= 2, "the rollout must exercise sparse resets"


def test_breadcrumbs_of_a_straight_drive():
    env = make_env(load_robot("turtlebot2", **{"observation.pose_trail": 3, "observation.trail_every": 1}), 1, seed=3)
    env.reset(seed=3)
    start = env.pose[0, :2].clone()
    for _ in range(2):  # 5 cm straight ahead per step: breadcrumbs here, 5 cm back, at the start
        obs, *_ = env.step(torch.tensor([[1.0, 0.0]]))
    assert torch.allclose(obs[0, -6:], torch.tensor([0.0, 0.0, -0.05, 0.0, -0.1, 0.0]), atol=1e-5)
    assert torch.equal(env.extras.trail.crumbs[0, 2], start)


def test_a_slot_reset_and_a_partial_step_leave_other_trails_bit_identical():
    env = make_env(load_robot("turtlebot2", **{"observation.pose_trail": 3, "observation.trail_every": 2,
                                               "agents.count": 2}), 8, seed=2)
    env.reset(seed=2)
    for _ in range(5):
        env.step(torch.full((8, 2), 0.3))
    crumbs, obs = env.extras.trail.crumbs.clone(), env.obs.clone()
    mask = torch.zeros(8, dtype=torch.bool)
    mask[[1, 5]] = True
    new, _ = env.reset(options={"reset_mask": mask})
    assert torch.equal(env.extras.trail.crumbs[~mask], crumbs[~mask]) and torch.equal(new[~mask], obs[~mask])
    for i in (1, 5):  # the reset slots: every breadcrumb is the start, seen from there (0, 0)
        assert torch.equal(env.extras.trail.crumbs[i], env.pose[i, :2].expand(3, -1))
        assert torch.equal(new[i, 34:], torch.zeros(6))

    crumbs = env.extras.trail.crumbs.clone()
    idx = torch.tensor([0, 6])
    env.step_slots(idx, torch.full((2, 2), 0.3))
    others = torch.ones(8, dtype=torch.bool)
    others[idx] = False
    assert torch.equal(env.extras.trail.crumbs[others], crumbs[others])


def test_set_state_starts_every_trail_afresh():
    env = make_env(load_robot("turtlebot2", **{"observation.pose_trail": 2, "observation.trail_every": 1}), 3, seed=0)
    env.reset(seed=0)
    for _ in range(3):
        env.step(torch.full((3, 2), 0.5))
    obs = env.set_state(env.world_pose(), env.world_goal())
    assert torch.equal(obs[:, 34:], torch.zeros(3, 4))


@pytest.mark.parametrize("key, value, match", [("observation.pose_trail", -1, "greater than or equal to 0"),
                                               ("observation.pose_trail", 33, "less than or equal to 32"),
                                               ("observation.trail_every", 0, "greater than or equal to 1")])
def test_a_bad_trail_option_names_the_key_and_the_value(key, value, match):
    with pytest.raises(ValueError, match=match) as err:
        load_robot("turtlebot2", **{key: value})
    assert key.split(".")[-1] in str(err.value)


def test_ipaprec_divides_the_breadcrumbs_by_the_trail_bound():
    preset = load_robot("turtlebot2", **{"observation.pose_trail": 3, "observation.trail_every": 4})
    layout = ObsLayout.from_robot(preset, 14.0)
    assert layout.obs_dim == preset.obs_dim == 40 and layout.trail_scale == trail_bound(preset)
    obs = torch.rand(5, 40) * 4 + 0.3
    feats = IPAPRec(layout)(obs)
    plain = IPAPRec(ObsLayout.from_robot(load_robot("turtlebot2"), 14.0))(obs[:, :34])
    assert torch.allclose(feats[:, :34], plain)
    assert torch.allclose(feats[:, 34:], obs[:, 34:] / trail_bound(preset))
    with pytest.raises(ValueError, match="pose_trail must be an integer >= 0"):
        ObsLayout(30, 0.2, 20.0, 14.1, (0.5, 0.78), pose_trail=-1)


@pytest.fixture(scope="module")
def trail_policy(tmp_path_factory):
    from test_export import random_actor

    from flashnav.export import export_policy

    preset = load_robot("turtlebot2", **{"observation.pose_trail": 4, "observation.trail_every": 3})
    actor = random_actor(preset, seed=3)
    return preset, export_policy(actor, preset, tmp_path_factory.mktemp("policy_trail"))


def test_export_records_the_trail_and_the_runtime_names_a_bad_one(trail_policy):
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import policy_metadata

    preset, paths = trail_policy
    meta = policy_metadata(preset)
    assert meta["obs_dim"] == 42
    assert meta["observation"]["pose_trail"]["count"] == 4 and meta["observation"]["pose_trail"]["every"] == 3
    assert meta["observation"]["pose_trail"]["columns"] == [34, 42]
    rt = PolicyRuntime.load(paths["onnx"])
    assert (rt.pose_trail, rt.trail_every, rt.velocity_dims) == (4, 3, 2)
    sectors = np.full(30, 2.0, np.float32)
    with pytest.raises(ValueError, match=r"trail must be \[4, 2\]"):
        rt.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), (0.0, 0.0))
    with pytest.raises(ValueError, match=r"trail must be \[4, 2\].*got \[3, 2\]"):
        rt.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), (0.0, 0.0), trail=np.zeros((3, 2)))
    obs = rt.observation(sectors, (1.0, 2.0, math.pi / 2), (1.0, 0.0), (0.0, 0.0),
                         trail=[[1.0, 1.0], [0.0, 2.0], [1.0, 2.0], [1.0, 2.0]])
    assert np.allclose(obs[34:], [-1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], atol=1e-6)  # behind; to the left
    plain = PolicyRuntime(None, policy_metadata(load_robot("turtlebot2")))
    with pytest.raises(ValueError, match="trail must be \\[0, 2\\]"):
        plain.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), (0.0, 0.0), trail=np.zeros((2, 2)))


def test_the_deploy_controller_rebuilds_the_envs_trail_from_odometry(trail_policy):
    """A simulated episode stream fed to the Controller as a robot would (odometry, scans, a goal per
    episode): every control step's observation equals the env's, breadcrumbs included."""
    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.deploy.scan import simulator_scan_fields

    preset, paths = trail_policy
    ctl = Controller(PolicyRuntime.load(paths["onnx"]), timeout=1.0)
    env = make_env(preset, 1, seed=4)
    env.reset(seed=4)
    scan = simulator_scan_fields(preset.lidar)
    t, dt, episodes, moved = 0.0, preset.episode.dt, 1, 0
    ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
    for _ in range(150):
        ctl.on_odom(*env.world_pose()[0].tolist(), now=t)
        command = ctl.on_scan(ranges=env.scan()[0].numpy(), stamp=t, now=t, **scan)
        if command is None or command.state != "driving":  # reached: the next goal
            break
        np.testing.assert_allclose(ctl.last_obs, env.obs[0].numpy(), rtol=0, atol=1e-4)
        moved += int(np.abs(ctl.last_obs[34:]).max() > 0.05)
        _, _, terminated, truncated, _ = env.step(torch.tensor([ctl.last_action]))
        t += dt
        if bool(terminated[0] | truncated[0]):  # a new episode: a new goal, the trail afresh
            ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
            episodes += 1
    assert moved > 20, "the breadcrumbs must have left the robot"
