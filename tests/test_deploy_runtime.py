"""The deploy runtime (policy.onnx without torch) and the controller's safety states."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
import types
import warnings
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
    with pytest.warns(RuntimeWarning, match="scans 0.5 s apart"):  # (the gap that made it stale)
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


def test_a_clock_that_moves_backwards_stops_the_robot_until_fresh_inputs():
    """A simulator restarting /clock (or the wall clock stepped back) while driving: the scans' stamps were all
    'not due' until they caught up with the old clock and the inputs' ages negative (fresh), so the last command
    stayed in force, unwatched. Now: one zero, the old clock's times and memory forgotten, and the goal driven
    to again once fresh inputs arrive on the new clock."""
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    ctl.on_odom(0.0, 0.0, 0.0, now=100.0)
    ctl.on_goal(3.0, 0.0, now=100.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=100.0, now=100.0, **SCAN).v > 0
    assert ctl.tick(100.04) is None  # a small step back (threads) is not a jump
    ctl.on_odom(0.0, 0.0, 0.0, now=1.0)  # the clock restarts
    assert ctl.state == "stale" and ctl.goal == (3.0, 0.0) and ctl.velocity == (0.0, 0.0)
    stop = ctl.tick(1.01)
    assert (stop.v, stop.w, stop.state) == (0.0, 0.0, "clock")
    assert ctl.tick(1.02).state == "stale"  # no scan on the new clock yet
    assert ctl.status(1.02)["clock_jumps"] == 1
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


def test_a_goal_sent_just_before_the_node_sees_the_new_clock_is_kept():
    """The race the ROS test met: the restarted simulator's goal reached the node before its /clock did, so the
    goal was set on the old clock - and dropping the goal at the jump lost it."""
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    ctl.on_odom(0.0, 0.0, 0.0, now=50.0)
    ctl.on_goal(3.0, 0.0, now=50.0)
    ctl.on_scan(ranges=_ranges(), stamp=50.0, now=50.0, **SCAN)
    ctl.on_goal(0.0, 3.0, now=50.05)  # the new goal, on the old clock
    ctl.on_odom(1.0, 1.0, 0.0, now=1.0)  # then the new clock
    assert ctl.goal == (0.0, 3.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=1.0, now=1.0, **SCAN).state == "clock"  # the owed zero
    assert ctl.on_scan(ranges=_ranges(), stamp=1.1, now=1.1, **SCAN).state == "driving"


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


def _driving(timeout=0.3, **kw):
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=timeout, **kw)
    ctl.on_odom(0.0, 0.0, 0.0, now=0.0)
    ctl.on_goal(3.0, 0.0, now=0.0)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.0, now=0.0, **SCAN).v > 0
    return ctl


@pytest.mark.parametrize("bad", [dict(ranges=[]), dict(angle_increment=0.0), dict(angle_min=float("nan")),
                                 dict(range_max=0.0), dict(range_min=float("nan")), dict(range_min=5.0, range_max=4.0)])
def test_an_unreadable_scan_stops_the_robot_and_says_why(bad):
    """It raised out of on_scan (rospy logged a 'bad callback') after the scan had counted as fresh: the last
    command stayed in force. range_max 0 (a LaserScan left at its defaults) read every wall as open space."""
    ctl = _driving()
    ctl.on_odom(0.0, 0.0, 0.0, now=0.1)
    fault = ctl.on_scan(**{**SCAN, "ranges": _ranges(0.25), **bad}, stamp=0.1, now=0.1)
    assert (fault.v, fault.w, fault.state) == (0.0, 0.0, "fault") and ctl.velocity == (0.0, 0.0)
    assert ctl.status(0.1)["fault"] == ctl.fault and "scan" in ctl.fault
    ctl.on_odom(0.0, 0.0, 0.0, now=0.2)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.2, now=0.2, **SCAN).state == "driving"
    assert ctl.status(0.2)["fault"] is None


def test_scans_whose_stamps_do_not_advance_stop_the_robot():
    """A driver that leaves header.stamp at 0 (or republishes one scan): no scan is due after the first, yet all
    arrive fresh. The first command stayed in force; now the watchdog stops it (stuck) and drives again with
    the next control step."""
    ctl = _driving()
    for now in (0.1, 0.2, 0.3):  # fresh inputs, frozen stamps
        ctl.on_odom(0.0, 0.0, 0.0, now=now)
        assert ctl.on_scan(ranges=_ranges(), stamp=0.0, now=now, **SCAN) is None
    assert ctl.tick(0.3) is None  # within the timeout of the last control step
    stuck = ctl.tick(0.31)
    assert (stuck.v, stuck.w, stuck.state) == (0.0, 0.0, "stuck") and ctl.velocity == (0.0, 0.0)
    assert ctl.tick(0.42).state == "stuck"  # sent again while it lasts
    again = ctl.on_scan(ranges=_ranges(), stamp=0.5, now=0.43, **SCAN)
    assert again.state == "driving" and ctl.tick(0.44) is None


def test_a_control_period_longer_than_the_timeout_is_refused():
    """--rate 0.001 drove 1000 s on its first command (past the goal); a rate the timeout cannot watch is refused."""
    rt = PolicyRuntime.load(POLICY)
    with pytest.raises(ValueError, match=r"period 0\.5 s .* shorter than the timeout 0\.3 s"):
        Controller(rt, timeout=0.3, period=0.5)
    with pytest.raises(ValueError, match=r"at least 0\.01 s \(100 Hz\), got 1e-06 s"):  # a timer at 4 MHz spun a core
        Controller(rt, timeout=0.3, period=1e-6)
    for timeout in (float("inf"), 1e9, 0.0):
        with pytest.raises(ValueError, match="timeout must be in"):
            Controller(rt, timeout=timeout)


def test_a_pose_that_is_not_finite_is_dropped_and_goes_stale():
    ctl = _driving()
    with pytest.raises(ValueError, match="odometry pose .* not finite"):
        ctl.on_odom(float("nan"), 0.0, 0.0, now=0.1)
    assert ctl.pose == (0.0, 0.0, 0.0) and ctl.odom_time == 0.0
    assert ctl.tick(0.35).state == "stale"


def test_yaw_of_a_quaternion_of_any_length_and_none_of_length_zero():
    s, c = math.sin(math.pi / 4), math.cos(math.pi / 4)  # 90 deg
    for scale in (2.0, 0.5, 1.0):
        assert yaw_from_quaternion(0.0, 0.0, scale * s, scale * c) == pytest.approx(math.pi / 2)  # 127 / 18 deg before
    for q in ((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, float("nan"), 1.0)):
        with pytest.raises(ValueError, match="not a rotation"):
            yaw_from_quaternion(*q)


@pytest.mark.parametrize("case", ["too_close", "outside"])
def test_only_too_close_readings_or_none_in_view_are_blind(case):
    """All -inf (REP 117: closer than range_min, a covered window) drove on readings of 0; a scan whose beams all
    miss the field of view (a wrong mounting yaw) read 20 m of open space in every sector and drove."""
    ctl = _driving()
    ctl.on_odom(0.0, 0.0, 0.0, now=0.1)
    if case == "too_close":
        scan = {**SCAN, "ranges": _ranges(-np.inf), "range_min": 0.1}
    else:
        scan = dict(ranges=np.full(100, 0.2, np.float32), angle_min=math.radians(140),
                    angle_increment=math.radians(0.8), range_min=0.0, range_max=20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (the scan that misses the view is warned of)
        blind = ctl.on_scan(**scan, stamp=0.1, now=0.1)
    assert (blind.v, blind.w, blind.state) == (0.0, 0.0, "blind")
    ranges = _ranges()
    ranges[:5] = -np.inf  # something closer than range_min on one side, the rest seen: not blind
    ctl.on_odom(0.0, 0.0, 0.0, now=0.2)
    assert ctl.on_scan(**{**SCAN, "ranges": ranges}, stamp=0.2, now=0.2).state == "driving"


def test_cancel_drops_the_goal_and_stops():
    ctl = _driving()
    stop = ctl.cancel(0.05)
    assert (stop.v, stop.w, stop.state) == (0.0, 0.0, "idle") and ctl.goal is None
    ctl.on_odom(0.0, 0.0, 0.0, now=0.1)
    assert ctl.on_scan(ranges=_ranges(), stamp=0.1, now=0.1, **SCAN) is None and ctl.tick(0.5) is None


class _FakeRospy:
    """The few rospy calls DeployNode's callbacks make, recorded (no ROS needed)."""

    def __init__(self, now=1.0):
        self.now, self.errors, self.warnings = now, [], []

    def get_time(self):
        return self.now

    def get_rostime(self):
        return types.SimpleNamespace(is_zero=lambda: self.now == 0.0)

    def logerr(self, msg):
        self.errors.append(msg)

    def logerr_throttle(self, _period, msg):
        self.errors.append(msg)

    def logwarn_once(self, msg):
        self.warnings.append(msg)

    logwarn = logwarn_once


