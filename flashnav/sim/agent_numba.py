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
    (:meth:`flashnav.sim.agents.AgentWorld.segment_clear`, the same float64 lookups), stopping at the
    first sample that fails.

    Args:
        a, b: [P, 2] float32 / float64 metres; radius: [P]; maps: [P] int64 map indices.
        samples: [S] float64 fractions along the segment (0 ... 1).
        clear: flat float64 clearance (metres) of every map; offset, wp, hp: [M] int64 per map;
        origin: [M, 2] float64 metres; res: [M] float64; pad: cells around each map.
        out: [P] bool, written.
    """
    n_seg = a.shape[0]
    n_s = samples.shape[0]
    for i in range(n_seg):
        m = maps[i]
        ax = np.float64(a[i, 0])
        ay = np.float64(a[i, 1])
        dx = np.float64(b[i, 0]) - ax
        dy = np.float64(b[i, 1]) - ay
        need = np.float64(radius[i]) + 0.5 * math.sqrt(dx * dx + dy * dy) / (n_s - 1)
        ok = True
        for s in range(n_s):
            px = ax + dx * samples[s]
            py = ay + dy * samples[s]
            j = int(math.floor((px - origin[m, 0]) / res[m])) + pad
            k = int(math.floor((py - origin[m, 1]) / res[m])) + pad
            j = min(max(j, 0), wp[m] - 1)
            k = min(max(k, 0), hp[m] - 1)
            if clear[offset[m] + k * wp[m] + j] < need:
                ok = False
                break
        out[i] = ok
