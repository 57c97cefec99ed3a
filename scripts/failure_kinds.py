"""How does a policy fail on a set of maps, and would a map-aware driver have had time? (issue 15)

    .venv/bin/python scripts/failure_kinds.py POLICY MAP_YAML [MAP_YAML ...] [--episodes 128] [--seed 12345]
        [--json OUT]

On each map, the fixed episodes ``flashnav eval POLICY --maps MAP --episodes N --seed S`` plays (goals by path
length) are played by the deterministic policy and, from the same starts and goals, by the map-aware oracle
(:class:`flashnav.sim.oracle.OracleController`: it follows the shortest grid path, so its step count is what the
route costs this robot's motion limits). Every policy failure is then one of:

* ``collision``;
* ``near miss``: a timeout that came within 0.1 m of the goal radius;
* ``stalled``: a timeout that drove under 0.5 m in the second half of the horizon (parked);
* ``long route``: a timeout on an episode the oracle too needed over 75 % of the horizon for, or failed;
* ``wandered``: any other timeout - the route was short enough and the robot kept driving elsewhere.

A memory of where the robot has been (``observation.pose_trail``) is for the last two kinds of a stall and a
wander; the horizon, not the policy, limits ``long route``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from flashnav.evaluate import evaluate_episodes
from flashnav.export import evaluated_robot, load_policy
from flashnav.sim.env import make_env
from flashnav.sim.oracle import OracleController
from flashnav.names import EVAL_SEED

STALL_M = 0.5  # metres driven in the second half of the horizon under which a timeout "stalled"
NEAR_M = 0.1  # a timeout this close to the goal radius is a near miss
LONG = 0.75  # a route the oracle needs more than this share of the horizon for is "long"
KINDS = ("collision", "near miss", "stalled", "long route", "wandered")


def drive(env, act, start: torch.Tensor, goal: torch.Tensor):
    """Plays every slot of ``env`` from ``start [n, 3]`` / ``goal [n, 2]`` (world frame) with ``act(obs)``
    until each one's first episode ends: per slot success [n] bool, steps [n], path [T + 1, n, 2] (NaN after
    its end)."""
    obs = env.set_state(start, goal)
    horizon = env.preset.episode.horizon
    n = len(goal)
    path = np.full((horizon + 1, n, 2), np.nan)
    done, success, steps = np.zeros(n, bool), np.zeros(n, bool), np.full(n, horizon)
    for t in range(horizon):
        path[t, ~done] = env.world_pose()[~torch.as_tensor(done), :2].numpy()
        obs, _, terminated, truncated, info = env.step(act(obs))
        end = (terminated | truncated).numpy() & ~done
        success[end], steps[end] = info["success"].numpy()[end], t + 1
        done |= end
        if done.all():
            break
    return success, steps, path


def classify(outcome: str, closest: float, late: float, oracle_steps: int, oracle_ok: bool, preset) -> str:
    """One failure's kind (see the module docstring)."""
    if outcome == "collision":
        return "collision"
    if closest < preset.episode.goal_threshold + NEAR_M:
        return "near miss"
    if late < STALL_M:
        return "stalled"
    if not oracle_ok or oracle_steps > LONG * preset.episode.horizon:
        return "long route"
    return "wandered"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy")
    p.add_argument("maps", nargs="+", metavar="MAP_YAML")
    p.add_argument("--episodes", type=int, default=128, help="episodes per map")
    p.add_argument("--seed", type=int, default=EVAL_SEED)
    p.add_argument("--json", help="write each map's counts and every failure here")
    args = p.parse_args()
    torch.set_num_threads(1)
    policy, meta = load_policy(args.policy)
    preset = evaluated_robot(meta, **{"episode.goal_sampling": "geodesic"})
    horizon = preset.episode.horizon
    rows, total = [], dict.fromkeys(("episodes", "success", *KINDS), 0)
    for map_path in args.maps:
        env = make_env(preset, args.episodes, map=map_path, seed=args.seed)
        e = evaluate_episodes(policy, env, args.seed)
        start, goal = e["start_pose"], e["goal"]
        oracle_env = make_env(preset, args.episodes, map=map_path, seed=0)
        oracle_env.reset(seed=0)
        oracle = OracleController(oracle_env)

        def oracle_act(_obs):
            return oracle.act()

        oracle_env.set_state(start, goal)
        oracle.plan()
        o_ok, o_steps, _ = drive(oracle_env, oracle_act, start, goal)
        failed = np.nonzero(~e["success"].numpy())[0]
        kinds = []
        if len(failed):
            replay = make_env(preset, len(failed), map=map_path, seed=0)
            replay.reset(seed=0)
            _, _, path = drive(replay, policy, start[failed], goal[failed])
            for j, k in enumerate(failed):
                track = path[:, j][~np.isnan(path[:, j, 0])]
                closest = float(np.linalg.norm(track - goal[k].numpy(), axis=1).min())
                late = float(np.linalg.norm(np.diff(track[-(horizon // 2 + 1):], axis=0), axis=1).sum())
                outcome = "collision" if bool(e["collision"][k]) else "timeout"
                kinds.append({"index": int(k), "kind": classify(outcome, closest, late, int(o_steps[k]), bool(o_ok[k]),
                                                                preset),
                              "closest_m": round(closest, 3), "late_m": round(late, 3),
                              "oracle_steps": int(o_steps[k]), "oracle_success": bool(o_ok[k])})
        counts = {kind: sum(f["kind"] == kind for f in kinds) for kind in KINDS}
        row = {"map": Path(map_path).stem, "episodes": args.episodes, "success": int(e["success"].sum()),
               **counts, "oracle_success": float(o_ok.mean()), "oracle_steps_mean": float(o_steps[o_ok].mean()),
               "oracle_over_long": int((o_steps > LONG * horizon).sum()), "failures": kinds}
        rows.append(row)
        for key in total:
            total[key] += row[key]
        print(f"{row['map']}: success {row['success']}/{args.episodes}; "
              + ", ".join(f"{kind} {counts[kind]}" for kind in KINDS)
              + f" | oracle {row['oracle_success']:.1%}, mean {row['oracle_steps_mean']:.0f} steps, "
                f"{row['oracle_over_long']} over {LONG:.0%} of the horizon", flush=True)
    print(f"all {len(rows)} maps: success {total['success']}/{total['episodes']} "
          f"({total['success'] / max(total['episodes'], 1):.1%}); "
          + ", ".join(f"{kind} {total[kind]}" for kind in KINDS))
    if args.json:
        Path(args.json).write_text(json.dumps({"policy": args.policy, "seed": args.seed, "maps": rows,
                                               "total": total}, indent=1), encoding="utf-8")
        print(f"json: {args.json}")


if __name__ == "__main__":
    main()
