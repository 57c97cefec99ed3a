"""``flashnav eval`` of a run still training: a ``--save-every`` snapshot's policy is named as such.

A script that waits for ``policy.onnx`` to appear and then evaluates it scores the snapshot, not the run's best
policy (session 45 found two scenario tables of session 44 played so); the note says so on stderr."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from flashnav.cli import main
from flashnav.policy_cli import snapshot_note

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "deploy_policy"


@pytest.fixture
def run_dir(tmp_path):
    out = tmp_path / "run"
    shutil.copytree(FIXTURE, out)
    return out


def test_a_snapshot_is_named_and_a_finished_run_is_not(run_dir, capsys):
    (run_dir / "metrics.json").write_text(json.dumps({"stop_reason": "running"}))
    for policy in (run_dir, run_dir / "policy.onnx"):
        assert "stop_reason 'running'" in snapshot_note(policy)
    assert main(["eval", str(run_dir / "policy.onnx"), "--episodes", "2"]) == 0
    assert "a snapshot of a run still training" in capsys.readouterr().err
    for finished in ({"stop_reason": "budget_env_steps"}, ["not", "a", "mapping"]):
        (run_dir / "metrics.json").write_text(json.dumps(finished))
        assert snapshot_note(run_dir / "policy.onnx") is None
    (run_dir / "metrics.json").write_text("{ torn")  # a half-written file is no claim either way
    assert snapshot_note(run_dir) is None
    (run_dir / "metrics.json").unlink()
    assert snapshot_note(run_dir / "policy.onnx") is None
    assert main(["eval", str(run_dir / "policy.onnx"), "--episodes", "2"]) == 0
    assert "snapshot" not in capsys.readouterr().err
