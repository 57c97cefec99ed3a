"""flashnav.outputs: an output path is checked before the work, and never one of the command's own inputs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from flashnav.cli import main as cli_main
from flashnav.outputs import check_figure_file, check_output_file

POLICY_DIR = Path(__file__).parent / "fixtures" / "deploy_policy"


def test_an_output_that_is_an_input_is_refused_by_any_name(tmp_path):
    source = tmp_path / "in.bag"
    source.write_bytes(b"data")
    (tmp_path / "link.bag").symlink_to(source)
    for same in (source, tmp_path / "link.bag", tmp_path / "sub" / ".." / "in.bag"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        with pytest.raises(ValueError, match=r"--out .*is one of the command's inputs"):
            check_output_file(same, "--out", inputs=(source,))
    not_yet = tmp_path / "new.csv"  # neither exists: compared by path
    with pytest.raises(ValueError, match="is one of the command's inputs"):
        check_output_file(not_yet, "--out", inputs=(str(not_yet),))
    assert check_output_file(tmp_path / "other.csv", "--out", inputs=(source, None)) == tmp_path / "other.csv"
    assert source.read_bytes() == b"data"


def test_a_figure_path_that_is_a_folder_is_refused_not_renamed(tmp_path):
    (tmp_path / "figs").mkdir()
    with pytest.raises(ValueError, match=r"--out .*figs: is a folder; give a file name"):
        check_figure_file(tmp_path / "figs", "--out")
    assert not (tmp_path / "figs.png").exists()
    assert check_figure_file(tmp_path / "curves", "--out") == tmp_path / "curves.png"


@pytest.mark.parametrize("which", ["bag", "policy"])
def test_deploy_replay_never_writes_over_its_bag_or_policy(tmp_path, capsys, which):
    bag = tmp_path / "in.bag"
    bag.write_bytes(b"not read: refused first")
    policy = tmp_path / "policy.onnx"
    policy.write_bytes((POLICY_DIR / "policy.onnx").read_bytes())
    out = bag if which == "bag" else policy
    before = out.read_bytes()
    assert cli_main(["deploy", "replay", str(bag), "--policy", str(policy), "--out", str(out)]) != 0
    err = capsys.readouterr().err
    assert "--out" in err and "is one of the command's inputs" in err, err
    assert out.read_bytes() == before


@pytest.mark.parametrize("flags, named", [
    (["--timeout", "inf"], "--timeout must be in"),
    (["--rate", "inf"], "--rate must be in (0, 100] Hz"),
    (["--rate", "1e6"], "--rate must be in (0, 100] Hz, got 1000000.0"),
    (["--fill", "-5"], "--fill must be a range in metres >= 0"),
    (["--fill", "99"], "--fill 99.0: fill must be in [0, max_range"),
])
def test_deploy_flags_are_named(tmp_path, capsys, flags, named):
    bag = tmp_path / "in.bag"
    bag.write_bytes(b"x")
    code = cli_main(["deploy", "replay", str(bag), "--policy", str(POLICY_DIR / "policy.onnx"), "--out",
                     str(tmp_path / "o.csv"), *flags])
    err = capsys.readouterr().err
    assert code != 0 and named in err, err
    assert not (tmp_path / "o.csv").exists()


def test_the_deploy_runtime_reads_a_run_folders_policy_and_names_a_folder_without_one(tmp_path):
    from flashnav.deploy.runtime import PolicyRuntime

    assert PolicyRuntime.load(POLICY_DIR).meta == PolicyRuntime.load(POLICY_DIR / "policy.onnx").meta
    with pytest.raises(ValueError, match="a folder without policy.onnx"):
        PolicyRuntime.load(tmp_path)


def test_eval_and_render_never_write_over_the_policy_or_the_map_they_read(tmp_path, capsys):
    import shutil

    from flashnav.maps.bundled import __file__ as bundled

    policy = tmp_path / "policy.onnx"
    policy.write_bytes((POLICY_DIR / "policy.onnx").read_bytes())
    maps = Path(bundled).parent / "data" / "benchmark" / "heldout"  # a map drawn as PNG: a picture suffix
    for name in ("mazes_900000.yaml", "mazes_900000.png"):
        shutil.copy(maps / name, tmp_path / name)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    for argv, flag in ((["eval", str(policy), "--episodes", "2", "--json", str(policy)], "--json"),
                       (["eval", str(policy), "--episodes", "2", "--map", str(tmp_path / "mazes_900000.yaml"),
                         "--json", str(tmp_path / "mazes_900000.yaml")], "--json"),
                       (["render", str(policy), "--episodes", "1", "--map", str(tmp_path / "mazes_900000.yaml"),
                         "--out", str(tmp_path / "mazes_900000.png")], "--out")):
        assert cli_main(argv) == 2
        err = capsys.readouterr().err
        assert flag in err and "is one of the command's inputs" in err, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_map_files_are_the_yaml_and_its_image(tmp_path):
    from flashnav.maps.ros import map_files

    (tmp_path / "m.yaml").write_text("image: pics/m.png\nresolution: 0.05\norigin: [0, 0, 0]\n")
    assert map_files(tmp_path / "m.yaml") == [tmp_path / "m.yaml", tmp_path / "pics" / "m.png"]
    (tmp_path / "bad.yaml").write_text(": : :")
    assert map_files(tmp_path / "bad.yaml") == [tmp_path / "bad.yaml"]
    assert map_files(tmp_path / "none.yaml") == [tmp_path / "none.yaml"]


@pytest.mark.parametrize("argv", [
    ["eval", str(POLICY_DIR / "policy.onnx"), "--scenario", "wander-4", "--episodes", "2", "--shield", "1e9"],
    ["deploy", "replay", "in.bag", "--policy", str(POLICY_DIR / "policy.onnx"), "--out", "o.csv", "--shield", "11"],
    ["bench", "shield", str(POLICY_DIR / "policy.onnx"), "--lookahead", "inf"],
])
def test_the_shield_look_ahead_is_bounded_and_its_flag_named(argv, tmp_path, monkeypatch, capsys):
    """1e9 s asked the shield for 80 GB and ended in torch's traceback; inf was 'lookahead must be > 0'."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "in.bag").write_bytes(b"x")
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert "must be > 0 and at most 10 seconds" in err and ("--shield" in err or "--lookahead" in err), err


