"""The user study's analyses: published ART results, independent libraries, planted effects."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pingouin as pg
import pytest
import statsmodels.formula.api as smf
from scipy import stats
from statsmodels.stats.anova import AnovaRM, anova_lm

from rapidds.errors import RapiddsError, StudyDataError
from rapidds.experiments.study import (
    SYSTEMS,
    art_anova,
    art_by_item,
    cost_reduction,
    planted_costs,
    planted_likert,
    planted_rankings,
    ranking_test,
    rankings_from_orders,
    rejection_rates,
    rm_anova_2x2,
)

DATA = Path(__file__).parent / "data"
N = 32  # participants, as in the paper
REPLICATES = 200
ALPHA = 0.05


def null_band(trials: int, alpha: float = ALPHA, tail: float = 5e-4) -> tuple[int, int]:
    """Rejection counts a level-alpha test stays within with probability 1 - 2 * tail."""
    return int(stats.binom.ppf(tail, trials, alpha)), int(stats.binom.isf(tail, trials, alpha))


# --- ART against published results -------------------------------------------------------------


@pytest.fixture(scope="module")
def higgins5() -> pd.DataFrame:
    return pd.read_csv(DATA / "higgins1990_table5.csv", comment="#")


def test_art_reproduces_artool_on_higgins1990_table5(higgins5):
    """Split-plot: Moisture between trays, Fertilizer within. Published by ARTool (test suite:
    "matches results of the original ARTool"; README for the p values)."""
    res = art_anova(higgins5, "DryMatter", ["Moisture", "Fertilizer"], "Tray", between=["Moisture"])
    t = res.table
    assert list(t.index) == ["Moisture", "Fertilizer", "Moisture:Fertilizer"]
    assert t["F"].round(4).tolist() == [23.8326, 122.4017, 5.1180]
    assert t["df1"].tolist() == [3, 3, 9] and t["df2"].tolist() == [8, 24, 24]
    assert t["error"].tolist() == ["subject", "within", "within"]
    assert f"{t.loc['Moisture', 'p']:.7f}" == "0.0002420"
    assert f"{t.loc['Fertilizer', 'p']:.3e}" == "1.112e-14"
    assert f"{t.loc['Moisture:Fertilizer', 'p']:.7f}" == "0.0006466"
    # ARTool's summary: column sums of aligned responses and F of effects not of interest ~0
    assert res.alignment_ok()
    assert res.aligned_sums.abs().max() < 1e-9
    assert np.nanmax(res.aligned_f.to_numpy()) < 1e-20
    assert res.ranks.shape == (48, 3) and np.isclose(res.ranks.sum().iloc[0], 48 * 49 / 2)


def test_art_mixed_and_between_paths_match_pingouin(higgins5):
    """The ANOVA on the aligned ranks equals pingouin's mixed and two-way between ANOVAs."""
    mixed = art_anova(higgins5, "DryMatter", ["Moisture", "Fertilizer"], "Tray",
                      between=["Moisture"])
    between = art_anova(higgins5, "DryMatter", ["Moisture", "Fertilizer"], None)
    for k, effect in enumerate(["Moisture", "Fertilizer", "Moisture:Fertilizer"]):
        data = higgins5.assign(r=mixed.ranks[effect])
        ref = pg.mixed_anova(data, dv="r", within="Fertilizer", between="Moisture",
                             subject="Tray")
        assert mixed.table.loc[effect, "F"] == pytest.approx(ref["F"][k], rel=1e-10)
        assert mixed.table.loc[effect, "partial_eta_sq"] == pytest.approx(ref["np2"][k], rel=1e-9)
        data = higgins5.assign(r=between.ranks[effect])
        ref = pg.anova(data, dv="r", between=["Moisture", "Fertilizer"])
        assert between.table.loc[effect, "F"] == pytest.approx(ref["F"][k], rel=1e-10)
        assert between.table.loc[effect, "df2"] == ref["DF"].iloc[-1]


