"""The README's Python snippets that run as written do run (one of them once used names it never defined)."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_simulator_snippet_runs_as_written():
    (block,) = [b for b in _python_blocks(README.read_text(encoding="utf-8")) if "flashnav.make_env(" in b]
    exec(compile(block, "README.md (the simulator snippet)", "exec"), {})
