"""The opt-in memory scan (observation.memory_frames, flashnav/sim/memory.py): the paper's columns and every
other opt-in column are unchanged; the memory columns equal a slow reference (stored frames kept as Python
lists of points from the raw scans, beam by beam, and pooled point by point with math.atan2 / math.hypot)
through sparse resets, with agents and many maps; a slot's reset or a partial step leaves the other slots'
memories bit-identical; the mirror reverses the sectors; the networks give the columns IPAPRec's
reciprocal; the export records the memory and the deploy controller rebuilds the env's observations from
odometry and scans alone (numpy, flashnav/deploy/memory.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_pose_trail import forward_actions  # seeded, forward-biased actions: episodes end, slots reset

from flashnav.learn.mirror import mirror_for
from flashnav.learn.networks import IPAPRec, ObsLayout
from flashnav.maps import generate_map
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv, make_env
from flashnav.sim.memory import WallMemory, points_per_frame
from flashnav.sim.observation import beam_angles

#: a point this close (radians) to a sector boundary may fall on either side in float32 and float64
EDGE = 1e-4


def reference_frame(preset, ranges: list[float], pose) -> list[tuple[float, float]]:
    """The hit points of one scan, beam by beam: per group of consecutive beams its first nearest beam,
    if it is below max range, at its bearing from ``pose``."""
    angles = beam_angles(preset.lidar.fov_deg, preset.lidar.beams).tolist()
    group = preset.lidar.beams // points_per_frame(preset)
    x, y, yaw = (float(v) for v in pose)
    out = []
    for start in range(0, len(ranges), group):
        k = min(range(start, start + group), key=lambda b: ranges[b])
        if ranges[k] < preset.lidar.max_range:
            out.append((x + ranges[k] * math.cos(yaw + angles[k]), y + ranges[k] * math.sin(yaw + angles[k])))
    return out


def reference_scan(points, pose, sectors: int, max_range: float) -> tuple[list[float], list[float]]:
    """(low, high) [sectors] bounds of the memory scan of ``points`` seen from ``pose``: a point within
    EDGE of a sector boundary counts in both neighbours for ``low`` and in neither for ``high``."""
    x, y, yaw = (float(v) for v in pose)
    low, high = [max_range] * sectors, [max_range] * sectors
    width = 2 * math.pi / sectors
    for px, py in points:
        dx, dy = px - x, py - y
        rx, ry = math.cos(yaw) * dx + math.sin(yaw) * dy, -math.sin(yaw) * dx + math.cos(yaw) * dy
        d, u = min(math.hypot(rx, ry), max_range), (math.atan2(ry, rx) + math.pi) / width
        j = min(int(math.floor(u)), sectors - 1)
        near = [j] if min(u - math.floor(u), math.ceil(u) - u) * width > EDGE else [(j - 1) % sectors, j,
                                                                                   (j + 1) % sectors]
        for i in near:
            low[i] = min(low[i], d)
        if len(near) == 1:
            high[j] = min(high[j], d)
    return low, high


CASES = {
    "tb2": ("turtlebot2", 4, 3, {}),
    "go2-every1": ("go2", 3, 1, {}),
    "tb2-with-everything": ("turtlebot2", 2, 4, {"agents.count": 3, "observation.agent_tracks": 2,
                                                 "observation.scan_history": 1, "observation.pose_trail": 2,
                                                 "lidar.noise_std": 0.05}),
    "tb2-many-maps": ("turtlebot2", 3, 2, {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_memory_columns_equal_a_list_of_stored_frames_per_slot(case):
    robot, frames, every, overrides = CASES[case]
    maps = [generate_map(6.0, 6.0, 0.05, seed=s, robot_radius=0.3, name=f"m{s}") for s in (1, 2)] \
        if case == "tb2-many-maps" else None
    n, seed = 5, 11

    def env(memory):
        preset = load_robot(robot, **overrides, **{"observation.memory_frames": memory,
                                                   "observation.memory_every": every})
        return NavVecEnv(preset, n, grid=maps or make_env(preset).map, seed=seed)

    plain, mem = env(0), env(frames)
    base, s, max_range = plain.obs_dim, mem.preset.lidar.sectors, mem.preset.lidar.max_range
    assert plain.extras.memory is None and mem.obs_dim == base + s
    assert np.allclose(mem.single_observation_space.high[base:], max_range)
    obs0, _ = plain.reset(seed=seed)
    obs1, _ = mem.reset(seed=seed)
    stored = [[reference_frame(mem.preset, mem.scan()[i].tolist(), mem.pose[i])] for i in range(n)]
    steps = [0] * n
    gen = torch.Generator().manual_seed(seed)
    resets = checked = 0
    for step in range(40):
        for i in range(n):
            assert torch.equal(obs1[i, :base], obs0[i]), (step, i)
            low, high = reference_scan([p for f in stored[i] for p in f], mem.pose[i], s, max_range)
            got = obs1[i, base:].double()
            assert (got >= torch.tensor(low) - 1e-4).all() and (got <= torch.tensor(high) + 1e-4).all(), (step, i)
            checked += int((got < max_range).sum())
        assert mem.single_observation_space.contains(obs1[0].numpy())
        action = forward_actions(gen, n)
        obs0, r0, term0, trunc0, info0 = plain.step(action)
        obs1, r1, term1, trunc1, info1 = mem.step(action)
        assert torch.equal(r0, r1) and torch.equal(term0, term1) and torch.equal(trunc0, trunc1)
        assert torch.equal(info1["final_obs"][:, :base], info0["final_obs"])
        ranges = mem.scan()
        for i in range(n):
            steps[i] += 1
            frame = reference_frame(mem.preset, ranges[i].tolist(), mem.pose[i])
            if bool(info0["_final_obs"][i]):  # a new episode: its first scan alone
                stored[i], steps[i] = [frame], 0
                resets += 1
            elif steps[i] % every == 0:
                stored[i] = [frame, *stored[i]][:frames]
    assert resets >= 2, "the rollout must exercise sparse resets"
    assert checked > 100, "the memory must hold walls"


def test_a_slot_reset_and_a_partial_step_leave_other_memories_bit_identical():
    env = make_env(load_robot("turtlebot2", **{"observation.memory_frames": 3, "observation.memory_every": 1,
                                               "agents.count": 2}), 8, seed=2)
    env.reset(seed=2)
    for _ in range(4):
        env.step(torch.full((8, 2), 0.3))
    m = env.extras.memory
    points, valid, obs = m.points.clone(), m.valid.clone(), env.obs.clone()
    mask = torch.zeros(8, dtype=torch.bool)
    mask[[1, 5]] = True
    new, _ = env.reset(options={"reset_mask": mask})
    assert torch.equal(m.points[~mask], points[~mask]) and torch.equal(m.valid[~mask], valid[~mask])
    assert torch.equal(new[~mask], obs[~mask])
    assert m.valid[mask, 0].any() and not m.valid[mask, 1:].any()  # the first scan alone

    points, valid = m.points.clone(), m.valid.clone()
    idx = torch.tensor([0, 6])
    env.step_slots(idx, torch.full((2, 2), 0.3))
    others = torch.ones(8, dtype=torch.bool)
    others[idx] = False
    assert torch.equal(m.points[others], points[others]) and torch.equal(m.valid[others], valid[others])
    assert not torch.equal(m.points[idx], points[idx])


def test_the_memory_keeps_a_wall_the_scan_no_longer_sees():
    """TurtleBot2 (270 deg) faces its nearest wall, then turns round in place: the wall is now in the live
    scan's blind spot behind, and the memory scan still reads it there."""
    preset = load_robot("turtlebot2", **{"observation.memory_frames": 2, "observation.memory_every": 1000})
    env = make_env(preset, 1, seed=0)
    env.reset(seed=0)
    pose, goal = env.world_pose(), env.world_goal()
    yaw = float(pose[0, 2]) + float(env.beam_angles[int(torch.argmin(env.scan()[0]))])
    env.set_state(torch.tensor([[float(pose[0, 0]), float(pose[0, 1]), yaw]], dtype=torch.float64), goal)
    wall = float(env.scan()[0].min())  # straight ahead (to half a beam), stored as the episode's first scan
    s, w_max = preset.lidar.sectors, preset.motion.w_bounds[1]
    turns = round(math.pi / (w_max * preset.episode.dt))
    for _ in range(turns):  # v = 0, full turn rate: half a turn, nothing more stored
        obs, *_ = env.step(torch.tensor([[-1.0, 1.0]]))
    assert float(env.world_pose()[0, 0]) == pytest.approx(float(pose[0, 0]), abs=1e-6)
    behind = math.atan2(math.sin(yaw - float(env.pose[0, 2])), math.cos(yaw - float(env.pose[0, 2])))
    assert abs(behind) > math.radians(preset.lidar.fov_deg) / 2  # outside the live scan's field of view
    memory = obs[0, preset.trail_end:]
    j = int(torch.argmin(memory))
    assert float(memory[j]) == pytest.approx(wall, abs=1e-3)
    sector = min(int((behind + math.pi) / (2 * math.pi / s)), s - 1)
    assert min(abs(j - sector), s - abs(j - sector)) <= 1


