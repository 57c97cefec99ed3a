"""The simulator on every torch device this machine has: the CPU always, CUDA where one is visible.

FlashNav's GPU paths have never run on a GPU (shared/notes/gpu.md, item 1). This module is what a first
``pytest`` on a CUDA machine checks them with: a device's transitions equal the CPU reference's.

- The reference is the CPU default: the numba raycaster ("exact") and the numba agent kernels.
- The device runs what a GPU runs: the "exact-torch" raycaster and the torch agent kernels (moving and
  sensing). On a CPU-only machine the device is the CPU itself with those torch paths, so the test
  checks the torch stack against the numba one over whole rollouts; with CUDA it checks the GPU too.
- Random draws come from each device's own generator (CUDA's differ from the CPU's for one seed), so the
  device env is given the reference's episodes (``set_state``) and its agents (their state copied) and
  both step without autoreset (``step_slots``): the same episodes, played with the same actions.

Tolerances: ranges agree to 1e-5 m (the raycasters' contract), observations (pooled ranges, goal,
velocity) and rewards to 1e-4; flags and step counts must be equal.
"""

from __future__ import annotations

import functools

import pytest
import torch

from flashnav.presets import load_robot
from flashnav.sim.env import make_env

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
MIX = {"waypoints": 1.0, "bounce": 1.0, "crossing": 1.0}
FLAGS = ("terminated", "truncated", "success", "collision", "collision_static", "collision_agent")


def reference_and_device(robot: str, device: str, agents: int, n: int, seed: int):
    """The CPU reference env (reset with ``seed``) and an env on ``device`` holding the same episodes."""
    preset = load_robot(robot, **({"agents.count": agents, "agents.mix": MIX} if agents else {}))
    ref = make_env(preset, n, seed=seed)
    dev = make_env(preset, n, seed=seed, device=device, raycaster="exact-torch")
    assert ref.raycaster_name == "exact" and dev.raycaster_name == "exact-torch"
    ref.reset(seed=seed)
    dev.set_state(ref.world_pose(), ref.world_goal())
    if agents:
        world = dev.agents
        world.step_kernel = "torch"
        world.sense = functools.partial(world.sense, kernel="torch")  # the CPU would pick numba
        copied = 0
        for name, value in vars(ref.agents).items():
            if torch.is_tensor(value) and value.shape == getattr(world, name).shape:
                getattr(world, name).copy_(value)
                copied += 1
        assert copied >= 10 and bool(ref.agents.active.any()), "the agents' state must travel"
    return ref, dev


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("robot,agents", [("turtlebot2", 0), ("go2", 0), ("turtlebot2", 8)],
                         ids=["tb2", "go2", "tb2-8-agents"])
def test_device_transitions_equal_the_cpu_reference(device, robot, agents):
    n, seed = 64, 3
    ref, dev = reference_and_device(robot, device, agents, n, seed)
    gen = torch.Generator().manual_seed(seed)
    active = torch.arange(n)
    start = ref.agents.pos.clone() if agents else None
    ended = {"collision": 0, "success": 0}
    for step in range(ref.preset.episode.horizon):  # every episode ends (no autoreset)
        action = torch.rand(active.numel(), 2, generator=gen) * 2 - 1
        action[:, 0] = action[:, 0] * 0.5 + 0.5  # biased forward: episodes end
        a = ref.step_slots(active, action)
        b = {k: v.cpu() for k, v in dev.step_slots(active.to(device), action.to(device)).items()}
        where = f"{robot}, {agents} agents, step {step} on {device}"
        for key in FLAGS:
            assert torch.equal(a[key], b[key]), f"{key} differs ({where})"
        torch.testing.assert_close(b["obs"], a["obs"], atol=1e-4, rtol=0, msg=lambda m: f"obs ({where}): {m}")
        torch.testing.assert_close(b["reward"], a["reward"], atol=1e-4, rtol=0)
        assert torch.equal(a["episode_steps"], b["episode_steps"])
        done = a["terminated"] | a["truncated"]
        for key in ended:
            ended[key] += int((done & a[key]).sum())
        active = active[~done]
        if active.numel() == 0:
            break
    # the rollout must exercise what it compares: collisions and arrivals (and moving agents, below)
    assert ended["collision"] > 0 and ended["success"] + active.numel() > 0
    if agents:  # the torch kernels moved the agents as numba did (slots freeze when their episode ends)
        moved = (ref.agents.pos - start).norm(dim=-1)[ref.agents.active]
        assert moved.numel() > 0 and float(moved.max()) > 0.5, "the agents must have moved"
        torch.testing.assert_close(dev.agents.pos.cpu(), ref.agents.pos, atol=1e-5, rtol=0)
        assert torch.equal(dev.agents.active.cpu(), ref.agents.active)


