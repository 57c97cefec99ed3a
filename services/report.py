"""MLflow runs -> the paper's tables and figures, and the `flashnav report` command.

Data contract: docs/run-schema.md (one nested child run per Tune trial, tags robot / algorithm /
seed / device_name (the machine) / threads, final metrics time_to_90 ... censored with reached_90 ...). Flow:

    load_runs (MLflow search -> normalize_runs: FINISHED only, one run per trial, typed columns)
      -> threshold_table (report_tables) -> Markdown / LaTeX / CSV
      -> curves (metric histories)        -> figures (report_figures)
      -> index.html (report_html + dashboards/report.html.j2)

MLflow is imported lazily: the table and figure code is pure pandas and tests without a store.
"""
from __future__ import annotations

import datetime as dt
import os
import re
import sys
from pathlib import Path

import pandas as pd

from services.paths import check_tracking_uri, redact_uri, resolve_tracking_uri
from services.report_select import pooling_warnings, select_invocation
from services.report_tables import (THRESHOLDS, comparison_table, latex_document, load_paper_table, split_platform,
                                    threshold_table, to_csv, to_latex, to_markdown)
from services.schema_base import CURVE_METRICS as ALL_CURVES
from services.schema_base import FINAL_METRICS

__all__ = ["NoRunsError", "default_tracking_uri", "normalize_runs", "load_runs", "curves", "threshold_table",
           "build_report", "write_report", "register_cli"]

#: the curves the report reads (the env_steps curve is every point's step, so it is not fetched again)
CURVE_METRICS = tuple(m for m in ALL_CURVES if m != "env_steps")
FORMATS = ("md", "tex", "csv", "html", "png", "svg")
_INT = re.compile(r"^[+-]?\d+$")
#: MLflow's HTTP settings for `flashnav report` (set only where the user has not set them)
HTTP_ENV = {"MLFLOW_HTTP_REQUEST_TIMEOUT": "30", "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2"}


class NoRunsError(LookupError):
    """Nothing to report: the message names the store and what was searched."""


def default_tracking_uri() -> str:
    """Where the sweeps write: $MLFLOW_TRACKING_URI, else ``sqlite:///<runs>/mlflow.db`` ($FLASHNAV_RUNS_DIR, else
    <project>/runs; services.paths.resolve_tracking_uri, the sweeps' own resolution, absolute so that the same file
    is found from any process)."""
    return resolve_tracking_uri(None)


def _cast_param(col: pd.Series) -> pd.Series:
    """MLflow stores params as strings: ints -> Int64, numbers -> float, True/False -> bool, else str."""
    s = col.dropna().astype(str)
    if s.empty:
        return col
    if s.map(lambda v: bool(_INT.match(v))).all():
        return pd.to_numeric(col).astype("Int64")
    num = pd.to_numeric(s, errors="coerce")
    if num.notna().all():
        return pd.to_numeric(col, errors="coerce").astype(float)
    if s.str.lower().isin(["true", "false"]).all():
        return col.map(lambda v: None if pd.isna(v) else str(v).lower() == "true").astype("boolean")
    return col


