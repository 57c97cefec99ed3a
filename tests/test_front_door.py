"""Every `flashnav` command answers a bad input with exit status 2 and one stderr line that names the
input, prints no traceback (unless `--debug`), leaves no half-made output and never hangs.

Each case here used to end in a traceback, a silent wrong result or a minutes-long wait.
"""

from __future__ import annotations

import shutil
import socket
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from flashnav.checkpoint import save_checkpoint
from flashnav.cli import main
from flashnav.export import export_policy
from flashnav.learn.networks import Actor, ObsLayout
from flashnav.maps.bundled import __file__ as _bundled_file
from flashnav.presets import load_robot

MAPS = Path(_bundled_file).parent / "data"


def fails(capsys, *argv: str) -> str:
    """Run `flashnav ARGV` in-process; assert exit 2, one stderr line, no traceback; return the line."""
    code = main(list(argv))
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """policy.pt, policy.onnx and checkpoint.pt of a random TurtleBot2 actor."""
    preset = load_robot("turtlebot2")
    actor = Actor(ObsLayout.from_robot(preset, 10.0 * 2 ** 0.5), 2, (32, 32), 3, torch.Generator().manual_seed(0))
    out = tmp_path_factory.mktemp("run")
    export_policy(actor, preset, out)
    save_checkpoint(out / "checkpoint.pt", {"actor": actor.state_dict()}, {"algorithm": "fastdsac"})
    return out


# ---- train: checked before the folder is made or a step is trained ---------------------------------
def test_train_out_is_an_existing_file(tmp_path, capsys):
    (tmp_path / "taken").write_text("x")
    line = fails(capsys, "train", "--out", str(tmp_path / "taken"))
    assert line.startswith("flashnav train: error: --out ") and "is a file, not a folder" in line


def test_train_refuses_a_folder_that_holds_a_run_unless_told(run_dir, tmp_path, capsys):
    """A finished run is never replaced by accident (it once was: a one-step run overwrote its policy)."""
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    line = fails(capsys, "train", "--out", str(run_dir), "budget.max_env_steps=1")
    assert f"--out {run_dir}: holds a run already (checkpoint.pt, policy.json, policy.onnx, policy.pt)" in line
    assert "--overwrite" in line
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before
    (tmp_path / "notes").mkdir()  # a folder of other files is fine
    (tmp_path / "notes" / "README.txt").write_text("x")
    assert "holds a run" not in fails(capsys, "train", "--out", str(tmp_path / "notes"), "--device", "tpu9")


@pytest.mark.parametrize("argv, named", [
    (["--device", "tpu9"], "device 'tpu9' is not one of auto, cpu, cuda, cuda:N"),
    (["algo.batch_size=[1"], "override 'algo.batch_size=[1': the value is not valid YAML"),
    (["algo.batch_sise=512"], "batch_sise"),
    (["--map", "nowhere.yaml"], "nowhere.yaml"),
])
def test_train_validation_errors_leave_no_folder(tmp_path, capsys, argv, named):
    out = tmp_path / "run"
    assert named in fails(capsys, "train", "--out", str(out), *argv)
    assert not out.exists()


def test_overrides_before_and_after_options_all_apply(tmp_path, capsys):
    # argparse alone refuses key=value items on both sides of an option; both groups must reach the config
    out = tmp_path / "run"
    line = fails(capsys, "train", "eval.episodes=64", "--out", str(out), "algo.batch_sise=512")
    assert "batch_sise" in line and not out.exists()
    with pytest.raises(SystemExit):  # anything that is not key=value stays an argparse error
        main(["train", "eval.episodes=64", "--out", str(out), "stray"])
    assert "unrecognized arguments: stray" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a command without overrides takes none
        main(["demo", "--envs", "4", "a=b"])
    assert "unrecognized arguments: a=b" in capsys.readouterr().err