def _fake_node(now=1.0):
    """A DeployNode without ROS: its callbacks on a real controller, its publishers recording."""
    import threading

    from flashnav.deploy.ros1 import DeployNode

    node = DeployNode.__new__(DeployNode)
    ns = types.SimpleNamespace
    node.rospy, node.lock = _FakeRospy(now), threading.Lock()
    node.ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    node.odom_frame = node.goal_frame = None
    node.wall_now = 100.0  # the node's wall clock (time.monotonic in the node), set by the tests
    node.wall, node.clock_seen, node.active = (lambda: node.wall_now), None, node.wall_now
    node.Twist = lambda: ns(linear=ns(x=0.0), angular=ns(z=0.0))
    node.String = lambda data: data
    node.sent = []
    node.cmd_pub = types.SimpleNamespace(publish=lambda t: node.sent.append((t.linear.x, t.angular.z)))
    node.status_pub = types.SimpleNamespace(publish=lambda s: None)
    return node


def _msg(frame="odom", x=0.0, y=0.0, q=(0.0, 0.0, 0.0, 1.0), stamp=1.0, **scan):
    ns = types.SimpleNamespace
    pose = ns(position=ns(x=x, y=y), orientation=ns(x=q[0], y=q[1], z=q[2], w=q[3]))
    header = ns(frame_id=frame, stamp=ns(to_sec=lambda: stamp))
    return ns(header=header, pose=ns(pose=pose), **scan)


