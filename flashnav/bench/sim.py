"""``flashnav bench sim``: whole-step simulator throughput per raycaster x num_envs x preset.

Every figure is measured in the same process, side by side, so ratios against the paper-literal
``march`` raycaster (and the peer simulator ir-sim, when installed) hold on a noisy machine.
A step here is the whole environment step (motion, full 1,080-beam scan, collision, reward,
observation, sparse reset of finished slots) driven by uniformly random actions.

With ``--maps`` every row is measured twice, in alternating blocks of steps: on the robot's bundled
map and on a set of many maps (each slot on its own map, drawing a new one at every reset), so the
ratio of the two is the cost of many maps, under the same load.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import torch

from flashnav.maps.generate import generate_map
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.stream import generation_radius
from flashnav.presets import load_robot
from flashnav.sim.env import make_env
from flashnav.sim.raycast import error_stats, make_raycaster, random_free_poses


@dataclass
class StepRow:
    robot: str
    raycaster: str
    num_envs: int
    device: str
    steps: int
    seconds: float
    maps: int = 1
    agents: int = 0  # moving agents per environment (issue 13)
    tracks: int = 0  # agent tracks in the observation (observation.agent_tracks)
    memory: int = 0  # stored scans of the memory scan (observation.memory_frames)
    wall_map: int = 0  # squares a side of the wall map (observation.wall_map)
    visited: bool = False  # the wall map's visited channel (observation.wall_map_visited)
    plan: bool = False  # the wall map's plan channel (observation.wall_map_plan)
    plan_penalty: float = 0.0  # its cost beside a wall (observation.wall_map_plan_penalty)

    @property
    def env_steps_per_s(self) -> float:
        return self.num_envs * self.steps / self.seconds

    def to_dict(self, beams: int) -> dict:
        d = asdict(self)
        d["env_steps_per_s"] = self.env_steps_per_s
        d["rays_per_s"] = self.env_steps_per_s * beams
        return d


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def bench_maps(robot: str, count: int, seed: int = 1000) -> list[OccupancyMap]:
    """``count`` different maps like the robot's bundled one (its size, 0.05 m cells, passages for
    its footprint at its start clearance), generated with seeds ``seed``, ``seed + 1``, ...: the
    many-map rows then differ from the single-map ones only in the number of maps."""
    if count < 1:
        raise ValueError(f"--maps must be >= 1 maps, got {count}")
    preset = load_robot(robot)
    width, height = preset.map_size
    radius = generation_radius(preset)
    return [generate_map(width, height, 0.05, seed + i, robot_radius=radius, name=f"{robot}-bench-{seed + i}")
            for i in range(count)]


def variant_overrides(agents: int = 0, tracks: int = 0, memory: int = 0, wall_map: int = 0,
                      visited: bool = False, plan: bool = False, plan_penalty: float = 0.0) -> list[dict]:
    """The preset overrides of the rows beside the static one, in the table's order (see :func:`time_steps`)."""
    if (visited or plan) and not wall_map:
        raise ValueError("the visited and plan channels' rows need a wall map (wall_map > 0)")
    rows = []
    if agents:
        rows.append({"agents.count": agents})
        if tracks:
            rows.append({"agents.count": agents, "observation.agent_tracks": tracks})
    if memory:
        rows.append({"observation.memory_frames": memory, "observation.memory_every": 1})
    if wall_map:
        rows.append({"observation.wall_map": wall_map})
        if visited:
            rows.append({"observation.wall_map": wall_map, "observation.wall_map_visited": True})
        if plan:
            rows.append({"observation.wall_map": wall_map, "observation.wall_map_plan": True})
            if plan_penalty:
                rows.append({"observation.wall_map": wall_map, "observation.wall_map_plan": True,
                             "observation.wall_map_plan_penalty": plan_penalty})
    return rows


