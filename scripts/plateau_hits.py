"""How long a run waits on its plateau for its first 100 % (issue 15 done-means 3, issue 16 item 4).

    .venv/bin/python scripts/plateau_hits.py [--plateau 0.97] [--failures OUT.png] [--which] ARM=RUN_DIR[,RUN_DIR...] [ARM=...]

A run that stops at its first 100 % evaluation (``flashnav train``'s default) spends its time in two parts:
climbing to a plateau just under 100 % and then waiting, evaluation after evaluation, for one that fails none of
the fixed episodes. For each arm (a name and its runs' directories, comma-separated; a ``flashnav bench train
--json`` file counts its runs) this prints, from every run's curve (read by :func:`flashnav.bench.runs.load_runs`):
the env steps to the plateau (the first evaluation at or above ``--plateau``), the evaluations on the plateau up
to and including the first 100 % (runs that never reach 100 % count all theirs), the mean success of those
evaluations, and the chance that one plateau evaluation reads 100 % (runs that reached it / evaluations on the
plateau: the maximum-likelihood rate of a geometric wait), with the wait it implies in env steps, and the mean
number of evaluation episodes failed per plateau evaluation (each run's ``eval.episodes``; "-" where the records
do not keep it). Two arms with the same chance differ only by their climb. The mean failures and the chance need
not move together: a policy whose failures are the same few episodes every time can fail fewer on average and
still seldom read 100 %.
``--failures OUT.png`` draws, per arm, the share of plateau evaluations that failed 0, 1, 2, ... episodes.
``--which`` lists, run by run, the episodes its plateau evaluations failed and in how many of them (runs whose
curves name their failed episodes, ``failed_episodes``: flashnav train since session 37).
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

from flashnav.bench.runs import load_runs, run_label


def plateau_points(curve: list[dict], level: float) -> list[dict] | None:
    """The evaluations from the first one >= ``level`` to the first 1.0 inclusive (or to the end); None where
    no evaluation reaches ``level``."""
    start = next((i for i, c in enumerate(curve) if c["success_rate"] >= level), None)
    if start is None:
        return None
    end = next((i for i in range(start, len(curve)) if curve[i]["success_rate"] >= 1.0), len(curve) - 1)
    return curve[start:end + 1]


def plateau(curve: list[dict], level: float) -> tuple[int | None, list[float], bool]:
    """(env steps at the first evaluation >= level or None, the success rates from there to the first
    1.0 inclusive, whether a 1.0 was reached)."""
    points = plateau_points(curve, level)
    if points is None:
        return None, [], False
    rates = [c["success_rate"] for c in points]
    return points[0]["env_steps"], rates, rates[-1] >= 1.0


def which_failed(curve: list[dict], level: float) -> tuple[int, Counter] | None:
    """(plateau evaluations that name their failed episodes, how many of them failed each episode), over the
    evaluations of :func:`plateau_points`; None where the run never reaches the plateau or none names them."""
    named = [c["failed_episodes"] for c in plateau_points(curve, level) or [] if c.get("failed_episodes") is not None]
    return (len(named), Counter(k for f in named for k in f)) if named else None


def failed_episodes(rates: list[float], episodes: int) -> list[int]:
    """Failed episodes of each evaluation: ``round((1 - rate) * episodes)``."""
    return [round((1.0 - r) * episodes) for r in rates]


def episodes_of(run: dict) -> int | None:
    """A run's evaluation episodes (its config's ``eval.episodes``; None for a record without its config, as
    ``bench train --json`` keeps them)."""
    episodes = ((run.get("config") or {}).get("eval") or {}).get("episodes")
    return None if episodes is None else int(episodes)


def plot_failures(arms: dict[str, list[int]], out: Path, cap: int = 8) -> None:
    """Bars per arm: the share of plateau evaluations that failed 0, 1, ..., ``cap`` or more episodes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    width = 0.8 / max(len(arms), 1)
    for i, (name, fails) in enumerate(arms.items()):
        shares = [sum(min(f, cap) == k for f in fails) / len(fails) for k in range(cap + 1)]
        ax.bar([k - 0.4 + width * (i + 0.5) for k in range(cap + 1)], shares, width,
               label=f"{name} ({len(fails)} evaluations, mean {sum(fails) / len(fails):.2f})")
    ax.set_xticks(range(cap + 1), [str(k) for k in range(cap)] + [f">={cap}"])
    ax.set_xlabel("failed evaluation episodes in one plateau evaluation (0 = a 100 % evaluation)")
    ax.set_ylabel("share of plateau evaluations")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arms", nargs="+", metavar="ARM=RUN_DIR[,RUN_DIR...]")
    p.add_argument("--plateau", type=float, default=0.97, help="success rate that starts the plateau (default 0.97)")
    p.add_argument("--failures", type=Path, metavar="OUT.png",
                   help="also draw each arm's distribution of failed episodes per plateau evaluation")
    p.add_argument("--which", action="store_true",
                   help="also list, run by run, which episodes its plateau evaluations failed and how often")
    args = p.parse_args(argv)
    print(f"{'arm':<12} {'runs':>4} {'to plateau (mean env steps)':>28} {'plateau evals':>14} {'mean success':>13} "
          f"{'P(100 %) per eval':>18} {'implied wait (env steps)':>25} {'failed / eval':>14}")
    drawn: dict[str, list[int]] = {}
    for arm in args.arms:
        name, _, dirs = arm.partition("=")
        if not dirs:
            p.error(f"{arm!r}: give ARM=RUN_DIR[,RUN_DIR...]")
        try:
            runs = [r for d in dirs.split(",") for r in load_runs(Path(d))]
        except ValueError as e:
            p.error(str(e))
        episodes = [episodes_of(r) for r in runs]
        curves = [r["curve"] for r in runs]
        climbs, rates, hits, spacing, fails = [], [], 0, None, []
        for curve, n in zip(curves, episodes):
            at, r, hit = plateau(curve, args.plateau)
            if at is None:
                continue
            climbs.append(at)
            rates += r
            fails += failed_episodes(r, n) if n else []
            hits += hit
            if spacing is None and len(curve) > 1:
                spacing = curve[1]["env_steps"] - curve[0]["env_steps"]  # env steps between evaluations
        if not climbs:
            print(f"{name:<12} {len(curves):>4} {'never on the plateau':>28}")
            continue
        chance = hits / len(rates)
        wait = f"{spacing / chance:,.0f}" if chance and spacing else "-"
        failed = f"{sum(fails) / len(fails):.2f}" if fails else "-"
        print(f"{name:<12} {len(curves):>4} {sum(climbs) / len(climbs):>28,.0f} {len(rates):>14} "
              f"{sum(rates) / len(rates):>12.1%} {chance:>18.3f} {wait:>25} {failed:>14}")
        if fails:
            drawn[name] = fails
        if args.which:
            for r in runs:
                seen = which_failed(r["curve"], args.plateau)
                label = run_label(r)
                if seen is None:
                    print(f"  {label}: no plateau evaluation names its failed episodes")
                    continue
                named, counts = seen
                listed = ", ".join(f"#{k} {n}/{named}" for k, n in counts.most_common())
                print(f"  {label}: {named} plateau evaluations; failed {listed or 'none'}")
    if args.failures and drawn:
        plot_failures(drawn, args.failures)
        print(f"failures per plateau evaluation: {args.failures}")


if __name__ == "__main__":
    main()
