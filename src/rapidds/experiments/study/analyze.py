"""The paper's user-study analyses on whatever a study store holds, real or simulated.

Objective measures, per round (the paper's two objectives, on what really happened):

* **temporal cost**: the round's realised makespan (s), the paper's temporal objective on the
  realised timeline (the person's actual durations, precedence and waits as they happened);
* **spatial cost**: the round's realised spatial cost, the paper's spatial objective: the sum over
  the robot's tasks of the largest S_i(xi_j^r) over the person's tasks that really overlapped it,
  S taken against the person's actual path in that round (:func:`rapidds.loop.deploy.deploy`),
  not the planner's belief.

Per participant x system the measure is the **reduction**: first round minus the mean of the last
three (positive = the cost fell), tested by a two-way repeated-measures ANOVA (spatial adaptation
x temporal adaptation). Ranking: Wilcoxon signed-rank (paired within participants; see
:func:`.stats.ranking_test`). Survey: ART ANOVA per item. Comfort (a study that asked the comfort
item): the learned gamma against the stated comfort (:mod:`.comfort`). Any analysis without
its data (no complete participant, no ranking, no survey answers: simulated participants give
none) is skipped with a statement saying so, never filled in.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from rapidds.experiments.study.art import art_by_item
from rapidds.experiments.study.comfort import comfort_section, comfort_table
from rapidds.experiments.study.stats import (
    cost_reduction,
    ranking_test,
    rankings_from_orders,
    rm_anova_2x2,
)
from rapidds.experiments.study.store import StudyStore, study_path
from rapidds.experiments.study.systems import ADAPTATION, ANALYSIS_FACTORS, adapts
from rapidds.fileio import atomic_write_text

if TYPE_CHECKING:
    from rapidds.experiments.study.design import StudyDesign
    from rapidds.experiments.study.store import Participant, SurveyItems
    from rapidds.loop.config import RunConfig

__all__ = ["COSTS", "Analysis", "analyze_study", "round_table"]

COSTS: tuple[tuple[str, str], ...] = (("spatial_cost", "spatial cost"),
                                      ("temporal_cost", "temporal cost (makespan, s)"))
LAST = 3
"""Rounds averaged at the end (the paper: the final three)."""
PAPER = {"spatial_cost_reduction": ("spatial", 0.001),
         "temporal_cost_reduction": ("temporal", 0.005)}
"""The paper's objective claims: this adaptation lowers this cost, at p below this."""


@dataclass
class Analysis:
    """summary: JSON-safe results; report: report.md's text; files: what was written."""

    summary: dict[str, Any]
    report: str
    files: list[Path] = field(default_factory=list)


def round_table(store: StudyStore) -> pd.DataFrame:
    """One row per stored round: participant, group, priming factors, system, block, round
    (0-based), spatial_cost, temporal_cost."""
    runs = store.study_runs().set_index("run_id")
    people = {p.id: p for p in store.participants()}
    factors = list(store.design.factors)
    rows = []
    for r in store.cycle_records():
        if r.run_id not in runs.index:
            continue
        who, system, block = runs.loc[r.run_id, ["participant", "system", "block"]]
        p = people[who]
        rows.append({"participant": who, "group": p.group, **p.factors, "system": system,
                     "block": int(block), "round": int(r.cycle),
                     "spatial_cost": float(r.realised.spatial),
                     "temporal_cost": float(r.realised.makespan)})
    cols = ["participant", "group", *factors, "system", "block", "round", "spatial_cost",
            "temporal_cost"]
    return pd.DataFrame.from_records(rows, columns=cols)


def _num(x: float | None) -> str:
    return "(the world's)" if x is None else f"{x:g}"


def _fmt_p(p: float) -> str:
    return "< .001" if p < 0.001 else f"{p:.3f}".lstrip("0")


def _anova_rows(table: pd.DataFrame) -> list[dict[str, Any]]:
    return [{"effect": str(e), **{k: float(v) for k, v in row.items() if k != "error"}}
            for e, row in table.iterrows()]


