"""Pictures of maps and trajectories (matplotlib, headless)."""

from __future__ import annotations

import textwrap
from collections import Counter
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402
import numpy as np  # noqa: E402

from flashnav.maps.grid import OccupancyMap  # noqa: E402
from flashnav.metrics import THRESHOLDS  # noqa: E402

AGENT_COLOUR = "tab:purple"
OUTCOME_COLOURS = {"success": "tab:green", "collision": "tab:red", "timeout": "tab:orange", "running": "tab:blue"}
#: Characters per line of a trajectory picture's title (7 inches wide at 10 pt): a longer title (a map's whole
#: path, the overrides) is wrapped, not cut at the figure's edges.
TITLE_WIDTH = 80
#: Metres of map drawn round the free space and the trajectories (:func:`view_bounds`)
VIEW_MARGIN_M = 0.5


def view_bounds(grid: OccupancyMap, points: np.ndarray, margin: float = VIEW_MARGIN_M) -> tuple[float, ...]:
    """(xmin, ymin, xmax, ymax), metres: the box round ``grid``'s free cells and ``points`` [K, 2] (the paths, goals
    and agents drawn; non-finite rows ignored), ``margin`` metres wider, inside the map's bounds: a 5 m arena in a
    19 m ROS map (nav2_tb3_sandbox) fills the picture instead of a fifth of it. The whole map where no cell is free."""
    xmin, ymin, xmax, ymax = grid.bounds
    rows, cols = np.nonzero(~grid.occupied)
    if rows.size == 0:
        return xmin, ymin, xmax, ymax
    half = grid.resolution / 2
    x, y = grid.cell_centres(rows, cols)
    lo, hi = np.array([x.min() - half, y.min() - half]), np.array([x.max() + half, y.max() + half])
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points):
        lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
    return (max(xmin, lo[0] - margin), max(ymin, lo[1] - margin), min(xmax, hi[0] + margin), min(ymax, hi[1] + margin))


