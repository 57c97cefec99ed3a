"""Golden tests for services/report*.py: fixture runs -> exact table cells in every format, figures,
the HTML page, the CLI, and one MLflow round trip (sqlite store, module-scoped: its init is slow)."""
from __future__ import annotations

import argparse
import importlib.util
import math
import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from services.report import (NoRunsError, build_report, curves, default_tracking_uri, load_runs,
                             normalize_runs, register_cli, write_report)
from services.report_figures import mean_se_on_grid
from services.report_tables import (bootstrap_mean_ci, latex_document, latex_escape, load_paper_table,
                                    threshold_table, to_csv, to_latex, to_markdown)


def _load_fixture():
    # by path: works whether or not tests/ is a package
    path = Path(__file__).parent / "fixtures" / "report_runs.py"
    spec = importlib.util.spec_from_file_location("report_runs_fixture", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


F = _load_fixture()
# the fixture's CPU runs have the old spelling "AMD EPYC 7B13 (2 threads)": the platform is the machine
H100, EPYC, R4090 = "NVIDIA H100 80GB HBM3", "AMD EPYC 7B13", "NVIDIA GeForce RTX 4090"
X = None  # no seed reached

# By hand from fixtures/report_runs.py TRIALS, over reached seeds only: {t: (best, mean, k)}, n.
EXPECTED = [  # in table order: paper order of robots / algorithms, platforms by device name
    ("turtlebot2", "fastdsac", EPYC, 3, {90: (20, 30, 3), 95: (25, 30, 2), 100: (X, X, 0)}),  # 95: 25,35
    ("turtlebot2", "fastdsac", R4090, 2, {90: (9, 13, 2), 95: (14, 16, 2), 100: (20, 20, 1)}),
    # the restored duplicate (t90 = 50) and the FAILED retry (t90 = 1) must not count:
    ("turtlebot2", "fastdsac", H100, 3, {90: (10, 12, 3), 95: (11, 13, 3), 100: (12, 14, 2)}),  # 100: 12,16
    ("turtlebot2", "fastsac", EPYC, 3, {90: (30, 45, 3), 95: (40, 45, 2), 100: (X, X, 0)}),
    ("turtlebot2", "fastsac", H100, 3, {90: (15, 18, 3), 95: (16, 20, 3), 100: (20, 25, 3)}),
    ("go2", "fastdsac", EPYC, 3, {90: (X, X, 0), 95: (X, X, 0), 100: (X, X, 0)}),
    ("go2", "fastdsac", H100, 3, {90: (14, 16, 3), 95: (15, 17, 2), 100: (25, 25, 1)}),
    ("go2", "fasttd3", EPYC, 3, {90: (28, 50, 3), 95: (33, 55, 3), 100: (90, 90, 1)}),
    ("go2", "fasttd3", H100, 3, {90: (30, 36, 3), 95: (33, 40, 3), 100: (X, X, 0)}),
]
# Bold = lowest of the group per column; 4090 wins best_90 only; go2/fasttd3 best_95 is a tie (33).
BOLD = {
    ("turtlebot2", "fastdsac", R4090): {"best_90"},
    ("turtlebot2", "fastdsac", H100): {"mean_90", "best_95", "mean_95", "best_100", "mean_100"},
    ("turtlebot2", "fastsac", H100): {"best_90", "mean_90", "best_95", "mean_95", "best_100", "mean_100"},
    ("go2", "fastdsac", H100): {"best_90", "mean_90", "best_95", "mean_95", "best_100", "mean_100"},
    ("go2", "fasttd3", EPYC): {"best_90", "best_95", "best_100", "mean_100"},
    ("go2", "fasttd3", H100): {"mean_90", "best_95", "mean_95"},
}
H100_TB2_DSAC_MD = ("| TurtleBot2 | FastDSAC | H100 80GB HBM3 | — | 10.0 | **12.0** [10.0, 14.0] | 3/3 | **11.0** | "
                    "**13.0** [11.0, 15.0] | 3/3 | **12.0** | **14.0** [12.0, 16.0] | 2/3 |")


@pytest.fixture(scope="module")
def runs():
    return normalize_runs(F.raw_runs())


@pytest.fixture(scope="module")
def table(runs):
    return threshold_table(runs)


def _bold_cells(row) -> set:
    return {c[len("bold_"):] for c in row.index if c.startswith("bold_") and row[c]}


# ------------------------------------------------------------------------------------ selection

def test_normalize_keeps_finished_latest_trial_runs(runs):
    assert runs.attrs == {"n_runs": 28, "n_finished": 27, "n_not_finished": 1, "n_duplicates": 1, "n_trials": 26}
    assert len(runs) == 26 and set(runs["status"]) == {"FINISHED"} and "sweep" not in set(runs["role"])
    seed1 = runs[(runs["trial_id"] == "abc12_00001")]
    assert len(seed1) == 1 and seed1["time_to_90"].item() == 12.0          # the later duplicate
    assert runs[runs["trial_id"] == "abc12_00002"]["time_to_90"].item() == 14.0  # FINISHED, not the FAILED retry
    assert str(runs["seed"].dtype) == "Int64" and str(runs["params.algo.batch_size"].dtype) == "Int64"
    assert runs["params.budget.max_train_seconds"].dtype == float and runs["reached_90"].dtype == float


def test_dedup_is_per_sweep_and_trial():
    raw = F.raw_runs()
    twin = raw[raw["tags.trial_id"] == "abc12_00003"].copy()
    twin["run_id"], twin["tags.sweep"] = "twin", "another_sweep"
    runs = normalize_runs(pd.concat([raw, twin], ignore_index=True))
    assert len(runs) == 27 and runs.attrs["n_duplicates"] == 1


# ------------------------------------------------------------------------------------ numbers

def test_threshold_table_values(table):
    assert [tuple(r) for r in table[["embodiment", "algorithm", "platform"]].itertuples(index=False)] == \
        [e[:3] for e in EXPECTED]
    for (_, _, _, n, per_t), (_, row) in zip(EXPECTED, table.iterrows()):
        assert row["n"] == n
        for t, (best, mean, k) in per_t.items():
            assert row[f"reached_{t}"] == k
            if best is None:
                assert math.isnan(row[f"best_{t}"]) and math.isnan(row[f"mean_{t}"])
            else:
                assert row[f"best_{t}"] == pytest.approx(best) and row[f"mean_{t}"] == pytest.approx(mean)


def test_steps_table_and_paper_budget(runs):
    # The fixture's env steps are seconds x a per-platform rate; the budget is the paper recipe's total.
    steps = threshold_table(runs, kind="env_steps_to")
    row = lambda e, a, p: steps[(steps.embodiment == e) & (steps.algorithm == a) & (steps.platform == p)].iloc[0]  # noqa: E731
    epyc = row("turtlebot2", "fastdsac", "AMD EPYC 7B13")
    assert (epyc.best_90, epyc.mean_90, epyc.reached_90, epyc.budget) == (40_000, 60_000, 3, 200_704)
    td3 = row("go2", "fasttd3", "AMD EPYC 7B13")
    assert (td3.budget, td3.reached_100, td3.budget_100) == (602_112, 1, 1)  # 180,000 <= 602,112
    h100 = row("turtlebot2", "fastdsac", "NVIDIA H100 80GB HBM3")
    assert (h100.reached_100, h100.budget_100) == (2, 0)  # reached, but past the paper's budget
    assert "0/3 (≤ 200,704)" in to_markdown(steps) and "| **40,000** |" in to_markdown(steps)
    with pytest.raises(ValueError, match="kind"):
        threshold_table(runs, kind="seconds")


def test_paper_budget_only_for_runs_on_the_papers_task(runs):
    """A generalist trial (its maps, scored on validation maps) or a fine-tuning on one building is not the task
    the paper's budget is for: its row shows no budget; runs with the params logged as "None" (MLflow's spelling
    of a null) stay on the task."""
    on = runs.assign(**{"params.map": "None", "params.maps": "None", "params.eval.maps": "None"})
    assert threshold_table(on, kind="env_steps_to")["budget"].notna().any()
    pd.testing.assert_frame_equal(threshold_table(on, kind="env_steps_to"), threshold_table(runs, kind="env_steps_to"))
    for key, value in (("params.maps.family", "['rooms', 'mazes']"), ("params.eval.maps", "validation"),
                       ("params.map", "/maps/building.yaml")):
        off = threshold_table(runs.assign(**{key: value}), kind="env_steps_to")
        assert off["budget"].isna().all() and (off["budget_100"] == 0).all(), key
        assert "in paper budget" in to_markdown(off) and "(≤ " not in to_markdown(off)
    one = runs.copy()
    one["params.eval.maps"] = None
    one.loc[one.index[0], "params.eval.maps"] = "validation"   # one off-task run makes its whole row off-task
    mixed = threshold_table(one, kind="env_steps_to")
    assert mixed["budget"].isna().sum() == 1


def test_bold_cells(table):
    for _, row in table.iterrows():
        assert _bold_cells(row) == BOLD.get((row["embodiment"], row["algorithm"], row["platform"]), set())


def test_bootstrap_interval(table):
    row = table.set_index(["embodiment", "algorithm", "platform"]).loc[("turtlebot2", "fastdsac", R4090)]
    # two seeds 9 and 17: resampled means are 9, 13 or 17 with p = 1/4, 1/2, 1/4 -> 2.5/97.5 % = 9, 17
    assert (row["ci_low_90"], row["ci_high_90"]) == (9.0, 17.0)
    assert row["ci_low_100"] is None and row["ci_high_100"] is None               # k = 1
    assert bootstrap_mean_ci([1.0]) is None and bootstrap_mean_ci([]) is None
    assert bootstrap_mean_ci([5.0, 5.0, 5.0]) == (5.0, 5.0)
    a = bootstrap_mean_ci([3.0, 1.0, 2.0, 8.0, 4.0])
    assert a == bootstrap_mean_ci([8.0, 4.0, 2.0, 1.0, 3.0])                      # order-free, seeded
    assert 1.0 < a[0] < 3.6 < a[1] < 8.0                                          # brackets the mean 3.6


def test_markdown(table):
    md = to_markdown(table)
    assert H100_TB2_DSAC_MD in md.splitlines()
    assert "| TurtleBot2 | FastDSAC | RTX 4090 | — | **9.0** | 13.0 [9.0, 17.0] | 2/2 |" in md
    assert "| Go2 | FastDSAC | AMD EPYC 7B13 | 2 | — | — | 0/3 | — | — | 0/3 | — | — | 0/3 |" in md
    assert md.count("**") // 2 == sum(len(v) for v in BOLD.values())


def test_latex(table):
    tex = to_latex(table)
    assert r"\multirow{5}{*}{TurtleBot2} & \multirow{3}{*}{FastDSAC} & AMD EPYC 7B13 & 2 & 20.0 &" in tex
    assert r"\multirow{4}{*}{Go2} & \multirow{2}{*}{FastDSAC}" in tex
    assert (r" &  & H100 80GB HBM3 & -- & 10.0 & \textbf{12.0}\,{\scriptsize[10.0, 14.0]} & 3/3 & \textbf{11.0} & "
            r"\textbf{13.0}\,{\scriptsize[11.0, 15.0]} & 3/3 & \textbf{12.0} & "
            r"\textbf{14.0}\,{\scriptsize[12.0, 16.0]} & 2/3 \\") in tex.splitlines()
    assert r"\textbf{9.0}" in tex and r"-- & -- & 0/3 \\" in tex
    assert tex.count(r"\textbf{") == sum(len(v) for v in BOLD.values())
    assert tex.count(r"\cmidrule(lr){2-13}") == 2 and tex.count(r"\midrule") == 2
    assert r"\toprule" in tex and r"\bottomrule" in tex and r"\begin{tabular}{llllccccccccc}" in tex
    assert latex_escape("a_b & 100% #1") == r"a\_b \& 100\% \#1"


def test_csv(table):
    text = to_csv(table)
    assert ("turtlebot2,fastdsac,NVIDIA H100 80GB HBM3,3,10.000,12.000,3,10.000,14.000,"
            "11.000,13.000,3,11.000,15.000,12.000,14.000,2,12.000,16.000,") in text
    back = pd.read_csv(pd.io.common.StringIO(text))
    assert back["reached_100"].tolist() == [e[4][100][2] for e in EXPECTED]
    assert back["bold_best_90"].tolist() == [("best_90" in BOLD.get(e[:3], set())) for e in EXPECTED]


def test_paper_table_reproduces_published_bold():
    paper = load_paper_table()
    assert len(paper) == 18 and list(paper["platform"][:3]) == ["RTX 5090", "RTX 4090", "RTX 5060 Ti"]
    row = paper.set_index(["embodiment", "algorithm", "platform"]).loc[("go2", "fasttd3", "RTX 5060 Ti")]
    assert (row["best_90"], row["mean_90"], row["mean_95"], row["mean_100"]) == (66.9, 98.5, 101.4, 118.3)
    bold = paper[[c for c in paper if c.startswith("bold_")]]
    assert bold.all(axis=1).tolist() == (paper["platform"] == "RTX 5090").tolist()   # as published
    assert not bold[paper["platform"] != "RTX 5090"].any().any()
    md = to_markdown(paper, with_counts=False)
    assert "| TurtleBot2 | FastDSAC | RTX 5090 | **12.9** | **15.4** | **13.1** | **15.6** | **14.9** | **17.2** |" in md


def test_latex_compiles(tmp_path, table):
    engines = {name: shutil.which(name) for name in ("pdflatex", "lualatex", "tectonic")}
    engine = next((n for n, p in engines.items() if p), None)
    if engine is None:
        pytest.skip("no TeX engine installed (looked for pdflatex, lualatex, tectonic)")
    kpsewhich = shutil.which("kpsewhich")
    if engine != "tectonic" and kpsewhich:   # TeX Live without the package: an install gap, not a bug
        for sty in ("booktabs.sty", "multirow.sty", "geometry.sty"):
            if not subprocess.run([kpsewhich, sty], capture_output=True, text=True).stdout.strip():
                pytest.skip(f"{engine} found but {sty} is missing (Debian: texlive-latex-extra)")
    (tmp_path / "t.tex").write_text(latex_document([to_latex(table),
                                                    to_latex(load_paper_table(), with_counts=False)]))
    cmd = [engines[engine], "t.tex"] if engine == "tectonic" else \
        [engines[engine], "-interaction=nonstopmode", "-halt-on-error", "t.tex"]
    res = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout[-3000:]
    assert (tmp_path / "t.pdf").stat().st_size > 1000


# ------------------------------------------------------------------------------------ platform names

def _respell(raw: pd.DataFrame, old: str, new: str, threads: dict | None = None) -> pd.DataFrame:
    """The fixture with device_name ``old`` renamed ``new`` and, per seed, a ``threads`` tag where given."""
    raw = raw.copy()
    hit = raw["tags.device_name"] == old
    raw.loc[hit, "tags.device_name"] = new
    if threads is not None:
        raw["tags.threads"] = None
        for seed, n in threads.items():
            raw.loc[hit & (raw["tags.seed"] == str(seed)), "tags.threads"] = str(n)
    return raw


def test_old_and_new_device_name_spellings(runs, table):
    # old spelling (the fixture): the machine, and threads parsed from the name; GPUs have no threads
    assert set(runs["device_name"]) == {H100, EPYC, R4090} and str(runs["threads"].dtype) == "Int64"
    assert runs.loc[runs["device_name"] == EPYC, "threads"].tolist() == [2] * 12
    assert runs.loc[runs["device_name"] != EPYC, "threads"].isna().all()
    # new spelling: machine with cores, threads as a tag -> the same numbers, one row per machine
    new = threshold_table(normalize_runs(_respell(F.raw_runs(), "AMD EPYC 7B13 (2 threads)",
                                                  "AMD EPYC 7B13 (2 cores)", threads={0: 2, 1: 2, 2: 2})))
    cpu = new["platform"] == "AMD EPYC 7B13 (2 cores)"
    assert cpu.sum() == 4 and (new.loc[cpu, "threads"] == "2").all()
    pd.testing.assert_frame_equal(new.drop(columns="platform"), table.drop(columns="platform"))
    # a thread setting no longer splits a machine's row: 1 and 2 threads (either spelling) are one row
    mixed = _respell(F.raw_runs(), "AMD EPYC 7B13 (2 threads)", "AMD EPYC 7B13 (2 threads)")
    mixed.loc[(mixed["tags.device_name"] == "AMD EPYC 7B13 (2 threads)") & (mixed["tags.seed"] == "1"),
              "tags.device_name"] = "AMD EPYC 7B13 (1 threads)"
    got = threshold_table(normalize_runs(mixed))
    pd.testing.assert_frame_equal(got.drop(columns="threads"), table.drop(columns="threads"))
    assert got.loc[got["platform"] == EPYC, "threads"].tolist() == ["1, 2"] * 4
    assert "| TurtleBot2 | FastDSAC | AMD EPYC 7B13 | 1, 2 | 20.0 |" in to_markdown(got)


# ------------------------------------------------------------------------------------ figures / html

def test_mean_se_on_grid_holds_last_value():
    grid, mean, se, n = mean_se_on_grid([([0, 10], [0, 10]), ([0, 10], [0, 20]), ([0, 5], [0, 30])], points=3)
    assert n == 3 and grid.tolist() == [0, 5, 10]
    assert mean.tolist() == pytest.approx([0, 15, 20])          # seed 3 holds 30 after its last eval at 5
    assert se[2] == pytest.approx(pd.Series([10, 20, 30]).std() / 3 ** 0.5)
    assert mean_se_on_grid([([0, 1], [2, 4])])[2].tolist() == [0.0] * 200      # one seed: no band


def _is_png(path: Path) -> bool:
    return path.stat().st_size > 5000 and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_build_report_offline(tmp_path, runs):
    written = build_report(runs, F.curve_frame(), tmp_path, formats=("md", "tex", "csv", "html"))
    assert {"md", "tex", "tex_paper", "tex_document", "csv", "csv_comparison", "html", "fig_curves_return",
            "fig_curves_success", "fig_success_vs_time", "fig_cycle_breakdown"} <= set(written)
    assert all(_is_png(p) for k, p in written.items() if k.startswith("fig_"))
    html = written["html"].read_text()
    assert html.count("data:image/png;base64,") == 4 and "<strong>9.0</strong>" in html
    assert 'rowspan="5"' in html and "RTX 5060 Ti" in html and "0/3" in html
    assert H100_TB2_DSAC_MD in written["md"].read_text()
    comparison = pd.read_csv(written["csv_comparison"])
    assert comparison["source"].value_counts().to_dict() == {"this report": 9, "paper": 18}
    md = written["md"].read_text()  # env steps first: the machine-independent headline
    assert md.index("## Environment steps to success threshold") < md.index("## Time to success threshold")
    assert "Environment steps to success threshold" in html and "100% in paper budget" in html
    assert pd.read_csv(written["csv_steps"])["budget"].tolist()[:1] == [200704]
    with pytest.raises(ValueError, match="pdf"):
        build_report(runs, None, tmp_path, formats=("pdf",))


# ------------------------------------------------------------------------------------ CLI

def _parser():
    parser = argparse.ArgumentParser(prog="flashnav")
    register_cli(parser.add_subparsers(dest="command"))
    return parser


def test_cli_arguments(tmp_path, monkeypatch):
    args = _parser().parse_args(["report", "--sweep", "a", "b", "--sweep", "c", "--format", "md,csv"])
    assert args.sweeps == ["a", "b", "c"] and args.experiment is None and callable(args.func)
    with pytest.raises(SystemExit):
        _parser().parse_args(["report", "--sweep", "a", "--experiment", "e"])
    for name in ("MLFLOW_TRACKING_URI", "FLASHNAV_RUNS_DIR", "FLASHNAV_PROJECT_DIR", "RAY_JOB_CONFIG_JSON_ENV_VAR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    assert default_tracking_uri() == f"sqlite:///{tmp_path.resolve()}/runs/mlflow.db"
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "elsewhere"))  # where the sweeps write (it read ./runs)
    assert default_tracking_uri() == f"sqlite:///{tmp_path.resolve()}/elsewhere/mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://127.0.0.1:5000")
    assert default_tracking_uri() == "http://127.0.0.1:5000"


