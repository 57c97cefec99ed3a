"""How long a run waits on its plateau for its first 100 % (issue 15 done-means 3, issue 16 item 4).

    .venv/bin/python scripts/plateau_hits.py [--plateau 0.97] ARM=RUN_DIR[,RUN_DIR...] [ARM=...]

A run that stops at its first 100 % evaluation (``flashnav train``'s default) spends its time in two parts:
climbing to a plateau just under 100 % and then waiting, evaluation after evaluation, for one that fails none of
the fixed episodes. For each arm (a name and its runs' directories, comma-separated; a ``flashnav bench train
--json`` file counts its runs) this prints, from every run's curve (read by :func:`flashnav.bench.runs.load_runs`):
the env steps to the plateau (the first evaluation at or above ``--plateau``), the evaluations on the plateau up
to and including the first 100 % (runs that never reach 100 % count all theirs), the mean success of those
evaluations, and the chance that one plateau evaluation reads 100 % (runs that reached it / evaluations on the
plateau: the maximum-likelihood rate of a geometric wait), with the wait it implies in env steps. Two arms with
the same chance differ only by their climb.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from flashnav.bench.runs import load_runs


def plateau(curve: list[dict], level: float) -> tuple[int | None, list[float], bool]:
    """(env steps at the first evaluation >= level or None, the success rates from there to the first
    1.0 inclusive, whether a 1.0 was reached)."""
    start = next((i for i, c in enumerate(curve) if c["success_rate"] >= level), None)
    if start is None:
        return None, [], False
    rates = []
    for c in curve[start:]:
        rates.append(c["success_rate"])
        if c["success_rate"] >= 1.0:
            return curve[start]["env_steps"], rates, True
    return curve[start]["env_steps"], rates, False


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arms", nargs="+", metavar="ARM=RUN_DIR[,RUN_DIR...]")
    p.add_argument("--plateau", type=float, default=0.97, help="success rate that starts the plateau (default 0.97)")
    args = p.parse_args(argv)
    print(f"{'arm':<12} {'runs':>4} {'to plateau (mean env steps)':>28} {'plateau evals':>14} {'mean success':>13} "
          f"{'P(100 %) per eval':>18} {'implied wait (env steps)':>25}")
    for arm in args.arms:
        name, _, dirs = arm.partition("=")
        if not dirs:
            p.error(f"{arm!r}: give ARM=RUN_DIR[,RUN_DIR...]")
        try:
            curves = [r["curve"] for d in dirs.split(",") for r in load_runs(Path(d))]
        except ValueError as e:
            p.error(str(e))
        climbs, rates, hits, spacing = [], [], 0, None
        for curve in curves:
            at, r, hit = plateau(curve, args.plateau)
            if at is None:
                continue
            climbs.append(at)
            rates += r
            hits += hit
            if spacing is None and len(curve) > 1:
                spacing = curve[1]["env_steps"] - curve[0]["env_steps"]  # env steps between evaluations
        if not climbs:
            print(f"{name:<12} {len(curves):>4} {'never on the plateau':>28}")
            continue
        chance = hits / len(rates)
        wait = f"{spacing / chance:,.0f}" if chance and spacing else "-"
        print(f"{name:<12} {len(curves):>4} {sum(climbs) / len(climbs):>28,.0f} {len(rates):>14} "
              f"{sum(rates) / len(rates):>12.1%} {chance:>18.3f} {wait:>25}")


if __name__ == "__main__":
    main()
