"""What does a policy command at the first step of each evaluation episode? (issue 16, docs/benchmarks.md
"Go2: wider networks, ten seeds")

    .venv/bin/python scripts/start_actions.py POLICY [POLICY ...] [--episodes 1024] [--seed 12345]

For each exported POLICY, on the fixed evaluation set ``flashnav train`` evaluates on (``--episodes`` start/goal
pairs, evaluation seed ``--seed``, the policy's robot and bundled map), the deterministic action at each episode's
first observation: the share of starts where it turns on the spot (forward command ``a_v <= -0.9``: under 5 % of top
speed; the action is in [-1, 1], -1 = stand still) or drives at top speed (``a_v >= 0.99``), and the mean
|turn command|, split by whether the goal lies ahead (within 90 deg of the start heading) or behind, and the share of
starts where each command is saturated (``|a| >= 0.999``: the actor's pre-tanh output beyond 3.8, where tanh passes on
under 0.2 % of its gradient). A policy that drives off at speed from starts facing a wall collides in its first steps;
a healthy one turns first.
"""

from __future__ import annotations

import argparse

import numpy as np

from flashnav.export import evaluated_robot, load_policy
from flashnav.sim.env import make_env
from flashnav.names import EVAL_EPISODES, EVAL_SEED

TURN_ON_SPOT = -0.9  # a_v at or below this: under 5 % of the top forward speed (the range [-1, 1] maps to [0, v_max])
TOP_SPEED = 0.99
SATURATED = 0.999  # |tanh(mu)| >= this: |mu| >= 3.8, d tanh / d mu <= 0.002


def start_actions(policy, preset, episodes: int, seed: int) -> dict:
    """The deterministic first action of every episode of the fixed evaluation set, summarised (see the module)."""
    env = make_env(preset, episodes, seed=seed)
    obs, _ = env.reset(seed=seed)  # the set's episodes, as flashnav.evaluate.evaluate_episodes draws them
    action = np.asarray(policy(obs))
    a_v, a_w = action[:, 0], action[:, 1]
    start, goal = env.world_pose().cpu().numpy(), env.world_goal().cpu().numpy()
    to_goal = np.arctan2(goal[:, 1] - start[:, 1], goal[:, 0] - start[:, 0]) - start[:, 2]
    ahead = np.abs((to_goal + np.pi) % (2 * np.pi) - np.pi) < np.pi / 2
    out = {"episodes": episodes}
    for name, sel in (("all", np.ones_like(ahead)), ("goal ahead", ahead), ("goal behind", ~ahead)):
        out[name] = {"starts": int(sel.sum()), "turn_on_spot": float(np.mean(a_v[sel] <= TURN_ON_SPOT)),
                     "top_speed": float(np.mean(a_v[sel] >= TOP_SPEED)), "mean_abs_turn": float(np.mean(np.abs(a_w[sel]))),
                     "saturated_v": float(np.mean(np.abs(a_v[sel]) >= SATURATED)),
                     "saturated_w": float(np.mean(np.abs(a_w[sel]) >= SATURATED))}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy", nargs="+")
    p.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    p.add_argument("--seed", type=int, default=EVAL_SEED, help="evaluation seed (flashnav train's eval.seed)")
    args = p.parse_args()
    print(f"{'policy':45s} {'starts':>12s} {'n':>5s} {'turn on spot':>13s} {'top speed':>10s} {'|turn|':>7s} {'sat v':>6s} {'sat w':>6s}")
    for path in args.policy:
        policy, meta = load_policy(path)
        # the policy's own preset (its observation options), evaluated with the paper's reward and episodes
        r = start_actions(policy, evaluated_robot(meta), args.episodes, args.seed)
        for name in ("all", "goal ahead", "goal behind"):
            s = r[name]
            print(f"{path[-45:]:45s} {name:>12s} {s['starts']:5d} {s['turn_on_spot']:13.1%} {s['top_speed']:10.1%} "
                  f"{s['mean_abs_turn']:7.3f} {s['saturated_v']:6.1%} {s['saturated_w']:6.1%}")


if __name__ == "__main__":
    main()
