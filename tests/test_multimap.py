"""Many maps in one batched environment (issue 15, item 1), each checked against the single-map code
map by map (the slow reference): raycasts, collisions, whole env steps; per-slot map draws at reset."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from flashnav.config import Footprint
from flashnav.maps.bundled import resolve_maps
from flashnav.maps.generate import generate_map
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.ros import save_ros_map
from flashnav.sim.collision import make_collision_checker
from flashnav.sim.env import beam_angles, make_env
from flashnav.sim.mapset import sim_frame
from flashnav.sim.raycast import make_raycaster, random_free_poses


@pytest.fixture(scope="module")
def maps() -> list[OccupancyMap]:
    """Four maps of different sizes, resolutions and origins (one far from the world origin)."""
    out = [generate_map(6.0, 5.0, 0.05, seed=1, name="a"), generate_map(9.0, 7.0, 0.1, seed=2, name="b"),
           generate_map(4.0, 6.0, 0.025, seed=3, name="c"), generate_map(7.0, 7.0, 0.05, seed=4, name="d")]
    out[1] = OccupancyMap(out[1].occupied, out[1].resolution, (-3.25, 7.1), "b")
    out[3] = OccupancyMap(out[3].occupied, out[3].resolution, (5.0e5, 4.0e6), "d-utm")
    return out


def mixed_poses(grids, n_per_map: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Poses [M * n, 3] on their maps (free ones, plus some anywhere in and around the map: on
    obstacles, on the boundary, outside) in a shuffled order, and their map index [M * n]."""
    gen = torch.Generator().manual_seed(seed)
    poses, index = [], []
    for m, g in enumerate(grids):
        free = random_free_poses(g, n_per_map - 4, generator=gen).double()
        xmin, ymin, xmax, ymax = g.bounds
        u = torch.rand(4, 3, generator=gen, dtype=torch.float64)
        wild = torch.stack([xmin - 0.2 + u[:, 0] * (xmax - xmin + 0.4), ymin - 0.2 + u[:, 1] * (ymax - ymin + 0.4),
                            (u[:, 2] * 2 - 1) * np.pi], dim=1)
        poses.append(torch.cat([free, wild]).float())
        index.append(torch.full((n_per_map,), m, dtype=torch.long))
    order = torch.randperm(len(grids) * n_per_map, generator=gen)
    return torch.cat(poses)[order], torch.cat(index)[order]


@pytest.mark.parametrize("name", ["exact", "exact-torch", "march"])
def test_raycasts_on_many_maps_equal_single_map_raycasts(maps, name):
    # map "d" lies at UTM coordinates: ray from the frame the env uses (its origin at 0)
    grids = maps[:3] + [maps[3].shifted(maps[3].origin)]
    angles = beam_angles(270, 216)
    pose, mi = mixed_poses(grids, 12, seed=0)
    multi = make_raycaster(name, grids, angles, 20.0)(pose, mi)
    assert multi.shape == (pose.shape[0], 216)
    for m, g in enumerate(grids):
        sel = mi == m
        single = make_raycaster(name, g, angles, 20.0)(pose[sel])
        assert torch.equal(multi[sel], single), f"{name}: map {g.name} differs from its single-map raycast"


@pytest.mark.parametrize("footprint", [Footprint(kind="disc", radius=0.2),
                                       Footprint(kind="rectangle", length=0.8, width=0.41)], ids=["disc", "rect"])
@pytest.mark.parametrize("prefilter", [True, False])
def test_collisions_on_many_maps_equal_single_map_collisions(maps, footprint, prefilter):
    grids = maps[:3] + [maps[3].shifted(maps[3].origin)]
    pose, mi = mixed_poses(grids, 40, seed=1)
    multi = make_collision_checker(footprint, grids, prefilter=prefilter)(pose, mi)
    assert multi.any() and not multi.all()
    for m, g in enumerate(grids):
        sel = mi == m
        single = make_collision_checker(footprint, g, prefilter=prefilter)(pose[sel])
        assert torch.equal(multi[sel], single), f"map {g.name} differs from its single-map collision check"


