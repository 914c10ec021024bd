"""Cost per cycle: one run's curves, and study panels with median and interquartile band."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from rapidds.plots._mpl import plt, save
from rapidds.record import CycleRecord


def plot_run_costs(
    records: Sequence[CycleRecord], path: str | Path, exploration_end: float | None = None
) -> Path:
    """Realised and expected cost of each cycle of one run, with its makespan and spatial parts."""
    cyc = np.array([r.cycle for r in records])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.2))
    a.plot(cyc, [r.realised.cost for r in records], "o-", label="realised cost")
    a.plot(cyc, [r.expected.makespan + r.plan.gamma * r.expected.spatial
                 for r in records], "s--", alpha=0.7, label="expected cost (no diversity)")
    b.plot(cyc, [r.realised.makespan for r in records], "o-", label="makespan [s]")
    b2 = b.twinx()
    b2.plot(cyc, [r.realised.spatial for r in records], "^-", color="C3",
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


def plot_gamma_posterior(records: Sequence[CycleRecord], path: str | Path) -> Path:
    """A run that learned gamma: the gamma each cycle was planned with, the posterior after it
    (geometric mean, 10-90 % band), the comfort answers, and the person's true gamma when the
    person was simulated."""
    cyc = np.array([r.cycle for r in records])
    post = [r.gamma_belief or {} for r in records]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.2))
    a.fill_between(cyc, [p["q10"] for p in post], [p["q90"] for p in post], alpha=0.2,
                   label="posterior 10-90 %")
    a.plot(cyc, [p["mean"] for p in post], "o-", label="posterior mean (after the cycle)")
    a.plot(cyc, [r.plan.gamma for r in records], "s--", alpha=0.7, label="planned with")
    truth = {r.comfort["true_gamma"] for r in records
             if r.comfort and "true_gamma" in r.comfort}
    for g in truth:
        a.axhline(g, color="k", ls=":", lw=1, label="true gamma (simulated person)")
    a.set_yscale("log")
    a.set_ylabel("gamma")
    answers = [(r.cycle, r.comfort["answer"]) for r in records
               if r.comfort and r.comfort["answer"] is not None]
    if answers:
        b.plot(*zip(*answers, strict=True), "o-", label='"came too close" (1-7)')
    b.bar(cyc, [len(r.comfort["too_close"]) if r.comfort else 0 for r in records],
          alpha=0.4, color="C3", label='"too close" signals')
    b.set_ylim(0, 7.5)
    for ax in (a, b):
        ax.set_xlabel("cycle")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, path)
