"""Experiments built on the adaptive loop: the fetch ablation study (paper, Figure 5) on Dask.

:mod:`rapidds.experiments.ablation` runs the trials (one Dask task per trial, stored by the
client in one SQLite file, resumable); :mod:`rapidds.experiments.report` turns the stored records
into the figure, the table and the check of the paper's claims without recomputing anything.
Names are imported on first use, so the CLI's ``--help`` does not pay for numpy and pandas.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rapidds.lazy import submodule_attributes

if TYPE_CHECKING:
    from rapidds.experiments.ablation import (
        ABLATION,
        BASELINES,
        PAPER_HUMANS,
        AblationConfig,
        StudyOutcome,
        run_ablation,
        run_trial,
    )
    from rapidds.experiments.report import AblationData, load_ablation, summarise, write_report

_WHERE = {
    "ABLATION": "ablation", "BASELINES": "ablation", "PAPER_HUMANS": "ablation",
    "AblationConfig": "ablation", "StudyOutcome": "ablation", "run_ablation": "ablation",
    "run_trial": "ablation",
    "AblationData": "report", "load_ablation": "report", "summarise": "report",
    "write_report": "report",
}
__all__ = [
    "ABLATION", "BASELINES", "PAPER_HUMANS", "AblationConfig", "AblationData", "StudyOutcome",
    "load_ablation", "run_ablation", "run_trial", "summarise", "write_report",
]


__getattr__ = submodule_attributes(__name__, _WHERE)
