"""Evaluation: ``env.step_slots`` semantics, and ``evaluate`` against the dense (every slot, every step) way."""

from __future__ import annotations

import math

import pytest
import torch

from flashnav.evaluate import FAILED_LISTED_MAX, STALL_M, episode_rates, evaluate, evaluate_episodes, stalled
from flashnav.sim.env import make_env


def heading_controller(obs: torch.Tensor) -> torch.Tensor:
    """A deterministic, row-wise policy (so batch size cannot change its output): turn towards the goal,
    drive when roughly facing it, slow down when the front sector is close. Reaches some goals, hits
    some walls, times out on others: every outcome occurs on the bundled map."""
    angle = obs[:, 31]
    front = obs[:, 14:16].amin(dim=1)
    turn = (2.0 * angle / math.pi).clamp(-1.0, 1.0)
    drive = torch.where((angle.abs() < 0.6) & (front > 0.3), 1.0, -1.0)
    return torch.stack([drive, turn], dim=1)


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_evaluate_equals_the_dense_reference(robot):
    env = make_env(robot, 96, seed=0)
    fast = evaluate(heading_controller, env, seed=7)
    slow = evaluate(heading_controller, env, seed=7, dense=True)  # every slot, every step: the plain way
    assert fast["success_rate"] == slow["success_rate"]
    assert fast["collision_rate"] == slow["collision_rate"]
    assert fast["timeout_rate"] == slow["timeout_rate"]
    assert fast["mean_return"] == pytest.approx(slow["mean_return"], abs=1e-5)
    assert fast["mean_steps"] == pytest.approx(slow["mean_steps"])
    assert 0 < fast["success_rate"] < 1 and fast["collision_rate"] > 0  # the comparison covers both outcomes


def test_an_evaluation_lists_the_episodes_it_failed():
    env = make_env("turtlebot2", 24, seed=0)
    e = evaluate_episodes(heading_controller, env, seed=3)
    failed = [k for k in range(24) if not bool(e["success"][k])]    # episode by episode
    assert 0 < len(failed) <= FAILED_LISTED_MAX
    assert evaluate(heading_controller, env, seed=3)["failed_episodes"] == failed
    assert evaluate(heading_controller, env, seed=3, dense=True)["failed_episodes"] == failed
    many = torch.zeros(FAILED_LISTED_MAX + 1, dtype=torch.bool)       # too many to list: None, not a cut list
    z = torch.zeros(FAILED_LISTED_MAX + 1)
    assert episode_rates(many, many, z, z)["failed_episodes"] is None
    assert episode_rates(~many, many, z, z)["failed_episodes"] == []


def test_each_episode_replayed_alone_from_its_start_ends_the_same_way():
    env = make_env("turtlebot2", 48, seed=0)
    e = evaluate_episodes(heading_controller, env, seed=3)
    assert e["success"].any() and e["collision"].any() and (~e["success"] & ~e["collision"]).any()
    # the recorded start/goal are the episodes that seed draws: replayed one by one with set_state, each ends alike
    for k in (int(e["success"].nonzero()[0]), int(e["collision"].nonzero()[0]),
              int((~e["success"] & ~e["collision"]).nonzero()[0])):
        one = make_env("turtlebot2", 1, seed=0)
        one.reset(seed=0)
        obs = one.set_state(e["start_pose"][k:k + 1], e["goal"][k:k + 1])
        for _ in range(one.preset.episode.horizon):
            t = one.step_slots(torch.tensor([0]), heading_controller(obs))
            obs = t["obs"]
            if bool(t["terminated"][0] | t["truncated"][0]):
                break
        assert bool(t["success"][0]) == bool(e["success"][k]) and bool(t["collision"][0]) == bool(e["collision"][k])
        assert int(t["episode_steps"][0]) == int(e["episode_steps"][k])


def circler(obs: torch.Tensor) -> torch.Tensor:
    """:func:`heading_controller` within 2.5 m of the goal; farther, a slow circle (0.1 m/s, turning at full rate):
    row-wise, with timeouts that keep driving besides the ones parked in front of a wall."""
    circle = torch.tensor([-0.6, 1.0]).expand(len(obs), 2)
    return torch.where((obs[:, 30] > 2.5)[:, None], circle, heading_controller(obs))