@pytest.mark.parametrize("device", DEVICES)
def test_device_scans_on_many_maps_equal_the_cpu_reference(device):
    """Per-slot maps of different sizes and resolutions: the exact-torch raycaster on ``device`` against
    the numba one on the CPU, map by map."""
    from flashnav.maps import generate_map

    grids = [generate_map(6.0, 6.0, 0.05, seed=1, robot_radius=0.3, name="a"),
             generate_map(9.0, 7.0, 0.1, seed=2, robot_radius=0.3, name="b"),
             generate_map(5.0, 8.0, 0.025, seed=3, robot_radius=0.3, name="c")]
    ref = make_env("turtlebot2", 96, maps=grids, seed=5)
    dev = make_env("turtlebot2", 96, maps=grids, seed=5, device=device, raycaster="exact-torch")
    ref.reset(seed=5)
    obs = dev.set_state(ref.world_pose(), ref.world_goal(), map_index=ref.map_index)
    assert len(set(ref.map_index.tolist())) == 3
    torch.testing.assert_close(obs.cpu(), ref.obs, atol=1e-4, rtol=0)
    torch.testing.assert_close(dev.scan().cpu(), ref.scan(), atol=1e-5, rtol=0)


@pytest.mark.parametrize("device", DEVICES)
def test_device_wall_map_equals_the_cpu_reference(device):
    """The wall map (observation.wall_map) kept and drawn on ``device`` against the CPU reference's over whole
    episodes: every other column as above; the squares equal but where a hit or a cell centre lies within float
    rounding of an edge (the two raycasters agree to 1e-5 m), at most a few in a thousand."""
    cells = 12
    preset = load_robot("turtlebot2", **{"observation.wall_map": cells})
    n, seed = 48, 4
    ref = make_env(preset, n, seed=seed)
    dev = make_env(preset, n, seed=seed, device=device, raycaster="exact-torch")
    ref.reset(seed=seed)
    a_obs, b_obs = ref.obs.clone(), dev.set_state(ref.world_pose(), ref.world_goal()).cpu()
    end = preset.memory_end
    gen = torch.Generator().manual_seed(seed)
    active, squares, differ = torch.arange(n), 0, 0
    for _ in range(60):
        torch.testing.assert_close(b_obs[:, :end], a_obs[:, :end], atol=1e-4, rtol=0)
        squares += int(a_obs[:, end: end + cells * cells].sum())
        differ += int((a_obs[:, end:] != b_obs[:, end:]).sum())
        action = torch.rand(active.numel(), 2, generator=gen) * 2 - 1
        a = ref.step_slots(active, action)
        b = {k: v.cpu() for k, v in dev.step_slots(active.to(device), action.to(device)).items()}
        done = a["terminated"] | a["truncated"]
        assert torch.equal(done, b["terminated"] | b["truncated"])
        active, a_obs, b_obs = active[~done], a["obs"][~done], b["obs"][~done]
        if active.numel() == 0:
            break
    assert squares > 5000 and differ <= 0.003 * squares
