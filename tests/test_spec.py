"""The configuration spine: TrainConfig -> resolve() -> RunSpec, the dotted setter, presets as data."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from flashnav import names
from flashnav.cli import build_parser
from flashnav.config import RobotPreset
from flashnav.learn.hparams import MODELS, load_hparams
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.ros import save_ros_map
from flashnav.presets import load_robot
from flashnav.machine import resolve_overlap
from flashnav.spec import RunSpec, TrainConfig, config_from_cli, resolve
from flashnav.yamlio import parse_assignment, set_dotted

FIXTURES = Path(__file__).parent / "fixtures"


# ---- presets: the appendix as data, resolved values pinned ------------------------------------------


def test_layered_presets_resolve_to_the_pinned_values():
    # tests/fixtures/preset_values.json holds every (algorithm, recipe, robot) and robot preset as they
    # were when each recipe was a flat block: the shared-block layout must not move a single value.
    pinned = json.loads((FIXTURES / "preset_values.json").read_text())
    for key, values in pinned.items():
        parts = key.split("/")
        if parts[0] == "robot":
            assert load_robot(parts[1]) == RobotPreset.model_validate(values), key
        else:
            algorithm, recipe, robot = parts
            assert load_hparams(algorithm, robot, recipe) == MODELS[algorithm].model_validate(values), key


def test_a_custom_robot_yaml_gets_the_shared_simulator_table(tmp_path):
    own = {"name": "tb2-wide", "footprint": {"kind": "disc", "radius": 0.3},
           "motion": {"v_bounds": [0, 0.4], "w_bounds": [-1, 1], "max_linear_velocity": 0.4,
                      "max_angular_velocity": 1.0},
           "lidar": {"fov_deg": 180}, "map": "turtlebot2", "map_size": [10, 10]}
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(own))
    preset = load_robot(str(path))
    assert preset.lidar.fov_deg == 180 and preset.lidar.beams == 1080  # own value, shared value
    assert preset.episode.horizon == 200 and preset.reward.goal == 10.0


# ---- the one dotted setter ----------------------------------------------------------------------------


def test_set_dotted_sets_creates_and_names_unknown_keys():
    data = {"budget": {"max_train_seconds": 5}}
    set_dotted(data, "budget.max_env_steps", 100, known=TrainConfig)
    set_dotted(data, "eval.episodes", 8, known=TrainConfig, create=True)
    assert data == {"budget": {"max_train_seconds": 5, "max_env_steps": 100}, "eval": {"episodes": 8}}
    with pytest.raises(ValueError, match=r"'budget.max_train_second'.*did you mean max_train_seconds"):
        set_dotted(data, "budget.max_train_second", 1, known=TrainConfig)
    with pytest.raises(ValueError, match=r"no section 'budjet'.*did you mean budget"):
        set_dotted(data, "budjet.max_env_steps", 1, known=TrainConfig)
    with pytest.raises(ValueError, match="is not a section"):
        set_dotted({"seed": 3}, "seed.x", 1)


def test_an_unknown_section_is_named_not_created():
    """``create`` makes only the sections the model has: ``foo.bar=1`` names ``foo`` and lists the sections
    (it once created ``foo`` and then said "unknown key 'bar'; known:" with nothing after it)."""
    data: dict = {}
    with pytest.raises(ValueError, match=r"no section 'foo'; sections here: algo, budget, eval, maps, robot"):
        set_dotted(data, "foo.bar", 1, known=TrainConfig, create=True, other_sections=("algo", "robot"))
    with pytest.raises(ValueError, match=r"no section 'algoo'; did you mean algo\?"):
        set_dotted(data, "algoo.batch_size", 1, known=TrainConfig, create=True, other_sections=("algo", "robot"))
    assert data == {}
    for bad, said in (("foo.bar=1", "no section 'foo'"), ("evl.episodes=1", "did you mean eval"),
                      ("algo.batch_size=-3", "algo.batch_size: Input should be greater than 0 (got -3)"),
                      ("algo.nope=1", "algo override 'nope': unknown key"),
                      ("robot.footprint.kind=disk", "robot.footprint.kind: Input should be 'disc' or 'rectangle' "
                                                    "(got 'disk')"),
                      ("eval.episodes=0", "eval.episodes: Input should be greater than 0 (got 0)")):
        with pytest.raises(ValueError, match=re.escape(said)):
            resolve(config_from_cli(assignments=[bad]))


def test_parse_assignment_reads_yaml_values_and_names_bad_ones():
    assert parse_assignment("algo.betas=[0.9, 0.99]") == ("algo.betas", [0.9, 0.99])
    assert parse_assignment("seed=3") == ("seed", 3)
    with pytest.raises(ValueError, match=r"'algo.batch_size=\[1'.*not valid YAML"):
        parse_assignment("algo.batch_size=[1")
    with pytest.raises(ValueError, match="not key=value"):
        parse_assignment("algo.batch_size")


# ---- TrainConfig from the command line, a file, flags -------------------------------------------------


def test_config_from_cli_layers_file_then_flags_then_assignments(tmp_path):
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump({"seed": 1, "algorithm": "fastsac", "budget": {"max_train_seconds": 30},
                                    "overrides": {"algo.batch_size": 128}}))
    config = config_from_cli(str(path), {"seed": 7, "robot": None},
                             ["budget.max_train_seconds=60", "algo.gamma=0.9", "robot.lidar.noise_std=0.01"])
    assert config.seed == 7 and config.algorithm == "fastsac" and config.robot == "turtlebot2"
    assert config.budget.max_train_seconds == 60
    assert config.overrides == {"algo.batch_size": 128, "algo.gamma": 0.9, "robot.lidar.noise_std": 0.01}


@pytest.mark.parametrize("assignment, message", [
    ("budget.max_train_second=5", "did you mean max_train_seconds"),
    ("algorithm=ppo", "algorithm"),
    ("device=tpu9", "tpu9"),
    ("raycaster=fast", "raycaster"),
    ("seed=abc", "seed"),
])
def test_config_from_cli_names_the_bad_input(assignment, message):
    with pytest.raises(ValueError, match=message):
        config_from_cli(None, {}, [assignment])


# ---- resolve(): the one resolver -----------------------------------------------------------------------


def test_resolve_fills_every_default_and_applies_overrides():
    config = TrainConfig(device="cpu", recipe="auto", overrides={"algo.batch_size": 64, "robot.lidar.noise_std": 0.02},
                         budget={"max_train_seconds": 5}, eval={"episodes": 8})
    spec = resolve(config)
    assert spec.device == "cpu" and spec.recipe == "cpu"  # auto -> cpu without a GPU
    assert spec.hparams.batch_size == 64 and spec.robot.lidar.noise_std == 0.02
    assert spec.max_env_steps == spec.hparams.total_env_steps and spec.eval_every == spec.hparams.eval_every
    assert spec.overlap is False and spec.threads is None  # sequential on a CPU: the learner keeps every core
    assert spec.goal_distance_max == pytest.approx(math.hypot(10.0, 10.0))
    assert spec.grid is not None and spec.grid.diagonal_m == spec.goal_distance_max


def test_resolve_names_bad_overrides_and_missing_maps():
    with pytest.raises(ValueError, match="batch_sise"):
        resolve(TrainConfig(device="cpu", overrides={"algo.batch_sise": 3}))
    with pytest.raises(ValueError, match="noise_stdd"):
        resolve(TrainConfig(device="cpu", overrides={"robot.lidar.noise_stdd": 3}))
    with pytest.raises((ValueError, FileNotFoundError), match="nowhere.yaml"):
        resolve(TrainConfig(device="cpu", map="nowhere.yaml"))


def test_goal_scale_follows_the_map_not_the_preset(tmp_path):
    # A 6 x 4 m map: the network's goal-distance scale is its diagonal, as the env's observation bound.
    grid = OccupancyMap(np.zeros((80, 120), dtype=bool), resolution=0.05)
    path = save_ros_map(grid, tmp_path / "small.yaml")
    spec = resolve(TrainConfig(device="cpu", map=str(path)))
    assert spec.goal_distance_max == pytest.approx(math.hypot(6.0, 4.0))
    from flashnav.sim.env import NavVecEnv

    env = NavVecEnv(spec.robot, 2, grid=spec.grid)
    assert env.single_observation_space.high[spec.robot.lidar.sectors] == pytest.approx(spec.goal_distance_max)


def test_run_spec_round_trips_through_plain_data():
    spec = resolve(TrainConfig(device="auto", seed=4, overrides={"algo.batch_size": 64}))
    data = yaml.safe_load(yaml.safe_dump(spec.to_dict()))  # what config.yaml holds
    back = RunSpec.from_dict(data)
    # config.yaml records the device, recipe, cuda_graph and overlap as resolved, so reading it back re-runs
    # the same run
    resolved = {"device": spec.device, "recipe": spec.recipe, "cuda_graph": "on" if spec.cuda_graph else "off",
                "overlap": spec.overlap}
    assert spec.config.overlap == "auto" and data["overlap"] is spec.overlap
    assert back.config == spec.config.model_copy(update=resolved)
    assert (back.robot, back.hparams, back.device, back.recipe, back.goal_distance_max, back.cuda_graph,
            back.overlap) == (spec.robot, spec.hparams, spec.device, spec.recipe, spec.goal_distance_max,
                              spec.cuda_graph, spec.overlap)
    assert resolve(back.config) == back  # the loaded map is not part of the comparison
    assert back.hparams.batch_size == 64 and back.seed == 4
    with pytest.raises(ValueError, match="robot_preset"):
        RunSpec.from_dict({"algorithm": "fastdsac"})


def test_a_config_written_before_the_newer_options_reads_back_with_them_off():
    # tests/fixtures/deploy_policy/config.yaml was written by main 86fe09a: no layer_norm, obs_norm,
    # policy_averaging (hparams), cuda_graph or maps
    data = yaml.safe_load((FIXTURES / "deploy_policy" / "config.yaml").read_text())
    assert "layer_norm" not in data["hparams"] and "cuda_graph" not in data
    spec = RunSpec.from_dict(data)
    assert (spec.hparams.layer_norm, spec.hparams.obs_norm, spec.hparams.policy_averaging) == (False, False, 0.0)
    assert spec.cuda_graph is False and spec.config.maps is None
    assert data["overlap"] is True and spec.overlap is True  # it ran overlapped (the default then): kept


@pytest.mark.parametrize("mode, device, expected", [("auto", "cpu", False), ("auto", "cuda", True),
                                                    ("auto", "cuda:1", True), (True, "cpu", True),
                                                    (False, "cuda", False)])
def test_overlap_resolves_by_device_and_keeps_an_explicit_choice(mode, device, expected):
    assert resolve_overlap(mode, device) is expected


def test_overlap_decides_the_learner_threads_on_a_cpu():
    # overlapped: one core for the learner, the other for the collector thread; sequential: torch's own count
    assert resolve(TrainConfig(device="cpu", overlap=True)).threads == 1
    assert resolve(TrainConfig(device="cpu")).threads is None and resolve(TrainConfig(device="cpu")).overlap is False
    assert resolve(TrainConfig(device="cpu", threads=3)).threads == 3
    with pytest.raises(ValueError, match="overlap"):
        TrainConfig(overlap="sometimes")
    with pytest.raises(ValueError, match="overlap"):
        resolve_overlap("sometimes", "cpu")


def test_a_decaying_learning_rate_is_refused_with_a_captured_cuda_graph(monkeypatch):
    import flashnav.spec as spec_module

    monkeypatch.setattr(spec_module, "resolve_device", lambda device: "cuda")  # no GPU needed to refuse
    with pytest.raises(ValueError, match="lr_final_ratio=0.1.*cuda_graph=on"):
        resolve(TrainConfig(device="cuda", cuda_graph="on", overrides={"algo.lr_final_ratio": 0.1}))
    monkeypatch.undo()
    ok = resolve(TrainConfig(device="cpu", cuda_graph="on", overrides={"algo.lr_final_ratio": 0.1}))
    assert ok.cuda_graph and ok.hparams.lr_final_ratio == 0.1  # eager updates on a CPU: the schedule applies


# ---- names defined once -------------------------------------------------------------------------------


def test_command_line_choices_come_from_flashnav_names():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    train = sub.choices["train"]
    choices = {a.dest: tuple(a.choices) for a in train._actions if a.choices}
    assert choices["algorithm"] == names.ALGORITHMS and choices["recipe"] == names.RECIPE_CHOICES
    assert TrainConfig.model_fields["algorithm"].annotation.__args__ == names.ALGORITHMS
