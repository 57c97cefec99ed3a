"""Render the report page (index.html) from dashboards/report.html.j2.

Figures are inlined as base64 PNG so the single file reads offline and survives being mailed or moved.
"""
from __future__ import annotations

import base64
from pathlib import Path

import jinja2
import pandas as pd

from services.report_tables import display_rows, has_threads, header_cells, is_steps

TEMPLATE = Path(__file__).resolve().parents[1] / "dashboards" / "report.html.j2"
FIGURE_CAPTIONS = {
    "curves_return": "Evaluation return vs env steps: mean over seeds, shaded ± standard error; one panel "
                     "per robot × algorithm, one line per platform.",
    "curves_success": "Success rate vs env steps (mean ± standard error over seeds).",
    "success_vs_time": "Success rate vs training seconds: the wall-clock view behind the threshold table.",
    "cycle_breakdown": "Mean collector and learner milliseconds per training cycle; the dashed line marks "
                       "the effective cycle (slower side when overlapped).",
}


def _table_context(table: pd.DataFrame, with_counts: bool) -> dict:
    budget = is_steps(table)
    groups, sub = header_cells(with_counts, budget=budget)
    per = len(sub[:-1] if budget else sub) // (len(groups) - budget)  # the budget group is one column wide
    spans = [(g, 1 if budget and i == len(groups) - 1 else per) for i, g in enumerate(groups)]
    return {"groups": spans, "sub": sub, "threads": has_threads(table),
            "rows": display_rows(table, with_counts) if not table.empty else []}


def _data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def render_html(ours: pd.DataFrame, paper: pd.DataFrame, figures: dict, provenance: dict,
                template: str | Path = TEMPLATE, steps: pd.DataFrame | None = None) -> str:
    """The dashboard page as a string. ours / paper: seconds tables; steps: the env-steps table (the
    headline); figures: {name: png path}; provenance: see write_report."""
    template = Path(template)
    if not template.is_file():
        raise FileNotFoundError(f"report template not found: {template} (it lives in the repository's "
                                f"dashboards/ folder)")
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(template.parent)),
                             autoescape=jinja2.select_autoescape(["html", "j2"]),
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    figs = [{"name": name, "src": _data_uri(p), "caption": FIGURE_CAPTIONS.get(name, name)}
            for name, p in figures.items() if Path(p).suffix == ".png"]
    return env.get_template(template.name).render(
        ours=_table_context(ours, True), paper=_table_context(paper, False), figures=figs, prov=provenance,
        steps=_table_context(steps, True) if steps is not None else None)
