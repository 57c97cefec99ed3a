"""Deployable policies (TorchScript / ONNX), checkpoints, and the ``flashnav eval`` / ``render`` commands."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest
import torch

from flashnav.checkpoint import CHECKPOINT_FORMAT_VERSION, load_checkpoint, save_checkpoint
from flashnav.export import DeployablePolicy, export_policy, load_policy, recorded_robot
from flashnav.observation_samples import sample_observations
from flashnav.learn.networks import Actor, DeterministicActor, ObsLayout
from flashnav.presets import load_robot
from flashnav.sim.motion import action_to_velocity

HIDDEN = (64, 64)


def random_actor(preset, seed: int = 0, heads: int = 3, layer_norm: bool = False, obs_norm: bool = False,
                 goal_sincos: bool = False, headroom: float = 1.0) -> Actor:
    """An actor with random weights; the output layer is re-drawn with a large std so that actions
    cover [-1, 1] (at the training init they sit near 0 and would test little)."""
    import dataclasses

    gen = torch.Generator().manual_seed(seed)
    layout = dataclasses.replace(ObsLayout.from_robot(preset, math.hypot(*preset.map_size)), goal_sincos=goal_sincos)
    actor = Actor(layout, 2, HIDDEN, heads, gen, layer_norm, obs_norm, headroom=headroom)
    with torch.no_grad():
        actor.mlp.net[-1].weight.normal_(0.0, 1.0, generator=gen)
    return actor


def observations(preset, n: int, seed: int = 1) -> torch.Tensor:
    """[n, D] valid observations; the first rows read exactly the inscribed radius / the max range
    on every sector (the two ends of the IPAPRec input range)."""
    obs = sample_observations(preset, n, torch.Generator().manual_seed(seed))
    s = preset.lidar.sectors
    obs[0, :s] = preset.footprint.inscribed_radius
    if n > 1:
        obs[1, :s] = preset.lidar.max_range
    return obs


@pytest.fixture(scope="module")
def tb2():
    return load_robot("turtlebot2")


@pytest.fixture(scope="module")
def exported(tb2, tmp_path_factory):
    """(eager DeployablePolicy, paths) for one random TurtleBot2 actor."""
    actor = random_actor(tb2)
    paths = export_policy(actor, tb2, tmp_path_factory.mktemp("policy"))
    eager = DeployablePolicy(actor, tb2).eval()
    return eager, paths


# ---- the deployable module -----------------------------------------------------------------------
@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_command_is_action_to_velocity(robot):
    preset = load_robot(robot)
    actor = random_actor(preset)
    policy = DeployablePolicy(actor, preset)
    obs = observations(preset, 257)
    with torch.no_grad():
        action, command = policy(obs)
        expected = DeterministicActor(actor)(obs)
    assert action.shape == command.shape == (257, 2)
    torch.testing.assert_close(action, expected, rtol=0, atol=0)
    assert float(action.abs().max()) <= 1.0 and float(action.abs().max()) > 0.5  # spans the range
    v, w = action_to_velocity(action, preset.motion)
    torch.testing.assert_close(command, torch.stack([v, w], dim=1), rtol=0, atol=1e-7)
    # out-of-range actions are clamped exactly as the simulator clamps them
    wild = torch.tensor([[-3.0, 3.0], [2.0, -2.0], [0.0, 0.0]])
    mapped = policy.low + (wild.clamp(-1, 1) + 1.0) * policy.half_span
    torch.testing.assert_close(torch.minimum(torch.maximum(mapped, -policy.limit), policy.limit),
                               torch.stack(action_to_velocity(wild, preset.motion), dim=1))


def test_deployable_rejects_an_actor_for_another_robot(tb2):
    with pytest.raises(ValueError, match="obs_dim 34"):
        DeployablePolicy(random_actor(load_robot("go2")), tb2)


# ---- TorchScript / ONNX --------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore:`torch.jit.load` is deprecated:DeprecationWarning")
@pytest.mark.parametrize("n", [1, 257])
def test_torchscript_equals_eager(exported, tb2, n):
    eager, paths = exported
    module = torch.jit.load(str(paths["torchscript"]))
    obs = observations(tb2, n)
    with torch.no_grad():
        want, got = eager(obs), module(obs)
    for w, g in zip(want, got):
        torch.testing.assert_close(g, w, rtol=0, atol=1e-6)
    policy, meta = load_policy(paths["torchscript"])
    torch.testing.assert_close(policy(obs), want[0], rtol=0, atol=1e-6)


@pytest.mark.parametrize("n", [1, 257])
def test_onnx_equals_torch(exported, tb2, n):
    import onnxruntime as ort  # the export extra is part of the dev install: a broken one must fail

    eager, paths = exported
    session = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["obs"]
    assert [o.name for o in session.get_outputs()] == ["action", "command"]
    obs = observations(tb2, n)
    with torch.no_grad():
        action, command = eager(obs)
    onnx_action, onnx_command = session.run(None, {"obs": obs.numpy()})
    np.testing.assert_allclose(onnx_action, action.numpy(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(onnx_command, command.numpy(), rtol=0, atol=1e-5)
    v, w = action_to_velocity(torch.from_numpy(onnx_action), tb2.motion)
    np.testing.assert_allclose(onnx_command, torch.stack([v, w], 1).numpy(), rtol=0, atol=1e-6)
    policy, _ = load_policy(paths["onnx"])
    torch.testing.assert_close(policy(obs), action, rtol=0, atol=1e-5)
    for path in (paths["onnx"], paths["torchscript"]):  # numpy in (the Gymnasium envs' observations), numpy out
        got = load_policy(path)[0](obs.numpy().astype(np.float64))
        assert isinstance(got, np.ndarray) and got.dtype == np.float32
        np.testing.assert_allclose(got, action.numpy(), rtol=0, atol=1e-5)


@pytest.mark.parametrize("goal_sincos", [False, True])
def test_a_normalised_actor_exports_to_the_same_actions(tb2, tmp_path, goal_sincos):
    """Layer norm, observation normalisation and (``goal_sincos``) the goal angle's sine and cosine live inside
    the exported policy: its input stays the robot's observation."""
    import onnxruntime as ort

    actor = random_actor(tb2, seed=5, layer_norm=True, obs_norm=True, goal_sincos=goal_sincos)
    actor.transform.update_stats(observations(tb2, 200, seed=7))  # non-trivial running statistics
    paths = export_policy(actor, tb2, tmp_path)
    obs = observations(tb2, 65)
    with torch.no_grad():
        action, _ = DeployablePolicy(actor, tb2).eval()(obs)
    session = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(session.run(None, {"obs": obs.numpy()})[0], action.numpy(), rtol=0, atol=1e-5)
    scripted, _ = load_policy(paths["torchscript"])
    torch.testing.assert_close(scripted(obs), action, rtol=0, atol=1e-5)


