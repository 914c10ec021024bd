"""The aligned rank transform ANOVA of the user study's survey items (Wobbrock et al. 2011).

* :func:`art_anova`: the aligned rank transform for factorial designs with subjects, then an
  ANOVA on the ranks with the subject error stratum (R: ``aov(y ~ A*B + Error(S))``), which for
  balanced complete data gives the F of ARTool's default mixed model ``art(y ~ A*B + (1|S))``.
  Within-subject effects are tested against the pooled within-subject residual, between-subject
  effects against the subject residual.
* :func:`art_by_item`: that ANOVA (spatial x temporal adaptation) of every survey item.

Effect sizes: partial eta squared of the ranks, as in the ARTool effect-size vignette. Every
function validates its input and raises :class:`~rapidds.errors.StudyDataError` with one line
that says what is wrong.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from rapidds.errors import StudyDataError
from rapidds.experiments.study.stats import (
    EFFECT_COLUMNS,
    _numeric,
    _one_per_system,
    _require,
    adaptation_factors,
)
from rapidds.experiments.study.systems import ADAPTATION, ANALYSIS_FACTORS

__all__ = ["RANK_DIGITS", "ArtResult", "art_anova", "art_by_item"]

RANK_DIGITS = 8
"""Aligned responses are rounded to this many decimals before ranking, so that values equal up to
floating-point noise tie (ARTool rounds to the same 8 digits, from sqrt of double epsilon)."""


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
