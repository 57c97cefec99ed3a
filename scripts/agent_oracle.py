"""Is issue 13's bar reachable at all? A clairvoyant planner on the agent scenarios (done-means 3).

    .venv/bin/python scripts/agent_oracle.py [--scenario wander-8] [--episodes 128] [--seed 2026]
        [--beam 2000] [--json OUT.json]

For each episode of a scenario (:mod:`flashnav.scenarios`, the evaluation seed's episodes, the same ones
``flashnav eval --scenario`` plays) this searches for an action sequence that reaches the goal without
touching a wall or an agent, **knowing where every agent will be at every step** - what no policy, and no
robot, knows. Non-reactive agents (the scenarios' ``reactive: 0``) move the same whatever the robot does,
so their tracks are recorded once beforehand (a crossing agent waits until it has room beside the robot:
that timing is recorded with the robot at its start, and the replay below settles it).

The search is a beam search in time: at every step each kept pose tries a grid of actions (``--v-levels``
x ``--w-levels`` of the preset's bounds), integrated by the simulator's own motion model; poses that touch
a wall (the simulator's collision checker) or an agent at that step (its footprint-disc test) are dropped;
the survivors are binned (``--bin`` m, ``--headings`` per turn) and the ``--beam`` with the shortest path to the goal through
the robot's free cells (Dijkstra on the 8-connected grid) are kept.

Every plan found is then **replayed in the simulator itself** (a fresh env, same seed), and only the
simulator's verdict counts. So the success printed is what a clairvoyant controller achieves: a lower
bound on what is possible (the search may miss a way through), not a promise about learned policies.
Episodes with no plan are played standing still and scored as the simulator scores them.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
import torch
from agent_hits import stand_still  # scripts/: the action that maps to v = 0, w = 0
from scipy.sparse.csgraph import dijkstra

from flashnav.names import SCENARIOS
from flashnav.scenarios import scenario_preset, scenario_rates, scenario_scored
from flashnav.sim.agent_geometry import footprint_hits_discs
from flashnav.sim.env import make_env
from flashnav.sim.motion import action_to_velocity, integrate
from flashnav.maps.graph import grid_graph


def agent_tracks(preset, episodes: int, seed: int, still: torch.Tensor):
    """Agent centres [H + 1, E, K, 2] and active flags [H + 1, E, K] after each step 0..H, every slot
    stepped for the whole horizon with the robot standing at its start (no reset after an ending).
    Only non-reactive agents move the same whatever the robot does; reactive ones are refused by name."""
    if preset.agents.reactive > 0:
        raise ValueError(f"agents.reactive = {preset.agents.reactive}: reactive agents move with the robot, "
                         "so their tracks cannot be recorded beforehand")
    env = make_env(preset, episodes, seed=seed)
    env.reset(seed=seed)
    idx = torch.arange(episodes)
    pos, act = [env.agents.pos.clone()], [env.agents.active.clone()]
    for _ in range(preset.episode.horizon):
        env.step_slots(idx, still.expand(episodes, 2))
        pos.append(env.agents.pos.clone())
        act.append(env.agents.active.clone())
    return torch.stack(pos), torch.stack(act)


def plan_episode(env, slot: int, field: np.ndarray, cells, pos, act, actions: torch.Tensor, beam: int,
                 cell_m: float = 0.05, headings: int = 16):
    """Normalised actions [T, 2] that reach slot ``slot``'s goal in the search, or None."""
    p = env.preset
    horizon = p.episode.horizon
    v, w = action_to_velocity(actions, p.motion)
    a_n = actions.shape[0]
    pose = env.pose[slot:slot + 1].clone()  # float32, as the simulator keeps it
    goal = env.goal[slot]
    radii = env.agents.radius[slot][None]
    parents: list[np.ndarray] = []
    choices: list[np.ndarray] = []
    for t in range(1, horizon + 1):
        s = pose.shape[0]
        new = integrate(pose.repeat_interleave(a_n, 0), v.repeat(s), w.repeat(s), p.episode.dt)
        parent = np.repeat(np.arange(s), a_n)
        choice = np.tile(np.arange(a_n), s)
        dist = torch.linalg.vector_norm(goal - new[:, :2], dim=1)
        reached = dist < p.episode.goal_threshold  # the goal is checked first (sim.reward.outcome)
        m = new.shape[0]
        hit = env._collides(new, None) | footprint_hits_discs(
            new, p.footprint, pos[t, slot][None].expand(m, -1, -1), radii.expand(m, -1), act[t, slot][None].expand(m, -1))
        if bool(reached.any()):
            k = int(torch.nonzero(reached)[0, 0])
            seq = [int(choice[k])]
            j = int(parent[k])
            for par, ch in zip(reversed(parents), reversed(choices)):
                seq.append(int(ch[j]))
                j = int(par[j])
            return actions[torch.tensor(seq[::-1])]
        keep = (~hit).nonzero().squeeze(1)
        if keep.numel() == 0:
            return None
        new, parent, choice = new[keep], parent[keep.numpy()], choice[keep.numpy()]
        xy = new[:, :2].double().numpy()
        score = field[cells(xy)]
        # a pose whose cell is off the free-cell graph (touching a wall's cell, or the goal's own
        # neighbourhood) is ranked by its straight-line distance behind every pose on the graph
        straight = dist[keep].double().numpy()  # breaks ties inside a cell: nearer the goal first
        score = np.where(np.isfinite(score), score + 0.1 * straight, 1e3 + straight)
        ix = np.floor(xy[:, 0] / cell_m).astype(np.int64)
        iy = np.floor(xy[:, 1] / cell_m).astype(np.int64)
        ih = np.floor((new[:, 2].double().numpy() + math.pi) / (2 * math.pi / headings)).astype(np.int64) % headings
        key = (ix * 100_003 + iy) * headings + ih
        order = np.argsort(score, kind="stable")
        _, first = np.unique(key[order], return_index=True)
        chosen = order[np.sort(first)][:beam]
        pose = new[torch.as_tensor(chosen)]
        parents.append(parent[chosen])
        choices.append(choice[chosen])
    return None