def test_art_within_path_matches_ols_with_subject_error_stratum():
    """Two within factors: each aligned-rank F equals OLS rank ~ participant + A*B (pooled
    within-subject residual, the random-intercept model's F for balanced data)."""
    data = planted_likert(np.random.default_rng(5), 0.8)
    res = art_anova(data, "response", ["spatial", "temporal"], "participant")
    assert res.table["error"].eq("within").all()
    assert res.table["df2"].eq(3 * (N - 1)).all()
    assert res.alignment_ok()
    for effect, term in [("spatial", "C(spatial)"), ("temporal", "C(temporal)"),
                         ("spatial:temporal", "C(spatial):C(temporal)")]:
        fit = smf.ols("r ~ C(participant) + C(spatial) * C(temporal)",
                      data=data.assign(r=res.ranks[effect])).fit()
        ref = anova_lm(fit, typ=2)
        assert res.table.loc[effect, "F"] == pytest.approx(ref.loc[term, "F"], rel=1e-9)
        assert res.table.loc[effect, "p"] == pytest.approx(ref.loc[term, "PR(>F)"], rel=1e-7)


def test_art_alignment_by_hand():
    """2 x 2 between, 2 per cell: aligned = y - cell mean + estimated effect; average ties."""
    df = pd.DataFrame({"a": list("xxxxyyyy"), "b": list("ppqqppqq"),
                       "y": [1.0, 3.0, 2.0, 6.0, 5.0, 5.0, 9.0, 7.0]})
    res = art_anova(df, "y", ["a", "b"], None)
    cell = df.groupby(["a", "b"])["y"].transform("mean")
    ma, mb, grand = (df.groupby("a")["y"].transform("mean"), df.groupby("b")["y"].transform("mean"),
                     df["y"].mean())
    np.testing.assert_allclose(res.aligned["a"], df["y"] - cell + ma - grand)
    np.testing.assert_allclose(res.aligned["b"], df["y"] - cell + mb - grand)
    np.testing.assert_allclose(res.aligned["a:b"], df["y"] - cell + cell - ma - mb + grand)
    # residuals -1, 1, -2, 2, 0, 0, 1, -1; effect of b -1.25 (p), +1.25 (q): aligned for b
    # -2.25, -0.25, -0.75, 3.25, -1.25, -1.25, 2.25, 0.25 -> the tie shares ranks 2 and 3
    np.testing.assert_allclose(res.aligned["b"], [-2.25, -0.25, -0.75, 3.25, -1.25, -1.25, 2.25,
                                                  0.25])
    assert res.ranks["b"].tolist() == [1.0, 5.0, 4.0, 8.0, 2.5, 2.5, 7.0, 6.0]


def test_art_by_item_runs_every_item():
    rng = np.random.default_rng(11)
    fluent = planted_likert(rng, 1.5).assign(item="fluent")
    noise = planted_likert(rng, 0.0).assign(item="noise")
    table = art_by_item(pd.concat([fluent, noise]))
    assert table.index.names == ["item", "effect"] and len(table) == 6
    assert table.loc[("fluent", "spatial"), "p"] < 1e-6
    assert table["alignment_ok"].all()


# --- parametric RM ANOVA, cost reduction ---------------------------------------------------------


def test_rm_anova_2x2_matches_statsmodels_anovarm():
    data = planted_costs(np.random.default_rng(3), 0.5)
    t = rm_anova_2x2(data, "y")
    assert list(t.index) == ["spatial", "temporal", "spatial:temporal"]
    ref = AnovaRM(data.assign(spatial=data["spatial"].astype(str),
                              temporal=data["temporal"].astype(str)),
                  "y", "participant", within=["spatial", "temporal"]).fit().anova_table
    np.testing.assert_allclose(t["F"], ref["F Value"], rtol=1e-9)
    np.testing.assert_allclose(t["p"], ref["Pr > F"], rtol=1e-7)
    assert t["df1"].eq(1).all() and t["df2"].eq(N - 1).all()
    np.testing.assert_allclose(t["partial_eta_sq"], t["F"] / (t["F"] + t["df2"]), rtol=1e-9)


def test_cost_reduction_is_first_round_minus_mean_of_last_three():
    rows = [
        {"participant": p, "system": s, "round": r, "spatial_cost": 10.0 * r + k,
         "temporal_cost": 100.0 - r}
        for k, p in enumerate(["P1", "P2"]) for s in SYSTEMS for r in range(1, 8)
    ]
    df = pd.DataFrame(rows).sample(frac=1.0, random_state=0)  # order must not matter
    out = cost_reduction(df)
    assert list(out.columns) == ["participant", "system", "spatial_cost_reduction",
                                 "temporal_cost_reduction"]
    assert len(out) == 8
    # spatial: 10 + k - mean(50, 60, 70) - k = -50; temporal: 99 - mean(95, 94, 93) = 5
    assert np.allclose(out["spatial_cost_reduction"], -50.0)
    assert np.allclose(out["temporal_cost_reduction"], 5.0)


# --- ranking ------------------------------------------------------------------------------------