def draw_trajectories(grid: OccupancyMap, paths: list[np.ndarray], goals: np.ndarray, outcomes: list[str],
                      out: str | Path, title: str = "", agents: list[tuple[np.ndarray, float]] = (),
                      shielded: np.ndarray | None = None) -> Path:
    """Save a PNG of the map with each path ([T, 2] metres), its start, goal and outcome colour, and
    each moving agent's track ([T', 2] metres, its radius) with its disc where the track ends; ``shielded``
    [P, 2] m: where a people shield took over (black dots on the paths).

    Paths and goals are in ``grid``'s coordinates: for an environment's state (``env.pose``,
    ``env.goal``, in its simulator frame) pass ``env.frame_map``, which is ``env.map`` itself unless
    the map lies far from the world origin (then re-centred on it, see :mod:`flashnav.sim.env`). The picture
    shows :func:`view_bounds`: the free space and everything drawn, not the occupied border round them."""
    drawn = [np.asarray(p, dtype=float).reshape(-1, 2) for p in paths] + [np.asarray(goals, dtype=float).reshape(-1, 2)]
    drawn += [np.asarray(track, dtype=float).reshape(-1, 2) for track, _ in agents]
    x0, y0, x1, y1 = view_bounds(grid, np.concatenate(drawn))
    title = textwrap.fill(title, TITLE_WIDTH, break_on_hyphens=False)
    lines = title.count("\n") + 1 if title else 0  # 0.17 inch a line of 10 pt above the map
    fig, ax = plt.subplots(figsize=(7, 7 * (y1 - y0) / (x1 - x0) + 0.4 + 0.17 * lines), dpi=110)
    xmin, ymin, xmax, ymax = grid.bounds
    ax.imshow(grid.occupied, origin="lower", extent=(xmin, xmax, ymin, ymax), cmap="Greys", vmin=0, vmax=1.4,
              interpolation="nearest")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    for track, radius in agents:
        ax.plot(track[:, 0], track[:, 1], color=AGENT_COLOUR, lw=0.7, alpha=0.6, ls=":")
        ax.add_patch(plt.Circle(tuple(track[-1]), radius, color=AGENT_COLOUR, alpha=0.5))
    for path, goal, outcome in zip(paths, goals, outcomes):
        colour = OUTCOME_COLOURS.get(outcome, "tab:blue")
        ax.plot(path[:, 0], path[:, 1], color=colour, lw=1.2, alpha=0.85)
        ax.plot(path[0, 0], path[0, 1], "o", color=colour, ms=3)
        ax.plot(goal[0], goal[1], "*", color=colour, ms=8, mec="black", mew=0.4)
    if shielded is not None and len(shielded):
        ax.plot(shielded[:, 0], shielded[:, 1], ".", color="black", ms=2.5, zorder=5)
    handles = [plt.Line2D([], [], color=c, label=k) for k, c in OUTCOME_COLOURS.items() if k in outcomes]
    if agents:
        handles.append(plt.Line2D([], [], color=AGENT_COLOUR, ls=":", label="agent"))
    if shielded is not None and len(shielded):
        handles.append(plt.Line2D([], [], color="black", marker=".", ls="", label="shield took over"))
    if handles:
        ax.legend(handles=handles, loc="upper right", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    return _save(fig, out)


def plot_training_runs(runs: list[dict], out: str | Path, title: str = "",
                       thresholds: tuple[float, ...] = THRESHOLDS, x: str = "train_seconds",
                       ymin: float = 0.0) -> Path:
    """Save a PNG of evaluation success against ``x`` (``train_seconds`` or ``env_steps``), one line
    per run (``bench train`` JSON records: ``robot``, ``algorithm``, ``seed`` or ``label``, and
    ``curve``), one panel per robot x algorithm, with each run's first crossing of ``thresholds`` marked.
    Runs with an ``arm`` name share one colour and one legend entry per arm (``NAME (n runs)``, n in that panel);
    success is drawn from ``ymin`` % up."""
    if x not in ("train_seconds", "env_steps"):
        raise ValueError(f"plot_training_runs: x must be train_seconds or env_steps, got {x!r}")
    arms = list(dict.fromkeys(r["arm"] for r in runs if r.get("arm")))
    arm_colour = {a: plt.get_cmap("tab10")(i % 10) for i, a in enumerate(arms)}
    hits_key = "time_to_threshold" if x == "train_seconds" else "env_steps_to_threshold"
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        groups.setdefault((r.get("robot", "?"), r.get("algorithm", "?")), []).append(r)
    if not groups:
        raise ValueError("no runs to plot")
    fig, axes = plt.subplots(1, len(groups), figsize=(5.5 * len(groups), 4), squeeze=False, sharey=True)
    for ax, ((robot, algo), members) in zip(axes[0], groups.items()):
        legend_due = Counter(r["arm"] for r in members if r.get("arm"))   # arm -> its runs here, until its entry
        for r in members:
            t = [p[x] for p in r["curve"]]
            s = [100 * p["success_rate"] for p in r["curve"]]
            arm = r.get("arm")
            if arm:
                n = legend_due.pop(arm, 0)
                label = f"{arm} ({n} run{'s' * (n != 1)})" if n else None
                (line,) = ax.plot(t, s, lw=0.9, alpha=0.75, color=arm_colour[arm], label=label)
            else:
                (line,) = ax.plot(t, s, lw=1.2, label=r.get("label") or f"seed {r.get('seed', '?')}")
            for th in thresholds:
                hit = (r.get(hits_key) or {}).get(str(th))
                if hit is not None:
                    ax.plot([hit], [100 * th], "o", ms=4, color=line.get_color())
        for th in thresholds:
            ax.axhline(100 * th, color="grey", lw=0.6, ls=":")
        ax.set_title(f"{robot} {algo}")
        ax.set_xlabel("training seconds (collection + learning)" if x == "train_seconds" else "environment steps")
        if x == "env_steps":
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1000:g}k"))
        ax.grid(alpha=0.3)
        pad = 0.04 * (100 - ymin) + 0.1
        ax.set_ylim(ymin - pad, 100 + pad)
        ax.legend(fontsize=8, loc="lower right")
    axes[0][0].set_ylabel("evaluation success (%)")
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, out, dpi=120)


def draw_map_sheet(rows: dict[str, list[OccupancyMap]], out: str | Path, title: str = "") -> Path:
    """Save a contact sheet PNG: one row of maps per key of ``rows`` (e.g. a map family), each map
    drawn at its own scale with its size and resolution underneath."""
    ncols = max(len(maps) for maps in rows.values())
    fig, axes = plt.subplots(len(rows), ncols, figsize=(2.6 * ncols, 2.7 * len(rows)), dpi=110, squeeze=False)
    for r, (label, maps) in enumerate(rows.items()):
        for k in range(ncols):
            ax = axes[r, k]
            ax.set_xticks([])
            ax.set_yticks([])
            if k >= len(maps):
                ax.axis("off")
                continue
            grid = maps[k]
            xmin, ymin, xmax, ymax = grid.bounds
            ax.imshow(grid.occupied, origin="lower", extent=(xmin, xmax, ymin, ymax), cmap="Greys", vmin=0,
                      vmax=1.2, interpolation="nearest")
            ax.set_xlabel(f"{grid.name}: {grid.width_m:.1f} x {grid.height_m:.1f} m, {grid.resolution:g} m",
                          fontsize=7)
            if k == 0:
                ax.set_ylabel(label, fontsize=11)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, out)


def _save(fig, out: str | Path, dpi: float | None = None) -> Path:
    """Lay out ``fig``, write it to ``out`` (parent folders created), close it; returns the path."""
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, **({} if dpi is None else {"dpi": dpi}))
    plt.close(fig)
    return out
