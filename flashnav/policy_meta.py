"""The exported-policy metadata format, torch-free (read by flashnav.export and flashnav.deploy).

Every exported policy (``policy.pt``'s ``_extra_files``, ``policy.onnx``'s ``metadata_props``) carries
one JSON document under :data:`METADATA_KEY`; :func:`flashnav.export.policy_metadata` writes it. This
module only knows how to read and check it, so that a robot-side runtime can do so without torch.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from flashnav.version import __version__

#: Version of the exported-policy metadata (bumped when its layout changes incompatibly; new keys are
#: added without a bump, and readers fall back to the ``preset`` block for files that lack them).
POLICY_FORMAT_VERSION = 1
#: Name of the metadata entry in policy.pt (``_extra_files``) and in policy.onnx (``metadata_props``).
METADATA_KEY = "flashnav.json"


def open_onnx(path: str | Path, threads: int | None = None):
    """(onnxruntime session on the CPU, its FlashNav metadata) of ``policy.onnx`` at ``path``: the one reader of
    an exported ONNX policy (:func:`flashnav.export.load_policy`, :class:`flashnav.deploy.runtime.PolicyRuntime`).
    ``threads``: onnxruntime's intra- and inter-op threads (None: its default). Raises ImportError without
    onnxruntime and ValueError naming ``path`` for a file it cannot read or without FlashNav metadata."""
    try:
        import onnxruntime as ort
    except ImportError:
        raise ImportError("running policy.onnx needs onnxruntime: pip install 'flashnav[export]'") from None
    options = ort.SessionOptions()
    if threads is not None:
        options.intra_op_num_threads = options.inter_op_num_threads = threads
    try:
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's own exception types (InvalidProtobuf, Fail, ...): a bad file
        raise ValueError(f"{path}: not a readable ONNX policy ({first_sentence(exc)})") from None
    return session, parse_metadata(path, session.get_modelmeta().custom_metadata_map.get(METADATA_KEY))


def first_sentence(exc: BaseException) -> str:
    """The gist of a runtime's error (torch appends a paragraph of advice about corrupt checkpoints), at most
    200 characters."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text.split(". ")[0].rstrip(".")[:200]


def parse_metadata(path: str | Path, text: str | bytes | None) -> dict[str, Any]:
    """The metadata dict of the policy file ``path`` from its stored JSON ``text``.

    Raises ValueError naming ``path`` for missing metadata, invalid JSON, no integer ``obs_dim`` or a
    format version newer than this FlashNav reads."""
    if not text:
        raise ValueError(f"{path}: no FlashNav metadata ({METADATA_KEY}); export it with flashnav.export.export_policy")
    try:
        meta = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{path}: FlashNav metadata ({METADATA_KEY}) is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("obs_dim"), int):
        raise ValueError(f"{path}: FlashNav metadata ({METADATA_KEY}) lacks an integer obs_dim")
    version = meta.get("format_version")
    if not isinstance(version, int) or version > POLICY_FORMAT_VERSION:
        raise ValueError(f"{path}: policy format version {version!r} is not supported "
                         f"(this FlashNav {__version__} reads <= {POLICY_FORMAT_VERSION})")
    return meta


def scan_history_frames(meta: dict[str, Any], path: str | Path = "<policy>") -> int:
    """The number of previous pooled scans k the policy's observation carries (``observation.scan_history``,
    :mod:`flashnav.sim.history`): ``observation.scan_history.frames``, else the exported preset's
    ``observation.scan_history``, else 0 (files written before the history existed).

    Raises ValueError naming ``path`` when the recorded value is not an integer >= 0."""
    return _recorded_count(meta, "scan_history", "frames", path)


