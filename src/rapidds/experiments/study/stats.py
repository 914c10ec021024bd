"""The user study's analyses, on tidy data frames (paper, section "Collaborative Painting: User
Study").

* :func:`cost_reduction`: per participant and system, first round minus the mean of the last three.
* :func:`rm_anova_2x2`: two-way repeated-measures ANOVA, spatial x temporal adaptation (pingouin;
  each effect against its own effect x participant error, the textbook RM ANOVA).
* :func:`ranking_test`: the forced-choice ranking. The paper names a Wilcoxon *rank-sum* test, but
  the four ranks of one participant are paired, so this is the *signed-rank* test on each
  participant's mean rank of the non-spatial systems minus that of the spatially adaptive ones.
* :func:`art_anova`: the aligned rank transform (Wobbrock et al. 2011) for factorial designs with
  subjects, then an ANOVA on the ranks with the subject error stratum (R:
  ``aov(y ~ A*B + Error(S))``), which for balanced complete data gives the F of ARTool's default
  mixed model ``art(y ~ A*B + (1|S))``. Within-subject effects are tested against the pooled
  within-subject residual, between-subject effects against the subject residual.

Effect sizes: partial eta squared SS_effect / (SS_effect + SS_error) = F df1 / (F df1 + df2) for
the ANOVAs (for ART, of the ranks, as in the ARTool effect-size vignette); the matched-pairs
rank-biserial correlation for the signed-rank test. Every function validates its input and
raises :class:`~rapidds.errors.StudyDataError` with one line that says what is wrong.
"""

from __future__ import annotations

import itertools
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
RANK_DIGITS = 8
"""Aligned responses are rounded to this many decimals before ranking, so that values equal up to
floating-point noise tie (ARTool rounds to the same 8 digits, from sqrt of double epsilon)."""


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


# --- aligned rank transform ---------------------------------------------------------------------


@dataclass(frozen=True)
class ArtResult:
    """Result of :func:`art_anova`.

    ``table``: one row per effect, the ANOVA on the ranks aligned for that effect (only that
    effect's row of each ANOVA), columns :data:`EFFECT_COLUMNS` and ``error`` (the stratum its
    F is tested in: ``subject``, ``within`` or ``residual``). ``aligned`` and ``ranks``: one
    column per effect. The alignment check (Wobbrock et al. 2011): ``aligned_sums`` are the
    column sums of the aligned responses and ``aligned_f`` the F of every *other* effect in an
    ANOVA of the aligned (unranked) responses (row = effect aligned for); both should be ~0.
    """

    table: pd.DataFrame
    aligned: pd.DataFrame
    ranks: pd.DataFrame
    aligned_sums: pd.Series
    aligned_f: pd.DataFrame

    def alignment_ok(self, tol: float = 1e-6) -> bool:
        """Whether the alignment stripped every effect but its own (sums and F within tol)."""
        scale = max(1.0, float(np.abs(self.aligned.to_numpy()).max()) * len(self.aligned))
        f = self.aligned_f.to_numpy().ravel()
        f = f[~np.isnan(f)]  # the diagonal, and 0/0 when an aligned response has no error at all
        sums_ok = bool((self.aligned_sums.abs() <= tol * scale).all())
        return sums_ok and (f.size == 0 or float(np.abs(f).max()) <= tol)


