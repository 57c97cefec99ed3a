"""Recipes that are more than hyperparameters: ``generalist`` is the cpu recipe with its own changes
(``base:``), and brings its training setup (presets/setups.yaml) that the run's own values override."""

from __future__ import annotations

import math

import pytest
import yaml

from flashnav.learn.hparams import load_hparams
from flashnav.maps.stream import GeneratedMaps
from flashnav.presets import load_preset_file, load_robot, preset_path
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.spec import RunSpec, TrainConfig, config_from_cli, resolve


def test_generalist_hyperparameters_are_the_cpu_recipe_with_its_own_changes():
    cpu = load_hparams("fastdsac", "turtlebot2", "cpu").model_dump()
    generalist = load_hparams("fastdsac", "turtlebot2", "generalist").model_dump()
    own = load_preset_file("fastdsac")["generalist"]
    mine = {**own["shared"], **own["turtlebot2"]}  # the robot's row wins over the shared one
    assert all(generalist[k] == v for k, v in mine.items())
    assert {k for k in cpu if cpu[k] != generalist[k]} == {k for k, v in mine.items() if cpu[k] != v}


def test_recipes_without_a_learner_section_or_setup_name_what_is_missing(tmp_path):
    with pytest.raises(ValueError, match=r"fastsac.yaml has no 'generalist' recipe \(it has: paper, cpu"):
        load_hparams("fastsac", "turtlebot2", "generalist")
    robot = tmp_path / "my_robot.yaml"  # a robot of the user's own: no setup of the generalist names it
    robot.write_text(preset_path("turtlebot2").read_text().replace("name: turtlebot2", "name: my_robot"))
    with pytest.raises(ValueError, match=r"recipe 'generalist' has a training setup for turtlebot2, go2 only "
                                         r"\(.*setups.yaml\), not for robot '.*my_robot.yaml'"):
        TrainConfig(recipe="generalist", robot=str(robot))


def test_the_go2_generalist_has_the_turtlebot2_setup_and_its_hyperparameters():
    setups = load_preset_file("setups")["generalist"]
    # the same maps, evaluation, budget and task, less the TurtleBot2's platform turn rate (Go2 keeps its own bounds)
    # and its share of long detours
    tb2_overrides = dict(setups["turtlebot2"]["overrides"])
    assert tb2_overrides.pop("robot.motion.w_bounds") == [-math.pi / 2, math.pi / 2]
    assert tb2_overrides.pop("robot.episode.hard_share") == 0.5  # more long detours: measured on the TurtleBot2 only
    assert setups["go2"] == {**setups["turtlebot2"], "overrides": tb2_overrides}
    tb2, go2 = (load_hparams("fastdsac", robot, "generalist").model_dump() for robot in ("turtlebot2", "go2"))
    # Go2's cpu recipe differs from TurtleBot2's; each robot's generalist row is its own Optuna study's pick
    # (sweeps/tb2_generalist_optuna.yaml, go2_generalist_optuna.yaml), the goal's sine and cosine is the
    # TurtleBot2's only (measured on its generalist), and the paper's per-robot collector sync interval
    # (pipeline.yaml) stays Go2's
    assert {k for k in tb2 if tb2[k] != go2[k]} == {"env_steps_per_sync", "goal_sincos", "updates_per_step",
                                                   "batch_size", "temperature", "n_step"}
    assert tb2["goal_sincos"] and not go2["goal_sincos"]
    assert (tb2["updates_per_step"], tb2["batch_size"], tb2["temperature"], tb2["n_step"]) == (9, 512, 0.6958791808396919, 3)
    assert (go2["updates_per_step"], go2["batch_size"], go2["temperature"], go2["n_step"]) == (8, 256, 1.2066141432362034, 5)
    spec = resolve(config_from_cli(None, {"recipe": "generalist", "robot": "go2", "device": "cpu"},
                                   ["maps.count=2", "eval.maps_per_family=1", "eval.episodes=16"]))
    assert spec.robot.name == "go2" and spec.robot.episode.goal_sampling == "geodesic"
    assert isinstance(spec.config.maps, GeneratedMaps) and spec.hparams.layer_norm and spec.hparams.gamma == 0.99


