"""The deploy runtime's scan adapter against the simulator and a slow per-beam reference."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from flashnav.deploy.runtime import PolicyRuntime
from flashnav.deploy.scan import Mount, ScanAdapter, SectorLayout
from flashnav.export import policy_metadata
from flashnav.presets import load_robot
from flashnav.sim.env import make_env

TB2 = SectorLayout(sectors=30, fov_deg=270.0, max_range=20.0)


def reference(angle_min, inc, ranges, range_min, range_max, layout, mount=Mount(), fill=None):
    """Beam by beam, sector by sector, in plain Python, from the conventions as written in scan.py."""
    fill = layout.max_range if fill is None else fill
    fov = math.radians(layout.fov_deg)
    width = fov / layout.sectors
    best = [math.inf] * layout.sectors
    for k, r in enumerate(ranges):
        r = float(r)
        a = angle_min + k * inc
        direction = mount.yaw + (-a if mount.flipped else a)
        if math.isnan(r) or (math.isfinite(r) and (r <= 0.0 or r < range_min)):
            continue  # invalid
        if r == math.inf or r > range_max:
            dist, ang = layout.max_range, direction
        else:
            if r == -math.inf:
                r = range_min
            px, py = mount.x + r * math.cos(direction), mount.y + r * math.sin(direction)
            dist, ang = math.hypot(px, py), math.atan2(py, px)
        # the sector whose angular span holds ang (angles compared modulo 2 pi)
        for s in range(layout.sectors):
            lo = -fov / 2 + s * width
            rel = (ang - lo) % (2 * math.pi)
            if rel < width:
                best[s] = min(best[s], dist)
                break
    return np.array([fill if math.isinf(b) else min(b, layout.max_range) for b in best], np.float32)


def _scan(n, fov_deg, seed, reverse=False):
    """A synthetic scan: n beams at bin centres over fov_deg, ranges in (0.1, 25) m."""
    fov = math.radians(fov_deg)
    inc = fov / n
    angle_min = -fov / 2 + inc / 2
    if reverse:
        angle_min, inc = -angle_min, -inc
    rng = np.random.default_rng(seed)
    return angle_min, inc, rng.uniform(0.1, 25.0, n).astype(np.float32)


def test_simulator_scans_give_the_environment_observation():
    env = make_env("turtlebot2", 16, seed=3)
    obs, _ = env.reset(seed=3)
    preset = env.preset
    rt = PolicyRuntime(None, policy_metadata(preset, 10 * 2 ** 0.5))
    lidar = preset.lidar
    fov = math.radians(lidar.fov_deg)
    inc = np.float32(fov / lidar.beams)  # LaserScan carries float32 angles
    angle_min = np.float32(-fov / 2 + fov / lidar.beams / 2)
    for step in range(3):
        scans = env.scan().numpy()
        pose, goal = env.world_pose().numpy(), env.world_goal().numpy()
        vel = env.velocity.numpy()
        for i in range(env.num_envs):
            sectors = rt.scan(float(angle_min), float(inc), scans[i], 0.0, lidar.max_range)
            assert np.array_equal(sectors, obs[i, :30].numpy())  # bit for bit
            full = rt.observation(sectors, pose[i], goal[i], vel[i])
            np.testing.assert_allclose(full, obs[i].numpy(), rtol=0, atol=2e-6)
        obs, *_ = env.step(torch.rand(env.num_envs, 2) * 2 - 1)


@pytest.mark.parametrize("n, fov, reverse", [(1080, 270, False), (720, 180, False), (1440, 360, False),
                                             (1080, 270, True), (360, 360, True)])
def test_beam_counts_and_directions_match_the_reference(n, fov, reverse):
    angle_min, inc, ranges = _scan(n, fov, seed=n + fov, reverse=reverse)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        got = ScanAdapter(TB2)(angle_min, inc, ranges, 0.05, 22.0)
    np.testing.assert_allclose(got, reference(angle_min, inc, ranges, 0.05, 22.0, TB2), rtol=0, atol=1e-6)


def test_reversed_scan_equals_the_forward_one():
    angle_min, inc, ranges = _scan(1080, 270, seed=1)
    forward = ScanAdapter(TB2)(angle_min, inc, ranges, 0.05, 22.0)
    backward = ScanAdapter(TB2)(angle_min + inc * 1079, -inc, ranges[::-1], 0.05, 22.0)
    np.testing.assert_array_equal(forward, backward)


def test_narrow_fov_warns_and_fills():
    angle_min, inc, ranges = _scan(720, 180, seed=2)
    adapter = ScanAdapter(TB2, fill=0.7)
    with pytest.warns(RuntimeWarning, match="covers only 20 of the policy's 30 sectors"):
        got = adapter(angle_min, inc, ranges, 0.05, 22.0)
    assert adapter.blind_sectors == [0, 1, 2, 3, 4, 25, 26, 27, 28, 29]
    assert (got[adapter.blind_sectors] == np.float32(0.7)).all()
    np.testing.assert_allclose(got, reference(angle_min, inc, ranges, 0.05, 22.0, TB2, fill=0.7), atol=1e-6)


def test_invalid_readings_follow_rep_117():
    angle_min, inc, ranges = _scan(1080, 270, seed=4)
    ranges = ranges.copy()
    ranges[0:36] = np.nan                    # sector 0: all invalid -> fill
    ranges[36:72] = 30.0                     # sector 1: above range_max -> max range
    ranges[72:108] = np.inf                  # sector 2: no return -> max range
    ranges[108:144] = 0.0                    # sector 3: zeros are invalid -> fill
    ranges[150] = -np.inf                    # sector 4: too close -> range_min
    ranges[190] = 0.01                       # sector 5: below range_min -> dropped
    ranges[200] = np.nan                     # sector 5: one NaN among valid beams -> ignored
    adapter = ScanAdapter(TB2, fill=1.5)
    with pytest.warns(RuntimeWarning, match=r"scan: sectors \[0, 3\] of 30 had no valid reading"):
        got = adapter(angle_min, inc, ranges, 0.05, 22.0)
    assert adapter.invalid_sectors == [0, 3] and not adapter.no_valid_reading
    want = reference(angle_min, inc, ranges, 0.05, 22.0, TB2, fill=1.5)
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert got[0] == got[3] == np.float32(1.5)
    assert got[1] == got[2] == 20.0
    assert got[4] == np.float32(0.05)
    assert got[5] == np.float32(ranges[180:216][(ranges[180:216] >= 0.05)].min())


@pytest.mark.parametrize("mount", [Mount(yaw=math.pi / 2), Mount(x=0.1, y=-0.05, yaw=math.pi / 2),
                                   Mount(yaw=-0.3, flipped=True)])
def test_mounting_yaw_offset_and_flip_match_the_reference(mount):
    angle_min, inc, ranges = _scan(1440, 360, seed=5)
    got = ScanAdapter(TB2, mount)(angle_min, inc, ranges, 0.05, 22.0)
    np.testing.assert_allclose(got, reference(angle_min, inc, ranges, 0.05, 22.0, TB2, mount), atol=1e-5)


def test_yaw_90_shifts_the_sectors():
    """A sensor turned 90 deg to the left sees at its angle a the base angle a + 90 deg: ten sectors on."""
    angle_min, inc, ranges = _scan(1080, 270, seed=6)
    plain = ScanAdapter(TB2)(angle_min, inc, ranges, 0.05, 22.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        turned = ScanAdapter(TB2, Mount(yaw=math.pi / 2))(angle_min, inc, ranges, 0.05, 22.0)
    np.testing.assert_array_equal(turned[10:], plain[:20])


def test_bad_inputs_name_themselves():
    with pytest.raises(ValueError, match="angle_increment"):
        ScanAdapter(TB2)(0.0, 0.0, [1.0], 0.0, 10.0)
    with pytest.raises(ValueError, match="no ranges"):
        ScanAdapter(TB2)(0.0, 0.1, [], 0.0, 10.0)
    with pytest.raises(ValueError, match="fill"):
        ScanAdapter(TB2, fill=-1.0)
    with pytest.raises(ValueError, match="mount.yaw"):
        Mount(yaw=math.nan)
