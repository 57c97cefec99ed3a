"""A scan-history policy end to end: the three learners train with it (CPU smoke), the export takes the
wider observation (ONNX = TorchScript = eager) and records scan_history, the metadata reader is
torch-free and backwards compatible, the deploy controller rebuilds the env's observations from raw
scans over an episode with resets, and eval / render / eval --scenario build the env with the history."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_export import observations, random_actor, run_cli

from flashnav.cli import main as cli_main
from flashnav.deploy.controller import Controller
from flashnav.deploy.runtime import PolicyRuntime
from flashnav.deploy.scan import simulator_scan_fields
from flashnav.export import DeployablePolicy, export_policy, load_policy, policy_metadata
from flashnav.policy_meta import scan_history_frames
from flashnav.presets import load_robot
from flashnav.sim.env import make_env

K = 3
TINY = ["algo.num_envs=16", "algo.learning_start=32", "algo.updates_per_step=1", "algo.batch_size=32",
        "algo.eval_every=2", "budget.max_env_steps=96", "eval.episodes=4", f"robot.observation.scan_history={K}"]


@pytest.fixture(scope="module")
def tb2k():
    return load_robot("turtlebot2", **{"observation.scan_history": K, "agents.count": 4})


@pytest.fixture(scope="module")
def exported_k(tb2k, tmp_path_factory):
    actor = random_actor(tb2k, seed=3)
    return actor, export_policy(actor, tb2k, tmp_path_factory.mktemp("policy_k"))


def test_export_takes_the_wider_observation_and_records_the_history(tb2k, exported_k):
    import onnxruntime as ort

    actor, paths = exported_k
    obs = observations(tb2k, 129, seed=4)
    assert obs.shape == (129, 34 + K * 30)
    obs[2, 34:] = tb2k.footprint.inscribed_radius  # the pole end of the history frames' transform
    with torch.no_grad():
        action, command = DeployablePolicy(actor, tb2k).eval()(obs)
    got_action, got_command = ort.InferenceSession(str(paths["onnx"]), providers=["CPUExecutionProvider"]).run(
        None, {"obs": obs.numpy()})
    np.testing.assert_allclose(got_action, action.numpy(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(got_command, command.numpy(), rtol=0, atol=1e-5)
    scripted, meta = load_policy(paths["torchscript"])
    torch.testing.assert_close(scripted(obs), action, rtol=0, atol=1e-6)
    # the history moves the actions: the policy reads its frames
    moved = obs.clone()
    moved[:, 34:] = torch.flip(moved[:, 34:], dims=[1])
    assert not torch.allclose(scripted(moved), action, atol=1e-4)

    assert meta["obs_dim"] == 124 and meta["observation"]["velocity"]["columns"] == [32, 34]
    assert meta["observation"]["scan_history"]["frames"] == K
    assert meta["observation"]["scan_history"]["columns"] == [34, 124]
    assert scan_history_frames(meta) == K and meta["preset"]["observation"]["scan_history"] == K
    with pytest.raises(ValueError, match="obs_dim"):
        load_policy(paths["onnx"], robot="turtlebot2")  # a robot without the history does not fit


def test_the_metadata_reader_falls_back_for_older_files_and_names_bad_values():
    meta = policy_metadata(load_robot("turtlebot2"))
    assert meta["observation"]["scan_history"] == {**meta["observation"]["scan_history"], "frames": 0}
    assert scan_history_frames(meta) == 0
    old = {k: v for k, v in meta.items() if k != "observation"}  # before the history existed
    old["preset"] = {k: v for k, v in meta["preset"].items() if k != "observation"}
    assert scan_history_frames(old) == 0
    old["preset"]["observation"] = {"scan_history": 2}  # a preset block carries it
    assert scan_history_frames(old) == 2
    meta["observation"]["scan_history"]["frames"] = -1
    with pytest.raises(ValueError, match=r"policy.onnx: .*scan_history -1"):
        scan_history_frames(meta, "policy.onnx")


def test_the_deploy_controller_rebuilds_the_envs_observations(tb2k, exported_k):
    """Raw env scans in, at the control rate; a reset mid-run (set to a new episode) and the env's own
    sparse resets both start the controller afresh through a new goal."""
    _, paths = exported_k
    ctl = Controller(PolicyRuntime.load(paths["onnx"]), timeout=1.0)
    assert ctl.rt.scan_history == K
    env = make_env(tb2k, 1, seed=8)
    env.reset(seed=8)
    scan = simulator_scan_fields(tb2k.lidar)
    t, dt, episodes, checked = 0.0, tb2k.episode.dt, 1, 0
    ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
    for step in range(120):
        if step == 25:  # a reset in the middle of an episode
            env.reset(options={"reset_mask": torch.ones(1, dtype=torch.bool)})
            ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
            episodes += 1
        ctl.on_odom(*env.world_pose()[0].tolist(), now=t)
        command = ctl.on_scan(ranges=env.scan()[0].numpy(), stamp=t, now=t, **scan)
        assert command is not None and command.state == "driving"
        np.testing.assert_allclose(ctl.last_obs, env.obs[0].numpy(), rtol=0, atol=1e-6)
        assert np.array_equal(ctl.last_obs[34:], env.obs[0, 34:].numpy())  # the frames bit for bit
        checked += 1
        _, _, terminated, truncated, _ = env.step(torch.tensor([ctl.last_action]))
        t += dt
        if bool(terminated[0] | truncated[0]):  # the env started a new episode in the same step
            ctl.on_goal(*env.world_goal()[0].tolist(), now=t)
            episodes += 1
    assert episodes >= 3 and checked == 120


def test_a_history_policy_needs_its_frames():
    rt = PolicyRuntime(None, policy_metadata(load_robot("turtlebot2", **{"observation.scan_history": 2})))
    sectors = np.full(30, 2.0, np.float32)
    with pytest.raises(ValueError, match=r"history must be \[2, 30\].*got None"):
        rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0))
    with pytest.raises(ValueError, match=r"history must be \[2, 30\].*got \[1, 30\]"):
        rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0), np.ones((1, 30)))
    obs = rt.observation(sectors, (0, 0, 0), (1, 1), (0, 0), np.stack([sectors + 1, sectors + 2]))
    assert obs.shape == (94,) and obs[34] == 3.0 and obs[64] == 4.0


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """(algorithm -> run folder) of three tiny CPU trainings with a 3-frame history."""
    runs = {}
    for algo in ("fastdsac", "fastsac", "fasttd3"):
        out = tmp_path_factory.mktemp(algo)
        assert cli_main(["train", "--recipe", "cpu", "--device", "cpu", "--algo", algo, "--out", str(out), *TINY]) == 0
        runs[algo] = out
    return runs


@pytest.mark.parametrize("algo", ["fastdsac", "fastsac", "fasttd3"])
def test_each_learner_trains_and_exports_with_a_history(trained, algo):
    out = trained[algo]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["env_steps"] == 96
    policy, meta = load_policy(out / "policy.onnx")
    assert meta["obs_dim"] == 124 and scan_history_frames(meta) == K
    action = policy(observations(load_robot("turtlebot2", **{"observation.scan_history": K}), 8))
    assert action.shape == (8, 2) and bool(torch.isfinite(action).all())


def test_eval_render_and_scenarios_build_the_env_with_the_history(trained, tmp_path):
    policy = str(trained["fastdsac"] / "policy.pt")
    assert run_cli("eval", policy, "--episodes", "4", "--json", str(tmp_path / "e.json")) == 0
    assert json.loads((tmp_path / "e.json").read_text())["episodes"] == 4
    assert run_cli("eval", policy, "--scenario", "wander-4", "--episodes", "4", "--json", str(tmp_path / "s.json")) == 0
    assert run_cli("render", policy, "--out", str(tmp_path / "r.png"), "--episodes", "2") == 0
    assert run_cli("render", policy, "--scenario", "wander-4", "--out", str(tmp_path / "s.png"), "--episodes", "2") == 0
    assert (tmp_path / "r.png").stat().st_size > 0 and (tmp_path / "s.png").stat().st_size > 0