def test_the_mirror_reverses_the_memory_sectors():
    gen = torch.Generator().manual_seed(5)
    preset = load_robot("go2", **{"observation.memory_frames": 2})
    m = WallMemory.from_preset(preset, 4, beam_angles(360.0, preset.lidar.beams), torch.device("cpu"))
    pts = torch.rand(4, 2, 2, 60, generator=gen) * 8 - 4  # [k, frames, (x, y), points]
    valid = torch.rand(4, 2, 60, generator=gen) < 0.8
    pose = torch.cat([torch.rand(4, 2, generator=gen) - 0.5, (torch.rand(4, 1, generator=gen) * 2 - 1) * math.pi], 1)
    width = 2 * math.pi / preset.lidar.sectors
    rel = pts - pose[:, None, :2, None]
    bearing = torch.atan2(rel[:, :, 1], rel[:, :, 0]) - pose[:, 2, None, None]
    u = torch.remainder(bearing + math.pi, 2 * math.pi) / width
    valid &= (u - u.round()).abs() * width > 1e-3  # keep the points off the sector boundaries
    pts = torch.where(valid[:, :, None], pts, torch.full_like(pts, math.inf))  # inf: no hit
    flip = torch.tensor([1.0, -1.0])[None, None, :, None]
    mirrored = m.scan(pts * flip, pose * torch.tensor([1.0, -1.0, -1.0]))
    assert torch.allclose(mirrored, m.scan(pts, pose).flip(1), atol=1e-5)
    mirror = mirror_for(preset, 1.0)
    obs = torch.rand(3, preset.obs_dim)
    tail = slice(preset.trail_end, preset.obs_dim)
    assert torch.equal(mirror.obs(obs)[:, tail], obs[:, tail].flip(1))


