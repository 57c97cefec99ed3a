"""The opt-in scan history (observation.scan_history, flashnav/sim/history.py): k = 0 is today's
observation bit for bit; with k > 0 the paper's columns are unchanged and the history columns equal a
slow reference (a Python list of past pooled scans per slot) through sparse resets, with agents, noise
and many maps; a slot's reset or a partial step leaves the other slots' histories bit-identical; the
IPAPRec transform treats history frames like the current one."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from flashnav.learn.networks import IPAPRec, ObsLayout
from flashnav.maps import generate_map
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv, make_env

FIXTURE = Path(__file__).parent / "fixtures" / "agents_k0_trajectory.npz"


def forward_actions(gen: torch.Generator, n: int) -> torch.Tensor:
    """Seeded random actions biased forward (episodes end in collisions and at goals: resets happen)."""
    action = torch.rand(n, 2, generator=gen) * 2 - 1
    action[:, 0] = action[:, 0] * 0.5 + 0.5
    return action


def test_zero_history_gives_exactly_the_saved_transitions():
    """The fixture of tests/test_agents_env.py (recorded before agents and history existed), with
    scan_history 0 given explicitly."""
    saved = np.load(FIXTURE)
    env = make_env(load_robot("turtlebot2", **{"observation.scan_history": 0}), 6, seed=5)
    assert env.extras.history is None and env.obs_dim == 34
    obs, _ = env.reset(seed=5)
    gen = torch.Generator().manual_seed(5)
    got = {"obs": [obs], "reward": [], "terminated": [], "final_obs": []}
    for _ in range(40):
        obs, reward, terminated, _, info = env.step(forward_actions(gen, 6))
        for key, value in (("obs", obs), ("reward", reward), ("terminated", terminated), ("final_obs", info["final_obs"])):
            got[key].append(value)
    assert saved["turtlebot2/terminated"].any()
    for key, values in got.items():
        assert np.array_equal(torch.stack(values).numpy(), saved[f"turtlebot2/{key}"]), key


def paired_envs(robot: str, k: int, n: int, seed: int, maps=None, **overrides):
    """The same env twice, without and with a k-frame history."""
    def env(history):
        preset = load_robot(robot, **overrides, **{"observation.scan_history": history})
        return NavVecEnv(preset, n, grid=maps or make_env(preset).map, seed=seed)
    return env(0), env(k)


CASES = {
    "tb2": ("turtlebot2", 3, {}),
    "go2-k1": ("go2", 1, {}),
    "tb2-agents-noise": ("turtlebot2", 4, {"agents.count": 4, "lidar.noise_std": 0.05, "lidar.dropout": 0.05}),
    "tb2-many-maps": ("turtlebot2", 2, {"agents.count": 2}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_history_columns_equal_a_list_of_past_scans_per_slot(case):
    robot, k, overrides = CASES[case]
    maps = [generate_map(6.0, 6.0, 0.05, seed=s, robot_radius=0.3, name=f"m{s}") for s in (1, 2)] \
        if case == "tb2-many-maps" else None
    n, seed = 6, 11
    plain, hist = paired_envs(robot, k, n, seed, maps, **overrides)
    s, base = plain.preset.lidar.sectors, plain.obs_dim
    assert hist.obs_dim == base + k * s and hist.single_observation_space.shape == (base + k * s,)
    assert np.array_equal(hist.single_observation_space.high[base:], np.tile(plain.single_observation_space.high[:s], k))

    obs0, _ = plain.reset(seed=seed)
    obs1, _ = hist.reset(seed=seed)
    past = [[obs0[i, :s].clone() for _ in range(k)] for i in range(n)]  # the reference: newest first
    gen = torch.Generator().manual_seed(seed)
    resets = 0
    for step in range(60):
        for i in range(n):  # obs = the paper's columns, then the previous frames newest first
            assert torch.equal(obs1[i, :base], obs0[i]), (step, i)
            assert torch.equal(obs1[i, base:], torch.cat(past[i])), (step, i)
        action = forward_actions(gen, n)
        seen = obs0[:, :s].clone()  # the scans the policy saw before this step
        obs0, r0, term0, trunc0, info0 = plain.step(action)
        obs1, r1, term1, trunc1, info1 = hist.step(action)
        assert torch.equal(r0, r1) and torch.equal(term0, term1) and torch.equal(trunc0, trunc1)
        for i in range(n):
            past[i] = [seen[i], *past[i][:-1]]  # the step's observation: the frames up to the last one
            final = info1["final_obs"][i]
            assert torch.equal(final[:base], info0["final_obs"][i])
            assert torch.equal(final[base:], torch.cat(past[i])), (step, i)
            if bool(info0["_final_obs"][i]):  # a new episode: its first scan, k times
                past[i] = [obs0[i, :s].clone() for _ in range(k)]
                resets += 1
    assert resets >= 2, "the rollout must exercise sparse resets"


def test_a_slot_reset_and_a_partial_step_leave_other_histories_bit_identical():
    env = make_env(load_robot("turtlebot2", **{"observation.scan_history": 3, "agents.count": 4}), 8, seed=2)
    env.reset(seed=2)
    for _ in range(4):
        env.step(torch.full((8, 2), 0.3))
    frames, obs = env.extras.history.frames.clone(), env.obs.clone()
    mask = torch.zeros(8, dtype=torch.bool)
    mask[[1, 5]] = True
    new, _ = env.reset(options={"reset_mask": mask})
    assert torch.equal(env.extras.history.frames[~mask], frames[~mask]) and torch.equal(new[~mask], obs[~mask])
    for i in (1, 5):  # the reset slots: every frame is the new first scan
        assert torch.equal(env.extras.history.frames[i], new[i, :30].expand(3, -1))
        assert torch.equal(new[i, 34:], new[i, :30].repeat(3))

    frames = env.extras.history.frames.clone()
    idx = torch.tensor([0, 6])
    out = env.step_slots(idx, torch.full((2, 2), 0.3))
    others = torch.ones(8, dtype=torch.bool)
    others[idx] = False
    assert torch.equal(env.extras.history.frames[others], frames[others])
    for j, i in enumerate(idx.tolist()):
        assert torch.equal(out["obs"][j, 34:], frames[i].flatten())
        assert torch.equal(env.extras.history.frames[i], torch.cat([out["obs"][j, None, :30], frames[i, :2]]))


def test_set_state_starts_every_history_afresh():
    env = make_env(load_robot("turtlebot2", **{"observation.scan_history": 2}), 3, seed=0)
    env.reset(seed=0)
    for _ in range(3):
        env.step(torch.full((3, 2), 0.5))
    obs = env.set_state(env.world_pose(), env.world_goal())
    assert torch.equal(obs[:, 34:], obs[:, :30].repeat(1, 2))


@pytest.mark.parametrize("value, match", [(-1, "greater than or equal to 0"), (17, "less than or equal to 16"),
                                          ("three", "valid integer")])
def test_a_bad_scan_history_names_the_key_and_the_value(value, match):
    with pytest.raises(ValueError, match=match) as exc:
        load_robot("turtlebot2", **{"observation.scan_history": value})
    assert "observation.scan_history" in str(exc.value) and repr(value) in str(exc.value)


# ---- the networks' input transform ------------------------------------------------------------------
def layouts(k: int) -> ObsLayout:
    preset = load_robot("turtlebot2", **{"observation.scan_history": k})
    return ObsLayout.from_robot(preset, math.hypot(10, 10))


@pytest.mark.parametrize("copies", [0, 2])
def test_history_frames_get_the_current_frames_transform_with_one_shared_beta(copies):
    lay0, lay3 = layouts(0), layouts(3)
    assert (lay3.base_dim, lay3.obs_dim) == (34, 124) and lay0.obs_dim == 34
    t0, t3 = IPAPRec(lay0, copies=copies), IPAPRec(lay3, copies=copies)
    assert [p.shape for p in t0.parameters()] == [p.shape for p in t3.parameters()]  # one rho per transform
    with torch.no_grad():
        t3.rho.copy_(torch.linspace(-1.0, 2.0, copies) if copies else torch.tensor(0.7))
        t0.rho.copy_(t3.rho)
    obs = torch.rand(5, 124, generator=torch.Generator().manual_seed(0)) * 25.0
    x3 = t3(obs)
    assert x3.shape == ((copies, 5, 124) if copies else (5, 124))
    assert torch.equal(x3[..., :34], t0(obs[:, :34]))  # the paper's columns as without a history
    beta = t3.beta().view(-1, 1, 1) if copies else t3.beta()
    for frame in range(3):  # slow reference: each history frame like a current frame
        cols = slice(34 + 30 * frame, 64 + 30 * frame)
        want = 1.0 / (obs[:, cols].clamp(0.2, 20.0) - beta)
        torch.testing.assert_close(x3[..., cols], want, rtol=0, atol=0)
    x3[..., 34:].sum().backward()
    assert t3.rho.grad is not None and bool((t3.rho.grad != 0).all())  # history frames train the shared beta


def test_a_layout_refuses_a_negative_history():
    with pytest.raises(ValueError, match="scan_history"):
        ObsLayout(30, 0.2, 20.0, 14.1, (0.5, 0.78), scan_history=-2)
