"""Torch raycasters (any device): "exact-torch", the exact semantics of :mod:`flashnav.sim.raycast`
as batched tensor ops, and "march", the paper's fixed-step ray march.

exact-torch works on an active set of rays (compacted every round). After checking the origin (an
origin touching an occupied closed cell gives 0), each round:
1. jumps ``jumps_per_round`` times by the directional safe distance of the cell containing p(t) in
   the ray's sector, minus DELTA, where it is at least ``JUMP_MIN_CELLS`` (the field of
   :func:`flashnav.maps.fields.cone_field`); landing points are clear of every obstacle;
2. checks the point p(t): any occupied closed cell containing it ends the ray at t;
3. enumerates the next ``chunk_lines`` vertical and horizontal grid-line crossings as [R, M] tensors
   (no sorting needed): at a crossing of line X the ray enters column X (or X - 1 going left), in the
   row(s) containing the crossing point - two rows at a vertex; the first crossing into an occupied
   cell up to T = min(last x-crossing, last y-crossing) ends the ray. Every cell the segment
   [t, T] touches is touched first at p(t) or at one of these crossings, so this is exact; else t = T.
Crossing indices beyond the padded grid are clamped onto its (occupied) border: such crossings lie
past the map boundary, whose own crossing is enumerated first, so they never decide a range.
"""

from __future__ import annotations

import math

import torch

from flashnav.maps.fields import cone_field
from flashnav.sim.mapset import map_table, pack
from flashnav.sim.raycast_base import AXIS_SNAP, DELTA, EPS, PAD, Raycaster

#: A round costs a few dozen tensor ops whatever it does, so jump wherever the field allows a cell
#: (the numba kernel's threshold, raycast_base.JUMP_MIN_CELLS, suits its per-ray loop instead).
JUMP_MIN_CELLS = 1.0