def _md_anova(title: str, rows: list[dict[str, Any]]) -> list[str]:
    out = [f"**{title}**", "", "| effect | F | df | p | partial eta^2 |", "|---|---|---|---|---|"]
    out += [f"| {r['effect']} | {r['F']:.2f} | {r['df1']:g}, {r['df2']:g} | {_fmt_p(r['p'])} | "
            f"{r['partial_eta_sq']:.3f} |" for r in rows]
    return [*out, ""]


def analyze_study(folder: str | Path) -> Analysis:
    """Run every analysis the stored data allows; write report.md, summary.json and the figures
    into ``folder``."""
    folder = Path(folder)
    with StudyStore.open_readonly(study_path(folder)) as store:
        design, run, items = store.design, store.base_config, store.items
        participants = store.participants()
        rounds = round_table(store)
        rankings = store.rankings()
        survey = store.survey_frame()
        comfort = comfort_table(store) if design.comfort else None
        failed = {rid: str(f.get("reason")) for rid, f in store.failures().items()}
    systems = list(design.systems)
    s, md = _design_section(design, run, systems)
    if failed:  # simulated runs that failed (kept by simulate): counted, left out
        s["runs_failed"] = failed
        md += [f"{len(failed)} simulated run(s) failed and are left out (a rerun of simulate "
               "retries them):", "", *(f"- {rid}: {why}" for rid, why in sorted(failed.items())),
               ""]
    files: list[Path] = []
    for key, title, (part, lines, drawn) in (
            ("objective", "Objective measures",
             _objective_section(design, participants, rounds, systems, folder)),
            ("ranking", "Ranking", _ranking_section(rankings, systems, folder)),
            ("survey", "Survey", _survey_section(survey, items, systems, folder))):
        s[key] = part
        md += [f"## {title}", "", *lines]
        files += drawn
    if comfort is not None:  # only a study that asked the item: others' outputs stay as they were
        s["comfort"], lines = comfort_section(comfort, run.gamma_learn, design.seed)
        md += ["## Comfort and the learned gamma", "", *lines]
    report = "\n".join(md)
    s = _finite(s)
    atomic_write_text(folder / "report.md", report + "\n")
    atomic_write_text(folder / "summary.json", json.dumps(s, indent=1) + "\n")
    files[:0] = [folder / "report.md", folder / "summary.json"]
    return Analysis(s, report, files)


def _design_section(design: StudyDesign, run: RunConfig, systems: list[str]
                    ) -> tuple[dict[str, Any], list[str]]:
    """The summary's design, world and definitions, and the report's opening paragraphs."""
    s: dict[str, Any] = {
        "design": {"participants": design.participants, "systems": systems,
                   "rounds": design.rounds, "factors": {k: list(v) for k, v in
                                                        design.factors.items()},
                   "seed": design.seed, "balanced": design.balanced,
                   "order_rows": [list(r) for r in design.square()]},
        "world": {"world": run.world, "variant": run.variant, "gamma": run.gamma,
                  "lam": run.lam},
        "definitions": {
            "temporal_cost": "realised makespan of the round (s)",
            "spatial_cost": "realised spatial cost of the round: sum over robot tasks of the "
                            "max S_i over the person's tasks that overlapped it, against the "
                            "person's actual paths",
            "reduction": f"first round minus mean of the last {LAST} (positive: cost fell)"},
    }
    md = ["# User study analysis", "",
          f"Design: {design.participants} participants, systems {', '.join(systems)} "
          f"(Williams order rows: {len(design.square())}), {design.rounds} rounds each, priming "
          f"groups {', '.join(design.group_name(g) for g in design.groups())} "
          f"({'balanced' if design.balanced else 'NOT balanced'}), seed {design.seed}; world "
          f"{run.world} ({run.variant}), gamma {_num(run.gamma)}, lambda {_num(run.lam)} for the "
          "first half of the rounds.", "",
          "Measures: temporal cost = the round's realised makespan (s); spatial cost = the "
          "round's realised spatial cost (sum over robot tasks of the largest S_i over the "
          "person's tasks that overlapped it, against the person's actual paths). Reduction = "
          f"first round minus the mean of the last {LAST}; positive = the cost fell.", ""]
    return s, md


