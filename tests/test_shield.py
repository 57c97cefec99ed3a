"""flashnav/shield.py: the people shield overrules the policy only for a predicted contact with a person, picks the
nearest action that keeps clear of people and walls, and its rollouts are the simulator's motion and footprint."""

from __future__ import annotations

import math

import pytest
import torch

from flashnav.cli import main as cli_main
from flashnav.presets import load_robot
from flashnav.scenarios import run_scenario, scenario_preset
from flashnav.shield import People, PeopleShield, blind_edges, blind_points, scan_points, with_blind_sector
from flashnav.sim.agent_geometry import footprint_hits_discs
from flashnav.sim.env import make_env
from flashnav.sim.motion import action_to_velocity, integrate

TB2 = load_robot("turtlebot2")


def people(rows: list[list[tuple]]) -> People:
    """People of E robots from rows (x, y, vx, vy, r) per robot, padded with absent rows."""
    m = max(1, max(len(r) for r in rows))
    t = torch.zeros(len(rows), m, 5)
    present = torch.zeros(len(rows), m, dtype=torch.bool)
    for i, r in enumerate(rows):
        for j, row in enumerate(r):
            t[i, j], present[i, j] = torch.tensor(row, dtype=torch.float32), True
    return People(t[..., :2], t[..., 2:4], t[..., 4], present)


def reference_first_contact(shield: PeopleShield, pose, action, who: People, walls=None) -> int:
    """One rollout, one step at a time, each person and wall point checked on its own."""
    v, w = action_to_velocity(action[None], shield.preset.motion)
    x = pose[None].float()
    for step in range(shield.steps):
        x = integrate(x, v, w, shield.dt)
        t = (step + 1) * shield.dt
        for j in range(who.centres.shape[0]):
            if not who.present[j]:
                continue
            c = (who.centres[j] + who.velocity[j] * t)[None, None]
            r = (who.radius[j] + shield.margin)[None, None]
            if footprint_hits_discs(x, shield.preset.footprint, c, r, torch.ones(1, 1, dtype=torch.bool)):
                return step
        for q in ([] if walls is None else walls):
            if torch.isfinite(q).all() and footprint_hits_discs(x, shield.preset.footprint, q[None, None],
                                                                torch.full((1, 1), 0.01), torch.ones(1, 1, dtype=torch.bool)):
                return step
    return shield.steps


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_first_contact_equals_a_step_by_step_reference_on_random_scenes(robot):
    preset = load_robot(robot)
    gen = torch.Generator().manual_seed(0)
    shield = PeopleShield(preset, lookahead=1.5, margin=0.1)
    e, c, m = 12, 7, 3
    pose = torch.cat([4 * torch.rand(e, 2, generator=gen), (2 * torch.rand(e, 1, generator=gen) - 1) * math.pi], 1)
    actions = 2 * torch.rand(e, c, 2, generator=gen) - 1
    centres = pose[:, None, :2] + 3 * (torch.rand(e, m, 2, generator=gen) - 0.5)
    who = People(centres, 0.6 * (torch.rand(e, m, 2, generator=gen) - 0.5), 0.2 + 0.2 * torch.rand(e, m, generator=gen),
                 torch.rand(e, m, generator=gen) < 0.8)
    # wall points near and far: the shield tests only those within its reach, the reference every one
    walls = pose[:, None, :2] + 2 * (torch.rand(e, 9, 2, generator=gen) - 0.5) * torch.tensor([1.0] * 5 + [3.0] * 4)[:, None]
    walls[0, 2] = math.inf
    far = torch.linalg.vector_norm(walls - pose[:, None, :2], dim=-1) > shield.reach
    assert far.any() and (~far & torch.isfinite(walls[..., 0])).any()
    got = shield.first_contact(pose, actions, who, walls)
    touched = 0
    for i in range(e):
        for k in range(c):
            ref = reference_first_contact(shield, pose[i], actions[i, k], who.rows(torch.tensor(i)), walls[i])
            assert int(got[i, k]) == ref, (i, k)
            touched += ref < shield.steps
    assert 0 < touched < e * c   # the scenes have both
    # a prediction given as centres per step is the same people walking straight on
    ahead = torch.arange(1, shield.steps + 1) * shield.dt
    stepped = People(centres[:, None] + who.velocity[:, None] * ahead[None, :, None, None], None, who.radius, who.present)
    assert torch.equal(shield.first_contact(pose, actions, stepped, walls), got)


