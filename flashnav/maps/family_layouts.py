"""The layouts of :mod:`flashnav.maps.families`: one function per family, drawing on a
:class:`~flashnav.maps.canvas.Canvas` with a seeded generator. Every passage is ``canvas.gap()``
wide or wider; loose furniture goes through ``canvas.scatter`` (which keeps it clear of passages)."""

from __future__ import annotations

import math

import numpy as np

from flashnav.maps.canvas import WALL, Canvas


def _split(rng: np.random.Generator, lo: float, hi: float, widths: tuple[float, float], least: float) -> list[float]:
    """Cut [lo, hi] at random widths drawn in ``widths``; no piece narrower than ``least`` (a short
    last piece joins the one before). Returns the cut positions, ends included."""
    cuts = [lo]
    while hi - cuts[-1] > widths[1]:
        cuts.append(cuts[-1] + rng.uniform(*widths))
    cuts.append(hi)
    if len(cuts) > 2 and cuts[-1] - cuts[-2] < least:
        del cuts[-2]
    return cuts


def _room_row(c: Canvas, rng, x0: float, x1: float, y0: float, y1: float, door_y: tuple[float, float], t: float,
              widths=(2.5, 5.0), p_inner_door=0.3) -> None:
    """Rooms side by side in [x0, x1] x [y0, y1], separated by walls of thickness ``t``; each gets a
    door through the wall that spans ``door_y`` (the wall between the row and its corridor)."""
    door = c.gap()
    cuts = _split(rng, x0, x1, widths, door + 2 * t + 2 * c.res)
    for k in range(1, len(cuts) - 1):  # walls between rooms
        c.rect(cuts[k], y0, cuts[k] + t, y1)
        if rng.random() < p_inner_door and y1 - y0 > door + 2 * t + 2 * c.res:
            yd = rng.uniform(y0 + t + c.res, y1 - t - c.res - door)
            c.rect(cuts[k] - c.res, yd, cuts[k] + t + c.res, yd + door, value=False)
    for k in range(len(cuts) - 1):
        a, b = cuts[k] + (t if k else 0.0) + c.res, cuts[k + 1] - c.res
        width = door + rng.uniform(0.1, 0.4)
        xd = rng.uniform(a, max(b - width, a))
        c.rect(xd, door_y[0] - c.res, min(xd + width, b), door_y[1] + c.res, value=False)


def rooms(c: Canvas, rng: np.random.Generator) -> None:
    """Blocks of [rooms | corridor | rooms] stacked in y, a spine corridor on one side joining the
    corridors, a door from every room onto its corridor."""
    t = rng.uniform(*WALL)
    b = c.border
    corridor = max(rng.uniform(1.2, 2.2), c.gap(0.2))
    spine_left = rng.random() < 0.5
    xs = b + corridor if spine_left else c.width - b - corridor - t  # the spine's wall
    c.rect(xs, b, xs + t, c.height - b)
    rx0, rx1 = (xs + t, c.width - b) if spine_left else (b, xs)
    least = c.gap(0.3)  # the shallowest room
    height = c.height - 2 * b
    depth = rng.uniform(2.5, 5.0)
    blocks = max(1, math.floor((height + t) / (2 * depth + corridor + 3 * t)))
    while blocks > 1 and (height - (blocks - 1) * t - blocks * (corridor + 2 * t)) / (2 * blocks) < least:
        blocks -= 1
    depth = (height - (blocks - 1) * t - blocks * (corridor + 2 * t)) / (2 * blocks)
    y = b
    for k in range(blocks):
        two_rows = depth >= least
        lower = depth if two_rows else 0.0
        upper = depth if two_rows else 2 * depth + t
        cy0 = y + lower + (t if two_rows else 0.0)  # the corridor
        if two_rows:
            c.rect(rx0, y + lower, rx1, y + lower + t)
            _room_row(c, rng, rx0, rx1, y, y + lower, (y + lower, y + lower + t), t)
        wy = cy0 + corridor
        c.rect(rx0, wy, rx1, wy + t)
        _room_row(c, rng, rx0, rx1, wy + t, wy + t + upper, (wy, wy + t), t)
        c.rect(xs - c.res, cy0, xs + t + c.res, cy0 + corridor, value=False)  # corridor meets spine
        y = wy + t + upper
        if k < blocks - 1:
            c.rect(rx0, y, rx1, y + t)
            y += t
    c.scatter(rng, count=int(c.width * c.height / 20), box=(0.4, 1.0), disc=(0.15, 0.35))


def offices(c: Canvas, rng: np.random.Generator) -> None:
    """An open-plan floor of desk islands between aisles, closed offices with doors along the top."""
    t = rng.uniform(*WALL)
    b = c.border
    top = c.height - b
    depth = rng.uniform(2.5, 4.0)
    if c.height - 2 * b - depth - t >= 3.0:  # room for a row of offices
        wy = top - depth - t
        c.rect(b, wy, c.width - b, wy + t)
        _room_row(c, rng, b, c.width - b, wy + t, top, (wy, wy + t), t, widths=(2.5, 4.0))
        top = wy
    desk_w, desk_d = rng.uniform(1.2, 1.6), rng.uniform(0.6, 0.8)
    iw, ih = desk_w * int(rng.integers(1, 4)), 2 * desk_d
    if rng.random() < 0.5:
        iw, ih = ih, iw
    aisle = c.gap(rng.uniform(0.2, 0.8))
    y = b + aisle
    while y + ih + aisle <= top:
        x = b + aisle
        while x + iw + aisle <= c.width - b:
            if rng.random() > 0.15:
                c.rect(x, y, x + iw, y + ih)
            x += iw + aisle
        y += ih + aisle
    c.scatter(rng, count=int(c.width * c.height / 25), box=(0.4, 0.9), disc=(0.2, 0.4), p_disc=0.5)


