"""``flashnav train``: one training run with a live progress display and its artefacts."""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import math
import signal
import threading
from pathlib import Path

from rich.console import Console
from rich.table import Table

from flashnav.learn.artefacts import RUN_FILES, save_run
from flashnav.learn.progress import LOG_EVERY, TrainProgress
from flashnav.names import (ALGORITHMS, DEVICE_HELP, RECIPE_CHOICES, RECIPE_HELP, ROBOT_HELP, SNAPSHOT_STOP_REASON,
                            THRESHOLDS, seed_arg)
from flashnav.spec import TrainConfig, config_from_cli, resolve, run_request


def register_cli(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a navigation policy (FastDSAC on TurtleBot2 by default)",
                       description="Train a policy; writes config.yaml, metrics.json, checkpoint.pt, "
                                   "policy.pt (TorchScript), policy.onnx and policy.json (a readable copy of the "
                                   "metadata both policy files embed: robot, sensor layout, observation) to --out.")
    p.add_argument("--robot", help=ROBOT_HELP)
    p.add_argument("--algo", dest="algorithm", choices=ALGORITHMS, help="learner (default fastdsac)")
    p.add_argument("--recipe", choices=RECIPE_CHOICES, help="hyperparameters: " + RECIPE_HELP)
    p.add_argument("--device", help=DEVICE_HELP)
    p.add_argument("--map", help="ROS map YAML (default: the preset's bundled map)")
    p.add_argument("--maps", metavar="DIR_OR_GLOB",
                   help="train over many maps: a directory or glob pattern of ROS map YAML files (quote the "
                        "pattern); each env slot draws a map when it resets. Or family:F1,F2 for maps generated "
                        "during training (with maps.count=K maps.refresh_every=C maps.seed=S)")
    p.add_argument("--eval-maps", dest="eval_maps", metavar="DIR_OR_GLOB|validation",
                   help="evaluate on other maps than the training maps (eval.maps): a directory or glob pattern "
                        "of ROS map YAML files, or 'validation' (eval.maps_per_family=K maps of each training "
                        "family, or of every family, seeds 800000..; never a benchmark suite). The curve, "
                        "time-to-threshold and the best policy then measure success on those maps")
    p.add_argument("--init-from", dest="init_from", metavar="RUN_DIR_OR_CHECKPOINT",
                   help="fine-tune: start from a trained run's learner (weights, optimiser state, temperature; "
                        "its replay only with --init-replay); its network shapes must match this run's")
    p.add_argument("--init-replay", dest="init_replay", action="store_true", default=None,
                   help="with --init-from: start from that run's replay buffer too (its replay.pt, written by "
                        "--save-replay; the same num_envs and observation layout): a run continued on its own maps "
                        "learns on without a new warm-up")
    p.add_argument("--seed", type=seed_arg, help="training seed (default 0)")
    p.add_argument("--out", help="output folder (default runs/train/<robot>-<algo>-s<seed>-<time>)")
    p.add_argument("--overwrite", action="store_true",
                   help="let --out be a folder that already holds a run (its files are replaced); without it such "
                        "a folder is refused before training starts")
    p.add_argument("--config", help="a TrainConfig YAML; flags and overrides apply on top")
    p.add_argument("--save-every", dest="save_every", type=float, default=600.0, metavar="SECONDS",
                   help="write the run so far (checkpoint.pt, the best policy, metrics.json with stop_reason "
                        "'running') to --out after an evaluation at most every SECONDS of wall-clock time "
                        "(default 600; 0 = after every evaluation), so a crash loses at most that much; the "
                        "finished run overwrites it")
    p.add_argument("--save-replay", dest="save_replay", action="store_true",
                   help="also write the replay buffer to --out as replay.pt with every save (the run's transitions: "
                        "8 bytes a float observation column and 2 a wall-map square per transition, e.g. 425 MB "
                        "for 163,840 transitions with a 24 x 24 wall map), "
                        "so that --init-from OUT --init-replay can continue the run with it")
    p.add_argument("--sequential", action="store_true",
                   help="the plain sequential loop, no collector thread (the default on a CPU; overlap=true asks for "
                        "the thread there)")
    p.add_argument("overrides", nargs="*", metavar="key=value",
                   help="e.g. algo.batch_size=512 budget.max_train_seconds=60 eval.episodes=256 robot.lidar.noise_std=0.01")
    p.set_defaults(func=run_train)


