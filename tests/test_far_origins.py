"""Maps far from the world origin (UTM coordinates, 1e12 m) simulate exactly like the same map at
(0, 0): the environment works in a re-centred float32 frame and converts world coordinates in
float64 at its boundary (set_state, world_pose / world_goal)."""

from __future__ import annotations

import pytest
import torch

from flashnav.maps.bundled import bundled_map
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.env import make_env
from flashnav.sim.mapset import FRAME_LIMIT_M, sim_frame
from flashnav.sim.oracle import run_oracle

ORIGINS = [(0.0, 0.0), (500_000.0, 4_000_000.0), (1e12, 1e12)]


def moved(origin, name="turtlebot2") -> OccupancyMap:
    base = bundled_map(name)
    return OccupancyMap(base.occupied, base.resolution, origin, name=name)


def rollout(origin, steps=80, n=16, robot="turtlebot2"):
    env = make_env(robot, n, map=moved(origin, robot), seed=4)
    obs, _ = env.reset(seed=4)
    gen = torch.Generator().manual_seed(9)
    out = {"obs": [obs]}
    for _ in range(steps):
        o, r, terminated, truncated, info = env.step(torch.rand(n, 2, generator=gen) * 2 - 1)
        for key, value in (("obs", o), ("reward", r), ("terminated", terminated), ("truncated", truncated),
                           ("final_obs", info["final_obs"]), ("success", info["success"]),
                           ("collision", info["collision"])):
            out.setdefault(key, []).append(value)
    return env, {k: torch.stack(v) for k, v in out.items()}


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_far_origins_give_the_same_transitions(robot):
    _, ref = rollout(ORIGINS[0], robot=robot)
    assert ref["success"].any() or ref["collision"].any()  # episodes do end: flags are compared too
    goal_dist = ref["obs"][..., -4 if robot == "turtlebot2" else -5]
    assert (goal_dist > 0.1).float().mean() > 0.9
    for origin in ORIGINS[1:]:
        env, got = rollout(origin, robot=robot)
        assert env.frame_origin == origin
        for key in ref:
            # float32 tolerance asked; the re-centred frame actually makes them identical
            torch.testing.assert_close(got[key], ref[key], rtol=0, atol=1e-5, msg=f"{key} at origin {origin}")


def test_world_coordinates_round_trip_in_float64():
    origin = (500_000.0, 4_000_000.0)
    env = make_env("turtlebot2", 2, map=moved(origin), seed=0)
    near = make_env("turtlebot2", 2, map=moved((0.0, 0.0)), seed=0)
    local = torch.tensor([[5.05, 5.0, 0.3], [2.5, 7.25, -1.0]], dtype=torch.float64)
    goal = torch.tensor([[6.0, 5.5], [3.0, 6.0]], dtype=torch.float64)
    shift = torch.tensor(origin, dtype=torch.float64)
    world = torch.cat([local[:, :2] + shift, local[:, 2:]], dim=1)
    obs = env.set_state(world, goal + shift)
    assert torch.equal(obs, near.set_state(local, goal))
    assert torch.equal(env.pose, local.float())  # the state lives in the re-centred frame
    assert torch.allclose(env.world_pose(), world, rtol=0, atol=1e-6)
    assert torch.allclose(env.world_goal(), goal + shift, rtol=0, atol=1e-6)
    assert obs[0, 30].item() == pytest.approx(((6.0 - 5.05) ** 2 + 0.5 ** 2) ** 0.5, abs=1e-5)


def test_maps_near_the_world_origin_stay_in_world_coordinates():
    # bit-exact with the simulator before re-centring existed, and env.pose is world coordinates
    assert sim_frame(moved((-3.3, 2.1))) == (0.0, 0.0)
    assert sim_frame(moved((FRAME_LIMIT_M - 10.0, 0.0))) == (0.0, 0.0)  # the 10 m map still fits
    assert sim_frame(moved((FRAME_LIMIT_M, 0.0))) == (FRAME_LIMIT_M, 0.0)
    env = make_env("turtlebot2", 1, map=moved((-3.3, 2.1)))
    env.set_state([[1.0, 3.0, 0.0]], [[2.0, 4.0]])
    assert env.pose[0, :2].tolist() == pytest.approx([1.0, 3.0]) and env.map is env.frame_map


def test_the_oracle_reaches_goals_on_a_utm_map_as_on_the_original():
    results = [run_oracle(make_env("turtlebot2", 32, map=moved(o), seed=1), episodes=32, seed=1)
               for o in ORIGINS[:2]]
    assert results[0]["success"] >= 0.9, results
    assert results[1] == results[0]
