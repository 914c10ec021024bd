"""Cost per cycle: one run's curves, and study panels with median and interquartile band."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from rapidds.plots._mpl import plt, save


def plot_run_costs(
    records: Sequence[Mapping], path: str | Path, exploration_end: float | None = None
) -> Path:
    """Realised and expected cost of each cycle of one run, with its makespan and spatial parts."""
    cyc = np.array([r["cycle"] for r in records])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.2))
    a.plot(cyc, [r["realised"]["cost"] for r in records], "o-", label="realised cost")
    a.plot(cyc, [r["expected"]["makespan"] + r["gamma"] * r["expected"]["spatial"]
                 for r in records], "s--", alpha=0.7, label="expected cost (no diversity)")
    b.plot(cyc, [r["realised"]["makespan"] for r in records], "o-", label="makespan [s]")
    b2 = b.twinx()
    b2.plot(cyc, [r["realised"]["spatial"] for r in records], "^-", color="C3",
            label="spatial cost")
    b2.set_ylabel("spatial cost", color="C3")
    for ax in (a, b):
        ax.set_xlabel("cycle")
        if exploration_end is not None:
            ax.axvline(exploration_end, color="r", lw=1, alpha=0.6)
    a.set_ylabel("cost")
    a.legend(fontsize=8)
    b.legend(loc="upper left", fontsize=8)
    b2.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def plot_study_panels(
    curves: Mapping[str, Mapping[str, np.ndarray]],
    path: str | Path,
    exploration_end: float | None = None,
    ylabel: str = "realised cost",
) -> Path:
    """One panel per archetype; each level drawn as median line and IQR band.

    ``curves[archetype][level]`` is a (trials, cycles) array.
    """
    names = list(curves)
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        for k, (level, arr) in enumerate(curves[name].items()):
            arr = np.asarray(arr, dtype=float)
            x = np.arange(arr.shape[1])
            q1, med, q3 = np.nanpercentile(arr, [25, 50, 75], axis=0)
            ax.plot(x, med, label=level, color=f"C{k}", lw=1.6)
            ax.fill_between(x, q1, q3, color=f"C{k}", alpha=0.15)
        if exploration_end is not None:
            ax.axvline(exploration_end, color="r", lw=1)
        ax.set_title(name)
        ax.set_xlabel("cycle")
    axes[0][0].set_ylabel(ylabel)
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)
