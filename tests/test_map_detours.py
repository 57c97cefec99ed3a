"""scripts/map_detours.py: the share of long detours in a map's task (issue 16, Go2's map)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import map_detours  # noqa: E402

from flashnav.maps.grid import OccupancyMap  # noqa: E402
from flashnav.maps.ros import save_ros_map  # noqa: E402
from flashnav.presets import load_robot  # noqa: E402


def _room(wall: bool) -> OccupancyMap:
    occ = np.zeros((120, 120), dtype=bool)  # 6 x 6 m at 0.05 m
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    if wall:  # a wall across the room from the left edge to 1 m short of the right one
        occ[58:62, :100] = True
    return OccupancyMap(occ, 0.05, (0.0, 0.0), "wall" if wall else "open")


def test_an_open_room_has_no_long_detours_and_a_wall_makes_them(tmp_path):
    preset = load_robot("turtlebot2")
    open_room = map_detours.map_detours(_room(False), preset, 2048, 0)
    walled = map_detours.map_detours(_room(True), preset, 2048, 0)
    # 8-connected paths are at most ~8 % longer than the straight line in the open
    assert open_room["detour_over_1.25"] == 0.0 and open_room["no_path"] == 0.0
    # about half the pairs lie on either side of the wall, and most of those go far round it
    assert walled["detour_over_1.25"] > 0.2 and walled["detour_over_1.5"] > 0.05
    assert walled["occupied"] > open_room["occupied"]
    save_ros_map(_room(True), tmp_path / "wall.yaml")
    out = tmp_path / "d.json"
    assert map_detours.main([str(tmp_path / "wall.yaml"), "--robot", "turtlebot2", "--episodes", "2048",
                             "--json", str(out)]) == 0
    assert json.loads(out.read_text())[0]["detour_over_1.25"] == walled["detour_over_1.25"]
