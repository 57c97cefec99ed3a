"""The opt-in agent tracks of the observation (observation.agent_tracks, flashnav/sim/tracks.py): the
columns equal a slow reference (plain Python over every agent and beam: the beam nearest the agent's
bearing, cast against the static range and every other disc in float64) through steps and sparse
resets, on both robots; M = 0 is the observation without tracks bit for bit; a slot's reset leaves
the other slots' tracks bit-identical; the networks scale the columns by their bounds; the export
records the layout and the deploy runtime rebuilds the simulator's observation from a tracker's list."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from flashnav.config import TRACK_FEATURES
from flashnav.learn.networks import IPAPRec, ObsLayout
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv, make_env
from flashnav.sim.tracks import SEEN_TOLERANCE, track_scales

W = len(TRACK_FEATURES)


def tracked_env(robot="turtlebot2", n=8, seed=0, tracks=3, agents=8, **extra):
    preset = load_robot(robot, **{"agents.count": agents, "observation.agent_tracks": tracks, **extra})
    return NavVecEnv(preset, n, grid=make_env(preset).map, seed=seed)


def ray_disc(ox, oy, dx, dy, cx, cy, r):
    """Distance along the ray (o, unit d) to the disc (c, r): 0 inside it, None when it misses."""
    fx, fy = ox - cx, oy - cy
    if fx * fx + fy * fy <= r * r:
        return 0.0
    b = fx * dx + fy * dy
    h2 = (fx * fx + fy * fy) - b * b
    if b > 0 or h2 > r * r:
        return None
    return -b - math.sqrt(max(r * r - h2, 0.0))


def reference_seen(env, pose, pos, radius, active, static):
    """[n][K] bools, by the definition in flashnav/sim/tracks.py, in plain Python."""
    p = env.preset
    angles = env.beam_angles.double().tolist()
    half = math.radians(p.lidar.fov_deg) / 2
    out = []
    for i in range(pose.shape[0]):
        x, y, yaw = (float(v) for v in pose[i])
        row = []
        for j in range(pos.shape[1]):
            if not active[i, j]:
                row.append(False)
                continue
            cx, cy, r = float(pos[i, j, 0]), float(pos[i, j, 1]), float(radius[i, j])
            bearing = math.atan2(cy - y, cx - x) - yaw
            bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
            near = math.hypot(cx - x, cy - y) - r
            if (p.lidar.fov_deg < 360 and abs(bearing) > half) or near > p.lidar.max_range:
                row.append(False)
                continue
            diff = [abs((a - bearing + math.pi) % (2 * math.pi) - math.pi) for a in angles]
            b = min(range(len(angles)), key=diff.__getitem__)
            dx, dy = math.cos(yaw + angles[b]), math.sin(yaw + angles[b])
            blockers = [float(static[i, b])]
            for o in range(pos.shape[1]):
                if o != j and active[i, o]:
                    t = ray_disc(x, y, dx, dy, float(pos[i, o, 0]), float(pos[i, o, 1]), float(radius[i, o]))
                    if t is not None:
                        blockers.append(t)
            row.append(min(blockers) >= near - SEEN_TOLERANCE)
        out.append(row)
    return out


def reference_tracks(pose, pos, velocity, radius, seen, tracks):
    """[n, tracks * 6] float64: the nearest seen agents first, robot frame, zeros after them."""
    n = pose.shape[0]
    out = np.zeros((n, tracks * W))
    for i in range(n):
        x, y, yaw = (float(v) for v in pose[i])
        c, s = math.cos(yaw), math.sin(yaw)
        rows = []
        for j in range(pos.shape[1]):
            if seen[i][j]:
                rx, ry = float(pos[i, j, 0]) - x, float(pos[i, j, 1]) - y
                vx, vy = float(velocity[i, j, 0]), float(velocity[i, j, 1])
                r = float(radius[i, j])
                rows.append((math.hypot(rx, ry) - r, [1.0, c * rx + s * ry, -s * rx + c * ry, c * vx + s * vy,
                                                       -s * vx + c * vy, r]))
        rows.sort(key=lambda item: item[0])
        for k, (_, feats) in enumerate(rows[:tracks]):
            out[i, k * W:(k + 1) * W] = feats
    return out


CASES = {"tb2": ("turtlebot2", 3, 8), "go2": ("go2", 2, 6), "tb2-more-tracks-than-agents": ("turtlebot2", 5, 3)}


@pytest.mark.parametrize("case", list(CASES))
def test_track_columns_equal_the_reference_through_steps_and_resets(case):
    robot, tracks, agents = CASES[case]
    n = 8
    env = tracked_env(robot, n=n, seed=4, tracks=tracks, agents=agents)
    e = env.preset.history_end
    assert env.obs_dim == e + tracks * W and env.single_observation_space.shape == (e + tracks * W,)
    obs, _ = env.reset(seed=4)
    a = env.agents
    prev_pos, prev_seen = a.pos.clone(), None
    gen = torch.Generator().manual_seed(4)
    counts = {"seen": 0, "unseen_active": 0, "moving_velocity": 0, "fresh": 0}
    for step in range(40):
        fresh = torch.ones(n, dtype=torch.bool) if prev_seen is None else None
        if fresh is None:
            action = torch.rand(n, 2, generator=gen) * 2 - 1
            action[:, 0] = -0.6  # slow: episodes last, agents come and go in the view
            obs, _, term, trunc, _ = env.step(action)
            done = term | trunc
        else:
            done = torch.zeros(n, dtype=torch.bool)
        # the state the finished slots ended in is gone after the reset: check the others' step here
        # and the finished ones' first observation of their new episode (velocity 0)
        keep = ~done
        pose, pos, radius, active = env.pose, a.pos, a.radius, a.active.numpy()
        static = env._cast(pose, None)
        seen = reference_seen(env, pose, pos, radius, active, static)
        if fresh is not None:
            velocity = torch.zeros_like(pos)
        else:
            both = torch.tensor(seen) & prev_seen
            velocity = torch.where(both[..., None], (pos - prev_pos) / env.preset.episode.dt, torch.zeros_like(pos))
        ref = reference_tracks(pose, pos, velocity, radius, seen, tracks)
        got = obs[:, e:].double().numpy()
        rows = np.nonzero(keep.numpy() if fresh is None else np.ones(n, bool))[0]
        # finished slots: obs is their new episode's first observation (velocity 0)
        fresh_rows = np.nonzero(done.numpy())[0]
        ref_fresh = reference_tracks(pose, pos, torch.zeros_like(pos), radius, seen, tracks)
        np.testing.assert_allclose(got[rows], ref[rows], atol=1e-4, rtol=0)
        np.testing.assert_allclose(got[fresh_rows], ref_fresh[fresh_rows], atol=1e-4, rtol=0)
        counts["seen"] += sum(map(sum, seen))
        counts["unseen_active"] += int(active.sum()) - sum(map(sum, seen))
        counts["moving_velocity"] += int((velocity.abs().sum(-1) > 0).sum())
        counts["fresh"] += len(fresh_rows)
        prev_pos, prev_seen = pos.clone(), torch.tensor(seen)
    assert counts["seen"] > 20 and counts["unseen_active"] > 20 and counts["moving_velocity"] > 10, counts
    if case == "tb2":
        assert counts["fresh"] > 0, counts  # a reset happened and was checked


def test_tracks_see_through_nothing_and_only_inside_the_field_of_view():
    """A hand-made scene on open floor (3.85 m free ahead, 5.85 m behind): one agent ahead, one hidden
    behind it, one behind the robot (outside the TurtleBot2's 270 deg), one beyond the range."""
    env = tracked_env(n=1, seed=0, tracks=4, agents=4)
    env.reset(seed=0)
    a = env.agents
    x, y = 6.0, 7.0
    env.pose[0] = torch.tensor([x, y, 0.0])
    a.pos[0] = torch.tensor([[x + 1.0, y], [x + 2.0, y], [x - 1.0, y], [x + 60.0, y]])
    a.radius[0] = 0.25
    a.active[0] = True
    ranges = env.scan()
    seen = env.extras.tracks.seen_by(env.pose, a.pos, a.radius, a.active, ranges)
    assert seen[0].tolist() == [True, False, False, False]
    feats = env.extras.tracks.observe(torch.tensor([0]), a, env.pose, ranges, fresh=True)
    assert feats[0, :W].tolist() == pytest.approx([1.0, 1.0, 0.0, 0.0, 0.0, 0.25], abs=1e-5)
    assert feats[0, W:].abs().sum() == 0


def test_without_agents_every_track_is_absent_and_zero_tracks_change_nothing():
    env = tracked_env(n=4, seed=1, tracks=2, agents=0)
    obs, _ = env.reset(seed=1)
    for _ in range(5):
        obs, *_ = env.step(torch.rand(4, 2) * 2 - 1)
    assert env.agents is None and obs[:, env.preset.history_end:].abs().sum() == 0
    plain = tracked_env(n=4, seed=1, tracks=0, agents=4)
    wide = tracked_env(n=4, seed=1, tracks=3, agents=4, **{"observation.scan_history": 2})
    assert plain.extras.tracks is None and plain.obs_dim == plain.preset.base_obs_dim
    o0, _ = plain.reset(seed=1)
    o1, _ = wide.reset(seed=1)
    gen = torch.Generator().manual_seed(1)
    for _ in range(30):
        act = torch.rand(4, 2, generator=gen) * 2 - 1
        o0, r0, t0, _, _ = plain.step(act)
        o1, r1, t1, _, _ = wide.step(act)
        assert torch.equal(o0, o1[:, : plain.obs_dim]) and torch.equal(r0, r1) and torch.equal(t0, t1)


def test_a_slot_reset_leaves_the_other_slots_tracks_bit_identical():
    env = tracked_env(n=8, seed=2, tracks=3)
    env.reset(seed=2)
    for _ in range(6):
        obs, *_ = env.step(torch.zeros(8, 2))
    before = (env.obs.clone(), env.extras.tracks.prev.clone(), env.extras.tracks.seen.clone())
    mask = torch.zeros(8, dtype=torch.bool)
    mask[[0, 6]] = True
    env.reset(options={"reset_mask": mask})
    after = (env.obs, env.extras.tracks.prev, env.extras.tracks.seen)
    for b, now in zip(before, after):
        assert torch.equal(b[~mask], now[~mask])


def test_ipaprec_divides_the_track_columns_by_their_bounds():
    preset = load_robot("turtlebot2", **{"agents.count": 4, "observation.agent_tracks": 2,
                                         "observation.scan_history": 1})
    layout = ObsLayout.from_robot(preset, 14.0)
    assert layout.obs_dim == preset.obs_dim and layout.history_end == preset.history_end
    plain = ObsLayout.from_robot(load_robot("turtlebot2", **{"observation.scan_history": 1}), 14.0)
    t_with, t_plain = IPAPRec(layout), IPAPRec(plain)
    obs = torch.rand(5, layout.obs_dim) * 3 + 0.5
    out = t_with(obs)
    e = layout.history_end
    assert torch.equal(out[:, :e], t_plain(obs[:, :e]))
    scales = torch.tensor(track_scales(preset) * 2)
    torch.testing.assert_close(out[:, e:], obs[:, e:] / scales)
    batched = IPAPRec(layout, copies=2)(obs)
    assert batched.shape == (2, 5, layout.obs_dim)
    torch.testing.assert_close(batched[0, :, e:], obs[:, e:] / scales)


# ---- export and the robot side ----------------------------------------------------------------------

TRACKS = 3


@pytest.fixture(scope="module")
def tb2t():
    return load_robot("turtlebot2", **{"observation.agent_tracks": TRACKS, "agents.count": 6})


@pytest.fixture(scope="module")
def exported_t(tb2t, tmp_path_factory):
    from test_export import random_actor

    from flashnav.export import export_policy

    actor = random_actor(tb2t, seed=3)
    return actor, export_policy(actor, tb2t, tmp_path_factory.mktemp("policy_t"))


def test_export_records_the_tracks_and_the_policy_reads_them(tb2t, exported_t):
    import onnxruntime as ort
    from test_export import observations

    from flashnav.export import DeployablePolicy, load_policy
    from flashnav.policy_meta import agent_track_count

    actor, paths = exported_t
    e = tb2t.history_end
    obs = observations(tb2t, 64, seed=4)
    assert obs.shape == (64, e + TRACKS * W)
    assert (obs[:, e::W] == 1).any() and (obs[:, e::W] == 0).any()  # present and absent tracks
    with torch.no_grad():
        action, command = DeployablePolicy(actor, tb2t).eval()(obs)
    got = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"]).run(None, {"obs": obs.numpy()})
    np.testing.assert_allclose(got[0], action.numpy(), rtol=0, atol=1e-5)
    scripted, meta = load_policy(paths["torchscript"])
    moved = obs.clone()
    moved[:, e:] = 0.0  # nobody tracked: other actions, so the policy reads the tracks
    assert not torch.allclose(scripted(moved), action, atol=1e-4)
    block = meta["observation"]["agent_tracks"]
    assert block["count"] == TRACKS and block["columns"] == [e, e + TRACKS * W] and block["features"] == list(TRACK_FEATURES)
    assert agent_track_count(meta) == TRACKS
    assert agent_track_count({"preset": {"observation": {}}}) == 0  # files from before the tracks
    with pytest.raises(ValueError, match="agent_tracks 'x'"):
        agent_track_count({"observation": {"agent_tracks": {"count": "x"}}}, "p.onnx")


def test_the_runtime_takes_a_trackers_people_and_names_bad_input(tb2t):
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import policy_metadata

    rt = PolicyRuntime(None, policy_metadata(tb2t))
    assert rt.agent_tracks == TRACKS and rt.velocity_dims == 2
    sectors = np.full(30, 2.0, np.float32)
    with pytest.raises(ValueError, match="tracks: the policy has 3 agent tracks"):
        rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0))
    with pytest.raises(ValueError, match=r"tracks must be rows of \(x, y, vx, vy, radius\)"):
        rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0), tracks=[[1.0, 2.0]])
    with pytest.raises(ValueError, match="finite with radius >= 0"):
        rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0), tracks=[[1.0, 2.0, 0, 0, -0.2]])
    empty = rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0), tracks=[])
    assert empty.shape == (34 + TRACKS * W,) and not empty[34:].any()
    people = [[3.0, 0.0, 0.1, 0.0, 0.3], [1.0, 1.0, 0.0, -0.2, 0.25], [0.5, -4.0, 0, 0, 0.2], [6.0, 0.0, 0, 0, 0.2]]
    obs = rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0), tracks=people)
    np.testing.assert_allclose(obs[34:].reshape(TRACKS, W), [[1, 1.0, 1.0, 0.0, -0.2, 0.25], [1, 3.0, 0.0, 0.1, 0.0, 0.3],
                                                             [1, 0.5, -4.0, 0, 0, 0.2]], rtol=0, atol=1e-6)
    plain = PolicyRuntime(None, policy_metadata(load_robot("turtlebot2")))
    with pytest.raises(ValueError, match="it takes no tracks"):
        plain.observation(sectors, (0, 0, 0), (1, 1), (0, 0), tracks=[])


