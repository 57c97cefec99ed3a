"""Optuna through Ray Tune: search space, the searcher, and what a finished study leaves behind.

The searcher is ``ray.tune.search.optuna.OptunaSearch`` over an ``optuna.storages.RDBStorage`` *object*
(an absolute SQLite path by default): OptunaSearch forces ``load_if_exists`` and would silently append
to an old study of the same name, so every sweep invocation gets its own study name unless the sweep
names one, and a named study that already holds trials is refused unless the sweep is resumed. The
searcher is wrapped in a ConcurrencyLimiter (TPE learns from finished trials only).

At the end of a study this module writes the best configuration as a sweep YAML ready for a 10-seed
run, and a summary (trials, best value, parameter importances where Optuna can compute them).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ray.tune.search.optuna import OptunaSearch

from flashnav.metrics import plain_number
from services.schema_base import SweepError
from services.search_space import Distribution
from services.sweep_schema import Sweep, sweep_to_yaml

PARAMS_KEY = "params"  # Tune config key holding the searched values; Optuna names them "params/<path>"


def tune_domain(dist: Distribution):
    """A Tune search domain; ``int``/``logint`` bounds are inclusive in the sweep, exclusive in Tune."""
    from ray import tune

    low_high = dist.args
    return {
        "choice": lambda: tune.choice(list(dist.args)),
        "int": lambda: tune.randint(low_high[0], low_high[1] + 1),
        "logint": lambda: tune.lograndint(low_high[0], low_high[1] + 1),
        "uniform": lambda: tune.uniform(*low_high),
        "loguniform": lambda: tune.loguniform(*low_high),
    }[dist.kind]()


def first_value(dist: Distribution) -> Any:
    """A valid sample (for validating a TrainConfig in the driver before anything runs)."""
    return dist.args[0]


def search_space(sweep: Sweep, algorithm: str) -> dict[str, Any]:
    return {path: tune_domain(dist) for path, dist in sweep.search.space_for(algorithm).items()}


def storage(url: str):
    """An Optuna RDBStorage for ``url`` (an absolute sqlite URL after path resolution); SweepError naming
    search.storage when it cannot be opened (a database driver that is not installed, a file that is not a
    database, a folder that cannot be made)."""
    import optuna
    import sqlalchemy.exc

    from services.paths import redact_uri

    try:
        if url.startswith("sqlite:///"):
            Path(url[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
        return optuna.storages.RDBStorage(url=url)
    except (ImportError, OSError, sqlalchemy.exc.SQLAlchemyError) as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SweepError(f"search.storage {redact_uri(url)}: Optuna cannot open it ({reason})") from None


def study_name(sweep: Sweep, robot: str, algorithm: str, stamp: str, n_targets: int) -> str:
    """The sweep's study name (suffixed per target when it has several), else a per-invocation name."""
    if sweep.search.study_name:
        base = sweep.search.study_name
        return base if n_targets == 1 else f"{base}-{robot}-{algorithm}"
    return f"{sweep.name}-{robot}-{algorithm}-{stamp}"


def check_fresh(url: str, name: str) -> None:
    """Refuse to append a new invocation to a study that already has trials."""
    import optuna

    if url.startswith("sqlite:///") and not Path(url[len("sqlite:///"):]).exists():
        return  # no database yet (and a dry run must not create one)
    try:
        study = optuna.load_study(study_name=name, storage=storage(url))
    except KeyError:
        return
    if study.trials:
        raise SweepError(f"Optuna study {name!r} in {url} already has {len(study.trials)} trials; "
                         "use --resume, another search.study_name, or leave study_name unset")


class FinalOnlyOptunaSearch(OptunaSearch):
    """OptunaSearch that tells Optuna only each trial's final value.

    Intermediate reports would feed Optuna's pruning, which is off here (time to threshold is known only
    at the end of a trial); they would also write a row per evaluation to the study's SQLite file, and
    a trial restored after a kill may report again although Optuna already holds it as finished, which
    Optuna rejects with UpdateFinishedTrialError.
    """

    def on_trial_result(self, trial_id: str, result: dict) -> None:
        return None


def start_points(sweep: Sweep, algorithm: str) -> list[dict[str, Any]]:
    """The sweep's start points as Optuna names them, restricted to ``algorithm``'s search space."""
    space = sweep.search.space_for(algorithm)
    points = [{f"{PARAMS_KEY}/{path}": value for path, value in point.items() if path in space}
              for point in sweep.search.start_points]
    return [point for point in points if point]


