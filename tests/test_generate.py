"""The seeded map generator: reproducible, cluttered, connected, easy to navigate, fast."""

from __future__ import annotations

import math
import shlex
import time

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from flashnav.maps import OccupancyMap, bundled_map, generate_map, load_ros_map
from flashnav.maps.bundled import _data_dir
from flashnav.maps.generate import connect_free_space, main

BORDER = 3  # cells: 0.15 m at 0.05 m


def test_same_seed_same_map_other_seed_other_map():
    a = generate_map(10, 10, seed=7, robot_radius=0.3)
    b = generate_map(10, 10, seed=7, robot_radius=0.3)
    c = generate_map(10, 10, seed=8, robot_radius=0.3)
    np.testing.assert_array_equal(a.occupied, b.occupied)
    assert (a.occupied != c.occupied).any()
    assert a.shape == (200, 200) and a.resolution == 0.05 and a.origin == (0.0, 0.0)
    assert a.name == "generated_10x10_seed7" and generate_map(10, 10, name="x").name == "x"


def test_rectangular_maps_and_resolution():
    grid = generate_map(6, 4, resolution=0.1, seed=1, robot_radius=0.25)
    assert grid.shape == (40, 60) and grid.width_m == pytest.approx(6) and grid.height_m == pytest.approx(4)
    assert grid.components(0.25)[1] == 1


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("size, radius", [(10.0, 0.3), (13.5, 0.55)])
def test_cluttered_walled_and_connected(seed, size, radius):
    grid = generate_map(size, size, seed=seed, robot_radius=radius)
    occ = grid.occupied
    for wall in (occ[:BORDER], occ[-BORDER:], occ[:, :BORDER], occ[:, -BORDER:]):
        assert wall.all()
    interior = occ[BORDER:-BORDER, BORDER:-BORDER]
    assert 0.06 < interior.mean() < 0.22
    # Several separate obstacles, not one blob: count the interior's occupied components.
    from scipy import ndimage

    assert ndimage.label(interior)[1] >= 8
    # Free space for the robot radius is one region, and even a disc 0.05 m wider (half the default
    # margin) still passes every passage.
    for r in (radius, radius + 0.05):
        labels, count = grid.components(r)
        assert count == 1, f"{count} free-space components for a {r} m disc"
    assert grid.free_space(radius).mean() > 0.35


def _detour_ratios(grid: OccupancyMap, radius: float, sources: int = 4) -> np.ndarray:
    """Shortest 8-connected path in the robot's free space over the straight line, for cell pairs
    1-5 m apart (the preset's goal band). The grid metric alone overestimates by up to ~8 %."""
    free = grid.free_space(radius)
    h, w = free.shape
    index = np.full(free.shape, -1)
    cells = np.flatnonzero(free)
    index.flat[cells] = np.arange(cells.size)
    rows, cols = np.divmod(cells, w)
    src, dst, length = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = rows + dr, cols + dc
        ok = (r2 < h) & (c2 >= 0) & (c2 < w)
        ok[ok] = free[r2[ok], c2[ok]] & free[rows[ok], c2[ok]] & free[r2[ok], cols[ok]]
        src.append(index[rows[ok], cols[ok]]), dst.append(index[r2[ok], c2[ok]])
        length.append(np.full(ok.sum(), math.hypot(dr, dc)))
    graph = csr_matrix((np.concatenate(length), (np.concatenate(src), np.concatenate(dst))), shape=(cells.size,) * 2)
    starts = np.random.default_rng(0).choice(cells.size, sources, replace=False)
    dist = dijkstra(graph, directed=False, indices=starts)
    ratios = []
    for k, s in enumerate(starts):
        straight = np.hypot(rows - rows[s], cols - cols[s]) * grid.resolution
        band = (straight >= 1.0) & (straight <= 5.0)
        ratios.append(dist[k, band] * grid.resolution / straight[band])
    return np.concatenate(ratios)


