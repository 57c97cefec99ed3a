"""scripts/export_final.py: a run's final learner (checkpoint.pt) exported as the policy its evaluations play."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import export_final  # noqa: E402

from flashnav.export import load_policy  # noqa: E402
from test_finetune import trained_checkpoint  # noqa: E402


@pytest.mark.parametrize("averaging", [0.0, 0.5])
def test_the_exported_policy_is_the_final_learners(tmp_path, averaging):
    learner, spec, run = trained_checkpoint(tmp_path, **{"algo.policy_averaging": averaging})
    assert export_final.main([str(run)]) == 0
    policy, meta = load_policy(run / "final" / "policy.pt")
    onnx, _ = load_policy(run / "final" / "policy.onnx")
    obs = torch.randn(32, spec.robot.obs_dim).abs()
    with torch.no_grad():
        want = learner.policy(obs)
        torch.testing.assert_close(policy(obs), want, atol=1e-5, rtol=0)
        torch.testing.assert_close(torch.as_tensor(onnx(obs)), want, atol=1e-5, rtol=0)
        if averaging:  # the average is what the run evaluates, not the trained actor
            assert (learner.policy(obs) - type(learner.policy)(learner.state.actor)(obs)).abs().max() > 1e-4
    assert meta["obs_dim"] == spec.robot.obs_dim


def test_it_names_what_it_will_not_do(tmp_path, capsys):
    _, _, run = trained_checkpoint(tmp_path)
    assert export_final.main([str(run / "checkpoint.pt"), "--out", str(tmp_path / "f")]) == 0
    assert export_final.main([str(run), "--out", str(tmp_path / "f")]) == 2
    assert f"--out {tmp_path / 'f'}: already holds policy.pt and policy.onnx" in capsys.readouterr().err
    assert export_final.main([str(tmp_path / "f" / "policy.pt")]) == 2  # an exported policy holds no learner
    assert "an exported policy, which holds the actor only" in capsys.readouterr().err
    assert export_final.main([str(tmp_path / "nowhere")]) == 2
    assert "no such run folder or checkpoint file" in capsys.readouterr().err


def test_a_bad_out_or_a_metrics_file_is_named_before_the_learner_is_read(tmp_path, capsys):
    _, _, run = trained_checkpoint(tmp_path)
    afile = tmp_path / "afile"
    afile.write_text("x")
    for out in (afile, afile / "sub"):
        assert export_final.main([str(run), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"--out {out}" in err and "Traceback" not in err, err
    (run / "policy.json").write_text("{}")  # the metadata flashnav train writes beside its policy
    assert export_final.main([str(run / "policy.json")]) == 2
    err = capsys.readouterr().err
    assert "RUN " in err and "a JSON file (a policy's metadata or a run's metrics), not a learner checkpoint" in err
    assert "init_from" not in err