def test_cli_missing_store(tmp_path, capsys):
    args = _parser().parse_args(["report", "--tracking-uri", f"sqlite:///{tmp_path}/none.db", "--out", str(tmp_path)])
    assert args.func(args) == 2
    assert f"{tmp_path}/none.db" in capsys.readouterr().err


# ------------------------------------------------------------------------------------ MLflow round trip

@pytest.fixture(scope="module")
def store(tmp_path_factory):
    uri = f"sqlite:///{tmp_path_factory.mktemp('mlflow')}/mlflow.db"
    F.log_to_mlflow(uri)
    return uri


def test_load_runs_matches_pure_path(store, table):
    loaded = load_runs(store, sweeps=[F.SWEEP])
    assert loaded.attrs["n_trials"] == 26 and loaded.attrs["n_duplicates"] == 1
    assert loaded.attrs["n_not_finished"] == 1 and set(loaded["experiment"]) == {F.EXPERIMENT}
    assert loaded["parent_run_id"].notna().all()
    pd.testing.assert_frame_equal(threshold_table(loaded), table)
    assert len(load_runs(store, experiment=F.EXPERIMENT)) == 27      # + the other sweep's run
    with pytest.raises(NoRunsError, match="nope"):
        load_runs(store, sweeps=["nope"])
    with pytest.raises(NoRunsError, match=F.EXPERIMENT):               # lists what exists
        load_runs(store, experiment="missing")


