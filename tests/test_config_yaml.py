"""flashnav.config's YAML loading: safe, one-line errors naming the file, no duplicate keys."""

from __future__ import annotations

import pytest

from flashnav.presets import load_robot
from flashnav.yamlio import load_yaml, parse_yaml


def test_duplicate_keys_name_the_key_and_both_lines(tmp_path):
    path = tmp_path / "robot.yaml"
    path.write_text("name: tb\nlidar:\n  beams: 360\n  sectors: 30\n  beams: 720\n")
    with pytest.raises(ValueError, match=r"robot\.yaml: not valid YAML: duplicate key 'beams' at line 5 \(first at line 3\)"):
        load_yaml(path)


def test_duplicates_on_one_line_and_merge_keys():
    with pytest.raises(ValueError, match="duplicate key 'a'"):
        parse_yaml("{a: 1, a: 2}")
    # a merge key ('<<') overriding a base is YAML's intended use, not a duplicate
    assert parse_yaml("base: &b {p: 1, q: 2}\nd:\n  <<: *b\n  p: 3\n")["d"] == {"p": 3, "q": 2}


def test_errors_are_one_line(tmp_path):
    path = tmp_path / "x.yaml"
    path.write_text("a: [1\n")
    with pytest.raises(ValueError) as info:
        load_yaml(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(f"{path}: not valid YAML: ")
    with pytest.raises(ValueError, match="is a folder"):
        load_yaml(tmp_path)
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_yaml(tmp_path / "missing.yaml")


def test_unsafe_tags_stay_refused():
    with pytest.raises(ValueError, match="not valid YAML"):
        parse_yaml("!!python/object/apply:os.system ['true']")


def test_presets_still_load():
    assert load_robot("turtlebot2").name == "turtlebot2" and load_robot("go2").name == "go2"
