"""The ROS 1 node: ROS messages <-> the ROS-free :class:`~flashnav.deploy.controller.Controller`.

Only message conversion and wiring live here (an rclpy node would be the same mapping). Topics:

* in: ``sensor_msgs/LaserScan`` (scan), ``nav_msgs/Odometry`` (pose in its ``header.frame_id``, the
  fixed frame), ``geometry_msgs/PoseStamped`` (goal, in the odometry's frame or with an empty frame);
* in, only for a policy with agent tracks (``observation.agent_tracks``): ``std_msgs/Float32MultiArray``
  (people), the people a tracker reports as rows of (x, y, vx, vy, radius) in the odometry's frame, m and
  m/s, flattened row by row (an empty array for nobody): a few lines of bridge turn a
  ``people_msgs/People`` or a SPENCER ``TrackedPersons`` message into it (neither package is in Debian);
* out: ``geometry_msgs/Twist`` (linear.x = v m/s, angular.z = w rad/s) and ``std_msgs/String`` with
  the controller's status as JSON.

Debian ships ROS 1 for its system python3 (/usr/lib/python3/dist-packages); the project's venv runs
its own CPython 3.11, so :func:`import_rospy` appends that directory at the *end* of ``sys.path``
(only when ROS is used, and only if ``rospy`` is not importable already): the venv's packages keep
precedence and only what the venv lacks (rospy, the message packages, rospkg) comes from Debian.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time

from flashnav.deploy.controller import Command, Controller
from flashnav.deploy.runtime import yaw_from_quaternion

#: where Debian's ROS 1 python packages live (override: FLASHNAV_ROS_PYTHONPATH, ':'-separated)
ROS_DIST_PACKAGES = "/usr/lib/python3/dist-packages"
#: wall seconds the shutdown hook waits after publishing the zero command: a rospy publisher with a queue_size
#: sends from a thread of its own, and the shutdown hooks that run next close its connections, so without the
#: wait the zero can be dropped and the robot keeps its last command (seen once in CI, 2026-11-28)
SHUTDOWN_FLUSH_S = 0.3
#: the shortest wall time, seconds, that a standing clock stops the robot after (the timeout if longer): a lock-step
#: simulator that takes a moment between the node's answer and its next /clock must not get a stop
FROZEN_MIN_S = 1.0
#: the Debian packages that provide what the node and the harness import
ROS_APT_PACKAGES = ("ros-core", "python3-rospy", "python3-sensor-msgs", "python3-geometry-msgs",
                    "python3-nav-msgs", "python3-rosbag")


class RosUnavailable(OSError):
    """ROS 1's python packages cannot be imported (an environment problem: exit 2, one line)."""


def import_rospy():
    """``rospy``, importing it from Debian's dist-packages when the venv does not have it."""
    try:
        import rospy
        return rospy
    except ImportError:
        pass
    for extra in os.environ.get("FLASHNAV_ROS_PYTHONPATH", ROS_DIST_PACKAGES).split(os.pathsep):
        if extra and os.path.isdir(extra) and extra not in sys.path:
            sys.path.append(extra)
    try:
        import rospy
        return rospy
    except ImportError as exc:
        raise RosUnavailable(f"ROS 1 (rospy) is not installed ({exc}); on Debian: apt-get install "
                             f"{' '.join(ROS_APT_PACKAGES)} (scripts/bootstrap.sh does this as root)") from None


def check_master(timeout: float = 3.0) -> None:
    """RosUnavailable unless something accepts connections at $ROS_MASTER_URI (rospy's own failure without a
    master is "Failed to initialize time" or a bare "Connection refused")."""
    import socket
    import urllib.parse

    uri = os.environ.get("ROS_MASTER_URI", "http://localhost:11311")
    parsed = urllib.parse.urlparse(uri)
    try:
        with socket.create_connection((parsed.hostname or "localhost", parsed.port or 11311), timeout=timeout):
            pass
    except (OSError, ValueError) as exc:
        raise RosUnavailable(f"no ROS master answers at {uri} (ROS_MASTER_URI; {getattr(exc, 'strerror', None) or exc}): "
                             "start roscore, or point ROS_MASTER_URI at the robot's master") from None


