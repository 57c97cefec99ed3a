"""Seed-aggregated threshold tables (the paper's Table 2) and their Markdown / LaTeX / CSV writers.

Pure functions over pandas DataFrames; no MLflow here. Input: the normalised run frame of
`services.report.normalize_runs` (one row per trial; tags and metrics as plain columns, see
docs/run-schema.md). Times are wall-clock training seconds (`time_to_90` etc., censored where
`reached_90 == 0`).
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from flashnav.machine import split_device_name
from flashnav.learn.hparams import paper_budget
from flashnav.metrics import THRESHOLD_TAGS, bootstrap_mean_ci, over_seeds, within_budget  # noqa: F401 - bootstrap_mean_ci re-exported
from flashnav.metrics import on_paper_task
from flashnav.names import ALGORITHM_LABELS, ROBOT_LABELS

THRESHOLDS = THRESHOLD_TAGS  # column-name tags: "90" -> best_90, "90% success"
GROUP = ("embodiment", "algorithm", "platform")
#: What a threshold table measures: training seconds, or environment steps (machine-independent).
KINDS = ("time_to", "env_steps_to")
PAPER_CSV = Path(__file__).resolve().parent / "data" / "paper_table2.csv"

# Display order and names follow the paper; unknown names sort after these, alphabetically.
ROBOT_ORDER = ROBOT_LABELS  # robot name -> label; the dict's order is the tables' row order
ALGO_ORDER = ALGORITHM_LABELS
MISSING = "—"


def _order_key(values: pd.Series, known: dict) -> pd.Series:
    rank = {name: i for i, name in enumerate(known)}
    return values.map(lambda v: (rank.get(v, len(rank)), str(v)))


def split_platform(runs: pd.DataFrame) -> pd.DataFrame:
    """A copy with ``device_name`` = the machine and ``threads`` (Int64, NA where unknown: GPU runs).

    threads comes from the ``threads`` tag, else from a name of the old spelling ``CPU (2 threads)``
    (runs logged before the tag existed), whose suffix is split off the machine so that a machine's
    runs form one platform whatever their thread setting. Idempotent.
    """
    out = runs.copy()
    names = out["device_name"] if "device_name" in out else pd.Series(pd.NA, index=out.index, dtype=object)
    parts = [split_device_name(None if pd.isna(v) else str(v)) for v in names]
    out["device_name"] = pd.Series([m if m is not None else pd.NA for m, _ in parts], index=out.index, dtype=object)
    tagged = pd.to_numeric(out["threads"], errors="coerce") if "threads" in out else \
        pd.Series(math.nan, index=out.index)
    parsed = pd.Series([math.nan if t is None else float(t) for _, t in parts], index=out.index)
    out["threads"] = tagged.astype(float).fillna(parsed).round().astype("Int64")
    return out


def _threads_cell(values: pd.Series) -> str:
    """Distinct thread counts of a row's runs, "1" or "1, 2"; "" where none is known (GPU runs)."""
    return ", ".join(str(int(v)) for v in sorted(set(values.dropna().astype(int))))


def threshold_table(runs: pd.DataFrame, thresholds=THRESHOLDS, kind: str = "time_to") -> pd.DataFrame:
    """Best / mean seconds (``kind="time_to"``) or environment steps (``kind="env_steps_to"``) to each
    success threshold, one row per embodiment x algorithm x platform.

    runs: one row per trial with columns robot, algorithm, device_name, time_to_<t> [s], reached_<t>
    and optionally threads (split_platform is applied: the platform is the machine).
    Returns columns embodiment, algorithm, platform (the machine), n (seeds), and per threshold t:
    best_<t>, mean_<t> [s] (over seeds with reached_<t> == 1; NaN when none), reached_<t> (k),
    ci_low_<t>, ci_high_<t> [s] (95 % bootstrap of the mean; None when k < 2),
    bold_best_<t>, bold_mean_<t> (the lowest value among platforms of the same embodiment x algorithm;
    ties are all bold; cells without a value are never bold), then threads (the learner thread
    counts of the row's runs, "1, 2"; "" on GPUs). With ``kind="env_steps_to"`` also budget (the
    paper's env-step budget of the embodiment x algorithm, flashnav.learn.hparams.paper_budget; NaN
    where the paper has none or the row's runs are not all on the paper's task, :func:`runs_on_paper_task`) and
    budget_<t> (seeds that reached t within it).
    """
    if kind not in KINDS:
        raise ValueError(f"unknown table kind {kind!r}; use one of {', '.join(KINDS)}")
    rows = []
    frame = split_platform(runs).rename(columns={"robot": "embodiment", "device_name": "platform"})
    for key, grp in frame.groupby(list(GROUP), sort=False, dropna=False):
        row = dict(zip(GROUP, key))
        row["n"] = int(len(grp))
        for t in thresholds:
            values = grp[f"{kind}_{t}"].astype(float).to_numpy()
            reached = grp[f"reached_{t}"].fillna(0).astype(float).to_numpy()
            stats = over_seeds(values, reached=reached)
            if kind == "env_steps_to":
                budget = paper_budget(str(row["algorithm"]), str(row["embodiment"])) if runs_on_paper_task(grp) else None
                row["budget"] = math.nan if budget is None else budget
                row[f"budget_{t}"] = within_budget(values, budget, reached)
            row[f"best_{t}"] = stats.best if stats.k else math.nan
            row[f"mean_{t}"] = stats.mean if stats.k else math.nan
            row[f"reached_{t}"] = stats.k
            row[f"ci_low_{t}"], row[f"ci_high_{t}"] = stats.ci if stats.ci else (None, None)
        row["threads"] = _threads_cell(grp["threads"])
        rows.append(row)
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    for col in [c for c in table if c.startswith("ci_")]:
        # None, not NaN, marks "no interval" (k < 2): DataFrame construction turned it into NaN
        table[col] = pd.Series([None if pd.isna(v) else float(v) for v in table[col]], dtype=object)
    table = sort_table(table)
    return mark_best(table, thresholds)


