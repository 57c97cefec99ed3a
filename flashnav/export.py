"""Deployable policies (TorchScript, ONNX); training checkpoints are flashnav/checkpoint.py.

A deployed policy is one self-contained graph from the *raw* observation to the robot command, so a
robot-side runtime needs no FlashNav code and no knowledge of the input scaling:

    obs [N, D] float32, physical units  ->  IPAPRec transform -> MLP -> tanh  ->  action [N, 2] in [-1, 1]
                                                                            ->  command [N, 2] (v m/s, w rad/s)

```python
paths = export_policy(learner.policy, preset, "runs/tb2")   # policy.pt, policy.onnx, policy.json
policy, meta = load_policy("runs/tb2/policy.onnx")           # obs tensor [N, D] -> action tensor [N, 2]
```
"""

from __future__ import annotations

import copy
import json
import math
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import nn

import flashnav
from flashnav.checkpoint import is_checkpoint
from flashnav.config import TRACK_FEATURES, RobotPreset
from flashnav.learn.networks import Actor, DeterministicActor
from flashnav.maps.seen_plan import PLAN_MARGIN_M
from flashnav.names import POLICY_METADATA, POLICY_ONNX, POLICY_TORCHSCRIPT
from flashnav.observation_samples import sample_observations
from flashnav.policy_meta import METADATA_KEY, POLICY_FORMAT_VERSION, first_sentence, open_onnx  # noqa: F401
from flashnav.policy_meta import wall_map_channel_names
from flashnav.policy_meta import parse_metadata as _parse_metadata
from flashnav.sim.memory import points_per_frame
from flashnav.sim.wall_grid import HIT_BEYOND_M

#: ONNX opset: well inside what onnxruntime >= 1.18 implements, and every op used here exists in it.
ONNX_OPSET = 17
#: Largest difference tolerated between the eager policy and an exported file when checking it.
EXPORT_CHECK_TOL = 1e-4


class DeployablePolicy(nn.Module):
    """``obs [N, D]`` raw units -> ``(action [N, 2] in [-1, 1], command [N, 2] = (v m/s, w rad/s))``.

    ``command`` is :func:`flashnav.sim.motion.action_to_velocity` of ``action``: the same clamp to
    [-1, 1], the same linear map onto the preset's bounds and the same clamp to the platform limits,
    with the bounds as float32 buffers. There is no branch on tensor values, so tracing records the
    whole computation for every input. Shares parameters with ``actor`` (deep-copy it to freeze).
    """

    def __init__(self, actor: nn.Module, preset: RobotPreset):
        super().__init__()
        self.policy = DeterministicActor(actor) if isinstance(actor, Actor) else actor
        m = preset.motion
        (v_lo, v_hi), (w_lo, w_hi) = m.v_bounds, m.w_bounds
        f32 = dict(dtype=torch.float32)
        self.register_buffer("low", torch.tensor([v_lo, w_lo], **f32))
        # the half span is rounded from the float64 product, as motion.py's Python-float scalar is
        self.register_buffer("half_span", torch.tensor([0.5 * (v_hi - v_lo), 0.5 * (w_hi - w_lo)], **f32))
        self.register_buffer("limit", torch.tensor([m.max_linear_velocity, m.max_angular_velocity], **f32))
        self.obs_dim = preset.obs_dim
        self._check_shapes(preset.name)

    def _check_shapes(self, robot: str) -> None:
        """Fail at construction, not on the robot, when the actor does not fit the robot's layout."""
        probe = torch.zeros(1, self.obs_dim, device=self.low.device)
        param = next(self.policy.parameters(), None)
        if param is not None:
            probe = probe.to(param.device)
        try:
            with torch.no_grad():
                out = self.policy(probe)
        except RuntimeError as exc:
            raise ValueError(f"the actor does not accept {robot}'s observation (obs_dim {self.obs_dim}): {exc}") from None
        if tuple(out.shape) != (1, 2):
            raise ValueError(f"the actor maps obs [1, {self.obs_dim}] to {tuple(out.shape)}, expected (1, 2)")

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        action = self.policy(obs).clamp(-1.0, 1.0)
        command = self.low + (action + 1.0) * self.half_span
        command = torch.minimum(torch.maximum(command, -self.limit), self.limit)
        return action, command