@pytest.mark.parametrize("key, value, match", [("observation.memory_frames", -1, "greater than or equal to 0"),
                                               ("observation.memory_frames", 65, "less than or equal to 64"),
                                               ("observation.memory_every", 0, "greater than or equal to 1")])
def test_a_bad_memory_option_names_the_key_and_the_value(key, value, match):
    with pytest.raises(ValueError, match=match) as err:
        load_robot("turtlebot2", **{key: value})
    assert key.split(".")[-1] in str(err.value)


def test_ipaprec_gives_the_memory_the_scans_reciprocal():
    preset = load_robot("turtlebot2", **{"observation.memory_frames": 4, "observation.pose_trail": 1})
    layout = ObsLayout.from_robot(preset, 14.0)
    assert layout.obs_dim == preset.obs_dim == 34 + 2 + 30 and layout.memory_sectors == 30
    obs = torch.rand(5, layout.obs_dim) * 4 + 0.3
    ipaprec = IPAPRec(layout)
    with torch.no_grad():
        ipaprec.rho.fill_(0.3)
    feats = ipaprec(obs)
    beta = ipaprec.beta()
    assert torch.allclose(feats[:, 36:], 1.0 / (obs[:, 36:].clamp(0.2, 20.0) - beta))
    trail_only = IPAPRec(ObsLayout.from_robot(load_robot("turtlebot2", **{"observation.pose_trail": 1}), 14.0))
    with torch.no_grad():
        trail_only.rho.fill_(0.3)
    assert torch.allclose(feats[:, :36], trail_only(obs[:, :36]))
    with pytest.raises(ValueError, match="memory_sectors must be an integer >= 0"):
        ObsLayout(30, 0.2, 20.0, 14.1, (0.5, 0.78), memory_sectors=-1)


