"""Mirror augmentation (``algo.mirror``, flashnav/learn/mirror.py): the reflected transition is the one the
simulator itself gives on the mirror image of the map, and the replay reflects the share it is asked to."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from flashnav.learn.hparams import load_hparams
from flashnav.learn.mirror import mirror_for
from flashnav.learn.replay import Replay, Transition
from flashnav.maps.grid import OccupancyMap
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv, make_env


def _mirrored_world(preset, n: int = 64, seed: int = 3):
    """(env on the bundled map with n sampled episodes, env on its mirror image with the mirrored episodes,
    the reflection of world points)."""
    env = make_env(preset, n, seed=seed)
    env.reset(seed=seed)
    g = env.map
    flipped = OccupancyMap(g.occupied[::-1].copy(), g.resolution, g.origin, name=g.name + "-mirrored")
    axis = 2 * g.origin[1] + g.height_m  # y -> axis - y reflects the map onto its mirror image
    twin = NavVecEnv(preset, n, grid=flipped, seed=seed)
    twin.reset(seed=seed)
    pose, goal = env.world_pose().double(), env.world_goal().double()
    mpose = torch.stack([pose[:, 0], axis - pose[:, 1], -pose[:, 2]], dim=1)
    mgoal = torch.stack([goal[:, 0], axis - goal[:, 1]], dim=1)
    return env, twin, (pose, goal), (mpose, mgoal)


@pytest.mark.parametrize("robot,extras", [("turtlebot2", {}), ("go2", {}),
                                          ("turtlebot2", {"observation.scan_history": 2, "observation.pose_trail": 3})])
def test_mirrored_observations_are_the_mirror_worlds(robot, extras):
    preset = load_robot(robot, **extras)
    mirror = mirror_for(preset, 1.0)
    env, twin, (pose, goal), (mpose, mgoal) = _mirrored_world(preset)
    obs = env.set_state(pose, goal)
    mobs = twin.set_state(mpose, mgoal)
    torch.testing.assert_close(mirror.obs(obs), mobs, atol=1e-4, rtol=0)
    gen = torch.Generator().manual_seed(0)
    active = torch.arange(env.num_envs)
    compared = 0
    for _ in range(40):
        action = torch.rand(len(active), 2, generator=gen) * 2 - 1
        a = env.step_slots(active, action)
        b = twin.step_slots(active, mirror.action(action))
        torch.testing.assert_close(mirror.obs(a["obs"]), b["obs"], atol=1e-3, rtol=0)  # float32 poses drift apart by ~1e-4 m
        for key in ("reward", "terminated", "truncated", "success", "collision"):
            torch.testing.assert_close(a[key], b[key], atol=1e-5, rtol=0, msg=f"{robot}: {key} differs")
        compared += len(active)
        running = ~(a["terminated"] | a["truncated"])
        active = active[running]
        if not len(active):
            break
    assert compared > 1000


@pytest.mark.parametrize("visited", [False, True])
def test_the_mirrored_wall_map_is_the_mirror_worlds(visited):
    """The wall map's squares (every channel, rows reversed; the visited squares too) reflect exactly as the mirror
    world draws them, with the memory scan and everything else, step after step until each episode ends."""
    cells = 12
    preset = load_robot("turtlebot2", **{"observation.wall_map": cells, "observation.memory_frames": 2,
                                         "observation.wall_map_visited": visited})
    mirror = mirror_for(preset, 1.0)
    env, twin, (pose, goal), (mpose, mgoal) = _mirrored_world(preset, n=32)
    obs, mobs = env.set_state(pose, goal), twin.set_state(mpose, mgoal)
    end = preset.memory_end
    gen = torch.Generator().manual_seed(0)
    active, walls, been = torch.arange(env.num_envs), 0, 0
    for _ in range(20):
        torch.testing.assert_close(mirror.obs(obs)[:, :end], mobs[:, :end], atol=1e-3, rtol=0)
        assert torch.equal(mirror.obs(obs)[:, end:], mobs[:, end:])
        assert not torch.equal(obs[:, end:], mobs[:, end:])  # the reflection is not the identity here
        walls += int(mobs[:, end: end + cells * cells].sum())
        been += int(mobs[:, end + 2 * cells * cells:].sum())
        action = torch.rand(len(active), 2, generator=gen) * 2 - 1
        a, b = env.step_slots(active, action), twin.step_slots(active, mirror.action(action))
        running = ~(a["terminated"] | a["truncated"])
        active, obs, mobs = active[running], a["obs"][running], b["obs"][running]
        if not len(active):
            break
    assert walls > 5000 and (been > 200 if visited else been == 0)
    assert mobs.shape[1] == end + (3 if visited else 2) * cells * cells


def test_mirror_is_an_involution_and_knows_every_column():
    preset = load_robot("turtlebot2", **{"observation.scan_history": 1, "observation.agent_tracks": 2,
                                         "observation.pose_trail": 1, "agents.count": 2})
    m = mirror_for(preset, 0.5)
    assert m.obs_index.numel() == preset.obs_dim
    assert sorted(m.obs_index.tolist()) == list(range(preset.obs_dim))  # a permutation
    x = torch.randn(5, preset.obs_dim)
    torch.testing.assert_close(m.obs(m.obs(x)), x)
    # a track (present, x, y, vx, vy, radius): only y and vy change sign
    start = preset.history_end
    track = x[:, start:start + 6]
    torch.testing.assert_close(m.obs(x)[:, start:start + 6], track * torch.tensor([1, 1, -1, 1, -1, 1.0]))
    # the trail's breadcrumb (x, y): y
    torch.testing.assert_close(m.obs(x)[:, preset.tracks_end:], x[:, preset.tracks_end:] * torch.tensor([1, -1.0]))


def test_mirror_refuses_what_it_cannot_reflect():
    assert mirror_for(load_robot("turtlebot2"), 0.0) is None
    with pytest.raises(ValueError, match=r"algo.mirror must be a fraction"):
        mirror_for(load_robot("turtlebot2"), 1.5)
    lopsided = load_robot("turtlebot2", **{"motion.w_bounds": [-0.5, 0.785]})
    with pytest.raises(ValueError, match=r"motion.w_bounds = \(-0.5, 0.785\)"):
        mirror_for(lopsided, 0.5)
    with pytest.raises(ValueError, match="mirror"):
        load_hparams("fastdsac", "turtlebot2", "cpu", {"mirror": -0.1})


def _filled_replay(mirror, n_step: int = 1):
    preset = load_robot("turtlebot2")
    d = preset.obs_dim
    r = Replay(4, d, 2, 64, seed=5, n_step=n_step, gamma=0.99 if n_step > 1 else None, mirror=mirror)
    gen = torch.Generator().manual_seed(1)
    for _ in range(16):
        r.add(torch.randn(4, d, generator=gen), torch.rand(4, 2, generator=gen) * 2 - 1,
              torch.randn(4, generator=gen), torch.zeros(4), torch.randn(4, d, generator=gen),
              ended=torch.zeros(4, dtype=torch.bool))
    return r, preset


@pytest.mark.parametrize("n_step", [1, 3])
def test_replay_mirrors_the_share_asked_and_nothing_else(n_step):
    plain, preset = _filled_replay(None, n_step)
    stored = plain.obs.clone()
    base = plain.sample(256, 2)
    for fraction, lo, hi in ((1.0, 1.0, 1.0), (0.5, 0.4, 0.6)):
        m = mirror_for(preset, fraction)
        r, _ = _filled_replay(m, n_step)
        got = r.sample(256, 2)
        torch.testing.assert_close(r.obs, stored)  # the buffer itself is never touched
        same = (got.obs == base.obs).all(-1) & (got.action == base.action).all(-1)
        twin = ((got.obs - m.obs(base.obs)).abs().max(-1).values < 1e-6) & (got.action == m.action(base.action)).all(-1)
        twin &= (got.next_obs - m.obs(base.next_obs)).abs().max(-1).values < 1e-6
        assert bool((same | twin).all())  # each row is either itself or its whole mirror image
        assert lo <= float(twin.float().mean()) <= hi
        torch.testing.assert_close(got.reward, base.reward)
        torch.testing.assert_close(got.bootstrap, base.bootstrap)
        out = Transition(*(torch.empty_like(x) for x in base))
        r2, _ = _filled_replay(m, n_step)
        torch.testing.assert_close(tuple(r2.sample(256, 2, out=out)), tuple(got))  # the static-buffer path too


def test_mirror_off_keeps_batches_bit_identical():
    a, _ = _filled_replay(None)
    b, _ = _filled_replay(mirror_for(load_robot("turtlebot2"), 0.0))
    for x, y in zip(a.sample(128, 3), b.sample(128, 3)):
        assert torch.equal(x, y)
    assert np.isclose(load_hparams("fastdsac", "turtlebot2", "paper", {}).mirror, 0.0)


def test_training_with_mirror_reaches_the_updates_and_is_recorded():
    from flashnav import train
    from tests.test_train import TINY, flat, tiny

    mirrored = train(tiny(overrides={**TINY, "algo.mirror": 0.5}))
    assert mirrored.spec.hparams.mirror == 0.5
    plain = train(tiny())
    a = flat(mirrored.learner.policy)
    b = flat(plain.learner.policy)
    assert not torch.equal(a, b)  # the reflected rows reached the updates
    again = train(tiny(overrides={**TINY, "algo.mirror": 0.5}))
    assert torch.equal(a, flat(again.learner.policy))  # seeded
