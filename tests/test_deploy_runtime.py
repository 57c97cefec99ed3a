"""The deploy runtime (policy.onnx without torch) and the controller's safety states."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from flashnav.deploy.controller import Controller
from flashnav.deploy.runtime import PolicyRuntime, yaw_from_quaternion
from flashnav.export import load_policy

POLICY = Path(__file__).parent / "fixtures" / "deploy_policy" / "policy.onnx"
FOV = math.radians(270.0)
SCAN = dict(angle_min=-FOV / 2 + FOV / 2160, angle_increment=FOV / 1080, range_min=0.0, range_max=20.0)


def _ranges(value=3.0):
    return np.full(1080, value, np.float32)


def test_runtime_runs_without_torch():
    code = textwrap.dedent(f"""
        import sys
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name == "torch" or name.startswith("torch."):
                    raise ImportError("torch is blocked in this test")
        sys.meta_path.insert(0, Block())
        import numpy as np
        from flashnav.deploy import PolicyRuntime, Controller
        rt = PolicyRuntime.load({str(POLICY)!r})
        s = rt.scan(0.0, 0.0043633, np.full(1080, 3.0, np.float32), 0.0, 20.0)
        d = rt.decide(s, (0.0, 0.0, 0.0), (2.0, 1.0), (0.0, 0.0))
        assert d.state == "driving" and 0.0 <= d.v <= 0.5, d
        assert "torch" not in sys.modules
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_commands_equal_the_exported_policy():
    rt = PolicyRuntime.load(POLICY)
    policy, meta = load_policy(POLICY)
    rng = np.random.default_rng(0)
    for _ in range(20):
        sectors = rng.uniform(0.2, 20.0, 30).astype(np.float32)
        obs = rt.observation(sectors, rng.uniform(0, 10, 3), rng.uniform(0, 10, 2), (rng.uniform(0, 0.5), 0.1))
        action, v, w = rt.act(obs)
        want = policy(torch.from_numpy(obs)[None])[0].numpy()
        np.testing.assert_allclose(action, want, atol=1e-6)
        m = meta["preset"]["motion"]
        assert v == pytest.approx(m["v_bounds"][0] + (want[0] + 1) * 0.5 * (m["v_bounds"][1] - m["v_bounds"][0]), abs=1e-6)
        assert w == pytest.approx(m["w_bounds"][0] + (want[1] + 1) * 0.5 * (m["w_bounds"][1] - m["w_bounds"][0]), abs=1e-6)


def test_goal_frame_and_quaternion():
    rt = PolicyRuntime.load(POLICY)
    d, a = rt.goal_in_robot_frame((1.0, 1.0, math.pi / 2), (0.0, 1.0))  # goal behind-left: to the left
    assert d == pytest.approx(1.0) and a == pytest.approx(math.pi / 2)
    d, a = rt.goal_in_robot_frame((0.0, 0.0, 0.0), (-1.0, 0.0))
    assert a == pytest.approx(-math.pi)  # [-pi, pi), as the simulator wraps
    yaw = 2.5
    assert yaw_from_quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)) == pytest.approx(yaw)


def test_old_metadata_without_the_new_keys_still_loads():
    rt = PolicyRuntime.load(POLICY)
    meta = {k: v for k, v in rt.meta.items() if k not in ("goal_threshold", "goal_distance_max")}
    old = PolicyRuntime(rt.session, meta)
    assert old.goal_threshold == rt.goal_threshold == meta["preset"]["episode"]["goal_threshold"]


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(ValueError, match="policy.pt.*policy.onnx"):
        PolicyRuntime.load(tmp_path / "policy.pt")
    with pytest.raises(FileNotFoundError, match="missing.onnx"):
        PolicyRuntime.load(tmp_path / "missing.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not onnx")
    with pytest.raises(ValueError, match="bad.onnx: not a readable ONNX policy"):
        PolicyRuntime.load(bad)


