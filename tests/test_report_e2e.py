"""Issue 5 end to end, through the real command line, as a user runs it:

    flashnav sweep run sweeps/quickstart.yaml --set ...        (in-process Ray, real flashnav.train)
    flashnav report --sweep quickstart --out reports/quickstart
    chromium --headless --screenshot ... reports/quickstart/index.html

in a temporary project-like directory (a copy of sweeps/quickstart.yaml, no environment pointing
elsewhere), so the sweep's default store (<project>/runs/mlflow.db) must be the one `flashnav report`
finds by default, and nothing lands in the repository's runs/. The budget is the smallest that still
gives every seed several evaluations (30 cycles of training, an evaluation every 10). About a minute
on 2 cores. The screenshot is left in the test's tmp dir (report_e2e_screenshot.png).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
CHROMIUM = Path("/usr/bin/chromium")
WIDTH, HEIGHT = 1400, 2000
# A budget in env steps (30 cycles of the cpu recipe's 128 envs: evaluations at cycles 10, 20, 30), so the count
# of evaluations does not depend on how loaded the machine is (a 3-s budget gave one evaluation under load).
TINY = ["--set", "budget.max_env_steps=3840", "--set", "budget.max_train_seconds=120", "--set", "base.eval.episodes=16",
        "--set", "base.eval.every=10"]
REPORT_FILES = ["report.md", "threshold_table.tex", "paper_table2.tex", "tables.tex", "threshold_table.csv",
                "comparison.csv", "index.html", "figures/curves_return.png", "figures/curves_success.png",
                "figures/success_vs_time.png", "figures/cycle_breakdown.png"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"




def _flashnav() -> list[str]:
    script = VENV_BIN / "flashnav"
    if script.exists():
        return [str(script)]
    found = shutil.which("flashnav")
    if not found:
        pytest.skip("the `flashnav` console script is not installed (pip install -e '.[services]')")
    return [found]


def _cli(command: list[str], cwd: Path, env: dict[str, str], timeout: int) -> subprocess.CompletedProcess:
    res = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert res.returncode == 0, f"{' '.join(command)} -> {res.returncode}\n{res.stdout[-4000:]}\n{res.stderr[-4000:]}"
    return res


def test_quickstart_sweep_report_and_page(tmp_path):
    project = tmp_path / "project"
    (project / "sweeps").mkdir(parents=True)
    shutil.copy(ROOT / "sweeps" / "quickstart.yaml", project / "sweeps" / "quickstart.yaml")
    env = {k: v for k, v in os.environ.items()
           if k not in ("FLASHNAV_RUNS_DIR", "FLASHNAV_PROJECT_DIR", "MLFLOW_TRACKING_URI", "RAY_ADDRESS",
                        "RAY_API_SERVER_ADDRESS", "RAY_AUTH_MODE")}
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    flashnav = _flashnav()

    # 1. The sweep: in-process Ray, the real training, MLflow in <project>/runs/mlflow.db.
    sweep = _cli(flashnav + ["sweep", "run", "sweeps/quickstart.yaml", *TINY], project, env, 300)
    store = project / "runs" / "mlflow.db"
    assert "sweep quickstart: 2/2 trials finished" in sweep.stdout, sweep.stdout[-3000:]
    assert f"sqlite:///{store}" in sweep.stdout and store.is_file()

    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{store}")
    found = client.search_runs([client.get_experiment_by_name("quickstart").experiment_id])
    parents = [r for r in found if r.data.tags.get("role") == "sweep"]
    children = [r for r in found if r.data.tags.get("role") == "trial"]
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    assert sorted(c.data.tags["seed"] for c in children) == ["0", "1"]
    for child in children:
        assert child.info.status == "FINISHED"
        assert child.data.tags["mlflow.parentRunId"] == parents[0].info.run_id
        assert len(client.get_metric_history(child.info.run_id, "success_rate")) >= 2, "too few evaluations"

    # 2. The report, with the default store (the one the sweep wrote: run from the project dir).
    report = _cli(flashnav + ["report", "--sweep", "quickstart", "--out", "reports/quickstart"], project, env, 180)
    out = project / "reports" / "quickstart"
    for name in REPORT_FILES:
        path = out / name
        assert path.is_file() and path.stat().st_size > 0, f"{name} missing or empty; report said:\n{report.stdout}"
        assert str(Path("reports/quickstart") / name) in report.stdout, f"{name} not listed by flashnav report"
        if name.endswith(".png"):
            assert path.read_bytes()[:8] == PNG_MAGIC, name
    md = (out / "report.md").read_text()
    assert re.search(r"\| TurtleBot2 \| FastDSAC \| [^|]+ \|.*\b\d/2 \|", md), md[:3000]
    assert f"sqlite:///{store}" in md and "2 trials tabulated" in md
    assert all(f"figures/{f}.png" in md for f in ("curves_return", "curves_success", "success_vs_time",
                                                   "cycle_breakdown"))
    csv_rows = (out / "threshold_table.csv").read_text().splitlines()
    assert csv_rows[0].startswith("embodiment,algorithm,platform,n,") and len(csv_rows) == 2
    assert csv_rows[1].startswith("turtlebot2,fastdsac,") and csv_rows[1].split(",")[3] == "2"
    assert "source" in (out / "comparison.csv").read_text().splitlines()[0]
    for tex in ("threshold_table.tex", "paper_table2.tex"):
        assert "\\begin{table*}" in (out / tex).read_text()
    html = (out / "index.html").read_text()
    assert html.count("data:image/png;base64,") >= 4 and 'src="figures/' not in html  # one offline file
    if shutil.which("pdflatex"):
        tex = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "-output-directory",
                              str(tmp_path), str(out / "tables.tex")], cwd=out, capture_output=True, text=True,
                             timeout=120)
        assert tex.returncode == 0 and (tmp_path / "tables.pdf").is_file(), tex.stdout[-3000:]
    assert not (project / "runs" / "report").exists()  # --out was honoured

    # 3. The page in headless Chromium.
    if not CHROMIUM.exists():
        pytest.skip("sweep and report checked; the screenshot needs /usr/bin/chromium (Debian package `chromium`)")
    from PIL import Image
    shot = tmp_path / "report_e2e_screenshot.png"
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}", f"--window-size={WIDTH},{HEIGHT}",
           (out / "index.html").resolve().as_uri()]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and shot.is_file(), res.stderr[-3000:]
    print(f"screenshot: {shot}")

    img = Image.open(shot).convert("RGB")
    assert img.size == (WIDTH, HEIGHT)
    px = np.asarray(img.resize((WIDTH // 4, HEIGHT // 4)), dtype=int)          # [H/4, W/4, 3] 0..255
    assert len(np.unique(px.reshape(-1, 3), axis=0)) > 50, "screenshot is (nearly) one colour: page not rendered"
    # The title, the intro and the threshold table (one row) fill the top of the page: dark text there.
    full = np.asarray(img, dtype=int)                                          # full resolution: sharp glyphs
    top = full[: HEIGHT // 6]
    ink = float((top.sum(axis=2) < 300).mean())
    assert ink > 0.01, f"only {ink:.1%} dark pixels in the top sixth: heading / table text missing?"
    # Figure lines, bands and bars are saturated colours; the tables are grey on white.
    lower = px[px.shape[0] // 4:]
    saturated = int(((lower.max(axis=2) - lower.min(axis=2)) > 60).sum())
    assert saturated > 200, f"{saturated} coloured pixels below the table: figures not shown?"