def make_searcher(sweep: Sweep, url: str, name: str, algorithm: str):
    """ConcurrencyLimiter(OptunaSearch) for one (robot, algorithm) study; metric/mode come from TuneConfig.

    The sweep's ``start_points`` are enqueued in the study (a fresh one: a resumed sweep restores its
    searcher instead and enqueues nothing again). TPE draws at random until ``search.startup_trials`` trials
    (start points included; Optuna's default 10) have finished, then from a model of the results.
    """
    import optuna
    from ray.tune.search import ConcurrencyLimiter

    startup = sweep.search.startup_trials
    sampler = optuna.samplers.TPESampler(seed=sweep.search.sampler_seed,
                                         **({"n_startup_trials": startup} if startup else {}))
    searcher = FinalOnlyOptunaSearch(sampler=sampler, study_name=name, storage=storage(url),
                                     points_to_evaluate=start_points(sweep, algorithm) or None)
    return ConcurrencyLimiter(searcher, max_concurrent=sweep.max_concurrent_trials or 4)


def fail_orphans(url: str, name: str) -> int:
    """Mark trials still RUNNING after the study's Tuner returned as FAIL; returns how many.

    They were asked for by a driver that was killed before Tune recorded them; the resumed driver
    suggests fresh trials instead, so nothing will ever finish these.
    """
    import optuna

    study = optuna.load_study(study_name=name, storage=storage(url))
    orphans = [t for t in study.trials if t.state == optuna.trial.TrialState.RUNNING]
    for trial in orphans:
        study._storage.set_trial_state_values(trial._trial_id, state=optuna.trial.TrialState.FAIL)
    return len(orphans)


def summarize(url: str, name: str, sweep: Sweep, robot: str, algorithm: str) -> dict[str, Any]:
    """Trials by state, the best trial (value, params) and parameter importances of a stored study."""
    import optuna

    study = optuna.load_study(study_name=name, storage=storage(url))
    states: dict[str, int] = {}
    for trial in study.trials:
        states[trial.state.name] = states.get(trial.state.name, 0) + 1
    summary: dict[str, Any] = {
        "study": name, "storage": url, "robot": robot, "algorithm": algorithm,
        "objective": sweep.search.objective, "direction": sweep.search.mode,
        "seeds_per_trial": sweep.search.seeds_per_trial, "trials": states,
    }
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    if complete:
        best = study.best_trial
        summary["best"] = {"number": best.number, "value": best.value, "params": config_params(best.params)}
    try:
        importances = optuna.importance.get_param_importances(study)
        summary["importances"] = {k.removeprefix(f"{PARAMS_KEY}/"): float(v) for k, v in importances.items()}
    except Exception as exc:  # too few trials, or a single distinct value: Optuna cannot tell
        summary["importances"] = None
        summary["importances_note"] = f"not computed: {exc}"
    return summary


def config_params(optuna_params: dict[str, Any]) -> dict[str, Any]:
    """Optuna's flattened names (``params/algo.batch_size``) -> config paths (``algo.batch_size``)."""
    return {k.removeprefix(f"{PARAMS_KEY}/"): plain_number(v) for k, v in optuna_params.items()}


def best_sweep(sweep: Sweep, robot: str, algorithm: str, params: dict[str, Any]) -> Sweep:
    """The sweep to run next: the best params as fixed overrides, ``search.best_seeds`` seeds, no search."""
    data = sweep.model_dump(mode="json")
    data.update(
        name=f"{sweep.name}_best_{Path(robot).stem}_{algorithm}",
        description=f"best of Optuna sweep {sweep.name!r} ({robot}, {algorithm}), {sweep.search.best_seeds} seeds",
        robots=[robot], algorithms=[algorithm], seeds=sweep.search.best_seeds, search=None,
        # The 10-seed run reports time to 90/95/100 %: train on to 100 % even if the search stopped at 90.
        budget={**sweep.budget.model_dump(),
                "stop_at_success": None if sweep.budget.stop_at_success is None else 1.0},
        overrides={**sweep.overrides, **params},
        algorithm_overrides={k: v for k, v in sweep.algorithm_overrides.items() if k == algorithm},
    )
    data["tracking"]["experiment"] = None
    return Sweep.model_validate(data)


def write_outputs(out_dir: Path, summaries: list[dict[str, Any]], sweep: Sweep) -> list[Path]:
    """``optuna_summary.json`` and one ``best_<robot>_<algorithm>.yaml`` per study with a best trial."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for summary in summaries:
        if "best" not in summary:
            continue
        best = best_sweep(sweep, summary["robot"], summary["algorithm"], summary["best"]["params"])
        path = out_dir / f"best_{Path(summary['robot']).stem}_{summary['algorithm']}.yaml"
        header = (f"# Best configuration of Optuna study {summary['study']} "
                  f"({summary['objective']} = {summary['best']['value']:.4g}, mean over "
                  f"{summary['seeds_per_trial']} seed(s)).\n# Run it: flashnav sweep run {path}\n")
        path.write_text(header + sweep_to_yaml(best), encoding="utf-8")
        summary["best_config"] = str(path)
        written.append(path)
    summary_path = out_dir / "optuna_summary.json"
    summary_path.write_text(json.dumps(summaries, indent=2), encoding="utf-8")
    return [summary_path, *written]
