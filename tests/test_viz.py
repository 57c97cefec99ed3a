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


def test_the_picture_shows_the_free_space_and_what_is_drawn_not_the_border_round_them(tmp_path, monkeypatch):
    occupied = np.ones((400, 400), dtype=bool)
    occupied[150:250, 100:200] = False  # a 5 x 5 m room in a 20 x 20 m map (a ROS map's unknown border)
    grid = OccupancyMap(occupied, 0.05, name="room")
    ox, oy = grid.origin
    room = (ox + 5.0, oy + 7.5, ox + 10.0, oy + 12.5)  # columns 100-199, rows 150-249
    m = viz.VIEW_MARGIN_M
    assert viz.view_bounds(grid, np.empty((0, 2))) == pytest.approx(
        (room[0] - m, room[1] - m, room[2] + m, room[3] + m))
    # a drawn point outside the room widens the view; one off the map and a NaN row do not take it past the map
    got = viz.view_bounds(grid, np.array([[ox + 11.0, oy + 8.0], [ox - 3.0, oy + 9.0], [np.nan, 0.0]]))
    assert got == pytest.approx((ox, room[1] - m, ox + 11.0 + m, room[3] + m))
    assert viz.view_bounds(OccupancyMap(np.ones((40, 60), dtype=bool), 0.1), np.zeros((1, 2))) == pytest.approx(
        OccupancyMap(np.ones((40, 60), dtype=bool), 0.1).bounds)  # nothing free: the whole map
    limits = []
    real_save = viz._save
    monkeypatch.setattr(viz, "_save", lambda fig, out, dpi=None: (limits.append((fig.axes[0].get_xlim(),
                                                                                  fig.axes[0].get_ylim())),
                                                                   real_save(fig, out, dpi))[1])
    path = np.array([[ox + 6.0, oy + 8.0], [ox + 9.0, oy + 12.0]])
    viz.draw_trajectories(grid, [path], path[-1:], ["timeout"], tmp_path / "room.png")
    ((xlim, ylim),) = limits
    assert (xlim + ylim) == pytest.approx((room[0] - m, room[2] + m, room[1] - m, room[3] + m))