def scan_args(msg) -> tuple:
    """LaserScan -> (angle_min, angle_increment, ranges, range_min, range_max) for the runtime."""
    return msg.angle_min, msg.angle_increment, msg.ranges, msg.range_min, msg.range_max


def people_rows(msg) -> list[list[float]]:
    """Float32MultiArray -> rows of (x, y, vx, vy, radius); ValueError unless its length is a multiple of 5."""
    data = list(msg.data)
    if len(data) % 5:
        raise ValueError(f"people: {len(data)} values, not rows of 5 (x, y, vx, vy, radius)")
    return [data[i:i + 5] for i in range(0, len(data), 5)]


def odom_pose(msg) -> tuple[float, float, float]:
    """Odometry (or a PoseStamped's pose holder) -> (x, y, yaw) in its header's frame."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    q = pose.orientation
    return pose.position.x, pose.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)


class DeployNode:
    """The node: subscriptions feed the controller under one lock; a timer at 4x the control rate
    runs its watchdog; with ``/use_sim_time`` a thread watches on wall time that the clock moves
    (:meth:`_check_clock`); every decision is published with a status message."""

    def __init__(self, controller: Controller, *, scan: str, odom: str, goal: str, cmd: str, status: str,
                 people: str = "/people", name: str = "flashnav_deploy"):
        self.rospy = rospy = import_rospy()
        check_master()
        from geometry_msgs.msg import PoseStamped, Twist
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import LaserScan
        from std_msgs.msg import String

        self.Twist, self.String = Twist, String
        self.ctl, self.lock = controller, threading.Lock()
        # the clock watch's state (before any subscription: a callback reads it)
        self.wall, self.clock_seen, self.active = time.monotonic, None, time.monotonic()
        self.odom_frame = None
        self.goal_frame = None  # a goal's frame given before any odometry: checked against the first odometry
        rospy.init_node(name)
        self.cmd_pub = rospy.Publisher(cmd, Twist, queue_size=1, tcp_nodelay=True)
        self.status_pub = rospy.Publisher(status, String, queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(odom, Odometry, self._on_odom, queue_size=1, tcp_nodelay=True)
        rospy.Subscriber(goal, PoseStamped, self._on_goal, queue_size=1, tcp_nodelay=True)
        rospy.Subscriber(scan, LaserScan, self._on_scan, queue_size=1, tcp_nodelay=True)
        if controller.rt.agent_tracks or controller.shield is not None:  # people: for the policy or the shield
            from std_msgs.msg import Float32MultiArray

            rospy.Subscriber(people, Float32MultiArray, self._on_people, queue_size=1, tcp_nodelay=True)
        rospy.on_shutdown(self._on_shutdown)
        # reset=True: when ROS time moves backwards (a simulator restarts /clock) rospy's Timer raises
        # ROSTimeMovedBackwardsException in its thread and the thread ends - the watchdog with it - unless told to
        # start over on the new clock (the controller then forgets the old clock's times: Controller._clock)
        self.timer = rospy.Timer(rospy.Duration(controller.period / 4.0), self._on_tick, reset=True)
        # that timer runs on ROS time: with /use_sim_time and a /clock that stops, it never fires again, and every
        # input's age is read on the stopped clock, so a wall-time thread watches the clock itself (Controller.frozen)
        if rospy.get_param("/use_sim_time", False):
            threading.Thread(target=self._watch_clock, name="flashnav-clock-watch", daemon=True).start()

    def _now(self) -> float:
        return self.rospy.get_time()

    def _watch_clock(self) -> None:
        while not self.rospy.is_shutdown():
            time.sleep(self.ctl.timeout / 4.0)
            try:
                self._check_clock()
            except Exception as exc:  # noqa: BLE001 - the watch must outlive one failed look (a publish at shutdown)
                self.rospy.logerr_throttle(5.0, f"clock watch: {type(exc).__name__}: {exc}")

    def _check_clock(self) -> None:
        """Stop the robot when ROS time has not moved, and no scan has been answered, for the timeout (at least
        ``FROZEN_MIN_S``), wall seconds. Only answered scans count as the node being live: in lock step a simulator's
        clock stands still while it waits for the answer, and other inputs (odometry or people on a wall timer) would
        hold the stop off for good."""
        with self.lock:
            now, wall = self._now(), self.wall()
            if now != self.clock_seen:
                self.clock_seen, self.active = now, wall
                return
            if wall - self.active > max(self.ctl.timeout, FROZEN_MIN_S):
                command = self.ctl.frozen()
                if command is not None:
                    self.rospy.logwarn(f"robot stopped: ROS time has stood at {now:.3f} s for {wall - self.active:.2g} "
                                       "wall seconds with no scan answered (/use_sim_time is set: did the simulator or "
                                       "`rosbag play --clock` stop?)")
                    self._publish(command, now)

    def _publish(self, command: Command | None, now: float, **extra) -> None:
        """The command (if any), then the status; ``extra`` keys join the status (the scan's stamp and
        whether it was answered: what a lock-step simulator waits for)."""
        if command is not None:
            twist = self.Twist()
            twist.linear.x, twist.angular.z = command.v, command.w
            self.cmd_pub.publish(twist)
        self.status_pub.publish(self.String(data=json.dumps(self.ctl.status(now) | extra)))

    def _on_odom(self, msg) -> None:
        with self.lock:
            now = self._now()
            try:
                self.ctl.on_odom(*odom_pose(msg), now)
            except ValueError as exc:  # dropped: the odometry goes stale and the watchdog stops the robot
                self.rospy.logerr_throttle(5.0, f"odometry ignored: {exc}")
                return
            self.odom_frame = msg.header.frame_id
            if self.goal_frame is not None and self.goal_frame != self.odom_frame.lstrip("/"):
                self.rospy.logerr(f"goal dropped: frame {self.goal_frame!r}, but the odometry is in "
                                  f"{self.odom_frame!r} (send the goal in the odometry frame)")
                self._publish(self.ctl.cancel(now), now)
            self.goal_frame = None

    def _on_goal(self, msg) -> None:
        with self.lock:
            # a goal the node cannot use stops the robot (it was sent to go elsewhere) rather than being ignored
            frame, now = msg.header.frame_id.lstrip("/"), self._now()
            if frame and self.odom_frame is not None and frame != self.odom_frame.lstrip("/"):
                self.rospy.logerr(f"goal refused, robot stopped: frame {frame!r}, but the odometry is in "
                                  f"{self.odom_frame!r} (send the goal in the odometry frame)")
                self._publish(self.ctl.cancel(now), now)
                return
            try:
                self.ctl.on_goal(msg.pose.position.x, msg.pose.position.y, now)
            except ValueError as exc:
                self.rospy.logerr(f"goal refused, robot stopped: {exc}")
                self._publish(self.ctl.cancel(now), now)
                return
            if self.odom_frame is None:  # nothing to check its frame against yet: the first odometry does
                self.goal_frame = frame or None
            self._publish(None, now)

    def _on_people(self, msg) -> None:
        with self.lock:
            try:
                self.ctl.on_people(people_rows(msg), self._now())
            except ValueError as exc:  # a malformed message is dropped (the input goes stale), not fatal
                self.rospy.logerr(f"people message ignored: {exc}")

    def _on_scan(self, msg) -> None:
        with self.lock:
            if self.rospy.get_rostime().is_zero():  # no time yet: every age would read 0 and the timer never fires
                self.rospy.logwarn_once("scans ignored: ROS time is 0 (/use_sim_time is set and nothing publishes "
                                        "/clock: unset it on a real robot, or start the simulator)")
                return
            now = self._now()
            stamp = msg.header.stamp.to_sec()
            command = self.ctl.on_scan(*scan_args(msg), stamp=stamp, now=now)
            if command is not None and command.state == "fault":
                self.rospy.logerr_throttle(5.0, f"scan not usable, robot stopped: {self.ctl.fault}")
            self._publish(command, now, scan_stamp=stamp, answered=command is not None)
            if command is not None:
                self.active = self.wall()

    def _on_tick(self, _event) -> None:
        with self.lock:
            now = self._now()
            command = self.ctl.tick(now)
            if command is not None:
                self._publish(command, now)

    def _on_shutdown(self) -> None:
        with self.lock:
            self._publish(self.ctl.shutdown(), self._now())
        time.sleep(SHUTDOWN_FLUSH_S)  # let the publisher's thread send the zero before the connections close

    def spin(self) -> None:
        self.rospy.spin()
