"""What the scheduler asks of robot motion: "trajectory, duration and spatial cost for robot
task j while human tasks C_j run".

Requests are answered in batches so an implementation backed by a diffusion policy can sample
every new (j, C_j) of a whole GA generation in one network batch. The :class:`TrajectoryCache`
is the paper's memory M (Algorithm 1, line 3: emptied every cycle).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from rapidds.problem import Problem

MotionKey = tuple[str, frozenset[str]]


@dataclass(frozen=True)
class MotionPlan:
    """A robot motion chosen for task ``task`` while human tasks ``concurrent`` run.

    ``duration`` is d_j^r in seconds; ``spatial_cost`` is max_{i in C_j} S_i(xi) (0 when C_j is
    empty); ``trajectory`` is the (H, d) path, or None for motion models without geometry;
    ``hold``: seconds the safety monitor is predicted to slow or hold it beside C_j (0 unless
    the run plans for the monitor: :mod:`rapidds.execution.slowdowns`), which the schedule's
    timeline adds to ``duration``.
    """

    task: str
    concurrent: frozenset[str]
    duration: float
    spatial_cost: float = 0.0
    trajectory: np.ndarray | None = None
    hold: float = 0.0


@runtime_checkable
class MotionModel(Protocol):
    """Answers motion requests for the scheduler."""

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        """(n,) robot duration guess per task in problem order (d_init of Algorithm 2); NaN where
        the robot may not do the task."""
        ...

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        """One plan per request, in order. Requests are distinct and not yet cached."""
        ...


class FixedDurationMotion:
    """The problem file's robot durations, no geometry, zero spatial cost."""

    def __init__(self, problem: Problem):
        self._dur = {t.id: t.robot_duration for t in problem.tasks}

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        return np.array(
            [np.nan if t.robot_duration is None else t.robot_duration for t in problem.tasks]
        )

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        out = []
        for task, concurrent in requests:
            d = self._dur[task]
            if d is None:
                raise ValueError(f"the robot cannot do task '{task}'")
            out.append(MotionPlan(task, concurrent, float(d)))
        return out


class TrajectoryCache:
    """Memory M: (j, C_j) -> MotionPlan. Misses are planned in one batch."""

    def __init__(self, motion: MotionModel):
        self.motion = motion
        self._plans: dict[MotionKey, MotionPlan] = {}
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._plans)

    def __contains__(self, key: MotionKey) -> bool:
        return key in self._plans

    def get_many(self, keys: Sequence[MotionKey]) -> list[MotionPlan]:
        missing = list(dict.fromkeys(k for k in keys if k not in self._plans))
        self.misses += len(missing)
        self.hits += len(keys) - len(missing)
        if missing:
            for key, plan in zip(missing, self.motion.plan(missing), strict=True):
                self._plans[key] = plan
        return [self._plans[k] for k in keys]

    def clear(self) -> None:
        self._plans.clear()
