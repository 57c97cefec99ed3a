"""scripts/stochastic_maps.py: a FastDSAC run's final learner played per map with its deterministic actor and with
actions sampled from its own tanh-Gaussian (issue 15, done-means 2)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import stochastic_maps  # noqa: E402

from flashnav.checkpoint import save_checkpoint  # noqa: E402
from flashnav.learn.loop import run_learner  # noqa: E402
from flashnav.learn.networks import DeterministicActor  # noqa: E402
from flashnav.maps import generate_map, save_ros_map  # noqa: E402
from flashnav.spec import TrainConfig, resolve  # noqa: E402

SMALL = {"algo.actor_hidden": [24, 24], "algo.critic_hidden": [24, 24], "algo.num_envs": 8, "algo.batch_size": 16}


def small_run(tmp_path, algorithm="fastdsac", **overrides):
    spec = resolve(TrainConfig(algorithm=algorithm, device="cpu", recipe="cpu", seed=1, overrides={**SMALL, **overrides}))
    learner = run_learner(spec, "cpu")
    run = tmp_path / "run"
    save_checkpoint(run / "checkpoint.pt", learner.state_dict(), spec.to_dict(), {"saved_at": "2026-11-30T16:00:00"})
    (run / "config.yaml").write_text(yaml.safe_dump(spec.to_dict()))
    return learner, spec, run


@pytest.mark.parametrize("headroom", [1.0, 1.1])
def test_a_vanishing_spread_is_the_deterministic_actor_and_a_wide_one_is_not(tmp_path, headroom):
    learner, spec, _ = small_run(tmp_path, **{"algo.action_headroom": headroom})
    actor, hp = learner.state.actor, learner.state.hp
    obs = torch.randn(64, spec.robot.obs_dim).abs()
    with torch.no_grad():
        det = DeterministicActor(actor)(obs)
        assert torch.allclose(stochastic_maps.sampled(actor, hp, 1e-6, 0)(obs), det, atol=1e-4)
        wide = stochastic_maps.sampled(actor, hp, 1.0, 0)(obs)
        assert (wide - det).abs().max() > 0.05 and wide.abs().max() <= 1.0
        # its own generator: the same seed draws the same actions, another seed others
        assert torch.equal(stochastic_maps.sampled(actor, hp, 1.0, 0)(obs), wide)
        assert not torch.equal(stochastic_maps.sampled(actor, hp, 1.0, 1)(obs), wide)


def test_the_script_writes_one_rate_per_arm_and_map(tmp_path, monkeypatch):
    _, _, run = small_run(tmp_path)
    maps = tmp_path / "maps"
    for seed in (4, 5):
        save_ros_map(generate_map(6.0, 6.0, 0.05, seed=seed, robot_radius=0.3, name=f"small_{seed}"),
                     maps / f"small_{seed}.yaml")
    out = tmp_path / "sampled.json"
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(run), "--maps", str(maps), "--only", "small_5",
                                      "--scales", "1,0.5", "--episodes", "4", "--json", str(out)])
    stochastic_maps.main()
    result = json.loads(out.read_text())
    assert list(result["success"]) == ["deterministic", "sampled x1", "sampled x0.5"]
    for rates in result["success"].values():
        assert list(rates) == ["small_5"] and 0.0 <= rates["small_5"] <= 1.0


def test_the_script_refuses_a_bad_scale_and_another_learner(tmp_path, monkeypatch):
    _, _, run = small_run(tmp_path)
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(run), "--scales", "1,0"])
    with pytest.raises(SystemExit, match="every scale must be > 0"):
        stochastic_maps.main()
    _, _, td3 = small_run(tmp_path / "td3", algorithm="fasttd3")
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(td3)])
    with pytest.raises(SystemExit, match="a fasttd3 run"):
        stochastic_maps.main()
