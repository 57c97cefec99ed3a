"""scripts/stochastic_maps.py: a FastDSAC run's final learner played per map with its deterministic actor and with
actions sampled from its own tanh-Gaussian (issue 15, done-means 2)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import stochastic_maps  # noqa: E402

from flashnav.checkpoint import save_checkpoint  # noqa: E402
from flashnav.cli import main as cli_main  # noqa: E402
from flashnav.export import export_policy  # noqa: E402
from flashnav.learn.networks import DeterministicActor  # noqa: E402
from flashnav.maps import generate_map, save_ros_map  # noqa: E402
from flashnav.yamlio import dump_yaml  # noqa: E402
from test_finetune import trained_checkpoint  # noqa: E402


def small_run(tmp_path, algorithm="fastdsac", **overrides):
    """A small learner after a few updates, its checkpoint and the run's config.yaml: a run folder."""
    learner, spec, run = trained_checkpoint(tmp_path, algorithm, **overrides)
    dump_yaml(spec.to_dict(), run / "config.yaml")
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
        assert (wide - det).abs().max() > 0.05
        # its own generator: the same seed draws the same actions, another seed others
        assert torch.equal(stochastic_maps.sampled(actor, hp, 1.0, 0)(obs), wide)
        assert not torch.equal(stochastic_maps.sampled(actor, hp, 1.0, 1)(obs), wide)


def test_the_deterministic_arm_plays_flashnav_evals_episodes_and_the_json_holds_every_arm(tmp_path, monkeypatch):
    """The deterministic arm is `flashnav eval --maps` of the same learner's exported policy, episode by episode
    (the same fixed episodes, goal scale and actions); every sampled arm gets one rate and outcome string per map."""
    learner, spec, run = small_run(tmp_path)
    with torch.no_grad():  # a robot that creeps (mean speed command tanh(-1)), turning a little with what it sees:
        last = [m for m in learner.state.actor.modules() if isinstance(m, torch.nn.Linear)][-1]   # some episodes
        last.weight.mul_(0.05)                                                           # end in a wall, some in time
        last.bias.zero_()
        last.bias[0] = -1.0
    save_checkpoint(run / "checkpoint.pt", learner.state_dict(), spec.to_dict(), {"saved_at": "2026-11-30T16:00:00"})
    export_policy(learner.state.actor, spec.robot, run, onnx=False)
    maps = tmp_path / "maps"
    for seed in (4, 5, 6):
        save_ros_map(generate_map(6.0, 6.0, 0.05, seed=seed, robot_radius=0.3, name=f"small_{seed}"),
                     maps / f"small_{seed}.yaml")
    evaluated = tmp_path / "eval.json"
    assert cli_main(["eval", str(run / "policy.pt"), "--maps", str(maps), "--episodes", "16", "--json",
                     str(evaluated)]) == 0
    expected = {m["map"]: m["outcomes"] for m in json.loads(evaluated.read_text())["maps"]}
    assert len(set("".join(expected.values()))) > 1      # more than one kind of ending: the comparison can tell
    out = tmp_path / "sampled.json"
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(run), "--maps", str(maps), "--scales", "1,0.5",
                                      "--episodes", "16", "--sample-seed", "3", "--json", str(out)])
    stochastic_maps.main()
    result = json.loads(out.read_text())
    assert result["outcomes"]["deterministic"] == expected
    assert list(result["success"]) == ["deterministic", "sampled x1", "sampled x0.5"] and result["sample_seed"] == 3
    for name, rates in result["success"].items():
        assert list(rates) == sorted(expected)
        for label, rate in rates.items():
            letters = result["outcomes"][name][label]
            assert len(letters) == 16 and rate == letters.count("s") / 16
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(run), "--maps", str(maps), "--only", "small_5",
                                      "--scales", "", "--episodes", "16", "--json", str(out)])
    stochastic_maps.main()
    assert json.loads(out.read_text())["outcomes"] == {"deterministic": {"small_5": expected["small_5"]}}


@pytest.mark.parametrize("scales, message", [("1,0", "must be a finite number > 0, got 0"),
                                             ("nan", "must be a finite number > 0, got nan"),
                                             ("1,abc", "'abc' is not a number")])
def test_the_script_names_a_bad_scale(scales, message, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", "any_run", "--scales", scales])
    with pytest.raises(SystemExit, match=message):
        stochastic_maps.main()


def test_the_script_refuses_a_folder_without_a_run_and_another_learner(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(tmp_path)])
    with pytest.raises(SystemExit, match="no config.yaml"):
        stochastic_maps.main()
    _, _, td3 = small_run(tmp_path / "td3", algorithm="fasttd3")
    monkeypatch.setattr(sys, "argv", ["stochastic_maps.py", str(td3)])
    with pytest.raises(SystemExit, match="a fasttd3 run"):
        stochastic_maps.main()
