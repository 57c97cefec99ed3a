"""The peer simulator ir-sim (pip ``ir-sim``) stepping one robot on the same map, for ``bench sim``.

ir-sim is driven headless: the map is written as an image (row 0 = the top, so our bottom-first grid
is flipped; dark = occupied), one robot with the preset's footprint carries a 1,080-beam lidar2d,
and ``env.step`` advances it (motion, collision, sensing) with a constant velocity command.
"""

from __future__ import annotations

import importlib.util
import math
import tempfile
import time
from pathlib import Path

import numpy as np


def irsim_available() -> bool:
    return importlib.util.find_spec("irsim") is not None


def _world_yaml(preset, grid, png: Path, start) -> str:
    xmin, ymin, xmax, ymax = grid.bounds
    fp = preset.footprint
    shape = (f"{{name: circle, radius: {fp.radius}}}" if fp.kind == "disc"
             else f"{{name: rectangle, length: {fp.length}, width: {fp.width}}}")
    return f"""
world:
  height: {ymax - ymin}
  width: {xmax - xmin}
  step_time: {preset.episode.dt}
  offset: [{xmin}, {ymin}]
  obstacle_map: {png}
robot:
  - kinematics: {{name: diff}}
    shape: {shape}
    state: [{start[0]}, {start[1]}, {start[2]}]
    goal: [{start[0]}, {start[1]}, {start[2]}]
    sensors:
      - name: lidar2d
        range_min: 0
        range_max: {preset.lidar.max_range}
        angle_range: {math.radians(preset.lidar.fov_deg)}
        number: {preset.lidar.beams}
"""


def irsim_steps(robot: str, seconds: float, seed: int = 0) -> dict:
    """Steps of one ir-sim robot per second on ``robot``'s bundled map (start poses re-drawn from our
    sampler whenever it collides or arrives)."""
    import irsim
    import matplotlib.image as mpimg

    from flashnav.sim.env import make_env

    env = make_env(robot, 64, seed=seed)
    env.reset(seed=seed)  # 64 solvable start poses from our sampler
    poses = env.pose.numpy().astype(float)
    with tempfile.TemporaryDirectory() as tmp:
        png = Path(tmp) / "map.png"
        mpimg.imsave(png, np.flipud(~env.map.occupied).astype(float), cmap="gray", vmin=0.0, vmax=1.0)
        world = Path(tmp) / "world.yaml"
        world.write_text(_world_yaml(env.preset, env.map, png, poses[0]))
        sim = irsim.make(str(world), headless=True, log_level="WARNING")
        action = np.array([[0.3], [0.2]])
        steps, k = 0, 0
        start = time.perf_counter()
        while steps < 5 or time.perf_counter() - start < seconds:
            if steps % 50 == 0:  # a fresh start pose every 50 steps (one episode's worth of motion)
                x, y, yaw = poses[k % len(poses)]
                sim.robot.set_state(np.array([[x], [y], [yaw]]))
                k += 1
            sim.step(action)
            steps += 1
        elapsed = time.perf_counter() - start
    return {"robot": robot, "steps": steps, "seconds": elapsed, "env_steps_per_s": steps / elapsed,
            "beams": env.preset.lidar.beams}