def test_train_on_cuda_without_cuda(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    line = fails(capsys, "train", "--device", "cuda:1", "--out", str(tmp_path / "run"))
    assert "device 'cuda:1' requested but CUDA is not available" in line and not (tmp_path / "run").exists()


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(ValueError, match="tpu9"):
        main(["--debug", "train", "--device", "tpu9", "--out", str(tmp_path / "run")])


# ---- eval / render -----------------------------------------------------------------------------------
@pytest.mark.parametrize("name, says", [("policy.pt", "not a readable TorchScript policy"),
                                        ("policy.onnx", "not a readable ONNX policy")])
def test_eval_of_random_bytes(tmp_path, capsys, name, says):
    path = tmp_path / name
    path.write_bytes(np.random.default_rng(0).bytes(2000))
    line = fails(capsys, "eval", str(path))
    assert f"flashnav eval: error: {path}: {says}" in line


def test_eval_of_a_training_checkpoint_says_so(run_dir, capsys):
    line = fails(capsys, "eval", str(run_dir / "checkpoint.pt"))
    assert "checkpoint.pt: a FlashNav training checkpoint, not an exported policy" in line


def test_eval_json_is_checked_before_evaluating(run_dir, tmp_path, capsys, monkeypatch):
    import flashnav.policy_cli as policy_cli

    def never(*a, **k):
        raise AssertionError("the evaluation ran before --json was checked")

    monkeypatch.setattr(policy_cli, "load_policy_and_env", never)
    line = fails(capsys, "eval", str(run_dir / "policy.pt"), "--json", str(tmp_path))
    assert f"--json {tmp_path}: is a folder" in line


def test_eval_on_cuda_without_cuda(run_dir, capsys, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    line = fails(capsys, "eval", str(run_dir / "policy.pt"), "--episodes", "2", "--device", "cuda")
    assert "--device: device 'cuda' requested but CUDA is not available" in line


def test_eval_device_name_is_checked(run_dir, capsys):
    assert "device 'tpu9' is not one of" in fails(capsys, "eval", str(run_dir / "policy.pt"), "--device", "tpu9")


def test_render_out_under_a_file(run_dir, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    out = tmp_path / "file" / "x.png"  # as /dev/null/x.png: the parent is not a folder
    line = fails(capsys, "render", str(run_dir / "policy.pt"), "--episodes", "2", "--out", str(out))
    assert f"--out {out}: cannot be created because {tmp_path / 'file'} is a file" in line


# ---- map YAML values that used to allocate petabytes or overflow -------------------------------------
@pytest.mark.parametrize("field, value, says", [
    ("resolution", "1.0e-9", "'resolution' 1e-09 m per pixel is finer than"),
    ("origin", "[1.0e+308, 1.0e+308, 0]", "'origin' [1e+308, 1e+308, 0.0] is too far out"),
])
def test_eval_on_an_absurd_map(run_dir, tmp_path, capsys, field, value, says):
    shutil.copy(MAPS / "turtlebot2.pgm", tmp_path)
    text = (MAPS / "turtlebot2.yaml").read_text()
    lines = [f"{field}: {value}" if line.startswith(f"{field}:") else line for line in text.splitlines()]
    (tmp_path / "bad.yaml").write_text("\n".join(lines) + "\n")
    line = fails(capsys, "eval", str(run_dir / "policy.pt"), "--episodes", "2", "--map", str(tmp_path / "bad.yaml"))
    assert f"{tmp_path / 'bad.yaml'}: {says}" in line


# ---- report: bad or dead tracking URIs ---------------------------------------------------------------
@pytest.fixture(autouse=True)
def _restore_mlflow_env(monkeypatch):
    """`flashnav report` sets MLflow's HTTP timeout variables for its process; undo that here."""
    from services.report import HTTP_ENV

    for key, value in HTTP_ENV.items():
        monkeypatch.setenv(key, value)


def test_report_unsupported_tracking_uri(tmp_path, capsys):
    line = fails(capsys, "report", "--tracking-uri", "bogus://nowhere", "--out", str(tmp_path / "r"))
    assert "tracking URI bogus://nowhere: unsupported scheme 'bogus'" in line


def test_report_dead_server_fails_fast(tmp_path, capsys):
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    start = time.monotonic()
    line = fails(capsys, "report", "--tracking-uri", f"http://127.0.0.1:{port}", "--out", str(tmp_path / "r"))
    assert f"no MLflow server answers at http://127.0.0.1:{port}" in line
    assert time.monotonic() - start < 20  # MLflow's own retries took minutes
    assert not (tmp_path / "r").exists()


def test_report_out_is_a_file(tmp_path, capsys):
    (tmp_path / "taken").write_text("x")
    line = fails(capsys, "report", "--tracking-uri", f"sqlite:///{tmp_path}/none.db", "--out", str(tmp_path / "taken"))
    assert "--out" in line and "is a file, not a folder" in line


# ---- sweep files: a repeated key used to win silently ------------------------------------------------
def test_sweep_with_a_duplicate_key(tmp_path, capsys):
    path = tmp_path / "dup.yaml"
    path.write_text("name: t\nrobots: [turtlebot2]\nalgorithms: [fastdsac]\nseeds: 10\nseeds: 1\n")
    assert main(["sweep", "run", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "duplicate key 'seeds' at line 5 (first at line 4)" in err and "Traceback" not in err


@pytest.mark.parametrize("argv", [["train"], ["eval", "policy.onnx"], ["render", "policy.onnx", "--out", "x.png"],
                                  ["demo"], ["bench", "eval", "policy.onnx"]])
def test_a_negative_seed_is_refused_up_front(argv, capsys):
    """numpy's generators refuse a negative seed: it failed deep in a training run, after the header."""
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, "--seed", "-1"])
    assert exit_info.value.code == 2
    assert "argument --seed: must be >= 0, got -1" in capsys.readouterr().err


def test_render_writes_what_it_says_and_never_a_gif_over_its_picture(run_dir, tmp_path, capsys):
    line = fails(capsys, "render", str(run_dir / "policy.pt"), "--out", str(tmp_path / "x.gif"), "--gif")
    assert "--gif writes the animation beside it as x.gif: give --out" in line and "x.png" in line
    assert main(["render", str(run_dir / "policy.pt"), "--out", str(tmp_path / "noext"), "--episodes", "2"]) == 0
    assert f"trajectories: {tmp_path / 'noext.png'}" in capsys.readouterr().out
    assert (tmp_path / "noext.png").is_file()


def test_init_from_an_exported_policy_says_what_to_give(run_dir, capsys):
    for name in ("policy.pt", "policy.onnx"):
        line = fails(capsys, "train", "--init-from", str(run_dir / name))
        assert "an exported policy, which holds the actor only" in line and "give its run folder or its checkpoint.pt" in line


def test_eval_takes_a_run_folder(run_dir, tmp_path, capsys):
    assert main(["eval", str(run_dir), "--episodes", "4", "--json", str(tmp_path / "e.json")]) == 0
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "a folder without policy.pt or policy.onnx" in fails(capsys, "eval", str(empty))


def test_a_runs_config_yaml_is_a_config_and_drift_is_named(tmp_path):
    """`--config RUN/config.yaml` re-runs a run (it once failed: "hparams: unknown key"); where the recipe
    changed since, the train command says which values differ."""
    from flashnav.learn.cli import recorded_drift
    from flashnav.spec import config_from_cli, resolve
    from flashnav.yamlio import dump_yaml

    spec = resolve(config_from_cli(None, {"recipe": "cpu", "device": "cpu", "seed": 3},
                                   ["algo.batch_size=256", "budget.max_train_seconds=5"]))
    path = tmp_path / "config.yaml"
    dump_yaml(spec.to_dict(), path)
    again = resolve(config_from_cli(str(path)))
    assert again.to_dict() == spec.to_dict() and recorded_drift(str(path), again) == []
    recorded = spec.to_dict()
    recorded["hparams"]["gamma"] = 0.5
    dump_yaml(recorded, path)
    (line,) = recorded_drift(str(path), resolve(config_from_cli(str(path))))
    assert "recorded other hparams than its request gives today (1): gamma 0.5 -> " in line
    assert recorded_drift(None, spec) == []
    recorded.update(device="cuda", cuda_graph="on", overlap=True, threads=7)  # a GPU run's config on this machine
    dump_yaml(recorded, path)
    request = config_from_cli(str(path))
    assert (request.device, request.cuda_graph, request.overlap, request.threads) == ("auto", "auto", "auto", None)
    assert request.recipe == "cpu" and request.seed == 3  # what it learnt with stays


def test_a_key_without_its_section_is_pointed_to_it(tmp_path, capsys):
    assert "override 'batch_size': not a training-config key; did you mean algo.batch_size?" in fails(
        capsys, "train", "batch_size=512", "--out", str(tmp_path / "r"))
    assert "did you mean robot.lidar.noise_std?" in fails(capsys, "train", "lidar.noise_std=0.1", "--out", str(tmp_path / "r"))
    config = tmp_path / "c.yaml"
    config.write_text("algo:\n  gamma: 0.99\n")
    assert "algo: not a section here; hyperparameters go under overrides as dotted keys: overrides: {algo.gamma: ...}" \
        in fails(capsys, "train", "--config", str(config), "--out", str(tmp_path / "r"))
    config.write_text("robot:\n  lidar:\n    noise_std: 0.1\n")  # once: "robot: Input should be a valid string"
    line = fails(capsys, "train", "--config", str(config), "--out", str(tmp_path / "r"))
    assert "robot: names a preset (turtlebot2, go2 or a preset YAML file), not a section" in line
    assert "overrides: {robot.lidar.noise_std: ...}" in line


def test_a_union_value_error_says_only_its_reason(tmp_path, capsys):
    line = fails(capsys, "train", "--maps", "family:room", "maps.count=2", "--out", str(tmp_path / "r"))
    assert line == ("flashnav train: error: training config: maps.family: unknown map family 'room' (did you mean "
                    "'rooms'?); use one of rooms, offices, halls, warehouses, mazes, clutter (got 'room')")


def test_a_union_member_failing_inside_its_field_says_only_that(tmp_path, capsys):
    """Generated maps with a bad count, and a generated-maps key without --maps family:F: the member the value was
    meant for answers alone (it once said "maps.str: ..., maps.list[str]: ..." around it, or "unknown key 'count';
    known:" with nothing after it)."""
    line = fails(capsys, "train", "--maps", "family:rooms", "maps.count=0", "--out", str(tmp_path / "r"))
    assert line == "flashnav train: error: training config: maps.count: Input should be greater than 0 (got 0)"
    line = fails(capsys, "train", "maps.count=3", "--out", str(tmp_path / "r"))
    assert line == "flashnav train: error: training config: maps.family: Field required"
    assert not (tmp_path / "r").exists()


# ---- pictures and files written after the work: checked before it -------------------------------------
@pytest.mark.parametrize("argv", [("demo", "--envs", "2"), ("bench", "plot", "DIR")])
def test_a_picture_flag_needs_a_picture_suffix_and_a_folder(argv, run_dir, tmp_path, capsys):
    """`demo` and `bench plot` once ran their episodes or read their runs, then failed in matplotlib (".txt") or
    in mkdir (a folder under a file) without naming --out."""
    argv = tuple(str(run_dir) if a == "DIR" else a for a in argv)
    (tmp_path / "file").write_text("x")
    line = fails(capsys, *argv, "--out", str(tmp_path / "d.txt"))
    assert f"--out {tmp_path / 'd.txt'}: a picture is written as .png, .pdf, .svg" in line and "got '.txt'" in line
    line = fails(capsys, *argv, "--out", str(tmp_path / "file" / "d.png"))
    assert f"cannot be created because {tmp_path / 'file'} is a file" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_an_output_folder_nothing_can_be_written_in(tmp_path, capsys, monkeypatch):
    """Permission bits do not tell (root passes os.access; /proc refuses anyway): the check tries a file."""
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    line = fails(capsys, "train", "--out", str(tmp_path / "run"), "budget.max_env_steps=1")
    assert line == (f"flashnav train: error: --out {tmp_path / 'run'}: cannot be created: cannot write in {tmp_path} "
                    "(Permission denied)")


@pytest.mark.parametrize("args, says", [
    (("--max-steps", "0"), "--seconds must be > 0 and --max-steps >= 1, got 2.0 and 0"),
    (("--seconds", "-1"), "--seconds must be > 0 and --max-steps >= 1, got -1.0 and 2000"),
    (("--quick", "--robots", "bogus"), "--quick runs turtlebot2, 64 envs and 0.5-s rows: drop --robots"),
    (("--robots", "turtlebot2,bogus"), "--robots bogus: unknown robot 'bogus'"),
    (("--num-envs", "abc"), "--num-envs abc: comma-separated whole numbers >= 1"),
    (("--num-envs", "0"), "every size >= 1"),
])
def test_bench_sim_checks_its_flags_before_the_first_row(args, says, capsys, monkeypatch):
    from flashnav.bench import sim

    monkeypatch.setattr(sim, "time_steps", _must_not_run)
    assert says in fails(capsys, "bench", "sim", "--raycasters", "exact", "--no-irsim", *args)


def _must_not_run(*args, **kwargs):
    raise AssertionError("the work started before the bad input was named")


def test_bench_sim_json_is_checked_before_the_first_row(tmp_path, capsys, monkeypatch):
    from flashnav.bench import sim

    monkeypatch.setattr(sim, "time_steps", _must_not_run)
    assert f"--json {tmp_path}: is a folder" in fails(capsys, "bench", "sim", "--quick", "--no-irsim", "--json",
                                                       str(tmp_path))


@pytest.mark.parametrize("fmt, says", [("bogus", "unknown format(s) 'bogus'"), ("md,,pdf", "format(s) 'pdf';"),
                                       (",", "unknown format(s) none")])
def test_report_formats_are_checked_before_a_folder_is_made(fmt, says, tmp_path, capsys):
    """`report --format bogus` once exited 0 with an empty folder; `md,,pdf` dropped pdf without a word."""
    doc = tmp_path / "g.json"
    doc.write_text("{}")
    line = fails(capsys, "report", "--generalisation", str(doc), "--format", fmt, "--out", str(tmp_path / "rep"))
    assert line.startswith(f"flashnav report: error: --format {fmt}: ") and says in line
    assert not (tmp_path / "rep").exists()


def test_a_preset_whose_map_is_a_ros_map_file(tmp_path, capsys):
    """A robot preset may name its map as a ROS map YAML path (config.RobotPreset.map): demo once read it as a
    bundled map's name ("unknown bundled map '/.../x.yaml'")."""
    import yaml

    shutil.copy(MAPS / "turtlebot2.yaml", tmp_path / "m.yaml")
    shutil.copy(MAPS / yaml.safe_load((MAPS / "turtlebot2.yaml").read_text())["image"], tmp_path)
    import flashnav.presets

    preset = yaml.safe_load((Path(flashnav.presets.__file__).parent / "turtlebot2.yaml").read_text())
    for name, where in (("abs", str(tmp_path / "m.yaml")), ("rel", "m.yaml")):  # relative: to the preset's folder
        preset.update(name="otherbot", map=where)
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(preset))
        out = tmp_path / f"d-{name}"
        assert main(["demo", "--robot", str(tmp_path / f"{name}.yaml"), "--envs", "2", "--out", str(out)]) == 0
        assert out.with_suffix(".png").is_file()


def test_bench_train_checks_json_and_plot_before_training(tmp_path, capsys, monkeypatch):
    from flashnav.learn import loop

    monkeypatch.setattr(loop, "train", _must_not_run)
    assert f"--json {tmp_path}: is a folder" in fails(capsys, "bench", "train", "--seeds", "1", "--json", str(tmp_path))
    assert "--plot c.txt: a picture is written as" in fails(capsys, "bench", "train", "--seeds", "1", "--plot", "c.txt")


def test_eval_label_goes_with_maps(run_dir, capsys):
    """--label names the policy in `eval --maps`'s JSON; without --maps it was accepted and ignored."""
    assert "--label foo goes with --maps" in fails(capsys, "eval", str(run_dir / "policy.onnx"), "--label", "foo")


def test_a_checkpoint_that_is_not_one_never_advises_weights_only_false(tmp_path, capsys):
    import pickle

    bad = tmp_path / "bad.pt"
    torch.save({"x": shutil.copy}, bad)  # a global: refused under weights_only, with torch's advice to turn it off
    (tmp_path / "code.pt").write_bytes(pickle.dumps(shutil.copy))
    for path in (bad, tmp_path / "code.pt"):  # torch's own reason follows; its wording is torch's to change
        line = fails(capsys, "train", "--init-from", str(path), "--out", str(tmp_path / "r"))
        assert f"{path}: not a readable FlashNav checkpoint (UnpicklingError: " in line
        assert "False" not in line and "two options" not in line  # torch's advice to load it unsafely


def test_a_map_image_given_for_its_yaml_is_named_as_such(tmp_path, capsys):
    """`--map turtlebot2.pgm` once said "not a UTF-8 text file"."""
    shutil.copy(MAPS / "turtlebot2.pgm", tmp_path)
    shutil.copy(MAPS / "turtlebot2.yaml", tmp_path)
    line = fails(capsys, "demo", "--map", str(tmp_path / "turtlebot2.pgm"), "--envs", "2", "--out", str(tmp_path / "d"))
    assert line == (f"flashnav demo: error: {tmp_path / 'turtlebot2.pgm'}: is a map image; give its ROS map YAML "
                    f"(resolution, origin, thresholds) ({tmp_path / 'turtlebot2.yaml'} is beside it)")


def test_eval_maps_names_the_committed_suites_when_nothing_matches(capsys):
    policy = Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx"
    line = fails(capsys, "eval", str(policy), "--maps", "bogus_suite")
    assert line.startswith("flashnav eval: error: --maps: maps 'bogus_suite': no such directory or file")
    assert line.endswith("; or a committed benchmark suite: heldout, real")


def test_eval_maps_per_family_goes_with_the_validation_suite(tmp_path, capsys):
    """Without eval.maps: validation it was accepted and ignored."""
    line = fails(capsys, "train", "eval.maps_per_family=3", "--out", str(tmp_path / "r"))
    assert line == ("flashnav train: error: eval.maps_per_family=3 goes with eval.maps: validation (--eval-maps "
                    "validation); eval.maps is None")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("override, named", [
    ("robot.episode.dt=.inf", "robot.episode.dt: Input should be a finite number"),
    ("robot.footprint.radius=.inf", "robot.footprint.radius: Input should be a finite number"),
    ("robot.reward.goal=nan", "robot.reward.goal: Input should be a finite number"),
    ("algo.actor_lr=.inf", "algo.actor_lr: Input should be a finite number"),
    ("algo.temperature=.nan", "algo.temperature: Input should be a finite number"),
    ("budget.max_train_seconds=.inf", "budget.max_train_seconds: Input should be a finite number"),
    ("seed=yes", "seed: Input should be a valid integer (got True)"),
    ("eval.seed=1.5", "eval.seed: Input should be a valid integer"),
    ("algo.buffer_size=2048", "algo: learning_start (4096) must be <= buffer_size (2048)"),
])
def test_values_that_once_trained_or_crashed_are_named_before_anything_runs(tmp_path, capsys, override, named):
    """inf passed gt=0 and crashed in a kernel's traceback (dt, radius), NaN trained into a NaN action with no word
    of its key, `seed=yes` trained seed 1, and a replay smaller than learning_start trained without an update."""
    out = tmp_path / "run"
    line = fails(capsys, "train", "--device", "cpu", "--out", str(out), override)
    assert named in line, line
    assert not out.exists()


def test_eval_refuses_an_infinite_override(tmp_path, capsys, run_dir):
    line = fails(capsys, "eval", str(run_dir / "policy.pt"), "--episodes", "4", "robot.lidar.noise_std=.inf")
    assert "robot.lidar.noise_std: Input should be a finite number" in line


def test_an_empty_out_and_a_budget_before_the_first_update_are_said(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = fails(capsys, "train", "--device", "cpu", "--out", "")
    assert "--out is empty; give a folder" in line and not (tmp_path / "runs").exists()
    from flashnav.learn.cli import budget_notes
    from flashnav.spec import config_from_cli, resolve

    short = resolve(config_from_cli(None, {"device": "cpu"}, ["budget.max_env_steps=2048"]))
    (note,) = budget_notes(short)
    assert "ends at 2,048 env steps, before algo.learning_start = 4,096" in note and "no update will run" in note
    assert budget_notes(resolve(config_from_cli(None, {"device": "cpu"}, ["budget.max_env_steps=4096"]))) == []


def test_argument_errors_show_the_commands_usage_and_a_hint_for_an_unquoted_glob(tmp_path, capsys):
    for name in ("a.yaml", "b.yaml"):
        (tmp_path / name).write_text("x")
    with pytest.raises(SystemExit):
        main(["train", "--sead", "3"])
    err = capsys.readouterr().err
    assert "flashnav train: error: unrecognized arguments: --sead" in err and "usage: flashnav train" in err
    with pytest.raises(SystemExit):  # what the shell makes of --maps DIR/*.yaml
        main(["eval", "p.onnx", "--maps", str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml")])
    assert "(a glob the shell expanded? quote it: --maps 'DIR/*.yaml')" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "runs", "x", "--bogus"])
    assert "flashnav bench runs: error: unrecognized arguments: --bogus" in capsys.readouterr().err


def test_running_out_of_memory_is_one_line():
    from flashnav.cli import USER_ERRORS, error_line

    assert issubclass(MemoryError, USER_ERRORS)
    line = error_line(MemoryError("Unable to allocate 12.7 GiB for an array"))
    assert line.startswith("out of memory (Unable to allocate 12.7 GiB") and "fewer environments" in line


def test_demo_names_envs(tmp_path, capsys):
    assert "--envs must be >= 1 (robots driven at once), got 0" in fails(
        capsys, "demo", "--envs", "0", "--out", str(tmp_path / "d.png"))


def test_a_long_override_list_is_cut_and_a_misspelt_family_spec_is_pointed_to(tmp_path, capsys):
    from flashnav.presets import _shown

    many = {f"agents.k{i}": i for i in range(7)}
    assert _shown(many) == "{'agents.k0': 0, 'agents.k1': 1, 'agents.k2': 2, 'agents.k3': 3, ... 3 more}"
    assert _shown({"a": 1}) == "{'a': 1}"
    line = fails(capsys, "train", "--device", "cpu", "--out", str(tmp_path / "r"), "--maps", "famliy:rooms")
    assert "maps 'famliy:rooms': no such directory or file" in line and "generated during training are family:" in line


def test_a_seed_past_torchs_range_and_bad_map_weights_fail_in_resolve_not_in_train(tmp_path):
    from flashnav.request import TrainConfig
    from flashnav.spec import resolve

    with pytest.raises(ValueError, match="seed"):
        TrainConfig(seed=2**70)
    maps = [str(MAPS / "turtlebot2.yaml"), str(MAPS / "go2.yaml")]
    for weights in ([1.0, -1.0], [0.0, 0.0]):
        with pytest.raises(ValueError, match=r"map_weights must be >= 0 and not all 0"):
            resolve(TrainConfig(device="cpu", maps=maps, map_weights=weights))


def test_load_policy_names_the_device_not_the_file(run_dir, monkeypatch):
    from flashnav.export import load_policy

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="device 'gpu' is not one of auto, cpu, cuda, cuda:N"):
        load_policy(run_dir / "policy.pt", device="gpu")
    with pytest.raises(ValueError, match="cuda"):
        load_policy(run_dir / "policy.pt", device="cuda")
    policy, _ = load_policy(run_dir / "policy.pt", device="auto")  # auto: the CPU here
    assert policy is not None


def test_the_family_generator_refuses_a_bool_seed_and_a_map_too_fine_to_allocate():
    from flashnav.maps.families import generate_family

    with pytest.raises(ValueError, match="seed must be an integer >= 0, got True"):
        generate_family("rooms", True)
    with pytest.raises(ValueError, match="has more than 268,435,456 cells"):
        generate_family("halls", 0, size=(8.0, 8.0), resolution=1e-5)


def test_a_name_twice_a_trailing_dot_and_a_config_as_checkpoint_are_named(tmp_path, capsys):
    from flashnav.names import parse_names
    from flashnav.outputs import check_figure_file

    with pytest.raises(ValueError, match=r"--scenario: scenario static named more than once in 'static,static'"):
        parse_names("scenario", "static,static", ("static", "wander-4"), "--scenario", unique=True)
    assert parse_names("map family", "mazes,mazes", ("mazes",)) == ["mazes", "mazes"]  # twice as often: kept
    from flashnav.scenarios import scenario_names

    with pytest.raises(ValueError, match="named more than once"):
        scenario_names("static,static")
    assert parse_names("scenario", "static, wander-4", ("static", "wander-4")) == ["static", "wander-4"]
    with pytest.raises(ValueError, match=r"--out r5\.: ends with a dot; give the picture's suffix \(e\.g\. r5\.png\)"):
        check_figure_file("r5.", "--out")
    (tmp_path / "config.yaml").write_text("seed: 0\n")
    line = fails(capsys, "train", "--init-from", str(tmp_path / "config.yaml"), "--out", str(tmp_path / "r"))
    assert "a YAML file (a run's config.yaml: --config takes it), not a learner checkpoint" in line


@pytest.mark.parametrize("kind", ["folder", "not_db", "empty"])
def test_report_refuses_a_store_that_is_not_an_mlflow_database(tmp_path, capsys, kind):
    """A folder or a text file: SQLAlchemy tracebacks; an empty file: the read-only report wrote MLflow's tables
    into it."""
    target = tmp_path / "store"
    if kind == "folder":
        target.mkdir()
    else:
        target.write_text("" if kind == "empty" else "not a database\n")
    line = fails(capsys, "report", "--tracking-uri", f"sqlite:///{target}", "--out", str(tmp_path / "r"))
    said = {"folder": "is a folder", "not_db": "is not an SQLite database", "empty": "is an empty file"}[kind]
    assert f"tracking URI sqlite:///{target}: {target} {said}" in line
    assert kind == "folder" or target.read_bytes() in (b"", b"not a database\n")  # left as it was