def agent_track_count(meta: dict[str, Any], path: str | Path = "<policy>") -> int:
    """The number of agent tracks M the policy's observation ends with (``observation.agent_tracks``,
    :mod:`flashnav.sim.tracks`): ``observation.agent_tracks.count``, else the exported preset's
    ``observation.agent_tracks``, else 0 (files written before the tracks existed).

    Raises ValueError naming ``path`` when the recorded value is not an integer >= 0."""
    return _recorded_count(meta, "agent_tracks", "count", path)


def pose_trail_shape(meta: dict[str, Any], path: str | Path = "<policy>") -> tuple[int, int]:
    """``(count, every)`` of the policy's pose trail (``observation.pose_trail`` breadcrumbs, one every
    ``observation.trail_every`` control steps, :mod:`flashnav.sim.trail`): the metadata's
    ``observation.pose_trail``, else the exported preset's, else ``(0, 1)`` (files written before the
    trail existed).

    Raises ValueError naming ``path`` when a recorded value is not an integer (count >= 0, every >= 1)."""
    count = _recorded_count(meta, "pose_trail", "count", path)
    return count, _recorded_int(meta, "pose_trail", "every", "trail_every", 1, path)


def memory_scan_shape(meta: dict[str, Any], path: str | Path = "<policy>") -> tuple[int, int, int]:
    """``(frames, every, points)`` of the policy's memory scan (``observation.memory_frames`` stored scans, one
    every ``observation.memory_every`` control steps, each kept as ``points`` hits, :mod:`flashnav.sim.memory`):
    the metadata's ``observation.memory_scan``, else the exported preset's, else ``(0, 1, 0)`` (files written
    before the memory existed). ``points`` is 0 without a memory.

    Raises ValueError naming ``path`` when a recorded value is not an integer (frames >= 0, every >= 1) or
    when a policy with a memory does not record its ``points_per_frame`` (>= 1)."""
    frames = _recorded_int(meta, "memory_scan", "frames", "memory_frames", 0, path)
    every = _recorded_int(meta, "memory_scan", "every", "memory_every", 1, path)
    if not frames:
        return frames, every, 0
    points = _metadata_field(meta, "memory_scan", "points_per_frame")
    if not isinstance(points, int) or isinstance(points, bool) or points < 1:
        raise ValueError(f"{path}: the policy's metadata records a memory scan of {frames} frames but "
                         f"observation.memory_scan.points_per_frame {points!r}; expected an integer >= 1")
    return frames, every, points


#: The wall map's channels in their order, as the metadata's ``observation.wall_map.channels`` lists them: walls and
#: goal, then the visited squares only with ``observation.wall_map_visited``, then the plan's only with
#: ``observation.wall_map_plan``.
WALL_MAP_CHANNEL_NAMES = ("walls", "goal", "visited", "plan")


def wall_map_channel_names(cells: int, visited: bool = False, plan: bool = False) -> tuple[str, ...]:
    """The wall map's channels in order, the one rule every reader of the layout uses (the preset's
    ``observation.wall_map_channels``, the networks' ``ObsLayout.wall_channels``, the export and this module's
    reader): none without a map (``cells`` 0), else walls and goal, then the visited squares with ``visited``, then
    the plan's with ``plan``."""
    if not cells:
        return ()
    return WALL_MAP_CHANNEL_NAMES[:2] + ("visited",) * bool(visited) + ("plan",) * bool(plan)


def wall_map_channel_list(meta: dict[str, Any], path: str | Path = "<policy>") -> tuple[str, ...]:
    """The policy's wall-map channels by name: none without a wall map, walls and goal (also for a file written before
    the metadata listed them), then visited and plan where listed. Raises ValueError naming ``path`` for any other
    list."""
    if not wall_map_shape(meta, path)[0]:
        return ()
    names = _metadata_field(meta, "wall_map", "channels")
    if names is None:
        return wall_map_channel_names(1)
    known = [list(wall_map_channel_names(1, visited, plan)) for plan in (False, True) for visited in (False, True)]
    if names in known:
        return tuple(names)
    raise ValueError(f"{path}: the policy's metadata lists wall-map channels {names!r}; this runtime knows "
                     f"{', '.join(map(str, known))}")


