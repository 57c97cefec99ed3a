"""Moving agents in the environment (issue 13): K = 0 is today's simulator bit for bit; agents never
overlap walls or start on the robot or its goal; a slot's reset leaves the other slots' agents
untouched; the env's scan and collision flags equal brute-force references; the behaviours do what
they say."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from test_agent_geometry import reference_collision, reference_ranges

from flashnav.presets import load_robot
from flashnav.sim.agents import BOUNCE, CROSSING, WAYPOINTS
from flashnav.sim.env import make_env

FIXTURE = Path(__file__).parent / "fixtures" / "agents_k0_trajectory.npz"
MIX = {"waypoints": 1.0, "bounce": 1.0, "crossing": 1.0}


def rollout(robot, steps=40, n=6, seed=5):
    """Seeded random actions biased forward (episodes end, slots reset). The fixture was recorded by
    this function with main at 81586fc (before agents existed)."""
    env = make_env(robot, n, seed=seed)
    obs, _ = env.reset(seed=seed)
    gen = torch.Generator().manual_seed(seed)
    out = {"obs": [obs], "reward": [], "terminated": [], "truncated": [], "collision": [], "final_obs": []}
    for _ in range(steps):
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        action[:, 0] = action[:, 0] * 0.5 + 0.5
        obs, reward, terminated, truncated, info = env.step(action)
        for k, v in (("obs", obs), ("reward", reward), ("terminated", terminated), ("truncated", truncated),
                     ("collision", info["collision"]), ("final_obs", info["final_obs"])):
            out[k].append(v)
    return {k: torch.stack(v).numpy() for k, v in out.items()}


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_no_agents_gives_exactly_the_saved_static_transitions(robot):
    assert load_robot(robot).agents.count == 0  # the default
    saved = np.load(FIXTURE)
    assert saved[f"{robot}/terminated"].any(), "the fixture must exercise resets"
    for key, value in rollout(robot).items():
        ref = saved[f"{robot}/{key}"]
        assert value.dtype == ref.dtype and np.array_equal(value, ref), f"{robot}: {key} differs"


def agent_env(robot="turtlebot2", n=16, seed=0, **agents):
    overrides = {"agents.count": 8, "agents.mix": MIX, **{f"agents.{k}": v for k, v in agents.items()}}
    return make_env(load_robot(robot, **overrides), n, seed=seed)


def wall_gap(grid, centres: np.ndarray) -> np.ndarray:
    """Brute force: distance from each point [P, 2] to the nearest occupied closed cell square or the
    map's edge (metres)."""
    rows, cols = np.nonzero(grid.occupied)
    res, (ox, oy) = grid.resolution, grid.origin
    lo_x, lo_y = ox + cols * res, oy + rows * res
    gx = np.maximum(np.maximum(lo_x[None] - centres[:, :1], centres[:, :1] - (lo_x[None] + res)), 0.0)
    gy = np.maximum(np.maximum(lo_y[None] - centres[:, 1:], centres[:, 1:] - (lo_y[None] + res)), 0.0)
    squares = np.sqrt(gx * gx + gy * gy).min(axis=1)
    xmin, ymin, xmax, ymax = grid.bounds
    edge = np.minimum.reduce([centres[:, 0] - xmin, xmax - centres[:, 0], centres[:, 1] - ymin, ymax - centres[:, 1]])
    return np.minimum(squares, edge)


def test_agents_keep_out_of_walls_and_spawn_clear_of_robot_and_goal():
    env = agent_env(n=12, seed=1)
    env.reset(seed=1)
    a, cfg = env.agents, env.preset.agents
    reach = a.radius + env.preset.footprint.circumscribed_radius + cfg.spawn_clearance
    for point in (env.pose[:, None, :2], env.goal[:, None, :]):
        gap = torch.linalg.vector_norm(a.pos.double() - point.double(), dim=-1)
        assert bool((gap[a.placed] >= reach[a.placed].double() - 1e-6).all())
    gen = torch.Generator().manual_seed(0)
    seen_active = 0
    for _ in range(120):
        before = a.active.clone()
        env.step(torch.rand(12, 2, generator=gen) * 2 - 1)
        on = a.active.numpy()
        gap = wall_gap(env.frame_map, a.pos.double().numpy()[on])
        assert (gap >= a.radius.double().numpy()[on] - 1e-6).all(), "an agent overlaps a wall"
        # a crossing agent appears only where it leaves the robot room
        new = (a.active & ~before & (a.kind == CROSSING))
        if bool(new.any()):
            rows = new.nonzero()[:, 0]
            d = torch.linalg.vector_norm(a.pos[new] - env.pose[rows, :2], dim=-1)
            assert bool((d >= reach[new] - 1e-5).all())
        seen_active += int(a.active.sum())
    assert seen_active > 12 * 4 * 120 * 0.5


