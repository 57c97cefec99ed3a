"""The Ray Tune function trainable: one trial = ``flashnav.train`` on one or more seeds.

What a trial reports (the metric names of docs/run-schema.md):

* at every evaluation (``on_eval``, outside flashnav's training clock by contract): ``success_rate``,
  ``mean_return``, ``train_seconds``, ``env_steps`` (+ collision/timeout rates), ``seed``, ``final=0``;
* once per seed, with a checkpoint: the final metrics (``time_to_90`` ... censored, never NaN/None),
  ``seed``, ``final=1`` and the strings the MLflow writer in the driver needs (``device_name``, the
  machine; ``threads``, the learner's CPU threads where training reported them; ...).
  The checkpoint carries the resolved config, the curve CSV and an exported policy if training wrote
  one, so that the driver can log them even when the trial ran on another node; it also lists the
  seeds already done so that a retried or restored trial does not train them again.

Search sweeps add ``objective`` to every report: the mean over the trial's seeds of the (censored)
objective metric, provisional until the last seed ends.
"""

from __future__ import annotations

import csv
import glob
import json
import logging
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable

import yaml

from flashnav.spec import config_from_data
from flashnav.metrics import THRESHOLD_TAGS, THRESHOLDS, censor, threshold_of, time_to_threshold
from flashnav.names import TRIAL_RESULT_FILE, TRIAL_SEED_DIR
from services import device as devices
from services.search_space import Search
from services.sweep_schema import Sweep

CURVE_KEYS = ("success_rate", "mean_return", "train_seconds", "env_steps", "collision_rate", "timeout_rate")
MANIFEST = "manifest.json"
logger = logging.getLogger(__name__)


# ---------------------------------------------------------------- metrics (pure)


def _at_threshold(table: dict | None, threshold: float) -> float | None:
    """``table[threshold]`` whether keyed by float (TrainResult) or by string (its to_dict()); NaN -> None."""
    if not table:
        return None
    for key, value in table.items():
        if math.isclose(float(key), threshold):
            if value is None or (isinstance(value, float) and math.isnan(value)):
                return None
            return float(value)
    return None


def final_metrics(result: Any) -> dict[str, float]:
    """The run-schema final metrics of a TrainResult; censored (the run's totals) where not reached."""
    curve = list(result.curve or [])
    total_seconds = float(result.train_seconds if result.train_seconds is not None else
                          (curve[-1]["train_seconds"] if curve else 0.0))
    total_steps = float(result.env_steps if result.env_steps is not None else (curve[-1]["env_steps"] if curve else 0))
    out: dict[str, float] = {}
    for threshold, tag in zip(THRESHOLDS, THRESHOLD_TAGS):
        # the seconds decide whether it was reached; steps follow (a missing step count is censored too)
        seconds, reached = censor(_at_threshold(result.time_to_threshold, threshold), total_seconds)
        steps = _at_threshold(result.env_steps_to_threshold, threshold) if reached else None
        out[f"time_to_{tag}"] = seconds
        out[f"env_steps_to_{tag}"] = censor(steps, total_steps)[0]
        out[f"reached_{tag}"] = 1.0 if reached else 0.0
    success = [float(point["success_rate"]) for point in curve]
    out["final_success_rate"] = success[-1] if success else 0.0
    out["best_success_rate"] = max(success) if success else 0.0
    out["train_seconds_total"] = total_seconds
    out["env_steps_total"] = total_steps
    cycle = result.cycle or {}
    for side in ("collector", "learner", "effective"):
        value = cycle.get(f"{side}_ms")
        out[f"cycle_{side}_ms"] = float(value) if value is not None and not math.isnan(float(value)) else 0.0
    return out