def test_without_a_predicted_contact_the_policy_is_left_alone():
    shield = PeopleShield(TB2, lookahead=2.0)
    pose = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    proposed = torch.tensor([[1.0, 0.0], [0.3, -0.5]])
    # nobody; and a person behind the robot walking away from it
    who = people([[], [(-1.5, 0.0, -0.4, 0.0, 0.3)]])
    wall = torch.tensor([[[0.3, 0.0]], [[0.3, 0.0]]])   # a wall point right ahead: walls never call the shield
    out, overruled = shield.filter(proposed, pose, who, wall)
    assert torch.equal(out, proposed) and not overruled.any()


def test_a_person_walking_into_the_robot_is_avoided_with_the_nearest_clear_action():
    shield = PeopleShield(TB2, lookahead=2.0)
    pose = torch.zeros(1, 3)
    proposed = torch.tensor([[1.0, 0.0]])                       # full speed ahead ...
    who = people([[(1.6, 0.0, -0.5, 0.0, 0.3)]])               # ... into a person walking at the robot
    assert int(shield.first_contact(pose, proposed[:, None], who)[0, 0]) < shield.steps
    out, overruled = shield.filter(proposed, pose, who)
    assert overruled.all() and not torch.equal(out, proposed)
    assert int(shield.first_contact(pose, out[:, None], who)[0, 0]) == shield.steps   # the played action is clear
    clear = shield.first_contact(pose, shield.grid[None], who)[0] == shield.steps
    nearest = torch.linalg.vector_norm(shield.grid[clear] - proposed, dim=1).min()
    assert float(torch.linalg.vector_norm(out - proposed)) == pytest.approx(float(nearest), abs=1e-6)


def test_the_shield_keeps_its_alternatives_off_the_scans_walls():
    shield = PeopleShield(TB2, lookahead=2.0)
    pose = torch.zeros(1, 3)
    proposed = torch.tensor([[1.0, 0.0]])
    who = people([[(1.0, 1.2, 0.0, -0.5, 0.3)]])   # a person from the left, across the robot's way
    free, _ = shield.filter(proposed, pose, who)
    assert float(free[0, 0]) > 0   # it drives on, turning away
    # a wall where the free choice would drive: points along its path from 0.6 to 1.5 s ahead
    v, w = action_to_velocity(free, TB2.motion)
    x, trail = pose, []
    for _ in range(15):
        x = integrate(x, v, w, shield.dt)
        trail.append(x[0, :2])
    walls = torch.stack(trail[5:])[None]
    assert int(shield.first_contact(pose, free[:, None], who, walls)[0, 0]) < shield.steps
    walled, _ = shield.filter(proposed, pose, who, walls)
    assert not torch.equal(walled, free)
    assert int(shield.first_contact(pose, walled[:, None], who, walls)[0, 0]) == shield.steps


def test_scan_points_are_each_groups_nearest_hit_without_max_range_or_people():
    pose = torch.tensor([[1.0, 2.0, 0.5]])
    angles = torch.linspace(-1.0, 1.0, 8)
    ranges = torch.tensor([[3.0, 2.0, 30.0, 30.0, 1.5, 1.0, 4.0, 4.0]])
    pts = scan_points(pose, ranges, angles, 30.0, group=2)
    for g, (r, a) in enumerate([(2.0, angles[1]), (None, None), (1.0, angles[5]), (4.0, angles[6])]):
        if r is None:
            assert torch.isinf(pts[0, g]).all()
            continue
        want = pose[0, :2] + r * torch.stack([torch.cos(pose[0, 2] + a), torch.sin(pose[0, 2] + a)])
        assert torch.allclose(pts[0, g], want, atol=1e-6)
    on_person = people([[(*pts[0, 2].tolist(), 0.0, 0.0, 0.2)]])
    assert torch.isinf(scan_points(pose, ranges, angles, 30.0, on_person, group=2)[0, 2]).all()
    with pytest.raises(ValueError, match="groups of 3"):
        scan_points(pose, ranges, angles, 30.0, group=3)


@pytest.mark.parametrize("bad", [dict(lookahead=0.0), dict(lookahead=math.nan), dict(margin=-0.1), dict(v_levels=1)])
def test_bad_settings_are_refused_by_name(bad):
    with pytest.raises(ValueError, match="shield"):
        PeopleShield(TB2, **bad)


def drive_at_goal(obs: torch.Tensor) -> torch.Tensor:
    """A policy that ignores everything but the goal: full speed, turning toward its bearing."""
    a = torch.zeros(obs.shape[0], 2)
    a[:, 0], a[:, 1] = 1.0, (obs[:, 31] / (math.pi / 4)).clamp(-1, 1)
    return a