def test_a_slot_reset_leaves_every_other_slot_bit_identical():
    env = agent_env(n=8, seed=2)
    env.reset(seed=2)
    for _ in range(5):
        env.step(torch.zeros(8, 2))
    names = ("pos", "vel", "target", "final", "radius", "speed", "kind", "reactive", "placed", "active", "appear")
    before = {k: getattr(env.agents, k).clone() for k in names}
    mask = torch.zeros(8, dtype=torch.bool)
    mask[[1, 5]] = True
    env.reset(options={"reset_mask": mask})
    for k in names:
        now = getattr(env.agents, k)
        assert torch.equal(now[~mask], before[k][~mask]), k
    assert not torch.equal(env.agents.pos[mask], before["pos"][mask])


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_env_scan_and_collision_flags_equal_the_references(robot):
    env = agent_env(robot, n=6, seed=3, count=8)
    env.reset(seed=3)
    gen = torch.Generator().manual_seed(3)
    static_cast = env._cast
    checked = 0
    for step in range(30):
        _, _, _, _, info = env.step(torch.rand(6, 2, generator=gen) * 2 - 1)
        if step % 10 == 9:
            a = env.agents
            ref = reference_ranges(env.pose, env.beam_angles, a.pos, a.radius, a.active.numpy(), static_cast(env.pose),
                                   env.preset.lidar.max_range)
            np.testing.assert_allclose(env.scan().double().numpy(), ref, atol=1e-5, rtol=0)
            checked += 1
    assert checked == 3


def test_collision_with_an_agent_is_terminal_minus_ten_and_named():
    env = agent_env(n=2, seed=5, count=1, mix={"bounce": 1.0})
    env.reset(seed=5)
    a = env.agents
    a.speed[:] = 1e-6
    a.vel[:] = 0.0
    a.active[:] = True
    a.pos[0, 0] = env.pose[0, :2] + torch.tensor([0.3, 0.0])  # 0.3 < 0.2 + radius: overlap
    a.pos[1, 0] = env.pose[1, :2] + torch.tensor([3.0, 3.0])
    expected = reference_collision(env.pose, env.preset.footprint, a.pos, a.radius, a.active.numpy())
    _, reward, terminated, _, info = env.step(torch.tensor([[-1.0, 0.0]] * 2))  # v = 0, turning
    assert expected[0] and not expected[1]
    assert info["collision_agent"].tolist() == [True, False]
    assert bool(terminated[0]) and float(reward[0]) == env.preset.reward.collision
    assert info["collision"].tolist() == (info["collision_agent"] | info["collision_static"]).tolist()


def test_behaviours():
    env = agent_env(n=32, seed=6, mix=MIX, speed=[0.4, 0.5])
    env.reset(seed=6)
    a = env.agents
    start = a.pos.clone()
    cross_side = None
    for t in range(200):
        pos = a.pos.clone()
        env.step_slots(torch.arange(32), torch.full((32, 2), -1.0))  # robots stand (v = 0), no reset
        moved = torch.linalg.vector_norm(a.pos - pos, dim=-1)
        bounce = a.active & (a.kind == BOUNCE)
        # bounce agents move at their own constant speed (reflections keep it)
        assert torch.allclose(torch.linalg.vector_norm(a.vel, dim=-1)[a.kind == BOUNCE], a.speed[a.kind == BOUNCE])
        assert bool((moved[bounce] <= a.speed[bounce] * env.preset.episode.dt + 1e-5).all())
        if t == 0:
            cross_side = side_of_route(env, a.pos)
    walked = torch.linalg.vector_norm(a.pos - start, dim=-1)
    for kind in (WAYPOINTS, BOUNCE):
        sel = a.placed & (a.kind == kind)
        assert float((walked[sel] > 0.3).float().mean()) > 0.8, kind
    # crossing agents that appeared end on the other side of their robot's start-goal line
    crossed = a.placed & (a.kind == CROSSING) & a.active
    assert int(crossed.sum()) >= 3
    end_side = side_of_route(env, a.pos)
    assert bool((end_side[crossed] != cross_side[crossed]).all())


