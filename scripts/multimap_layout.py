"""Many maps in one batched env: one flat buffer with per-map offsets (what FlashNav uses) against a
stack of the maps padded to a common shape, for the raycasters that read them.

Both layouts run through the same kernels (the numba "exact" kernel and the torch "exact-torch"
raycaster take per-map offsets and plane shapes; a stack is the case of equal planes at a fixed
stride), on the same poses, alternating, so their ratio holds on a busy machine. The ranges must be
equal. For the numba kernel it also times casting the poses in slot order instead of grouped by map
(the cache effect of reading many maps' fields at once). Usage::

    python scripts/multimap_layout.py [--maps 64] [--envs 1024] [--repeats 7] [--torch-envs 64]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from flashnav.maps.generate import generate_map
from flashnav.sim.env import beam_angles
from flashnav.sim.raycast import NumbaExactRaycaster, random_free_poses
from flashnav.sim.raycast_base import JUMP_MIN_CELLS, PAD
from flashnav.sim.raycast_torch import TorchExactRaycaster


def make_maps(count: int) -> list:
    """Maps of different sizes (6-20 m a side) at 0.05 m: every one keeps the 32-sector field, so a
    stack of them is well defined."""
    rng = np.random.default_rng(0)
    return [generate_map(float(rng.uniform(6, 20)), float(rng.uniform(6, 20)), 0.05, seed=2000 + i,
                         robot_radius=0.3, name=f"m{i}") for i in range(count)]


def stack_numba(rc: NumbaExactRaycaster) -> dict:
    """The numba raycaster's buffers re-laid as a stack [M, S, Hp_max, Wp_max] (0 = occupied fill)."""
    m = len(rc.grids)
    s, hp, wp = int(rc._sectors.max()), int(rc._hps.max()), int(rc._wps.max())
    assert (rc._sectors == s).all(), "a stack needs the same number of sectors for every map"
    stack = np.zeros((m, s, hp, wp), dtype=np.uint8)
    for i in range(m):
        size = s * rc._hps[i] * rc._wps[i]
        field = rc._field[rc._base0[i]: rc._base0[i] + size].reshape(s, rc._hps[i], rc._wps[i])
        stack[i, :, : rc._hps[i], : rc._wps[i]] = field
    return {"_field": stack.reshape(-1), "_base0": np.arange(m, dtype=np.int64) * s * hp * wp,
            "_hps": np.full(m, hp, dtype=np.int64), "_wps": np.full(m, wp, dtype=np.int64)}


def stack_torch(rc: TorchExactRaycaster) -> dict:
    """The torch raycaster's buffers re-laid as stacks (fields [M, S, Hp, Wp], occupancy [M, Hp, Wp])."""
    maps = rc._maps
    m, s = len(rc.grids), int(maps["sectors"].max())
    hp, wp = int(maps["hp"].max()), int(maps["wp"].max())
    cone = torch.zeros(m, s, hp, wp, dtype=torch.uint8)
    occ = torch.ones(m, hp, wp, dtype=torch.bool)
    for i in range(m):
        h_i, w_i = int(maps["hp"][i]), int(maps["wp"][i])
        c0, o0 = int(maps["cone_base"][i]), int(maps["occ_base"][i])
        cone[i, :, :h_i, :w_i] = rc._cone[c0: c0 + s * h_i * w_i].view(s, h_i, w_i)
        occ[i, :h_i, :w_i] = rc._flat[o0: o0 + h_i * w_i].view(h_i, w_i)
    stacked = dict(maps, hp=torch.full_like(maps["hp"], hp), wp=torch.full_like(maps["wp"], wp),
                   cone_base=torch.arange(m) * s * hp * wp, occ_base=torch.arange(m) * hp * wp)
    return {"_cone": cone.reshape(-1), "_flat": occ.reshape(-1), "_maps": stacked}


def timed(rc, layouts: dict, pose, mi, repeats: int) -> dict[str, list[float]]:
    """Seconds per call of ``rc(pose, mi)`` under each layout (attributes swapped in), alternating."""
    times: dict[str, list[float]] = {name: [] for name in layouts}
    results = {}
    for _ in range(repeats):
        for name, attrs in layouts.items():
            for key, value in attrs.items():
                setattr(rc, key, value)
            t0 = time.perf_counter()
            results[name] = rc(pose, mi)
            times[name].append(time.perf_counter() - t0)
    first, *others = results.values()
    for other in others:
        assert torch.equal(first, other), "the layouts disagree"
    return times


