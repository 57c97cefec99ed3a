"""The generalisation tables of `flashnav report --generalisation EVAL_JSON...`: policies on map suites.

Input: the JSON files written by ``flashnav eval POLICY --maps SUITE --json FILE`` (``flashnav/eval_maps.py``,
kind ``flashnav.eval_maps``), one per policy and suite. Three tables, pure pandas (and, drawn from the second and
third by services.report_figures.plot_per_map, a figure of every map's success per policy):

- :func:`summary_table`: one row per file (policy x suite): mean / pooled / worst-map success, the maps under
  issue 15's 95 % bar (and those whose whole 95 % success interval lies under it), mean collision and timeout,
  maps and episodes, goal sampling, how many maps exceed the policy's goal-distance scale and how many episodes
  went beyond it, where and when it was measured.
- :func:`per_map_table`: one row per (suite, map), one success column per policy, and a mean row per suite;
  a policy not evaluated on a map leaves its cell empty.
- :func:`per_map_intervals`: one row per (suite, map, policy) with the success's 95 % interval (Wilson, as
  ``flashnav eval --maps`` wrote it), which the pages print beside each rate and the figure draws as a vertical
  line.
"""
from __future__ import annotations

import json
from html import escape
from pathlib import Path

import pandas as pd

# flashnav/eval_maps.py's EVAL_MAPS_KIND / EVAL_MAPS_FORMAT, spelt here so that the report does not import
# torch and the simulator; tests/test_report_generalisation.py checks that they agree
KIND = "flashnav.eval_maps"
FORMAT = 1
MEAN_ROW = "mean over maps"  # the per-map table's closing row of each suite
BAR = 0.95  # flashnav/eval_maps.py's MAP_BAR (the test checks that they agree)
STALL_M = 0.5  # flashnav/evaluate.py's STALL_M: a timeout under it in the horizon's second half stalled (tested too)
SUMMARY_COLUMNS = ["policy", "suite", "robot", "goal_sampling", "maps", "episodes_per_map", "success_mean",
                   "success_pooled", "success_worst", "worst_map", "maps_under_bar", "maps_surely_under_bar",
                   "collision_mean", "timeout_mean", "stalled_mean",
                   "maps_beyond_scale", "episodes_beyond_scale", "goal_distance_scale", "machine", "date"]


def load_evals(paths) -> list[dict]:
    """The eval JSON documents, in order. ValueError naming the file for a missing file, invalid JSON, another
    kind of document or a newer format."""
    docs, paths_seen = [], []
    for path in map(Path, paths):
        if not path.is_file():
            raise ValueError(f"--generalisation {path}: no such file (write one with flashnav eval POLICY --maps "
                             f"SUITE --json FILE)")
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except ValueError as exc:
            raise ValueError(f"--generalisation {path}: not valid JSON: {exc}") from None
        if not isinstance(doc, dict) or doc.get("kind") != KIND:
            raise ValueError(f"--generalisation {path}: not a `flashnav eval --maps --json` result (kind "
                             f"{doc.get('kind') if isinstance(doc, dict) else None!r}, expected {KIND!r})")
        version = doc.get("format_version")
        if isinstance(version, int) and not isinstance(version, bool) and version > FORMAT:
            raise ValueError(f"--generalisation {path}: format version {version} is newer than this report reads "
                             f"({FORMAT}); update flashnav")
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise ValueError(f"--generalisation {path}: format version {version!r} is not one this report reads "
                             f"(1 to {FORMAT})")
        if problem := doc_problem(doc):
            raise ValueError(f"--generalisation {path}: {problem}")
        seen = [(p, d) for p, d in zip(paths_seen, docs) if (d["label"], d["suite"]) == (doc["label"], doc["suite"])]
        if seen:
            raise ValueError(f"--generalisation {path}: policy {doc['label']!r} on the {doc['suite']} suite is "
                             f"already in {seen[0][0]}; the two would share one column: name them apart with "
                             f"flashnav eval ... --label NAME (e.g. a guided and an unguided run of one policy)")
        docs.append(doc)
        paths_seen.append(path)
    if not docs:
        raise ValueError("--generalisation needs at least one JSON file")
    return docs


