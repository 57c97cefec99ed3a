"""The numba builder of the directional safe-distance field (:func:`flashnav.maps.fields.cone_field`,
which caches it per map; nothing else should call this module).

The circle of directions is cut into S sectors. For sector s and cell c, D_s(c) is a lower bound on
how far *any* ray starting in the closed cell c with a direction in sector s travels before touching
an occupied square. With cell centres on the integer lattice and an occupied cell q at offset
dq = q - c, such a ray meets q no earlier than
``g_s(dq) = min |w| over w in (dq + [-1, 1]^2) intersected with the closed cone of sector s``
(P in c and Q in q give Q - P in dq + [-1, 1]^2), so D_s(c) = min over occupied q of g_s(q - c): a
min-convolution with a fixed kernel, computed by scanning the kernel's offsets in order of g_s and
stopping at the first occupied one. Unlike an isotropic distance field, obstacles beside or behind
the ray do not limit the jump. D_s >= the isotropic bound, and a ray jumping by D_s - DELTA lands
clear of every occupied square, so no cell needs checking there.

The field is uint8 [S, H + 2 pad, W + 2 pad]: 0 = occupied, else 1 + floor(2 D) (half cells, capped
at ``reach`` cells), so one byte per lookup answers both "hit?" and "how far may I jump?". Building
it takes ~0.2 s for a 200 x 200 map (up to ~2 s for large open ones).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

ANGLE_MARGIN = 1e-7  # rad: sectors are widened by this so float sector assignment is always safe


# ---- the kernel: per sector, offsets sorted by their gap ----------------------------------------
@njit(cache=True)
def _cone_gap(cx, cy, a0, a1):
    """min |w| over w in ([cx-1, cx+1] x [cy-1, cy+1]) intersected with the cone a0 <= angle <= a1
    (a1 - a0 < pi); inf if they do not meet. Clips the square by the cone's two half-planes
    (Sutherland-Hodgman) and takes the distance from the origin to the clipped polygon."""
    if abs(cx) <= 1.0 and abs(cy) <= 1.0:
        return 0.0
    px = np.empty(12)
    py = np.empty(12)
    qx = np.empty(12)
    qy = np.empty(12)
    px[0], py[0], px[1], py[1] = cx - 1.0, cy - 1.0, cx + 1.0, cy - 1.0
    px[2], py[2], px[3], py[3] = cx + 1.0, cy + 1.0, cx - 1.0, cy + 1.0
    n = 4
    for half in range(2):  # keep w . normal >= 0: left of direction a0, right of direction a1
        nx, ny = (-math.sin(a0), math.cos(a0)) if half == 0 else (math.sin(a1), -math.cos(a1))
        m = 0
        for k in range(n):
            ax, ay, bx, by = px[k], py[k], px[(k + 1) % n], py[(k + 1) % n]
            da, db = ax * nx + ay * ny, bx * nx + by * ny
            if da >= 0.0:
                qx[m], qy[m] = ax, ay
                m += 1
            if (da >= 0.0) != (db >= 0.0):
                f = da / (da - db)
                qx[m], qy[m] = ax + f * (bx - ax), ay + f * (by - ay)
                m += 1
        n = m
        if n == 0:
            return np.inf
        px[:n], py[:n] = qx[:n], qy[:n]
    best = np.inf
    for k in range(n):
        ax, ay, bx, by = px[k], py[k], px[(k + 1) % n], py[(k + 1) % n]
        ex, ey = bx - ax, by - ay
        ee = ex * ex + ey * ey
        f = 0.0 if ee == 0.0 else min(1.0, max(0.0, -(ax * ex + ay * ey) / ee))
        best = min(best, math.hypot(ax + f * ex, ay + f * ey))
    return best


@njit(cache=True)
def _sector_gaps(s, sectors, reach):
    """All offsets (di, dj) with g_s < reach for sector s: (gaps, di, dj), unsorted."""
    a0 = 2.0 * math.pi * s / sectors - ANGLE_MARGIN
    a1 = 2.0 * math.pi * (s + 1) / sectors + ANGLE_MARGIN
    side = 2 * (reach + 1) + 1
    g = np.empty(side * side)
    di = np.empty(side * side, np.int64)
    dj = np.empty(side * side, np.int64)
    m = 0
    for i in range(-reach - 1, reach + 2):
        for j in range(-reach - 1, reach + 2):
            d = _cone_gap(float(j), float(i), a0, a1)
            if d < reach:
                g[m], di[m], dj[m] = d, i, j
                m += 1
    return g[:m], di[:m], dj[:m]


_KERNELS: dict = {}


def cone_kernel(sectors: int, reach: int):
    """Per sector, the offsets with g_s < reach sorted by g_s: (gaps [S, M] float64 (inf-padded),
    row offsets [S, M], column offsets [S, M], counts [S])."""
    key = (sectors, reach)
    if key not in _KERNELS:
        parts = []
        for s in range(sectors):
            g, di, dj = _sector_gaps(s, sectors, reach)
            order = np.argsort(g, kind="stable")
            parts.append((g[order], di[order], dj[order]))
        m = max(len(p[0]) for p in parts)
        gaps = np.full((sectors, m), np.inf)
        di = np.zeros((sectors, m), np.int64)
        dj = np.zeros((sectors, m), np.int64)
        for s, (g, a, b) in enumerate(parts):
            gaps[s, : len(g)], di[s, : len(g)], dj[s, : len(g)] = g, a, b
        _KERNELS[key] = (gaps, di, dj, np.array([len(p[0]) for p in parts], np.int64))
    return _KERNELS[key]


@njit(parallel=True, cache=True)
def _cone_field(occ, iso, gaps, di, dj, counts, reach):
    sectors = counts.shape[0]
    h, w = occ.shape
    out = np.empty((sectors, h, w), np.uint8)
    for p in prange(sectors * h):
        s = p // h
        i = p - s * h
        g = gaps[s, : counts[s]]
        for j in range(w):
            if occ[i, j]:
                out[s, i, j] = 0
                continue
            d = float(reach)
            # offsets nearer than the isotropic distance are free: start the scan past them
            for k in range(np.searchsorted(g, iso[i, j]), counts[s]):
                ii = i + di[s, k]
                jj = j + dj[s, k]
                # off the padded array counts as occupied (conservative; rays cross the pad first)
                if ii < 0 or ii >= h or jj < 0 or jj >= w or occ[ii, jj]:
                    d = g[k]
                    break
            out[s, i, j] = 1 + min(int(math.floor(2.0 * d)), 2 * reach)
    return out


def build_cone_field(occ: np.ndarray, iso: np.ndarray, sectors: int, reach: int) -> np.ndarray:
    """[S, H, W] uint8 cone field of the padded occupancy ``occ`` [H, W] bool, given its
    :func:`flashnav.maps.fields.iso_field` ``iso`` [H, W] float64 cells (see the module docstring)."""
    return _cone_field(occ, iso, *cone_kernel(sectors, reach), reach)
