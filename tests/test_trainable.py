"""services.trainable: final metrics (censored, never NaN), the objective, checkpoint files, device choice, and
the trainable inside Ray Tune, with a FAKE training function (plumbing) and with the real flashnav.train."""

from __future__ import annotations

import functools
import json
import math
import types
from pathlib import Path

import pytest
from conftest import ship_by_value

from services import device as devices
from services.sweep_schema import parse_sweep
from services.trainable import Objective, _write_seed, final_metrics, load_manifest, write_curve_csv




class _FakeSpec:
    """What the trainable reads of a RunSpec: its plain data."""

    def __init__(self, data: dict):
        self.data = data

    def to_dict(self) -> dict:
        return self.data


def fake_result(rates, dt=1.0, times=None, steps=None, cycle=None, config=None):
    curve = [{"train_seconds": dt * (i + 1), "env_steps": 100.0 * (i + 1), "success_rate": r, "mean_return": r}
             for i, r in enumerate(rates)]
    result = types.SimpleNamespace(curve=curve, time_to_threshold=times or {}, env_steps_to_threshold=steps or {},
                                   cycle=cycle if cycle is not None else {"collector_ms": 1.0, "learner_ms": 3.0,
                                                                          "effective_ms": 3.0},
                                   train_seconds=curve[-1]["train_seconds"] if curve else 0.0,
                                   env_steps=curve[-1]["env_steps"] if curve else 0, spec=_FakeSpec(config or {"seed": 0}),
                                   device_name="Fake CPU (1 threads)")
    result.to_dict = lambda: {"curve": curve}
    return result


def fake_train(config, on_eval=None, *, log_dir: str | None = None, evals: int = 3):
    """FAKE flashnav.train (plumbing tests only): success rises 0.4 per evaluation; records the config it got."""
    data = config if isinstance(config, dict) else config.model_dump()
    curve, times, steps = [], {0.9: None, 0.95: None, 1.0: None}, {0.9: None, 0.95: None, 1.0: None}
    for i in range(evals):
        point = {"env_steps": 100.0 * (i + 1), "train_seconds": 0.5 * (i + 1), "success_rate": min(1.0, 0.4 * (i + 1)),
                 "mean_return": float(i), "collision_rate": 0.0, "timeout_rate": 0.0, "eval_index": float(i)}
        curve.append(point)
        for threshold in times:
            if times[threshold] is None and point["success_rate"] >= threshold:
                times[threshold], steps[threshold] = point["train_seconds"], point["env_steps"]
        if on_eval:
            on_eval(dict(point))
    if log_dir:
        Path(log_dir, f"seed_{data['seed']}.json").write_text(json.dumps(data))
    result = types.SimpleNamespace(curve=curve, time_to_threshold=times, env_steps_to_threshold=steps,
                                   cycle={"collector_ms": 1.0, "learner_ms": 2.0, "effective_ms": 2.0},
                                   train_seconds=curve[-1]["train_seconds"], env_steps=curve[-1]["env_steps"],
                                   spec=_FakeSpec(data), device_name="Fake CPU (1 threads)")
    result.to_dict = lambda: {"curve": curve}
    return result


# ---------------------------------------------------------------- pure


def test_final_metrics_reached():
    result = fake_result([0.5, 0.95, 1.0], times={0.9: 2.0, 0.95: 2.0, 1.0: 3.0},
                         steps={0.9: 200.0, 0.95: 200.0, 1.0: 300.0})
    m = final_metrics(result)
    assert m["time_to_90"] == 2.0 and m["time_to_100"] == 3.0 and m["env_steps_to_95"] == 200.0
    assert m["reached_90"] == m["reached_95"] == m["reached_100"] == 1.0
    assert m["final_success_rate"] == 1.0 and m["best_success_rate"] == 1.0
    assert m["train_seconds_total"] == 3.0 and m["env_steps_total"] == 300.0
    assert (m["cycle_collector_ms"], m["cycle_learner_ms"], m["cycle_effective_ms"]) == (1.0, 3.0, 3.0)


