"""The environment's public entry points refuse bad inputs with a ValueError that names the argument.

Before these checks a [2, N] or flat [2N] action was silently reshaped (rows scrambled), a NaN action
raised an IndexError deep in the collision code, and a goal outside the map could never be reached.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from flashnav.maps import grid as grid_module
from flashnav.maps.grid import OccupancyMap
from flashnav.sim.env import make_env
from test_env import open_room  # the same empty room as the env tests

N = 4


@pytest.fixture(scope="module")
def env():
    env = make_env("turtlebot2", N, map=open_room())
    env.reset(seed=0)
    return env


POSE = [[5.0, 5.0, 0.0]] * N
GOAL = [[8.0, 8.0]] * N


@pytest.mark.parametrize("shape", [(2, N), (2 * N,), (N, 3), (N + 1, 2), (N, 2, 1)])
def test_step_refuses_actions_of_another_shape(env, shape):
    # (2, N) and (2N,) hold exactly N * 2 numbers: the old reshape accepted them with rows scrambled
    with pytest.raises(ValueError, match=rf"actions must have shape \[num_envs, 2\] = \[{N}, 2\], got \[{', '.join(map(str, shape))}\]"):
        env.step(torch.zeros(shape))


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_step_refuses_non_finite_actions(env, bad):
    actions = torch.zeros(N, 2)
    actions[2, 1] = bad
    with pytest.raises(ValueError, match=r"actions\[2\] = .* is not finite"):
        env.step(actions)


def test_a_refused_step_changes_nothing(env):
    obs = env.set_state(POSE, GOAL)
    pose, steps = env.pose.clone(), env.steps.clone()
    with pytest.raises(ValueError):
        env.step(torch.full((N, 2), float("nan")))
    assert torch.equal(env.pose, pose) and torch.equal(env.steps, steps) and torch.equal(env.obs, obs)


def test_valid_inputs_in_every_accepted_form(env):
    env.set_state(np.array(POSE), np.array(GOAL))  # numpy and lists are still accepted
    obs, reward, *_ = env.step(np.zeros((N, 2), dtype=np.float64))
    assert obs.shape == (N, env.obs_dim) and reward.shape == (N,)


@pytest.mark.parametrize("name, pose, goal", [
    ("pose", [[5.0, float("nan"), 0.0]] + POSE[1:], GOAL),
    ("pose", POSE[:-1] + [[5.0, 5.0, float("inf")]], GOAL),
    ("goal", POSE, [[8.0, 8.0], [float("nan"), 8.0]] + GOAL[2:]),
])
def test_set_state_refuses_non_finite_values(env, name, pose, goal):
    with pytest.raises(ValueError, match=rf"{name}\[\d\] = .* is not finite"):
        env.set_state(pose, goal)


@pytest.mark.parametrize("name, pose, goal, layout", [
    ("pose", [[5.0, 5.0]] * N, GOAL, "x, y m, yaw rad"),
    ("pose", POSE[:-1], GOAL, "x, y m, yaw rad"),
    ("goal", POSE, [[8.0, 8.0, 0.0]] * N, "x, y m"),
    ("goal", POSE, [8.0, 8.0] * N, "x, y m"),
])
def test_set_state_refuses_other_shapes(env, name, pose, goal, layout):
    with pytest.raises(ValueError, match=rf"{name} must have shape \[{layout}\]"):
        env.set_state(pose, goal)


@pytest.mark.parametrize("goal", [[1e6, 5.0], [5.0, -3.0], [10.5, 5.0]])
def test_set_state_refuses_a_goal_outside_the_map(env, goal):
    goals = GOAL[:1] + [goal] + GOAL[2:]
    with pytest.raises(ValueError, match=r"goal\[1\] = .* lies outside the map 'room' \(x in \[0, 10\] m"):
        env.set_state(POSE, goals)


@pytest.mark.parametrize("pose", [[100.0, 100.0, 0.0], [-2.0, 5.0, 1.0]])
def test_set_state_refuses_a_robot_outside_the_map(env, pose):
    with pytest.raises(ValueError, match=r"pose\[3\] = .* lies outside the map 'room' \(x in \[0, 10\] m"):
        env.set_state(POSE[:3] + [pose], GOAL)


def test_a_network_output_stepped_with_its_graph_leaves_no_graph_in_the_env(env):
    """Stepping `net(obs)` without torch.no_grad() chained the graph into the env's state, which grew every
    step (1,024 envs: 0.4 -> 2.1 GB in 400 steps)."""
    env.set_state(POSE, GOAL)
    weight = torch.ones(2, requires_grad=True)
    env.step(torch.full((N, 2), 0.3) * weight)
    assert not any(t.requires_grad for t in (env.pose, env.episode_return, env.obs))


def test_a_goal_on_the_map_edge_is_accepted(env):
    env.set_state(POSE, [[10.0, 10.0], [0.0, 0.0]] + GOAL[2:])


def test_step_slots_checks_indices_and_actions(env):
    env.set_state(POSE, GOAL)
    idx = torch.tensor([0, 2])
    assert env.step_slots(idx, torch.zeros(2, 2))["obs"].shape == (2, env.obs_dim)
    with pytest.raises(ValueError, match=r"actions must have shape \[len\(idx\), 2\] = \[2, 2\], got \[4\]"):
        env.step_slots(idx, torch.zeros(4))
    with pytest.raises(ValueError, match=r"actions\[1\] = .* is not finite"):
        env.step_slots(idx, torch.tensor([[0.0, 0.0], [float("nan"), 0.0]]))
    with pytest.raises(ValueError, match=rf"idx holds slot {N}, outside \[0, {N}\)"):
        env.step_slots(torch.tensor([0, N]), torch.zeros(2, 2))
    with pytest.raises(ValueError, match=r"idx holds slot -1"):  # -1 would silently pick the last slot
        env.step_slots(torch.tensor([-1]), torch.zeros(1, 2))
    before = env.pose.clone()
    with pytest.raises(ValueError, match=r"idx holds slot 2 more than once"):  # advanced twice, written back in no order
        env.step_slots(torch.tensor([3, 2, 0, 2]), torch.zeros(4, 2))
    assert torch.equal(env.pose, before)  # refused before anything moved
    for bad in (torch.tensor([0.0, 1.0]), torch.tensor([True, False, True, False]), torch.tensor([[0, 1]])):
        with pytest.raises(ValueError, match="idx must be a 1-D integer tensor"):
            env.step_slots(bad, torch.zeros(2, 2))


def test_reset_mask_must_be_bool_per_env(env):
    with pytest.raises(ValueError, match=rf"reset_mask'\] must be a bool tensor of shape \[num_envs\] = \[{N}\]"):
        env.reset(options={"reset_mask": torch.ones(N + 1, dtype=torch.bool)})
    with pytest.raises(ValueError, match="reset_mask"):  # slot indices, once silently read as a mask
        env.reset(options={"reset_mask": [1, 3, 0, 2]})
    env.reset(options={"reset_mask": torch.tensor([True, False, True, False])})


def test_a_map_too_fine_for_the_robot_is_refused(monkeypatch):
    monkeypatch.setattr(grid_module, "MAX_CELLS", 100_000)
    fine = OccupancyMap(np.zeros((40, 40), dtype=bool), 0.001, name="fine")  # TB2's radius: ~700 cells
    with pytest.raises(ValueError, match=r"map 'fine': resolution 0.001 m is too fine for turtlebot2"):
        make_env("turtlebot2", 1, map=fine)


def test_a_step_before_any_reset_is_refused():
    """Every robot and goal start at (0, 0): a step from there scored every slot a success."""
    fresh = make_env("turtlebot2", 3, map=open_room())
    for step in (lambda: fresh.step(torch.zeros(3, 2)), lambda: fresh.step_slots(torch.arange(3), torch.zeros(3, 2))):
        with pytest.raises(RuntimeError, match=r"step\(\) before reset\(\).*call env.reset"):
            step()
    fresh.reset(seed=0)
    _, reward, terminated, _, info = fresh.step(torch.zeros(3, 2))
    assert not bool(info["success"].all())
    placed = make_env("turtlebot2", 1, map=open_room())
    placed.set_state(torch.tensor([[2.0, 2.0, 0.0]]), torch.tensor([[4.0, 2.0]]))  # set_state starts episodes too
    placed.step(torch.zeros(1, 2))


@pytest.mark.parametrize("seed, error, said", [
    (1.9, TypeError, "seed must be an integer, got float 1.9"),
    ("1", TypeError, "seed must be an integer, got str '1'"),
    (True, TypeError, "seed must be an integer, got bool True"),
    (-1, ValueError, "seed must be in [0, 2**63 - 1], got -1"),
    (2**70, ValueError, "seed must be in [0, 2**63 - 1]"),
])
def test_seeds_are_whole_numbers_in_torchs_range(seed, error, said):
    with pytest.raises(error, match=said.replace("[", r"\[").replace("]", r"\]").replace("*", r"\*")):
        make_env("turtlebot2", 2, map=open_room(), seed=seed)
    env = make_env("turtlebot2", 2, map=open_room(), seed=np.int64(3))  # numpy's integers are integers
    with pytest.raises(error):
        env.reset(seed=seed)
    a, _ = env.reset(seed=np.int64(5))
    b, _ = make_env("turtlebot2", 2, map=open_room()).reset(seed=5)
    assert torch.equal(a, b)


@pytest.mark.parametrize("n, error", [("4", TypeError), (2.5, TypeError), (True, TypeError), (0, ValueError)])
def test_num_envs_is_a_whole_number(n, error):
    with pytest.raises(error, match="num_envs must be"):
        make_env("turtlebot2", n, map=open_room())


def test_a_refused_map_set_leaves_the_env_as_it_was():
    rooms = [open_room(), OccupancyMap(np.zeros((300, 300), bool), 0.05)]
    env = make_env("turtlebot2", 8, maps=rooms, seed=1)
    env.reset(seed=1)
    before = (env.maps, env.map_index.clone(), env.goal_distance_max, env.pose.clone())
    with pytest.raises(ValueError, match="map_weights has 2 entries for 1 maps"):
        env.replace_maps([open_room()], map_weights=[1, 2])
    assert env.maps is before[0] and torch.equal(env.map_index, before[1]) and env.goal_distance_max == before[2]
    assert torch.equal(env.pose, before[3])
    env.step(torch.zeros(8, 2))  # still the old set, whole
    env.world_pose()


@pytest.mark.parametrize("origin", [(float("nan"), 0.0), (0.0, float("inf")), (1.0,), "ab"])
def test_an_origin_is_two_finite_numbers(origin):
    with pytest.raises(ValueError, match="origin must be two finite numbers"):
        OccupancyMap(np.zeros((10, 10), bool), 0.05, origin)
