"""A raw 2D laser scan -> the policy's pooled LiDAR sectors (numpy only).

The policy sees ``S`` sectors covering its field of view ``fov`` centred on the robot's heading:
sector ``s`` spans base-frame angles ``[-fov/2 + s * fov/S, -fov/2 + (s+1) * fov/S)`` counter-clockwise
(sector 0 on the robot's right), and reads the minimum range (metres, from the base origin) of the
beams in it, at most the policy's ``max_range``. A real sensor's scan is mapped onto that layout beam
by beam, whatever its beam count, angular direction or mounting:

* **angles**: beam ``k`` points at ``angle_min + k * angle_increment`` in the sensor frame (a negative
  increment is a clockwise sensor); the mounting yaw (and ``flipped`` for an upside-down sensor, whose
  angles run the other way) turns that into the base frame;
* **offset**: a sensor mounted at ``(x, y)`` from the base origin: each return's end point is moved
  into the base frame and its base-frame angle and distance are used; a no-return beam keeps its
  direction and reads ``max_range``;
* **readings** (REP 117): NaN, zero and other readings below ``range_min`` are invalid and dropped;
  ``+inf`` and readings above ``range_max`` mean nothing within range and read ``max_range``; ``-inf``
  means an object closer than ``range_min`` and reads ``range_min``;
* **field of view**: beams outside the policy's field of view are dropped (a wider sensor is cropped);
  a sector that no beam covers (a narrower sensor) or whose beams were all invalid reads ``fill``,
  by default ``max_range`` (free, what the simulator shows for open space), with a warning once per
  scan geometry for the sectors the sensor cannot see, and once per sector for those without a valid
  reading (:attr:`ScanAdapter.invalid_sectors`); a scan without one valid reading in the field of view,
  whose readings in it are all ``-inf`` (too close: a covered window), or whose beams miss the field of view
  altogether (a wrong mounting yaw) (:attr:`ScanAdapter.no_valid_reading`) stops the deploy node (``blind``);
* **limits**: ``range_min`` and ``range_max`` must be finite with ``0 <= range_min < range_max`` (a LaserScan
  left at its defaults, ``range_max = 0``, would read every wall as "nothing within range", open space).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np


def simulator_scan_fields(lidar) -> dict[str, float]:
    """The ``sensor_msgs/LaserScan`` fields (``angle_min``, ``angle_increment``, ``range_min``,
    ``range_max``) of the simulator's raw scan for a preset's ``lidar`` block: beams at bin centres from
    -fov/2 counter-clockwise (:func:`flashnav.sim.observation.beam_angles`), 0 to ``max_range`` metres;
    the angles rounded to float32 as the message carries them."""
    fov, n = math.radians(lidar.fov_deg), lidar.beams
    return {"angle_min": float(np.float32(-0.5 * fov + 0.5 * fov / n)), "angle_increment": float(np.float32(fov / n)),
            "range_min": 0.0, "range_max": float(lidar.max_range)}


@dataclass(frozen=True)
class Mount:
    """Where the LiDAR sits on the robot: ``x, y`` metres in the base frame (x forward, y left) and
    ``yaw`` radians (counter-clockwise); ``flipped`` for a sensor mounted upside down."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    flipped: bool = False

    def __post_init__(self):
        for name in ("x", "y", "yaw"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"mount.{name} must be finite, got {getattr(self, name)}")


@dataclass(frozen=True)
class SectorLayout:
    """The policy's LiDAR input: ``sectors`` over ``fov_deg`` degrees, readings clipped to ``max_range`` m."""

    sectors: int
    fov_deg: float
    max_range: float

    def __post_init__(self):
        if self.sectors < 1 or not 0 < self.fov_deg <= 360 or not self.max_range > 0:
            raise ValueError(f"invalid sector layout: sectors {self.sectors} (>= 1), fov_deg {self.fov_deg} "
                             f"(0, 360], max_range {self.max_range} (> 0)")


def sector_of(angle: np.ndarray, layout: SectorLayout) -> np.ndarray:
    """Sector index [B] int64 of base-frame angles [B] (radians, any wrap); -1 outside the field of view."""
    fov = math.radians(layout.fov_deg)
    wrapped = np.remainder(np.asarray(angle, np.float64) + math.pi, 2.0 * math.pi) - math.pi
    pos = np.nan_to_num((wrapped + 0.5 * fov) / (fov / layout.sectors), nan=-1.0)  # (a NaN angle: outside)
    idx = np.floor(pos).astype(np.int64)
    return np.where((idx >= 0) & (idx < layout.sectors), idx, -1)


