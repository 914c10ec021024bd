"""Gantt chart of one cycle: a row per agent, a bar per task, wait tokens as markers."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from rapidds.plots._mpl import plt, save
from rapidds.problem import AGENTS
from rapidds.schedule import Timeline, Wait

_COLORS = {"human": "#e8a33d", "robot": "#3d7be8"}


def plot_gantt(
    timeline: Timeline, sample: int = 0, title: str = "", ax: plt.Axes | None = None,
    pauses: Iterable[Mapping[str, Any]] = (), replans: Iterable[Mapping[str, Any]] = (),
) -> plt.Axes:
    """Draw timeline ``sample`` (one row of the (K, n) start/finish arrays). ``pauses`` and
    ``replans`` of a cycle executed reactively (its record's lists) are drawn over it: a
    hatched band where an agent was held back (red: stopped, grey: slowed), a red triangle
    above the chart at each re-plan."""
    replans = list(replans)
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
    _draw_reactions(ax, pauses, replans)
    ax.set_yticks(range(len(AGENTS)), list(reversed(AGENTS)))
    ax.set_xlabel("time [s]")
    ax.set_xlim(0, float(np.max(finish)) * 1.02 + 1e-9)
    ax.set_ylim(-0.6, len(AGENTS) - 0.2 + 0.4 * bool(replans))
    if title:
        ax.set_title(title, fontsize=9)
    return ax


def _draw_reactions(ax: plt.Axes, pauses: Iterable[Mapping[str, Any]],
                    replans: Iterable[Mapping[str, Any]]) -> None:
    rows = {"human": 1, "person": 1, "robot": 0}
    for p in pauses:
        stopped = "stop" in p["reason"] or p["reason"] == "deviation"
        ax.barh(rows[p["agent"]], p["end"] - p["start"], left=p["start"], height=0.6,
                color="none", edgecolor="#c0392b" if stopped else "#777777", hatch="///",
                lw=0)
    for r in replans:
        ax.plot([r["time"]], [len(AGENTS) - 0.35], marker="v", color="#c0392b", ms=7)
        ax.text(r["time"], len(AGENTS) - 0.3, r["reason"], ha="center", va="bottom", fontsize=6)


def save_gantt(timeline: Timeline, path: str | Path, title: str = "",
               pauses: Iterable[Mapping[str, Any]] = (),
               replans: Iterable[Mapping[str, Any]] = ()) -> Path:
    ax = plot_gantt(timeline, title=title, pauses=pauses, replans=replans)
    return save(ax.figure, path)