class Objective:
    """The search objective of one trial: a per-seed metric averaged over the trial's seeds.

    Time/steps objectives are censored (the run's total where not reached) plus ``unreached_penalty``.
    While a seed trains, its provisional value is what the curve so far implies: the time it reached
    the threshold, else the time spent so far (a lower bound of the censored value).
    """

    def __init__(self, search: Search):
        self.name = search.objective
        self.penalty = search.unreached_penalty
        self.threshold_tag = self.name.rsplit("_", 1)[1] if self.name.startswith(("time_to_", "env_steps_to_")) else None

    def of_final(self, final: dict[str, float]) -> float:
        value = float(final[self.name])
        if self.threshold_tag and final[f"reached_{self.threshold_tag}"] < 1.0:
            value += self.penalty
        return value

    def of_curve(self, curve: list[dict[str, float]]) -> float:
        if not curve:
            return 0.0
        if self.threshold_tag is None:
            rates = [p["success_rate"] for p in curve]
            return rates[-1] if self.name == "final_success_rate" else max(rates)
        key = "train_seconds" if self.name.startswith("time_to_") else "env_steps"
        success, x = [p["success_rate"] for p in curve], [p[key] for p in curve]
        return time_to_threshold(success, x, threshold_of(self.threshold_tag))[0]

    def mean(self, finished: list[float], running: float | None = None) -> float:
        values = finished + ([running] if running is not None else [])
        return float(sum(values) / len(values)) if values else 0.0


# ---------------------------------------------------------------- files


def write_curve_csv(curve: list[dict], path: Path) -> None:
    """The evaluation curve, one row per evaluation; the schema's columns first, then any others."""
    extra = sorted({key for point in curve for key in point} - set(CURVE_KEYS))
    columns = [key for key in CURVE_KEYS if any(key in p for p in curve)] + extra
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=columns or list(CURVE_KEYS))
        writer.writeheader()
        for point in curve:
            writer.writerow({key: point.get(key, "") for key in columns})


def load_manifest(directory: str | Path) -> dict:
    """``{"done": {seed: final metrics}, "latest": seed | None}`` of a trial checkpoint directory."""
    path = Path(directory) / MANIFEST
    if not path.exists():
        return {"done": {}, "latest": None}
    data = json.loads(path.read_text())
    data["done"] = {int(seed): final for seed, final in data.get("done", {}).items()}
    return data


def _write_seed(stage: Path, seed: int, result: Any, final: dict, done: dict, export: bool = False) -> None:
    """Add ``seed_<seed>/`` (config, curve, result, policy) to the staging folder and rewrite the manifest."""
    seed_dir = stage / TRIAL_SEED_DIR.format(seed=seed)
    shutil.rmtree(seed_dir, ignore_errors=True)
    seed_dir.mkdir()
    with open(seed_dir / "config.yaml", "w", encoding="utf-8") as f:
        yaml.safe_dump(_plain(result.spec.to_dict()), f, sort_keys=False)
    write_curve_csv(list(result.curve or []), seed_dir / "curve.csv")
    with open(seed_dir / TRIAL_RESULT_FILE, "w", encoding="utf-8") as f:
        json.dump(_plain(result.to_dict()) if hasattr(result, "to_dict") else final, f, indent=1)
    if export:
        _export_policy(result, seed_dir)
    manifest = {"done": {str(s): f for s, f in done.items()}, "latest": seed}
    (stage / MANIFEST).write_text(json.dumps(manifest, indent=1))


def _export_policy(result: Any, out_dir: Path) -> None:
    """``policy.pt`` (TorchScript) + ``policy.json`` through flashnav.export: the policy ``flashnav train --out``
    exports, the best evaluation's (ties: the earliest; none: the final learner's), the one whose success the trial's
    best_success_rate reports. A failure costs the artifact only."""
    policy = getattr(result, "policy", None)
    if policy is None:
        return
    try:
        from flashnav.export import export_policy

        export_policy(policy, result.spec.robot, out_dir, onnx=False)  # ONNX: `flashnav` can convert later
    except Exception as exc:  # noqa: BLE001 - the run's metrics matter more than its artifact
        logger.warning("policy export failed: %s", exc)


def _plain(value: Any) -> Any:
    """JSON/YAML-safe copy (tuples -> lists, numpy/torch scalars -> Python numbers, paths -> str)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if hasattr(value, "item"):
        return value.item()
    return str(value)


# ---------------------------------------------------------------- the trainable


def _localise(value: Any) -> Any:
    """A relative path in the sweep (preset, map, maps directory or glob, evaluation maps, ``init_from``) is
    relative to the working dir Ray shipped to this node, not to the trial's own folder; keywords (a bundled
    map's name, ``validation``, ``family:...``) and generated-map mappings pass through."""
    if isinstance(value, list):
        return [_localise(item) for item in value]
    if not isinstance(value, str) or not value or os.path.isabs(value):
        return value
    base = Path(os.environ.get("TUNE_ORIG_WORKING_DIR", os.getcwd()))
    if value.endswith((".yaml", ".yml")) or (base / value).exists() or glob.glob(str(base / value)):
        return str(base / value)
    return value