def timed_kernel(rc: NumbaExactRaycaster, layouts: dict, pose, mi, repeats: int) -> dict[str, list[float]]:
    """Seconds per call of the numba kernel itself per (layout, cast order), alternating: "flat"
    (FlashNav: flat buffer, poses grouped by map), "flat, slot order" (poses in slot order) and
    "stack" (grouped)."""
    p, m = pose.numpy(), mi.numpy()
    grouped, slots = np.argsort(m, kind="stable"), np.arange(len(m), dtype=np.int64)
    ways = {"flat": (layouts["flat"], grouped), "flat, slot order": (layouts["flat"], slots),
            "stack": (layouts["stack"], grouped)}
    times: dict[str, list[float]] = {name: [] for name in ways}
    outs = {}
    for _ in range(repeats):
        for name, (lay, order) in ways.items():
            out = np.empty((len(m), rc._cos_a.shape[0]), dtype=np.float32)
            t0 = time.perf_counter()
            rc._kernel(p, m, order, rc._cos_a, rc._sin_a, rc._angles, lay["_field"], lay["_base0"], rc._sectors,
                       rc._hs, rc._ws, lay["_hps"], lay["_wps"], rc._ox, rc._oy, rc._res, PAD, rc.max_range,
                       JUMP_MIN_CELLS, out)
            times[name].append(time.perf_counter() - t0)
            outs[name] = out
    first, *others = outs.values()
    for other in others:
        assert np.array_equal(first, other), "the layouts disagree"
    return times


def report(title: str, times: dict[str, list[float]], nbytes: dict[str, int]) -> None:
    print(title)
    base = statistics.median(times["flat"])
    for name, values in times.items():
        med = statistics.median(values)
        print(f"  {name:16s}: median {med * 1e3:8.2f} ms, min {min(values) * 1e3:8.2f} ms per call "
              f"({med / base:.3f}x the flat layout's time), buffer {nbytes[name] / 2**20:.1f} MiB")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--maps", type=int, default=64)
    p.add_argument("--envs", type=int, default=1024)
    p.add_argument("--torch-envs", type=int, default=64)
    p.add_argument("--repeats", type=int, default=7)
    a = p.parse_args()
    grids = make_maps(a.maps)
    angles = beam_angles(270, 1080)
    gen = torch.Generator().manual_seed(0)
    mi = torch.randint(a.maps, (a.envs,), generator=gen)
    pose = torch.empty(a.envs, 3)
    for i in range(a.maps):
        sel = (mi == i).nonzero().squeeze(1)
        if len(sel):
            pose[sel] = random_free_poses(grids[i], len(sel), generator=gen)
    print(f"{a.maps} maps, sides {min(min(g.shape) for g in grids)}-{max(max(g.shape) for g in grids)} cells; "
          f"load average {open('/proc/loadavg').read().split()[:3]}")

    rc = NumbaExactRaycaster(grids, angles, 20.0)
    flat = {k: getattr(rc, k) for k in ("_field", "_base0", "_hps", "_wps")}
    stack = stack_numba(rc)
    rc(pose[:8], mi[:8])  # compile
    size = {"flat": flat["_field"].nbytes, "stack": stack["_field"].nbytes}
    size["flat, slot order"] = size["flat"]
    report(f"numba exact kernel, {a.envs} envs x 1080 beams",
           timed_kernel(rc, {"flat": flat, "stack": stack}, pose, mi, a.repeats), size)

    trc = TorchExactRaycaster(grids, angles, 20.0)
    flat_t = {k: getattr(trc, k) for k in ("_cone", "_flat", "_maps")}
    stack_t = stack_torch(trc)
    n = a.torch_envs
    size = lambda d: d["_cone"].numel() + d["_flat"].numel()  # noqa: E731  (one byte per element)
    report(f"exact-torch (CPU), {n} envs x 1080 beams",
           timed(trc, {"flat": flat_t, "stack": stack_t}, pose[:n], mi[:n], a.repeats),
           {"flat": size(flat_t), "stack": size(stack_t)})


if __name__ == "__main__":
    main()
