"""``flashnav bench runs``: the table of finished training runs, environment steps first (issue 16, item 1).

Reads ``flashnav train`` run folders (their ``metrics.json``), ``flashnav sweep run`` output folders (each
trial's per-seed ``result.json``) and ``flashnav bench train --json`` files,
and prints one row per run - environment steps to 90 / 95 / 100 % on the fixed evaluation set, the best
evaluation, the mean and the worst of the last evaluations (how steady the end of the run is), and where
the training episodes reached 100 % - then one row per robot x algorithm with the paper-budget view: how
many runs reached 100 % within the paper's environment-step budget. Nothing is re-run: the numbers are the
runs' own records.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from rich.console import Console
from rich.table import Table

from flashnav.learn.hparams import paper_budget
from flashnav.metrics import THRESHOLDS, on_paper_task, over_seeds, within_budget
from flashnav.names import METRICS_FILE, SWEEP_STATE_FILE, TRIAL_RESULT_FILE, TRIAL_SEED_DIR
from flashnav.yamlio import flatten_dotted

LAST = 10  # the last evaluations read for "steady at the end"


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("runs", help="the table of finished runs (run folders, sweep outputs, bench train --json "
                                     "files): "
                                     "env steps to 90/95/100 %%, best, last evaluations, paper budget")
    p.add_argument("sources", nargs="+", metavar="JSON_OR_RUN_OR_SWEEP_DIR",
                   help="a flashnav train run folder (its metrics.json), a flashnav sweep run output folder "
                        "(runs/ray/NAME/STAMP: each trial's latest checkpoint) or a flashnav bench train --json file")
    p.add_argument("--last", type=int, default=LAST, help="how many of the last evaluations the steadiness columns read")
    p.add_argument("--json", metavar="FILE", help="also write the rows and the groups as JSON")
    p.set_defaults(func=run_bench_runs)


def _record(result: dict, label: str) -> dict:
    c = result["config"]
    if not isinstance(c, dict):
        raise TypeError(f"its config is {c!r:.40}, not an object")
    return {**result, "label": label, "robot": c["robot"], "algorithm": c["algorithm"], "seed": c["seed"]}


def sweep_results(folder: Path) -> list[Path]:
    """The per-seed result files of a ``flashnav sweep run`` output (runs/ray/NAME/STAMP or any folder above its
    trials): each trial's latest checkpoint holds every seed the trial finished, so only that one is read."""
    latest: dict[Path, Path] = {}
    for ckpt in folder.rglob("checkpoint_*"):
        if ckpt.is_dir() and (ckpt.parent not in latest or ckpt.name > latest[ckpt.parent].name):
            latest[ckpt.parent] = ckpt
    pattern = f"{TRIAL_SEED_DIR.format(seed='*')}/{TRIAL_RESULT_FILE}"
    found, empty = [], []
    for ckpt in sorted(latest.values()):
        files = sorted(ckpt.glob(pattern))
        found += files
        if not files:
            empty.append(ckpt)
    if empty and found:  # (a damaged trial was dropped from the count without a word)
        warnings.warn(f"{len(empty)} trial checkpoint(s) without a {TRIAL_SEED_DIR.format(seed='*')}/"
                      f"{TRIAL_RESULT_FILE}, left out: {', '.join(str(c) for c in empty[:3])}"
                      + (" ..." if len(empty) > 3 else ""), RuntimeWarning, stacklevel=2)
    return found