def test_the_setup_fills_what_the_run_leaves_open_and_the_run_wins():
    setup = load_preset_file("setups")["generalist"]["turtlebot2"]
    config = config_from_cli(None, {"recipe": "generalist", "device": "cpu"},
                             ["maps.count=4", "eval.episodes=64", "robot.lidar.noise_std=0.02"])
    assert isinstance(config.maps, GeneratedMaps) and config.maps.family == setup["maps"]["family"]
    assert config.maps.count == 4 and config.maps.refresh_every == setup["maps"]["refresh_every"]
    assert config.eval.maps == "validation" and config.eval.episodes == 64
    assert config.eval.every == setup["eval"]["every"]
    assert config.overrides == {**setup["overrides"], "robot.lidar.noise_std": 0.02}
    assert config.budget.max_env_steps == setup["budget"]["max_env_steps"]
    # the Python API gets the same setup as the command line
    assert TrainConfig(recipe="generalist").maps == TrainConfig.model_validate(
        {"recipe": "generalist", "maps": setup["maps"]}).maps
    # a map of its own (fine-tuning on one building) replaces the setup's maps and evaluation maps
    one = config_from_cli(None, {"recipe": "generalist", "map": "building.yaml"}, [])
    assert one.maps is None and one.map == "building.yaml" and one.eval == TrainConfig().eval
    assert one.overrides == setup["overrides"]
    # other recipes are untouched
    assert TrainConfig(recipe="cpu") == TrainConfig(recipe="cpu", maps=None, overrides={})


def test_generalist_map_is_the_turtlebot2_generalist_with_the_wall_map_its_plan_and_carrot():
    # hyperparameters: the generalist's, DrQ's shift of the wall map and the longer discount, nothing else
    generalist = load_hparams("fastdsac", "turtlebot2", "generalist").model_dump()
    mapped = load_hparams("fastdsac", "turtlebot2", "generalist-map").model_dump()
    assert {k for k in mapped if mapped[k] != generalist[k]} == {"wall_shift", "gamma"}
    assert mapped["wall_shift"] == 1 and mapped["gamma"] == 0.995 and generalist["gamma"] == 0.99
    # setup: the generalist's maps, evaluation and task, the wall map with its priced plan and its carrot at 0.5 m,
    # and the measured budget
    setups = load_preset_file("setups")
    tb2, mine = setups["generalist"]["turtlebot2"], setups["generalist-map"]["turtlebot2"]
    assert mine["maps"] == tb2["maps"] and mine["eval"] == tb2["eval"]
    assert mine["overrides"] == {**tb2["overrides"], "robot.observation.wall_map": 24,
                                 "robot.observation.wall_map_plan": True,
                                 "robot.observation.wall_map_plan_penalty": 2,
                                 "robot.observation.wall_map_carrot": 0.5}
    assert mine["budget"]["max_env_steps"] == 163840  # what docs/benchmarks.md measures
    spec = resolve(config_from_cli(None, {"recipe": "generalist-map", "device": "cpu"},
                                   ["maps.count=2", "eval.maps_per_family=1", "eval.episodes=16"]))
    o = spec.robot.observation
    assert (o.wall_map, o.wall_map_cell, o.wall_map_plan, o.wall_map_plan_penalty, o.wall_map_carrot) == \
        (24, 0.5, True, 2.0, 0.5)
    assert spec.hparams.wall_shift == 1 and spec.robot.episode.goal_sampling == "geodesic"
    # measured on the TurtleBot2 only: Go2 is refused by name, by the setup and by the learner's recipe
    with pytest.raises(ValueError, match=r"recipe 'generalist-map' has a training setup for turtlebot2 only "
                                         r"\(.*setups.yaml\), not for robot 'go2'"):
        TrainConfig(recipe="generalist-map", robot="go2")
    with pytest.raises(ValueError, match=r"fastdsac.yaml: no 'generalist-map' recipe for robot 'go2'"):
        load_hparams("fastdsac", "go2", "generalist-map")