def test_late_metres_equal_each_episode_replayed_alone_and_name_the_parked_timeouts():
    env = make_env("turtlebot2", 48, seed=0)
    e = evaluate_episodes(circler, env, seed=3)
    horizon = env.preset.episode.horizon
    timeout = ~e["success"] & ~e["collision"]
    assert e["success"].any() and e["collision"].any()
    assert stalled(e).any() and (e["late_m"][timeout] >= STALL_M).any()  # parked timeouts and driving ones
    # the slow reference: each episode alone, summing its moves over the horizon's last horizon // 2 steps
    for k in range(48):
        one = make_env("turtlebot2", 1, seed=0)
        one.reset(seed=0)
        obs = one.set_state(e["start_pose"][k:k + 1], e["goal"][k:k + 1])
        xy, late = one.world_pose()[0, :2].clone(), 0.0
        for step in range(horizon):
            t = one.step_slots(torch.tensor([0]), circler(obs))
            obs, now = t["obs"], one.world_pose()[0, :2]
            if step >= horizon - horizon // 2:
                late += float(torch.linalg.vector_norm(now - xy))
            xy = now.clone()
            if bool(t["terminated"][0] | t["truncated"][0]):
                break
        assert e["late_m"][k].item() == pytest.approx(late, abs=1e-4)
    assert torch.equal(stalled(e), timeout & (e["late_m"] < STALL_M))
    # a robot that only turns on the spot never drives: every episode is a stalled timeout
    spin = evaluate_episodes(lambda o: torch.stack([-torch.ones(len(o)), torch.ones(len(o))], dim=1), env, seed=3)
    assert torch.equal(spin["late_m"], torch.zeros(48)) and stalled(spin).all()


def test_step_slots_equals_step_on_those_slots_and_leaves_the_others():
    a, b = make_env("turtlebot2", 16, seed=1), make_env("turtlebot2", 16, seed=1)
    a.reset(seed=1)
    b.reset(seed=1)
    idx = torch.tensor([1, 4, 5, 11])
    others = torch.tensor([i for i in range(16) if i not in idx.tolist()])
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        actions = torch.rand(16, 2, generator=gen) * 2 - 1
        before = {k: getattr(a, k)[others].clone() for k in ("pose", "velocity", "steps", "obs", "episode_return")}
        t = a.step_slots(idx, actions[idx])
        obs, reward, terminated, truncated, info = b.step(actions)
        assert torch.equal(t["obs"], info["final_obs"][idx]) and torch.equal(t["reward"], reward[idx])
        assert torch.equal(t["terminated"], terminated[idx]) and torch.equal(t["truncated"], truncated[idx])
        assert torch.equal(t["success"], info["success"][idx]) and torch.equal(t["collision"], info["collision"][idx])
        assert torch.equal(t["episode_steps"], info["episode_steps"][idx])
        for k, v in before.items():
            assert torch.equal(getattr(a, k)[others], v), k
        b.pose[others], b.velocity[others], b.steps[others] = a.pose[others], a.velocity[others], a.steps[others]
        b.obs[others], b.episode_return[others] = a.obs[others], a.episode_return[others]
        b.goal_distance[others] = a.goal_distance[others]
        if bool((terminated | truncated)[idx].any()):
            break


def test_step_slots_does_not_reset_a_finished_slot():
    env = make_env("turtlebot2", 2, seed=0)
    env.reset(seed=0)
    env.set_state(torch.tensor([[5.0, 5.0, 0.0], [5.0, 5.0, 0.0]]), torch.tensor([[5.05, 5.0], [8.0, 5.0]]))
    t = env.step_slots(torch.tensor([0]), torch.tensor([[1.0, 0.0]]))
    assert t["terminated"].tolist() == [True] and t["success"].tolist() == [True]
    assert env.steps[0].item() == 1 and env.pose[0, 0].item() > 5.0  # where it ended, not a new episode
    assert env.steps[1].item() == 0 and env.pose[1].tolist() == [5.0, 5.0, 0.0]


def test_training_episodes_pools_the_newest_windows_against_a_reference():
    """Random windows of random steps: each reading equals a plain-Python pool of the newest whole windows
    holding >= pool episodes; success where nothing ended never counts; None until pool episodes ended."""
    from flashnav.evaluate import TrainingEpisodes

    with pytest.raises(ValueError, match="pool"):
        TrainingEpisodes("cpu", 0)
    gen = torch.Generator().manual_seed(5)
    count, windows = TrainingEpisodes("cpu", pool=30), []
    for _ in range(25):
        steps = int(torch.randint(0, 6, (), generator=gen))
        done = torch.rand(steps, 16, generator=gen) < 0.15
        success = torch.rand(steps, 16, generator=gen) < 0.7
        for d, s in zip(done, success):
            count.add(d, s)
        windows.append((int(done.sum()), int((done & success).sum())))
        got = count.take()
        pooled, k = 0, len(windows)
        while k > 0 and pooled < 30:  # the reference: newest windows first until >= 30 episodes
            k -= 1
            pooled += windows[k][0]
        won = sum(w[1] for w in windows[k:])
        assert got["train_episodes"] == pooled
        assert got["train_success_rate"] == (pytest.approx(won / pooled) if pooled >= 30 else None)
    assert any(w[0] == 0 for w in windows) and sum(w[0] for w in windows) > 60  # the draw covered both cases
