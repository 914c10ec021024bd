"""The user study's instrument: counterbalanced design and statistics (paper, "User Study").

Pure, world-independent pieces that the study app and the simulated study call:
:mod:`~rapidds.experiments.study.design` assigns orders and priming groups.
"""

from __future__ import annotations

from rapidds.experiments.study.design import StudyDesign, cell_sequence, williams_square
from rapidds.experiments.study.systems import ADAPTATION, FACTORS, SYSTEMS

__all__ = ["ADAPTATION", "FACTORS", "SYSTEMS", "StudyDesign", "cell_sequence", "williams_square"]
