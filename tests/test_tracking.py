"""services.tracking against a real SQLite MLflow store, driven with synthetic trials and results (no Ray run).

The callback is fed exactly what Tune hands it: a trial (id + config), result dicts as the trainable
reports them, and a checkpoint written by the trainable's own code from a TrainResult-like object.
"""

from __future__ import annotations

import contextlib
import pickle
import types
from pathlib import Path

import pytest

from services import tracking
from services.trainable import _write_seed, final_metrics

SCHEMA_TAGS = {"sweep", "role", "trial_id", "robot", "algorithm", "seed", "recipe", "device_name", "device_kind",
               "host", "flashnav_version", "git_commit", "torch_version"}


def fake_result(seed: int = 0, reach: bool = True):
    """A TrainResult-shaped object (docs/train-api.md) with a 4-point curve."""
    rates = [0.2, 0.6, 0.92, 1.0] if reach else [0.1, 0.2, 0.3, 0.4]
    curve = [{"train_seconds": 1.0 + i, "env_steps": 1000.0 * (i + 1), "success_rate": r, "mean_return": 10 * r,
              "collision_rate": 1 - r, "timeout_rate": 0.0} for i, r in enumerate(rates)]
    times = {0.9: 3.0, 0.95: 4.0, 1.0: 4.0} if reach else {0.9: None, 0.95: None, 1.0: None}
    steps = {0.9: 3000.0, 0.95: 4000.0, 1.0: 4000.0} if reach else {0.9: None, 0.95: None, 1.0: None}
    config = {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": seed, "recipe": "cpu",
              "algo": {"batch_size": 512, "updates_per_step": 8}, "budget": {"max_train_seconds": 20.0}}
    result = types.SimpleNamespace(curve=curve, time_to_threshold=times, env_steps_to_threshold=steps,
                                   cycle={"collector_ms": 1.5, "learner_ms": 2.5, "effective_ms": 2.5},
                                   train_seconds=4.0, env_steps=4000, device_name="Test CPU (2 threads)",
                                   spec=types.SimpleNamespace(to_dict=lambda: config))
    result.to_dict = lambda: {"curve": curve, "time_to_threshold": {str(k): v for k, v in times.items()}}
    return result


def trial(trial_id: str, seeds=None):
    config = {"robot": "turtlebot2", "algorithm": "fastdsac"}
    config.update({"seeds": seeds} if seeds else {"seed": 0})
    return types.SimpleNamespace(trial_id=trial_id, config=config)


class DirCheckpoint:
    """What the callback uses of ray.tune.Checkpoint."""

    def __init__(self, path: Path):
        self.path = path

    @contextlib.contextmanager
    def as_directory(self):
        yield str(self.path)


def feed(callback, tr, seed: int, result, tmp_path: Path, done: dict | None = None, export: bool = False) -> None:
    """Everything Tune passes for one seed: every evaluation, the final report, its checkpoint."""
    for point in result.curve:
        callback.on_trial_result(0, [], tr, {**point, "seed": seed, "final": 0.0})
    final = final_metrics(result)
    strings = {"device_name": result.device_name, "device_kind": "cpu", "host": "node-1", "recipe": "cpu",
               "flashnav_version": "0.1.0", "git_commit": "abc123", "torch_version": "2.x"}
    callback.on_trial_result(0, [], tr, {**final, **strings, "seed": seed, "final": 1.0})
    stage = tmp_path / f"ckpt_{tr.trial_id}_{seed}"
    stage.mkdir(exist_ok=True)
    done = {**(done or {}), seed: final}
    _write_seed(stage, seed, result, final, done, export=export)
    callback.on_checkpoint(0, [], tr, DirCheckpoint(stage))


@pytest.fixture
def store(tmp_path):
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    parent = tracking.SweepRun(uri, "exp")
    parent.start("unit", "unit-1", {"invocation": "1"}, {"name": "unit", "budget": {"max_train_seconds": 20}})
    return parent


def children(store, status=None):
    runs = store.client.search_runs([store.experiment_id], f"tags.`mlflow.parentRunId` = '{store.run_id}'")
    return [r for r in runs if status is None or r.info.status == status]


def test_flatten():
    flat = tracking.flatten({"algo": {"batch_size": 512, "betas": [0.9, 0.95]}, "map": None, "seed": 3})
    assert flat == {"algo.batch_size": "512", "algo.betas": "[0.9, 0.95]", "map": "None", "seed": "3"}


def test_experiment_artifacts_live_next_to_the_sqlite_store(tmp_path, store):
    experiment = store.client.get_experiment(store.experiment_id)
    assert experiment.artifact_location.endswith(f"{tmp_path}/mlartifacts/exp")
    assert tracking.default_artifact_root("http://127.0.0.1:5000") is None


def test_parent_run_tags_and_params(store):
    run = store.client.get_run(store.run_id)
    assert run.data.tags["sweep"] == "unit" and run.data.tags["role"] == "sweep"
    assert run.data.params["budget.max_train_seconds"] == "20"
    store.finish()
    assert store.client.get_run(store.run_id).info.status == "FINISHED"


def test_child_run_follows_the_run_schema(tmp_path, store):
    callback = store.callback("unit", {"recipe": "cpu", "invocation": "1"})
    feed(callback, trial("aa_00000"), 0, fake_result(0), tmp_path)
    (run,) = children(store)
    assert run.info.status == "FINISHED"
    tags = run.data.tags
    assert SCHEMA_TAGS <= set(tags)
    assert tags["role"] == "trial" and tags["trial_id"] == "aa_00000" and tags["seed"] == "0"
    assert tags["device_name"] == "Test CPU (2 threads)" and tags["host"] == "node-1"
    assert set(tracking.FINAL_METRICS) <= set(run.data.metrics)
    assert run.data.metrics["time_to_90"] == 3.0 and run.data.metrics["reached_100"] == 1.0
    assert run.data.params["algo.batch_size"] == "512" and run.data.params["budget.max_train_seconds"] == "20.0"
    history = store.client.get_metric_history(run.info.run_id, "success_rate")
    assert [(m.step, m.value) for m in history] == [(1000, 0.2), (2000, 0.6), (3000, 0.92), (4000, 1.0)]
    artifacts = {a.path for a in store.client.list_artifacts(run.info.run_id)}
    assert {"config.yaml", "curve.csv", "result.json"} <= artifacts


