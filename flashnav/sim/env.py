"""The batched navigation environment (paper section 2.2).

All N environments share one occupancy map, or each slot runs on its own map of a set of M maps
(``make_env(..., maps=[...])``, :mod:`flashnav.sim.mapset`): a slot draws its map when it resets
(uniformly or by ``map_weights``, with the env's generator), ``map_index`` [N] holds each slot's map,
and sensing, collision and sampling read that map. Per-env state lives in tensors [N, ...] on one device.
One step follows the paper's path::

    action -> motion -> range scan -> collision / goal / reward / flags -> observation -> sparse reset

The observation's layout (``obs_dim`` = 34 for TurtleBot2, 35 for Go2, more with the opt-in extras) is in
:mod:`flashnav.sim.observation`.

Rewards and flags (:mod:`flashnav.sim.reward`): goal reached (distance < goal_threshold) -> +goal,
terminated; else collision -> collision, terminated (the goal is checked first, as the paper lists it);
else progress * (d_old - c d_new), d the straight-line goal distance (``reward.progress_metric: geodesic``:
the path length), c = ``reward.progress_discount`` (1, the paper's). Reaching the horizon without a terminal
event is a truncation. Finished slots are reset in the same step (Gymnasium's SAME_STEP autoreset):
``info["final_obs"]`` holds the observation *before* the reset for every slot (equal to ``obs`` where nothing
finished) and ``info["_final_obs"]`` marks the slots that finished, so ``info["final_obs"]`` is always the
correct next observation for replay.

Frames: the state tensors (``pose``, ``goal``) are float32 metres in the *simulator frame* of each slot's map
(:mod:`flashnav.sim.mapset`, "Frames": world coordinates for maps near the world origin, else re-centred);
``set_state`` takes world coordinates (give float64 for far maps); ``world_pose`` / ``world_goal`` return them in
float64.

The goal-distance bound of the observation space (``goal_distance_max``) is the map's diagonal, or
with several maps the largest diagonal among them: one fixed scale for every map.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from flashnav.config import RobotPreset
from flashnav.maps.bundled import resolve_map, resolve_maps
from flashnav.maps.grid import OccupancyMap
from flashnav.names import DEFAULT_RAYCASTER, DEFAULT_ROBOT
from flashnav.presets import load_robot
from flashnav.sim.agents import AgentWorld
from flashnav.sim.collision import make_collision_checker
from flashnav.sim.extras import ObservationExtras
from flashnav.sim.inputs import as_batch, check_finite, check_num_envs, check_seed, check_slots, check_state
from flashnav.sim.mapset import (MapDraw, as_grids, check_map_scale, frame_to_world, sample_on_maps, sim_frame,
                                 world_to_frame)
from flashnav.sim.motion import Actuation, action_to_velocity, integrate
from flashnav.sim.observation import beam_angles, observation_bounds, observe  # noqa: F401 (beam_angles: re-exported)
from flashnav.sim.raycast import make_raycaster
from flashnav.sim.reward import Shaping, outcome
from flashnav.sim.sampling import EpisodeSampler, MapSetSampler


class NavVecEnv(VectorEnv):
    """Batched 2D-LiDAR navigation; see the module docstring for the layout and semantics."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        preset: RobotPreset,
        num_envs: int,
        *,
        grid: OccupancyMap | Sequence[OccupancyMap],
        device: torch.device | str = "cpu",
        seed: int = 0,
        raycaster: str | None = None,
        map_weights: Sequence[float] | None = None,
    ):
        num_envs, seed = check_num_envs(num_envs), check_seed(seed)
        self.preset, self.num_envs = preset, num_envs
        self.device = torch.device(device)
        self.raycaster_name = raycaster or DEFAULT_RAYCASTER
        self.beam_angles = beam_angles(preset.lidar.fov_deg, preset.lidar.beams).to(self.device)
        self.extras = ObservationExtras(preset, num_envs, self.beam_angles, self.device)  # all off: the paper's step
        self._use_maps(grid, map_weights)
        self.obs_dim = preset.obs_dim

        low, high = self._obs_bounds()
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)

        n, f32 = num_envs, dict(device=self.device, dtype=torch.float32)
        self.pose = torch.zeros(n, 3, **f32)  # x, y (m, simulator frame), yaw (rad)
        self.goal = torch.zeros(n, 2, **f32)  # m, simulator frame
        self.start_pose = torch.zeros(n, 3, **f32)  # each slot's episode start and goal (episode.retry_failed)
        self.start_goal = torch.zeros(n, 2, **f32)
        self.velocity = torch.zeros(n, 2, **f32)  # executed (v m/s, w rad/s); the observation has the command
        self.steps = torch.zeros(n, dtype=torch.int32, device=self.device)
        self.goal_distance = torch.zeros(n, **f32)
        self.episode_return = torch.zeros(n, **f32)
        self.obs = torch.zeros(n, self.obs_dim, **f32)
        self.map_index = torch.zeros(n, dtype=torch.long, device=self.device)  # each slot's map
        # latency and acceleration limits between command and motion (sim.motion.Actuation); None: the paper's
        self.actuation = None if preset.motion.instant else Actuation(preset.motion, n, preset.episode.dt, self.device)
        self.noise_std = None if preset.lidar.noise_std_max is None else torch.zeros(n, **f32)  # per episode
        self._gen = torch.Generator(device=self.device)
        self._gen.manual_seed(seed)
        self._seed = seed
        self._placed = False  # no episode until reset() or set_state(): a step from the zero state means nothing

    def _use_maps(self, grid: OccupancyMap | Sequence[OccupancyMap], map_weights: Sequence[float] | None) -> None:
        """Build everything that reads the maps: frames, raycaster, collision, samplers, map draws."""
        preset, lidar = self.preset, self.preset.lidar
        maps = as_grids(grid)
        for g in maps:
            check_map_scale(g, preset)
        draw = MapDraw(len(maps), map_weights, self.device)  # the weights checked too: a refused set changes nothing
        self.maps = maps
        self.map = self.maps[0]  # the map of a single-map env (with several: the first)
        # all geometry runs on the map in the simulator frame (the same cells and cached fields)
        origins = [sim_frame(g) for g in self.maps]
        self.frame_maps = tuple(g if o == (0.0, 0.0) else g.shifted(o) for g, o in zip(self.maps, origins))
        self.frame_origin, self.frame_map = origins[0], self.frame_maps[0]
        self._frame_origins = torch.tensor(origins, dtype=torch.float64, device=self.device)  # [M, 2]
        geometry = self.frame_map if len(self.maps) == 1 else self.frame_maps
        self._cast = make_raycaster(self.raycaster_name, geometry, self.beam_angles, lidar.max_range, self.device,
                                    lidar.march_step)
        self._collides = make_collision_checker(preset.footprint, geometry, self.device)
        self.samplers = [EpisodeSampler(g, preset, self.device) for g in self.frame_maps]
        self.sampler = self.samplers[0]
        # the shaping term's distance (reward.progress_metric geodesic: path lengths to each goal source)
        self.shaping = Shaping(preset, self.frame_maps, self.samplers, self.num_envs, self.device)
        self._map_sampler = MapSetSampler(self.samplers) if len(self.maps) > 1 else None
        self._draw_map = draw
        self.goal_distance_max = max(g.diagonal_m for g in self.maps)
        # moving agents (issue 13): None with agents.count 0, and then every step is exactly the static one;
        # they move on each slot's own map (rebuilt with the maps)
        self.agents = (AgentWorld(preset, self.frame_maps, self.num_envs, self.beam_angles, self.device)
                       if preset.agents.count else None)
        self.extras.use_maps(self.frame_maps)  # the wall map's grids span the maps

    def replace_maps(self, grid: OccupancyMap | Sequence[OccupancyMap], map_weights: Sequence[float] | None = None):
        """Swap the map set between steps (fresh generated maps during training): every slot ends its
        episode where it stands (nothing is reported for it: no step info, no final_obs) and starts a
        new one on a map drawn from the new set, as :meth:`reset` does; the generator's stream goes on
        (no reseed). All slots at once rather than each at its next reset: the old maps' geometry can
        then be dropped at once, and no slot trains on a retired map for up to a horizon. Returns
        ``(obs, info)`` as :meth:`reset`; the goal-distance bound of the observation space follows
        the new maps."""
        self._use_maps(grid, map_weights)
        low, high = self._obs_bounds()
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.map_index.zero_()
        return self.reset()

    # ---- spaces -----------------------------------------------------------------------------------
    def _obs_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return observation_bounds(self.preset, self.goal_distance_max)

    # ---- observation ------------------------------------------------------------------------------
    def scan(self, slots: torch.Tensor | None = None) -> torch.Tensor:
        """Noise-free ranges [N, beams] float32 metres at the current poses (before pooling), moving
        agents included; of ``slots`` [k] (long) only, if given."""
        if slots is None:
            return self._scan(self.pose, slice(None))
        return self._scan(self.pose[slots], slots)

    def _scan(self, pose: torch.Tensor, sel) -> torch.Tensor:
        """Ranges [k, beams] of slots ``sel`` at ``pose`` [k, 3], each on its map: min(static range,
        agent hit)."""
        ranges = self._cast(pose, self._maps_of(sel))
        return ranges if self.agents is None else self.agents.sense(ranges, pose, sel)

    @property
    def num_maps(self) -> int:
        return len(self.maps)

    def _maps_of(self, sel) -> torch.Tensor | None:
        """The map index of slots ``sel`` for the geometry, or None with a single map."""
        return None if len(self.maps) == 1 else self.map_index[sel]

    def _observe(self, sel, ranges: torch.Tensor, pose: torch.Tensor, goal: torch.Tensor, velocity: torch.Tensor,
                 start: bool, steps: torch.Tensor | None = None) -> torch.Tensor:
        """Observations [k, obs_dim] of slots ``sel`` from ranges [k, beams] and their state: the paper's,
        then the opt-in extras (:meth:`ObservationExtras.append`; ``start``: new episodes)."""
        noise = None if self.noise_std is None else self.noise_std[sel]
        obs = observe(self.preset, ranges, pose, goal, velocity, self._gen, noise)
        return self.extras.append(obs, sel, self.agents, pose, ranges, start, steps, goal, self._maps_of(sel))

    # ---- episode control --------------------------------------------------------------------------
    def _reset_slots(self, idx: torch.Tensor) -> None:
        """Start new episodes in slots ``idx`` [k] (long); every other slot is left untouched. With
        several maps each slot first draws its map, then one batched sampler serves all of them."""
        if idx.numel() == 0:
            return
        if len(self.maps) == 1:
            pose, goal = self.sampler.sample(idx.numel(), self._gen)
            self._place(idx, pose, goal)
            return
        self.map_index[idx], pose, goal = sample_on_maps(self._map_sampler, self._draw_map, idx.numel(), self._gen)
        self._place(idx, pose, goal)

    def _retry_or_reset(self, done: torch.Tensor, success: torch.Tensor) -> None:
        """Autoreset of the slots whose episode ended (``done`` [N] bool): with ``episode.retry_failed`` p > 0, each
        slot that failed (``~success``) restarts from its last start and goal, on its map, with chance p (one
        uniform draw per slot from the environment's generator); every other ended slot draws a new episode."""
        p = self.preset.episode.retry_failed
        if p > 0:
            retry = done & ~success & (torch.rand(self.num_envs, generator=self._gen, device=self.device) < p)
            again = retry.nonzero().squeeze(1)
            if again.numel():
                self._place(again, self.start_pose[again], self.start_goal[again])
            done = done & ~retry
        self._reset_slots(done.nonzero().squeeze(1))

    def _place(self, idx: torch.Tensor, pose: torch.Tensor, goal: torch.Tensor) -> None:
        zeros = torch.zeros(idx.numel(), 2, device=self.device)
        self.pose[idx] = pose
        self.goal[idx] = goal
        self.start_pose[idx] = pose
        self.start_goal[idx] = goal
        self.velocity[idx] = zeros
        if self.actuation is not None:
            self.actuation.reset(idx)
        if self.noise_std is not None:  # this episode's range noise, from [noise_std, noise_std_max]
            lo, hi = self.preset.lidar.noise_std, self.preset.lidar.noise_std_max
            self.noise_std[idx] = lo + (hi - lo) * torch.rand(idx.numel(), generator=self._gen, device=self.device)
        self.steps[idx] = 0
        self.episode_return[idx] = 0.0
        self.goal_distance[idx] = torch.linalg.vector_norm(goal - pose[:, :2], dim=1)
        self.shaping.start(idx, pose[:, :2], goal, self.goal_distance[idx], self._maps_of(idx))
        if self.agents is not None:  # the slots' agents start with their episodes, on the slots' maps
            self.agents.reset(idx, pose, goal, self._gen, self._maps_of(idx))
        ranges = self._scan(pose, idx)
        self.obs[idx] = self._observe(idx, ranges, pose, goal, zeros, start=True)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset all slots, or only ``options["reset_mask"]`` ([N] bool). ``seed`` reseeds the
        environment's generator: the same seed gives the same episodes."""
        if seed is not None:
            self._seed = check_seed(seed)
            self._gen.manual_seed(self._seed)
        mask = None if options is None else options.get("reset_mask")
        if mask is None:
            idx = torch.arange(self.num_envs, device=self.device)
        else:
            mask = torch.as_tensor(mask, device=self.device)
            if mask.shape != (self.num_envs,) or mask.dtype != torch.bool:
                raise ValueError(f"options['reset_mask'] must be a bool tensor of shape [num_envs] = "
                                 f"[{self.num_envs}], got {mask.dtype} {list(mask.shape)}")
            idx = mask.nonzero().squeeze(1)
        self._reset_slots(idx)
        self._placed = True
        return self.obs.clone(), {}

    def set_state(self, pose: torch.Tensor, goal: torch.Tensor, map_index=None) -> torch.Tensor:
        """Place every robot at ``pose`` [N, 3] (x, y m world, yaw rad) with ``goal`` [N, 2] (m world;
        float64 keeps the precision of far maps); zero its velocity and step counter; return the
        recomputed observation [N, obs_dim]. ``map_index`` [N] (integers in [0, num_maps)) moves the
        slots onto those maps first; None keeps each slot's map.

        Raises ValueError naming ``pose`` / ``goal`` / ``map_index`` for another shape, a NaN or
        infinite value, a map index out of range, or a goal outside its map's extent (it could never
        be reached; :func:`flashnav.sim.inputs.check_state`)."""
        pose, goal, mi = check_state(self.maps, pose, goal, map_index, self.map_index)
        self.map_index[:] = mi
        if len(self.maps) > 1 or self.frame_origin != (0.0, 0.0):  # (else the world's frame: as they are)
            pose, goal = world_to_frame(pose, goal, self._frame_origins[self.map_index])
        self._place(torch.arange(self.num_envs, device=self.device), pose.float(), goal.float())
        self._placed = True
        return self.obs.clone()

    def _check_placed(self) -> None:
        if not self._placed:
            raise RuntimeError("step() before reset(): every robot and goal is still at (0, 0), which would count "
                               "as reached; call env.reset(seed=...) (or set_state) first")

    def world_pose(self) -> torch.Tensor:
        """[N, 3] float64: the current poses in world coordinates (x, y m, yaw rad)."""
        return frame_to_world(self.pose, self._frame_origins[self.map_index])

    def world_goal(self) -> torch.Tensor:
        """[N, 2] float64: the current goals in world coordinates (m)."""
        return frame_to_world(self.goal, self._frame_origins[self.map_index])

    def step(self, actions):
        """Advance every slot by one step. ``actions`` [N, 2] in [-1, 1] (clamped); another shape or a
        NaN / infinite value is a ValueError naming ``actions``."""
        self._check_placed()
        actions = as_batch(self.device, actions, "actions", (self.num_envs, 2), "num_envs, 2")
        if not bool(torch.isfinite(actions).all()):  # the one host sync the checks cost per step
            check_finite(actions, "actions")
        t = self._advance(slice(None), actions)
        done = t["terminated"] | t["truncated"]
        info = {
            "final_obs": t["obs"],  # a tensor of its own: the reset below writes into self.obs
            "_final_obs": done,
            "final_pose": t["pose"],  # [N, 3] where each robot ended this step (simulator frame), before any reset
            "success": t["success"],
            "collision": t["collision"],
            "collision_static": t["collision_static"],  # with a wall or the map's edge
            "collision_agent": t["collision_agent"],  # with a moving agent (both can hold)
            # length and return of the episode that ended in this step (meaningful where done)
            "episode_steps": t["episode_steps"],
            "episode_return": t["episode_return"],
        }
        self._retry_or_reset(done, t["success"])
        return self.obs.clone(), t["reward"], t["terminated"], t["truncated"], info

    def step_slots(self, idx: torch.Tensor, actions) -> dict[str, torch.Tensor]:
        """Advance only slots ``idx`` [k] (long) by one step, with no autoreset: a slot whose episode
        ends stays as it ended until it is reset. ``actions`` [k, 2]. For evaluation, where only each
        slot's first episode counts and finished slots need not be simulated any further.

        Returns [k] tensors for those slots: obs [k, obs_dim], reward, terminated, truncated, success,
        collision, collision_static, collision_agent, episode_steps, episode_return (the same semantics as :meth:`step`),
        pose [k, 3]. ``idx`` outside [0, N), repeating a slot or not 1-D integer, or ``actions`` of another shape or
        not finite: a ValueError."""
        self._check_placed()
        idx = torch.as_tensor(idx, device=self.device)
        actions = check_slots(idx, actions, self.num_envs)
        return self._advance(idx, actions)

    def _advance(self, sel, actions: torch.Tensor) -> dict[str, torch.Tensor]:
        """One transition of the slots ``sel`` (``slice(None)`` for all, else [k] long indices): motion (the
        command through the preset's actuation, if any), scan, goal / collision / reward / flags, observation (its
        velocity state the command: what the robot's controller knows); writes their state back."""
        p = self.preset
        command = torch.stack(action_to_velocity(actions, p.motion), dim=1)  # the observation's velocity state
        velocity = command if self.actuation is None else self.actuation.execute(sel, command, self.velocity[sel])
        pose = integrate(self.pose[sel], velocity[:, 0], velocity[:, 1], p.episode.dt)
        steps = self.steps[sel] + 1
        goal = self.goal[sel]

        maps = self._maps_of(sel)
        if self.agents is not None:
            self.agents.step(sel, pose, steps, self._gen, maps)
        ranges = self._scan(pose, sel)
        dist = torch.linalg.vector_norm(goal - pose[:, :2], dim=1)
        static = self._collides(pose, maps)
        agent = torch.zeros_like(static) if self.agents is None else self.agents.collides(pose, sel)
        shaping = self.shaping.step(sel, pose[:, :2], self.goal_distance[sel], dist, maps)
        if self.agents is not None and p.reward.agent_proximity > 0:  # off by default: the paper's reward
            near = (p.reward.agent_proximity_distance - self.agents.gap(pose, sel)).clamp(min=0.0)
            shaping = shaping - p.reward.agent_proximity * near
        out = outcome(p, dist, static, agent, steps, shaping)
        episode_return = self.episode_return[sel] + out["reward"]
        obs = self._observe(sel, ranges, pose, goal, command, start=False, steps=steps)

        self.pose[sel], self.velocity[sel], self.steps[sel] = pose, velocity, steps
        self.goal_distance[sel], self.episode_return[sel], self.obs[sel] = dist, episode_return, obs
        return {"obs": obs, **out, "episode_steps": steps, "episode_return": episode_return, "pose": pose}

    def close_extras(self, **kwargs) -> None:  # nothing to release: no processes, no files
        pass

    def __repr__(self) -> str:
        where = f"map={self.map.name!r}" if len(self.maps) == 1 else f"maps={len(self.maps)}"
        return (f"NavVecEnv({self.preset.name}, num_envs={self.num_envs}, {where}, "
                f"device={self.device}, raycaster={self.raycaster_name!r})")


