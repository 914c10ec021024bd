"""Pictures of one run: cost per cycle, a Gantt chart per cycle, and the map of a cycle with
both agents' paths over the learned spatial cost of each human task (paper Figure 3 style)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes

from rapidds.human.spatial import SpatialModel
from rapidds.plots._mpl import plt, save
from rapidds.plots.curves import plot_run_costs
from rapidds.plots.maps import MapView, plot_paths, plot_spatial_cost
from rapidds.record import CycleRecord
from rapidds.store import cycle_paths

if TYPE_CHECKING:  # a type only: worlds sit above plots
    from rapidds.worlds.base import World


def gantt_path(out: Path, run_id: str, cycle: int) -> Path:
    """Where a run's Gantt chart of ``cycle`` goes in its folder ``out``."""
    return out / "gantt" / f"{run_id}-cycle-{cycle:02d}.png"


def save_run_pictures(out: Path, run_id: str, records: Sequence[CycleRecord],
                      arrays: Mapping[str, np.ndarray], spatial: SpatialModel, world: World,
                      exploration_end: float) -> list[Path]:
    """Cost curve over ``records`` (a run's stored cycles), the gamma posterior of a run that
    learns it, and the map of the last cycle
    (``arrays``: its stored arrays) in each of the world's views (the first ``{run}-map.png``,
    others ``{run}-map-{view}.png``), named after the run (two runs in one folder keep their
    own pictures)."""
    if not records:
        return []
    written = [plot_run_costs(records, out / f"{run_id}-cost.png", exploration_end)]
    if any(r.gamma_belief is not None for r in records):  # a run that learns the person's gamma
        from rapidds.plots.curves import plot_gamma_posterior

        written.append(plot_gamma_posterior(records, out / f"{run_id}-gamma.png"))
    rec = records[-1]
    paths = cycle_paths(arrays)
    for k, (view, axes) in enumerate(world.views.items()):
        name = f"{run_id}-map.png" if k == 0 else f"{run_id}-map-{view}.png"
        written.append(save_cycle_map(
            spatial, out / name, human_paths=paths["human"],
            robot_paths={j: np.swapaxes(world.robot_points(v), 0, 1)
                         for j, v in paths["robot"].items()},
            overlaps=rec.realised.overlaps, scene=partial(world.draw, view=view),
            axes=axes, title=f"{run_id}, cycle {rec.cycle} ({view}): learned spatial cost, "
                             "human (gold) and concurrent robot (blue) paths",
        ))
    return written


def save_cycle_map(
    spatial: SpatialModel,
    path: str | Path,
    *,
    human_paths: Mapping[str, np.ndarray],
    robot_paths: Mapping[str, np.ndarray],
    overlaps: Mapping[str, Sequence[str]],
    scene: Callable[[Axes], None] | None = None,
    title: str = "",
    axes: tuple[int, int] = (0, 1),
) -> Path:
    """One panel per human task: its learned cost s_i(x), the static scene (``scene(ax)``, e.g.
    a world's ``draw``), the person's path for it (if they did it this cycle) and the robot's
    workspace paths that ran while it ran.

    human_paths: task -> (T, d) path or (T, K, d) paths of K body points (each point's path is
    drawn on its own). robot_paths: task -> (P, H, d), one path per arm point. axes: workspace
    axes drawn (horizontal, vertical); a 3-D cost is maximised along the third."""
    tasks = list(spatial.tasks)
    fig, panels = plt.subplots(1, len(tasks), figsize=(3.4 * len(tasks), 3.6), squeeze=False)
    for ax, task in zip(panels[0], tasks, strict=True):
        plot_spatial_cost(spatial[task], ax, view=MapView(axes=axes), colorbar=False,
                          title=f"s_{task}(x)")
        if scene is not None:
            scene(ax)
        if task in human_paths:
            hp = np.asarray(human_paths[task], dtype=float)
            plot_paths(ax, np.swapaxes(hp, 0, 1) if hp.ndim == 3 else hp, color="gold",
                       lw=2.0, label=f"human {task}", axes=axes)
        for j, concurrent in overlaps.items():
            if task in concurrent and j in robot_paths:
                plot_paths(ax, robot_paths[j], color="deepskyblue", lw=1.2, label=f"robot {j}",
                           axes=axes)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="lower center")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save(fig, path)
