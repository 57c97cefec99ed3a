"""``flashnav bench update``: milliseconds per learner update, eager against ``torch.compile``, in one run.

The learner update (critic step, actor/temperature step every ``policy_frequency``-th, Polyak) is the
learning side of the paper's cycle. This bench times it on fixed random batches of the recipe's batch
size, once per way: ``eager`` (what ``flashnav train`` runs) and each ``torch.compile`` mode named,
applied to the actor, the twin critic and its target (the networks; noise draws, losses and the
optimiser stay eager). Every way starts from the same seed and the same batches; each reports its
warm-up seconds (compilation, which a training clock would pay) apart from the timed updates, and its
speed as a ratio to eager. ``bf16-autocast`` keeps the networks eager and runs the whole update under
``torch.autocast(dtype=torch.bfloat16)`` as ``flashnav train`` does with ``algo.precision=bf16``
(:mod:`flashnav.learn.precision`; matrix products in bf16: AVX-512 BF16 / AMX on this CPU
family, tensor cores on GPUs). ``cuda-graph`` runs the updates a cycle at a time (U =
``updates_per_step``) through :class:`flashnav.learn.cuda_graph.CycleUpdates`, what ``flashnav train``
runs with ``cuda_graph=on``: on a GPU one captured graph replay per cycle (the capture is in the
warm-up), on a CPU the same updates on static buffers, eagerly (its ratio to eager is then the
static-buffer path's own overhead). Use it to decide whether a way pays on a machine before turning it on.
"""

from __future__ import annotations

import dataclasses

import argparse
import datetime as dt
import json
import time
from typing import Any, Callable

from rich.console import Console
from rich.table import Table

from flashnav.names import ALGORITHMS, DEFAULT_ROBOT, DEVICE_HELP, RECIPE_CHOICES, RECIPE_HELP, ROBOT_HELP

#: ``--ways`` values: eager, or a torch.compile mode ("default" is torch's default mode).
WAYS = ("eager", "bf16-autocast", "cuda-graph", "default", "reduce-overhead", "max-autotune",
        "max-autotune-no-cudagraphs")
#: Ways that keep the networks eager and change the arithmetic instead: the update runs under
#: ``torch.autocast`` in bfloat16 (matrix products in bf16, on CPUs with AVX-512 BF16 / AMX and on GPUs).
AUTOCAST_WAYS = ("bf16-autocast",)
#: Ways that keep the networks eager and run a cycle's U updates on static buffers, captured as one
#: CUDA graph on a GPU (:mod:`flashnav.learn.cuda_graph`).
GRAPH_WAYS = ("cuda-graph",)


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("update", help="ms per learner update: eager vs torch.compile modes, bf16, CUDA graph")
    p.add_argument("--robot", default=DEFAULT_ROBOT,
                   help=ROBOT_HELP + ": sets the networks' input size")
    p.add_argument("--algo", default="fastdsac", choices=ALGORITHMS, help="learner (default fastdsac)")
    p.add_argument("--recipe", default="auto", choices=RECIPE_CHOICES, help="hyperparameters: " + RECIPE_HELP)
    p.add_argument("--device", default="auto", help=DEVICE_HELP)
    p.add_argument("--ways", default="eager,default", help=f"comma-separated, from {', '.join(WAYS)}")
    p.add_argument("--seconds", type=float, default=10.0, help="timed seconds per way (after warm-up)")
    p.add_argument("--warmup", type=int, default=24, help="untimed updates per way (compilation happens here)")
    p.add_argument("--threads", type=int, default=None,
                   help="torch threads on a CPU (default: torch's count, every core, as the learner of a sequential "
                        "CPU run has; 1: the learner's share of an overlapped run, overlap=true)")
    p.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    p.add_argument("--wall-map", type=int, default=0, metavar="C",
                   help="also time every way with the networks reading a wall map of C x C squares "
                        "(observation.wall_map: its CNN in the actor and both critics), right after the same way "
                        "without it; the table gives the ratio ('x no map')")
    p.add_argument("overrides", nargs="*", metavar="key=value",
                   help="hyperparameter overrides, e.g. batch_size=256 (an algo. prefix is accepted)")
    p.set_defaults(func=run_bench_update)


def parse_ways(text: str) -> list[str]:
    from flashnav.names import parse_names

    return parse_names("way", text, tuple(WAYS), "--ways")