def test_censored_metrics_where_not_reached(tmp_path, store):
    callback = store.callback("unit", {})
    feed(callback, trial("bb_00000"), 0, fake_result(0, reach=False), tmp_path)
    metrics = children(store)[0].data.metrics
    assert metrics["reached_90"] == 0.0 and metrics["time_to_90"] == 4.0 and metrics["env_steps_to_100"] == 4000.0


def test_policy_artifact_is_the_trials_best_policy(tmp_path, store, monkeypatch):
    """policy.pt reaches MLflow, exported from the result's policy (the best evaluation's: services.trainable)."""
    import flashnav.export

    monkeypatch.setattr(flashnav.export, "export_policy",
                        lambda policy, robot, out, onnx=True: (Path(out) / "policy.pt").write_bytes(policy))
    result = fake_result(0)
    result.policy, result.spec.robot = b"the best evaluation's policy", "preset"
    feed(store.callback("unit", {}), trial("pp_00000"), 0, result, tmp_path, export=True)
    run_id = children(store)[0].info.run_id
    assert "policy.pt" in {a.path for a in store.client.list_artifacts(run_id)}
    got = store.client.download_artifacts(run_id, "policy.pt", str(tmp_path / "down"))
    assert Path(got).read_bytes() == b"the best evaluation's policy"


def test_multi_seed_trial_gives_one_child_per_seed(tmp_path, store):
    callback = store.callback("unit", {})
    tr = trial("cc", seeds=[0, 1])
    feed(callback, tr, 0, fake_result(0), tmp_path)
    feed(callback, tr, 1, fake_result(1), tmp_path, done={0: final_metrics(fake_result(0))})
    runs = children(store, "FINISHED")
    assert sorted(r.data.tags["trial_id"] for r in runs) == ["cc_s0", "cc_s1"]
    assert {r.data.tags["ray_trial_id"] for r in runs} == {"cc"}


def test_retry_leaves_failed_then_one_finished(tmp_path, store):
    callback = store.callback("unit", {})
    tr = trial("dd_00000")
    callback.on_trial_result(0, [], tr, {"success_rate": 0.1, "env_steps": 10.0, "train_seconds": 1.0, "seed": 0,
                                         "final": 0.0})
    callback.on_trial_recover(0, [], tr)  # the trial raised; Tune retries it
    feed(callback, tr, 0, fake_result(0), tmp_path)
    callback.on_trial_complete(0, [], tr)
    assert len(children(store, "FAILED")) == 1
    assert len(children(store, "FINISHED")) == 1


def test_restored_trial_never_duplicates_a_finished_run(tmp_path, store):
    tr = trial("ee_00000")
    feed(store.callback("unit", {}), tr, 0, fake_result(0), tmp_path)
    # The driver died before Tune saved its state: after restore the trial runs again with a new
    # (unpickled) callback; its results must not produce a second FINISHED run for the trial.
    revived = pickle.loads(pickle.dumps(store.callback("unit", {})))
    feed(revived, tr, 0, fake_result(0), tmp_path)
    revived.on_trial_complete(0, [], tr)
    assert len(children(store)) == 1


def test_resume_fails_stale_running_children(tmp_path, store):
    callback = store.callback("unit", {})
    callback.on_trial_result(0, [], trial("ff_00000"), {"success_rate": 0.1, "env_steps": 10.0, "seed": 0,
                                                        "final": 0.0})
    assert children(store, "RUNNING")
    store.finish("KILLED")
    again = tracking.SweepRun(store.tracking_uri, "exp")
    again.resume(store.run_id)
    assert again.client.get_run(store.run_id).info.status == "RUNNING"
    assert not children(store, "RUNNING") and len(children(store, "FAILED")) == 1


def test_error_and_experiment_end_close_open_runs(tmp_path, store):
    callback = store.callback("unit", {})
    callback.on_trial_result(0, [], trial("gg_00000"), {"success_rate": 0.1, "env_steps": 1.0, "seed": 0, "final": 0.0})
    callback.on_trial_result(0, [], trial("hh_00000"), {"success_rate": 0.1, "env_steps": 1.0, "seed": 0, "final": 0.0})
    callback.on_trial_error(0, [], trial("gg_00000"))
    callback.on_experiment_end([])
    assert len(children(store, "FAILED")) == 2


def test_callback_pickles_without_client_or_open_runs(store):
    callback = store.callback("unit", {"recipe": "cpu"})
    _ = callback.client
    clone = pickle.loads(pickle.dumps(callback))
    assert clone._client is None and clone._open == {}
    assert clone.parent_run_id == store.run_id and clone.tags == {"recipe": "cpu"}


def test_threads_tag_beside_the_machine(store):
    callback = store.callback("unit", {})
    tr = trial("th_00000")
    final = final_metrics(fake_result(0))
    callback.on_trial_result(0, [], tr, {**final, "device_name": "Test CPU (2 cores)", "threads": 1,
                                         "seed": 0, "final": 1.0})
    callback.on_trial_complete(0, [], tr)
    (run,) = children(store)
    assert run.data.tags["device_name"] == "Test CPU (2 cores)" and run.data.tags["threads"] == "1"
