"""What does the critic think of a parked robot? (issue 16, items 3 and 4)

    .venv/bin/python scripts/stall_values.py RUN_DIR [--episodes 1024] [--seed 12345] [--step 100] [--samples K]
                                             [--trace EPISODE]

Loads a FastDSAC run's final learner (``RUN_DIR/checkpoint.pt`` with its ``config.yaml``), evaluates its final
deterministic actor on the fixed set ``flashnav train`` evaluates on (``--episodes`` start/goal pairs, evaluation
seed ``--seed``, the run's robot on its bundled map), replays the failed episodes alone and, at step ``--step``,
prints the critic's value (the smaller of the twin critics' means, the target the actor climbs) of the actor's own
action, of the best action on a 21 x 21 grid over [-1, 1]^2, of driving straight at top speed, and of turning in
place at full rate either way, beside the goal distance and bearing. A parked robot whose critic rates turning and
driving no better than staying put is a value problem (how far the discount sees), not an actor stuck on a slope.

``--samples K`` also replays each failed episode K times with the *stochastic* policy (the tanh-Gaussian the learner
trains and collects with, DEM scale 1) and prints how often it succeeds, beside the actor's mean action and spread
at the start: a start the stochastic policy solves almost always, but its mean action does not, is a deterministic
actor that sits between two ways round (a mode-averaging mean), not a start the policy cannot solve.

``--trace EPISODE`` replays that evaluation episode alone with the deterministic actor and prints, every step for
``--step`` steps, the goal's distance and bearing, the speed, the actor's action and the nearest sector's range: a
robot that turns back and forth between two bearings sits on an attracting fixed point of its own turn command.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
import yaml

from flashnav.checkpoint import load_checkpoint
from flashnav.evaluate import evaluate_episodes, play_episodes
from flashnav.learn.fastdsac import policy_log_std, sample
from flashnav.learn.loop import run_learner
from flashnav.sim.env import make_env
from flashnav.spec import RunSpec
from flashnav.names import EVAL_EPISODES, EVAL_SEED


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", help="a flashnav train --out directory of a FastDSAC run")
    p.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    p.add_argument("--seed", type=int, default=EVAL_SEED, help="evaluation seed (flashnav train's eval.seed)")
    p.add_argument("--step", type=int, default=100, help="the replay step at which the critic is read")
    p.add_argument("--samples", type=int, default=0, help="stochastic replays of each failed episode (0: none)")
    p.add_argument("--trace", type=int, default=None, metavar="EPISODE",
                   help="print that evaluation episode step by step (deterministic actor, --step steps)")
    args = p.parse_args()
    run = Path(args.run)
    spec = RunSpec.from_dict(yaml.safe_load((run / "config.yaml").read_text()))
    if spec.algorithm != "fastdsac":
        raise SystemExit(f"{run}: a {spec.algorithm} run; this reads FastDSAC's Gaussian critic means")
    learner = run_learner(spec, "cpu")
    learner.load_state_dict(load_checkpoint(run / "checkpoint.pt")["learner"])
    actor, critic = learner.state.actor, learner.state.critic

    def policy(obs):
        return torch.tanh(actor(obs)[..., :2])

    def value(obs, action):  # min over the twin critics of the Gaussian mean
        return critic(obs, action)[..., 0].min(0).values

    env = make_env(spec.robot.name, args.episodes, seed=args.seed)
    with torch.no_grad():
        e = {k: v.cpu().numpy() for k, v in evaluate_episodes(policy, env, args.seed).items()}
        failed = np.nonzero(~e["success"])[0]
        print(f"{run}: final actor, {args.episodes} episodes, success {e['success'].mean():.2%}; "
              f"failed: {', '.join(f'#{k}' for k in failed) or 'none'}")
        if args.trace is not None:
            trace(policy, spec.robot.name, e, args.trace, args.step)
        if not len(failed):
            return
        if args.samples > 0:
            stochastic(actor, learner.state.hp, spec.robot.name, e, failed, args.samples)
        replay, obs = placed(spec.robot.name, e, failed)
        axis = torch.linspace(-1, 1, 21)
        grid = torch.stack(torch.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
        named = {"drive straight": (1.0, 0.0), "turn left in place": (-1.0, 1.0), "turn right in place": (-1.0, -1.0)}
        for _ in range(args.step):
            obs = replay.step_slots(torch.arange(len(failed)), policy(obs))["obs"]
        action = policy(obs)
        print(f"at step {args.step} (actions normalised: v -1 = stop, +1 = 0.5 m/s; w +-1 = +-pi/4 rad/s):")
        for j, k in enumerate(failed):
            q = value(obs[j:j + 1].expand(len(grid), -1), grid)
            best = int(q.argmax())
            fixed = {name: value(obs[j:j + 1], torch.tensor([a])).item() for name, a in named.items()}
            print(f"  #{k}: goal {obs[j, 30]:.2f} m at {obs[j, 31]:+.2f} rad, speed {obs[j, 32]:.2f} m/s; "
                  f"Q(actor's ({action[j, 0]:+.2f}, {action[j, 1]:+.2f})) {value(obs[j:j + 1], action[j:j + 1]).item():.3f}, "
                  f"best on the grid {q[best]:.3f} at ({grid[best, 0]:+.1f}, {grid[best, 1]:+.1f}), "
                  + ", ".join(f"{name} {v:.3f}" for name, v in fixed.items()))


def placed(robot: str, e: dict, episodes: np.ndarray):
    """An env with one slot per entry of ``episodes`` (indices into the evaluation ``e``), each placed at
    that episode's start and goal; returns (env, observations)."""
    env = make_env(robot, len(episodes), seed=0)
    env.reset(seed=0)
    return env, env.set_state(torch.as_tensor(e["start_pose"][episodes]), torch.as_tensor(e["goal"][episodes]))


