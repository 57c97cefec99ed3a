"""Moving disc agents (pedestrians) of the batched environment: K discs per slot, their state as
[N, K, ...] tensors, their behaviours, and the hooks the environment calls (reset, step, sense, collide).

Behaviours (``RobotPreset.agents.mix`` weights them; each agent draws its own at reset):

- ``waypoints``: walks at its own speed along legs between random free points; a leg is a straight
  segment of LEG_LENGTH metres whose whole swept disc is clear of walls (checked when it is chosen),
  so the agent's path stays in the free space; at the end of a leg it chooses the next one.
- ``bounce``: constant velocity; a step that would touch a wall is replaced by the velocity reflected
  in x, in y, or reversed (the first that is clear): the agent turns away from walls.
- ``crossing``: for evaluation scenarios. It waits, invisible, at a point ``crossing_offset`` metres
  to one side of the robot's start-goal line, and appears at the step chosen so that, walking at its
  speed, it reaches the line when a robot driving at full speed along it would; it then walks
  straight across the line to the mirror point and stands there. An agent appears only where it
  leaves ``spawn_clearance`` to the robot (else one step later).
- ``reactive`` agents (any behaviour, a share ``agents.reactive``) slow down linearly and stop as
  the gap to a robot ahead of them (within 60 deg of their heading) falls below ``reactive_distance``.

Invariants: an agent's disc never overlaps a wall or leaves the map (every position it takes is
checked against the map's :func:`~flashnav.maps.fields.safe_field`, a lower bound on the clearance of
every point of a cell); a new agent leaves at least ``spawn_clearance`` between its disc and the
robot's footprint (its circumscribed disc) at the start and at the goal; an agent that finds no such
place among SPAWN_CANDIDATES draws is absent for the episode. Agents may overlap each other.

Sensing and collision are exact (:mod:`flashnav.sim.agent_geometry`; the CPU beams run the numba
kernel :mod:`flashnav.sim.agent_numba`); where agents may be on the maps (clearance, free cells, clear
legs) is :class:`flashnav.sim.agent_space.AgentSpace`. State is float32 metres in the simulator frame of
each slot's map; with several maps (``grids``) every call takes a map index per slot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from flashnav.config import RobotPreset
from flashnav.maps.fields import PAD
from flashnav.maps.grid import OccupancyMap
from flashnav.names import AGENT_BEHAVIOURS
from flashnav.sim.agent_draws import hash_uniform
from flashnav.sim.agent_geometry import footprint_disc_gap, footprint_hits_discs, ray_disc_ranges
from flashnav.sim.agent_space import AgentSpace

WAYPOINTS, BOUNCE, CROSSING = (AGENT_BEHAVIOURS.index(b) for b in ("waypoints", "bounce", "crossing"))
SPAWN_CANDIDATES = 16  # random places tried per new agent
CROSSING_CANDIDATES = 64  # random crossings tried per crossing agent (a clear straight leg is rarer)
LEG_CANDIDATES = 8  # random legs tried per agent that needs one
LEG_LENGTH = (0.5, 3.0)  # metres, a waypoint leg's length range
CROSSING_POINT = (0.3, 0.7)  # where a crossing agent crosses the route, as a fraction of its length
SEGMENT_SPACING = 0.1  # metres at most between the clearance samples of a leg
ARRIVED = 1e-4  # metres: a leg's end is reached (float32 positions of a 10 m map are ~1e-6 apart)
REACT_COS = 0.5  # a reactive agent reacts to a robot within 60 deg of its heading


class AgentWorld:
    """The agents of ``num_envs`` slots; see the module docstring. ``grids`` are the environment's
    maps in their simulator frames (one, or one per map index)."""

    def __init__(self, preset: RobotPreset, grids: OccupancyMap | Sequence[OccupancyMap], num_envs: int,
                 beam_angles: torch.Tensor, device: torch.device | str = "cpu"):
        cfg = preset.agents
        if cfg.count < 1:
            raise ValueError(f"AgentWorld needs agents.count >= 1, got {cfg.count}")
        grids = (grids,) if isinstance(grids, OccupancyMap) else tuple(grids)
        self.cfg, self.preset, self.device = cfg, preset, torch.device(device)
        self.num_envs, self.count = num_envs, cfg.count
        self.robot_radius = preset.footprint.circumscribed_radius
        self.dt = preset.episode.dt
        self.robot_speed = max(abs(v) for v in preset.motion.v_bounds)
        self.mix = torch.tensor([cfg.mix.get(b, 0.0) for b in AGENT_BEHAVIOURS], dtype=torch.float64, device=self.device)
        max_leg = max(LEG_LENGTH[1], 2.0 * cfg.crossing_offset[1])
        #: where agents may be on the maps: clearance lookups, free cells, clear legs
        self.space = AgentSpace(grids, cfg.radius[1], math.ceil(max_leg / SEGMENT_SPACING) + 1, self.device)
        n, k, dev = num_envs, cfg.count, self.device
        self.pos = torch.zeros(n, k, 2, device=dev)  # centres, m
        self.vel = torch.zeros(n, k, 2, device=dev)  # bounce: velocity, m/s
        self.target = torch.zeros(n, k, 2, device=dev)  # waypoints / crossing: the end of the leg, m
        self.final = torch.zeros(n, k, 2, device=dev)  # crossing: the far point, after the crossing point
        self.radius = torch.zeros(n, k, device=dev)  # m
        self.speed = torch.zeros(n, k, device=dev)  # m/s
        self.kind = torch.zeros(n, k, dtype=torch.long, device=dev)  # index into AGENT_BEHAVIOURS
        self.reactive = torch.zeros(n, k, dtype=torch.bool, device=dev)
        self.placed = torch.zeros(n, k, dtype=torch.bool, device=dev)  # exists in this episode
        self.active = torch.zeros(n, k, dtype=torch.bool, device=dev)  # placed and visible now
        self.appear = torch.zeros(n, k, dtype=torch.int32, device=dev)  # step at which a crossing agent appears
        self.key = torch.zeros(n, dtype=torch.int64, device=dev)  # the slot's episode key for leg draws
        # the beams, as the static raycasters form their directions (float64 cos / sin of the angles)
        a = torch.as_tensor(beam_angles, dtype=torch.float32).reshape(-1).double()
        self.max_range = preset.lidar.max_range
        self._cos_a, self._sin_a = torch.cos(a).to(dev), torch.sin(a).to(dev)
        self._a0 = float(a[0])
        self._a_step = float(a[-1] - a[0]) / (a.numel() - 1) if a.numel() > 1 else 0.0
        self._numba = None
        self._crossings = cfg.mix.get("crossing", 0.0) > 0
        #: "numba" (the CPU default) or "torch": how :meth:`step` moves the agents
        self.step_kernel = "numba" if self.device.type == "cpu" else "torch"

    # ---- episode start ---------------------------------------------------------------------------
    def reset(self, idx: torch.Tensor, pose: torch.Tensor, goal: torch.Tensor, gen: torch.Generator,
              maps: torch.Tensor | None = None) -> None:
        """New agents for slots ``idx`` [k] whose robots start at ``pose`` [k, 3] with ``goal`` [k, 2];
        every other slot is left untouched."""
        k, K, dev = idx.numel(), self.count, self.device
        if k == 0:
            return
        maps = torch.zeros(k, dtype=torch.long, device=dev) if maps is None else maps
        cfg = self.cfg
        kind = torch.multinomial(self.mix, k * K, replacement=True, generator=gen).view(k, K)
        u = torch.rand(k, K, 4, generator=gen, device=dev)
        radius = cfg.radius[0] + u[..., 0] * (cfg.radius[1] - cfg.radius[0])
        speed = cfg.speed[0] + u[..., 1] * (cfg.speed[1] - cfg.speed[0])
        reactive = u[..., 2] < cfg.reactive
        heading = (u[..., 3] * 2.0 - 1.0) * math.pi
        # free places: the first candidate far enough from the robot's start and goal
        mk = maps[:, None, None].expand(k, K, SPAWN_CANDIDATES)
        cand = self.space.free_points(mk, gen)  # [k, K, C, 2]
        ok = self._clear_of_robot(cand, radius[..., None], pose[:, None, None, :2], goal[:, None, None])
        pos, placed = _first(cand, ok)
        target = pos.clone()  # a waypoints agent chooses its first leg on its first step
        appear = torch.zeros(k, K, dtype=torch.int32, device=dev)
        cross = kind == CROSSING
        final = pos.clone()
        if bool(cross.any()):  # a host sync, at resets only
            c_pos, c_target, c_final, c_ok, c_appear = self._crossing(pose, goal, radius, speed, maps, gen)
            pos = torch.where(cross[..., None], c_pos, pos)
            target = torch.where(cross[..., None], c_target, target)
            final = torch.where(cross[..., None], c_final, final)
            placed = torch.where(cross, c_ok, placed)
            appear = torch.where(cross, c_appear, appear)
        vel = speed[..., None] * torch.stack([torch.cos(heading), torch.sin(heading)], dim=-1)
        self.pos[idx], self.vel[idx], self.target[idx], self.final[idx] = pos, vel, target, final
        self.radius[idx], self.speed[idx], self.kind[idx], self.reactive[idx] = radius, speed, kind, reactive
        self.placed[idx], self.appear[idx] = placed, appear
        self.key[idx] = torch.randint(0, 2**62, (k,), generator=gen, device=dev)
        self.active[idx] = placed & ~cross

    def _clear_of_robot(self, p: torch.Tensor, r: torch.Tensor, start: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Discs (p, r) leave ``spawn_clearance`` to the robot's circumscribed disc at start and goal."""
        reach = r + self.robot_radius + self.cfg.spawn_clearance
        return ((torch.linalg.vector_norm(p - start, dim=-1) >= reach)
                & (torch.linalg.vector_norm(p - goal, dim=-1) >= reach))

    def _crossing(self, pose, goal, radius, speed, maps, gen):
        """Waiting place, crossing point, far point, found?, appearance step of a crossing agent, for
        every [k, K]: the point q where it crosses the start-goal line, a waiting place ``a`` on one
        side and a far point ``b`` on the other (each within 45 deg of the line's normal), legs a -> q
        and q -> b clear; the first of CROSSING_CANDIDATES draws that fits."""
        k, K, C, dev = pose.shape[0], self.count, CROSSING_CANDIDATES, self.device
        u = torch.rand(k, K, C, 6, generator=gen, device=dev)
        start = pose[:, None, None, :2]
        route = (goal - pose[:, :2])[:, None, None, :]
        length = torch.linalg.vector_norm(route, dim=-1).clamp(min=1e-6)  # [k, 1, 1]
        normal = torch.stack([-route[..., 1], route[..., 0]], dim=-1) / length[..., None]
        frac = CROSSING_POINT[0] + u[..., 0] * (CROSSING_POINT[1] - CROSSING_POINT[0])
        side = torch.where(u[..., 1] < 0.5, -1.0, 1.0)
        lo, hi = self.cfg.crossing_offset
        q = start + frac[..., None] * route
        ends = []
        for d_u, tilt_u, sign in ((u[..., 2], u[..., 3], 1.0), (u[..., 4], u[..., 5], -1.0)):
            tilt = (tilt_u * 2.0 - 1.0) * (math.pi / 4)
            c, s_ = torch.cos(tilt)[..., None], torch.sin(tilt)[..., None]
            direction = torch.cat([c * normal[..., :1] - s_ * normal[..., 1:], s_ * normal[..., :1] + c * normal[..., 1:]], -1)
            ends.append(q + (sign * side * (lo + d_u * (hi - lo)))[..., None] * direction)
        a, b = ends
        r = radius[..., None].expand(k, K, C)
        mk = maps[:, None, None].expand(k, K, C)
        space = self.space
        ok = ((space.clearance(a, mk) >= r) & (space.clearance(q, mk) >= r) & (space.clearance(b, mk) >= r)
              & space.segment_clear(a, q, r, mk) & space.segment_clear(q, b, r, mk))
        ok &= self._clear_of_robot(a, r, start, goal[:, None, None])
        (a, q, b), found = _first([a, q, b], ok)
        frac = torch.gather(frac, 2, ok.float().argmax(dim=-1, keepdim=True)).squeeze(2)
        robot_t = frac * length[..., 0] / self.robot_speed
        walk_t = torch.linalg.vector_norm(q - a, dim=-1) / speed
        appear = torch.round((robot_t - walk_t).clamp(min=0.0) / self.dt).to(torch.int32)
        return a, q, b, found, appear

    # ---- one step --------------------------------------------------------------------------------
    def step(self, sel, robot_pose: torch.Tensor, steps: torch.Tensor, gen: torch.Generator,
             maps: torch.Tensor | None = None) -> None:
        """Move the agents of slots ``sel`` (``slice(None)`` or [k] long) by one step; ``robot_pose``
        [k, 3] is where the robots are after this step's motion, ``steps`` [k] their step counters.
        On the CPU one numba kernel does it all (:func:`flashnav.sim.agent_numba.step_agents`: the
        ~50 small tensor ops below cost more than the LiDAR there); elsewhere these torch ops."""
        if self.step_kernel == "numba":
            return self._step_numba(sel, robot_pose, steps, maps)
        pos, vel, target = self.pos[sel], self.vel[sel], self.target[sel]
        radius, speed, kind, active = self.radius[sel], self.speed[sel], self.kind[sel], self.active[sel]
        k, K = pos.shape[:2]
        maps = torch.zeros(k, dtype=torch.long, device=self.device) if maps is None else maps
        mk = maps[:, None].expand(k, K)
        robot = robot_pose[:, None, :2]
        if self._crossings:  # crossing agents appear at their step, where they leave the robot room
            waiting = self.placed[sel] & ~active & (steps[:, None] >= self.appear[sel])
            active = active | (waiting & self._clear_of_robot(pos, radius, robot, robot))
        walker = kind != BOUNCE
        to_target = target - pos
        remaining = torch.linalg.vector_norm(to_target, dim=-1)
        direction = torch.where(walker[..., None], to_target / remaining.clamp(min=1e-9)[..., None],
                                vel / speed.clamp(min=1e-9)[..., None])
        length = speed * self.dt * self._reaction(pos, direction, radius, robot, self.reactive[sel])
        length = torch.where(walker, torch.minimum(length, remaining), length)
        proposed = pos + direction * length[..., None]
        ok = self.space.clearance(proposed, mk) >= radius
        new_pos = torch.where((ok & active)[..., None], proposed, pos)
        vel = self._bounce(active & ~ok & (kind == BOUNCE), pos, new_pos, vel, direction * length[..., None], radius, mk)
        # crossing agents at the crossing point head for the far point; waypoints agents at the end
        # of their leg (or blocked) choose the next leg
        arrived = torch.linalg.vector_norm(target - new_pos, dim=-1) <= ARRIVED
        if self._crossings:
            target = torch.where((arrived & (kind == CROSSING))[..., None], self.final[sel], target)
        need = active & (kind == WAYPOINTS) & (arrived | ~ok)
        target = self._new_legs(new_pos, target, radius, mk, need, self.key[sel], steps)
        self.pos[sel], self.vel[sel], self.target[sel], self.active[sel] = new_pos, vel, target, active

    def _step_numba(self, sel, robot_pose, steps, maps) -> None:
        from flashnav.sim.agent_numba import step_agents

        slots = torch.arange(self.num_envs) if isinstance(sel, slice) else sel
        k = slots.numel()
        maps = torch.zeros(k, dtype=torch.long) if maps is None else maps
        cfg = self.cfg
        consts = np.array([self.dt, self.robot_radius, cfg.spawn_clearance,
                           cfg.reactive_distance if cfg.reactive > 0 else 0.0, REACT_COS, LEG_LENGTH[0],
                           LEG_LENGTH[1], LEG_CANDIDATES, ARRIVED, 1.0 if self._crossings else 0.0])
        v = lambda t: t.detach().contiguous().numpy()  # noqa: E731
        step_agents(v(slots.long()), v(robot_pose.float()), v(steps.int()), v(maps.long()), self.pos.numpy(),
                    self.vel.numpy(), self.target.numpy(), self.final.numpy(), self.radius.numpy(),
                    self.speed.numpy(), self.kind.numpy(), self.reactive.numpy(), self.placed.numpy(),
                    self.active.numpy(), self.appear.numpy(), self.key.numpy(), *self.space.numba_tables(),
                    PAD, self.space.samples.numpy(), consts)

    def _bounce(self, blocked, pos, new_pos, vel, move, radius, mk) -> torch.Tensor:
        """Bounce agents ``blocked`` [k, K] by a wall: the move reflected in x, in y, or reversed, the
        first that is clear, written into ``new_pos``; returns the velocities, reflected the same way."""
        rows = blocked.nonzero()  # few agents; a host sync
        if rows.numel() == 0:
            return vel
        n_, j_ = rows[:, 0], rows[:, 1]
        p, r, m = pos[n_, j_], radius[n_, j_], mk[n_, j_]
        flips = torch.tensor([[-1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]], device=self.device)
        alt = p[:, None] + move[n_, j_][:, None] * flips  # [b, 3, 2]
        fits = self.space.clearance(alt, m[:, None].expand(-1, 3)) >= r[:, None]
        pick = fits.float().argmax(dim=1)
        found = fits.any(dim=1)[:, None]
        new_pos[n_, j_] = torch.where(found, alt[torch.arange(len(pick), device=self.device), pick], p)
        vel = vel.clone()
        vel[n_, j_] = torch.where(found, vel[n_, j_] * flips[pick], vel[n_, j_])
        return vel

    def _reaction(self, pos, direction, radius, robot, reactive) -> torch.Tensor:
        """[k, K] speed factor in [0, 1]: reactive agents slow down for a robot ahead of them."""
        if self.cfg.reactive <= 0:
            return torch.ones_like(radius)
        rel = robot - pos
        dist = torch.linalg.vector_norm(rel, dim=-1)
        ahead = (rel * direction).sum(-1) >= REACT_COS * dist
        gap = dist - radius - self.robot_radius
        factor = (gap / self.cfg.reactive_distance).clamp(0.0, 1.0)
        return torch.where(reactive & ahead, factor, torch.ones_like(factor))

    def _new_legs(self, pos, target, radius, mk, need, keys, steps) -> torch.Tensor:
        """``target`` with a new clear leg end for the agents ``need`` (their position if none is found).
        The draws are a hash of (slot key, step, agent, candidate): a slot's agents move the same
        whichever other slots are stepped (``step_slots``) or reset, so an evaluation episode's agents
        do not depend on how long the other episodes last."""
        rows = need.nonzero()  # a host sync; only agents at the end of a leg do any work
        if rows.numel() == 0:
            return target
        n_, j_ = rows[:, 0], rows[:, 1]
        lanes = torch.arange(LEG_CANDIDATES * 2, device=self.device).view(1, LEG_CANDIDATES, 2)
        u = hash_uniform(keys[n_][:, None, None], steps[n_].long()[:, None, None], j_[:, None, None], lanes)
        angle = (u[..., 0] * 2.0 - 1.0) * math.pi
        reach = LEG_LENGTH[0] + u[..., 1] * (LEG_LENGTH[1] - LEG_LENGTH[0])
        start = pos[n_, j_][:, None, :]
        end = start + reach[..., None] * torch.stack([torch.cos(angle), torch.sin(angle)], dim=-1)
        r = radius[n_, j_][:, None].expand(-1, LEG_CANDIDATES)
        m = mk[n_, j_][:, None].expand(-1, LEG_CANDIDATES)
        ok = self.space.segment_clear(start, end, r, m) & (self.space.clearance(end, m) >= r)
        chosen, found = _first(end, ok)
        target = target.clone()
        target[n_, j_] = torch.where(found[:, None], chosen, pos[n_, j_])
        return target

    # ---- sensing and collision -------------------------------------------------------------------
    def sense(self, ranges: torch.Tensor, pose: torch.Tensor, sel, kernel: str | None = None) -> torch.Tensor:
        """[k, B] float32 m: the static ``ranges`` lowered to the agents' exact hits, for ``pose``
        [k, 3] of slots ``sel``. ``kernel``: "numba" (CPU only; the default there; it writes into
        ``ranges``) or "torch" (the default elsewhere)."""
        centres, radii, active = self.pos[sel], self.radius[sel], self.active[sel]
        kernel = kernel or ("numba" if ranges.device.type == "cpu" else "torch")
        if kernel == "torch":
            hit = ray_disc_ranges(pose, self._cos_a, self._sin_a, centres, radii, active, self.max_range)
            return torch.minimum(ranges.double(), hit).to(ranges.dtype)
        if kernel != "numba" or ranges.device.type != "cpu":
            raise ValueError(f"kernel must be 'torch', or 'numba' on the CPU; got {kernel!r} on {ranges.device}")
        if self._numba is None:
            from flashnav.sim import agent_numba  # lazily: the first import may JIT-compile

            self._numba = agent_numba.lower_by_discs
        out = ranges.contiguous()
        self._numba(pose.detach().float().contiguous().numpy(), self._cos_a.numpy(), self._sin_a.numpy(),
                    self._a0, self._a_step, centres.contiguous().numpy(), radii.contiguous().numpy(),
                    active.contiguous().numpy(), float(self.max_range), out.numpy())
        return out

    def collides(self, pose: torch.Tensor, sel) -> torch.Tensor:
        """[k] bool: the robot's footprint at ``pose`` [k, 3] overlaps an active agent of slots ``sel``."""
        return footprint_hits_discs(pose, self.preset.footprint, self.pos[sel], self.radius[sel], self.active[sel])

    def gap(self, pose: torch.Tensor, sel) -> torch.Tensor:
        """[k] m: the smallest gap between the robot's footprint at ``pose`` [k, 3] and an active agent of
        slots ``sel`` (0 on contact, inf with none active)."""
        return footprint_disc_gap(pose, self.preset.footprint, self.pos[sel], self.radius[sel], self.active[sel])


def _first(cand, ok: torch.Tensor):
    """The first candidate of ``cand`` [..., C, 2] (or of each of a list of them) whose ``ok`` [..., C]
    holds, and whether any does (the first candidate where none does)."""
    pick = ok.float().argmax(dim=-1)[..., None, None]
    take = lambda c: torch.gather(c, -2, pick.expand(*pick.shape[:-2], 1, 2)).squeeze(-2)  # noqa: E731
    return ([take(c) for c in cand] if isinstance(cand, list) else take(cand)), ok.any(dim=-1)
