"""scripts/ensemble_scenarios.py: the mean action of several policies on the agent scenarios (issue 13 probe)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import ensemble_scenarios as ens  # noqa: E402

POLICY = str(Path(__file__).resolve().parent / "fixtures" / "deploy_policy" / "policy.onnx")


def test_the_mean_action_is_the_members_mean():
    a, b = (lambda o: torch.full((o.shape[0], 2), 0.6)), (lambda o: torch.full((o.shape[0], 2), -0.2))
    assert torch.allclose(ens.mean_policy([a, b])(torch.zeros(3, 5)), torch.full((3, 2), 0.2))
    with pytest.raises(ValueError, match="at least one member"):
        ens.mean_policy([])


def test_an_ensemble_of_one_policy_twice_plays_as_that_policy(tmp_path):
    members, robot = ens.load_members([POLICY, POLICY])
    alone = ens.score(members[0], robot, ["wander-4"], 12, 5)
    both = ens.score(ens.mean_policy(members), robot, ["wander-4"], 12, 5)
    assert both == alone and alone["wander-4"]["episodes"] == 12
    out = tmp_path / "rows.json"
    assert ens.main([POLICY, POLICY, "--scenario", "static", "--episodes", "4", "--json", str(out)]) == 0
    assert out.is_file()
