"""Run a sweep: sweep YAML -> Ray Tune (seed grid, or one Optuna study per robot x algorithm) -> MLflow.

The driver behind ``flashnav sweep run`` (the command line and ``flashnav sweep submit`` live in
services.sweep_cli; ``python -m services.sweep_cli run|submit ...`` is the same command line where the
console script is missing): in-process Ray on this machine by default, the cluster named by ``--address`` /
RAY_ADDRESS otherwise (inside ``ray job submit`` Ray sets RAY_ADDRESS). Where things go, all resolved
to absolute paths here before anything is shipped to a worker:

    <runs>/sweeps/<name>/<stamp>/   sweep_state.json (what --resume needs), sweep.yaml, Optuna outputs
    <storage>/<name>/<stamp>/<target>/   the Ray Tune experiment of one target (default storage <runs>/ray)
    MLflow: one parent run per invocation, a child per trial (services.tracking, the only writer)

``<runs>`` is $FLASHNAV_RUNS_DIR, else ``<project>/runs`` (services.paths.runs_dir).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from services import optuna_search
from services.paths import (check_sqlite_url, check_tracking_uri, project_dir, resolve_db_url, resolve_storage,
                            resolve_tracking_uri, runs_dir)
from services.sweep_schema import Sweep, SweepError, load_sweep, set_flags, sweep_to_yaml
from services.sweep_state import STAMP_FORMAT, STATE_FILE, check_resumable, invocation_state, unfinished


@dataclass
class Target:
    """One Tuner: ``grid`` (every robot x algorithm x seed) or one Optuna study per (robot, algorithm)."""

    name: str
    robot: str | None = None
    algorithm: str | None = None
    study: str | None = None


@dataclass
class Plan:
    sweep: Sweep
    source: str
    stamp: str
    tracking_uri: str
    ray_storage: str
    out_dir: Path
    optuna_url: str | None
    targets: list[Target]
    git_commit: str
    state: dict[str, Any] = field(default_factory=dict)

    @property
    def n_trials(self) -> int:
        s = self.sweep
        per = s.search.n_trials if s.search else len(s.seed_list)
        return len(s.robots) * len(s.algorithms) * per

    def save_state(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        (self.out_dir / STATE_FILE).write_text(json.dumps(self.state, indent=1))


def git_commit(where: Path) -> str:
    """$FLASHNAV_GIT_COMMIT (set by ``sweep submit``: a job's working dir has no .git), else git's HEAD."""
    if os.environ.get("FLASHNAV_GIT_COMMIT"):
        return os.environ["FLASHNAV_GIT_COMMIT"]
    for repo in (where, Path(__file__).resolve().parents[1]):  # the project, else this checkout
        try:
            head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True,
                                  timeout=10, check=True).stdout.strip()
            dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                                   capture_output=True, text=True, timeout=10).stdout.strip()
            return head + ("-dirty" if dirty else "")
        except (OSError, subprocess.SubprocessError):
            continue
    return "unknown"


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) during a sweep; ``stamp``: the invocation that ``--resume`` continues, None when
    nothing of it was recorded yet."""

    def __init__(self, message: str = "", stamp: str | None = None):
        super().__init__(message)
        self.stamp = stamp


def make_plan(sweep: Sweep, source: str, resume: bool | str = False) -> Plan:
    """Resolve every location of one invocation: a new one, or when resuming the newest one (``resume`` True) or
    the one of that stamp (``resume`` a stamp, e.g. ``20261203-174502``)."""
    state = invocation_state(sweep, resume if isinstance(resume, str) else None) if resume else {}
    stamp = state.get("stamp") or time.strftime(STAMP_FORMAT)
    if resume:
        check_resumable(sweep, runs_dir() / "sweeps" / sweep.name / stamp, source)
    try:
        tracking_uri = state.get("tracking_uri") or resolve_tracking_uri(sweep.tracking.tracking_uri)
        # before Ray starts (and in a dry run): a server that does not answer hung, a file that is not a database
        # failed in SQLAlchemy's words once Ray was up
        check_tracking_uri(tracking_uri, what="tracking URI (tracking.tracking_uri, else $MLFLOW_TRACKING_URI)")
    except ValueError as exc:
        raise SweepError(f"{source}: {exc}") from None
    ray_storage = state.get("ray_storage") or f"{resolve_storage(sweep.storage).rstrip('/')}/{sweep.name}/{stamp}"
    optuna_url = None
    targets = [Target("grid")]
    if sweep.search:
        optuna_url = state.get("optuna_url") or resolve_db_url(sweep.search.storage, "optuna.db")
        try:
            check_sqlite_url(optuna_url, "search.storage")
        except ValueError as exc:
            raise SweepError(f"{source}: {exc}") from None
        pairs = [(r, a) for r in sweep.robots for a in sweep.algorithms]
        studies = state.get("studies", {})
        targets = []
        for robot, algorithm in pairs:
            name = f"{Path(robot).stem}-{algorithm}"
            study = studies.get(name) or optuna_search.study_name(sweep, robot, algorithm, stamp, len(pairs))
            targets.append(Target(name, robot, algorithm, study))
    state = state or {"sweep": sweep.name, "stamp": stamp, "tracking_uri": tracking_uri, "ray_storage": ray_storage,
                      "optuna_url": optuna_url, "studies": {t.name: t.study for t in targets if t.study},
                      "experiment": sweep.experiment, "done_targets": [], "parent_run_id": None}
    return Plan(sweep, source, stamp, tracking_uri, ray_storage, runs_dir() / "sweeps" / sweep.name / stamp,
                optuna_url, targets, git_commit(project_dir()), state)


def validate_train_configs(plan: Plan) -> None:
    """Resolve every (robot, algorithm) run in the driver, through the library's one resolver, so a bad
    key, a misspelt searched hyperparameter or a missing map fails before Ray starts."""
    from flashnav.machine import resolve_recipe
    from flashnav.maps.families import reuse_generated_maps
    from flashnav.spec import config_from_data, resolve

    sweep = plan.sweep
    with reuse_generated_maps():  # each searched point resolves the same generated maps: made once
        for robot in sweep.robots:
            for algorithm in sweep.algorithms:
                for extra, what in _search_points(sweep, algorithm):
                    data = sweep.train_config(robot, algorithm, sweep.seed_list[0], "cpu", extra)
                    # the trials' recipe: their device is not known here, their resources say whether it is a GPU
                    data["recipe"] = resolve_recipe(data.get("recipe", "auto"),
                                                    "cuda" if sweep.resources.gpu > 0 else "cpu")
                    try:
                        resolve(config_from_data(data, f"{robot}/{algorithm}"))
                    except ValueError as exc:
                        raise SweepError(f"{plan.source}: {robot}/{algorithm}{what}: not a valid training "
                                         f"config:\n{exc}") from None


def _search_points(sweep: Sweep, algorithm: str) -> list[tuple[dict[str, Any], str]]:
    """The searched values to check, with how to name them: every parameter at its first value, then each
    parameter in turn at every other choice or at the other end of its range (the rest at their first)."""
    if not sweep.search:
        return [({}, "")]
    space = sweep.search.space_for(algorithm)
    first = {path: optuna_search.first_value(dist) for path, dist in space.items()}
    points = [(first, "")]
    for path, dist in space.items():
        for value in dist.extremes():
            if value != first[path]:
                where = ("a choice" if dist.kind == "choice" else "the end of its range" if value in dist.args
                         else "a value inside its range")
                points.append(({**first, path: value}, f" with the searched {path}={value!r} ({where})"))
    return points


def describe(plan: Plan) -> str:
    s = plan.sweep
    lines = [f"sweep {s.name}: {plan.n_trials} trials ({len(s.robots)} robot(s) x {len(s.algorithms)} algorithm(s) x "
             + (f"{s.search.n_trials} Optuna trials of {s.search.seeds_per_trial} seed(s))" if s.search
                else f"{len(s.seed_list)} seeds)"),
             f"  per trial: {s.resources.cpu:g} CPU, {s.resources.gpu:g} GPU; recipe {s.base.recipe}; "
             f"budget {s.budget.max_train_seconds:g} s; max_failures {s.retry.max_failures}",
             f"  MLflow: {plan.tracking_uri} (experiment {s.experiment})",
             f"  Ray storage: {plan.ray_storage}", f"  outputs: {plan.out_dir}"]
    if plan.optuna_url:
        lines.append(f"  Optuna: {plan.optuna_url}, objective {s.search.objective} ({s.search.mode}), studies: "
                     + ", ".join(t.study for t in plan.targets))
    return "\n".join(lines)


# ---------------------------------------------------------------- the driver


def connect(address: str | None) -> bool:
    """Initialise Ray unless already up; returns True when this call started it (and must shut it down)."""
    import ray

    if ray.is_initialized():
        return False
    source = "--address" if address else "RAY_ADDRESS"
    address = address or os.environ.get("RAY_ADDRESS")
    if address and address.startswith(("http://", "https://")):
        raise SweepError(f"{address} is a dashboard/jobs address: use `flashnav sweep submit --address {address}`; "
                         "`sweep run --address` takes the cluster address (HOST:6379 or auto)")
    if address:
        check_reachable(address, source)
    ray.init(address=address or "local", include_dashboard=False if not address else None)
    return True


def check_reachable(address: str, source: str = "--address", timeout: float = 5.0) -> None:
    """A SweepError naming ``address`` (and where it came from, ``source``) when nothing answers there within
    ``timeout`` seconds (Ray itself would retry for minutes before it gives up). ``auto``/``local`` and addresses
    without a port are left to Ray."""
    import socket

    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        raise SweepError(f"{source} {address}: no Ray cluster answers there ({exc.strerror or exc}); start one "
                         f"(`flashnav services up`, or `ray start --head` on that machine) or drop {source} to run "
                         "in-process here") from None


def _trainable(plan: Plan, train_fn: Callable | None):
    from ray import tune

    from services.trainable import train_trial

    resources = {"cpu": plan.sweep.resources.cpu, "gpu": plan.sweep.resources.gpu}
    bound = tune.with_parameters(train_trial, sweep=plan.sweep.model_dump(mode="json"),
                                 git_commit=plan.git_commit, train_fn=train_fn)
    return tune.with_resources(bound, resources)


def _tuner(plan: Plan, target: Target, trainable, callback, verbose: int):
    from ray import tune

    sweep = plan.sweep
    run_config = tune.RunConfig(
        name=target.name, storage_path=plan.ray_storage, callbacks=[callback], verbose=verbose,
        failure_config=tune.FailureConfig(max_failures=sweep.retry.max_failures),
        # num_to_keep makes Tune snapshot the experiment state at every trial checkpoint (one per finished
        # seed, each holding every seed done so far), so --resume after a kill re-trains no finished seed.
        checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
    )
    if sweep.search is None:
        space = {"robot": tune.grid_search(sweep.robots), "algorithm": tune.grid_search(sweep.algorithms),
                 "seed": tune.grid_search(sweep.seed_list)}
        config = tune.TuneConfig(max_concurrent_trials=sweep.max_concurrent_trials, reuse_actors=False)
    else:
        space = {"robot": target.robot, "algorithm": target.algorithm,
                 "seeds": sweep.seed_list[: sweep.search.seeds_per_trial],
                 optuna_search.PARAMS_KEY: optuna_search.search_space(sweep, target.algorithm)}
        searcher = optuna_search.make_searcher(sweep, plan.optuna_url, target.study, target.algorithm)
        config = tune.TuneConfig(search_alg=searcher,
                                 num_samples=sweep.search.n_trials, metric="objective", mode=sweep.search.mode,
                                 reuse_actors=False)
    return tune.Tuner(trainable, param_space=space, tune_config=config, run_config=run_config)


def _fit_target(plan: Plan, target: Target, tracker, resume: bool, train_fn, verbose: int) -> int:
    """Run (or restore and finish) one target; returns the number of trials that ended in error."""
    from ray import tune

    trainable = _trainable(plan, train_fn)
    path = f"{plan.ray_storage}/{target.name}"
    if resume and tune.Tuner.can_restore(path):
        # The pickled MLflow callback comes back with the experiment (same parent run); finished trials
        # stay finished, errored ones restart from their last checkpoint.
        tuner = tune.Tuner.restore(path, trainable=trainable, resume_errored=True)
    else:
        tags = {"recipe": plan.sweep.base.recipe, "git_commit": plan.git_commit, "invocation": plan.stamp}
        tuner = _tuner(plan, target, trainable, tracker.callback(plan.sweep.name, tags), verbose)
    results = tuner.fit()
    expected = plan.sweep.search.n_trials if target.study else plan.n_trials
    ended = sum(1 for result in results if result.error is not None or trial_completed(result))
    if ended < expected:
        # Tune catches Ctrl-C (SIGINT), saves its state and returns early, with trials still pending or
        # stopped mid-seed (Tune marks those TERMINATED too): that target is not done, and the sweep must say
        # so rather than finish.
        raise KeyboardInterrupt(f"{target.name}: {ended}/{expected} trials ended before the interrupt")
    return results.num_errors


def trial_completed(result) -> bool:
    """Whether a Tune trial's last report is the final one of its last seed (``final=1``, services.trainable):
    a trial stopped by Ctrl-C mid-seed ends TERMINATED as well, with an evaluation (``final=0``) or nothing."""
    metrics, config = result.metrics or {}, result.config or {}
    seeds = config.get("seeds") or [config.get("seed")]
    return metrics.get("final") == 1.0 and metrics.get("seed") is not None and int(metrics["seed"]) == int(seeds[-1])


def _relay_sigterm():
    """SIGTERM (``kill PID``, a scheduler's stop) as Ctrl-C: Tune saves its state and the sweep stops as interrupted,
    with the --resume line. Before, Ray's handler aborted the driver (exit 134, a stack dump, the MLflow parent left
    RUNNING, no hint). Returns the handler to put back (None off the main thread, where none can be set; the
    default where the one replaced was not Python's, e.g. Ray's, which Python cannot put back)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.signal(signal.SIGTERM, lambda *_: os.kill(os.getpid(), signal.SIGINT))
    return signal.SIG_DFL if previous is None else previous


def run_sweep(path: str | Path, *, address: str | None = None, resume: bool | str = False, dry_run: bool = False,
              sets: list[str] | None = None, train_fn: Callable | None = None, verbose: int = 1,
              echo: Callable[[str], Any] = print) -> int:
    """Run a sweep file to completion; 0 when every trial finished, 1 when some errored after retries.

    ``train_fn`` replaces ``flashnav.train`` in every trial (tests use a fake to exercise the plumbing).
    """
    sweep = load_sweep(path, sets)
    plan = make_plan(sweep, str(path), resume)
    validate_train_configs(plan)
    for target in plan.targets if not resume else []:
        if target.study:
            optuna_search.check_fresh(plan.optuna_url, target.study)
    echo(describe(plan))
    if not resume:
        unfinished(sweep, path, echo)
    if dry_run:
        return 0

    from services import device, tracking

    # Those forced snapshots are cheap (a few kB); Tune would warn about each of them.
    os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
    started = connect(address)
    tracker, relayed = None, _relay_sigterm()
    try:
        try:
            device.check_cluster_fits(sweep.resources.cpu, sweep.resources.gpu)
        except ValueError as exc:
            raise SweepError(f"{path}: {exc}") from None
        tracker = tracking.SweepRun(plan.tracking_uri, plan.state["experiment"])
        if plan.state.get("parent_run_id"):
            tracker.resume(plan.state["parent_run_id"])
        else:
            tags = {"invocation": plan.stamp, "sweep_file": str(path), "ray_storage": plan.ray_storage,
                    "git_commit": plan.git_commit, "n_trials": str(plan.n_trials)}
            plan.state["parent_run_id"] = tracker.start(sweep.name, f"{sweep.name}-{plan.stamp}", tags,
                                                        sweep.model_dump(mode="json"))
            plan.save_state()
            (plan.out_dir / "sweep.yaml").write_text(sweep_to_yaml(sweep), encoding="utf-8")
            tracker.log_artifact(plan.out_dir / "sweep.yaml")
        errors = 0
        for target in plan.targets:
            if target.name in plan.state["done_targets"]:
                continue
            failed = _fit_target(plan, target, tracker, resume, train_fn, verbose)
            errors += failed
            if target.study:
                optuna_search.fail_orphans(plan.optuna_url, target.study)
            if not failed:  # (a target with errored trials stays to do: --resume runs them again)
                plan.state["done_targets"].append(target.name)
            plan.save_state()
        if sweep.search:
            summaries = [optuna_search.summarize(plan.optuna_url, t.study, sweep, t.robot, t.algorithm)
                         for t in plan.targets]
            for written in optuna_search.write_outputs(plan.out_dir, summaries, sweep):
                tracker.log_artifact(written)
                echo(f"wrote {written}")
        tracker.set_tags({"errored_trials": errors})
        tracker.finish("FINISHED" if errors == 0 else "FAILED")
        echo(f"sweep {sweep.name}: {plan.n_trials - errors}/{plan.n_trials} trials finished; MLflow "
             f"{plan.tracking_uri}, parent run {plan.state['parent_run_id']}")
        if errors:
            given = set_flags(sets)  # (without them --resume refuses the sweep as changed)
            echo(f"  {errors} trial(s) ended in error (their tracebacks are above and in MLflow); after a fix, "
                 f"`flashnav sweep run {path} --resume {plan.stamp}{given}` runs them again and keeps the finished "
                 "ones")
        return 0 if errors == 0 else 1
    except KeyboardInterrupt as exc:
        if tracker and tracker.run_id:
            tracker.finish("KILLED")  # `--resume` reopens it
        # the stamp to resume, once the invocation's state is on disk (before, a bare --resume took an older one)
        raise SweepInterrupted(str(exc), plan.stamp if (plan.out_dir / STATE_FILE).is_file() else None) from exc
    except Exception:
        if tracker and tracker.run_id:
            tracker.finish("FAILED")
        raise
    finally:
        if relayed is not None:
            signal.signal(signal.SIGTERM, relayed)
        if started:
            import ray

            ray.shutdown()


if __name__ == "__main__":
    # The command line lives in services.sweep_cli, which imports this module; importing it back from
    # here would close an import cycle. Fail loudly rather than run nothing.
    sys.exit("the sweep command line moved: python -m services.sweep_cli run|submit ... (or flashnav sweep)")