def _rate(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 1


def doc_problem(doc: dict) -> str | None:
    """What makes an eval document unreadable by these tables (None: nothing): the names, the per-map rows (a
    ``map`` name, ``episodes`` >= 1, success / collision / timeout rates in [0, 1], an optional two-number
    ``success_interval``) and the aggregate that :func:`summary_table` reads."""
    for key in ("label", "suite", "robot"):
        if not isinstance(doc.get(key), str) or not doc[key]:
            return f"its {key} is {doc.get(key)!r}, not a name"
    for key in ("goal_sampling", "episodes_per_map", "goal_distance_scale", "machine", "date"):
        if key not in doc:
            return f"it has no {key}"
    rows = doc.get("maps")
    if not isinstance(rows, list) or not rows:
        return f"its maps are {rows!r:.40}, not a list of per-map results"
    for i, r in enumerate(rows):
        if not isinstance(r, dict) or not isinstance(r.get("map"), str):
            return f"map row {i} is {r!r:.60}, not a per-map result with a map name"
        for key in ("success_rate", "collision_rate", "timeout_rate"):
            if not _rate(r.get(key)):
                return f"map {r['map']}: its {key} is {r.get(key)!r}, not a fraction in [0, 1]"
        if not isinstance(r.get("episodes"), int) or isinstance(r.get("episodes"), bool) or r["episodes"] < 1:
            return f"map {r['map']}: its episodes are {r.get('episodes')!r}, not a count >= 1"
        interval = r.get("success_interval")
        if interval is not None and not (isinstance(interval, list) and len(interval) == 2
                                         and all(_rate(x) for x in interval)):
            return f"map {r['map']}: its success_interval is {interval!r}, not [low, high] fractions"
    a = doc.get("aggregate")
    if not isinstance(a, dict):
        return f"its aggregate is {a!r:.40}, not an object"
    for part, keys in (("mean", ("success_rate", "collision_rate", "timeout_rate")), ("pooled", ("success_rate",)),
                       ("worst", ("success_rate",))):
        if not isinstance(a.get(part), dict) or not all(_rate(a[part].get(k)) for k in keys):
            return f"its aggregate's {part} is {a.get(part)!r:.60}, not {', '.join(keys)} fractions"
    if not isinstance(a["worst"].get("map"), str):
        return "its aggregate's worst names no map"
    for key in ("maps", "maps_beyond_scale", "episodes_beyond_scale"):
        if key not in a:
            return f"its aggregate has no {key}"
    return None


def summary_table(docs: list[dict]) -> pd.DataFrame:
    """One row per eval document (columns :data:`SUMMARY_COLUMNS`; rates as fractions)."""
    rows = []
    for d in docs:
        a = d["aggregate"]
        rows.append({
            "policy": d["label"], "suite": d["suite"], "robot": d["robot"], "goal_sampling": d["goal_sampling"],
            "maps": a["maps"], "episodes_per_map": d["episodes_per_map"],
            "success_mean": a["mean"]["success_rate"], "success_pooled": a["pooled"]["success_rate"],
            "success_worst": a["worst"]["success_rate"], "worst_map": a["worst"]["map"],
            "maps_under_bar": sum(r["success_rate"] < BAR for r in d["maps"]),
            "maps_surely_under_bar": sum(_high(r) < BAR for r in d["maps"]),
            "collision_mean": a["mean"]["collision_rate"], "timeout_mean": a["mean"]["timeout_rate"],
            # the timeouts that stalled (flashnav eval counts them since 2026-12-04; None in older files)
            "stalled_mean": a["mean"].get("stalled_rate"),
            "maps_beyond_scale": a["maps_beyond_scale"], "episodes_beyond_scale": a["episodes_beyond_scale"],
            "goal_distance_scale": d["goal_distance_scale"], "machine": d["machine"], "date": d["date"]})
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def _high(row: dict) -> float:
    """The top of a map row's success interval (``success_interval``; files written before it: the rate)."""
    return (row.get("success_interval") or [row["success_rate"]] * 2)[1]


def per_map_table(docs: list[dict]) -> pd.DataFrame:
    """Columns ``suite``, ``map`` and one per policy label (success fraction, NaN where not evaluated); a
    ``mean over maps`` row closes each suite (the mean over the maps that policy was evaluated on)."""
    policies = list(dict.fromkeys(d["label"] for d in docs))
    cells: dict[tuple[str, str], dict[str, float]] = {}
    for d in docs:
        for r in d["maps"]:
            cells.setdefault((d["suite"], r["map"]), {})[d["label"]] = r["success_rate"]
    rows = []
    for suite in dict.fromkeys(s for s, _ in cells):
        maps = [(s, m) for s, m in cells if s == suite]
        rows += [{"suite": s, "map": m, **cells[(s, m)]} for s, m in maps]
        mean = {}
        for p in policies:
            values = [cells[k][p] for k in maps if p in cells[k]]
            if values:
                mean[p] = sum(values) / len(values)
        rows.append({"suite": suite, "map": MEAN_ROW, **mean})
    return pd.DataFrame(rows, columns=["suite", "map", *policies])


INTERVAL_COLUMNS = ["suite", "map", "policy", "episodes", "success", "success_low", "success_high"]


def per_map_intervals(docs: list[dict]) -> pd.DataFrame:
    """One row per (suite, map, policy): columns :data:`INTERVAL_COLUMNS`, fractions; the interval NaN in files
    written before ``flashnav eval --maps`` recorded it."""
    rows = []
    for d in docs:
        for r in d["maps"]:
            low, high = r.get("success_interval") or (float("nan"), float("nan"))
            rows.append({"suite": d["suite"], "map": r["map"], "policy": d["label"], "episodes": r["episodes"],
                         "success": r["success_rate"], "success_low": low, "success_high": high})
    return pd.DataFrame(rows, columns=INTERVAL_COLUMNS)


def _pct(x) -> str:
    return "" if pd.isna(x) else f"{100 * x:.1f}"


def _cell(rate, interval) -> str:
    """A per-map cell in per cent: the rate, and its interval in brackets where one is known."""
    if pd.isna(rate) or interval is None:
        return _pct(rate)
    return f"{_pct(rate)} ({_pct(interval[0])}-{_pct(interval[1])})"


def interval_lookup(intervals: pd.DataFrame | None) -> dict[tuple[str, str, str], tuple[float, float]]:
    """:func:`per_map_intervals` as {(suite, map, policy): (low, high)}, the known intervals only (the pages'
    cells and services.report_figures.plot_per_map read it)."""
    if intervals is None:
        return {}
    return {(r["suite"], r["map"], r["policy"]): (r["success_low"], r["success_high"])
            for r in intervals.to_dict("records") if pd.notna(r["success_low"]) and pd.notna(r["success_high"])}


def summary_markdown(table: pd.DataFrame) -> str:
    head = ["Policy", "Suite", "Robot", "Goals", "Maps x episodes", "Success mean %", "Pooled %", "Worst map %",
            f"Maps < {100 * BAR:g} % (wholly)", "Collision %", "Timeout % (stalled)", "Beyond goal scale", "Machine",
            "Date"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * 5 + "--:|" * 7 + "---|" * 2]
    for r in table.to_dict("records"):
        beyond = (f"{r['maps_beyond_scale']}/{r['maps']} maps, {r['episodes_beyond_scale']} ep"
                  if r["maps_beyond_scale"] else "-")
        lines.append("| " + " | ".join([
            r["policy"], r["suite"], r["robot"], r["goal_sampling"], f"{r['maps']} x {r['episodes_per_map']}",
            _pct(r["success_mean"]), _pct(r["success_pooled"]), f"{_pct(r['success_worst'])} ({r['worst_map']})",
            f"{r['maps_under_bar']} ({r['maps_surely_under_bar']})", _pct(r["collision_mean"]),
            _pct(r["timeout_mean"]) + (f" ({_pct(r['stalled_mean'])})" if pd.notna(r["stalled_mean"]) else ""),
            beyond, r["machine"], r["date"]]) + " |")
    return "\n".join(lines) + "\n"


def per_map_markdown(table: pd.DataFrame, intervals: pd.DataFrame | None = None) -> str:
    """:func:`per_map_table` in per cent; with ``intervals`` (:func:`per_map_intervals`) each map's rate is
    followed by its 95 % interval in brackets."""
    policies = list(table.columns[2:])
    known = interval_lookup(intervals)
    lines = ["| Suite | Map | " + " | ".join(f"{p} success %" for p in policies) + " |",
             "|---|---|" + "--:|" * len(policies)]
    for r in table.to_dict("records"):
        bold = r["map"] == MEAN_ROW
        cells = [_cell(r[p], known.get((r["suite"], r["map"], p))) for p in policies]
        if bold:
            cells = [f"**{c}**" if c else c for c in cells]
        lines.append("| " + " | ".join([r["suite"], f"**{r['map']}**" if bold else r["map"], *cells]) + " |")
    return "\n".join(lines) + "\n"


def markdown(summary: pd.DataFrame, maps: pd.DataFrame, figure: str | None = None,
             intervals: pd.DataFrame | None = None) -> str:
    """The page: :func:`summary_table` and :func:`per_map_table` (with ``intervals``: each rate's interval) as
    Markdown, with what they mean, and the per-map figure's file (``figure``, relative to the page) where one
    was drawn."""
    shown = [f"![success per map]({figure})", ""] if figure else []
    return "\n".join([
        "# Generalisation", "",
        "Success of each policy on map suites it was not trained on (`flashnav eval POLICY --maps SUITE`): the "
        "same fixed episodes per map for every policy, deterministic policy. Mean: over maps; pooled: over all "
        "episodes; worst: the map with the lowest success. Maps < 95 %: the maps under the bar, in brackets "
        "those whose whole 95 % success interval (Wilson) lies under it, so that another draw of as many episodes "
        "would not lift them over it. Timeout: in brackets the timeouts that stalled (the robot drove under "
        f"{STALL_M:g} m in the second half of the horizon: parked or turning on the spot). 'Beyond goal scale': maps "
        "whose diagonal exceeds the "
        "policy's goal-distance scale (its training map's diagonal), and the episodes whose goal-distance input "
        "went beyond it (passed unclipped). Per map: the success and, in brackets, its 95 % interval (the "
        "figure's vertical lines; its dotted line is the 95 % bar).", "",
        summary_markdown(summary), "## Success per map", "", *shown, per_map_markdown(maps, intervals)])


def html(summary: pd.DataFrame, maps: pd.DataFrame, figure: str | None = None,
         intervals: pd.DataFrame | None = None) -> str:
    """A page with :func:`summary_table` and :func:`per_map_table` (with ``intervals``: each rate's interval;
    escaped cells; the tables given are left as they are) and the per-map figure's file (``figure``, relative
    to the page) where one was drawn."""
    shown = f"<img src='{escape(figure, quote=True)}' alt='success per map'>" if figure else ""
    summary = summary.assign(**{c: summary[c].map(_pct) for c in
                                ("success_mean", "success_pooled", "success_worst", "collision_mean", "timeout_mean",
                                 "stalled_mean")})
    known = interval_lookup(intervals)
    maps = maps.assign(**{p: [_cell(rate, known.get((suite, name, p)))
                              for suite, name, rate in zip(maps["suite"], maps["map"], maps[p])]
                          for p in maps.columns[2:]})
    style = ("body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;margin-bottom:2em}"
             "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:nth-child(-n+2){text-align:left}")
    return ("<!doctype html><html><head><meta charset='utf-8'><title>FlashNav generalisation</title>"
            f"<style>{style}</style></head><body><h1>Generalisation</h1>"
            "<p>Success rates in per cent, per map with the 95 % interval in brackets; see generalisation.md for "
            "the columns.</p><h2>Policies x suites</h2>"
            + summary.to_html(index=False, escape=True) + "<h2>Success per map (%)</h2>" + shown
            + maps.to_html(index=False, escape=True, na_rep="") + "</body></html>\n")


def write_generalisation(paths, out_dir, formats=("md", "csv", "html")) -> dict[str, Path]:
    """Write generalisation.md / generalisation.csv + generalisation_maps.csv + generalisation_intervals.csv /
    generalisation.html (the formats among ``formats``) into ``out_dir``, and the per-map figure
    generalisation.png (with "html", "png" or "svg"; .svg too with "svg"), which the pages show; returns
    {name: Path}."""
    docs = load_evals(paths)
    # the rows, once; each format below formats them
    summary, maps, intervals = summary_table(docs), per_map_table(docs), per_map_intervals(docs)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written, figure = {}, None
    if {"html", "png", "svg"} & set(formats):
        from services.report_figures import plot_per_map  # matplotlib only when a figure is asked for

        written["generalisation_png"] = plot_per_map(maps[maps["map"] != MEAN_ROW], out / "generalisation.png",
                                                     svg="svg" in formats, intervals=interval_lookup(intervals),
                                                     bar=BAR)[0]
        figure = written["generalisation_png"].name

    def put(name, filename, text):
        (out / filename).write_text(text, encoding="utf-8")
        written[name] = out / filename

    if "md" in formats:
        put("generalisation_md", "generalisation.md", markdown(summary, maps, figure, intervals))
    if "csv" in formats:
        put("generalisation_csv", "generalisation.csv",
            summary.to_csv(index=False, float_format="%.4f", lineterminator="\n"))
        put("generalisation_maps_csv", "generalisation_maps.csv",
            maps.to_csv(index=False, float_format="%.4f", lineterminator="\n"))
        put("generalisation_intervals_csv", "generalisation_intervals.csv",
            intervals.to_csv(index=False, float_format="%.4f", lineterminator="\n"))
    if "html" in formats:
        put("generalisation_html", "generalisation.html", html(summary, maps, figure, intervals))
    return written