def normalize_runs(raw: pd.DataFrame) -> pd.DataFrame:
    """mlflow.search_runs-style frame (tags.*, params.*, metrics.* columns) -> one row per trial.

    Keeps child runs (role != "sweep") with robot and algorithm tags and status FINISHED, then per
    (sweep, trial_id) the run with the latest end_time (a restored trial can leave a duplicate; runs
    without trial_id count as their own trial). Filtering before de-duplicating matters: a later
    FAILED retry must not hide the trial's FINISHED run. Columns: run_id, experiment_id, status,
    start_time, end_time, tags by name (seed as int; device_name the machine and threads an Int64, an
    old-spelling name ``CPU (2 threads)`` split into both, see report_tables.split_platform),
    final metrics by name (float, NaN if absent),
    params as `params.<dotted key>` cast to int / float / bool where every value parses.
    Counts for the provenance block are left in `.attrs`.
    """
    if raw is None or raw.empty:
        out = pd.DataFrame(columns=["run_id", "status", "robot", "algorithm", "device_name", "threads", "seed",
                                    *FINAL_METRICS])
        out.attrs.update(n_runs=0, n_finished=0, n_not_finished=0, n_duplicates=0, n_trials=0)
        return out
    ren = {}
    for c in raw.columns:
        if c.startswith("tags."):
            name = c[len("tags."):]
            ren[c] = "parent_run_id" if name == "mlflow.parentRunId" else name
        elif c.startswith("metrics."):
            ren[c] = c[len("metrics."):]
    df = raw.rename(columns=ren)
    df = df.drop(columns=[c for c in df.columns if c.startswith("mlflow.")])
    for col in ("role", "robot", "algorithm", "sweep", "trial_id", "device_name", "seed"):
        if col not in df:
            df[col] = pd.NA
    trials = df[(df["role"].fillna("trial") != "sweep") & df["robot"].notna() & df["algorithm"].notna()]
    finished = trials[trials["status"] == "FINISHED"].copy()
    finished["_trial"] = finished["trial_id"].fillna(finished["run_id"]).astype(str)
    finished["_sweep"] = finished["sweep"].fillna("").astype(str)
    finished = finished.sort_values(["end_time", "start_time", "run_id"], na_position="first")
    kept = finished.drop_duplicates(["_sweep", "_trial"], keep="last").drop(columns=["_trial", "_sweep"])
    kept = split_platform(kept)
    kept["device_name"] = kept["device_name"].fillna("unknown device")
    kept["seed"] = pd.to_numeric(kept.get("seed"), errors="coerce").astype("Int64")
    for m in FINAL_METRICS:
        kept[m] = pd.to_numeric(kept[m], errors="coerce").astype(float) if m in kept else float("nan")
    for c in [c for c in kept.columns if c.startswith("params.")]:
        kept[c] = _cast_param(kept[c])
    kept = kept.sort_values(["robot", "algorithm", "device_name", "seed", "run_id"]).reset_index(drop=True)
    kept.attrs.update(n_runs=int(len(trials)), n_finished=int(len(finished)),
                      n_not_finished=int(len(trials) - len(finished)),
                      n_duplicates=int(len(finished) - len(kept)), n_trials=int(len(kept)))
    return kept


def _runs_to_frame(runs) -> pd.DataFrame:
    """MlflowClient Run objects -> the frame mlflow.search_runs would build (prefixed columns)."""
    rows = []
    for r in runs:
        row = {"run_id": r.info.run_id, "experiment_id": r.info.experiment_id, "status": r.info.status,
               "start_time": r.info.start_time, "end_time": r.info.end_time}
        row.update({f"metrics.{k}": v for k, v in r.data.metrics.items()})
        row.update({f"params.{k}": v for k, v in r.data.params.items()})
        row.update({f"tags.{k}": v for k, v in r.data.tags.items()})
        rows.append(row)
    df = pd.DataFrame(rows)
    for col in ("start_time", "end_time"):
        if col in df:
            df[col] = pd.to_datetime(df[col], unit="ms", utc=True)
    return df


def _searched(experiment, sweeps) -> str:
    what = [f"experiment(s) {', '.join(experiment)}" if experiment else "all experiments"]
    if sweeps:
        what.append(f"sweep tag(s) {', '.join(sweeps)}")
    return " with ".join(what)


def load_runs(tracking_uri: str | None = None, experiment: str | list[str] | None = None,
              sweeps: list[str] | None = None, invocation: str | None = None) -> pd.DataFrame:
    """Search MLflow for trial runs and normalise them (see normalize_runs).

    experiment: name(s) to search (None = all active experiments); sweeps: keep runs whose tag
    `sweep` is one of these; invocation: ``latest`` or a stamp keeps one invocation per sweep
    (services.report_select; None = every invocation). Uses an MlflowClient for the given URI rather than
    mlflow.search_runs, which reads the process-global tracking URI. Raises NoRunsError naming what was searched.
    """
    from mlflow import MlflowClient

    uri = tracking_uri or default_tracking_uri()
    check_tracking_uri(uri, read_only=True)  # (an empty file would get MLflow's tables)
    experiments = [experiment] if isinstance(experiment, str) else list(experiment or [])
    sweeps = list(sweeps or [])
    if uri.startswith("sqlite:///") and ":memory:" not in uri and not Path(uri[len("sqlite:///"):]).exists():
        # MLflow would silently create an empty store here; a missing file is a wrong path.
        raise NoRunsError(f"no MLflow store at {uri} (set --tracking-uri or MLFLOW_TRACKING_URI)")
    for s in sweeps:
        if "'" in s:
            raise ValueError(f"sweep name may not contain a quote: {s!r}")
    client = MlflowClient(uri)
    if experiments:
        found = {n: client.get_experiment_by_name(n) for n in experiments}
        missing = [n for n, e in found.items() if e is None]
        if missing:
            names = sorted(e.name for e in client.search_experiments())
            raise NoRunsError(f"no MLflow experiment named {', '.join(missing)} at {redact_uri(uri)}; "
                              f"experiments there: {', '.join(names) or 'none'}")
        exps = list(found.values())
    else:
        exps = client.search_experiments()
    names = {e.experiment_id: e.name for e in exps}
    runs = []
    for filt in [f"tags.sweep = '{s}'" for s in sweeps] or [""]:
        token = None
        while True:
            page = client.search_runs(list(names), filter_string=filt, max_results=5000, page_token=token)
            runs += list(page)
            token = page.token
            if not token:
                break
    df = normalize_runs(_runs_to_frame(runs))
    if df.empty:
        found = df.attrs.get("n_runs", 0)
        raise NoRunsError(f"no trial runs to report at {redact_uri(uri)} in {_searched(experiments, sweeps)}"
                          + (f" ({found} trial runs found, none FINISHED)" if found else ""))
    df["experiment"] = df["experiment_id"].map(names)
    return select_invocation(df, invocation)


