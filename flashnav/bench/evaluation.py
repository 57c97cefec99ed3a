"""``flashnav bench eval``: the evaluation protocol's cost, compact (the default) vs dense, in one run.

Evaluation runs outside the training clock, but on a CPU it is most of a training run's wall time, so
its speed is what a user waits for. Both ways play the same episodes with the same deterministic policy
and must give the same rates; the table says whether they did.
"""

from __future__ import annotations

import argparse
import statistics
import time

from rich.console import Console
from rich.table import Table

from flashnav.names import EVAL_EPISODES, EVAL_SEED, seed_arg


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("eval", help="evaluation wall time: compact (only running episodes) vs dense (every slot)")
    p.add_argument("policy", metavar="POLICY", help="policy.pt (TorchScript) or policy.onnx")
    p.add_argument("--robot", default=None, help="default: the robot recorded in the policy")
    p.add_argument("--map", default=None, help="ROS map YAML or bundled map name (default: the robot's map)")
    p.add_argument("--episodes", type=int, default=EVAL_EPISODES, help="episodes, run in parallel (one per env)")
    p.add_argument("--seed", type=seed_arg, default=EVAL_SEED, help="start/goal sampling seed")
    p.add_argument("--device", default="cpu", help="simulator device")
    p.add_argument("--repeats", type=int, default=3, help="timed evaluations per way, interleaved")
    p.set_defaults(func=run_bench_eval)


def run_bench_eval(args) -> int:
    from flashnav.evaluate import evaluate
    from flashnav.policy_cli import load_policy_and_env

    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    console = Console()
    policy, _, env = load_policy_and_env(args, args.device)
    evaluate(policy, env, args.seed)  # warm-up: JIT caches, allocator
    seconds: dict[str, list[float]] = {"dense": [], "compact": []}
    rates: dict[str, dict] = {}
    for _ in range(args.repeats):
        for way in ("dense", "compact"):
            start = time.perf_counter()
            rates[way] = evaluate(policy, env, args.seed, dense=way == "dense")
            seconds[way].append(time.perf_counter() - start)
    same = all(rates["dense"][k] == rates["compact"][k] for k in ("success_rate", "collision_rate", "timeout_rate"))
    t = Table(title=f"flashnav bench eval: {env.num_envs} episodes of {env.preset.name} on {env.map.name!r}, "
                    f"{args.repeats} interleaved repeats, device {args.device}")
    for col in ("way", "seconds (min / median)", "x dense", "success", "collision", "timeout", "mean steps"):
        t.add_column(col, justify="right")
    base = min(seconds["dense"])
    for way in ("dense", "compact"):
        r = rates[way]
        t.add_row(way, f"{min(seconds[way]):.2f} / {statistics.median(seconds[way]):.2f}",
                  f"{base / min(seconds[way]):.1f}x", f"{r['success_rate']:.2%}", f"{r['collision_rate']:.2%}",
                  f"{r['timeout_rate']:.2%}", f"{r['mean_steps']:.1f}")
    console.print(t)
    console.print("same rates both ways" if same else "[red]the two ways disagree[/]")
    return 0 if same else 1