def _goal(frame="odom", x=0.0, y=0.0):
    """A PoseStamped's fields (its pose one level less deep than an Odometry's)."""
    msg = _msg(frame, x, y)
    return types.SimpleNamespace(header=msg.header, pose=msg.pose.pose)


def test_node_checks_a_goal_sent_before_odometry_against_the_first_odometry():
    """A goal in 'map' sent before any odometry was accepted unchecked and driven to in the odometry frame."""
    node = _fake_node()
    node._on_goal(_goal(frame="map", x=3.0))
    assert node.ctl.goal == (3.0, 0.0)
    node._on_odom(_msg(frame="odom"))
    assert node.ctl.goal is None and node.ctl.state == "idle" and node.sent[-1] == (0.0, 0.0)
    assert "frame 'map'" in node.rospy.errors[-1]
    node._on_goal(_goal(frame="odom", x=3.0))  # the right frame drives
    node._on_scan(_msg(ranges=_ranges(), stamp=1.0, **SCAN))
    assert node.sent[-1][0] > 0
    node._on_goal(_goal(frame="map", x=0.0, y=3.0))  # a wrong frame now: refused, and the robot stops
    assert node.ctl.goal is None and node.sent[-1] == (0.0, 0.0) and "refused" in node.rospy.errors[-1]


def test_node_drops_a_pose_that_is_not_a_rotation_and_a_nan_goal_stops():
    node = _fake_node()
    node._on_odom(_msg(q=(0.0, 0.0, 0.0, 0.0)))  # an orientation never set
    assert node.ctl.pose is None and "odometry ignored" in node.rospy.errors[-1]
    node._on_odom(_msg())
    node._on_goal(_goal(x=3.0))
    node._on_scan(_msg(ranges=_ranges(), stamp=1.0, **SCAN))
    assert node.sent[-1][0] > 0
    node._on_goal(_goal(x=float("nan")))
    assert node.ctl.goal is None and node.sent[-1] == (0.0, 0.0) and "not finite" in node.rospy.errors[-1]


def test_node_does_not_drive_while_ros_time_is_zero():
    """/use_sim_time left set with nothing on /clock: ROS time stays 0, every age reads 0 and rospy's timer never
    fires, so one command would have been in force for good."""
    node = _fake_node(now=0.0)
    node._on_odom(_msg())
    node._on_goal(_goal(x=3.0))
    node._on_scan(_msg(ranges=_ranges(), stamp=0.0, **SCAN))
    node._on_scan(_msg(ranges=_ranges(), stamp=0.0, **SCAN))
    assert node.sent == [] and len(node.rospy.warnings) == 2 and "/use_sim_time" in node.rospy.warnings[0]