def test_a_generalist_run_spec_round_trips_through_config_yaml():
    config = config_from_cli(None, {"recipe": "generalist", "device": "cpu"},
                             ["maps.count=2", "eval.maps_per_family=1", "eval.episodes=16"])
    spec = resolve(config)
    assert spec.recipe == "generalist" and spec.hparams.layer_norm and spec.hparams.obs_norm
    assert spec.robot.reward.progress_metric == "euclidean" and spec.robot.episode.goal_sampling == "geodesic"
    back = RunSpec.from_dict(yaml.safe_load(yaml.safe_dump(spec.to_dict())))
    assert back.config == spec.config.model_copy(update={"cuda_graph": "off", "overlap": False})  # as resolved on a CPU
    assert back.hparams == spec.hparams and back.robot == spec.robot


def test_map_assignments_replace_the_setups_maps_like_the_flags():
    by_flag = config_from_cli(None, {"recipe": "generalist", "map": "building.yaml"}, [])
    assert config_from_cli(None, {"recipe": "generalist"}, ["map=building.yaml"]) == by_flag
    own = config_from_cli(None, {"recipe": "generalist"}, ["maps=my_maps/", "eval.episodes=64"])
    assert own.maps == "my_maps/" and own.eval.maps is None and own.eval.every is None and own.eval.episodes == 64


def test_a_config_read_back_keeps_the_setup_it_was_written_with(monkeypatch):
    import flashnav.presets as presets

    spec = resolve(config_from_cli(None, {"recipe": "generalist", "device": "cpu"},
                                   ["maps.count=2", "eval.maps_per_family=1", "eval.episodes=16"]))
    data = yaml.safe_load(yaml.safe_dump(spec.to_dict()))
    real = presets.load_preset_file

    def changed(name):  # a later setups.yaml with one more override must not reach an old run's config
        out = real(name)
        if name == "setups":
            out["generalist"]["turtlebot2"]["overrides"]["robot.lidar.noise_std"] = 0.05
        return out

    monkeypatch.setattr(presets, "load_preset_file", changed)
    assert "robot.lidar.noise_std" in TrainConfig(recipe="generalist").overrides  # new runs get it
    assert RunSpec.from_dict(data).config.overrides == spec.config.overrides


def test_recipe_bases_that_go_round_in_a_circle_are_named(monkeypatch):
    import flashnav.learn.hparams as hp

    real = hp.load_preset_file

    def looped(name):
        out = real(name)
        if name == "fastdsac":
            out["cpu"]["base"] = "generalist"
        return out

    monkeypatch.setattr(hp, "load_preset_file", looped)
    with pytest.raises(ValueError, match=r"recipe 'cpu' is based on 'generalist', which is based on it"):
        load_hparams("fastdsac", "turtlebot2", "generalist")


@pytest.mark.parametrize("robot", ["turtlebot2", "go2"])
def test_paper_mirror_is_the_paper_recipe_with_its_departures(robot):
    """Four departures for both robots (docs/benchmarks.md "The goal angle as sine and cosine"); Go2 adds pink
    forward-speed noise to them, two changes to its training task, more long detours and geodesic progress
    (setups.yaml; "Go2: ten-step returns, 80 updates a step, and geodesic progress ..."), and the plan's carrot in its
    observation, in training and in every evaluation ("Go2: the plan's carrot"). TurtleBot2 trains on the paper's
    task and observation."""
    paper = load_hparams("fastdsac", robot, "paper").model_dump()
    mirror = load_hparams("fastdsac", robot, "paper-mirror").model_dump()
    changed = {k: mirror[k] for k in paper if paper[k] != mirror[k]}
    assert changed == {"n_step": 5, "gamma": 0.99, "mirror": 0.5, "goal_sincos": True,
                       **({"noise_color": (1.0, 0.0), "wall_map_convs": ((8, 1),)} if robot == "go2" else {})}
    # the paper's own numbers, budget included, stay: the departures are only these
    assert mirror["total_env_steps"] == paper["total_env_steps"]
    # the task: the run's robot preset against the plain one, and what every evaluation plays
    spec = resolve(config_from_cli(None, {"robot": robot, "recipe": "paper-mirror", "device": "cpu"}))
    plain = load_robot(robot)
    seen = {"robot.observation.wall_map": 2, "robot.observation.wall_map_plan": True,
            "robot.observation.wall_map_plan_penalty": 2, "robot.observation.wall_map_carrot": 0.5}
    task = ({"robot.episode.hard_share": 0.5, "robot.reward.progress_metric": "geodesic", **seen}
            if robot == "go2" else {})
    assert spec.robot == load_robot(robot, **{k.removeprefix("robot."): v for k, v in task.items()})
    assert (spec.robot == plain) == (robot == "turtlebot2")
    # every evaluation plays the task's episodes with the paper's reward, and the policy keeps what it sees
    sees = load_robot(robot, **{k.removeprefix("robot."): v for k, v in seen.items()}) if robot == "go2" else plain
    assert evaluation_preset(spec.robot) == sees
    # the run's own values win over the setup's
    own = resolve(config_from_cli(None, {"robot": robot, "recipe": "paper-mirror", "device": "cpu"},
                                  ["robot.episode.hard_share=0.25"]))
    assert own.robot.episode.hard_share == 0.25