def test_in_the_scenarios_it_cuts_the_agent_collisions_and_leaves_static_episodes_alone():
    torch.set_num_threads(1)
    for name in ("wander-8", "crossing"):
        p = scenario_preset("turtlebot2", name)
        plain = run_scenario(drive_at_goal, make_env(p, 64, seed=7), 7)
        shielded = run_scenario(drive_at_goal, make_env(p, 64, seed=7), 7, shield=PeopleShield(p, 2.0))
        assert shielded["agent_collision_rate"] < 0.6 * plain["agent_collision_rate"], name
        assert 0 < shielded["shield_overruled"] < 0.5 and shielded["scored"] == plain["scored"]
    p = scenario_preset("turtlebot2", "static")
    plain = run_scenario(drive_at_goal, make_env(p, 32, seed=7), 7)
    shielded = run_scenario(drive_at_goal, make_env(p, 32, seed=7), 7, shield=PeopleShield(p, 2.0))
    assert shielded.pop("shield_overruled") == 0.0 and shielded == plain


def test_rollout_behind_the_shield_plays_the_scenarios_episodes_and_marks_its_take_overs():
    from flashnav.rollout import rollout, took_over_points

    torch.set_num_threads(1)
    p = scenario_preset("turtlebot2", "wander-8")
    r = rollout(drive_at_goal, make_env(p, 24, seed=7), 7, shield=PeopleShield(p, 2.0))
    ref = run_scenario(drive_at_goal, make_env(p, 24, seed=7), 7, shield=PeopleShield(p, 2.0))
    assert r["outcomes"].count("success") / 24 == ref["success_rate"]
    played = int((r["length"] - 1).sum())   # steps of running episodes; rows past an episode's end are never marked
    assert int(r["took_over"].sum()) / played == ref["shield_overruled"] > 0
    assert took_over_points(r).shape == (int(r["took_over"].sum()), 2)
    assert "took_over" not in rollout(drive_at_goal, make_env(p, 4, seed=7), 7)


