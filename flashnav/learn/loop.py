"""The training loop: collect -> store -> U updates, evaluated on a fixed set of episodes.

One *cycle* is one vector step of collection (act, env.step, store) plus the U gradient updates of
that step. With ``spec.overlap`` (``TrainConfig.overlap``; auto = on for cuda) the collector runs in a
second thread with its own actor weight copy (synced every ``env_steps_per_sync`` cycles) while the
learner updates on batches sampled before the collector's step, so the cycle takes as long as the
slower side (the paper's producer-consumer pipeline; on a CPU each side gets one core). Without it
(auto on a CPU) the same work runs in the same order in one thread, collector then learner, each on
every core the process has: on a CPU the collector is a small part of the cycle, and the learner's
matrix products gain more from the second core than the overlap saves (docs/benchmarks.md).

With ``spec.cuda_graph`` (``TrainConfig.cuda_graph``; auto = on for cuda) the replay gathers each
cycle's batches into static buffers and the U updates run through
:class:`flashnav.learn.cuda_graph.CycleUpdates`: captured once as a CUDA graph and replayed on a GPU
(the capture cycle runs without the collector beside it), the same updates eagerly on a CPU.
On a GPU the collector's kernels go to a stream of its own, ordered after the cycle's sample and
weight sync and before the next sample.

The training clock counts cycles only (the device synchronised before it is read): never
evaluation, logging, progress or the ``on_eval`` callback.
"""

from __future__ import annotations

import copy
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import torch

from flashnav.checkpoint import load_replay
from flashnav.eval_maps import EvalSet
from flashnav.evaluate import ThresholdTracker, TrainingEpisodes, evaluate
from flashnav.finetune import load_learner
from flashnav.learn.cuda_graph import CycleUpdates
from flashnav.learn.learners import Learner, make_learner
from flashnav.learn.mirror import mirror_for
from flashnav.learn.wall_shift import wall_shift_for
from flashnav.learn.networks import ObsLayout
from flashnav.learn.replay import Replay
from flashnav.learn.precision import update_precision
from flashnav.machine import learner_threads, machine_name, numba_threads
from flashnav.maps.stream import GeneratedMaps, MapStream, generation_radius
from flashnav.metrics import reaches
from flashnav.names import SNAPSHOT_STOP_REASON
from flashnav.sim.env import NavVecEnv
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.spec import RunSpec, TrainConfig, resolve


@dataclass
class TrainResult:
    """What a run produced. ``to_dict()`` is what ``metrics.json`` holds (see docs/train-api.md)."""

    curve: list[dict[str, float]]
    time_to_threshold: dict[float, float | None]
    env_steps_to_threshold: dict[float, int | None]
    cycle: dict[str, float]
    train_seconds: float
    env_steps: int
    spec: RunSpec
    device_name: str
    stop_reason: str
    best_success_rate: float = 0.0
    threads: int | None = None  # the learner's torch CPU threads (None on a GPU); device_name is the machine
    # the same thresholds read from the training episodes' success between evaluations (curve's
    # train_success_rate): the rolling count of some references, not the evaluation (docs/learners.md S1)
    training_episodes_to_threshold: dict[str, dict[float, Any]] = field(default_factory=dict)
    learner: Learner | None = field(default=None, repr=False)
    best_policy: torch.nn.Module | None = field(default=None, repr=False)
    replay: Replay | None = field(default=None, repr=False)  # with train(keep_replay=True): the run's buffer

    @property
    def policy(self) -> torch.nn.Module | None:
        """The deterministic policy of the best evaluation (ties: the earliest), else the final one."""
        if self.best_policy is not None:
            return self.best_policy
        return None if self.learner is None else self.learner.policy

    def to_dict(self) -> dict[str, Any]:
        return {
            "curve": self.curve,
            "time_to_threshold": {str(k): v for k, v in self.time_to_threshold.items()},
            "env_steps_to_threshold": {str(k): v for k, v in self.env_steps_to_threshold.items()},
            "training_episodes_to_threshold": {what: {str(k): v for k, v in d.items()}
                                               for what, d in self.training_episodes_to_threshold.items()},
            "cycle": self.cycle,
            "train_seconds": self.train_seconds,
            "env_steps": self.env_steps,
            "device_name": self.device_name,
            "threads": self.threads,
            "stop_reason": self.stop_reason,
            "best_success_rate": self.best_success_rate,
            "config": self.spec.to_dict(),
        }


