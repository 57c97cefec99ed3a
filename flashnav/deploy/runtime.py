"""Run an exported policy (policy.onnx) on a robot: numpy + onnxruntime, no torch.

```python
rt = PolicyRuntime.load("policy.onnx", mount=Mount(yaw=0.0))
sectors = rt.scan(angle_min, angle_increment, ranges, range_min, range_max)       # [S] float32, metres
d = rt.decide(sectors, pose=(x, y, yaw), goal=(gx, gy), velocity=(v, w))          # pose/goal: one frame
d.state, d.v, d.w                                                                   # "driving" | "reached"
```

The observation is the simulator's (``flashnav/sim/env.py``): the pooled sectors, the goal distance
(m) and angle (rad, robot frame, [-pi, pi), positive = left), then the velocity state, the command
executed in the last control step (``(v, w)``; ``(vx, 0, w)`` for a 3-D velocity state), then, for
a policy trained with ``observation.scan_history`` k > 0, the sectors of the k previous control steps
(newest first; ``history`` [k, S], kept by :class:`flashnav.deploy.controller.Controller`), then, for a
policy trained with ``observation.agent_tracks`` M > 0, the M nearest people a tracker reports
(``tracks``: rows of (x, y, vx, vy, radius) in the robot frame, m and m/s; :func:`track_columns`), then,
for a policy trained with ``observation.pose_trail`` P > 0, the robot's own P earlier positions
(``trail`` [P, 2], x and y in the same fixed frame as the pose, newest first, one every ``trail_every``
control steps; kept by the controller; :mod:`flashnav.sim.trail`), which the runtime turns into the
robot frame, then, for a policy trained with ``observation.wall_map_carrot`` L > 0, the point L m of path along the
wall map's plan (``carrot`` [2], x and y m in the robot frame: :attr:`flashnav.deploy.memory.WallCells.carrot_xy`,
which the controller keeps), then the memory scan and the wall map (``memory``, ``wall_map``).
The network holds its own input scaling, so the runtime passes physical units. Inside the goal radius
the runtime commands (0, 0) without running the network.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flashnav.deploy.scan import Mount, ScanAdapter, SectorLayout
from flashnav.maps.seen_plan import PLAN_MARGIN_M
from flashnav.policy_meta import (agent_track_count, memory_scan_shape, open_onnx, pose_trail_shape,
                                  scan_history_frames, wall_map_carrot, wall_map_channel_list, wall_map_shape)

#: columns per agent track (flashnav.config.TRACK_FEATURES: present, x, y, vx, vy, radius)
TRACK_WIDTH = 6


def wrap_angle(a: float) -> float:
    """Radians wrapped to [-pi, pi) (the simulator's convention)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Heading (rad) of an orientation quaternion: the rotation about z (ROS's yaw), of any length (the
    unit-length formula's ``1 - 2 (y^2 + z^2)`` turned a quaternion of length 2 at 90 deg into 127 deg).
    ValueError for a quaternion of length 0 (an orientation never set) or one that is not finite."""
    norm = w * w + x * x + y * y + z * z
    if not (math.isfinite(norm) and norm > 1e-12):
        raise ValueError(f"orientation quaternion ({x}, {y}, {z}, {w}) is not a rotation (length 0 or not finite)")
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


@dataclass(frozen=True)
class Decision:
    """One control step: ``state`` ("driving" or "reached"), the command ``v`` m/s, ``w`` rad/s, the
    network's ``action`` [2] in [-1, 1] (None when it did not run), goal ``distance`` m and ``angle`` rad,
    and the ``obs`` [D] float32 given to the network."""

    state: str
    v: float
    w: float
    distance: float
    angle: float
    action: np.ndarray | None
    obs: np.ndarray


def _lidar_meta(meta: dict[str, Any], path) -> tuple[SectorLayout, int]:
    try:
        lidar = meta["observation"]["lidar"]
        sectors = int(lidar["columns"][1]) - int(lidar["columns"][0])
        return SectorLayout(sectors, float(lidar["fov_deg"]), float(lidar["range"][1])), int(lidar["beams"])
    except (KeyError, IndexError, TypeError) as exc:
        raise ValueError(f"{path}: the policy's metadata lacks the LiDAR layout (observation.lidar: {exc})") from None


class PolicyRuntime:
    """An exported policy with what it needs on the robot: the sector layout, the goal radius, the
    command bounds and the control period, all read from the file's metadata."""

    def __init__(self, session, meta: dict[str, Any], path: str | Path = "<policy>", *,
                 mount: Mount = Mount(), fill: float | None = None):
        self.session, self.meta, self.path = session, meta, str(path)
        self.layout, self.beams = _lidar_meta(meta, path)
        self.adapter = ScanAdapter(self.layout, mount, fill)
        self.obs_dim = int(meta["obs_dim"])
        preset = meta.get("preset") or {}
        episode = preset.get("episode") or {}
        # files written before these keys existed carry them in their preset block
        self.goal_threshold = float(meta.get("goal_threshold", episode.get("goal_threshold", 0.0)))
        self.control_period = float(meta.get("control_period_s", episode.get("dt", 0.0)))
        if not self.goal_threshold > 0 or not self.control_period > 0:
            raise ValueError(f"{path}: the policy's metadata lacks goal_threshold / control_period_s")
        self.scan_history = scan_history_frames(meta, path)  # k previous frames after the paper's layout
        self.agent_tracks = agent_track_count(meta, path)  # M people of a tracker
        self.pose_trail, self.trail_every = pose_trail_shape(meta, path)  # P breadcrumbs
        # the memory scan, last: F stored scans, one every E control steps, P hits each
        self.memory_frames, self.memory_every, self.memory_points = memory_scan_shape(meta, path)
        memory = self.layout.sectors if self.memory_frames else 0
        # the wall map, after everything: C x C squares of cell_m, hits kept in cells of grid_m, beyond_m past them;
        # channels walls and goal, then where the robot has been and the plan where listed
        self.wall_map, self.wall_cell, self.wall_grid, self.wall_beyond = wall_map_shape(meta, path)
        self.wall_channel_names = wall_map_channel_list(meta, path)
        self.wall_channels = len(self.wall_channel_names)
        if "plan" in self.wall_channel_names:  # the box the plan searched in training is this runtime's
            margin = (meta["observation"]["wall_map"] or {}).get("plan_margin_m")
            if margin != PLAN_MARGIN_M:
                raise ValueError(f"{path}: the policy's plan channel was drawn within plan_margin_m {margin!r} of the "
                                 f"robot and the goal; this runtime plans within {PLAN_MARGIN_M} m")
        # what a move beside a wall cost the plan (0 = the shortest way: also every policy exported before the key)
        penalty = (meta["observation"].get("wall_map") or {}).get("plan_penalty", 0.0)
        if isinstance(penalty, bool) or not isinstance(penalty, (int, float)) or not 0 <= penalty < math.inf:
            raise ValueError(f"{path}: observation.wall_map.plan_penalty must be a number >= 0, got {penalty!r}")
        self.plan_penalty = float(penalty)
        self.carrot = wall_map_carrot(meta, path)  # metres along the plan: two columns after the trail (0 = none)
        squares = self.wall_channels * self.wall_map ** 2
        self.velocity_dims = (self.obs_dim - (1 + self.scan_history) * self.layout.sectors - 2
                              - TRACK_WIDTH * self.agent_tracks - 2 * self.pose_trail - 2 * bool(self.carrot) - memory
                              - squares)
        if self.velocity_dims not in (2, 3):
            raise ValueError(f"{path}: obs_dim {self.obs_dim} does not fit {self.layout.sectors} sectors + goal + "
                             f"velocity + {self.scan_history} history frames + {self.agent_tracks} agent tracks + "
                             f"{self.pose_trail} pose-trail breadcrumbs + {2 * bool(self.carrot)} carrot columns + "
                             f"{memory} memory-scan sectors + "
                             f"{squares} wall-map squares")
        bounds = meta.get("command_bounds") or {}
        self.v_limit = float(bounds.get("max_linear_velocity", math.inf))
        self.w_limit = float(bounds.get("max_angular_velocity", math.inf))

    @classmethod
    def load(cls, path: str | Path, *, mount: Mount = Mount(), fill: float | None = None) -> "PolicyRuntime":
        """Load ``policy.onnx`` (the ONNX file ``flashnav train`` / ``flashnav.export`` writes; a run folder reads its
        ``policy.onnx``).

        Raises FileNotFoundError for a missing file and ValueError naming ``path`` for another suffix,
        an unreadable file or missing FlashNav metadata."""
        path = Path(path)
        if path.is_dir() and (path / "policy.onnx").is_file():  # a run folder: its exported policy
            path = path / "policy.onnx"
        if path.is_dir():
            raise ValueError(f"{path}: a folder without policy.onnx; give the policy's .onnx file or a run folder "
                             f"that holds one")
        if path.suffix != ".onnx":
            raise ValueError(f"{path}: the deploy runtime runs policy.onnx (numpy + onnxruntime, no torch); "
                             f"got {path.suffix or 'no suffix'!r}")
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such policy file")
        # a 34-number MLP: threads only add latency on the robot
        session, meta = open_onnx(path, threads=1)
        return cls(session, meta, path, mount=mount, fill=fill)

    # ---- the observation ------------------------------------------------------------------------
    def scan(self, angle_min: float, angle_increment: float, ranges, range_min: float, range_max: float) -> np.ndarray:
        """Raw scan -> the policy's sectors [S] float32 metres (see :mod:`flashnav.deploy.scan`)."""
        return self.adapter(angle_min, angle_increment, ranges, range_min, range_max)

    def goal_in_robot_frame(self, pose, goal) -> tuple[float, float]:
        """(distance m, angle rad in [-pi, pi), positive = left) of ``goal`` (x, y) seen from ``pose``
        (x, y, yaw); both in the same fixed frame."""
        dx, dy = float(goal[0]) - float(pose[0]), float(goal[1]) - float(pose[1])
        return math.hypot(dx, dy), wrap_angle(math.atan2(dy, dx) - float(pose[2]))

    def observation(self, sectors, pose, goal, velocity, history=None, tracks=None, trail=None,
                    memory=None, wall_map=None, carrot=None) -> np.ndarray:
        """[obs_dim] float32: sectors [S] m, goal from pose, ``velocity`` (v m/s, w rad/s) last executed,
        then ``history`` [k, S] m (the sectors of the k previous control steps, newest first; None
        when the policy has no scan history), then the policy's M agent tracks from ``tracks`` (the
        people a tracker reports, rows of (x, y, vx, vy, radius) in the robot frame; an empty list when
        it reports nobody; None when the policy has no tracks), then ``trail`` [P, 2] (the robot's
        earlier positions in the pose's frame, newest first; None when the policy has no pose trail)
        in the robot frame of ``pose``, then ``carrot`` [2] m (the point along the wall map's plan in the robot
        frame, :attr:`flashnav.deploy.memory.WallCells.carrot_xy`; None when the policy has none), then ``memory``
        [S] m (the memory scan, :class:`flashnav.deploy.memory.ScanMemory`; None when the policy has none), then
        ``wall_map`` [2 C^2] of
        0 / 1 (3 C^2 with a visited channel; :class:`flashnav.deploy.memory.WallCells`; None when the policy has
        none)."""
        sectors = np.asarray(sectors, np.float32).reshape(-1)
        if sectors.size != self.layout.sectors:
            raise ValueError(f"sectors must have {self.layout.sectors} values, got {sectors.size}")
        for name, value, parts in (("pose", pose, "x, y, yaw"), ("goal", goal, "x, y"), ("velocity", velocity, "v, w")):
            n = parts.count(",") + 1
            if np.size(value) != n:  # an (x, y) pose once failed as an IndexError deep in the goal's frame
                raise ValueError(f"{name} must have {n} values ({parts}), got {np.size(value)}")
        dist, angle = self.goal_in_robot_frame(pose, goal)
        v, w = float(velocity[0]), float(velocity[1])
        vel = [v, w] if self.velocity_dims == 2 else [v, 0.0, w]
        parts = [sectors, np.array([dist, angle, *vel], np.float32)]
        want = (self.scan_history, self.layout.sectors)
        if history is not None or self.scan_history:
            past = np.asarray(history, np.float32) if history is not None else None
            if past is None or past.shape != want:
                got = None if past is None else list(past.shape)
                raise ValueError(f"history must be [{want[0]}, {want[1]}] (the policy's scan_history frames "
                                 f"of sectors, newest first), got {got}")
            parts.append(past.reshape(-1))
        if tracks is not None or self.agent_tracks:
            if tracks is None or not self.agent_tracks:
                raise ValueError(f"tracks: the policy has {self.agent_tracks} agent tracks (observation.agent_tracks); "
                                 + ("pass the people the tracker reports (an empty list for nobody)" if tracks is None
                                    else "it takes no tracks, got some"))
            parts.append(track_columns(tracks, self.agent_tracks))
        if trail is not None or self.pose_trail:
            crumbs = np.asarray(trail, np.float64) if trail is not None else None
            if crumbs is None or crumbs.shape != (self.pose_trail, 2) or not np.isfinite(crumbs).all():
                got = None if crumbs is None else (list(crumbs.shape) if np.isfinite(crumbs).all() else "not finite")
                raise ValueError(f"trail must be [{self.pose_trail}, 2] finite (x, y) positions (the policy's "
                                 f"observation.pose_trail breadcrumbs, newest first), got {got}")
            parts.append(trail_columns(crumbs, pose))
        if carrot is not None or self.carrot:
            point = np.asarray(carrot, np.float64).reshape(-1) if carrot is not None else None
            if not self.carrot:
                raise ValueError(f"carrot: the policy has no carrot (observation.wall_map_carrot 0), got "
                                 f"{point.tolist()}")
            if point is None or point.size != 2 or not np.isfinite(point).all():
                got = None if point is None else (point.tolist() if np.isfinite(point).all() else "not finite")
                raise ValueError(f"carrot must be 2 finite numbers (x, y m in the robot frame: the policy's "
                                 f"observation.wall_map_carrot {self.carrot:g} m), got {got}")
            parts.append(point.astype(np.float32))
        if memory is not None or self.memory_frames:
            mem = np.asarray(memory, np.float32).reshape(-1) if memory is not None else None
            want_mem = self.layout.sectors if self.memory_frames else 0
            if mem is None or mem.size != want_mem or not np.isfinite(mem).all():
                got = None if mem is None else (mem.size if np.isfinite(mem).all() else "not finite")
                raise ValueError(f"memory must be {want_mem} finite distances (the policy's memory scan, "
                                 f"observation.memory_frames {self.memory_frames}), got {got}")
            parts.append(mem)
        if wall_map is not None or self.wall_map:
            squares = np.asarray(wall_map, np.float32).reshape(-1) if wall_map is not None else None
            want = self.wall_channels * self.wall_map ** 2
            if squares is None or squares.size != want or not np.isin(squares, (0.0, 1.0)).all():
                got = None if squares is None else (squares.size if np.isin(squares, (0.0, 1.0)).all() else "not 0 / 1")
                raise ValueError(f"wall_map must be {want} squares of 0 or 1 (the policy's observation.wall_map "
                                 f"{self.wall_map}), got {got}")
            parts.append(squares)
        return np.concatenate(parts)

    # ---- the command ----------------------------------------------------------------------------
    def act(self, obs: np.ndarray) -> tuple[np.ndarray, float, float]:
        """The network on one observation: (action [2] in [-1, 1], v m/s, w rad/s), v and w as the
        export maps the action onto the preset's bounds and clamps them to the platform limits."""
        x = np.asarray(obs, np.float32).reshape(1, self.obs_dim)
        if not np.isfinite(x).all():
            raise ValueError(f"observation is not finite: {x.tolist()}")
        action, command = self.session.run(["action", "command"], {"obs": x})
        v = min(max(float(command[0, 0]), -self.v_limit), self.v_limit)
        w = min(max(float(command[0, 1]), -self.w_limit), self.w_limit)
        return action[0], v, w

    def decide(self, sectors, pose, goal, velocity, history=None, tracks=None, trail=None, memory=None,
               wall_map=None, carrot=None) -> Decision:
        """One control step: stop inside the goal radius, else the policy's command (``history``,
        ``tracks``, ``trail``, ``memory``, ``wall_map`` and ``carrot`` as in :meth:`observation`)."""
        obs = self.observation(sectors, pose, goal, velocity, history, tracks, trail, memory, wall_map, carrot)
        dist, angle = float(obs[self.layout.sectors]), float(obs[self.layout.sectors + 1])
        if dist < self.goal_threshold:
            return Decision("reached", 0.0, 0.0, dist, angle, None, obs)
        action, v, w = self.act(obs)
        return Decision("driving", v, w, dist, angle, action, obs)


def track_columns(tracks, count: int) -> np.ndarray:
    """[count * 6] float32: the ``count`` nearest of ``tracks`` (rows of (x, y, vx, vy, radius), robot
    frame, m and m/s) by the distance from the robot's centre to their edge, each as (1, x, y, vx, vy,
    radius), then zeros for absent tracks: the simulator's layout (:mod:`flashnav.sim.tracks`).

    Raises ValueError naming ``tracks`` for another shape, a value that is not finite or a negative radius."""
    rows = np.asarray(tracks, np.float64)
    rows = rows.reshape(0, 5) if rows.size == 0 else rows
    if rows.ndim != 2 or rows.shape[1] != 5:
        raise ValueError(f"tracks must be rows of (x, y, vx, vy, radius), got shape {list(rows.shape)}")
    if not np.isfinite(rows).all() or (rows[:, 4] < 0).any():
        raise ValueError(f"tracks must be finite with radius >= 0, got {rows.tolist()}")
    order = np.argsort(np.hypot(rows[:, 0], rows[:, 1]) - rows[:, 4], kind="stable")[:count]
    out = np.zeros((count, TRACK_WIDTH), np.float32)
    out[: len(order), 0] = 1.0
    out[: len(order), 1:] = rows[order]
    return out.reshape(-1)


def robot_frame(xy: np.ndarray, pose) -> np.ndarray:
    """Points ``xy`` [n, 2] of the pose's fixed frame in the robot frame of ``pose`` (x, y, yaw): x ahead,
    y to the left [n, 2] float64 (numpy's :func:`flashnav.sim.trail.to_robot_frame`). With ``pose`` =
    (0, 0, yaw) it rotates vectors (velocities) into the robot frame."""
    dx, dy = xy[:, 0] - float(pose[0]), xy[:, 1] - float(pose[1])
    c, s = math.cos(float(pose[2])), math.sin(float(pose[2]))
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=1)


def trail_columns(crumbs: np.ndarray, pose) -> np.ndarray:
    """[2 P] float32: breadcrumbs ``crumbs`` [P, 2] (x, y in the pose's fixed frame) in the robot frame of
    ``pose`` (:func:`robot_frame`), flattened x0, y0, x1, ..."""
    return robot_frame(crumbs, pose).astype(np.float32).reshape(-1)
