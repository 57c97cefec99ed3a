"""The occupancy map: the one geometry that LiDAR, collision and start/goal sampling all read.

Conventions (used everywhere in FlashNav):
- ``occupied[i, j]`` is cell row ``i`` (y increases with i) and column ``j`` (x increases with j).
  Row 0 is the *bottom* of the map (lowest y); ROS images store the top row first, and the ROS
  reader flips them.
- Cell ``(i, j)`` is the closed square ``[ox + j*res, ox + (j+1)*res] x [oy + i*res, oy + (i+1)*res]``.
- Everything outside the map rectangle counts as occupied; so do unknown cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flashnav.maps import fields

MAX_CELLS = 1 << 28  # 268 M cells (~256 MiB as bool): larger maps are refused with a clear error


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A boolean occupancy grid with its resolution and origin.

    Attributes:
        occupied: [H, W] bool, True = obstacle (or unknown). Row 0 is the lowest y.
        resolution: metres per cell (> 0).
        origin: world (x, y) of the lower-left corner of cell (0, 0), metres.
        name: a label (the bundled map's name, or the file stem).
        source: the file it was read from, if any.
    """

    occupied: np.ndarray
    resolution: float
    origin: tuple[float, float] = (0.0, 0.0)
    name: str = "map"
    source: Path | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        where = f"{self.source}: " if self.source else ""
        occ = np.asarray(self.occupied)
        if occ.ndim != 2 or occ.shape[0] < 1 or occ.shape[1] < 1:
            raise ValueError(f"{where}occupancy grid must be 2-D and non-empty, got shape {occ.shape}")
        if occ.size > MAX_CELLS:
            raise ValueError(f"{where}map of {occ.shape[1]} x {occ.shape[0]} cells exceeds the limit of {MAX_CELLS} cells")
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise ValueError(f"{where}resolution must be a positive number of metres per cell, got {self.resolution}")
        try:
            origin = tuple(float(v) for v in self.origin)
        except (TypeError, ValueError):
            origin = ()
        if len(origin) != 2 or not all(math.isfinite(v) for v in origin):  # a NaN origin gave NaN observations
            raise ValueError(f"{where}origin must be two finite numbers (x, y metres), got {self.origin!r}")
        object.__setattr__(self, "occupied", np.array(occ, dtype=bool, order="C"))  # own copy: frozen below
        object.__setattr__(self, "origin", origin)
        self.occupied.setflags(write=False)

    # ---- geometry ---------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self.occupied.shape

    @property
    def width_m(self) -> float:
        return self.occupied.shape[1] * self.resolution

    @property
    def height_m(self) -> float:
        return self.occupied.shape[0] * self.resolution

    @property
    def diagonal_m(self) -> float:
        """The map's diagonal, metres: no goal is farther than this. The environment's observation
        bound and the networks' goal-distance scale both read it."""
        return math.hypot(self.width_m, self.height_m)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) in metres."""
        ox, oy = self.origin
        return ox, oy, ox + self.width_m, oy + self.height_m

    def cell_centres(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ox, oy = self.origin
        return ox + (cols + 0.5) * self.resolution, oy + (rows + 0.5) * self.resolution

    def cell_of(self, xy, clip: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(rows, cols)``, int64 arrays of ``xy``'s leading shape: the cells holding the points ``xy``
        [..., 2] (x, y metres in this map's frame; a numpy array, or a tensor on any device). The floor
        runs in ``xy``'s own float type, as the simulator's float32 does. A point off the grid gets an
        index outside [0, H) x [0, W), or with ``clip`` the nearest cell on the grid's edge."""
        if hasattr(xy, "detach"):  # a torch tensor
            xy = xy.detach().cpu().numpy()
        xy = np.asarray(xy)
        cols = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        rows = np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        if clip:
            rows, cols = np.clip(rows, 0, self.shape[0] - 1), np.clip(cols, 0, self.shape[1] - 1)
        return rows, cols

    def padded(self, pad: int) -> np.ndarray:
        """[H + 2 pad, W + 2 pad] bool: the grid inside a border of ``pad`` occupied cells."""
        key = ("padded", pad)
        if key not in self._cache:
            out = np.ones((self.shape[0] + 2 * pad, self.shape[1] + 2 * pad), dtype=bool)
            out[pad : pad + self.shape[0], pad : pad + self.shape[1]] = self.occupied
            out.setflags(write=False)
            self._cache[key] = out
        return self._cache[key]

    def shifted(self, by: tuple[float, float]) -> "OccupancyMap":
        """The same map with its origin moved by ``-by`` metres (float64): world coordinates ``w``
        become ``w - by``. The copy shares this map's cache of derived fields (they depend only on
        the cells), so re-centring costs nothing. ``shifted(self.origin)`` is the map frame, origin
        (0, 0), where float32 coordinates keep their precision however far the map is from (0, 0)."""
        out = OccupancyMap(self.occupied, self.resolution, (self.origin[0] - by[0], self.origin[1] - by[1]),
                           self.name, self.source)
        object.__setattr__(out, "_cache", self._cache)
        return out

    # ---- derived once per map (computed and cached in flashnav.maps.fields) -----------------------
    @property
    def centre_distance(self) -> np.ndarray:
        """[H, W] float64 metres: see :func:`flashnav.maps.fields.centre_distance`."""
        return fields.centre_distance(self)

    @property
    def clearance(self) -> np.ndarray:
        """[H, W] float64 metres: see :func:`flashnav.maps.fields.clearance`."""
        return fields.clearance(self)

    def free_space(self, radius: float) -> np.ndarray:
        """[H, W] bool: cells whose centre is farther than ``radius`` metres from any obstacle."""
        return fields.free_space(self, radius)

    def components(self, radius: float) -> tuple[np.ndarray, int]:
        """Connected components (4-connected) of ``free_space(radius)``: (labels [H, W] int32, count).
        Label 0 is 'not free'. Two cells with the same label can be joined by a path along which a
        disc of ``radius`` never touches an obstacle."""
        return fields.components(self, radius)

    def check_free_space(self, radius: float, what: str = "the robot") -> None:
        """Raise a clear error if no cell can hold a disc of ``radius`` metres."""
        if not self.free_space(radius).any():
            where = f"{self.source}: " if self.source else f"map {self.name!r}: "
            raise ValueError(
                f"{where}no free space for {what}: no cell centre is more than {radius:.3f} m from an "
                f"obstacle (map {self.shape[1]} x {self.shape[0]} cells at {self.resolution} m)"
            )

    def __repr__(self) -> str:
        return (
            f"OccupancyMap(name={self.name!r}, cells={self.shape[1]}x{self.shape[0]}, "
            f"resolution={self.resolution}, origin={self.origin}, occupied={self.occupied.mean():.1%})"
        )
