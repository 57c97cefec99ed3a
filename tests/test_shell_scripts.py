"""The shell scripts parse (``bash -n``): a GPU session is too short to find a syntax error in
scripts/gpu_checklist.sh on the device (its ``DRY=1`` mode runs every step on the CPU; see its header)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).resolve().parents[1] / "scripts").glob("*.sh"))


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
@pytest.mark.parametrize("script", SCRIPTS, ids=[s.name for s in SCRIPTS])
def test_the_script_parses(script):
    done = subprocess.run(["bash", "-n", str(script)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_the_gpu_checklist_is_there():
    assert any(s.name == "gpu_checklist.sh" for s in SCRIPTS)
