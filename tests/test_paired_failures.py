"""scripts/paired_failures.py: failed evaluation episodes per evaluation, paired run by run (issue 16)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import paired_failures  # noqa: E402


def run(tmp_path, name, curve, episodes=1024):
    folder = tmp_path / name
    folder.mkdir()
    data = {"config": {"eval": {"episodes": episodes}},
            "curve": [{"env_steps": s, "success_rate": 1 - f / episodes} for s, f in curve]}
    (folder / "metrics.json").write_text(json.dumps(data))
    return str(folder)


def test_only_evaluations_both_runs_made_from_the_start_step_count(tmp_path):
    base = run(tmp_path, "b0", [(50, 900), (100, 10), (150, 4), (200, 2)])
    arm = run(tmp_path, "a0", [(50, 800), (100, 6), (150, 0)])          # stopped at 100 % after 150
    base1 = run(tmp_path, "b1", [(100, 1), (150, 3)])
    arm1 = run(tmp_path, "a1", [(100, 2), (150, 3)], episodes=1024)
    out = paired_failures.paired([base, base1], [arm, arm1], start=100)
    assert out["evaluations"] == 4                                        # (100, 150) of each pair; 50 and 200 not
    assert out["pairs"][0]["evaluations"] == 2 and out["pairs"][0]["base_mean"] == 7 and out["pairs"][0]["arm_mean"] == 3
    assert out["base_mean"] == pytest.approx((10 + 4 + 1 + 3) / 4) and out["arm_mean"] == pytest.approx((6 + 0 + 2 + 3) / 4)
    assert (out["arm_fewer"], out["arm_more"]) == (2, 1)
    assert paired_failures.failures(base, 0) == {50: 900, 100: 10, 150: 4, 200: 2}


def test_bad_inputs_are_named(tmp_path):
    a = run(tmp_path, "a", [(100, 1)])
    with pytest.raises(ValueError, match="one base run per arm run"):
        paired_failures.paired([a, a], [a], start=0)
    with pytest.raises(ValueError, match="no evaluation at or after 1,000"):
        paired_failures.paired([a], [a], start=1000)
    with pytest.raises(FileNotFoundError, match="no metrics.json"):
        paired_failures.failures(tmp_path / "missing", 0)