def test_many_map_geometry_needs_a_map_index(maps):
    rc = make_raycaster("exact", maps[:2], beam_angles(270, 36), 20.0)
    with pytest.raises(ValueError, match="give map_index"):
        rc(torch.zeros(3, 3))
    with pytest.raises(ValueError, match="outside \\[0, 2\\)"):
        rc(torch.zeros(3, 3), torch.tensor([0, 2, 1]))
    with pytest.raises(ValueError, match="map_index must be a 1-D integer"):
        make_collision_checker(Footprint(kind="disc", radius=0.2), maps[:2])(torch.zeros(3, 3), torch.zeros(3))


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_env_steps_on_many_maps_equal_single_map_envs(maps, robot):
    """Whole transitions (scan, collision, reward, flags, observation) of slots spread over four maps
    equal single-map envs holding the same slots, map by map."""
    n = 16
    env = make_env(robot, n, maps=maps, seed=0)
    env.reset(seed=0)
    # each slot at a pose its map's own sampler drew (world coordinates), on a fixed map assignment
    mi = torch.arange(n) % len(maps)
    pose = torch.empty(n, 3, dtype=torch.float64)
    goal = torch.empty(n, 2, dtype=torch.float64)
    for m, g in enumerate(maps):
        sel = (mi == m).nonzero().squeeze(1)
        p, q = env.samplers[m].sample(len(sel), torch.Generator().manual_seed(m))
        off = torch.tensor(sim_frame(g), dtype=torch.float64)  # the map's simulator frame -> world
        pose[sel] = torch.cat([p.double()[:, :2] + off, p.double()[:, 2:]], dim=1)
        goal[sel] = q.double() + off
    singles = [make_env(robot, int((mi == m).sum()), map=g, seed=0) for m, g in enumerate(maps)]
    obs = env.set_state(pose, goal, map_index=mi)
    assert torch.equal(env.map_index, mi)
    for m, single in enumerate(singles):
        sel = mi == m
        assert torch.equal(single.set_state(pose[sel], goal[sel]), obs[sel])
    gen = torch.Generator().manual_seed(5)
    for _ in range(12):
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        action[:, 0] = 1.0  # full speed ahead: collisions happen
        out = env.step_slots(torch.arange(n), action)
        for m, single in enumerate(singles):
            sel = mi == m
            ref = single.step_slots(torch.arange(single.num_envs), action[sel])
            for key, value in ref.items():
                assert torch.equal(out[key][sel], value), f"map {maps[m].name}: {key} differs"
    assert torch.equal(env.world_pose()[mi == 3], singles[3].world_pose())


def test_reset_slot_draws_a_map_and_other_slots_stay_bit_identical(maps):
    n = 64
    env = make_env("turtlebot2", n, maps=maps, seed=3)
    env.reset(seed=3)
    assert set(env.map_index.tolist()) == {0, 1, 2, 3}  # 64 uniform draws over 4 maps
    gen = torch.Generator().manual_seed(0)
    drawn = []
    for _ in range(30):
        before = {k: getattr(env, k).clone() for k in ("pose", "goal", "map_index", "steps", "obs")}
        action = torch.rand(n, 2, generator=gen) * 2 - 1
        ref = make_env("turtlebot2", n, maps=maps, seed=3)  # the same transition, without the reset
        ref.reset(seed=3)  # a fresh env refuses to step; the state written next is env's
        ref.map_index[:] = before["map_index"]
        ref.pose[:], ref.goal[:], ref.steps[:] = before["pose"], before["goal"], before["steps"]
        ref.goal_distance[:], ref.episode_return[:] = env.goal_distance, env.episode_return
        expect = ref.step_slots(torch.arange(n), action)
        obs, reward, terminated, truncated, info = env.step(action)
        done = terminated | truncated
        keep = ~done
        assert torch.equal(info["final_obs"], expect["obs"]) and torch.equal(reward, expect["reward"])
        # slots that did not finish: their map and state are exactly those of the plain transition
        assert torch.equal(env.map_index[keep], before["map_index"][keep])
        assert torch.equal(obs[keep], expect["obs"][keep]) and torch.equal(env.pose[keep], ref.pose[keep])
        assert torch.equal(env.goal[keep], before["goal"][keep])
        # finished slots start afresh on the map they drew, at a start its sampler allows
        assert torch.all(env.steps[done] == 0)
        for i in done.nonzero().squeeze(1).tolist():
            m = int(env.map_index[i])
            drawn.append(m)
            g = env.frame_maps[m]
            col = int((float(env.pose[i, 0]) - g.origin[0]) / g.resolution)
            row = int((float(env.pose[i, 1]) - g.origin[1]) / g.resolution)
            assert g.free_space(env.samplers[m].radius)[row, col], f"slot {i}: start not free on map {g.name}"
            ref_scan = make_raycaster("exact", g, env.beam_angles, 20.0)(env.pose[i:i + 1])
            assert torch.equal(env.scan()[i:i + 1], ref_scan)
    assert len(drawn) > 20 and set(drawn) == {0, 1, 2, 3}


