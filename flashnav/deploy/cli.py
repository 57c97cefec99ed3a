"""``flashnav deploy ros|sim-robot|replay``: run an exported policy on a ROS 1 robot, on the simulator
behind ROS topics, or over a recorded bag."""

from __future__ import annotations

import argparse
import math
import re
import sys

from flashnav.deploy.scan import Mount
from flashnav.names import DEFAULT_ROBOT, EVAL_SEED, GOAL_SAMPLINGS, ROBOT_HELP, seed_arg


def _floats(n: int, name: str):
    def parse(text: str) -> list[float]:
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != n or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{name} must be {n} comma-separated finite numbers, got {text!r}")
        return values
    return parse


#: a ROS 1 graph name (wiki.ros.org/Names): a letter, "/" or "~" first, then letters, digits, "_" and "/"
_ROS_NAME = re.compile(r"[A-Za-z/~][A-Za-z0-9_/]*")


def topic_name(text: str) -> str:
    """A topic flag's value, checked as a ROS 1 name before anything starts (rospy failed only once the node was up,
    in its own words, after the policy had loaded)."""
    if not _ROS_NAME.fullmatch(text) or "//" in text or text[-1] in "/~":
        raise argparse.ArgumentTypeError(f"{text!r} is not a ROS topic name (a letter, '/' or '~' first, then "
                                         "letters, digits, '_' and single '/'; e.g. /scan)")
    return text


def _topics(p: argparse.ArgumentParser, cmd: bool = True) -> None:
    p.add_argument("--scan", type=topic_name, default="/scan", help="sensor_msgs/LaserScan topic (default /scan)")
    p.add_argument("--odom", type=topic_name, default="/odom", help="nav_msgs/Odometry topic (default /odom)")
    p.add_argument("--goal", type=topic_name, default="/move_base_simple/goal",
                   help="geometry_msgs/PoseStamped goal topic, in the odometry frame (default /move_base_simple/goal)")
    p.add_argument("--people", type=topic_name, default="/people",
                   help="std_msgs/Float32MultiArray of tracked people, rows (x, y, vx, vy, radius) in the odometry "
                        "frame; read only for a policy trained with observation.agent_tracks (default /people)")
    if cmd:
        p.add_argument("--cmd", type=topic_name, default="/cmd_vel",
                       help="geometry_msgs/Twist command topic (default /cmd_vel)")
        p.add_argument("--status", type=topic_name, default="/flashnav_deploy/status",
                       help="std_msgs/String JSON status topic (default /flashnav_deploy/status)")


def _runtime_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lidar-pose", type=_floats(3, "--lidar-pose"), default=[0.0, 0.0, 0.0], metavar="X,Y,YAW",
                   help="the LiDAR's mounting in the base frame: metres, metres, radians (default 0,0,0)")
    p.add_argument("--lidar-flipped", action="store_true", help="the LiDAR is mounted upside down")
    p.add_argument("--fill", type=float, default=None, metavar="M",
                   help="range read by sectors the scan does not cover (default: the policy's max range)")
    p.add_argument("--timeout", type=float, default=0.3,
                   help="seconds after which a missing scan or odometry stops the robot (default 0.3)")
    p.add_argument("--rate", type=float, default=None,
                   help="control rate, Hz, at most 100 (default: the policy's, 1 / control_period_s = 10 for the "
                        "presets)")
    p.add_argument("--guide", type=float, default=None, metavar="LOOKAHEAD_M",
                   help="mapless guidance (flashnav/mapless.py): aim the policy at the point LOOKAHEAD_M metres along "
                        "a path planned on the walls this goal's scans have shown, not at the goal (e.g. 0.5; no map)")
    p.add_argument("--shield", type=float, default=None, metavar="SECONDS",
                   help="a people shield (flashnav/shield.py): each command is held SECONDS ahead against the people "
                        "of --people walking straight on, and a predicted contact replaces it with the nearest "
                        "command clear of them and of the scan (e.g. 2); the people topic must then be fresh")


