"""Exact geometry between the robot and moving disc agents: LiDAR beams against discs, and the robot's
footprint against discs. Torch ops on any device (the GPU path); the CPU path of the beams is the
numba kernel :mod:`flashnav.sim.agent_numba`, which computes the same thing. Both are float64 inside.

Beams (semantics shared with the numba kernel)
----------------------------------------------
A beam from pose (x, y, yaw) at beam angle a is the ray ``o + t d``, d the unit vector at yaw + a.
Against a disc of centre c and radius r, with ``g = R(-yaw) (o - c)`` (the offset in the robot's
frame, where d is (cos a, sin a)), ``b = g . (cos a, sin a)`` and ``h = g x (cos a, sin a)`` the
signed distance from c to the ray's line (a cross product: no cancellation at tangency):

- ``|f| <= r`` (the sensor inside or on the disc): range 0 for every beam;
- else the beam hits when ``b <= 0`` (the disc lies ahead) and ``|h| <= r + TANGENT_EPS``, at
  ``t = -b - sqrt(max(r^2 - h^2, 0))``: touching counts, as it does for walls, and the tolerance makes
  a beam meant to be tangent hit in any rounding;
- ranges are ``min(static range, nearest disc hit)``, so a disc behind a wall changes nothing and
  one overlapping a wall is seen wherever it is nearer.

Footprint collision (touching is not a collision, as with walls)
----------------------------------------------------------------
- disc robot of radius R: ``|p - c| < R + r``;
- oriented rectangle (length along the heading, width across): the distance from c to the
  rectangle, measured in the robot's frame, ``< r``.
"""

from __future__ import annotations

import torch

from flashnav.config import Footprint

#: metres: a beam passing within r + TANGENT_EPS of a disc's centre hits it (exact tangents hit)
TANGENT_EPS = 1e-9


def ray_disc_ranges(pose: torch.Tensor, cos_a: torch.Tensor, sin_a: torch.Tensor, centres: torch.Tensor,
                    radii: torch.Tensor, active: torch.Tensor, max_range: float) -> torch.Tensor:
    """[n, B] float64 metres: the nearest disc hit per beam, ``max_range`` where none (see the module
    docstring). ``pose`` [n, 3] (x m, y m, yaw rad), ``cos_a`` / ``sin_a`` [B] float64, ``centres``
    [n, K, 2] metres, ``radii`` [n, K] metres, ``active`` [n, K] bool (inactive discs are absent).
    One [n, B] pass per agent: memory stays n x B whatever K is."""
    p = pose.double()
    cy, sy = torch.cos(p[:, 2:3]), torch.sin(p[:, 2:3])
    best = torch.full((p.shape[0], cos_a.numel()), float(max_range), dtype=torch.float64, device=p.device)
    for j in range(centres.shape[1]):
        fx = p[:, 0:1] - centres[:, j, 0:1].double()  # [n, 1], world frame
        fy = p[:, 1:2] - centres[:, j, 1:2].double()
        gx, gy = cy * fx + sy * fy, cy * fy - sy * fx  # the robot's frame
        r = radii[:, j:j + 1].double()
        b = gx * cos_a + gy * sin_a  # [n, B]
        h = gx * sin_a - gy * cos_a
        t = -b - torch.sqrt((r * r - h * h).clamp(min=0.0))
        hit = (b <= 0) & (h * h <= (r + TANGENT_EPS) ** 2)
        inside = fx * fx + fy * fy <= r * r  # [n, 1]
        t = torch.where(inside, torch.zeros_like(t), t)
        use = active[:, j:j + 1] & (hit | inside)
        best = torch.where(use, torch.minimum(best, t), best)
    return best


def footprint_hits_discs(pose: torch.Tensor, footprint: Footprint, centres: torch.Tensor, radii: torch.Tensor,
                         active: torch.Tensor) -> torch.Tensor:
    """[n] bool: the footprint at ``pose`` [n, 3] overlaps some active disc (``centres`` [n, K, 2] m,
    ``radii`` [n, K] m, ``active`` [n, K] bool); touching is not a collision. float64 inside. Leading
    dimensions broadcast: ``pose`` [..., 3] against ``centres`` [..., K, 2], ``radii`` and ``active`` [..., K]
    give [...] (the people shield's rollouts [E, C, L] against discs per step [E, 1, L, K] or fixed [E, 1, 1, K]
    without copying either)."""
    p = pose.double()
    ddx = centres[..., 0].double() - p[..., 0:1]  # [..., K]
    ddy = centres[..., 1].double() - p[..., 1:2]
    r = radii.double()
    if footprint.kind == "disc":
        reach = footprint.radius + r
        touch = ddx * ddx + ddy * ddy < reach * reach
    else:
        c, s = torch.cos(p[..., 2:3]), torch.sin(p[..., 2:3])
        lx, ly = ddx * c + ddy * s, ddy * c - ddx * s  # the disc centre in the robot's frame
        gx = (lx.abs() - 0.5 * footprint.length).clamp(min=0.0)
        gy = (ly.abs() - 0.5 * footprint.width).clamp(min=0.0)
        touch = gx * gx + gy * gy < r * r
    return (touch & active).any(dim=-1)


def footprint_disc_gap(pose: torch.Tensor, footprint: Footprint, centres: torch.Tensor, radii: torch.Tensor,
                       active: torch.Tensor) -> torch.Tensor:
    """[n] float32: the smallest gap (m) between the footprint at ``pose`` [n, 3] and an active disc
    (arguments as :func:`footprint_hits_discs`); 0 where they overlap, inf where no disc is active."""
    p = pose.double()
    ddx = centres[..., 0].double() - p[:, 0:1]  # [n, K]
    ddy = centres[..., 1].double() - p[:, 1:2]
    if footprint.kind == "disc":
        gap = torch.sqrt(ddx * ddx + ddy * ddy) - footprint.radius
    else:
        c, s = torch.cos(p[:, 2:3]), torch.sin(p[:, 2:3])
        lx, ly = ddx * c + ddy * s, ddy * c - ddx * s  # the disc centre in the robot's frame
        gx = (lx.abs() - 0.5 * footprint.length).clamp(min=0.0)
        gy = (ly.abs() - 0.5 * footprint.width).clamp(min=0.0)
        gap = torch.sqrt(gx * gx + gy * gy)
    gap = (gap - radii.double()).clamp(min=0.0)
    gap = torch.where(active, gap, torch.full_like(gap, float("inf")))
    return gap.min(dim=1).values.float()
