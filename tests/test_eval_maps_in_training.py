"""``eval.maps``: a training run evaluated on maps other than its training maps (flashnav/maps/validation.py,
flashnav/eval_maps.py EvalSet). The curve is checked against each map evaluated alone with
flashnav.evaluate.evaluate (the slow reference); the validation suite against generate_family."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from flashnav import train
from flashnav.cli import main as cli_main
from flashnav.evaluate import evaluate
from flashnav.maps import generate_map, load_ros_map, save_ros_map
from flashnav.maps.families import generate_family
from flashnav.maps.validation import (benchmark_dir, spread_episodes, validation_families, validation_seeds)
from flashnav.names import HELDOUT_SEEDS_FROM, MAP_FAMILIES, VALIDATION_SEEDS
from flashnav.sim.env import NavVecEnv
from flashnav.spec import RunSpec, TrainConfig, config_from_cli, resolve
from test_train import tiny_config

ROOT = Path(__file__).resolve().parents[1]
TINY = {"algo.num_envs": 16, "algo.learning_start": 32, "algo.updates_per_step": 1, "algo.batch_size": 32,
        "algo.eval_every": 1000}  # one evaluation: the last, whose policy is the run's best_policy


def tiny(**kw) -> TrainConfig:
    return tiny_config(TINY, 16 * 6, 8, **kw)


@pytest.fixture(scope="module")
def two_maps(tmp_path_factory) -> Path:
    """A folder of two small maps unlike the training map (6 x 6 m at 0.05 m, 5 x 7 m at 0.1 m)."""
    folder = tmp_path_factory.mktemp("evalmaps")
    save_ros_map(generate_map(6.0, 6.0, 0.05, seed=11, robot_radius=0.3, name="small_a"), folder / "small_a.yaml")
    save_ros_map(generate_map(5.0, 7.0, 0.1, seed=12, robot_radius=0.3, name="small_b"), folder / "small_b.yaml")
    return folder


def pooled_reference(policy, preset, grids, counts, seed) -> dict[str, float]:
    """The slow reference: each map alone in a one-map env of its ``counts[m]`` slots, reset with ``seed``
    (flashnav.evaluate.evaluate), pooled over all episodes."""
    rows = [evaluate(policy, NavVecEnv(preset, n, grid=g, seed=999), seed) for g, n in zip(grids, counts)]
    total = sum(counts)
    return {k: sum(r[k] * n for r, n in zip(rows, counts)) / total
            for k in ("success_rate", "collision_rate", "mean_return", "mean_steps")}


def test_default_evaluates_on_the_training_map_as_before():
    result = train(tiny())
    spec = result.spec
    assert spec.eval_env_maps() is None and "eval_maps" not in spec.to_dict()
    (last,) = result.curve
    env = NavVecEnv(spec.robot, 8, grid=spec.env_maps(), seed=4321)  # today's eval env
    ref = evaluate(result.policy.eval(), env, spec.config.eval.seed)
    assert {k: last[k] for k in ref} == ref


def test_a_run_with_two_map_files_evaluates_on_them(two_maps):
    # a wide goal and a short horizon: the barely trained policy meets all three outcomes
    config = tiny(eval={"episodes": 9, "maps": str(two_maps), "seed": 77},
                  overrides={**TINY, "robot.episode.goal_threshold": 0.9, "robot.episode.horizon": 25})
    result = train(config)
    spec = result.spec
    files = sorted(str(p) for p in two_maps.glob("*.yaml"))
    assert spec.to_dict()["eval_maps"] == {"files": files}
    assert [g.name for g in RunSpec.from_dict(spec.to_dict()).eval_env_maps()] == ["small_a", "small_b"]
    (last,) = result.curve
    policy = result.policy.eval()
    grids = [load_ros_map(f) for f in files]
    ref = pooled_reference(policy, spec.robot, grids, [5, 4], 77)  # 9 slots: 5 on the first map, 4 on the second
    assert max(last[k] for k in ("success_rate", "collision_rate", "timeout_rate")) < 1  # more than one outcome
    assert last["success_rate"] * 9 == pytest.approx(round(ref["success_rate"] * 9), abs=1e-4)
    for key in ref:
        assert last[key] == pytest.approx(ref[key], rel=1e-5, abs=1e-6), key
    # not what the training map gives: the evaluation did move to the other maps
    on_training_map = evaluate(policy, NavVecEnv(spec.robot, 9, grid=spec.env_maps(), seed=1), 77)
    assert on_training_map["mean_steps"] != pytest.approx(last["mean_steps"])


def test_train_command_flag_records_the_evaluation_maps(two_maps, tmp_path):
    out = tmp_path / "run"
    code = cli_main(["train", "--recipe", "cpu", "--device", "cpu", "--out", str(out), "--eval-maps",
                     str(two_maps / "*.yaml"), *[f"{k}={v}" for k, v in TINY.items()], "budget.max_env_steps=32",
                     "eval.episodes=4"])
    assert code == 0
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["eval"]["maps"] == str(two_maps / "*.yaml")
    assert config["eval_maps"] == {"files": sorted(str(p) for p in two_maps.glob("*.yaml"))}
    assert len(json.loads((out / "metrics.json").read_text())["curve"]) == 1


def test_episodes_are_spread_in_blocks_and_every_map_gets_some():
    assert spread_episodes(9, 2) == [5, 4]
    assert spread_episodes(24, 24) == [1] * 24
    assert spread_episodes(1024, 24) == [43] * 16 + [42] * 8
    for episodes, maps in ((7, 3), (256, 24), (100, 1)):
        counts = spread_episodes(episodes, maps)
        assert sum(counts) == episodes and min(counts) >= 1 and max(counts) - min(counts) <= 1
    with pytest.raises(ValueError, match=r"eval\.episodes = 1 .* 2 evaluation maps"):
        spread_episodes(1, 2)


def test_too_few_episodes_for_the_maps_is_refused_when_resolved(two_maps):
    with pytest.raises(ValueError, match=r"eval\.episodes = 1 is fewer than the 2 evaluation maps"):
        resolve(tiny(eval={"episodes": 1, "maps": str(two_maps)}))


def test_validation_is_the_documented_suite_of_the_training_families():
    config = tiny(maps={"family": ["mazes", "mazes", "rooms"], "count": 2},
                  eval={"maps": "validation", "maps_per_family": 2, "episodes": 8})
    spec = resolve(config)
    assert spec.to_dict()["eval_maps"] == {"suite": "validation", "families": ["mazes", "rooms"],
                                           "maps_per_family": 2, "seeds": [800000, 800001]}
    grids = spec.eval_env_maps()
    expected = [("mazes", 800000), ("mazes", 800001), ("rooms", 800000), ("rooms", 800001)]
    assert [g.name for g in grids] == [f"{f}_{s}" for f, s in expected]
    for grid, (family, seed) in zip(grids, expected):
        ref = generate_family(family, seed)  # the README's validation suite (a 0.3 m disc: the TurtleBot2's)
        assert grid.resolution == ref.resolution and np.array_equal(grid.occupied, ref.occupied)
    for _, seed in validation_seeds(MAP_FAMILIES, 100):
        assert VALIDATION_SEEDS[0] <= seed <= VALIDATION_SEEDS[1] < HELDOUT_SEEDS_FROM


def test_validation_families_without_generated_training_maps_are_all_families():
    assert validation_families(None) == list(MAP_FAMILIES)
    assert validation_families(["halls", "clutter", "halls"]) == ["halls", "clutter"]
    pairs = validation_seeds(validation_families(None), 3)
    assert pairs[:4] == [("rooms", 800000), ("rooms", 800001), ("rooms", 800002), ("offices", 800000)]
    assert len(pairs) == 18 and validation_seeds(MAP_FAMILIES, 2) == [p for p in pairs if p[1] < 800002]
    with pytest.raises(ValueError, match="eval.maps_per_family"):
        validation_seeds(MAP_FAMILIES, VALIDATION_SEEDS[1] - VALIDATION_SEEDS[0] + 2)


@pytest.mark.parametrize("suite", ["heldout", "real"])
def test_benchmark_suites_are_refused_by_name(suite):
    with pytest.raises(ValueError, match=rf"eval\.maps: '{suite}' is a benchmark suite"):
        config_from_cli(None, {}, [f"eval.maps={suite}"])
    with pytest.raises(ValueError, match=rf"eval\.maps: '{suite}' is a benchmark suite"):
        tiny(eval={"maps": ["turtlebot2", suite]})


def test_held_out_maps_are_refused_by_path_and_by_seed(tmp_path):
    heldout = benchmark_dir() / "heldout"
    for value in (str(heldout), str(heldout / "*.yaml"), [str(heldout / "mazes_900001.yaml")]):
        with pytest.raises(ValueError, match=r"eval\.maps: .*heldout.* benchmark suite"):
            resolve(tiny(eval={"maps": value}))
    with pytest.raises(ValueError, match=r"eval\.maps: .*'real' benchmark suite"):
        resolve(tiny(eval={"maps": str(benchmark_dir() / "real")}))
    # a copy elsewhere is refused by its held-out seed; a validation seed is fine
    shutil.copy(heldout / "rooms_900003.yaml", tmp_path / "rooms_900003.yaml")
    shutil.copy(heldout / "rooms_900003.png", tmp_path / "rooms_900003.png")
    with pytest.raises(ValueError, match=r"eval\.maps: map 'rooms_900003' .* held-out seed \(>= 900000\)"):
        resolve(tiny(eval={"maps": str(tmp_path)}))
    save_ros_map(generate_family("rooms", 800003), tmp_path / "rooms_800003.yaml")
    spec = resolve(tiny(eval={"maps": str(tmp_path / "rooms_800003.yaml")}))
    assert [g.name for g in spec.eval_env_maps()] == ["rooms_800003"]


def test_training_over_the_benchmark_suites_is_refused_one_map_is_not():
    """A generalist trained on the benchmark maps would measure nothing held-out (it once trained without a
    word); fine-tuning on one building of a suite is issue 15's measurement and stays allowed."""
    for suite in ("heldout", "real"):
        with pytest.raises(ValueError, match=rf"^maps: .*'{suite}' benchmark suite, kept for the final measurement; "
                                             "train on generated maps"):
            resolve(tiny(maps=str(benchmark_dir() / suite)))
    one = benchmark_dir() / "heldout" / "rooms_900003.yaml"
    assert resolve(tiny(map=str(one))).env_maps().name == "rooms_900003"


