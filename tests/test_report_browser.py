"""Screenshot of the report page in headless Chromium: the page renders offline with its table and
figures. Chromium comes from the Debian package (/usr/bin/chromium, installed by the CI set-up)."""
from __future__ import annotations

import importlib.util
import subprocess
from pathlib import Path

import numpy as np
import pytest

from services.report import build_report, normalize_runs

CHROMIUM = Path("/usr/bin/chromium")
WIDTH, HEIGHT = 1400, 2000


def _fixture():
    path = Path(__file__).parent / "fixtures" / "report_runs.py"
    spec = importlib.util.spec_from_file_location("report_runs_fixture", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_index_html_screenshot(tmp_path):
    if not CHROMIUM.exists():
        pytest.skip("headless screenshot needs /usr/bin/chromium (Debian package `chromium`), not installed")
    from PIL import Image

    F = _fixture()
    written = build_report(normalize_runs(F.raw_runs()), F.curve_frame(), tmp_path / "report", formats=("html",))
    shot = tmp_path / "shot.png"
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}", f"--window-size={WIDTH},{HEIGHT}",
           written["html"].resolve().as_uri()]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and shot.is_file(), res.stderr[-3000:]

    img = Image.open(shot).convert("RGB")
    assert img.size == (WIDTH, HEIGHT)
    px = np.asarray(img.resize((WIDTH // 4, HEIGHT // 4)), dtype=int)          # [H/4, W/4, 3] 0..255
    assert len(np.unique(px.reshape(-1, 3), axis=0)) > 50, "screenshot is (nearly) one colour: page not rendered"
    ink = float((px.sum(axis=2) < 600).mean())
    assert ink > 0.02, f"only {ink:.1%} non-white pixels: table text missing?"
    # Figure lines and bands are saturated colours; the table is grey on white. Saturated pixels in
    # the lower half of the page mean the inlined PNG figures were decoded and drawn.
    lower = px[px.shape[0] // 2:]
    saturated = int(((lower.max(axis=2) - lower.min(axis=2)) > 60).sum())
    assert saturated > 200, f"{saturated} coloured pixels below the table: figures not shown?"
