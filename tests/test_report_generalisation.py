"""`flashnav report --generalisation`: the tables from small eval JSON documents, in every format, and the
command line without MLflow."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from flashnav.eval_maps import EVAL_MAPS_FORMAT, EVAL_MAPS_KIND, MAP_BAR, aggregate, success_interval
from flashnav.evaluate import STALL_M as EVAL_STALL_M
from services.report_generalisation import (BAR, FORMAT, KIND, MEAN_ROW, STALL_M, html, interval_lookup, load_evals,
                                            markdown, per_map_intervals, per_map_markdown, per_map_table,
                                            summary_markdown, summary_table, write_generalisation)


def _doc(label, suite, rates):
    rows = [{"map": m, "source": None, "width_m": 10.0, "height_m": 10.0, "resolution": 0.05,
             "diagonal_m": 14.1, "beyond_scale": m == "big", "episodes_beyond_scale": 3 if m == "big" else 0,
             "episodes": 8, "success_rate": s, "success_interval": success_interval(round(8 * s), 8),
             "collision_rate": c, "timeout_rate": 1 - s - c,
             "mean_steps": 50.0, "mean_return": 10.0} for m, s, c in rates]
    return {"kind": KIND, "format_version": FORMAT, "label": label, "policy": f"{label}.onnx", "suite": suite,
            "maps_arg": suite, "robot": "turtlebot2", "goal_sampling": "geodesic", "goal_band_m": [1.0, 5.0],
            "episodes_per_map": 8, "seed": 1, "goal_distance_scale": 14.1, "date": "2026-11-24 04:00 UTC",
            "machine": "CPU (2 cores)", "seconds": 1.0, "maps": rows, "aggregate": aggregate(rows)}


DOCS = [_doc("single", "heldout", [("a", 1.0, 0.0), ("big", 0.5, 0.25)]),
        _doc("general", "heldout", [("a", 0.875, 0.125)]),
        _doc("single", "real", [("house", 0.75, 0.0)])]


def test_kind_and_format_agree_with_the_writer():
    assert (KIND, FORMAT, BAR, STALL_M) == (EVAL_MAPS_KIND, EVAL_MAPS_FORMAT, MAP_BAR, EVAL_STALL_M)


def test_summary_rows_per_policy_and_suite():
    t = summary_table(DOCS)
    assert list(zip(t["policy"], t["suite"])) == [("single", "heldout"), ("general", "heldout"), ("single", "real")]
    first = t.iloc[0]
    assert first["success_mean"] == pytest.approx(0.75) and first["success_worst"] == 0.5
    assert first["worst_map"] == "big" and first["maps_beyond_scale"] == 1 and first["episodes_beyond_scale"] == 3
    assert first["collision_mean"] == pytest.approx(0.125) and first["timeout_mean"] == pytest.approx(0.125)
    # 4 of 8 is under 95 % on any draw; 7 of 8 (87.5 %) only on this one: its interval reaches 97.8 %
    assert list(t["maps_under_bar"]) == [1, 1, 1] and list(t["maps_surely_under_bar"]) == [1, 0, 1]
    md = summary_markdown(t)
    assert "| single | heldout | turtlebot2 | geodesic | 2 x 8 | 75.0 | 75.0 | 50.0 (big) | 1 (1) | 12.5 | 12.5 | " \
           "1/2 maps, 3 ep |" in md
    assert "| general | heldout | turtlebot2 | geodesic | 1 x 8 | 87.5 | 87.5 | 87.5 (a) | 1 (0) |" in md
    old = [{**d, "maps": [{k: v for k, v in r.items() if k != "success_interval"} for r in d["maps"]]} for d in DOCS]
    assert list(summary_table(old)["maps_surely_under_bar"]) == [1, 1, 1]   # files from before the interval
    assert t["stalled_mean"].isna().all()  # files from before the stalled share: none, and no bracket above
    rows = [{**r, "stalled_rate": 0.125 if r["map"] == "big" else 0.0} for r in DOCS[0]["maps"]]
    counted = summary_table([{**DOCS[0], "maps": rows, "aggregate": aggregate(rows)}])
    assert counted["stalled_mean"].iloc[0] == pytest.approx(0.0625)
    assert "| 1 (1) | 12.5 | 12.5 (6.2) | 1/2 maps, 3 ep |" in summary_markdown(counted)


def test_per_map_cells_and_suite_means():
    t = per_map_table(DOCS)
    assert list(t.columns) == ["suite", "map", "single", "general"]
    rows = {(r["suite"], r["map"]): r for r in t.to_dict("records")}
    assert rows[("heldout", "big")]["single"] == 0.5
    assert rows[("heldout", "big")]["general"] != rows[("heldout", "big")]["general"]  # NaN: not evaluated there
    assert rows[("heldout", "mean over maps")]["single"] == pytest.approx(0.75)
    assert rows[("heldout", "mean over maps")]["general"] == pytest.approx(0.875)
    assert rows[("real", "mean over maps")]["single"] == pytest.approx(0.75)
    md = per_map_markdown(t)
    assert "| heldout | big | 50.0 |  |" in md and "| heldout | **mean over maps** | **75.0** | **87.5** |" in md


def test_per_map_intervals_beside_each_rate():
    """Each (suite, map, policy) keeps the interval its file recorded; the page prints it in brackets after the
    rate (4 of 8 by the Wilson score formula by hand: 0.5 +- 1.96 sqrt(1/32 + 1.96^2/256) / (1 + 1.96^2/8), that
    is 21.5-78.5 %), never on a mean row, and a file from before the interval prints its rate alone."""
    t = per_map_intervals(DOCS)
    assert list(t.columns) == ["suite", "map", "policy", "episodes", "success", "success_low", "success_high"]
    big = t[(t["map"] == "big")].iloc[0]
    assert (big["policy"], big["episodes"], big["success"]) == ("single", 8, 0.5)
    assert (big["success_low"], big["success_high"]) == pytest.approx((0.2152, 0.7848), abs=1e-4)
    md = per_map_markdown(per_map_table(DOCS), t)
    assert "| heldout | big | 50.0 (21.5-78.5) |  |" in md
    assert "| heldout | **mean over maps** | **75.0** | **87.5** |" in md
    old = [{**d, "maps": [{k: v for k, v in r.items() if k != "success_interval"} for r in d["maps"]]} for d in DOCS]
    without = per_map_intervals(old)
    assert without["success_low"].isna().all() and without["success_high"].isna().all()
    assert "| heldout | big | 50.0 |  |" in per_map_markdown(per_map_table(old), without)
    page = html(summary_table(DOCS), per_map_table(DOCS), intervals=t)
    assert "<td>50.0 (21.5-78.5)</td>" in page


def test_page_formats_read_the_tables_once_built_and_leave_them_as_they_are():
    summary, maps = summary_table(DOCS), per_map_table(DOCS)
    page, md = html(summary, maps), markdown(summary, maps)
    pd.testing.assert_frame_equal(summary, summary_table(DOCS))  # still fractions, for the CSV beside them
    pd.testing.assert_frame_equal(maps, per_map_table(DOCS))
    assert "<td>75.0</td>" in page and "<td>87.5</td>" in page  # single's mean, general's map a, in per cent
    assert summary_markdown(summary) in md and per_map_markdown(maps) in md


def test_files_in_every_format_and_bad_input_named(tmp_path):
    paths = []
    for i, d in enumerate(DOCS):
        paths.append(tmp_path / f"e{i}.json")
        paths[-1].write_text(json.dumps(d))
    written = write_generalisation(paths, tmp_path / "out")
    assert sorted(written) == ["generalisation_csv", "generalisation_html", "generalisation_intervals_csv",
                               "generalisation_maps_csv", "generalisation_md", "generalisation_png"]
    assert written["generalisation_png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "![success per map](generalisation.png)" in written["generalisation_md"].read_text()
    assert "<img src='generalisation.png'" in written["generalisation_html"].read_text()
    only_tables = write_generalisation(paths, tmp_path / "tables", formats=("md", "csv"))   # no figure asked for
    assert "generalisation_png" not in only_tables and not (tmp_path / "tables" / "generalisation.png").exists()
    assert "generalisation.png" not in only_tables["generalisation_md"].read_text()
    csv = written["generalisation_maps_csv"].read_text().splitlines()
    assert csv[0] == "suite,map,single,general" and "heldout,a,1.0000,0.8750" in csv
    spans = written["generalisation_intervals_csv"].read_text().splitlines()
    assert spans[0] == "suite,map,policy,episodes,success,success_low,success_high"
    assert "heldout,big,single,8,0.5000,0.2152,0.7848" in spans
    assert "| heldout | big | 50.0 (21.5-78.5) |  |" in written["generalisation_md"].read_text()
    html = written["generalisation_html"].read_text()
    assert "<table" in html and "87.5" in html
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"kind": "other"}))
    with pytest.raises(ValueError, match="bad.json.*not a `flashnav eval --maps --json` result"):
        load_evals([bad])
    with pytest.raises(ValueError, match="missing.json: no such file"):
        load_evals([tmp_path / "missing.json"])


def test_report_command_with_only_generalisation_needs_no_mlflow(tmp_path, capsys):
    from flashnav.cli import main

    path = tmp_path / "e.json"
    path.write_text(json.dumps(DOCS[0]))
    out = tmp_path / "report"
    assert main(["report", "--generalisation", str(path), "--out", str(out), "--format", "md,csv"]) == 0
    assert (out / "generalisation.md").is_file() and not (out / "report.md").exists()
    assert "generalisation_md" in capsys.readouterr().out


def test_per_map_figure_one_panel_per_suite_every_policy_its_mean(monkeypatch, tmp_path):
    """The figure draws, per suite, one marker per (policy, map) it was evaluated on (none where it was not)
    and each policy's mean over those maps as a dashed line."""
    import matplotlib.pyplot as plt

    from services import report_figures

    kept = {}
    monkeypatch.setattr(report_figures, "_save", lambda fig, path, svg: kept.setdefault("fig", fig) and [path])
    maps = per_map_table(DOCS)
    report_figures.plot_per_map(maps[maps["map"] != MEAN_ROW], tmp_path / "f.png")
    heldout, real = kept["fig"].axes
    assert heldout.get_title().startswith("heldout") and real.get_title().startswith("real")
    assert [t.get_text() for t in heldout.get_xticklabels()] == ["a", "big"]
    points = {line.get_label(): line.get_ydata() for line in heldout.lines if not line.get_linestyle() == "--"}
    assert list(points["single"]) == [100.0, 50.0] and list(points["general"][:1]) == [87.5]
    means = sorted(line.get_ydata()[0] for line in heldout.lines if line.get_linestyle() == "--")
    assert means == [75.0, 87.5]   # single (100 + 50) / 2, general its one map
    real_means = [line.get_ydata()[0] for line in real.lines if line.get_linestyle() == "--"]
    assert real_means == [75.0]    # general was not evaluated on the real suite: no line of its own
    plt.close(kept["fig"])


