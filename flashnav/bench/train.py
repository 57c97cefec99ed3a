"""``flashnav bench train``: S seeds of robot x algorithm x recipe -> time-to-threshold statistics."""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import statistics
import sys
from dataclasses import replace
from pathlib import Path

from rich.console import Console
from rich.table import Table

from flashnav.learn.hparams import paper_budget
from flashnav.learn.progress import TrainProgress
from flashnav.metrics import THRESHOLDS, over_seeds, within_budget
from flashnav.names import ALGORITHMS, DEFAULT_ROBOT, DEVICE_HELP, METRICS_FILE, RECIPE_CHOICES, RECIPE_HELP, ROBOTS


def register_cli(bsub: argparse._SubParsersAction) -> None:
    p = bsub.add_parser("train", help="time-to-90/95/100%% success over several seeds")
    add_run_choices(p)
    p.add_argument("--seeds", type=int, default=3, help="seeds 0..S-1")
    p.add_argument("--budget-seconds", type=float, default=600.0, help="training-clock budget per run")
    p.add_argument("--json", metavar="FILE", help="write every run's metrics")
    p.add_argument("--plot", metavar="PNG", help="draw success against training seconds, one line per seed")
    p.add_argument("overrides", nargs="*", metavar="key=value", help="as for flashnav train")
    p.set_defaults(func=run_bench_train)
    q = bsub.add_parser("plot", help="draw the success curves of `bench train --json` files, `flashnav train` "
                                     "run folders and `flashnav sweep run` outputs")
    q.add_argument("sources", nargs="*", metavar="JSON_OR_RUN_OR_SWEEP_DIR",
                   help="a file written by flashnav bench train --json, a run folder (its metrics.json) or a sweep's "
                        "output folder or one trial's folder in it (each trial's latest checkpoint)")
    q.add_argument("--arm", nargs="+", action="append", default=[], metavar=("NAME", "JSON_OR_RUN_DIR"),
                   help="NAME and its sources: one colour and one legend entry per arm instead of per run "
                        "(repeat for each arm, e.g. --arm fine-tuned runs/ft-s* --arm scratch runs/sc-s*)")
    q.add_argument("--out", required=True, metavar="PNG")
    q.add_argument("--x", choices=("env-steps", "seconds"), default="env-steps",
                   help="horizontal axis: environment steps (default; machine-independent) or training seconds")
    q.add_argument("--ymin", type=float, default=0.0,
                   help="lowest success (%%) drawn, e.g. 90 to see the plateau under 100 %% (default 0)")
    q.set_defaults(func=run_bench_plot)


def add_run_choices(p: argparse.ArgumentParser) -> None:
    """The flags that choose what a training bench runs: --robots, --algos, --recipe, --device."""
    p.add_argument("--robots", default=DEFAULT_ROBOT, help=f"comma-separated presets ({', '.join(ROBOTS)} or YAML paths)")
    p.add_argument("--algos", default="fastdsac", help=f"comma-separated learners ({', '.join(ALGORITHMS)})")
    p.add_argument("--recipe", default="auto", choices=RECIPE_CHOICES, help="hyperparameters: " + RECIPE_HELP)
    p.add_argument("--device", default="auto", help=DEVICE_HELP)


def summarise(runs: list[dict], budget: int | None = None) -> dict:
    """Best / mean env steps and seconds to each threshold over the runs that reached it, k/S, and
    (with the paper's env-step ``budget`` of the robot x algorithm) how many reached it within that."""
    out = {"runs": len(runs), "budget": budget}
    for t in THRESHOLDS:
        secs = over_seeds([r["time_to_threshold"][str(t)] for r in runs], interval=False)
        step_values = [r["env_steps_to_threshold"][str(t)] for r in runs]
        steps = over_seeds(step_values, interval=False)
        out[str(t)] = {"reached": secs.k, "best_s": secs.best, "mean_s": secs.mean, "best_env_steps": steps.best,
                       "mean_env_steps": steps.mean, "within_budget": within_budget(step_values, budget)}
    # 100 % read on the training episodes (metrics.json training_episodes_to_threshold; older JSON: none)
    train_values = [r.get("training_episodes_to_threshold", {}).get("env_steps", {}).get(str(THRESHOLDS[-1]))
                    for r in runs]
    train = over_seeds(train_values, interval=False)
    out["training_episodes"] = {"reached": train.k, "best_env_steps": train.best, "mean_env_steps": train.mean,
                                "within_budget": within_budget(train_values, budget)}
    for k in ("collector_ms", "learner_ms", "effective_ms"):
        out[k] = statistics.fmean(r["cycle"][k] for r in runs)
    out["threads"] = sorted({r["threads"] for r in runs if r.get("threads") is not None})  # [] on a GPU
    return out