def side_of_route(env, pos):
    """[N, K] sign of the agents' side of the line from each robot's pose to its goal."""
    route = env.goal - env.pose[:, :2]
    rel = pos - env.pose[:, None, :2]
    return torch.sign(route[:, None, 0] * rel[..., 1] - route[:, None, 1] * rel[..., 0])


def test_leg_check_kernels_agree_and_clear_legs_are_clear():
    env = agent_env(n=4, seed=7)
    a = env.agents
    g = torch.Generator().manual_seed(7)
    p = 3000
    start = a.space.free_points(torch.zeros(p, dtype=torch.long), g)
    angle = torch.rand(p, generator=g) * 2 * math.pi
    end = start + (0.5 + 2.5 * torch.rand(p, 1, generator=g)) * torch.stack([torch.cos(angle), torch.sin(angle)], -1)
    radius = 0.2 + 0.1 * torch.rand(p, generator=g)
    maps = torch.zeros(p, dtype=torch.long)
    numba_ok = a.space.segment_clear(start, end, radius, maps, kernel="numba")
    torch_ok = a.space.segment_clear(start, end, radius, maps, kernel="torch")
    assert torch.equal(numba_ok, torch_ok) and 50 < int(numba_ok.sum()) < p - 50
    # broadcasting, as the leg search calls it: one start [P, 1, 2] for several ends [P, C, 2]
    ends = torch.stack([end, start + 0.5 * (end - start), start + 2.0 * (end - start)], dim=1)
    args = (start[:, None], ends, radius[:, None], maps[:, None])
    assert torch.equal(a.space.segment_clear(*args, kernel="numba"), a.space.segment_clear(*args, kernel="torch"))
    # brute force: every centimetre of a clear leg keeps the whole disc off the walls
    rows = numba_ok.nonzero()[:, 0][:40]
    s = torch.linspace(0, 1, 121, dtype=torch.float64)
    pts = start[rows, None].double() + (end - start)[rows, None].double() * s[:, None]
    gap = wall_gap(env.frame_map, pts.reshape(-1, 2).numpy()).reshape(len(rows), -1)
    assert (gap >= radius[rows].double().numpy()[:, None] - 1e-6).all()


@pytest.mark.parametrize("mix", [{"waypoints": 1.0}, {"bounce": 1.0}, MIX])
def test_numba_and_torch_agent_steps_agree(mix):
    """The CPU kernel and the torch ops (the GPU path) move the agents alike: the same legs (the same
    counter-based draws), positions equal to float32 rounding."""
    worlds = []
    for kernel in ("numba", "torch"):
        env = agent_env(n=16, seed=8, mix=mix, reactive=0.5)
        env.reset(seed=8)
        env.agents.step_kernel = kernel
        worlds.append(env)
    start = worlds[0].agents.pos.clone()
    for t in range(60):
        steps = torch.full((16,), t + 1, dtype=torch.int32)
        for env in worlds:
            env.agents.step(slice(None), env.pose, steps, env._gen)
    a, b = worlds[0].agents, worlds[1].agents
    assert torch.equal(a.active, b.active)
    near = torch.linalg.vector_norm(a.pos - b.pos, dim=-1) < 1e-4
    assert float(near.float().mean()) >= 0.97, float(near.float().mean())
    moved = torch.linalg.vector_norm(a.pos - start, dim=-1)
    assert float((moved[a.active] > 0.5).float().mean()) > 0.5