def test_map_draws_are_seeded_and_weighted(maps):
    def draws(seed, **kw):
        env = make_env("turtlebot2", 200, maps=maps, seed=seed, **kw)
        env.reset(seed=seed)
        return env.map_index.clone()

    assert torch.equal(draws(7), draws(7)) and not torch.equal(draws(7), draws(8))
    weighted = draws(7, map_weights=[0.0, 1.0, 3.0, 0.0])
    counts = torch.bincount(weighted, minlength=4)
    assert counts[0] == 0 and counts[3] == 0 and counts[2] > 2 * counts[1] > 0
    with pytest.raises(ValueError, match="map_weights has 3 entries for 4 maps"):
        make_env("turtlebot2", 2, maps=maps, map_weights=[1, 1, 1])
    with pytest.raises(ValueError, match="not all 0"):
        make_env("turtlebot2", 2, maps=maps, map_weights=[0, 0, 0, 0])
    with pytest.raises(ValueError, match="either map or maps"):
        make_env("turtlebot2", 2, map="turtlebot2", maps=maps)


def test_goal_distance_bound_is_the_largest_diagonal(maps):
    env = make_env("turtlebot2", 4, maps=maps)
    largest = max(g.diagonal_m for g in maps)
    assert env.goal_distance_max == largest
    assert env.single_observation_space.high[30] == np.float32(largest)


def test_set_state_checks_each_slot_against_its_map(maps):
    env = make_env("turtlebot2", 2, maps=maps[:2])
    pose = torch.tensor([[1.0, 1.0, 0.0], [-2.0, 8.0, 0.0]], dtype=torch.float64)
    goal = torch.tensor([[2.0, 2.0], [5.5, 9.0]], dtype=torch.float64)  # map "b": x in [-3.25, 5.75] m
    env.set_state(pose, goal, map_index=torch.tensor([0, 1]))
    with pytest.raises(ValueError, match="goal\\[1\\].*outside the map 'b'"):
        env.set_state(pose, torch.tensor([[2.0, 2.0], [6.0, 2.0]], dtype=torch.float64), map_index=torch.tensor([0, 1]))
    with pytest.raises(ValueError, match="map_index holds 2"):
        env.set_state(pose, goal, map_index=torch.tensor([0, 2]))