class _Factorial:
    """A validated balanced factorial layout: integer codes per factor and per subject, and the
    marginal means of any response over any subset of factors."""

    def __init__(
        self,
        df: pd.DataFrame,
        factors: Sequence[str],
        subject: str | None,
        between: Sequence[str],
        what: str,
    ) -> None:
        self.factors = tuple(factors)
        self.between = tuple(between)
        self.within = tuple(f for f in factors if f not in between)
        self.n = len(df)
        codes, levels = [], []
        for f in self.factors:
            c, u = pd.factorize(df[f], sort=True)
            if len(u) < 2:
                raise StudyDataError(f"{what}: factor '{f}' has one level ({u[0]}); needs >= 2")
            codes.append(c)
            levels.append(len(u))
        self.codes = dict(zip(self.factors, codes, strict=True))
        self.levels = dict(zip(self.factors, levels, strict=True))
        self._cache: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}
        cell, _ = self._index(self.factors)
        ncells = int(np.prod(levels))
        per_cell = np.bincount(cell, minlength=ncells)
        if (per_cell == 0).any() or (per_cell != per_cell[0]).any():
            raise StudyDataError(
                f"{what}: unbalanced design: {per_cell.min()} to {per_cell.max()} rows per cell "
                f"of {' x '.join(self.factors)} ({ncells} cells); ART needs equal counts"
            )
        self.subject: np.ndarray | None = None
        if subject is None:
            if (per_cell < 2).any():
                raise StudyDataError(
                    f"{what}: one row per cell leaves no error term; needs replicates or a subject"
                )
            return
        s, subjects = pd.factorize(df[subject], sort=True)
        self.subject, self.n_subjects = s, len(subjects)
        if self.between:
            b_cell, _ = self._index(self.between)
            per_subject = pd.Series(b_cell).groupby(s).nunique()
            if (per_subject > 1).any():
                who = subjects[per_subject.index[per_subject > 1][0]]
                raise StudyDataError(
                    f"{what}: {subject} {who} changes level of a between factor "
                    f"({', '.join(self.between)})"
                )
        w_cell, _ = self._index(self.within)
        n_within = int(np.prod([self.levels[f] for f in self.within])) if self.within else 1
        seen = np.zeros((self.n_subjects, n_within), dtype=int)
        np.add.at(seen, (s, w_cell), 1)
        bad = np.flatnonzero((seen != 1).any(axis=1))
        if bad.size:
            cells = " x ".join(self.within) or "the design"
            problem = (
                f"lacks a cell of {cells}"
                if (seen[bad[0]] == 0).any()
                else f"has several rows in a cell of {cells}; average them first"
            )
            raise StudyDataError(
                f"{what}: {subject} {subjects[bad[0]]} {problem} (one row per cell needed)"
            )
        if self.between:
            n_between = int(np.prod([self.levels[f] for f in self.between]))
            if self.n_subjects <= n_between:
                raise StudyDataError(
                    f"{what}: {self.n_subjects} subjects in {n_between} between-subject cells "
                    "leave no subject error term"
                )
        elif self.n_subjects < 2:
            raise StudyDataError(f"{what}: needs at least 2 subjects")

    def _index(self, subset: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Combined code of the factors in ``subset`` per row, and the rows per code."""
        if subset not in self._cache:
            if not subset:
                code = np.zeros(self.n, dtype=np.intp)
            else:
                code = np.ravel_multi_index(
                    [self.codes[f] for f in subset], [self.levels[f] for f in subset]
                )
            self._cache[subset] = (code, np.bincount(code))
        return self._cache[subset]

    def effects(self) -> list[tuple[str, ...]]:
        """Every main effect and interaction, main effects first (R's order)."""
        k_max = len(self.factors)
        return [e for k in range(1, k_max + 1) for e in itertools.combinations(self.factors, k)]

    def marginal(self, y: np.ndarray, subset: tuple[str, ...]) -> np.ndarray:
        code, counts = self._index(subset)
        return (np.bincount(code, weights=y, minlength=len(counts)) / counts)[code]

    def estimated_effect(self, y: np.ndarray, effect: tuple[str, ...]) -> np.ndarray:
        """The effect's estimate per row by inclusion-exclusion of marginal means (Wobbrock et
        al. 2011; e.g. A:B = mean_AB - mean_A - mean_B + grand mean)."""
        total = np.zeros(self.n)
        for k in range(len(effect) + 1):
            for sub in itertools.combinations(effect, k):
                total += (-1) ** (len(effect) - k) * self.marginal(y, sub)
        return total

    def anova(self, y: np.ndarray) -> pd.DataFrame:
        """Sums of squares by orthogonal projection (exact for balanced complete data), each
        effect tested in its stratum: effects of between factors only against subjects within
        between cells, all others against the within-subject residual (R ``Error(subject)``)."""
        grand = y.mean()
        ss_total = float(((y - grand) ** 2).sum())
        rows = {}
        for e in self.effects():
            ss = float((self.estimated_effect(y, e) ** 2).sum())
            df = int(np.prod([self.levels[f] - 1 for f in e]))
            rows[e] = (ss, df)
        if self.subject is None:
            ss_err = ss_total - sum(ss for ss, _ in rows.values())
            df_err = self.n - int(np.prod(list(self.levels.values())))
            errors = {e: ("residual", ss_err, df_err) for e in rows}
        else:
            s = self.subject
            subj_mean = (np.bincount(s, weights=y) / np.bincount(s))[s]
            ss_subjects = float(((subj_mean - grand) ** 2).sum())
            between_only = [e for e in rows if set(e) <= set(self.between)]
            n_between = int(np.prod([self.levels[f] for f in self.between])) if self.between else 1
            ss_subj_err = ss_subjects - sum(rows[e][0] for e in between_only)
            df_subj_err = self.n_subjects - n_between
            within_effects = [e for e in rows if e not in between_only]
            ss_within_err = ss_total - ss_subjects - sum(rows[e][0] for e in within_effects)
            df_within_err = self.n - self.n_subjects - sum(rows[e][1] for e in within_effects)
            errors = {
                e: ("subject", ss_subj_err, df_subj_err)
                if e in between_only
                else ("within", ss_within_err, df_within_err)
                for e in rows
            }
        records = []
        for e, (ss, df1) in rows.items():
            stratum, ss_err, df2 = errors[e]
            ss_err = max(ss_err, 0.0)  # rounding can leave -1e-12 when the error is exactly 0
            f = _f_ratio(ss / df1, ss_err / df2)
            records.append(
                {
                    "effect": ":".join(e),
                    "F": f,
                    "df1": float(df1),
                    "df2": float(df2),
                    "p": float(stats.f.sf(f, df1, df2)) if np.isfinite(f) else float("nan"),
                    "partial_eta_sq": ss / (ss + ss_err) if ss + ss_err > 0 else float("nan"),
                    "error": stratum,
                }
            )
        return pd.DataFrame.from_records(records).set_index("effect")


def _f_ratio(ms: float, ms_err: float) -> float:
    if ms_err > 0:
        return ms / ms_err
    return float("inf") if ms > 0 else float("nan")


def art_anova(
    df: pd.DataFrame,
    dv: str,
    factors: Sequence[str],
    subject: str | None = "participant",
    *,
    between: Sequence[str] = (),
) -> ArtResult:
    """Aligned rank transform ANOVA (Wobbrock, Findlater, Gergle & Higgins 2011).

    For each effect: align (response minus its cell mean over all ``factors``, plus the
    effect's estimate), rank with average ties, ANOVA the ranks, keep only that effect's row.
    ``factors`` are the fixed factors (all interactions are modelled); ``between`` names those
    that vary between subjects (the rest vary within); ``subject=None`` means every row is its
    own unit (all factors between). The design must be balanced and complete: equal rows per
    cell, and with a subject exactly one row per subject and within-subject cell.
    """
    what = "ART ANOVA"
    if isinstance(factors, str) or not factors:
        raise StudyDataError(f"{what}: factors must be a non-empty list of column names")
    if len(set(factors)) != len(factors):
        raise StudyDataError(f"{what}: a factor is named twice in {list(factors)}")
    if isinstance(between, str):
        raise StudyDataError(f"{what}: between must be a list of column names")
    stray = [b for b in between if b not in factors]
    if stray:
        raise StudyDataError(f"{what}: between factor(s) {stray} are not among factors")
    if subject is None and between:
        raise StudyDataError(
            f"{what}: without a subject every factor is between-subject; leave between empty"
        )
    if subject is not None and subject in factors:
        raise StudyDataError(f"{what}: the subject column '{subject}' cannot also be a factor")
    cols = [dv, *factors] + ([subject] if subject is not None else [])
    _require(df, cols, what)
    y = _numeric(df, dv, what)
    layout = _Factorial(df, factors, subject, between, what)
    residual = y - layout.marginal(y, layout.factors)
    names = [":".join(e) for e in layout.effects()]
    aligned = pd.DataFrame(
        {":".join(e): residual + layout.estimated_effect(y, e) for e in layout.effects()},
        index=df.index,
    )
    ranks = aligned.apply(lambda col: stats.rankdata(np.round(col.to_numpy(), RANK_DIGITS)))
    rows, checks = [], {}
    for name in names:
        rows.append(layout.anova(ranks[name].to_numpy()).loc[name])
        f_aligned = layout.anova(aligned[name].to_numpy())["F"]
        checks[name] = f_aligned.where(f_aligned.index != name)
    table = pd.DataFrame(rows)
    table.index.name = "effect"
    return ArtResult(
        table=table[[*EFFECT_COLUMNS, "error"]],
        aligned=aligned,
        ranks=ranks,
        aligned_sums=aligned.sum().rename("aligned_sum"),
        aligned_f=pd.DataFrame(checks).T.rename_axis(index="aligned_for", columns="effect"),
    )


def art_by_item(
    survey: pd.DataFrame,
    *,
    item: str = "item",
    response: str = "response",
    subject: str = "participant",
    system: str = "system",
    adaptation: Mapping[str, tuple[bool, bool]] = ADAPTATION,
) -> pd.DataFrame:
    """ART ANOVA (spatial x temporal, within-subject) of every survey item.

    ``survey``: one row per participant, system and item. Returns one row per (item, effect)
    with :data:`EFFECT_COLUMNS` and the alignment check's verdict ``alignment_ok``.
    """
    what = "survey ART"
    _require(survey, [item, response, subject, system], what)
    data = adaptation_factors(survey, system, adaptation)
    frames = []
    for name, g in data.groupby(item, sort=False):
        _one_per_system(g, subject, system, list(adaptation), f"{what} (item {name!r})")
        try:
            res = art_anova(g, response, list(ANALYSIS_FACTORS), subject)
        except StudyDataError as exc:
            raise StudyDataError(f"{what} (item {name!r}): {exc}") from None
        frames.append(
            res.table[list(EFFECT_COLUMNS)].assign(alignment_ok=res.alignment_ok(), **{item: name})
        )
    return pd.concat(frames).reset_index().set_index([item, "effect"])
