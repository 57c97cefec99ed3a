"""ROS map_server / Nav2 map files (a YAML + an image) in and out.

The YAML keys are the ones Nav2's ``map_server`` reads:

- ``image``: the image file, relative to the YAML file's folder, or absolute.
- ``resolution``: metres per pixel (> 0).
- ``origin``: ``[x, y, yaw]``, the world pose of the *lower-left* pixel. FlashNav maps are axis-aligned:
  a non-zero yaw is ignored with a warning that names the file.
- ``negate``: 0/1 (or a bool): if set, dark pixels are free and light pixels are occupied.
- ``occupied_thresh``, ``free_thresh``: in [0, 1], ``free_thresh < occupied_thresh``.
- ``mode`` (optional, default ``trinary``): ``trinary`` | ``scale`` | ``raw``.

Nav2 requires every key but ``mode``; so do we (a missing key is an error that names it).

How a pixel becomes a cell (the rule of Nav2's ``map_io.cpp``, re-derived here, not copied):

- ``shade`` is the brightness in [0, 1]: the mean of the red, green and blue channels (a grey image
  counts its grey value three times) divided by the channel maximum (255, or 65535 for 16-bit grey).
  In ``trinary`` mode only, an image with an alpha channel adds the alpha (255 = opaque) as a fourth
  channel to the mean, so a transparent pixel reads darker. ``scale`` and ``raw`` leave alpha out of
  the mean.
- ``occ = shade`` if ``negate`` else ``1 - shade``.
- ``trinary``: occupied if ``occ > occupied_thresh``, free if ``occ < free_thresh``, else unknown.
- ``scale``: a pixel that is not fully opaque is unknown; otherwise occupied / free by the same two
  thresholds, and in between Nav2 stores ``rint(100 * (occ - free) / (occupied - free))``, an
  occupancy probability in percent.
- ``raw``: the cell value is ``round(255 * shade)`` (``negate`` and the thresholds are not used);
  values 0..100 are kept as occupancy percent, anything above is unknown.

Pitfall kept as Nav2 has it: map savers write unknown cells as grey 205, and with ``free_thresh``
0.25 (Nav2's default) that grey reads as *free*; the loader then warns (set ``free_thresh`` <= 0.196,
ROS 1's default, to keep unknown space an obstacle).

FlashNav's grid is binary, so a cell is free only where Nav2 would store 0 (FREE); occupied, unknown
and every intermediate probability count as obstacles (the conservative reading: a policy trained on
it never plans through a cell the map is unsure about).

Image row 0 is the top of the map; ``OccupancyMap`` row 0 is the bottom: rows are flipped on the way
in and out. Images are read with Pillow: PGM (P5 and P2, comments allowed, any maxval), PNG (grey,
grey + alpha, RGB, RGBA, palette), 8-bit or 16-bit grey.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from flashnav.maps import grid as _grid
from flashnav.maps.grid import OccupancyMap
from flashnav.yamlio import load_yaml

MODES = ("trinary", "scale", "raw")
REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")
SAVE_OCCUPIED, SAVE_FREE = 0, 254  # what Nav2's map_saver writes for occupied / free in trinary mode
SAVE_OCCUPIED_THRESH, SAVE_FREE_THRESH = 0.65, 0.25
UNKNOWN_GREY = 205  # the grey ROS / Nav2 map savers write for unknown cells
_CHUNK_PIXELS = 1 << 22  # classify big images in row blocks to bound the float64 temporaries
#: finest accepted resolution, metres per pixel: a robot spans (size / resolution) cells in the
#: collision and distance grids, so 1e-9 m asks for petabytes; no LiDAR map is finer than a millimetre.
MIN_RESOLUTION = 1e-3
#: a cell must span at least this many float64 steps at the map's coordinates, or cell positions
#: round (1e308 as an origin overflows; 1e12 m still leaves 0.05 m cells ~400 steps)
MIN_STEPS_PER_CELL = 8


def load_ros_map(yaml_path: str | Path) -> OccupancyMap:
    """Read a ROS map_server / Nav2 map.

    Args:
        yaml_path: the map's YAML file.

    Returns:
        An ``OccupancyMap`` of ``[H, W]`` cells (H, W = image height, width in pixels), resolution and
        origin (x, y) in metres from the YAML, ``name`` = the YAML file's stem, ``source`` = its path.

    Raises:
        FileNotFoundError: the YAML or the image does not exist (the message names both).
        ValueError: malformed YAML values, an unreadable or oversized image, or no free cell at all.
    """
    yaml_path = Path(yaml_path)
    meta = _read_yaml(yaml_path)
    image_path = _image_path(yaml_path, meta["image"])
    free = _classify_image(image_path, yaml_path, meta)  # [H, W] bool, image row order (top first)
    if not free.any():
        raise ValueError(
            f"{yaml_path}: empty free space: no pixel of {image_path} is free under mode {meta['mode']!r}, "
            f"negate {int(meta['negate'])}, free_thresh {meta['free_thresh']}, occupied_thresh "
            f"{meta['occupied_thresh']} (is negate inverted?)"
        )
    _check_extent(yaml_path, meta, free.shape)
    ox, oy, _ = meta["origin"]
    return OccupancyMap(
        occupied=~free[::-1], resolution=meta["resolution"], origin=(ox, oy), name=yaml_path.stem, source=yaml_path
    )


def save_ros_map(
    grid: OccupancyMap, yaml_path: str | Path, image_format: str = "pgm", *, comment: str | None = None
) -> Path:
    """Write ``grid`` as a trinary ROS map: ``<yaml stem>.<image_format>`` next to the YAML.

    Occupied cells are written black (0), free cells white (254), as Nav2's map_saver does; the YAML
    names the image relative to itself and sets negate 0, occupied_thresh 0.65, free_thresh 0.25, mode
    trinary, origin [x, y, 0.0]. ``load_ros_map`` of the result gives back ``grid`` exactly.

    Args:
        grid: the map to write.
        yaml_path: where to write the YAML (its folder is created if needed).
        image_format: ``"pgm"`` (binary P5) or ``"png"`` (8-bit grey).
        comment: optional text written as ``#`` comment lines at the top of the YAML.

    Returns:
        The YAML file's path.
    """
    fmt = str(image_format).lower()
    if fmt not in ("pgm", "png"):
        raise ValueError(f"image_format must be 'pgm' or 'png', got {image_format!r}")
    yaml_path = Path(yaml_path)
    yaml_path.parent.mkdir(parents=True, exist_ok=True)
    image_path = yaml_path.with_name(f"{yaml_path.stem}.{fmt}")
    pixels = np.where(grid.occupied[::-1], SAVE_OCCUPIED, SAVE_FREE).astype(np.uint8)
    Image.fromarray(pixels).save(image_path, format="PPM" if fmt == "pgm" else "PNG")
    meta = {
        "image": image_path.name,
        "mode": "trinary",
        "resolution": float(grid.resolution),
        "origin": [float(grid.origin[0]), float(grid.origin[1]), 0.0],
        "negate": 0,
        "occupied_thresh": SAVE_OCCUPIED_THRESH,
        "free_thresh": SAVE_FREE_THRESH,
    }
    header = "".join(f"# {line}\n".replace("# \n", "#\n") for line in (comment or "").splitlines())
    yaml_path.write_text(header + yaml.safe_dump(meta, sort_keys=False, default_flow_style=None), encoding="utf-8")
    return yaml_path


# ---- YAML ------------------------------------------------------------------------------------------
def _read_yaml(yaml_path: Path) -> dict[str, Any]:
    """Validated metadata: image (str), resolution (float), origin (x, y, yaw), negate (bool),
    occupied_thresh, free_thresh (float), mode (str)."""
    if not yaml_path.is_file():
        raise FileNotFoundError(f"{yaml_path}: map YAML not found")
    if yaml_path.suffix.lower() in (".pgm", ".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff"):
        beside = yaml_path.with_suffix(".yaml")
        hint = f" ({beside} is beside it)" if beside.is_file() else ""
        raise ValueError(f"{yaml_path}: is a map image; give its ROS map YAML (resolution, origin, thresholds){hint}")
    doc = load_yaml(yaml_path)
    if not isinstance(doc, dict):
        raise ValueError(
            f"{yaml_path}: a ROS map YAML must be a mapping with keys {', '.join(REQUIRED_KEYS)} "
            f"(and optionally mode), got {type(doc).__name__}"
        )
    for key in REQUIRED_KEYS:
        if key not in doc or doc[key] is None:
            raise ValueError(f"{yaml_path}: missing required key {key!r} (a ROS map YAML needs {', '.join(REQUIRED_KEYS)})")

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise ValueError(f"{yaml_path}: 'image' must be a non-empty file name, got {image!r}")
    resolution = _number(doc, "resolution", yaml_path)
    if resolution <= 0:
        raise ValueError(f"{yaml_path}: 'resolution' must be > 0 metres per pixel, got {resolution}")
    if resolution < MIN_RESOLUTION:
        raise ValueError(f"{yaml_path}: 'resolution' {resolution} m per pixel is finer than {MIN_RESOLUTION} m: "
                         "a robot would span an absurd number of cells (is the value in metres?)")

    origin = doc["origin"]
    if not isinstance(origin, (list, tuple)) or len(origin) != 3 or not all(_is_number(v) for v in origin):
        raise ValueError(f"{yaml_path}: 'origin' must be [x, y, yaw] (three numbers), got {origin!r}")
    origin = tuple(float(v) for v in origin)
    if not all(math.isfinite(v) for v in origin):
        raise ValueError(f"{yaml_path}: 'origin' must be finite, got {list(origin)}")
    if origin[2] != 0.0:
        # The simulator (LiDAR, collision, sampling) works on an axis-aligned grid; rotating the map
        # would resample it. The yaw only rotates the map in the world frame, which a policy that
        # sees ranges and a relative goal never observes, so dropping it is safe for training.
        warnings.warn(
            f"{yaml_path}: origin yaw {origin[2]} rad ignored: FlashNav maps are axis-aligned "
            "(the map is used unrotated)",
            stacklevel=3,
        )

    negate = doc["negate"]
    if isinstance(negate, bool) or (isinstance(negate, int)):
        negate = bool(negate)  # Nav2 reads an int (non-zero = negate) or a bool
    else:
        raise ValueError(f"{yaml_path}: 'negate' must be 0 or 1 (or true/false), got {negate!r}")

    occ_t = _number(doc, "occupied_thresh", yaml_path)
    free_t = _number(doc, "free_thresh", yaml_path)
    if not (0.0 <= free_t <= 1.0 and 0.0 <= occ_t <= 1.0):
        raise ValueError(
            f"{yaml_path}: thresholds must lie in [0, 1], got free_thresh {free_t}, occupied_thresh {occ_t}"
        )
    if not free_t < occ_t:
        raise ValueError(
            f"{yaml_path}: free_thresh ({free_t}) must be smaller than occupied_thresh ({occ_t})"
        )

    mode = doc.get("mode", "trinary")
    if mode is None:
        mode = "trinary"
    if mode not in MODES:
        raise ValueError(f"{yaml_path}: 'mode' must be one of {', '.join(MODES)}, got {mode!r}")
    return dict(image=image, resolution=resolution, origin=origin, negate=negate,
                occupied_thresh=occ_t, free_thresh=free_t, mode=mode)


def _check_extent(yaml_path: Path, meta: dict[str, Any], shape: tuple[int, int]) -> None:
    """The map's far corner must be finite and cells wide enough for float64 at that magnitude."""
    res, (ox, oy, _) = meta["resolution"], meta["origin"]
    extent = (shape[1] * res, shape[0] * res)
    if not all(math.isfinite(v) for v in extent):
        raise ValueError(f"{yaml_path}: 'resolution' {res} makes the {shape[1]} x {shape[0]} pixel map infinitely large")
    far = max(abs(ox) + extent[0], abs(oy) + extent[1])
    step = math.ulp(far) if math.isfinite(far) else math.inf
    if step * MIN_STEPS_PER_CELL > res:
        raise ValueError(f"{yaml_path}: 'origin' {list(meta['origin'])} is too far out for {res} m cells: "
                         f"coordinates near {far:.3g} m are only representable in steps of {step:.3g} m")


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(doc: dict, key: str, yaml_path: Path) -> float:
    v = doc[key]
    if not _is_number(v) or not math.isfinite(float(v)):
        raise ValueError(f"{yaml_path}: {key!r} must be a finite number, got {v!r}")
    return float(v)


