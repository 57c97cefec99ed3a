"""The paper's figures from run data: learning curves (mean +- standard error over seeds) and the
training-cycle breakdown; and the per-map success of policies on map suites (`flashnav report
--generalisation`). matplotlib with the Agg backend (no display needed).

Inputs: the normalised run frame (services.report.normalize_runs) and a curve frame with columns
run_id, step (env steps), success_rate (0..1), mean_return, train_seconds (services.report.curves).
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from services.report_tables import ALGO_ORDER, ROBOT_ORDER, short_platform, sort_table  # noqa: E402

GRID_POINTS = 200
METRIC_LABELS = {"mean_return": "evaluation return", "success_rate": "success rate",
                 "step": "env steps", "train_seconds": "train seconds [s]"}


def mean_se_on_grid(curves: list[tuple[np.ndarray, np.ndarray]], points: int = GRID_POINTS):
    """Interpolate each seed's (x, y) curve onto one grid; return (grid, mean, standard error, n).

    The grid spans the earliest first x to the latest last x. Past a seed's last evaluation its last
    value is held (runs stop once they reach 100 % success, so their curve would otherwise vanish);
    before its first evaluation its first value is used. SE = std(ddof=1) / sqrt(n), 0 for n = 1.
    """
    curves = [(np.asarray(x, float), np.asarray(y, float)) for x, y in curves if len(x)]
    if not curves:
        return np.array([]), np.array([]), np.array([]), 0
    lo, hi = min(x[0] for x, _ in curves), max(x[-1] for x, _ in curves)
    grid = np.linspace(lo, hi, points) if hi > lo else np.array([lo])
    ys = np.stack([np.interp(grid, x, y) for x, y in curves])
    n = ys.shape[0]
    se = ys.std(axis=0, ddof=1) / np.sqrt(n) if n > 1 else np.zeros_like(grid)
    return grid, ys.mean(axis=0), se, n


def _panels(runs: pd.DataFrame) -> list[tuple[str, str]]:
    keys = runs[["robot", "algorithm"]].drop_duplicates().rename(columns={"robot": "embodiment"})
    keys = sort_table(keys.assign(platform=""))
    return list(zip(keys["embodiment"], keys["algorithm"]))


def _grid_axes(panels, width=4.2, height=3.2):
    robots = list(dict.fromkeys(r for r, _ in panels))
    ncols = max(sum(1 for r, _ in panels if r == robot) for robot in robots)
    fig, axes = plt.subplots(len(robots), ncols, figsize=(width * ncols, height * len(robots)),
                             squeeze=False, constrained_layout=True)
    where, used = {}, set()
    for robot_i, robot in enumerate(robots):
        for col, (r, a) in enumerate([p for p in panels if p[0] == robot]):
            where[(r, a)] = axes[robot_i, col]
            used.add((robot_i, col))
    for (i, j), ax in np.ndenumerate(axes):
        if (i, j) not in used:
            ax.set_visible(False)
    return fig, where


def platform_colors(names) -> dict:
    """One colour per platform, the same in every panel and figure (sorted names -> tab10)."""
    cmap = plt.get_cmap("tab10")
    return {name: cmap(i % 10) for i, name in enumerate(sorted(set(map(str, names))))}


def _title(robot, algo) -> str:
    return f"{ROBOT_ORDER.get(robot, robot)} · {ALGO_ORDER.get(algo, algo)}"


def _save(fig, path: Path, svg: bool) -> list[Path]:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    out = [path]
    if svg:
        fig.savefig(path.with_suffix(".svg"))
        out.append(path.with_suffix(".svg"))
    plt.close(fig)
    return out


def plot_curves(runs: pd.DataFrame, curves: pd.DataFrame, y: str, x: str, path: str | Path,
                svg: bool = False) -> list[Path]:
    """One panel per robot x algorithm, one line per platform: mean over seeds, shaded +- 1 SE.

    y: "mean_return" or "success_rate"; x: "step" (env steps) or "train_seconds" (seconds).
    Each panel keeps its own x range (budgets differ between robots and algorithms, as in the paper).
    """
    panels = _panels(runs)
    fig, where = _grid_axes(panels)
    merged = curves.merge(runs[["run_id", "robot", "algorithm", "device_name"]], on="run_id")
    colors = platform_colors(runs["device_name"])
    for (robot, algo), ax in where.items():
        sub = merged[(merged["robot"] == robot) & (merged["algorithm"] == algo)]
        for platform in sorted(sub["device_name"].unique(), key=str):
            per_seed = []
            for _, c in sub[sub["device_name"] == platform].groupby("run_id"):
                c = c.dropna(subset=[x, y]).sort_values(x)
                per_seed.append((c[x].to_numpy(), c[y].to_numpy()))
            grid, mean, se, n = mean_se_on_grid(per_seed)
            if n == 0:
                continue
            color = colors[str(platform)]
            ax.plot(grid, mean, color=color, label=f"{short_platform(platform)} (n={n})")
            ax.fill_between(grid, mean - se, mean + se, color=color, alpha=0.25, linewidth=0)
        if sub.empty:
            ax.text(0.5, 0.5, "no curve data", ha="center", va="center", transform=ax.transAxes)
        ax.set_title(_title(robot, algo))
        ax.set_xlabel(METRIC_LABELS.get(x, x))
        ax.set_ylabel(METRIC_LABELS.get(y, y))
        ax.grid(alpha=0.3)
        if y == "success_rate":
            ax.set_ylim(-0.02, 1.02)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    fig.suptitle(f"{METRIC_LABELS.get(y, y).capitalize()} vs {METRIC_LABELS.get(x, x)}\n"
                 f"mean ± standard error over seeds", fontsize=11)
    return _save(fig, Path(path), svg)


def cycle_frame(runs: pd.DataFrame) -> pd.DataFrame:
    """Mean collector / learner / effective ms per training cycle, per robot x algorithm x platform."""
    cols = ["cycle_collector_ms", "cycle_learner_ms", "cycle_effective_ms"]
    have = runs.dropna(subset=[c for c in cols if c in runs], how="all")
    if have.empty or not all(c in have for c in cols):
        return pd.DataFrame(columns=["robot", "algorithm", "device_name", *cols, "n"])
    return (have.groupby(["robot", "algorithm", "device_name"], sort=False)
            .agg(**{c: (c, "mean") for c in cols}, n=("run_id", "count")).reset_index())


def plot_cycle_breakdown(runs: pd.DataFrame, path: str | Path, svg: bool = False) -> list[Path]:
    """Collector and learner ms per cycle for each platform; a dashed black line marks the effective
    cycle (the logged `cycle_effective_ms`: the slower side when overlapped, the sum when sequential)."""
    cyc = cycle_frame(runs)
    panels = _panels(cyc) if not cyc.empty else [("", "")]
    fig, where = _grid_axes(panels, width=4.8, height=0.6 + 0.8 * max(1, cyc["device_name"].nunique()))
    for (robot, algo), ax in where.items():
        sub = cyc[(cyc["robot"] == robot) & (cyc["algorithm"] == algo)].sort_values("device_name")
        if sub.empty:
            ax.text(0.5, 0.5, "no cycle metrics", ha="center", va="center", transform=ax.transAxes)
            continue
        y = np.arange(len(sub))
        h = 0.38
        ax.barh(y - h / 2, sub["cycle_collector_ms"], height=h, color="#4C72B0", label="collector")
        ax.barh(y + h / 2, sub["cycle_learner_ms"], height=h, color="#DD8452", label="learner")
        for yi, eff in zip(y, sub["cycle_effective_ms"]):
            ax.vlines(eff, yi - h - 0.05, yi + h + 0.05, colors="black", linestyles="dashed", linewidth=1.5)
            ax.annotate(f"{eff:.1f} ms", (eff, yi + h + 0.05), xytext=(3, 0), textcoords="offset points",
                        fontsize=8, va="bottom")
        ax.set_yticks(y, [short_platform(p) for p in sub["device_name"]])
        ax.invert_yaxis()
        ax.set_xlim(0, 1.25 * float(np.nanmax(sub[["cycle_collector_ms", "cycle_learner_ms",
                                                     "cycle_effective_ms"]].to_numpy())))
        ax.set_xlabel("ms per training cycle")
        ax.set_title(_title(robot, algo))
        ax.grid(axis="x", alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("Training-cycle breakdown\n(dashed: effective cycle)", fontsize=11)
    return _save(fig, Path(path), svg)


def write_figures(runs: pd.DataFrame, curves: pd.DataFrame, out_dir: str | Path, svg: bool = False) -> dict:
    """All report figures as PNG (and SVG) under out_dir; returns {name: png path}."""
    out = Path(out_dir)
    specs = {"curves_return": ("mean_return", "step"), "curves_success": ("success_rate", "step"),
             "success_vs_time": ("success_rate", "train_seconds")}
    paths = {name: plot_curves(runs, curves, y, x, out / f"{name}.png", svg)[0] for name, (y, x) in specs.items()}
    paths["cycle_breakdown"] = plot_cycle_breakdown(runs, out / "cycle_breakdown.png", svg)[0]
    return paths


def plot_per_map(maps: pd.DataFrame, path: str | Path, svg: bool = False,
                 intervals: dict[tuple[str, str, str], tuple[float, float]] | None = None,
                 bar: float | None = None) -> list[Path]:
    """One panel per suite: each map's success (per cent) for every policy, side by side, and each policy's mean
    over the maps it was evaluated on as a dashed line of its colour. ``maps``: one row per (suite, map), columns
    suite, map and one per policy (fractions; NaN where not evaluated): services.report_generalisation's per-map
    table without its mean rows. ``intervals`` ({(suite, map, policy): (low, high)}, its interval_lookup): each
    interval as a vertical line through its marker; ``bar``: a dotted line there."""
    policies = list(maps.columns[2:])
    suites = list(dict.fromkeys(maps["suite"]))
    known = intervals or {}
    widest = max((int((maps["suite"] == s).sum()) for s in suites), default=1)
    legend_in = 0.8 + 0.065 * max((len(str(p)) for p in policies), default=0)   # the legend beside the panel
    fig, axes = plt.subplots(len(suites), 1, figsize=(max(6.0, 0.45 * widest + 2.5) + legend_in, 3.4 * len(suites)),
                             squeeze=False, constrained_layout=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    markers = "osD^vP*Xh<>"
    for ax, suite in zip(axes[:, 0], suites):
        rows = maps[maps["suite"] == suite]
        x = np.arange(len(rows))
        spread = 0.6 / max(len(policies), 1)
        if bar is not None:
            ax.axhline(100 * bar, color="0.3", linestyle=":", linewidth=1, label=f"{100 * bar:g} % bar")
        for i, policy in enumerate(policies):
            values = 100 * rows[policy].to_numpy(dtype=float)
            color, offset = colors[i % len(colors)], (i - (len(policies) - 1) / 2) * spread
            ax.plot(x + offset, values, linestyle="none", marker=markers[i % len(markers)], color=color,
                    label=policy)
            spans = [(xi + offset, *known[(suite, m, policy)]) for xi, m in zip(x, rows["map"])
                     if (suite, m, policy) in known]
            if spans:
                at, low, high = np.array(spans).T
                ax.vlines(at, 100 * low, 100 * high, color=color, linewidth=1, alpha=0.7)
            if np.isfinite(values).any():
                ax.axhline(np.nanmean(values), color=color, linestyle="--", linewidth=1, alpha=0.8)
        ax.set_xticks(x, rows["map"], rotation=60, ha="right", fontsize=8)
        ax.set_ylabel("success [%]")
        ax.set_title(f"{suite} (dashed: mean over maps" + ("; vertical lines: 95 % interval)" if known else ")"))
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))   # beside: no marker hidden
    return _save(fig, Path(path), svg)
