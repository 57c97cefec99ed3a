"""The maps shipped with FlashNav (``flashnav/maps/data/NAME.yaml`` + image), and map resolution.

Each bundled map was made once by :mod:`flashnav.maps.generate` (the exact command is the comment at
the top of its YAML) and is stored as a ROS map, so benchmark numbers stay comparable across versions
even if the generator changes (or numpy's random streams do).

- ``turtlebot2``: 10 x 10 m, 0.05 m cells, passages for a 0.3 m disc (radius 0.2 + clearance 0.1)
  plus a 0.1 m margin on each side; 15 % of the interior occupied, 18 obstacles.
- ``go2``: 13.5 x 13.5 m, 0.05 m cells, passages for a 0.55 m disc (circumscribed radius 0.449 +
  clearance 0.1) plus the margin; 11.5 % of the interior occupied, 14 obstacles.

Their seeds (4 and 6) were picked among seeds 0-11 as the ones with the most clutter and the shortest
detours (shortest path / straight line for start-goal pairs 1-5 m apart: mean 1.12 and 1.10 on an
8-connected grid, worst 1.74).
"""

from __future__ import annotations

import functools
import shutil
import tempfile
from importlib import resources
from pathlib import Path

from flashnav.maps.grid import OccupancyMap
from flashnav.maps.ros import load_ros_map

_PACKAGE, _FOLDER = "flashnav.maps", "data"


@functools.lru_cache(maxsize=1)
def _data_dir() -> Path:
    """The bundled maps' folder on the file system (copied out once if the package is zipped)."""
    data = resources.files(_PACKAGE).joinpath(_FOLDER)
    if isinstance(data, Path):
        return data
    # A zip or other non-file-system install: the loader needs real files (the YAML names its image
    # relative to itself), so copy the folder out once for this process.
    out = Path(tempfile.mkdtemp(prefix="flashnav_maps_"))
    for item in data.iterdir():
        if item.is_file():
            with item.open("rb") as src, open(out / item.name, "wb") as dst:
                shutil.copyfileobj(src, dst)
    return out


def bundled_map_names() -> list[str]:
    """Names of the bundled maps, sorted (``["go2", "turtlebot2"]``)."""
    return sorted(p.stem for p in _data_dir().glob("*.yaml"))


@functools.lru_cache(maxsize=None)
def bundled_map(name: str) -> OccupancyMap:
    """A bundled map by name, loaded once per process (an ``OccupancyMap`` is read-only, so the cached
    object is safely shared).

    Raises:
        ValueError: ``name`` is not a bundled map (the message lists the names).
    """
    names = bundled_map_names()
    if name not in names:
        raise ValueError(f"unknown bundled map {name!r}; bundled maps: {', '.join(names)}")
    return load_ros_map(_data_dir() / f"{name}.yaml")


def resolve_map(map: OccupancyMap | str | Path | None, default: str) -> OccupancyMap:  # noqa: A002
    """Turn what a user or a preset names as a map into an ``OccupancyMap``.

    Args:
        map: ``None`` (the map ``default``), an ``OccupancyMap`` (returned as is), a bundled
            map name (e.g. ``"turtlebot2"``), or a path to a ROS map YAML.
        default: what is used when ``map`` is None: a preset's ``map``, a bundled map name or a ROS map YAML path.

    Raises:
        ValueError: a string that is neither a bundled name nor an existing ``.yaml``/``.yml`` file.
        FileNotFoundError, ValueError: from :func:`load_ros_map` for a bad map file.
        TypeError: any other kind of value.
    """
    if map is None:
        if default in bundled_map_names():
            return bundled_map(default)
        map = default  # noqa: A001  (a preset whose own map is a ROS map YAML)
    if isinstance(map, OccupancyMap):
        return map
    if isinstance(map, (str, Path)):
        text = str(map)
        path = Path(map).expanduser()
        looks_like_name = isinstance(map, str) and not path.suffix and "/" not in text and "\\" not in text
        if looks_like_name and text in bundled_map_names():
            return bundled_map(text)
        if path.suffix.lower() in (".yaml", ".yml") or path.is_file():
            return load_ros_map(path)
        raise ValueError(
            f"map {text!r} is neither a bundled map ({', '.join(bundled_map_names())}) nor a ROS map "
            "YAML file (a path ending in .yaml)"
        )
    raise TypeError(
        f"map must be None, an OccupancyMap, a bundled map name or a ROS map YAML path, got {type(map).__name__}"
    )


class MapsNotFound(ValueError):
    """A single string given as maps that names nothing: no file, folder, bundled map or glob match (a caller that
    takes more forms, such as `eval --maps` and its committed suites, can say so)."""


def resolve_maps(maps, default: str) -> list[OccupancyMap]:
    """Turn what a user names as a set of maps into a list of ``OccupancyMap`` (in a stable order).

    Args:
        maps: a sequence of what :func:`resolve_map` takes (OccupancyMap, bundled name, ROS YAML
            path); or one string/path: a directory (its ``*.yaml`` / ``*.yml`` files, sorted by name),
            a glob pattern (``maps/*.yaml``, sorted matches), or one map as :func:`resolve_map` takes.
        default: the bundled map for a ``None`` entry.

    Raises:
        MapsNotFound: a pattern matching no file, or a single string naming nothing that exists.
        ValueError: an empty sequence, a directory with no map YAML, or an entry :func:`resolve_map` refuses
            (the message names it).
    """
    if isinstance(maps, (str, Path)):
        text = str(maps)
        path = Path(text).expanduser()
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".yaml", ".yml") and p.is_file())
            if not files:
                raise ValueError(f"maps directory {text!r} holds no ROS map YAML file (*.yaml, *.yml)")
            return [load_ros_map(p) for p in files]
        if any(ch in text for ch in "*?["):
            import glob

            files = sorted(glob.glob(str(path)))
            if not files:
                raise MapsNotFound(f"maps pattern {text!r} matches no file")
            return [resolve_map(Path(f), default) for f in files]
        if not path.exists() and text not in bundled_map_names():
            raise MapsNotFound(
                f"maps {text!r}: no such directory or file; maps are a directory of ROS map YAML files, a glob "
                f"pattern (quote it), or one map: a bundled name ({', '.join(bundled_map_names())}) or a .yaml path"
                + ("; maps generated during training are family:F1,F2" if ":" in text else "")
            )
        return [resolve_map(maps, default)]
    if isinstance(maps, OccupancyMap):
        return [maps]
    items = list(maps)
    if not items:
        raise ValueError("maps must name at least one map, got an empty list")
    return [resolve_map(item, default) for item in items]
