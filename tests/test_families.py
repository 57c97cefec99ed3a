"""Map families: reproducible, in the stated size and resolution ranges, connected for the robot,
and written as ROS maps by the generator's command line."""

from __future__ import annotations

import shlex

import numpy as np
import pytest

from flashnav.maps import load_ros_map
from flashnav.maps.families import RESOLUTIONS, SIZE_RANGE, generate_family
from flashnav.maps.generate import main
from flashnav.names import MAP_FAMILIES


@pytest.mark.parametrize("family", MAP_FAMILIES)
def test_same_seed_same_map_other_seed_other_map(family):
    a, b, c = generate_family(family, 5), generate_family(family, 5), generate_family(family, 6)
    np.testing.assert_array_equal(a.occupied, b.occupied)
    assert a.resolution == b.resolution and a.name == f"{family}_5"
    assert a.shape != c.shape or (a.occupied != c.occupied).any()


@pytest.mark.parametrize("family", MAP_FAMILIES)
@pytest.mark.parametrize("seed, radius", [(0, 0.3), (1, 0.3), (2, 0.55)])
def test_sizes_resolutions_and_one_free_region_for_the_robot(family, seed, radius):
    grid = generate_family(family, seed, robot_radius=radius)
    assert grid.resolution in RESOLUTIONS
    for side in (grid.width_m, grid.height_m):
        assert SIZE_RANGE[0] - grid.resolution <= side <= SIZE_RANGE[1] + grid.resolution
    occ = grid.occupied
    assert occ[0].all() and occ[-1].all() and occ[:, 0].all() and occ[:, -1].all()  # walled
    assert 0.03 < occ.mean() < 0.6
    # one region for the robot, and every passage wider still (half the default 0.1 m margin)
    for r in (radius, radius + 0.05):
        assert grid.components(r)[1] == 1, f"{grid.name}: free space for a {r} m disc is split"
    assert grid.free_space(radius).mean() > 0.2


def test_given_size_and_resolution_are_kept_and_bad_input_is_named():
    grid = generate_family("mazes", 0, size=(8.0, 6.0), resolution=0.1)
    assert grid.shape == (60, 80)
    with pytest.raises(ValueError, match="unknown map family 'maze'.*did you mean 'mazes'"):
        generate_family("maze", 0)
    with pytest.raises(ValueError, match="too small"):
        generate_family("rooms", 0, size=(2.0, 2.0), resolution=0.05, robot_radius=0.55)
    with pytest.raises(ValueError, match="seed"):
        generate_family("halls", -1)


def test_command_line_writes_k_maps_per_family_that_reload_bit_for_bit(tmp_path):
    out = tmp_path / "maps"
    main(["--family", "rooms,mazes", "--count", "2", "--seed", "7", "--resolution", "0.1", "--out", str(out),
          "--sheet", str(tmp_path / "sheet.png")])
    assert sorted(p.name for p in out.glob("*.yaml")) == ["mazes_7.yaml", "mazes_8.yaml", "rooms_7.yaml", "rooms_8.yaml"]
    assert (tmp_path / "sheet.png").stat().st_size > 0
    for path in out.glob("*.yaml"):
        family, seed = path.stem.split("_")
        loaded = load_ros_map(path)
        np.testing.assert_array_equal(loaded.occupied, generate_family(family, int(seed), resolution=0.1).occupied)
        # the comment's command regenerates the file
        command = shlex.split(path.read_text().splitlines()[1].lstrip("# "))
        assert command[command.index("--family") + 1] == family and command[command.index("--seed") + 1] == seed
    with pytest.raises(SystemExit):
        main(["--family", "caves", "--out", str(tmp_path / "x")])


def test_reuse_generated_maps_gives_the_same_map_once_drawn_and_only_inside_the_block():
    from flashnav.maps.families import generate_family, reuse_generated_maps

    fresh = generate_family("mazes", 7, size=(8.0, 8.0))
    assert generate_family("mazes", 7, size=(8.0, 8.0)) is not fresh  # outside: drawn every time
    with reuse_generated_maps():
        a = generate_family("mazes", 7, size=(8.0, 8.0))
        with reuse_generated_maps():  # nested: the outer block's maps
            assert generate_family("mazes", 7, size=(8.0, 8.0)) is a
        assert generate_family("mazes", 7, size=[8.0, 8.0]) is a
        assert generate_family("mazes", 8, size=(8.0, 8.0)) is not a  # other arguments, another map
        assert generate_family("mazes", 7, size=(8.0, 8.0), robot_radius=0.25) is not a
        with pytest.raises(ValueError, match="too small"):  # errors are not kept
            generate_family("mazes", 7, size=(2.0, 2.0))
    np.testing.assert_array_equal(a.occupied, fresh.occupied)
    assert not a.occupied.flags.writeable  # shared safely: immutable
    assert generate_family("mazes", 7, size=(8.0, 8.0)) is not a  # after the block: drawn again