def runs_on_paper_task(runs: pd.DataFrame) -> bool:
    """Whether every run of the frame is on the paper's task (flashnav.metrics.on_paper_task over its
    ``params.*`` columns); a frame without those params (runs logged before configs were) counts as on it."""
    cols = [c for c in runs.columns if c.startswith("params.")]
    return all(on_paper_task({c[len("params."):]: v for c, v in zip(cols, values)})
               for values in runs[cols].itertuples(index=False, name=None))


def sort_table(table: pd.DataFrame, platforms: list[str] | None = None) -> pd.DataFrame:
    """Paper order for robots and algorithms; platforms in the given order, else by name (the same
    order in every group)."""
    keys = pd.DataFrame({"e": _order_key(table["embodiment"], ROBOT_ORDER),
                         "a": _order_key(table["algorithm"], ALGO_ORDER),
                         "p": _order_key(table["platform"], dict.fromkeys(platforms or []))})
    order = sorted(range(len(table)), key=lambda i: (keys["e"].iat[i], keys["a"].iat[i], keys["p"].iat[i]))
    return table.iloc[order].reset_index(drop=True)


def mark_best(table: pd.DataFrame, thresholds=THRESHOLDS) -> pd.DataFrame:
    """Add bold_best_<t> / bold_mean_<t>: the paper bolds, per column, the fastest platform of a group."""
    table = table.copy()
    for t in thresholds:
        for stat in ("best", "mean"):
            col = f"{stat}_{t}"
            if col not in table:
                continue
            group_min = table.groupby(["embodiment", "algorithm"], sort=False)[col].transform("min")
            # Exact float equality is intended: ties come from identical logged values.
            table[f"bold_{col}"] = table[col].notna() & (table[col] == group_min)
    return table


def load_paper_table(path: str | Path = PAPER_CSV) -> pd.DataFrame:
    """The paper's published Table 2 in threshold_table's layout (k, n and intervals unknown)."""
    paper = pd.read_csv(path, comment="#")
    paper = paper.rename(columns={"seeds": "n"})
    for t in THRESHOLDS:
        paper[f"reached_{t}"] = pd.NA
        paper[f"ci_low_{t}"], paper[f"ci_high_{t}"] = None, None
    return mark_best(sort_table(paper, platforms=list(dict.fromkeys(paper["platform"]))))  # paper's row order


def comparison_table(ours: pd.DataFrame, paper: pd.DataFrame) -> pd.DataFrame:
    """Both tables stacked with a `source` column ("this report" / "paper"), for CSV and plotting."""
    cols = [c for c in ours.columns if c in paper.columns]
    return pd.concat([ours[cols].assign(source="this report"), paper[cols].assign(source="paper")],
                     ignore_index=True)


# ---------------------------------------------------------------- display (shared by md / tex / html)

def short_platform(name: str) -> str:
    """'NVIDIA GeForce RTX 5090' -> 'RTX 5090', the paper's platform labels; others unchanged."""
    s = str(name)
    for prefix in ("NVIDIA ", "GeForce "):
        s = s[len(prefix):] if s.startswith(prefix) else s
    return s


