"""Map pictures: the per-task cost figure really draws something."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib.image as mpimg
import numpy as np
import pytest

from rapidds.human.spatial import SpatialConfig, SpatialCostModel, SpatialModel
from rapidds.plots._mpl import plt
from rapidds.plots.maps import (
    MapView,
    plot_obstacles,
    plot_paths,
    plot_points,
    plot_spatial_cost,
    save_cost_maps,
)


def _line(a, b, n=60) -> np.ndarray:
    return np.linspace(a, b, n)


def _scene(ax) -> None:
    plot_obstacles(ax, [(4.5, 4.0, 5.5, 6.0),
                        SimpleNamespace(xmin=0.0, ymin=6.0, xmax=1.0, ymax=7.0)])
    plot_points(ax, {"home": (5, 1), "obj": (5, 9)})


def test_cost_map_figure_writes_a_png_with_content(tmp_path):
    cfg = SpatialConfig(bounds=((0, 10), (0, 10)), grid_points=16)
    left = [_line((5, 1), (2, 5)), _line((2, 5), (5, 9))]
    model = SpatialModel.from_population(cfg, {
        "t2": [np.concatenate(left)],
        "t3": [_line((5, 1), (8, 9))],
        "t0": [_line((1, 9), (9, 9))],
    })
    samples = np.stack([_line((9, 1), (9, 9), 32), _line((9, 1), (6, 9), 32)])
    out = save_cost_maps(
        model, tmp_path / "maps.png",
        paths={"t2": samples, "t3": [left[0], left[1][:10]]},
        scene=_scene,
    )
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(out)[..., :3]
    assert img.shape[0] > 100 and img.shape[1] > 300  # three panels side by side
    assert img.std() > 0.1
    assert len(np.unique(img.reshape(-1, 3).round(2), axis=0)) > 50  # a heat map, not flat


def test_3d_projection_and_bad_input():
    cfg = SpatialConfig(bounds=((0, 1), (0, 1), (0, 1)), beta=8.0, grid_points=8)
    m = SpatialCostModel.from_population(cfg, [np.linspace((0, 0, 0.2), (1, 1, 0.8), 40)])
    fig, (a, b) = plt.subplots(1, 2)
    top = plot_spatial_cost(m, a, view=MapView(resolution=40), colorbar=False).get_array()
    mid = plot_spatial_cost(m, b, view=MapView(resolution=40, projection="slice"),
                            colorbar=False).get_array()
    assert np.all(top >= mid - 1e-12) and top.max() > mid.max() + 0.15  # max over z dominates
    with pytest.raises(ValueError, match="must be an"):
        plot_paths(a, [np.zeros((3, 1))])
    plt.close(fig)
    one_d = SpatialCostModel.from_population(
        SpatialConfig(bounds=((0, 1),), grid_points=4), [np.zeros((2, 1))])
    with pytest.raises(ValueError, match="2-D or 3-D"):
        plot_spatial_cost(one_d)


def test_side_view_projects_along_the_remaining_axis_and_body_points_draw_apart(tmp_path,
                                                                                monkeypatch):
    """A side view (y, z) is the max over x of the cost, not a top view relabelled; a person's
    (T, K, 3) paths are K lines, one per body point, not one line through all of them."""
    from rapidds.plots.run import save_cycle_map

    cfg = SpatialConfig(bounds=((0, 1), (0, 2), (0, 1)), beta=8.0, grid_points=8)
    path = np.linspace((0.9, 0.2, 0.1), (0.9, 1.8, 0.9), 40)  # at x = 0.9 only
    m = SpatialCostModel.from_population(cfg, [path])
    fig, ax = plt.subplots()
    side = plot_spatial_cost(m, ax, view=MapView(resolution=30, axes=(1, 2)),
                             colorbar=False).get_array()
    assert side.shape == (30, 30) and ax.get_xlim() == (0, 2) and ax.get_ylim() == (0, 1)
    ys, zs = np.linspace(0, 2, 30), np.linspace(0, 1, 30)
    for i, j in ((5, 10), (20, 25), (15, 3)):  # row = z, column = y
        along_x = m.point_cost(np.stack([np.linspace(0, 1, 15), np.full(15, ys[j]),
                                         np.full(15, zs[i])], axis=-1))
        assert side[i, j] == pytest.approx(along_x.max(), abs=0.02)
    with pytest.raises(ValueError, match="two different axes"):
        plot_spatial_cost(m, ax, view=MapView(axes=(1, 1)))
    plt.close(fig)

    model = SpatialModel.from_population(cfg, {"a": [path]})
    up, back = np.array([0.0, 0.0, 0.05]), np.array([0.5, 0.0, 0.0])
    body = np.stack([path, path + up, path - back], axis=1)  # (T, 3, 3)
    drawn = []
    import rapidds.plots.run as run_plots

    def recorded(ax, trajectories, **kw):  # the real plot_paths, its input noted
        drawn.append(np.asarray(trajectories).shape)
        return plot_paths(ax, trajectories, **kw)

    monkeypatch.setattr(run_plots, "plot_paths", recorded)
    save_cycle_map(model, tmp_path / "m.png", human_paths={"a": body}, robot_paths={},
                   overlaps={}, axes=(1, 2))
    assert drawn == [(3, 40, 3)]
