"""Actuation between command and motion (``motion.command_delay``, ``max_linear_accel``, ``max_angular_accel``):
off, every step is the paper's (no Actuation at all); a delay of d plays the commands of d steps before; the
acceleration limits equal a per-slot scalar reference; a reset clears only its slots' queues; the observation's
velocity state is the command sent."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.presets import load_robot
from flashnav.sim.env import make_env

N, STEPS = 16, 30


def _env(**motion):
    return make_env(load_robot("turtlebot2", **{f"motion.{k}": v for k, v in motion.items()}), N, seed=3)


def _actions(steps=STEPS, seed=0):
    g = torch.Generator().manual_seed(seed)
    return [torch.rand(N, 2, generator=g) * 2 - 1 for _ in range(steps)]


def test_the_paper_motion_has_no_actuation_at_all():
    env = _env()
    assert env.actuation is None and env.preset.motion.instant
    assert not load_robot("turtlebot2", **{"motion.command_delay": 1}).motion.instant


@pytest.mark.parametrize("delay", [1, 3])
def test_a_delay_plays_the_commands_of_d_steps_before(delay):
    """The delayed env given a_0, a_1, ... moves exactly as the paper's env given d rests, then a_0, a_1, ...
    (until the first episode ends: the delayed env's reset then starts its slot's queue afresh)."""
    late, now = _env(command_delay=delay), _env()
    late.reset(seed=5)
    now.reset(seed=5)
    actions = _actions()
    rest = torch.tensor([-1.0, 0.0]).expand(N, 2)  # v = 0 (TurtleBot2 forward-only: -1 maps to 0), w = 0
    shifted = [rest] * delay + actions
    alive = torch.ones(N, dtype=torch.bool)
    for t in range(STEPS):
        _, _, term_l, trunc_l, _ = late.step(actions[t])
        _, _, term_n, trunc_n, _ = now.step(shifted[t])
        assert torch.equal(late.pose[alive], now.pose[alive])
        assert torch.equal(late.velocity[alive], now.velocity[alive])
        alive &= ~(term_l | trunc_l | term_n | trunc_n)
    assert alive.sum() >= N // 2  # the comparison covered most slots to the end


def test_acceleration_limits_equal_a_scalar_reference():
    a_v, a_w = 0.4, 1.5
    env = _env(max_linear_accel=a_v, max_angular_accel=a_w)
    env.reset(seed=5)
    dt, m = env.preset.episode.dt, env.preset.motion
    v_ref = [[0.0, 0.0] for _ in range(N)]
    alive = torch.ones(N, dtype=torch.bool)
    for a in _actions():
        want = []
        for i in range(N):
            act = [min(max(float(x), -1.0), 1.0) for x in a[i]]
            cmd = [m.v_bounds[0] + (act[0] + 1) * 0.5 * (m.v_bounds[1] - m.v_bounds[0]),
                   m.w_bounds[0] + (act[1] + 1) * 0.5 * (m.w_bounds[1] - m.w_bounds[0])]
            cmd = [max(-m.max_linear_velocity, min(m.max_linear_velocity, cmd[0])),
                   max(-m.max_angular_velocity, min(m.max_angular_velocity, cmd[1]))]
            step = [a_v * dt, a_w * dt]
            want.append([v_ref[i][j] + max(-step[j], min(step[j], cmd[j] - v_ref[i][j])) for j in range(2)])
        _, _, term, trunc, _ = env.step(a)
        alive &= ~(term | trunc)  # a slot that ended this step starts afresh (velocity 0): compared no more
        got = env.velocity.tolist()
        for i in range(N):
            if alive[i]:
                assert got[i] == pytest.approx(want[i], abs=1e-6), (i, got[i], want[i])
        v_ref = want
    assert alive.sum() >= N // 2


def test_a_reset_clears_its_slots_queue_only_and_the_observation_has_the_command():
    env = _env(command_delay=2)
    env.reset(seed=5)
    env.step(torch.ones(N, 2))
    env.step(torch.zeros(N, 2))
    before = env.actuation.queue.clone()
    env.reset(options={"reset_mask": torch.arange(N) < 4})
    assert (env.actuation.queue[:4] == 0).all() and torch.equal(env.actuation.queue[4:], before[4:])
    obs, *_ = env.step(torch.ones(N, 2))
    m = env.preset.motion
    # the observation's velocity state is the command (top speed, top turn rate), the executed one lags two steps
    v_col = env.preset.lidar.sectors + 2
    assert obs[:, v_col].tolist() == pytest.approx([m.v_bounds[1]] * N)
    assert obs[:, v_col + 1].tolist() == pytest.approx([m.w_bounds[1]] * N)
    assert (env.velocity[:4] == 0).all()  # reset slots: their first command is two steps away
    assert env.velocity[4:, 0].tolist() == pytest.approx([m.v_bounds[1]] * (N - 4))  # the first step's command


def test_bad_actuation_values_are_named():
    with pytest.raises(ValueError, match="command_delay"):
        load_robot("turtlebot2", **{"motion.command_delay": -1})
    with pytest.raises(ValueError, match="max_linear_accel"):
        load_robot("turtlebot2", **{"motion.max_linear_accel": 0})
    assert math.isinf(float(_env(max_linear_accel=1.0).actuation.step_limit[1]))


def test_the_people_shield_warns_that_its_rollouts_assume_instant_motion():
    from flashnav.shield import PeopleShield

    with pytest.warns(RuntimeWarning, match="rollouts are optimistic"):
        PeopleShield(load_robot("turtlebot2", **{"motion.command_delay": 1}))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        PeopleShield(load_robot("turtlebot2"))  # the paper's motion: no warning


def test_a_rendered_rollout_ends_where_the_delayed_robot_did():
    """``rollout`` draws the env's own poses (``info["final_pose"]``), so a robot with latency is drawn where it
    went, not where an instant robot would have gone."""
    from flashnav.rollout import rollout

    env = _env(command_delay=3)
    forward = lambda obs: torch.tensor([1.0, 0.0]).expand(obs.shape[0], 2)  # noqa: E731
    result = rollout(forward, env, seed=5)
    first = result["poses"][:4, :, :2]  # the first three steps execute the queue's rests
    assert (abs(first - first[0]) < 1e-6).all()
    moved = np.linalg.norm(result["poses"][4, :, :2] - result["poses"][0, :, :2], axis=1)
    assert moved[result["length"] > 4] == pytest.approx(0.05, abs=1e-5)  # then 0.05 m per step forward
