"""services/report_select.py: a report keeps one invocation of a sweep when asked, and warns when its table
pools runs that are not seeds of one setting (two invocations, an Optuna search, a seed counted twice)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pandas as pd
import pytest

from services.report import build_report, normalize_runs
from services.report_select import pooling_warnings, select_invocation
from services.report_tables import threshold_table

_spec = importlib.util.spec_from_file_location("report_runs_fixture",
                                               Path(__file__).parent / "fixtures" / "report_runs.py")
F = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(F)
OLD, NEW = "20261129-100000", "20261129-120000"


def _two_invocations() -> pd.DataFrame:
    """The fixture's sweep, its trials run once (OLD) and its TurtleBot2 FastDSAC H100 seeds again (NEW),
    twice as slow: the same sweep name, other trial ids."""
    raw = F.raw_runs()
    raw["tags.invocation"] = OLD
    again = raw[(raw["tags.robot"] == "turtlebot2") & (raw["tags.algorithm"] == "fastdsac")
                & (raw["tags.device_name"].str.startswith("NVIDIA H100"))].copy()
    again["run_id"] = again["run_id"] + "b"
    again["tags.trial_id"] = again["tags.trial_id"] + "b"
    again["tags.invocation"] = NEW
    again["metrics.time_to_90"] *= 2
    again["end_time"] += pd.Timedelta(hours=1)
    return normalize_runs(pd.concat([raw, again], ignore_index=True))


def _h100_tb2(runs: pd.DataFrame) -> pd.Series:
    table = threshold_table(runs)
    return table[(table["embodiment"] == "turtlebot2") & (table["algorithm"] == "fastdsac")
                 & table["platform"].str.startswith("NVIDIA H100")].iloc[0]


def test_pooled_invocations_are_warned_of_and_one_can_be_kept():
    runs = _two_invocations()
    warnings = pooling_warnings(runs)
    assert any(f"sweep {F.SWEEP}: trials of 2 invocations pooled ({OLD}: 26 trials, {NEW}: 3 trials)" in w
               for w in warnings), warnings
    assert any("turtlebot2/fastdsac on NVIDIA H100 80GB HBM3: seed 0 x2, seed 1 x2, seed 2 x2 counted as "
               "separate seeds" in w for w in warnings), warnings
    assert _h100_tb2(runs)["n"] == 6  # pooled: six "seeds" of three
    latest = select_invocation(runs, "latest")
    assert set(latest["invocation"]) == {NEW} and len(latest) == 3 and latest.attrs["n_trials"] == 3
    assert _h100_tb2(latest)["mean_90"] == pytest.approx(24.0)  # the new invocation's 20, 24, 28
    old = select_invocation(runs, OLD)
    assert len(old) == 26 and pooling_warnings(old) == []
    assert _h100_tb2(old)["mean_90"] == pytest.approx(12.0)
    with pytest.raises(ValueError, match=f"--invocation 2026: no trial run from it; invocations there: {OLD}, {NEW}"):
        select_invocation(runs, "2026")
    assert select_invocation(runs, None) is runs


def test_runs_without_invocation_tags_say_so():
    runs = normalize_runs(F.raw_runs())
    assert pooling_warnings(runs) == []
    with pytest.raises(ValueError, match="none .runs logged before invocations were tagged"):
        select_invocation(runs, "latest")


def test_an_optuna_search_is_named_as_such_and_the_report_shows_the_warnings(tmp_path):
    raw = F.raw_runs()
    raw["tags.search_trial"] = [None] + [f"{k:05d}" for k in range(len(raw) - 1)]
    runs = normalize_runs(raw)
    warnings = pooling_warnings(runs)
    assert any(w.startswith(f"sweep {F.SWEEP} is an Optuna search") for w in warnings), warnings
    written = build_report(runs, None, tmp_path, formats=("md", "html"))
    assert f"**Pooled:** sweep {F.SWEEP} is an Optuna search" in written["md"].read_text()
    assert "<strong>Pooled:</strong> sweep" in written["html"].read_text()
