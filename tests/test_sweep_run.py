"""Whole sweeps in-process: Ray Tune + MLflow + Optuna, retry and --resume.

Plumbing tests train with FAKE functions (named fake_*: they only shape a TrainResult); the test at the
end runs the real flashnav.train.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
import types
from pathlib import Path

import pytest
import yaml
from conftest import ship_by_value

from services.sweep import run_sweep
from services.sweep_schema import SweepError, load_sweep
from services.tracking import FINAL_METRICS, client_for

ROOT = Path(__file__).resolve().parents[1]
SCHEMA_TAGS = {"sweep", "role", "trial_id", "robot", "algorithm", "seed", "recipe", "device_name", "device_kind",
               "host", "flashnav_version", "git_commit", "torch_version"}




def fake_train(config, on_eval=None, *, marks: str | None = None, fail_once: bool = False, evals: int = 3):
    """FAKE flashnav.train: a rising success curve; optionally raises once per seed (marker files)."""
    data = config if isinstance(config, dict) else config.model_dump()
    seed, params = data["seed"], data.get("overrides", {})
    slope = 0.2 + 0.02 * int(params.get("algo.updates_per_step", 0))
    curve, times, steps = [], {0.9: None, 0.95: None, 1.0: None}, {0.9: None, 0.95: None, 1.0: None}
    if marks:
        Path(marks, f"start_{seed}_{time.time_ns()}").touch()
    for i in range(evals):
        point = {"env_steps": 100.0 * (i + 1), "train_seconds": 0.5 * (i + 1),
                 "success_rate": min(1.0, slope * (i + 1)), "mean_return": float(i)}
        curve.append(point)
        for threshold in times:
            if times[threshold] is None and point["success_rate"] >= threshold:
                times[threshold], steps[threshold] = point["train_seconds"], point["env_steps"]
        if on_eval:
            on_eval(dict(point))
        if fail_once and marks and not Path(marks, f"raised_{seed}").exists():
            Path(marks, f"raised_{seed}").touch()
            raise RuntimeError("fake training failure")
    result = types.SimpleNamespace(curve=curve, time_to_threshold=times, env_steps_to_threshold=steps,
                                   cycle={"collector_ms": 1.0, "learner_ms": 2.0, "effective_ms": 2.0},
                                   train_seconds=curve[-1]["train_seconds"], env_steps=curve[-1]["env_steps"],
                                   spec=types.SimpleNamespace(to_dict=lambda data=data: data), device_name="Fake CPU (1 threads)")
    result.to_dict = lambda: {"curve": curve}
    return result


@pytest.fixture(scope="module", autouse=True)
def _workers_can_run_this_module():
    ship_by_value(__name__)


@pytest.fixture
def runs(tmp_path, monkeypatch):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    return tmp_path / "runs"


def write_sweep(path: Path, **extra) -> Path:
    data = {"name": "unit", "robots": ["turtlebot2"], "algorithms": ["fastdsac"], "seeds": 2,
            "base": {"recipe": "cpu", "eval": {"episodes": 8}}, "budget": {"max_train_seconds": 5},
            "resources": {"cpu": 1, "gpu": 0}, **extra}
    path.write_text(yaml.safe_dump(data))
    return path


def runs_of(runs_dir: Path, experiment: str):
    client = client_for(f"sqlite:///{runs_dir}/mlflow.db")
    exp = client.get_experiment_by_name(experiment)
    all_runs = client.search_runs([exp.experiment_id], max_results=1000)
    parents = [r for r in all_runs if r.data.tags.get("role") == "sweep"]
    return client, parents, [r for r in all_runs if r.data.tags.get("role") == "trial"]


def test_seed_sweep_logs_one_parent_and_a_child_per_seed(tmp_path, runs, ray_session):
    sweep = write_sweep(tmp_path / "unit.yaml")
    assert run_sweep(sweep, train_fn=fake_train, verbose=0) == 0
    client, parents, children = runs_of(runs, "unit")
    (parent,) = parents
    assert parent.info.status == "FINISHED" and parent.data.tags["sweep"] == "unit"
    assert len(children) == 2 and {c.data.tags["seed"] for c in children} == {"0", "1"}
    for child in children:
        assert child.info.status == "FINISHED"
        assert child.data.tags["mlflow.parentRunId"] == parent.info.run_id
        assert SCHEMA_TAGS <= set(child.data.tags) and child.data.tags["device_kind"] == "cpu"
        assert set(FINAL_METRICS) <= set(child.data.metrics)
        assert child.data.params["device"] == "cpu" and child.data.params["budget.max_train_seconds"] == "5.0"
        assert len(client.get_metric_history(child.info.run_id, "success_rate")) == 3
        artifacts = {a.path for a in client.list_artifacts(child.info.run_id)}
        assert {"config.yaml", "curve.csv"} <= artifacts
    assert len({c.data.tags["trial_id"] for c in children}) == 2
    state = json.loads(next((runs / "sweeps" / "unit").glob("*/sweep_state.json")).read_text())
    assert state["done_targets"] == ["grid"] and state["parent_run_id"] == parent.info.run_id
    if "torch" in sys.modules:  # the driver never initialises CUDA (trials choose their own device)
        assert not sys.modules["torch"].cuda.is_initialized()


def test_gpu_sweep_on_a_cpu_cluster_is_refused_before_anything_runs(tmp_path, runs, ray_session):
    if ray_session.cluster_resources().get("GPU", 0) > 0:
        pytest.skip("this machine has a GPU")
    sweep = write_sweep(tmp_path / "unit.yaml", resources={"cpu": 1, "gpu": 1})
    with pytest.raises(SweepError, match=r"asks for 1 CPU / 1 GPU .*--set resources.gpu=0"):
        run_sweep(sweep, train_fn=fake_train, verbose=0)
    assert not (runs / "mlflow.db").exists()


def test_trial_that_raises_once_is_retried(tmp_path, runs, ray_session):
    marks = tmp_path / "marks"
    marks.mkdir()
    sweep = write_sweep(tmp_path / "unit.yaml", retry={"max_failures": 1})
    train = functools.partial(fake_train, marks=str(marks), fail_once=True)
    assert run_sweep(sweep, train_fn=train, verbose=0) == 0
    _, parents, children = runs_of(runs, "unit")
    assert parents[0].info.status == "FINISHED"
    finished = [c for c in children if c.info.status == "FINISHED"]
    assert sorted(c.data.tags["seed"] for c in finished) == ["0", "1"]  # one FINISHED run per trial
    assert len([c for c in children if c.info.status == "FAILED"]) == 2  # each first attempt
    assert len(list(marks.glob("start_*"))) == 4


def test_trial_that_keeps_failing_fails_the_sweep(tmp_path, runs, ray_session):
    def always_fails(config, on_eval=None):  # FAKE
        raise RuntimeError("broken")

    sweep = write_sweep(tmp_path / "unit.yaml", seeds=1, retry={"max_failures": 0})
    said, sets = [], ["budget.max_train_seconds=4"]
    assert run_sweep(sweep, sets=sets, train_fn=always_fails, verbose=0, echo=said.append) == 1
    _, parents, _ = runs_of(runs, "unit")
    assert parents[0].info.status == "FAILED" and parents[0].data.tags["errored_trials"] == "1"
    # the invocation by name, with its --set (without it --resume refuses the sweep as changed)
    stamp = re.search(r"--resume (\d{8}-\d{6}) --set budget.max_train_seconds=4` runs them again", said[-1]).group(1)
    # --resume after the fix runs the errored trial (it printed "1/1 trials finished", trained nothing and marked the
    # parent FINISHED with errored_trials 0: the target had been recorded as done)
    assert run_sweep(sweep, resume=stamp, sets=sets, train_fn=fake_train, verbose=0, echo=said.append) == 0
    _, parents, children = runs_of(runs, "unit")
    assert parents[0].info.status == "FINISHED" and parents[0].data.tags["errored_trials"] == "0"
    assert [c.data.tags["seed"] for c in children if c.info.status == "FINISHED"] == ["0"]


def test_resume_refuses_a_changed_sweep_and_a_new_run_names_the_unfinished_one(tmp_path, runs, ray_session):
    """--resume with another seed list (or --set) ran the old trials under the old parameters and counted the new
    file's trials as finished; a run without --resume started afresh without a word about the unfinished one."""
    def always_fails(config, on_eval=None):  # FAKE
        raise RuntimeError("broken")

    sweep = write_sweep(tmp_path / "unit.yaml", seeds=1, retry={"max_failures": 0})
    assert run_sweep(sweep, train_fn=always_fails, verbose=0, echo=lambda _: None) == 1
    with pytest.raises(SweepError, match=r"--resume: the sweep differs .* in budget\.max_train_seconds, seeds;"):
        run_sweep(sweep, resume=True, sets=["seeds=[0,7]", "budget.max_train_seconds=3"], train_fn=fake_train)
    said = []
    assert run_sweep(sweep, dry_run=True, echo=said.append) == 0
    assert any("did not finish; this starts a new one" in line for line in said)


