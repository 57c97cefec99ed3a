"""``flashnav deploy sim-robot``: one environment of the simulator as a robot behind ROS 1 topics.

Publishes ``sensor_msgs/LaserScan`` (the raw beams, frame ``laser`` at the base origin, angles from
-fov/2 counter-clockwise at bin centres) and ``nav_msgs/Odometry`` (pose in frame ``odom`` = the map's
world frame, child ``base_link``, twist = the executed (v, w)) once per control period, and applies the
latest ``geometry_msgs/Twist`` received on the command topic (mapped back onto the action the
simulator integrates, so the preset's bounds and limits apply).

Two clocks:
* simulated (default): publishes ``/clock`` and runs in lock step with the node (``use_sim_time``):
  after each scan it waits for the node's status for that scan (and its command), then steps; runs as
  fast as the node answers. A node that does not answer within ``--answer-timeout`` wall seconds
  leaves the last command in force (the step still happens, and is counted as ``missed``).
* real time (``--real-time``): one step per period of wall time, the last command received in force.

With ``--episodes N`` it plays the N start/goal pairs that ``flashnav eval --episodes N --seed S``
plays (goal sent on the goal topic, frame ``odom``), each until the goal (< goal radius), a collision
or the horizon, and writes the outcomes to ``--results``. Without it, the robot waits at ``--start``
for goals sent by anyone (e.g. rviz). SIGUSR1 stops the scan publisher for good (the node's safety
check), as does ``--scans-stop-after S`` S seconds of its own clock after the start (the same point of the run on
any machine: in lock step a fast node covers more simulated time in a wall second); the results then hold how long
after the last scan the robot's command became zero. ``--stall AT,WALL_S`` has it publish nothing for WALL_S wall
seconds from AT seconds of its clock on: a simulator that hangs (its /clock stands still).
"""

from __future__ import annotations

import json
import math
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import torch

from flashnav.deploy.ros1 import check_master, import_rospy
from flashnav.deploy.scan import simulator_scan_fields


