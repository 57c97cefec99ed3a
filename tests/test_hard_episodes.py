"""episode.hard_share (a training curriculum over the task's draws): the detour against a reference Dijkstra, the
choice of the longest detour among the candidates (straight-line and path-length draws, one map and many: each
slot's candidates on its own map), the task's draws untouched at 0, evaluations on the task's episodes, and
refusals that name the input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from flashnav.maps.fields import free_space
from flashnav.sim.env import NavVecEnv
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.sim.sampling import EpisodeSampler, MapSetSampler
from test_goal_fields import blocked_room
from test_sampling import cells, reference_distances, robot, serpentine

HARD = {"episode.hard_share": 1.0, "episode.hard_candidates": 4}


def replayed_hard_draws(sample, draw, detour, n: int, seed: int) -> torch.Tensor:
    """Check that ``sample(gen)``'s n episodes (every slot hard, 4 candidates: HARD) are the longest detours of their
    candidates, replaying its stream by hand: the task's draws (``draw(1, gen)``), the share's coins, then 4
    candidates per slot (``draw(4, gen)`` -> pose, goal), measured by ``detour(start, goal)``. Returns the
    candidates' ratios [n, 4]."""
    pose, goal = sample(torch.Generator().manual_seed(seed))
    gen = torch.Generator().manual_seed(seed)
    draw(1, gen)
    assert (torch.rand(n, generator=gen) < 1.0).all()
    cand_pose, cand_goal = draw(4, gen)
    ratio = detour(cand_pose[:, :2], cand_goal).view(n, 4)
    best = ratio.argmax(dim=1) + torch.arange(n) * 4
    assert torch.equal(pose, cand_pose[best]) and torch.equal(goal, cand_goal[best])
    return ratio


def test_detour_is_the_reference_path_length_over_the_straight_line():
    grid = blocked_room(0.05)
    preset = robot("euclidean", **HARD)
    sampler = EpisodeSampler(grid, preset, torch.device("cpu"))
    pose, goal, _ = sampler._sample_euclidean(64, torch.Generator().manual_seed(1))
    got = sampler.detour(pose[:, :2], goal)
    free = free_space(grid, preset.footprint.circumscribed_radius)
    path = reference_distances(free, grid.resolution, cells(grid, goal.double().numpy()),
                               cells(grid, pose[:, :2].double().numpy()), limit=np.inf)
    want = torch.as_tensor(path, dtype=torch.float32) / torch.linalg.vector_norm(goal - pose[:, :2], dim=1)
    assert torch.isfinite(want).all()
    assert torch.allclose(got, want, rtol=1e-5)
    assert (got > 1.5).any() and (got >= 0.9).all()  # the wall makes some long ways round


def test_a_hard_draw_is_the_longest_detour_of_its_candidates():
    grid = blocked_room(0.05)
    sampler = EpisodeSampler(grid, robot("euclidean", **HARD), torch.device("cpu"))
    ratio = replayed_hard_draws(lambda gen: sampler.sample(32, gen),
                                lambda c, gen: sampler._sample_euclidean(32 * c, gen)[:2], sampler.detour, 32, seed=4)
    pose, goal = sampler.sample(32, torch.Generator().manual_seed(4))
    assert (sampler.detour(pose[:, :2], goal) >= ratio.amax(dim=1) - 1e-6).all()
    # and over many draws the share shows long ways round more often than the task does
    plain = EpisodeSampler(grid, robot("euclidean"), torch.device("cpu"))
    p0, g0 = plain.sample(512, torch.Generator().manual_seed(5))
    p1, g1 = EpisodeSampler(grid, robot("euclidean", **{"episode.hard_share": 0.5}),
                            torch.device("cpu")).sample(512, torch.Generator().manual_seed(5))
    assert (sampler.detour(p1[:, :2], g1) > 1.3).float().mean() > 1.5 * (sampler.detour(p0[:, :2], g0) > 1.3).float().mean()


