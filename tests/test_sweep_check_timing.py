"""scripts/sweep_check_timing.py: both arms run the driver's real check, and the reused arm draws each map once."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import sweep_check_timing  # noqa: E402

import flashnav.maps.families as families  # noqa: E402


def test_both_arms_check_the_sweep_and_the_reused_one_draws_each_map_once(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "gen.yaml"
    sweep.write_text("name: gen\nrobots: [turtlebot2]\nalgorithms: [fastdsac]\nseeds: 1\n"
                     "base: {recipe: generalist, maps: {family: [mazes], count: 2},\n"
                     "       eval: {maps: validation, maps_per_family: 1}}\n"
                     "search: {n_trials: 2, parameters: {algo.batch_size: {choice: [256, 512, 1024]}}}\n")
    drawn = []
    real = families._draw_family
    monkeypatch.setattr(families, "_draw_family", lambda *a: drawn.append(a[:2]) or real(*a))
    times = sweep_check_timing.main([str(sweep), "--rounds", "1"])
    assert len(times["gen.yaml"]["reused"]) == 2 and len(times["gen.yaml"]["drawn anew"]) == 2
    assert "gen.yaml: drawn anew" in capsys.readouterr().out
    maps = set(drawn)
    # three searched points, four checks: drawn anew every point's maps, reused each map once per check
    assert len(drawn) == 2 * 3 * len(maps) + 2 * len(maps)
    with pytest.raises(SystemExit):
        sweep_check_timing.main([str(sweep), "--rounds", "0"])
