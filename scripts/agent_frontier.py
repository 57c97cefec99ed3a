"""Success against agent collisions on one scenario, for policies and planners side by side (issue 13).

    .venv/bin/python scripts/agent_frontier.py LABEL=RESULT.json [LABEL=RESULT.json ...] [--scenario wander-8]
        [--out docs/figures/agents_frontier.png]

RESULT.json is what ``flashnav eval --scenario ... --json`` writes (a ``scenarios`` block; the named scenario
is read) or what ``scripts/agent_mpc.py`` / ``scripts/agent_oracle.py`` write with ``--json`` (one scenario's
rates; its ``scenario`` must be the one named). Each becomes a point: agent collisions (x) against success
(y), the issue's bar (>= 90 % success with <= 3 % agent collisions on wander-8) shaded; labels ``GROUP: NAME``
(seeds of one arm) share a colour, a marker and a legend entry. Prints the table too.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

BAR = {"wander-8": (0.90, 0.03), "crossing": (0.85, None)}  # issue 13, done-means 3: (success >=, agent coll. <=)


def rates_of(path: str, scenario: str) -> dict:
    """The scenario's rates in a result file of either kind (module docstring); errors name the file."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"{path}: not a readable JSON result ({e})") from None
    if "scenarios" in data:
        if scenario not in data["scenarios"]:
            raise SystemExit(f"{path}: no scenario {scenario!r} in it (has {', '.join(data['scenarios'])})")
        return data["scenarios"][scenario]
    if data.get("scenario") != scenario:
        raise SystemExit(f"{path}: a result for scenario {data.get('scenario')!r}, not {scenario!r}")
    return data


def groups(points: list[tuple[str, dict]]) -> dict[str, list[tuple[str, dict]]]:
    """Points by group, in first-seen order: a label ``GROUP: NAME`` (e.g. ``crowd: seed 0``) joins GROUP, drawn
    in one colour and marker with one legend entry; a label without ``: `` is a group of its own."""
    out: dict[str, list[tuple[str, dict]]] = {}
    for label, r in points:
        out.setdefault(label.split(": ", 1)[0], []).append((label, r))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", metavar="LABEL=RESULT.json")
    ap.add_argument("--scenario", default="wander-8")
    ap.add_argument("--out", help="write the figure here (PNG)")
    args = ap.parse_args()
    points = []
    for item in args.results:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            raise SystemExit(f"{item!r}: give each result as LABEL=RESULT.json")
        points.append((label, rates_of(path, args.scenario)))
    print(f"| {args.scenario} | episodes | success | agent coll. | wall coll. | timeout |\n|---|--:|--:|--:|--:|--:|")
    for label, r in points:
        print(f"| {label} | {r['scored']} | {r['success_rate']:.1%} | {r['agent_collision_rate']:.1%} | "
              f"{r['wall_collision_rate']:.1%} | {r['timeout_rate']:.1%} |")
    if not args.out:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10.0, 5.0))
    success_min, agent_max = BAR.get(args.scenario, (None, None))
    if success_min is not None:
        right = agent_max * 100 if agent_max is not None else 100
        ax.fill_between([0, right], success_min * 100, 100.5, color="tab:green", alpha=0.15, label="issue 13's bar")
    markers = "osD^vP*Xh<>p"
    for i, (name, members) in enumerate(groups(points).items()):
        xs = [r["agent_collision_rate"] * 100 for _, r in members]
        ys = [r["success_rate"] * 100 for _, r in members]
        scored = sorted({r["scored"] for _, r in members})
        what = f"{len(members)} results, " if len(members) > 1 else ""
        ax.scatter(xs, ys, s=50, color=f"C{i % 10}", marker=markers[i % len(markers)], zorder=3,
                   label=f"{name} ({what}{'/'.join(map(str, scored))} ep.)")
    ax.set_xlabel(f"agent collisions on {args.scenario} (% of episodes)")
    ax.set_ylabel(f"success on {args.scenario} (%)")
    ax.set_xlim(left=-0.5)
    ax.set_ylim(top=100.5)
    ax.grid(alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
