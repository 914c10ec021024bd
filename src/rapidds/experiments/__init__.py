"""Experiments built on the adaptive loop: the fetch ablation study (paper, Figure 5) on Dask.

:mod:`rapidds.experiments.ablation` runs the trials (one Dask task per trial, stored by the
client in one SQLite file, resumable); :mod:`rapidds.experiments.report` turns the stored records
into the figure, the table and the check of the paper's claims without recomputing anything.
"""

from __future__ import annotations

from rapidds.experiments.ablation import (
    ABLATION,
    BASELINES,
    PAPER_HUMANS,
    StudyConfig,
    StudyOutcome,
    run_study,
    run_trial,
)
from rapidds.experiments.report import StudyData, load_study, summarise, write_report

__all__ = [
    "ABLATION",
    "BASELINES",
    "PAPER_HUMANS",
    "StudyConfig",
    "StudyData",
    "StudyOutcome",
    "load_study",
    "run_study",
    "run_trial",
    "summarise",
    "write_report",
]