def test_optuna_sweep_persists_study_and_writes_best_config(tmp_path, runs, ray_session):
    import optuna

    search = {"n_trials": 3, "seeds_per_trial": 2, "study_name": "unit-study", "sampler_seed": 0,
              "parameters": {"algo.updates_per_step": {"int": [2, 16]}, "algo.batch_size": {"choice": [256, 512]}},
              "start_points": [{"algo.updates_per_step": 7, "algo.batch_size": 512}]}
    sweep = write_sweep(tmp_path / "unit.yaml", search=search)
    assert run_sweep(sweep, train_fn=fake_train, verbose=0) == 0
    study = optuna.load_study(study_name="unit-study", storage=f"sqlite:///{runs}/optuna.db")
    assert [t.state.name for t in study.trials] == ["COMPLETE"] * 3
    # The start point is the study's first trial, exactly as written.
    assert study.trials[0].params == {"params/algo.updates_per_step": 7, "params/algo.batch_size": 512}
    (out_dir,) = (runs / "sweeps" / "unit").iterdir()
    best = load_sweep(out_dir / "best_turtlebot2_fastdsac.yaml")
    assert best.search is None and best.seed_list == list(range(10))
    assert best.overrides == {k.removeprefix("params/"): v for k, v in study.best_params.items()}
    summary = json.loads((out_dir / "optuna_summary.json").read_text())[0]
    assert summary["trials"] == {"COMPLETE": 3} and summary["best"]["value"] == pytest.approx(study.best_value)
    assert "importances" in summary
    client, parents, children = runs_of(runs, "unit")
    assert len(children) == 6 and all(c.info.status == "FINISHED" for c in children)  # 3 trials x 2 seeds
    assert len({c.data.tags["trial_id"] for c in children}) == 6
    # each child names its search trial, so two settings of one seed can be told apart
    assert len({c.info.run_name for c in children}) == 6
    assert {c.info.run_name for c in children} == {f"turtlebot2-fastdsac-t{c.data.tags['search_trial']}-s{c.data.tags['seed']}"
                                                   for c in children}
    assert len({c.data.tags["search_trial"] for c in children}) == 3
    artifacts = {a.path for a in client.list_artifacts(parents[0].info.run_id)}
    assert {"best_turtlebot2_fastdsac.yaml", "optuna_summary.json", "sweep.yaml"} <= artifacts
    # The same named study again without --resume would silently append: refused.
    with pytest.raises(SweepError, match="'unit-study' .* already has 3 trials"):
        run_sweep(sweep, train_fn=fake_train, verbose=0)
    assert len(runs_of(runs, "unit")[1]) == 1  # refused before anything was logged


