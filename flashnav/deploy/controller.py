"""The deploy node's logic without ROS: inputs with their times in, commands and a status out.

A ROS node (``flashnav/deploy/ros1.py``; an rclpy node would be the same few lines), the bag replayer
and the tests all drive this one state machine, so the safety behaviour is written and tested once:

* ``idle``: no goal yet; nothing is commanded.
* ``driving``: a goal is set and the inputs are fresh: each scan at least ``0.8 * period`` (by its
  stamp) after the last control step runs the policy, and its command is sent. A scan stamped more than
  ``timeout`` before the last control step's scan is due too (the scanner's clock restarted).
* ``stale``: the latest scan or odometry arrived more than ``timeout`` seconds ago: zero velocity, sent again
  on every :meth:`tick`; driving resumes with fresh inputs.
* ``blind``: the latest scan had not one valid reading in the policy's field of view (NaN, 0 or below
  ``range_min``: a dead or covered sensor, which the policy would see as open space; only ``-inf``, too close;
  or no beam in the field of view): zero velocity, sent for every such scan; the next scan with a valid reading
  drives again.
* ``fault``: the latest due scan could not be read (no ranges, angles or range limits that are not a scan's),
  or its observation could not be made (:attr:`fault` says why): zero velocity, sent for every such scan; the
  next readable scan drives again.
* ``stuck``: a command other than zero has been in force for ``timeout`` seconds without a control step while
  the inputs kept arriving (scans whose stamps do not advance - a driver that leaves them at 0 or republishes
  one scan - or anything else that keeps every scan from acting): zero velocity, sent again on every
  :meth:`tick`; the next control step drives again. The watchdog's own backstop: before, the scans counted
  as fresh by their arrival and the last command stayed in force.
* ``frozen``: the node saw its clock stand still (simulated time, ``/use_sim_time``, and nothing advancing
  ``/clock``: a simulator or ``rosbag play --clock`` that died) with no scan answered, for ``timeout`` (at least 1 s)
  wall seconds (:meth:`frozen`): zero velocity, sent once, if a command other than zero is in force (the one sent
  last, whatever a new goal did to the velocity state); the next due scan drives again. Every age is measured on
  that clock, so the watchdog above never saw a stale input: the last command stayed in force.
* ``reached``: within the goal radius: zero velocity, sent once; a new goal starts driving again.
* ``stopped``: :meth:`shutdown`: zero velocity; nothing after it.

The clock moving backwards (an input's time earlier than one seen before by more than ``CLOCK_SLACK``: a
simulator restarted its /clock, a bag looped, the wall clock was stepped back) puts every time the controller
holds on the old clock: they are forgotten, with the pose and what was remembered since the goal (history,
trail, memory, wall map, the guide's walls), a zero is sent once (state ``clock``, by the next :meth:`tick` or
scan) if a command may be in force, and the controller is ``stale`` until fresh inputs arrive; the goal stays
(a new goal sent just before the node's clock caught up would otherwise be lost). Before, scans were ignored as
not due until their stamps caught up with the old clock, and the ages came out negative, i.e. fresh: the last
command stayed in force, unwatched, for as long as the clock had jumped.

The velocity state given to the policy is the command the controller sent last (what the simulator
calls the executed command; a stop counts as (0, 0)); a new goal starts from the robot's measured
velocity being unknown, so from (0, 0) as in the simulator's episodes.

A policy with a scan history (``observation.scan_history`` k > 0, :mod:`flashnav.sim.history`) gets the
sectors of the k previous control steps (only the scans that ran a step count: one frame per control
period, as one per env step in the simulator). Like the simulator's new episode, the first control
step after a new goal - or after any stop (stale, reached), which also zeroes the velocity state -
sees its own scan in every history frame.
A policy with agent tracks (``observation.agent_tracks`` M > 0, :mod:`flashnav.sim.tracks`) also needs
the people a tracker reports (:meth:`Controller.on_people`: rows of (x, y, vx, vy, radius) in the
odometry's fixed frame, an empty list for nobody); each control step turns them into the robot frame
of the current pose. For such a policy the people input is one more input that must be fresh: a
tracker that falls silent for ``timeout`` stops the robot like a silent scanner does.
A policy with a pose trail (``observation.pose_trail`` P > 0, :mod:`flashnav.sim.trail`) gets the robot's
own earlier positions from the odometry pose: every breadcrumb is the goal's first control step's pose at
first, and after every ``trail_every``-th control step since the goal that step's pose becomes the newest
(as the simulator's episode steps). Only a new goal restarts the trail: a stop (stale) does not change
where the robot has been.
A policy with a memory scan (``observation.memory_frames`` F > 0, :mod:`flashnav.sim.memory`) gets it from
:class:`flashnav.deploy.memory.ScanMemory`: the goal's first control step's scan is stored, then that of
every ``memory_every``-th control step since the goal (its wall hits in the odometry frame, the last F
kept); only a new goal forgets them.
A policy with a wall map (``observation.wall_map`` C > 0, :class:`flashnav.sim.wall_grid.WallGrid`) gets it from
:class:`flashnav.deploy.memory.WallCells`: every beam's return of every control step since the goal marks a cell of
the policy's grid in the odometry frame, and the marked cells' centres are drawn as the C x C squares around the
robot with the goal's square (the target's, with guidance), and, with a visited channel, the cells its odometry pose
has been in at the control steps since the goal; only a new goal forgets them.
With a ``shield`` (:class:`flashnav.shield.PeopleShield`: a people shield, ``flashnav deploy ros --shield S``) every
command the policy gives is checked against the tracker's people (:meth:`Controller.on_people`), each walking straight
on, and the scan's points, and only a predicted contact with a person replaces it (:func:`flashnav.shield.robot_command`);
the people input is then one more input that must be fresh, whatever the policy observes. The shield is the one part
of the node that needs torch (imported only with it).
With a ``guide`` (:class:`flashnav.mapless.ScanGuide`: mapless guidance, ``flashnav deploy ros --guide M``)
the policy is not aimed at the goal but, at every control step, at a point M metres along a path planned
on the walls this goal's scans have shown so far (its memory starts afresh with every goal; no map); the
goal radius and the status are still about the goal itself.
Times are seconds on one clock (ROS time: wall or simulated).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from flashnav.deploy.memory import ScanMemory, WallCells
from flashnav.deploy.runtime import PolicyRuntime, robot_frame
from flashnav.mapless import ScanGuide

#: a scan triggers a control step when its stamp is at least this fraction of the period after the
#: last one: a 10 Hz policy on a 40 Hz scanner acts on every 4th scan despite stamp jitter
DUE_FRACTION = 0.8
#: the longest watchdog timeout, seconds (a robot driving on for longer without news is not being watched)
MAX_TIMEOUT = 10.0
#: the shortest control period, seconds (100 Hz): a step needs a scan of its own (2D LiDARs scan at 5-50 Hz), and the
#: watchdog's timer runs at 4x the rate (1 MHz asked for had it spin a core)
MIN_PERIOD = 0.01
#: seconds an input's time may lie before the latest time seen (callbacks of several threads read the clock
#: and then wait for the lock) before it counts as the clock moving backwards (state ``clock``)
CLOCK_SLACK = 0.05


@dataclass(frozen=True)
class Command:
    """(v m/s, w rad/s) to publish, and why (the state that produced it)."""

    v: float
    w: float
    state: str


class Controller:
    """See the module docstring. ``timeout`` seconds: the largest input age that still drives."""

    def __init__(self, runtime: PolicyRuntime, timeout: float = 0.5, period: float | None = None,
                 guide: ScanGuide | None = None, shield=None):
        if not (math.isfinite(timeout) and 0 < timeout <= MAX_TIMEOUT):
            raise ValueError(f"timeout must be in (0, {MAX_TIMEOUT:g}] s, got {timeout}")
        self.rt, self.timeout, self.guide, self.shield = runtime, float(timeout), guide, shield
        self.shielded = 0  # control steps whose command the shield replaced
        self.carrot: tuple[float, float] | None = None  # the guide's latest point
        self.period = runtime.control_period if period is None else float(period)
        if not (math.isfinite(self.period) and self.period >= MIN_PERIOD):
            raise ValueError(f"the control period must be at least {MIN_PERIOD:g} s ({1 / MIN_PERIOD:g} Hz), got "
                             f"{self.period:g} s")
        if self.period >= self.timeout:  # (a slower rate would stop the robot between every two steps: stuck)
            raise ValueError(f"the control period {self.period:g} s (--rate {1 / self.period:g} Hz) must be shorter "
                             f"than the timeout {self.timeout:g} s (--timeout): raise one of them")
        self.state = "idle"
        self.goal: tuple[float, float] | None = None
        self.pose: tuple[float, float, float] | None = None
        self.odom_time = self.scan_time = self.people_time = -math.inf
        self.latest = -math.inf  # the latest input time seen (a time well before it: the clock moved backwards)
        self.clock_jumps, self.owed_stop = 0, False  # backward jumps seen; a zero owed since the last one
        self.people = np.zeros((0, 5))  # the tracker's latest people, fixed frame
        self.last_step_stamp = -math.inf
        self.step_time = -math.inf  # when the last control step ran (the ``stuck`` backstop's clock)
        self.fault: str | None = None  # why the last due scan could not be read (state ``fault``)
        self.slow_scans_warned = False
        self.velocity = (0.0, 0.0)
        self.in_force = (0.0, 0.0)  # the command sent last (the velocity state is zeroed by a goal, the robot is not)
        self.distance = math.nan
        self.last_action: list[float] | None = None
        self.last_obs: np.ndarray | None = None  # the observation of the last control step
        self.frames: list[np.ndarray] = []  # sectors of the previous control steps, newest first
        self.crumbs: list[tuple[float, float]] = []  # the pose trail, newest first (empty: a new goal)
        self.goal_steps = 0  # control steps since the goal (the pose trail's and the memory's clock)
        self.steps = 0
        rt = runtime
        self.memory = (ScanMemory(rt.memory_frames, rt.memory_every, rt.layout.sectors, rt.memory_points,
                                  rt.layout.fov_deg, rt.layout.max_range) if rt.memory_frames else None)
        self.walls = (WallCells(rt.wall_map, rt.wall_cell, rt.wall_grid, rt.layout.max_range, rt.wall_beyond,
                                visited="visited" in rt.wall_channel_names, plan="plan" in rt.wall_channel_names,
                                plan_penalty=rt.plan_penalty, carrot=rt.carrot)
                      if rt.wall_map else None)

    # ---- inputs ---------------------------------------------------------------------------------
    def on_goal(self, x: float, y: float, now: float) -> None:
        """A new goal (same frame as the odometry pose)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"goal ({x}, {y}) is not finite")
        self._clock(now)
        if self.state == "stopped":
            return
        self.goal, self.velocity, self.last_step_stamp = (float(x), float(y)), (0.0, 0.0), -math.inf
        self.state, self.frames, self.crumbs, self.goal_steps = "driving", [], [], 0
        if self.memory is not None:
            self.memory.forget()
        if self.walls is not None:
            self.walls.forget()
        if self.guide is not None:
            self.guide.start(self.goal)
            self.carrot = None

    def on_odom(self, x: float, y: float, yaw: float, now: float) -> None:
        """The odometry pose (fixed frame). ValueError for a pose that is not finite: it is dropped, so the
        odometry goes stale and stops the robot unless a good one follows."""
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            raise ValueError(f"odometry pose ({x}, {y}, {yaw}) is not finite")
        self._clock(now)
        self.pose, self.odom_time = (float(x), float(y), float(yaw)), float(now)

    def on_people(self, people, now: float) -> None:
        """The people a tracker reports: rows of (x, y, vx, vy, radius) in the odometry's frame, m and
        m/s (an empty list when it sees nobody). Raises ValueError naming ``people`` for another shape or
        a value that is not finite."""
        rows = np.asarray(people, np.float64)
        rows = rows.reshape(0, 5) if rows.size == 0 else rows
        if rows.ndim != 2 or rows.shape[1] != 5 or not np.isfinite(rows).all():
            raise ValueError(f"people must be finite rows of (x, y, vx, vy, radius), got shape {list(rows.shape)}")
        self._clock(now)
        self.people, self.people_time = rows, float(now)

    def on_scan(self, angle_min: float, angle_increment: float, ranges, range_min: float, range_max: float,
                stamp: float, now: float) -> Command | None:
        """A scan (``stamp``: its header time; ``now``: when it arrived). Returns the command to send, if any."""
        self._clock(now)
        gap, self.scan_time = float(now) - self.scan_time, float(now)
        if self.timeout < gap < math.inf and self.goal is not None and not self.slow_scans_warned:
            self.slow_scans_warned = True  # (stale between every two scans: stop and go, with no other sign)
            warnings.warn(f"scans {gap:.3g} s apart, more than the timeout {self.timeout:g} s: the robot stops between "
                          "them (a slow or stalling scanner; raise --timeout if it is that slow)", RuntimeWarning,
                          stacklevel=2)
        if self.owed_stop:
            return self._owed()
        if self.state in ("idle", "stopped", "reached"):
            return None
        if stamp < self.last_step_stamp - self.timeout:  # the scanner's stamps went back (its clock restarted, a bag
            self.last_step_stamp = -math.inf  # looped without /clock): due now, or none is until they catch up
        if stamp < self.last_step_stamp + DUE_FRACTION * self.period:
            return None
        if self._stale(now):
            return self._stop("stale")
        try:
            sectors = self.rt.scan(angle_min, angle_increment, ranges, range_min, range_max)
        except ValueError as exc:  # raised out of the callback, it left the last command in force
            self.fault = str(exc)
            return self._stop("fault")
        self.fault = None
        if self.rt.adapter.no_valid_reading:  # a dead or covered sensor would read as open space
            return self._stop("blind")
        target, goal_distance, memory, walls = self.goal, None, None, None
        if self.guide is not None or self.memory is not None or self.walls is not None or self.shield is not None:
            angles, beams = self.rt.adapter.beams(angle_min, angle_increment, ranges, range_min, range_max)
        if self.guide is not None:
            goal_distance = self.rt.goal_in_robot_frame(self.pose, self.goal)[0]
            if goal_distance < self.rt.goal_threshold:
                return self._stop("reached")  # the goal itself, whatever the carrot
            self.carrot = self.guide.step(self.pose, angles, beams, self.rt.layout.max_range)
            if self.rt.goal_in_robot_frame(self.pose, self.carrot)[0] > self.rt.goal_threshold + 1e-3:
                target = self.carrot  # (a carrot at the goal radius would read as arrived: aim at the goal)
        if self.memory is not None:
            memory = self.memory.step(self.pose, angles, beams, self.goal_steps)
        if self.walls is not None:  # the goal's square is the target's (a carrot with guidance)
            walls = self.walls.step(self.pose, angles, beams, target)
        try:
            d = self.rt.decide(sectors, self.pose, target, self.velocity, self._history(sectors), self._tracks(),
                               self._trail(), memory, walls, self.walls.carrot_xy if self.walls is not None else None)
        except ValueError as exc:  # (an observation that is not finite, say): stopped, not the last command kept
            self.fault = str(exc)
            return self._stop("fault")
        self.last_step_stamp, self.steps, self.goal_steps = float(stamp), self.steps + 1, self.goal_steps + 1
        self.step_time = float(now)
        self.last_obs = d.obs
        self.distance = d.distance if target is self.goal else goal_distance
        self.last_action = None if d.action is None else [float(a) for a in np.asarray(d.action)]
        if d.state == "reached":
            return self._stop("reached")
        v, w = d.v, d.w
        if self.shield is not None:
            from flashnav.shield import robot_command

            sv, sw, overruled, played = robot_command(self.shield, d.action, self.pose, self.people, angles, beams)
            if overruled:  # else the policy's own command, as it came from the network
                v = min(max(sv, -self.rt.v_limit), self.rt.v_limit)
                w = min(max(sw, -self.rt.w_limit), self.rt.w_limit)
                self.shielded += 1
                self.last_action = played
        self.state, self.velocity, self.in_force = "driving", (v, w), (v, w)
        return Command(v, w, "driving")

    def tick(self, now: float) -> Command | None:
        """The watchdog, called often (e.g. 4x the control rate): zero velocity while inputs are stale."""
        self._clock(now)
        if self.owed_stop:
            return self._owed()
        if self.state in ("driving", "stale", "blind", "fault", "stuck", "frozen") and self._stale(now):
            return self._stop("stale")
        if self.state == "stuck" or (self.state == "driving" and self.in_force != (0.0, 0.0)
                                     and now - self.step_time > self.timeout):
            return self._stop("stuck")
        if self.state == "stale":  # fresh again: the next due scan drives
            self.state = "driving"
        return None

    def frozen(self) -> Command | None:
        """The node's clock has stood still, with no scan answered, for ``timeout`` (at least 1 s) wall seconds
        (state ``frozen``, :meth:`flashnav.deploy.ros1.DeployNode._check_clock`): zero velocity if a command other
        than zero is in force (the zero owed since a backward jump of the clock, if one is: no tick or scan will come
        to send it), else nothing."""
        if self.owed_stop:
            return self._owed()
        if self.in_force != (0.0, 0.0) and self.state != "stopped":
            return self._stop("frozen")
        return None

    def cancel(self, now: float) -> Command:
        """Drop the goal (the node: a goal whose frame turned out not to be the odometry's): zero velocity, idle
        until a new goal."""
        self._clock(now)
        self.goal, self.carrot, self.distance = None, None, math.nan
        return Command(0.0, 0.0, "stopped") if self.state == "stopped" else self._stop("idle")

    def shutdown(self) -> Command:
        return self._stop("stopped")

    # ---- helpers --------------------------------------------------------------------------------
    def _clock(self, now: float) -> None:
        """Every input's time passes here first: one well before the latest seen is the clock moving backwards
        (module docstring, state ``clock``)."""
        now = float(now)
        if now >= self.latest - CLOCK_SLACK:
            self.latest = max(self.latest, now)
            return
        self.latest, self.clock_jumps = now, self.clock_jumps + 1
        self.odom_time = self.scan_time = self.people_time = self.last_step_stamp = self.step_time = -math.inf
        if self.state in ("driving", "stale", "blind", "fault", "stuck"):  # a command other than zero may be in force
            self.owed_stop, self.state = True, "stale"
        self.pose, self.carrot, self.distance = None, None, math.nan
        self.velocity, self.frames, self.crumbs, self.goal_steps = (0.0, 0.0), [], [], 0
        if self.memory is not None:
            self.memory.forget()
        if self.walls is not None:
            self.walls.forget()
        if self.guide is not None and self.goal is not None:
            self.guide.start(self.goal)

    def _owed(self) -> Command:
        """The zero owed since the clock moved backwards (the state stays)."""
        self.owed_stop, self.velocity, self.in_force = False, (0.0, 0.0), (0.0, 0.0)
        return Command(0.0, 0.0, "clock")

    def _stale(self, now: float) -> bool:
        return (self.pose is None or now - self.scan_time > self.timeout or now - self.odom_time > self.timeout
                or ((self.rt.agent_tracks > 0 or self.shield is not None) and now - self.people_time > self.timeout))

    def _tracks(self) -> np.ndarray | None:
        """The tracker's people in the robot frame of the current pose (None for a policy without tracks)."""
        if not self.rt.agent_tracks:
            return None
        p = self.people
        return np.concatenate([robot_frame(p[:, :2], self.pose), robot_frame(p[:, 2:4], (0.0, 0.0, self.pose[2])),
                               p[:, 4:5]], axis=1)

    def _stop(self, state: str) -> Command:
        self.state, self.velocity, self.in_force, self.frames = state, (0.0, 0.0), (0.0, 0.0), []
        self.owed_stop = False  # (this is the zero: none owed after it, nor after `stopped`)
        return Command(0.0, 0.0, state)

    def _history(self, sectors: np.ndarray) -> np.ndarray | None:
        """The previous frames [k, S] for this control step (None without a scan history), then
        ``sectors`` becomes the newest frame. A fresh start repeats ``sectors`` k times."""
        k = self.rt.scan_history
        if not k:
            return None
        past = self.frames or [sectors] * k
        self.frames = [sectors, *past[:-1]]
        return np.stack(past)

    def _trail(self) -> np.ndarray | None:
        """The breadcrumbs [P, 2] (odometry frame, newest first) for this control step (None without a
        pose trail): the current pose repeated at the goal's first step, then the pose of every
        ``trail_every``-th step since the goal pushed in front."""
        p = self.rt.pose_trail
        if not p:
            return None
        here = (self.pose[0], self.pose[1])
        if not self.crumbs:
            self.crumbs = [here] * p
        elif self.goal_steps % self.rt.trail_every == 0:
            self.crumbs = [here, *self.crumbs[:-1]]
        return np.asarray(self.crumbs, np.float64)

    def status(self, now: float) -> dict:
        """What the node publishes on its status topic (JSON)."""
        dist = self.distance
        if self.goal is not None and self.pose is not None:
            dist, _ = self.rt.goal_in_robot_frame(self.pose, self.goal)
        return {"state": self.state, "distance": None if math.isnan(dist) else round(dist, 4),
                "goal": None if self.goal is None else list(self.goal),
                "carrot": None if self.carrot is None else [round(c, 4) for c in self.carrot],
                "command": list(self.velocity), "action": self.last_action, "steps": self.steps,
                "shielded": self.shielded if self.shield is not None else None, "clock_jumps": self.clock_jumps,
                "fault": self.fault,
                "scan_age": _age(now, self.scan_time), "odom_age": _age(now, self.odom_time),
                "people_age": _age(now, self.people_time),
                "last_step_stamp": None if math.isinf(self.last_step_stamp) else self.last_step_stamp}


def _age(now: float, t: float) -> float | None:
    return None if math.isinf(t) else round(now - t, 4)