def test_paths_are_only_moderately_longer_than_the_straight_line():
    ratios = _detour_ratios(generate_map(10, 10, seed=3, robot_radius=0.3), 0.3)
    assert np.isfinite(ratios).all()  # every goal reachable
    assert ratios.mean() < 1.25 and np.percentile(ratios, 95) < 1.6


def test_fast_enough():
    generate_map(13.5, 13.5, seed=0, robot_radius=0.55)  # warm-up (imports, allocator)
    start = time.perf_counter()
    generate_map(13.5, 13.5, seed=1, robot_radius=0.55)
    assert time.perf_counter() - start < 1.0


def test_connect_free_space_fills_a_closed_room():
    occupied = np.zeros((60, 60), dtype=bool)
    occupied[:2], occupied[-2:], occupied[:, :2], occupied[:, -2:] = True, True, True, True
    occupied[35:37, 35:58] = True  # a closed room in the upper-right corner
    occupied[35:58, 35:37] = True
    before = OccupancyMap(occupied, 0.05)
    assert before.components(0.2)[1] == 2
    after = OccupancyMap(connect_free_space(occupied, 0.05, 0.2), 0.05)
    assert after.components(0.2)[1] == 1
    main_before = before.components(0.2)[0] == 1
    assert not (after.occupied & main_before).any()  # the big region keeps its shape
    assert after.occupied[40:55, 40:55].all()


def test_bad_arguments():
    with pytest.raises(ValueError, match="density"):
        generate_map(10, 10, density=0.7)
    with pytest.raises(ValueError, match="width_m"):
        generate_map(0, 10)
    with pytest.raises(ValueError, match="too small"):
        generate_map(1.0, 1.0, robot_radius=0.5)


def test_command_line_writes_a_ros_map(tmp_path, capsys):
    out = tmp_path / "gen.yaml"
    main(["--width", "6", "--height", "5", "--seed", "3", "--robot-radius", "0.25", "--out", str(out)])
    text = out.read_text()
    assert text.startswith("# Generated by") and "--seed 3 --robot-radius 0.25" in text
    loaded = load_ros_map(out)
    np.testing.assert_array_equal(loaded.occupied, generate_map(6, 5, seed=3, robot_radius=0.25).occupied)
    assert loaded.name == "gen"


@pytest.mark.parametrize("argv, said", [
    (["--width", "-8", "--height", "6", "--out", "neg.yaml"], "--width -8: must be a positive number of metres"),
    (["--width", "8", "--height", "6", "--resolution", "nan", "--out", "n.yaml"], "--resolution nan: must be a positive"),
    (["--family", "mazes", "--resolution", "3", "--out", "fam"], "--resolution 3: a cell coarser than the robot's"),
    (["--family", "mazes", "--robot-radius", "0", "--out", "fam"], "--robot-radius 0: must be a positive number"),
    (["--family", "mazes", "--margin", "-1", "--out", "fam"], "--margin -1: must be >= 0 metres"),
    (["--family", "mazes", "--density", "0.2", "--out", "fam"], "--density applies to the single cluttered map"),
    (["--width", "8", "--height", "6", "--density", "0.7", "--out", "d.yaml"], "--density 0.7: the occupied fraction"),
    (["--width", "8", "--height", "6", "--out", "c"], "--out c: the map's YAML file (NAME.yaml"),
    (["--family", "rooms", "--width", "-3", "--height", "5", "--out", "fam"], "--width -3: must be a positive number"),
    # the rooms map would fit; the mazes one does not: nothing of either is written (rooms_0 was, once)
    (["--family", "rooms,mazes", "--width", "2", "--height", "2", "--out", "fam"], "a 2 x 2 m mazes map is too small"),
    (["--width", "8", "--height", "8", "--count", "0", "--out", "m.yaml"], "--count 0 goes with --family"),
    (["--width", "8", "--height", "8", "--count", "3", "--out", "m.yaml"], "--count 3 goes with --family"),
    (["--family", "", "--out", "fam"], "--family: no map family named in ''"),
])
def test_command_line_errors_are_one_line(argv, said, tmp_path, monkeypatch, capsys):
    """Generator errors once ended in a traceback (exit 1), and an --out without .yaml wrote a map file that
    `--maps DIR` then ignored."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and said in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, said", [
    (["--family", "rooms", "--out", "afile"], "--out afile: exists and is a file, not a folder"),
    (["--family", "rooms", "--out", "afile/sub"], "--out afile/sub: cannot be created because"),
    (["--width", "5", "--height", "5", "--out", "afile/one.yaml"], "--out afile/one.yaml: cannot be created because"),
    (["--family", "rooms", "--out", "maps", "--sheet", "sheet.txt"], "--sheet sheet.txt: a picture is written as"),
    (["--family", "rooms", "--out", "maps", "--sheet", "afile/s.png"], "--sheet afile/s.png: cannot be created"),
    (["--width", "5", "--height", "5", "--out", "one.yaml", "--sheet", "s.png"], "--sheet needs --family"),
])
def test_output_paths_are_checked_before_any_map_is_made(argv, said, tmp_path, monkeypatch, capsys):
    """A folder under a file once ended in a traceback (FileExistsError, NotADirectoryError), and a sheet that
    matplotlib cannot write failed only after every map was written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and said in err and "Traceback" not in err
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]