def test_a_bad_path_is_named(tmp_path):
    for value in (str(tmp_path / "nowhere" / "*.yaml"), str(tmp_path / "missing.yaml"), "no_such_map"):
        with pytest.raises(ValueError, match=r"eval\.maps") as info:
            resolve(tiny(eval={"maps": value}))
        assert value in str(info.value)
    with pytest.raises(ValueError, match=r"eval\.maps: an empty list"):
        tiny(eval={"maps": []})


def test_the_generalist_sweep_validates_and_its_trials_resolve():
    """sweeps/tb2_generalist_optuna.yaml searches around `--recipe generalist`: every trial gets the recipe's maps,
    task and validation suite (its setup), the budget of the sweep, and its start point (the recipe before the
    study) is the searched values over the recipe."""
    from services.sweep_schema import load_sweep

    sweep = load_sweep(ROOT / "sweeps/tb2_generalist_optuna.yaml", sets=["base.eval.maps_per_family=1"])  # cheap
    assert sweep.base.recipe == "generalist" and sweep.budget.max_env_steps == 409600
    for point in sweep.search.start_points:
        data = sweep.train_config("turtlebot2", "fastdsac", 0, "cpu", point)
        spec = resolve(TrainConfig.model_validate(data))
        assert spec.recipe == "generalist" and spec.robot.episode.goal_sampling == "geodesic"
        assert spec.robot.episode.hard_share == 0.5 and spec.config.maps.count == 16
        assert (spec.hparams.updates_per_step, spec.hparams.temperature, spec.hparams.n_step) == (8, 1.34, 1)
        assert spec.config.budget.max_env_steps == 409600 and spec.config.eval.episodes == 512
        assert spec.to_dict()["eval_maps"]["families"] == list(MAP_FAMILIES)
        assert [g.name for g in spec.eval_env_maps()] == [f"{f}_800000" for f in MAP_FAMILIES]