def test_resolve_maps_directory_glob_and_list(tmp_path, maps):
    for g in maps[:3]:
        save_ros_map(g, tmp_path / f"{g.name}.yaml")
    assert [g.name for g in resolve_maps(tmp_path, "turtlebot2")] == ["a", "b", "c"]
    assert [g.name for g in resolve_maps(str(tmp_path / "[ab].yaml"), "turtlebot2")] == ["a", "b"]
    assert [g.name for g in resolve_maps(["turtlebot2", maps[0]], "go2")] == ["turtlebot2", "a"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no ROS map YAML"):
        resolve_maps(tmp_path / "empty", "turtlebot2")
    with pytest.raises(ValueError, match="matches no file"):
        resolve_maps(str(tmp_path / "*.yml"), "turtlebot2")
    with pytest.raises(ValueError, match="at least one map"):
        resolve_maps([], "turtlebot2")
    with pytest.raises(ValueError, match=r"'.*no_such_dir': no such directory or file; .*turtlebot2"):
        resolve_maps(str(tmp_path / "no_such_dir"), "turtlebot2")
    assert [g.name for g in resolve_maps("go2", "turtlebot2")] == ["go2"]  # one bundled name is still one map


# ---- configuration and training over many maps ---------------------------------------------------
def test_spec_resolves_maps_with_one_goal_scale(tmp_path, maps):
    from flashnav.spec import RunSpec, TrainConfig, config_from_cli, resolve

    for g in maps[:3]:
        save_ros_map(g, tmp_path / f"{g.name}.yaml")
    spec = resolve(config_from_cli(None, {"maps": str(tmp_path), "device": "cpu"}, ["map_weights=[1, 2, 1]"]))
    assert [g.name for g in spec.grids] == ["a", "b", "c"]
    assert spec.goal_distance_max == max(g.diagonal_m for g in maps[:3])
    back = RunSpec.from_dict(spec.to_dict())  # config.yaml round trip: the maps load again
    assert back.goal_distance_max == spec.goal_distance_max
    assert [g.name for g in back.env_maps()] == ["a", "b", "c"]
    with pytest.raises(ValueError, match="either map or maps"):
        TrainConfig(map="turtlebot2", maps=str(tmp_path))
    with pytest.raises(ValueError, match="map_weights has 2 entries for the 3 maps"):
        resolve(TrainConfig(maps=str(tmp_path), map_weights=[1, 1], device="cpu"))
    with pytest.raises(ValueError, match="matches no file"):
        resolve(TrainConfig(maps=str(tmp_path / "*.yml"), device="cpu"))


def test_train_command_over_a_maps_directory(tmp_path, maps):
    import json

    from flashnav.cli import main as cli_main

    (tmp_path / "maps").mkdir()
    for g in maps[:2]:
        save_ros_map(g, tmp_path / "maps" / f"{g.name}.yaml")
    out = tmp_path / "run"
    tiny = ["algo.num_envs=16", "algo.learning_start=32", "algo.updates_per_step=1", "algo.batch_size=32",
            "algo.eval_every=4", "budget.max_env_steps=64", "eval.episodes=8"]
    assert cli_main(["train", "--recipe", "cpu", "--device", "cpu", "--maps", str(tmp_path / "maps"),
                     "--out", str(out), *tiny]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["env_steps"] == 64
    import yaml

    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["maps"] == str(tmp_path / "maps")
    assert config["goal_distance_max"] == pytest.approx(max(g.diagonal_m for g in maps[:2]))


# ---- the oracle, per slot on its map ---------------------------------------------------------------
def test_oracle_acts_per_slot_as_on_each_single_map(maps):
    from flashnav.sim.oracle import OracleController

    n = 12
    env = make_env("turtlebot2", n, maps=maps, seed=2)
    env.reset(seed=2)
    mi = env.map_index.clone()
    pose, goal = env.world_pose(), env.world_goal()
    singles = {m: make_env("turtlebot2", int((mi == m).sum()), map=maps[m], seed=0) for m in mi.unique().tolist()}
    oracle = OracleController(env)
    oracle.plan()
    refs = {}
    for m, single in singles.items():
        single.set_state(pose[mi == m], goal[mi == m])
        refs[m] = OracleController(single)
        refs[m].plan()
    for _ in range(8):
        action = oracle.act()
        for m, single in singles.items():
            assert torch.equal(action[mi == m], refs[m].act()), f"map {maps[m].name}: oracle actions differ"
            single.step_slots(torch.arange(single.num_envs), action[mi == m])
        env.step_slots(torch.arange(n), action)


def test_oracle_solves_episodes_on_many_maps(maps):
    from flashnav.sim.oracle import run_oracle

    env = make_env("turtlebot2", 32, maps=maps, seed=4)
    result = run_oracle(env, episodes=96, seed=4)
    assert result["success"] >= 0.95, result


def test_bench_sim_times_many_maps_beside_the_bundled_map(tmp_path):
    import json

    from flashnav.cli import main as cli_main

    out = tmp_path / "bench.json"
    assert cli_main(["bench", "sim", "--robots", "turtlebot2", "--raycasters", "exact", "--num-envs", "8",
                     "--seconds", "0.05", "--max-steps", "8", "--no-irsim", "--maps", "3", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["maps"], r["num_envs"]) for r in rows] == [(1, 8), (3, 8)]
    assert all(r["steps"] >= 2 and r["env_steps_per_s"] > 0 for r in rows)