def fmt_s(x) -> str:
    """Seconds with one decimal, as in the paper; MISSING when no seed reached."""
    return MISSING if x is None or (isinstance(x, float) and math.isnan(x)) or pd.isna(x) else f"{x:.1f}"


def fmt_steps(x) -> str:
    """Environment steps with thousands separators; MISSING when no seed reached."""
    return MISSING if x is None or (isinstance(x, float) and math.isnan(x)) or pd.isna(x) else f"{x:,.0f}"


def is_steps(table: pd.DataFrame) -> bool:
    """Whether ``table`` is an env-steps table (it carries the paper's budget)."""
    return "budget" in table


def display_rows(table: pd.DataFrame, with_counts: bool = True, thresholds=THRESHOLDS) -> list[dict]:
    """Rows ready to print: labels, row spans for the multirow cells, and per-threshold cells.

    Each cell is {"text", "bold", "ci"} (ci: "[low, high]" or ""). Spans are 0 on continuation rows.
    ``threads`` is the row's thread counts (MISSING where none is known), None for tables without them
    (the paper's).
    """
    out = []
    fmt = fmt_steps if is_steps(table) else fmt_s
    for i, r in table.reset_index(drop=True).iterrows():
        cells = []
        for t in thresholds:
            cells.append({"text": fmt(r[f"best_{t}"]), "bold": bool(r.get(f"bold_best_{t}", False)), "ci": ""})
            lo, hi = r.get(f"ci_low_{t}"), r.get(f"ci_high_{t}")
            ci = f"[{fmt(lo)}, {fmt(hi)}]" if lo is not None and not pd.isna(lo) else ""
            cells.append({"text": fmt(r[f"mean_{t}"]), "bold": bool(r.get(f"bold_mean_{t}", False)), "ci": ci})
            if with_counts:
                cells.append({"text": f"{int(r[f'reached_{t}'])}/{int(r['n'])}", "bold": False, "ci": ""})
        if is_steps(table):  # the paper-budget view: 100 % reached within the paper's env steps, k/n
            last = thresholds[-1]
            cells.append({"text": MISSING if pd.isna(r["budget"]) else
                          f"{int(r[f'budget_{last}'])}/{int(r['n'])} (≤ {fmt_steps(r['budget'])})",
                          "bold": False, "ci": ""})
        out.append({"embodiment": ROBOT_ORDER.get(r["embodiment"], str(r["embodiment"])),
                    "algorithm": ALGO_ORDER.get(r["algorithm"], str(r["algorithm"])),
                    "platform": short_platform(r["platform"]), "cells": cells,
                    "threads": (r["threads"] or MISSING) if "threads" in table else None,
                    "embodiment_span": 0, "algorithm_span": 0, "new_embodiment": False, "new_algorithm": False})
    for i, row in enumerate(out):
        e, a = table["embodiment"].iat[i], table["algorithm"].iat[i]
        if i == 0 or table["embodiment"].iat[i - 1] != e:
            row["new_embodiment"] = row["new_algorithm"] = True
            row["embodiment_span"] = int((table["embodiment"].iloc[i:] == e).cummin().sum())
        if row["new_embodiment"] or table["algorithm"].iat[i - 1] != a:
            row["new_algorithm"] = True
            same = (table["embodiment"].iloc[i:] == e) & (table["algorithm"].iloc[i:] == a)
            row["algorithm_span"] = int(same.cummin().sum())
    return out


def has_threads(table: pd.DataFrame) -> bool:
    """Whether the table shows a Threads column (ours do; the paper's table has no thread counts)."""
    return "threads" in table


def header_cells(with_counts: bool = True, thresholds=THRESHOLDS, budget: bool = False) -> tuple[list[str], list[str]]:
    """(threshold group labels, sub-column labels); ``budget`` adds the paper-budget group (one column)."""
    sub = ["Best", "Mean", "k/n"] if with_counts else ["Best", "Mean"]
    groups, cols = [f"{t}% success" for t in thresholds], sub * len(thresholds)
    if budget:
        groups, cols = groups + [f"{thresholds[-1]}% in paper budget"], cols + ["k/n"]
    return groups, cols


def to_markdown(table: pd.DataFrame, with_counts: bool = True) -> str:
    """GitHub Markdown table; bold cells as **x**; the bootstrap interval after the mean."""
    groups, sub = header_cells(with_counts)
    per = len(sub) // len(groups)
    labels = ["Embodiment", "Algorithm", "Platform"] + (["Threads"] if has_threads(table) else [])
    head = labels + [f"{g.split()[0]} {s}" for g in groups for s in sub[:per]]
    if is_steps(table):
        head, sub = head + [f"{THRESHOLDS[-1]}% in paper budget"], sub + ["budget"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(labels) + "--:|" * len(sub)]
    for row in display_rows(table, with_counts):
        cells = []
        for c in row["cells"]:
            text = f"**{c['text']}**" if c["bold"] else c["text"]
            cells.append(f"{text} {c['ci']}".strip())
        lead = [row["embodiment"], row["algorithm"], row["platform"]] + ([row["threads"]] if row["threads"] else [])
        lines.append("| " + " | ".join(lead + cells) + " |")
    return "\n".join(lines) + "\n"