def test_render_draws_the_shields_take_overs_and_refuses_it_without_a_scenario(tmp_path, capsys):
    from pathlib import Path

    fixture = str(Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx")
    out = tmp_path / "shield.png"
    assert cli_main(["render", fixture, "--scenario", "wander-8", "--shield", "2", "--episodes", "4",
                     "--out", str(out), "--gif"]) == 0
    assert out.stat().st_size > 0 and out.with_suffix(".gif").stat().st_size > 0
    assert cli_main(["render", fixture, "--shield", "2", "--out", str(tmp_path / "x.png")]) != 0
    assert "--scenario" in capsys.readouterr().err


def test_eval_refuses_a_shield_without_a_scenario_or_of_no_length(tmp_path, capsys):
    for argv, words in ((["--shield", "2"], "--scenario"), (["--scenario", "crossing", "--shield", "0"], "> 0")):
        assert cli_main(["eval", str(tmp_path / "policy.onnx"), *argv]) != 0
        assert words in capsys.readouterr().err


# --- on a robot: the deploy controller's shield -----------------------------------------------------------------

def _controller(shield_s):
    from pathlib import Path

    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import recorded_robot

    rt = PolicyRuntime.load(Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx")
    shield = None if shield_s is None else PeopleShield(recorded_robot(rt.meta), lookahead=shield_s)
    return Controller(rt, timeout=0.3, shield=shield)


FOV = math.radians(270.0)
SCAN = dict(angle_min=-FOV / 2 + FOV / 2160, angle_increment=FOV / 1080, range_min=0.0, range_max=20.0)


def _drive(ctl, people_rows, steps=3):
    import numpy as np

    ctl.on_odom(0.0, 0.0, 0.0, now=0.0)
    ctl.on_goal(4.0, 0.0, now=0.0)
    out = []
    for k in range(steps):
        t = 0.1 * k
        ctl.on_odom(0.0, 0.0, 0.0, now=t)
        ctl.on_people(people_rows, now=t)
        out.append(ctl.on_scan(ranges=np.full(1080, 6.0, np.float32), stamp=t, now=t, **SCAN))
    return out


def test_the_deploy_controller_with_a_shield_drives_as_without_when_nobody_is_near():
    plain, shielded = _drive(_controller(None), []), _drive(_controller(2.0), [])
    assert [(c.v, c.w, c.state) for c in plain] == [(c.v, c.w, c.state) for c in shielded]
    assert plain[0].v > 0.3   # the fixture policy drives at its goal straight ahead


def test_the_deploy_controller_with_a_shield_gives_way_to_a_person_walking_at_the_robot():
    person = [[1.6, 0.0, -0.5, 0.0, 0.3]]   # 1.6 m ahead in the odometry frame, walking at the robot
    plain = _drive(_controller(None), person)
    ctl = _controller(2.0)
    shielded = _drive(ctl, person)
    assert shielded[0].state == "driving" and shielded[0].v < plain[0].v - 0.1
    assert ctl.status(0.3)["shielded"] >= 1 and _controller(None).status(0.0)["shielded"] is None


def test_the_deploy_controller_with_a_shield_stops_when_the_people_go_stale():
    import numpy as np

    ctl = _controller(2.0)
    _drive(ctl, [], steps=1)
    ctl.on_odom(0.0, 0.0, 0.0, now=0.5)   # odometry and scan fresh, people 0.5 s old
    stop = ctl.on_scan(ranges=np.full(1080, 6.0, np.float32), stamp=0.5, now=0.5, **SCAN)
    assert (stop.v, stop.w, stop.state) == (0.0, 0.0, "stale")


def test_deploy_refuses_a_shield_of_no_length_by_name(tmp_path, capsys):
    from pathlib import Path

    policy = Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx"
    code = cli_main(["deploy", "replay", str(tmp_path / "in.bag"), "--policy", str(policy), "--out",
                     str(tmp_path / "o.csv"), "--shield", "-1"])
    assert code != 0 and "--shield must be > 0 and at most 10 seconds" in capsys.readouterr().err


def test_robot_command_is_the_shield_on_the_scans_grouped_points_pruned_only_where_unreachable():
    import numpy as np

    from flashnav.shield import SCAN_GROUP, robot_command

    rng = np.random.default_rng(4)
    shield = PeopleShield(TB2, lookahead=2.0)
    fov = math.radians(270.0)
    angles = -fov / 2 + fov / 2160 + np.arange(1080) * fov / 1080
    took_over = 0
    for _ in range(12):
        pose = (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)), float(rng.uniform(-math.pi, math.pi)))
        ranges = rng.uniform(0.4, 6.0, 1080)
        ranges[rng.random(1080) < 0.1] = np.inf
        rows = [[pose[0] + rng.uniform(-2, 2), pose[1] + rng.uniform(-2, 2), rng.uniform(-0.5, 0.5),
                 rng.uniform(-0.5, 0.5), 0.3] for _ in range(3)]
        action = rng.uniform(-1, 1, 2)
        v, w, over, played = robot_command(shield, action, pose, rows, angles, ranges)
        # the reference: every group's nearest point, none pruned, points on a person dropped (scan_points)
        here = torch.tensor([pose], dtype=torch.float32)
        t = torch.tensor(rows, dtype=torch.float32)[None]
        who = People(t[..., :2], t[..., 2:4], t[..., 4], torch.ones(1, 3, dtype=torch.bool))
        r = torch.tensor(np.where(np.isfinite(ranges), ranges, 1e9), dtype=torch.float32)[None]
        walls = scan_points(here, r, torch.tensor(angles, dtype=torch.float32), 1e9, who, group=SCAN_GROUP)
        out, ref_over = shield.filter(torch.tensor(action[None], dtype=torch.float32), here, who, walls)
        assert over == bool(ref_over[0]) and played == pytest.approx(out[0].tolist(), abs=1e-6)
        rv, rw = action_to_velocity(out, TB2.motion)
        assert (v, w) == pytest.approx((float(rv[0]), float(rw[0])), abs=1e-6)
        took_over += over
    assert took_over >= 2