@pytest.fixture(scope="module", params=["turtlebot2", "go2"])
def memory_policy(request, tmp_path_factory):
    from test_export import random_actor

    from flashnav.export import export_policy

    preset = load_robot(request.param, **{"observation.memory_frames": 5, "observation.memory_every": 3})
    actor = random_actor(preset, seed=3)
    return preset, export_policy(actor, preset, tmp_path_factory.mktemp("policy_memory"))


def test_export_records_the_memory_and_the_runtime_names_a_bad_one(memory_policy):
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import policy_metadata

    preset, paths = memory_policy
    meta = policy_metadata(preset)
    base = preset.base_obs_dim
    assert meta["obs_dim"] == base + 30
    rec = meta["observation"]["memory_scan"]
    assert (rec["frames"], rec["every"], rec["points_per_frame"], rec["columns"]) == (5, 3, 60, [base, base + 30])
    rt = PolicyRuntime.load(paths["onnx"])
    assert (rt.memory_frames, rt.memory_every, rt.memory_points) == (5, 3, 60)
    sectors = np.full(30, 2.0, np.float32)
    vel = (0.0, 0.0)
    with pytest.raises(ValueError, match="memory must be 30 finite distances.*got None"):
        rt.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), vel)
    with pytest.raises(ValueError, match="memory must be 30 finite distances.*got 29"):
        rt.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), vel, memory=np.ones(29))
    assert rt.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), vel, memory=np.ones(30)).shape == (base + 30,)
    plain = PolicyRuntime(None, policy_metadata(load_robot(preset.name)))
    with pytest.raises(ValueError, match="memory must be 0 finite distances"):
        plain.observation(sectors, (0.0, 0.0, 0.0), (1.0, 0.0), vel, memory=np.ones(30))


def test_the_deploy_controller_rebuilds_the_envs_memory_from_odometry_and_scans(memory_policy):
    """A simulated episode stream fed to the Controller as a robot would (odometry, scans, a goal per
    episode): every control step's observation equals the env's, the memory scan included."""
    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.deploy.scan import simulator_scan_fields

    preset, paths = memory_policy
    ctl = Controller(PolicyRuntime.load(paths["onnx"]), timeout=1.0)
    env = make_env(preset, 1, seed=4)
    env.reset(seed=4)
    scan = simulator_scan_fields(preset.lidar)
    t, dt, episodes, remembered = 0.0, preset.episode.dt, 1, 0
    ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
    base = preset.trail_end
    for _ in range(120):
        ctl.on_odom(*env.world_pose()[0].tolist(), now=t)
        command = ctl.on_scan(ranges=env.scan()[0].numpy(), stamp=t, now=t, **scan)
        if command is None or command.state != "driving":  # reached: the next goal
            break
        np.testing.assert_allclose(ctl.last_obs, env.obs[0].numpy(), rtol=0, atol=1e-3)
        remembered += int((ctl.last_obs[base:] < preset.lidar.max_range).sum() > 0)
        _, _, terminated, truncated, _ = env.step(torch.tensor([ctl.last_action]))
        t += dt
        if bool(terminated[0] | truncated[0]):  # a new episode: a new goal, the memory afresh
            ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
            episodes += 1
    assert remembered > 20, "the memory must hold walls"


def test_the_robot_memory_keeps_the_nearest_hit_of_each_wedge():
    from flashnav.deploy.memory import ScanMemory

    mem = ScanMemory(frames=2, every=2, sectors=4, points=4, fov_deg=360.0, max_range=10.0)
    # four wedges of 90 deg from straight behind; beams: two in wedge 1 (ahead-right), one no return, one NaN
    angles = np.array([-0.6, -0.2, 0.3, 2.0, -2.0])
    ranges = np.array([3.0, 2.0, np.inf, np.nan, 4.0])
    pts = mem.frame((1.0, 1.0, 0.0), angles, ranges)
    want = np.array([[1.0 + 4.0 * math.cos(-2.0), 1.0 + 4.0 * math.sin(-2.0)],
                     [1.0 + 2.0 * math.cos(-0.2), 1.0 + 2.0 * math.sin(-0.2)]])
    np.testing.assert_allclose(pts, want)
    out = mem.step((1.0, 1.0, 0.0), angles, ranges, goal_steps=0)
    assert out.dtype == np.float32 and out.shape == (4,)
    np.testing.assert_allclose(out, [4.0, 2.0, 10.0, 10.0], rtol=1e-6)
    mem.step((1.0, 1.0, math.pi), angles, np.full(5, np.inf), goal_steps=1)  # not stored (every 2)
    assert len(mem.stored) == 1
    out = mem.step((1.0, 1.0, math.pi), angles, np.full(5, np.inf), goal_steps=2)  # stored: nothing hit
    assert len(mem.stored) == 2
    np.testing.assert_allclose(out, [10.0, 10.0, 4.0, 2.0], rtol=1e-6)  # turned round: the same points behind
    mem.forget()
    np.testing.assert_allclose(mem.scan((0.0, 0.0, 0.0)), np.full(4, 10.0))
    with pytest.raises(ValueError, match="ScanMemory needs"):
        ScanMemory(frames=0, every=1, sectors=4, points=4, fov_deg=360.0, max_range=10.0)


