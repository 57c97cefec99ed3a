"""ir-sim (pip ``ir-sim``) as an external oracle: its 2D LiDAR intersects each beam exactly with the
boundary of the union of occupied cell boxes, so from a free origin it must agree with our exact
raycaster to float precision.

How ir-sim is driven headless: the world YAML names the map as an image (row 0 = the top of the
map, so our bottom-first grid is flipped; dark = occupied), one robot carries the lidar2d, and
each pose is applied with ``robot.set_state`` + ``robot.sensor_step()`` (no stepping, no window).
ir-sim treats the outside of its world as free, so the map has border walls.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

irsim = pytest.importorskip("irsim")  # the optional `bench` extra (ir-sim): its absence is a documented skip
import matplotlib.image as mpimg  # noqa: E402

from flashnav.maps.grid import OccupancyMap  # noqa: E402
from flashnav.sim.raycast import make_raycaster, random_free_poses  # noqa: E402


def oracle_map(res=0.1, origin=(-1.0, 2.0)):
    rng = np.random.default_rng(0)
    occ = np.zeros((40, 60), bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    for _ in range(14):
        i, j = rng.integers(0, 40), rng.integers(0, 60)
        occ[i : i + rng.integers(1, 6), j : j + rng.integers(1, 6)] = True
    occ[8:30:3, 45] = True  # isolated cells and diagonal pairs: corner cases for both sides
    occ[10, 10] = occ[11, 11] = occ[12, 10] = True
    return OccupancyMap(occ, res, origin)


def irsim_env(grid, tmp_path, beams, max_range):
    png = tmp_path / "map.png"
    mpimg.imsave(png, np.flipud(~grid.occupied).astype(float), cmap="gray", vmin=0.0, vmax=1.0)
    xmin, ymin, xmax, ymax = grid.bounds
    world = tmp_path / "world.yaml"
    world.write_text(f"""
world:
  height: {ymax - ymin}
  width: {xmax - xmin}
  offset: [{xmin}, {ymin}]
  obstacle_map: {png}
robot:
  - kinematics: {{name: diff}}
    shape: {{name: circle, radius: 0.01}}
    state: [{xmin + 1.0}, {ymin + 1.0}, 0.0]
    sensors:
      - name: lidar2d
        range_min: 0
        range_max: {max_range}
        angle_range: {3 * math.pi / 2}
        number: {beams}
""")
    return irsim.make(str(world), headless=True, log_level="WARNING")


def test_irsim_lidar_agrees_with_exact(tmp_path):
    grid = oracle_map()
    env = irsim_env(grid, tmp_path, beams=270, max_range=20.0)
    lidar = env.robot.sensors[0]
    angles = torch.tensor(lidar.angle_list, dtype=torch.float32)  # linspace over 270 deg
    poses = random_free_poses(grid, 40, 3, min_clearance=0.02)
    ours = {name: make_raycaster(name, grid, angles, 20.0)(poses).double().numpy() for name in ("exact", "exact-torch")}
    theirs = []
    for x, y, yaw in poses.double().numpy():
        env.robot.set_state(np.array([[x], [y], [yaw]]))
        env.robot.sensor_step()
        theirs.append(np.array(lidar.get_scan()["ranges"], dtype=np.float64))
    theirs = np.stack(theirs)
    assert theirs.min() > 0 and theirs.max() < 20.0  # every beam hit a wall in both
    for name, r in ours.items():
        err = np.abs(r - theirs)
        assert err.max() < 1e-3, f"{name}: max |ours - ir-sim| = {err.max():.2e} m"
        assert np.median(err) < 1e-5