def test_final_metrics_censored_never_nan_or_none():
    result = fake_result([0.2, 0.93, 0.5], times={"0.9": 2.0, "0.95": None, "1.0": float("nan")},
                         steps={"0.9": 200.0}, cycle={})
    m = final_metrics(result)  # string keys, as in TrainResult.to_dict()
    assert m["time_to_90"] == 2.0 and m["reached_90"] == 1.0
    assert m["time_to_95"] == 3.0 and m["reached_95"] == 0.0  # censored: the run's total train seconds
    assert m["time_to_100"] == 3.0 and m["env_steps_to_100"] == 300.0 and m["reached_100"] == 0.0
    assert m["final_success_rate"] == 0.5 and m["best_success_rate"] == 0.93
    assert all(isinstance(v, float) and math.isfinite(v) for v in m.values())


def test_final_metrics_of_an_empty_run():
    m = final_metrics(fake_result([], cycle={"collector_ms": None}))
    assert all(isinstance(v, float) and math.isfinite(v) for v in m.values())
    assert m["reached_90"] == 0.0 and m["best_success_rate"] == 0.0


def search(**kw):
    return parse_sweep({"name": "s", "robots": ["turtlebot2"], "algorithms": ["fastdsac"], "seeds": 2,
                        "search": {"n_trials": 2, "parameters": {"algo.batch_size": {"choice": [256]}}, **kw}}).search


def test_objective_censored_with_penalty_and_provisional():
    objective = Objective(search(objective="time_to_90", unreached_penalty=100.0))
    reached = final_metrics(fake_result([0.95], times={0.9: 1.0}))
    missed = final_metrics(fake_result([0.1, 0.2]))
    assert objective.of_final(reached) == 1.0 and objective.of_final(missed) == 2.0 + 100.0
    curve = [{"train_seconds": 1.0, "env_steps": 10.0, "success_rate": 0.5},
             {"train_seconds": 2.0, "env_steps": 20.0, "success_rate": 0.9}]
    assert objective.of_curve(curve[:1]) == 1.0 and objective.of_curve(curve) == 2.0
    assert objective.mean([4.0], 2.0) == 3.0
    best = Objective(search(objective="best_success_rate"))
    assert best.of_curve(curve) == 0.9 and best.of_final(reached) == 0.95


def test_curve_csv_and_checkpoint_manifest(tmp_path):
    result = fake_result([0.2, 1.0], times={0.9: 2.0}, config={"seed": 3, "algo": {"batch_size": 512}})
    write_curve_csv(result.curve, tmp_path / "c.csv")
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert lines[0] == "success_rate,mean_return,train_seconds,env_steps" and len(lines) == 3
    final = final_metrics(result)
    _write_seed(tmp_path, 3, result, final, {3: final})
    assert {p.name for p in (tmp_path / "seed_3").iterdir()} == {"config.yaml", "curve.csv", "result.json"}
    manifest = load_manifest(tmp_path)
    assert manifest["latest"] == 3 and manifest["done"] == {3: final}
    assert load_manifest(tmp_path / "nowhere") == {"done": {}, "latest": None}


def test_the_trials_policy_artifact_is_the_best_evaluations(tmp_path, monkeypatch):
    """policy.pt is what `flashnav train --out` exports (result.policy: the best evaluation's), not the final
    learner's actor (it was, while best_success_rate reported the best evaluation's success)."""
    import flashnav.export

    exported = []
    monkeypatch.setattr(flashnav.export, "export_policy",
                        lambda policy, robot, out, onnx=True: exported.append((policy, robot, onnx)))
    result = fake_result([0.9, 0.5])
    best, final = object(), object()
    result.learner = types.SimpleNamespace(policy=final)
    result.policy = best
    result.spec.robot = "preset"
    _write_seed(tmp_path, 0, result, final_metrics(result), {0: {}}, export=True)
    assert exported == [(best, "preset", False)]
    _write_seed(tmp_path, 0, result, final_metrics(result), {0: {}}, export=False)   # export off: nothing
    assert len(exported) == 1


def test_device_from_assigned_gpus(monkeypatch):
    import ray

    monkeypatch.setattr(ray, "get_gpu_ids", lambda: [])
    assert devices.trial_device() == "cpu"  # gpu=0 trial on a GPU host: all GPUs visible, none assigned
    monkeypatch.setattr(ray, "get_gpu_ids", lambda: [3])
    assert devices.trial_device() == "cuda"
    assert devices.device_kind("cuda:1") == "cuda" and devices.device_kind("cpu") == "cpu"
    assert devices.device_name("cpu").endswith(" cores)")  # the machine; threads are a tag of their own


