"""scripts/ensemble_eval.py: the mean action of several policies on the agent scenarios (issue 13 probe) and on a
map suite (issue 15 probe)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

from flashnav.cli import main as flashnav_main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import ensemble_eval as ens  # noqa: E402

POLICY = str(Path(__file__).resolve().parent / "fixtures" / "deploy_policy" / "policy.onnx")


def test_the_mean_action_is_the_members_mean():
    a, b = (lambda o: torch.full((o.shape[0], 2), 0.6)), (lambda o: torch.full((o.shape[0], 2), -0.2))
    assert torch.allclose(ens.mean_policy([a, b])(torch.zeros(3, 5)), torch.full((3, 2), 0.2))
    with pytest.raises(ValueError, match="at least one member"):
        ens.mean_policy([])


def test_the_medoid_action_is_the_member_nearest_the_others_row_by_row():
    acts = [torch.tensor([[1.0, 0.0], [0.0, 0.0]]), torch.tensor([[0.9, 0.1], [0.0, 1.0]]),
            torch.tensor([[-1.0, 0.0], [0.0, 0.9]])]
    members = [lambda o, a=a: a for a in acts]
    # row 0: two agree on ahead, one says back -> the one between them; row 1: two say left -> the one nearer both
    assert torch.equal(ens.medoid_policy(members)(torch.zeros(2, 5)), torch.tensor([[0.9, 0.1], [0.0, 0.9]]))
    with pytest.raises(ValueError, match="at least one member"):
        ens.medoid_policy([])


def test_an_ensemble_of_one_policy_twice_plays_as_that_policy(tmp_path):
    members, robot, _ = ens.load_members([POLICY, POLICY])
    alone = ens.score(members[0], robot, ["wander-4"], 12, 5)
    both = ens.score(ens.mean_policy(members), robot, ["wander-4"], 12, 5)
    assert both == alone and alone["wander-4"]["episodes"] == 12
    out = tmp_path / "rows.json"
    assert ens.main([POLICY, POLICY, "--scenario", "static", "--episodes", "4", "--json", str(out)]) == 0
    assert out.is_file()


def test_on_maps_an_ensemble_of_one_policy_twice_scores_as_flashnav_eval(tmp_path, capsys, small_heldout_maps):
    maps = small_heldout_maps
    ref = tmp_path / "eval.json"
    assert flashnav_main(["eval", POLICY, "--maps", str(maps), "--episodes", "6", "--seed", "3",
                          "--json", str(ref)]) == 0
    out = tmp_path / "rows.json"
    assert ens.main([POLICY, POLICY, "--maps", str(maps), "--episodes", "6", "--seed", "3", "--ensemble-only",
                     "--combine", "medoid", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    want = {r["map"]: r["outcomes"] for r in json.loads(ref.read_text())["maps"]}
    doc = json.loads(out.read_text())
    assert list(doc["rows"]) == ["ensemble (medoid action)"]  # --ensemble-only: no member rows
    got = {r["map"]: r["outcomes"] for r in doc["rows"]["ensemble (medoid action)"]["maps"]}
    assert got == want and len(want) == 2
    worst = min(json.loads(ref.read_text())["maps"], key=lambda r: r["success_rate"])
    assert f"{worst['map']} {100 * worst['success_rate']:.1f} %" in text


def test_members_that_read_the_goal_distance_differently_are_refused_by_name():
    _, robot, metas = ens.load_members([POLICY])
    other = {**metas[0], "goal_distance_max": float(metas[0]["goal_distance_max"]) + 1.0}
    assert ens.goal_distance_scale(["a.onnx", "b.onnx"], [metas[0], metas[0]], robot) == metas[0]["goal_distance_max"]
    with pytest.raises(ValueError, match="b.onnx: goal-distance scale"):
        ens.goal_distance_scale(["a.onnx", "b.onnx"], [metas[0], other], robot)


def test_maps_and_scenarios_together_are_refused(capsys):
    with pytest.raises(SystemExit):
        ens.main([POLICY, "--maps", "heldout", "--scenario", "static"])
    assert "give one" in capsys.readouterr().err
