"""``flashnav bench cycle``: overlapped against sequential training cycles, side by side."""

from __future__ import annotations

import json

import pytest

from flashnav.bench.cycle import cycle_config, parse_schedules, run_order, summarise
from flashnav.cli import main as cli_main
from flashnav.spec import resolve

TINY = ["algo.num_envs=32", "algo.learning_start=64", "algo.updates_per_step=2", "algo.batch_size=64"]


def test_schedules_name_the_bad_input():
    assert parse_schedules("overlap, sequential") == ["overlap", "sequential"]
    with pytest.raises(ValueError, match="--schedules: unknown schedule 'parallel'"):
        parse_schedules("overlap,parallel")
    with pytest.raises(ValueError, match="twice"):
        parse_schedules("overlap,overlap")


def test_runs_alternate_so_a_drift_in_load_hits_every_schedule():
    assert run_order(["overlap", "sequential"], 3) == ["overlap", "sequential", "sequential", "overlap",
                                                       "overlap", "sequential"]
    assert run_order(["sequential"], 2) == ["sequential", "sequential"]
    with pytest.raises(ValueError, match="repeats"):
        run_order(["overlap"], 0)


def test_a_timed_run_is_the_recipe_for_a_fixed_number_of_learning_cycles():
    spec = resolve(cycle_config("turtlebot2", "fastdsac", "cpu", "cpu", "overlap", 5, TINY))
    hp = spec.hparams
    assert spec.overlap is True and spec.threads == 1 and spec.recipe == "cpu"
    assert hp.num_envs == 32 and hp.updates_per_step == 2  # the overrides hold
    assert spec.max_env_steps == (2 + 5) * 32  # 2 warm-up cycles fill learning_start = 64 transitions
    assert spec.budget.stop_at_success is None and spec.eval_every == 7  # one evaluation, at the end
    assert resolve(cycle_config("turtlebot2", "fastdsac", "cpu", "cpu", "sequential", 5, TINY)).overlap is False
    with pytest.raises(ValueError, match="cycles"):
        cycle_config("turtlebot2", "fastdsac", "cpu", "cpu", "overlap", 0)


def test_summary_takes_medians_and_the_first_schedule_as_baseline():
    runs = [{"schedule": "overlap", "threads": 1, "collector_ms": 10, "learner_ms": 100, "effective_ms": 104},
            {"schedule": "sequential", "threads": 2, "collector_ms": 5, "learner_ms": 70, "effective_ms": 80},
            {"schedule": "sequential", "threads": 2, "collector_ms": 7, "learner_ms": 74, "effective_ms": 82},
            {"schedule": "overlap", "threads": 1, "collector_ms": 12, "learner_ms": 110, "effective_ms": 116}]
    base, seq = summarise(runs, ["overlap", "sequential"])
    assert (base["effective_ms"], base["speed"], base["runs"], base["threads"]) == (110, 1.0, 2, 1)
    assert (seq["collector_ms"], seq["learner_ms"], seq["effective_ms"]) == (6, 72, 81)
    assert seq["speed"] == pytest.approx(110 / 81) and seq["effective_ms_each"] == [80, 82]


def test_the_command_times_both_schedules_and_writes_json(tmp_path):
    out = tmp_path / "cycle.json"
    assert cli_main(["bench", "cycle", "--recipe", "cpu", "--device", "cpu", "--cycles", "3", "--repeats", "2",
                     "--json", str(out), *TINY]) == 0
    data = json.loads(out.read_text())
    (group,) = data["groups"]
    assert [r["schedule"] for r in group["runs"]] == ["overlap", "sequential", "sequential", "overlap"]
    assert all(r["overlap"] == (1.0 if r["schedule"] == "overlap" else 0.0) for r in group["runs"])
    assert [r["threads"] for r in group["runs"] if r["schedule"] == "overlap"] == [1, 1]
    assert [row["schedule"] for row in group["rows"]] == ["overlap", "sequential"]
    assert all(row["effective_ms"] > 0 for row in group["rows"]) and group["rows"][0]["speed"] == 1.0
