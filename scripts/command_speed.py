"""How fast does a policy drive, and would it succeed more if it drove faster? (issue 16, docs/learners.md S19)

    .venv/bin/python scripts/command_speed.py POLICY [POLICY ...] [--episodes 1024] [--seed 12345]
        [--scales 1,1.05,1.1,1.15] [--json OUT]
    .venv/bin/python scripts/command_speed.py POLICY [...] --maps heldout [--episodes 128] [--scales 1,1.1,1.2]

For each exported POLICY, on the fixed evaluation set ``flashnav train`` evaluates on (``--episodes`` start/goal
pairs, evaluation seed ``--seed``, the policy's robot and bundled map; with ``--maps SUITE``, the episodes of
``flashnav eval POLICY --maps SUITE --episodes E --seed S`` instead, ``--episodes`` a map):

1. the distribution of its deterministic forward command ``a_v`` (the action in [-1, 1]; -1 = stand still, 1 = top
   speed) over every step of every episode: what share of steps reach 0.9, 0.95, 0.99 of the action range, and its
   percentiles;
2. its evaluation with the forward speed scaled by each factor k of ``--scales`` (speed ``min(k v, v_max)``: the
   action ``clamp(k (a_v + 1) - 1, -1, 1)`` where the lower speed bound is 0), the rest of the policy untouched:
   success, collision and mean episode steps (on a suite: means over its maps, and the maps under 95 % with the
   worst). k = 1 is the policy as it is. A policy whose failures are timeouts
   that a faster drive turns into successes, without new collisions, is held back by its speed.

A diagnostic, not a policy: an exported policy is evaluated as it is (``flashnav eval``); ``algo.action_headroom``
is the training-side option that lets the actor reach its bounds.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from flashnav.evaluate import evaluate_episodes
from flashnav.export import evaluated_robot, load_policy
from flashnav.sim.env import make_env
from flashnav.names import EVAL_EPISODES, EVAL_SEED

LEVELS = (0.5, 0.8, 0.9, 0.95, 0.99)


def faster(policy, k: float, v_lo: float):
    """``policy`` with its forward speed scaled by ``k`` (clamped at the top speed); needs ``v_lo == 0``."""
    if v_lo != 0.0:
        raise ValueError(f"speed scaling assumes a lower speed bound of 0, this robot's is {v_lo}")

    def scaled(obs: torch.Tensor) -> torch.Tensor:
        a = policy(obs).clone()
        a[..., 0] = torch.clamp(k * (a[..., 0] + 1.0) - 1.0, -1.0, 1.0)
        return a
    return scaled


def recorder(policy):
    """(``policy`` that also keeps every forward action it returns, the list they are kept in)."""
    taken = []

    def record(obs: torch.Tensor) -> torch.Tensor:
        action = policy(obs)
        taken.append(action[:, 0].cpu().numpy())
        return action
    return record, taken


def forward_commands(policy, env, seed: int) -> tuple[np.ndarray, dict]:
    """``policy`` evaluated as it is on ``env``'s episode set for ``seed`` (:func:`flashnav.evaluate.evaluate_episodes`),
    and every deterministic forward action ``a_v`` it took over those episodes (each slot's first)."""
    record, taken = recorder(policy)
    evaluation = evaluate_episodes(record, env, seed)   # it asks for the running slots' actions only
    return np.concatenate(taken), evaluation


def forward_commands_on_maps(policy, meta: dict, maps: str, episodes: int,
                             seed: int) -> tuple[np.ndarray, dict, tuple]:
    """As :func:`forward_commands` on the suite or folder ``maps`` (:func:`flashnav.eval_maps.evaluate_maps`, as
    ``flashnav eval --maps`` plays it); also returns the (preset, maps, goal-distance scale) it played, for the
    scaled runs."""
    from flashnav.eval_maps import evaluate_maps, policy_goal_scale, suite_maps, suite_preset

    preset = suite_preset(evaluated_robot(meta))
    grids, scale = suite_maps(maps, preset), policy_goal_scale(meta, preset)
    record, taken = recorder(policy)
    report = evaluate_maps(record, preset, grids, episodes, seed, goal_distance_scale=scale)
    return np.concatenate(taken), report, (preset, grids, scale)


def suite_row(k: float, report: dict) -> dict:
    """One speed factor's row from an ``evaluate_maps`` report: means over the maps, maps under 95 %, the worst."""
    from flashnav.eval_maps import maps_under

    maps = report["maps"]
    mean = report["aggregate"]["mean"]
    return {"scale": k, "success": mean["success_rate"], "collision": mean["collision_rate"],
            "mean_steps": sum(r["mean_steps"] for r in maps) / len(maps),
            "maps_under_95": maps_under(maps),
            "worst": report["aggregate"]["worst"]}


def main(argv: list[str] | None = None) -> None:
    from flashnav.eval_maps import evaluate_maps

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policies", nargs="+", metavar="POLICY")
    p.add_argument("--maps", default=None, help="a map suite (heldout, real, ...) or folder instead of the bundled map")
    p.add_argument("--episodes", type=int, default=None,
                   help=f"episodes (default {EVAL_EPISODES}; with --maps a map, default 128)")
    p.add_argument("--seed", type=int, default=EVAL_SEED, help="evaluation seed (flashnav train's eval.seed)")
    p.add_argument("--scales", default="1,1.05,1.1,1.15", help="forward-speed factors, comma-separated")
    p.add_argument("--json", help="write every policy's numbers here")
    args = p.parse_args(argv)
    scales = [float(x) for x in args.scales.split(",")]
    if any(k <= 0 for k in scales):
        raise SystemExit(f"--scales must be positive, got {args.scales}")
    episodes = args.episodes or (128 if args.maps else EVAL_EPISODES)
    report = {}
    for path in args.policies:
        policy, meta = load_policy(path)
        if args.maps:
            a_v, as_is, (preset, grids, scale) = forward_commands_on_maps(policy, meta, args.maps, episodes, args.seed)
        else:
            preset = evaluated_robot(meta)
            env = make_env(preset, episodes, seed=args.seed)   # evaluate_episodes resets it to the same episodes
            a_v, as_is = forward_commands(policy, env, args.seed)
        share = {f"{q:g}": float((a_v >= q).mean()) for q in LEVELS}
        pct = np.percentile(a_v, [5, 25, 50, 75, 95]).round(3).tolist()
        print(f"{path}: forward action over {len(a_v):,} steps: percentiles 5/25/50/75/95 {pct}, max {a_v.max():.3f}; "
              "share of steps at or above " + ", ".join(f"{q}: {v:.1%}" for q, v in share.items()))
        rows = []
        for k in scales:
            fast = faster(policy, k, preset.motion.v_bounds[0])
            if args.maps:
                e = as_is if k == 1 else evaluate_maps(fast, preset, grids, episodes, args.seed,
                                                       goal_distance_scale=scale)
                row = suite_row(k, e)
            else:
                e = as_is if k == 1 else evaluate_episodes(fast, env, args.seed)
                row = {"scale": k, "success": float(e["success"].float().mean()),
                       "collision": float(e["collision"].float().mean()),
                       "mean_steps": float(e["episode_steps"].float().mean())}
            rows.append(row)
            under = (f"  maps < 95 %: {len(row['maps_under_95'])}, worst {row['worst']['map']} "
                     f"{row['worst']['success_rate']:.1%}" if args.maps else "")
            print(f"  speed x{k:<5g} success {row['success']:7.2%}  collision {row['collision']:6.2%}  "
                  f"mean steps {row['mean_steps']:6.1f}{under}")
        report[path] = {"forward_action_percentiles": pct, "forward_action_max": float(a_v.max()),
                        "share_at_or_above": share, "speed_scaled": rows}
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"maps": args.maps, "episodes": episodes, "seed": args.seed, "policies": report}
                      if args.maps else report, f, indent=1)


if __name__ == "__main__":
    main()
