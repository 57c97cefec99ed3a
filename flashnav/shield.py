"""A people shield: the policy drives, and the shield overrules it only when it is about to touch a person.

A policy reacts to the people it sees; it does not look ahead. The shield does, with what a people tracker
reports - each person's position, velocity and radius - and the current scan:

1. the policy's action, held for ``lookahead`` seconds with the robot's motion model (:mod:`flashnav.sim.motion`),
   against every person walking straight on at their tracked velocity, their radius grown by ``margin``: if the
   footprint touches nobody, the policy's action is played;
2. otherwise, of ``v_levels`` x ``w_levels`` constant actions over the action bounds (and the policy's own), the
   one nearest the policy's (Euclidean, in action units) whose rollout touches nobody and no wall - the scan's
   points (:func:`scan_points`: the nearest hit of each group of beams, points on a tracked person dropped), so
   no map is needed, and the edges of the sector the sensor does not see (:func:`blind_edges`: a 270-deg LiDAR's
   rear quarter is unknown, not free, so a robot that can reverse is not sent backwards into it) - is played; if
   every rollout touches something, the one whose first contact comes latest (then the nearest).

Walls alone never call the shield: the policy answers for them. Everything is in one planar frame of the
caller's choosing (the simulator's, or the robot's odometry frame on a robot). Torch ops on [E, ...] batches, so
the simulator's evaluation shields every episode at once and the deploy node uses E = 1.

Measured on issue 13's scenarios (docs/benchmarks.md "A people shield in front of the policy"): ``flashnav eval
POLICY --scenario crossing,wander-8 --shield 2``.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import torch

from flashnav.config import RobotPreset
from flashnav.sim.agent_geometry import footprint_hits_discs
from flashnav.sim.motion import action_to_velocity, integrate

#: a scan point as a disc of this radius, m (touching is not a collision)
POINT_RADIUS = 0.01
#: beams per scan point (the nearest hit of each group)
SCAN_GROUP = 4
#: a scan point this close to a tracked person's disc (m) is the person, not a wall
ON_PERSON = 0.1
#: a gap between neighbouring beams wider than this (rad) is a sector the sensor does not see
BLIND_GAP = math.radians(10.0)
#: metres between the points laid on a blind sector's edges (less than any footprint's size)
BLIND_SPACING = 0.05


class People(NamedTuple):
    """What a tracker reports for E robots: ``centres`` [E, M, 2] m, ``velocity`` [E, M, 2] m/s, ``radius``
    [E, M] m, ``present`` [E, M] bool (rows of absent people are ignored). With ``velocity`` None, ``centres``
    [E, L, M, 2] are where the people *will be* after each of the shield's L steps (a prediction other than
    straight on, or the recorded future of a diagnostic: scripts/agent_shield.py), and ``radius`` may be
    [E, L, M] too (a prediction whose uncertainty grows with the look-ahead)."""

    centres: torch.Tensor
    velocity: torch.Tensor | None
    radius: torch.Tensor
    present: torch.Tensor

    def rows(self, idx: torch.Tensor) -> "People":
        return People(*(None if t is None else t[idx] for t in self))

    def now(self) -> torch.Tensor:
        """[E, M, 2]: the centres now (the first predicted step's, for a prediction)."""
        return self.centres if self.velocity is not None else self.centres[:, 0]

    def radius_now(self) -> torch.Tensor:
        """[E, M]: the radii now (the first predicted step's, for radii per step)."""
        return self.radius if self.radius.dim() == 2 else self.radius[:, 0]


#: the longest look-ahead, seconds: the shield rolls each candidate command out for lookahead / dt steps against every
#: person, so its memory and time grow with it (1e3 s asked for 74 GB); people walking 1 m/s are 10 m away in 10 s
MAX_LOOKAHEAD = 10.0


def check_lookahead(lookahead: float, flag: str = "shield lookahead") -> float:
    """``lookahead`` if it is a finite number of seconds in (0, :data:`MAX_LOOKAHEAD`]; else a ValueError naming
    ``flag``."""
    if not (math.isfinite(lookahead) and 0 < lookahead <= MAX_LOOKAHEAD):
        raise ValueError(f"{flag} must be > 0 and at most {MAX_LOOKAHEAD:g} seconds, got {lookahead}")
    return lookahead


class PeopleShield:
    """The shield of the module docstring for a robot ``preset`` (its motion bounds, footprint and step)."""

    def __init__(self, preset: RobotPreset, lookahead: float = 2.0, margin: float = 0.05, v_levels: int = 5,
                 w_levels: int = 9):
        check_lookahead(lookahead)
        if not (math.isfinite(margin) and margin >= 0):
            raise ValueError(f"shield margin must be >= 0 metres, got {margin}")
        if v_levels < 2 or w_levels < 2:
            raise ValueError(f"shield v_levels and w_levels must be >= 2, got {v_levels} and {w_levels}")
        if not preset.motion.instant:
            warnings.warn(f"{preset.name}: the people shield rolls each command out as executed at once; this robot's "
                          "motion has latency or acceleration limits (motion.command_delay / max_*_accel), so its "
                          "rollouts are optimistic", RuntimeWarning, stacklevel=2)
        self.preset = preset
        self.dt = preset.episode.dt
        self.steps = max(1, round(lookahead / self.dt))
        self.lookahead, self.margin = lookahead, margin
        self.grid = torch.cartesian_prod(torch.linspace(-1, 1, v_levels), torch.linspace(-1, 1, w_levels))
        # the farthest a wall point can be from the robot's centre and still be touched within the look-ahead
        self.reach = (max(abs(b) for b in preset.motion.v_bounds) * self.steps * self.dt
                      + preset.footprint.circumscribed_radius + POINT_RADIUS + 1e-3)

    def first_contact(self, pose: torch.Tensor, actions: torch.Tensor, people: People,
                      walls: torch.Tensor | None = None) -> torch.Tensor:
        """[E, C] long: for ``pose`` [E, 3] and ``actions`` [E, C, 2] each held constant, the first step (0-based)
        of the rollout at which the footprint touches a predicted person or a wall point of ``walls`` [E, P, 2]
        (``inf`` rows: no point); ``self.steps`` where it touches nothing. The rollouts [E, C, L] meet the people
        and the points by broadcasting, never copied per rollout step; of the points only those within
        :attr:`reach` of ``pose`` are tested (exact: no rollout gets nearer the others)."""
        p, horizon = self.preset, self.steps
        e, c = actions.shape[:2]
        v, w = action_to_velocity(actions.reshape(-1, 2), p.motion)
        x = pose.float().repeat_interleave(c, 0)
        traj = []
        for _ in range(horizon):
            x = integrate(x, v, w, self.dt)
            traj.append(x)
        rollouts = torch.stack(traj, 1).reshape(e, c, horizon, 3)
        if people.velocity is None:
            future = people.centres  # [E, L, M, 2]
        else:
            ahead = torch.arange(1, horizon + 1, dtype=people.centres.dtype, device=pose.device) * self.dt
            future = people.centres[:, None] + people.velocity[:, None] * ahead[None, :, None, None]  # [E, L, M, 2]
        radius = people.radius + self.margin
        radius = radius[:, None] if radius.dim() == 2 else radius  # [E, 1 | L, M]
        bad = footprint_hits_discs(rollouts, p.footprint, future[:, None], radius[:, None],
                                   people.present[:, None, None])  # [E, C, L]
        near = self._near(pose, walls)
        if near is not None:
            there = torch.isfinite(near[..., 0])
            bad |= footprint_hits_discs(rollouts, p.footprint, torch.where(there[..., None], near, 0.0)[:, None, None],
                                        torch.full(there.shape, POINT_RADIUS, device=pose.device)[:, None, None],
                                        there[:, None, None])
        steps = torch.arange(horizon, device=pose.device)
        return torch.where(bad, steps, horizon).amin(2)

    def _near(self, pose: torch.Tensor, walls: torch.Tensor | None) -> torch.Tensor | None:
        """[E, P', 2]: of the points ``walls`` [E, P, 2], those within :attr:`reach` of ``pose`` [E, 3], nearest
        first, P' the most any row has (``inf`` pads the others); None when no row has one."""
        if walls is None or not walls.shape[1]:
            return None
        d = torch.linalg.vector_norm(walls - pose[:, None, :2].to(walls.dtype), dim=-1).nan_to_num(math.inf)
        d = torch.where(d <= self.reach, d, math.inf)
        k = int(torch.isfinite(d).sum(1).max())
        if k == 0:
            return None
        d, idx = d.topk(k, dim=1, largest=False)
        near = torch.gather(walls, 1, idx[..., None].expand(-1, -1, 2))
        return torch.where(torch.isfinite(d)[..., None], near, math.inf)

    def filter(self, proposed: torch.Tensor, pose: torch.Tensor, people: People,
               walls: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(actions [E, 2] to play, [E] bool where the shield took over) for the policy's ``proposed`` [E, 2] at
        ``pose`` [E, 3]; ``walls`` [E, P, 2]: the scan's points (:func:`scan_points`), or None. The shield takes over
        where the policy's action predicts a contact with a person; it then chooses the action, which can be the
        policy's own when nothing does better ("overruled" in the reports counts these steps)."""
        out = proposed.clone()
        threat = self.first_contact(pose, proposed[:, None], people)[:, 0] < self.steps
        if not bool(threat.any()):
            return out, threat
        idx = torch.nonzero(threat).squeeze(1)
        grid = self.grid.to(proposed.device)
        cand = torch.cat([proposed[idx, None], grid.expand(idx.numel(), -1, -1)], 1)  # [T, 1 + G, 2]
        first = self.first_contact(pose[idx], cand, people.rows(idx), None if walls is None else walls[idx])
        near = torch.linalg.vector_norm(cand - proposed[idx, None], dim=-1)
        # rollouts that touch nothing, nearest first; else the latest first contact, then the nearest
        score = torch.where(first >= self.steps, -1e3 + near, -first.float() + 1e-3 * near)
        out[idx] = cand[torch.arange(idx.numel(), device=proposed.device), score.argmin(1)]
        return out, threat


def scan_points(pose: torch.Tensor, ranges: torch.Tensor, beam_angles: torch.Tensor, max_range: float,
                people: People | None = None, group: int = SCAN_GROUP) -> torch.Tensor:
    """[E, B // group, 2]: the scans ``ranges`` [E, B] m (beams at ``beam_angles`` [B] rad in the robot frame,
    the sensor at the robot's centre) taken at ``pose`` [E, 3], as points in the pose's frame: the nearest hit
    of each group of ``group`` consecutive beams at its own bearing; ``inf`` where the group hit nothing
    (``max_range``) or the point lies within ``ON_PERSON`` of a present person's disc."""
    e, b = ranges.shape
    if b % group:
        raise ValueError(f"scan_points: {b} beams do not split into groups of {group}")
    near, arg = ranges.reshape(e, -1, group).min(dim=2)
    angles = beam_angles.to(ranges.device, ranges.dtype).reshape(-1, group).expand(e, -1, -1)
    bearing = torch.gather(angles, 2, arg[..., None])[..., 0] + pose[:, 2:3]
    pts = pose[:, None, :2] + near[..., None] * torch.stack([torch.cos(bearing), torch.sin(bearing)], -1)
    gone = near >= max_range
    if people is not None and people.present.shape[1]:
        gap = torch.linalg.vector_norm(pts[:, :, None] - people.now()[:, None], dim=-1) - people.radius_now()[:, None]
        gone |= ((gap < ON_PERSON) & people.present[:, None]).any(-1)
    return torch.where(gone[..., None], torch.full_like(pts, math.inf), pts)


def blind_edges(beam_angles: torch.Tensor) -> torch.Tensor | None:
    """[2] float64 bearings (rad, robot frame) of the edges of the widest gap between ``beam_angles`` [B] - the
    sector the sensor does not see: the last beam before the gap, the first after it; None for a sensor without a
    gap wider than :data:`BLIND_GAP` (360 deg). A scan's geometry: compute it once per beam layout."""
    a = torch.sort(torch.remainder(beam_angles.detach().double().cpu().flatten(), 2 * math.pi)).values
    if a.numel() < 2:
        return None
    gaps = torch.diff(torch.cat([a, a[:1] + 2 * math.pi]))
    k = int(gaps.argmax())
    return torch.stack([a[k], a[k] + gaps[k]]) if float(gaps[k]) > BLIND_GAP else None


def blind_points(pose: torch.Tensor, edges: torch.Tensor | None, reach: float, inner: float,
                 spacing: float = BLIND_SPACING) -> torch.Tensor | None:
    """[E, P, 2]: points on the two ``edges`` (:func:`blind_edges`) of the sector the sensor does not see, from
    ``inner`` to ``reach`` m from the robot's centre at ``pose`` [E, 3], every ``spacing`` m, in the pose's frame
    and on its device; None without edges. A footprint that moves into the unseen sector crosses an edge (spacing
    below the footprint's size), so the shield takes what it has not seen for occupied. ``inner`` beyond the
    footprint's circumscribed radius keeps the robot where it stands (and turning on the spot) clear of them."""
    if edges is None or not reach > inner:
        return None
    here = pose.double()  # float64 to the end, as the scan's geometry
    t = torch.arange(inner, reach + 1e-9, spacing, dtype=torch.float64, device=pose.device)  # [T] m from the centre
    bearing = here[:, 2:3] + edges.to(pose.device)[None]  # [E, 2]
    direction = torch.stack([torch.cos(bearing), torch.sin(bearing)], -1)  # [E, 2, 2]
    pts = here[:, None, None, :2] + t[None, None, :, None] * direction[:, :, None]  # [E, 2, T, 2]
    return pts.reshape(pose.shape[0], -1, 2).to(pose.dtype)


def with_blind_sector(shield: "PeopleShield", walls: torch.Tensor, pose: torch.Tensor,
                      edges: torch.Tensor | None) -> torch.Tensor:
    """``walls`` [E, P, 2] (the scan's points) with :func:`blind_points` on ``edges`` for ``shield``'s reach and
    footprint."""
    inner = shield.preset.footprint.circumscribed_radius + POINT_RADIUS + 1e-3
    blind = blind_points(pose, edges, shield.reach, inner)
    return walls if blind is None else torch.cat([walls, blind.to(walls.dtype)], 1)


class SimShield:
    """A :class:`PeopleShield` on a simulator ``env`` with agents (:mod:`flashnav.sim.agents`), for the evaluation
    loop (:func:`flashnav.evaluate.play_episodes` ``shield=``): every step it plays a people tracker - the agents
    the robot sees in its scan (:class:`flashnav.sim.tracks.TrackerView`, as the policy's agent tracks see them),
    each with the velocity of its last step if it was seen then too, else 0 - and the shield over the scan's
    points. One episode per slot, as the evaluation plays them (a loop that restarts slots calls :meth:`forget`).
    ``overruled`` / ``steps`` count what it did; ``took_over`` [k] bool: where it took over on its last call, and
    ``last`` (pose, people, walls): what it decided that call from (a diagnostic's record: scripts/agent_shield.py)."""

    def __init__(self, env, shield: PeopleShield):
        from flashnav.sim.tracks import TrackerView

        if env.agents is None:
            raise ValueError("the people shield needs agents in the simulator (a --scenario with agents)")
        self.env, self.shield = env, shield
        self.view = TrackerView(env.preset, env.beam_angles)
        self.blind = blind_edges(env.beam_angles)  # the sector the LiDAR does not see (fixed beams: once)
        self.prev = env.agents.pos.clone()
        self.seen = torch.zeros_like(env.agents.active)
        self.overruled = self.steps = 0
        self.took_over: torch.Tensor | None = None
        self.last: tuple | None = None

    def __call__(self, active: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        env = self.env
        pose, ranges = env.pose[active], env.scan(active)
        people = self.people(active, pose, ranges)
        walls = scan_points(pose, ranges, env.beam_angles, env.preset.lidar.max_range, people)
        walls = with_blind_sector(self.shield, walls, pose, self.blind)
        out, self.took_over = self.shield.filter(action, pose, people, walls)
        self.last = pose, people, walls
        self.overruled += int(self.took_over.sum())
        self.steps += active.numel()
        return out

    def forget(self, slots: torch.Tensor) -> None:
        """Slots ``slots`` ([N] bool or [k] long) start a new episode: their agents are new, so no velocity
        comes from the old episode's positions."""
        self.seen[slots] = False
        self.prev[slots] = self.env.agents.pos[slots]

    def people(self, active: torch.Tensor, pose: torch.Tensor, ranges: torch.Tensor) -> People:
        """What the tracker reports this step for the running slots ``active`` [k] at ``pose`` [k, 3] with their
        scans ``ranges`` [k, B]; a diagnostic overrides it for another prediction (scripts/agent_shield.py)."""
        env = self.env
        pos, radius, on = env.agents.pos[active], env.agents.radius[active], env.agents.active[active]
        seen = self.view.seen_by(pose, pos, radius, on, ranges)
        velocity = torch.where((seen & self.seen[active])[..., None], (pos - self.prev[active]) / env.preset.episode.dt,
                               torch.zeros_like(pos))
        self.prev[active], self.seen[active] = pos, seen
        return People(pos, velocity, radius, seen)


def robot_command(shield: PeopleShield, action, pose, people_rows, angles, ranges) -> tuple[float, float, bool, list]:
    """The shield on a robot, one control step (:class:`flashnav.deploy.controller.Controller` ``shield=``; numpy in,
    plain numbers out, so the controller itself stays free of torch): the policy's ``action`` [2] in [-1, 1] at
    odometry ``pose`` (x, y, yaw), the tracker's ``people_rows`` [M, 5] (x, y, vx, vy, radius in the odometry frame)
    and the scan as ``angles`` [B] (radians from the heading) and ``ranges`` [B] m (``inf``: no return, NaN: not
    valid). Returns (v m/s, w rad/s, whether the shield took over (:meth:`PeopleShield.filter`), the action played).
    The scan enters as the simulator's shield sees it (the nearest hit of each group of ``SCAN_GROUP`` beams), less
    the points farther than the footprint can reach within the look-ahead (``PeopleShield.reach``), which no rollout
    can touch: a step that takes over costs one to a few tens of milliseconds on one CPU thread, not hundreds."""
    import numpy as np

    rows = np.asarray(people_rows, np.float64).reshape(-1, 5)
    here = torch.tensor([pose], dtype=torch.float32)
    who = People(torch.tensor(rows[None, :, :2], dtype=torch.float32), torch.tensor(rows[None, :, 2:4], dtype=torch.float32),
                 torch.tensor(rows[None, :, 4], dtype=torch.float32), torch.ones(1, len(rows), dtype=torch.bool))
    r = np.asarray(ranges, np.float64).reshape(-1)
    r = torch.tensor(np.where(np.isfinite(r), r, np.inf)[None], dtype=torch.float32)
    a = torch.tensor(np.asarray(angles, np.float64).reshape(-1), dtype=torch.float32)
    # the simulator's points (scan_points); the shield tests only those within its reach (PeopleShield._near)
    walls = scan_points(here, r, a, math.inf, who, SCAN_GROUP if r.shape[1] % SCAN_GROUP == 0 else 1)
    walls = with_blind_sector(shield, walls, here, blind_edges(a))
    out, overruled = shield.filter(torch.tensor([list(action)], dtype=torch.float32), here, who, walls)
    v, w = action_to_velocity(out, shield.preset.motion)
    return float(v[0]), float(w[0]), bool(overruled[0]), [float(a) for a in out[0]]