def run_spec(algo: str, robot: str, recipe: str, device: str, overrides: list[str] | tuple[str, ...] = ()):
    """The RunSpec whose learner is timed, through ``flashnav train``'s own path; ``overrides`` are
    ``key=value`` hyperparameters (the ``algo.`` prefix optional)."""
    from flashnav.spec import config_from_cli, resolve

    items = [item if item.startswith(("algo.", "robot.")) else f"algo.{item}" for item in overrides]
    return resolve(config_from_cli(None, dict(algorithm=algo, robot=robot, recipe=recipe, device=device), items))


def compile_networks(learner, way: str) -> None:
    """``torch.compile`` the learner's actor, twin critic and target critic in mode ``way`` (in place;
    nothing for ``"eager"``)."""
    if way not in WAYS:
        raise ValueError(f"unknown way {way!r}: use one of {', '.join(WAYS)}")
    if way == "eager" or way in AUTOCAST_WAYS or way in GRAPH_WAYS:
        return
    s = learner.state
    for module in (s.actor, s.critic, s.critic_target):
        module.compile(mode=None if way == "default" else way, dynamic=False)


def random_batches(obs_dim: int, batch_size: int, device, seed: int, n: int) -> list:
    """``n`` fixed random :class:`~flashnav.learn.replay.Transition` batches ``[batch_size, ...]``
    (observations positive, like ranges in metres; 5 % terminal), the same for the same seed."""
    import torch

    from flashnav.learn.replay import Transition

    gen = torch.Generator().manual_seed(seed)
    batches = []
    for _ in range(n):
        obs = torch.rand(batch_size, obs_dim, generator=gen) * 3.0 + 0.3
        fields = (obs, torch.rand(batch_size, 2, generator=gen) * 2 - 1, torch.randn(batch_size, generator=gen),
                  (torch.rand(batch_size, generator=gen) >= 0.05).float(), obs + 0.01)  # bootstrap
        batches.append(Transition(*(t.to(device) for t in fields)))
    return batches


def time_updates(spec, way: str, *, seconds: float, warmup: int, seed: int = 0, num_batches: int = 8,
                 wall_map: int = 0) -> dict:
    """Build the learner of ``spec`` (a :class:`flashnav.spec.RunSpec`; ``seed``), compile its networks
    (a torch.compile way) or run the update under bf16 autocast (``bf16-autocast``), run ``warmup``
    updates, then time whole updates for at least ``seconds`` (device synchronised at both ends).
    ``wall_map`` C > 0: the networks read a wall map of C x C squares besides the robot's observation (random
    0 / 1 squares in the batches).

    Returns ``{"way", "batch_size", "warmup_s", "updates", "ms_per_update", "wall_map"}``."""
    import torch

    from flashnav.learn.learners import make_learner
    from flashnav.learn.networks import ObsLayout
    from flashnav.learn.precision import update_precision

    hp, device = spec.hparams, spec.device
    layout = ObsLayout.from_robot(spec.robot, spec.goal_distance_max)
    if wall_map:
        layout = dataclasses.replace(layout, wall_map=wall_map)
    learner = make_learner(spec.algorithm, hp, layout, 2, hp.num_envs, device, seed)
    compile_networks(learner, way)
    batches = random_batches(layout.obs_dim, hp.batch_size, device, seed, num_batches)
    if wall_map:  # the map's squares are 0 / 1, as the env gives them
        for b in batches:
            for obs in (b.obs, b.next_obs):
                obs[:, layout.memory_end:] = (obs[:, layout.memory_end:] > 2.0).float()
    if way in GRAPH_WAYS:
        return {**_time_cycles(learner, layout.obs_dim, batches, hp, device, seconds=seconds, warmup=warmup),
                "wall_map": wall_map}

    arithmetic = update_precision("bf16" if way in AUTOCAST_WAYS else "float32", device)  # what training runs

    def update(batch):
        with arithmetic():
            return learner.update(batch)

    def all_batches():
        for batch in batches:
            update(batch)

    timed = time_steps(lambda i: update(batches[i % num_batches]), warmup, all_batches, num_batches,
                       seconds=seconds, device=device)
    return {"way": way, "batch_size": hp.batch_size, **timed, "wall_map": wall_map}


