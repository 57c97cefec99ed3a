"""The run so far on disk: ``train(on_snapshot=...)`` and ``flashnav train --save-every``. A snapshot never
changes the run; a run that fails after one leaves it readable (a policy that loads, metrics that say
``running``); the finished run replaces it."""

from __future__ import annotations

import json

import pytest

from flashnav import train
from flashnav.cli import main as cli_main
from tests.test_train import TINY, flat, tiny


def test_snapshots_come_after_evaluations_and_change_nothing():
    seen = []
    with_snapshots = train(tiny(), on_snapshot=lambda r: seen.append(
        (r.stop_reason, r.env_steps, len(r.curve), r.best_success_rate == max(c["success_rate"] for c in r.curve),
         r.policy is not None)), snapshot_every=0)
    plain = train(tiny())
    # every evaluation (every 2 vector steps of 32 slots), the run so far as it stood then
    assert seen == [("running", 64 * k, k, True, True) for k in range(1, 5)]
    assert [c["success_rate"] for c in with_snapshots.curve] == [c["success_rate"] for c in plain.curve]
    assert (flat(with_snapshots.learner.policy) == flat(plain.learner.policy)).all()
    late = []
    train(tiny(), on_snapshot=late.append, snapshot_every=3600)
    assert late == []  # an hour apart: none in a run of seconds
    with pytest.raises(ValueError, match="snapshot_every must be >= 0"):
        train(tiny(), on_snapshot=late.append, snapshot_every=-1)


def test_the_library_writes_the_run_folder_the_cli_writes(tmp_path):
    """docs/train-api.md: save_run, then the folder is what eval, init_from and TrainConfig.from_yaml read."""
    import numpy as np

    from flashnav.export import load_policy
    from flashnav.learn.artefacts import RUN_FILES, save_run
    from flashnav.spec import TrainConfig, resolve

    result = train(tiny())
    out = save_run(result, tmp_path / "mine")
    assert sorted(p.name for p in out.iterdir()) == sorted(RUN_FILES)
    policy, meta = load_policy(out)
    assert policy(np.zeros((3, meta["obs_dim"]), np.float32)).shape == (3, 2)
    again = TrainConfig.from_yaml(out / "config.yaml")  # a run's config.yaml: its request, the same run again
    assert resolve(again).to_dict() == result.spec.to_dict()
    finetuned = train(tiny(init_from=str(out)))
    assert finetuned.spec.init is not None


def _fail_at_third_evaluation(real_train):
    def failing(spec, **kw):
        evals = []

        def on_eval(m):
            evals.append(m)
            if len(evals) == 3:
                raise RuntimeError("the machine fell over")
            return kw["on_eval"](m)
        return real_train(spec, **{**kw, "on_eval": on_eval})
    return failing


def test_a_failed_train_command_leaves_its_last_snapshot(tmp_path, monkeypatch, capsys):
    from flashnav.learn import loop

    monkeypatch.setattr(loop, "train", _fail_at_third_evaluation(loop.train))
    out = tmp_path / "run"
    args = ["train", "--recipe", "cpu", "--device", "cpu", "--out", str(out), "--save-every", "0",
            *[f"{k}={v}" for k, v in TINY.items()], "budget.max_env_steps=320", "eval.episodes=8"]
    with pytest.raises(RuntimeError, match="fell over"):  # a crash keeps its traceback
        cli_main(args)
    assert "the run as it stood at 192 env steps" in capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["stop_reason"] == "running" and metrics["env_steps"] == 192 and len(metrics["curve"]) == 3
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt", "config.yaml", "metrics.json", "policy.json",
                                                     "policy.onnx", "policy.pt"]  # no .saving-* left behind
    assert cli_main(["eval", str(out / "policy.onnx"), "--episodes", "4"]) == 0
    # the snapshot is a run: kept unless told (--overwrite); the finished run then replaces it
    monkeypatch.undo()
    assert cli_main(args) == 2 and "holds a run already" in capsys.readouterr().err
    assert cli_main(args + ["--overwrite"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["stop_reason"] == "budget_env_steps" and metrics["env_steps"] == 320


def test_save_every_is_checked_before_anything_runs(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli_main(["train", "--out", str(out), "--save-every", "-5"]) != 0
    assert "--save-every must be >= 0 seconds, got -5" in capsys.readouterr().err
    assert not out.exists()
