"""Deterministic evaluation and time-to-threshold bookkeeping.

Protocol: the evaluation environment is reset with a fixed seed, so every evaluation (of every run and
every training seed) plays the same E start/goal pairs; each slot's *first* episode counts; success =
the goal reached before a collision or the horizon.
"""

from __future__ import annotations

from typing import Callable

import torch

from flashnav.metrics import THRESHOLDS, reaches
from flashnav.sim.env import NavVecEnv

#: An evaluation lists its failed episodes' indices (``failed_episodes``) when at most this many failed.
FAILED_LISTED_MAX = 32

#: A timeout "stalled" when its robot drove less than this, metres, in the second half of the horizon (of the 5 m a
#: TurtleBot2's top speed allows there): a deterministic policy parked in front of an obstacle or turning back and
#: forth on the spot, where the other timeouts wandered (docs/benchmarks.md "The last 0.1-1 %: parked robots and the
#: discount")
STALL_M = 0.5


@torch.no_grad()
def evaluate(policy: Callable[[torch.Tensor], torch.Tensor], env: NavVecEnv, seed: int, *,
             dense: bool = False) -> dict[str, float]:
    """Run one episode per slot of ``env`` with the deterministic ``policy`` (obs [k, D] -> action [k, 2]).

    Only the slots whose episode is still running are simulated (``env.step_slots``, no autoreset):
    an evaluation costs the sum of its episodes' lengths, not slots x the longest episode, and the
    finished slots are never re-sampled. ``dense=True`` is the plain way, kept as the benchmark
    baseline (``flashnav bench eval``) and the tests' reference: every slot steps (and autoresets)
    until each has finished once. Returns success_rate, collision_rate, timeout_rate (fractions of the
    N episodes), mean_return (undiscounted), mean_steps and failed_episodes (:func:`episode_rates`).
    """
    if dense:
        return _evaluate_dense(policy, env, seed)
    e = evaluate_episodes(policy, env, seed)
    return episode_rates(e["success"], e["collision"], e["episode_return"], e["episode_steps"])


def evaluate_episodes(policy: Callable[[torch.Tensor], torch.Tensor], env: NavVecEnv,
                      seed: int) -> dict[str, torch.Tensor]:
    """:func:`evaluate`'s episodes one by one: ``success`` / ``collision`` / ``collision_agent`` (the
    collision was with a moving agent) [N] bool, ``episode_return``
    and ``episode_steps`` [N] float, each episode's ``start_pose`` [N, 3] / ``goal`` [N, 2] in the
    map's own (world) frame, and ``max_goal_distance`` [N] float (metres: the largest goal distance the
    policy was given, start included). Slot k holds the k-th episode of the set that ``seed`` draws."""
    obs, _ = env.reset(seed=seed)
    return play_episodes(policy, env, obs)


@torch.no_grad()
def play_episodes(policy: Callable[[torch.Tensor], torch.Tensor], env: NavVecEnv,
                  obs: torch.Tensor, guide=None, shield=None) -> dict[str, torch.Tensor]:
    """:func:`evaluate_episodes` from the episodes already placed in ``env`` (by ``reset`` or
    ``set_state``; ``obs`` [N, D] their observations): one episode per slot, same returns. ``guide``:
    a :class:`flashnav.guidance.PathGuide` whose carrots the policy sees instead of the goals (the
    recorded goal distances stay the environment's). ``shield``: a callable (running slots [k], actions [k, A])
    -> actions played instead (:class:`flashnav.shield.SimShield`).

    Also ``late_m`` [N]: metres each episode's robot drove in the steps of the horizon's second half (the last
    ``horizon // 2`` steps of a timeout; 0 for an episode that ended before them), what :func:`stalled` reads."""
    start_pose, goal = env.world_pose(), env.world_goal()
    n, dev = env.num_envs, env.device
    horizon = env.preset.episode.horizon
    late_from = horizon - horizon // 2  # the first step whose driving counts towards late_m
    late = torch.zeros(n, device=dev)
    xy = env.pose[:, :2].clone()
    col = env.preset.lidar.sectors  # the goal-distance column
    success = torch.zeros(n, dtype=torch.bool, device=dev)
    collision = torch.zeros(n, dtype=torch.bool, device=dev)
    collision_agent = torch.zeros(n, dtype=torch.bool, device=dev)
    returns = torch.zeros(n, device=dev)
    steps = torch.zeros(n, device=dev)
    max_goal = obs[:, col].clone()
    active = torch.arange(n, device=dev)
    for step in range(horizon):
        action = policy(obs if guide is None else guide.observe(obs, active))
        t = env.step_slots(active, action if shield is None else shield(active, action))
        if step >= late_from:
            late[active] += torch.linalg.vector_norm(t["pose"][:, :2] - xy[active], dim=1)
        xy[active] = t["pose"][:, :2]
        max_goal[active] = torch.maximum(max_goal[active], t["obs"][:, col])
        done = t["terminated"] | t["truncated"]
        ended = active[done]
        success[ended] = t["success"][done]
        collision[ended] = t["collision"][done]
        collision_agent[ended] = t["collision_agent"][done]
        returns[ended] = t["episode_return"][done]
        steps[ended] = t["episode_steps"][done].float()
        running = ~done
        active, obs = active[running], t["obs"][running]
        if active.numel() == 0:  # a host sync per step: evaluation is outside the training clock
            break
    return {"success": success, "collision": collision, "collision_agent": collision_agent,
            "episode_return": returns, "episode_steps": steps,
            "start_pose": start_pose, "goal": goal, "max_goal_distance": max_goal, "late_m": late}


