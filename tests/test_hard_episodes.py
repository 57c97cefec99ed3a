"""episode.hard_share (a training curriculum over the paper's straight-line draws): the detour against a
reference Dijkstra, the choice of the longest detour among the candidates, the paper's draws untouched at
0, evaluations on the task's episodes, and refusals that name the input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from flashnav.maps.fields import free_space
from flashnav.sim.env import NavVecEnv
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.sim.sampling import EpisodeSampler
from test_goal_fields import blocked_room
from test_sampling import cells, reference_distances, robot, serpentine

HARD = {"episode.hard_share": 1.0, "episode.hard_candidates": 4}


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
    pose, goal = sampler.sample(32, torch.Generator().manual_seed(4))
    # the same stream by hand: the task's draws, the share's coins, then 4 candidates per hard slot
    gen = torch.Generator().manual_seed(4)
    sampler._sample_euclidean(32, gen)
    assert (torch.rand(32, generator=gen) < 1.0).all()
    cand_pose, cand_goal, _ = sampler._sample_euclidean(32 * 4, gen)
    ratio = sampler.detour(cand_pose[:, :2], cand_goal).view(32, 4)
    best = ratio.argmax(dim=1) + torch.arange(32) * 4
    assert torch.equal(pose, cand_pose[best]) and torch.equal(goal, cand_goal[best])
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


def test_refusals_name_the_input():
    with pytest.raises(ValueError, match=r"episode.hard_share=0.5 needs episode.goal_sampling=euclidean"):
        robot("geodesic", **{"episode.hard_share": 0.5})
    with pytest.raises(ValueError, match=r"episode.hard_share=0.5 re-weights one map's .* this env has 2 maps"):
        NavVecEnv(robot("euclidean", **{"episode.hard_share": 0.5}), 8, grid=[serpentine(0.05), blocked_room(0.05)])
    with pytest.raises(ValueError, match=r"hard_share"):
        robot("euclidean", **{"episode.hard_share": 1.5})