def config_from_args(args) -> TrainConfig:
    """The TrainConfig of ``flashnav train``'s arguments (through :func:`flashnav.spec.config_from_cli`)."""
    flags = {name: getattr(args, name) for name in ("robot", "algorithm", "recipe", "device", "map", "maps", "seed",
                                                "init_from", "init_replay")}
    if args.sequential:
        flags["overlap"] = False
    # the path as a quoted YAML string (a bare `*.yaml` would read as a YAML alias); later key=value wins
    assignments = ([f"eval.maps={json.dumps(args.eval_maps)}"] if args.eval_maps else []) + list(args.overrides)
    return config_from_cli(args.config, flags, assignments)


def run_train(args) -> int:
    from flashnav.learn.loop import train
    from flashnav.outputs import check_output_dir

    console = Console()
    if not args.save_every >= 0:
        raise ValueError(f"--save-every must be >= 0 seconds, got {args.save_every}")
    if args.out is not None and not args.out.strip():  # an unset shell variable: not the default folder
        raise ValueError("--out is empty; give a folder, or leave --out out for "
                         "runs/train/<robot>-<algo>-s<seed>-<time>")
    spec = resolve(config_from_args(args))  # every bad input fails here, before anything is written
    config = spec.config
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = check_output_dir(args.out or f"runs/train/{spec.robot_name}-{config.algorithm}-s{config.seed}-{stamp}",
                           "--out")
    held = sorted(name for name in RUN_FILES if (out / name).exists())
    if held and not args.overwrite:
        raise ValueError(f"--out {out}: holds a run already ({', '.join(held)}); give a new folder, or --overwrite "
                         "to replace it")
    console.print(f"[bold]flashnav train[/] {spec.robot_name} / {config.algorithm} ({spec.recipe} recipe, "
                  f"{spec.device}), seed {config.seed} -> {out}")
    for line in recorded_drift(args.config, spec) + budget_notes(spec):
        console.print(f"[yellow]note[/]: {line}", soft_wrap=True)
    if spec.init is not None:
        run = spec.init.run
        console.print(f"fine-tuning from {spec.init.path} (seed {run['seed']}, {run['recipe']} recipe, saved "
                      f"{run['saved_at']}); goal-distance scale {spec.goal_distance_max:.2f} m from its run"
                      + (f"; its replay from {spec.init.replay}" if spec.init.replay else ""), soft_wrap=True)
    if spec.eval_maps is not None:
        grids = spec.eval_env_maps()
        console.print(f"evaluating on {len(grids)} maps of eval.maps = {config.eval.maps} "
                      f"({config.eval.episodes} episodes spread over them), not on the training maps")
    saved: list[int] = []  # env steps of the snapshots written

    def snapshot(so_far) -> None:
        save_run(so_far, out, replay=args.save_replay)
        saved.append(so_far.env_steps)
        progress.console.print(f"saved the run so far to {out} ({so_far.env_steps:,} env steps, best "
                               f"{so_far.best_success_rate:.1%})", soft_wrap=True)

    with TrainProgress(console, log_every=LOG_EVERY) as progress, sigterm_as_ctrl_c():
        try:
            result = train(spec, on_eval=progress.on_eval, on_progress=progress.on_progress, interruptible=True,
                           on_snapshot=snapshot, snapshot_every=args.save_every, keep_replay=args.save_replay)
        except Exception:
            if saved:
                progress.console.print(f"[red]training failed[/]: the run as it stood at {saved[-1]:,} env steps "
                                       f"is in {out} (metrics.json stop_reason {SNAPSHOT_STOP_REASON!r})")
            raise
    if result.stop_reason == "interrupted":
        console.print("[yellow]interrupted[/]: writing the run so far (Ctrl-C again aborts)")

    save_run(result, out, replay=args.save_replay)  # only now (or at the first snapshot): a failed start leaves none
    _summary(console, result, out)
    return 0