def _objective_section(design: StudyDesign, participants: Sequence[Participant],
                       rounds: pd.DataFrame, systems: list[str], folder: Path
                       ) -> tuple[dict[str, Any], list[str], list[Path]]:
    """Cost reductions per system and the rm-ANOVAs that test the paper's claims on them."""
    from rapidds.plots.study import plot_cost_reductions, plot_round_costs

    files: list[Path] = []
    md: list[str] = []
    done = rounds.groupby(["participant", "system"]).size()
    complete = [p.id for p in participants
                if all(done.get((p.id, sys_), 0) >= design.rounds for sys_ in p.systems)]
    part: dict[str, Any] = {"n": len(complete), "rounds_stored": len(rounds)}
    four = set(systems) == set(ADAPTATION)
    if len(complete) < 2 or design.rounds < LAST + 1:
        why = (f"{len(complete)} participant(s) have finished every system" if
               design.rounds >= LAST + 1 else f"{design.rounds} rounds < {LAST + 1}")
        md += [f"Not analysed: {why}; the analysis needs at least 2 and {LAST + 1} rounds.", ""]
        part["skipped"] = why
    else:
        data = rounds[rounds["participant"].isin(complete)]
        red = cost_reduction(data, [c for c, _ in COSTS], last=LAST)
        red = red.merge(data[["participant", "group"]].drop_duplicates(), on="participant")
        cols = [(f"{c}_reduction", f"{label} reduction") for c, label in COSTS]
        files.append(plot_cost_reductions(red, cols, systems, folder / "study_costs.png"))
        files.append(plot_round_costs(data, COSTS, systems, folder / "study_rounds.png"))
        means = red.groupby("system")[[c for c, _ in cols]].agg(["mean", "std"])
        part["reduction_by_system"] = {
            sys_: {c: {"mean": float(means.loc[sys_, (c, "mean")]),
                       "sd": float(means.loc[sys_, (c, "std")])} for c, _ in cols}
            for sys_ in systems}
        md += [f"n = {len(complete)} participants with every system finished "
               f"({len(participants) - len(complete)} not yet).", "",
               "| system | " + " | ".join(f"{label}, mean (sd)" for _, label in cols) + " |",
               "|---|" + "---|" * len(cols)]
        for sys_ in systems:
            md.append(f"| {sys_} | " + " | ".join(
                f"{means.loc[sys_, (c, 'mean')]:.3f} ({means.loc[sys_, (c, 'std')]:.3f})"
                for c, _ in cols) + " |")
        md.append("")
        if not four:
            md += [f"rm-ANOVA not run: it needs the four systems {', '.join(ADAPTATION)} "
                   f"(the 2 x 2 of {' x '.join(ANALYSIS_FACTORS)} adaptation).", ""]
        else:
            part["anova"] = {}
            part["claims"] = {}
            for (c, label), (_, cost) in zip(cols, COSTS, strict=True):
                cost = cost.split(" (")[0]
                rows = _anova_rows(rm_anova_2x2(red, c))
                part["anova"][c] = rows
                md += _md_anova(f"Two-way rm-ANOVA of the {label} (spatial x temporal "
                                "adaptation)", rows)
                factor, alpha = PAPER[c]
                row = next(r for r in rows if r["effect"] == factor)
                adaptive = red[red["system"].map(lambda x, f=factor: adapts(x, f))][c].mean()
                other = red[~red["system"].map(lambda x, f=factor: adapts(x, f))][c].mean()
                holds = bool(row["p"] < alpha and adaptive > other)
                part["claims"][c] = {
                    "claim": f"{factor} adaptation lowers the {cost} (paper p < {alpha:g})",
                    "p": row["p"], "F": row["F"], "mean_with": float(adaptive),
                    "mean_without": float(other), "holds": holds}
                md += [f"Paper: {factor} adaptation lowers the {cost}, "
                       f"p < {alpha:g}. Here: mean reduction {adaptive:.3f} with {factor} "
                       f"adaptation vs {other:.3f} without, F({row['df1']:g}, {row['df2']:g}) = "
                       f"{row['F']:.2f}, p {_fmt_p(row['p'])}: "
                       f"**{'holds' if holds else 'does not hold'}**.", ""]
    return part, md, files


