"""End to end on a real Ray head through the real CLIs (``ray job submit``, ``flashnav sweep submit``).

Starts a head on 127.0.0.1 (``ray start --head`` in a subprocess with its own temp dir, free ports and
runs dir, through services.stack), submits ``ray job submit --working-dir . -- flashnav sweep run
sweeps/quickstart.yaml`` with a tiny budget and the real flashnav.train, waits for success, finds the
runs in MLflow, resumes the finished sweep with ``flashnav sweep submit --resume`` (nothing new), then
stops the head. The head hands job drivers FLASHNAV_RUNS_DIR, so what the job writes is found here
rather than in its temporary working dir.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from services import stack
from services.tracking import FINAL_METRICS, client_for

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
TINY = ["--set", "budget.max_train_seconds=3", "--set", "base.eval.episodes=16", "--set", "base.eval.every=10"]




@pytest.fixture(scope="module")
def head(tmp_path_factory):
    runs = tmp_path_factory.mktemp("head") / "runs"
    temp_dir = tempfile.mkdtemp(prefix="fnray", dir="/tmp")  # short: Ray's socket paths have a length limit
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("FLASHNAV_RUNS_DIR", str(runs))
        for name in ("MLFLOW_TRACKING_URI", "RAY_ADDRESS", "RAY_API_SERVER_ADDRESS", "RAY_AUTH_MODE"):
            patch.delenv(name, raising=False)
        try:
            state = stack.up(mlflow=False, ray_temp_dir=temp_dir, num_cpus=2, ray_port=stack.free_port(),
                             dashboard_port=stack.free_port(), echo=print)
            yield runs, state["ray"]["jobs_address"]
        finally:
            stack.down(echo=print)
            subprocess.run(["rm", "-rf", temp_dir], check=False)


def _cli(command: list[str], cwd: Path, timeout: int) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}",
           "RAY_AUTH_MODE": "token"}  # the line `services up` prints: its head runs with token auth
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _runs(runs: Path, experiment: str):
    client = client_for(f"sqlite:///{runs}/mlflow.db")
    found = client.search_runs([client.get_experiment_by_name(experiment).experiment_id])
    return ([r for r in found if r.data.tags.get("role") == "sweep"],
            [r for r in found if r.data.tags.get("role") == "trial"])


def test_ray_job_submit_quickstart(head):
    runs, address = head
    job = _cli(["ray", "job", "submit", "--address", address, "--working-dir", ".", "--",
                "flashnav", "sweep", "run", "sweeps/quickstart.yaml", *TINY], ROOT, 420)
    assert job.returncode == 0 and "succeeded" in job.stdout + job.stderr, job.stdout[-4000:] + job.stderr[-4000:]
    parents, children = _runs(runs, "quickstart")
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    assert sorted(c.data.tags["seed"] for c in children) == ["0", "1"]
    for child in children:
        assert child.info.status == "FINISHED" and set(FINAL_METRICS) <= set(child.data.metrics)
        assert child.data.tags["device_kind"] == "cpu" and child.data.tags["git_commit"]
        # the --set budget reached the trial and stopped it: the sweep file's own is 20 s. Not a timing bound
        # (a cycle's overrun past 3 s grows with the machine's load: 6.5 s beside a training, 2026-11-27)
        assert child.data.params["budget.max_train_seconds"] == "3.0"
        assert 3.0 <= float(child.data.metrics["train_seconds_total"]) < 20.0
    assert (runs / "ray" / "quickstart").is_dir()

    # `flashnav sweep submit --resume` of the finished sweep: validated here, submitted as a job with the
    # working dir uploaded, logs followed; it trains and logs nothing new and closes the same parent run.
    again = _cli([str(VENV_BIN / "flashnav"), "sweep", "submit", "sweeps/quickstart.yaml", "--address", address,
                  "--resume", *TINY], ROOT, 300)
    assert again.returncode == 0, again.stdout[-4000:] + again.stderr[-4000:]
    assert "SUCCEEDED" in again.stdout and "flashnav sweep run sweeps/quickstart.yaml --resume" in again.stdout
    parents_after, children_after = _runs(runs, "quickstart")
    assert [p.info.run_id for p in parents_after] == [parents[0].info.run_id]
    assert parents_after[0].info.status == "FINISHED" and len(children_after) == 2