DRIVER = textwrap.dedent('''
    """Sweep driver for the resume test; its FAKE training is slow enough to be killed mid-sweep."""
    import sys, time, types
    from pathlib import Path
    from services.sweep import run_sweep

    MARKS = Path(sys.argv[2])

    def fake_slow_train(config, on_eval=None):
        data = config if isinstance(config, dict) else config.model_dump()
        (MARKS / f"start_{data['seed']}_{time.time_ns()}").touch()
        curve = []
        for i in range(4):
            time.sleep(0.4)
            point = {"env_steps": 100.0 * (i + 1), "train_seconds": 0.4 * (i + 1), "success_rate": 0.25 * (i + 1),
                     "mean_return": 0.0}
            curve.append(point)
            on_eval(dict(point))
        result = types.SimpleNamespace(curve=curve, time_to_threshold={1.0: 1.6}, env_steps_to_threshold={1.0: 400.0},
                                       cycle={}, train_seconds=1.6, env_steps=400, spec=types.SimpleNamespace(to_dict=lambda data=data: data), device_name="Fake")
        result.to_dict = lambda: {}
        return result

    sys.exit(run_sweep(sys.argv[1], resume="--resume" in sys.argv, train_fn=fake_slow_train, verbose=0))
''')


def test_resume_after_ctrl_c_and_after_kill_reruns_nothing_finished(tmp_path, runs):
    """One sweep of three seeds (one trial at a time), stopped twice and resumed twice (three Ray start-ups, not
    four: the suite's time). First killed (SIGKILL: the driver and its in-process Ray die at once) while seed 1
    trains. Then ``--resume``, stopped by SIGTERM (``kill PID``; the driver relays it as Ctrl-C) while seed 2, the
    last trial, trains: Tune catches SIGINT, saves its state, marks the stopped trial TERMINATED and returns; the
    sweep must stop as interrupted (parent KILLED, target not done), not finish (it once counted the stopped trial
    as finished and said "3/3"). Then
    ``--resume`` again: every seed finished exactly once, the interrupted ones trained again, the finished one
    not."""
    sweep = write_sweep(tmp_path / "unit.yaml", seeds=3, max_concurrent_trials=1, retry={"max_failures": 0})
    (tmp_path / "driver.py").write_text(DRIVER)
    marks = tmp_path / "marks"
    marks.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RAY_AUTH_MODE": "disabled"}
    command = [sys.executable, str(tmp_path / "driver.py"), str(sweep), str(marks)]

    def run_until_seed_starts(seed: int, args: list[str], stop: str) -> None:
        driver = subprocess.Popen(command + args, env=env, cwd=tmp_path, start_new_session=True,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 120
            while not list(marks.glob(f"start_{seed}_*")):  # the seeds before it are done (one trial at a time)
                assert time.monotonic() < deadline and driver.poll() is None, f"the driver never reached seed {seed}"
                time.sleep(0.2)
            time.sleep(0.6)
            if stop in ("ctrl-c", "term"):  # SIGTERM is relayed as SIGINT: the same graceful stop
                os.kill(driver.pid, signal.SIGINT if stop == "ctrl-c" else signal.SIGTERM)
                assert driver.wait(timeout=120) != 0
        finally:
            with contextlib.suppress(ProcessLookupError):  # after ctrl-c the group may be gone already
                os.killpg(driver.pid, signal.SIGKILL)  # the driver and its in-process Ray die mid-trial
            driver.wait()

    run_until_seed_starts(1, [], "kill")
    run_until_seed_starts(2, ["--resume"], "term")  # (it aborted the driver: exit 134, the parent left RUNNING)
    _, parents, _ = runs_of(runs, "unit")
    assert [p.info.status for p in parents] == ["KILLED"]
    (state_file,) = (runs / "sweeps" / "unit").glob("*/sweep_state.json")
    assert json.loads(state_file.read_text())["done_targets"] == []
    assert {seed: len(list(marks.glob(f"start_{seed}_*"))) for seed in range(3)} == {0: 1, 1: 2, 2: 1}
    resumed = subprocess.run(command + ["--resume"], env=env, cwd=tmp_path, capture_output=True, text=True,
                             timeout=240)
    assert resumed.returncode == 0, resumed.stdout[-3000:] + resumed.stderr[-3000:]
    starts = {seed: len(list(marks.glob(f"start_{seed}_*"))) for seed in range(3)}
    # seed 0 finished before the kill: never trained again; seed 1 (killed) and seed 2 (stopped by Ctrl-C):
    # trained again once each
    assert starts == {0: 1, 1: 2, 2: 2}
    _, parents, children = runs_of(runs, "unit")
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"  # the same parent run, reopened twice
    finished = [c for c in children if c.info.status == "FINISHED"]
    assert sorted(c.data.tags["seed"] for c in finished) == ["0", "1", "2"]  # nothing lost, no duplicate
    assert all(c.info.status in ("FINISHED", "FAILED") for c in children)  # the stopped attempts: FAILED


def test_quickstart_with_real_train(runs, ray_session):
    sets = ["budget.max_train_seconds=3", "base.eval.episodes=16", "base.eval.every=10"]
    assert run_sweep(ROOT / "sweeps/quickstart.yaml", sets=sets, verbose=0) == 0
    client, parents, children = runs_of(runs, "quickstart")
    assert len(parents) == 1 and len(children) == 2
    for child in children:
        assert child.info.status == "FINISHED" and SCHEMA_TAGS <= set(child.data.tags)
        assert set(FINAL_METRICS) <= set(child.data.metrics)
        assert child.data.params["recipe"] == "cpu" and child.data.params["seed"] == child.data.tags["seed"]
        assert client.get_metric_history(child.info.run_id, "success_rate")
        artifacts = {a.path for a in client.list_artifacts(child.info.run_id)}
        assert {"config.yaml", "curve.csv", "policy.pt"} <= artifacts


def test_an_address_where_nothing_answers_is_named_before_ray_waits(monkeypatch):
    """`sweep run --address` to a dashboard URL or to a port where no Ray listens: a SweepError naming the address
    within seconds, not Ray's minutes of retries."""
    import socket

    import ray
    from services.sweep import check_reachable, connect

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray, "is_initialized", lambda: False)  # as in a fresh process, whatever ran before
    with pytest.raises(SweepError, match="dashboard/jobs address"):
        connect("http://127.0.0.1:8265")
    with socket.socket() as s:  # a free port: bound, then closed, so nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(SweepError, match=rf"--address 127\.0\.0\.1:{port}: no Ray cluster answers there"):
        connect(f"127.0.0.1:{port}")
    assert time.perf_counter() - t0 < 30
    with socket.socket() as server:  # something listening: no error (Ray's own handshake comes after)
        server.bind(("127.0.0.1", 0))
        server.listen()
        check_reachable(f"ray://127.0.0.1:{server.getsockname()[1]}")
    check_reachable("auto")  # left to Ray
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")  # from the environment: named as such
    with pytest.raises(SweepError, match=rf"RAY_ADDRESS 127\.0\.0\.1:{port}: no Ray .* or drop RAY_ADDRESS to run"):
        connect(None)