def run_bench_train(args) -> int:
    from flashnav.learn.loop import train
    from flashnav.outputs import check_figure_file, check_output_file
    from flashnav.spec import config_from_cli, resolve

    if args.json:  # before any training: a bad path costs nothing
        check_output_file(args.json, "--json")
    if args.plot:
        args.plot = check_figure_file(args.plot, "--plot")
    console = Console()
    if not console.is_terminal:  # a log file: rich's 80 columns would cut the eleven-column table to stubs
        console = Console(width=220)
    when = dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    # Every run's spec first, through flashnav train's own path: a bad name or key fails before any training.
    assignments = [*args.overrides, f"budget.max_train_seconds={args.budget_seconds}"]
    # One resolution per robot x algorithm; the seeds differ in the seed alone and share its loaded map
    # (and the map's derived fields, computed once).
    firsts = [(robot, algo, resolve(config_from_cli(None, dict(robot=robot, algorithm=algo, recipe=args.recipe,
                                                                device=args.device, seed=0), assignments)))
              for robot in args.robots.split(",") for algo in args.algos.split(",")]
    plan = [[(robot, algo, seed, replace(spec, config=spec.config.model_copy(update={"seed": seed})))
             for seed in range(args.seeds)] for robot, algo, spec in firsts]
    results, groups = [], []
    for specs in plan:
        runs = []
        for robot, algo, seed, spec in specs:
            with TrainProgress(console, label=f"{robot} {algo} seed {seed}", eval_lines=False,
                               transient=True) as progress:
                result = train(spec, on_eval=progress.on_eval, on_progress=progress.on_progress)
            r = result.to_dict()
            r.pop("config")
            r.update(robot=robot, algorithm=algo, seed=seed, recipe=spec.recipe)
            runs.append(r)
            t90 = r["time_to_threshold"]["0.9"]
            console.print(f"  {robot} {algo} seed {seed}: 90% at {'-' if t90 is None else f'{t90:.1f} s'}, "
                          f"final success {r['curve'][-1]['success_rate']:.1%} ({r['stop_reason']})")
            _save(args.json, when, groups, results + runs)  # after every run: an interrupted bench keeps its runs
        results += runs
        robot, algo = specs[0][0], specs[0][1]
        budget = paper_budget(algo, specs[0][3].robot_name)
        groups.append((robot, algo, runs[0]["recipe"], runs[0]["device_name"], summarise(runs, budget)))
        _save(args.json, when, groups, results)
    _print(console, groups, args.seeds, when)
    if args.plot:
        from flashnav.viz import plot_training_runs

        console.print(f"success curves: {plot_training_runs(results, args.plot, _plot_title(when, args.budget_seconds))}")
    return 0


def _plot_title(when: str, budget_seconds: float | None) -> str:
    budget = "" if budget_seconds is None else f", budget {budget_seconds:g} s per run"
    return f"flashnav bench train {when}{budget}; dots: first 90/95/100 % crossing"


