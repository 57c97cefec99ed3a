"""How far can a people shield go? The shield of ``flashnav eval --scenario --shield`` with other predictions
(issue 13, done-means 3).

    .venv/bin/python scripts/agent_shield.py POLICY [--scenario wander-8[,crossing]] [--episodes 512] [--seed 2026]
        [--lookahead 2] [--tracker tracks|future] [--json OUT.json]

``flashnav eval POLICY --scenario S --shield SECONDS`` puts :class:`flashnav.shield.PeopleShield` in front of a
policy with what a people tracker sees: every agent in the scan, straight on at its last step's velocity. This
script plays the same shield (the same walls: the scan's points) with the agents predicted otherwise:

- ``--tracker tracks``: only the agents of the policy's own track columns (``observation.agent_tracks``, the M
  nearest seen; the policy must have them), straight on;
- ``--tracker future``: where every agent *will be* over the look-ahead - the scenarios' agents are not reactive,
  so their futures are recorded beforehand, as ``scripts/agent_oracle.py`` does: the bound of any predictor
  behind this shield.

The episodes and the scoring are ``flashnav eval --scenario``'s (the simulator alone says success, agent or wall
collision, or timeout); ``--tracker seen`` repeats ``flashnav eval --shield`` (the check that this loop is the
evaluation's). A diagnostic, not a controller.
"""

from __future__ import annotations

import argparse
import json
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
    """:class:`SimShield` with the agents predicted from the policy's tracks or from their recorded future."""

    def __init__(self, env, shield: PeopleShield, tracker: str, future=None):
        super().__init__(env, shield)
        self.tracker, self.future, self.t = tracker, future, 0

    def people(self, active: torch.Tensor, pose: torch.Tensor, ranges: torch.Tensor) -> People:
        env = self.env
        if self.tracker == "seen":
            return super().people(active, pose, ranges)
        if self.tracker == "tracks":
            obs = env.obs[active]   # the observation the policy acted on
            return People(*tracked_agents(obs, pose, env.preset.observation.agent_tracks))
        track, on = self.future
        span = torch.arange(self.t + 1, self.t + 1 + self.shield.steps).clamp(max=env.preset.episode.horizon)
        self.t += 1
        return People(track[span][:, active].transpose(0, 1), None, env.agents.radius[active], on[self.t][active])


def run(policy, preset, episodes: int, seed: int, lookahead: float, tracker: str) -> dict:
    """The scenario rates of ``policy`` behind the shield with ``tracker``'s prediction, plus ``shield_overruled``."""
    if tracker not in TRACKERS:
        raise ValueError(f"tracker must be one of {', '.join(TRACKERS)}, got {tracker!r}")
    if tracker == "tracks" and preset.observation.agent_tracks < 1:
        raise ValueError("--tracker tracks reads the policy's agent tracks: this policy has observation.agent_tracks 0")
    future = agent_tracks(preset, episodes, seed, stand_still(preset)) if tracker == "future" else None
    env = make_env(preset, episodes, seed=seed)
    obs, _ = env.reset(seed=seed)
    scored = scenario_scored(env)
    guard = PredictedShield(env, PeopleShield(preset, lookahead), tracker, future)
    rates = scenario_rates(play_episodes(policy, env, obs, shield=guard), scored)
    rates["shield_overruled"] = guard.overruled / max(guard.steps, 1)
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
    ap.add_argument("--json", help="write the rates and settings here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    report = {"policy": args.policy, "seed": args.seed, "episodes": args.episodes, "lookahead": args.lookahead,
              "tracker": args.tracker, "scenarios": {}}
    try:
        policy, meta = load_policy(args.policy)
        robot = load_robot(recorded_robot(meta))
        for name in scenario_names(args.scenario):
            t0 = time.time()
            preset = scenario_preset(robot, name)
            if preset.agents.count == 0:
                raise ValueError(f"scenario {name} has no agents: nothing to shield from")
            r = run(policy, preset, args.episodes, args.seed, args.lookahead, args.tracker)
            report["scenarios"][name] = r
            print(f"{name}: success {r['success_rate']:.1%}, agent {r['agent_collision_rate']:.1%}, wall "
                  f"{r['wall_collision_rate']:.1%}, timeout {r['timeout_rate']:.1%} ({r['scored']} scored); "
                  f"overruled {r['shield_overruled']:.1%} of steps; {time.time() - t0:.0f} s", flush=True)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)


if __name__ == "__main__":
    main()
