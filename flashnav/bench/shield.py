"""``flashnav bench shield``: what the people shield costs in a scenario evaluation, as a ratio to the policy alone.

``flashnav eval POLICY --scenario S --shield SECONDS`` plays every step of every running episode through
:class:`flashnav.shield.SimShield`. This bench plays the scenario's episodes both ways, interleaved, and reports
each way's wall seconds per simulated step (a step of one running episode: the two ways' episodes end at
different times, so their totals differ), the shielded step's cost as a multiple of the step alone ("x alone"),
and the share of the shielded evaluation spent inside the shield. The rates show that both are the evaluation
``flashnav eval --scenario`` reports.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from flashnav.names import seed_arg
from flashnav.shield import check_lookahead


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("shield", help="the people shield's cost in a scenario evaluation, x the policy alone")
    p.add_argument("policy", metavar="POLICY", help="policy.pt (TorchScript) or policy.onnx")
    p.add_argument("--robot", default=None, help="default: the robot recorded in the policy")
    p.add_argument("--scenario", default="wander-8", help="a scenario with agents (flashnav eval --scenario)")
    p.add_argument("--episodes", type=int, default=512, help="episodes, run in parallel (one per env)")
    p.add_argument("--seed", type=seed_arg, default=2026, help="the scenario seed (flashnav eval --seed)")
    p.add_argument("--lookahead", type=float, default=2.0, help="the shield's look-ahead, s (flashnav eval --shield)")
    p.add_argument("--repeats", type=int, default=2, help="timed evaluations per way, interleaved")
    p.add_argument("--device", default="cpu", help="simulator and shield device (cpu, cuda, cuda:N, auto); ONNX "
                                                  "policies run on the CPU")
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: the figures of docs/benchmarks.md)")
    p.add_argument("--json", metavar="FILE", help="also write every timed evaluation as JSON")
    p.set_defaults(func=run_bench_shield)


class _Timed:
    """A :class:`flashnav.shield.SimShield` call that also adds its wall seconds to ``seconds``."""

    def __init__(self, guard):
        self.guard, self.seconds = guard, 0.0

    def __call__(self, active, action):
        start = time.perf_counter()
        out = self.guard(active, action)
        self.seconds += time.perf_counter() - start
        return out


def play(policy, preset, episodes: int, seed: int, lookahead: float | None, device="cpu") -> dict:
    """One evaluation of the scenario ``preset`` (alone with ``lookahead`` None): its rates
    (:func:`flashnav.scenarios.scenario_rates`), ``seconds``, ``steps`` (steps of running episodes) and
    ``shield_seconds``."""
    import torch

    from flashnav.evaluate import play_episodes
    from flashnav.scenarios import scenario_rates, scenario_scored
    from flashnav.shield import PeopleShield, SimShield
    from flashnav.sim.env import make_env

    env = make_env(preset, episodes, seed=seed, device=device)
    obs, _ = env.reset(seed=seed)
    scored = scenario_scored(env)
    guard = None if lookahead is None else _Timed(SimShield(env, PeopleShield(preset, lookahead)))
    start = time.perf_counter()
    ended = play_episodes(policy, env, obs, shield=guard)
    if env.device.type == "cuda":
        torch.cuda.synchronize(env.device)
    seconds = time.perf_counter() - start
    return {**scenario_rates(ended, scored), "seconds": seconds, "steps": int(ended["episode_steps"].sum()),
            "shield_seconds": 0.0 if guard is None else guard.seconds}


def run_bench_shield(args) -> int:
    import torch

    from flashnav.machine import machine_name
    from flashnav.policy_cli import load_policy_for
    from flashnav.scenarios import scenario_preset

    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    check_lookahead(args.lookahead, "--lookahead")
    if args.json:  # before the runs, which take minutes
        from flashnav.outputs import check_output_file

        check_output_file(args.json, "--json", inputs=(args.policy,))
    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    torch.set_num_threads(args.threads)
    policy, _, robot, device = load_policy_for(args, args.device)
    preset = scenario_preset(robot, args.scenario, own_agents=args.robot is not None)
    if preset.agents.count == 0:
        raise ValueError(f"--scenario {args.scenario} has no agents: the shield has nothing to do there")
    ways = {"alone": None, "shield": args.lookahead}
    play(policy, preset, min(args.episodes, 16), args.seed, args.lookahead, device)  # warm-up: JIT caches, allocator
    runs: dict[str, list[dict]] = {way: [] for way in ways}
    for _ in range(args.repeats):
        for way, lookahead in ways.items():
            runs[way].append(play(policy, preset, args.episodes, args.seed, lookahead, device))
    per_step = {way: [r["seconds"] / max(r["steps"], 1) for r in rs] for way, rs in runs.items()}
    base = min(per_step["alone"])
    machine = machine_name(str(device))
    t = Table(title=f"flashnav bench shield: {args.episodes} episodes of {preset.name} {args.scenario!r} (seed "
                    f"{args.seed}), a {args.lookahead:g}-s shield, {args.repeats} interleaved repeats, "
                    f"{args.threads} torch thread(s), {machine}")
    for col in ("way", "seconds (min)", "steps", "us per step", "x alone", "in the shield", "success", "agent hit"):
        t.add_column(col, justify="right")
    for way, rs in runs.items():
        r, best = rs[0], min(per_step[way])
        share = statistics.median(x["shield_seconds"] / x["seconds"] for x in rs)
        t.add_row(way, f"{min(x['seconds'] for x in rs):.2f}",
                  f"{r['steps']:,}", f"{best * 1e6:,.0f}", f"{best / base:.2f}x",
                  "" if ways[way] is None else f"{share:.0%}", f"{r['success_rate']:.1%}",
                  f"{r['agent_collision_rate']:.1%}")
    Console().print(t)
    if args.json:
        import json

        Path(args.json).parent.mkdir(parents=True, exist_ok=True)  # checked creatable before the runs
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "device": str(device), "threads": args.threads, "scenario": args.scenario, "seed": args.seed,
                       "episodes": args.episodes, "lookahead": args.lookahead, "runs": runs,
                       "x_alone": min(per_step["shield"]) / base}, f, indent=2)
    return 0
