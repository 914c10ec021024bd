"""A small study on the fetch world for the study app's tests: two systems x two rounds, one or
two participants, priming groups named like fetch's simulated teammates (speed x route)."""

from __future__ import annotations

from pathlib import Path

from rapidds.experiments.study.design import StudyDesign
from rapidds.experiments.study.store import create_study
from rapidds.loop.config import RunConfig
from rapidds.worlds.base import World

SEARCH = dict(population=8, generations=4, samples=8, patience=2, particles=2, candidates=4)
FACTORS = {"speed": ("fast", "slow"), "route": ("middle", "outside")}


def make_study(folder: Path, world: World, participants: int = 1, seed: int = 3,
               comfort: bool = False, execution: str = "planned") -> Path:
    """A study in ``folder`` (design.csv, study.sqlite); returns the folder. comfort: the
    round pages ask the comfort item and the runs learn each person's gamma from it.
    execution: the robot inside the rounds (reactive: the game's robot reacts live)."""
    design = StudyDesign(participants=participants, systems=("full", "none"), rounds=2,
                         factors=FACTORS, seed=seed, require_balance=False, comfort=comfort)
    cfg = RunConfig(world=world.name, gamma_learn=comfort, execution=execution,
                    **SEARCH).resolved(world)
    create_study(folder, design, cfg).close()
    return folder