def test_bench_shield_plays_the_scenario_both_ways_and_refuses_one_without_agents(tmp_path, capsys):
    import json
    from pathlib import Path

    from flashnav.export import load_policy, recorded_robot

    fixture = str(Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx")
    out = tmp_path / "bench.json"
    assert cli_main(["bench", "shield", fixture, "--episodes", "8", "--repeats", "1", "--json", str(out)]) == 0
    runs = json.loads(out.read_text())["runs"]
    alone, shielded = runs["alone"][0], runs["shield"][0]
    assert alone["shield_seconds"] == 0 < shielded["shield_seconds"] < shielded["seconds"]
    # the shielded way is flashnav eval --scenario wander-8 --shield 2 on the same episodes
    policy, meta = load_policy(fixture)
    p = scenario_preset(recorded_robot(meta), "wander-8")
    ref = run_scenario(policy, make_env(p, 8, seed=2026), 2026, shield=PeopleShield(p, 2.0))
    assert {k: shielded[k] for k in ref if k != "shield_overruled"} == {k: v for k, v in ref.items() if k != "shield_overruled"}
    assert cli_main(["bench", "shield", fixture, "--scenario", "static", "--episodes", "4"]) != 0
    assert "has no agents" in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA (scripts/gpu_checklist.sh runs it on a GPU)")
def test_the_shield_on_cuda_decides_as_on_the_cpu_and_runs_a_scenario():
    gen = torch.Generator().manual_seed(3)
    shield = PeopleShield(TB2, lookahead=2.0)
    e, m = 64, 4
    pose = torch.cat([4 * torch.rand(e, 2, generator=gen), (2 * torch.rand(e, 1, generator=gen) - 1) * math.pi], 1)
    who = People(pose[:, None, :2] + 3 * (torch.rand(e, m, 2, generator=gen) - 0.5),
                 torch.rand(e, m, 2, generator=gen) - 0.5, 0.2 + 0.1 * torch.rand(e, m, generator=gen),
                 torch.ones(e, m, dtype=torch.bool))
    walls = pose[:, None, :2] + 4 * (torch.rand(e, 40, 2, generator=gen) - 0.5)
    proposed = 2 * torch.rand(e, 2, generator=gen) - 1
    cpu = shield.filter(proposed, pose, who, walls)
    cuda = shield.filter(proposed.cuda(), pose.cuda(), People(*(t.cuda() for t in who)), walls.cuda())
    assert torch.equal(cuda[1].cpu(), cpu[1]) and torch.allclose(cuda[0].cpu(), cpu[0]) and bool(cpu[1].any())
    p = scenario_preset("turtlebot2", "wander-8")
    r = run_scenario(lambda obs: drive_at_goal(obs.cpu()).to(obs.device), make_env(p, 32, seed=7, device="cuda"), 7,
                     shield=PeopleShield(p, 2.0))
    assert r["scored"] == 32 and 0 < r["shield_overruled"] < 0.5


def test_blind_points_lie_on_the_edges_of_the_unseen_sector_and_a_full_circle_has_none():
    env = make_env(TB2, 1)
    pose = torch.tensor([[1.0, 2.0, 0.5]])
    pts = blind_points(pose, blind_edges(env.beam_angles), reach=1.0, inner=0.3)
    rel = pts[0].double() - pose[0, :2].double()
    dist, bearing = rel.norm(dim=1), torch.atan2(rel[:, 1], rel[:, 0]) - 0.5
    edge = math.radians(TB2.lidar.fov_deg / 2)  # the 270-deg scan's first and last beams: +-135 deg from the heading
    off = torch.minimum((torch.remainder(bearing - edge + math.pi, 2 * math.pi) - math.pi).abs(),
                        (torch.remainder(bearing + edge + math.pi, 2 * math.pi) - math.pi).abs())
    assert float(off.max()) < math.radians(0.5) and 0.3 - 1e-6 <= float(dist.min()) and float(dist.max()) <= 1.0 + 1e-6
    assert (off < math.radians(0.5)).sum() == len(pts[0])  # every point on one of the two edges
    full = torch.linspace(-math.pi, math.pi, 360 + 1)[:-1]
    assert blind_edges(full) is None and blind_points(pose, None, reach=1.0, inner=0.3) is None


def test_a_reversing_robot_takes_the_unseen_sector_behind_it_for_occupied_and_a_forward_one_never_meets_it():
    """A robot that may reverse (v_bounds below 0) and a 270-deg LiDAR: in open space the shield's rollouts backwards
    touch the blind sector's edges, forward ones and turns on the spot do not; for the paper's forward-only bounds
    no rollout of the shield's grid meets them within 2 or 3 s, so its choices are the ones measured before."""
    open_scan = torch.full((1, 4, 2), math.inf)
    pose = torch.zeros(1, 3)
    nobody = people([[]])
    rev = PeopleShield(load_robot("turtlebot2", **{"motion.v_bounds": [-0.25, 0.5]}), lookahead=2.0)
    walls = with_blind_sector(rev, open_scan, pose, blind_edges(make_env(TB2, 1).beam_angles))
    still = -1 + 2 * 0.25 / 0.75  # the action of v = 0 for v_bounds [-0.25, 0.5]
    acts = torch.tensor([[[-1.0, 0.0], [1.0, 0.0], [still, 1.0], [still, -1.0]]])
    first = rev.first_contact(pose, acts, nobody, walls)[0]
    assert int(first[0]) < rev.steps and (first[1:] == rev.steps).all()
    for lookahead in (2.0, 3.0):
        fwd = PeopleShield(TB2, lookahead=lookahead)
        walls = with_blind_sector(fwd, open_scan, pose, blind_edges(make_env(TB2, 1).beam_angles))
        first = fwd.first_contact(pose, fwd.grid[None], nobody, walls)[0]
        assert (first == fwd.steps).all()
