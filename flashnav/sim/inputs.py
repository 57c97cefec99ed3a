"""Checks of what a caller hands the environment (poses, goals, actions): exact shapes and finite
values, with errors that name the input and the offending row."""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import torch

from flashnav.maps.grid import OccupancyMap
from flashnav.names import MAX_SEED
from flashnav.sim.mapset import check_map_index, outside_maps


def as_batch(device: torch.device, value, name: str, shape: tuple[int, int], layout: str,
             dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``value`` as ``dtype`` on ``device``, exactly ``shape``: no reshape, so [2, N] or a flat [2N] is an
    error rather than a silent scramble of the rows. Detached: a network's output stepped without
    ``torch.no_grad()`` would otherwise chain its graph into the env's state, growing every step."""
    t = torch.as_tensor(value, device=device, dtype=dtype).detach()
    if tuple(t.shape) != shape:
        raise ValueError(f"{name} must have shape [{layout}] = {list(shape)}, got {list(t.shape)}")
    return t


def check_finite(value: torch.Tensor, name: str) -> None:
    """ValueError naming ``name`` and the first row holding a NaN or an infinity (if any)."""
    rows = (~torch.isfinite(value)).any(dim=1).nonzero()
    if rows.numel():
        row = int(rows[0, 0])
        raise ValueError(f"{name}[{row}] = {value[row].tolist()} is not finite (NaN or inf)")


def check_slots(idx: torch.Tensor, actions, num_envs: int) -> torch.Tensor:
    """``step_slots``' request checked; returns ``actions`` as a [k, 2] float32 batch on ``idx``'s device. A
    ValueError for ``idx`` not a 1-D integer tensor, holding a slot outside [0, ``num_envs``) or one slot twice (the
    slot would be advanced twice from the same state and written back in no defined order), and for ``actions`` of
    another shape or not finite."""
    if idx.ndim != 1 or idx.dtype.is_floating_point or idx.dtype == torch.bool or idx.is_complex():
        raise ValueError(f"idx must be a 1-D integer tensor of slot indices, got {idx.dtype} {list(idx.shape)}")
    actions = as_batch(idx.device, actions, "actions", (idx.numel(), 2), "len(idx), 2")
    s = idx.sort().values
    ok = torch.isfinite(actions).all() & ((idx >= 0) & (idx < num_envs)).all() & (s[1:] != s[:-1]).all()
    if not bool(ok):  # one host sync for all checks; the details only on failure
        check_finite(actions, "actions")
        bad = idx[(idx < 0) | (idx >= num_envs)]
        if bad.numel():
            raise ValueError(f"idx holds slot {int(bad[0])}, outside [0, {num_envs}) (num_envs = {num_envs})")
        twice = s[1:][s[1:] == s[:-1]]
        raise ValueError(f"idx holds slot {int(twice[0])} more than once (each slot advances at most once a step)")
    return actions


def check_state(grids: Sequence[OccupancyMap], pose, goal, map_index, current: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A ``NavVecEnv.set_state`` request checked: (pose [N, 3], goal [N, 2], both float64 world coordinates; the
    slots' map indices [N] long: ``map_index``, or the ``current`` ones where it is None). A ValueError names
    ``pose`` / ``goal`` / ``map_index`` for another shape, a NaN or infinite value, a map index out of range, a
    goal outside its map's extent (it could never be reached) or a robot outside it."""
    n, device = len(current), current.device
    pose = as_batch(device, pose, "pose", (n, 3), "x, y m, yaw rad", torch.float64)
    goal = as_batch(device, goal, "goal", (n, 2), "x, y m", torch.float64)
    mi = current if map_index is None else check_map_index(map_index, n, len(grids), device)
    # goals and robots in one pass (world coordinates, before the frame shift): a goal off its map could never be
    # reached, a robot off it is a caller's slip, not a test of walls
    outside, off_map = outside_maps(grids, torch.cat([goal, pose[:, :2]]), mi.repeat(2)).split(n)
    in_range = ((mi >= 0) & (mi < len(grids))).all()
    ok = torch.isfinite(pose).all() & torch.isfinite(goal).all() & ~outside.any() & ~off_map.any() & in_range
    if not bool(ok):  # one host sync for all checks; the details only on failure
        check_finite(pose, "pose")
        check_finite(goal, "goal")
        check_map_index(mi.cpu(), n, len(grids), torch.device("cpu"))
        name, values, bad = ("goal", goal, outside) if outside.any() else ("pose", pose, off_map)
        row = int(bad.nonzero()[0, 0])
        g = grids[int(mi[row])]
        xmin, ymin, xmax, ymax = g.bounds
        raise ValueError(f"{name}[{row}] = {values[row].tolist()} lies outside the map {g.name!r} "
                         f"(x in [{xmin:g}, {xmax:g}] m, y in [{ymin:g}, {ymax:g}] m)")
    return pose, goal, mi


def check_seed(seed, name: str = "seed") -> int:
    """``seed`` as an int: an integer (numpy's too) in [0, :data:`MAX_SEED`]; a float, string or bool is a
    TypeError naming ``name`` (``1.9`` was once taken as 1), a value out of range a ValueError."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {type(seed).__name__} {seed!r}")
    if not 0 <= int(seed) <= MAX_SEED:
        raise ValueError(f"{name} must be in [0, 2**63 - 1], got {seed}")
    return int(seed)


def check_num_envs(num_envs) -> int:
    """``num_envs`` as an int >= 1 (numpy's integers too); another type a TypeError, fewer a ValueError."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, numbers.Integral):
        raise TypeError(f"num_envs must be an integer, got {type(num_envs).__name__} {num_envs!r}")
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    return int(num_envs)