def test_bench_sim_times_the_memory_beside_the_static_step(tmp_path, capsys):
    import json

    from flashnav.cli import main

    out = tmp_path / "sim.json"
    assert main(["bench", "sim", "--quick", "--raycasters", "exact", "--memory", "3", "--no-irsim",
                 "--max-steps", "4", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["raycaster"], r["memory"]) for r in rows] == [("exact", 0), ("exact", 3)]
    assert all(r["steps"] >= 2 and r["env_steps_per_s"] > 0 for r in rows)
    capsys.readouterr()
    assert main(["bench", "sim", "--quick", "--memory", "-1", "--no-irsim"]) == 2
    assert "--memory must be >= 0, got 0, 0 and -1" in " ".join(capsys.readouterr().err.split())
    # a size the preset refuses is named by its flag before the first row (it failed after the static rows, in the
    # preset's override words)
    assert main(["bench", "sim", "--quick", "--raycasters", "exact", "--memory", "100000", "--no-irsim"]) == 2
    out, err = capsys.readouterr()
    assert "--memory 100000 on turtlebot2: robot.observation.memory_frames: Input should be less than" in err, err
    assert "exact" not in out  # no row timed


def test_the_metadata_reader_falls_back_and_names_a_bad_memory_record():
    from flashnav.policy_meta import memory_scan_shape

    assert memory_scan_shape({}) == (0, 1, 0)  # a file written before the memory existed
    assert memory_scan_shape({"preset": {"observation": {"memory_frames": 0, "memory_every": 4}}}) == (0, 4, 0)
    assert memory_scan_shape({"observation": {"memory_scan": {"frames": 3, "every": 2, "points_per_frame": 60}},
                              "preset": {"observation": {"memory_frames": 6}}}) == (3, 2, 60)
    # a memory without its points per frame is not guessed (a wrong count misreads every stored scan)
    with pytest.raises(ValueError, match=r"p.onnx: the policy's metadata records a memory scan of 6 frames but "
                                         r"observation.memory_scan.points_per_frame None; expected an integer >= 1"):
        memory_scan_shape({"preset": {"observation": {"memory_frames": 6, "memory_every": 4}}}, "p.onnx")
    with pytest.raises(ValueError, match=r"p.onnx: the policy's metadata records memory_every 0; expected an integer >= 1"):
        memory_scan_shape({"observation": {"memory_scan": {"frames": 3, "every": 0}}}, "p.onnx")
    with pytest.raises(ValueError, match=r"memory_frames '2'; expected an integer >= 0"):
        memory_scan_shape({"observation": {"memory_scan": {"frames": "2", "every": 1}}})