def policy_metadata(preset: RobotPreset, goal_distance_max: float | None = None) -> dict[str, Any]:
    """The JSON stored with every exported policy: robot, versions, the observation layout and what a
    robot-side runtime needs besides it (goal radius; ``goal_distance_max``, the goal-distance scale
    inside the network, when known). Keys are only ever added, so older files stay readable."""
    s, lidar, m = preset.lidar.sectors, preset.lidar, preset.motion
    velocity = ["v", "w"] if m.velocity_state_dims == 2 else ["vx", "vy", "w"]
    base, k = preset.base_obs_dim, preset.observation.scan_history
    units = {"v": "m/s", "vx": "m/s", "vy": "m/s", "w": "rad/s"}
    return {
        "format_version": POLICY_FORMAT_VERSION,
        "flashnav_version": flashnav.__version__,
        "torch_version": torch.__version__,
        "robot": preset.name,
        "obs_dim": preset.obs_dim,
        "action_dim": 2,
        "control_period_s": preset.episode.dt,
        # the episode's goal radius (metres): a deployed robot stops when closer than this
        "goal_threshold": preset.episode.goal_threshold,
        "inputs": {"obs": "[N, obs_dim] float32, physical units, layout in 'observation'"},
        "outputs": {"action": "[N, 2] float32 in [-1, 1] (v, w)",
                    "command": "[N, 2] float32 (v m/s, w rad/s), the action mapped onto the robot's bounds"},
        "observation": {
            "lidar": {"columns": [0, s], "units": "m", "range": [0.0, lidar.max_range],
                      "pooling": f"minimum over {lidar.beams_per_sector} consecutive beams per sector",
                      "beams": lidar.beams, "fov_deg": lidar.fov_deg,
                      "order": "sector 0 starts at -fov/2 (the robot's right), counter-clockwise",
                      "inscribed_radius": preset.footprint.inscribed_radius},
            "goal_distance": {"column": s, "units": "m"},
            "goal_angle": {"column": s + 1, "units": "rad", "range": [-math.pi, math.pi],
                           "convention": "robot frame, positive = left"},
            "velocity": {"columns": [s + 2, base], "names": velocity,
                         "units": [units[v] for v in velocity],
                         "meaning": "the command executed in the last control step (0 after a reset)"},
            # always written (0 = none), so a reader can tell a history-free policy from an old file
            "scan_history": {"frames": k, "columns": [base, preset.history_end], "units": "m",
                             "order": "frame j (0-based) is the pooled scan of j + 1 control steps ago, "
                                      "newest first; each frame has the 'lidar' sector layout",
                             "reset": "a new episode (goal) fills every frame with its first scan"},
            # always written (0 = none): the people tracker's input (flashnav.sim.tracks)
            "agent_tracks": {"count": preset.observation.agent_tracks,
                             "columns": [preset.history_end, preset.tracks_end], "features": list(TRACK_FEATURES),
                             "units": ["1", "m", "m", "m/s", "m/s", "m"],
                             "frame": "robot frame: x ahead, y to the left; velocity rotated into it",
                             "order": "nearest first by the distance from the robot's centre to the agent's "
                                      "edge; absent tracks are all zero",
                             "velocity": "displacement over the last control step / control_period_s; 0 for an "
                                         "agent not seen at the previous step"},
            # always written (0 = none): the robot's own earlier positions from odometry (flashnav.sim.trail)
            "pose_trail": {"count": preset.observation.pose_trail, "every": preset.observation.trail_every,
                           "columns": [preset.tracks_end, preset.trail_end], "features": ["x", "y"], "units": "m",
                           "frame": "robot frame of the current pose: x ahead, y to the left",
                           "order": "breadcrumb j (0-based) newest first; a breadcrumb is the position after "
                                    "every 'every'-th control step of the episode",
                           "reset": "a new episode (goal) sets every breadcrumb to the start position"},
            # always written (0 = none): the point along the wall map's plan (flashnav.maps.seen_plan.carrot_points)
            "carrot": {"length_m": preset.observation.wall_map_carrot,
                       "columns": [preset.trail_end, preset.carrot_end], "features": ["x", "y"], "units": "m",
                       "frame": "robot frame of the current pose: x ahead, y to the left",
                       "meaning": "the centre of the first grid_m cell of the wall map's plan at least length_m "
                                  "of path (moves of 1 and sqrt 2 cells) from the robot's cell; the goal where the "
                                  "plan is shorter or there is none; brought within length_m of the robot along "
                                  "its bearing"},
            # always written (0 = none): the memory scan of remembered wall hits (flashnav.sim.memory)
            "memory_scan": {"frames": preset.observation.memory_frames, "every": preset.observation.memory_every,
                            "points_per_frame": points_per_frame(preset),
                            "columns": [preset.carrot_end, preset.memory_end], "units": "m",
                            "order": "sector j covers bearings [-pi + j w, -pi + (j + 1) w), w = 2 pi / columns, in "
                                     "the robot frame (from straight behind, counter-clockwise); max_range where "
                                     "nothing is remembered",
                            "meaning": "distance to the nearest wall hit stored in the last 'frames' stored scans; "
                                       "a scan is stored after every 'every'-th control step of the episode, as "
                                       "'points_per_frame' points (the nearest hit of each group of consecutive beams)",
                            "reset": "a new episode (goal) stores its first scan and forgets the rest"},
            # always written (0 = none): the egocentric wall map (flashnav.sim.wall_grid.WallGrid, wall_image)
            "wall_map": {"cells": preset.observation.wall_map, "cell_m": preset.observation.wall_map_cell,
                         "grid_m": preset.observation.wall_map_grid, "beyond_m": HIT_BEYOND_M,
                         "columns": [preset.memory_end, preset.obs_dim],
                         "channels": list(wall_map_channel_names(preset.observation.wall_map,
                                                                preset.observation.wall_map_visited,
                                                                preset.observation.wall_map_plan)),
                         "order": "channel by channel, then row by row: square (row i, column j) spans "
                                  "[(i - cells / 2) cell_m, (i + 1 - cells / 2) cell_m) to the left of the robot "
                                  "(row 0 rightmost) and [(j - cells / 2) cell_m, (j + 1 - cells / 2) cell_m) ahead",
                         "meaning": "walls: 1 where the centre of a grid_m cell that a LiDAR beam ended in (beyond_m "
                                    "past its return) during this episode lies in the square, else 0 (unknown reads "
                                    "as free); goal: 1 in the goal's square, clipped onto the edge when farther; "
                                    "visited (when listed): 1 where the centre of a grid_m cell that the robot's "
                                    "centre was in at a control step of this episode lies in the square; plan "
                                    "(when listed): 1 where the centre of a grid_m cell of the shortest "
                                    "8-connected way from the robot's cell to the goal's over the cells not marked "
                                    "as walls (unknown free; flashnav.maps.seen_plan, within plan_margin_m of both; "
                                    "with plan_penalty > 0 the cheapest way, a move into a cell beside a marked one "
                                    "costing 1 + plan_penalty times its length) lies in the square",
                         "plan_margin_m": PLAN_MARGIN_M,
                         "plan_penalty": preset.observation.wall_map_plan_penalty,
                         "reset": "a new episode (goal) forgets every wall (and every visited cell) and marks "
                                  "its first scan (and its start)"},
        },
        "command_bounds": {"v": list(m.v_bounds), "w": list(m.w_bounds),
                           "max_linear_velocity": m.max_linear_velocity,
                           "max_angular_velocity": m.max_angular_velocity},
        # the exact robot the policy was exported for, so a custom preset can be rebuilt from the file
        "preset": preset.model_dump(mode="json"),
    } | ({} if goal_distance_max is None else {"goal_distance_max": goal_distance_max})


