"""User-study figures: cost reductions per participant and system (marked by priming group),
cost per round, ranking distribution, survey answers per item and system."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from rapidds.plots._mpl import plt, save

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def _ci95(values: np.ndarray) -> float:
    """Half-width of a t 95 % interval of the mean (0 for fewer than 2 values)."""
    from scipy import stats

    n = len(values)
    if n < 2:
        return 0.0
    return float(stats.t.ppf(0.975, n - 1) * values.std(ddof=1) / np.sqrt(n))


def plot_cost_reductions(reductions: pd.DataFrame, columns: Sequence[tuple[str, str]],
                         systems: Sequence[str], path: str | Path, seed: int = 0) -> Path:
    """One panel per (column, label): every participant's reduction per system (jittered),
    coloured and shaped by priming ``group``, with the mean and its 95 % interval."""
    groups = sorted(reductions["group"].unique())
    rng = np.random.default_rng(seed)  # jitter only; the same picture every time
    fig, axes = plt.subplots(1, len(columns), figsize=(5.2 * len(columns), 3.8), squeeze=False)
    for ax, (col, label) in zip(axes[0], columns, strict=True):
        for x, system in enumerate(systems):
            cell = reductions[reductions["system"] == system]
            for g, group in enumerate(groups):
                v = cell.loc[cell["group"] == group, col].to_numpy(float)
                ax.scatter(x + rng.uniform(-0.22, 0.22, len(v)), v, s=16, alpha=0.75,
                           color=f"C{g}", marker=_MARKERS[g % len(_MARKERS)],
                           label=group if x == 0 else None)
            v = cell[col].to_numpy(float)
            if len(v):
                ax.errorbar(x + 0.32, v.mean(), yerr=_ci95(v), fmt="_", color="k", ms=14,
                            capsize=4, lw=1.5)
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.set_xticks(range(len(systems)), systems)
        ax.set_xlabel("system")
        ax.set_ylabel(label)
    axes[0][0].legend(title="priming group", fontsize=7, title_fontsize=7)
    fig.suptitle("first round minus mean of the last three (positive: the cost fell); "
                 "black: mean, 95 % CI", fontsize=9)
    fig.tight_layout()
    return save(fig, path)


def plot_round_costs(rounds: pd.DataFrame, columns: Sequence[tuple[str, str]],
                     systems: Sequence[str], path: str | Path) -> Path:
    """Mean cost per round and system over participants, with 95 % intervals."""
    fig, axes = plt.subplots(1, len(columns), figsize=(5.2 * len(columns), 3.5), squeeze=False)
    for ax, (col, label) in zip(axes[0], columns, strict=True):
        for k, system in enumerate(systems):
            g = rounds[rounds["system"] == system].groupby("round")[col]
            mean = g.mean()
            ci = g.apply(lambda s: _ci95(s.to_numpy(float)))
            x = mean.index.to_numpy() + 1
            ax.plot(x, mean.to_numpy(), "o-", color=f"C{k}", label=system, ms=3)
            ax.fill_between(x, mean - ci, mean + ci, color=f"C{k}", alpha=0.12)
        ax.set_xlabel("round")
        ax.set_ylabel(label)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def plot_ranking_distribution(distribution: pd.DataFrame, path: str | Path) -> Path:
    """Stacked bars: how many participants ranked each system 1st, 2nd, ... (rows: systems,
    columns: ranks)."""
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    bottom = np.zeros(len(distribution))
    for k, rank in enumerate(distribution.columns):
        v = distribution[rank].to_numpy(float)
        ax.bar(range(len(distribution)), v, bottom=bottom, color=plt.cm.viridis(
            k / max(1, len(distribution.columns) - 1)), label=f"rank {rank}")
        bottom += v
    ax.set_xticks(range(len(distribution)), list(distribution.index))
    ax.set_ylabel("participants")
    ax.set_xlabel("system")
    ax.legend(fontsize=7, ncols=2)
    fig.tight_layout()
    return save(fig, path)


def plot_survey(survey: pd.DataFrame, items: Sequence[str], systems: Sequence[str],
                path: str | Path, scale: tuple[int, int] = (1, 7)) -> Path:
    """Mean answer (with 95 % interval) per survey item and system."""
    fig, ax = plt.subplots(figsize=(max(6.0, 0.75 * len(items) * len(systems) / 2), 3.8))
    width = 0.8 / len(systems)
    for k, system in enumerate(systems):
        means, cis = [], []
        for item in items:
            v = survey.loc[(survey["item"] == item) & (survey["system"] == system),
                           "value"].to_numpy(float)
            means.append(v.mean() if len(v) else np.nan)
            cis.append(_ci95(v))
        ax.bar(np.arange(len(items)) + (k - (len(systems) - 1) / 2) * width, means, width,
               yerr=cis, capsize=2, color=f"C{k}", label=system)
    ax.set_xticks(range(len(items)), list(items), rotation=35, ha="right", fontsize=7)
    ax.set_ylim(scale[0] - 0.5, scale[1] + 0.5)
    ax.set_ylabel(f"answer ({scale[0]} = strongly disagree, {scale[1]} = strongly agree)",
                  fontsize=8)
    ax.legend(fontsize=7, ncols=len(systems))
    fig.tight_layout()
    return save(fig, path)