class _Timer:
    """Accumulates seconds of a side of the cycle (its CUDA stream synchronised at the end of each span:
    one host sync per side per cycle, the price of an honest clock; see the README's notes on GPUs)."""

    def __init__(self, device: torch.device):
        self.device, self.total, self.count = device, 0.0, 0

    def __enter__(self):
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        if self.device.type == "cuda":  # this side's stream only: the other side keeps running
            torch.cuda.current_stream(self.device).synchronize()
        self.total += time.perf_counter() - self._t0
        self.count += 1

    @property
    def mean_ms(self) -> float:
        return 1e3 * self.total / max(self.count, 1)


def train(config: TrainConfig | RunSpec | None = None, *, on_eval: Callable[[dict], bool | None] | None = None,
          on_progress: Callable[[dict], None] | None = None, interruptible: bool = False,
          on_snapshot: Callable[[TrainResult], None] | None = None, snapshot_every: float = 600.0,
          keep_replay: bool = False) -> TrainResult:
    """Train one policy; see docs/train-api.md. ``config``: a TrainConfig (resolved here by
    :func:`flashnav.spec.resolve`) or an already resolved RunSpec. ``on_progress`` (optional, outside
    the clock) gets a dict with env_steps, max_env_steps (the budget's), train_seconds and the last evaluation
    after every cycle.
    ``interruptible``: a KeyboardInterrupt (Ctrl-C) during the cycles ends the run like a budget
    (``stop_reason`` "interrupted", the curve and best policy so far kept) instead of propagating;
    ``flashnav train`` sets it, so a stopped run still writes its artefacts. Off by default: a sweep
    or script that calls train() keeps Ctrl-C for itself. ``on_snapshot`` (optional, outside the clock) gets
    the run so far as a TrainResult with ``stop_reason`` "running" after an evaluation, at most once per
    ``snapshot_every`` wall-clock seconds (0: after every evaluation), so that a caller can keep it on disk
    against a crash; ``flashnav train --save-every`` writes it to the run folder. ``keep_replay``: the results
    (snapshots too) carry the replay buffer (``TrainResult.replay``, for ``save_run(..., replay=True)``,
    ``flashnav train --save-replay``); off by default, so that a caller keeping a result does not keep its
    buffer (hundreds of MB and more) alive."""
    if not snapshot_every >= 0:
        raise ValueError(f"snapshot_every must be >= 0 seconds, got {snapshot_every}")
    spec = config if isinstance(config, RunSpec) else resolve(config)
    threads_before = torch.get_num_threads()
    try:
        return _train(spec, on_eval, on_progress, interruptible, threads_before, on_snapshot, snapshot_every,
                      keep_replay)
    finally:
        torch.set_num_threads(threads_before)