def episodes_of(robot, map_, n: int, seed: int, goal_sampling: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The (pose [n, 3], goal [n, 2]) world-frame pairs of ``flashnav eval --episodes n --seed seed``;
    ``goal_sampling`` (euclidean / geodesic) replaces the robot preset's."""
    from flashnav.presets import load_robot
    from flashnav.sim.env import make_env

    if goal_sampling is not None:
        robot = load_robot(robot, **{"episode.goal_sampling": goal_sampling})
    env = make_env(robot, n, map=map_, seed=seed)
    env.reset(seed=seed)
    return env.world_pose().numpy(), env.world_goal().numpy()


class SimRobot:
    def __init__(self, robot, map_, *, scan: str, odom: str, cmd: str, goal: str, status: str,
                 real_time: bool, answer_timeout: float = 2.0, people: str = "/people"):
        from flashnav.sim.env import make_env
        from flashnav.sim.tracks import TrackerView

        self.rospy = rospy = import_rospy()
        from geometry_msgs.msg import PoseStamped, Twist
        from nav_msgs.msg import Odometry
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import LaserScan
        from std_msgs.msg import Float32MultiArray, String

        self.msgs = dict(PoseStamped=PoseStamped, Odometry=Odometry, Clock=Clock, LaserScan=LaserScan,
                         People=Float32MultiArray)
        self.env = make_env(robot, 1, map=map_)
        # the people tracker a policy with agent tracks listens to: the agents the robot sees (none
        # without agents in the --robot preset), published before every scan
        self.view, self.people_state = TrackerView(self.env.preset, self.env.beam_angles), None
        self.preset, self.real_time, self.answer_timeout = self.env.preset, real_time, answer_timeout
        self.dt = self.preset.episode.dt
        self.t = 1.0  # simulated seconds (ROS time 0 means "no clock yet")
        self.cond = threading.Condition()
        self.cmd, self.cmd_count, self.cmd_times = (0.0, 0.0), 0, []
        self.answer: dict | None = None
        self.scan_on, self.scan_off_wall, self.scan_off_t = True, None, None
        self.stop_wall = self.stop_t = None
        self.last_scan_wall = self.command_at_scan_off = None
        check_master()
        if not real_time:
            rospy.set_param("/use_sim_time", True)
        rospy.init_node("flashnav_sim_robot", disable_signals=True)
        self.clock_pub = None if real_time else rospy.Publisher("/clock", Clock, queue_size=10, tcp_nodelay=True)
        self.scan_pub = rospy.Publisher(scan, LaserScan, queue_size=1, tcp_nodelay=True)
        self.odom_pub = rospy.Publisher(odom, Odometry, queue_size=1, tcp_nodelay=True)
        self.goal_pub = rospy.Publisher(goal, PoseStamped, queue_size=1, latch=True)
        self.people_pub = rospy.Publisher(people, Float32MultiArray, queue_size=1, tcp_nodelay=True)
        self.cmd_sub = rospy.Subscriber(cmd, Twist, self._on_cmd, queue_size=10, tcp_nodelay=True)
        self.status_sub = rospy.Subscriber(status, String, self._on_status, queue_size=100, tcp_nodelay=True)
        signal.signal(signal.SIGUSR1, lambda *_: self.scan_off())

    # ---- callbacks ------------------------------------------------------------------------------
    def _on_cmd(self, msg) -> None:
        with self.cond:
            self.cmd, self.cmd_count = (msg.linear.x, msg.angular.z), self.cmd_count + 1
            if self.scan_off_wall is not None and self.stop_wall is None and self.cmd == (0.0, 0.0):
                self.stop_wall, self.stop_t = time.monotonic(), self.t
            self.cond.notify_all()

    def _on_status(self, msg) -> None:
        with self.cond:
            self.answer = json.loads(msg.data)
            self.cond.notify_all()

    def scan_off(self) -> None:
        """Stop the scan publisher for good (from the next step on), remembering the command in force."""
        self.command_at_scan_off = self.cmd
        self.scan_on = False

    # ---- publishing -----------------------------------------------------------------------------
    def _stamp(self):
        return self.rospy.Time.from_sec(self.t) if not self.real_time else self.rospy.Time.now()

    def publish_clock(self) -> None:
        if self.clock_pub is not None:
            self.clock_pub.publish(self.msgs["Clock"](clock=self.rospy.Time.from_sec(self.t)))

    def publish_state(self) -> float:
        """Odometry then (unless switched off) the scan, stamped now; returns the stamp (s)."""
        stamp = self._stamp()
        pose = self.env.world_pose()[0].tolist()
        v, w = self.env.velocity[0].tolist()
        odom = self.msgs["Odometry"]()
        odom.header.stamp, odom.header.frame_id, odom.child_frame_id = stamp, "odom", "base_link"
        odom.pose.pose.position.x, odom.pose.pose.position.y = pose[0], pose[1]
        odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(pose[2] / 2), math.cos(pose[2] / 2)
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = v, w
        self.odom_pub.publish(odom)
        self.publish_people()
        if not self.scan_on and self.scan_off_wall is None:
            self.scan_pub.unregister()
            self.scan_off_wall, self.scan_off_t = time.monotonic(), self.t
        if self.scan_on:
            self.last_scan_wall = time.monotonic()
            fields = simulator_scan_fields(self.preset.lidar)
            scan = self.msgs["LaserScan"]()
            scan.header.stamp, scan.header.frame_id = stamp, "laser"
            scan.angle_increment, scan.angle_min = fields["angle_increment"], fields["angle_min"]
            scan.angle_max = scan.angle_min + (self.preset.lidar.beams - 1) * scan.angle_increment
            scan.scan_time, scan.range_min, scan.range_max = self.dt, fields["range_min"], fields["range_max"]
            scan.ranges = self.env.scan()[0].tolist()
            self.scan_pub.publish(scan)
        return stamp.to_sec()

    def publish_people(self) -> None:
        """The agents the robot sees now, as rows (x, y, vx, vy, radius) in the odometry frame."""
        from flashnav.sim.tracks import seen_world_rows

        env = self.env
        rows, self.people_state = seen_world_rows(self.view, env.agents, env.pose, env.scan(), self.people_state,
                                                  self.dt, env.frame_origin)
        self.people_pub.publish(self.msgs["People"](data=[v for row in rows for v in row]))

    def wait_for_node(self, timeout: float = 60.0) -> None:
        """Block (wall) until something subscribes to the scan, odometry and goal and publishes the
        command and status topics, so that no message of the first episode is lost."""
        deadline = time.monotonic() + timeout
        ends = [self.scan_pub, self.odom_pub, self.goal_pub, self.cmd_sub, self.status_sub]
        while not all(e.get_num_connections() > 0 for e in ends):
            if time.monotonic() > deadline:
                raise TimeoutError(f"no deploy node connected within {timeout:g} s (topics {[e.name for e in ends]}); "
                                   f"start one: flashnav deploy ros POLICY")
            time.sleep(0.05)

    def send_goal(self, goal) -> None:
        """Publish the goal (again every half second) until the node's status shows it."""
        msg = self.msgs["PoseStamped"]()
        msg.header.stamp, msg.header.frame_id = self._stamp(), "odom"
        msg.pose.position.x, msg.pose.position.y, msg.pose.orientation.w = float(goal[0]), float(goal[1]), 1.0
        deadline = time.monotonic() + 10 * self.answer_timeout
        with self.cond:
            self.answer = None
        while True:
            self.goal_pub.publish(msg)
            with self.cond:
                self.cond.wait_for(lambda: _same_goal(self.answer, goal), timeout=0.5)
                if _same_goal(self.answer, goal):
                    return
            if time.monotonic() > deadline:
                raise RuntimeError(f"the node did not acknowledge goal {list(goal)} on its status topic")

    # ---- stepping -------------------------------------------------------------------------------
    def _wait_answer(self, stamp: float, count_before: int) -> bool:
        """Lock step: the node's status for the scan stamped ``stamp`` and, if it answered, its command."""
        deadline = time.monotonic() + self.answer_timeout
        with self.cond:
            def ready():
                a = self.answer
                if a is None or a.get("scan_stamp") is None or abs(a["scan_stamp"] - stamp) > 1e-6:
                    return False
                return not a.get("answered") or self.cmd_count > count_before
            while not ready():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(left)
            return True

    def step(self) -> dict:
        """One control period: publish, wait for (or let time pass for) the command, integrate."""
        if self.real_time:
            t0 = time.monotonic()
            self.publish_state()
            time.sleep(max(0.0, self.dt - (time.monotonic() - t0)))
            answered = True
        else:
            self.publish_clock()
            with self.cond:
                before = self.cmd_count
            stamp = self.publish_state()
            answered = self._wait_answer(stamp, before) if self.scan_on else True
        with self.cond:
            v, w = self.cmd
        out = self.env.step_slots(torch.tensor([0]), torch.from_numpy(self._action(v, w))[None])
        self.t = round(self.t + self.dt, 9)
        self.publish_clock()
        return {k: bool(out[k][0]) for k in ("success", "collision", "terminated", "truncated")} | {"answered": answered}

    def _action(self, v: float, w: float) -> np.ndarray:
        """(v, w) -> the action in [-1, 1] whose command it is (the preset's linear map, inverted)."""
        m = self.preset.motion
        (v_lo, v_hi), (w_lo, w_hi) = m.v_bounds, m.w_bounds
        a = [(v - v_lo) / (0.5 * (v_hi - v_lo)) - 1.0, (w - w_lo) / (0.5 * (w_hi - w_lo)) - 1.0]
        return np.clip(np.array(a, np.float32), -1.0, 1.0)

    def run_episode(self, pose, goal) -> dict:
        self.env.set_state(torch.tensor(pose, dtype=torch.float64)[None], torch.tensor(goal, dtype=torch.float64)[None])
        self.people_state = None  # a new episode: the tracker starts afresh, as in the simulator
        with self.cond:
            self.cmd = (0.0, 0.0)
        self.publish_clock()
        self.send_goal(goal)
        wall0, missed = time.monotonic(), 0
        for k in range(self.preset.episode.horizon):
            r = self.step()
            missed += not r["answered"]
            if r["terminated"] or r["truncated"]:
                break
        outcome = "success" if r["success"] else "collision" if r["collision"] else "timeout"
        return {"start": list(map(float, pose)), "goal": list(map(float, goal)), "outcome": outcome,
                "steps": k + 1, "missed_answers": missed, "wall_s": round(time.monotonic() - wall0, 3)}

    def scan_stop_report(self) -> dict | None:
        if self.scan_off_wall is None:
            return None
        waited = None if self.stop_wall is None else self.stop_wall - self.scan_off_wall
        since_scan = None if self.stop_wall is None else self.stop_wall - self.last_scan_wall
        return {"stopped": self.stop_wall is not None, "wall_s_to_zero_command": waited,
                "wall_s_from_last_scan_to_zero_command": since_scan,
                "sim_s_to_zero_command": None if self.stop_t is None else round(self.stop_t - self.scan_off_t, 6),
                "command_before": list(self.command_at_scan_off),
                "command_now": list(self.cmd), "velocity_now": self.env.velocity[0].tolist()}


def _same_goal(status: dict | None, goal) -> bool:
    g = None if status is None else status.get("goal")
    return g is not None and abs(g[0] - float(goal[0])) < 1e-6 and abs(g[1] - float(goal[1])) < 1e-6


def run(args) -> dict:
    """The ``flashnav deploy sim-robot`` job (parsed arguments: see :mod:`flashnav.deploy.cli`)."""
    robot = SimRobot(args.robot, args.map, scan=args.scan, odom=args.odom, cmd=args.cmd, goal=args.goal,
                     status=args.status, real_time=args.real_time, answer_timeout=args.answer_timeout,
                     people=args.people)
    robot.publish_clock()
    if args.episodes or args.goal_at is not None:
        print(f"flashnav deploy sim-robot: waiting up to 60 s for a deploy node on {args.scan}, {args.odom}, "
              f"{args.goal} -> {args.cmd}", file=sys.stderr, flush=True)
        robot.wait_for_node()
    report: dict = {"clock": "real" if args.real_time else "simulated", "robot": robot.preset.name,
                    "map": robot.env.map.name}
    if args.episodes:
        poses, goals = episodes_of(args.robot, args.map, args.episodes, args.seed, args.goal_sampling)
        results = []
        for pose, goal in zip(poses, goals):
            results.append(robot.run_episode(pose, goal))
            print(f"episode {len(results):3d}: {results[-1]['outcome']:9s} in {results[-1]['steps']:3d} steps "
                  f"({results[-1]['wall_s']:.2f} s wall)", flush=True)
        report |= {"episodes": results, "seed": args.seed,
                   "success_rate": sum(r["outcome"] == "success" for r in results) / len(results)}
    else:
        pose = args.start or [float(v) for v in episodes_of(args.robot, args.map, 1, args.seed, args.goal_sampling)[0][0]]
        goal = args.goal_at if args.goal_at is not None else pose[:2]
        try:
            robot.env.set_state(torch.tensor([pose], dtype=torch.float64), torch.tensor([goal], dtype=torch.float64))
        except ValueError as exc:  # the goal defaults to the start: name the flag the user gave
            flag = "--goal-at" if args.goal_at is not None and "goal" in str(exc) else "--start"
            raise ValueError(f"{flag}: {exc}") from None
        robot.publish_clock()
        if args.goal_at is not None:
            robot.send_goal(args.goal_at)
            print(f"goal acknowledged: {args.goal_at}", flush=True)
        end = math.inf if not args.duration else time.monotonic() + args.duration
        scans_off_at = None if args.scans_stop_after is None else robot.t + args.scans_stop_after
        stall_at, stall_s = (None, 0.0) if args.stall is None else (robot.t + args.stall[0], args.stall[1])
        while time.monotonic() < end and not robot.rospy.is_shutdown():
            if scans_off_at is not None and robot.scan_on and robot.t >= scans_off_at - 1e-9:
                robot.scan_off()
            if stall_at is not None and robot.t >= stall_at - 1e-9:
                print(f"stalled at {robot.t:.3f} s (its clock) for {stall_s:g} wall seconds", flush=True)
                stall_at, end = None, end + stall_s
                time.sleep(stall_s)
                print("going on after the stall", flush=True)
            robot.step()
        report |= {"final_pose": robot.env.world_pose()[0].tolist(), "commands_received": robot.cmd_count,
                   "command_now": list(robot.cmd), "velocity_now": robot.env.velocity[0].tolist()}
    report["scan_stop"] = robot.scan_stop_report()
    if args.results:
        Path(args.results).parent.mkdir(parents=True, exist_ok=True)  # checked creatable before the run
        Path(args.results).write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    robot.rospy.signal_shutdown("done")
    return report