def test_agents_move_on_their_slots_own_maps():
    from flashnav.maps.generate import generate_map

    maps = [generate_map(8.0, 8.0, 0.05, seed, robot_radius=0.3, name=f"m{seed}") for seed in (11, 12)]
    preset = load_robot("turtlebot2", **{"agents.count": 6, "agents.mix": {"waypoints": 1.0, "bounce": 1.0}})
    env = make_env(preset, 10, maps=maps, seed=9)
    env.reset(seed=9)
    gen = torch.Generator().manual_seed(9)
    for _ in range(60):
        env.step(torch.rand(10, 2, generator=gen) * 2 - 1)
    a = env.agents
    seen = set()
    for slot in range(10):
        m = int(env.map_index[slot])
        seen.add(m)
        on = a.active[slot].numpy()
        gap = wall_gap(env.frame_maps[m], a.pos[slot].double().numpy()[on])
        assert (gap >= a.radius[slot].double().numpy()[on] - 1e-6).all(), f"slot {slot} overlaps a wall of map {m}"
        # the slot's scan includes its agents on its own map: equal to the reference on that map
        static = env._cast(env.pose[slot:slot + 1], env.map_index[slot:slot + 1])
        ref = reference_ranges(env.pose[slot:slot + 1], env.beam_angles, a.pos[slot:slot + 1],
                               a.radius[slot:slot + 1], a.active[slot:slot + 1].numpy(), static,
                               env.preset.lidar.max_range)
        np.testing.assert_allclose(env.scan()[slot:slot + 1].double().numpy(), ref, atol=1e-5, rtol=0)
    assert seen == {0, 1}


def test_replacing_the_maps_puts_the_agents_on_the_new_maps():
    from flashnav.maps.generate import generate_map

    old, new = (generate_map(8.0, 8.0, 0.05, seed, robot_radius=0.3, name=f"m{seed}") for seed in (21, 22))
    preset = load_robot("turtlebot2", **{"agents.count": 6, "agents.mix": {"waypoints": 1.0, "bounce": 1.0}})
    env = make_env(preset, 8, map=old, seed=3)
    env.reset(seed=3)
    env.replace_maps(new)
    gen = torch.Generator().manual_seed(3)
    for _ in range(30):
        env.step(torch.rand(8, 2, generator=gen) * 2 - 1)
        a = env.agents
        for slot in range(8):
            on = a.active[slot].numpy()
            gap = wall_gap(env.frame_maps[0], a.pos[slot].double().numpy()[on])
            assert (gap >= a.radius[slot].double().numpy()[on] - 1e-6).all(), f"slot {slot}: an agent in a new wall"


@pytest.mark.parametrize("kernel", ["numba", "torch"])
def test_a_reactive_agent_stops_short_of_the_robot_and_a_plain_one_walks_into_it(kernel):
    from test_env import open_room

    preset = load_robot("turtlebot2", **{"agents.count": 1, "agents.mix": {"bounce": 1.0}, "agents.reactive": 1.0})
    env = make_env(preset, 2, map=open_room(), seed=10)
    env.set_state(torch.tensor([[5.0, 5.0, 0.0]] * 2), torch.tensor([[8.0, 8.0]] * 2))
    a = env.agents
    a.step_kernel = kernel
    a.pos[:, 0] = torch.tensor([2.0, 5.0])  # 3 m to the robot's left (-x), walking at it
    a.speed[:] = 0.5
    a.vel[:, 0] = torch.tensor([0.5, 0.0])
    a.radius[:] = 0.25
    a.active[:] = True
    a.reactive[:, 0] = torch.tensor([True, False])
    hit = torch.zeros(2, dtype=torch.bool)
    for t in range(80):
        out = env.step_slots(torch.arange(2), torch.tensor([[-1.0, 0.0]] * 2))  # the robots stand
        hit |= out["collision_agent"]
        if bool(hit[1]):
            break
    assert hit.tolist() == [False, True]
    gap = float(torch.linalg.vector_norm(a.pos[0, 0] - env.pose[0, :2])) - 0.25 - 0.2
    assert 0.0 < gap < preset.agents.reactive_distance
