"""Derived map fields (flashnav.maps.fields): one computation per map, shared by every consumer, with
the values the consumers used to compute for themselves."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from flashnav.maps import fields
from flashnav.maps.grid import OccupancyMap
from flashnav.presets import load_robot
from flashnav.sim.collision import make_collision_checker
from flashnav.sim.env import NavVecEnv
from flashnav.sim.oracle import OracleController
from flashnav.sim.raycast import make_raycaster
from flashnav.sim.sampling import EpisodeSampler


def clutter(seed: int, shape=(60, 70), res=0.05, origin=(0.4, -0.7)) -> OccupancyMap:
    rng = np.random.default_rng(seed)
    occ = np.zeros(shape, bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    for _ in range(8):
        i, j = rng.integers(5, shape[0] - 8), rng.integers(5, shape[1] - 8)
        occ[i:i + rng.integers(2, 6), j:j + rng.integers(2, 6)] = True
    return OccupancyMap(occ, res, origin)


@pytest.fixture
def counting(monkeypatch):
    """Counts the expensive builds: the padded EDT and the numba cone-field builder."""
    calls = {"iso": 0, "cone": 0, "label": 0}
    iso, label = fields.iso_field, fields.ndimage.label

    def counted_iso(occ):
        calls["iso"] += 1
        return iso(occ)

    def counted_label(*a, **k):
        calls["label"] += 1
        return label(*a, **k)

    from flashnav.maps import fields_numba

    build = fields_numba.build_cone_field

    def counted_build(*a, **k):
        calls["cone"] += 1
        return build(*a, **k)

    monkeypatch.setattr(fields, "iso_field", counted_iso)
    monkeypatch.setattr(fields.ndimage, "label", counted_label)
    monkeypatch.setattr(fields_numba, "build_cone_field", counted_build)
    return calls


def test_every_consumer_of_one_map_shares_one_computation(counting):
    grid = clutter(1)
    preset = load_robot("turtlebot2")
    angles = torch.linspace(-math.pi, math.pi, 16)
    make_raycaster("exact", grid, angles, 5.0)  # numba raycaster: cone field
    make_raycaster("exact-torch", grid, angles, 5.0)  # torch raycaster: the same cone field
    make_collision_checker(preset.footprint, grid, prefilter=True)  # safe field: the same EDT
    assert counting == {"iso": 1, "cone": 1, "label": 0}
    EpisodeSampler(grid, preset, torch.device("cpu"))
    EpisodeSampler(grid, preset, torch.device("cpu"))
    assert counting == {"iso": 1, "cone": 1, "label": 1}
    # a re-centred copy (the simulator frame of a far map) reads the same cache
    far = grid.shifted((-1e12, 3.0))
    assert far.origin == (0.4 + 1e12, -3.7)
    make_raycaster("exact", far, angles, 5.0)
    make_collision_checker(preset.footprint, far, prefilter=True)
    EpisodeSampler(far, preset, torch.device("cpu"))
    assert counting == {"iso": 1, "cone": 1, "label": 1}
    # a second map is a second computation
    make_raycaster("exact", clutter(2), angles, 5.0)
    assert counting == {"iso": 2, "cone": 2, "label": 1}


def test_env_and_oracle_share_the_maps_fields(counting):
    grid = clutter(3, shape=(80, 80))
    preset = load_robot("turtlebot2")
    env = NavVecEnv(preset, 2, grid=grid)
    twin = NavVecEnv(preset, 3, grid=grid, seed=1)
    assert counting == {"iso": 1, "cone": 1, "label": 1}
    OracleController(env)
    OracleController(twin)
    assert counting["iso"] == 1 and counting["cone"] == 1
    assert twin._collides._clear.equal(env._collides._clear)


def test_cached_fields_are_read_only_and_keyed_by_radius():
    grid = clutter(4)
    for arr in (fields.safe_field(grid), fields.cone_field(grid), fields.clearance(grid), fields.free_space(grid, 0.2),
                fields.components(grid, 0.2)[0], fields.clear_cells(grid, 0.2)):
        assert not arr.flags.writeable
    assert fields.free_space(grid, 0.2) is fields.free_space(grid, 0.2 + 1e-12)
    assert fields.free_space(grid, 0.2).sum() > fields.free_space(grid, 0.3).sum()
    assert fields.clear_cells(grid, 0.2).sum() > fields.clear_cells(grid, 0.3).sum()


def test_field_values_are_the_definitions():
    # the formulas the consumers used before the fields moved here, recomputed from scratch
    grid = clutter(5)
    res = grid.resolution
    free = np.pad(~grid.occupied, 1, constant_values=False)
    centre = ndimage.distance_transform_edt(free)[1:-1, 1:-1] * res
    assert np.array_equal(grid.centre_distance, centre)
    clear = np.maximum(centre - res * math.sqrt(0.5), 0.0)
    clear[grid.occupied] = 0.0
    assert np.array_equal(grid.clearance, clear)
    labels, count = ndimage.label(clear > 0.25)
    got, got_count = grid.components(0.25)
    assert got_count == count and np.array_equal(got, labels)

    occ = grid.padded(fields.PAD)
    dilated = ndimage.binary_dilation(occ, structure=np.ones((3, 3), bool), border_value=1)
    s64 = ndimage.distance_transform_edt(~dilated)
    safe = fields.safe_field(grid)
    assert (safe[occ] == -1).all()
    assert (safe[~occ].astype(np.float64) <= s64[~occ]).all()  # rounded down: a lower bound
    assert np.allclose(safe[~occ], s64[~occ], rtol=2.5e-7, atol=0)  # within one float32 step
    assert np.array_equal(fields.clear_cells(grid, 0.3), safe.astype(np.float64) * res >= 0.3)

    rows, cols, first, counts = fields.component_cells(grid, 0.25, 16)
    lab = labels[rows, cols]
    assert (np.bincount(labels.ravel())[lab] >= 16).all() and (np.diff(lab) >= 0).all()
    assert (lab[first] == lab).all() and (counts == np.bincount(lab)[lab]).all()
