"""The opt-in memory scan: the walls the robot has seen (``observation.memory_frames``, issues 15 and 16).

A policy that sees one scan and the straight-line direction to its goal forgets a wall the moment it
leaves the field of view or is hidden behind another: in a maze it walks back into the dead end it just
left, and Go2's last failures dither at a thin wall with the goal behind it (docs/benchmarks.md). The
pose trail (:mod:`flashnav.sim.trail`) remembers where the robot has been, not where the walls were.
With ``memory_frames = F > 0`` every observation ends with a second, 360-deg pooled scan of the wall
points the robot's LiDAR has hit in its last F stored frames::

    [M, M + S)    memory sector j: the distance, metres, from the robot to the nearest remembered wall
                  point whose bearing in the robot frame lies in [-pi + j w, -pi + (j + 1) w), w = 2 pi / S;
                  ``lidar.max_range`` where no remembered point lies (and no farther than it)

with M = ``preset.carrot_end`` (after every column but the wall map's) and S = ``lidar.sectors``. The columns are
LiDAR-like: the networks give them IPAPRec's ``1 / (l - beta)`` with the scan's beta. Sector 0 starts
straight behind (-pi) and sectors go counter-clockwise, so a mirror image reverses their order.

What is stored: a frame every ``memory_every`` control steps (the step that brings the episode's step
count to a multiple of it; a new episode stores its first scan as frame 0 and forgets the rest). A
frame is the scan's hits cut into ``points_per_frame(preset)`` groups of consecutive beams; each group
keeps its nearest hit (range below ``max_range``) as one point in the simulator frame, at that beam's
exact bearing. The memory scan is the minimum over every stored point, with no occlusion: the nearest
remembered point in a direction hides the ones behind it anyway. The points are kept in the simulator
frame and turned into the robot frame when observed; a robot keeps them in its odometry frame
(:class:`flashnav.deploy.controller.Controller`). With moving agents the memory also holds where they
were: it is a memory of hits, as a robot's own would be.

The same points can also be drawn as an egocentric image (:func:`wall_image`, :meth:`WallMemory.image`): squares
around the robot, 1 where a stored point lies, and the goal's square. :class:`WallGrid` is the dense form of the same
memory: every beam's hit of every scan, kept as the cells of a coarse grid; its image is the observation's wall map
(``observation.wall_map``; on the CPU drawn by the numba kernel of :mod:`flashnav.sim.wall_numba`). With
``observation.wall_map_visited`` it also keeps the cells the robot's centre has passed, drawn as a third channel:
where the robot has been, beside what it has seen. Issue 15's behaviour-cloning probe (``scripts/bc_memory_probe.py
--wall-map-frames`` and ``--wall-map-grid``) reads both through a CNN.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flashnav.sim.trail import to_robot_frame

#: Stored points per pooled sector of the live scan: a frame keeps ``sectors * POINTS_PER_SECTOR`` points
#: (60 for both robots' 30 sectors; the groups' width is the nearest divisor of the sector's beams).
POINTS_PER_SECTOR = 2


def points_per_frame(preset) -> int:
    """Points one stored frame keeps: ``lidar.beams`` cut into equal groups of consecutive beams, the
    widest group at most ``beams_per_sector / POINTS_PER_SECTOR`` beams that divides a sector's beams."""
    bps = preset.lidar.beams_per_sector
    cap = max(1, bps // POINTS_PER_SECTOR)
    group = max(d for d in range(1, cap + 1) if bps % d == 0)
    return preset.lidar.beams // group


def check_wall_image(cells: int, cell: float) -> None:
    """Raise ValueError unless a :func:`wall_image` of ``cells`` x ``cells`` squares of ``cell`` metres can be drawn."""
    if cells < 2 or not (math.isfinite(cell) and cell > 0):
        raise ValueError(f"a wall image needs at least 2 cells a side of > 0 metres, got {cells} x {cell}")


def cell_index(r: torch.Tensor, c: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Flat index ``r * w + c`` (long) of rows ``r`` and columns ``c`` (whole numbers, float or integer) on an
    ``h`` x ``w`` grid, -1 off it (NaN and inf are off it: they compare False); the same ops whatever the values."""
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    return torch.where(inside, torch.where(inside, r, 0).long() * w + torch.where(inside, c, 0).long(), -1)


def wall_image(points: torch.Tensor, pose: torch.Tensor, goal: torch.Tensor, cells: int, cell: float,
               visited: torch.Tensor | None = None, plan: torch.Tensor | None = None) -> torch.Tensor:
    """An egocentric image [k, 2, cells, cells] of wall ``points [k, Q, 2]`` (simulator frame, metres; a point
    with a non-finite coordinate is none) seen from ``pose [k, 3]``, with the goal ``goal [k, 2]``: squares of
    ``cell`` metres centred on the robot and turned with its heading, row = left (row 0 rightmost), column =
    forward (column 0 behind); channel 0 is 1 where a point falls in the square, channel 1 is 1 in the goal's
    square (clipped onto the image's edge when farther). Unknown reads as free. With ``visited [k, V, 2]`` (points
    the robot has been at, drawn as the walls are) a third channel [k, 3, cells, cells]; with ``plan [k, L, 2]`` (the
    cells of the plan, :mod:`flashnav.maps.seen_plan`, drawn likewise) one more, last. Computed in the inputs'
    dtype, on their device, with no host sync (the same ops whatever the points).

    The input of issue 15's behaviour-cloning probe (``scripts/bc_memory_probe.py --wall-map``): drawn from a
    slot's stored points (:meth:`WallMemory.image`) or from any other set of wall points."""
    check_wall_image(cells, cell)
    channels = [_point_squares(points, pose, cells, cell), _goal_square(goal, pose, cells, cell, points.dtype)]
    if visited is not None:
        channels.append(_point_squares(visited.to(points.dtype), pose, cells, cell))
    if plan is not None:
        channels.append(_point_squares(plan.to(points.dtype), pose, cells, cell))
    return torch.stack(channels, dim=1)


def _point_squares(points: torch.Tensor, pose: torch.Tensor, cells: int, cell: float) -> torch.Tensor:
    """[k, cells, cells]: 1 in each of :func:`wall_image`'s squares that holds one of ``points [k, Q, 2]``."""
    k = points.shape[0]
    square = cell_index(*_squares(points, pose, cells, cell), cells, cells)
    inside = torch.isfinite(points).all(-1) & (square >= 0)
    at = torch.arange(k, device=pose.device)[:, None] * (cells * cells) + square
    at = torch.where(inside, at, k * cells * cells)  # outside: one spare square, dropped
    marks = torch.zeros(k * cells * cells + 1, device=pose.device, dtype=points.dtype)
    return marks.index_fill_(0, at.reshape(-1), 1.0)[:-1].view(k, cells, cells)


def _squares(xy: torch.Tensor, pose: torch.Tensor, cells: int, cell: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(row, column) of :func:`wall_image`'s squares, unclipped, as floats, of ``xy [k, Q, 2]`` seen from ``pose``."""
    fwd, left = to_robot_frame(xy, pose).unbind(-1)
    half = cells * cell / 2
    return torch.floor((left + half) / cell), torch.floor((fwd + half) / cell)


def _goal_square(goal: torch.Tensor, pose: torch.Tensor, cells: int, cell: float, dtype) -> torch.Tensor:
    """:func:`wall_image`'s goal channel [k, cells, cells]: 1 in the goal's square, clipped onto the edge."""
    k = goal.shape[0]
    r, c = (v[:, 0].clamp(0, cells - 1).long() for v in _squares(goal[:, None], pose, cells, cell))
    target = torch.zeros(k, cells, cells, device=pose.device, dtype=dtype)
    target[torch.arange(k, device=pose.device), r, c] = 1.0
    return target


class WallMemory:
    """The last ``frames`` stored frames of wall points [N, frames, 2, P] (x and y rows, simulator frame,
    metres; ``inf`` where a group of beams hit nothing) of each of N slots, and the memory scan of ``sectors``
    they give. x and y are separate rows so that every elementwise op reads runs of contiguous memory (atan2
    on interleaved pairs is ten times slower on a CPU).

    The frames are a ring: the frame stored after episode step t (a multiple of ``every``) goes to row
    ``(t // every) % frames``, overwriting the oldest; the order does not matter to a minimum, and one
    write per stored frame costs less than shifting every frame at every step."""

    def __init__(self, num_envs: int, frames: int, every: int, sectors: int, max_range: float,
                 beam_angles: torch.Tensor, points: int, device: torch.device):
        beams = beam_angles.numel()
        if num_envs < 1 or frames < 1 or every < 1 or sectors < 1 or points < 1 or beams % points:
            raise ValueError(f"WallMemory needs num_envs, frames, every, sectors, points >= 1 and points dividing "
                             f"the {beams} beams, got {num_envs}, {frames}, {every}, {sectors}, {points}")
        self.every, self.sectors, self.max_range = every, sectors, float(max_range)
        self.group_angles = beam_angles.to(device=device, dtype=torch.float32).view(points, beams // points)
        self.points = torch.full((num_envs, frames, 2, points), math.inf, device=device, dtype=torch.float32)
        self.rows = torch.arange(num_envs, device=device)

    @classmethod
    def from_preset(cls, preset, num_envs: int, beam_angles: torch.Tensor, device: torch.device) -> "WallMemory":
        o = preset.observation
        return cls(num_envs, o.memory_frames, o.memory_every, preset.lidar.sectors, preset.lidar.max_range,
                   beam_angles, points_per_frame(preset), device)

    @property
    def columns(self) -> int:
        """Observation columns the memory adds: the sectors."""
        return self.sectors

    @property
    def valid(self) -> torch.Tensor:
        """[N, frames, P] bool: the stored points that are hits."""
        return torch.isfinite(self.points[:, :, 0])

    def image(self, idx, pose: torch.Tensor, goal: torch.Tensor, cells: int, cell: float) -> torch.Tensor:
        """:func:`wall_image` [k, 2, cells, cells] of slots ``idx``'s stored points, seen from ``pose [k, 3]``
        with goals ``goal [k, 2]``."""
        pts = self.points[idx]  # [k, F, 2, P]
        return wall_image(pts.transpose(2, 3).reshape(pts.shape[0], -1, 2), pose, goal, cells, cell)

    def frame(self, pose: torch.Tensor, ranges: torch.Tensor) -> torch.Tensor:
        """One frame of ``k`` scans: points [k, 2, P] (x and y planes) in the frame of ``pose [k, 3]``, the
        nearest hit of each group of beams at its beam's bearing, ``inf`` where the group's nearest range is
        max range."""
        k, (p, g) = ranges.shape[0], self.group_angles.shape
        near, arg = ranges.reshape(k, p, g).min(dim=2)
        bearing = torch.gather(self.group_angles.expand(k, -1, -1), 2, arg[..., None])[..., 0] + pose[:, 2:3]
        near = torch.where(near < self.max_range, near, torch.full_like(near, math.inf))
        return pose[:, :2, None] + near[:, None] * torch.stack([torch.cos(bearing), torch.sin(bearing)], dim=1)

    def scan(self, points: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """The memory scan [k, S] of stored ``points [k, F, 2, P]`` (``inf`` = none) seen from ``pose [k, 3]``:
        the bearing is taken in the simulator frame and turned by the heading, the distance needs no turn."""
        k = pose.shape[0]
        dx = points[:, :, 0].reshape(k, -1) - pose[:, 0:1]
        dy = points[:, :, 1].reshape(k, -1) - pose[:, 1:2]
        dist = torch.hypot(dx, dy).clamp(max=self.max_range)  # inf (no hit) -> max range
        turn = torch.atan2(dy, dx) - pose[:, 2:3] + math.pi
        width = 2.0 * math.pi / self.sectors
        sector = (torch.remainder(turn, 2.0 * math.pi) / width).long().clamp(0, self.sectors - 1)
        out = torch.full((k, self.sectors), self.max_range, device=pose.device, dtype=torch.float32)
        return out.scatter_reduce(1, sector, dist, reduce="amin")

    def start(self, idx, pose: torch.Tensor, ranges: torch.Tensor) -> torch.Tensor:
        """New episodes in slots ``idx`` at ``pose [k, 3]`` with first scans ``ranges [k, beams]``: row 0
        holds that scan's points, every other row is forgotten. Returns the memory scan [k, S]."""
        points = torch.full((pose.shape[0], *self.points.shape[1:]), math.inf, device=pose.device,
                            dtype=torch.float32)
        points[:, 0] = self.frame(pose, ranges)
        self.points[idx] = points
        return self.scan(points, pose)

    def push(self, idx, pose: torch.Tensor, ranges: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        """One step of slots ``idx`` now at ``pose [k, 3]`` with scans ``ranges [k, beams]`` after
        ``steps [k]`` steps of their episodes: where ``steps`` is a multiple of ``every`` this scan replaces
        the oldest stored one. Returns the memory scan [k, S] from ``pose``."""
        rows = self.rows[idx]
        ring = (steps // self.every) % self.points.shape[1]
        store = (steps % self.every == 0)[:, None, None]  # no host sync: the same ops every step
        old = self.points[rows, ring]  # [k, 2, P]
        self.points[rows, ring] = torch.where(store, self.frame(pose, ranges), old)
        return self.scan(self.points[idx], pose)


def grid_shape(maps, cell: float) -> tuple[int, int]:
    """(H, W): the cells of ``cell`` metres that span the largest extent of ``maps`` (OccupancyMaps: shape times
    resolution), row by row and column by column."""
    return (max(math.ceil(g.shape[0] * g.resolution / cell - 1e-9) for g in maps),
            max(math.ceil(g.shape[1] * g.resolution / cell - 1e-9) for g in maps))


#: Metres past a hit where the env's wall map marks it (:class:`WallGrid`'s ``beyond``): a wall face that lies on a
#: grid cell's edge then puts its hits in the wall's cell from whichever side the robot sees it, so the map of a
#: mirrored world is the mirror of the map (tests/test_mirror.py); far below any cell.
HIT_BEYOND_M = 1e-3


class WallGrid:
    """The dense memory of hits: per slot, the cells of a coarse grid (``shape`` (H, W) cells of ``cell``
    metres, simulator frame) in which a beam of any scan of the slot's episode has ended (a range below
    ``max_range``), every beam counted, nothing forgotten until the slot's next episode; one bool (a byte) a cell
    and slot. Each slot's grid has its own ``origin`` (the corner of cell (0, 0), metres: the slot's map's, in a
    many-map batch), set when its episode starts; a hit off the grid is dropped. ``beyond``: metres past the hit
    along its beam where it is marked (0: the hit itself; half a map cell puts a hit on a wall cell's edge into
    the wall's cell, as :class:`flashnav.mapless.SeenWalls` marks it). With ``visited`` a second grid of the same
    cells keeps where the slot's robot has been: the cell of its centre at the start and after every step (at
    0.25 m cells and 0.05 m a step at most, the cells of its path, with no gap). With ``plan`` its image has one more
    channel, last: the cells of the slot's plan from the robot's cell to its goal's over the cells not marked
    (:mod:`flashnav.maps.seen_plan`, computed when the image is drawn, on the CPU: a host sync on a GPU), the
    cheapest way with ``plan_penalty`` > 0 (a cell beside a marked one dearer). With ``carrot`` > 0 (metres, needs
    ``plan``) every :meth:`image` also leaves the drawn slots' carrots in :attr:`carrots`
    (:func:`flashnav.maps.seen_plan.carrot_points`: the point that far along the plan, in the robot frame).

    :meth:`image` draws the marked cells' centres as :func:`wall_image` draws points, reading only the window of
    cells whose centres can fall in the image, so its cost is the image's, not the map's."""

    def __init__(self, num_envs: int, shape: tuple[int, int], cell: float, max_range: float,
                 beam_angles: torch.Tensor, device: torch.device, beyond: float = 0.0, visited: bool = False,
                 plan: bool = False, plan_penalty: float = 0.0, carrot: float = 0.0):
        h, w = (int(v) for v in shape)
        if num_envs < 1 or h < 1 or w < 1 or not (math.isfinite(cell) and cell > 0):
            raise ValueError(f"WallGrid needs num_envs >= 1, a shape of >= 1 x 1 cells and cells of > 0 metres, "
                             f"got {num_envs}, {h} x {w}, {cell}")
        if not (math.isfinite(beyond) and beyond >= 0):
            raise ValueError(f"WallGrid: beyond must be >= 0 metres, got {beyond}")
        self.shape, self.cell, self.max_range, self.beyond = (h, w), float(cell), float(max_range), float(beyond)
        self.angles = beam_angles.to(device=device, dtype=torch.float32)
        # one spare cell a slot (the last column): every dropped hit goes there, so that marking is the same
        # ops whatever the hits (no host sync); it is never read
        self.known = torch.zeros(num_envs, h * w + 1, device=device, dtype=torch.bool)
        #: the cells the robot has been in (same layout and spare cell), None without ``visited``
        self.visited = torch.zeros_like(self.known) if visited else None
        #: whether :meth:`image` draws the plan channel (:meth:`plan_cells`)
        self.plan = bool(plan)
        #: what a move into a cell beside a marked one costs the plan on top of its length, times it
        self.plan_penalty = float(plan_penalty)
        from flashnav.maps.seen_plan import check_carrot

        #: metres along the plan of the carrot (0 = none) and the carrots [k, 2] of the last :meth:`image`'s slots
        self.carrot, self.carrots = check_carrot("WallGrid", carrot, plan), None
        self.origin = torch.zeros(num_envs, 2, device=device, dtype=torch.float32)
        self.rows = torch.arange(num_envs, device=device)
        #: how :meth:`image` draws: "numba" (the CPU default: :mod:`flashnav.sim.wall_numba`, the marked cells only)
        #: or "torch" (every cell of the window; the only path on a GPU); the same squares either way
        self.kernel = "numba" if self.known.device.type == "cpu" else "torch"

    @classmethod
    def covering(cls, geometry, num_envs: int, cell: float, max_range: float, beam_angles: torch.Tensor,
                 device: torch.device, beyond: float = 0.0, visited: bool = False,
                 plan: bool = False) -> "WallGrid":
        """A grid of ``cell`` metres over ``geometry``'s extent (an OccupancyMap: its shape times its
        resolution), every slot's origin at the map's."""
        grid = cls(num_envs, grid_shape([geometry], cell), cell, max_range, beam_angles, device, beyond, visited,
                   plan)
        grid.origin[:] = torch.tensor(geometry.origin, dtype=torch.float32)
        return grid

    def _cell_rc(self, xy: torch.Tensor, origin: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Row and column [...] of the cells of points ``xy [..., 2]`` on grids of origins ``origin [..., 2]``
        (broadcast against ``xy``), as floats, unclipped (``nan`` / ``inf`` kept)."""
        c = torch.floor((xy[..., 0] - origin[..., 0]) / self.cell)
        return torch.floor((xy[..., 1] - origin[..., 1]) / self.cell), c

    def _flat(self, xy: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
        """Flat cell index [k, Q] of points ``xy [k, Q, 2]`` on grids of origins ``origin [k, 2]``; a point off
        the grid or not finite gets the spare cell."""
        h, w = self.shape
        flat = cell_index(*self._cell_rc(xy, origin[:, None]), h, w)
        return torch.where(flat >= 0, flat, h * w)

    def hits(self, pose: torch.Tensor, ranges: torch.Tensor) -> torch.Tensor:
        """[k, beams, 2] where the hits of scans ``ranges [k, beams]`` from ``pose [k, 3]`` are marked (``beyond``
        past them; ``inf`` where a beam met nothing within ``max_range``)."""
        bearing = self.angles[None] + pose[:, 2:3]
        r = torch.where(ranges < self.max_range, ranges + self.beyond, torch.full_like(ranges, math.inf))
        return pose[:, None, :2] + r[..., None] * torch.stack([torch.cos(bearing), torch.sin(bearing)], dim=-1)

    def push(self, idx, pose: torch.Tensor, ranges: torch.Tensor) -> None:
        """Marks the cells where the beams of slots ``idx`` (at ``pose [k, 3]``, scans ``ranges [k, beams]``) end
        (and, with ``visited``, the cell of each robot's centre)."""
        rows = self.rows[idx]
        origin = self.origin[rows]
        at = rows[:, None] * self.known.shape[1] + self._flat(self.hits(pose, ranges), origin)
        self.known.view(-1).index_fill_(0, at.reshape(-1), True)
        if self.visited is not None:
            at = rows * self.visited.shape[1] + self._flat(pose[:, None, :2], origin)[:, 0]
            self.visited.view(-1).index_fill_(0, at, True)

    def start(self, idx, pose: torch.Tensor, ranges: torch.Tensor, origin: torch.Tensor | None = None) -> None:
        """New episodes in slots ``idx``: their grids are cleared (and moved to ``origin [k, 2]`` when given), then
        their first scans marked."""
        rows = self.rows[idx]
        self.known[rows] = False
        if self.visited is not None:
            self.visited[rows] = False
        if origin is not None:
            self.origin[rows] = origin.to(self.origin)
        self.push(rows, pose, ranges)

    def centres(self, idx, visited: bool = False) -> torch.Tensor:
        """[k, H W, 2] every cell's centre of slots ``idx``, ``inf`` where the cell is not marked (a reference
        and a small-map form of :meth:`image`'s window); with ``visited``, the cells the robot has been in."""
        h, w = self.shape
        rows = self.rows[idx]
        marks = self.visited if visited else self.known
        if marks is None:
            raise ValueError("WallGrid.centres(visited=True): this grid keeps no visited cells (visited=False)")
        r, c = torch.meshgrid(torch.arange(h, device=rows.device), torch.arange(w, device=rows.device), indexing="ij")
        xy = (torch.stack([c, r], -1).reshape(-1, 2).to(self.origin) + 0.5) * self.cell + self.origin[rows][:, None]
        return torch.where(marks[rows, :-1, None], xy, math.inf)

    def plan_cells(self, idx, pose: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """[k, H W + 1] bool (the layout of :attr:`known`, the spare column never set; on the grid's device): the cells
        of the plan of slots ``idx`` from the cell of ``pose [k, 3]`` to the cell of ``goal [k, 2]`` (both clipped onto
        the grid), :func:`flashnav.maps.seen_plan.plan_cells` within :data:`~flashnav.maps.seen_plan.PLAN_MARGIN_M`
        (at :attr:`plan_penalty`); with :attr:`carrot`, :attr:`carrots` set to the slots' carrots."""
        from flashnav.maps.seen_plan import PLAN_MARGIN_M, carrot_points, plan_route

        rows = self.rows[idx]
        org = self.origin[rows].to(pose.dtype)

        def cell_of(xy: torch.Tensor) -> np.ndarray:
            rc = torch.stack(self._cell_rc(xy, org), -1)
            return torch.nan_to_num(rc, nan=0.0, posinf=1e9, neginf=-1e9).clamp(-1e9, 1e9).long().cpu().numpy()

        out, carrots = plan_route(self.known.cpu().numpy(), rows.cpu().numpy(), cell_of(pose[:, :2]), cell_of(goal),
                                  self.shape, math.ceil(PLAN_MARGIN_M / self.cell - 1e-9), self.plan_penalty,
                                  self.carrot / self.cell)
        if self.carrot:
            xy = carrot_points(carrots, org.cpu().numpy(), self.cell, pose.detach().cpu().numpy(),
                               goal.detach().cpu().numpy(), self.carrot)
            self.carrots = torch.from_numpy(xy).to(device=pose.device, dtype=pose.dtype)
        return torch.from_numpy(out).to(self.known.device)

    def image(self, idx, pose: torch.Tensor, goal: torch.Tensor, cells: int, cell: float) -> torch.Tensor:
        """:func:`wall_image` [k, 2, cells, cells] of the marked cells' centres of slots ``idx``, seen from
        ``pose [k, 3]`` with goals ``goal [k, 2]`` (and, with ``visited``, the visited cells' centres as a third
        channel; with ``plan``, the plan's cells (:meth:`plan_cells`) as the last): the same image as from every
        marked centre, drawn from the square window of cells around the robot that holds every centre within the
        image's half-diagonal."""
        check_wall_image(cells, cell)
        h, w = self.shape
        rows = self.rows[idx]
        reach = cells * cell / 2 * math.sqrt(2.0)
        n = math.ceil(2 * reach / self.cell) + 3
        org = self.origin[rows].to(pose.dtype)
        base = torch.floor((pose[:, :2] - reach - org) / self.cell).long() - 1  # [k, 2]: first column, first row
        if self.kernel == "numba":
            from flashnav.sim.wall_numba import wall_squares

            heading = pose[:, 2]
            args = (rows.numpy(), base.numpy(), org.numpy(), pose.numpy(), torch.cos(heading).numpy(),
                    torch.sin(heading).numpy(), n, self.shape, self.cell, cells, cell)
            channels = [torch.from_numpy(wall_squares(self.known.numpy(), *args)),
                        _goal_square(goal, pose, cells, cell, pose.dtype)]
            if self.visited is not None:
                channels.append(torch.from_numpy(wall_squares(self.visited.numpy(), *args)))
            if self.plan:
                plan = self.plan_cells(idx, pose, goal).numpy()
                args = (np.arange(len(rows)),) + args[1:]
                channels.append(torch.from_numpy(wall_squares(plan, *args)))
            return torch.stack(channels, dim=1)
        step = torch.arange(n, device=pose.device)
        c = (base[:, 0:1] + step)[:, None, :].expand(-1, n, -1)  # [k, n, n]: column varies along the last axis
        r = (base[:, 1:2] + step)[:, :, None].expand(-1, -1, n)
        flat = cell_index(r, c, h, w).reshape(len(rows), -1)
        inside = flat >= 0
        # off the grid: the spare cell, read as unmarked (it holds the dropped hits)
        at = torch.where(inside, flat, h * w)
        xy = (torch.stack([c, r], -1).reshape(len(rows), -1, 2).to(pose.dtype) + 0.5) * self.cell + org[:, None]

        def centres(marks: torch.Tensor) -> torch.Tensor:  # marks: [k, H W + 1], the slots' rows
            return torch.where((torch.gather(marks, 1, at) & inside)[..., None], xy, math.inf)

        visited = centres(self.visited[rows]) if self.visited is not None else None
        plan = centres(self.plan_cells(idx, pose, goal)) if self.plan else None
        return wall_image(centres(self.known[rows]), pose, goal, cells, cell, visited, plan)