# ---------------------------------------------------------------- inside Ray Tune


@pytest.fixture(scope="module", autouse=True)
def _workers_can_run_this_module():
    ship_by_value(__name__)


def run_trials(tmp_path, sweep_data: dict, param_space: dict, train_fn):
    """Run the trainable directly under a Tuner; returns every result dict Tune handed the driver."""
    from ray import tune

    from services.trainable import train_trial

    seen: list[dict] = []

    class Capture(tune.Callback):
        def on_trial_result(self, iteration, trials, trial, result, **info):
            seen.append(dict(result))

    sweep = parse_sweep(sweep_data).model_dump(mode="json")
    trainable = tune.with_resources(tune.with_parameters(train_trial, sweep=sweep, git_commit="abc", train_fn=train_fn),
                                    {"cpu": 1, "gpu": 0})
    tune.Tuner(trainable, param_space=param_space,
               run_config=tune.RunConfig(storage_path=str(tmp_path / "ray"), name="t", callbacks=[Capture()],
                                         verbose=0)).fit()
    return seen


def test_trainable_reports_curve_then_final_with_strings(tmp_path, ray_session):
    data = {"name": "t", "robots": ["turtlebot2"], "algorithms": ["fastdsac"], "seeds": 1,
            "base": {"recipe": "cpu", "eval": {"episodes": 8}}, "budget": {"max_train_seconds": 5}}
    seen = run_trials(tmp_path, data, {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": 0},
                      functools.partial(fake_train, log_dir=str(tmp_path)))
    evals = [r for r in seen if r.get("final") == 0.0]
    (final,) = [r for r in seen if r.get("final") == 1.0]
    assert [r["success_rate"] for r in evals] == [0.4, 0.8, 1.0]
    assert final["time_to_90"] == 1.5 and final["reached_90"] == 1.0 and final["env_steps_total"] == 300.0
    assert final["device_name"] == "Fake CPU (1 threads)" and final["device_kind"] == "cpu"
    assert final["git_commit"] == "abc" and final["recipe"] == "cpu" and final["host"]
    got = json.loads((tmp_path / "seed_0.json").read_text())
    assert got["device"] == "cpu"  # gpu=0 -> CPU, never "auto"
    assert got["budget"]["max_train_seconds"] == 5 and got["eval"]["episodes"] == 8


def test_trainable_runs_every_seed_and_reports_the_mean_objective(tmp_path, ray_session):
    data = {"name": "t", "robots": ["turtlebot2"], "algorithms": ["fastdsac"], "seeds": 2,
            "search": {"n_trials": 1, "seeds_per_trial": 2, "parameters": {"algo.batch_size": {"choice": [256]}}}}
    seen = run_trials(tmp_path, data, {"robot": "turtlebot2", "algorithm": "fastdsac", "seeds": [0, 1],
                                       "params": {"algo.batch_size": 256}},
                      functools.partial(fake_train, log_dir=str(tmp_path)))
    finals = [r for r in seen if r.get("final") == 1.0]
    assert [r["seed"] for r in finals] == [0, 1]
    assert all("objective" in r for r in seen)
    assert finals[-1]["objective"] == 1.5  # mean censored time_to_90 over both seeds
    assert json.loads((tmp_path / "seed_1.json").read_text())["overrides"] == {"algo.batch_size": 256}


def test_trainable_with_real_train(tmp_path, ray_session):
    data = {"name": "t", "robots": ["turtlebot2"], "algorithms": ["fastdsac"], "seeds": 1,
            "base": {"recipe": "cpu", "eval": {"episodes": 16, "every": 10}}, "budget": {"max_train_seconds": 4},
            "overrides": {"algo.updates_per_step": 4}}  # short cycles: the run may overshoot by one
    seen = run_trials(tmp_path, data, {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": 0}, None)
    evals = [r for r in seen if r.get("final") == 0.0]
    (final,) = [r for r in seen if r.get("final") == 1.0]
    assert evals and all(0.0 <= r["success_rate"] <= 1.0 for r in evals)
    for tag in ("90", "95", "100"):
        assert math.isfinite(final[f"time_to_{tag}"]) and final[f"reached_{tag}"] in (0.0, 1.0)
    assert final["device_kind"] == "cpu" and final["device_name"]
    assert final["train_seconds_total"] <= 4.0 * 1.5
