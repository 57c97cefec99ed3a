"""flashnav.names: the checked name lists and their parsers."""

from __future__ import annotations

import itertools

import pytest

from flashnav.names import check_name, check_robot, parse_names

ALLOWED = ("rooms", "offices", "halls")


def test_parse_names_reads_comma_lists_lists_and_all():
    for k in range(1, len(ALLOWED) + 1):
        for names in itertools.permutations(ALLOWED, k):
            assert parse_names("map family", ",".join(names), ALLOWED) == list(names)
            assert parse_names("map family", " , ".join(names) + ",", ALLOWED) == list(names)
            assert parse_names("map family", [f" {n}" for n in names], ALLOWED) == list(names)
    assert parse_names("map family", "all", ALLOWED) == list(ALLOWED)
    assert parse_names("map family", " all ", ALLOWED) == list(ALLOWED)
    assert parse_names("map family", ["all"], ALLOWED) == list(ALLOWED)


def test_parse_names_errors_name_the_option_and_the_bad_name():
    with pytest.raises(ValueError, match=r"^--family: unknown map family 'room' \(did you mean 'rooms'\?\); "
                                         r"use one of rooms, offices, halls$"):
        parse_names("map family", "halls,room", ALLOWED, "--family")
    with pytest.raises(ValueError, match=r"^unknown map family 'all'"):  # all stands alone
        parse_names("map family", "all,rooms", ALLOWED)
    with pytest.raises(ValueError, match=r"^--family: no map family named in ' , '; use one of rooms, offices, "
                                         r"halls, or all$"):
        parse_names("map family", " , ", ALLOWED, "--family")
    with pytest.raises(ValueError, match=r"^no map family named in \[\]"):
        parse_names("map family", [], ALLOWED)
    with pytest.raises(ValueError, match=r"unknown map family 3"):
        parse_names("map family", ["rooms", 3], ALLOWED)


def test_check_name():
    assert check_name("robot", "go2", ("turtlebot2", "go2")) == "go2"
    with pytest.raises(ValueError, match=r"unknown robot 'go3' \(did you mean 'go2'\?\)"):
        check_name("robot", "go3", ("turtlebot2", "go2"))


def test_check_robot_says_a_folder_is_a_folder(tmp_path):
    assert check_robot("go2") == "go2" and check_robot("my/robot.yaml") == "my/robot.yaml"
    with pytest.raises(ValueError, match="it holds no .yaml file"):
        check_robot(str(tmp_path))
    (tmp_path / "wheelie.yaml").write_text("name: wheelie\n")
    with pytest.raises(ValueError, match=r"is a folder: give a robot preset YAML file \(here: .*wheelie\.yaml\)"):
        check_robot(str(tmp_path))
    with pytest.raises(ValueError, match="unknown robot 'wheelie'"):
        check_robot("wheelie")
