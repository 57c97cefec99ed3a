"""Checks that an output path can be written, run *before* the work that produces it.

A command that trains for minutes or evaluates a thousand episodes and only then finds that ``--out``
is a file, or that ``--json`` names a folder, wastes the run; these checks fail at once with a
ValueError that names the flag and the path, and create nothing (no empty folder is left behind).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

#: What a figure flag (``--out`` of a picture, ``--plot``, ``--sheet``) may end with: matplotlib's raster and vector
#: formats that every backend writes.
FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".svgz", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".eps", ".ps", ".pgf",
                   ".raw", ".rgba")


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
    _check_writable_dir(base, f"{flag} {path}: cannot be created")


def _check_writable_dir(folder: Path, what: str) -> None:
    """Raise ValueError (``what``: the message's start) unless a file can be made in ``folder``: tried with a
    temporary file, removed at once, since permission bits do not tell (root passes every ``os.access``; a read-only
    or pseudo file system such as /proc refuses anyway)."""
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".flashnav-write-check-"):  # unnamed where the OS allows
            pass
    except OSError as exc:
        raise ValueError(f"{what}: cannot write in {folder} ({exc.strerror or exc})") from None


def check_output_dir(path: str | Path, flag: str) -> Path:
    """A folder that is (or can be made) writable. Raises ValueError naming ``flag`` and ``path``."""
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise ValueError(f"{flag} {path}: exists and is a file, not a folder")
        _check_writable_dir(path, f"{flag} {path}")
    else:
        _check_creatable(path, flag)
    return path


def _same_file(a: Path, b: Path) -> bool:
    """Whether paths ``a`` and ``b`` name one file (the same inode where both exist, else the same resolved path)."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except OSError:
        return False


def check_output_file(path: str | Path, flag: str, inputs=()) -> Path:
    """A file that can be (over)written and is none of the command's ``inputs`` (paths: the files it reads, which an
    output written over them would destroy). Raises ValueError naming ``flag`` and ``path``."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{flag} {path}: is a folder; give a file name")
    for source in inputs:
        if source is not None and _same_file(path, Path(source)):
            raise ValueError(f"{flag} {path}: is one of the command's inputs ({source}); writing it would destroy "
                             f"it: give another file name")
    if path.exists():
        if not os.access(path, os.W_OK):
            raise ValueError(f"{flag} {path}: no permission to overwrite this file")
    else:
        _check_creatable(path, flag)
    return path


def check_figure_file(path: str | Path, flag: str, inputs=()) -> Path:
    """A picture file to be written (``.png`` added when ``path`` has no suffix): a suffix that matplotlib writes
    (:data:`FIGURE_SUFFIXES`) and a path that :func:`check_output_file` accepts. Returns the path that will be
    written; raises ValueError naming ``flag`` and ``path``."""
    if str(path).endswith("."):  # "r5." has no suffix to Path: it would become "r5..png"
        raise ValueError(f"{flag} {path}: ends with a dot; give the picture's suffix (e.g. {str(path)}png)")
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{flag} {path}: is a folder; give a file name (e.g. {path / 'figure.png'})")
    if not path.suffix:
        path = path.with_suffix(".png")
    if path.suffix.lower() not in FIGURE_SUFFIXES:
        raise ValueError(f"{flag} {path}: a picture is written as {', '.join(FIGURE_SUFFIXES)}; got "
                         f"{path.suffix!r}")
    return check_output_file(path, flag, inputs)


def write_json_report(path: str | Path, report: dict) -> Path:
    """Write a command's ``--json`` report (parent folders created, indented, newline-terminated) and
    say where; returns the path."""
    import json

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"results: {out}")
    return out
