"""``flashnav train``: one training run with a live progress display and its artefacts."""

from __future__ import annotations

import argparse
import datetime as dt
import json
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from rich.table import Table

from flashnav.config import dump_yaml
from flashnav.learn.config import THRESHOLDS, TrainConfig
from flashnav.learn.progress import TrainProgress


def register_cli(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a navigation policy (FastDSAC on TurtleBot2 by default)",
                       description="Train a policy; writes config.yaml, metrics.json, checkpoint.pt, "
                                   "policy.pt (TorchScript) and policy.onnx to --out.")
    p.add_argument("--robot", help="turtlebot2 (default), go2, or a preset YAML")
    p.add_argument("--algo", dest="algorithm", choices=["fastdsac", "fastsac", "fasttd3"], help="learner (default fastdsac)")
    p.add_argument("--recipe", choices=["auto", "paper", "cpu"], help="hyperparameters: paper (GPU), cpu, auto (by device)")
    p.add_argument("--device", help="auto (default), cpu, cuda, cuda:N")
    p.add_argument("--map", help="ROS map YAML (default: the preset's bundled map)")
    p.add_argument("--seed", type=int, help="training seed (default 0)")
    p.add_argument("--out", help="output folder (default runs/train/<robot>-<algo>-s<seed>-<time>)")
    p.add_argument("--config", help="a TrainConfig YAML; flags and overrides apply on top")
    p.add_argument("--sequential", action="store_true", help="the plain sequential loop (no collector/learner overlap)")
    p.add_argument("overrides", nargs="*", metavar="key=value",
                   help="e.g. algo.batch_size=512 budget.max_train_seconds=60 eval.episodes=256 robot.lidar.noise_std=0.01")
    p.set_defaults(func=run_train)


def split_override(item: str) -> tuple[str, Any]:
    """``"algo.batch_size=512"`` -> ``("algo.batch_size", 512)``: the value read as YAML (safely)."""
    key, sep, raw = item.partition("=")
    if not sep or not key:
        raise ValueError(f"override {item!r} is not key=value")
    try:
        return key, yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        from flashnav.config import yaml_error_line
        raise ValueError(f"override {item!r}: the value is not valid YAML ({yaml_error_line(exc)})") from None


def build_config(args) -> TrainConfig:
    data: dict[str, Any] = {}
    if args.config:
        data = TrainConfig.from_yaml(args.config).model_dump()
    for name in ("robot", "algorithm", "recipe", "device", "map", "seed"):
        if getattr(args, name) is not None:
            data[name] = getattr(args, name)
    if args.sequential:
        data["overlap"] = False
    for item in args.overrides:
        key, value = split_override(item)
        if key.startswith(("algo.", "robot.")):
            data.setdefault("overrides", {})[key] = value
        else:
            node = data
            *parents, leaf = key.split(".")
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = value
    return TrainConfig.model_validate(data)


def run_train(args) -> int:
    from flashnav.learn.loop import resolved_config, train
    from flashnav.maps.bundled import resolve_map
    from flashnav.outputs import check_output_dir

    console = Console()
    config = build_config(args)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    robot_name = Path(config.robot).stem
    out = check_output_dir(args.out or f"runs/train/{robot_name}-{config.algorithm}-s{config.seed}-{stamp}", "--out")
    # Device, robot, hyperparameters and map are resolved before the minutes of training (train()
    # resolves them again, consuming no randomness): a bad one fails now and leaves no folder behind.
    resolve_map(config.map, resolved_config(config)["robot_preset"]["map"])
    console.print(f"[bold]flashnav train[/] {robot_name} / {config.algorithm}, seed {config.seed} -> {out}")
    with TrainProgress(console) as progress:
        result = train(config, on_eval=progress.on_eval, on_progress=progress.on_progress)

    out.mkdir(parents=True, exist_ok=True)  # only now: a failed run leaves no empty folder
    _write_artefacts(result, out)
    _summary(console, result, out)
    return 0


def _write_artefacts(result, out: Path) -> None:
    from flashnav.config import RobotPreset
    from flashnav.export import export_policy, save_checkpoint

    dump_yaml(result.config, out / "config.yaml")
    with open(out / "metrics.json", "w", encoding="utf-8") as f:
        json.dump(result.to_dict(), f, indent=2)
    save_checkpoint(out / "checkpoint.pt", result.learner.state_dict(), result.config,
                    {"metrics": {k: v for k, v in result.to_dict().items() if k != "config"}})
    preset = RobotPreset.model_validate(result.config["robot_preset"])
    export_policy(result.policy, preset, out)  # the best evaluated policy


def _summary(console: Console, result, out: Path) -> None:
    t = Table(title=f"{result.config['robot_preset']['name']} / {result.config['algorithm']} on {result.device_name}")
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
    console.print(f"artefacts in {out}: config.yaml metrics.json checkpoint.pt policy.pt policy.onnx")