def map_files(yaml_path: str | Path) -> list[Path]:
    """The files a ROS map is read from: its YAML and, where the YAML names one, its image (resolved as
    :func:`load_ros_map` resolves it, whether or not it exists); just the YAML when it cannot be read. For the checks
    that an output never overwrites a command's map (:func:`flashnav.outputs.check_output_file`)."""
    path = Path(yaml_path)
    try:
        image = load_yaml(path).get("image")
    except Exception:  # noqa: BLE001 - any unreadable YAML: the loader will say what is wrong with it
        return [path]
    if not isinstance(image, str) or not image:
        return [path]
    return [path, Path(image) if Path(image).is_absolute() else path.parent / image]


def _image_path(yaml_path: Path, image: str) -> Path:
    path = Path(image)
    if not path.is_absolute():
        path = yaml_path.parent / path  # Nav2: relative to the YAML's folder, not the working directory
    if path.is_dir():
        raise FileNotFoundError(f"{yaml_path}: image: {image!r} is a folder ({path}), not the map's image file")
    if not path.is_file():
        raise FileNotFoundError(
            f"{yaml_path}: image file not found: tried {path} (from image: {image!r}; a relative path is "
            f"resolved against the YAML file's folder {yaml_path.parent})"
        )
    return path


# ---- image -----------------------------------------------------------------------------------------
def _open_image(image_path: Path, yaml_path: Path) -> Image.Image:
    """Open and decode the image, refusing one larger than ``grid.MAX_CELLS`` pixels from its header
    (Pillow reads the size lazily; nothing is decoded before the check)."""
    # Our own limit (MAX_CELLS) replaces Pillow's decompression-bomb guard, whose default
    # (~179 M pixels) is lower than the maps the grid accepts.
    saved_limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None
    try:
        try:
            img = Image.open(image_path)
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
            raise ValueError(f"{yaml_path}: cannot read image {image_path}: not a readable image ({exc})") from None
        try:
            width, height = img.size
            if width * height > _grid.MAX_CELLS:
                raise ValueError(
                    f"{yaml_path}: image {image_path} is too large: {width} x {height} = {width * height} "
                    f"pixels exceeds the limit of {_grid.MAX_CELLS} cells (crop or downsample the map)"
                )
            if width * height == 0:
                raise ValueError(f"{yaml_path}: image {image_path} is empty ({width} x {height} pixels)")
            try:
                img.load()
            except (OSError, SyntaxError, ValueError, MemoryError) as exc:
                raise ValueError(
                    f"{yaml_path}: cannot decode image {image_path}: corrupt or truncated ({exc})"
                ) from None
        except BaseException:
            img.close()
            raise
        return img
    finally:
        Image.MAX_IMAGE_PIXELS = saved_limit