def test_ranking_test_by_hand_and_against_pingouin():
    orders = {
        "P1": ["full", "spatial", "temporal", "none"],  # difference 3.5 - 1.5 = 2
        "P2": ["spatial", "none", "full", "temporal"],  # (2 + 4) / 2 - (3 + 1) / 2 = 1
        "P3": ["none", "full", "spatial", "temporal"],  # (1 + 4) / 2 - (2 + 3) / 2 = 0
        "P4": ["temporal", "full", "none", "spatial"],  # (1 + 3) / 2 - (2 + 4) / 2 = -1
        "P5": ["full", "temporal", "spatial", "none"],  # (2 + 4) / 2 - (1 + 3) / 2 = 1
    }
    res = ranking_test(rankings_from_orders(orders))
    assert res.difference.to_dict() == {"P1": 2.0, "P2": 1.0, "P3": 0.0, "P4": -1.0, "P5": 1.0}
    assert (res.n, res.n_zero) == (4, 1)
    # |d| = 2, 1, 1, 1 -> ranks 4, 2, 2, 2; R+ = 8, R- = 2; r = 6 / 10
    assert res.r == pytest.approx(0.6)
    assert res.statistic == 2.0
    ref = pg.wilcoxon(res.difference[res.difference != 0].to_numpy())
    assert res.r == pytest.approx(ref["RBC"].iloc[0])
    assert res.mean_rank["full"] == pytest.approx((1 + 3 + 2 + 2 + 1) / 5)
    assert res.distribution.loc["full"].tolist() == [2, 2, 1, 0]
    assert res.distribution.sum(axis=1).eq(5).all() and res.distribution.sum().eq(5).all()


def test_ranking_test_no_preference_at_all():
    orders = {f"P{i}": ["full", "none", "temporal", "spatial"] for i in range(4)}
    res = ranking_test(rankings_from_orders(orders))
    assert (res.p, res.r, res.n, res.n_zero) == (1.0, 0.0, 0, 4)


# --- planted effects ----------------------------------------------------------------------------


def test_planted_spatial_effect_on_costs_is_found_and_nulls_hold():
    """delta = 0.7 noise sd: the spatial contrast is a one-sample t test with d = 0.7 and n = 32,
    designed power 0.97 (pingouin.power_ttest; 0.968 over 2,000 simulated studies in
    docs/benchmarks.md, where the null effects are rejected at 0.046 and 0.054)."""
    assert pg.power_ttest(d=0.7, n=N, contrast="one-sample") > 0.95
    rates = rejection_rates(lambda rng: rm_anova_2x2(planted_costs(rng, 0.7), "y")["p"],
                            REPLICATES, seed=10_000)
    assert rates[0] > 0.8
    lo, hi = null_band(2 * REPLICATES)
    assert lo <= round(rates[1:].sum() * REPLICATES) <= hi, rates


def test_ranking_test_power_and_level():
    """beta = 0.8: designed power 0.96; level 0.042, slightly conservative from the continuity
    correction (2,000 simulated studies each, docs/benchmarks.md)."""
    power = rejection_rates(lambda rng: ranking_test(planted_rankings(rng, 0.8)).p,
                            REPLICATES, seed=20_000)
    level = rejection_rates(lambda rng: ranking_test(planted_rankings(rng, 0.0)).p,
                            REPLICATES, seed=30_000)
    assert power[0] > 0.8
    lo, hi = null_band(REPLICATES)
    assert lo <= round(level[0] * REPLICATES) <= hi, level


def test_art_finds_planted_spatial_effect_on_likert_answers_and_nulls_hold():
    """delta = 0.7 on the latent scale of 7-point answers: designed power 0.96, temporal and
    interaction rejected at 0.040 and 0.053 (2,000 simulated studies, docs/benchmarks.md)."""
    rates = rejection_rates(
        lambda rng: art_anova(planted_likert(rng, 0.7), "response", ["spatial", "temporal"],
                              "participant").table["p"],
        REPLICATES, seed=40_000,
    )
    assert rates[0] > 0.8
    lo, hi = null_band(2 * REPLICATES)
    assert lo <= round(rates[1:].sum() * REPLICATES) <= hi, rates


# --- bad input ----------------------------------------------------------------------------------


