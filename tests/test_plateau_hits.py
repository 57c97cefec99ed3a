"""scripts/plateau_hits.py: the climb to a plateau and the wait on it for a first 100 % (issue 15 done-means 3)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import plateau_hits  # noqa: E402


def curve(rates: list[float], every: int = 5120) -> list[dict]:
    return [{"env_steps": every * (i + 1), "success_rate": r} for i, r in enumerate(rates)]


def test_the_plateau_starts_at_the_level_and_ends_at_the_first_100():
    at, rates, hit = plateau_hits.plateau(curve([0.5, 0.96, 0.97, 0.99, 1.0, 0.98]), 0.97)
    assert (at, rates, hit) == (3 * 5120, [0.97, 0.99, 1.0], True)
    at, rates, hit = plateau_hits.plateau(curve([0.5, 0.98, 0.99]), 0.97)
    assert (at, rates, hit) == (2 * 5120, [0.98, 0.99], False)
    assert plateau_hits.plateau(curve([0.5, 0.9]), 0.97) == (None, [], False)


def write_run(root: Path, name: str, rates: list[float], episodes: int | None = 100,
              failed: list[list[int] | None] | None = None) -> str:
    d = root / name
    d.mkdir()
    config = {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": 0}
    if episodes is not None:
        config["eval"] = {"episodes": episodes}
    points = curve(rates)
    for point, f in zip(points, failed or []):
        point["failed_episodes"] = f
    (d / "metrics.json").write_text(json.dumps({"config": config, "curve": points}))
    return str(d)


def test_the_chance_per_evaluation_is_hits_over_plateau_evaluations(tmp_path, capsys):
    a = write_run(tmp_path, "a", [0.98, 0.99, 1.0])          # 3 plateau evaluations, a hit
    b = write_run(tmp_path, "b", [0.5, 0.97, 0.98, 0.99])    # 3, no hit
    plateau_hits.main([f"arm={a},{b}"])
    row = capsys.readouterr().out.splitlines()[1].split()
    # runs 2; climb mean (5120 + 10240) / 2; 6 plateau evaluations; chance 1/6; wait 5120 * 6 env steps;
    # failed of 100 per plateau evaluation: a 2, 1, 0; b 3, 2, 1 -> mean 9 / 6
    assert row[:3] == ["arm", "2", "7,680"] and row[3] == "6" and row[5] == "0.167" and row[6] == "30,720"
    assert row[7] == "1.50"


def test_failures_count_each_runs_own_episodes_and_are_drawn(tmp_path, capsys):
    assert plateau_hits.failed_episodes([1.0, 0.99902, 0.99512], 1024) == [0, 1, 5]
    a = write_run(tmp_path, "a", [0.98, 1.0], episodes=100)       # 2 and 0 failed of 100
    b = write_run(tmp_path, "b", [0.99, 0.995], episodes=1000)    # 10 and 5 failed of 1,000
    out = tmp_path / "fig" / "fails.png"
    plateau_hits.main(["--failures", str(out), f"x={a}", f"y={b}"])
    rows = capsys.readouterr().out.splitlines()
    assert rows[1].split()[-1] == "1.00" and rows[2].split()[-1] == "7.50"
    assert out.stat().st_size > 10_000


def test_records_without_their_episode_count_leave_the_failures_out(tmp_path, capsys):
    a = write_run(tmp_path, "old", [0.99, 1.0], episodes=None)     # as bench train --json keeps its runs
    plateau_hits.main([f"arm={a}"])
    row = capsys.readouterr().out.splitlines()[1].split()
    assert row[5] == "0.500" and row[-1] == "-"


def test_a_missing_run_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit):
        plateau_hits.main([f"arm={tmp_path / 'nope'}"])
    assert "nope: not a flashnav train run folder with metrics.json" in capsys.readouterr().err


def test_which_episodes_each_run_fails_on_its_plateau(tmp_path, capsys):
    # evaluations 2-5 are the plateau (>= 0.97) up to the first 100 %; the first and the last are not counted
    a = write_run(tmp_path, "a", [0.5, 0.98, 0.98, 0.99, 1.0, 0.97],
                  failed=[None, [7, 9], [7, 11], [7], [], [1, 2, 3]])
    b = write_run(tmp_path, "b", [0.98, 0.99])                      # an older run: no episodes named
    assert plateau_hits.which_failed(json.loads((Path(a) / "metrics.json").read_text())["curve"], 0.97) == (
        4, {7: 3, 9: 1, 11: 1})
    plateau_hits.main(["--which", f"arm={a},{b}"])
    out = capsys.readouterr().out
    assert "a: 4 plateau evaluations; failed #7 3/4, #9 1/4, #11 1/4" in out
    assert "b: no plateau evaluation names its failed episodes" in out
