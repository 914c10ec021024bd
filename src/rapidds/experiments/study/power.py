"""Power and level of the study's analyses by simulation: synthetic studies with a planted
spatial-adaptation effect, and the rate at which an analysis rejects each effect.

The generators follow the paper's design (n participants x the four systems) with a participant
offset, so the repeated measures are correlated as in a real study. Used by the tests (200
studies) and by ``benchmarks/bench_study_power.py`` (thousands) to state the designed power.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from rapidds.experiments.study.stats import adaptation_factors, rankings_from_orders
from rapidds.experiments.study.systems import SYSTEMS, adapts

N_PARTICIPANTS = 32
_SPATIAL = np.array([adapts(s, "spatial") for s in SYSTEMS])


def study_frame(n: int = N_PARTICIPANTS) -> pd.DataFrame:
    """One row per participant (P00...) and system, with the adaptation factors."""
    frame = pd.DataFrame(
        {
            "participant": np.repeat([f"P{i:02d}" for i in range(n)], len(SYSTEMS)),
            "system": np.tile(SYSTEMS, n),
        }
    )
    return adaptation_factors(frame)


def planted_costs(
    rng: np.random.Generator, delta: float, n: int = N_PARTICIPANTS
) -> pd.DataFrame:
    """Column ``y`` (e.g. a cost reduction) = participant offset N(0, 1) + ``delta`` if the
    system adapts spatially + noise N(0, 1). The spatial main-effect contrast is then a one-sample
    t test with effect size d = delta; temporal and interaction effects are null."""
    frame = study_frame(n)
    offset = np.repeat(rng.normal(size=n), len(SYSTEMS))
    return frame.assign(y=offset + delta * frame["spatial"] + rng.normal(size=len(frame)))


def planted_likert(
    rng: np.random.Generator,
    delta: float,
    n: int = N_PARTICIPANTS,
    levels: int = 7,
    spread: float = 1.2,
) -> pd.DataFrame:
    """Column ``response``: a ``levels``-point answer, the latent participant offset + ``delta``
    if spatial + noise (all sd 1), times ``spread``, rounded around the middle and cut to the
    scale, so ties and floor/ceiling effects are as in survey data."""
    frame = study_frame(n)
    latent = (
        np.repeat(rng.normal(size=n), len(SYSTEMS))
        + delta * frame["spatial"]
        + rng.normal(size=len(frame))
    )
    middle = (levels + 1) / 2
    return frame.assign(response=np.clip(np.round(middle + spread * latent), 1, levels))


def planted_rankings(
    rng: np.random.Generator, beta: float, n: int = N_PARTICIPANTS
) -> pd.DataFrame:
    """Forced-choice rankings (participant, system, rank): each participant orders the systems
    by utility ``beta`` x spatial + N(0, 1), best first."""
    utility = beta * _SPATIAL + rng.normal(size=(n, len(SYSTEMS)))
    orders = {f"P{i:02d}": [SYSTEMS[j] for j in np.argsort(-utility[i])] for i in range(n)}
    return rankings_from_orders(orders)


def rejection_rates(
    analysis: Callable[[np.random.Generator], Sequence[float]],
    replicates: int,
    seed: int,
    alpha: float = 0.05,
) -> np.ndarray:
    """Share of ``replicates`` simulated studies in which each p value returned by ``analysis``
    (called with ``np.random.default_rng(seed + k)`` for study k) is below ``alpha``."""
    p = np.array([np.atleast_1d(analysis(np.random.default_rng(seed + k)))
                  for k in range(replicates)])
    return (p < alpha).mean(axis=0)
