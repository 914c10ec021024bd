"""Gantt chart of one cycle: a row per agent, a bar per task, wait tokens as markers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rapidds.plots._mpl import plt, save
from rapidds.problem import AGENTS
from rapidds.schedule import Timeline, Wait

_COLORS = {"human": "#e8a33d", "robot": "#3d7be8"}


def plot_gantt(
    timeline: Timeline, sample: int = 0, title: str = "", ax: plt.Axes | None = None
) -> plt.Axes:
    """Draw timeline ``sample`` (one row of the (K, n) start/finish arrays)."""
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 2.2))
    idx = timeline.problem.index
    start, finish = timeline.start[sample], timeline.finish[sample]
    for row, agent in enumerate(AGENTS):
        y = len(AGENTS) - 1 - row
        for item in timeline.schedule.sequence(agent):
            if isinstance(item, Wait):
                t = finish[idx[item.task]]
                ax.plot([t, t], [y - 0.4, y + 0.4], color="k", lw=1.5, ls=":")
                ax.text(t, y + 0.42, f"w:{item.task}", ha="center", va="bottom", fontsize=7)
                continue
            c = idx[item]
            ax.barh(y, finish[c] - start[c], left=start[c], height=0.6,
                    color=_COLORS[agent], edgecolor="k", alpha=0.85)
            ax.text((start[c] + finish[c]) / 2, y, item, ha="center", va="center", fontsize=8)
    ax.set_yticks(range(len(AGENTS)), list(reversed(AGENTS)))
    ax.set_xlabel("time [s]")
    ax.set_xlim(0, float(np.max(finish)) * 1.02 + 1e-9)
    ax.set_ylim(-0.6, len(AGENTS) - 0.2)
    if title:
        ax.set_title(title, fontsize=9)
    return ax


def save_gantt(timeline: Timeline, path: str | Path, title: str = "") -> Path:
    ax = plot_gantt(timeline, title=title)
    return save(ax.figure, path)