class ScanAdapter:
    """``adapter(angle_min, angle_increment, ranges, range_min, range_max) -> sectors [S] float32``.

    See the module docstring for every convention. ``fill`` (metres, default the layout's
    ``max_range``) is what a sector without a valid beam reads.
    """

    def __init__(self, layout: SectorLayout, mount: Mount = Mount(), fill: float | None = None):
        self.layout, self.mount = layout, mount
        self.fill = layout.max_range if fill is None else float(fill)
        if not 0.0 <= self.fill <= layout.max_range:
            raise ValueError(f"fill must be in [0, max_range = {layout.max_range}] m, got {fill}")
        self._geometry_key = None
        self._blind: list[int] = []
        self._aimed = np.zeros(0, np.int64)
        self.invalid_sectors: list[int] = []  # the last scan's covered sectors without one valid reading
        self.too_close_only = False  # the last scan's readings in the field of view were all -inf
        self._warned_invalid: set[int] = set()

    def __call__(self, angle_min: float, angle_increment: float, ranges, range_min: float,
                 range_max: float) -> np.ndarray:
        raw = np.asarray(ranges, dtype=np.float64).reshape(-1)
        r, angle, valid, _ = self._base_frame(angle_min, angle_increment, raw, range_min, range_max)
        idx = sector_of(angle, self.layout)
        keep = valid & (idx >= 0)
        self.too_close_only = bool(keep.any() and (raw[keep] == -np.inf).all())
        out = np.full(self.layout.sectors, np.inf)
        np.minimum.at(out, idx[keep], r[keep])
        # by the beams' directions (an invalid reading has no end point): the sectors whose every beam was invalid
        has_valid = np.zeros(self.layout.sectors, bool)
        has_valid[self._aimed[valid & (self._aimed >= 0)]] = True
        covered = np.ones(self.layout.sectors, bool)
        covered[self._blind] = False
        self.invalid_sectors = np.flatnonzero(covered & ~has_valid).tolist()
        if set(self.invalid_sectors) - self._warned_invalid:
            self._warned_invalid |= set(self.invalid_sectors)
            warnings.warn(f"scan: sectors {self.invalid_sectors} of {self.layout.sectors} had no valid reading "
                          f"(NaN, 0 or below range_min: a fault, a dirty window or something on the sensor) and read "
                          f"the fill value {self.fill:g} m", RuntimeWarning, stacklevel=2)
        out = np.where(np.isinf(out), self.fill, np.minimum(out, self.layout.max_range))
        return out.astype(np.float32)

    @property
    def no_valid_reading(self) -> bool:
        """Whether the last scan had not one valid reading in the policy's field of view (a sensor that is
        dead or covered: its sectors would read the fill value, open space, and the deploy node stops): no
        covered sector with a valid reading (none covered at all counts too), or only ``-inf`` readings."""
        # (before any scan: no sector invalid, none uncovered, so False)
        return len(self.invalid_sectors) == self.layout.sectors - len(self._blind) or self.too_close_only

    def beams(self, angle_min: float, angle_increment: float, ranges, range_min: float,
              range_max: float) -> tuple[np.ndarray, np.ndarray]:
        """Every beam in the base frame: (direction [B] radians from the heading, range [B] metres from the
        base's origin: ``inf`` where the beam met nothing within the sensor's range, NaN where its reading is
        not valid), with the conventions of ``__call__``."""
        r, angle, valid, no_return = self._base_frame(angle_min, angle_increment, ranges, range_min, range_max)
        return angle, np.where(valid, np.where(no_return, np.inf, r), np.nan)

    def _base_frame(self, angle_min, angle_increment, ranges, range_min, range_max):
        """(range, direction, valid, no_return) [B] per beam in the base frame; no return reads max_range."""
        r = np.asarray(ranges, dtype=np.float64).reshape(-1)
        if r.size == 0:
            raise ValueError("scan has no ranges")
        if not (math.isfinite(angle_min) and math.isfinite(angle_increment) and angle_increment != 0.0):
            raise ValueError(f"scan angle_min {angle_min} / angle_increment {angle_increment} must be finite, "
                             "the increment non-zero")
        if not (math.isfinite(range_min) and math.isfinite(range_max) and 0.0 <= range_min < range_max):
            raise ValueError(f"scan range_min {range_min} / range_max {range_max} must be finite with "
                             "0 <= range_min < range_max (a LaserScan left at its defaults has range_max 0)")
        m, max_range = self.mount, self.layout.max_range
        sensor_angle = angle_min + angle_increment * np.arange(r.size, dtype=np.float64)
        direction = m.yaw + (-sensor_angle if m.flipped else sensor_angle)  # base frame
        self._check_coverage(direction, (float(angle_min), float(angle_increment), r.size))

        valid = ~np.isnan(r) & ~(np.isfinite(r) & ((r < range_min) | (r <= 0.0)))
        no_return = (r == np.inf) | ((r > range_max) & np.isfinite(r))
        r = np.where(r == -np.inf, float(range_min), r)  # too close: at most range_min away
        r = np.where(no_return, max_range, r)
        angle = direction
        if m.x != 0.0 or m.y != 0.0:  # the return's end point in the base frame
            px, py = m.x + r * np.cos(direction), m.y + r * np.sin(direction)
            angle = np.where(no_return, direction, np.arctan2(py, px))
            r = np.where(no_return, max_range, np.hypot(px, py))
        return r, angle, valid, no_return

    def _check_coverage(self, direction: np.ndarray, key) -> None:
        """Warn once per scan geometry about the sectors no beam falls in (the sensor's blind side)."""
        if key == self._geometry_key:
            return
        self._geometry_key = key
        self._aimed = idx = sector_of(direction, self.layout)  # each beam's sector by its direction
        self._blind = sorted(set(range(self.layout.sectors)) - set(idx[idx >= 0].tolist()))
        if self._blind:
            warnings.warn(f"the scan covers only {self.layout.sectors - len(self._blind)} of the policy's "
                          f"{self.layout.sectors} sectors ({self.layout.fov_deg:g} deg): sectors {self._blind} "
                          f"read the fill value {self.fill:g} m", RuntimeWarning, stacklevel=3)

    @property
    def blind_sectors(self) -> list[int]:
        """Sectors the last scan's geometry does not cover (they read ``fill``)."""
        return list(self._blind)