_TEX_ESCAPE = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
               "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def latex_escape(text: str) -> str:
    return "".join(_TEX_ESCAPE.get(ch, ch) for ch in str(text))


def to_latex(table: pd.DataFrame, with_counts: bool = True, caption: str | None = None,
             label: str = "tab:flashnav_report_thresholds") -> str:
    """A booktabs + multirow `table*` like the paper's Table 2 (needs \\usepackage{booktabs,multirow})."""
    groups, sub = header_cells(with_counts)
    threads = has_threads(table)
    nlead = 4 if threads else 3  # label columns before the per-threshold cells
    per, ncol = len(sub) // len(groups), nlead + len(sub)
    if caption is None:
        caption = ("Time to success threshold over seeds: best / mean wall-clock seconds computed over "
                   "reached seeds only" + (", $k/n$ seeds reached, 95\\,\\% bootstrap interval of the mean "
                                           "in brackets" if with_counts else "") + ". Bold: fastest platform.")
    spec = "l" * nlead + "".join("c" * per for _ in groups)
    head1 = " & ".join([r"\multirow{2}{*}{Embodiment}", r"\multirow{2}{*}{Algorithm}",
                        r"\multirow{2}{*}{Platform}"] + ([r"\multirow{2}{*}{Threads}"] if threads else [])
                       + [rf"\multicolumn{{{per}}}{{c}}{{{latex_escape(g)}}}" for g in groups]) + r" \\"
    rules = " ".join(rf"\cmidrule(lr){{{nlead + 1 + i * per}-{nlead + (i + 1) * per}}}" for i in range(len(groups)))
    head2 = " " + "& " * nlead + " & ".join(r"$k/n$" if s == "k/n" else s for s in sub) + r" \\"
    body = []
    for i, row in enumerate(display_rows(table, with_counts)):
        if i and row["new_embodiment"]:
            body.append(r"\midrule")
        elif i and row["new_algorithm"]:
            body.append(rf"\cmidrule(lr){{2-{ncol}}}")
        emb = rf"\multirow{{{row['embodiment_span']}}}{{*}}{{{latex_escape(row['embodiment'])}}}" \
            if row["embodiment_span"] else ""
        alg = rf"\multirow{{{row['algorithm_span']}}}{{*}}{{{latex_escape(row['algorithm'])}}}" \
            if row["algorithm_span"] else ""
        cells = []
        for c in row["cells"]:
            text = "--" if c["text"] == MISSING else latex_escape(c["text"])
            text = rf"\textbf{{{text}}}" if c["bold"] else text
            cells.append(text + (rf"\,{{\scriptsize{latex_escape(c['ci'])}}}" if c["ci"] else ""))
        tcell = "--" if row["threads"] == MISSING else latex_escape(row["threads"])
        lead = [emb, alg, latex_escape(row["platform"])] + ([tcell] if threads else [])
        body.append(" & ".join(lead + cells) + r" \\")
    return "\n".join([r"\begin{table*}[t]", r"\centering", rf"\caption{{{caption}}}", rf"\label{{{label}}}",
                      r"\setlength{\tabcolsep}{4pt}", rf"\begin{{tabular}}{{{spec}}}", r"\toprule", head1,
                      rules, head2, r"\midrule", *body, r"\bottomrule", r"\end{tabular}", r"\end{table*}", ""])


def latex_document(fragments: list[str]) -> str:
    """A standalone document around table fragments (landscape: the 12-column table is wide)."""
    return "\n".join([r"\documentclass{article}", r"\usepackage[a4paper,landscape,margin=1.5cm]{geometry}",
                      r"\usepackage[T1]{fontenc}", r"\usepackage{booktabs}", r"\usepackage{multirow}",
                      r"\begin{document}", *fragments, r"\end{document}", ""])


def to_csv(table: pd.DataFrame) -> str:
    """Machine-readable table: raw names (robot key, full device_name), seconds with 3 decimals."""
    floats = {c: pd.to_numeric(table[c], errors="coerce") for c in table if c.startswith("ci_")}
    return table.assign(**floats).to_csv(index=False, float_format="%.3f", lineterminator="\n")
