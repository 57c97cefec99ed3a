"""``flashnav bench cycle``: the training cycle's milliseconds, overlapped against sequential, in one run.

A training cycle is one vector step of collection plus its U updates (:mod:`flashnav.learn.loop`). The
loop runs it in one of two schedules that do the same work in the same order (``TrainConfig.overlap``):
``overlap`` - the collector steps in a second thread beside the learner (on a CPU: one core each) - or
``sequential`` - collector then learner in one thread, each on every core the process has. Which one is
faster depends on the machine and the recipe, so this bench runs short trainings of each schedule,
alternating (A B B A ... so that a drift in the machine's load hits both), and reports each one's
collector / learner / effective milliseconds per learning cycle (the median over its repeats) and its
speed as a ratio to the first schedule named. Only learning cycles count (the warm-up before
``learning_start`` is excluded by the loop) and evaluation is outside the clock.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import statistics

from rich.console import Console
from rich.table import Table

from flashnav.bench.train import add_run_choices
from flashnav.names import parse_names

#: ``--schedules`` values -> ``TrainConfig.overlap``.
SCHEDULES = {"overlap": True, "sequential": False}


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("cycle", help="ms per training cycle: collector thread beside the learner vs sequential")
    add_run_choices(p)
    p.add_argument("--schedules", default="overlap,sequential",
                   help=f"comma-separated, from {', '.join(SCHEDULES)}; the first is the ratio's baseline")
    p.add_argument("--cycles", type=int, default=60, help="learning cycles per run (after the warm-up)")
    p.add_argument("--repeats", type=int, default=2, help="runs per schedule, alternating A B B A ...")
    p.add_argument("--json", metavar="FILE", help="also write every run and the summary rows as JSON")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="as for flashnav train")
    p.set_defaults(func=run_bench_cycle)


def parse_schedules(text: str) -> list[str]:
    names = parse_names("schedule", text, tuple(SCHEDULES), "--schedules")
    if len(set(names)) != len(names):
        raise ValueError(f"--schedules: {text!r} names a schedule twice")
    return names


def run_order(schedules: list[str], repeats: int) -> list[str]:
    """The schedules in the order they run: forward, then backward, ... (A B, B A, A B for 3 repeats)."""
    if repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {repeats}")
    return [s for r in range(repeats) for s in (schedules if r % 2 == 0 else schedules[::-1])]


def cycle_config(robot: str, algo: str, recipe: str, device: str, schedule: str, cycles: int,
                 overrides: list[str] | tuple[str, ...] = ()):
    """The TrainConfig of one timed run: the recipe as ``flashnav train`` resolves it, ``cycles``
    learning cycles after the warm-up, one small evaluation at the end, no stop on success."""
    from flashnav.spec import config_from_cli, resolve

    if cycles < 1:
        raise ValueError(f"--cycles must be >= 1, got {cycles}")
    flags = dict(robot=robot, algorithm=algo, recipe=recipe, device=device)
    base = resolve(config_from_cli(None, flags, list(overrides)))
    hp = base.hparams
    warmup = math.ceil(hp.learning_start / hp.num_envs)
    settings = [f"overlap={str(SCHEDULES[schedule]).lower()}", f"budget.max_env_steps={(warmup + cycles) * hp.num_envs}",
                "budget.max_train_seconds=1e9", "budget.stop_at_success=null", "eval.episodes=16",
                f"eval.every={warmup + cycles}"]
    return config_from_cli(None, flags, list(overrides) + settings)


def summarise(runs: list[dict], schedules: list[str]) -> list[dict]:
    """One row per schedule: median collector / learner / effective ms over its runs, and its speed
    (the baseline's effective ms / its own; the baseline is ``schedules[0]``)."""
    rows = []
    for s in schedules:
        mine = [r for r in runs if r["schedule"] == s]
        row = {"schedule": s, "threads": mine[0]["threads"], "runs": len(mine)}
        for k in ("collector_ms", "learner_ms", "effective_ms"):
            row[k] = statistics.median(r[k] for r in mine)
        row["effective_ms_each"] = [r["effective_ms"] for r in mine]
        rows.append(row)
    for row in rows:
        row["speed"] = rows[0]["effective_ms"] / row["effective_ms"]
    return rows


def run_bench_cycle(args) -> int:
    from flashnav.learn.loop import train
    from flashnav.machine import machine_name
    from flashnav.spec import resolve

    schedules = parse_schedules(args.schedules)
    order = run_order(schedules, args.repeats)
    console = Console()
    out = {"date": dt.datetime.now().strftime("%Y-%m-%d %H:%M"), "cycles": args.cycles, "repeats": args.repeats,
           "overrides": list(args.overrides), "groups": []}
    for robot in [r for r in args.robots.split(",") if r]:
        for algo in [a for a in args.algos.split(",") if a]:
            runs = []
            for i, schedule in enumerate(order):
                spec = resolve(cycle_config(robot, algo, args.recipe, args.device, schedule, args.cycles,
                                            args.overrides))
                result = train(spec)
                runs.append({"schedule": schedule, "threads": result.threads, **result.cycle})
                console.print(f"  {robot} / {algo} / {spec.recipe}  run {i + 1}/{len(order)} {schedule:10s} "
                              f"{result.cycle['effective_ms']:8.1f} ms/cycle ({result.threads or '-'} learner threads)")
            rows = summarise(runs, schedules)
            out["machine"] = machine_name(spec.device)
            out["groups"].append({"robot": robot, "algo": algo, "recipe": spec.recipe, "device": spec.device,
                                  "runs": runs, "rows": rows})
            t = Table(title=f"{robot} / {algo} / recipe {spec.recipe}, {spec.device} ({out['machine']}): "
                            f"{args.cycles} learning cycles x {args.repeats}")
            for col in ("schedule", "learner threads", "collector ms", "learner ms", "cycle ms (median)",
                        "each run", f"speed vs {schedules[0]}"):
                t.add_column(col, justify="right")
            for r in rows:
                t.add_row(r["schedule"], str(r["threads"] or "-"), f"{r['collector_ms']:.1f}", f"{r['learner_ms']:.1f}",
                          f"{r['effective_ms']:.1f}", ", ".join(f"{v:.1f}" for v in r["effective_ms_each"]),
                          f"{r['speed']:.2f}x")
            console.print(t)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=2)
    return 0