def wall_map_channels(meta: dict[str, Any], path: str | Path = "<policy>") -> int:
    """The policy's wall-map channels: 0 without a wall map, else 2 to 4 (:func:`wall_map_channel_list`)."""
    return len(wall_map_channel_list(meta, path))


def wall_map_shape(meta: dict[str, Any], path: str | Path = "<policy>") -> tuple[int, float, float, float]:
    """``(cells, cell_m, grid_m, beyond_m)`` of the policy's wall map (``observation.wall_map``,
    :class:`flashnav.sim.wall_grid.WallGrid`): the metadata's ``observation.wall_map``; ``(0, 0, 0, 0)`` for a policy
    without one or a file written before the wall map existed.

    Raises ValueError naming ``path`` when a recorded value has the wrong type or range."""
    cells = _recorded_int(meta, "wall_map", "cells", "wall_map", 0, path)
    if not cells:
        return 0, 0.0, 0.0, 0.0
    values = []
    for field, low in (("cell_m", 0.0), ("grid_m", 0.0), ("beyond_m", None)):
        v = _metadata_field(meta, "wall_map", field)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and (
            v > low if low is not None else v >= 0)
        if not ok:
            raise ValueError(f"{path}: the policy's metadata records a wall map of {cells} squares but "
                             f"observation.wall_map.{field} {v!r}; expected a finite number "
                             f"{'> 0' if low is not None else '>= 0'} (metres)")
        values.append(float(v))
    return (cells, *values)


def wall_map_carrot(meta: dict[str, Any], path: str | Path = "<policy>") -> float:
    """Metres along the plan of the policy's carrot (``observation.wall_map_carrot``; 0 = none): the metadata's
    ``observation.carrot.length_m``, else the exported preset's, else 0 (files written before the carrot existed).
    Raises ValueError naming ``path`` unless it is a finite number >= 0 (> 0 needs the wall map's plan channel)."""
    value, key = _metadata_field(meta, "carrot", "length_m"), "observation.carrot.length_m"
    if value is None:
        value = ((meta.get("preset") or {}).get("observation") or {}).get("wall_map_carrot", 0.0)
        key = "preset.observation.wall_map_carrot"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{path}: the policy's metadata records {key} {value!r}; expected a finite number >= 0 "
                         "(metres)")
    if value and "plan" not in wall_map_channel_list(meta, path):
        raise ValueError(f"{path}: the policy's metadata records a carrot {value:g} m along the plan but no plan "
                         "channel in its wall map")
    return float(value)


def _recorded_count(meta: dict[str, Any], option: str, field: str, path: str | Path) -> int:
    """``observation.<option>.<field>`` of the metadata, else the preset block's ``observation.<option>``,
    else 0; a ValueError naming ``path`` unless it is an integer >= 0."""
    return _recorded_int(meta, option, field, option, 0, path)


def _metadata_field(meta: dict[str, Any], block: str, field: str) -> Any:
    """``observation.<block>.<field>`` of the metadata, None where any level is missing."""
    return ((meta.get("observation") or {}).get(block) or {}).get(field)


def _recorded_int(meta: dict[str, Any], block: str, field: str, preset_key: str, least: int,
                  path: str | Path) -> int:
    """``observation.<block>.<field>`` of the metadata, else the preset block's ``observation.<preset_key>``,
    else ``least`` (files written before the option existed); a ValueError naming ``path`` and ``preset_key``
    unless it is an integer >= ``least``."""
    recorded = _metadata_field(meta, block, field)
    if recorded is None:
        recorded = ((meta.get("preset") or {}).get("observation") or {}).get(preset_key, least)
    if not isinstance(recorded, int) or isinstance(recorded, bool) or recorded < least:
        raise ValueError(f"{path}: the policy's metadata records {preset_key} {recorded!r}; expected an integer "
                         f">= {least}")
    return recorded
