"""``flashnav deploy replay``: what a policy would have commanded over a recorded ROS 1 bag.

The bag's LaserScan, Odometry and (if any) goal messages are fed in recording order, on the bag's
clock, to the same :class:`~flashnav.deploy.controller.Controller` the node runs (the watchdog checked
before each message), and every command it would have sent is written as a CSV row:
``time`` (bag seconds), ``scan_stamp`` (header time of the scan that produced it; empty for a watchdog
stop), ``v`` (m/s), ``w`` (rad/s), ``state``, ``distance`` (m to the goal). Messages the node would drop
(a pose or people that are not finite, a goal it refuses and stops for) are dropped alike, with one warning.
"""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

from flashnav.deploy.controller import Controller
from flashnav.deploy.ros1 import import_rospy, odom_pose, people_rows, scan_args

COLUMNS = ["time", "scan_stamp", "v", "w", "state", "distance"]


def _open_bag(path: Path):
    import_rospy()  # puts Debian's ROS packages on the path
    try:
        import rosbag
    except ImportError as exc:
        from flashnav.deploy.ros1 import RosUnavailable
        raise RosUnavailable(f"reading bags needs rosbag ({exc}); on Debian: apt-get install python3-rosbag") from None
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such bag file")
    try:
        return rosbag.Bag(str(path))
    except Exception as exc:  # rosbag's ROSBagException / ROSBagFormatException: not a bag
        raise ValueError(f"{path}: not a readable ROS 1 bag ({exc})") from None


def replay_bag(bag_path, controller: Controller, out, *, scan: str = "/scan", odom: str = "/odom",
               goal: str = "/move_base_simple/goal", goal_at=None, people: str = "/people") -> int:
    """Replay ``bag_path`` through ``controller``; write the commands to the CSV ``out``; return their count.

    Raises ValueError naming the bag when it holds no messages on ``scan`` or ``odom``, or when it has
    no goal messages and ``goal_at`` is not given, or (for a policy with agent tracks) no messages on
    ``people``."""
    bag_path = Path(bag_path)
    with _open_bag(bag_path) as bag:
        topics = bag.get_type_and_topic_info().topics
        for name, flag in ((scan, "--scan"), (odom, "--odom")):
            if name not in topics:
                raise ValueError(f"{bag_path}: no messages on {flag} {name} (topics: {', '.join(sorted(topics))})")
        tracks = controller.rt.agent_tracks > 0
        if tracks and people not in topics:
            raise ValueError(f"{bag_path}: the policy sees tracked people (observation.agent_tracks = "
                             f"{controller.rt.agent_tracks}) but the bag has no messages on --people {people}")
        if goal not in topics and goal_at is None:
            raise ValueError(f"{bag_path}: no goal messages on --goal {goal}; give the goal with --goal-at X,Y")
        rows, dropped = [], []
        started = goal_at is None
        for topic, msg, t in bag.read_messages(topics=[scan, odom, goal] + ([people] if tracks else [])):
            now = t.to_sec()
            if not started:  # the fixed goal starts with the first message
                controller.on_goal(goal_at[0], goal_at[1], now)
                started = True
            stop = controller.tick(now)
            if stop is not None:
                rows.append([now, "", stop.v, stop.w, stop.state, controller.distance])
            try:
                if topic == odom:
                    controller.on_odom(*odom_pose(msg), now)
                elif topic == goal:
                    controller.on_goal(msg.pose.position.x, msg.pose.position.y, now)
                elif topic == people and tracks:
                    controller.on_people(people_rows(msg), now)
            except ValueError as exc:  # as the node: dropped; a refused goal stops the robot
                dropped.append(f"{topic} at {now:.3f} s: {exc}")
                if topic == goal:
                    stop = controller.cancel(now)
                    rows.append([now, "", stop.v, stop.w, stop.state, controller.distance])
            if topic == scan:
                stamp = msg.header.stamp.to_sec()
                command = controller.on_scan(*scan_args(msg), stamp=stamp, now=now)
                if command is not None:
                    rows.append([now, stamp, command.v, command.w, command.state, controller.distance])
    if dropped:
        warnings.warn(f"{bag_path}: {len(dropped)} message(s) dropped as the node drops them (first: {dropped[0]})",
                      RuntimeWarning, stacklevel=2)
    with open(out, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        writer.writerows(rows)
    return len(rows)
