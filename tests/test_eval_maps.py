"""`flashnav eval POLICY --maps`: the per-map table against each map evaluated alone (the slow reference),
the aggregate arithmetic, the command line and its JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from conftest import SMALL_HELDOUT

from flashnav.cli import main
from flashnav.eval_maps import (EVAL_MAPS_FORMAT, EVAL_MAPS_KIND, aggregate, evaluate_maps, maps_surely_under,
                                maps_under, success_interval, suite_path)
from flashnav.evaluate import evaluate_episodes, stalled
from flashnav.maps import bundled_map, load_ros_map
from flashnav.presets import load_robot
from flashnav.sim.env import make_env

HELDOUT = Path(suite_path("heldout"))
FIXTURE_POLICY = Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx"


def heading_controller(obs: torch.Tensor) -> torch.Tensor:
    """Deterministic and row-wise (a row's action does not depend on the batch): turn towards the goal,
    drive when facing it and the front is clear. Reaches, collides and times out on these maps."""
    angle = obs[:, 31]
    front = obs[:, 14:16].amin(dim=1)
    turn = (2.0 * angle / math.pi).clamp(-1.0, 1.0)
    drive = torch.where((angle.abs() < 0.6) & (front > 0.3), 1.0, -1.0)
    return torch.stack([drive, turn], dim=1)


def _grids():
    return [bundled_map("turtlebot2")] + [load_ros_map(HELDOUT / f"{name}.yaml") for name in SMALL_HELDOUT]


@pytest.mark.parametrize("sampling", ["geodesic", "euclidean"])
def test_each_maps_row_equals_that_map_evaluated_alone(sampling):
    preset = load_robot("turtlebot2", **{"episode.goal_sampling": sampling})
    grids, episodes, seed = _grids(), 24, 5
    got = evaluate_maps(heading_controller, preset, grids, episodes, seed, goal_distance_scale=14.0)
    outcomes = []
    for grid, row in zip(grids, got["maps"]):
        # the slow reference: a one-map env on this map alone, reset with the same seed
        env = make_env(preset, episodes, map=grid, seed=123)
        ref = evaluate_episodes(heading_controller, env, seed=seed)
        success, collision = ref["success"], ref["collision"]
        assert row["map"] == grid.name and row["episodes"] == episodes
        assert row["success_rate"] == success.float().mean().item()
        assert row["success_interval"] == success_interval(int(success.sum()), episodes)
        assert row["collision_rate"] == collision.float().mean().item()
        assert row["timeout_rate"] == (~success & ~collision).float().mean().item()
        assert row["stalled_rate"] == stalled(ref).float().mean().item() <= row["timeout_rate"]
        assert row["outcomes"] == "".join("s" if a else "c" if b else "t" for a, b in zip(success.tolist(),
                                                                                         collision.tolist()))
        assert row["mean_steps"] == pytest.approx(ref["episode_steps"].mean().item())
        assert row["mean_return"] == pytest.approx(ref["episode_return"].mean().item(), abs=1e-5)
        beyond = int((ref["max_goal_distance"] > 14.0).sum())
        assert row["beyond_scale"] == (grid.diagonal_m > 14.0)
        assert row["episodes_beyond_scale"] == beyond
        outcomes += [row["success_rate"], row["collision_rate"]]
    assert max(outcomes) > 0 and min(outcomes) < 1  # the comparison covers more than one outcome
    assert got["aggregate"] == aggregate(got["maps"])


def test_a_maps_rows_do_not_depend_on_the_other_maps():
    preset = load_robot("turtlebot2", **{"episode.goal_sampling": "geodesic"})
    grids = _grids()
    three = evaluate_maps(heading_controller, preset, grids, 16, 9, goal_distance_scale=14.0)["maps"]
    one = evaluate_maps(heading_controller, preset, grids[2:], 16, 9, goal_distance_scale=14.0)["maps"]
    assert three[2] == one[0]


def test_max_goal_distance_is_the_largest_goal_distance_input():
    env = make_env("turtlebot2", 8, seed=0)
    seen = torch.zeros(8)
    e = evaluate_episodes(heading_controller, env, seed=2)
    # slow reference: replay every episode alone, reading the goal distance of every observation
    for k in range(8):
        one = make_env("turtlebot2", 1, seed=0)
        obs = one.set_state(e["start_pose"][k: k + 1], e["goal"][k: k + 1])
        top = obs[0, 30].item()
        for _ in range(one.preset.episode.horizon):
            t = one.step_slots(torch.tensor([0]), heading_controller(obs))
            obs = t["obs"]
            top = max(top, obs[0, 30].item())
            if bool(t["terminated"][0] | t["truncated"][0]):
                break
        seen[k] = top
    assert torch.allclose(e["max_goal_distance"], seen, atol=1e-5)


def test_aggregate_by_hand():
    rows = [{"map": "a", "episodes": 10, "success_rate": 0.9, "collision_rate": 0.1, "timeout_rate": 0.0,
             "beyond_scale": True, "episodes_beyond_scale": 2},
            {"map": "b", "episodes": 30, "success_rate": 0.5, "collision_rate": 0.0, "timeout_rate": 0.5,
             "beyond_scale": False, "episodes_beyond_scale": 0}]
    a = aggregate(rows)
    assert a["mean"]["success_rate"] == pytest.approx(0.7)
    assert a["pooled"]["success_rate"] == pytest.approx((9 + 15) / 40)
    assert a["pooled"]["timeout_rate"] == pytest.approx(15 / 40)
    assert a["worst"] == {"map": "b", "success_rate": 0.5}
    assert (a["maps"], a["episodes"], a["maps_beyond_scale"], a["episodes_beyond_scale"]) == (2, 40, 1, 2)
    assert "stalled_rate" not in a["mean"]  # rows written before the stalled share: the rates they have
    rows[0]["stalled_rate"], rows[1]["stalled_rate"] = 0.0, 0.2
    a = aggregate(rows)
    assert a["mean"]["stalled_rate"] == pytest.approx(0.1) and a["pooled"]["stalled_rate"] == pytest.approx(6 / 40)


def test_success_interval_is_wilsons_score_interval_by_hand():
    z = 1.959963984540054  # the normal quantile of 0.975

    def wilson(k, n):
        p = k / n
        centre, half = p + z * z / (2 * n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
        return (centre - half) / (1 + z * z / n), (centre + half) / (1 + z * z / n)

    for k, n in [(121, 128), (128, 128), (0, 5), (3, 7), (500, 512)]:
        low, high = success_interval(k, n)
        assert (low, high) == pytest.approx(wilson(k, n), abs=1e-12) and low <= k / n <= high
    assert success_interval(121, 128)[1] > 0.95 > success_interval(110, 128)[1]   # 94.5 % may be a 95 % map, 85.9 % is not
    rows = [{"map": "a", "success_rate": 121 / 128, "success_interval": success_interval(121, 128)},
            {"map": "b", "success_rate": 110 / 128, "success_interval": success_interval(110, 128)},
            {"map": "c", "success_rate": 1.0, "success_interval": success_interval(128, 128)},
            {"map": "d", "success_rate": 0.9}]                         # a row from before the interval: its rate
    assert maps_under(rows) == ["a", "b", "d"] and maps_surely_under(rows) == ["b", "d"]


def test_command_line_table_and_json(tmp_path, capsys, small_heldout_maps):
    pytest.importorskip("onnxruntime")  # the `export` extra runs policy.onnx
    maps = small_heldout_maps
    out = tmp_path / "eval.json"
    assert main(["eval", str(FIXTURE_POLICY), "--maps", str(maps), "--episodes", "6", "--seed", "3",
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["kind"] == EVAL_MAPS_KIND and doc["format_version"] == EVAL_MAPS_FORMAT
    assert doc["goal_sampling"] == "geodesic" and doc["suite"] == "maps" and doc["episodes_per_map"] == 6
    meta = json.loads((FIXTURE_POLICY.parent / "policy.json").read_text())
    assert doc["goal_distance_scale"] == pytest.approx(meta["goal_distance_max"])
    assert [r["map"] for r in doc["maps"]] == sorted(SMALL_HELDOUT)
    for r in doc["maps"]:
        assert r["episodes"] == 6 and r["success_rate"] + r["collision_rate"] + r["timeout_rate"] == pytest.approx(1)
        assert r["beyond_scale"] == (r["diagonal_m"] > doc["goal_distance_scale"])
        assert r["map"] in text
    assert "goal sampling geodesic" in " ".join(text.split())
    assert "95 % interval" in text and f"maps under 95 % success: {len(maps_under(doc['maps']))} of 2" in text
    assert "of them stalled" in text and all(0 <= r["stalled_rate"] <= r["timeout_rate"] for r in doc["maps"])
    for r in doc["maps"]:
        low, high = r["success_interval"]
        assert f"{100 * low:.1f}-{100 * high:.1f}" in text


def test_command_line_refuses_map_with_maps_and_sampling_without_maps(capsys):
    assert main(["eval", str(FIXTURE_POLICY), "--maps", "heldout", "--map", "turtlebot2"]) == 2
    assert "either --map or --maps" in capsys.readouterr().err
    assert main(["eval", str(FIXTURE_POLICY), "--goal-sampling", "geodesic"]) == 2
    assert "--goal-sampling goes with --maps" in capsys.readouterr().err
    assert main(["eval", str(FIXTURE_POLICY), "--maps", "heldout", "--guide-from", "scans"]) == 2
    assert "--guide-from scans goes with --guide" in capsys.readouterr().err


def test_suite_names_resolve_to_the_committed_folders():
    for name in ("heldout", "real"):
        assert (Path(suite_path(name)) / "README.md").parent.is_dir()
        assert list(Path(suite_path(name)).glob("*.yaml"))
    assert suite_path("some/dir") == "some/dir"
