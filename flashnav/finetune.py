"""Fine-tuning: a run that starts from a trained learner (``TrainConfig.init_from``, ``flashnav train
--init-from RUN_DIR_OR_CHECKPOINT``).

:func:`flashnav.spec.resolve` calls :func:`load_init_source` and :func:`check_compatible`; the
training loop calls :func:`load_learner`. What carries over is everything in the checkpoint's learner
state dict (``Learner.state_dict()``): the networks (actor, collector copy, critics, target critics,
the averaged policy, the input transforms with their running feature statistics), the optimisers'
moments and step counts, the temperature and its optimiser, FastDSAC's running critic std, the update
counter (the actor schedule continues) and the RNG streams of collection and updates. What does not:

- the replay buffer, unless asked for: checkpoints do not store one (it holds ``buffer_size`` transitions,
  100 MB and more for the paper recipes), so a fine-tuning run starts with an empty replay and warms up for
  ``learning_start`` transitions, as any run. A run trained with ``flashnav train --save-replay`` has its
  buffer in ``replay.pt`` beside the checkpoint, and ``init_replay`` (``--init-replay``) starts from it
  too (:meth:`flashnav.learn.replay.Replay.load_state_dict`: the same envs and observation layout; the
  newest rows where this run's buffer is smaller; every env's last stored step an episode end, since the
  environments start afresh): a run continued on its own maps then learns on without a new warm-up;
- the optimisers' hyperparameters (learning rates, betas, weight decay, fused/foreach) and the
  temperature's target entropy: they are this run's, so ``algo.actor_lr=...`` takes effect (with the
  same hyperparameters the loaded state equals the checkpoint's bit for bit);
- per-environment exploration scales (FastDSAC's ``dem_scale``, FastTD3's ``noise_std``, ``[N, 1]``)
  when this run has another ``num_envs``: they are drawn afresh for the new N (with the same N they
  are the checkpoint's).

The network shapes must match (:func:`check_compatible` names every mismatched key), and the
goal-distance scale of the observation is the checkpoint's run's (``RunSpec.goal_distance_max``), not
the new map's diagonal: the network keeps reading goal distances on the scale it was trained on.
:func:`check_goal_scale` refuses new maps only where a *sampled episode* could start farther from its
goal than that scale: the start-goal distance is bounded by the episode band (euclidean: the
straight-line ``max_goal_distance``; geodesic: the path-length band, an upper bound on the straight
line), not by the map's size, so a larger building is accepted. There, a robot that wanders farther
from its goal than the scale sees a goal-distance feature above 1 (the network extrapolates, as it
does for any input beyond its training range); within the band it sees exactly the values it knows.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from flashnav.names import CHECKPOINT_FILE as CHECKPOINT_NAME  # the checkpoint file a run folder holds
from flashnav.names import REPLAY_FILE
#: Per-environment exploration state in ``state_dict()["algo"]`` (shape ``[num_envs, 1]``).
PER_ENV_STATE = ("dem_scale", "noise_std")
#: Optimiser param-group settings that belong to the run, not to the checkpoint.
RUN_OPTIMISER_SETTINGS = ("lr", "betas", "weight_decay", "fused", "foreach", "capturable", "differentiable")


@dataclass(frozen=True)
class InitSource:
    """Where a fine-tuning run's learner comes from: ``path`` (the checkpoint file, absolute) and
    ``run`` (its run's seed, algorithm, robot, recipe, goal_distance_max, date and FlashNav version,
    as far as the checkpoint records them). ``learner_state``: the learner state dict (None for a
    spec read back from a config.yaml; :meth:`state` then reads the file again)."""

    path: str
    run: dict[str, Any]
    learner_state: dict[str, Any] | None = field(default=None, repr=False, compare=False)
    replay: str | None = None  # with init_replay: the run's replay.pt (absolute), loaded when training starts

    def state(self) -> dict[str, Any]:
        if self.learner_state is not None:
            return self.learner_state
        from flashnav.checkpoint import load_checkpoint

        return load_checkpoint(self.path)["learner"]

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, **({"replay": self.replay} if self.replay else {}), **self.run}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "InitSource":
        data = dict(data)
        return cls(str(data.pop("path")), data, replay=data.pop("replay", None))


def checkpoint_file(source: str | Path, name: str = "init_from") -> Path:
    """A run directory -> its ``checkpoint.pt``; a file -> itself. FileNotFoundError or ValueError naming it, as
    ``name`` (the option or argument that gave it), otherwise."""
    path = Path(source).expanduser()
    if path.is_dir():
        path = path / CHECKPOINT_NAME
        if not path.is_file():
            raise FileNotFoundError(f"{name} {str(source)!r}: a folder without {CHECKPOINT_NAME} "
                                    "(give a flashnav train run folder or a checkpoint file)")
        return path.resolve()
    if not path.is_file():
        raise FileNotFoundError(f"{name} {str(source)!r}: no such run folder or checkpoint file")
    from flashnav.checkpoint import is_torchscript

    if path.suffix == ".json":
        raise ValueError(f"{name} {str(source)!r}: a JSON file (a policy's metadata or a run's metrics), not a "
                         f"learner checkpoint: give its run folder or its {CHECKPOINT_NAME}")
    if path.suffix in (".yaml", ".yml"):
        raise ValueError(f"{name} {str(source)!r}: a YAML file (a run's config.yaml: --config takes it), not a "
                         f"learner checkpoint: give its run folder or its {CHECKPOINT_NAME}")
    if path.suffix == ".onnx" or is_torchscript(path):
        raise ValueError(f"{name} {str(source)!r}: an exported policy, which holds the actor only, not the "
                         f"learner (critics, optimisers, temperature): give its run folder or its {CHECKPOINT_NAME}")
    return path.resolve()


def load_init_source(source: str | Path | None, read_spec: Callable[..., Any], replay: bool = False):
    """(:class:`InitSource`, the checkpoint's run spec) for ``init_from``; ``read_spec`` is
    :meth:`flashnav.spec.RunSpec.from_dict` (passed in: the spec module imports this one). ``replay``
    (``init_replay``): the source's run folder must hold its ``replay.pt`` too (read when training starts)."""
    from flashnav.checkpoint import load_checkpoint

    if source is None:
        raise ValueError("init_replay needs init_from: the run (trained with --save-replay) whose replay to start from")
    path = checkpoint_file(source)
    replay_path = path.parent / REPLAY_FILE
    if replay and not replay_path.is_file():
        raise FileNotFoundError(f"init_from {str(source)!r} with init_replay: no {REPLAY_FILE} in {path.parent} "
                                "(a run writes it with flashnav train --save-replay)")
    payload = load_checkpoint(path)
    spec = read_spec(payload["config"], source=f"{path} (its run config)")
    if payload["learner"].get("algorithm") != spec.algorithm:
        raise ValueError(f"{path}: the learner state is for {payload['learner'].get('algorithm')!r} but its run "
                         f"config says {spec.algorithm!r}")
    extra = payload.get("extra") or {}
    saved = extra.get("saved_at") or dt.datetime.fromtimestamp(path.stat().st_mtime).isoformat(timespec="seconds")
    run = {"seed": spec.seed, "algorithm": spec.algorithm, "robot": spec.robot_name, "recipe": spec.recipe,
           "goal_distance_max": spec.goal_distance_max, "saved_at": saved,
           "saved_at_source": "checkpoint" if extra.get("saved_at") else "file modification time",
           "flashnav_version": payload.get("flashnav_version")}
    return InitSource(str(path), run, payload["learner"], str(replay_path) if replay else None), spec


def _layout_keys(robot) -> dict[str, Any]:
    """The robot's observation layout as the networks see it, by the key that sets each value."""
    return {
        "robot.lidar.sectors": robot.lidar.sectors,
        "robot.lidar.max_range": robot.lidar.max_range,
        "robot.footprint (inscribed radius)": robot.footprint.inscribed_radius,
        "robot.motion.velocity_state_dims": robot.motion.velocity_state_dims,
        "robot.motion.v_bounds (velocity scale)": max(abs(b) for b in robot.motion.v_bounds),
        "robot.motion.w_bounds (velocity scale)": max(abs(b) for b in robot.motion.w_bounds),
        "robot.observation.scan_history": robot.observation.scan_history,
        "robot.observation.agent_tracks": robot.observation.agent_tracks,
        "robot.observation.pose_trail": robot.observation.pose_trail,
        "robot.observation.trail_every (trail scale)": robot.observation.trail_every,
        "robot.observation.memory_frames (on/off)": robot.observation.memory_frames > 0,
        "robot.observation.wall_map": robot.observation.wall_map,
        "robot.observation.wall_map_visited": robot.observation.wall_map_visited,
        "robot.observation.wall_map_plan": robot.observation.wall_map_plan,
        "robot.observation.wall_map_plan_penalty": robot.observation.wall_map_plan_penalty,
        "robot.observation.wall_map_carrot": robot.observation.wall_map_carrot,
    }


def _shape_keys(algorithm: str, hp) -> dict[str, Any]:
    """The hyperparameters that decide the learner state's shapes or what its networks' inputs and outputs mean
    (the goal angle's features, the action the tanh output maps to), by their ``algo.`` key."""
    keys = {"algorithm": algorithm, "algo.actor_hidden": tuple(hp.actor_hidden),
            "algo.critic_hidden": tuple(hp.critic_hidden), "algo.layer_norm": hp.layer_norm,
            "algo.obs_norm": hp.obs_norm, "algo.policy_averaging (on/off)": hp.policy_averaging > 0,
            "algo.goal_sincos": hp.goal_sincos, "algo.action_headroom": hp.action_headroom}
    if hasattr(hp, "num_atoms"):
        keys["algo.num_atoms"] = hp.num_atoms
    return keys


def check_compatible(checkpoint_spec, algorithm: str, hp, robot, source: str, recipe: str | None = None) -> None:
    """A ValueError naming every key where this run's networks would differ in shape or input layout
    from the checkpoint's (``checkpoint_spec``: its RunSpec), and the flags that would make this run the checkpoint's
    robot, algorithm and ``recipe`` where they differ (most mismatches follow from those); nothing when they match."""
    ours = {**_shape_keys(algorithm, hp), **_layout_keys(robot)}
    theirs = {**_shape_keys(checkpoint_spec.algorithm, checkpoint_spec.hparams), **_layout_keys(checkpoint_spec.robot)}
    if robot.observation.wall_map or checkpoint_spec.robot.observation.wall_map:  # the map's CNN, where one reads it
        ours["algo.wall_map_convs"] = tuple(tuple(c) for c in hp.wall_map_convs)
        theirs["algo.wall_map_convs"] = tuple(tuple(c) for c in checkpoint_spec.hparams.wall_map_convs)
    bad = [f"{key}: checkpoint {theirs.get(key)!r}, this run {value!r}" for key, value in ours.items()
           if theirs.get(key) != value]
    if bad:
        flags = [f"{flag} {theirs_}" for flag, theirs_, ours_ in (
            ("--robot", checkpoint_spec.robot_name, robot.name), ("--algo", checkpoint_spec.algorithm, algorithm),
            ("--recipe", checkpoint_spec.recipe, recipe)) if ours_ is not None and theirs_ != ours_]
        fix = (f"train with {' '.join(flags)} as the checkpoint's run did" if flags
               else "set them as the checkpoint's run did")
        raise ValueError(f"init_from {source}: this run's networks do not match the checkpoint's "
                         f"({checkpoint_spec.robot_name} / {checkpoint_spec.algorithm}, {checkpoint_spec.recipe} "
                         f"recipe): {'; '.join(bad)} ({fix})")


def goal_band_top(robot) -> float:
    """The largest start-goal distance a sampled episode can have, metres: the goal band's top
    (euclidean: ``max_goal_distance``; geodesic: the horizon-capped path-length band, an upper bound
    on the straight line)."""
    if robot.episode.goal_sampling == "geodesic":
        from flashnav.sim.sampling import geodesic_band

        return geodesic_band(robot)[1]
    return robot.episode.max_goal_distance


def check_goal_scale(scale: float, robot, source: str) -> None:
    """Refuse a run whose episodes could start farther from their goal than the checkpoint's
    goal-distance scale ``scale`` (metres); see the module docstring."""
    top = goal_band_top(robot)
    if top > scale:
        raise ValueError(
            f"init_from {source}: episodes of this run start up to {top:g} m from their goal "
            f"(robot.episode.max_goal_distance / goal_sampling), beyond the {scale:g} m goal-distance scale the "
            f"checkpoint's network was trained with (its run's goal_distance_max); lower the band's top")


def load_learner(learner, init: InitSource) -> None:
    """Load ``init``'s learner state into ``learner`` (built for this run), in place; see the module
    docstring for what is kept of this run (optimiser settings, per-env scales of another N)."""
    data = dict(init.state())
    algo = dict(data.get("algo") or {})
    current = learner.state_dict()
    for key in PER_ENV_STATE:
        if key in algo and key in current["algo"] and tuple(algo[key].shape) != tuple(current["algo"][key].shape):
            algo[key] = current["algo"][key]
    if "temperature" in algo and "temperature" in current["algo"]:  # a constant of this run's hyperparameters
        algo["temperature"] = {**algo["temperature"],
                               "target_entropy": current["algo"]["temperature"]["target_entropy"]}
    data["algo"] = algo
    from flashnav.learn.common import optimizers

    optimisers = optimizers(learner.state)  # every optimiser of the state, nested temperature included
    settings = [[{k: g[k] for k in RUN_OPTIMISER_SETTINGS if k in g} for g in opt.param_groups] for opt in optimisers]
    learner.load_state_dict(data)
    for opt, groups in zip(optimisers, settings):
        for group, keep in zip(opt.param_groups, groups):
            group.update(keep)