def _ranking_section(rankings: pd.DataFrame, systems: list[str], folder: Path
                     ) -> tuple[dict[str, Any], list[str], list[Path]]:
    """The signed-rank test of the forced-choice rankings (spatial adaptation preferred?)."""
    from rapidds.plots.study import plot_ranking_distribution

    files: list[Path] = []
    md: list[str] = []
    part: dict[str, Any] = {"n": len(rankings)}
    spatial_split = len({adapts(x, "spatial") for x in systems}) == 2
    if len(rankings) < 2 or not spatial_split:
        why = (f"{len(rankings)} ranking(s) stored (simulated participants rank nothing)"
               if len(rankings) < 2 else "no systems both with and without spatial adaptation")
        md += [f"Not analysed: {why}.", ""]
        part["skipped"] = why
    else:
        test = ranking_test(rankings_from_orders(rankings), systems=systems)
        part.update(statistic=float(test.statistic), p=float(test.p), r=float(test.r),
                            n_nonzero=test.n, n_zero=test.n_zero,
                            mean_rank={k: float(v) for k, v in test.mean_rank.items()})
        files.append(plot_ranking_distribution(test.distribution.reindex(systems),
                                               folder / "study_ranking.png"))
        md += [f"n = {len(rankings)}. Wilcoxon signed-rank test, two-sided, on each "
               "participant's mean rank of the systems without spatial adaptation minus that of "
               "the systems with it (positive: spatial adaptation preferred). Signed-rank, not "
               "the paper's rank-sum: the four ranks of one participant are paired (they are "
               "not independent samples), and rank-sum would ignore that.", "",
               f"W = {test.statistic:g}, p {_fmt_p(test.p)}, matched-pairs rank-biserial r = "
               f"{test.r:.2f} ({test.n} nonzero differences, {test.n_zero} zero). Mean rank: "
               + ", ".join(f"{k} {v:.2f}" for k, v in test.mean_rank.items()) + ".", ""]
    return part, md, files


def _survey_section(survey: pd.DataFrame, items: SurveyItems, systems: list[str], folder: Path
                    ) -> tuple[dict[str, Any], list[str], list[Path]]:
    """The ART ANOVA of every survey item."""
    from rapidds.plots.study import plot_survey

    files: list[Path] = []
    md: list[str] = []
    four = set(systems) == set(ADAPTATION)
    n_items = len(items.ids)
    answered = survey.groupby("participant")["system"].nunique() if len(survey) else pd.Series()
    full = [p for p, k in answered.items() if k == len(systems)]
    part: dict[str, Any] = {"n": len(full), "items": list(items.ids)}
    if len(full) < 2 or not four:
        why = (f"{len(full)} participant(s) answered the survey about every system "
               "(simulated participants answer nothing)" if len(full) < 2 else
               f"ART needs the four systems {', '.join(ADAPTATION)} (a 2 x 2)")
        md += [f"Not analysed: {why}.", ""]
        part["skipped"] = why
    else:
        data = survey[survey["participant"].isin(full)]
        art = art_by_item(data, response="value")
        part["art"] = [
            {"item": str(i), "effect": str(e), **{k: (bool(v) if k == "alignment_ok" else
                                                      float(v)) for k, v in row.items()}}
            for (i, e), row in art.iterrows()]
        files.append(plot_survey(data, list(items.ids), systems, folder / "study_survey.png"))
        md += [f"n = {len(full)}; {n_items} items, 1-7. ART ANOVA per item (aligned rank "
               "transform, spatial x temporal adaptation within participants).", "",
               "| item | effect | F | df | p | partial eta^2 | alignment ok |",
               "|---|---|---|---|---|---|---|"]
        md += [f"| {r['item']} | {r['effect']} | {r['F']:.2f} | {r['df1']:g}, {r['df2']:g} | "
               f"{_fmt_p(r['p'])} | {r['partial_eta_sq']:.3f} | {r['alignment_ok']} |"
               for r in part["art"]]
        md.append("")
    return part, md, files


def _finite(obj: Any) -> Any:
    """NaN (e.g. an F of 0/0) as null: JSON has no NaN."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj
