"""Pictures: what a reader needs stays inside the figure."""

import numpy as np
import pytest

from flashnav import viz
from flashnav.maps.grid import OccupancyMap


@pytest.mark.parametrize("shape", [(300, 120), (100, 100), (60, 300)])  # a tall maze, a square, a wide hall
def test_a_long_trajectory_title_is_wrapped_inside_the_figure(tmp_path, monkeypatch, shape):
    saved = []
    real_save = viz._save

    def keep(fig, out, dpi=None):
        fig.tight_layout()  # the layout as written (_save lays it out so)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        box = fig.axes[0].title.get_window_extent(renderer)
        saved.append((box, fig.bbox.bounds, fig.axes[0].get_title(), fig.axes[0].get_window_extent(renderer)))
        return real_save(fig, out, dpi)

    monkeypatch.setattr(viz, "_save", keep)
    grid = OccupancyMap(np.zeros(shape, dtype=bool), 0.05, name="maze")
    title = ("turtlebot2 / flashnav/maps/data/benchmark/heldout/mazes_900002.yaml: policy.onnx "
             "robot.episode.horizon=400 robot.lidar.noise_std=0.03, 58/64 reached, 0 collided")
    path = np.array([[1.0, 1.0], [2.0, 2.0]])
    out = viz.draw_trajectories(grid, [path], np.array([[2.0, 2.0]]), ["success"], tmp_path / "t.png", title=title)
    assert out.stat().st_size > 1_000
    ((box, (x0, y0, width, height), text, axes),) = saved
    assert text.replace("\n", " ") == title and max(len(line) for line in text.split("\n")) <= viz.TITLE_WIDTH
    assert box.x0 >= x0 and box.x1 <= x0 + width and box.y1 <= y0 + height + 0.5, (box, width, height)  # 0.5 px
    assert axes.width >= 0.7 * width, (axes, width)  # the map keeps the figure's width: the title took no room from it
