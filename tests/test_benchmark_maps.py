"""The committed benchmark suites (flashnav/maps/data/benchmark): every map loads, the geodesic sampler finds
TurtleBot2 episodes on it, the held-out maps are what their seeds generate, and the files stay small."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from flashnav.eval_maps import suite_path
from flashnav.maps import load_ros_map
from flashnav.maps.families import generate_family
from flashnav.names import BENCHMARK_SUITES, HELDOUT_SEEDS_FROM, MAP_FAMILIES
from flashnav.presets import load_robot
from flashnav.sim.sampling import EpisodeSampler

ROOT = Path(suite_path("heldout")).parent
MAPS = sorted(p for s in BENCHMARK_SUITES for p in (ROOT / s).glob("*.yaml"))


def test_suites_hold_maps_of_every_family_and_stay_small():
    heldout = sorted(p.stem for p in (ROOT / "heldout").glob("*.yaml"))
    assert {name.rsplit("_", 1)[0] for name in heldout} == set(MAP_FAMILIES)
    assert len(list((ROOT / "real").glob("*.yaml"))) >= 4
    assert sum(p.stat().st_size for p in ROOT.rglob("*") if p.is_file()) < 1_000_000  # bytes


@pytest.mark.parametrize("yaml", [p for p in MAPS if p.parent.name == "heldout"], ids=lambda p: p.stem)
def test_heldout_maps_are_their_seeds_maps_and_no_training_seed(yaml):
    family, seed = yaml.stem.rsplit("_", 1)
    assert int(seed) >= HELDOUT_SEEDS_FROM
    grid = load_ros_map(yaml)
    again = generate_family(family, int(seed), robot_radius=0.3)
    assert grid.resolution == again.resolution and grid.origin == again.origin
    assert np.array_equal(grid.occupied, again.occupied)


def test_real_maps_are_listed_with_source_and_licence():
    readme = (ROOT / "README.md").read_text()
    for yaml in (ROOT / "real").glob("*.yaml"):
        assert f"`{yaml.stem}`" in readme
        assert "@" in yaml.read_text().splitlines()[0]  # repository@commit in the YAML's first comment line


@pytest.mark.parametrize("yaml", MAPS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_every_map_gives_geodesic_turtlebot2_episodes(yaml):
    preset = load_robot("turtlebot2", **{"episode.goal_sampling": "geodesic"})
    grid = load_ros_map(yaml)
    sampler = EpisodeSampler(grid, preset, "cpu")
    pose, goal = sampler.sample(64, torch.Generator().manual_seed(0))
    dist = torch.linalg.vector_norm(goal - pose[:, :2], dim=1)
    # a path of at most 5 m bounds the straight line; cell centres may sit half a diagonal off the points
    assert float(dist.max()) <= preset.episode.max_goal_distance + grid.resolution
    assert float(dist.min()) > 0.5
    xmin, ymin, xmax, ymax = grid.bounds
    assert bool(((goal[:, 0] > xmin) & (goal[:, 0] < xmax) & (goal[:, 1] > ymin) & (goal[:, 1] < ymax)).all())