def test_the_go2_generalist_sweep_starts_from_its_recipe_and_the_turtlebot2_studys_best():
    """sweeps/go2_generalist_optuna.yaml: Go2's own generalist setup (its action bounds, no hardened episodes),
    the same validation suite and budget; start point 0 is the Go2 recipe before the study, start point 1 the
    TurtleBot2 recipe (its study's best), each resolving to exactly those values."""
    from services.sweep_schema import load_sweep

    sweep = load_sweep(ROOT / "sweeps/go2_generalist_optuna.yaml", sets=["base.eval.maps_per_family=1"])
    assert sweep.robots == ["go2"] and sweep.budget.max_env_steps == 409600
    tb2 = resolve(TrainConfig.model_validate({"recipe": "generalist", "robot": "turtlebot2"})).hparams
    resolved = []
    for point in sweep.search.start_points:
        spec = resolve(TrainConfig.model_validate(sweep.train_config("go2", "fastdsac", 0, "cpu", point)))
        assert spec.robot_name == "go2" and spec.robot.episode.goal_sampling == "geodesic"
        assert spec.robot.episode.hard_share == 0.0 and spec.robot.motion.w_bounds[1] < 1.0   # Go2's own
        assert spec.config.eval.episodes == 512 and spec.config.maps.count == 16
        h = spec.hparams
        resolved.append((h.updates_per_step, h.batch_size, h.temperature, h.n_step))
    assert resolved[0] == (8, 512, 1.34, 1)   # the Go2 generalist before the study
    assert resolved[1] == (tb2.updates_per_step, tb2.batch_size, tb2.temperature, tb2.n_step) == (9, 512, 0.6958791808396919, 3)


@pytest.mark.parametrize("robot, sweep_file", [("turtlebot2", "tb2_generalist_optuna.yaml"),
                                               ("go2", "go2_generalist_optuna.yaml")])
def test_the_generalist_recipe_trains_as_long_as_its_study_measured(robot, sweep_file):
    """`flashnav train --recipe generalist` runs the env-step budget every held-out figure of the recipe comes from
    (its Optuna study's; docs/benchmarks.md "How long to train a generalist"): a run of the recipe repeats the
    measured runs, and a run's own budget still wins."""
    from services.sweep_schema import load_sweep

    sweep = load_sweep(ROOT / "sweeps" / sweep_file, sets=["base.eval.maps_per_family=1"])
    spec = resolve(TrainConfig.model_validate({"recipe": "generalist", "robot": robot}))
    assert spec.config.budget.max_env_steps == sweep.budget.max_env_steps == 409600
    own = resolve(config_from_cli(None, {"recipe": "generalist", "robot": robot}, ["budget.max_env_steps=3000000"]))
    assert own.config.budget.max_env_steps == 3000000