def stalled(e: dict[str, torch.Tensor]) -> torch.Tensor:
    """[N] bool: the episodes of :func:`play_episodes`' ``e`` that timed out (neither success nor collision) with
    their robot having driven under :data:`STALL_M` metres in the second half of the horizon."""
    return ~e["success"] & ~e["collision"] & (e["late_m"] < STALL_M)


def _evaluate_dense(policy, env: NavVecEnv, seed: int) -> dict[str, float]:
    obs, _ = env.reset(seed=seed)
    n, dev = env.num_envs, env.device
    finished = torch.zeros(n, dtype=torch.bool, device=dev)
    success, collision = torch.zeros_like(finished), torch.zeros_like(finished)
    returns, steps = torch.zeros(n, device=dev), torch.zeros(n, device=dev)
    for _ in range(env.preset.episode.horizon):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        first = (terminated | truncated) & ~finished
        success |= first & info["success"]
        collision |= first & info["collision"]
        returns = torch.where(first, info["episode_return"], returns)
        steps = torch.where(first, info["episode_steps"].float(), steps)
        finished |= first
    return episode_rates(success, collision, returns, steps)


def episode_rates(success, collision, returns, steps) -> dict[str, float | list[int] | None]:
    """The rates :func:`evaluate` returns, from one outcome per episode ([N] bool / float tensors), and
    ``failed_episodes``: the indices of the episodes that did not succeed (episode k = slot k of the set),
    ascending, or None where more than :data:`FAILED_LISTED_MAX` failed - which episodes a policy near 100 %
    keeps failing, evaluation after evaluation."""
    failed = (~success).nonzero().flatten()
    return {
        "success_rate": success.float().mean().item(),
        "collision_rate": collision.float().mean().item(),
        "timeout_rate": (~success & ~collision).float().mean().item(),
        "mean_return": returns.mean().item(),
        "mean_steps": steps.mean().item(),
        "failed_episodes": failed.tolist() if failed.numel() <= FAILED_LISTED_MAX else None,
    }


class TrainingEpisodes:
    """The success of the most recent *training* episodes (the collection policy's, exploration included):
    the rolling count some reference codes log instead of evaluating (docs/learners.md, S1). Episodes are
    counted on the env's device without a host sync per step, in windows that :meth:`take` closes (one per
    evaluation); a reading pools the newest whole windows until they hold at least ``pool`` episodes.

    It cannot see what never ends during training: an environment slot lives ``total_env_steps /
    num_envs`` steps in a whole run (196 in the paper's TurtleBot2 recipe, under its 200-step horizon),
    so no training episode there ever times out."""

    def __init__(self, device: torch.device | str, pool: int = 100):
        if pool < 1:
            raise ValueError(f"pool must be >= 1 training episodes, got {pool}")
        self.pool = pool
        self._ended = torch.zeros((), dtype=torch.long, device=device)
        self._succeeded = torch.zeros((), dtype=torch.long, device=device)
        self._windows: list[tuple[int, int]] = []  # (ended, succeeded), oldest first

    def add(self, done: torch.Tensor, success: torch.Tensor) -> None:
        """One vector step: ``done`` [N] bool (terminated or truncated), ``success`` [N] bool."""
        self._ended += done.sum()
        self._succeeded += (done & success).sum()

    def take(self) -> dict[str, float | int | None]:
        """Close the window: ``train_episodes`` pooled (the newest whole windows holding >= ``pool``
        episodes, or all so far) and their ``train_success_rate`` (None while fewer than ``pool`` ended)."""
        self._windows.append((int(self._ended), int(self._succeeded)))
        self._ended.zero_()
        self._succeeded.zero_()
        while len(self._windows) > 1 and sum(e for e, _ in self._windows[1:]) >= self.pool:
            self._windows.pop(0)
        ended = sum(e for e, _ in self._windows)
        succeeded = sum(k for _, k in self._windows)
        return {"train_episodes": ended, "train_success_rate": succeeded / ended if ended >= self.pool else None}


class ThresholdTracker:
    """First training time and env step at which the success rate reached each threshold.

    The incremental form of :func:`flashnav.metrics.first_crossing`, fed one evaluation at a time
    by the training loop (which stops at a success target, so it needs the crossing as it happens).
    """

    def __init__(self, thresholds=THRESHOLDS):
        self.seconds: dict[float, float | None] = {t: None for t in thresholds}
        self.env_steps: dict[float, int | None] = {t: None for t in thresholds}

    def update(self, success_rate: float, train_seconds: float, env_steps: int) -> list[float]:
        """Record an evaluation; returns the thresholds reached for the first time."""
        new = []
        for t in self.seconds:
            if self.seconds[t] is None and reaches(success_rate, t):
                self.seconds[t], self.env_steps[t] = train_seconds, env_steps
                new.append(t)
        return new
