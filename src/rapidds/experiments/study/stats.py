"""The user study's analyses, on tidy data frames (paper, section "Collaborative Painting: User
Study").

* :func:`cost_reduction`: per participant and system, first round minus the mean of the last three.
* :func:`rm_anova_2x2`: two-way repeated-measures ANOVA, spatial x temporal adaptation (pingouin;
  each effect against its own effect x participant error, the textbook RM ANOVA).
* :func:`ranking_test`: the forced-choice ranking. The paper names a Wilcoxon *rank-sum* test, but
  the four ranks of one participant are paired, so this is the *signed-rank* test on each
  participant's mean rank of the non-spatial systems minus that of the spatially adaptive ones.
* the aligned rank transform ANOVA of the survey items lives in :mod:`.art`.

Effect sizes: partial eta squared SS_effect / (SS_effect + SS_error) = F df1 / (F df1 + df2) for
the ANOVAs (for ART, of the ranks, as in the ARTool effect-size vignette); the matched-pairs
rank-biserial correlation for the signed-rank test. Every function validates its input and
raises :class:`~rapidds.errors.StudyDataError` with one line that says what is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pingouin as pg
from scipy import stats

from rapidds.errors import StudyDataError
from rapidds.experiments.study.systems import ADAPTATION, ANALYSIS_FACTORS, FACTORS, SYSTEMS

EFFECT_COLUMNS: tuple[str, ...] = ("F", "df1", "df2", "p", "partial_eta_sq")
"""Columns of every ANOVA table this module returns (one row per effect, index ``effect``)."""


# --- validation helpers -------------------------------------------------------------------------


def _require(df: object, columns: Sequence[str], what: str) -> pd.DataFrame:
    if not isinstance(df, pd.DataFrame):
        raise StudyDataError(f"{what}: expected a pandas DataFrame, got {type(df).__name__}")
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise StudyDataError(
            f"{what}: missing column(s) {', '.join(map(repr, missing))}; "
            f"has {', '.join(map(repr, df.columns))}"
        )
    if df.empty:
        raise StudyDataError(f"{what}: the table has no rows")
    nan = [c for c in columns if df[c].isna().any()]
    if nan:
        first = df.index[df[nan[0]].isna()][0]
        raise StudyDataError(f"{what}: column '{nan[0]}' has missing values (first at row {first})")
    return df


def _numeric(df: pd.DataFrame, column: str, what: str) -> np.ndarray:
    values = df[column]
    if not (pd.api.types.is_numeric_dtype(values) or pd.api.types.is_bool_dtype(values)):
        raise StudyDataError(f"{what}: column '{column}' must be numeric, got {values.dtype}")
    out = values.to_numpy(dtype=float)
    if not np.isfinite(out).all():
        raise StudyDataError(f"{what}: column '{column}' has non-finite values")
    return out


def adaptation_factors(
    df: pd.DataFrame,
    system: str = "system",
    adaptation: Mapping[str, tuple[bool, bool]] = ADAPTATION,
) -> pd.DataFrame:
    """A copy of ``df`` with boolean columns ``spatial`` and ``temporal`` from the system."""
    _require(df, [system], "adaptation factors")
    unknown = sorted(set(df[system].astype(str)) - set(adaptation))
    if unknown:
        raise StudyDataError(
            f"adaptation factors: unknown system(s) {', '.join(unknown)}; "
            f"known: {', '.join(adaptation)}"
        )
    flags = df[system].astype(str).map(adaptation)
    return df.assign(**{name: flags.map(lambda f, i=i: f[i]) for i, name in enumerate(FACTORS)})


def _counts(df: pd.DataFrame, rows: str, columns: str) -> pd.DataFrame:
    """Rows per (rows, columns) pair as a table (a faster pd.crosstab)."""
    return df.groupby([rows, columns], sort=False).size().unstack(fill_value=0)


def _one_per_system(
    df: pd.DataFrame, subject: str, system: str, systems: Sequence[str], what: str
) -> None:
    """Every subject has exactly one row for each of ``systems`` and no others."""
    counts = _counts(df, subject, system)
    extra = sorted(set(counts.columns.astype(str)) - set(systems))
    if extra:
        raise StudyDataError(f"{what}: unknown system(s) {', '.join(extra)}")
    counts = counts.reindex(columns=list(systems), fill_value=0)
    bad = counts.index[(counts.to_numpy() != 1).any(axis=1)]
    if len(bad):
        row = counts.loc[bad[0]]
        wrong = ", ".join(f"{s} x{n}" for s, n in row.items() if n != 1)
        raise StudyDataError(
            f"{what}: participant {bad[0]} needs exactly one row per system ({wrong}); "
            "the repeated-measures design must be complete and balanced"
        )
    if len(counts) < 2:
        raise StudyDataError(f"{what}: needs at least 2 participants, got {len(counts)}")


# --- objective costs ----------------------------------------------------------------------------


def cost_reduction(
    df: pd.DataFrame,
    costs: Sequence[str] = ("spatial_cost", "temporal_cost"),
    *,
    subject: str = "participant",
    system: str = "system",
    round: str = "round",
    last: int = 3,
) -> pd.DataFrame:
    """Per participant and system: cost of the first round minus the mean of the last ``last``.

    ``df`` has one row per participant, system and round. Returns one row per participant and
    system with ``subject``, ``system`` and ``<cost>_reduction`` per cost (positive = the cost
    fell). Every (participant, system) must have the same rounds, at least ``last + 1``.
    """
    what = "cost reduction"
    if isinstance(costs, str) or not costs:
        raise StudyDataError(f"{what}: costs must be a non-empty list of column names")
    _require(df, [subject, system, round, *costs], what)
    if last < 1:
        raise StudyDataError(f"{what}: last must be >= 1, got {last}")
    rounds = _numeric(df, round, what)
    if not np.array_equal(rounds, np.round(rounds)):
        raise StudyDataError(f"{what}: column '{round}' must hold whole round numbers")
    for c in costs:
        _numeric(df, c, what)
    dup = df.duplicated([subject, system, round])
    if dup.any():
        r = df[dup].iloc[0]
        raise StudyDataError(
            f"{what}: participant {r[subject]}, system {r[system]} has round {r[round]} twice"
        )
    per_cell = df.groupby([subject, system], sort=False)[round].apply(lambda s: tuple(sorted(s)))
    expected = per_cell.iloc[0]
    odd = per_cell[per_cell.map(lambda t: t != expected)]
    if not odd.empty:
        (who, sys_), got = odd.index[0], odd.iloc[0]
        raise StudyDataError(
            f"{what}: participant {who}, system {sys_} has rounds {list(got)}, "
            f"others have {list(expected)}"
        )
    if len(expected) < last + 1:
        raise StudyDataError(
            f"{what}: needs at least {last + 1} rounds per system (first + last {last}), "
            f"got {len(expected)}"
        )
    cells = df.sort_values([subject, system, round], kind="stable").groupby(
        [subject, system], sort=False
    )[list(costs)]
    reduction = cells.first() - cells.apply(lambda g: g.tail(last).mean())
    return reduction.rename(columns={c: f"{c}_reduction" for c in costs}).reset_index()


# --- two-way repeated-measures ANOVA ------------------------------------------------------------


def rm_anova_2x2(
    df: pd.DataFrame,
    dv: str,
    *,
    subject: str = "participant",
    system: str = "system",
    adaptation: Mapping[str, tuple[bool, bool]] = ADAPTATION,
) -> pd.DataFrame:
    """Two-way repeated-measures ANOVA of ``dv`` with factors spatial and temporal adaptation,
    both derived from the system. One row per participant and system, all four systems.

    Returns one row per effect (``spatial``, ``temporal``, ``spatial:temporal``) with F, df1,
    df2, p and partial eta squared. Each effect is tested against its own effect x participant
    error (df2 = participants - 1); with two levels per factor sphericity holds trivially.
    """
    what = "repeated-measures ANOVA"
    _require(df, [subject, system, dv], what)
    _numeric(df, dv, what)
    _one_per_system(df, subject, system, list(adaptation), what)
    data = adaptation_factors(df, system, adaptation)
    # string levels and a private dv name: pingouin pivots on them, and a level equal to the dv
    # name would break its melt
    data = pd.DataFrame(
        {
            "_subject": data[subject].astype(str),
            **{f: np.where(data[f], "yes", "no") for f in ANALYSIS_FACTORS},
            "_dv": data[dv].astype(float),
        }
    )
    within = list(ANALYSIS_FACTORS)
    res = pg.rm_anova(data, dv="_dv", within=within, subject="_subject", effsize="np2")
    names = {within[0]: within[0], within[1]: within[1], " * ".join(within): ":".join(within)}
    table = pd.DataFrame(
        {
            "F": res["F"].to_numpy(float),
            "df1": res["ddof1"].to_numpy(float),
            "df2": res["ddof2"].to_numpy(float),
            "p": res["p_unc"].to_numpy(float),
            "partial_eta_sq": res["np2"].to_numpy(float),
        },
        index=pd.Index([names[s] for s in res["Source"]], name="effect"),
    )
    return table


# --- ranking ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RankingTest:
    """Wilcoxon signed-rank test of spatially adaptive vs other systems in the final ranking.

    ``difference`` per participant = mean rank of the non-spatial systems minus mean rank of the
    spatial ones (rank 1 = most preferred), so positive = spatial adaptation preferred.
    ``statistic`` is scipy's (two-sided: the smaller of the signed-rank sums), ``r`` the
    matched-pairs rank-biserial correlation (R+ - R-) / (R+ + R-) over nonzero differences, in
    [-1, 1] and positive when spatial systems are ranked better. ``n`` counts nonzero
    differences (zeros are dropped, Wilcoxon's convention), ``n_zero`` the dropped ones.
    """

    statistic: float
    p: float
    r: float
    n: int
    n_zero: int
    difference: pd.Series
    mean_rank: pd.Series
    distribution: pd.DataFrame


def rankings_from_orders(
    orders: Mapping[str, Sequence[str]], *, subject: str = "participant"
) -> pd.DataFrame:
    """Long table (participant, system, rank) from each participant's systems, best first."""
    rows = [
        {subject: who, "system": s, "rank": k + 1}
        for who, order in orders.items()
        for k, s in enumerate(order)
    ]
    return pd.DataFrame.from_records(rows, columns=[subject, "system", "rank"])


def ranking_test(
    rankings: pd.DataFrame,
    *,
    subject: str = "participant",
    system: str = "system",
    rank: str = "rank",
    systems: Sequence[str] = SYSTEMS,
    adaptation: Mapping[str, tuple[bool, bool]] = ADAPTATION,
) -> RankingTest:
    """Test whether spatially adaptive systems are ranked better (forced-choice ranking).

    ``rankings`` has one row per participant and system with the rank (1 = best). Each
    participant's ranks must be a permutation of 1..len(systems) over exactly ``systems``.
    Two-sided signed-rank test (scipy, ``zero_method="wilcox"``, continuity correction as R's
    ``wilcox.test``): exact over all sign flips up to 13 nonzero differences, else normal
    approximation with the tie-corrected variance. The differences take few values (mean ranks
    of two out of four), so ties are the rule and the exact table of untied ranks never applies.
    """
    what = "ranking test"
    _require(rankings, [subject, system, rank], what)
    unknown = sorted(set(systems) - set(adaptation))
    if unknown:
        raise StudyDataError(f"{what}: no adaptation known for system(s) {', '.join(unknown)}")
    spatial = [s for s in systems if adaptation[s][FACTORS.index("spatial")]]
    other = [s for s in systems if not adaptation[s][FACTORS.index("spatial")]]
    if not spatial or not other:
        raise StudyDataError(f"{what}: needs spatially adaptive and other systems among {systems}")
    ranks = _numeric(rankings, rank, what)
    if not np.array_equal(ranks, np.round(ranks)):
        raise StudyDataError(f"{what}: column '{rank}' must hold whole ranks 1..{len(systems)}")
    data = rankings.assign(**{rank: ranks.astype(int), system: rankings[system].astype(str)})
    want_ranks = np.arange(1, len(systems) + 1)
    counts = _counts(data, subject, system)
    named = counts.reindex(columns=list(systems), fill_value=0)
    bad = counts.index[
        (named.to_numpy() != 1).any(axis=1) | (counts.sum(axis=1) != len(systems)).to_numpy()
    ]
    if len(bad):
        got = data.loc[data[subject] == bad[0], system]
        raise StudyDataError(
            f"{what}: participant {bad[0]} ranked {', '.join(got)}; "
            f"a ranking must name each of {', '.join(systems)} once"
        )
    wide = data.pivot(index=subject, columns=system, values=rank)[list(systems)]
    sorted_ranks = np.sort(wide.to_numpy(), axis=1)
    bad_rows = np.flatnonzero((sorted_ranks != want_ranks).any(axis=1))
    if bad_rows.size:
        raise StudyDataError(
            f"{what}: participant {wide.index[bad_rows[0]]} has ranks "
            f"{sorted_ranks[bad_rows[0]].tolist()}; a forced-choice ranking is a permutation of "
            f"{want_ranks.tolist()}"
        )
    if len(wide) < 2:
        raise StudyDataError(f"{what}: needs at least 2 participants, got {len(wide)}")
    diff = wide[other].mean(axis=1) - wide[spatial].mean(axis=1)
    nonzero = diff[diff != 0].to_numpy()
    if nonzero.size:
        res = stats.wilcoxon(nonzero, zero_method="wilcox", correction=True, method="auto")
        statistic, p = float(res.statistic), float(res.pvalue)
        signed = stats.rankdata(np.abs(nonzero)) * np.sign(nonzero)
        r = float(signed.sum() / np.abs(signed).sum())
    else:  # every participant split the systems evenly: no evidence either way
        statistic, p, r = 0.0, 1.0, 0.0
    distribution = (
        _counts(data, system, rank)
        .reindex(index=list(systems), columns=want_ranks.tolist(), fill_value=0)
        .rename_axis(index="system", columns="rank")
    )
    return RankingTest(
        statistic=statistic,
        p=p,
        r=r,
        n=int(nonzero.size),
        n_zero=int((diff == 0).sum()),
        difference=diff.rename("difference"),
        mean_rank=wide[list(systems)].mean().rename("mean_rank"),
        distribution=distribution,
    )
