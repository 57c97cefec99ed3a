"""scripts/agent_hits.py: which agents hit the robot, and had they just turned? (issue 13)"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import agent_hits  # noqa: E402

from flashnav.names import AGENT_BEHAVIOURS  # noqa: E402
from flashnav.scenarios import scenario_preset  # noqa: E402


def _path(points):  # agent centres [1, 1, 2] after each step
    return [torch.tensor([[p]], dtype=torch.float32) for p in points]


def test_turn_degrees_reads_the_heading_change_over_the_window():
    n = agent_hits.TURN_STEPS + 2
    straight = _path([(0.1 * k, 0.0) for k in range(n)])
    assert agent_hits.turn_degrees(straight, 0, 0) == pytest.approx(0.0, abs=1e-4)
    corner = _path([(0.1 * k, 0.0) for k in range(n - 1)] + [(0.1 * (n - 2), 0.1)])  # the last step goes left
    assert agent_hits.turn_degrees(corner, 0, 0) == pytest.approx(90.0, abs=1e-3)
    back = _path([(0.1 * k, 0.0) for k in range(n - 1)] + [(0.1 * (n - 3), 0.0)])
    assert agent_hits.turn_degrees(back, 0, 0) == pytest.approx(180.0, abs=1e-3)
    assert agent_hits.turn_degrees(straight[1:], 0, 0) is None  # too early in the episode
    standing = _path([(0.0, 0.0)] * n)
    assert agent_hits.turn_degrees(standing, 0, 0) is None


def test_every_hit_names_its_agent_and_the_base_rate_counts_moving_agents():
    torch.set_num_threads(1)
    preset = scenario_preset("turtlebot2", "wander-8")
    still = agent_hits.stand_still(preset)
    hitters, base = [], {}
    bearings = agent_hits.hit_bearings(lambda o: still.expand(o.shape[0], 2), preset, 24, 2026, hitters=hitters,
                                       base=base)
    assert len(bearings) == len(hitters) > 0  # a standing robot is hit in about a third of wander-8 episodes
    assert all(kind in AGENT_BEHAVIOURS[:2] and (t is None or 0.0 <= t <= 180.0) for kind, t in hitters)
    assert base["known"] > 1000 and 0 < base["turned"] < base["known"]


def test_sight_says_when_the_tracker_last_saw_each_hitting_agent():
    """One entry per hit: 0 when the hitting agent was in the observation the robot acted on, n > 0 when it was lost
    from sight n observations before that, None when the tracker never saw it. A standing robot on these 24 episodes
    is hit from the front (seen) and from behind its 270-deg view (never seen, or lost from sight earlier)."""
    torch.set_num_threads(1)
    preset = scenario_preset("turtlebot2", "wander-8")
    still = agent_hits.stand_still(preset)
    sight = []
    bearings = agent_hits.hit_bearings(lambda o: still.expand(o.shape[0], 2), preset, 24, 2026, sight=sight)
    assert len(sight) == len(bearings) > 0
    assert all(x is None or (isinstance(x, int) and 0 <= x < preset.episode.horizon) for x in sight)
    # the hits from behind the field of view were not in the last observation
    half = preset.lidar.fov_deg / 2
    behind = [x for x, b in zip(sight, bearings) if b > half + 5]
    assert behind and all(x != 0 for x in behind)
    assert any(x == 0 for x in sight)  # a standing robot also sees agents walk into it from the front
