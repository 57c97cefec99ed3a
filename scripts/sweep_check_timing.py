"""The check `flashnav sweep run` makes before Ray starts, with the generated maps reused and drawn anew, side by side.

    .venv/bin/python scripts/sweep_check_timing.py [SWEEP.yaml ...] [--rounds 2]

Before a sweep starts Ray, its driver resolves every (robot, algorithm) training config at every searched point
(``services.sweep.validate_train_configs``), so that a bad key or map fails in seconds. A generalist's config
generates its training and validation maps; since 2026-12-03 the check makes each map once
(``flashnav.maps.families.reuse_generated_maps``) instead of once per searched point. This times the check both
ways, alternating A B B A per round on each sweep file (default: the two generalist Optuna sweeps), and prints the
median seconds of each and their ratio, with the machine.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from pathlib import Path
from types import SimpleNamespace

import flashnav.maps.families as families
from flashnav.machine import machine_name
from services.sweep import validate_train_configs
from services.sweep_schema import load_sweep

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = [ROOT / "sweeps" / "tb2_generalist_optuna.yaml", ROOT / "sweeps" / "go2_generalist_optuna.yaml"]
ARMS = {"drawn anew": contextlib.nullcontext, "reused": families.reuse_generated_maps}


def time_check(path: Path, arm: str) -> float:
    """Seconds of one check of ``path``'s sweep with the maps ``arm`` (a key of :data:`ARMS`)."""
    sweep, real = load_sweep(path), families.reuse_generated_maps
    families.reuse_generated_maps = ARMS[arm]  # what validate_train_configs enters
    try:
        start = time.perf_counter()
        validate_train_configs(SimpleNamespace(sweep=sweep, source=str(path)))
        return time.perf_counter() - start
    finally:
        families.reuse_generated_maps = real


def main(argv: list[str] | None = None) -> dict[str, dict[str, list[float]]]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sweeps", nargs="*", type=Path, default=DEFAULT, metavar="SWEEP.yaml")
    p.add_argument("--rounds", type=int, default=2, help="A B B A rounds per sweep file (default 2)")
    a = p.parse_args(argv)
    if a.rounds < 1:
        p.error(f"--rounds must be >= 1, got {a.rounds}")
    print(f"machine: {machine_name()}")
    times: dict[str, dict[str, list[float]]] = {}
    for path in a.sweeps:
        t = times.setdefault(path.name, {arm: [] for arm in ARMS})
        for _ in range(a.rounds):
            for arm in ("drawn anew", "reused", "reused", "drawn anew"):
                t[arm].append(time_check(path, arm))
        anew, reused = (statistics.median(t[arm]) for arm in ARMS)
        print(f"{path.name}: drawn anew {anew:.2f} s, reused {reused:.2f} s (median of {2 * a.rounds} each): "
              f"{anew / reused:.1f}x")
    return times


if __name__ == "__main__":
    main()