def test_an_actor_with_action_headroom_exports_its_clamped_actions(tb2, tmp_path):
    """``algo.action_headroom`` lives inside the exported policy: clamp(k tanh(mu), -1, 1), bounds reached."""
    import onnxruntime as ort

    actor = random_actor(tb2, seed=6, headroom=1.2)
    paths = export_policy(actor, tb2, tmp_path)
    obs = observations(tb2, 65)
    with torch.no_grad():
        action, _ = DeployablePolicy(actor, tb2).eval()(obs)
        squashed = torch.tanh(actor(obs)[:, :2])
    torch.testing.assert_close(action, (1.2 * squashed).clamp(-1, 1), rtol=0, atol=0)
    assert (action.abs() == 1.0).any() and (squashed.abs() < 1.0).all()
    session = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(session.run(None, {"obs": obs.numpy()})[0], action.numpy(), rtol=0, atol=1e-5)
    scripted, _ = load_policy(paths["torchscript"])
    torch.testing.assert_close(scripted(obs), action, rtol=0, atol=1e-5)


def test_metadata(exported, tb2):
    _, paths = exported
    for kind in ("torchscript", "onnx"):
        _, meta = load_policy(paths[kind])
        assert meta["robot"] == "turtlebot2" and meta["obs_dim"] == 34 and meta["action_dim"] == 2
        assert meta["flashnav_version"]
        layout = meta["observation"]
        assert layout["lidar"]["columns"] == [0, 30] and layout["goal_distance"]["column"] == 30
        assert layout["goal_angle"]["column"] == 31 and layout["velocity"]["names"] == ["v", "w"]
        assert meta["preset"] == tb2.model_dump(mode="json")
    assert json.loads(paths["metadata"].read_text()) == meta


