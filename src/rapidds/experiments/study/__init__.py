"""The user study's instrument: counterbalanced design and statistics (paper, "User Study").

Pure, world-independent pieces that the study app and the simulated study call:
:mod:`~rapidds.experiments.study.design` assigns orders and priming groups,
:mod:`~rapidds.experiments.study.stats` runs the analyses on tidy data frames,
:mod:`~rapidds.experiments.study.power` simulates studies with planted effects.
"""

from __future__ import annotations

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
    ArtResult,
    RankingTest,
    adaptation_factors,
    art_anova,
    art_by_item,
    cost_reduction,
    ranking_test,
    rankings_from_orders,
    rm_anova_2x2,
)
from rapidds.experiments.study.systems import ADAPTATION, FACTORS, SYSTEMS

__all__ = [
    "ADAPTATION",
    "EFFECT_COLUMNS",
    "FACTORS",
    "SYSTEMS",
    "ArtResult",
    "RankingTest",
    "StudyDesign",
    "adaptation_factors",
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