def test_curves_from_history(store):
    loaded = load_runs(store, sweeps=[F.SWEEP])
    rid = loaded.loc[loaded["trial_id"] == "abc12_00000", "run_id"].item()
    got = curves(store, [rid])
    want = pd.DataFrame(F.curve(F.TRIALS[0]))
    assert list(got.columns) == ["run_id", "step", "success_rate", "mean_return", "train_seconds"]
    assert got["step"].tolist() == want["step"].tolist()
    assert got["success_rate"].tolist() == pytest.approx(want["success_rate"].tolist())


def test_write_report_and_cli_end_to_end(store, tmp_path):
    written = write_report(store, tmp_path / "r", sweeps=[F.SWEEP])
    for name, path in written.items():
        assert path.is_file() and path.stat().st_size > 0, name
    assert all(_is_png(p) for k, p in written.items() if k.startswith("fig_"))
    html = written["html"].read_text()
    assert F.SWEEP in html and "26 trials tabulated" in html and "<strong>9.0</strong>" in html
    args = _parser().parse_args(["report", "--sweep", F.SWEEP, "--tracking-uri", store,
                                 "--out", str(tmp_path / "cli"), "--format", "md,csv"])
    assert args.func(args) == 0
    assert H100_TB2_DSAC_MD in (tmp_path / "cli" / "report.md").read_text()
