"""Schedule search: genetic scheduler with trajectory adaptation, and the exact CP-SAT baseline.

- :class:`GeneticScheduler` plans one cycle (paper Algorithm 1, lines 3-9) with settings from
  :class:`GAConfig`; it returns a :class:`PlanResult` whose ``best`` :class:`Evaluation` holds the
  schedule and the robot motions to deploy.
- :func:`evaluate_population` is Algorithm 2 for a batch of candidates.
- :func:`diversity` and :class:`AllocationHistory` are the corrected diversity term z_d.
- :func:`solve_exact` is the CP-SAT baseline on mean durations.

The search and the CP-SAT baseline load on first use: listing the CLI's options imports
neither, and the genetic search never pays for importing OR-Tools.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rapidds.lazy import submodule_attributes
from rapidds.scheduler.config import MUTATIONS, GAConfig
from rapidds.scheduler.diversity import AllocationHistory, diversity, diversity_term

if TYPE_CHECKING:
    from rapidds.scheduler.evaluate import Evaluation, EvaluationContext, evaluate_population
    from rapidds.scheduler.exact import ExactResult, solve_exact
    from rapidds.scheduler.ga import GeneticScheduler, PlanResult

_LAZY = {"Evaluation": "evaluate", "EvaluationContext": "evaluate",
         "evaluate_population": "evaluate", "ExactResult": "exact",
         "solve_exact": "exact", "GeneticScheduler": "ga", "PlanResult": "ga"}

__all__ = [
    "MUTATIONS",
    "AllocationHistory",
    "Evaluation",
    "EvaluationContext",
    "ExactResult",
    "GAConfig",
    "GeneticScheduler",
    "PlanResult",
    "diversity",
    "diversity_term",
    "evaluate_population",
    "solve_exact",
]


__getattr__ = submodule_attributes(__name__, _LAZY)