def halls(c: Canvas, rng: np.random.Generator) -> None:
    """A regular grid of pillars (square or round; a few missing) in an open hall, and benches."""
    b = c.border
    size = rng.uniform(0.3, 0.8)
    round_ = rng.random() < 0.5
    pitch = max(rng.uniform(2.5, 6.0), size + c.gap(0.3))
    first = b + c.gap(0.1) + size / 2
    ox, oy = first + rng.uniform(0, pitch / 2), first + rng.uniform(0, pitch / 2)
    for x in np.arange(ox, c.width - first + 1e-9, pitch):
        for y in np.arange(oy, c.height - first + 1e-9, pitch):
            if rng.random() < 0.1:
                continue
            if round_:
                c.disc(x, y, size / 2)
            else:
                c.rect(x - size / 2, y - size / 2, x + size / 2, y + size / 2)
    c.scatter(rng, count=int(c.width * c.height / 30), box=(0.4, 1.8), disc=(0.2, 0.5))


def warehouses(c: Canvas, rng: np.random.Generator) -> None:
    """Rows of shelving racks with aisles and cross aisles; a loading area of pallets and boxes."""
    b = c.border
    along_x = rng.random() < 0.5
    length, span = (c.width, c.height) if along_x else (c.height, c.width)

    def put(a0, c0, a1, c1):  # (along, across) -> the canvas
        c.rect(a0, c0, a1, c1) if along_x else c.rect(c0, a0, c1, a1)

    loading = rng.uniform(2.0, 4.0) if span > 12 else 0.0
    rack = rng.uniform(0.8, 1.2) * (2 if rng.random() < 0.7 else 1)  # double- or single-sided
    aisle = c.gap(rng.uniform(0.2, 1.0))
    cross = c.gap(rng.uniform(0.3, 1.0))
    row = b + loading + aisle
    while row + rack + aisle <= span - b:
        cuts = _split(rng, b + cross, length - b - cross, (4.0, 10.0), 1.0)
        for k in range(len(cuts) - 1):
            a0, a1 = cuts[k] + (cross if k else 0.0), cuts[k + 1]
            if a1 - a0 >= 0.5:
                put(a0, row, a1, row + rack)
        row += rack + aisle
    x1, y1 = (c.width, b + loading + aisle) if along_x else (b + loading + aisle, c.height)
    c.scatter(rng, count=int(c.width * c.height / 12), box=(0.8, 1.4), disc=(0.25, 0.35), p_disc=0.25)
    c.scatter(rng, count=int(c.width * c.height / 40), box=(0.8, 1.4), region=(0.0, 0.0, x1, y1))


def mazes(c: Canvas, rng: np.random.Generator) -> None:
    """A maze of narrow corridors: a random spanning tree of a grid of cells (depth-first), with a
    few extra openings that make loops."""
    t = rng.uniform(*WALL)
    b = c.border
    pitch = c.gap(rng.uniform(0.05, 0.5)) + t
    nx = max(1, math.floor((c.width - 2 * b - t) / pitch))
    ny = max(1, math.floor((c.height - 2 * b - t) / pitch))
    # walls: vertical[i, j] is at x = b + i pitch beside cell row j; horizontal[i, j] at y = b + j pitch
    vertical = np.ones((nx + 1, ny), dtype=bool)
    horizontal = np.ones((nx, ny + 1), dtype=bool)
    seen = np.zeros((nx, ny), dtype=bool)
    stack = [(int(rng.integers(nx)), int(rng.integers(ny)))]
    seen[stack[0]] = True
    while stack:
        i, j = stack[-1]
        nexts = [(i + di, j + dj) for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1))
                 if 0 <= i + di < nx and 0 <= j + dj < ny and not seen[i + di, j + dj]]
        if not nexts:
            stack.pop()
            continue
        ni, nj = nexts[int(rng.integers(len(nexts)))]
        if ni != i:
            vertical[max(i, ni), j] = False
        else:
            horizontal[i, max(j, nj)] = False
        seen[ni, nj] = True
        stack.append((ni, nj))
    vertical[1:-1] &= rng.random((nx - 1, ny)) > 0.08  # loops
    horizontal[:, 1:-1] &= rng.random((nx, ny - 1)) > 0.08
    for i, j in zip(*np.nonzero(vertical)):
        c.rect(b + i * pitch, b + j * pitch, b + i * pitch + t, b + (j + 1) * pitch + t)
    for i, j in zip(*np.nonzero(horizontal)):
        c.rect(b + i * pitch, b + j * pitch, b + (i + 1) * pitch + t, b + j * pitch + t)
    # the strips between the maze and the outer walls are solid
    c.rect(b + nx * pitch + t, 0, c.width, c.height)
    c.rect(0, b + ny * pitch + t, c.width, c.height)