def _train(spec: RunSpec, on_eval, on_progress, interruptible: bool = False, threads: int | None = None,
           on_snapshot=None, snapshot_every: float = 600.0, keep_replay: bool = False) -> TrainResult:
    config, preset, hp = spec.config, spec.robot, spec.hparams
    dev = torch.device(spec.device)
    torch.manual_seed(config.seed)
    grid = spec.env_maps()
    env = NavVecEnv(preset, hp.num_envs, grid=grid, device=dev, seed=config.seed, raycaster=config.raycaster,
                    map_weights=config.map_weights)
    play_eval = _eval_set(spec, grid, dev)
    count = spec.threads or (threads if dev.type == "cpu" else None)
    if count:
        # After the environments exist: the first numba parallel kernel of a process starts its
        # OpenMP pool, which resets the thread count torch shares with it (the first run of every
        # process used to learn on 2 threads, competing with the collector for the same cores).
        # Without a count of the spec's, a CPU learner keeps the count train() was called with.
        torch.set_num_threads(count)
    learner = run_learner(spec, dev)
    cycles = math.ceil(spec.max_env_steps / hp.num_envs)
    maps = _map_stream(spec, cycles)
    replay = Replay(hp.num_envs, preset.obs_dim, 2, hp.buffer_size, dev, seed=config.seed,
                    n_step=hp.n_step, gamma=hp.gamma, mirror=mirror_for(preset, hp.mirror, dev),
                    wall_shift=wall_shift_for(preset, hp.wall_shift),
                    binary_columns=preset.obs_dim - preset.memory_end)  # the wall map's 0 / 1 squares, as uint8
    if spec.init is not None and spec.init.replay is not None:  # config.init_replay: the run's transitions too
        replay.load_state_dict(load_replay(spec.init.replay), spec.init.replay)
    # The static-buffer updates of one batch size; with algo.late_batch_size they are replaced (and, on a
    # GPU, captured anew) for the late batch when the run gets there.
    def static_updates(batch_size: int) -> CycleUpdates:
        return CycleUpdates(learner, preset.obs_dim, 2, batch_size, hp.updates_per_step, capture=dev.type == "cuda")

    updates = static_updates(hp.batch_size) if spec.cuda_graph else None

    eval_every = spec.eval_every
    overlap = spec.overlap
    collect_t, learn_t, cycle_t = _Timer(dev), _Timer(dev), _Timer(dev)
    learning_cycles = _Timer(dev)  # cycles with updates: the paper's cycle (warm-up excluded)
    tracker, train_tracker = ThresholdTracker(), ThresholdTracker()
    episodes = TrainingEpisodes(dev, config.eval.training_episodes)
    curve: list[dict[str, float]] = []
    obs_box = [env.reset(seed=config.seed)[0]]

    # On a GPU the collector thread issues its kernels on a stream of its own, so they can run
    # beside the learner's: it waits for the cycle's sample and collector sync (it overwrites the
    # replay's oldest rows and reads the collector's weights), and the next sample waits for it.
    collector_stream = torch.cuda.Stream(dev) if overlap and dev.type == "cuda" else None

    def collect() -> None:
        if collector_stream is not None:
            with torch.cuda.stream(collector_stream):
                _collect()
        elif overlap and dev.type == "cpu":
            with numba_threads(1):  # the learner owns the other core (also the warm-up's main thread: restored)
                _collect()
        else:
            _collect()

    def _collect() -> None:
        with collect_t:
            obs = obs_box[0]
            action = learner.act(obs)
            next_obs, reward, terminated, truncated, info = env.step(action)
            ended = terminated | truncated
            replay.add(obs, action, reward, terminated, info["final_obs"], ended)
            learner.on_episode_end(ended)
            episodes.add(ended, info["success"])
            obs_box[0] = next_obs

    def sample(batch_size: int):
        if updates is not None:
            return updates.sample(replay)
        return replay.sample(batch_size, hp.updates_per_step)

    precision = update_precision(hp.precision, dev)

    def learn(batches) -> None:
        with learn_t, precision():
            if updates is not None:
                updates.run()  # the same updates on updates.batches (= batches), one graph replay on a GPU
                return
            for i in range(hp.updates_per_step):
                learner.update(batches.at(i))

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="collector") if overlap else None
    stop_reason, env_steps, last_eval = "budget_env_steps", 0, None
    best_rate, best_policy = 0.0, None
    saved_at = time.monotonic()

    def result(stop_reason: str) -> TrainResult:
        cycle_stats = {
            "collector_ms": collect_t.mean_ms,
            "learner_ms": learn_t.mean_ms,
            "effective_ms": learning_cycles.mean_ms if learning_cycles.count else cycle_t.mean_ms,
            "overlap": float(overlap),
        }
        return TrainResult(
            curve=list(curve),
            time_to_threshold=dict(tracker.seconds),
            env_steps_to_threshold=dict(tracker.env_steps),
            training_episodes_to_threshold={"env_steps": dict(train_tracker.env_steps),
                                            "seconds": dict(train_tracker.seconds)},
            cycle=cycle_stats,
            train_seconds=cycle_t.total,
            env_steps=env_steps,
            spec=spec,
            device_name=machine_name(spec.device),
            threads=learner_threads(spec.device),  # read before train() restores the caller's thread count
            stop_reason=stop_reason,
            best_success_rate=best_rate,
            learner=learner,
            best_policy=best_policy,
            replay=replay if keep_replay else None,
        )

    try:
        for cycle in range(1, cycles + 1):
            learning = replay.size >= hp.learning_start
            t0 = time.perf_counter()
            with cycle_t:
                if maps is not None and maps.due(cycle):  # a fresh map set; every slot starts anew
                    obs_box[0] = env.replace_maps(maps.take())[0]
                    learner.on_episode_end(torch.ones(hp.num_envs, dtype=torch.bool, device=dev))
                progress = (cycle - 1) * hp.num_envs / spec.max_env_steps
                batch_size = hp.batch_size_at(progress)
                if updates is not None and updates.batch_size != batch_size:
                    updates = static_updates(batch_size)
                batches = sample(batch_size) if learning else None
                learner.schedule(progress)  # this cycle's learning rates
                if collector_stream is not None:
                    collector_stream.wait_stream(torch.cuda.current_stream(dev))
                capturing = updates is not None and learning and updates.captures_next
                if pool is not None and learning and not capturing:
                    pending = pool.submit(collect)  # collector steps while the learner updates
                    learn(batches)
                    pending.result()
                else:
                    collect()
                    if learning:
                        learn(batches)
                if collector_stream is not None:
                    torch.cuda.current_stream(dev).wait_stream(collector_stream)
                if cycle % hp.env_steps_per_sync == 0:
                    learner.sync_collector()
            if learning:
                learning_cycles.total += time.perf_counter() - t0
                learning_cycles.count += 1
            env_steps = cycle * hp.num_envs
            if on_progress is not None:
                on_progress({"env_steps": env_steps, "max_env_steps": spec.max_env_steps,
                             "train_seconds": cycle_t.total, "last_eval": last_eval})
            out_of_time = cycle_t.total >= config.budget.max_train_seconds
            if cycle % eval_every and cycle != cycles and not out_of_time:
                continue  # every run ends with an evaluation, whichever budget ends it
            last_eval = {**_evaluate(learner, play_eval, env_steps, cycle_t.total, len(curve)), **episodes.take()}
            curve.append(last_eval)
            tracker.update(last_eval["success_rate"], cycle_t.total, env_steps)
            if last_eval["train_success_rate"] is not None:
                train_tracker.update(last_eval["train_success_rate"], cycle_t.total, env_steps)
            if best_policy is None or last_eval["success_rate"] > best_rate:
                best_rate, best_policy = last_eval["success_rate"], copy.deepcopy(learner.policy)
            if on_snapshot is not None and time.monotonic() - saved_at >= snapshot_every:
                on_snapshot(result(SNAPSHOT_STOP_REASON))
                saved_at = time.monotonic()
            if on_eval is not None and on_eval(dict(last_eval)):
                stop_reason = "callback"
                break
            target = config.budget.stop_at_success
            if target is not None and reaches(last_eval["success_rate"], target):
                stop_reason = "success"
                break
            if out_of_time:
                stop_reason = "budget_seconds"
                break
    except KeyboardInterrupt:
        if not interruptible:
            raise
        # The cycle in flight is dropped where it stood (its collector finishes below); the learner state
        # may be between two steps of one update; the evaluations and the best policy so far are whole.
        stop_reason = "interrupted"
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
        if maps is not None:
            maps.close()

    return result(stop_reason)