def make_env(robot: str | RobotPreset = DEFAULT_ROBOT, num_envs: int = 1, *, map=None, maps=None,
             map_weights: Sequence[float] | None = None, device: torch.device | str = "cpu", seed: int = 0,
             raycaster: str | None = None) -> NavVecEnv:
    """The batched environment.

    Args:
        robot: a preset name ("turtlebot2", "go2"), a preset YAML path, or a RobotPreset.
        num_envs: N, the number of parallel environments.
        map: None (the preset's bundled map), an OccupancyMap, a bundled map name, or a ROS YAML path.
        maps: instead of ``map``, a set of maps for the slots to draw from at every reset: a list of
            what ``map`` takes, or a directory / glob pattern of ROS map YAML files
            (:func:`flashnav.maps.bundled.resolve_maps`).
        map_weights: with ``maps``, the relative probability of each map (default: uniform).
        device: where every tensor lives ("cpu", "cuda", ...).
        seed: seeds start/goal sampling and map draws (and sensor noise when enabled).
        raycaster: "exact" (default; on CUDA the "exact-cuda" kernel), "exact-torch", "exact-cuda" or "march" (the paper's fixed-step algorithm).
    """
    if isinstance(device, str):  # "cuda" without a GPU: a ValueError naming it, not torch's AssertionError
        from flashnav.machine import resolve_device

        device = resolve_device(device)
    preset = load_robot(robot)
    if maps is not None:
        if map is not None:
            raise ValueError("give either map or maps, not both")
        grids = resolve_maps(maps, preset.map)
    else:
        if map_weights is not None:
            raise ValueError("map_weights needs maps=[...]")
        grids = [resolve_map(map, preset.map)]
    return NavVecEnv(preset, num_envs, grid=grids[0] if len(grids) == 1 else grids, device=device, seed=seed,
                     raycaster=raycaster, map_weights=map_weights)