def _time_cycles(learner, obs_dim: int, batches: list, hp, device, *, seconds: float, warmup: int) -> dict:
    """:func:`time_updates` for the ``cuda-graph`` way: whole cycles of U updates through
    :class:`~flashnav.learn.cuda_graph.CycleUpdates` (captured on a GPU), static batch i = ``batches[i %
    len(batches)]``; at least 2 warm-up cycles (the eager one and the capture), more to cover ``warmup``."""
    import math

    import torch

    from flashnav.learn.cuda_graph import CycleUpdates

    u = hp.updates_per_step
    cycles = CycleUpdates(learner, obs_dim, 2, hp.batch_size, u, capture=torch.device(device).type == "cuda")
    for i in range(u):
        for dst, src in zip(cycles.batches, batches[i % len(batches)]):
            dst[i].copy_(src)
    timed = time_steps(lambda i: cycles.run(), max(2, math.ceil(warmup / u)), cycles.run, u,
                       seconds=seconds, device=device)
    return {"way": "cuda-graph", "batch_size": hp.batch_size, **timed, "captured": cycles.graphs > 0}


def time_steps(warm_step: Callable[[int], Any], warm_steps: int, step: Callable[[], Any], updates_per_step: int,
               *, seconds: float, device, clock: Callable[[], float] = time.perf_counter) -> dict:
    """The timing harness of every way: ``warm_step(i)`` for i < ``warm_steps`` (untimed apart), then
    ``step()`` (``updates_per_step`` updates) again and again until at least ``seconds`` have passed,
    the device synchronised before each reading of ``clock``.

    Returns ``{"warmup_s", "updates", "ms_per_update"}``."""
    import torch

    def sync():
        if torch.device(device).type == "cuda":
            torch.cuda.synchronize(device)

    start = clock()
    for i in range(warm_steps):
        warm_step(i)
    sync()
    warmup_s = clock() - start
    updates, start = 0, clock()
    while True:
        step()
        updates += updates_per_step
        sync()
        elapsed = clock() - start
        if elapsed >= seconds:
            break
    return {"warmup_s": warmup_s, "updates": updates, "ms_per_update": 1000.0 * elapsed / updates}


def run_bench_update(args) -> int:
    import torch

    from flashnav.machine import machine_name

    ways = parse_ways(args.ways)
    if args.seconds <= 0 or args.warmup < 1 or (args.threads is not None and args.threads < 1):
        raise ValueError("--seconds must be > 0, --warmup >= 1 and --threads >= 1")
    if args.wall_map < 0 or args.wall_map == 1:
        raise ValueError(f"--wall-map must be 0 (none) or at least 2 squares a side, got {args.wall_map}")
    spec = run_spec(args.algo, args.robot, args.recipe, args.device, args.overrides)
    device, recipe = spec.device, spec.recipe
    if device == "cpu" and args.threads is not None:
        torch.set_num_threads(args.threads)
    console = Console()
    machine, when = machine_name(device), dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    threads = torch.get_num_threads() if device == "cpu" else None  # the learner's torch threads
    on = f"{machine}, {threads} torch threads" if threads else machine
    console.print(f"[bold]flashnav bench update[/] {when} on {on}: {args.robot} / {args.algo} / "
                  f"recipe {recipe}, >= {args.seconds:g} s per way after {args.warmup} warm-up updates")
    rows = []
    for way in ways:
        for cells in (0, args.wall_map) if args.wall_map else (0,):
            row = time_updates(spec, way, seconds=args.seconds, warmup=args.warmup, wall_map=cells)
            rows.append(row)
            note = "" if row.get("captured", True) else ", capture skipped: static buffers, eager"
            what = f"{way} + wall map {cells}" if cells else way
            console.print(f"  {what:28s} {row['ms_per_update']:8.2f} ms/update (warm-up {row['warmup_s']:.1f} s{note})")
    plain = [r for r in rows if not r["wall_map"]]
    ref = next((r for r in plain if r["way"] == "eager"), plain[0])   # the ratio's baseline
    t = Table(title=f"learner update, batch {rows[0]['batch_size']}, device {device}")
    for col in ("way", *(("wall map",) if args.wall_map else ()), "ms / update", f"speed vs {ref['way']}",
                *(("x no map",) if args.wall_map else ()), "warm-up s", "updates timed"):
        t.add_column(col, justify="right")
    for r in rows:
        same = next(p for p in plain if p["way"] == r["way"])
        t.add_row(r["way"], *((str(r["wall_map"]),) if args.wall_map else ()), f"{r['ms_per_update']:.2f}",
                  f"{ref['ms_per_update'] / r['ms_per_update']:.2f}x",
                  *((f"{same['ms_per_update'] / r['ms_per_update']:.2f}x",) if args.wall_map else ()),
                  f"{r['warmup_s']:.1f}", f"{r['updates']:,}")
    console.print(t)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "threads": threads, "date": when, "robot": args.robot, "algo": args.algo,
                       "recipe": recipe, "device": device, "rows": rows}, f, indent=2)
    return 0