def time_steps(robot: str, raycaster: str, num_envs: int, device: str, min_seconds: float,
               max_steps: int, seed: int = 0, maps: list[OccupancyMap] | None = None,
               agents: int = 0, tracks: int = 0, memory: int = 0, wall_map: int = 0,
               visited: bool = False, plan: bool = False, plan_penalty: float = 0.0) -> list[StepRow]:
    """Step ``num_envs`` environments with random actions for at least ``min_seconds`` (at least 2
    steps, at most ``max_steps``) after 2 warm-up steps (JIT compilation, caches), on the robot's
    bundled map. With ``maps``, a second env of the same size on those maps (each slot drawing its
    map at every reset) is stepped too, in alternating blocks of 4 steps, so that both rows see the
    same load; each gets ``min_seconds`` of its own. With ``agents`` > 0, one more env on the bundled
    map with that many moving agents per slot (the preset's behaviour mix) joins the rotation, and with
    ``tracks`` > 0 too, one more with those agents and ``observation.agent_tracks = tracks``; with ``memory``
    > 0, one more on the bundled map, static, with the memory scan of that many stored scans
    (``observation.memory_frames``, one stored every step); with ``wall_map`` > 0, one more on the bundled map,
    static, with the wall map of that many squares a side (``observation.wall_map``, the other wall-map keys at
    their defaults), and with ``visited`` too, one more with that wall map and its visited channel
    (``observation.wall_map_visited``), and with ``plan``, one more with that wall map and its plan channel
    (``observation.wall_map_plan``), and with ``plan_penalty`` too, one more with that plan at that penalty
    (``observation.wall_map_plan_penalty``). Returns the bundled-map row first, then the many-map row, then the agents
    row, then the tracks row, then the memory row, then the wall-map rows (those asked for)."""
    envs = [make_env(robot, num_envs, device=device, seed=seed, raycaster=raycaster)]
    if maps is not None:
        envs.append(make_env(robot, num_envs, maps=maps, device=device, seed=seed, raycaster=raycaster))
    for overrides in variant_overrides(agents, tracks, memory, wall_map, visited, plan, plan_penalty):
        envs.append(make_env(load_robot(robot, **overrides), num_envs, device=device, seed=seed, raycaster=raycaster))
    dev = envs[0].device
    gen = torch.Generator(device=dev).manual_seed(seed)
    actions = [torch.rand(num_envs, 2, generator=gen, device=dev) * 2 - 1 for _ in range(16)]
    for env in envs:
        env.reset(seed=seed)
        for i in range(2):
            env.step(actions[i])
    _sync(dev)
    steps, seconds = [0] * len(envs), [0.0] * len(envs)
    while min(steps) < max_steps and (min(steps) < 2 or min(seconds) < min_seconds):
        for k, env in enumerate(envs):
            start = time.perf_counter()
            for _ in range(min(4, max_steps - steps[k])):
                env.step(actions[steps[k] % len(actions)])
                steps[k] += 1
            _sync(dev)
            seconds[k] += time.perf_counter() - start
    return [StepRow(robot, raycaster, num_envs, str(dev), steps[k], seconds[k], env.num_maps,
                    env.preset.agents.count, env.preset.observation.agent_tracks, env.preset.observation.memory_frames,
                    env.preset.observation.wall_map, env.preset.observation.wall_map_visited,
                    env.preset.observation.wall_map_plan, env.preset.observation.wall_map_plan_penalty)
            for k, env in enumerate(envs)]


def accuracy(robot: str, raycaster: str, device: str, num_poses: int = 256, seed: int = 1) -> dict:
    """Error of ``raycaster`` against the exact raycaster on random free poses of the robot's map."""
    env = make_env(robot, 1, device=device, seed=seed)
    poses = random_free_poses(env.map, num_poses, seed=seed).to(env.device)
    exact = make_raycaster("exact", env.map, env.beam_angles, env.preset.lidar.max_range, env.device)(poses)
    other = make_raycaster(raycaster, env.map, env.beam_angles, env.preset.lidar.max_range, env.device,
                           env.preset.lidar.march_step)(poses)
    return {"robot": robot, "raycaster": raycaster, **error_stats(other, exact)}
