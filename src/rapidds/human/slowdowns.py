"""What the planner learns of the safety monitor's slowdowns: per (robot task, concurrent person's
task), how much longer the monitor actually held or slowed the robot than predicted.

The planner predicts a robot motion's lost time P from the person's path belief
(:mod:`rapidds.execution.slowdowns`); the executor records the time L it really lost. The
correction is a factor theta with L | theta ~ Exponential(mean theta P) and theta ~
Inverse-Gamma(a, b): conjugate, so one observation is a += 1, b += L / P and the posterior
mean is b / (a - 1).

Why this pair rather than a Normal on the ratio L / P: lost time is never negative, it is often
exactly 0 (the person walked elsewhere that cycle) and now and then long (one stop while the
person works beside the robot); the exponential is the least committal positive law with a given
mean, takes a 0 as the evidence it is (theta goes down), and keeps theta > 0, which a Normal
would not. The update is two additions, so a resumed run learns exactly as an uninterrupted one.
Pairs whose prediction is (near) 0 carry no information about a ratio: they are not learned
from, and the record keeps what was lost there (an unexplained hold).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["MIN_PREDICTED", "SlowdownBelief", "pair_key"]

MIN_PREDICTED = 0.05
"""Seconds of predicted lost time below which an observation is not learned from."""


def pair_key(robot_task: str, human_task: str) -> str:
    """The stored name of a (robot task, person's task) pair."""
    return f"{robot_task}|{human_task}"


def _prior(mean: float, sd: float) -> tuple[float, float]:
    """Inverse-Gamma (a, b) with the given mean and standard deviation of theta."""
    if not (math.isfinite(mean) and mean > 0 and math.isfinite(sd) and sd > 0):
        raise ValueError(f"the slowdown prior needs a mean and a spread > 0, got {mean!r} and "
                         f"{sd!r}")
    a = 2.0 + (mean / sd) ** 2
    return a, mean * (a - 1.0)


@dataclass
class SlowdownBelief:
    """theta per (robot task, person's task) pair: posterior (a, b) and how many cycles it
    learned from; a pair never seen has the prior's."""

    mean: float = 1.0
    sd: float = 1.0
    pairs: dict[str, tuple[float, float, int]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._a0, self._b0 = _prior(self.mean, self.sd)

    def _state(self, key: str) -> tuple[float, float, int]:
        return self.pairs.get(key, (self._a0, self._b0, 0))

    def factor(self, robot_task: str, human_task: str) -> float:
        """Posterior mean of theta: what a predicted lost time is multiplied by."""
        a, b, _ = self._state(pair_key(robot_task, human_task))
        return b / (a - 1.0)

    def observe(self, robot_task: str, human_task: str, predicted: float, lost: float) -> bool:
        """One cycle's lost time ``lost`` where ``predicted`` was predicted (seconds); False
        (nothing learned) when the prediction is below :data:`MIN_PREDICTED`."""
        if not (math.isfinite(predicted) and math.isfinite(lost)) or lost < 0:
            raise ValueError(f"lost time must be finite and >= 0, got {lost!r} for a "
                             f"prediction of {predicted!r}")
        if predicted < MIN_PREDICTED:
            return False
        key = pair_key(robot_task, human_task)
        a, b, n = self._state(key)
        self.pairs[key] = (a + 1.0, b + lost / predicted, n + 1)
        return True

    def summary(self) -> dict[str, dict[str, float]]:
        """pair -> {factor: posterior mean, sd: posterior sd (None below a = 2), n}."""
        out: dict[str, dict[str, Any]] = {}
        for key, (a, b, n) in sorted(self.pairs.items()):
            sd = b / (a - 1.0) / math.sqrt(a - 2.0) if a > 2.0 else None
            out[key] = {"factor": b / (a - 1.0), "sd": sd, "n": n}
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"mean": self.mean, "sd": self.sd,
                "pairs": {k: list(v) for k, v in sorted(self.pairs.items())}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SlowdownBelief:
        pairs = {str(k): (float(v[0]), float(v[1]), int(v[2])) for k, v in d["pairs"].items()}
        return cls(float(d["mean"]), float(d["sd"]), pairs)
