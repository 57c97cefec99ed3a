"""Many maps in one batched env: the reset's episode sampling, one batch over all maps (MapSetSampler,
what the env uses) against the per-map loop it replaced (each map's EpisodeSampler for its group of
slots, written out here), and the one-map sampler for scale. By-hand timing to see where a step's
time goes, not a benchmark: the three run interleaved in one process, so their ratio holds on a busy
machine; print the load average beside the figures. Usage::

    python scripts/multimap_sampler.py [--maps 64] [--envs 1024] [--slots 15] [--repeats 400] [--threads 1]

``--slots`` is the number of slots that reset in one step (about 15 of 1,024 with random actions).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings

import torch

from flashnav.bench.sim import bench_maps
from flashnav.sim.env import make_env


def per_map_loop(samplers, maps: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """The replaced path: a host sync for the group sizes, then one sampler call per map drawn."""
    n = maps.numel()
    pose, goal = torch.empty(n, 3), torch.empty(n, 2)
    for m, count in enumerate(torch.bincount(maps, minlength=len(samplers)).tolist()):
        if count:
            group = (maps == m).nonzero().squeeze(1)
            pose[group], goal[group] = samplers[m].sample(count, gen)
    return pose, goal


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--maps", type=int, default=64)
    ap.add_argument("--envs", type=int, default=1024)
    ap.add_argument("--slots", type=int, default=15)
    ap.add_argument("--repeats", type=int, default=400)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(f"load average at the start: {os.getloadavg()}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # fallback notes of the generated maps
        many = make_env("turtlebot2", args.envs, maps=bench_maps("turtlebot2", args.maps), seed=0)
        one = make_env("turtlebot2", args.envs, seed=0)
    gen = torch.Generator().manual_seed(0)
    runs = {
        "batched": lambda: many._map_sampler.sample(many._draw_map(args.slots, gen), gen),
        "per-map loop": lambda: per_map_loop(many.samplers, many._draw_map(args.slots, gen), gen),
        "one map": lambda: one.sampler.sample(args.slots, gen),
    }
    times = {name: [] for name in runs}
    for rep in range(args.repeats):
        for name in (list(runs) if rep % 2 == 0 else list(runs)[::-1]):
            start = time.perf_counter()
            runs[name]()
            times[name].append(time.perf_counter() - start)
    print(f"{args.slots} resetting slots over {args.maps} maps, {args.repeats} draws each, {args.threads} thread(s)")
    for name, t in times.items():
        print(f"  {name:13s} median {statistics.median(t) * 1e3:7.3f} ms   min {min(t) * 1e3:7.3f} ms")
    print(f"load average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
