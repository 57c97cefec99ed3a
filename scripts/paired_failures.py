"""Failed evaluation episodes per evaluation, paired run by run: does an arm lower the late-run failure rate?

``100 % within the budget`` (``flashnav bench runs``) asks whether a run's best evaluation happens to fail none of
its episodes - an extreme of a few evaluations. This reads the whole late curve instead: for each pair of runs (the
same seed, two arms; both deterministic in env steps), every evaluation at or after ``--from`` env steps that both
ran (a run that reached 100 % stops early), as failed episodes (``(1 - success) x episodes``), and prints per seed
and pooled the mean and median, and in how many evaluations the arm failed fewer episodes than the base.

    python scripts/paired_failures.py --base runs/s18/n5_g099_m05-s{0..7} runs/s19/n5_g099_m05-s{8,9} \
        --arm runs/s21/fwdpink-s{0..9} --from 100000
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def failures(run: str | Path, start: int) -> dict[int, int]:
    """``{env_steps: failed episodes}`` of a run's evaluations at or after ``start`` env steps (metrics.json)."""
    path = Path(run) / "metrics.json"
    if not path.is_file():
        raise FileNotFoundError(f"{run}: no metrics.json (not a finished flashnav train run folder)")
    data = json.loads(path.read_text(encoding="utf-8"))
    episodes = data["config"]["eval"]["episodes"]
    return {int(e["env_steps"]): round((1.0 - e["success_rate"]) * episodes)
            for e in data["curve"] if e["env_steps"] >= start}


def paired(base: list[str], arm: list[str], start: int) -> dict:
    """Per pair and pooled: evaluations both ran, mean failures of each, evaluations where the arm failed fewer / more."""
    if len(base) != len(arm):
        raise ValueError(f"--base has {len(base)} runs and --arm {len(arm)}: give one base run per arm run (the same seed)")
    rows, a_all, b_all = [], [], []
    for b, a in zip(base, arm):
        fb, fa = failures(b, start), failures(a, start)
        common = sorted(set(fb) & set(fa))
        xb, xa = [fb[k] for k in common], [fa[k] for k in common]
        b_all += xb
        a_all += xa
        rows.append({"base": str(b), "arm": str(a), "evaluations": len(common),
                     "base_mean": statistics.fmean(xb) if xb else None, "arm_mean": statistics.fmean(xa) if xa else None})
    if not b_all:
        raise ValueError(f"no evaluation at or after {start:,} env steps that both runs of a pair ran")
    return {"pairs": rows, "evaluations": len(b_all),
            "base_mean": statistics.fmean(b_all), "arm_mean": statistics.fmean(a_all),
            "base_median": statistics.median(b_all), "arm_median": statistics.median(a_all),
            "arm_fewer": sum(x < y for x, y in zip(a_all, b_all)), "arm_more": sum(x > y for x, y in zip(a_all, b_all))}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--base", nargs="+", required=True, help="the base arm's run folders, one per seed")
    p.add_argument("--arm", nargs="+", required=True, help="the other arm's run folders, in the same seed order")
    p.add_argument("--from", dest="start", type=int, default=100000, help="first env step counted (default 100,000)")
    p.add_argument("--json", help="write the result here")
    args = p.parse_args()
    out = paired(args.base, args.arm, args.start)
    for r in out["pairs"]:
        means = "-" if r["evaluations"] == 0 else f"{r['base_mean']:.1f} / {r['arm_mean']:.1f}"
        print(f"{r['base']} / {r['arm']}: {r['evaluations']} evaluations, mean failed episodes {means}")
    print(f"pooled: {out['evaluations']} paired evaluations from {args.start:,} env steps; failed episodes per evaluation "
          f"base mean {out['base_mean']:.2f} (median {out['base_median']:g}), arm mean {out['arm_mean']:.2f} "
          f"(median {out['arm_median']:g}); the arm failed fewer in {out['arm_fewer']}, more in {out['arm_more']}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