def curves(tracking_uri: str | None, run_ids) -> pd.DataFrame:
    """Evaluation curves: columns run_id, step (env steps), success_rate (0..1), mean_return,
    train_seconds [s]; one row per run and evaluation. The last logged value wins where a
    (restored) run logged one step twice."""
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri or default_tracking_uri())
    rows = [(rid, key, m.step, m.timestamp, m.value)
            for rid in run_ids for key in CURVE_METRICS for m in client.get_metric_history(rid, key)]
    cols = ["run_id", "step", *CURVE_METRICS]
    if not rows:
        return pd.DataFrame(columns=cols)
    long = pd.DataFrame(rows, columns=["run_id", "metric", "step", "timestamp", "value"])
    long = long.sort_values("timestamp", kind="stable").drop_duplicates(["run_id", "metric", "step"], keep="last")
    wide = long.pivot(index=["run_id", "step"], columns="metric", values="value").reset_index()
    for c in CURVE_METRICS:
        if c not in wide:
            wide[c] = float("nan")
    return wide[cols].sort_values(["run_id", "step"]).reset_index(drop=True)


def provenance(runs: pd.DataFrame, tracking_uri: str = "", experiments=(), sweeps=()) -> dict:
    """What the report was built from: store, selection, run counts, code versions, UTC time."""
    def uniq(col):
        return sorted(str(v) for v in runs[col].dropna().unique()) if col in runs else []
    return {"tracking_uri": redact_uri(tracking_uri), "experiments": list(experiments) or uniq("experiment"),
            "sweeps": list(sweeps) or uniq("sweep"), "platforms": uniq("device_name"),
            "flashnav_versions": uniq("flashnav_version"), "git_commits": uniq("git_commit"),
            "generated_at": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
            **{k: int(runs.attrs.get(k, len(runs) if k in ("n_runs", "n_finished", "n_trials") else 0))
               for k in ("n_runs", "n_finished", "n_not_finished", "n_duplicates", "n_trials")},
            "warnings": pooling_warnings(runs)}


def _markdown(ours, paper, prov, figures, out: Path, steps=None) -> str:
    lines = ["# FlashNav training report", "",
             f"Generated {prov['generated_at']} from "
             f"{'`' + prov['tracking_uri'] + '`' if prov['tracking_uri'] else 'a run table'}; experiments: "
             f"{', '.join(prov['experiments']) or 'all'}; sweeps: {', '.join(prov['sweeps']) or '—'}; "
             f"{prov['n_runs']} trial runs, {prov['n_not_finished']} not FINISHED and {prov['n_duplicates']} "
             f"duplicates dropped, {prov['n_trials']} trials tabulated.", ""]
    if prov.get("warnings"):
        lines += [f"**Pooled:** {w}  " for w in prov["warnings"]] + [""]
    if steps is not None and not steps.empty:
        lines += ["## Environment steps to success threshold", "",
                  "Best / mean environment steps over the seeds that reached the threshold (machine-independent: "
                  "comparable with the paper's budgets); k/n seeds reached; [95 % bootstrap interval of the "
                  "mean]. Last column: seeds that reached 100 % within the paper's environment-step budget "
                  "(its recipe's total) for the embodiment x algorithm; — where the paper has no budget or the runs are "
                  "not on the paper's task (trained or scored on other maps: a generalist, a fine-tuning).", "",
                  to_markdown(steps)]
    lines += ["## Time to success threshold", "",
             "Best / mean wall-clock training seconds over the seeds that reached the threshold; k/n seeds "
             "reached; [95 % bootstrap interval of the mean]. Bold: fastest platform per embodiment x "
             "algorithm.", "", to_markdown(ours),
             "## The paper's published numbers (Table 2)", "", to_markdown(paper, with_counts=False)]
    if figures:
        lines += ["## Figures", ""] + [f"![{n}]({Path(p).relative_to(out).as_posix()})" for n, p in figures.items()]
    return "\n".join(lines) + "\n"