def _pixels(img: Image.Image, image_path: Path, yaml_path: Path) -> tuple[np.ndarray, np.ndarray | None, int]:
    """(colour [H, W] or [H, W, 3] integer array, alpha [H, W] or None, channel maximum)."""
    mode = img.mode
    if mode == "1":
        img, mode = img.convert("L"), "L"
    elif mode in ("P", "PA"):
        transparent = mode == "PA" or img.has_transparency_data
        img = img.convert("RGBA" if transparent else "RGB")
        mode = img.mode
    elif mode in ("L", "RGB") and "transparency" in img.info:
        img = img.convert("RGBA")  # a tRNS transparent colour is an alpha channel to Nav2 too
        mode = img.mode
    if mode in ("I", "I;16", "I;16B", "I;16L", "I;16N"):
        arr = np.asarray(img)  # uint16 or int32
        if arr.min() < 0 or arr.max() > 65535:
            raise ValueError(f"{yaml_path}: image {image_path}: 32-bit integer pixels are not supported")
        return arr, None, 65535
    if mode in ("L", "RGB"):
        return np.asarray(img), None, 255
    if mode in ("LA", "RGBA"):
        arr = np.asarray(img)
        return arr[..., :-1] if mode == "RGBA" else arr[..., 0], arr[..., -1], 255
    if mode in ("CMYK", "YCbCr", "LAB", "HSV"):
        return np.asarray(img.convert("RGB")), None, 255
    raise ValueError(f"{yaml_path}: image {image_path}: unsupported pixel format {mode!r} (use 8-bit grey or RGB(A))")