def replay(preset, episodes: int, seed: int, plans: list, still: torch.Tensor) -> dict:
    """Play every episode's plan (standing still where there is none, or after it ends) in a fresh env;
    scored by :func:`flashnav.scenarios.scenario_rates`, as ``flashnav eval --scenario`` scores a policy."""
    env = make_env(preset, episodes, seed=seed)
    env.reset(seed=seed)
    scored = scenario_scored(env)
    ended = {k: torch.zeros(episodes, dtype=torch.bool) for k in ("success", "collision", "collision_agent")}
    active = torch.arange(episodes)
    for t in range(preset.episode.horizon):
        a = torch.stack([plans[i][t] if plans[i] is not None and t < len(plans[i]) else still[0] for i in active.tolist()])
        r = env.step_slots(active, a)
        done = r["terminated"] | r["truncated"]
        for k, flags in ended.items():
            flags[active[done]] = r[k][done]
        active = active[~done]
        if active.numel() == 0:
            break
    return scenario_rates(ended, scored)


def path_fields(env):
    """(cells, field_of) for the episodes placed in ``env`` (one map): ``cells(xy)`` the flat cell index of
    simulator-frame points [n, 2] (float64 numpy), ``field_of(i)`` the path length (m) from every cell to slot
    ``i``'s goal through the cells where the footprint's circumscribed disc is free (inf off them; Dijkstra
    on the 8-connected grid)."""
    g = env.map
    graph = grid_graph(g.free_space(env.preset.footprint.circumscribed_radius), g.resolution)
    (x0, y0), res, (h, w) = env.frame_maps[0].origin, g.resolution, g.shape

    def cells(xy: np.ndarray) -> np.ndarray:
        j = np.clip(((xy[:, 0] - x0) / res).astype(np.int64), 0, w - 1)
        i = np.clip(((xy[:, 1] - y0) / res).astype(np.int64), 0, h - 1)
        return i * w + j

    goals = cells(env.goal.double().numpy())
    return cells, lambda i: dijkstra(graph, directed=True, indices=int(goals[i]))


def clairvoyant(preset, episodes: int, seed: int, *, beam: int = 3000, v_levels: int = 5, w_levels: int = 5,
                bin_m: float = 0.05, headings: int = 16, progress=None) -> tuple[dict, list]:
    """Search every episode of ``preset``'s scenario, then replay the plans in the simulator: (its rates,
    with ``plans_found``; the plans, [T, 2] actions or None per episode)."""
    still = stand_still(preset)
    grid = torch.cartesian_prod(torch.linspace(-1, 1, v_levels), torch.linspace(-1, 1, w_levels))
    pos, act = agent_tracks(preset, episodes, seed, still)
    env = make_env(preset, episodes, seed=seed)
    env.reset(seed=seed)
    cells, field_of = path_fields(env)
    plans: list = []
    for i in range(episodes):
        plans.append(plan_episode(env, i, field_of(i), cells, pos, act, grid, beam, bin_m, headings))
        if progress is not None:
            progress(i + 1, sum(p is not None for p in plans))
    result = replay(preset, episodes, seed, plans, still)
    result["plans_found"] = sum(p is not None for p in plans)
    return result, plans


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="wander-8", choices=[s for s in SCENARIOS if s != "static"])
    ap.add_argument("--robot", default="turtlebot2")
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--seed", type=int, default=2026, help="the evaluation seed (flashnav eval --seed)")
    ap.add_argument("--beam", type=int, default=2000, help="poses kept per step")
    ap.add_argument("--v-levels", type=int, default=3, help="forward speeds tried, evenly over the preset's bounds")
    ap.add_argument("--w-levels", type=int, default=5, help="turn rates tried, evenly over the preset's bounds")
    ap.add_argument("--bin", type=float, default=0.05, help="metres per position bin (one pose kept per bin)")
    ap.add_argument("--headings", type=int, default=16, help="heading bins per turn")
    ap.add_argument("--json", help="write the rates and settings here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    t0 = time.time()

    def progress(done: int, found: int) -> None:
        if done % 16 == 0 or done == args.episodes:
            print(f"  {done}/{args.episodes} episodes searched, plans found {found}, {time.time() - t0:.0f} s", flush=True)

    try:
        result, _ = clairvoyant(scenario_preset(args.robot, args.scenario), args.episodes, args.seed, beam=args.beam,
                                v_levels=args.v_levels, w_levels=args.w_levels, bin_m=args.bin, headings=args.headings,
                                progress=progress)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    report(result, args, t0, "clairvoyant planner", f" (plans found for {result['plans_found']})")


def report(result: dict, args, t0: float, title: str, detail: str = "") -> None:
    """Print a scenario result of the planner scripts as one line (``detail`` after the episode count) and
    write it, with every command-line setting and the seconds taken, to ``args.json`` if given."""
    result.update({k: v for k, v in vars(args).items() if k != "json"}, seconds=round(time.time() - t0, 1))
    print(f"{title}, {args.scenario}: success {result['success_rate']:.1%}, agent collision "
          f"{result['agent_collision_rate']:.1%}, wall {result['wall_collision_rate']:.1%}, timeout "
          f"{result['timeout_rate']:.1%} of {result['scored']} scored episodes{detail}; {result['seconds']} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)

if __name__ == "__main__":
    main()