def export_policy(actor: nn.Module, preset: RobotPreset, out_dir: str | Path, onnx: bool = True) -> dict[str, Path]:
    """Write ``policy.pt`` (TorchScript), ``policy.onnx`` and ``policy.json`` (the metadata) to ``out_dir``.

    ``actor``: an :class:`Actor` or a :class:`DeterministicActor` (``obs [N, D] -> action [N, 2]``)
    on any device; a frozen CPU copy is exported. Both files are checked against the eager policy on
    a probe batch before returning. ``onnx=False`` skips ONNX (needs ``pip install 'flashnav[export]'``).

    Returns ``{"torchscript": path, "onnx": path, "metadata": path}`` (``onnx`` absent when skipped).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    module = DeployablePolicy(copy.deepcopy(actor).cpu(), preset).cpu().eval()
    module.requires_grad_(False)
    goal_max = goal_distance_scale(actor, preset)
    meta = policy_metadata(preset, goal_distance_max=goal_max)
    meta_json = json.dumps(meta, indent=1)
    gen = torch.Generator().manual_seed(0)
    example = sample_observations(preset, 8, gen, goal_max)

    paths: dict[str, Path] = {"torchscript": out_dir / POLICY_TORCHSCRIPT, "metadata": out_dir / POLICY_METADATA}
    # torch.jit.script cannot compile IPAPRec (it reads a module-level float); tracing is exact here
    # because the forward pass has no value-dependent control flow. The deprecation warnings of
    # torch.jit / the TorchScript ONNX exporter are expected and would only confuse the user.
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        traced = torch.jit.trace(module, (example,), check_inputs=[(example[:1],), (example[:5],)])
        torch.jit.save(traced, str(paths["torchscript"]), _extra_files={METADATA_KEY: meta_json})
        if onnx:
            paths["onnx"] = out_dir / POLICY_ONNX
            _export_onnx(module, example, paths["onnx"], meta_json)
    paths["metadata"].write_text(meta_json + "\n", encoding="utf-8")

    probe = sample_observations(preset, 64, gen, goal_max)
    with torch.no_grad():
        expected = module(probe)[0]
    for kind in ("torchscript", "onnx"):
        if kind in paths:
            got = load_policy(paths[kind])[0](probe)
            err = float((got - expected).abs().max())
            if not err <= EXPORT_CHECK_TOL:
                raise RuntimeError(f"{paths[kind]}: exported policy differs from the eager one by {err:.3g}")
    return paths


def _export_onnx(module: nn.Module, example: torch.Tensor, path: Path, meta_json: str) -> None:
    """ONNX through the TorchScript-based exporter (``dynamo=False``): the torch.export-based
    default needs onnxscript, which FlashNav does not depend on. The batch axis is dynamic."""
    try:
        import onnx
    except ImportError:
        raise ImportError("ONNX export needs the onnx package: pip install 'flashnav[export]'") from None
    batch = {0: "batch"}
    torch.onnx.export(module, (example,), str(path), dynamo=False, opset_version=ONNX_OPSET,
                      input_names=["obs"], output_names=["action", "command"],
                      dynamic_axes={"obs": batch, "action": batch, "command": batch})
    model = onnx.load(str(path))
    entry = model.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, meta_json
    model.producer_name = f"flashnav {flashnav.__version__}"
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def goal_distance_scale(actor: nn.Module, preset: RobotPreset) -> float:
    """The goal-distance scale (metres) the actor's input transform was built with: the training
    map's diagonal. An actor without an :class:`IPAPRec` falls back to the preset's map size."""
    from flashnav.learn.networks import IPAPRec

    for module in actor.modules():
        if isinstance(module, IPAPRec):
            return float(1.0 / module.inv_scale[0])
    return math.hypot(*preset.map_size)


# ---- loading -------------------------------------------------------------------------------------
def recorded_robot(meta: dict[str, Any]) -> "str | RobotPreset":
    """The robot a loaded policy was exported for, from its metadata (:func:`load_policy`): the exact preset it
    recorded (observation options such as a scan history or a pose trail included, so custom robots need no YAML
    at hand), else, for files written before presets were recorded, its robot's name. Pass it to
    :func:`flashnav.presets.load_robot` (with overrides) or :func:`flashnav.sim.env.make_env`."""
    if "preset" in meta:
        return RobotPreset.model_validate(meta["preset"])
    return meta["robot"]


def evaluated_robot(meta: dict[str, Any], **overrides: Any) -> RobotPreset:
    """The preset an evaluation of a loaded policy plays (as ``flashnav eval`` does): its :func:`recorded_robot` with
    ``overrides`` (dotted preset keys, e.g. ``**{"lidar.noise_std": 0.3}``), scored with the paper's reward and the
    task's own episode draws (:func:`flashnav.sim.goal_fields.evaluation_preset`)."""
    from flashnav.presets import load_robot
    from flashnav.sim.goal_fields import evaluation_preset

    return evaluation_preset(load_robot(recorded_robot(meta), **overrides))


