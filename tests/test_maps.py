"""ROS map_server / Nav2 map I/O and the bundled maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from flashnav.maps import OccupancyMap, bundled_map, bundled_map_names, load_ros_map, resolve_map, save_ros_map
from flashnav.maps import grid as grid_module
from flashnav.maps.ros import REQUIRED_KEYS
from flashnav.presets import __file__ as _presets_init

PRESETS = Path(_presets_init).parent
BASE = dict(resolution=0.05, origin="[0.0, 0.0, 0.0]", negate=0, occupied_thresh=0.65, free_thresh=0.25)


def write_yaml(path: Path, image: str | None = "map.pgm", **overrides) -> Path:
    """A map YAML with BASE values; an override of None drops the key."""
    keys = {"image": image, **BASE, **overrides}
    path.write_text("".join(f"{k}: {v}\n" for k, v in keys.items() if v is not None), encoding="utf-8")
    return path


def write_map(tmp_path: Path, pixels, fmt: str = "pgm", mode: str | None = None, **overrides) -> Path:
    """Write ``pixels`` (image order: row 0 = top; uint8 [H, W] grey or [H, W, C]) and its YAML."""
    arr = np.asarray(pixels)
    Image.fromarray(arr if arr.dtype != np.int64 else arr.astype(np.uint8)).save(tmp_path / f"map.{fmt}")
    return write_yaml(tmp_path / "map.yaml", f"map.{fmt}", **({"mode": mode} if mode else {}), **overrides)


def free_cells(yaml_path: Path) -> np.ndarray:
    """[H, W] bool free cells of the loaded map, flipped back to image order for easy comparison."""
    return ~load_ros_map(yaml_path).occupied[::-1]


# ---- round trip ------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["pgm", "png"])
def test_round_trip_is_exact_with_origin(tmp_path, fmt):
    rng = np.random.default_rng(0)
    grid = OccupancyMap(rng.random((37, 53)) < 0.3, 0.025, origin=(-12.345, 7.125), name="x")
    yaml_path = save_ros_map(grid, tmp_path / "sub" / "room.yaml", image_format=fmt, comment="made by a test\nline 2")
    assert yaml_path == tmp_path / "sub" / "room.yaml" and (tmp_path / "sub" / f"room.{fmt}").is_file()
    text = yaml_path.read_text()
    assert text.startswith("# made by a test\n# line 2\n")
    assert f"image: room.{fmt}" in text and "mode: trinary" in text and "negate: 0" in text
    back = load_ros_map(yaml_path)
    np.testing.assert_array_equal(back.occupied, grid.occupied)
    assert back.resolution == grid.resolution and back.origin == grid.origin
    assert back.name == "room" and back.source == yaml_path
    with Image.open(tmp_path / "sub" / f"room.{fmt}") as img:
        assert img.mode == "L"


def test_saved_pixels_are_nav2_trinary_and_top_row_first(tmp_path):
    occupied = np.zeros((3, 4), dtype=bool)
    occupied[0, 0] = True  # lowest y, lowest x -> bottom-left pixel of the image
    save_ros_map(OccupancyMap(occupied, 0.1), tmp_path / "m.yaml")
    pixels = np.asarray(Image.open(tmp_path / "m.pgm"))
    assert pixels[-1, 0] == 0 and (pixels.ravel()[:-4] == 254).all() and set(np.unique(pixels)) == {0, 254}


def test_save_rejects_unknown_format(tmp_path):
    with pytest.raises(ValueError, match="image_format"):
        save_ros_map(OccupancyMap(np.zeros((2, 2), bool), 0.1), tmp_path / "m.yaml", image_format="jpg")


def test_absolute_and_relative_image_paths(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "yamls").mkdir()
    Image.fromarray(np.array([[0, 254]], np.uint8)).save(tmp_path / "images" / "a.pgm")
    absolute = write_yaml(tmp_path / "yamls" / "abs.yaml", str(tmp_path / "images" / "a.pgm"))
    relative = write_yaml(tmp_path / "yamls" / "rel.yaml", "../images/a.pgm")
    for path in (absolute, relative):
        np.testing.assert_array_equal(free_cells(path), [[False, True]])


def test_rows_are_flipped_into_lowest_y_first(tmp_path):
    top_black = np.array([[0, 0], [254, 254], [254, 254]], np.uint8)
    grid = load_ros_map(write_map(tmp_path, top_black, origin="[1.5, -2.0, 0.0]"))
    assert grid.occupied[-1].all() and not grid.occupied[0].any()
    assert grid.origin == (1.5, -2.0) and grid.bounds == pytest.approx((1.5, -2.0, 1.6, -1.85))


# ---- Nav2's pixel rule -----------------------------------------------------------------------------
# Grey values and what they mean at free_thresh 0.25 / occupied_thresh 0.65 (occ = 1 - v/255):
# 0 -> occ 1 (occupied); 100 -> 0.61, 150 -> 0.41, 191 -> 0.2510 (unknown in trinary);
# 200 -> 0.216, 254 -> 0.004, 255 -> 0 (free).
GREYS = np.array([[0, 100, 150, 191, 200, 254, 255]], np.uint8)


def test_trinary_thresholds_and_unknown_is_occupied(tmp_path):
    expected = [[False, False, False, False, True, True, True]]
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, GREYS)), expected)


def test_negate_swaps_dark_and_light(tmp_path):
    # negate: occ = v / 255 -> free below 0.25 (v <= 63), occupied above 0.65.
    expected = [[True, False, False, False, False, False, False]]
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, GREYS, negate=1)), expected)
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, GREYS, negate="true")), expected)


def test_scale_mode_keeps_what_rounds_to_zero_percent(tmp_path):
    # 191: occ 0.2510 lies between the thresholds, but Nav2 stores rint(100 * 0.00098 / 0.4) = 0 -> free.
    expected = [[False, False, False, True, True, True, True]]
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, GREYS, mode="scale")), expected)


def test_scale_mode_non_opaque_is_unknown(tmp_path):
    la = np.zeros((1, 3, 2), np.uint8)
    la[0, :, 0] = 254
    la[0, :, 1] = [255, 254, 0]  # opaque, almost opaque, transparent
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, la, fmt="png", mode="scale")), [[True, False, False]])


def test_raw_mode_uses_pixel_values_and_ignores_negate(tmp_path):
    # raw: value = pixel; 0 = free, 1..100 = occupancy percent, > 100 = unknown: only 0 is free.
    raw = np.array([[0, 1, 100, 101, 254, 255]], np.uint8)
    for negate in (0, 1):
        expected = [[True, False, False, False, False, False]]
        np.testing.assert_array_equal(free_cells(write_map(tmp_path, raw, mode="raw", negate=negate)), expected)


def test_rgb_shade_is_the_channel_mean(tmp_path):
    rgb = np.array([[[255, 255, 200], [255, 255, 0], [0, 0, 0], [254, 254, 254]]], np.uint8)
    # means 236.7 (occ 0.07, free), 170 (occ 0.33, unknown), 0 (occupied), 254 (free)
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, rgb, fmt="png")), [[True, False, False, True]])


def test_rgba_trinary_averages_alpha_in(tmp_path):
    rgba = np.array([[[254, 254, 254, 255], [254, 254, 254, 0], [255, 255, 255, 0], [0, 0, 0, 255]]], np.uint8)
    # transparent white: (3 * 255 + 0) / 4 = 191.25 -> occ 0.25, not < 0.25 -> unknown -> occupied
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, rgba, fmt="png")), [[True, False, False, False]])
    # raw mode leaves alpha out: transparent black is value 0 -> free
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, rgba, fmt="png", mode="raw")), [[False, False, False, True]])


def test_pgm_p2_and_p5_with_comments(tmp_path):
    (tmp_path / "map.pgm").write_text("P2\n# CREATOR: a ROS tool\n3 2\n# maxval next\n255\n0 254 100\n254 # inline\n 0 254\n")
    expected = [[False, True, False], [True, False, True]]
    np.testing.assert_array_equal(free_cells(write_yaml(tmp_path / "map.yaml")), expected)
    (tmp_path / "map.pgm").write_bytes(b"P5\n# CREATOR: GIMP\n3 2\n255\n" + bytes([0, 254, 100, 254, 0, 254]))
    np.testing.assert_array_equal(free_cells(write_yaml(tmp_path / "map.yaml")), expected)


def test_sixteen_bit_grey_png(tmp_path):
    Image.fromarray(np.array([[0, 65535, 30000]], np.uint16)).save(tmp_path / "map.png")
    np.testing.assert_array_equal(free_cells(write_yaml(tmp_path / "map.yaml", "map.png")), [[False, True, False]])


def test_palette_png_with_transparency(tmp_path):
    img = Image.fromarray(np.array([[0, 1, 2]], np.uint8), mode="P")
    img.putpalette([254, 254, 254, 0, 0, 0, 254, 254, 254])
    img.save(tmp_path / "map.png", transparency=2)  # index 2 is transparent white
    np.testing.assert_array_equal(free_cells(write_yaml(tmp_path / "map.yaml", "map.png")), [[True, False, False]])


def test_grey_png_with_a_transparent_colour(tmp_path):
    Image.fromarray(np.array([[254, 0, 200]], np.uint8)).save(tmp_path / "map.png", transparency=200)
    # the tRNS grey 200 is transparent: (3 * 200 + 0) / 4 = 150 -> occ 0.41 -> unknown -> occupied
    np.testing.assert_array_equal(free_cells(write_yaml(tmp_path / "map.yaml", "map.png")), [[True, False, False]])


def test_yaw_is_ignored_with_a_warning_naming_the_file(tmp_path):
    path = write_map(tmp_path, [[0, 254]], origin="[1.0, 2.0, 0.5]")
    with pytest.warns(UserWarning, match=r"map\.yaml.*yaw 0\.5"):
        grid = load_ros_map(path)
    assert grid.origin == (1.0, 2.0)


def test_unknown_grey_read_as_free_warns(tmp_path):
    with pytest.warns(UserWarning, match=r"1 pixels .* grey 205 .* free_thresh 0.25"):
        load_ros_map(write_map(tmp_path, [[205, 254, 0]]))
    np.testing.assert_array_equal(free_cells(write_map(tmp_path, [[205, 254, 0]], free_thresh=0.196)), [[False, True, False]])


# ---- errors ----------------------------------------------------------------------------------------
def test_missing_yaml(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.yaml"):
        load_ros_map(tmp_path / "nope.yaml")


def test_missing_image_names_the_path_it_tried_and_the_yaml(tmp_path):
    path = write_yaml(tmp_path / "room.yaml", "pics/room.pgm")
    with pytest.raises(FileNotFoundError) as err:
        load_ros_map(path)
    assert str(tmp_path / "pics" / "room.pgm") in str(err.value) and str(path) in str(err.value)
    folder = write_yaml(tmp_path / "dir.yaml", ".")  # image: a folder (once "image file not found: tried DIR")
    with pytest.raises(FileNotFoundError, match=r"dir\.yaml: image: '\.' is a folder .*not the map's image file"):
        load_ros_map(folder)


def test_unreadable_and_truncated_images(tmp_path):
    (tmp_path / "map.pgm").write_bytes(b"this is not an image at all")
    with pytest.raises(ValueError, match=r"map\.yaml.*cannot read image .*map\.pgm"):
        load_ros_map(write_yaml(tmp_path / "map.yaml"))
    (tmp_path / "map.pgm").write_bytes(b"P5\n40 40\n255\n" + bytes(100))  # header promises 1,600 bytes
    with pytest.raises(ValueError, match=r"map\.yaml.*cannot decode image .*map\.pgm"):
        load_ros_map(write_yaml(tmp_path / "map.yaml"))


@pytest.mark.parametrize("text, match", [
    ("- a\n- b\n", "must be a mapping"),
    ("image: [unclosed\n", "not valid YAML"),
    ("", "must be a mapping"),
])
def test_yaml_that_is_not_a_mapping(tmp_path, text, match):
    (tmp_path / "m.yaml").write_text(text)
    with pytest.raises(ValueError, match=match):
        load_ros_map(tmp_path / "m.yaml")


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_missing_required_key_is_named(tmp_path, key):
    path = write_map(tmp_path, [[254]], **{key: None}) if key != "image" else write_yaml(tmp_path / "m.yaml", None)
    with pytest.raises(ValueError, match=rf"\.yaml: missing required key '{key}'"):
        load_ros_map(path)


@pytest.mark.parametrize("overrides, match", [
    (dict(free_thresh=0.7), r"free_thresh \(0.7\) must be smaller than occupied_thresh \(0.65\)"),
    (dict(free_thresh=0.65), "must be smaller"),
    (dict(occupied_thresh=1.5), r"thresholds must lie in \[0, 1\]"),
    (dict(free_thresh=-0.1), r"thresholds must lie in \[0, 1\]"),
    (dict(free_thresh="low"), "'free_thresh' must be a finite number"),
    (dict(mode="binary"), "'mode' must be one of trinary, scale, raw"),
    (dict(resolution=0), "'resolution' must be > 0"),
    (dict(resolution=-0.05), "'resolution' must be > 0"),
    (dict(resolution="fine"), "'resolution' must be a finite number"),
    (dict(origin="[0.0, 0.0]"), r"'origin' must be \[x, y, yaw\]"),
    (dict(origin="[0.0, .nan, 0.0]"), "'origin' must be finite"),
    # a robot would span 3e8 cells: the collision grid once asked numpy for 568 PiB
    (dict(resolution="1.0e-9"), r"'resolution' 1e-09 m per pixel is finer than 0.001 m"),
    # finite, but float32 poses overflow and float64 cannot place 0.05 m cells out there
    (dict(origin="[1.0e+308, 1.0e+308, 0]"), r"'origin' \[1e\+308, 1e\+308, 0.0\] is too far out for 0.05 m cells"),
    (dict(origin="[1.0e+15, 0.0, 0]"), r"'origin' .* too far out .* steps of 0.125 m"),
    (dict(negate=0.5), "'negate' must be 0 or 1"),
])
def test_bad_values_are_named(tmp_path, overrides, match):
    with pytest.raises(ValueError, match=r"map\.yaml: .*" + match):
        load_ros_map(write_map(tmp_path, [[254, 0]], **overrides))


@pytest.mark.parametrize("origin", ["[-1.0e+6, 4.0e+6, 0.0]", "[1.0e+12, 1.0e+12, 0.0]"])
def test_far_but_representable_origins_load(tmp_path, origin):
    # UTM-sized and larger origins stay legal: the float64 step there is far below a 0.05 m cell
    grid = load_ros_map(write_map(tmp_path, [[254, 0]], origin=origin))
    assert grid.origin == tuple(float(v) for v in origin.strip("[]").split(",")[:2])


def test_image_key_must_be_a_name(tmp_path):
    (tmp_path / "m.yaml").write_text("image: 12\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.25\n")
    with pytest.raises(ValueError, match="'image' must be a non-empty file name"):
        load_ros_map(tmp_path / "m.yaml")


def test_no_free_cell_is_empty_free_space(tmp_path):
    with pytest.raises(ValueError, match=r"map\.yaml: empty free space.*map\.pgm"):
        load_ros_map(write_map(tmp_path, np.zeros((4, 5), np.uint8)))


def test_too_large_image_is_refused_from_its_header(tmp_path, monkeypatch):
    monkeypatch.setattr(grid_module, "MAX_CELLS", 1000)
    # The header says 40 x 40 but the pixel data is missing: decoding it would fail with another
    # error, so this passes only if the size is checked before anything is decoded.
    (tmp_path / "map.pgm").write_bytes(b"P5\n40 40\n255\n")
    with pytest.raises(ValueError, match=r"map\.yaml: image .*map\.pgm is too large: 40 x 40 = 1600 pixels exceeds"):
        load_ros_map(write_yaml(tmp_path / "map.yaml"))


# ---- bundled maps and resolve_map ------------------------------------------------------------------
def test_bundled_names():
    assert bundled_map_names() == ["go2", "turtlebot2"]


@pytest.mark.parametrize("name, size_m, radius", [("turtlebot2", 10.0, 0.2 + 0.1), ("go2", 13.5, 0.449 + 0.1)])
def test_bundled_maps_fit_their_robot(name, size_m, radius):
    grid = bundled_map(name)
    assert grid is bundled_map(name)  # cached
    assert grid.resolution == 0.05 and grid.origin == (0.0, 0.0) and grid.name == name
    assert grid.width_m == pytest.approx(size_m) and grid.height_m == pytest.approx(size_m)
    grid.check_free_space(radius)
    labels, count = grid.components(radius)
    assert count == 1 and (labels > 0).mean() > 0.35  # one region holding any start and goal
    interior = grid.occupied[3:-3, 3:-3].mean()
    assert 0.08 < interior < 0.22 and grid.occupied[:3].all() and grid.occupied[:, -3:].all()


def test_presets_name_the_bundled_maps():
    for preset in ("turtlebot2", "go2"):
        assert f"map: {preset}" in (PRESETS / f"{preset}.yaml").read_text()


def test_unknown_bundled_name_lists_the_names():
    with pytest.raises(ValueError, match="unknown bundled map 'office'; bundled maps: go2, turtlebot2"):
        bundled_map("office")


def test_resolve_map(tmp_path):
    assert resolve_map(None, "go2") is bundled_map("go2")
    assert resolve_map("turtlebot2", "go2") is bundled_map("turtlebot2")
    own = OccupancyMap(np.zeros((3, 3), bool), 0.1)
    assert resolve_map(own, "go2") is own
    path = save_ros_map(bundled_map("turtlebot2"), tmp_path / "copy.yaml")
    for value in (path, str(path)):
        np.testing.assert_array_equal(resolve_map(value, "go2").occupied, bundled_map("turtlebot2").occupied)
    with pytest.raises(ValueError, match="'office' is neither a bundled map .*go2, turtlebot2"):
        resolve_map("office", "go2")
    with pytest.raises(FileNotFoundError, match=r"missing\.yaml"):
        resolve_map(str(tmp_path / "missing.yaml"), "go2")
    with pytest.raises(TypeError, match="got int"):
        resolve_map(3, "go2")


def test_cell_of_matches_a_per_point_floor_and_clips_on_request():
    import math

    import torch

    grid = OccupancyMap(np.zeros((7, 11), dtype=bool), 0.05, (-1.3, 2.7))
    rng = np.random.default_rng(0)
    xy = np.stack([rng.uniform(-1.6, -1.3 + 0.7, 500), rng.uniform(2.4, 2.7 + 0.45, 500)], axis=1)
    xy[:4] = [(-1.3, 2.7), (-1.3 + 0.55, 2.7 + 0.35), (-1.31, 2.69), (-0.75, 3.05)]  # corners and edges
    rows, cols = grid.cell_of(xy)
    want_r = [math.floor((y - 2.7) / 0.05) for _, y in xy]
    want_c = [math.floor((x + 1.3) / 0.05) for x, _ in xy]
    assert rows.dtype == np.int64 and rows.tolist() == want_r and cols.tolist() == want_c
    assert (rows < 0).any() and (cols >= 11).any()  # off the grid: not clipped unless asked
    r2, c2 = grid.cell_of(xy, clip=True)
    assert r2.tolist() == np.clip(want_r, 0, 6).tolist() and c2.tolist() == np.clip(want_c, 0, 10).tolist()
    # a float32 tensor floors in float32, as the simulator's torch arithmetic does
    t = torch.as_tensor(xy, dtype=torch.float32)
    origin, res = torch.tensor([-1.3, 2.7]), torch.tensor(0.05)
    ref = torch.floor((t - origin) / res).long()
    r3, c3 = grid.cell_of(t)
    assert r3.tolist() == ref[:, 1].tolist() and c3.tolist() == ref[:, 0].tolist()
    r4, c4 = grid.cell_of(xy.reshape(20, 25, 2))  # any leading shape
    assert r4.shape == (20, 25) and r4.reshape(-1).tolist() == want_r
