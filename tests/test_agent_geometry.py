"""Beams against moving discs and the robot's footprint against discs: both kernels (numba on CPU, torch)
against brute-force references written out here (float64, one beam and one disc at a time)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.config import Footprint
from flashnav.sim.agent_geometry import TANGENT_EPS, footprint_hits_discs, ray_disc_ranges
from flashnav.sim.agent_numba import lower_by_discs
from flashnav.sim.env import beam_angles, make_env

TOL = 1e-5  # metres


def reference_ranges(pose, angles, centres, radii, active, static, max_range):
    """min(static, first ray-circle hit) per beam: the textbook quadratic |o + t d - c|^2 = r^2 with
    d = (cos(yaw + a), sin(yaw + a)); a beam within TANGENT_EPS of touching counts as touching."""
    pose, centres, radii = pose.double().numpy(), centres.double().numpy(), radii.double().numpy()
    out = static.double().numpy().copy()
    for n in range(pose.shape[0]):
        ox, oy, yaw = pose[n]
        for k, a in enumerate(angles.double().tolist()):
            dx, dy = math.cos(yaw + a), math.sin(yaw + a)
            for j in range(centres.shape[1]):
                if not active[n, j]:
                    continue
                fx, fy = ox - centres[n, j, 0], oy - centres[n, j, 1]
                r = radii[n, j]
                b, c = fx * dx + fy * dy, fx * fx + fy * fy - r * r
                if c <= 0:
                    t = 0.0
                else:
                    disc = b * b - c
                    if b > 0 or disc < -2 * r * TANGENT_EPS:
                        continue
                    t = -b - math.sqrt(max(disc, 0.0))
                if t <= max_range:
                    out[n, k] = min(out[n, k], t)
    return out


def random_scene(env, k_agents: int, seed: int):
    """Poses of the env's map with discs around them: random ones (overlapping walls, behind walls,
    behind the robot), one touching the robot's footprint, one tangent to a chosen beam, and in the
    last slot the sensor inside a disc."""
    g = torch.Generator().manual_seed(seed)
    n = env.num_envs
    env.reset(seed=seed)
    pose = env.pose.clone()
    centres = pose[:, None, :2] + (torch.rand(n, k_agents, 2, generator=g) - 0.5) * 8.0
    radii = 0.1 + 0.3 * torch.rand(n, k_agents, generator=g)
    active = torch.rand(n, k_agents, generator=g) < 0.85
    angles = env.beam_angles.double()
    r_robot = env.preset.footprint.circumscribed_radius
    for i in range(n):
        # touching the robot's circumscribed disc, in a random direction
        th = float(torch.rand(1, generator=g)) * 2 * math.pi
        centres[i, 0] = pose[i, :2] + (r_robot + radii[i, 0]) * torch.tensor([math.cos(th), math.sin(th)])
        # tangent to beam kb at distance t: centre = o + t d + r n (n the beam's normal)
        kb = int(torch.randint(angles.numel(), (1,), generator=g))
        yaw = float(pose[i, 2]) + float(angles[kb])
        t = 1.0 + 3.0 * float(torch.rand(1, generator=g))
        c = torch.tensor([float(pose[i, 0]) + t * math.cos(yaw) - float(radii[i, 1]) * math.sin(yaw),
                          float(pose[i, 1]) + t * math.sin(yaw) + float(radii[i, 1]) * math.cos(yaw)])
        centres[i, 1] = c
        active[i, :2] = True
    centres[-1, 2] = pose[-1, :2] + 0.05  # the sensor inside this disc: every beam reads 0
    radii[-1, 2] = 0.2
    active[-1, 2] = True
    return pose, centres, radii, active


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])  # 270 deg and 360 deg (wrapping windows)
def test_beam_disc_ranges_match_the_brute_force_reference(robot):
    env = make_env(robot, 6, seed=0)
    lidar = env.preset.lidar
    angles = env.beam_angles
    a64 = angles.double()
    cos_a, sin_a = torch.cos(a64), torch.sin(a64)
    step = float(a64[-1] - a64[0]) / (a64.numel() - 1)
    for seed in range(3):
        pose, centres, radii, active = random_scene(env, 8, seed)
        static = env.scan()
        ref = reference_ranges(pose, angles, centres, radii, active.numpy(), static, lidar.max_range)
        assert (ref < static.double().numpy() - 1e-3).sum() > 50, "the scene must have agents in view"
        assert (ref[-1] == 0).all()
        torch_out = torch.minimum(static.double(), ray_disc_ranges(pose, cos_a, sin_a, centres, radii, active,
                                                                   lidar.max_range))
        numba_out = static.clone()
        lower_by_discs(pose.numpy(), cos_a.numpy(), sin_a.numpy(), float(a64[0]), step, centres.numpy(),
                       radii.numpy(), active.numpy(), lidar.max_range, numba_out.numpy())
        np.testing.assert_allclose(torch_out.numpy(), ref, atol=TOL, rtol=0)
        np.testing.assert_allclose(numba_out.double().numpy(), ref, atol=TOL, rtol=0)


def test_tangent_beam_hits_and_a_disc_behind_the_sensor_is_unseen():
    angles = beam_angles(270, 1080).double()
    cos_a, sin_a = torch.cos(angles), torch.sin(angles)
    k = 540  # the beam just left of straight ahead
    pose = torch.tensor([[0.0, 0.0, 0.0]], dtype=torch.float64)
    a = float(angles[k])
    # tangent from the right at distance 2 m along beam k, and a disc behind the robot (outside the FOV)
    c_tan = [2.0 * math.cos(a) + 0.25 * math.sin(a), 2.0 * math.sin(a) - 0.25 * math.cos(a)]
    centres = torch.tensor([[c_tan, [-2.0, 0.0]]], dtype=torch.float64)  # float64: tangent to 1e-16 m
    radii = torch.tensor([[0.25, 0.5]], dtype=torch.float64)
    active = torch.ones(1, 2, dtype=torch.bool)
    out = ray_disc_ranges(pose, cos_a, sin_a, centres, radii, active, 20.0)[0]
    assert float(out[k]) == pytest.approx(2.0, abs=TOL)  # tangent: hits at the touching point
    assert out[k + 1:].eq(20.0).all()  # the beams left of it pass; the disc behind is in no beam


def footprint_centre_distances(pose, footprint: Footprint, centres, radii, active):
    """(row, disc radius, distance from the footprint to the disc's centre) for every active disc, by
    another route than the kernels: disc footprint by the distance of the centres (minus its radius);
    rectangle: 0 with the centre strictly inside (cross products against its four edges), else the
    point-segment distance to the nearest edge."""
    for n in range(pose.shape[0]):
        x, y, yaw = (float(v) for v in pose[n])
        for j in range(centres.shape[1]):
            if not active[n, j]:
                continue
            cx, cy, r = float(centres[n, j, 0]), float(centres[n, j, 1]), float(radii[n, j])
            if footprint.kind == "disc":
                yield n, r, math.hypot(cx - x, cy - y) - footprint.radius
                continue
            hl, hw, c, s = footprint.length / 2, footprint.width / 2, math.cos(yaw), math.sin(yaw)
            corners = [(x + c * u - s * v, y + s * u + c * v) for u, v in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]
            edges = list(zip(corners, corners[1:] + corners[:1]))
            inside = all((bx - ax) * (cy - ay) - (by - ay) * (cx - ax) > 0 for (ax, ay), (bx, by) in edges)
            yield n, r, 0.0 if inside else min(_segment_distance(cx, cy, a, b) for a, b in edges)


def reference_collision(pose, footprint: Footprint, centres, radii, active) -> np.ndarray:
    """Positive-area overlap of footprint and disc: the centre nearer the footprint than the radius."""
    out = np.zeros(pose.shape[0], bool)
    for n, r, d in footprint_centre_distances(pose, footprint, centres, radii, active):
        out[n] |= d < r
    return out


def _segment_distance(px, py, a, b) -> float:
    (ax, ay), (bx, by) = a, b
    t = ((px - ax) * (bx - ax) + (py - ay) * (by - ay)) / ((bx - ax) ** 2 + (by - ay) ** 2)
    t = min(max(t, 0.0), 1.0)
    return math.hypot(px - (ax + t * (bx - ax)), py - (ay + t * (by - ay)))


def random_discs(n: int, k: int, seed: int, extent: float, p_active: float):
    """Random robot poses [n, 3] in an extent x extent square and k discs per row near them: centres
    [n, k, 2], radii [n, k] in [0.05, 0.35] m, active [n, k] with probability p_active."""
    g = torch.Generator().manual_seed(seed)
    pose = torch.cat([torch.rand(n, 2, generator=g) * extent, (torch.rand(n, 1, generator=g) * 2 - 1) * math.pi], 1)
    centres = torch.rand(n, k, 2, generator=g) * extent
    radii = 0.05 + 0.3 * torch.rand(n, k, generator=g)
    return pose, centres, radii, torch.rand(n, k, generator=g) < p_active


@pytest.mark.parametrize("footprint", [Footprint(kind="disc", radius=0.2),
                                       Footprint(kind="rectangle", length=0.8, width=0.41)])
def test_footprint_disc_collision_matches_the_geometric_reference(footprint):
    pose, centres, radii, active = random_discs(4000, 3, seed=4, extent=2.0, p_active=0.9)
    got = footprint_hits_discs(pose, footprint, centres, radii, active).numpy()
    ref = reference_collision(pose, footprint, centres, radii, active)
    assert 0.1 < ref.mean() < 0.9  # both outcomes are exercised
    np.testing.assert_array_equal(got, ref)
    # touching is not a collision: a disc placed exactly at the footprint's side (binary-exact sizes)
    footprint = footprint.model_copy(update={"radius": 0.25} if footprint.kind == "disc" else {"width": 0.5})
    half = 0.25
    touch = torch.tensor([[[0.0, half + 0.25]]], dtype=torch.float64)
    at = torch.zeros(1, 3, dtype=torch.float64)
    assert not footprint_hits_discs(at, footprint, touch, torch.tensor([[0.25]], dtype=torch.float64),
                                    torch.ones(1, 1, dtype=torch.bool))
    assert footprint_hits_discs(at, footprint, touch, torch.tensor([[0.2501]], dtype=torch.float64),
                                torch.ones(1, 1, dtype=torch.bool))


@pytest.mark.parametrize("footprint", [Footprint(kind="disc", radius=0.2),
                                       Footprint(kind="rectangle", length=0.8, width=0.41)])
def test_footprint_disc_collision_broadcasts_leading_dimensions_as_row_by_row(footprint):
    # the people shield's form: poses [A, B, 3] against discs shared along B ([A, 1, K, 2]), as every pair row by row
    pose, centres, radii, active = random_discs(60, 4, seed=5, extent=2.0, p_active=0.9)
    poses = pose.reshape(6, 10, 3)
    c, r, a = centres[::10][:, None], radii[::10][:, None], active[::10][:, None]   # [6, 1, 4, ...]
    got = footprint_hits_discs(poses, footprint, c, r, a)
    assert got.shape == (6, 10)
    rows = footprint_hits_discs(pose, footprint, c.expand(-1, 10, -1, -1).reshape(60, 4, 2),
                                r.expand(-1, 10, -1).reshape(60, 4), a.expand(-1, 10, -1).reshape(60, 4))
    assert torch.equal(got.reshape(60), rows) and 0 < int(rows.sum()) < 60


def test_counter_based_draws_are_the_same_bits_in_torch_and_numba():
    from flashnav.sim.agent_draws import hash_uniform as torch_hash
    from flashnav.sim.agent_numba import hash_uniform as numba_hash

    g = torch.Generator().manual_seed(0)
    keys = torch.randint(0, 2**62, (50,), generator=g)
    got = torch_hash(keys[:, None, None, None], torch.arange(3)[:, None, None], torch.arange(4)[:, None], torch.arange(6))
    for i in range(0, 50, 7):
        for s in range(3):
            for j in range(4):
                for lane in range(6):
                    assert float(got[i, s, j, lane]) == float(numba_hash(int(keys[i]), s, j, lane))
    assert 0.45 < float(got.mean()) < 0.55 and float(got.min()) >= 0.0 and float(got.max()) < 1.0
