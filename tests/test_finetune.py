"""Fine-tuning (issue 15, item 5): ``init_from`` resumes the exact learner state of a checkpoint, keeps
the checkpoint's goal-distance scale, and refuses a run whose networks would differ, naming the key."""

from __future__ import annotations

import math

import pytest
import torch
import yaml

from flashnav.checkpoint import load_checkpoint, save_checkpoint
from flashnav.learn.loop import run_learner
from flashnav.learn.replay import Transition
from flashnav.names import ALGORITHMS
from flashnav.spec import RunSpec, TrainConfig, resolve

#: small networks and batches: the tests are about state, not learning
SMALL = {"algo.actor_hidden": [24, 24], "algo.critic_hidden": [24, 24], "algo.num_envs": 8, "algo.batch_size": 16}


def config(algorithm="fastdsac", seed=0, init_from=None, map=None, **overrides) -> TrainConfig:  # noqa: A002
    return TrainConfig(algorithm=algorithm, device="cpu", recipe="cpu", seed=seed, init_from=init_from, map=map,
                       overrides={**SMALL, **overrides})


def batch(spec: RunSpec, seed: int, b: int = 16) -> Transition:
    """Observations in the robot's ranges (LiDAR, goal distance and angle, velocities), random actions."""
    gen = torch.Generator().manual_seed(seed)
    robot = spec.robot

    def obs():
        lidar = 0.2 + (robot.lidar.max_range - 0.2) * torch.rand(b, robot.lidar.sectors, generator=gen)
        rest = torch.rand(b, 4, generator=gen) * torch.tensor([5.0, 2 * math.pi, 0.5, 1.5]) - torch.tensor(
            [0.0, math.pi, 0.0, 0.75])
        return torch.cat([lidar, rest], 1)

    return Transition(obs(), torch.rand(b, 2, generator=gen) * 2 - 1, torch.randn(b, generator=gen),
                      (torch.rand(b, generator=gen) >= 0.2).float(), obs())   # bootstrap


def trained_checkpoint(tmp_path, algorithm="fastdsac", updates=5, **overrides):
    """A learner after some updates (non-trivial optimiser moments, temperature, running statistics)
    and the run folder its checkpoint is saved to."""
    spec = resolve(config(algorithm, seed=3, **overrides))
    learner = run_learner(spec, "cpu")
    for i in range(updates):
        learner.update(batch(spec, i))
    learner.on_episode_end(torch.arange(spec.hparams.num_envs) % 2 == 0)
    run = tmp_path / "run"
    save_checkpoint(run / "checkpoint.pt", learner.state_dict(), spec.to_dict(), {"saved_at": "2026-11-24T10:00:00"})
    return learner, spec, run