def test_controller_safety_states():
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.0, now=0.0, **SCAN) is None and ctl.state == "idle"
    ctl.on_odom(0.0, 0.0, 0.0, now=0.0)
    ctl.on_goal(3.0, 0.0, now=0.0)
    first = ctl.on_scan(ranges=_ranges(), stamp=0.0, now=0.0, **SCAN)
    assert first.state == "driving" and first.v > 0
    assert ctl.on_scan(ranges=_ranges(), stamp=0.05, now=0.05, **SCAN) is None  # not due (10 Hz)
    ctl.on_odom(0.0, 0.0, 0.0, now=0.1)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.1, now=0.1, **SCAN).state == "driving"
    assert ctl.velocity != (0.0, 0.0)
    assert ctl.tick(0.35) is None  # 0.25 s since the last inputs: still fresh
    stop = ctl.tick(0.45)  # scan and odometry 0.35 s old
    assert (stop.v, stop.w, stop.state) == (0.0, 0.0, "stale") and ctl.velocity == (0.0, 0.0)
    assert ctl.tick(0.5).state == "stale"  # repeated while stale
    ctl.on_odom(0.0, 0.0, 0.0, now=0.6)
    again = ctl.on_scan(ranges=_ranges(), stamp=0.6, now=0.6, **SCAN)
    assert again.state == "driving"
    ctl.on_odom(2.9, 0.0, 0.0, now=0.7)  # within the 0.2 m goal radius
    reached = ctl.on_scan(ranges=_ranges(), stamp=0.7, now=0.7, **SCAN)
    assert (reached.v, reached.w, reached.state) == (0.0, 0.0, "reached")
    assert ctl.on_scan(ranges=_ranges(), stamp=0.8, now=0.8, **SCAN) is None  # sent once
    assert ctl.status(0.8)["state"] == "reached"
    assert ctl.shutdown().state == "stopped"
    ctl.on_goal(0.0, 5.0, now=0.9)
    assert ctl.state == "stopped"  # nothing after shutdown


@pytest.mark.parametrize("dead", [float("nan"), 0.0, 0.01])  # NaN, zero, below range_min
def test_a_scan_without_a_valid_reading_stops_the_robot(dead):
    """A dead or covered LiDAR read as open space (every sector at the fill value) and the robot drove on."""
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    scan = {**SCAN, "range_min": 0.05}
    ctl.on_odom(0.0, 0.0, 0.0, now=0.0)
    ctl.on_goal(3.0, 0.0, now=0.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.0, now=0.0, **scan).state == "driving"
    with pytest.warns(RuntimeWarning, match=r"had no valid reading .* read the fill value"):
        blind = ctl.on_scan(ranges=_ranges(dead), stamp=0.1, now=0.1, **scan)
    assert (blind.v, blind.w, blind.state) == (0.0, 0.0, "blind") and ctl.status(0.1)["state"] == "blind"
    assert ctl.on_scan(ranges=_ranges(dead), stamp=0.2, now=0.2, **scan).state == "blind"  # every such scan
    ctl.on_odom(0.0, 0.0, 0.0, now=0.3)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.3, now=0.3, **scan).state == "driving"  # valid again


def test_an_offset_mounted_sensor_without_a_valid_reading_is_blind_too():
    """An invalid reading has no end point: with the LiDAR off the base origin its sector was NaN, so no sector
    counted as covered and a dead sensor read as open space."""
    from flashnav.deploy.scan import Mount

    rt = PolicyRuntime.load(POLICY, mount=Mount(0.1, -0.05, 0.0))
    with pytest.warns(RuntimeWarning, match="had no valid reading"):
        sectors = rt.scan(ranges=_ranges(float("nan")), **SCAN)
    assert rt.adapter.no_valid_reading and (sectors == rt.adapter.fill).all()
    rt.scan(ranges=_ranges(), **SCAN)
    assert not rt.adapter.no_valid_reading and rt.adapter.invalid_sectors == []


def test_some_sectors_without_a_valid_reading_are_warned_of_and_drive():
    rt = PolicyRuntime.load(POLICY)
    ranges = _ranges()
    ranges[:200] = np.nan  # the robot's right side: its first sectors
    with pytest.warns(RuntimeWarning, match=r"scan: sectors \[0, 1, 2, 3, 4\] of \d+ had no valid reading"):
        sectors = rt.scan(ranges=ranges, **SCAN)
    assert not rt.adapter.no_valid_reading and sectors[0] == rt.adapter.fill and rt.adapter.invalid_sectors[:1] == [0]


def test_no_ros_master_is_named_with_its_uri(monkeypatch):
    """rospy without a master fails as "Failed to initialize time" or a bare "Connection refused"."""
    import socket

    from flashnav.deploy.ros1 import RosUnavailable, check_master

    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        monkeypatch.setenv("ROS_MASTER_URI", f"http://127.0.0.1:{port}")
        check_master()  # something answers: no error
    monkeypatch.setenv("ROS_MASTER_URI", f"http://127.0.0.1:{port}")  # closed now
    with pytest.raises(RosUnavailable, match=f"no ROS master answers at http://127.0.0.1:{port} .ROS_MASTER_URI; "
                                             ".*start roscore"):
        check_master()