def test_share_zero_is_the_papers_draws_and_evaluations_play_the_tasks_episodes():
    grid = serpentine(0.05)
    hard = robot("euclidean", **{"episode.hard_share": 0.5})
    assert evaluation_preset(hard).episode == robot("euclidean").episode
    a = NavVecEnv(evaluation_preset(hard), 64, grid=grid, seed=3)
    b = NavVecEnv(robot("euclidean"), 64, grid=grid, seed=3)
    a.reset(seed=3), b.reset(seed=3)
    assert torch.equal(a.pose, b.pose) and torch.equal(a.goal, b.goal)
    c = NavVecEnv(hard, 64, grid=grid, seed=3)
    c.reset(seed=3)
    assert not torch.equal(c.pose, b.pose)  # training draws do change


def test_path_length_draws_harden_too_and_stay_pairs_of_the_band():
    """goal_sampling geodesic (the generalist's task): a hard draw is the longest detour of candidates drawn from the
    map's geodesic pairs, so it is itself one of them (in the band by construction)."""
    grid = blocked_room(0.05)
    sampler = EpisodeSampler(grid, robot("geodesic", **HARD), torch.device("cpu"))
    replayed_hard_draws(lambda gen: sampler.sample(32, gen), lambda c, gen: sampler._sample_geodesic(32 * c, gen),
                        sampler.detour, 32, seed=6)
    plain = EpisodeSampler(grid, robot("geodesic"), torch.device("cpu"))
    p0, g0 = plain.sample(512, torch.Generator().manual_seed(7))
    p1, g1 = EpisodeSampler(grid, robot("geodesic", **{"episode.hard_share": 0.5}),
                            torch.device("cpu")).sample(512, torch.Generator().manual_seed(7))
    # the long ways round the wall: 4.3 % of the task's draws, 15.2 % with half of them hard (fixed seeds)
    assert (sampler.detour(p1[:, :2], g1) > 1.3).float().mean() > 2 * (sampler.detour(p0[:, :2], g0) > 1.3).float().mean()


@pytest.mark.parametrize("mode", ["euclidean", "geodesic"])
def test_many_maps_harden_each_slot_on_its_own_map(mode):
    """A many-map env's sampler: the same stream by hand, each candidate's detour measured on its slot's map by
    that map's own sampler; the slots' episodes lie in their own map's free space."""
    grids = [serpentine(0.05), blocked_room(0.05)]
    preset = robot(mode, **HARD)
    batched = MapSetSampler([EpisodeSampler(g, preset, torch.device("cpu")) for g in grids])
    maps = torch.tensor([0, 1, 1, 0, 1, 0, 0, 1] * 4)
    draw = batched._sample_geodesic if mode == "geodesic" else (lambda m, g: batched._sample_euclidean(m, g)[:2])
    cand_maps = maps.repeat_interleave(4)

    def on_its_map(start, end):  # one candidate at a time, by its own map's sampler
        return torch.stack([batched.samplers[int(m)].detour(p[None], g[None])[0]
                            for m, p, g in zip(cand_maps, start, end)])

    replayed_hard_draws(lambda gen: batched.sample(maps, gen), lambda c, gen: draw(maps.repeat_interleave(c), gen),
                        on_its_map, maps.numel(), seed=8)
    pose, goal = batched.sample(maps, torch.Generator().manual_seed(8))
    for m, g in enumerate(grids):
        on = maps == m
        free = free_space(g, preset.footprint.circumscribed_radius)
        assert free.flat[cells(g, pose[on, :2].double().numpy())].all() and free.flat[cells(g, goal[on].double().numpy())].all()
    # an env over both maps trains on them; its evaluations play the task's episodes
    env = NavVecEnv(preset, 16, grid=grids, seed=2)
    env.reset(seed=2)
    assert evaluation_preset(preset).episode.hard_share == 0


def test_refusals_name_the_input():
    with pytest.raises(ValueError, match=r"hard_share"):
        robot("euclidean", **{"episode.hard_share": 1.5})
    with pytest.raises(ValueError, match=r"hard_candidates"):
        robot("geodesic", **{"episode.hard_candidates": 1})
