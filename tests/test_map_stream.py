"""Fresh generated maps during training (issue 15, item 2): the seed schedule (never a map twice,
never a held-out seed), the background stream, and the env's map swap between steps, each checked
against a slow reference (the maps generated one by one; a fresh env built on the new maps)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from flashnav.learn import loop
from flashnav.maps.families import RESERVED_SEED_START, generate_family
from flashnav.maps.generate import generate_map
from flashnav.maps.stream import GeneratedMaps, MapStream, generate_set, parse_family_maps
from flashnav.names import MAP_FAMILIES
from flashnav.presets import load_robot
from flashnav.sim.env import NavVecEnv
from flashnav.spec import TrainConfig, config_from_cli, resolve


def test_sets_draw_each_seed_once_families_in_turn():
    maps = GeneratedMaps(family=["rooms", "mazes", "halls"], count=4, refresh_every=10, seed=100)
    assert maps.seeds(0) == [("rooms", 100), ("mazes", 101), ("halls", 102), ("rooms", 103)]
    assert maps.seeds(2) == [("rooms", 108), ("mazes", 109), ("halls", 110), ("rooms", 111)]
    seeds = [s for i in range(50) for _, s in maps.seeds(i)]
    assert len(set(seeds)) == len(seeds) == 200
    assert [maps.sets_needed(c) for c in (1, 10, 11, 20, 21)] == [1, 1, 2, 2, 3]  # new sets at cycles 11, 21, ...
    assert GeneratedMaps(family="all").family == list(MAP_FAMILIES)
    assert GeneratedMaps(family="all", count=2).sets_needed(10**6) == 1  # no refresh_every: one set


def test_a_family_named_twice_is_drawn_twice_as_often():
    maps = GeneratedMaps.model_validate(parse_family_maps("family:mazes,rooms,mazes") | {"count": 6})
    assert maps.family == ["mazes", "rooms", "mazes"]
    families = [f for f, _ in maps.seeds(0)]
    assert families.count("mazes") == 4 and families.count("rooms") == 2
    assert len({s for _, s in maps.seeds(0)}) == 6  # still one seed per map


def test_held_out_seeds_are_refused():
    GeneratedMaps(family="rooms", count=10, refresh_every=1, seed=RESERVED_SEED_START - 100).check_seeds(10)
    with pytest.raises(ValueError, match=r"maps.seed: .* seeds 799900-800009; seeds from 800000 up are reserved"):
        GeneratedMaps(family="rooms", count=10, refresh_every=1, seed=799_900).check_seeds(11)
    with pytest.raises(ValueError, match="maps.seed"):  # resolve counts the budget's cycles
        resolve(TrainConfig(device="cpu", recipe="cpu", maps={"family": "rooms", "count": 4, "refresh_every": 1,
                                                               "seed": 799_000}, budget={"max_env_steps": 128 * 300}))
    with pytest.raises(ValueError, match="reserved for validation"):
        generate_set(GeneratedMaps(family="mazes", count=1, seed=RESERVED_SEED_START), 0, 0.3)


def test_the_command_line_form_and_its_overrides():
    config = config_from_cli(None, {"maps": "family:rooms,offices"}, ["maps.count=3", "maps.refresh_every=50"])
    assert config.maps == GeneratedMaps(family=["rooms", "offices"], count=3, refresh_every=50, seed=0)
    assert TrainConfig(maps="family:all").maps.family == list(MAP_FAMILIES)  # YAML's string form too
    with pytest.raises(ValueError, match=r"training config: maps.*unknown map family 'room' \(did you mean 'rooms'"):
        config_from_cli(None, {"maps": "family:room"})
    with pytest.raises(ValueError, match="'maps.coutn': unknown key 'coutn'; did you mean count"):
        config_from_cli(None, {"maps": "family:rooms"}, ["maps.coutn=3"])
    with pytest.raises(ValueError, match="map_weights needs maps"):
        TrainConfig(maps="family:rooms", map_weights=[1.0])


def test_a_resolved_run_starts_on_set_0_at_one_fixed_goal_scale():
    spec = resolve(TrainConfig(device="cpu", recipe="cpu", maps="family:mazes,halls",
                               overrides={"algo.num_envs": 8}, budget={"max_env_steps": 64}).model_copy(
        update={"maps": GeneratedMaps(family=["mazes", "halls"], count=2, seed=7)}))
    reference = [generate_family("mazes", 7, robot_radius=0.3), generate_family("halls", 8, robot_radius=0.3)]
    assert [g.name for g in spec.grids] == ["mazes_7", "halls_8"]
    for got, want in zip(spec.grids, reference):
        assert np.array_equal(got.occupied, want.occupied) and got.resolution == want.resolution
    assert spec.goal_distance_max == pytest.approx(30.0 * 2**0.5)  # the largest a generated map can be
    assert [g.name for g in spec.env_maps()] == ["mazes_7", "halls_8"]


def test_the_stream_draws_the_next_sets_on_a_thread():
    maps = GeneratedMaps(family=["mazes", "clutter"], count=2, refresh_every=5, seed=40)
    threads = []
    stream = MapStream(maps, 0.3, warm=lambda grids: threads.append(threading.current_thread().name), sets=3)
    try:
        assert [stream.due(c) for c in (1, 5, 6, 10, 11)] == [False, False, True, False, True]
        for index in (1, 2):
            got = stream.take()
            want = generate_set(maps, index, 0.3)
            assert [g.name for g in got] == [g.name for g in want] == [f"mazes_{40 + 2 * index}",
                                                                       f"clutter_{41 + 2 * index}"]
            assert all(np.array_equal(a.occupied, b.occupied) for a, b in zip(got, want))
        assert stream._next is None  # a run of 3 sets: nothing drawn past the last
    finally:
        stream.close()
    assert len(threads) == 2 and all(name.startswith("maps") for name in threads)


@pytest.fixture(scope="module")
def grids():
    return ([generate_map(6.0, 5.0, 0.05, seed=1, name="a"), generate_map(7.0, 6.0, 0.1, seed=2, name="b")],
            [generate_map(5.0, 7.0, 0.05, seed=3, name="c"), generate_map(8.0, 8.0, 0.05, seed=4, name="d"),
             generate_map(6.0, 6.0, 0.025, seed=5, name="e")])


@pytest.mark.parametrize("new", ["three", "one"])
def test_replace_maps_equals_a_fresh_env_on_the_new_maps(grids, new):
    old, fresh = grids
    fresh = fresh if new == "three" else fresh[1:2]
    preset = load_robot("turtlebot2")
    env = NavVecEnv(preset, 12, grid=old, seed=0)
    env.reset(seed=0)
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):
        env.step(torch.rand(12, 2, generator=gen) * 2 - 1)
    # the reference: a new env on the new maps whose generator continues the old env's stream
    reference = NavVecEnv(preset, 12, grid=fresh, seed=123)
    reference._gen.set_state(env._gen.get_state())
    want, _ = reference.reset()
    got, _ = env.replace_maps(fresh)
    assert torch.equal(got, want)
    assert torch.equal(env.map_index, reference.map_index) and torch.equal(env.pose, reference.pose)
    assert env.maps == tuple(fresh) and env.num_maps == len(fresh)
    assert int(env.map_index.max()) < len(fresh)
    assert env.single_observation_space.high[30] == pytest.approx(max(g.diagonal_m for g in fresh))
    for _ in range(20):
        action = torch.rand(12, 2, generator=gen) * 2 - 1
        a, b = env.step(action), reference.step(action)
        assert all(torch.equal(x, y) for x, y in zip(a[:4], b[:4]))
        assert torch.equal(a[4]["final_obs"], b[4]["final_obs"])


def test_training_swaps_to_a_new_set_every_refresh(monkeypatch):
    swaps = []
    original = NavVecEnv.replace_maps

    def record(self, grid, map_weights=None):
        swaps.append([g.name for g in grid])
        return original(self, grid, map_weights)

    monkeypatch.setattr(NavVecEnv, "replace_maps", record)
    config = TrainConfig(device="cpu", recipe="cpu", maps={"family": ["mazes"], "count": 2, "refresh_every": 3,
                                                           "seed": 20},
                         overrides={"algo.num_envs": 8, "algo.learning_start": 1024, "algo.buffer_size": 1024},
                         budget={"max_env_steps": 8 * 7, "stop_at_success": None}, eval={"episodes": 4})
    result = loop.train(config)
    assert result.env_steps == 56
    assert swaps == [["mazes_22", "mazes_23"], ["mazes_24", "mazes_25"]]  # at cycles 4 and 7
