"""How far can a people shield go? The shield of ``flashnav eval --scenario --shield`` with other predictions
(issue 13, done-means 3).

    .venv/bin/python scripts/agent_shield.py POLICY [--scenario wander-8[,crossing]] [--episodes 512] [--seed 2026]
        [--lookahead 2] [--tracker seen|tracks|future] [--memory S] [--growth G] [--margin M] [--why]
        [--json OUT.json]

``flashnav eval POLICY --scenario S --shield SECONDS`` puts :class:`flashnav.shield.PeopleShield` in front of a
policy with what a people tracker sees: every agent in the scan, straight on at its last step's velocity. This
script plays the same shield (the same walls: the scan's points) with the agents predicted otherwise:

- ``--tracker tracks``: only the agents of the policy's own track columns (``observation.agent_tracks``, the M
  nearest seen; the policy must have them), straight on;
- ``--tracker future``: where every agent *will be* over the look-ahead - the scenarios' agents are not reactive,
  so their futures are recorded beforehand, as ``scripts/agent_oracle.py`` does: the bound of any predictor
  behind this shield;
- with ``--tracker seen``: ``--memory S`` keeps an agent that left the scan for up to S seconds, walking straight on
  at its last velocity (a tracker's track outliving the view); ``--growth G`` grows every predicted disc by G metres
  per second of look-ahead (a prediction whose uncertainty grows: the agents turn).

``--why`` sorts every agent collision by what the shield saw and did the step before it: whether the hitting agent
was tracked, whether the shield was in charge, and whether any action of its grid was clear (with the steps of
threat before the contact) - docs/benchmarks.md, "What the shield costs" and after.

The episodes and the scoring are ``flashnav eval --scenario``'s (the simulator alone says success, agent or wall
collision, or timeout); ``--tracker seen`` repeats ``flashnav eval --shield`` (the check that this loop is the
evaluation's). A diagnostic, not a controller.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import torch
from agent_hits import stand_still  # scripts/
from agent_mpc import tracked_agents
from agent_oracle import agent_tracks

from flashnav.evaluate import play_episodes
from flashnav.export import load_policy, recorded_robot
from flashnav.presets import load_robot
from flashnav.scenarios import scenario_names, scenario_preset, scenario_rates, scenario_scored
from flashnav.shield import People, PeopleShield, SimShield
from flashnav.sim.env import make_env

TRACKERS = ("seen", "tracks", "future")


class PredictedShield(SimShield):
    """:class:`SimShield` with the agents predicted from the policy's tracks or from their recorded future, or as
    they are seen with a memory and growing discs; with ``why`` it also records each step for :func:`why_hits`."""

    def __init__(self, env, shield: PeopleShield, tracker: str, future=None, memory: float = 0.0, growth: float = 0.0,
                 why: bool = False):
        super().__init__(env, shield)
        self.tracker, self.future, self.t = tracker, future, 0
        self.memory, self.growth = memory, growth
        self.age = torch.full(env.agents.active.shape, math.inf)   # seconds since each agent was last seen
        self.last_pos, self.last_vel = env.agents.pos.clone(), torch.zeros_like(env.agents.pos)
        self.record = {} if why else None   # slot -> [(took over, a clear action played, tracked agents [K])]

    def __call__(self, active: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        out = super().__call__(active, action)
        if self.record is not None:
            pose, people, walls = self.last
            clear = self.shield.first_contact(pose, out[:, None], people, walls)[:, 0] >= self.shield.steps
            for j, slot in enumerate(active.tolist()):
                self.record.setdefault(slot, []).append((bool(self.took_over[j]), bool(clear[j]),
                                                         people.present[j].clone()))
        return out

    def people(self, active: torch.Tensor, pose: torch.Tensor, ranges: torch.Tensor) -> People:
        env = self.env
        if self.tracker == "tracks":
            obs = env.obs[active]   # the observation the policy acted on
            return People(*tracked_agents(obs, pose, env.preset.observation.agent_tracks))
        if self.tracker == "future":
            track, on = self.future
            span = torch.arange(self.t + 1, self.t + 1 + self.shield.steps).clamp(max=env.preset.episode.horizon)
            self.t += 1
            return People(track[span][:, active].transpose(0, 1), None, env.agents.radius[active], on[self.t][active])
        seen = super().people(active, pose, ranges)
        if self.memory > 0:
            dt, now = env.preset.episode.dt, seen.present
            age = torch.where(now, 0.0, self.age[active] + dt)
            # a new sighting's velocity is 0 until its second step: the remembered one until then
            vel = torch.where(now[..., None] & (seen.velocity != 0).any(-1, keepdim=True), seen.velocity,
                              self.last_vel[active])
            pos = torch.where(now[..., None], seen.centres, self.last_pos[active] + self.last_vel[active] * dt)
            self.age[active], self.last_pos[active], self.last_vel[active] = age, pos, vel
            seen = People(pos, vel, seen.radius, age <= self.memory)
        if self.growth > 0:
            ahead = torch.arange(1, self.shield.steps + 1, dtype=seen.centres.dtype) * self.shield.dt
            seen = People(seen.centres[:, None] + seen.velocity[:, None] * ahead[None, :, None, None], None,
                          seen.radius[:, None] + self.growth * ahead[None, :, None], seen.present)
        return seen


def why_hits(guard: PredictedShield, env, ended: dict) -> dict:
    """Each agent collision sorted by the step before it (:class:`PredictedShield` ``why``): the hitting agent (the
    nearest at the end) tracked or not, the shield in charge or not, a clear action played or not; and the median
    steps of threat (the shield in charge) and without a clear action before the contact."""
    from flashnav.sim.agent_geometry import footprint_disc_gap

    fp, k = env.preset.footprint, env.agents.pos.shape[1]
    gap = torch.stack([footprint_disc_gap(env.pose, fp, env.agents.pos[:, j:j + 1], env.agents.radius[:, j:j + 1],
                                          env.agents.active[:, j:j + 1]) for j in range(k)], 1)
    kinds, threat, unclear = {}, [], []
    for slot in ended["collision_agent"].nonzero().flatten().tolist():
        steps = guard.record[slot]
        over, clear, tracked = steps[-1]
        key = (f"agent {'tracked' if bool(tracked[int(gap[slot].argmin())]) else 'not tracked'}, "
               f"shield {'in charge' if over else 'idle'}, {'a clear action' if clear else 'no clear action'}")
        kinds[key] = kinds.get(key, 0) + 1
        threat.append(next((i for i, s in enumerate(reversed(steps)) if not s[0]), len(steps)))
        unclear.append(next((i for i, s in enumerate(reversed(steps)) if s[1]), len(steps)))
    return {"hits": sum(kinds.values()), "kinds": dict(sorted(kinds.items(), key=lambda kv: -kv[1])),
            "median_threat_steps": statistics.median(threat) if threat else None,
            "median_unclear_steps": statistics.median(unclear) if unclear else None}


def run(policy, preset, episodes: int, seed: int, lookahead: float, tracker: str, memory: float = 0.0,
        growth: float = 0.0, why: bool = False, margin: float = 0.05) -> dict:
    """The scenario rates of ``policy`` behind the shield with ``tracker``'s prediction, plus ``shield_overruled``
    (and with ``why`` the hits sorted, ``why``: :func:`why_hits`)."""
    if tracker not in TRACKERS:
        raise ValueError(f"tracker must be one of {', '.join(TRACKERS)}, got {tracker!r}")
    if tracker == "tracks" and preset.observation.agent_tracks < 1:
        raise ValueError("--tracker tracks reads the policy's agent tracks: this policy has observation.agent_tracks 0")
    if (memory or growth) and tracker != "seen":
        raise ValueError(f"--memory and --growth change the seen tracker's prediction: not --tracker {tracker}")
    if not (memory >= 0 and growth >= 0):
        raise ValueError(f"--memory and --growth must be >= 0, got {memory} and {growth}")
    future = agent_tracks(preset, episodes, seed, stand_still(preset)) if tracker == "future" else None
    env = make_env(preset, episodes, seed=seed)
    obs, _ = env.reset(seed=seed)
    scored = scenario_scored(env)
    guard = PredictedShield(env, PeopleShield(preset, lookahead, margin), tracker, future, memory, growth, why)
    ended = play_episodes(policy, env, obs, shield=guard)
    rates = scenario_rates(ended, scored)
    rates["shield_overruled"] = guard.overruled / max(guard.steps, 1)
    if why:
        rates["why"] = why_hits(guard, env, ended)
    return rates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("policy", help="an exported policy (policy.pt / policy.onnx)")
    ap.add_argument("--scenario", default="wander-8", help="scenario name(s) with agents, comma-separated")
    ap.add_argument("--episodes", type=int, default=512)
    ap.add_argument("--seed", type=int, default=2026, help="the evaluation seed (flashnav eval --seed)")
    ap.add_argument("--lookahead", type=float, default=2.0, help="seconds each rollout is predicted")
    ap.add_argument("--tracker", default="future", choices=TRACKERS,
                    help="seen: every agent the scan sees (flashnav eval --shield); tracks: the policy's own track "
                         "columns; future: where every agent will be (clairvoyant)")
    ap.add_argument("--memory", type=float, default=0.0, metavar="S",
                    help="with --tracker seen: keep an agent that left the scan for S seconds, straight on")
    ap.add_argument("--growth", type=float, default=0.0, metavar="G",
                    help="with --tracker seen: grow every predicted disc by G metres per second of look-ahead")
    ap.add_argument("--margin", type=float, default=0.05, metavar="M",
                    help="metres added to every person's radius (the shield's margin; flashnav eval's is 0.05)")
    ap.add_argument("--why", action="store_true", help="sort the agent collisions by what the shield saw and did")
    ap.add_argument("--json", help="write the rates and settings here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    report = {"policy": args.policy, "seed": args.seed, "episodes": args.episodes, "lookahead": args.lookahead,
              "tracker": args.tracker, "memory": args.memory, "growth": args.growth, "margin": args.margin,
              "scenarios": {}}
    try:
        policy, meta = load_policy(args.policy)
        robot = load_robot(recorded_robot(meta))
        for name in scenario_names(args.scenario):
            t0 = time.time()
            preset = scenario_preset(robot, name)
            if preset.agents.count == 0:
                raise ValueError(f"scenario {name} has no agents: nothing to shield from")
            r = run(policy, preset, args.episodes, args.seed, args.lookahead, args.tracker, args.memory,
                    args.growth, args.why, args.margin)
            report["scenarios"][name] = r
            print(f"{name}: success {r['success_rate']:.1%}, agent {r['agent_collision_rate']:.1%}, wall "
                  f"{r['wall_collision_rate']:.1%}, timeout {r['timeout_rate']:.1%} ({r['scored']} scored); "
                  f"overruled {r['shield_overruled']:.1%} of steps; {time.time() - t0:.0f} s", flush=True)
            if args.why:
                w = r["why"]
                print(f"  {w['hits']} agent collisions; median steps before the contact with the shield in charge "
                      f"{w['median_threat_steps']}, without a clear action {w['median_unclear_steps']}")
                for kind, count in w["kinds"].items():
                    print(f"  {count:4d}  {kind}")
    except ValueError as e:
        raise SystemExit(str(e)) from None
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)


if __name__ == "__main__":
    main()
