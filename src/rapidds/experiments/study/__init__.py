"""The user study's instrument: counterbalanced design and statistics (paper, "User Study").

Pure, world-independent pieces that the study app and the simulated study call:
:mod:`~rapidds.experiments.study.design` assigns orders and priming groups,
:mod:`~rapidds.experiments.study.stats` runs the analyses on tidy data frames,
:mod:`~rapidds.experiments.study.power` simulates studies with planted effects.
Names are imported on first use: the statistics load pingouin and pandas, which the CLI's
``--help`` (and a command that only needs :mod:`.systems`) must not pay for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rapidds.lazy import submodule_attributes

if TYPE_CHECKING:
    from rapidds.experiments.study.art import ArtResult, art_anova, art_by_item
    from rapidds.experiments.study.design import StudyDesign, cell_sequence, williams_square
    from rapidds.experiments.study.power import (
        planted_costs,
        planted_likert,
        planted_rankings,
        rejection_rates,
        study_frame,
    )
    from rapidds.experiments.study.stats import (
        EFFECT_COLUMNS,
        RankingTest,
        adaptation_factors,
        cost_reduction,
        ranking_test,
        rankings_from_orders,
        rm_anova_2x2,
    )
    from rapidds.experiments.study.systems import (
        ADAPTATION,
        ANALYSIS_FACTORS,
        FACTORS,
        SYSTEMS,
        adapts,
    )

_WHERE = {
    **dict.fromkeys(("StudyDesign", "cell_sequence", "williams_square"), "design"),
    **dict.fromkeys(("planted_costs", "planted_likert", "planted_rankings", "rejection_rates",
                     "study_frame"), "power"),
    **dict.fromkeys(("ArtResult", "art_anova", "art_by_item"), "art"),
    **dict.fromkeys(("EFFECT_COLUMNS", "RankingTest", "adaptation_factors",
                     "cost_reduction", "ranking_test",
                     "rankings_from_orders", "rm_anova_2x2"), "stats"),
    **dict.fromkeys(("ADAPTATION", "ANALYSIS_FACTORS", "FACTORS", "SYSTEMS", "adapts"),
                    "systems"),
}
__all__ = [
    "ADAPTATION",
    "ANALYSIS_FACTORS",
    "EFFECT_COLUMNS",
    "FACTORS",
    "SYSTEMS",
    "ArtResult",
    "RankingTest",
    "StudyDesign",
    "adaptation_factors",
    "adapts",
    "art_anova",
    "art_by_item",
    "cell_sequence",
    "cost_reduction",
    "planted_costs",
    "planted_likert",
    "planted_rankings",
    "ranking_test",
    "rankings_from_orders",
    "rejection_rates",
    "rm_anova_2x2",
    "study_frame",
    "williams_square",
]

__getattr__ = submodule_attributes(__name__, _WHERE)
