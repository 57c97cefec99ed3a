"""The learners' reading of the wall map (observation.wall_map; flashnav/learn/wall_map.py): one encoder serves the
actor and the critics (the critic loss trains it), encoding a batch once is the update the networks would make reading
the squares, IPAPRec leaves the map's columns to the encoder, the actor step writes no encoder gradient, and a run
with the map trains, saves and exports what it reads; on the robot (flashnav/deploy/memory.py: WallCells) the deploy
controller rebuilds the env's map from odometry and scans alone."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from flashnav.observation_samples import sample_observations
from flashnav.learn.networks import Actor, IPAPRec, ObsLayout, TwinCritic
from flashnav.learn.hparams import WALL_MAP_CONVS
from flashnav.learn.wall_map import WALL_MAP_FEATURES, WallMapEncoder, conv_side, receptive_field, with_features
from flashnav.presets import load_robot

CELLS = 10
PRESET = load_robot("turtlebot2", **{"observation.wall_map": CELLS, "observation.memory_frames": 2})
LAYOUT = ObsLayout.from_robot(PRESET, 14.0)


def observations(n: int, seed: int = 0) -> torch.Tensor:
    return sample_observations(PRESET, n, torch.Generator().manual_seed(seed), 14.0)


def test_the_layout_places_the_map_after_every_other_column():
    assert LAYOUT.obs_dim == PRESET.obs_dim == LAYOUT.memory_end + 2 * CELLS * CELLS
    assert LAYOUT.memory_end == PRESET.memory_end == 34 + 30
    assert LAYOUT.feature_dim == LAYOUT.vector_feature_dim + WALL_MAP_FEATURES
    assert [conv_side(c) for c in (24, 12, 10, 5, 2)] == [6, 3, 3, 2, 1]
    obs = observations(64)
    squares = obs[:, LAYOUT.memory_end:]
    assert obs.shape == (64, PRESET.obs_dim) and set(squares.unique().tolist()) == {0.0, 1.0}
    assert squares[:, CELLS * CELLS:].sum(1).eq(1).all()  # one goal square each
    with pytest.raises(ValueError, match="ObsLayout.wall_map must be 0 or an integer >= 2, got 1"):
        ObsLayout(30, 0.2, 8.0, 10.0, (0.5, 1.0), wall_map=1)
    with pytest.raises(ValueError, match="at least 2 x 2 squares, got 1"):
        WallMapEncoder(1)


def learner(algo: str, **hp):
    from flashnav.learn.hparams import load_hparams
    from flashnav.learn.learners import make_learner
    small = {"batch_size": 16, "actor_hidden": [32, 32], "critic_hidden": [32, 32], **hp}
    return make_learner(algo, load_hparams(algo, "turtlebot2", "cpu", small), LAYOUT, 2, 4, "cpu", seed=5)


def batch(n: int, seed: int):
    from flashnav.learn.replay import Transition
    gen = torch.Generator().manual_seed(seed)
    return Transition(obs=observations(n, seed), action=torch.rand(n, 2, generator=gen) * 2 - 1,
                      reward=torch.randn(n, generator=gen), bootstrap=torch.ones(n) * 0.9,
                      next_obs=observations(n, seed + 100))


@pytest.mark.parametrize("algo", ["fastdsac", "fastsac", "fasttd3"])
def test_one_encoder_serves_the_actor_and_the_critics_and_the_critic_loss_trains_it(algo):
    from flashnav.learn.common import actor_own_params
    state = learner(algo).state
    assert state.actor.walls is state.critic.walls and state.critic_target.walls is not state.critic.walls
    assert state.collector.walls is not state.actor.walls  # the collector's copy, synced with the actor's weights
    encoder = {id(p) for p in state.critic.walls.parameters()}
    in_actor_opt = {id(p) for g in state.actor_opt.param_groups for p in g["params"]}
    in_critic_opt = {id(p) for g in state.critic_opt.param_groups for p in g["params"]}
    assert encoder <= in_critic_opt and not encoder & in_actor_opt
    assert {id(p) for p in actor_own_params(state.actor)} == in_actor_opt
    assert len(in_actor_opt) == len(list(state.actor.parameters())) - len(encoder)


def test_the_encoder_is_built_from_the_learners_wall_map_convs():
    convs = ((8, 1), (16, 2), (16, 2), (16, 1))
    state = learner("fastdsac", wall_map_convs=[list(c) for c in convs]).state
    enc = state.actor.walls
    assert enc is state.critic.walls and enc.convs == convs == state.critic_target.walls.convs
    assert [tuple(w.shape[:2]) for w in enc.conv_weights] == [(8, 2), (16, 8), (16, 16), (16, 16)]
    assert enc.flat == 16 * conv_side(CELLS, convs) ** 2 == 16 * 9
    obs = observations(4, seed=3)
    assert state.actor(obs).shape[0] == 4  # the actor reads the map through those layers
    assert learner("fastdsac").state.actor.walls.convs == WALL_MAP_CONVS == ((16, 1), (32, 2), (32, 2))
    from flashnav.learn.hparams import load_hparams
    for bad, said in (([[16, 1], [0, 2]], r"\[\[0, 2\]\]"), ([[16, 3]], r"\[\[16, 3\]\]")):
        with pytest.raises(ValueError, match=rf"algo.wall_map_convs: every layer is \[out channels > 0, "
                                             rf"stride 1 or 2\], got {said}"):
            load_hparams("fastdsac", "turtlebot2", "cpu", {"wall_map_convs": bad})
    with pytest.raises(ValueError, match="at least one"):
        WallMapEncoder(6, convs=())


@pytest.mark.parametrize("convs, field", [(WALL_MAP_CONVS, 9), (((16, 1), (32, 2), (32, 2), (32, 1)), 17),
                                          (((4, 2), (4, 1), (4, 2)), 11)])
def test_receptive_field_is_what_one_output_of_the_convolutions_sees(convs, field):
    """Found by the gradient of one output in the middle of a 48 x 48 map: the squares it depends on."""
    enc = WallMapEncoder(48, generator=torch.Generator().manual_seed(1), convs=convs)
    image = torch.zeros(1, 2, 48, 48, requires_grad=True)
    grid = enc.conv_grid(image + 0.5)
    mid = grid.shape[-1] // 2
    grid[0, :, mid, mid].sum().backward()
    seen = image.grad[0].abs().sum(0) > 0
    rows, cols = seen.any(1).nonzero().flatten(), seen.any(0).nonzero().flatten()
    assert 0 < rows[0] and rows[-1] < 47 and 0 < cols[0] and cols[-1] < 47  # inside the map: not cut by its edge
    assert rows[-1] - rows[0] + 1 == cols[-1] - cols[0] + 1 == receptive_field(convs) == field


def test_the_networks_read_encoded_features_as_they_read_the_squares():
    state = learner("fastdsac").state
    obs, action = observations(9, seed=2), torch.rand(9, 2) * 2 - 1
    end = LAYOUT.memory_end
    encoded = with_features(obs, state.critic.walls, end)
    assert encoded.shape == (9, end + WALL_MAP_FEATURES + 2 * CELLS ** 2) and torch.equal(encoded[:, :end], obs[:, :end])
    torch.testing.assert_close(encoded[:, end:end + WALL_MAP_FEATURES], state.critic.walls(obs[:, end:]))
    assert torch.equal(encoded[:, end + WALL_MAP_FEATURES:], obs[:, end:])
    torch.testing.assert_close(state.actor(encoded), state.actor(obs))
    torch.testing.assert_close(state.critic(encoded, action), state.critic(obs, action))
    torch.testing.assert_close(state.critic(encoded, action, detach_params=True), state.critic(obs, action))


@pytest.mark.parametrize("algo", ["fastdsac", "fastsac", "fasttd3"])
def test_encoding_a_batch_once_is_the_update_the_networks_reading_the_squares_would_make(algo):
    """With tau 1 the target encoder is the encoder itself after every update, so encoding each batch once
    (:func:`encode_wall_maps`) must give exactly the update that the learner's own functions make on the raw squares
    (every network reading them through the shared encoder, the actor step after the critic's; the actor loss's
    gradient into the encoder, which only the critic's optimiser holds, is cleared by the next critic step); four
    updates, two actor steps."""
    from flashnav.learn.learners import MODULES
    fast, slow = learner(algo, tau=1.0), learner(algo, tau=1.0)  # the same seed: the same weights and draws
    raw = MODULES[algo].update
    for i in range(4):
        b = batch(16, seed=10 + i)
        fast.update(b)
        raw(slow.state, b)
    before = learner(algo, tau=1.0).state.critic.walls
    for net in ("actor", "critic", "critic_target"):
        for (name, p), q in zip(getattr(fast.state, net).named_parameters(), getattr(slow.state, net).parameters()):
            torch.testing.assert_close(p, q, rtol=1e-4, atol=1e-5, msg=f"{net}.{name}")
    assert not torch.allclose(fast.state.critic.walls.out_weight, before.out_weight)  # the critic loss trained it
    torch.testing.assert_close(fast.state.critic_target.walls.out_weight, fast.state.critic.walls.out_weight)


def test_ipaprec_leaves_the_map_to_the_encoder_and_the_networks_read_it():
    obs = observations(16, seed=1)
    moved = obs.clone()
    moved[:, LAYOUT.memory_end:] = 1.0 - moved[:, LAYOUT.memory_end:]
    for transform in (IPAPRec(LAYOUT), IPAPRec(LAYOUT, copies=2, normalize=True)):
        out = transform(obs)
        assert out.shape[-1] == LAYOUT.vector_feature_dim
        assert torch.equal(out, transform(moved))
    gen = torch.Generator().manual_seed(0)
    actor = Actor(LAYOUT, 2, [64, 64], 3, gen)
    critic = TwinCritic(LAYOUT, 2, [64, 64], 2, gen)
    action = torch.rand(16, 2) * 2 - 1
    assert not torch.allclose(actor(obs), actor(moved))
    q = critic(obs, action)
    assert q.shape == (2, 16, 2) and not torch.allclose(q, critic(moved, action))


def test_the_actor_loss_writes_no_gradient_into_the_critics_encoder():
    from flashnav.learn.common import actor_view
    from flashnav.learn.fastdsac import update_actor
    from flashnav.learn.wall_map import encode_wall_maps
    critic = TwinCritic(LAYOUT, 2, [32], 2, torch.Generator().manual_seed(0))
    obs, action = observations(8), (torch.rand(8, 2) * 2 - 1).requires_grad_()
    critic(obs, action, detach_params=True).sum().backward()
    assert action.grad is not None and action.grad.abs().sum() > 0
    assert all(p.grad is None for p in critic.walls.parameters())
    critic(obs, action).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in critic.walls.parameters())
    state = learner("fastdsac").state  # the learner's actor step on an encoded batch: the actor trains, not the encoder
    encoded = encode_wall_maps(batch(16, seed=3), state.critic, state.critic_target)
    assert encoded.obs.requires_grad and not encoded.next_obs.requires_grad
    update_actor(state, actor_view(state, encoded))
    assert all(p.grad is None for p in state.critic.walls.parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in state.actor.mlp.parameters())


def test_a_run_with_the_wall_map_trains_saves_and_exports_what_it_reads(tmp_path):
    from flashnav import train
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.export import load_policy
    from flashnav.learn.artefacts import save_run
    from flashnav.sim.wall_grid import HIT_BEYOND_M
    from tests.test_train import TINY, tiny

    result = train(tiny(overrides={**TINY, "robot.observation.wall_map": 6, "algo.mirror": 0.5}), keep_replay=True)
    assert result.spec.robot.observation.wall_map == 6 and result.learner.state.actor.walls is not None
    bits = result.replay.obs_bits  # the replay keeps the 72 squares as uint8, the walls the runs saw among them
    assert bits.dtype == torch.uint8 and bits.shape[-1] == 72 and result.replay.obs.shape[-1] == 34
    assert set(bits[: result.replay.size // result.replay.num_envs].unique().tolist()) == {0, 1}
    out = save_run(result, tmp_path / "run")
    policy, meta = load_policy(out / "policy.onnx")
    wm = meta["observation"]["wall_map"]
    assert (wm["cells"], wm["cell_m"], wm["grid_m"], wm["beyond_m"]) == (6, 0.5, 0.25, HIT_BEYOND_M)
    assert wm["columns"] == [34, 34 + 72] and meta["obs_dim"] == 34 + 72
    assert meta["observation"]["memory_scan"]["columns"] == [34, 34]
    torch_policy, _ = load_policy(out / "policy.pt")
    obs = sample_observations(result.spec.robot, 5, torch.Generator().manual_seed(0), 14.0)
    torch.testing.assert_close(torch.as_tensor(policy(obs)), torch_policy(obs), atol=1e-5, rtol=0)
    rt = PolicyRuntime.load(out / "policy.onnx")
    assert (rt.wall_map, rt.wall_cell, rt.wall_grid, rt.wall_beyond) == (6, 0.5, 0.25, HIT_BEYOND_M)
    sectors, pose, goal, vel = np.full(30, 2.0, np.float32), (0.0, 0.0, 0.0), (1.0, 0.0), (0.0, 0.0)
    assert rt.observation(sectors, pose, goal, vel, wall_map=np.zeros(72)).shape == (106,)
    for bad, said in ((None, "got None"), (np.zeros(71), "got 71"), (np.full(72, 0.5), "got not 0 / 1")):
        with pytest.raises(ValueError, match=f"wall_map must be 72 squares of 0 or 1 .*{said}"):
            rt.observation(sectors, pose, goal, vel, wall_map=bad)


def test_the_robot_wall_image_is_the_simulators():
    """numpy's wall image (the robot's) against the simulator's torch one, on random points, poses and goals."""
    from flashnav.deploy.memory import wall_image as robot_image
    from flashnav.sim.wall_image import wall_image

    rng = np.random.default_rng(2)
    for cells, cell in ((24, 0.5), (7, 0.3)):
        pts = rng.uniform(-6, 6, (5, 300, 2))
        pts[:, :20] = np.inf  # no hit
        pose = np.concatenate([rng.uniform(-1, 1, (5, 2)), rng.uniform(-np.pi, np.pi, (5, 1))], 1)
        goal = rng.uniform(-9, 9, (5, 2))
        been = np.random.default_rng(cells).uniform(-3, 3, (5, 40, 2))  # its own draws: the walls' are as before
        been[:, :5] = np.inf  # none
        want = wall_image(*(torch.from_numpy(v) for v in (pts, pose, goal)), cells, cell).numpy()
        want3 = wall_image(*(torch.from_numpy(v) for v in (pts, pose, goal)), cells, cell,
                           visited=torch.from_numpy(been)).numpy()
        for k in range(5):
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # the points at infinity are dropped, not turned into nan
                got = robot_image(pts[k], pose[k], goal[k], cells, cell)
                got3 = robot_image(pts[k], pose[k], goal[k], cells, cell, visited=been[k])
            np.testing.assert_array_equal(got, want[k])
            np.testing.assert_array_equal(got3, want3[k])
        assert want[:, 0].sum() > 30 and want3[:, 2].sum() > 10
        np.testing.assert_array_equal(want3[:, :2], want)