class TorchExactRaycaster(Raycaster):
    """Exact ranges with torch ops on ``device``; float64 internally.

    A round costs a few dozen kernel launches whatever it does, and on a GPU the launches are the
    cost (an H100 profile of 4,096 TurtleBot2 environments: ~13,000 launches per step), so fewer,
    longer rounds pay there: 8 lines and 4 jumps per round cast 1.4x (1,024 envs) and 2.2x (4,096)
    faster than 4 and 2 on an H100, the same ranges (docs/benchmarks.md); on a CPU the work is the
    cost and 4 and 2 stay.

    Args:
        chunk_lines: grid lines per axis enumerated per round (memory ~ rays x chunk_lines); ``None``:
            8 on CUDA, 4 elsewhere.
        jumps_per_round: free-space jumps before each round's crossings; ``None``: 4 on CUDA, 2 elsewhere.
        max_batch_rays: rays processed together (bounds peak memory); ``None``: :func:`default_batch_rays`.
    """

    name = "exact-torch"

    def __init__(self, grid, beam_angles, max_range, device="cpu", chunk_lines: int | None = None,
                 jumps_per_round: int | None = None, max_batch_rays: int | None = None, name: str | None = None) -> None:
        super().__init__(grid, beam_angles, max_range, device)
        if name is not None:
            self.name = name
        gpu = self.device.type == "cuda"
        self.chunk_lines = (8 if gpu else 4) if chunk_lines is None else int(chunk_lines)
        self.jumps_per_round = (4 if gpu else 2) if jumps_per_round is None else int(jumps_per_round)
        self.max_batch_rays = default_batch_rays(self.device) if max_batch_rays is None else int(max_batch_rays)
        cones = [cone_field(g, PAD) for g in self.grids]
        cone, cone_base = pack(cones)
        occ, occ_base = pack([g.padded(PAD) for g in self.grids])
        self._cone = torch.from_numpy(cone.copy()).to(self.device)
        self._flat = torch.from_numpy(occ.copy()).to(self.device)  # occupied
        # one map: Python numbers (the single-map ops, unchanged); several: [M] tensors gathered per ray
        self._sectors, self._hp, self._wp = cones[0].shape
        self._maps = None if len(self.grids) == 1 else _per_map(self.grids, self.device, sectors=[c.shape[0] for c in cones],
                                                                cone_base=cone_base, occ_base=occ_base)
        self._jump_byte = 1 + math.ceil(2 * JUMP_MIN_CELLS)
        a = self.beam_angles.double()
        self._cos_a, self._sin_a = torch.cos(a), torch.sin(a)
        self._steps = torch.arange(self.chunk_lines, device=self.device, dtype=torch.float64)

    def __call__(self, pose: torch.Tensor, map_index=None) -> torch.Tensor:
        mi = self._check(pose, map_index)
        g = self.grid
        p = pose.to(self.device, torch.float64)
        n, k = p.shape[0], self._cos_a.shape[0]
        if mi is None:
            inv = 1.0 / g.resolution
            ox, oy, res, per_rad = g.origin[0], g.origin[1], g.resolution, self._sectors / (2 * math.pi)
            sectors, plane_cells, geo = self._sectors, self._hp * self._wp, self._geo
        else:  # per-env [n, 1] values of each env's map; the ray geometry [n * k] per ray
            m = {key: value[mi.to(self.device)][:, None] for key, value in self._maps.items()}
            inv, ox, oy, res = 1.0 / m["res"], m["ox"], m["oy"], m["res"]
            sectors, per_rad = m["sectors"], m["sectors"].double() / (2 * math.pi)
            plane_cells = m["hp"] * m["wp"]
            geo = _Geo(**{key: m[key].expand(n, k).reshape(-1) for key in _Geo.KEYS}, maxc=(self.max_range * inv).expand(n, k).reshape(-1))
        cy, sy = torch.cos(p[:, 2:3]), torch.sin(p[:, 2:3])
        dx = (cy * self._cos_a - sy * self._sin_a).reshape(-1)
        dy = (sy * self._cos_a + cy * self._sin_a).reshape(-1)
        dx = torch.where(dx.abs() < AXIS_SNAP, torch.zeros_like(dx), dx)
        dy = torch.where(dy.abs() < AXIS_SNAP, torch.zeros_like(dy), dy)
        u = ((p[:, 0:1] - ox) * inv).expand(n, k).reshape(-1)
        v = ((p[:, 1:2] - oy) * inv).expand(n, k).reshape(-1)
        # the sector plane of each ray's direction, as a flat offset into the field
        sector = torch.floor((p[:, 2:3] + self.beam_angles.double()) * per_rad)
        plane = (sector.long().remainder(sectors) * plane_cells)
        if mi is not None:
            plane = plane + m["cone_base"]
        plane = plane.reshape(-1)
        out = torch.empty(n * k, dtype=torch.float64, device=self.device)
        for s in range(0, n * k, self.max_batch_rays):
            e = min(s + self.max_batch_rays, n * k)
            out[s:e] = self._cast(u[s:e], v[s:e], dx[s:e], dy[s:e], plane[s:e], geo.take(slice(s, e)))
        scale = res if mi is None else res.expand(n, k).reshape(-1)
        return (out * scale).clamp_(max=self.max_range).to(torch.float32).reshape(n, k)

    @property
    def _geo(self) -> "_Geo":
        """The single map's ray geometry (Python numbers)."""
        h, w = self.grid.shape
        return _Geo(h=h, w=w, hp=self._hp, wp=self._wp, occ_base=0, maxc=self.max_range * (1.0 / self.grid.resolution))

    # ---- helpers on flat ray batches ---------------------------------------------------------------
    def _occupied(self, rows: torch.Tensor, cols: torch.Tensor, geo: "_Geo") -> torch.Tensor:
        """Occupancy of unpadded cell indices ([R] or [R, M]), clamped onto the occupied pad border
        of each ray's map."""
        hp, wp = geo.bcast("hp", rows), geo.bcast("wp", rows)
        index = _clamp(rows + PAD, hp - 1) * wp + _clamp(cols + PAD, wp - 1)
        return self._flat[index if geo.single else index + geo.bcast("occ_base", rows)]

    @staticmethod
    def _span(c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Cell indices (lo, hi) of the closed cells containing coordinate c: two on a grid line."""
        f = torch.floor(c)
        lo = f.long()
        hi = lo.clone()
        lo -= (c - f < EPS).long()
        hi += (f + 1.0 - c < EPS).long()
        return lo, hi

    def _touches(self, pu: torch.Tensor, pv: torch.Tensor, geo: "_Geo") -> torch.Tensor:
        j0, j1 = self._span(pu)
        i0, i1 = self._span(pv)
        return (self._occupied(i0, j0, geo) | self._occupied(i0, j1, geo) | self._occupied(i1, j0, geo)
                | self._occupied(i1, j1, geo))

    def _crossings(self, t, d_along, d_other, p_along, p_other, along_is_x, geo):
        """Crossings of the next M lines across one axis from p(t) (``along`` = that axis):
        (crossing times [R, M], entered cell occupied [R, M])."""
        inf = torch.full_like(t, math.inf)
        pos = d_along > 0
        first = torch.where(pos, torch.floor(p_along + EPS) + 1.0, torch.ceil(p_along - EPS) - 1.0)
        sgn = torch.where(pos, 1.0, -1.0)
        lines = first[:, None] + sgn[:, None] * self._steps  # [R, M] line coordinates
        safe_d = torch.where(d_along == 0, torch.ones_like(d_along), d_along)
        tc = t[:, None] + (lines - p_along[:, None]) / safe_d[:, None]
        tc = torch.where((d_along == 0)[:, None], inf[:, None], tc)
        other = p_other[:, None] + (tc - t[:, None]) * d_other[:, None]
        other = torch.where(torch.isfinite(tc), other, p_other[:, None])
        into = (lines - (~pos).double()[:, None]).long()  # the column/row entered
        lo, hi = self._span(other)
        if along_is_x:
            hit = self._occupied(lo, into, geo) | self._occupied(hi, into, geo)
        else:
            hit = self._occupied(into, lo, geo) | self._occupied(into, hi, geo)
        return tc, hit

    def _jump(self, u, v, dx, dy, plane, t, geo):
        """t advanced by the directional safe distance of the cell containing p(t) (any closed cell
        containing the point bounds it), where that is at least JUMP_MIN_CELLS."""
        pu, pv = u + t * dx, v + t * dy
        b = self._cone[plane + _clamp(torch.floor(pv).long() + PAD, geo.hp - 1) * geo.wp
                       + _clamp(torch.floor(pu).long() + PAD, geo.wp - 1)].long()
        return torch.where(b >= self._jump_byte, t + (b - 1) * 0.5 - DELTA, t)

    def _cast(self, u, v, dx, dy, plane, geo: "_Geo") -> torch.Tensor:
        """Ranges in cells for flat [R] rays (grid-unit origins, unit directions). The active set is
        compacted by one ``nonzero`` per round (one host synchronisation; results are written by
        index, never through boolean masks)."""
        maxc = geo.maxc
        res = torch.full_like(u, maxc) if geo.single else maxc.clone()
        inside = (u > 0) & (u < geo.w) & (v > 0) & (v < geo.h)
        # an origin touching an occupied cell ends the ray before any jump could skip past it
        start = inside & self._touches(u, v, geo)  # (indices clamp: safe on every ray)
        res = torch.where(inside & ~start, res, torch.zeros_like(res))
        ids = torch.nonzero(inside & ~start).squeeze(1)
        u, v, dx, dy, plane = (a.index_select(0, ids) for a in (u, v, dx, dy, plane))
        geo = geo.take(ids)
        t = torch.zeros_like(u)
        while ids.numel() > 0:
            for _ in range(self.jumps_per_round):  # cheap [R] ops: skip free space first
                t = self._jump(u, v, dx, dy, plane, t, geo)
            pu, pv = u + t * dx, v + t * dy
            hit_t = torch.where(self._touches(pu, pv, geo), t, math.inf)
            tx, hx = self._crossings(t, dx, dy, pu, pv, True, geo)
            ty, hy = self._crossings(t, dy, dx, pv, pu, False, geo)
            end = torch.minimum(tx[:, -1], ty[:, -1])
            cand = torch.minimum(torch.where(hx & (tx <= end[:, None]), tx, math.inf).amin(1),
                                 torch.where(hy & (ty <= end[:, None]), ty, math.inf).amin(1))
            hit_t = torch.minimum(hit_t, cand)
            t = end
            hit = torch.isfinite(hit_t)
            maxc = geo.maxc
            done = hit | (t >= maxc)
            # the active rays still hold maxc: write them all (= maxc where nothing was hit yet)
            res[ids] = torch.where(hit, torch.clamp(hit_t, max=maxc) if geo.single else torch.minimum(hit_t, maxc), maxc)
            keep = torch.nonzero(~done).squeeze(1)  # the round's one host synchronisation
            ids, u, v, dx, dy, plane, t = (a.index_select(0, keep) for a in (ids, u, v, dx, dy, plane, t))
            geo = geo.take(keep)
        return res


class _Geo:
    """Each ray's map geometry: unpadded shape ``h``, ``w``, padded ``hp``, ``wp`` (cells),
    ``occ_base`` (flat offset of the map's padded occupancy) and ``maxc`` (max range in the map's
    cells). Python numbers for a single map (shared by all rays: the single-map ops, unchanged), else
    [R] tensors that follow the active rays."""

    KEYS = ("h", "w", "hp", "wp", "occ_base")

    def __init__(self, h, w, hp, wp, occ_base, maxc) -> None:
        self.h, self.w, self.hp, self.wp, self.occ_base, self.maxc = h, w, hp, wp, occ_base, maxc
        self.single = not isinstance(maxc, torch.Tensor)

    def take(self, sel) -> "_Geo":
        if self.single:
            return self
        return _Geo(*(getattr(self, key)[sel] for key in (*self.KEYS, "maxc")))

    def bcast(self, key: str, like: torch.Tensor):
        """The value ``key`` shaped to broadcast against ``like`` ([R] or [R, M])."""
        value = getattr(self, key)
        return value if self.single or like.ndim == 1 else value[:, None]


def _clamp(index: torch.Tensor, high):
    """``index`` clamped in place to [0, high] (``high`` a number, or a tensor of ``index``'s shape)."""
    if isinstance(high, torch.Tensor):
        return torch.minimum(index.clamp_(min=0), high)
    return index.clamp_(0, high)


def _per_map(grids, device, *, sectors, cone_base, occ_base) -> dict[str, torch.Tensor]:
    """[M] tensors of each map's values, gathered per env by the multi-map raycasters."""
    long = dict(device=device, dtype=torch.long)
    table = map_table(grids, device, PAD)
    return {**{key: table[key] for key in ("h", "w", "hp", "wp", "ox", "oy", "res")},
            "sectors": torch.tensor(sectors, **long), "cone_base": torch.as_tensor(cone_base, **long),
            "occ_base": torch.as_tensor(occ_base, **long)}


class MarchRaycaster(Raycaster):
    """The paper's ray march: samples at t = step, 2 step, ... (metres); the first sample whose cell
    (``floor``) is occupied or off the map gives the range; none up to ``max_range`` gives
    ``max_range``. float32, over the still-active rays a chunk of samples at a time.

    The chunking decides only how much work is done, never a range (tests/test_raycast.py checks
    the ranges against a one-sample-at-a-time march for several schedules): the first chunk has
    ``chunk_steps`` samples and each next one ``chunk_growth`` times the last, capped so that a chunk
    holds at most ``max_batch_rays * chunk_steps`` samples (the memory bound of the first chunk).
    Each chunk costs one host synchronisation (the active set is compacted by one ``nonzero``): on a
    GPU, where a chunk's kernels take microseconds, fewer and larger chunks are the speed; on a CPU
    the samples a ray takes past its hit are the cost, so chunks stay small there.

    Args:
        max_batch_rays: rays processed together; ``None``: :func:`default_batch_rays`.
        chunk_growth: factor from one chunk's size to the next; ``None``: 2 on CUDA, 1 elsewhere.
    """

    name = "march"

    def __init__(self, grid, beam_angles, max_range, device="cpu", step: float = 0.03,
                 chunk_steps: int = 32, max_batch_rays: int | None = None, chunk_growth: int | None = None) -> None:
        super().__init__(grid, beam_angles, max_range, device)
        if not step > 0:
            raise ValueError(f"march step must be > 0 metres, got {step}")
        if int(chunk_steps) < 1:
            raise ValueError(f"march chunk_steps must be >= 1 samples, got {chunk_steps}")
        self.step = float(step)
        self.chunk_steps = int(chunk_steps)
        self.max_batch_rays = default_batch_rays(self.device) if max_batch_rays is None else int(max_batch_rays)
        self.chunk_growth = (2 if self.device.type == "cuda" else 1) if chunk_growth is None else int(chunk_growth)
        if self.chunk_growth < 1:
            raise ValueError(f"march chunk_growth must be >= 1, got {chunk_growth}")
        self._n_steps = math.ceil(self.max_range / self.step - 1e-9)
        occ, occ_base = pack([g.padded(1) for g in self.grids])
        self._flat = torch.from_numpy(occ.copy()).to(self.device)
        self._hp, self._wp = self.grid.shape[0] + 2, self.grid.shape[1] + 2
        # [M] per map, gathered per ray; float32 as the single-map ops' Python numbers act on float32
        self._maps = None
        if len(self.grids) > 1:
            table = map_table(self.grids, self.device, 1, torch.float32)
            self._maps = {key: table[key].float() for key in ("ox", "oy", "inv", "hp", "wp")}
            self._maps["base"] = torch.as_tensor(occ_base, device=self.device, dtype=torch.long)

    def __call__(self, pose: torch.Tensor, map_index=None) -> torch.Tensor:
        mi = self._check(pose, map_index)
        p = pose.to(self.device, torch.float32)
        n, k = p.shape[0], self.beam_angles.numel()
        ang = p[:, 2:3] + self.beam_angles
        c, s = torch.cos(ang).reshape(-1), torch.sin(ang).reshape(-1)
        x = p[:, 0:1].expand(n, k).reshape(-1)
        y = p[:, 1:2].expand(n, k).reshape(-1)
        g = self.grid
        if mi is None:  # Python numbers: the single-map ops, unchanged
            geo = {"ox": g.origin[0], "oy": g.origin[1], "inv": 1.0 / g.resolution, "hp": self._hp, "wp": self._wp}
        else:  # [R, 1] per ray, from each env's map
            geo = {key: value[mi.to(self.device)][:, None].expand(n, k).reshape(-1, 1) for key, value in self._maps.items()}
        out = torch.empty(n * k, dtype=torch.float32, device=self.device)
        for b in range(0, n * k, self.max_batch_rays):
            e = min(b + self.max_batch_rays, n * k)
            part = geo if mi is None else {key: value[b:e] for key, value in geo.items()}
            out[b:e] = self._march(x[b:e], y[b:e], c[b:e], s[b:e], part)
        return out.reshape(n, k)

    def _march(self, x, y, c, s, geo: dict) -> torch.Tensor:
        """Ranges of flat [R] rays from (x, y) along (c, s); ``geo``: each ray's map (origin, 1 /
        resolution, padded shape, flat offset), Python numbers for one map or [R, 1] tensors."""
        single = not isinstance(geo["inv"], torch.Tensor)
        out = torch.full_like(x, self.max_range)
        ids = torch.arange(x.numel(), device=self.device)
        budget = self.max_batch_rays * self.chunk_steps  # samples per chunk at most
        k0, size = 0, self.chunk_steps
        while k0 < self._n_steps and ids.numel() > 0:
            size = min(size, self._n_steps - k0)
            kk = torch.arange(k0 + 1, k0 + size + 1, device=self.device).float()
            t = kk * self.step  # [C] metres
            col = torch.floor((x[:, None] + t * c[:, None] - geo["ox"]) * geo["inv"])
            row = torch.floor((y[:, None] + t * s[:, None] - geo["oy"]) * geo["inv"])
            # indices off the map clamp onto the occupied border of the 1-cell padding
            col = _clamp(col + 1, geo["wp"] - 1).long()
            row = _clamp(row + 1, geo["hp"] - 1).long()
            if single:
                hit = self._flat[row * geo["wp"] + col]  # [R, C] bool
            else:
                hit = self._flat[row * geo["wp"].long() + col + geo["base"]]
            any_hit = hit.any(1)
            first = hit.to(torch.uint8).argmax(1)
            # active rays still hold max_range: write every one, no boolean indexing (no host sync)
            out[ids] = torch.where(any_hit, torch.clamp(t[first], max=self.max_range), self.max_range)
            keep = torch.nonzero(~any_hit).squeeze(1)  # the chunk's one host synchronisation
            ids, x, y, c, s = (a.index_select(0, keep) for a in (ids, x, y, c, s))
            if not single:
                geo = {key: value.index_select(0, keep) for key, value in geo.items()}
            k0 += size
            size = min(self.chunk_growth * size, max(self.chunk_steps, budget // max(1, ids.numel())))
        return out


def default_batch_rays(device: torch.device) -> int:
    """Rays a torch raycaster processes together when not told: on CUDA one batch for 4,096
    environments of 1,080 beams (fewer, larger launches; the temporaries fit a 16 GB card), on a
    CPU 2^18 (cache-sized pieces)."""
    return 1 << 22 if torch.device(device).type == "cuda" else 1 << 18