def test_node_stops_the_robot_when_the_simulated_clock_stands_still():
    """/use_sim_time with a /clock that stopped (a simulator or `rosbag play --clock` died): rospy's timer runs on
    that clock and every age is read on it, so the last command stayed in force for good. The node's wall-time watch
    stops the robot once ROS time has stood still, and no scan has been answered, for the timeout (at least
    FROZEN_MIN_S = 1 s); the next scan drives again."""
    node = _fake_node(now=1.0)
    node._on_odom(_msg())
    node._on_goal(_goal(x=3.0))
    node._on_scan(_msg(ranges=_ranges(), stamp=1.0, **SCAN))  # answered at wall 100
    assert node.sent[-1][0] > 0
    node._check_clock()  # the first look: ROS time 1.0
    node.wall_now = 100.9  # past the timeout (0.3 s), within FROZEN_MIN_S: a lock-step simulator may be that slow
    node._check_clock()
    assert len(node.sent) == 1
    node.wall_now = 100.95
    node._on_scan(_msg(ranges=_ranges(), stamp=1.0, **SCAN))  # not due (its stamp stands): not answered
    for wall in (101.0, 101.5):  # nor does odometry on a wall timer hold the stop off
        node.wall_now = wall
        node._on_odom(_msg())
        node._check_clock()
    assert node.sent[-1] == (0.0, 0.0) and node.ctl.state == "frozen" and "stood at 1.000 s" in node.rospy.warnings[-1]
    node.wall_now = 105.0
    node._check_clock()  # sent once
    assert len(node.sent) == 2
    node.rospy.now = 1.1  # the clock moves again: the next scan drives
    node._check_clock()
    node._on_odom(_msg())
    node._on_scan(_msg(ranges=_ranges(), stamp=1.1, **SCAN))
    assert node.sent[-1][0] > 0 and node.ctl.state == "driving"


def test_an_answered_scan_holds_the_clock_stop_off():
    """In lock step the simulator's clock stands still while it waits for the node's answer: a slow answer is not a
    frozen clock."""
    node = _fake_node(now=1.0)
    node._on_odom(_msg())
    node._on_goal(_goal(x=3.0))
    node._on_scan(_msg(ranges=_ranges(), stamp=1.0, **SCAN))
    node._check_clock()
    node.wall_now = 100.8
    node._on_scan(_msg(ranges=_ranges(), stamp=1.1, **SCAN))  # due by its stamp: answered at wall 100.8
    node.wall_now = 101.5
    node._check_clock()
    assert len(node.sent) == 2 and node.sent[-1][0] > 0


def test_the_clock_stop_sees_the_command_in_force_not_the_velocity_state():
    """A new goal zeroes the policy's velocity state but sends nothing: the robot still runs the old command, and the
    frozen-clock stop took it for stopped. A zero owed since the clock jumped back is sent by it too (no tick or scan
    would come to send it)."""
    ctl = _driving()
    ctl.on_goal(5.0, 1.0, now=0.05)
    assert ctl.velocity == (0.0, 0.0) and ctl.frozen().state == "frozen"
    assert ctl.frozen() is None  # the zero is in force
    ctl = _driving()
    ctl.on_odom(0.0, 0.0, 0.0, now=-5.0)  # the clock jumped back: a zero owed
    assert ctl.frozen().state == "clock" and ctl.frozen() is None
    ctl = _driving()
    ctl.on_odom(0.0, 0.0, 0.0, now=-5.0)
    assert ctl.shutdown().state == "stopped"  # the zero: none owed after it (one was sent after `stopped`)
    assert ctl.frozen() is None and ctl.tick(-4.9) is None
    ctl = Controller(PolicyRuntime.load(POLICY), timeout=0.3)
    ctl.on_goal(1.0, 0.0, now=0.0)
    assert ctl.frozen() is None  # nothing sent yet


def test_scans_further_apart_than_the_timeout_are_warned_of_once():
    ctl = _driving()
    with pytest.warns(RuntimeWarning, match=r"scans 0\.5 s apart, more than the timeout 0\.3 s"):
        ctl.on_odom(0.0, 0.0, 0.0, now=0.5)
        ctl.on_scan(ranges=_ranges(), stamp=0.5, now=0.5, **SCAN)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ctl.on_odom(0.0, 0.0, 0.0, now=1.0)
        ctl.on_scan(ranges=_ranges(), stamp=1.0, now=1.0, **SCAN)


def test_an_observation_that_cannot_be_made_stops_the_robot(monkeypatch):
    ctl = _driving()

    def refuse(*_a, **_k):
        raise ValueError("observation is not finite")

    monkeypatch.setattr(ctl.rt, "decide", refuse)
    ctl.on_odom(0.0, 0.0, 0.0, now=0.1)
    fault = ctl.on_scan(ranges=_ranges(), stamp=0.1, now=0.1, **SCAN)
    assert (fault.v, fault.state, ctl.fault) == (0.0, "fault", "observation is not finite")
