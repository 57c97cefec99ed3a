"""Does sampling the policy's own Gaussian get a memoryless generalist out of dead ends? (issue 15, done-means 2)

    .venv/bin/python scripts/stochastic_maps.py RUN_DIR [--maps heldout] [--only mazes] [--scales 1,0.5,0.25]
                                                [--episodes 128] [--seed 12345] [--sample-seed 0] [--json FILE]

Loads a FastDSAC run's final learner (``RUN_DIR/checkpoint.pt`` with its ``config.yaml``) and evaluates it per map, as
``flashnav eval POLICY --maps SUITE`` does (the same fixed episodes: goals by path length, ``--episodes`` per map,
``--seed``), once with the deterministic actor (tanh of the mean: what ``flashnav eval`` plays) and once per scale f
with actions sampled from the actor's tanh-Gaussian, its standard deviation multiplied by f (1: the policy the learner
updates, DEM scale 1; the collector draws a scale per env from the recipe's range), each sampled arm's draws from a
generator seeded with ``--sample-seed``. A deterministic reactive policy that loops in a dead end repeats its loop; a
sampled one might wander out of it. ``--only`` keeps the maps whose name contains that text. ``--json`` writes every
arm's success rate and episode outcomes (``s``/``c``/``t`` per episode, as ``flashnav eval --json``) per map, with the
checkpoint's env steps.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch

from flashnav.checkpoint import load_checkpoint
from flashnav.eval_maps import evaluate_maps, suite_path
from flashnav.learn.fastdsac import policy_log_std
from flashnav.learn.loop import run_learner
from flashnav.learn.networks import DeterministicActor, squashed_gaussian
from flashnav.maps.bundled import resolve_maps
from flashnav.names import CHECKPOINT_FILE, CONFIG_FILE, EVAL_SEED
from flashnav.presets import load_robot
from flashnav.spec import RunSpec
from flashnav.yamlio import load_yaml


def sampled(actor, hp, scale: float, seed: int):
    """The actor's tanh-Gaussian with its standard deviation times ``scale``, drawn from its own generator."""
    gen = torch.Generator().manual_seed(seed)
    shift = math.log(scale)

    def policy(obs: torch.Tensor) -> torch.Tensor:
        mu, log_std = policy_log_std(actor(obs), hp)
        noise = torch.randn(mu.shape, generator=gen, device=mu.device)
        return squashed_gaussian(mu, log_std + shift, noise, hp.action_headroom)[0].clamp(-1.0, 1.0)

    return policy


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", help="a flashnav train --out directory of a FastDSAC run")
    p.add_argument("--maps", default="heldout", help="a benchmark suite (heldout, real) or a folder / glob of map YAMLs")
    p.add_argument("--only", default="", help="keep the maps whose name contains this")
    p.add_argument("--scales", default="1,0.5,0.25", help="standard-deviation multipliers of the sampled arms")
    p.add_argument("--episodes", type=int, default=128)
    p.add_argument("--seed", type=int, default=EVAL_SEED, help="start/goal sampling seed (flashnav eval's --seed)")
    p.add_argument("--sample-seed", type=int, default=0, help="seed of each sampled arm's action noise")
    p.add_argument("--json", default=None, help="write every arm's per-map rates and outcomes here")
    args = p.parse_args()
    scales = parse_scales(args.scales)
    run = Path(args.run)
    for needed in (CONFIG_FILE, CHECKPOINT_FILE):
        if not (run / needed).is_file():
            raise SystemExit(f"{run}: no {needed} (a flashnav train --out folder holds config.yaml and checkpoint.pt)")
    spec = RunSpec.from_dict(load_yaml(run / CONFIG_FILE), str(run / CONFIG_FILE))
    if spec.algorithm != "fastdsac":
        raise SystemExit(f"{run}: a {spec.algorithm} run; this samples FastDSAC's DEM policy")
    checkpoint = load_checkpoint(run / CHECKPOINT_FILE)
    learner = run_learner(spec, "cpu")
    learner.load_state_dict(checkpoint["learner"])
    actor, hp = learner.state.actor, learner.state.hp
    preset = load_robot(spec.robot, **{"episode.goal_sampling": "geodesic"})
    grids = [g for g in resolve_maps(suite_path(args.maps), preset.map) if args.only in g.name]
    if not grids:
        raise SystemExit(f"--maps {args.maps} --only {args.only!r}: no map")
    arms = [("deterministic", DeterministicActor(actor))] + [
        (f"sampled x{s:g}", sampled(actor, hp, s, args.sample_seed)) for s in scales]
    success, outcomes = {}, {}
    with torch.no_grad():
        for name, policy in arms:
            r = evaluate_maps(policy, preset, grids, args.episodes, args.seed, goal_distance_scale=spec.goal_distance_max)
            success[name] = {m["map"]: m["success_rate"] for m in r["maps"]}
            outcomes[name] = {m["map"]: m["outcomes"] for m in r["maps"]}
            rates = " ".join(f"{m['map']} {m['success_rate']:.1%}" for m in r["maps"])
            print(f"{name:>14}: mean {r['aggregate']['mean']['success_rate']:.1%} | {rates}", flush=True)
    if args.json:
        env_steps = (checkpoint.get("extra") or {}).get("metrics", {}).get("env_steps")
        Path(args.json).write_text(json.dumps({
            "run": str(run), "checkpoint_env_steps": env_steps, "maps": args.maps, "episodes": args.episodes,
            "seed": args.seed, "sample_seed": args.sample_seed, "success": success, "outcomes": outcomes}, indent=1))


def parse_scales(text: str) -> list[float]:
    """``--scales`` "1,0.5" -> [1.0, 0.5] ("" -> none: the deterministic arm alone); each a finite number > 0."""
    scales = []
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        try:
            value = float(item)
        except ValueError:
            raise SystemExit(f"--scales {text}: {item!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise SystemExit(f"--scales {text}: every scale must be a finite number > 0, got {item}")
        scales.append(value)
    return scales


if __name__ == "__main__":
    main()
