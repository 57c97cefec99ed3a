"""A live status line for a training run, shared by ``flashnav train`` and ``flashnav bench train``."""

from __future__ import annotations

import time
from typing import Callable

from rich.console import Console
from rich.live import Live
from rich.table import Table

from flashnav.metrics import THRESHOLDS, reaches

#: Off a terminal, ``flashnav train`` prints a plain progress line at most this often, seconds of wall-clock time.
LOG_EVERY = 60.0


class TrainProgress:
    """Context manager: pass ``on_eval`` / ``on_progress`` to ``flashnav.train``.

    Shows env steps, training seconds, the last success rate and the thresholds reached so far. With
    ``eval_lines`` every evaluation also prints a line; otherwise only a threshold's first crossing does.
    ``log_every``: off a terminal (a log file, a batch job's output), where the live line is not drawn until the
    end, print a plain progress line at most every that many seconds of wall-clock time (None = never), so that a
    long run's log shows it moving between evaluations.
    """

    def __init__(self, console: Console, *, label: str = "", eval_lines: bool = True, transient: bool = False,
                 log_every: float | None = None, clock: Callable[[], float] = time.monotonic):
        self.console, self.label, self.eval_lines = console, label, eval_lines
        self.log_every, self._clock = (log_every if not console.is_terminal else None), clock
        self._logged = clock()
        self.thresholds: dict[float, float | None] = {t: None for t in THRESHOLDS}
        self.state: dict = {}
        self._live = Live(self._render(), console=console, refresh_per_second=4, transient=transient)

    def __enter__(self) -> "TrainProgress":
        self._live.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._live.__exit__(*exc)
        if not self.console.is_terminal and not self._live.transient:
            # Off a terminal (a log file, CI) rich leaves the final status without a line end.
            self.console.line()

    def _render(self) -> Table:
        t = Table.grid(padding=(0, 2))
        ev = self.state.get("last_eval") or {}
        rate = f"{ev['success_rate']:.1%}" if ev else "-"
        reached = ", ".join(f"{int(k * 100)}% @ {v:.1f}s" for k, v in self.thresholds.items() if v is not None) or "-"
        cells = [f"env steps [bold]{self.state.get('env_steps', 0):,}[/]",
                 f"train time [bold]{self.state.get('train_seconds', 0.0):.1f} s[/]",
                 f"last success [bold]{rate}[/]", f"reached {reached}"]
        t.add_row(*([self.label] if self.label else []), *cells)
        return t

    def on_progress(self, progress: dict) -> None:
        self.state.update(progress)
        self._live.update(self._render())
        if self.log_every is not None and self._clock() - self._logged >= self.log_every:
            self._logged = self._clock()
            self._live.console.print(self._log_line(), soft_wrap=True)

    def _log_line(self) -> str:
        """``progress 12,288 of 40,960 env steps (30%), train time 250.1 s, last success 96.9%``."""
        steps, budget = self.state.get("env_steps", 0), self.state.get("max_env_steps")
        of = f" of {budget:,} env steps ({steps / budget:.0%})" if budget else " env steps"
        ev = self.state.get("last_eval") or {}
        last = f", last success {ev['success_rate']:.1%}" if ev else ""
        prefix = f"{self.label} " if self.label else ""
        return f"{prefix}progress {steps:,}{of}, train time {self.state.get('train_seconds', 0.0):.1f} s{last}"

    def on_eval(self, m: dict) -> None:
        self.state["last_eval"] = m
        prefix = f"{self.label} " if self.label else ""
        for t in THRESHOLDS:
            if self.thresholds[t] is None and reaches(m["success_rate"], t):
                self.thresholds[t] = m["train_seconds"]
                if not self.eval_lines:
                    self._live.console.print(f"{prefix}{int(t * 100)}% success at {m['train_seconds']:.1f} s "
                                             f"({m['env_steps']:,} env steps)", soft_wrap=True)
        if self.eval_lines:
            self._live.console.print(f"{prefix}eval {m['eval_index']:3d} {m['env_steps']:>9,} steps "
                                     f"{m['train_seconds']:6.1f} s  success {m['success_rate']:6.1%} "
                                     f"collision {m['collision_rate']:5.1%} return {m['mean_return']:6.2f}"
                                     f"{_training_episodes(m)}", soft_wrap=True)
        self._live.update(self._render())


def _training_episodes(m: dict) -> str:
    """`` | train eps 97.6% of 112``: the newest training episodes' success, once enough have ended."""
    if m.get("train_success_rate") is None:
        return ""
    return f"  | train eps {m['train_success_rate']:6.1%} of {m['train_episodes']}"