def localise_paths(data: dict) -> dict:
    """The training config ``data`` with its relative paths made absolute (:func:`_localise`)."""
    data = dict(data)
    for key in ("robot", "map", "maps", "init_from"):
        if key in data:
            data[key] = _localise(data[key])
    if isinstance(data.get("eval"), dict) and "maps" in data["eval"]:
        data["eval"] = {**data["eval"], "maps": _localise(data["eval"]["maps"])}
    return data


def _provenance() -> dict[str, str]:
    import torch

    import flashnav

    return {"flashnav_version": flashnav.__version__, "torch_version": torch.__version__, "host": devices.host_name()}


def train_trial(config: dict, *, sweep: dict, git_commit: str = "unknown",
                train_fn: Callable | None = None) -> None:
    """Tune function trainable (bind the keyword arguments with ``tune.with_parameters``).

    ``config`` (the Tune trial config): ``robot``, ``algorithm``, and ``seed`` (grid) or ``seeds``
    (search, several seeds per trial), plus ``params`` ({config path: value}) sampled by the search.
    ``train_fn`` replaces ``flashnav.train`` (same signature); None = the library's.
    """
    from ray import tune

    if train_fn is None:
        from flashnav import train as train_fn
    spec = Sweep.model_validate(sweep)
    robot, algorithm = config["robot"], config["algorithm"]
    seeds = [int(s) for s in config.get("seeds") or [config["seed"]]]
    params = dict(config.get("params") or {})
    objective = Objective(spec.search) if spec.search else None
    device = devices.trial_device()
    info = {"robot": robot, "algorithm": algorithm, "recipe": spec.base.recipe, "device": device,
            "device_kind": devices.device_kind(device), "git_commit": git_commit, **_provenance()}

    # The staging folder holds every finished seed; each per-seed report checkpoints all of it (Ray
    # copies it to storage inside tune.report), so the latest checkpoint alone says what is done.
    stage = Path(tempfile.mkdtemp(prefix="flashnav-trial-"))
    checkpoint = tune.get_checkpoint()
    if checkpoint:
        checkpoint.to_directory(str(stage))
    done = load_manifest(stage)["done"]
    finished = [objective.of_final(done[s]) for s in seeds if s in done] if objective else []
    try:
        for seed in seeds:
            if seed in done:  # trained before a retry/restore: its run is already in MLflow
                continue
            data = localise_paths(spec.train_config(robot, algorithm, seed, device, extra=params))
            curve: list[dict[str, float]] = []

            def on_eval(metrics: dict[str, float], seed: int = seed, curve: list = curve) -> None:
                point = {key: float(metrics[key]) for key in CURVE_KEYS if key in metrics}
                curve.append(point)
                report = {**point, "seed": seed, "final": 0.0}
                if objective:
                    report["objective"] = objective.mean(finished, objective.of_curve(curve))
                tune.report(report)  # blocks until the driver takes it; flashnav's clock is paused here

            result = train_fn(config_from_data(data, f"{robot}/{algorithm} seed {seed}"), on_eval=on_eval)
            final = final_metrics(result)
            done[seed] = final
            if objective:
                finished.append(objective.of_final(final))
            report = {**final, **info, "seed": seed, "final": 1.0,
                      "device_name": str(getattr(result, "device_name", "") or devices.device_name(device))}
            if getattr(result, "threads", None) is not None:  # a CPU run's learner threads, beside the machine
                report["threads"] = int(result.threads)
            if objective:
                report["objective"] = objective.mean(finished)
            _write_seed(stage, seed, result, final, done, export=spec.export_policy)
            tune.report(report, checkpoint=tune.Checkpoint.from_directory(str(stage)))
        # A trial restored with every seed done reports nothing: its last result (restored with it) stands.
    finally:
        shutil.rmtree(stage, ignore_errors=True)