@pytest.mark.parametrize("channel", [None, "visited", "plan"])
def test_the_deploy_controller_rebuilds_the_envs_wall_map_from_odometry_and_scans(tmp_path, channel):
    """A simulated episode stream fed to the Controller as a robot would (odometry, scans, a goal per episode):
    every control step's observation equals the env's, the wall map included (the robot's grid starts at the
    odometry origin, the bundled map's at the same point; with the visited channel, where the robot has been; with
    the plan's, the plan on the robot's own marks), through new goals."""
    from test_export import random_actor

    from flashnav.deploy.controller import Controller
    from flashnav.deploy.runtime import PolicyRuntime
    from flashnav.deploy.scan import simulator_scan_fields
    from flashnav.export import export_policy
    from flashnav.sim.env import make_env

    visited = channel == "visited"
    preset = load_robot("turtlebot2", **{"observation.wall_map": 12, "observation.wall_map_visited": visited,
                                         "observation.wall_map_plan": channel == "plan"})
    paths = export_policy(random_actor(preset, seed=3), preset, tmp_path)
    ctl = Controller(PolicyRuntime.load(paths["onnx"]), timeout=1.0)
    assert ctl.rt.wall_channels == (3 if channel else 2) and (ctl.walls.visited is not None) == visited
    assert ctl.walls.plan == (channel == "plan")
    env = make_env(preset, 1, seed=4)
    env.reset(seed=4)
    assert env.frame_map.origin == (0.0, 0.0)
    scan = simulator_scan_fields(preset.lidar)
    t, dt, end, goals, walls, differ, been = 0.0, preset.episode.dt, preset.memory_end, 1, 0, 0, 0
    planned = same_plan = steps = 0
    ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
    for _ in range(150):
        ctl.on_odom(*env.world_pose()[0].tolist(), now=t)
        command = ctl.on_scan(ranges=env.scan()[0].numpy(), stamp=t, now=t, **scan)
        if command is None or command.state != "driving":
            break
        want = env.obs[0].numpy()
        np.testing.assert_allclose(ctl.last_obs[:end], want[:end], rtol=0, atol=1e-3)
        differ += int((ctl.last_obs[end:] != want[end:]).sum())
        walls += int(want[end: end + 144].sum())
        been += int(want[end + 288:].sum())
        if visited:  # where the robot has been: from odometry, exactly the env's squares
            np.testing.assert_array_equal(ctl.last_obs[end + 288:], want[end + 288:])
        steps += 1
        if channel == "plan":  # the same plan unless a wall's hit fell in another cell (or the map's edge clips it)
            same_plan += int(np.array_equal(ctl.last_obs[end + 288:], want[end + 288:]))
            planned += int(want[end + 288:].sum() > 0)
        _, _, terminated, truncated, _ = env.step(torch.tensor([ctl.last_action]))
        t += dt
        if bool(terminated[0] | truncated[0]):
            ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
            goals += 1
    assert walls > 3000 and goals >= 2 and differ <= 0.002 * walls  # (a hit on a cell's edge in float32 / 64)
    assert len(want) == end + (3 if channel else 2) * 144 and (been > 300 if channel else been == 0)
    if channel == "plan":
        assert planned == steps and same_plan >= 0.95 * steps