def _trial_records(found: list[Path]) -> list[dict]:
    """The records of a sweep's result files, labelled with the trial's name (Tune's ``train_trial_<id>_<n>``)
    and seed, sorted by trial folder and seed."""
    records, invocations = [], set()
    for path in found:
        trial = path.parent.parent.parent  # <stamp>/<target>/<trial>/checkpoint_<i>/seed_<s>/result.json
        try:
            result = json.loads(path.read_text(encoding="utf-8"))
            label = f"{trial.name.split('_algorithm=')[0]} seed {result['config']['seed']}"
            records.append((str(trial), _record(result, label)))
        except (OSError, json.JSONDecodeError, KeyError, TypeError) as e:  # the file, not the folder above it
            raise ValueError(f"{path}: not a trial's result ({type(e).__name__}: {e})") from None
        invocations.add(trial.parent.parent)
    if len(invocations) > 1:  # each seed once per invocation: pooled, they count as more seeds
        warnings.warn(f"{len(invocations)} sweep invocations pooled ({', '.join(sorted(p.name for p in invocations))}"
                      f"): a seed run by several counts once per run; give one invocation's folder "
                      f"({sorted(invocations)[-1]}) to count each once", RuntimeWarning, stacklevel=2)
    return [r for _, r in sorted(records, key=lambda x: (x[0], x[1]["seed"]))]


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def record_problem(r) -> str | None:
    """What makes ``r`` no run record (None: nothing): ``robot`` and ``algorithm`` names, an integer ``seed``, a
    ``curve`` of evaluations (objects with a ``success_rate`` in [0, 1]; ``env_steps`` and ``train_seconds``
    numbers where given) and, where given, an ``env_steps_to_threshold`` object, as ``flashnav train`` writes them."""
    if not isinstance(r, dict):
        return f"a run is {type(r).__name__} {r!r:.40}, not a JSON object"
    for key in ("robot", "algorithm"):
        if not isinstance(r.get(key), str):
            return f"its {key} is {r.get(key)!r}, not a name"
    if not isinstance(r.get("seed"), int) or isinstance(r.get("seed"), bool):
        return f"its seed is {r.get('seed')!r}, not an integer"
    curve = r.get("curve")
    if not isinstance(curve, list):
        return f"its curve is {curve!r:.40}, not a list of evaluations"
    for i, point in enumerate(curve):
        if not isinstance(point, dict):
            return f"evaluation {i} of its curve is {point!r:.40}, not a JSON object"
        rate = point.get("success_rate")
        if not (_number(rate) and 0 <= rate <= 1):
            return f"evaluation {i} of its curve has success_rate {rate!r}, not a number in [0, 1]"
        for key in ("env_steps", "train_seconds"):
            if key in point and not _number(point[key]):
                return f"evaluation {i} of its curve has {key} {point[key]!r}, not a number"
    if not isinstance(r.get("env_steps_to_threshold", {}), dict):
        return f"its env_steps_to_threshold is {r['env_steps_to_threshold']!r:.40}, not a JSON object"
    return None


def load_runs(source: Path) -> list[dict]:
    """The run records of a run folder (``label``: the folder's name), of a sweep's output folder (``label``:
    the trial's name - Tune's ``train_trial_<id>_<n>`` - and seed) or of a ``bench train --json`` file
    (``source``: the file's stem), each with ``robot``, ``algorithm``, ``seed``, ``curve``, the threshold records
    and, from run folders and sweeps, ``config`` (:func:`record_problem`); a ValueError names the source."""
    try:
        if source.is_dir() and (source / SWEEP_STATE_FILE).is_file():  # the outputs folder `sweep run` prints
            source = Path(json.loads((source / SWEEP_STATE_FILE).read_text(encoding="utf-8"))["ray_storage"])
        if source.is_dir():
            if not (source / METRICS_FILE).exists() and (found := sweep_results(source)):
                runs = _trial_records(found)
            else:
                runs = [_record(json.loads((source / METRICS_FILE).read_text(encoding="utf-8")), source.name)]
        else:
            runs = json.loads(source.read_text(encoding="utf-8"))["runs"]
            if not isinstance(runs, list):
                raise TypeError("its runs are not a list")
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(f"{source}: not a flashnav train run folder with {METRICS_FILE}, a flashnav sweep run output "
                         f"(trial checkpoints with {TRIAL_RESULT_FILE}) or a flashnav bench train --json file "
                         f"({type(e).__name__}: {e})") from None
    for i, r in enumerate(runs):
        if problem := record_problem(r):
            which = "" if len(runs) == 1 else f"run {i}: "
            raise ValueError(f"{source}: {which}{problem}")
    return runs if source.is_dir() else [{**r, "source": source.stem} for r in runs]


def sources_files(sources) -> list[Path]:
    """The files that ``sources`` (run folders, sweep outputs, bench files) are read from, that an output must not
    overwrite: each folder's metrics.json, each file itself (a sweep's result files are under its folder)."""
    return [Path(s) / METRICS_FILE if Path(s).is_dir() else Path(s) for s in sources]


def run_label(r: dict) -> str:
    """A run record's name: its folder's (``label``), else its bench file's stem and seed."""
    return r.get("label") or f"{r.get('source', '?')} seed {r['seed']}"


