"""Evaluation scenarios with moving agents (issue 13): fixed, seeded episode sets that ``flashnav eval
--scenario NAME`` runs, scored as success / collision with an agent / collision with a wall / timeout.

- ``static``: the robot's preset as it is, no agents;
- ``wander-4`` / ``wander-8``: 4 / 8 agents per episode, half ``waypoints`` and half ``bounce`` walkers
  on average (the preset's radius and speed ranges);
- ``crossing``: one agent that appears and walks across the robot's start-goal line when the robot
  would reach it (:mod:`flashnav.sim.agents`). A crossing needs a clear straight way across the line,
  which a cluttered map does not offer in every episode: only episodes whose crossing agent could be
  placed are scored, and the report says how many of the episodes drawn that is.

A scenario's agents are fixed: the simulator's agent defaults (``agents:`` in
``flashnav/presets/simulator.yaml``: radius, speed, no reactive agents, ...) with the scenario's count and
mix, whatever agent options the policy trained with, so a policy trained among agents that yield is
scored on the same sets as every other. ``own_agents=True`` (``flashnav eval --robot PRESET.yaml``: a
preset the user names) keeps that preset's agent options instead; ``agents`` (``flashnav eval --agents
reactive=0.5``) changes named options on top, reported beside the rates. The episodes are those of the
evaluation seed, the same for every policy.
"""

from __future__ import annotations

from typing import Callable

import torch

from flashnav.config import RobotPreset
from flashnav.evaluate import play_episodes
from flashnav.names import SCENARIOS, check_name, parse_names
from flashnav.presets import load_preset_file, load_robot

WANDER_MIX = {"waypoints": 0.5, "bounce": 0.5}
#: agents.* overrides of each scenario
SCENARIO_AGENTS = {
    "static": {"count": 0},
    "wander-4": {"count": 4, "mix": WANDER_MIX},
    "wander-8": {"count": 8, "mix": WANDER_MIX},
    "crossing": {"count": 1, "mix": {"crossing": 1.0}},
}


def scenario_preset(robot: str | RobotPreset, name: str, own_agents: bool = False,
                    agents: dict | None = None) -> RobotPreset:
    """The robot's preset with the agents of scenario ``name`` (one of :data:`SCENARIOS`): the simulator's
    agent defaults with the scenario's count and mix, or with ``own_agents`` the preset's own agent options
    with them (see the module docstring); then ``agents`` (``{"reactive": 0.5}``: ``flashnav eval --agents``)
    over all of it, each key an ``agents.*`` option (an unknown one is a ValueError naming it). Everything
    else (observation, motion, ...) is the preset's."""
    check_name("scenario", name, SCENARIOS)
    changes = agents or {}
    agents = {} if own_agents else dict(load_preset_file("simulator").get("agents") or {})
    agents.update(SCENARIO_AGENTS[name])
    agents.update(changes)
    return load_robot(robot, **{f"agents.{k}": v for k, v in agents.items()})


def scenario_names(text: str) -> list[str]:
    """``"wander-8,crossing"`` or ``"all"`` -> the scenario names, each checked (``--scenario``)."""
    return parse_names("scenario", text, SCENARIOS, "--scenario", unique=True)


@torch.no_grad()
def run_scenario(policy: Callable[[torch.Tensor], torch.Tensor], env, seed: int, guide=None, shield=None) -> dict:
    """One episode per slot of ``env`` (made from a :func:`scenario_preset`) with the deterministic
    ``policy``, played by :func:`flashnav.evaluate.play_episodes` (only running slots are simulated).
    ``guide``: a callable env -> a guide (:mod:`flashnav.guidance`) whose carrots the policy steers at.
    ``shield``: a :class:`flashnav.shield.PeopleShield` in front of the policy (on a scenario without agents
    it has nothing to do). Returns the rates over the scored episodes (success, agent_collision,
    wall_collision, timeout; a collision with both counts as an agent collision), ``episodes`` drawn and
    ``scored``; with a shield also ``shield_overruled``, the share of the steps played where it took over from the
    policy."""
    from flashnav.shield import SimShield

    obs, _ = env.reset(seed=seed)
    scored = scenario_scored(env)
    guard = SimShield(env, shield) if shield is not None and env.agents is not None else None
    rates = scenario_rates(play_episodes(policy, env, obs, guide=None if guide is None else guide(env), shield=guard),
                           scored)
    if shield is not None:
        rates["shield_overruled"] = guard.overruled / max(guard.steps, 1) if guard is not None else 0.0
    return rates


def scenario_scored(env) -> torch.Tensor:
    """[N] bool: the episodes just placed in ``env`` that a scenario scores - all of them, except on a
    crossing scenario, where only those whose crossing agent could be placed."""
    crossing = env.agents is not None and env.preset.agents.mix.get("crossing", 0.0) > 0
    return env.agents.placed.any(dim=1) if crossing else torch.ones(env.num_envs, dtype=torch.bool, device=env.device)


def scenario_rates(e: dict, scored: torch.Tensor) -> dict:
    """The report of :func:`run_scenario` from each episode's ending flags ``e`` (``success``,
    ``collision_agent``, ``collision``: [N] bool) over the ``scored`` [N] episodes."""
    # 0 timeout, 1 success, 2 agent, 3 wall (success and either collision exclude each other)
    outcome = torch.where(e["success"], 1, torch.where(e["collision_agent"], 2, torch.where(e["collision"], 3, 0)))
    counted = outcome[scored]
    total = max(int(scored.sum()), 1)
    rate = lambda k: float((counted == k).sum()) / total  # noqa: E731
    return {"success_rate": rate(1), "agent_collision_rate": rate(2), "wall_collision_rate": rate(3),
            "timeout_rate": rate(0), "episodes": len(scored), "scored": int(scored.sum())}
