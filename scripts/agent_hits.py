"""How often do the moving agents hit the robot, and from where? (issue 13, done-means 3)

    .venv/bin/python scripts/agent_hits.py [POLICY ...] [--episodes 1024] [--seed 2026] [--scenario wander-8]

First a robot that stands still (action v = 0, w = 0) on the episodes of every agent scenario
(:mod:`flashnav.scenarios`): the share of them in which an agent walks into it within the horizon - the
hits that no policy avoids without moving out of the way. Then, for each exported POLICY, its episodes of
``--scenario`` played with its deterministic actions, and for each agent collision the bearing of the
agent that hit, relative to the robot's heading at the moment of contact: behind the LiDAR's field of view,
from the side (45-135 deg) or from the front (within 45 deg); and the forward speed it commands (mean over
every step played, and the share of steps below 0.1 m/s: a hesitant robot stays longer among the agents);
and the hitting agents' behaviours and how many of them turned (> 20 deg) in the second before the contact,
beside how often any moving agent does in a second: are the hits the agents' turns? And when the tracker (the
agent tracks of the observation, :mod:`flashnav.sim.tracks`) last saw the hitting agent: in the observation the
robot acted on last, some steps before (lost from sight: what a track that outlives the field of view would still
hold), or never in the episode (what only an all-round sensor would have seen).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from flashnav.export import load_policy, recorded_robot
from flashnav.names import AGENT_BEHAVIOURS, EVAL_EPISODES, SCENARIOS
from flashnav.scenarios import run_scenario, scenario_preset
from flashnav.sim.env import make_env
from flashnav.sim.motion import action_to_velocity
from flashnav.sim.tracks import TrackerView


TURN_STEPS = 10  # steps back over which an agent's turn before a contact is read (1 s at dt 0.1)
TURNED = 20.0  # degrees: a heading change above this counts as a turn


def stand_still(preset) -> torch.Tensor:
    """The action [1, 2] that maps to v = 0, w = 0 on ``preset`` (the action bounds may be asymmetric)."""
    m = preset.motion
    to_action = lambda x, lo, hi: 2.0 * (x - lo) / (hi - lo) - 1.0  # noqa: E731
    return torch.tensor([[to_action(0.0, *m.v_bounds), to_action(0.0, *m.w_bounds)]])


def hit_bearings(policy, preset, episodes: int, seed: int, speeds: list | None = None,
                 hitters: list | None = None, base: dict | None = None, sight: list | None = None) -> list[float]:
    """Degrees in [0, 180]: |bearing| of the hitting agent (the one nearest the footprint) per agent collision.
    ``speeds``, if given, collects the forward speed (m/s) the policy commands at every step played;
    ``hitters`` (kind, turn) per collision: the hitting agent's behaviour and how far its heading turned
    (degrees) between the step ``TURN_STEPS`` before the contact and the contact's step (None: too early in
    the episode, or the agent stood still in one of the two steps); ``base`` counts the same for every moving
    agent of the running slots at every step (``known``, ``turned`` > ``TURNED``): how often agents turn at all;
    ``sight`` per collision: how many observations before the last one the robot acted on the tracker last saw the
    hitting agent (0: in that last one; None: not once in the episode)."""
    env = make_env(preset, episodes, seed=seed)
    obs, _ = env.reset(seed=seed)
    active, out = torch.arange(episodes), []
    view = TrackerView(preset, env.beam_angles) if sight is not None else None
    last_seen = torch.full(env.agents.pos.shape[:2], -1, dtype=torch.long)  # observation index, -1: not yet

    def look(index: int, slots: torch.Tensor) -> None:  # the tracker's view in observation ``index`` of ``slots``
        if view is not None and slots.numel():
            a = env.agents
            seen = view.seen_by(env.pose[slots], a.pos[slots], a.radius[slots], a.active[slots], env.scan(slots))
            last_seen[slots] = torch.where(seen, index, last_seen[slots])

    look(0, active)
    past = [env.agents.pos.clone()]  # agent centres after each step (every slot), newest last
    for step in range(1, preset.episode.horizon + 1):  # acting on observation step - 1
        action = policy(obs)
        if speeds is not None:
            speeds.extend(action_to_velocity(action, preset.motion)[0].tolist())
        t = env.step_slots(active, action)
        past = (past + [env.agents.pos.clone()])[-(TURN_STEPS + 2):]
        turns = agent_turns(past) if hitters is not None or base is not None else None
        if base is not None and turns is not None:  # every moving agent of the running slots, this step
            turn, known = turns
            moving = known[active] & env.agents.active[active]
            base["known"] = base.get("known", 0) + int(moving.sum())
            base["turned"] = base.get("turned", 0) + int((moving & (turn[active] > TURNED)).sum())
        for i in active[t["collision_agent"]].tolist():
            d = env.agents.pos[i] - env.pose[i, :2]
            gap = torch.linalg.vector_norm(d, dim=1) - env.agents.radius[i]
            gap = torch.where(env.agents.active[i], gap, torch.full_like(gap, math.inf))
            j = int(gap.argmin())
            b = math.atan2(float(d[j, 1]), float(d[j, 0])) - float(env.pose[i, 2])
            out.append(abs(math.degrees(math.atan2(math.sin(b), math.cos(b)))))
            if hitters is not None:
                hitters.append((AGENT_BEHAVIOURS[int(env.agents.kind[i, j])], turn_at(turns, i, j)))
            if sight is not None:
                seen_at = int(last_seen[i, j])
                sight.append(None if seen_at < 0 else step - 1 - seen_at)
        running = ~(t["terminated"] | t["truncated"])
        active, obs = active[running], t["obs"][running]
        look(step, active)
        if active.numel() == 0:
            break
    return out


def agent_turns(past: list):
    """Heading change (degrees, [0, 180]) of every agent [N, K] from its last-step displacement ``TURN_STEPS``
    steps ago to its last one, from ``past`` (agent centres [N, K, 2] after each step, newest last), and
    [N, K] whether it is known (it moved in both steps); None without enough steps."""
    if len(past) < TURN_STEPS + 2:
        return None
    now, before = past[-1] - past[-2], past[-1 - TURN_STEPS] - past[-2 - TURN_STEPS]
    known = (now.norm(dim=-1) >= 1e-6) & (before.norm(dim=-1) >= 1e-6)
    a = torch.atan2(now[..., 1], now[..., 0]) - torch.atan2(before[..., 1], before[..., 0])
    return torch.rad2deg(torch.atan2(torch.sin(a), torch.cos(a)).abs()), known


def turn_at(turns, i: int, j: int) -> float | None:
    """Agent ``j`` of slot ``i`` in :func:`agent_turns`' result; None without enough steps or where it did not move."""
    return None if turns is None or not turns[1][i, j] else float(turns[0][i, j])