@pytest.mark.parametrize("algo", ["fastsac", "fasttd3"])
def test_fastsac_and_fasttd3_paper_mirror_have_their_departures_on_turtlebot2_only(algo):
    """Measured on FastSAC (docs/benchmarks.md "FastSAC with the four departures: ten seeds") and FastTD3 ("FastTD3
    with pink forward-speed noise: ten seeds on the CPU": the four and pink noise on the forward speed) for
    TurtleBot2; Go2 has no measurement, so no recipe: asking for it is an error that names the file and the robot."""
    paper = load_hparams(algo, "turtlebot2", "paper").model_dump()
    mirror = load_hparams(algo, "turtlebot2", "paper-mirror").model_dump()
    fifth = {"noise_color": (1.0, 0.0)} if algo == "fasttd3" else {}
    assert {k: mirror[k] for k in paper if paper[k] != mirror[k]} == {"n_step": 5, "gamma": 0.99, "mirror": 0.5,
                                                                        "goal_sincos": True, **fifth}
    with pytest.raises(ValueError, match=rf"{algo}.yaml: no 'paper-mirror' recipe for robot 'go2'"):
        load_hparams(algo, "go2", "paper-mirror")


def test_crowd_is_paper_mirror_without_the_sine_and_cosine_and_brings_people_and_the_platforms_motion():
    """The recipe among moving people (issue 13; docs/benchmarks.md "Among people, a robot that turns and reverses"):
    paper-mirror's first three departures, and a setup with 8 agents, 4 tracks, the TurtleBot2's platform turn rate,
    a reverse and a LiDAR that sees all round; the run's own values win, and there is no Go2 crowd (nothing measured)."""
    paper = load_hparams("fastdsac", "turtlebot2", "paper").model_dump()
    crowd = load_hparams("fastdsac", "turtlebot2", "crowd").model_dump()
    assert {k: crowd[k] for k in paper if paper[k] != crowd[k]} == {"n_step": 5, "gamma": 0.99, "mirror": 0.5}
    spec = resolve(config_from_cli(None, {"recipe": "crowd", "device": "cpu"}))
    plain = load_robot("turtlebot2")
    assert (spec.robot.agents.count, spec.robot.observation.agent_tracks) == (8, 4)
    assert spec.robot.motion.w_bounds == (-plain.motion.max_angular_velocity, plain.motion.max_angular_velocity)
    assert spec.robot.motion.v_bounds == (-0.25, plain.motion.max_linear_velocity)
    assert (plain.lidar.fov_deg, spec.robot.lidar.fov_deg) == (270, 360)  # it reverses: it sees behind
    assert spec.robot.lidar.beams == plain.lidar.beams and spec.robot.obs_dim == plain.obs_dim + 4 * 6
    assert spec.robot.agents.reactive == 0  # the agents never yield, as in the scenarios
    assert (spec.config.eval.episodes, spec.config.budget.max_env_steps) == (256, 600_000)
    own = resolve(config_from_cli(None, {"recipe": "crowd", "device": "cpu"}, ["robot.agents.count=4"]))
    assert own.robot.agents.count == 4 and own.robot.motion.v_bounds == spec.robot.motion.v_bounds
    with pytest.raises(ValueError, match="crowd"):
        resolve(config_from_cli(None, {"recipe": "crowd", "robot": "go2", "device": "cpu"}))