def run_row(r: dict, last: int = LAST) -> dict:
    """One run's row: env steps to each threshold (None: not reached), best, the mean and the minimum of
    the last ``last`` evaluations, the env steps where the training episodes reached 100 %, env steps run."""
    if last < 1:
        raise ValueError(f"--last must be >= 1, got {last}")
    label = run_label(r)
    curve = r["curve"]
    if not curve:
        raise ValueError(f"{label}: no evaluations in its curve")
    if not isinstance(r.get("env_steps_to_threshold"), dict):
        raise ValueError(f"{label}: its record has no env_steps_to_threshold (flashnav train's metrics.json has)")
    tail = [p["success_rate"] for p in curve[-last:]]
    train = (r.get("training_episodes_to_threshold") or {}).get("env_steps", {})
    return {"label": label, "robot": r["robot"], "algorithm": r["algorithm"], "seed": r["seed"],
            **{f"to_{t}": r["env_steps_to_threshold"].get(str(t)) for t in THRESHOLDS},
            "best": max(p["success_rate"] for p in curve), "last_mean": sum(tail) / len(tail), "last_min": min(tail),
            "last_n": len(tail), "train_episodes_100": train.get(str(THRESHOLDS[-1])),
            "env_steps": r.get("env_steps", curve[-1].get("env_steps")), "stop_reason": r.get("stop_reason"),
            "paper_task": on_paper_task(flatten_dotted(r.get("config") or {}))}


def group_rows(rows: list[dict]) -> list[dict]:
    """Per robot x algorithm: runs, k reached and mean env steps per threshold, 100 % within the paper's
    budget (k / runs; None where the paper has no recipe for the pair or a run is off the paper's task: trained
    or scored on other maps, flashnav.metrics.on_paper_task) and ``cut_short``: the runs without
    100 % that ended before that budget (stopped by time, interrupted, a snapshot of a run still going), which
    the budget's k / runs counts as misses although they never had the whole budget."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["robot"], row["algorithm"]), []).append(row)
    out = []
    for (robot, algo), rs in groups.items():
        budget = paper_budget(algo, Path(robot).stem) if all(x.get("paper_task", True) for x in rs) else None
        g = {"robot": robot, "algorithm": algo, "runs": len(rs), "budget": budget}
        for t in THRESHOLDS:
            stats = over_seeds([x[f"to_{t}"] for x in rs], interval=False)
            g[f"to_{t}"] = {"reached": stats.k, "mean": stats.mean}
        top = [x[f"to_{THRESHOLDS[-1]}"] for x in rs]
        g["within_budget"] = None if budget is None else within_budget(top, budget)
        g["cut_short"] = 0 if budget is None else sum(
            1 for x in rs if x[f"to_{THRESHOLDS[-1]}"] is None and x["env_steps"] is not None and x["env_steps"] < budget)
        g["best"] = [min(x["best"] for x in rs), max(x["best"] for x in rs)]
        out.append(g)
    return out


def _steps(v) -> str:
    return "-" if v is None else f"{v:,.0f}"


def run_bench_runs(args) -> int:
    from flashnav.outputs import check_output_file

    console = Console()
    if not console.is_terminal:
        console = Console(width=200)
    try:
        if args.json:  # before the table: a bad path, or one of the runs' own files, costs nothing
            check_output_file(args.json, "--json", inputs=sources_files(args.sources))
        records = [r for source in args.sources for r in load_runs(Path(source))]
        rows = [run_row(r, args.last) for r in records]
    except ValueError as e:
        print(f"flashnav bench runs: {e}", file=sys.stderr)
        return 2
    groups = group_rows(rows)
    t = Table(title="finished runs: environment steps to success on the fixed evaluation set")
    for col in ("run", "robot", "algo", "seed", "to 90%", "to 95%", "to 100%", "best",
                f"last {args.last}: mean (min)", "training episodes 100% at", "env steps run", "stopped by"):
        t.add_column(col, justify="right")
    for x in rows:
        t.add_row(x["label"], x["robot"], x["algorithm"], str(x["seed"]), *(_steps(x[f"to_{th}"]) for th in THRESHOLDS),
                  f"{x['best']:.2%}", f"{x['last_mean']:.1%} ({x['last_min']:.1%})", _steps(x["train_episodes_100"]),
                  _steps(x["env_steps"]), x["stop_reason"] or "-")
    console.print(t)
    g = Table(title="per robot x algorithm: mean env steps over the runs that reached each threshold (k/n)")
    for col in ("robot", "algo", "runs", "90%", "95%", "100%", "100% within the paper's budget", "best"):
        g.add_column(col, justify="right")
    for x in groups:
        cells = [f"{_steps(x[f'to_{th}']['mean'])} ({x[f'to_{th}']['reached']}/{x['runs']})" for th in THRESHOLDS]
        budget = "-" if x["budget"] is None else f"{x['within_budget']}/{x['runs']} (<= {x['budget']:,})" + (
            f"; {x['cut_short']} cut short" if x["cut_short"] else "")
        g.add_row(x["robot"], x["algorithm"], str(x["runs"]), *cells, budget, f"{x['best'][0]:.2%}-{x['best'][1]:.2%}")
    console.print(g)
    if args.json:
        Path(args.json).write_text(json.dumps({"runs": rows, "groups": groups}, indent=2), encoding="utf-8")
        console.print(f"written: {args.json}", markup=False)
    return 0