def register_cli(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("deploy", help="run an exported policy on a ROS 1 robot (or the simulator behind ROS topics)")
    dsub = p.add_subparsers(dest="deploy_command", metavar="WHAT", required=True)

    q = dsub.add_parser("ros", help="the ROS 1 node: LaserScan + Odometry + goal -> Twist")
    q.add_argument("policy", metavar="POLICY", help="policy.onnx, or a run folder that holds one")
    _topics(q)
    _runtime_args(q)
    q.set_defaults(func=run_ros)

    q = dsub.add_parser("sim-robot", help="the simulator as a robot behind ROS 1 topics (closed-loop harness)")
    q.add_argument("--robot", default=DEFAULT_ROBOT, help=ROBOT_HELP)
    q.add_argument("--map", default=None, help="ROS map YAML or bundled map name (default: the robot's map)")
    q.add_argument("--episodes", type=int, default=0,
                   help="play the start/goal pairs of `flashnav eval --episodes N --seed S` (default 0: free running)")
    q.add_argument("--seed", type=seed_arg, default=EVAL_SEED,
                   help=f"start/goal sampling seed (default {EVAL_SEED}, as flashnav eval)")
    q.add_argument("--goal-sampling", default=None, choices=GOAL_SAMPLINGS,
                   help="goal band as straight line or path length (default: the robot preset's; geodesic is what "
                        "`flashnav eval --maps` plays, every goal reachable within the horizon)")
    q.add_argument("--start", type=_floats(3, "--start"), default=None, metavar="X,Y,YAW",
                   help="free running: the start pose (default: the first sampled start)")
    q.add_argument("--goal-at", type=_floats(2, "--goal-at"), default=None, metavar="X,Y",
                   help="free running: send this goal (odom frame) once at the start")
    q.add_argument("--duration", type=float, default=0.0, help="free running: wall seconds to run (default 0: forever)")
    q.add_argument("--scans-stop-after", type=float, default=None, metavar="SECONDS",
                   help="free running: stop the scan publisher for good this many seconds of the sim-robot's own clock "
                        "(simulated, or real with --real-time) after the start - a node's watchdog check that holds on "
                        "any machine speed (SIGUSR1 does the same at once)")
    q.add_argument("--stall", type=_floats(2, "--stall"), default=None, metavar="AT,WALL_S",
                   help="free running: at AT seconds of its own clock the sim-robot publishes nothing (/clock, "
                        "odometry, scans) for WALL_S wall seconds, then goes on: a simulator that hangs, at the same "
                        "point of the run on any machine speed (the stall does not count towards --duration)")
    q.add_argument("--real-time", action="store_true",
                   help="step once per control period of wall time (default: simulated /clock in lock step with the node)")
    q.add_argument("--answer-timeout", type=float, default=2.0,
                   help="lock step: wall seconds to wait for the node's answer to a scan (default 2)")
    q.add_argument("--results", default=None, metavar="FILE", help="write the outcomes as JSON")
    _topics(q)
    q.set_defaults(func=run_sim_robot)

    q = dsub.add_parser("replay", help="the commands a policy would have sent over a recorded ROS 1 bag")
    q.add_argument("bag", metavar="BAG", help="a ROS 1 bag with LaserScan and Odometry messages")
    q.add_argument("--policy", required=True, help="policy.onnx, or a run folder that holds one")
    q.add_argument("--out", required=True, metavar="FILE", help="CSV of the commands (t, v, w, state, distance)")
    q.add_argument("--goal-at", type=_floats(2, "--goal-at"), default=None, metavar="X,Y",
                   help="the goal (odom frame) when the bag has no goal messages")
    _topics(q, cmd=False)
    _runtime_args(q)
    q.set_defaults(func=run_replay)


def make_controller(args):
    """The runtime and controller for parsed `ros` / `replay` arguments."""
    from flashnav.deploy.controller import MAX_TIMEOUT, MIN_PERIOD, Controller
    from flashnav.deploy.runtime import PolicyRuntime

    # the flags first: loading the policy costs a session
    if args.rate is not None and not (math.isfinite(args.rate) and 0 < args.rate <= 1 / MIN_PERIOD):
        raise ValueError(f"--rate must be in (0, {1 / MIN_PERIOD:g}] Hz, got {args.rate}")
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= MAX_TIMEOUT):  # inf: never a stop when scans stop
        raise ValueError(f"--timeout must be in (0, {MAX_TIMEOUT:g}] seconds, got {args.timeout}")
    if args.fill is not None and not (math.isfinite(args.fill) and args.fill >= 0):
        raise ValueError(f"--fill must be a range in metres >= 0 (at most the policy's max range), got {args.fill}")
    if args.guide is not None and not (math.isfinite(args.guide) and args.guide > 0):
        raise ValueError(f"--guide must be > 0 metres, got {args.guide}")
    if args.shield is not None:
        from flashnav.shield import check_lookahead

        check_lookahead(args.shield, "--shield")
    x, y, yaw = args.lidar_pose
    try:
        rt = PolicyRuntime.load(args.policy, mount=Mount(x, y, yaw, args.lidar_flipped), fill=args.fill)
    except ValueError as exc:
        if args.fill is not None and str(exc).startswith("fill must be"):
            raise ValueError(f"--fill {args.fill}: {exc}") from None
        raise
    guide = None
    if args.guide is not None:
        from flashnav.mapless import ScanGuide

        guide = ScanGuide(footprint_radius(rt.meta), lookahead=args.guide)
    shield = None
    if args.shield is not None:
        from flashnav.export import recorded_robot
        from flashnav.shield import PeopleShield

        if "preset" not in rt.meta:
            raise ValueError(f"--shield needs the robot's preset (footprint, motion) in {args.policy}'s metadata")
        shield = PeopleShield(recorded_robot(rt.meta), lookahead=args.shield)
    return Controller(rt, timeout=args.timeout, period=None if args.rate is None else 1.0 / args.rate, guide=guide,
                      shield=shield)