def turn_degrees(past: list, i: int, j: int) -> float | None:
    """:func:`turn_at` of ``past`` (agent centres [N, K, 2] after each step, newest last)."""
    return turn_at(agent_turns(past), i, j)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("policies", nargs="*", metavar="POLICY", help="exported policy.pt / policy.onnx")
    ap.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--scenario", default="wander-8", choices=[s for s in SCENARIOS if s != "static"])
    args = ap.parse_args()
    torch.set_num_threads(1)
    for name in SCENARIOS:
        if name == "static":
            continue
        preset = scenario_preset("turtlebot2", name)
        still = stand_still(preset)
        r = run_scenario(lambda o: still.expand(o.shape[0], 2), make_env(preset, args.episodes, seed=args.seed), args.seed)
        print(f"stand still, {name}: agent collision {r['agent_collision_rate']:.1%} of {r['scored']} scored episodes")
    for path in args.policies:
        policy, meta = load_policy(path)  # the policy's own preset (e.g. its scan history), as `flashnav eval` does
        preset = scenario_preset(recorded_robot(meta), args.scenario)
        half_fov = preset.lidar.fov_deg / 2
        speeds: list[float] = []
        hitters: list = []
        base: dict = {}
        sight: list = []
        b = np.array(hit_bearings(policy, preset, args.episodes, args.seed, speeds, hitters, base, sight))
        v = np.array(speeds)
        print(f"{path} on {args.scenario}: {b.size} agent collisions in {args.episodes} episodes; agent behind the "
              f"field of view (> {half_fov:g} deg) {(b > half_fov).sum()}, side (45-{half_fov:g} deg) "
              f"{((b > 45) & (b <= half_fov)).sum()}, front (<= 45 deg) {(b <= 45).sum()}; forward speed over "
              f"{v.size} steps: mean {v.mean():.3f} m/s, {np.mean(v < 0.1):.1%} of steps below 0.1 m/s")
        print("  the hitting agents: " + "; ".join(
            f"{kind} {sum(k == kind for k, _ in hitters)} (turned > {TURNED:g} deg in the last "
            f"{TURN_STEPS * preset.episode.dt:g} s: {sum(k == kind and x is not None and x > TURNED for k, x in hitters)}, "
            f"unknown {sum(k == kind and x is None for k, x in hitters)})"
            for kind in AGENT_BEHAVIOURS if any(k == kind for k, _ in hitters))
            + f"; every moving agent at every step: turned in {base.get('turned', 0) / max(base.get('known', 0), 1):.1%}")
        second = round(1.0 / preset.episode.dt)
        lost = [x for x in sight if x]
        print(f"  the tracker saw the hitting agent: in the last observation {sum(x == 0 for x in sight)}; lost from "
              f"sight <= 1 s before {sum(x <= second for x in lost)}, 1-2 s {sum(second < x <= 2 * second for x in lost)}, "
              f"> 2 s {sum(x > 2 * second for x in lost)}; never in the episode {sum(x is None for x in sight)}")


if __name__ == "__main__":
    main()