def trace(policy, robot: str, e: dict, episode: int, steps: int) -> None:
    """Replay evaluation episode ``episode`` alone with ``policy`` and print every step."""
    if not 0 <= episode < len(e["success"]):
        raise SystemExit(f"--trace {episode}: the evaluation has episodes 0-{len(e['success']) - 1}")
    env, obs = placed(robot, e, np.array([episode]))
    print(f"episode #{episode} ({'success' if e['success'][episode] else 'failed'} in the evaluation), "
          f"start pose {np.round(e['start_pose'][episode], 3).tolist()}, goal {np.round(e['goal'][episode], 3).tolist()}:")
    for t in range(steps):
        action = policy(obs)
        print(f"  step {t:3d}: goal {obs[0, 30]:.2f} m at {obs[0, 31]:+.2f} rad, speed {obs[0, 32]:.2f} m/s, "
              f"action ({action[0, 0]:+.2f}, {action[0, 1]:+.2f}), nearest sector {obs[0, :30].min():.2f} m")
        out = env.step_slots(torch.arange(1), action)
        if bool(out["terminated"][0] | out["truncated"][0]):
            print(f"  ended at step {t + 1}: {'success' if out['success'][0] else 'collision' if out['collision'][0] else 'timeout'}")
            break
        obs = out["obs"]


def stochastic(actor, hp, robot: str, e: dict, failed: np.ndarray, k: int) -> None:
    """Replay each failed episode ``k`` times with sampled actions; print the success rate per episode."""
    env, obs = placed(robot, e, np.repeat(failed, k))
    mu, log_std = policy_log_std(actor(obs[::k]), hp)
    gen = torch.Generator().manual_seed(0)
    out = play_episodes(lambda o: sample(actor, o, hp, gen)[0], env, obs)
    won = out["success"].view(len(failed), k).float().mean(1)
    print(f"stochastic replays ({k} per failed episode; start: the actor's tanh(mean) and pre-tanh std per action):")
    for j, ep in enumerate(failed):
        a, sd = torch.tanh(mu[j]), log_std[j].exp()
        print(f"  #{ep}: success {won[j]:.0%}; start action ({a[0]:+.2f}, {a[1]:+.2f}), std ({sd[0]:.2f}, {sd[1]:.2f})")


if __name__ == "__main__":
    main()
