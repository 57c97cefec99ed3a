"""The service's only MLflow code: one parent run per sweep, one nested child run per trial (seed).

Everything is written by ONE process, the Tune driver, through :class:`MlflowSweepCallback`, which
receives every result the trials report: many processes writing one SQLite file is how "database is
locked" happens, and MLflow's own Tune callback drops the strings (``device_name``) the tables need.
The layout follows docs/run-schema.md. Child runs are keyed by the ``trial_id`` tag:

* the Ray Tune trial id when a trial trains one seed (grid sweeps: the schema exactly);
* ``<trial id>_s<seed>`` when a search trial trains several seeds: one child per training run, so
  every metric keeps its per-run meaning and readers' one-run-per-trial_id rule still holds
  (the Ray id is in the ``ray_trial_id`` tag).

A retried or restored trial never yields a second FINISHED run for one ``trial_id``: a child whose
FINISHED run exists under the parent is not logged again, and runs left RUNNING by a killed driver are
marked FAILED when the sweep resumes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from ray import tune

from flashnav.yamlio import flatten_dotted
from flashnav.names import TRIAL_SEED_DIR
from services.schema_base import CURVE_METRICS, FINAL_METRICS

logger = logging.getLogger(__name__)

RESULT_TAGS = ("device_name", "threads", "device_kind", "host", "recipe", "flashnav_version", "git_commit", "torch_version")
PARENT_TAG = "mlflow.parentRunId"
_MAX_PARAM_VALUE = 6000  # MLflow 3's limit on a param value


def flatten(data: dict) -> dict[str, str]:
    """Nested dict -> {dotted key: string value}, the form MLflow params take (lists kept whole, values cut at
    MLflow's limit)."""
    return {key: ("None" if value is None else str(value))[:_MAX_PARAM_VALUE]
            for key, value in flatten_dotted(data).items()}


def default_artifact_root(tracking_uri: str) -> str | None:
    """Next to a SQLite store: ``<db dir>/mlartifacts``. MLflow's default is relative to the cwd, which
    in a Ray job is a temporary folder; a server (http) decides for itself."""
    if tracking_uri.startswith("sqlite:///"):
        return str(Path(tracking_uri[len("sqlite:///"):]).parent / "mlartifacts")
    return None


def client_for(tracking_uri: str):
    from mlflow.tracking import MlflowClient

    if tracking_uri.startswith("sqlite:///"):
        Path(tracking_uri[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    return MlflowClient(tracking_uri=tracking_uri)


def experiment_id(client, name: str, tracking_uri: str) -> str:
    """The id of experiment ``name``, created (with an absolute artifact root) where missing."""
    found = client.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    root = default_artifact_root(tracking_uri)
    return client.create_experiment(name, artifact_location=f"{root}/{name}" if root else None)


def _log_batch(client, run_id: str, metrics=(), params=(), tags=()) -> None:
    """log_batch in chunks under MLflow's per-call limits (100 params, 1000 metrics)."""
    metrics, params, tags = list(metrics), list(params), list(tags)
    while metrics or params or tags:
        client.log_batch(run_id, metrics=metrics[:1000], params=params[:100], tags=tags[:100])
        metrics, params, tags = metrics[1000:], params[100:], tags[100:]


def _runs(client, experiment: str, filter_string: str) -> list:
    return list(client.search_runs([experiment], filter_string=filter_string, max_results=5000))


# ---------------------------------------------------------------- parent run


class SweepRun:
    """The parent run of one sweep invocation (driver side)."""

    def __init__(self, tracking_uri: str, experiment: str):
        self.tracking_uri = tracking_uri
        self.experiment = experiment
        self.client = client_for(tracking_uri)
        self.experiment_id = experiment_id(self.client, experiment, tracking_uri)
        self.run_id: str | None = None

    def start(self, sweep: str, run_name: str, tags: dict[str, str], params: dict[str, Any]) -> str:
        from mlflow.entities import Param

        run = self.client.create_run(self.experiment_id, run_name=run_name,
                                     tags={"sweep": sweep, "role": "sweep", **tags})
        self.run_id = run.info.run_id
        _log_batch(self.client, self.run_id, params=[Param(k, v) for k, v in flatten(params).items()])
        return self.run_id

    def resume(self, run_id: str) -> None:
        """Reopen the parent of an interrupted invocation; its children left RUNNING become FAILED."""
        self.run_id = run_id
        self.client.update_run(run_id, status="RUNNING")
        stale = _runs(self.client, self.experiment_id,
                      f"tags.`{PARENT_TAG}` = '{run_id}' and attributes.status = 'RUNNING'")
        for run in stale:
            self.client.set_terminated(run.info.run_id, status="FAILED")

    def log_artifact(self, path: str | Path) -> None:
        self.client.log_artifact(self.run_id, str(path))

    def set_tags(self, tags: dict[str, Any]) -> None:
        from mlflow.entities import RunTag

        _log_batch(self.client, self.run_id, tags=[RunTag(k, str(v)) for k, v in tags.items()])

    def finish(self, status: str = "FINISHED") -> None:
        self.client.set_terminated(self.run_id, status=status)

    def callback(self, sweep: str, tags: dict[str, str]) -> "MlflowSweepCallback":
        return MlflowSweepCallback(self.tracking_uri, self.experiment_id, self.run_id, sweep, tags)


# ---------------------------------------------------------------- child runs (Tune callback)


@dataclass
class _Child:
    run_id: str
    final_logged: bool = False


def child_trial_id(trial_id: str, seed: int, seeds_in_trial: int) -> str:
    """The ``trial_id`` tag: the Ray trial id, suffixed ``_s<seed>`` when the trial trains several seeds."""
    return trial_id if seeds_in_trial <= 1 else f"{trial_id}_s{seed}"


class MlflowSweepCallback(tune.Callback):
    """Tune callback (driver) writing one nested child run per (trial, seed) under the parent run.

    It is pickled into the Tune experiment state (Tuner.restore brings it back), so it holds only
    plain settings; the client and the open-run table are rebuilt after unpickling.
    """

    def __init__(self, tracking_uri: str, experiment_id: str, parent_run_id: str, sweep: str,
                 tags: dict[str, str] | None = None):
        self.tracking_uri = tracking_uri
        self.experiment_id = experiment_id
        self.parent_run_id = parent_run_id
        self.sweep = sweep
        self.tags = dict(tags or {})
        self._client = None
        self._open: dict[tuple[str, int], _Child] = {}
        self._skip: set[tuple[str, int]] = set()

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state.update(_client=None, _open={}, _skip=set())
        return state

    @property
    def client(self):
        if self._client is None:
            self._client = client_for(self.tracking_uri)
        return self._client

    # -- Tune hooks

    def on_trial_result(self, iteration, trials, trial, result, **info):
        if result.get("seed") is None:
            return
        key = (trial.trial_id, int(result["seed"]))
        child = self._open.get(key) or (None if key in self._skip else self._open_child(trial, key))
        if child is None:
            return
        try:
            if float(result.get("final", 0.0)) >= 1.0:
                self._log_final(child, result)
            else:
                self._log_curve(child, result)
        except Exception:  # a tracking hiccup must not kill the sweep; the run ends FAILED instead
            logger.exception("MLflow logging failed for trial %s", trial.trial_id)

    def on_checkpoint(self, iteration, trials, trial, checkpoint, **info):
        from services.trainable import load_manifest

        with checkpoint.as_directory() as directory:
            seed = load_manifest(directory)["latest"]
            if seed is None:
                return
            key = (trial.trial_id, int(seed))
            child = self._open.pop(key, None)
            run_id = child.run_id if child and child.final_logged else None
            if child and not child.final_logged:
                self._open[key] = child  # checkpoint without its final result: wait for it
                return
            if run_id is None:  # already closed (e.g. by on_trial_complete): find the FINISHED run
                found = self._finished(self._trial_tag(trial, int(seed)))
                run_id = found[0].info.run_id if found else None
            if run_id is None:
                return
            self._log_artifacts(run_id, Path(directory) / TRIAL_SEED_DIR.format(seed=seed))
            if child:
                self.client.set_terminated(run_id, status="FINISHED")
            self._skip.add(key)

    def on_trial_recover(self, iteration, trials, trial, **info):
        self._close_trial(trial, "FAILED")

    def on_trial_error(self, iteration, trials, trial, **info):
        self._close_trial(trial, "FAILED")

    def on_trial_complete(self, iteration, trials, trial, **info):
        # A child whose final metrics arrived is a completed run even if its artifacts never came.
        self._close_trial(trial, "FINISHED", only_final=True)
        self._close_trial(trial, "FAILED")

    def on_experiment_end(self, trials, **info):
        for key in list(self._open):
            self.client.set_terminated(self._open.pop(key).run_id, status="FAILED")

    # -- helpers

    def _trial_tag(self, trial, seed: int) -> str:
        return child_trial_id(trial.trial_id, seed, len(trial.config.get("seeds") or [0]))

    def _finished(self, trial_tag: str) -> list:
        return _runs(self.client, self.experiment_id,
                     f"tags.`{PARENT_TAG}` = '{self.parent_run_id}' and tags.trial_id = '{trial_tag}' "
                     f"and attributes.status = 'FINISHED'")

    def _open_child(self, trial, key: tuple[str, int]) -> _Child | None:
        seed = key[1]
        trial_tag = self._trial_tag(trial, seed)
        if self._finished(trial_tag):  # logged before a restore/retry: never a second FINISHED run
            self._skip.add(key)
            return None
        robot, algorithm = trial.config.get("robot", ""), trial.config.get("algorithm", "")
        tags = {**self.tags, PARENT_TAG: self.parent_run_id, "sweep": self.sweep, "role": "trial",
                "trial_id": trial_tag, "ray_trial_id": trial.trial_id, "robot": str(robot),
                "algorithm": str(algorithm), "seed": str(seed)}
        name = f"{robot}-{algorithm}-s{seed}"
        if trial.config.get("params") is not None:  # a search trial: its number (Tune's), in the name and a tag
            tags["search_trial"] = number = trial.trial_id.rsplit("_", 1)[-1]
            name = f"{robot}-{algorithm}-t{number}-s{seed}"
        run = self.client.create_run(self.experiment_id, run_name=name, tags=tags)
        child = self._open[key] = _Child(run.info.run_id)
        return child

    def _log_curve(self, child: _Child, result: dict) -> None:
        from mlflow.entities import Metric

        step = int(result.get("env_steps", 0))
        stamp = int(float(result.get("timestamp", 0)) * 1000) or _now_ms()
        metrics = [Metric(k, float(result[k]), stamp, step) for k in CURVE_METRICS if k in result]
        _log_batch(self.client, child.run_id, metrics=metrics)

    def _log_final(self, child: _Child, result: dict) -> None:
        from mlflow.entities import Metric, RunTag

        stamp = _now_ms()
        step = int(result.get("env_steps_total", 0))
        metrics = [Metric(k, float(result[k]), stamp, step) for k in FINAL_METRICS if k in result]
        tags = [RunTag(k, str(result[k])) for k in RESULT_TAGS if result.get(k) not in (None, "")]
        _log_batch(self.client, child.run_id, metrics=metrics, tags=tags)
        child.final_logged = True

    def _log_artifacts(self, run_id: str, seed_dir: Path) -> None:
        from mlflow.entities import Param

        config_path = seed_dir / "config.yaml"
        if config_path.exists():
            config = yaml.safe_load(config_path.read_text()) or {}
            existing = set(self.client.get_run(run_id).data.params)
            params = [Param(k, v) for k, v in flatten(config).items() if k not in existing]
            _log_batch(self.client, run_id, params=params)
        for path in sorted(seed_dir.iterdir()):
            if path.is_file():
                self.client.log_artifact(run_id, str(path))

    def _close_trial(self, trial, status: str, only_final: bool = False) -> None:
        for key in [k for k in self._open if k[0] == trial.trial_id]:
            if only_final and not self._open[key].final_logged:
                continue
            self.client.set_terminated(self._open.pop(key).run_id, status=status)
            if status == "FINISHED":
                self._skip.add(key)


def _now_ms() -> int:
    import time

    return int(time.time() * 1000)