def test_a_clock_that_moves_backwards_stops_the_robot_and_drops_the_goal():
    """A simulator restarting /clock (or the wall clock stepped back) while driving: the scans' stamps were all
    'not due' until they caught up with the old clock and the inputs' ages negative (fresh), so the last command
    stayed in force, unwatched. Now: one zero, the goal dropped, and a new goal drives on the new clock."""
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    ctl.on_odom(0.0, 0.0, 0.0, now=100.0)
    ctl.on_goal(3.0, 0.0, now=100.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=100.0, now=100.0, **SCAN).v > 0
    assert ctl.tick(100.04) is None  # a small step back (threads) is not a jump
    ctl.on_odom(0.0, 0.0, 0.0, now=1.0)  # the clock restarts
    assert ctl.state == "clock" and ctl.goal is None and ctl.velocity == (0.0, 0.0)
    stop = ctl.tick(1.01)
    assert (stop.v, stop.w, stop.state) == (0.0, 0.0, "clock")
    assert ctl.tick(1.02) is None  # sent once
    assert ctl.on_scan(ranges=_ranges(), stamp=1.05, now=1.05, **SCAN) is None  # no goal: nothing is driven
    status = ctl.status(1.05)
    assert status["state"] == "clock" and status["clock_jumps"] == 1 and status["goal"] is None
    ctl.on_goal(3.0, 0.0, now=1.1)
    ctl.on_odom(0.0, 0.0, 0.0, now=1.1)
    again = ctl.on_scan(ranges=_ranges(), stamp=1.1, now=1.1, **SCAN)  # due at once: the old stamps are forgotten
    assert again.state == "driving" and again.v > 0
    assert ctl.tick(1.5).state == "stale"  # the watchdog on the new clock


def test_a_jump_between_a_goal_and_its_first_scan_owes_the_zero_once():
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    ctl.on_odom(0.0, 0.0, 0.0, now=50.0)
    ctl.on_goal(3.0, 0.0, now=50.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=50.0, now=50.0, **SCAN).v > 0
    ctl.on_goal(0.0, 3.0, now=2.0)  # the restarted simulator's goal is the first message on the new clock
    assert ctl.state == "driving" and ctl.goal == (0.0, 3.0) and ctl.clock_jumps == 1
    ctl.on_odom(0.0, 0.0, 0.0, now=2.0)
    owed = ctl.on_scan(ranges=_ranges(), stamp=2.0, now=2.0, **SCAN)
    assert (owed.v, owed.w, owed.state) == (0.0, 0.0, "clock") and ctl.state == "driving"
    assert ctl.on_scan(ranges=_ranges(), stamp=2.1, now=2.1, **SCAN).state == "driving"


def test_scan_stamps_that_go_back_are_due_again():
    """A bag played in a loop without /clock, or a scanner whose clock restarted: stamps go back while the node's
    clock goes on. Every scan was 'not due' until the stamps caught up, yet fresh by arrival: the last command
    stayed in force. A stamp more than the timeout before the last step's drives; a little earlier (out of
    order) does not."""
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    ctl.on_odom(0.0, 0.0, 0.0, now=0.0)
    ctl.on_goal(3.0, 0.0, now=0.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=60.0, now=0.0, **SCAN).state == "driving"
    assert ctl.on_scan(ranges=_ranges(), stamp=59.9, now=0.1, **SCAN) is None  # out of order
    ctl.on_odom(0.0, 0.0, 0.0, now=0.2)
    looped = ctl.on_scan(ranges=_ranges(), stamp=0.5, now=0.2, **SCAN)
    assert looped is not None and looped.state == "driving" and ctl.last_step_stamp == 0.5
    assert ctl.on_scan(ranges=_ranges(), stamp=0.55, now=0.25, **SCAN) is None  # the period counts from there


@pytest.mark.parametrize("bad", ["", "scan topic", "/scan/", "//scan", "1scan", "/", "~", "/scan-1"])
def test_topic_flags_are_checked_as_ros_names_before_anything_starts(bad):
    import argparse

    from flashnav.deploy.cli import topic_name

    for good in ("/scan", "scan", "~scan", "/robot_1/base_scan"):
        assert topic_name(good) == good
    with pytest.raises(argparse.ArgumentTypeError, match="not a ROS topic name"):
        topic_name(bad)


def test_a_bad_topic_is_a_usage_error_naming_the_flag():
    bad = subprocess.run([sys.executable, "-m", "flashnav.cli", "deploy", "ros", str(POLICY), "--cmd", "cmd vel"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--cmd" in bad.stderr and "not a ROS topic name" in bad.stderr, bad.stderr
