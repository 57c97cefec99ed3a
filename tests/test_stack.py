"""services.stack: process-tree handling, and a real local stack (Ray head + MLflow server) up / job / down.

The real stack runs on free ports with its own runs dir and Ray temp dir, so it never meets another
Ray instance on the machine; ``down`` must leave no process of it behind.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from services import stack



def test_stop_tree_stops_children_and_grandchildren():
    parent = subprocess.Popen(["sh", "-c", "sleep 60 & sh -c 'sleep 60' & wait"], start_new_session=True)
    deadline = time.monotonic() + 10
    while len(stack.descendants(parent.pid)) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    tree = [parent.pid, *stack.descendants(parent.pid)]
    assert len(tree) >= 4
    assert stack.stop_tree(parent.pid, stack.start_time(parent.pid), timeout=5)
    parent.wait(timeout=5)
    assert not any(stack.alive(p) for p in tree)


def test_stop_tree_refuses_a_recycled_pid():
    proc = subprocess.Popen(["sleep", "60"])
    try:
        assert not stack.stop_tree(proc.pid, started=(stack.start_time(proc.pid) or 0) + 1)  # not the one we started
        assert stack.alive(proc.pid)
    finally:
        proc.kill()
        proc.wait()


def test_status_and_down_with_nothing_started(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path))
    assert stack.main(["status"]) == 3
    assert stack.main(["down"]) == 0
    out = capsys.readouterr().out
    assert "ray: not started" in out and "nothing was running" in out
    assert stack.jobs_address() == "http://127.0.0.1:8265"


def test_align_client_auth_follows_the_head(tmp_path, monkeypatch):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path))
    # setenv first so that monkeypatch records the variable and removes what align_client_auth sets:
    # a RAY_AUTH_MODE=token left behind would start later tests' Ray clusters in token mode
    monkeypatch.setenv("RAY_AUTH_MODE", "unset")
    monkeypatch.delenv("RAY_AUTH_MODE")
    (tmp_path / "services").mkdir()
    (tmp_path / "services" / "state.json").write_text('{"ray": {"auth_mode": "token", "jobs_address": "http://h:1"}}')
    stack.align_client_auth()
    assert os.environ["RAY_AUTH_MODE"] == "token" and stack.jobs_address() == "http://h:1"


@pytest.fixture
def local_stack(tmp_path, monkeypatch):
    """A real Ray head + MLflow server on free ports; always brought down."""
    runs = tmp_path / "runs"
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(runs))
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    temp_dir = tempfile.mkdtemp(prefix="fnray", dir="/tmp")  # short: Ray's socket paths have a length limit
    ports = {"ray_port": stack.free_port(), "dashboard_port": stack.free_port(), "mlflow_port": stack.free_port()}
    try:
        state = stack.up(ray_temp_dir=temp_dir, num_cpus=2, echo=lambda s: None, **ports)
        yield runs, state
    finally:
        stack.down(echo=lambda s: None)
        subprocess.run(["rm", "-rf", temp_dir], check=False)


def test_stack_up_job_down(local_stack, capsys):
    runs, state = local_stack
    ray_pid, mlflow_pid = state["ray"]["pid"], state["mlflow"]["pid"]
    tree = [ray_pid, mlflow_pid, *stack.descendants(ray_pid), *stack.descendants(mlflow_pid)]
    assert state["ray"]["auth_mode"] == "token"  # Ray's agent takes jobs on every interface: never open by default
    with pytest.raises(urllib.error.HTTPError) as refused:  # no token, no answer
        urllib.request.urlopen(state["ray"]["health"], timeout=30)
    assert refused.value.code == 401
    assert state["ray"]["jobs_address"].startswith("http://127.0.0.1:")
    assert state["mlflow"]["tracking_uri"].startswith("http://127.0.0.1:")
    for name in ("ray", "mlflow"):  # each answers within 30 s (one slow answer on a loaded machine is not a dead
        # server), else this raises with its log's last lines - the wait `up` itself uses
        entry = state[name]
        stack._wait_healthy(name, entry["health"], entry["pid"], Path(entry["log"]), 30.0)
    assert stack.status() == 0
    assert (runs / "services" / "ray.pid").read_text().strip() == str(ray_pid)
    assert (runs / "services" / "mlflow.log").exists()

    # (a job through this head is tested in test_ray_job.py)
    assert stack.down(echo=lambda s: None) == 2
    left = [(p, Path(f"/proc/{p}/cmdline").read_text()[:80]) for p in tree if stack.alive(p)]
    assert not left
    assert not (runs / "services" / "ray.pid").exists()
    assert stack.status() == 3