def test_per_map_figure_draws_each_known_interval_and_the_bar(monkeypatch, tmp_path):
    """With the intervals, one vertical line per (policy, map) whose file recorded one, from its low to its high
    end in per cent at that policy's marker; the bar as a dotted line; no interval, no line."""
    from services import report_figures

    kept = {}
    monkeypatch.setattr(report_figures, "_save", lambda fig, path, svg: kept.setdefault("fig", fig) and [path])
    maps = per_map_table(DOCS)
    old = DOCS[1] | {"maps": [{k: v for k, v in r.items() if k != "success_interval"} for r in DOCS[1]["maps"]]}
    spans = per_map_intervals([DOCS[0], old, DOCS[2]])   # general's map a: no interval recorded
    report_figures.plot_per_map(maps[maps["map"] != MEAN_ROW], tmp_path / "f.png", intervals=interval_lookup(spans),
                                bar=BAR)
    heldout, real = kept["fig"].axes
    segments = [seg for c in heldout.collections for seg in c.get_segments()]
    marker_x = {line.get_label(): line.get_xdata() for line in heldout.lines if line.get_linestyle() == "None"}
    expected = [(x, 100 * r["success_interval"][0], 100 * r["success_interval"][1])
                for x, r in zip(marker_x["single"], DOCS[0]["maps"])]
    assert len(segments) == 2   # single on a and big; general's one map has none
    for seg, (x, low, high) in zip(segments, expected):
        assert seg[:, 0] == pytest.approx([x, x]) and seg[:, 1] == pytest.approx([low, high])
    dotted = [line for line in heldout.lines if line.get_linestyle() == ":"]
    assert len(dotted) == 1 and list(dotted[0].get_ydata()) == [95.0, 95.0]
    assert "vertical lines: 95 % interval" in heldout.get_title()
    kept.clear()
    report_figures.plot_per_map(maps[maps["map"] != MEAN_ROW], tmp_path / "g.png")
    assert not kept["fig"].axes[0].collections and "interval" not in kept["fig"].axes[0].get_title()


