"""The dense memory of hits: the observation's wall map (``observation.wall_map``, issues 15 and 16).

:class:`WallGrid` keeps every beam's hit of every scan of an episode as the cells of a coarse grid, the dense form of
the point memory of :mod:`flashnav.sim.memory`; its image (:func:`flashnav.sim.wall_image.wall_image` of the marked
cells' centres; on the CPU drawn by the numba kernel of :mod:`flashnav.sim.wall_numba`) is the observation's wall map.
With ``observation.wall_map_visited`` it also keeps the cells the robot's centre has passed, drawn as a third channel:
where the robot has been, beside what it has seen; with ``observation.wall_map_plan`` the plan over the cells not
marked (:mod:`flashnav.maps.seen_plan`), and with ``observation.wall_map_carrot`` the plan's carrot. Issue 15's
behaviour-cloning probe (``scripts/bc_memory_probe.py --wall-map-frames`` and ``--wall-map-grid``) reads both through
a CNN.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flashnav.sim.wall_image import cell_index, check_wall_image, goal_square, wall_image


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
    ``plan``) :meth:`plan_cells` also returns the slots' carrots (:func:`flashnav.maps.seen_plan.carrot_points`: the
    point that far along the plan, in the robot frame); hand its cells to :meth:`image` to draw the same plan.

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

        #: metres along the plan of the carrot that :meth:`plan_cells` returns (0 = none)
        self.carrot = check_carrot("WallGrid", carrot, plan)
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

    def plan_cells(self, idx, pose: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The plans of slots ``idx`` from the cell of ``pose [k, 3]`` to the cell of ``goal [k, 2]`` (both clipped
        onto the grid), :func:`flashnav.maps.seen_plan.plan_cells` within :data:`~flashnav.maps.seen_plan.PLAN_MARGIN_M`
        (at :attr:`plan_penalty`): their cells [k, H W + 1] bool (the layout of :attr:`known`, the spare column never
        set; on the grid's device) and, with :attr:`carrot`, their carrots [k, 2] (x, y m in the robot frame, the
        dtype and device of ``pose``; None without)."""
        from flashnav.maps.seen_plan import PLAN_MARGIN_M, carrot_points, plan_route

        rows = self.rows[idx]
        org = self.origin[rows].to(pose.dtype)

        def cell_of(xy: torch.Tensor) -> np.ndarray:
            rc = torch.stack(self._cell_rc(xy, org), -1)
            return torch.nan_to_num(rc, nan=0.0, posinf=1e9, neginf=-1e9).clamp(-1e9, 1e9).long().cpu().numpy()

        out, carrots = plan_route(self.known.cpu().numpy(), rows.cpu().numpy(), cell_of(pose[:, :2]), cell_of(goal),
                                  self.shape, math.ceil(PLAN_MARGIN_M / self.cell - 1e-9), self.plan_penalty,
                                  self.carrot / self.cell)
        points = None
        if self.carrot:
            xy = carrot_points(carrots, org.cpu().numpy(), self.cell, pose.detach().cpu().numpy(),
                               goal.detach().cpu().numpy(), self.carrot)
            points = torch.from_numpy(xy).to(device=pose.device, dtype=pose.dtype)
        return torch.from_numpy(out).to(self.known.device), points

    def image(self, idx, pose: torch.Tensor, goal: torch.Tensor, cells: int, cell: float,
              plan: torch.Tensor | None = None) -> torch.Tensor:
        """:func:`wall_image` [k, 2, cells, cells] of the marked cells' centres of slots ``idx``, seen from
        ``pose [k, 3]`` with goals ``goal [k, 2]`` (and, with ``visited``, the visited cells' centres as a third
        channel; with ``plan``, the plan's cells as the last: the ``plan`` given, the cells that :meth:`plan_cells`
        returned for the same slots and poses, else planned here): the same image as from every
        marked centre, drawn from the square window of cells around the robot that holds every centre within the
        image's half-diagonal."""
        check_wall_image(cells, cell)
        h, w = self.shape
        rows = self.rows[idx]
        reach = cells * cell / 2 * math.sqrt(2.0)
        n = math.ceil(2 * reach / self.cell) + 3
        org = self.origin[rows].to(pose.dtype)
        base = torch.floor((pose[:, :2] - reach - org) / self.cell).long() - 1  # [k, 2]: first column, first row
        if self.plan and plan is None:
            plan = self.plan_cells(idx, pose, goal)[0]
        if self.kernel == "numba":
            from flashnav.sim.wall_numba import wall_squares

            heading = pose[:, 2]
            args = (rows.numpy(), base.numpy(), org.numpy(), pose.numpy(), torch.cos(heading).numpy(),
                    torch.sin(heading).numpy(), n, self.shape, self.cell, cells, cell)
            channels = [torch.from_numpy(wall_squares(self.known.numpy(), *args)),
                        goal_square(goal, pose, cells, cell, pose.dtype)]
            if self.visited is not None:
                channels.append(torch.from_numpy(wall_squares(self.visited.numpy(), *args)))
            if self.plan:
                args = (np.arange(len(rows)),) + args[1:]
                channels.append(torch.from_numpy(wall_squares(plan.numpy(), *args)))
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
        plan = centres(plan) if self.plan else None
        return wall_image(centres(self.known[rows]), pose, goal, cells, cell, visited, plan)