@pytest.mark.parametrize("name", ["turtlebot2", "go2"])
def test_bundled_map_comment_reproduces_it(name):
    """The command in the YAML's comment regenerates the bundled map bit for bit. If the generator
    changes on purpose, keep the bundled files (benchmarks stay comparable) and update this test."""
    header = (_data_dir() / f"{name}.yaml").read_text().splitlines()[1].lstrip("# ")
    args = shlex.split(header)
    opt = {args[i].lstrip("-").replace("-", "_"): args[i + 1] for i in range(3, len(args), 2)}
    grid = generate_map(float(opt["width"]), float(opt["height"]), float(opt["resolution"]), int(opt["seed"]),
                        robot_radius=float(opt["robot_radius"]), density=float(opt["density"]),
                        margin=float(opt["margin"]))
    np.testing.assert_array_equal(grid.occupied, bundled_map(name).occupied)


def _near_brute(occupied: np.ndarray, cells: int) -> np.ndarray:
    """Every cell whose centre is closer than ``cells`` to an occupied cell's centre, by brute force."""
    yy, xx = np.nonzero(occupied)
    r, c = np.indices(occupied.shape)
    d2 = (r[..., None] - yy) ** 2 + (c[..., None] - xx) ** 2
    return (d2 < cells * cells).any(axis=-1)


def test_place_keeps_blocked_equal_to_a_full_recompute():
    """clutter.place (the generator's and the families' Canvas.scatter's obstacle step) updates
    ``blocked`` only near the new obstacle; the result must equal recomputing it over the whole grid."""
    from flashnav.maps.clutter import border_cells, bordered, grow, place

    rng = np.random.default_rng(3)
    spacing = 4
    occupied = bordered(30, 40, border_cells(0.05))
    assert occupied[:3].all() and occupied[:, -3:].all() and not occupied[3:-3, 3:-3].any()
    blocked = grow(occupied, spacing)
    np.testing.assert_array_equal(blocked, _near_brute(occupied, spacing))
    for _ in range(6):
        h, w = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        r0, c0 = int(rng.integers(0, 30 - h + 1)), int(rng.integers(0, 40 - w + 1))
        mask = rng.random((h, w)) < 0.7
        mask[0, 0] = True
        place(occupied, blocked, (slice(r0, r0 + h), slice(c0, c0 + w)), mask, spacing)
        assert occupied[r0:r0 + h, c0:c0 + w][mask].all()
        np.testing.assert_array_equal(blocked, _near_brute(occupied, spacing))
