"""Train behind the people shield: ``flashnav train`` with the shield of ``flashnav eval --shield`` in the collector
(issue 13, done-means 3; docs/benchmarks.md "Trained with the shield in the loop").

    .venv/bin/python scripts/shield_in_loop.py [--lookahead 2] [--penalty 0] -- train ARGS...   # flashnav train's

Every vector step of collection, the training env's agents as its tracker sees them
(:class:`flashnav.shield.SimShield`) go through :class:`flashnav.shield.PeopleShield` with the policy's action: the
env plays the shield's action and the replay stores it (the executed action). ``--penalty P`` is subtracted from the
reward of each step on which the shield took over (the policy's own action predicted a contact with an agent). The
runs' own evaluations are of the policy alone; ``flashnav eval POLICY --scenario all --shield S`` puts it behind the
shield again. Measured, and not adopted: no option of the package trains this way. A diagnostic, not a recipe: it
wraps the training loop's env class and learner factory (``flashnav.learn.loop``) for the one process it runs.
"""

from __future__ import annotations

import argparse
import sys

import torch

import flashnav.learn.loop as loop
from flashnav.shield import PeopleShield, SimShield


class _Shielded:
    """The training env (the first env the loop builds) and its shield; the other envs (evaluation) are left alone."""

    def __init__(self, lookahead: float, penalty: float):
        self.lookahead, self.penalty = lookahead, penalty
        self.env = self.guard = self.took_over = None

    def attach(self, env) -> None:
        if self.env is None:
            if env.agents is None:
                raise ValueError("the shield in the loop needs agents in training (robot.agents.count=K)")
            self.env, self.guard = env, SimShield(env, PeopleShield(env.preset, self.lookahead))

    def act(self, action: torch.Tensor) -> torch.Tensor:
        out = self.guard(torch.arange(self.env.num_envs, device=action.device), action)
        self.took_over = self.guard.took_over
        return out

    def after_step(self, reward: torch.Tensor, ended: torch.Tensor) -> torch.Tensor:
        self.guard.forget(ended)   # the env restarted the ended slots
        if self.penalty and self.took_over is not None:
            reward = reward - self.penalty * self.took_over.float()
        return reward


def install(lookahead: float, penalty: float) -> _Shielded:
    """Wrap ``flashnav.learn.loop``'s env class and learner factory for this process; returns the shield's state."""
    state = _Shielded(lookahead, penalty)
    base_env, base_learner = loop.NavVecEnv, loop.run_learner

    class ShieldedEnv(base_env):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            state.attach(self)

        def step(self, actions):
            obs, reward, terminated, truncated, info = super().step(actions)
            if self is state.env:
                reward = state.after_step(reward, terminated | truncated)
            return obs, reward, terminated, truncated, info

    def run_learner(*args, **kwargs):
        learner = base_learner(*args, **kwargs)
        act = learner.act
        learner.act = lambda obs: state.act(act(obs))   # the collector's action; evaluations use learner.policy
        return learner

    loop.NavVecEnv, loop.run_learner = ShieldedEnv, run_learner
    return state


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv:
        raise SystemExit("usage: shield_in_loop.py [--lookahead S] [--penalty P] -- train ARGS...")
    cut = argv.index("--")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lookahead", type=float, default=2.0, help="the shield's look-ahead, s (flashnav eval --shield)")
    ap.add_argument("--penalty", type=float, default=0.0, help="subtracted from the reward of each take-over step")
    args = ap.parse_args(argv[:cut])
    if not args.lookahead > 0 or args.penalty < 0:
        raise SystemExit(f"--lookahead must be > 0 and --penalty >= 0, got {args.lookahead} and {args.penalty}")
    rest = argv[cut + 1:]
    if not rest or rest[0] != "train":
        raise SystemExit(f"after --: flashnav train's arguments, starting with 'train'; got {' '.join(rest)!r}")
    state = install(args.lookahead, args.penalty)
    from flashnav.cli import main as flashnav_main

    rc = flashnav_main(rest)
    if state.guard is not None:
        print(f"shield in the loop: took over {state.guard.overruled / max(state.guard.steps, 1):.1%} of the "
              f"{state.guard.steps:,} collected steps")
    return rc


if __name__ == "__main__":
    sys.exit(main())