def footprint_radius(meta: dict) -> float:
    """The circumscribed radius (m) of the robot in a policy's metadata (its preset's footprint)."""
    from flashnav.config import Footprint

    try:
        return Footprint.model_validate(meta["preset"]["footprint"]).circumscribed_radius
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"--guide needs the robot's footprint in the policy's metadata (preset.footprint: {exc})") from None


def run_ros(args) -> int:
    from flashnav.deploy.ros1 import DeployNode

    ctl = make_controller(args)
    node = DeployNode(ctl, scan=args.scan, odom=args.odom, goal=args.goal, cmd=args.cmd, status=args.status,
                      people=args.people)
    people = f" + {args.people}" if ctl.rt.agent_tracks or ctl.shield is not None else ""
    guided = "" if ctl.guide is None else f"; mapless guidance, carrots {args.guide:g} m along the path"
    guided += "" if ctl.shield is None else f"; people shield, {args.shield:g} s ahead"
    print(f"flashnav deploy ros: {args.policy} ({ctl.rt.meta.get('robot')}) at {1 / ctl.period:g} Hz: "
          f"{args.scan} + {args.odom} + {args.goal}{people} -> {args.cmd}{guided}", file=sys.stderr, flush=True)
    node.spin()
    return 0


def run_sim_robot(args) -> int:
    from flashnav.deploy import sim_robot
    from flashnav.outputs import check_output_file

    if args.episodes < 0:
        raise ValueError(f"--episodes must be >= 0, got {args.episodes}")
    if not (math.isfinite(args.duration) and args.duration >= 0):
        raise ValueError(f"--duration must be a finite number of seconds >= 0 (0: run until stopped), got "
                         f"{args.duration}")
    if not (math.isfinite(args.answer_timeout) and args.answer_timeout > 0):
        raise ValueError(f"--answer-timeout must be a finite number of seconds > 0, got {args.answer_timeout}")
    if args.scans_stop_after is not None and not (math.isfinite(args.scans_stop_after) and args.scans_stop_after >= 0):
        raise ValueError(f"--scans-stop-after must be a finite number of seconds >= 0, got {args.scans_stop_after}")
    if args.stall is not None and not (args.stall[0] >= 0 and args.stall[1] > 0):
        raise ValueError(f"--stall AT,WALL_S must have AT >= 0 and WALL_S > 0 seconds, got {args.stall}")
    free_flags = (("--start", args.start), ("--goal-at", args.goal_at), ("--duration", args.duration or None),
                  ("--scans-stop-after", args.scans_stop_after), ("--stall", args.stall))
    if args.episodes and (given := [flag for flag, value in free_flags if value is not None]):
        raise ValueError(f"{', '.join(given)} drive the free-running mode; with --episodes {args.episodes} the "
                         f"episodes' own starts, goals and horizons are played: drop one or the other")
    if args.results:
        check_output_file(args.results, "--results")
    sim_robot.run(args)
    return 0


def run_replay(args) -> int:
    from flashnav.deploy import replay
    from flashnav.outputs import check_output_file

    check_output_file(args.out, "--out", inputs=(args.bag, args.policy))
    n = replay.replay_bag(args.bag, make_controller(args), args.out, scan=args.scan, odom=args.odom,
                          goal=args.goal, goal_at=args.goal_at, people=args.people)
    print(f"flashnav deploy replay: {n} commands -> {args.out}")
    return 0