def budget_notes(spec) -> list[str]:
    """A line where the run's env-step budget ends before the learner's first update (``algo.learning_start``
    transitions): such a run evaluates the untrained policy only (a smoke test may mean it; a study rarely does)."""
    hp = spec.hparams
    steps = math.ceil(spec.max_env_steps / hp.num_envs) * hp.num_envs  # whole vector steps, as the loop runs them
    if steps >= hp.learning_start:
        return []
    return [f"the budget ends at {steps:,} env steps, before algo.learning_start = {hp.learning_start:,} stored "
            f"transitions: no update will run (raise budget.max_env_steps or lower algo.learning_start)"]


def recorded_drift(config_file: str | None, spec) -> list[str]:
    """Where a run's ``config.yaml`` given to ``--config`` recorded other hyperparameters or another robot than
    its request resolves to today (a recipe or preset changed since): one line per section, the first keys."""
    from flashnav.yamlio import flatten_dotted, load_yaml

    recorded = load_yaml(config_file) if config_file else None
    if not isinstance(recorded, dict) or run_request(recorded) is None:
        return []
    now, lines = spec.to_dict(), []
    for section in ("hparams", "robot_preset"):
        then, today = flatten_dotted(recorded[section]), flatten_dotted(now[section])
        changed = []
        for key in sorted(then.keys() | today.keys()):
            if key not in then:  # a field added since the run
                changed.append(f"{key} (not recorded) -> {today[key]!r}")
            elif key not in today or then[key] != today[key]:
                changed.append(f"{key} {then[key]!r} -> {today.get(key)!r}")
        if changed:
            lines.append(f"{config_file} recorded other {section} than its request gives today ({len(changed)}): "
                         + "; ".join(changed[:4]) + (" ..." if len(changed) > 4 else ""))
    return lines


@contextlib.contextmanager
def sigterm_as_ctrl_c():
    """While training, SIGTERM (``kill PID``, ``timeout``, a batch scheduler's stop) ends the run as Ctrl-C
    does, and the run so far is written. A job started with ``cmd &`` from a script inherits SIGINT as
    ignored, so SIGTERM is the way to stop it gracefully. The previous handler is back before the
    artefacts are written: a second SIGTERM then ends the process at once."""
    if threading.current_thread() is not threading.main_thread():  # signal handlers live in the main thread
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _summary(console: Console, result, out: Path) -> None:
    t = Table(title=f"{result.spec.robot_name} / {result.spec.algorithm} on {result.device_name}")
    for col in ("threshold", "train seconds", "env steps"):
        t.add_column(col, justify="right")
    for k in THRESHOLDS:
        s, e = result.time_to_threshold[k], result.env_steps_to_threshold[k]
        t.add_row(f"{k:.0%}", "not reached" if s is None else f"{s:.1f}", "-" if e is None else f"{e:,}")
    console.print(t)
    c = result.cycle
    console.print(f"cycle: collector {c['collector_ms']:.1f} ms, learner {c['learner_ms']:.1f} ms, "
                  f"effective {c['effective_ms']:.1f} ms; stopped by {result.stop_reason}; "
                  f"{result.env_steps:,} env steps in {result.train_seconds:.1f} s of training")
    console.print(f"exported policy: the best evaluation ({result.best_success_rate:.1%} success); "
                  f"checkpoint.pt holds the final learner state")
    console.print(f"artefacts in {out}: {' '.join(RUN_FILES)}")