def load_policy(path: str | Path, robot: "str | RobotPreset | None" = None,
                device: torch.device | str = "cpu") -> tuple[Callable[[torch.Tensor], torch.Tensor], dict[str, Any]]:
    """Load ``policy.pt`` (TorchScript) or ``policy.onnx`` (onnxruntime, CPU); a run folder gives its ``policy.pt``
    (else its ``policy.onnx``).

    Returns ``(policy, metadata)``: ``policy(obs [N, D] float32 tensor) -> action [N, 2]`` float32 in
    [-1, 1] on ``obs.device`` (a numpy array in, a numpy array out); ``metadata`` is the JSON written by
    :func:`export_policy` (``robot``, ``obs_dim``, the observation layout, ...). ``robot`` (a preset name, YAML or RobotPreset), when
    given, must have the policy's observation size.

    Raises:
        FileNotFoundError: no such file.
        ValueError: a suffix other than .pt/.onnx, a file without FlashNav metadata, or an obs-dim
            mismatch (with ``robot`` at load time, with the observation at call time).
    """
    path = Path(path)
    if path.is_dir():  # a `flashnav train` run folder: its best policy, TorchScript first
        found = [path / name for name in (POLICY_TORCHSCRIPT, POLICY_ONNX) if (path / name).is_file()]
        if not found:
            raise FileNotFoundError(f"{path}: a folder without policy.pt or policy.onnx (give a flashnav train run "
                                    "folder or a policy file)")
        path = found[0]
    if path.suffix not in (".pt", ".onnx"):
        raise ValueError(f"{path}: unknown policy format {path.suffix!r}; expected policy.pt (TorchScript) or policy.onnx")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such policy file")
    if isinstance(device, str):  # "cuda" without a GPU, or "gpu": named as the device, not as the file's fault
        from flashnav.machine import resolve_device

        device = resolve_device(device)
    run, meta = _load_onnx(path) if path.suffix == ".onnx" else _load_torchscript(path, device)
    obs_dim = int(meta["obs_dim"])
    if robot is not None:
        from flashnav.presets import load_robot

        preset = load_robot(robot)
        if preset.obs_dim != obs_dim:
            raise ValueError(f"{path}: the policy expects obs_dim {obs_dim} ({meta.get('robot')}), but robot "
                             f"{preset.name!r} produces obs_dim {preset.obs_dim}")

    def policy(obs):
        if not isinstance(obs, torch.Tensor):  # numpy (what the Gymnasium envs hand out): numpy back
            return policy(torch.from_numpy(np.asarray(obs, dtype=np.float32))).numpy()
        if obs.ndim != 2 or obs.shape[1] != obs_dim:
            raise ValueError(f"{path}: expected observations [N, {obs_dim}], got {list(obs.shape)}")
        return run(obs)

    return policy, meta


def _load_torchscript(path: Path, device: torch.device | str):
    extra = {METADATA_KEY: ""}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            module = torch.jit.load(str(path), map_location=device, _extra_files=extra)
    except RuntimeError as exc:  # torch reports a corrupt or foreign file as a RuntimeError
        if is_checkpoint(path):
            raise ValueError(f"{path}: a FlashNav training checkpoint, not an exported policy; evaluate the "
                             "policy.pt or policy.onnx that flashnav train writes next to it") from None
        raise ValueError(f"{path}: not a readable TorchScript policy ({first_sentence(exc)})") from None
    meta = _parse_metadata(path, extra[METADATA_KEY])
    module.eval()
    device = torch.device(device)

    @torch.no_grad()
    def run(obs: torch.Tensor) -> torch.Tensor:
        return module(obs.to(device, torch.float32))[0].to(obs.device)

    return run, meta


def _load_onnx(path: Path):
    session, meta = open_onnx(path)

    def run(obs: torch.Tensor) -> torch.Tensor:
        x = obs.detach().to("cpu", torch.float32).contiguous().numpy()
        action = session.run(["action"], {"obs": x})[0]
        return torch.from_numpy(action).to(obs.device)

    return run, meta