def run_bench_plot(args) -> int:
    from flashnav.outputs import check_figure_file
    from flashnav.viz import plot_training_runs

    args.out = check_figure_file(args.out, "--out")
    x = "env_steps" if args.x == "env-steps" else "train_seconds"
    bad = [a[0] for a in args.arm if len(a) < 2]
    if not (math.isfinite(args.ymin) and 0 <= args.ymin < 100):
        return _plot_error(f"--ymin is the success (%) the axis starts at, in [0, 100); got {args.ymin}")
    if bad or not (args.sources or args.arm):
        return _plot_error(f"--arm {bad[0]} names no run" if bad else
                           "give run folders or bench files, or --arm NAME SOURCE...")
    runs, dates = [], []
    for arm, source in [(None, s) for s in args.sources] + [(a[0], s) for a in args.arm for s in a[1:]]:
        try:
            found, date = load_curves(Path(source))
        except (OSError, ValueError, KeyError) as e:
            return _plot_error(f"{source} is not a `flashnav bench train --json` file or a `flashnav train` run "
                               f"folder with metrics.json ({e})")
        if empty := [r for r in found if not r["curve"]]:
            return _plot_error(f"{source}: {len(empty)} of its runs have no evaluations in their curve")
        if not all(x in p for r in found for p in r["curve"]):
            return _plot_error(f"{source}: its curves have no {x}; use --x seconds")
        runs += [dict(r, arm=arm) if arm else r for r in found]
        dates.append(date)
    title = f"success curves, {', '.join(sorted(set(dates)))}; dots: first 90/95/100 % crossing"
    print(f"success curves: {plot_training_runs(runs, args.out, title, x=x, ymin=args.ymin)}")
    return 0


def _plot_error(message: str) -> int:
    print(f"flashnav bench plot: {message}", file=sys.stderr)
    return 2


def load_curves(source: Path) -> tuple[list[dict], str]:
    """The runs (records with ``curve``) of a ``bench train --json`` file, the one run of a ``flashnav train``
    folder (its metrics.json; labelled with the folder's name) or the trials of a ``flashnav sweep run`` output
    (each trial's latest checkpoint, :func:`flashnav.bench.runs.load_runs`), and their date."""
    from flashnav.bench.runs import load_runs

    runs = load_runs(source)
    if not runs or not all("curve" in r for r in runs):
        raise KeyError("curve")
    if source.is_dir():  # a run folder (its metrics.json) or a sweep's output (the folder itself)
        stamp = source / METRICS_FILE if (source / METRICS_FILE).exists() else source
        return runs, dt.datetime.fromtimestamp(stamp.stat().st_mtime).strftime("%Y-%m-%d")
    with open(source, encoding="utf-8") as f:
        return runs, json.load(f).get("date", "?")


def _save(path: str | None, when: str, groups, runs: list[dict]) -> None:
    if path:
        with open(path, "w", encoding="utf-8") as f:
            json.dump({"date": when, "groups": [g[:4] + (g[4],) for g in groups], "runs": runs}, f, indent=2)


def _print(console: Console, groups, seeds: int, when: str) -> None:
    """Environment steps first (machine-independent, comparable with the paper), then seconds."""
    t = Table(title=f"flashnav bench train ({when}): environment steps, then seconds of training, to success "
                    f"thresholds; {seeds} seeds")
    for col in ("robot", "algo", "recipe", "device", "threads", "env steps to 90% best/mean (k/S)",
                "to 95%", "to 100%", "100% in paper budget", "100% on training episodes (k/S)",
                "seconds to 90/95/100% mean", "collector/learner/cycle ms"):
        t.add_column(col, justify="right")
    for robot, algo, recipe, device, s in groups:
        cells = []
        for th in THRESHOLDS:
            c = s[str(th)]
            cells.append("-" if not c["reached"] else
                         f"{c['best_env_steps']:,.0f} / {c['mean_env_steps']:,.0f} ({c['reached']}/{s['runs']})")
        last, budget = s[str(THRESHOLDS[-1])], s.get("budget")
        in_budget = "-" if budget is None else f"{last['within_budget']}/{s['runs']} (<= {budget:,})"
        seconds = " / ".join("-" if s[str(th)]["mean_s"] is None else f"{s[str(th)]['mean_s']:.1f}" for th in THRESHOLDS)
        threads = ", ".join(str(n) for n in s.get("threads", [])) or "-"
        tr = s.get("training_episodes", {})
        on_train = ("-" if not tr.get("reached") else
                    f"{tr['best_env_steps']:,.0f} / {tr['mean_env_steps']:,.0f} ({tr['reached']}/{s['runs']})")
        t.add_row(robot, algo, recipe, device, threads, *cells, in_budget, on_train, seconds,
                  f"{s['collector_ms']:.1f} / {s['learner_ms']:.1f} / {s['effective_ms']:.1f}")
    console.print(t)
