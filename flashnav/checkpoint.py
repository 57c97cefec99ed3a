"""Training checkpoints: plain payloads written with ``torch.save`` and read with
``torch.load(weights_only=True)``, so loading a checkpoint never runs code from the file.

Payload: ``{format_version, flashnav_version, learner, config, extra}``; tensors, dicts, lists, str,
int, float, bool and None only (:func:`save_checkpoint` refuses anything else, naming where it sits).
A run's replay buffer has a file of its own (:func:`save_replay`, ``replay.pt``, the same rules): it is
hundreds of MB and more, and only ``flashnav train --save-replay`` writes it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import torch

from flashnav.version import __version__

#: Version of the checkpoint payload; load_checkpoint accepts exactly these.
CHECKPOINT_FORMAT_VERSION = 1
SUPPORTED_CHECKPOINT_VERSIONS = (1,)
CHECKPOINT_KEYS = ("format_version", "flashnav_version", "learner", "config", "extra")


def is_torchscript(path: Path) -> bool:
    """Whether ``path`` is a TorchScript archive (a zip with a ``code/`` folder), read without loading it."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            return any("/code/" in name or name.startswith("code/") for name in archive.namelist())
    except (zipfile.BadZipFile, OSError):
        return False


def is_checkpoint(path: Path) -> bool:
    """Whether ``path`` is a :func:`save_checkpoint` file (read with weights_only: runs no code)."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # any unreadable file is simply not a checkpoint here
        return False
    return isinstance(payload, dict) and "format_version" in payload and "learner" in payload


def save_checkpoint(path: str | Path, learner_state: dict, config: Any, extra: dict | None = None) -> Path:
    """Write a training checkpoint: ``{format_version, flashnav_version, learner, config, extra}``.

    ``learner_state``: e.g. ``Learner.state_dict()`` (tensors, state dicts, RNG states as uint8
    tensors); ``config``: a dict or a pydantic model (dumped to plain data); ``extra``: anything
    plain (env steps, timings, ...). Everything must be a tensor, dict, list, tuple, str, int,
    float, bool or None, so the file loads with ``weights_only=True``; anything else is a TypeError
    here, naming where it sits, rather than an unreadable checkpoint later. The file is written to
    a temporary name and renamed, so an interrupted save never leaves a truncated checkpoint.
    """
    if hasattr(config, "model_dump"):
        config = config.model_dump(mode="json")
    payload = {"format_version": CHECKPOINT_FORMAT_VERSION, "flashnav_version": __version__,
               "learner": learner_state, "config": config, "extra": dict(extra or {})}
    return _save_plain(payload, path, "checkpoint")


def _save_plain(payload: dict, path: str | Path, what: str) -> Path:
    """``torch.save`` a plain ``payload`` (refused by name otherwise) to a temporary name beside ``path``, renamed."""
    _check_plain(payload, what)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)
    return path


def _check_plain(value: Any, where: str) -> None:
    if isinstance(value, (torch.Tensor, str, int, float, bool, type(None))):
        return
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, (str, int)):
                raise TypeError(f"{where}: key {key!r} is a {type(key).__name__}; checkpoint keys must be str or int")
            _check_plain(item, f"{where}.{key}")
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_plain(item, f"{where}[{i}]")
    else:
        raise TypeError(f"{where} is a {type(value).__name__}; a checkpoint holds only tensors, dicts, lists, "
                        "str, int, float, bool and None (convert it, e.g. model_dump() or state_dict())")


def _reason(exc: Exception) -> str:
    """What torch.load(weights_only=True) refused, in one sentence: its WeightsUnpickler reason where it gives one
    (an unsupported global or operand), else its first line."""
    text = str(exc)
    if "WeightsUnpickler error:" in text:
        text = text.split("WeightsUnpickler error:", 1)[1]
    line = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
    first = re.match(r"(.*?\.)(?:\s|$)", line)
    return (first.group(1) if first else line)[:200]


def load_checkpoint(path: str | Path, map_location: torch.device | str | None = "cpu") -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` (``weights_only=True``: no code runs).

    Returns the payload dict (``format_version``, ``flashnav_version``, ``learner``, ``config``, ``extra``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a FlashNav checkpoint, a format version this FlashNav does not read (the
            message names the file, the found and the supported versions), or a missing key.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # pickle errors, zip errors, disallowed globals: all mean "not ours"
        # the reason alone: torch's weights_only text around it offers loading with weights_only False, which a
        # checkpoint from elsewhere must never get (it would run the file's code)
        raise ValueError(f"{path}: not a readable FlashNav checkpoint ({type(exc).__name__}: {_reason(exc)})") from None
    if not isinstance(payload, dict) or "format_version" not in payload:
        raise ValueError(f"{path}: not a FlashNav checkpoint (no format_version)")
    found, supported = payload["format_version"], SUPPORTED_CHECKPOINT_VERSIONS
    if isinstance(found, bool) or not isinstance(found, int) or found not in supported:
        newer = " (written by a newer FlashNav?)" if isinstance(found, int) and found > max(supported) else ""
        raise ValueError(f"{path}: checkpoint format_version {found!r} is not supported{newer}; "
                         f"this FlashNav {__version__} reads format_version {', '.join(map(str, supported))}")
    missing = [k for k in CHECKPOINT_KEYS if k not in payload]
    if missing:
        raise ValueError(f"{path}: checkpoint (format_version {found}) lacks {', '.join(missing)}")
    return payload


#: Version of the replay payload (``{format_version, flashnav_version, replay}``); load_replay accepts exactly it.
REPLAY_FORMAT_VERSION = 1


def save_replay(path: str | Path, state: dict) -> Path:
    """Write a replay buffer's state (:meth:`flashnav.learn.replay.Replay.state_dict`) to ``path``, as
    :func:`save_checkpoint` writes (plain data only; a temporary name renamed, never a truncated file)."""
    return _save_plain({"format_version": REPLAY_FORMAT_VERSION, "flashnav_version": __version__, "replay": state},
                       path, "replay")


def load_replay(path: str | Path) -> dict:
    """A :func:`save_replay` file's replay state (``weights_only=True``: no code runs). FileNotFoundError or
    ValueError naming the file where it is missing, unreadable or of another format version."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such replay file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise ValueError(f"{path}: not a readable FlashNav replay ({type(exc).__name__}: {_reason(exc)})") from None
    found = payload.get("format_version") if isinstance(payload, dict) else None
    if found != REPLAY_FORMAT_VERSION or "replay" not in payload:
        raise ValueError(f"{path}: not a FlashNav replay of format_version {REPLAY_FORMAT_VERSION} (found {found!r})")
    return payload["replay"]