def build_report(runs: pd.DataFrame, curve_frame: pd.DataFrame | None, out_dir: str | Path,
                 formats=("md", "tex", "csv", "html"), prov: dict | None = None) -> dict:
    """Write the report files for already-loaded runs; returns {name: Path}. Pure of MLflow.

    Figures (figures/*.png) are drawn when "html", "png" or "svg" is asked for.
    """
    from services import report_figures, report_html   # matplotlib only when drawing

    bad = sorted(set(formats) - set(FORMATS))
    if bad:
        raise ValueError(f"unknown report format(s) {', '.join(bad)}; choose from {', '.join(FORMATS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prov = prov or provenance(runs)
    ours, paper = threshold_table(runs), load_paper_table()
    steps = threshold_table(runs, kind="env_steps_to")
    written: dict[str, Path] = {}

    def put(name, filename, text):
        path = out / filename
        path.write_text(text, encoding="utf-8")
        written[name] = path

    figures = {}
    if {"html", "png", "svg"} & set(formats):
        cf = curve_frame if curve_frame is not None else pd.DataFrame(columns=["run_id", "step", *CURVE_METRICS])
        figures = report_figures.write_figures(runs, cf, out / "figures", svg="svg" in formats)
        written.update({f"fig_{k}": v for k, v in figures.items()})
    if "md" in formats:
        put("md", "report.md", _markdown(ours, paper, prov, figures, out, steps))
    if "tex" in formats:
        tex_ours = to_latex(ours)
        tex_paper = to_latex(paper, with_counts=False, label="tab:paper_table2",
                             caption="FlashNav paper, Table 2: multi-platform 10-seed training results, best / "
                                     "mean seconds over reached seeds (published numbers).")
        put("tex", "threshold_table.tex", tex_ours)
        put("tex_paper", "paper_table2.tex", tex_paper)
        put("tex_document", "tables.tex", latex_document([tex_ours, tex_paper]))
    if "csv" in formats:
        put("csv", "threshold_table.csv", to_csv(ours))
        put("csv_steps", "steps_table.csv", to_csv(steps))
        put("csv_comparison", "comparison.csv", to_csv(comparison_table(ours, paper)))
    if "html" in formats:
        put("html", "index.html", report_html.render_html(ours, paper, figures, prov, steps=steps))
    return written


def write_report(tracking_uri: str | None, out_dir: str | Path, experiment: str | list[str] | None = None,
                 sweeps: list[str] | None = None, formats=("md", "tex", "csv", "html"),
                 invocation: str | None = None, warn=None) -> dict:
    """Load the runs from MLflow, then build_report. Returns {name: Path} of the files written; ``warn``
    (a callable) gets each pooling warning (services.report_select), which the report's header shows too."""
    uri = tracking_uri or default_tracking_uri()
    runs = load_runs(uri, experiment=experiment, sweeps=sweeps, invocation=invocation)
    need_curves = bool({"html", "png", "svg"} & set(formats))
    cf = curves(uri, runs["run_id"].tolist()) if need_curves else None
    exps = [experiment] if isinstance(experiment, str) else list(experiment or [])
    prov = provenance(runs, uri, exps, sweeps or [])
    for line in prov["warnings"] if warn else []:
        warn(line)
    return build_report(runs, cf, out_dir, formats, prov)


def _cli(args) -> int:
    from mlflow.exceptions import MlflowException
    from sqlalchemy.exc import SQLAlchemyError

    from flashnav.outputs import check_output_dir

    formats = tuple(f.strip() for f in args.format.split(",") if f.strip())
    bad = sorted({f for f in formats if f not in FORMATS})
    if bad or not formats:  # before any work and before any folder is made
        shown = ", ".join(repr(f) for f in bad) or "none"
        print(f"flashnav report: error: --format {args.format}: unknown format(s) {shown}; choose from "
              f"{', '.join(FORMATS)} (comma-separated)", file=sys.stderr)
        return 2
    mlflow_asked = not args.generalisation or args.experiment or args.sweeps
    if not mlflow_asked:  # the generalisation tables alone: flags that only the MLflow report reads are refused
        gen_formats = ("md", "csv", "html", "png", "svg")
        if args.invocation is not None:
            print(f"flashnav report: error: --invocation {args.invocation} selects MLflow sweep runs; with "
                  f"--generalisation alone there are none (add --sweep NAME or --experiment NAME)", file=sys.stderr)
            return 2
        if not set(formats) & set(gen_formats):
            print(f"flashnav report: error: --format {args.format}: the generalisation tables are written as "
                  f"{', '.join(gen_formats)}; nothing would be written", file=sys.stderr)
            return 2
    for key, value in HTTP_ENV.items():  # a server that dies mid-report fails in seconds, not minutes
        os.environ.setdefault(key, value)
    try:
        uri = args.tracking_uri or default_tracking_uri()
        check_output_dir(args.out, "--out")
        written = {}
        if args.generalisation:
            from services.report_generalisation import write_generalisation

            written.update(write_generalisation(args.generalisation, args.out, formats))
        if mlflow_asked:  # MLflow runs asked for, or nothing else
            written.update(write_report(uri, args.out, experiment=args.experiment, sweeps=args.sweeps,
                                        formats=formats, invocation=args.invocation,
                                        warn=lambda line: print(f"flashnav report: warning: {line}",
                                                                file=sys.stderr)))
    except (NoRunsError, ValueError, MlflowException, SQLAlchemyError) as err:
        if getattr(args, "debug", False):
            raise
        message = " ".join(str(getattr(err, "message", err)).split())
        if isinstance(err, SQLAlchemyError):  # (its text ends in a page of SQL and a link)
            message = f"tracking URI {redact_uri(uri)}: {message.split('[SQL')[0].strip()}"
        print(f"flashnav report: error: {message}", file=sys.stderr)
        return 2
    for name, path in written.items():
        print(f"{name:20s} {path}")
    return 0


def register_cli(subparsers):
    """Add `flashnav report` (found through the flashnav.commands entry point)."""
    p = subparsers.add_parser(
        "report", help="tables, figures and an HTML page from MLflow sweep runs",
        description="Aggregate FlashNav trial runs over seeds into the paper's Table 2 (best / mean seconds "
                    "to 90/95/100 % success, k/n, bootstrap interval), learning-curve and cycle figures, "
                    "and DIR/index.html.")
    sel = p.add_mutually_exclusive_group()
    sel.add_argument("--experiment", metavar="NAME", help="MLflow experiment to report (default: all)")
    sel.add_argument("--sweep", metavar="NAME", dest="sweeps", action="extend", nargs="+",
                     help="keep runs tagged sweep=NAME (repeatable)")
    p.add_argument("--invocation", default=None, metavar="latest|STAMP",
                   help="one invocation per sweep: the latest, or the stamp of one (a sweep's outputs folder name, "
                        "e.g. 20261129-231500; its runs' `invocation` tag); default: every invocation, pooled, "
                        "with a warning")
    p.add_argument("--tracking-uri", default=None, metavar="URI",
                   help="MLflow store (default: where the sweeps write: $MLFLOW_TRACKING_URI, else "
                        "sqlite:///<runs>/mlflow.db, <runs> = $FLASHNAV_RUNS_DIR or ./runs)")
    p.add_argument("--out", default="runs/report", metavar="DIR", help="output folder (default: runs/report)")
    p.add_argument("--generalisation", metavar="EVAL_JSON", nargs="+", default=None,
                   help="also (alone: only) the generalisation tables from `flashnav eval POLICY --maps SUITE "
                        "--json FILE` results, one file per policy and suite (generalisation.md/.csv/.html)")
    p.add_argument("--format", default="md,tex,csv,html",
                   help=f"comma-separated, from {','.join(FORMATS)} (default: md,tex,csv,html)")
    p.set_defaults(func=_cli)
    return p