def test_bad_cost_tables_are_refused():
    good = pd.DataFrame([{"participant": "P1", "system": s, "round": r, "spatial_cost": 1.0,
                          "temporal_cost": 2.0} for s in SYSTEMS for r in range(1, 8)])
    cases = [
        (good.drop(columns="round"), "missing column"),
        (good.assign(spatial_cost=np.where(good["round"] == 3, np.nan, 1.0)), "missing values"),
        (pd.concat([good, good.iloc[[0]]]), "round 1 twice"),
        (good[~((good["system"] == "none") & (good["round"] == 4))], "has rounds"),
        (good[good["round"] <= 3], "at least 4 rounds"),
        (good.assign(round=good["round"] + 0.5), "whole round"),
        (good.assign(spatial_cost="high"), "numeric"),
    ]
    for frame, message in cases:
        with pytest.raises(StudyDataError, match=message):
            cost_reduction(frame)
    with pytest.raises(StudyDataError, match="DataFrame"):
        cost_reduction([1, 2, 3])  # type: ignore[arg-type]


def test_bad_anova_tables_are_refused():
    data = planted_costs(np.random.default_rng(0), 0.0)
    with pytest.raises(StudyDataError, match="P00 needs exactly one row per system \\(none x0\\)"):
        rm_anova_2x2(data.drop(index=3), "y")
    with pytest.raises(StudyDataError, match="unknown system"):
        rm_anova_2x2(data.replace({"system": {"none": "nothing"}}), "y")
    with pytest.raises(StudyDataError, match="missing values"):
        rm_anova_2x2(data.assign(y=np.where(data.index == 5, np.nan, data["y"])), "y")
    with pytest.raises(StudyDataError, match="missing column"):
        rm_anova_2x2(data, "cost")


def test_bad_art_tables_are_refused(higgins5):
    data = planted_likert(np.random.default_rng(1), 0.0)
    f = ["spatial", "temporal"]
    cases = [
        (lambda: art_anova(data.iloc[1:], "response", f, "participant"), "unbalanced"),
        (lambda: art_anova(pd.concat([data, data]), "response", f, "participant"),
         "P00 has several rows in a cell of spatial x temporal; average them first"),
        (lambda: art_anova(data.iloc[:4], "response", f, None), "one row per cell leaves no error"),
        (lambda: art_anova(data.iloc[:8], "response", f, "participant", between=["spatial"]),
         "changes level"),
        (lambda: art_anova(data, "response", ["spatial"], "participant", between=["temporal"]),
         "not among factors"),
        (lambda: art_anova(data, "response", f, None, between=["spatial"]), "without a subject"),
        (lambda: art_anova(data, "response", ["participant"], "participant"), "cannot also be"),
        (lambda: art_anova(data, "response", "spatial", "participant"), "non-empty list"),
        (lambda: art_anova(data, "response", ["spatial", "spatial"], "participant"),
         "named twice"),
        (lambda: art_anova(data[data["spatial"]], "response", f, "participant"), "one level"),
        (lambda: art_anova(data, "system", f, "participant"), "numeric"),
        (lambda: art_anova(data.iloc[:4].assign(participant=["a", "a", "b", "b"]), "response", f,
                           "participant", between=["spatial"]),
         "2 subjects in 2 between-subject cells leave no subject error"),
        (lambda: art_anova(higgins5.iloc[:8], "DryMatter", ["Moisture", "Fertilizer"], "Tray",
                           between=["Moisture"]), "one level"),
    ]
    for call, message in cases:
        with pytest.raises(StudyDataError, match=message) as exc:
            call()
        assert isinstance(exc.value, RapiddsError) and "\n" not in str(exc.value)


def test_bad_rankings_are_refused():
    good = rankings_from_orders({"P1": list(SYSTEMS), "P2": list(reversed(SYSTEMS))})
    cases = [
        (good.assign(rank=good["rank"].replace({4: 3})), "permutation of \\[1, 2, 3, 4\\]"),
        (good.replace({"system": {"none": "spatial"}}), "name each of"),
        (good.iloc[:-1], "name each of"),
        (good.assign(rank=good["rank"] * 1.5), "whole ranks"),
        (good[good["participant"] == "P1"], "at least 2 participants"),
        (good.drop(columns="rank"), "missing column"),
    ]
    for frame, message in cases:
        with pytest.raises(StudyDataError, match=message):
            ranking_test(frame)


def test_no_warnings_from_the_analyses(higgins5):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        art_anova(higgins5, "DryMatter", ["Moisture", "Fertilizer"], "Tray", between=["Moisture"])
        rm_anova_2x2(planted_costs(np.random.default_rng(2), 0.3), "y")
        ranking_test(planted_rankings(np.random.default_rng(2), 0.3))
