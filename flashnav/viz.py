"""Pictures of maps and trajectories (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from flashnav.maps.grid import OccupancyMap  # noqa: E402

OUTCOME_COLOURS = {"success": "tab:green", "collision": "tab:red", "timeout": "tab:orange", "running": "tab:blue"}


def draw_trajectories(grid: OccupancyMap, paths: list[np.ndarray], goals: np.ndarray, outcomes: list[str],
                      out: str | Path, title: str = "") -> Path:
    """Save a PNG of the map with each path ([T, 2] metres), its start, goal and outcome colour."""
    xmin, ymin, xmax, ymax = grid.bounds
    fig, ax = plt.subplots(figsize=(7, 7 * (ymax - ymin) / (xmax - xmin) + 0.4), dpi=110)
    ax.imshow(grid.occupied, origin="lower", extent=(xmin, xmax, ymin, ymax), cmap="Greys", vmin=0, vmax=1.4,
              interpolation="nearest")
    for path, goal, outcome in zip(paths, goals, outcomes):
        colour = OUTCOME_COLOURS.get(outcome, "tab:blue")
        ax.plot(path[:, 0], path[:, 1], color=colour, lw=1.2, alpha=0.85)
        ax.plot(path[0, 0], path[0, 1], "o", color=colour, ms=3)
        ax.plot(goal[0], goal[1], "*", color=colour, ms=8, mec="black", mew=0.4)
    handles = [plt.Line2D([], [], color=c, label=k) for k, c in OUTCOME_COLOURS.items() if k in outcomes]
    if handles:
        ax.legend(handles=handles, loc="upper right", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
