"""The CPU kernels of moving disc agents (numba): LiDAR beams against the discs, and the clearance
check of agents' legs.
Semantics: :mod:`flashnav.sim.agent_geometry` (this kernel and its torch path compute the same ranges).

Culling: a beam whose range so far is already <= D - r (a wall, or a nearer disc, in front of the
whole disc) is skipped before any arithmetic, and a disc at distance D from the sensor can only be hit by beams within ``asin((r + eps) / D)``
of the direction to its centre, and the beams are evenly spaced, so each disc tests only the beams of
that window (widened by CULL_MARGIN beams against rounding) instead of all of them: with 1,080 beams
over 270 deg a disc of 0.25 m at 3 m covers about 40 beams, so 8 agents cost ~300 ray-disc tests per
environment instead of 8,640. Each tested beam gets the exact test of the torch path. The window is
tried at the centre direction and at +-2 pi from it, so wrapping needs no special case (a beam seen
twice takes the same minimum).

Both kernels are serial: with the culling, 1,024 environments x 8 agents x 1,080 beams take ~2 ms on
one core of the 2-core dev CPU, and on that (shared, busy) machine a numba parallel launch measured
slower than the whole serial pass (8 ms against 2.3 ms).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from flashnav.sim.agent_geometry import TANGENT_EPS

#: beams added on each side of a disc's angular window: the window is computed in float64 from
#: float32 beam angles whose spacing is uniform only to rounding, and a beam outside it never hits
CULL_MARGIN = 2


@njit(cache=True, inline="always")
def _disc_window(out, n, cy, sy, yaw, cos_a, sin_a, a0, step, fx, fy, r, max_range):
    """Lower ``out[n, k]`` to the hit distance of the disc at offset ``f = o - c`` (world frame) and
    radius r, for the beams of its window."""
    k_beam = cos_a.shape[0]
    # f in the robot's frame: a beam's direction there is (cos a, sin a)
    gx = cy * fx + sy * fy
    gy = cy * fy - sy * fx
    dist = math.sqrt(fx * fx + fy * fy)
    reach = r + TANGENT_EPS
    half = math.pi / 2 if reach >= dist else math.asin(reach / dist)
    phi = math.atan2(-gy, -gx)  # direction to the centre, relative to the heading, in [-pi, pi]
    nearest = dist - r  # no hit of this disc is nearer
    if nearest >= max_range:
        return
    for shift in (-2.0 * math.pi, 0.0, 2.0 * math.pi):
        if step > 0.0:
            lo = int(math.floor((phi + shift - half - a0) / step)) - CULL_MARGIN
            hi = int(math.ceil((phi + shift + half - a0) / step)) + CULL_MARGIN
        else:  # a single beam
            lo, hi = 0, 0
        lo = max(lo, 0)
        hi = min(hi, k_beam - 1)
        for k in range(lo, hi + 1):
            if out[n, k] <= nearest:  # a wall (or a nearer disc) is in front of the whole disc
                continue
            b = gx * cos_a[k] + gy * sin_a[k]
            if b > 0.0:
                continue
            h = gx * sin_a[k] - gy * cos_a[k]  # signed distance from the centre to the beam's line
            if h * h > reach * reach:
                continue
            t = -b - math.sqrt(max(r * r - h * h, 0.0))
            if t < out[n, k] and t <= max_range:
                out[n, k] = t


@njit(cache=True)  # serial: see the module docstring
def lower_by_discs(pose, cos_a, sin_a, a0, step, centres, radii, active, max_range, out):
    """``out[n, k] = min(out[n, k], nearest disc hit of beam k of pose n)`` in place.

    Args:
        pose: [N, 3] float32 (x m, y m, yaw rad).
        cos_a, sin_a: [B] float64 cos / sin of the beam angles (rad, relative to the heading).
        a0, step: the first beam angle and the (uniform) spacing, radians; step 0 for a single beam.
        centres: [N, K, 2] float32 metres; radii: [N, K] float32 metres; active: [N, K] bool.
        max_range: metres (hits beyond it are not recorded).
        out: [N, B] float32 metres, the static ranges, lowered in place.
    """
    n_env = pose.shape[0]
    k_agents = centres.shape[1]
    k_beam = cos_a.shape[0]
    for n in range(n_env):
        ox = np.float64(pose[n, 0])
        oy = np.float64(pose[n, 1])
        yaw = np.float64(pose[n, 2])
        cy = math.cos(yaw)
        sy = math.sin(yaw)
        for j in range(k_agents):
            if not active[n, j]:
                continue
            cx = np.float64(centres[n, j, 0])
            cyc = np.float64(centres[n, j, 1])
            r = np.float64(radii[n, j])
            fx = ox - cx
            fy = oy - cyc
            if fx * fx + fy * fy <= r * r:  # the sensor inside the disc: every beam reads 0
                for k in range(k_beam):
                    out[n, k] = 0.0
                break
            _disc_window(out, n, cy, sy, yaw, cos_a, sin_a, a0, step, fx, fy, r, max_range)


@njit(cache=True)  # serial: a few thousand short segments, less than a thread launch is worth
def segments_clear(a, b, radius, maps, samples, clear, offset, origin, res, wp, hp, pad, out):
    """``out[i] = every sample of segment a[i] -> b[i] has clearance >= radius[i] + spacing / 2``
    (:meth:`flashnav.sim.agent_space.AgentSpace.segment_clear`, the same float64 lookups), stopping at the
    first sample that fails.

    Args:
        a, b: [P, 2] float32 / float64 metres; radius: [P]; maps: [P] int64 map indices.
        samples: [S] float64 fractions along the segment (0 ... 1).
        clear: flat float64 clearance (metres) of every map; offset, wp, hp: [M] int64 per map;
        origin: [M, 2] float64 metres; res: [M] float64; pad: cells around each map.
        out: [P] bool, written.
    """
    for i in range(a.shape[0]):
        out[i] = _leg_clear(np.float64(a[i, 0]), np.float64(a[i, 1]), np.float64(b[i, 0]), np.float64(b[i, 1]),
                            np.float64(radius[i]), maps[i], samples, clear, offset, origin, res, wp, hp, pad)


@njit(cache=True, inline="always")
def _clearance(x, y, m, clear, offset, origin, res, wp, hp, pad):
    """The clearance lower bound (metres) of the cell holding (x, y) on map m (AgentWorld.clearance)."""
    j = int(math.floor((x - origin[m, 0]) / res[m])) + pad
    k = int(math.floor((y - origin[m, 1]) / res[m])) + pad
    j = min(max(j, 0), wp[m] - 1)
    k = min(max(k, 0), hp[m] - 1)
    return clear[offset[m] + k * wp[m] + j]


@njit(cache=True, inline="always")
def _lsr(x, s):
    return (x >> np.int64(s)) & np.int64((1 << (64 - s)) - 1)


@njit(cache=True)
def hash_uniform(key, step, agent, lane):
    """The float32 uniform of :func:`flashnav.sim.agent_draws.hash_uniform` for one (key, step, agent, lane)."""
    x = (np.int64(key) * np.int64(-7046029254386353131) + np.int64(step) * np.int64(1442695040888963407)
         + np.int64(agent) * np.int64(6364136223846793005) + np.int64(lane))
    x = (x ^ _lsr(x, 30)) * np.int64(-4658895280553007687)
    x = (x ^ _lsr(x, 27)) * np.int64(-7723592293110705685)
    x = x ^ _lsr(x, 31)
    return np.float32(_lsr(x, 40)) * np.float32(1.0 / (1 << 24))


@njit(cache=True)
def _leg_clear(ax, ay, bx, by, r, m, samples, clear, offset, origin, res, wp, hp, pad):
    """Whether every sample of the segment (ax, ay) -> (bx, by) (float64 metres, on map m) has
    clearance >= r + half the sample spacing; stops at the first sample that fails."""
    dx = bx - ax
    dy = by - ay
    need = r + 0.5 * math.sqrt(dx * dx + dy * dy) / (samples.shape[0] - 1)
    for s in range(samples.shape[0]):
        if _clearance(ax + dx * samples[s], ay + dy * samples[s], m, clear, offset, origin, res, wp, hp, pad) < need:
            return False
    return True


@njit(cache=True)
def step_agents(slots, robot, steps, maps, pos, vel, target, final, radius, speed, kind, reactive, placed, active,
                appear, key, clear, offset, origin, res, wp, hp, pad, samples, consts):
    """One step of the agents of ``slots`` [k] (AgentWorld.step's semantics, in place on the [N, K]
    state arrays), ``robot`` [k, 3] / ``steps`` [k] / ``maps`` [k] of those slots. ``consts``: dt,
    robot radius, spawn clearance, reactive distance (0 = off), reactive cos, leg length min and max,
    leg candidates, arrival distance, crossings on (1.0 / 0.0)."""
    dt, r_robot, spawn, react_d, react_cos = consts[0], consts[1], consts[2], consts[3], consts[4]
    leg_lo, leg_hi, cands, arrived_eps, crossings = consts[5], consts[6], int(consts[7]), consts[8], consts[9]
    for i in range(slots.shape[0]):
        n = slots[i]
        m = maps[i]
        rx = np.float64(robot[i, 0])
        ry = np.float64(robot[i, 1])
        for j in range(pos.shape[1]):
            r = np.float64(radius[n, j])
            px = np.float64(pos[n, j, 0])
            py = np.float64(pos[n, j, 1])
            if crossings > 0 and placed[n, j] and not active[n, j] and steps[i] >= appear[n, j]:
                if math.sqrt((px - rx) ** 2 + (py - ry) ** 2) >= r + r_robot + spawn:
                    active[n, j] = True
            if not active[n, j]:
                continue
            sp = np.float64(speed[n, j])
            walker = kind[n, j] != 1
            if walker:
                tx = np.float64(target[n, j, 0]) - px
                ty = np.float64(target[n, j, 1]) - py
                rem = math.sqrt(tx * tx + ty * ty)
                dx = tx / max(rem, 1e-9)
                dy = ty / max(rem, 1e-9)
            else:
                dx = np.float64(vel[n, j, 0]) / max(sp, 1e-9)
                dy = np.float64(vel[n, j, 1]) / max(sp, 1e-9)
            length = sp * dt
            if react_d > 0 and reactive[n, j]:
                ox = rx - px
                oy = ry - py
                d = math.sqrt(ox * ox + oy * oy)
                if ox * dx + oy * dy >= react_cos * d:
                    length *= min(max((d - r - r_robot) / react_d, 0.0), 1.0)
            if walker:
                length = min(length, rem)
            nx = np.float32(px + dx * length)
            ny = np.float32(py + dy * length)
            ok = _clearance(np.float64(nx), np.float64(ny), m, clear, offset, origin, res, wp, hp, pad) >= r
            if not ok:
                nx = np.float32(px)
                ny = np.float32(py)
                if kind[n, j] == 1:  # bounce: reflect in x, in y, or reverse, the first that is clear
                    for fx, fy in ((-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)):
                        ax = np.float32(px + fx * dx * length)
                        ay = np.float32(py + fy * dy * length)
                        if _clearance(np.float64(ax), np.float64(ay), m, clear, offset, origin, res, wp, hp, pad) >= r:
                            nx, ny = ax, ay
                            vel[n, j, 0] *= fx
                            vel[n, j, 1] *= fy
                            break
            pos[n, j, 0] = nx
            pos[n, j, 1] = ny
            px = np.float64(nx)
            py = np.float64(ny)
            arrived = math.sqrt((np.float64(target[n, j, 0]) - px) ** 2
                                + (np.float64(target[n, j, 1]) - py) ** 2) <= arrived_eps
            if crossings > 0 and arrived and kind[n, j] == 2:
                target[n, j, 0] = final[n, j, 0]
                target[n, j, 1] = final[n, j, 1]
            if kind[n, j] == 0 and (arrived or not ok):  # a new leg: the first clear candidate
                target[n, j, 0] = nx
                target[n, j, 1] = ny
                for c in range(cands):
                    u0 = hash_uniform(key[n], steps[i], j, 2 * c)
                    u1 = hash_uniform(key[n], steps[i], j, 2 * c + 1)
                    angle = np.float32((u0 * np.float32(2.0) - np.float32(1.0)) * np.float32(math.pi))
                    reach = np.float32(leg_lo + u1 * (leg_hi - leg_lo))
                    ex = np.float32(nx + reach * np.float32(math.cos(angle)))
                    ey = np.float32(ny + reach * np.float32(math.sin(angle)))
                    if (_leg_clear(px, py, np.float64(ex), np.float64(ey), r, m, samples, clear, offset, origin,
                                   res, wp, hp, pad)
                            and _clearance(np.float64(ex), np.float64(ey), m, clear, offset, origin, res, wp, hp,
                                           pad) >= r):
                        target[n, j, 0] = ex
                        target[n, j, 1] = ey
                        break