def _classify_image(image_path: Path, yaml_path: Path, meta: dict[str, Any]) -> np.ndarray:
    """[H, W] bool, True where Nav2 would store FREE (0); image row order (row 0 = top)."""
    with _open_image(image_path, yaml_path) as img:
        colour, alpha, maxval = _pixels(img, image_path, yaml_path)
    free = np.empty(colour.shape[:2], dtype=bool)
    grey_205_free = 0
    rows = max(1, _CHUNK_PIXELS // colour.shape[1])
    for r0 in range(0, colour.shape[0], rows):
        sl = slice(r0, r0 + rows)
        free[sl] = _free_cells(colour[sl], None if alpha is None else alpha[sl], maxval, meta)
        if meta["mode"] == "trinary" and maxval == 255:
            grey = colour[sl] == UNKNOWN_GREY if colour.ndim == 2 else (colour[sl] == UNKNOWN_GREY).all(axis=-1)
            grey_205_free += int((grey & free[sl]).sum())
    if grey_205_free:
        # Nav2's map_saver writes unknown cells as grey 205 but its default free_thresh 0.25 reads 205
        # back as free (1 - 205/255 = 0.196 < 0.25): unmapped space would become drivable. We keep
        # Nav2's rule (the map means what Nav2 serves) and say so.
        warnings.warn(
            f"{yaml_path}: {grey_205_free} pixels of {image_path} have the grey 205 that map savers use "
            f"for 'unknown', yet free_thresh {meta['free_thresh']} makes them free (as Nav2 does); if they "
            "are unmapped space, set free_thresh to 0.196 or below so that they count as obstacles",
            stacklevel=3,
        )
    return free


def _free_cells(colour: np.ndarray, alpha: np.ndarray | None, maxval: int, meta: dict[str, Any]) -> np.ndarray:
    """Nav2's per-pixel rule (see the module docstring) for one block of rows."""
    mode, f, o = meta["mode"], meta["free_thresh"], meta["occupied_thresh"]
    # Sum of R, G, B: a grey pixel is R = G = B, as ImageMagick reports it to Nav2.
    rgb_sum = colour.astype(np.float64) * 3.0 if colour.ndim == 2 else colour.astype(np.float64).sum(axis=-1)
    if mode == "trinary" and alpha is not None:
        shade = (rgb_sum + alpha) / 4.0 / maxval
    else:
        shade = rgb_sum / 3.0 / maxval
    if mode == "raw":
        return np.floor(shade * 255.0 + 0.5) == 0  # std::round of a non-negative value; 0 = FREE
    occ = shade if meta["negate"] else 1.0 - shade
    if mode == "trinary":
        return occ < f
    # scale: opaque, not above occupied_thresh, and either below free_thresh or rounding to 0 %.
    opaque = True if alpha is None else alpha == maxval
    between_zero = np.rint((occ - f) / (o - f) * 100.0) == 0
    return opaque & (occ <= o) & ((occ < f) | between_zero)