def _broken(edit):
    doc = json.loads(json.dumps(DOCS[0]))
    edit(doc)
    return doc


@pytest.mark.parametrize("edit, named", [
    (lambda d: d.update(maps=None), "its maps are None, not a list of per-map results"),
    (lambda d: d.update(maps=[]), "its maps are [], not a list of per-map results"),
    (lambda d: d.update(maps=[1, 2]), "map row 0 is 1, not a per-map result with a map name"),
    (lambda d: d["maps"][1].update(success_rate="0.5"), "map big: its success_rate is '0.5', not a fraction"),
    (lambda d: d["maps"][0].update(success_rate=1.7), "map a: its success_rate is 1.7, not a fraction in [0, 1]"),
    (lambda d: d["maps"][0].update(episodes=0), "map a: its episodes are 0, not a count >= 1"),
    (lambda d: d["maps"][0].update(success_interval=[0.5]), "map a: its success_interval is [0.5]"),
    (lambda d: d.update(label=None), "its label is None, not a name"),
    (lambda d: d.pop("machine"), "it has no machine"),
    (lambda d: d["aggregate"].pop("worst"), "its aggregate's worst is None"),
    (lambda d: d.update(format_version="1"), "format version '1' is not one this report reads (1 to 1)"),
    (lambda d: d.update(format_version=0), "format version 0 is not one this report reads"),
    (lambda d: d.update(format_version=True), "format version True is not one this report reads"),
    (lambda d: d.update(format_version=FORMAT + 1), f"format version {FORMAT + 1} is newer than this report reads"),
])
def test_a_malformed_eval_file_is_named_and_nothing_is_written(tmp_path, capsys, edit, named):
    from flashnav.cli import main

    path = tmp_path / "broken.json"
    path.write_text(json.dumps(_broken(edit)))
    out = tmp_path / "report"
    assert main(["report", "--generalisation", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "broken.json" in err and named in err, err
    assert not out.exists()


def test_one_policy_twice_on_a_suite_is_refused_not_merged(tmp_path):
    """A guided and an unguided eval of one policy file share the default label: one column would hold both."""
    first, second = tmp_path / "unguided.json", tmp_path / "guided.json"
    first.write_text(json.dumps(DOCS[0]))
    second.write_text(json.dumps({**DOCS[0], "guide_lookahead_m": 0.5}))
    with pytest.raises(ValueError, match=r"guided.json: policy 'single' on the heldout suite is already in "
                                         r".*unguided.json.*--label NAME"):
        load_evals([first, second])
    second.write_text(json.dumps({**DOCS[0], "label": "single, guided"}))
    assert [d["label"] for d in load_evals([first, second])] == ["single", "single, guided"]


def test_flags_that_only_the_mlflow_report_reads_are_refused_with_generalisation_alone(tmp_path, capsys):
    from flashnav.cli import main

    path = tmp_path / "e.json"
    path.write_text(json.dumps(DOCS[0]))
    out = tmp_path / "report"
    assert main(["report", "--generalisation", str(path), "--out", str(out), "--format", "tex"]) == 2
    assert "--format tex: the generalisation tables are written as md, csv, html" in capsys.readouterr().err
    assert main(["report", "--generalisation", str(path), "--out", str(out), "--invocation", "latest"]) == 2
    assert "--invocation latest selects MLflow sweep runs" in capsys.readouterr().err
    assert not out.exists()
