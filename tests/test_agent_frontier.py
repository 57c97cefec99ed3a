"""scripts/agent_frontier.py: reads both kinds of scenario result, names a wrong file, draws the figure."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "agent_frontier.py"
RATES = {"success_rate": 0.8, "agent_collision_rate": 0.15, "wall_collision_rate": 0.01, "timeout_rate": 0.04,
         "episodes": 512, "scored": 512}


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True)


def test_both_result_kinds_make_rows_and_a_figure(tmp_path):
    policy = tmp_path / "policy.json"
    policy.write_text(json.dumps({"scenarios": {"wander-8": RATES, "static": {**RATES, "success_rate": 1.0}}}))
    planner = tmp_path / "mpc.json"
    planner.write_text(json.dumps({**RATES, "success_rate": 0.9, "scenario": "wander-8"}))
    out = tmp_path / "f.png"
    r = run(f"policy={policy}", f"mpc={planner}", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "| policy | 512 | 80.0% | 15.0% | 1.0% | 4.0% |" in r.stdout
    assert "| mpc | 512 | 90.0% |" in r.stdout
    assert out.stat().st_size > 10_000


def test_a_result_for_another_scenario_is_named(tmp_path):
    planner = tmp_path / "mpc.json"
    planner.write_text(json.dumps({**RATES, "scenario": "crossing"}))
    r = run(f"mpc={planner}")
    assert r.returncode != 0 and "mpc.json" in r.stderr and "crossing" in r.stderr
    r = run(f"gone={tmp_path / 'gone.json'}")
    assert r.returncode != 0 and "gone.json" in r.stderr and "Traceback" not in r.stderr
    r = run(str(planner))
    assert r.returncode != 0 and "LABEL=RESULT.json" in r.stderr


def test_labels_with_a_group_share_one_legend_entry():
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        from agent_frontier import groups
    finally:
        sys.path.remove(str(SCRIPT.parent))
    points = [("crowd: s0", RATES), ("mpc", RATES), ("crowd: s1", RATES), ("crowd 360: s0", RATES)]
    got = groups(points)
    assert list(got) == ["crowd", "mpc", "crowd 360"]
    assert [label for label, _ in got["crowd"]] == ["crowd: s0", "crowd: s1"]
