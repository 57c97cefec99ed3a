"""The live training status shared by ``flashnav train`` and ``flashnav bench train``."""

from __future__ import annotations

import io

from rich.console import Console

from flashnav.learn.progress import TrainProgress


def _eval(i, rate, seconds):
    return {"eval_index": i, "env_steps": 1000 * (i + 1), "train_seconds": seconds, "success_rate": rate,
            "collision_rate": 0.0, "mean_return": 1.0}


def _feed(progress, rates):
    for i, rate in enumerate(rates):
        progress.on_progress({"env_steps": 1000 * (i + 1), "train_seconds": 10.0 * (i + 1)})
        progress.on_eval(_eval(i, rate, 10.0 * (i + 1)))


def test_thresholds_are_first_crossings():
    console = Console(file=io.StringIO(), width=200)
    with TrainProgress(console, eval_lines=False) as progress:
        _feed(progress, [0.5, 0.92, 0.89, 0.96, 1.0, 1.0])
    assert progress.thresholds == {0.9: 20.0, 0.95: 40.0, 1.0: 50.0}


def test_bench_mode_prints_only_threshold_crossings():
    console = Console(file=io.StringIO(), width=200)
    with TrainProgress(console, label="tb2 dsac seed 1", eval_lines=False, transient=True) as progress:
        _feed(progress, [0.5, 0.92, 0.93])
    out = console.file.getvalue()
    assert "tb2 dsac seed 1 90% success at 20.0 s (2,000 env steps)" in out
    assert "eval " not in out and "95%" not in out


def test_train_mode_prints_every_evaluation():
    console = Console(file=io.StringIO(), width=200)
    with TrainProgress(console) as progress:
        _feed(progress, [0.5, 0.92, 0.93])
    lines = [line for line in console.file.getvalue().splitlines() if line.startswith("eval ")]
    assert len(lines) == 3 and "success  93.0%" in lines[-1]


def test_final_status_ends_its_line_in_a_log_file():
    # Off a terminal rich writes the last status without a line end; what follows must not share it.
    console = Console(file=io.StringIO(), width=200)
    with TrainProgress(console) as progress:
        _feed(progress, [0.5])
    console.print("SUMMARY")
    lines = console.file.getvalue().splitlines()
    assert lines[-1] == "SUMMARY" and lines[-2].startswith("env steps 1,000"), lines


class _Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_off_a_terminal_a_progress_line_at_most_every_log_every_seconds():
    """A log file gets no live line until the end: flashnav train prints a plain one every LOG_EVERY seconds."""
    console, clock = Console(file=io.StringIO(), width=200), _Clock()
    with TrainProgress(console, log_every=60.0, clock=clock) as progress:
        for cycle in range(1, 11):  # a cycle every 25 s of wall clock: lines at 75, 150 and 225 s
            clock.now = 25.0 * cycle
            progress.on_progress({"env_steps": 128 * cycle, "max_env_steps": 1280, "train_seconds": 20.0 * cycle})
            if cycle == 4:
                progress.on_eval(_eval(0, 0.969, 80.0))
    lines = [line for line in console.file.getvalue().splitlines() if line.startswith("progress ")]
    assert lines == ["progress 384 of 1,280 env steps (30%), train time 60.0 s",
                     "progress 768 of 1,280 env steps (60%), train time 120.0 s, last success 96.9%",
                     "progress 1,152 of 1,280 env steps (90%), train time 180.0 s, last success 96.9%"], lines


def test_no_progress_lines_on_a_terminal_or_without_log_every():
    for console, every in ((Console(file=io.StringIO(), width=200, force_terminal=True), 60.0),
                           (Console(file=io.StringIO(), width=200), None)):
        clock = _Clock()
        with TrainProgress(console, log_every=every, clock=clock) as progress:
            for cycle in range(1, 6):
                clock.now = 100.0 * cycle
                progress.on_progress({"env_steps": cycle, "max_env_steps": 5, "train_seconds": 1.0})
        assert "progress " not in console.file.getvalue()
