"""A sweep invocation's state on disk (``<runs>/sweeps/<name>/<stamp>/sweep_state.json`` and the ``sweep.yaml`` it
ran): the newest one of a sweep (or one named by its stamp), whether a ``--resume`` may continue it, and whether it
finished."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Callable

from flashnav.names import SWEEP_STATE_FILE
from services.paths import runs_dir
from services.sweep_schema import Sweep, SweepError, load_sweep

STATE_FILE = SWEEP_STATE_FILE
#: an invocation's stamp (its folder's name under <runs>/sweeps/<name>/): local time, YYYYMMDD-HHMMSS
STAMP_FORMAT = "%Y%m%d-%H%M%S"


def stamp_arg(text: str) -> str:
    """argparse type of ``--resume STAMP``: a stamp, not a sweep file given after the flag."""
    import re
    import time

    try:
        if not re.fullmatch(r"\d{8}-\d{6}", text):  # (strptime alone takes 2026123-1745)
            raise ValueError(text)
        time.strptime(text, STAMP_FORMAT)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--resume takes an invocation's stamp (YYYYMMDD-HHMMSS, the folder name "
                                         f"under <runs>/sweeps/<name>/) or nothing (the newest), got {text!r}; give "
                                         "the sweep file before --resume") from None
    return text


def invocation_state(sweep: Sweep, stamp: str | None = None, must: bool = True) -> dict[str, Any]:
    """The state of this sweep's invocation ``stamp``, or of the newest one ({} when there is none and not
    ``must``)."""
    root = runs_dir() / "sweeps" / sweep.name
    states = sorted(root.glob(f"*/{STATE_FILE}")) if root.exists() else []
    if stamp is not None:
        chosen = [s for s in states if s.parent.name == stamp]
        if not chosen:
            known = ", ".join(s.parent.name for s in states[-5:]) or "none"
            raise SweepError(f"--resume {stamp}: sweep {sweep.name} has no invocation {stamp} under {root} "
                             f"(the newest: {known})")
        states = chosen
    if not states:
        if not must:
            return {}
        raise SweepError(f"nothing to resume: no {STATE_FILE} under {root}")
    return json.loads(states[-1].read_text())


def _changed_keys(old: Any, new: Any, prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between two JSON-like trees."""
    if isinstance(old, dict) and isinstance(new, dict):
        return [k for key in sorted(set(old) | set(new))
                for k in _changed_keys(old.get(key), new.get(key), f"{prefix}{key}.")]
    return [] if old == new else [prefix.rstrip(".") or "(the whole sweep)"]


def check_resumable(sweep: Sweep, out_dir: Path, source: str) -> None:
    """SweepError unless ``sweep`` (the file with its --set values) is the sweep the invocation started with:
    Tune restores the trials it planned, so new seeds never ran and a new budget applied to the rest only,
    under the old parameters in MLflow, and the count printed the file's trials as finished."""
    saved = out_dir / "sweep.yaml"
    if not saved.is_file():
        return  # stopped before it started anything
    changed = _changed_keys(load_sweep(saved).model_dump(mode="json"), sweep.model_dump(mode="json"))
    if changed:
        raise SweepError(f"{source} --resume: the sweep differs from the one invocation {out_dir.name} started with "
                         f"({saved}) in {', '.join(changed)}; a resumed invocation runs what it started with: undo "
                         "the change (or the --set), or run without --resume for a new invocation")


def unfinished(sweep: Sweep, path: str | Path, echo: Callable[[str], Any]) -> None:
    """Say so when the newest invocation of this sweep did not finish: a run without --resume starts afresh and
    trains again what that one finished (and --resume afterwards continues the new one)."""
    state = invocation_state(sweep, must=False)
    if state and state.get("parent_run_id"):
        planned = len(state.get("studies") or {}) or 1
        if len(state.get("done_targets") or []) < planned:
            stamp = state.get("stamp")
            echo(f"note: invocation {stamp} of this sweep did not finish; this starts a new one. To continue that "
                 f"one instead (keeping its finished trials): `flashnav sweep run {path} --resume {stamp}`")