def test_a_json_in_a_new_folder_is_written_after_the_rows(tmp_path):
    out = tmp_path / "new" / "sub" / "sim.json"
    assert cli_main(["bench", "sim", "--no-irsim", "--raycasters", "exact", "--robots", "turtlebot2",
                     "--num-envs", "4", "--seconds", "0.05", "--max-steps", "3", "--json", str(out)]) == 0
    assert out.is_file()


@pytest.mark.parametrize("flags, named", [
    (["--duration", "nan"], "--duration must be a finite number of seconds >= 0"),
    (["--duration", "-5"], "--duration must be a finite number of seconds >= 0"),
    (["--answer-timeout", "0"], "--answer-timeout must be a finite number of seconds > 0"),
    (["--episodes", "1", "--start", "1,1,0", "--goal-at", "2,2"], "--start, --goal-at drive the free-running mode"),
    (["--scans-stop-after", "-1"], "--scans-stop-after must be a finite number of seconds >= 0, got -1.0"),
    (["--scans-stop-after", "inf"], "--scans-stop-after must be a finite number of seconds >= 0, got inf"),
    (["--episodes", "2", "--scans-stop-after", "0"], "--scans-stop-after drive the free-running mode"),
    (["--stall", "1,0"], "--stall AT,WALL_S must have AT >= 0 and WALL_S > 0 seconds, got [1.0, 0.0]"),
    (["--stall=-1,2"], "--stall AT,WALL_S must have AT >= 0 and WALL_S > 0 seconds"),
    (["--episodes", "2", "--stall", "1,1"], "--stall drive the free-running mode"),
])
def test_sim_robot_flags_are_checked_before_ros(flags, named, capsys):
    assert cli_main(["deploy", "sim-robot", *flags]) == 2
    assert named in capsys.readouterr().err


def test_eval_names_a_bad_guide_before_loading_anything(tmp_path, capsys):
    assert cli_main(["eval", str(tmp_path / "absent.onnx"), "--maps", "heldout", "--guide", "0"]) == 2
    assert "--guide must be > 0 metres, got 0.0" in capsys.readouterr().err


def test_the_deploy_runtime_names_a_pose_goal_or_velocity_of_another_length():
    import numpy as np

    from flashnav.deploy.runtime import PolicyRuntime

    rt = PolicyRuntime.load(POLICY_DIR / "policy.onnx")
    sectors = np.full(rt.layout.sectors, 3.0, np.float32)
    for args, said in (((sectors, (0, 0), (3, 0), (0, 0)), "pose must have 3 values (x, y, yaw), got 2"),
                       ((sectors, (0, 0, 0), (3,), (0, 0)), "goal must have 2 values (x, y), got 1"),
                       ((sectors, (0, 0, 0), (3, 0), (0,)), "velocity must have 2 values (v, w), got 1")):
        with pytest.raises(ValueError, match=re.escape(said)):
            rt.decide(*args)
    assert rt.decide(sectors, (0, 0, 0), (3, 0), (0, 0)).state == "driving"