def test_bench_sim_times_the_wall_map_beside_the_static_step(tmp_path, capsys):
    import json

    from flashnav.cli import main

    out = tmp_path / "sim.json"
    assert main(["bench", "sim", "--quick", "--raycasters", "exact", "--wall-map", "8", "--visited", "--plan",
                 "--plan-penalty", "2", "--no-irsim", "--max-steps", "4", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["raycaster"], r["wall_map"], r["visited"], r["plan"], r["plan_penalty"]) for r in rows] == [
        ("exact", 0, False, False, 0), ("exact", 8, False, False, 0), ("exact", 8, True, False, 0),
        ("exact", 8, False, True, 0), ("exact", 8, False, True, 2)]
    assert all(r["steps"] >= 2 and r["env_steps_per_s"] > 0 for r in rows)
    printed = capsys.readouterr().out
    assert "wall map" in printed and "8+v" in printed and "8+p" in printed and "8+p2" in printed
    assert main(["bench", "sim", "--quick", "--visited", "--no-irsim"]) == 2
    assert "--visited times the wall map's visited channel: it needs --wall-map C" in capsys.readouterr().err
    assert main(["bench", "sim", "--quick", "--plan", "--no-irsim"]) == 2
    assert "--plan times the wall map's plan channel: it needs --wall-map C" in capsys.readouterr().err
    assert main(["bench", "sim", "--quick", "--wall-map", "8", "--plan-penalty", "2", "--no-irsim"]) == 2
    assert "--plan-penalty 2 prices the plan channel's cells: it needs --plan" in capsys.readouterr().err
    assert main(["bench", "sim", "--quick", "--wall-map", "1", "--no-irsim"]) == 2
    assert "--wall-map must be 0 (none) or at least 2 squares a side, got 1" in " ".join(capsys.readouterr().err.split())


