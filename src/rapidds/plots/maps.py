"""Workspace maps: spatial-cost heat maps with walls, points of interest and paths on top (paper
Figure 3: the learned cost s_i(x) of a human task with trajectories drawn over it).

World geometry is passed in, not imported, so the same helpers draw the fetch map and the arm's
table: walls and obstacles as axis-aligned rectangles (tuples (xmin, ymin, xmax, ymax) or objects
with those attributes, such as ``world.obstacles()``) and points of interest as a dict
name -> (x, y) (``world.points_of_interest()``). Paths and points with d > 2 are drawn by their
first two coordinates (top-down view).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from matplotlib.axes import Axes
from matplotlib.image import AxesImage
from matplotlib.patches import Rectangle
from numpy.typing import ArrayLike

from rapidds.human.spatial import SpatialCostModel, SpatialModel
from rapidds.plots._mpl import plt, save

__all__ = ["MapView", "plot_obstacles", "plot_paths", "plot_points", "plot_spatial_cost",
           "save_cost_maps"]

RectLike = Any  # (xmin, ymin, xmax, ymax) or an object with those four attributes


def _cost_image(
    model: SpatialCostModel, resolution: int, projection: Literal["max", "slice"],
    slice_at: float | None, axes: tuple[int, int] = (0, 1),
) -> np.ndarray:
    """(resolution, resolution) costs over the workspace axes ``axes`` (h, v), row = v,
    column = h; a 3-D workspace's remaining axis is maximised over or sliced."""
    cfg = model.config
    h, v = axes
    (x0, x1), (y0, y1) = cfg.bounds[h], cfg.bounds[v]
    xs, ys = np.linspace(x0, x1, resolution), np.linspace(y0, y1, resolution)
    gx, gy = np.meshgrid(xs, ys)  # (res_y, res_x)
    if cfg.dim == 2:
        plane = np.zeros((*gx.shape, 2))
        plane[..., h], plane[..., v] = gx, gy
        return model.point_cost(plane)
    depth = 3 - h - v  # the axis the picture looks along
    z0, z1 = cfg.bounds[depth]
    if projection == "slice":
        z = (z0 + z1) / 2 if slice_at is None else float(slice_at)
        levels = np.array([z])
    else:
        # multilinear interpolation is linear along an axis between grid levels, so its maximum
        # lies on a level; twice the levels also covers the MLP's smoother profile.
        levels = np.linspace(z0, z1, 2 * cfg.shape[depth] - 1)
    pts = np.zeros((len(levels), *gx.shape, 3))
    pts[..., h], pts[..., v] = gx, gy
    pts[..., depth] = levels[:, None, None]
    return model.point_cost(pts).max(axis=0)


@dataclass(frozen=True)
class MapView:
    """How a cost map is drawn: ``resolution`` pixels a side; ``projection`` "max" or "slice"
    (at ``slice_at``) for a 3-D workspace; the workspace ``axes`` shown (horizontal,
    vertical); the colour map and its range; the colour of paths drawn over it."""

    resolution: int = 200
    projection: Literal["max", "slice"] = "max"
    slice_at: float | None = None
    axes: tuple[int, int] = (0, 1)
    cmap: str = "magma"
    vmin: float = 0.0
    vmax: float = 1.0
    path_color: str = "cyan"


def plot_spatial_cost(model: SpatialCostModel, ax: Axes | None = None, *,
                      view: MapView | None = None, colorbar: bool = True,
                      title: str | None = None) -> AxesImage:
    """Heat map of s_i(x) over the workspace's first two axes, evaluated the way the planner
    evaluates it (MLP or grid interpolation per ``model.config.use_surrogate``).

    ``view`` (:class:`MapView`): for a 3-D workspace, projection "max" shows the top-down
    maximum over the third axis (the worst height a robot could meet the person at each
    (x, y)); "slice" shows the plane z = ``slice_at`` (default: the middle of the bounds);
    ``axes``: the workspace axes drawn (horizontal, vertical), e.g. (1, 2) for a side view
    projected along x. Returns the image, for a shared colour bar; a new figure is made when
    ``ax`` is None (close it with ``plt.close``).
    """
    view = view or MapView()
    resolution, projection, slice_at, axes = (view.resolution, view.projection, view.slice_at,
                                              view.axes)
    if model.config.dim not in (2, 3):
        raise ValueError(f"plot_spatial_cost draws 2-D or 3-D workspaces, got d={model.config.dim}")
    if projection not in ("max", "slice"):
        raise ValueError(f"projection must be 'max' or 'slice', got {projection!r}")
    if ax is None:
        _, ax = plt.subplots(figsize=(4.5, 4))
    if len(set(axes)) != 2 or not all(0 <= a < model.config.dim for a in axes):
        raise ValueError(f"axes must be two different axes of the {model.config.dim}-D "
                         f"workspace, got {axes}")
    img = _cost_image(model, resolution, projection, slice_at, axes)
    (x0, x1), (y0, y1) = model.config.bounds[axes[0]], model.config.bounds[axes[1]]
    im = ax.imshow(img, origin="lower", extent=(x0, x1, y0, y1), cmap=view.cmap, vmin=view.vmin,
                   vmax=view.vmax,
                   interpolation="nearest", aspect="equal")
    if colorbar:
        ax.figure.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="spatial cost $s_i(x)$")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    if title is not None:
        ax.set_title(title)
    return im