def test_the_deploy_controller_rebuilds_the_envs_observations_from_a_trackers_people(tb2t, exported_t):
    """The simulated tracker's people (world frame, as flashnav deploy sim-robot publishes them) go
    through Controller.on_people; each control step's observation equals the env's, tracks included,
    over episodes with resets."""
    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.deploy.scan import simulator_scan_fields
    from flashnav.sim.tracks import TrackerView, seen_world_rows

    _, paths = exported_t
    ctl = Controller(PolicyRuntime.load(paths["onnx"]), timeout=1.0)
    env = make_env(tb2t, 1, seed=8)
    env.reset(seed=8)
    view, state = TrackerView(tb2t, env.beam_angles), None
    scan = simulator_scan_fields(tb2t.lidar)
    t, dt, episodes, people_seen = 0.0, tb2t.episode.dt, 1, 0
    ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
    for _ in range(120):
        ctl.on_odom(*env.world_pose()[0].tolist(), now=t)
        rows, state = seen_world_rows(view, env.agents, env.pose, env.scan(), state, dt, env.frame_origin)
        ctl.on_people(rows, now=t)
        people_seen += len(rows)
        command = ctl.on_scan(ranges=env.scan()[0].numpy(), stamp=t, now=t, **scan)
        assert command is not None and command.state == "driving"
        np.testing.assert_allclose(ctl.last_obs, env.obs[0].numpy(), rtol=0, atol=1e-4)
        _, _, terminated, truncated, _ = env.step(torch.tensor([ctl.last_action]))
        t += dt
        if bool(terminated[0] | truncated[0]):  # a new episode: a new goal, the tracker afresh
            ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
            episodes, state = episodes + 1, None
    assert episodes >= 2 and people_seen > 30


