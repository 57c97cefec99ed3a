"""What can a controller do that sees only what a people tracker sees? A constant-velocity MPC on the agent
scenarios (issue 13, done-means 3).

    .venv/bin/python scripts/agent_mpc.py [--scenario wander-8] [--episodes 512] [--seed 2026]
        [--tracker lidar|all] [--lookahead 20] [--margin 0.05] [--json OUT.json]

The clairvoyant planner (``scripts/agent_oracle.py``) knows where every agent will be and reaches 99.2 % on
wander-8: the scenarios are solvable. A policy knows far less: the agents it sees now and how fast they
moved in the last step (``observation.agent_tracks``). This controller knows the same of the agents and no
more, and is otherwise generous: it knows the map (the simulator's own collision checker, and the path
length to the goal through the free cells), so its failures with agents are failures of *prediction*.

Every step, for each running episode, it rolls out ``--v-levels`` x ``--w-levels`` constant actions over
``--lookahead`` steps with the simulator's motion model, and predicts each tracked agent straight on at its
tracked velocity (the tracks the policy would get with ``observation.agent_tracks`` = the agent count;
``--tracker all``: every agent, seen or not - what a perfect tracker with no occlusion would give). A
rollout that reaches the goal before touching anything wins (soonest first); then the rollouts that touch
nothing within the look-ahead, ranked by the path length left from their end pose (plus a small penalty for
ending with the goal's path behind the heading); then the rest, the latest contact first. It plays the
first action of the best rollout and plans again at the next step (receding horizon). The episodes and the
scoring are ``flashnav eval --scenario``'s: the simulator alone says success, agent or wall collision, or
timeout.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from agent_hits import stand_still  # scripts/
from agent_oracle import agent_tracks, path_fields, report

from flashnav.names import SCENARIOS
from flashnav.presets import load_robot
from flashnav.scenarios import scenario_preset, scenario_rates, scenario_scored
from flashnav.sim.agent_geometry import footprint_hits_discs
from flashnav.sim.env import make_env
from flashnav.sim.motion import action_to_velocity, integrate
from flashnav.sim.tracks import WIDTH
from flashnav.yamlio import parse_assignment

TRACKERS = ("lidar", "all", "future")
HEADING_AHEAD = 0.3  # metres: the end pose's heading is judged by the path length this far in front of it


def tracked_agents(obs: torch.Tensor, pose: torch.Tensor, tracks: int):
    """The tracks in the last ``tracks`` x 6 columns of ``obs`` [E, D] (robot frame of ``pose`` [E, 3]) as
    simulator-frame (centres [E, M, 2], velocities [E, M, 2] m/s, radii [E, M], present [E, M])."""
    t = obs[:, obs.shape[1] - tracks * WIDTH:].reshape(-1, tracks, WIDTH)
    present = t[..., 0] > 0.5
    c, s = torch.cos(pose[:, 2:3]), torch.sin(pose[:, 2:3])
    x, y, vx, vy = t[..., 1], t[..., 2], t[..., 3], t[..., 4]
    centres = torch.stack((pose[:, 0:1] + c * x - s * y, pose[:, 1:2] + s * x + c * y), dim=-1)
    velocity = torch.stack((c * vx - s * vy, s * vx + c * vy), dim=-1)
    return centres, velocity, t[..., 5], present


class ConstantVelocityMPC:
    """The receding-horizon controller of the module docstring, for the episodes placed in ``env``."""

    def __init__(self, env, *, v_levels: int = 5, w_levels: int = 9, lookahead: int = 20, margin: float = 0.05,
                 growth: float = 0.0):
        self.env, self.preset = env, env.preset
        self.lookahead, self.margin, self.growth = lookahead, margin, growth
        self.actions = torch.cartesian_prod(torch.linspace(-1, 1, v_levels), torch.linspace(-1, 1, w_levels))
        self.v, self.w = action_to_velocity(self.actions, self.preset.motion)
        self.cells, field_of = path_fields(env)
        self.fields = np.stack([field_of(i) for i in range(env.num_envs)])  # [N, cells] m to each slot's goal
        self.goal = env.goal.clone()

    def _path_left(self, slots: np.ndarray, xy: torch.Tensor) -> np.ndarray:
        """Path length (m) to the goal of each row's slot from ``xy`` [n, 2]; off the free cells: 1,000 m
        plus the straight line, behind every point on them."""
        p = xy.double().numpy()
        f = self.fields[slots, self.cells(p)]
        straight = np.linalg.norm(p - self.goal[torch.as_tensor(slots)].double().numpy(), axis=1)
        return np.where(np.isfinite(f), f, 1e3 + straight)

    def act(self, active: torch.Tensor, agents) -> torch.Tensor:
        """Actions [E, 2] for the running slots ``active`` [E]; ``agents``: (centres, velocities, radii,
        present) [E, M, ...] in the simulator frame, or (future centres [E, L, M, 2], None, radii, present),
        or None."""
        p, env = self.preset, self.env
        e, c, horizon = active.numel(), self.actions.shape[0], self.lookahead
        pose = env.pose[active].repeat_interleave(c, 0)
        v, w = self.v.repeat(e), self.w.repeat(e)
        traj = []
        for _ in range(horizon):
            pose = integrate(pose, v, w, p.episode.dt)
            traj.append(pose)
        traj = torch.stack(traj, 1)  # [E * C, L, 3]
        flat = traj.reshape(-1, 3)
        bad = env._collides(flat, None).reshape(e * c, horizon)
        if agents is not None:
            centres, velocity, radii, present = agents
            if velocity is None:  # centres [E, L, M, 2]: where the agents will be after each step ahead
                future = centres
            else:
                ahead = torch.arange(1, horizon + 1, dtype=centres.dtype) * p.episode.dt
                future = centres[:, None] + velocity[:, None] * ahead[None, :, None, None]  # [E, L, M, 2]
            m = future.shape[2]
            future = future[:, None].expand(e, c, horizon, m, 2).reshape(-1, m, 2)
            grow = self.growth * torch.arange(1, horizon + 1, dtype=radii.dtype) * p.episode.dt  # [L] m
            r = (radii[:, None, None] + self.margin + grow[None, None, :, None]).expand(e, c, horizon, m).reshape(-1, m)
            on = present[:, None, None].expand(e, c, horizon, m).reshape(-1, m)
            bad |= footprint_hits_discs(flat, p.footprint, future, r, on).reshape(e * c, horizon)
        goal = self.goal[active].repeat_interleave(c, 0)
        reached = torch.linalg.vector_norm(traj[..., :2] - goal[:, None], dim=-1) < p.episode.goal_threshold
        steps = torch.arange(horizon)
        first_bad = torch.where(bad, steps, horizon).amin(1)
        first_goal = torch.where(reached, steps, horizon + 1).amin(1)
        wins = first_goal <= first_bad  # the simulator checks the goal first (first_bad <= horizon)
        last = (first_bad - 1).clamp(min=0)
        end = traj[torch.arange(e * c), last]
        slots = np.repeat(active.numpy(), c)
        left = self._path_left(slots, end[:, :2])
        front = end[:, :2] + HEADING_AHEAD * torch.stack((torch.cos(end[:, 2]), torch.sin(end[:, 2])), 1)
        turn = np.clip(self._path_left(slots, front) - left + HEADING_AHEAD, 0.0, 2 * HEADING_AHEAD)
        cost = np.where(wins.numpy(), -1e5 + first_goal.numpy(),
                        np.where((first_bad >= horizon).numpy(), left + 0.5 * turn,
                                 1e4 + 100.0 * (horizon - first_bad.numpy()) + left))
        best = cost.reshape(e, c).argmin(1)
        return self.actions[torch.as_tensor(best)]


def run_mpc(preset, episodes: int, seed: int, *, tracker: str = "lidar", progress=None, **kw) -> dict:
    """Play the scenario episodes of ``preset`` (:func:`flashnav.scenarios.scenario_preset`) with the MPC;
    their rates as :func:`flashnav.scenarios.scenario_rates` gives them, plus ``mean_speed`` (m/s)."""
    if tracker not in TRACKERS:
        raise ValueError(f"tracker must be one of {', '.join(TRACKERS)}, got {tracker!r}")
    count = preset.agents.count
    if tracker == "future" and count:  # non-reactive agents only: their tracks do not depend on the robot
        track, on = agent_tracks(preset, episodes, seed, stand_still(preset))  # [H + 1, E, K, ...]
    if count:  # the tracks the policy would see of every agent: the nearest agent_tracks = count
        preset = load_robot(preset, **{"observation.agent_tracks": count})
    env = make_env(preset, episodes, seed=seed)
    obs, _ = env.reset(seed=seed)
    scored = scenario_scored(env)
    mpc = ConstantVelocityMPC(env, **kw)
    ended = {k: torch.zeros(episodes, dtype=torch.bool) for k in ("success", "collision", "collision_agent")}
    active, speeds = torch.arange(episodes), []
    previous = env.agents.pos.clone() if count else None
    for t in range(preset.episode.horizon):
        agents = None
        if count and tracker == "lidar":
            agents = tracked_agents(obs, env.pose[active], count)
        elif count and tracker == "future":
            span = torch.arange(t + 1, t + 1 + mpc.lookahead).clamp(max=preset.episode.horizon)
            future = track[span][:, active].transpose(0, 1)  # [E, L, K, 2]
            agents = (future, None, env.agents.radius[active], on[t + 1][active])
        elif count:  # every agent, velocity from the last step's displacement (0 at the start)
            pos = env.agents.pos[active]
            velocity = (pos - previous[active]) / preset.episode.dt
            agents = (pos, velocity, env.agents.radius[active], env.agents.active[active])
        a = mpc.act(active, agents)
        speeds.append(action_to_velocity(a, preset.motion)[0])
        if count:
            previous = env.agents.pos.clone()
        r = env.step_slots(active, a)
        done = r["terminated"] | r["truncated"]
        for k, flags in ended.items():
            flags[active[done]] = r[k][done]
        active, obs = active[~done], r["obs"][~done]
        if progress is not None:
            progress(t + 1, active.numel())
        if active.numel() == 0:
            break
    rates = scenario_rates(ended, scored)
    rates["mean_speed"] = float(torch.cat(speeds).mean())
    return rates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="wander-8", choices=SCENARIOS)
    ap.add_argument("--robot", default="turtlebot2")
    ap.add_argument("--episodes", type=int, default=512)
    ap.add_argument("--seed", type=int, default=2026, help="the evaluation seed (flashnav eval --seed)")
    ap.add_argument("--tracker", default="lidar", choices=TRACKERS,
                    help="lidar: the agents the robot sees, straight on (the policy's tracks); all: every agent, "
                         "straight on; future: where every agent will be (clairvoyant, non-reactive agents only)")
    ap.add_argument("--lookahead", type=int, default=20, help="steps each rollout is predicted")
    ap.add_argument("--margin", type=float, default=0.05, help="metres added to each agent's radius")
    ap.add_argument("--growth", type=float, default=0.0,
                    help="m/s: each predicted agent's radius grows by this per second ahead (prediction doubt)")
    ap.add_argument("--v-levels", type=int, default=5, help="forward speeds tried, evenly over the action bounds")
    ap.add_argument("--w-levels", type=int, default=9, help="turn rates tried, evenly over the action bounds")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a robot preset override (motion.v_bounds=[-0.25,0.5]: a robot that can reverse); repeat for more")
    ap.add_argument("--json", help="write the rates and settings here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    t0 = time.time()

    def progress(step: int, running: int) -> None:
        if step % 25 == 0:
            print(f"  step {step}: {running} episodes running, {time.time() - t0:.0f} s", flush=True)

    try:
        robot = load_robot(args.robot, **dict(parse_assignment(s) for s in args.set)) if args.set else args.robot
        result = run_mpc(scenario_preset(robot, args.scenario), args.episodes, args.seed, tracker=args.tracker,
                         lookahead=args.lookahead, margin=args.margin, growth=args.growth, v_levels=args.v_levels,
                         w_levels=args.w_levels, progress=progress)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    report(result, args, t0, f"constant-velocity MPC ({args.tracker} tracker)",
           f"; mean speed {result['mean_speed']:.3f} m/s")

if __name__ == "__main__":
    main()