def run_learner(spec: RunSpec, device: torch.device | str) -> Learner:
    """The run's learner: fresh from its seed, or, fine-tuning (``spec.init``), with its checkpoint's
    learner state loaded (:func:`flashnav.finetune.load_learner`); the clocks start at 0 either way."""
    hp = spec.hparams
    layout = ObsLayout.from_robot(spec.robot, spec.goal_distance_max)
    learner = make_learner(spec.algorithm, hp, layout, 2, hp.num_envs, device, spec.seed)
    if spec.init is not None:
        load_learner(learner, spec.init)
    return learner


def _map_stream(spec: RunSpec, cycles: int) -> MapStream | None:
    """With generated maps refreshed during training (``maps: {family, refresh_every}``): the stream of
    the next sets, each drawn on a background thread with the fields the env reads computed there."""
    maps = spec.config.maps
    if not (isinstance(maps, GeneratedMaps) and maps.refresh_every):
        return None

    def warm(grids) -> None:  # a one-slot CPU env computes (and caches on the maps) every field
        NavVecEnv(spec.robot, 1, grid=grids, device="cpu", raycaster=spec.config.raycaster)

    return MapStream(maps, generation_radius(spec.robot), warm=warm, sets=maps.sets_needed(cycles))


def _eval_set(spec: RunSpec, grid, dev: torch.device) -> Callable[[torch.nn.Module], dict[str, float]]:
    """The run's fixed evaluation set, as a function of the policy: ``eval.episodes`` episodes on the
    training maps (``grid``; their first set for generated maps), slots drawing their maps as the training
    env's do; or, with ``eval.maps``, spread over those maps (:class:`flashnav.eval_maps.EvalSet`). Either
    way the episodes follow the run's robot preset (its goal sampling), and the policy reads goal distances
    on the run's scale (its input transform holds ``spec.goal_distance_max``; the env passes them unclipped)."""
    config = spec.config
    eval_grids = spec.eval_env_maps()
    if eval_grids is not None:
        eval_set = EvalSet(spec.robot, eval_grids, config.eval.episodes, config.eval.seed, device=dev,
                           raycaster=config.raycaster)
        return eval_set.evaluate
    eval_env = NavVecEnv(evaluation_preset(spec.robot), config.eval.episodes, grid=grid, device=dev,
                         seed=config.eval.seed, raycaster=config.raycaster, map_weights=config.map_weights)
    return lambda policy: evaluate(policy, eval_env, config.eval.seed)


def _evaluate(learner: Learner, play_eval: Callable[[torch.nn.Module], dict[str, float]], env_steps: int,
              train_seconds: float, index: int) -> dict[str, float]:
    policy = learner.policy
    was_training = policy.training
    policy.eval()
    with numba_threads():  # the learner and collector wait: the scans may use every core
        result = play_eval(policy)
    policy.train(was_training)
    return {"env_steps": env_steps, "train_seconds": train_seconds, "eval_index": index, **result}


__all__ = ["train", "TrainResult", "run_learner"]
