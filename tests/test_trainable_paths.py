"""A trial runs in a folder of Ray's, not where the sweep was started: every relative path the sweep names
(preset, map, maps, evaluation maps, init_from) must reach the trial as the file under the shipped working dir."""

from __future__ import annotations

import shutil
from pathlib import Path

from flashnav.spec import config_from_data, resolve
from services.trainable import localise_paths

DATA = Path(__file__).resolve().parents[1] / "flashnav" / "maps" / "data"


def test_relative_paths_are_made_absolute_and_keywords_pass(tmp_path, monkeypatch):
    project = tmp_path / "project"
    (project / "mymaps").mkdir(parents=True)
    (project / "runs" / "general").mkdir(parents=True)
    monkeypatch.setenv("TUNE_ORIG_WORKING_DIR", str(project))
    monkeypatch.chdir(tmp_path)  # the trial's own folder
    data = {"robot": "turtlebot2", "map": "robots/my_map.yaml", "maps": "mymaps/*.yaml", "init_from": "runs/general",
            "eval": {"maps": ["mymaps", "validation"], "episodes": 8}}
    out = localise_paths(data)
    assert out["robot"] == "turtlebot2"  # a preset's name, not a path
    assert out["map"] == str(project / "robots/my_map.yaml")  # a YAML: always under the shipped dir
    assert out["maps"] == str(project / "mymaps/*.yaml")
    assert out["init_from"] == str(project / "runs/general")
    assert out["eval"] == {"maps": [str(project / "mymaps"), "validation"], "episodes": 8}
    assert data["eval"]["maps"] == ["mymaps", "validation"]  # the caller's dict is left alone
    generated = {"family": "rooms", "count": 4}
    assert localise_paths({"robot": "/abs/go2.yaml", "maps": generated}) == {"robot": "/abs/go2.yaml",
                                                                             "maps": generated}
    assert localise_paths({"maps": "family:rooms,offices"})["maps"] == "family:rooms,offices"


def test_a_trial_in_another_folder_resolves_the_sweeps_relative_maps(tmp_path, monkeypatch):
    project = tmp_path / "project"
    (project / "maps").mkdir(parents=True)
    for name in ("turtlebot2.yaml", "turtlebot2.pgm"):
        shutil.copy(DATA / name, project / "maps" / name)
    trial_dir = tmp_path / "trial"
    trial_dir.mkdir()
    monkeypatch.setenv("TUNE_ORIG_WORKING_DIR", str(project))
    monkeypatch.chdir(trial_dir)
    data = {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": 0, "device": "cpu", "recipe": "cpu",
            "maps": "maps/*.yaml", "eval": {"maps": "maps", "episodes": 8}}
    spec = resolve(config_from_data(localise_paths(data), "test"))
    assert [Path(p).name for p in spec.eval_maps["files"]] == ["turtlebot2.yaml"]