def test_bench_update_times_the_wall_map_beside_each_way(tmp_path, capsys):
    import json

    from flashnav.cli import main

    out = tmp_path / "update.json"
    assert main(["bench", "update", "--ways", "eager", "--seconds", "0.05", "--warmup", "1", "--device", "cpu",
                 "--wall-map", "6", "--json", str(out), "batch_size=16"]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["way"], r["wall_map"]) for r in rows] == [("eager", 0), ("eager", 6)]
    assert all(r["updates"] >= 1 and r["ms_per_update"] > 0 for r in rows)
    assert "x no map" in capsys.readouterr().out
    assert main(["bench", "update", "--device", "cpu", "--wall-map", "1"]) == 2
    assert "--wall-map must be 0 (none) or at least 2 squares a side, got 1" in " ".join(capsys.readouterr().err.split())


def test_the_metadata_reader_names_a_bad_wall_map_record():
    from flashnav.export import policy_metadata
    from flashnav.policy_meta import wall_map_shape

    assert wall_map_shape(policy_metadata(load_robot("turtlebot2"))) == (0, 0.0, 0.0, 0.0)
    assert wall_map_shape({"obs_dim": 34}) == (0, 0.0, 0.0, 0.0)  # a file from before the wall map
    meta = policy_metadata(PRESET)
    assert wall_map_shape(meta)[:3] == (CELLS, 0.5, 0.25)
    for field, value, said in (("cell_m", 0, "cell_m 0; expected a finite number > 0"),
                               ("beyond_m", -1.0, "beyond_m -1.0; expected a finite number >= 0"),
                               ("grid_m", "x", "grid_m 'x'"), ("cells", 2.5, "wall_map 2.5; expected an integer")):
        bad = {**meta, "observation": {**meta["observation"], "wall_map": {**meta["observation"]["wall_map"],
                                                                           field: value}}}
        with pytest.raises(ValueError, match=f"policy.onnx: .*{said}"):
            wall_map_shape(bad, "policy.onnx")
