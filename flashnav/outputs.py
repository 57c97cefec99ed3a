"""Checks that an output path can be written, run *before* the work that produces it.

A command that trains for minutes or evaluates a thousand episodes and only then finds that ``--out``
is a file, or that ``--json`` names a folder, wastes the run; these checks fail at once with a
ValueError that names the flag and the path, and create nothing (no empty folder is left behind).
"""

from __future__ import annotations

import os
from pathlib import Path


def _nearest_existing(path: Path) -> Path:
    """``path`` itself or its closest ancestor that exists (the folder a mkdir would start from)."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")


def _check_creatable(path: Path, flag: str) -> None:
    """``path`` does not exist yet: its nearest existing ancestor must be a writable folder."""
    base = _nearest_existing(path.absolute().parent)
    if not base.is_dir():
        raise ValueError(f"{flag} {path}: cannot be created because {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise ValueError(f"{flag} {path}: cannot be created: no permission to write in {base}")


def check_output_dir(path: str | Path, flag: str) -> Path:
    """A folder that is (or can be made) writable. Raises ValueError naming ``flag`` and ``path``."""
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise ValueError(f"{flag} {path}: exists and is a file, not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise ValueError(f"{flag} {path}: no permission to write in this folder")
    else:
        _check_creatable(path, flag)
    return path


def check_output_file(path: str | Path, flag: str) -> Path:
    """A file that can be (over)written. Raises ValueError naming ``flag`` and ``path``."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{flag} {path}: is a folder; give a file name")
    if path.exists():
        if not os.access(path, os.W_OK):
            raise ValueError(f"{flag} {path}: no permission to overwrite this file")
    else:
        _check_creatable(path, flag)
    return path


def write_json_report(path: str | Path, report: dict) -> Path:
    """Write a command's ``--json`` report (parent folders created, indented, newline-terminated) and
    say where; returns the path."""
    import json

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"results: {out}")
    return out
