"""Several trained policies as one: the mean (or the medoid) of their deterministic actions, on issue 13's agent
scenarios or on a map suite (a probe).

    .venv/bin/python scripts/ensemble_eval.py POLICY POLICY [...] [--scenario wander-8,crossing]
        [--episodes 512] [--seed 2026] [--json FILE]
    .venv/bin/python scripts/ensemble_eval.py POLICY POLICY [...] --maps heldout [--episodes 128] [--ensemble-only]

Every POLICY (an exported policy.onnx / policy.pt or a run folder) acts on the same observation and the robot
takes the mean of their actions (each in [-1, 1]; ``--combine medoid``: per row, the member's action nearest the
others'). The episodes are those of ``flashnav eval POLICY --scenario NAME --episodes E --seed S`` (or ``flashnav
eval POLICY --maps SUITE --episodes E --seed S``, geodesic goals) on the first policy's recorded robot, so each
member's own row is comparable with the ensemble's. The members must share the robot preset and observation (as
seeds of one recipe do), and on maps the goal-distance scale too; a member that does not is refused by name. Prints
one row per scenario (or per map suite: mean success, worst map, maps under 95 %) for each member alone (unless
``--ensemble-only``) and for the ensemble.
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
MAP_RATES = ("success_rate", "collision_rate", "timeout_rate")


def mean_policy(members: Sequence[Callable[[torch.Tensor], torch.Tensor]]) -> Callable[[torch.Tensor], torch.Tensor]:
    """One policy whose action is the mean of ``members``' actions on the same observation."""
    if not members:
        raise ValueError("an ensemble needs at least one member policy")
    return lambda obs: torch.stack([m(obs) for m in members]).mean(dim=0)


def medoid_policy(members: Sequence[Callable[[torch.Tensor], torch.Tensor]]) -> Callable[[torch.Tensor], torch.Tensor]:
    """One policy that takes, row by row, the member action nearest to the others (least summed distance; the first
    of equals): a vote that never averages two ways round an obstacle into a third."""
    if not members:
        raise ValueError("an ensemble needs at least one member policy")

    def act(obs: torch.Tensor) -> torch.Tensor:
        actions = torch.stack([m(obs) for m in members], dim=1)  # [N, M, 2]
        pick = torch.cdist(actions, actions).sum(dim=2).argmin(dim=1)
        return actions[torch.arange(actions.shape[0], device=actions.device), pick]

    return act


COMBINE = {"mean": mean_policy, "medoid": medoid_policy}


def load_members(paths: Sequence[str]):
    """(policies, the first one's recorded robot preset, metadata per member); a member recorded with another robot
    is a ValueError."""
    loaded = [load_policy(p) for p in paths]
    presets = [evaluated_robot(meta) for _, meta in loaded]  # as flashnav eval plays
    robot = presets[0]
    for path, preset in zip(paths[1:], presets[1:]):
        if preset != robot:
            raise ValueError(f"{path}: recorded with another robot preset than {paths[0]} (an ensemble's members "
                             "must share the robot and its observation)")
    return [policy for policy, _ in loaded], robot, [meta for _, meta in loaded]


def score(policy, robot, names: Sequence[str], episodes: int, seed: int) -> dict[str, dict]:
    """``run_scenario``'s rates per scenario name, as ``flashnav eval --scenario`` plays them."""
    return {name: run_scenario(policy, make_env(scenario_preset(robot, name), episodes, seed=seed), seed)
            for name in names}


def goal_distance_scale(paths: Sequence[str], metas: Sequence[dict], robot) -> float:
    """The members' common goal-distance scale (as ``flashnav eval --maps`` reads it); members that differ are a
    ValueError naming the first that does (their goal-distance inputs would mean different things)."""
    from flashnav.eval_maps import policy_goal_scale

    scales = [policy_goal_scale(meta, robot) for meta in metas]
    for path, s in zip(paths[1:], scales[1:]):
        if s != scales[0]:
            raise ValueError(f"{path}: goal-distance scale {s:.2f} m, but {paths[0]} has {scales[0]:.2f} m (an "
                             "ensemble's members must read the goal distance alike)")
    return scales[0]


def suite(robot, maps: str) -> tuple:
    """(preset, maps) of the suite or folder ``maps`` as ``flashnav eval --maps`` plays it (geodesic goals), loaded
    once for every member and the ensemble."""
    from flashnav.eval_maps import suite_maps, suite_preset

    preset = suite_preset(robot)
    return preset, suite_maps(maps, preset)


def print_scenario_rows(rows: dict) -> None:
    print(f"{'policy':<48} {'scenario':<10} " + " ".join(f"{k.replace('_rate', ''):>16}" for k in RATES))
    for label, by_name in rows.items():
        for name, r in by_name.items():
            print(f"{label[-48:]:<48} {name:<10} " + " ".join(f"{100 * r[k]:>15.1f}%" for k in RATES))


def print_map_rows(rows: dict) -> None:
    from flashnav.eval_maps import maps_under

    print(f"{'policy':<48} {'success':>8} {'collision':>10} {'timeout':>8}  {'maps < 95 %':>11}  worst map")
    for label, report in rows.items():
        mean, worst = report["aggregate"]["mean"], report["aggregate"]["worst"]
        under = len(maps_under(report["maps"]))
        print(f"{label[-48:]:<48} " + " ".join(f"{100 * mean[k]:>{w}.1f}%" for k, w in zip(MAP_RATES, (7, 9, 7)))
              + f"  {under:>11}  {worst['map']} {100 * worst['success_rate']:.1f} %")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("policies", nargs="+", metavar="POLICY")
    ap.add_argument("--scenario", default=None, help="agent scenarios (default wander-8,crossing without --maps)")
    ap.add_argument("--maps", default=None, help="a map suite (heldout, real, validation, ...) or folder instead")
    ap.add_argument("--episodes", type=int, default=None, help="per scenario (default 512) or per map (default 128)")
    ap.add_argument("--seed", type=int, default=EVAL_SEED)
    ap.add_argument("--combine", choices=sorted(COMBINE), default="mean",
                    help="mean: the members' mean action; medoid: per row, the member action nearest the others")
    ap.add_argument("--ensemble-only", action="store_true", help="skip the members' own rows")
    ap.add_argument("--json", metavar="FILE", help="also write every row as JSON")
    args = ap.parse_args(argv)
    if args.maps is not None and args.scenario is not None:
        ap.error("--maps and --scenario: give one (an ensemble is scored on map suites or on agent scenarios)")
    members, robot, metas = load_members(args.policies)
    labelled = [] if args.ensemble_only else list(zip(args.policies, members))
    labelled.append((f"ensemble ({args.combine} action)", COMBINE[args.combine](members)))
    if args.maps is not None:
        episodes = args.episodes or 128
        from flashnav.eval_maps import evaluate_maps

        scale = goal_distance_scale(args.policies, metas, robot)
        preset, grids = suite(robot, args.maps)
        rows = {label: evaluate_maps(p, preset, grids, episodes, args.seed, goal_distance_scale=scale)
                for label, p in labelled}
        print_map_rows(rows)
        header = {"maps": args.maps, "goal_distance_scale": scale}
    else:
        episodes = args.episodes or 512
        names = scenario_names(args.scenario or "wander-8,crossing")
        rows = {label: score(p, robot, names, episodes, args.seed) for label, p in labelled}
        print_scenario_rows(rows)
        header = {"scenarios": names}
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({**header, "policies": args.policies, "episodes": episodes, "seed": args.seed, "rows": rows},
                      f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
