"""Several trained policies as one: the mean of their deterministic actions on issue 13's agent scenarios (a probe).

    .venv/bin/python scripts/ensemble_scenarios.py POLICY POLICY [...] [--scenario wander-8,crossing]
        [--episodes 512] [--seed 2026] [--json FILE]

Every POLICY (an exported policy.onnx / policy.pt or a run folder) acts on the same observation and the robot
takes the mean of their actions (each in [-1, 1]); the episodes are those of ``flashnav eval POLICY --scenario
NAME --episodes E --seed S`` on the first policy's recorded robot, so each member's own row is comparable with
the ensemble's. The members must share the robot preset and observation (as seeds of one recipe do); a member
recorded with another robot is refused by name. Prints one row per scenario for each member alone and for the
ensemble: success / agent collision / wall collision / timeout.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Sequence

import torch

from flashnav.export import evaluated_robot, load_policy
from flashnav.names import EVAL_SEED
from flashnav.scenarios import run_scenario, scenario_names, scenario_preset
from flashnav.sim.env import make_env

RATES = ("success_rate", "agent_collision_rate", "wall_collision_rate", "timeout_rate")


def mean_policy(members: Sequence[Callable[[torch.Tensor], torch.Tensor]]) -> Callable[[torch.Tensor], torch.Tensor]:
    """One policy whose action is the mean of ``members``' actions on the same observation."""
    if not members:
        raise ValueError("an ensemble needs at least one member policy")
    return lambda obs: torch.stack([m(obs) for m in members]).mean(dim=0)


def load_members(paths: Sequence[str]):
    """(policies, the first one's recorded robot preset); a member recorded with another robot is a ValueError."""
    loaded = [load_policy(p) for p in paths]
    presets = [evaluated_robot(meta) for _, meta in loaded]  # as flashnav eval plays
    robot = presets[0]
    for path, preset in zip(paths[1:], presets[1:]):
        if preset != robot:
            raise ValueError(f"{path}: recorded with another robot preset than {paths[0]} (an ensemble's members "
                             "must share the robot and its observation)")
    return [policy for policy, _ in loaded], robot


def score(policy, robot, names: Sequence[str], episodes: int, seed: int) -> dict[str, dict]:
    """``run_scenario``'s rates per scenario name, as ``flashnav eval --scenario`` plays them."""
    return {name: run_scenario(policy, make_env(scenario_preset(robot, name), episodes, seed=seed), seed)
            for name in names}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("policies", nargs="+", metavar="POLICY")
    ap.add_argument("--scenario", default="wander-8,crossing")
    ap.add_argument("--episodes", type=int, default=512)
    ap.add_argument("--seed", type=int, default=EVAL_SEED)
    ap.add_argument("--json", metavar="FILE", help="also write every row as JSON")
    args = ap.parse_args(argv)
    names = scenario_names(args.scenario)
    members, robot = load_members(args.policies)
    rows = {path: score(p, robot, names, args.episodes, args.seed) for path, p in zip(args.policies, members)}
    rows["ensemble (mean action)"] = score(mean_policy(members), robot, names, args.episodes, args.seed)
    print(f"{'policy':<48} {'scenario':<10} " + " ".join(f"{k.replace('_rate', ''):>16}" for k in RATES))
    for label, by_name in rows.items():
        for name, r in by_name.items():
            print(f"{label[-48:]:<48} {name:<10} " + " ".join(f"{100 * r[k]:>15.1f}%" for k in RATES))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"scenarios": names, "episodes": args.episodes, "seed": args.seed, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