def test_a_silent_tracker_stops_a_tracks_policy(tb2t):
    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import policy_metadata

    ctl = Controller(PolicyRuntime(None, policy_metadata(tb2t)), timeout=0.5)
    ctl.on_goal(3.0, 3.0, now=0.0)
    ctl.on_odom(1.0, 1.0, 0.0, now=0.0)
    ctl.scan_time = 0.0
    assert ctl.tick(0.1) is not None and ctl.state == "stale"  # no people message yet
    ctl.on_people([], now=0.2)
    ctl.on_odom(1.0, 1.0, 0.0, now=0.2)
    ctl.scan_time = 0.2
    assert ctl.tick(0.3) is None and ctl.state == "driving"
    ctl.on_odom(1.0, 1.0, 0.0, now=0.7)
    ctl.scan_time = 0.7
    assert ctl.tick(0.75) is not None and ctl.state == "stale"  # scan and odometry fresh, people 0.55 s old
    with pytest.raises(ValueError, match="people must be finite rows"):
        ctl.on_people([[1.0, 2.0, 3.0]], now=1.0)


def test_bench_sim_times_the_tracks_beside_the_static_and_agent_steps(tmp_path):
    import json

    from flashnav.cli import main as cli_main

    out = tmp_path / "bench.json"
    assert cli_main(["bench", "sim", "--robots", "turtlebot2", "--raycasters", "exact", "--num-envs", "8",
                     "--seconds", "0.05", "--max-steps", "8", "--no-irsim", "--agents", "4", "--tracks", "2",
                     "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["agents"], r["tracks"]) for r in rows] == [(0, 0), (4, 0), (4, 2)]
    assert all(r["steps"] >= 2 and r["env_steps_per_s"] > 0 for r in rows)
    assert cli_main(["bench", "sim", "--quick", "--no-irsim", "--tracks", "2"]) == 2  # tracks of no agents