def test_recorded_robot_is_the_exported_preset_with_its_observation_options(tmp_path):
    """Scripts and `flashnav eval` build a policy's env from recorded_robot: a pose-trail Go2 policy gets its trail
    (the bundled preset by name would give 35 columns, not 55); files without a preset block fall back to the name."""
    go2_trail = load_robot("go2", **{"observation.pose_trail": 10})
    paths = export_policy(random_actor(go2_trail), go2_trail, tmp_path, onnx=False)
    policy, meta = load_policy(paths["torchscript"])
    robot = recorded_robot(meta)
    assert robot == go2_trail and load_robot(robot).obs_dim == 55 == meta["obs_dim"]
    assert policy(sample_observations(load_robot(robot), 4)).shape == (4, 2)
    legacy = {k: v for k, v in meta.items() if k != "preset"}
    assert recorded_robot(legacy) == "go2"


def test_load_policy_errors(exported, tmp_path):
    _, paths = exported
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        load_policy(tmp_path / "nope.pt")
    with pytest.raises(ValueError, match="expected policy.pt"):
        load_policy(tmp_path / "policy.pth")
    with pytest.raises(ValueError, match="obs_dim 34.*go2.*obs_dim 35"):
        load_policy(paths["torchscript"], robot="go2")
    policy, _ = load_policy(paths["torchscript"], robot="turtlebot2")
    with pytest.raises(ValueError, match=r"\[N, 34\]"):
        policy(torch.zeros(3, 35))


# ---- checkpoints ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def learner():
    from flashnav.learn.hparams import load_hparams
    from flashnav.learn.learners import make_learner

    preset = load_robot("turtlebot2")
    hp = load_hparams("fasttd3", "turtlebot2", "cpu", {"actor_hidden": [16], "critic_hidden": [16]})
    return make_learner("fasttd3", hp, ObsLayout.from_robot(preset, math.hypot(*preset.map_size)), 2, 4, "cpu", seed=0)


def test_checkpoint_round_trip(learner, tmp_path):
    from flashnav.spec import TrainConfig

    config = TrainConfig(seed=3)
    path = save_checkpoint(tmp_path / "ckpt" / "last.pt", learner.state_dict(), config, {"env_steps": 4096})
    payload = load_checkpoint(path)
    assert payload["format_version"] == CHECKPOINT_FORMAT_VERSION
    assert TrainConfig.model_validate(payload["config"]) == config
    assert payload["extra"] == {"env_steps": 4096}
    before = {k: v.clone() for k, v in learner.state.actor.state_dict().items()}
    with torch.no_grad():
        for p in learner.state.actor.parameters():
            p.add_(1.0)
    learner.load_state_dict(payload["learner"])
    for key, value in learner.state.actor.state_dict().items():
        torch.testing.assert_close(value, before[key], rtol=0, atol=0)
    assert not (tmp_path / "ckpt" / "last.pt.tmp").exists()


