"""The optional agent-proximity reward term (``reward.agent_proximity``, issue 13): the footprint-agent
gap against a geometric reference, and the reward it changes (and only that)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from flashnav.config import Footprint
from flashnav.presets import load_robot
from flashnav.sim.agent_geometry import footprint_disc_gap, footprint_hits_discs
from flashnav.sim.env import make_env
from tests.test_agent_geometry import footprint_centre_distances, random_discs


def reference_gap(pose, footprint: Footprint, centres, radii, active) -> np.ndarray:
    """Per row, the smallest gap to an active disc (inf with none), from the reference distances."""
    out = np.full(pose.shape[0], np.inf)
    for n, r, d in footprint_centre_distances(pose, footprint, centres, radii, active):
        out[n] = min(out[n], max(d - r, 0.0))
    return out


@pytest.mark.parametrize("footprint", [Footprint(kind="disc", radius=0.2),
                                       Footprint(kind="rectangle", length=0.8, width=0.41)])
def test_gap_matches_the_geometric_reference_and_is_zero_exactly_on_collision(footprint):
    pose, centres, radii, active = random_discs(3000, 3, seed=7, extent=3.0, p_active=0.8)
    active[0] = False  # a row with no active agent: an infinite gap
    got = footprint_disc_gap(pose, footprint, centres, radii, active).numpy()
    ref = reference_gap(pose, footprint, centres, radii, active)
    assert np.isinf(got[0]) and np.isinf(ref[0])
    np.testing.assert_allclose(got[1:], ref[1:], atol=1e-5)
    hits = footprint_hits_discs(pose, footprint, centres, radii, active).numpy()
    assert 0.05 < hits.mean() < 0.95
    np.testing.assert_array_equal(got[hits], 0.0)
    assert (got[~hits] >= 0).all() and (got[~hits] > 0).mean() > 0.99


def test_proximity_term_changes_only_the_reward_by_its_definition():
    def run(weight):
        p = load_robot("turtlebot2", **{"agents.count": 8, "reward.agent_proximity": weight,
                                        "reward.agent_proximity_distance": 0.6})
        env = make_env(p, 64, seed=3)
        env.reset(seed=3)
        g = torch.Generator().manual_seed(0)
        rows = []
        for _ in range(40):
            a = torch.rand(64, 2, generator=g) * 2 - 1
            obs, r, term, trunc, info = env.step(a)
            gap = env.agents.gap(env.pose, slice(None))  # meaningful where the slot did not reset
            rows.append((obs, r, term | trunc, gap))
        return rows

    plain, shaped = run(0.0), run(0.75)
    near_seen = 0
    for (o0, r0, d0, gap), (o1, r1, d1, _) in zip(plain, shaped):
        assert torch.equal(o0, o1) and torch.equal(d0, d1)  # dynamics untouched
        live = ~d0
        near = (0.6 - gap[live]).clamp(min=0)
        near_seen += int((near > 0).sum())
        torch.testing.assert_close(r1[live], r0[live] - 0.75 * near, atol=1e-6, rtol=0)
        assert torch.equal(r1[~live], r0[~live])  # terminal rewards are the paper's
    assert near_seen > 0  # the term was exercised


def test_bad_proximity_settings_name_the_key():
    with pytest.raises(Exception, match="agent_proximity"):
        load_robot("turtlebot2", **{"reward.agent_proximity": -1.0})