def assert_same(a, b, where="state"):
    """Recursive bit-for-bit equality of two state dicts (tensors: dtype, shape and every bit)."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape, where
        assert torch.equal(a, b), f"{where} differs"
    elif isinstance(a, dict):
        assert set(a) == set(b), f"{where}: keys {sorted(map(str, a))} vs {sorted(map(str, b))}"
        for key in a:
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}"


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_fine_tuning_resumes_the_exact_learner_state(tmp_path, algorithm):
    original, _, run = trained_checkpoint(tmp_path, algorithm, **{"algo.obs_norm": True})
    # another seed and map: neither changes the learner state that is loaded
    spec = resolve(config(algorithm, seed=11, init_from=str(run), map="go2", **{"algo.obs_norm": True}))
    tuned = run_learner(spec, "cpu")
    assert_same(tuned.state_dict(), load_checkpoint(run / "checkpoint.pt")["learner"])
    assert tuned.num_updates == original.num_updates == 5
    # one update from there equals one update of the original learner, continued
    metrics_a, metrics_b = original.update(batch(spec, 99)), tuned.update(batch(spec, 99))
    assert_same(metrics_a, metrics_b, "metrics")
    assert_same(original.state_dict(), tuned.state_dict())
    obs = batch(spec, 5, spec.hparams.num_envs).obs
    assert torch.equal(original.act(obs), tuned.act(obs))


def test_this_runs_optimiser_settings_and_env_count_apply(tmp_path):
    original, _, run = trained_checkpoint(tmp_path)
    saved = load_checkpoint(run / "checkpoint.pt")["learner"]
    spec = resolve(config(init_from=str(run), **{"algo.actor_lr": 1e-5, "algo.num_envs": 5,
                                                 "algo.target_entropy_ratio": 1.0}))
    tuned = run_learner(spec, "cpu")
    state = tuned.state_dict()
    assert [g["lr"] for g in tuned.state.actor_opt.param_groups] == [1e-5]
    assert tuned.state.algo.temperature.target_entropy == -2.0 != saved["algo"]["temperature"]["target_entropy"]
    assert [g["lr"] for g in tuned.state.critic_opt.param_groups] == [spec.hparams.critic_lr]
    assert_same(state["actor_opt"]["state"], saved["actor_opt"]["state"], "Adam moments")
    assert state["algo"]["dem_scale"].shape == (5, 1)  # drawn for this run's 5 envs
    del state["algo"]["dem_scale"], saved["algo"]["dem_scale"]
    del state["algo"]["temperature"]["target_entropy"], saved["algo"]["temperature"]["target_entropy"]
    for key in ("actor_opt", "critic_opt"):
        for group in (state[key]["param_groups"] + saved[key]["param_groups"]):
            group.pop("lr")
    assert_same(state, saved)


@pytest.mark.parametrize(("overrides", "key"), [
    ({"algo.actor_hidden": [24, 24, 24]}, "algo.actor_hidden"),
    ({"algo.critic_hidden": [32, 24]}, "algo.critic_hidden"),
    ({"algo.layer_norm": True}, "algo.layer_norm"),
    ({"algo.obs_norm": True}, "algo.obs_norm"),
    ({"algo.policy_averaging": 0.01}, "algo.policy_averaging"),
    ({"algo.goal_sincos": False}, "algo.goal_sincos"),           # the cpu recipe's TurtleBot2 values: true, 1.1
    ({"algo.action_headroom": 1.0}, "algo.action_headroom"),
    ({"robot.lidar.sectors": 36}, "robot.lidar.sectors"),
    ({"robot.lidar.max_range": 12.0}, "robot.lidar.max_range"),
    ({"robot.footprint.radius": 0.25}, "robot.footprint"),
    ({"robot.motion.v_bounds": [0.0, 0.7]}, "robot.motion.v_bounds"),
    ({"robot.observation.scan_history": 2}, "robot.observation.scan_history"),
    ({"robot.observation.wall_map": 4}, "robot.observation.wall_map"),
    ({"robot.observation.wall_map": 4, "robot.observation.wall_map_visited": True},
     "robot.observation.wall_map_visited"),
    ({"robot.observation.wall_map": 4, "algo.wall_map_convs": [[8, 2]]}, "algo.wall_map_convs"),
])
def test_a_network_mismatch_is_refused_by_name(tmp_path, overrides, key):
    _, _, run = trained_checkpoint(tmp_path, updates=1)
    with pytest.raises(ValueError, match=rf"init_from .*{key.replace('.', '[.]')}[^:;]*: checkpoint"):
        resolve(config(init_from=str(run), **overrides))


def test_the_wall_maps_cnn_must_match_where_a_map_is_read(tmp_path):
    wall = {"robot.observation.wall_map": 4, "algo.wall_map_convs": [[8, 1], [8, 2]]}
    _, _, run = trained_checkpoint(tmp_path, updates=1, **wall)
    with pytest.raises(ValueError, match=r"networks do not match the checkpoint's .*: "
                                         r"algo[.]wall_map_convs: checkpoint \(\(8, 1\), \(8, 2\)\), "
                                         r"this run \(\(8, 2\),\) \(set them"):
        resolve(config(init_from=str(run), **{**wall, "algo.wall_map_convs": [[8, 2]]}))
    assert resolve(config(init_from=str(run), **wall)).init is not None  # the same layers: accepted
    _, _, plain = trained_checkpoint(tmp_path / "plain", updates=1)  # no map: the CNN's layers are not compared
    assert resolve(config(init_from=str(plain), **{"algo.wall_map_convs": [[8, 2]]})).init is not None


def test_another_algorithm_or_robot_is_refused_by_name(tmp_path):
    _, _, run = trained_checkpoint(tmp_path, updates=1)
    with pytest.raises(ValueError, match=r"algorithm: checkpoint 'fastdsac', this run 'fasttd3'.*"
                                         r"\(train with --algo fastdsac as the checkpoint's run did\)"):
        resolve(config("fasttd3", init_from=str(run)))
    with pytest.raises(ValueError, match=r"robot.motion.velocity_state_dims: checkpoint 2, this run 3.*"
                                         r"\(train with --robot turtlebot2 as the checkpoint's run did\)"):
        resolve(config(init_from=str(run)).model_copy(update={"robot": "go2"}))


def test_the_goal_distance_scale_is_the_checkpoints(tmp_path):
    _, source, run = trained_checkpoint(tmp_path, updates=1)
    assert source.goal_distance_max == pytest.approx(math.hypot(10.0, 10.0))  # the bundled 10 x 10 m map
    spec = resolve(config(init_from=str(run), map="go2"))  # a larger map: its own diagonal is not used
    assert spec.grid.diagonal_m > source.goal_distance_max
    assert spec.goal_distance_max == source.goal_distance_max
    actor = run_learner(spec, "cpu").state.actor
    assert float(1.0 / actor.transform.inv_scale[0]) == pytest.approx(source.goal_distance_max)
    # a checkpoint whose scale is below this run's goal band (straight line up to 5 m) is refused
    payload = load_checkpoint(run / "checkpoint.pt")
    payload["config"]["goal_distance_max"] = 4.5
    save_checkpoint(tmp_path / "small.pt", payload["learner"], payload["config"])
    with pytest.raises(ValueError, match=r"start up to 5 m from their goal .*beyond the 4.5 m goal-distance scale"):
        resolve(config(init_from=str(tmp_path / "small.pt")))
    spec = resolve(config(init_from=str(tmp_path / "small.pt"), **{"robot.episode.max_goal_distance": 4.0}))
    assert spec.goal_distance_max == 4.5


def test_the_run_config_records_the_init_source_and_reads_back(tmp_path):
    _, _, run = trained_checkpoint(tmp_path, updates=1)
    spec = resolve(config(seed=5, init_from=str(run / "checkpoint.pt")))
    data = yaml.safe_load(yaml.safe_dump(spec.to_dict()))  # what config.yaml holds
    assert data["init_from"] == str(run / "checkpoint.pt")
    assert data["init_source"] == {
        "path": str((run / "checkpoint.pt").resolve()), "seed": 3, "algorithm": "fastdsac", "robot": "turtlebot2",
        "recipe": "cpu", "goal_distance_max": pytest.approx(math.hypot(10, 10)), "saved_at": "2026-11-24T10:00:00",
        "saved_at_source": "checkpoint", "flashnav_version": data["init_source"]["flashnav_version"]}
    back = RunSpec.from_dict(data)
    assert back.init == spec.init and back.goal_distance_max == spec.goal_distance_max
    assert_same(run_learner(back, "cpu").state_dict(), run_learner(spec, "cpu").state_dict())  # re-read


def test_a_missing_source_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such run folder or checkpoint file"):
        resolve(config(init_from=str(tmp_path / "nothing")))
    with pytest.raises(FileNotFoundError, match="a folder without checkpoint.pt"):
        resolve(config(init_from=str(tmp_path)))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable FlashNav checkpoint"):
        resolve(config(init_from=str(tmp_path / "junk.pt")))