def _as_paths(trajectories: ArrayLike | Sequence[ArrayLike],
              axes: tuple[int, int] = (0, 1)) -> list[np.ndarray]:
    if isinstance(trajectories, np.ndarray) and trajectories.ndim == 3:
        items: Iterable[ArrayLike] = list(trajectories)
    elif isinstance(trajectories, np.ndarray) and trajectories.ndim == 2:
        items = [trajectories]
    else:
        items = trajectories  # type: ignore[assignment]  # a sequence of (H, d) paths
    paths = []
    for k, p in enumerate(items):
        a = np.asarray(p, dtype=float)
        if a.ndim != 2 or a.shape[1] <= max(axes) or a.shape[0] == 0:
            raise ValueError(f"path {k} must be an (H, d > {max(axes)}) array, got shape "
                             f"{a.shape}")
        paths.append(a[:, list(axes)])
    return paths


def plot_paths(
    ax: Axes,
    trajectories: ArrayLike | Sequence[ArrayLike],
    *,
    color: str = "C0",
    alpha: float = 0.7,
    lw: float = 1.2,
    label: str | None = None,
    markers: bool = True,
    axes: tuple[int, int] = (0, 1),
) -> Axes:
    """Draw paths: an (N, H, d) array, one (H, d) array, or a list of (H_k, d) arrays of
    different lengths (observed human paths). A circle marks each start, a square each end;
    the label goes to the first path only, so a legend has one entry per call. ``axes``: the
    coordinates drawn (horizontal, vertical)."""
    for k, p in enumerate(_as_paths(trajectories, axes)):
        ax.plot(p[:, 0], p[:, 1], color=color, alpha=alpha, lw=lw, label=label if k == 0 else None)
        if markers:
            ax.plot(*p[0], "o", color=color, ms=4, mec="white", mew=0.5)
            ax.plot(*p[-1], "s", color=color, ms=4, mec="white", mew=0.5)
    return ax


def _rect(r: RectLike) -> tuple[float, float, float, float]:
    if all(hasattr(r, a) for a in ("xmin", "ymin", "xmax", "ymax")):
        return float(r.xmin), float(r.ymin), float(r.xmax), float(r.ymax)  # type: ignore[union-attr]
    vals = tuple(float(v) for v in r)  # type: ignore[union-attr]
    if len(vals) != 4:
        raise ValueError(f"a rectangle is (xmin, ymin, xmax, ymax), got {r}")
    return vals  # type: ignore[return-value]


def plot_obstacles(ax: Axes, rectangles: Iterable[RectLike], *, color: str = "0.15") -> Axes:
    """Filled axis-aligned rectangles: walls, tables, obstacles. Each is a tuple
    (xmin, ymin, xmax, ymax) or any object with those attributes (e.g. a world's ``Rect``)."""
    for k, r in enumerate(rectangles):
        x0, y0, x1, y1 = _rect(r)
        if not (x0 < x1 and y0 < y1):
            raise ValueError(f"rectangle {k} needs xmin < xmax and ymin < ymax, got {r}")
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color=color, zorder=3))
    return ax


def plot_points(ax: Axes, points: Mapping[str, ArrayLike], *, color: str = "tab:red") -> Axes:
    """Labelled markers for points of interest (homes, objects): name -> (x, y, ...)."""
    for name, p in points.items():
        x, y = np.asarray(p, dtype=float)[:2]
        ax.plot(x, y, "D", color=color, ms=6, mec="white", mew=0.8, zorder=4)
        ax.annotate(name, (x, y), xytext=(4, 4), textcoords="offset points", fontsize=8,
                    color="white", zorder=5,
                    bbox={"boxstyle": "round,pad=0.15", "fc": "0.2", "ec": "none", "alpha": 0.6})
    return ax


def save_cost_maps(
    models: SpatialModel | Mapping[str, SpatialCostModel],
    path: str | Path,
    *,
    paths: Mapping[str, ArrayLike | Sequence[ArrayLike]] | None = None,
    scene: Callable[[Axes], None] | None = None,
    titles: Mapping[str, str] | None = None,
    view: MapView | None = None,
    ncols: int | None = None,
    dpi: int = 120,
) -> Path:
    """One panel per human task: its learned cost s_i(x), the static scene (``scene(ax)``, e.g.
    a world's ``draw``), and ``paths[task]`` (robot samples or observed human paths) over it;
    one shared colour bar. Writes ``path`` (format from the suffix, e.g. PNG) and returns it."""
    items = [(tid, models[tid]) for tid in models]
    view = view or MapView(resolution=150)
    if not items:
        raise ValueError("save_cost_maps needs at least one task model")
    ncols = min(len(items), 4) if ncols is None else ncols
    nrows = math.ceil(len(items) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.6 * ncols + 0.8, 3.4 * nrows),
                             squeeze=False, layout="constrained")
    im: AxesImage | None = None
    for ax, (tid, model) in zip(axes.flat, items, strict=False):
        title = (titles or {}).get(tid, f"{tid} (n={model.n_obs})")
        im = plot_spatial_cost(model, ax, view=view, colorbar=False, title=title)
        if scene is not None:
            scene(ax)
        if paths and tid in paths:
            plot_paths(ax, paths[tid], color=view.path_color, alpha=0.8)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    for ax in list(axes.flat)[len(items):]:
        ax.set_visible(False)
    assert im is not None  # items is not empty
    fig.colorbar(im, ax=axes, shrink=0.85, label="spatial cost $s_i(x)$")
    return save(fig, path, dpi=dpi)