def robot_frame(px: float, py: float, pose) -> tuple[float, float]:
    """(forward, left) of the point (px, py) seen from ``pose`` (x, y, yaw), in float64."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    return c * (px - x) + s * (py - y), -s * (px - x) + c * (py - y)


def reference_image(points, pose, goal, cells: int, cell: float) -> np.ndarray:
    """[2, cells, cells] of one slot, point by point in float64: a finite point's square in the robot frame
    (row from the left offset, column from the forward one), the goal's square clipped onto the edge."""
    half = cells * cell / 2
    out = np.zeros((2, cells, cells))

    def square(px: float, py: float) -> tuple[int, int]:
        fwd, left = robot_frame(px, py, pose)
        return math.floor((left + half) / cell), math.floor((fwd + half) / cell)

    for px, py in points:
        if math.isfinite(px) and math.isfinite(py):
            r, q = square(px, py)
            if 0 <= r < cells and 0 <= q < cells:
                out[0, r, q] = 1
    r, q = square(*goal)
    out[1, min(max(r, 0), cells - 1), min(max(q, 0), cells - 1)] = 1
    return out


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_wall_image_against_a_point_by_point_reference(dtype):
    """Random points (some none: inf or NaN in either coordinate, a slot with none at all), poses and goals (some
    far outside): every square the batched image marks is the reference's, and a quarter turn of the robot
    turns the image a quarter (a point ahead lands to the right)."""
    from flashnav.sim.wall_image import wall_image

    rng = np.random.default_rng(11)
    k, q, cells, cell = 5, 300, 9, 0.4
    pts = rng.uniform(-3, 3, (k, q, 2))
    pts[rng.random((k, q)) < 0.2, 0] = np.inf
    pts[rng.random((k, q)) < 0.1, 1] = np.nan
    pts[4] = np.inf
    pose = np.column_stack([rng.uniform(-1, 1, (k, 2)), rng.uniform(-math.pi, math.pi, k)])
    goal = rng.uniform(-2, 2, (k, 2))
    goal[1] = [40.0, -25.0]
    got = wall_image(*(torch.as_tensor(v, dtype=dtype) for v in (pts, pose, goal)), cells, cell)
    assert got.dtype == dtype and got.shape == (k, 2, cells, cells)
    walls = 0
    for n in range(k):
        want = reference_image(pts[n], pose[n], goal[n], cells, cell)
        if dtype == torch.float32:  # a point within 1e-5 m of a square's edge may fall on either side
            fwd_left = np.asarray([robot_frame(px, py, pose[n]) for px, py in pts[n]
                                   if math.isfinite(px) and math.isfinite(py)])
            frac = (fwd_left + cells * cell / 2) / cell % 1.0 if len(fwd_left) else np.zeros((0, 2))
            assert not len(frac) or np.minimum(frac, 1 - frac).min() > 1e-4, "a point on an edge: pick another seed"
        np.testing.assert_array_equal(got[n].numpy(), want)
        walls += int(want[0].sum())
    assert walls > 50 and got[4, 0].sum() == 0 and got[:, 1].sum((1, 2)).eq(1).all()
    one = torch.tensor([[[1.1, 0.0]]], dtype=dtype)  # 1.1 m east of a robot at the origin
    east = wall_image(one, torch.zeros(1, 3, dtype=dtype), torch.zeros(1, 2, dtype=dtype), cells, cell)
    north = wall_image(one, torch.tensor([[0.0, 0.0, math.pi / 2]], dtype=dtype), torch.zeros(1, 2, dtype=dtype),
                       cells, cell)
    assert torch.nonzero(east[0, 0]).tolist() == [[4, 7]] and torch.nonzero(north[0, 0]).tolist() == [[1, 4]]
    with pytest.raises(ValueError, match="at least 2 cells a side"):
        wall_image(one, torch.zeros(1, 3), torch.zeros(1, 2), 1, 0.5)


def test_a_slots_wall_image_draws_its_stored_points():
    """:meth:`WallMemory.image` of some slots is :func:`wall_image` of those slots' stored points, from the
    env's own memory after some steps."""
    from flashnav.sim.wall_image import wall_image

    preset = load_robot("turtlebot2", **{"observation.memory_frames": 3, "observation.memory_every": 2})
    env = make_env(preset, 6, map=generate_map(8.0, 8.0, 0.05, seed=2, robot_radius=0.3), seed=0)
    env.reset(seed=0)
    gen = torch.Generator().manual_seed(0)
    for _ in range(7):
        env.step(forward_actions(gen, 6))
    mem, idx = env.extras.memory, torch.tensor([4, 1, 3])
    pts = mem.points[idx].transpose(2, 3).reshape(3, -1, 2)
    assert torch.isfinite(pts).all(-1).sum() > 20
    got = mem.image(idx, env.pose[idx], env.goal[idx], 16, 0.5)
    torch.testing.assert_close(got, wall_image(pts, env.pose[idx], env.goal[idx], 16, 0.5), rtol=0, atol=0)
    assert got[:, 0].sum() > 10
