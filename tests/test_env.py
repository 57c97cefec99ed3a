"""Pins the environment's semantics: layout, action mapping, reward, flags, resets, determinism."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
import torch

import flashnav
from flashnav.maps.grid import OccupancyMap
from flashnav.presets import load_robot
from flashnav.sim.env import beam_angles, make_env


def open_room(size_m: float = 10.0, res: float = 0.05) -> OccupancyMap:
    """An empty square room with a one-cell wall."""
    n = int(round(size_m / res))
    occ = np.zeros((n, n), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    return OccupancyMap(occ, res, name="room")


@pytest.fixture(scope="module")
def room():
    return open_room()


def test_observation_layout_and_dims(room):
    for robot, dim, vel_dims in (("turtlebot2", 34, 2), ("go2", 35, 3)):
        env = make_env(robot, 4, map=room)
        obs, _ = env.reset(seed=0)
        assert obs.shape == (4, dim) and obs.dtype == torch.float32
        assert env.single_observation_space.shape == (dim,)
        assert env.single_action_space.shape == (2,)
        assert float(env.single_action_space.low.min()) == -1.0 and float(env.single_action_space.high.max()) == 1.0
        # robot at (5, 5) facing +x, goal 2 m to the left (+y): angle +pi/2, distance 2
        obs = env.set_state(torch.tensor([[5.0, 5.0, 0.0]] * 4), torch.tensor([[5.0, 7.0]] * 4))
        assert obs[:, 30] == pytest.approx(2.0)
        assert obs[:, 31] == pytest.approx(math.pi / 2)
        assert torch.all(obs[:, 32:] == 0)  # velocity zero after set_state
        # sectors = minimum over 36 consecutive beams of the raw scan
        scan = env.scan()
        assert scan.shape == (4, 1080)
        assert torch.allclose(obs[:, :30], scan.view(4, 30, 36).amin(dim=2))
        assert len(env.beam_angles) == 1080


def test_sector_order_and_wall_distance(room):
    # TurtleBot2 FOV 270 deg: sector 0 starts at -135 deg (right), sector 29 ends at +135 deg (left).
    env = make_env("turtlebot2", 1, map=room)
    obs = env.set_state(torch.tensor([[5.0, 2.0, 0.0]]), torch.tensor([[8.0, 8.0]]))
    # the wall at y = 0.05 m (inner face of the bottom wall) is to the robot's right
    right = obs[0, :30].argmin().item()
    assert right < 5
    assert obs[0, right] == pytest.approx(2.0 - 0.05, abs=1e-3)
    ang = beam_angles(270, 1080)
    assert ang[0] == pytest.approx(math.radians(-135) + math.radians(270) / 2160)
    assert ang[-1] == pytest.approx(math.radians(135) - math.radians(270) / 2160)
    full = beam_angles(360, 1080)
    assert (full[1:] - full[:-1]).std() < 1e-6 and full[-1] - full[0] < 2 * math.pi


def test_action_mapping(room):
    env = make_env("turtlebot2", 3, map=room)
    env.set_state(torch.tensor([[5.0, 5.0, 0.0]] * 3), torch.tensor([[9.0, 9.0]] * 3))
    obs, *_ = env.step(torch.tensor([[-1.0, -1.0], [1.0, 1.0], [0.0, 0.0]]))
    v, w = obs[:, 32], obs[:, 33]
    assert v.tolist() == pytest.approx([0.0, 0.5, 0.25])
    assert w.tolist() == pytest.approx([-math.pi / 4, math.pi / 4, 0.0], abs=1e-6)
    # out-of-range actions are clamped to [-1, 1]
    obs, *_ = env.step(torch.tensor([[5.0, -7.0]] * 3))
    assert obs[:, 32].tolist() == pytest.approx([0.5] * 3) and obs[:, 33].tolist() == pytest.approx([-math.pi / 4] * 3)
    # the pose moved 0.05 m along the heading in one step at full speed
    env.set_state(torch.tensor([[5.0, 5.0, 0.0]] * 3), torch.tensor([[9.0, 9.0]] * 3))
    env.step(torch.tensor([[1.0, 0.0]] * 3))
    assert env.pose[0, 0].item() == pytest.approx(5.05, abs=1e-5)


def test_progress_reward(room):
    env = make_env("turtlebot2", 1, map=room)
    env.set_state(torch.tensor([[2.0, 5.0, 0.0]]), torch.tensor([[8.0, 5.0]]))
    _, reward, terminated, truncated, info = env.step(torch.tensor([[1.0, 0.0]]))
    assert reward.item() == pytest.approx(2.0 * 0.05, abs=1e-5)  # c1 * (d_old - d_new)
    assert not terminated.item() and not truncated.item()
    # driving away from the goal is penalised
    env.set_state(torch.tensor([[5.0, 5.0, math.pi]]), torch.tensor([[8.0, 5.0]]))
    _, reward, *_ = env.step(torch.tensor([[1.0, 0.0]]))
    assert reward.item() == pytest.approx(-0.1, abs=1e-5)


def test_goal_reward_and_termination(room):
    env = make_env("turtlebot2", 1, map=room)
    env.set_state(torch.tensor([[5.0, 5.0, 0.0]]), torch.tensor([[5.2, 5.0]]))  # 0.2 m: not yet (< 0.2 needed)
    _, reward, terminated, truncated, info = env.step(torch.tensor([[1.0, 0.0]]))  # now 0.15 m away
    assert reward.item() == 10.0 and terminated.item() and not truncated.item()
    assert info["success"].item() and not info["collision"].item() and info["_final_obs"].item()
    assert info["final_obs"][0, 30].item() == pytest.approx(0.15, abs=1e-5)


def test_collision_reward_and_termination(room):
    env = make_env("turtlebot2", 1, map=room)
    # disc radius 0.2; inner wall face at x = 9.95: centre at 9.70 moving +0.05 -> 0.2 from the wall face
    env.set_state(torch.tensor([[9.72, 5.0, 0.0]]), torch.tensor([[2.0, 2.0]]))
    _, reward, terminated, truncated, info = env.step(torch.tensor([[1.0, 0.0]]))
    assert reward.item() == -10.0 and terminated.item() and info["collision"].item()
    assert not info["success"].item()


def test_goal_is_checked_before_collision(room):
    env = make_env("turtlebot2", 1, map=room)
    env.set_state(torch.tensor([[9.72, 5.0, 0.0]]), torch.tensor([[9.80, 5.0]]))
    _, reward, terminated, _, info = env.step(torch.tensor([[1.0, 0.0]]))
    assert reward.item() == 10.0 and terminated.item()
    assert info["success"].item() and not info["collision"].item()


def test_truncation_at_horizon_without_terminal_event(room):
    env = make_env("turtlebot2", 2, map=room)
    env.set_state(torch.tensor([[5.0, 5.0, 0.0]] * 2), torch.tensor([[8.0, 8.0]] * 2))
    still = torch.tensor([[-1.0, 0.0]] * 2)  # v = 0, w = 0: never reaches, never collides
    for t in range(1, 200):
        _, _, terminated, truncated, _ = env.step(still)
        assert not terminated.any() and not truncated.any(), t
    _, reward, terminated, truncated, info = env.step(still)
    assert truncated.all() and not terminated.any()
    assert info["_final_obs"].all()
    assert reward.tolist() == pytest.approx([0.0, 0.0])
    assert torch.all(env.steps == 0)  # reset in the same step


def test_final_obs_preserved_and_partial_reset_leaves_others_identical(room):
    env = make_env("turtlebot2", 8, map=room, seed=3)
    env.reset(seed=3)
    pose = torch.tensor([[5.0, 5.0, 0.0]] * 8)
    goal = torch.tensor([[8.0, 5.0]] * 8)
    goal[2] = torch.tensor([5.1, 5.0])  # slot 2 reaches its goal in the next step
    env.set_state(pose, goal)
    for _ in range(3):
        env.step(torch.zeros(8, 2))
    env.set_state(pose, goal)
    before = {k: getattr(env, k).clone() for k in ("pose", "goal", "velocity", "steps", "obs")}
    obs, reward, terminated, truncated, info = env.step(torch.tensor([[1.0, 0.0]] * 8))
    assert terminated.tolist() == [i == 2 for i in range(8)]
    # the final observation is the pre-reset one (at the goal), the returned one is a new episode
    assert info["final_obs"][2, 30].item() == pytest.approx(0.05, abs=1e-5)
    assert not torch.equal(obs[2], info["final_obs"][2])
    assert torch.equal(obs[[0, 1, 3, 4, 5, 6, 7]], info["final_obs"][[0, 1, 3, 4, 5, 6, 7]])
    # reset of slot 2 only: compare others against an identical env stepped without the goal event
    twin = make_env("turtlebot2", 8, map=room, seed=3)
    goal2 = goal.clone()
    goal2[2] = torch.tensor([8.0, 5.0])
    twin.set_state(pose, goal2)
    obs_twin, *_ = twin.step(torch.tensor([[1.0, 0.0]] * 8))
    others = [0, 1, 3, 4, 5, 6, 7]
    assert torch.equal(obs[others], obs_twin[others])
    assert torch.equal(env.pose[others], twin.pose[others])
    assert env.steps[2].item() == 0 and before["steps"][2].item() == 0
    # gymnasium partial reset through options leaves unmasked slots bit-identical
    snapshot = env.obs.clone(), env.pose.clone()
    mask = torch.zeros(8, dtype=torch.bool)
    mask[5] = True
    obs, _ = env.reset(options={"reset_mask": mask})
    assert torch.equal(obs[~mask], snapshot[0][~mask]) and torch.equal(env.pose[~mask], snapshot[1][~mask])
    assert not torch.equal(env.pose[5], snapshot[1][5])


def test_same_seed_same_trajectory():
    def rollout(seed):
        env = make_env("turtlebot2", 16, seed=seed)
        obs, _ = env.reset(seed=seed)
        gen = torch.Generator().manual_seed(99)
        out = [obs]
        for _ in range(30):
            obs, reward, *_ = env.step(torch.rand(16, 2, generator=gen) * 2 - 1)
            out += [obs, reward[:, None]]
        return torch.cat(out, dim=1)

    assert torch.equal(rollout(7), rollout(7))
    assert not torch.equal(rollout(7), rollout(8))


def test_sampled_episodes_are_valid():
    env = make_env("turtlebot2", 512, seed=1)
    obs, _ = env.reset(seed=1)
    d = torch.linalg.vector_norm(env.goal - env.pose[:, :2], dim=1)
    assert d.min() >= 1.0 - 1e-5 and d.max() <= 5.0 + 1e-5
    assert not env._collides(env.pose).any()
    assert obs[:, :30].min() > 0.2  # nothing closer than the footprint (+ clearance) at the start


def test_gymnasium_registration_and_checker():
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("flashnav/TurtleBot2-v0")
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert isinstance(obs, np.ndarray) and obs.shape == (34,)
    vec = gymnasium.make_vec("flashnav/Go2-v0", num_envs=4, vectorization_mode="vector_entry_point")
    obs, _ = vec.reset(seed=0)
    assert tuple(obs.shape) == (4, 35)
    assert flashnav.make_env("go2", 2).num_envs == 2


def test_the_single_env_refuses_a_step_after_the_end_and_names_bad_actions():
    env = gymnasium.make("flashnav/TurtleBot2-v0").unwrapped
    env.reset(seed=0)
    for shape in [(3,), (2, 1), (1, 2)]:
        with pytest.raises(ValueError, match=rf"action must have shape \[2\] .*got \[{', '.join(map(str, shape))}\]"):
            env.step(np.zeros(shape))
    info, ended = {}, False
    for _ in range(400):  # full speed ahead: a collision or the horizon within 400 steps
        _, _, terminated, truncated, info = env.step(np.array([1.0, 0.3]))
        if terminated or truncated:
            ended = True
            break
    assert ended and set(info) == {"success", "collision", "collision_static", "collision_agent", "episode_steps",
                                   "episode_return", "final_pose"}
    assert info["episode_steps"] >= 1 and info["final_pose"].shape == (3,)
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        env.step(np.zeros(2))
    env.reset(seed=1)
    env.step(np.zeros(2))
    with pytest.raises(NotImplementedError, match="flashnav render"):
        env.render()
    with pytest.raises(ValueError, match="no render mode"):
        gymnasium.make("flashnav/TurtleBot2-v0", render_mode="rgb_array")


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="unknown robot"):
        make_env("turtlebot3", 1)
    if not torch.cuda.is_available():  # torch's own "Torch not compiled with CUDA enabled" AssertionError before
        with pytest.raises(ValueError, match="device 'cuda' requested but CUDA is not available"):
            make_env("turtlebot2", 1, device="cuda")
    with pytest.raises(ValueError, match="tpu"):
        make_env("turtlebot2", 1, device="tpu")
    with pytest.raises(ValueError, match="num_envs"):
        make_env("turtlebot2", 0)
    with pytest.raises(ValueError, match="raycaster"):
        make_env("turtlebot2", 1, raycaster="nope")
    tiny = OccupancyMap(np.zeros((8, 8), dtype=bool), 0.05, name="tiny")
    with pytest.raises(ValueError, match="no free space"):
        make_env("turtlebot2", 1, map=tiny)


def retry_env(p, n=6, seed=5, **overrides):
    return make_env(load_robot("turtlebot2", **{"episode.retry_failed": p, **overrides}), n, seed=seed)


def test_retry_failed_restarts_failed_slots_from_their_start_and_draws_afresh_elsewhere():
    # slots 0-1 collide, 2-3 reach the goal, 4-5 keep driving: p = 1 restarts exactly the failed ones
    env = retry_env(1.0)
    env.reset(seed=5)
    pose = env.world_pose().clone()
    pose[:2, 2] = 0.0
    goal = env.world_goal().clone()
    goal[2:4] = pose[2:4, :2].double() + torch.tensor([0.05, 0.0], dtype=torch.float64)  # 5 cm ahead
    pose[2:4, 2] = 0.0
    env.set_state(pose, goal)
    starts = env.start_pose.clone(), env.start_goal.clone()
    env.pose[:2, 0] = 100.0                       # off the map: a collision in the next step, whatever the action
    before = env.pose[4:].clone(), env.goal[4:].clone()
    _, _, terminated, _, info = env.step(torch.tensor([[1.0, 0.0]] * 6))
    assert info["collision"][:2].all() and info["success"][2:4].all() and not terminated[4:].any()
    assert torch.equal(env.pose[:2], starts[0][:2]) and torch.equal(env.goal[:2], starts[1][:2])
    assert (env.steps[:4] == 0).all() and torch.equal(env.start_pose[:2], starts[0][:2])
    assert not torch.equal(env.goal[2:4], starts[1][2:4])          # the successes drew new episodes
    assert torch.equal(env.goal[4:], before[1]) and not torch.equal(env.pose[4:], before[0])  # still driving
    # the restarted slot's observation is its episode's first one again
    fresh = retry_env(1.0)
    fresh.set_state(pose, goal)
    assert torch.equal(env.obs[:2], fresh.obs[:2])


def test_retry_failed_zero_is_todays_environment_and_timeouts_count_as_failures():
    def rollout(env):
        env.reset(seed=7)
        gen = torch.Generator().manual_seed(1)
        out = []
        for _ in range(250):   # past the horizon: timeouts and collisions under random actions
            obs, reward, *_ = env.step(torch.rand(6, 2, generator=gen) * 2 - 1)
            out += [obs, reward[:, None]]
        return torch.cat(out, 1)

    assert torch.equal(rollout(make_env("turtlebot2", 6, seed=7)), rollout(retry_env(0.0, seed=7)))
    env = retry_env(1.0, n=2)
    env.reset(seed=1)
    start = env.pose.clone()
    for _ in range(200):                      # standing still: a timeout at the horizon, then the same start
        env.step(torch.tensor([[-1.0, 0.0]] * 2))
    assert torch.equal(env.pose, start) and (env.steps == 0).all()


def test_retry_failed_is_a_probability_and_leaves_evaluation_as_it_is():
    with pytest.raises(ValueError, match="retry_failed"):
        load_robot("turtlebot2", **{"episode.retry_failed": 1.5})
    from flashnav.evaluate import evaluate
    weights = torch.randn(34, 2, generator=torch.Generator().manual_seed(0)) * 0.3

    def policy(obs):
        return torch.tanh(obs @ weights)

    for dense in (False, True):   # each slot's first episode counts, whatever follows it
        plain = evaluate(policy, make_env("turtlebot2", 64, seed=3), seed=11, dense=dense)
        assert plain["success_rate"] < 1 and plain == evaluate(policy, retry_env(1.0, n=64, seed=3), seed=11, dense=dense)