def test_checkpoint_rejects_what_it_cannot_read(tmp_path):
    path = save_checkpoint(tmp_path / "c.pt", {"w": torch.ones(2)}, {"robot": "turtlebot2"}, {})
    payload = torch.load(path, weights_only=True)
    payload["format_version"] = 99
    torch.save(payload, tmp_path / "newer.pt")
    with pytest.raises(ValueError, match=r"newer\.pt.*format_version 99.*newer FlashNav.*reads format_version 1"):
        load_checkpoint(tmp_path / "newer.pt")
    payload["format_version"] = CHECKPOINT_FORMAT_VERSION
    del payload["learner"]
    torch.save(payload, tmp_path / "partial.pt")
    with pytest.raises(ValueError, match=r"partial\.pt.*lacks learner"):
        load_checkpoint(tmp_path / "partial.pt")
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save(torch.nn.Linear(2, 2), tmp_path / "module.pt")  # a pickled object: refused, never run
    with pytest.raises(ValueError, match="not a readable FlashNav checkpoint"):
        load_checkpoint(tmp_path / "module.pt")
    with pytest.raises(TypeError, match=r"checkpoint\.extra\.when is a object"):
        save_checkpoint(tmp_path / "bad.pt", {}, {}, {"when": object()})


# ---- flashnav eval / render ----------------------------------------------------------------------
def run_cli(*argv: str) -> int:
    """The two commands through a stand-alone parser (flashnav.cli wires the same register_cli)."""
    from flashnav import policy_cli

    parser = argparse.ArgumentParser(prog="flashnav")
    policy_cli.register_cli(parser.add_subparsers(dest="command"))
    args = parser.parse_args(list(argv))
    return args.func(args)


@pytest.mark.parametrize("kind", ["torchscript", "onnx"])
def test_eval_command(exported, tmp_path, kind, capsys):
    _, paths = exported
    out = tmp_path / "eval.json"
    assert run_cli("eval", str(paths[kind]), "--episodes", "6", "--seed", "7", "--json", str(out)) == 0
    report = json.loads(out.read_text())
    assert {"success_rate", "collision_rate", "timeout_rate", "mean_return", "episodes", "robot", "map",
            "policy"} <= set(report)
    assert report["episodes"] == 6 and report["robot"] == "turtlebot2" and report["map"] == "turtlebot2"
    rates = [report[k] for k in ("success_rate", "collision_rate", "timeout_rate")]
    assert all(0.0 <= r <= 1.0 for r in rates) and sum(rates) == pytest.approx(1.0)
    assert "success rate" in capsys.readouterr().out


def test_bench_eval_compares_both_ways_on_an_exported_policy(exported, capsys):
    _, paths = exported
    from flashnav.cli import main as flashnav_main

    assert flashnav_main(["bench", "eval", str(paths["torchscript"]), "--episodes", "12", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    assert "dense" in out and "compact" in out and "same rates both ways" in out


def test_eval_refuses_a_robot_of_another_size(exported):
    _, paths = exported
    with pytest.raises(ValueError, match="obs_dim"):
        run_cli("eval", str(paths["torchscript"]), "--robot", "go2", "--episodes", "2")


def test_render_command(exported, tmp_path):
    from PIL import Image

    _, paths = exported
    png = tmp_path / "traj.png"
    assert run_cli("render", str(paths["torchscript"]), "--out", str(png), "--episodes", "4", "--gif") == 0
    with Image.open(png) as image:
        assert image.format == "PNG" and image.width > 100
    with Image.open(tmp_path / "traj.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames > 1
    assert (tmp_path / "traj.gif").stat().st_size < 1_000_000


def test_rollout_paths_end_where_the_episode_ended(exported, tb2):
    from flashnav.rollout import rollout
    from flashnav.sim.env import make_env

    _, paths = exported
    policy, _ = load_policy(paths["torchscript"])
    env = make_env(tb2, 4, seed=0)
    result = rollout(policy, env, seed=5)
    poses, length = result["poses"], result["length"]
    assert poses.shape[1:] == (4, 3) and (length >= 2).all() and len(result["outcomes"]) == 4
    for i, outcome in enumerate(result["outcomes"]):
        end = poses[length[i] - 1, i, :2]
        if outcome == "success":
            assert np.linalg.norm(end - result["goals"][i]) < tb2.episode.goal_threshold
        if outcome == "timeout":
            assert length[i] == tb2.episode.horizon + 1
