"""Re-planning the rest of a cycle while it runs (the two-layer cell's reactive layer).

Finished tasks keep their times and running ones their agents; the tasks not started yet are
re-allocated and re-sequenced. The jobs rapidds knows have at most five tasks, so the search is
exhaustive: every allocation (the robot only takes tasks it already has a steered trajectory
for) and every order of each agent's part, scored on the expected timeline (the learned mean
durations as they stand) by makespan + gamma x spatial cost of the robot's motions against the
person's tasks that overlap them. It is warm-started from the current plan: the current
remainder is scored first and only a strictly better one replaces it. Above ``max_candidates``
the current order is kept.

The search scores the motions the robot has; where the chosen remainder changes the person's
tasks a robot motion runs beside (:func:`robot_concurrency`), the executor asks a
:class:`MotionSupply` for a motion steered for the new (task, concurrent set) pair: one the plan's
search already steered (memory M, free), else steered now (a steering call, bounded per re-plan
so the re-plan's latency stays small). Steering inside the search itself would cost one call per
candidate.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from rapidds.motion.interface import MotionKey, MotionPlan
from rapidds.problem import Problem

__all__ = ["MotionSupply", "Progress", "Remainder", "replan_remainder", "robot_concurrency"]


@runtime_checkable
class MotionSupply(Protocol):
    """Robot motions for re-plans: what the cycle started with, what the plan's search steered
    (free to recall) and new steering (costs a steering call)."""

    def planned(self, task: str) -> MotionPlan | None:
        """The motion the robot has for ``task`` at the cycle's start (None: none)."""
        ...

    def recall(self, key: MotionKey) -> MotionPlan | None:
        """A motion already steered for ``key`` against the models as they stand, if any."""
        ...

    def steer(self, keys: Sequence[MotionKey]) -> list[MotionPlan]:
        """One steered motion per key, in one batch."""
        ...

    def cost(self, concurrent: frozenset[str], trajectory: np.ndarray) -> float:
        """max over ``concurrent`` of the learned spatial cost of a robot trajectory (H, d)."""
        ...


@dataclass(frozen=True)
class Remainder:
    """The rest of a cycle: each agent's tasks still to start, in order, and its score;
    ``current``: the score of the rest as it was planned (what the re-plan improved on)."""

    human: tuple[str, ...]
    robot: tuple[str, ...]
    objective: float
    evaluated: int
    current: float = math.nan


Times = tuple[dict[str, float], dict[str, float], dict[str, str]]  # start, finish, agent


def _timeline(problem: Problem, human: Sequence[str], robot: Sequence[str], now: float,
              fixed: Mapping[str, tuple[str, float, float]], free: Mapping[str, float],
              mean: Mapping[str, float]) -> Times | None:
    """The expected timeline of one remainder; None when it deadlocks."""
    start = {t: s for t, (_, s, _) in fixed.items()}
    finish = {t: f for t, (_, _, f) in fixed.items()}
    agent = {t: a for t, (a, _, _) in fixed.items()}
    seqs = {"human": list(human), "robot": list(robot)}
    pos = {"human": 0, "robot": 0}
    clock = dict(free)
    preds = problem.preceding
    left = len(human) + len(robot)
    while left:
        moved = False
        for a, seq in seqs.items():
            while pos[a] < len(seq):
                t = seq[pos[a]]
                if any(p not in finish for p in preds[t]):
                    break
                s = max([clock[a], now, *(finish[p] for p in preds[t])])
                start[t], finish[t], agent[t] = s, s + mean[t], a
                clock[a] = finish[t]
                pos[a] += 1
                left -= 1
                moved = True
        if not moved:
            return None
    return start, finish, agent


def _near(times: Times) -> dict[str, frozenset[str]]:
    """Robot task -> the person's tasks that overlap it on the timeline (C_j)."""
    start, finish, agent = times
    return {j: frozenset(i for i, b in agent.items() if b == "human"
                         and max(start[i], start[j]) < min(finish[i], finish[j]) - 1e-9)
            for j, a in agent.items() if a == "robot"}


def robot_concurrency(problem: Problem, now: float, human: Sequence[str],
                      robot: Sequence[str], fixed: Mapping[str, tuple[str, float, float]],
                      free: Mapping[str, float],
                      mean: Mapping[str, float]) -> dict[str, frozenset[str]]:
    """Each robot task of the remainder ``robot`` -> the person's tasks expected to run beside
    it (the C_j a motion for it is steered against); arguments as for
    :func:`replan_remainder`, ``mean`` keyed "agent:task". Empty when the remainder deadlocks."""
    dur = {t: mean[f"{a}:{t}"] for a, seq in (("human", human), ("robot", robot)) for t in seq}
    times = _timeline(problem, human, robot, now, fixed, free, dur)
    if times is None:
        return {}
    near = _near(times)
    return {j: near[j] for j in robot}


@dataclass(frozen=True)
class Progress:
    """Where a running cycle stands at ``now``, what a re-plan starts from.

    current: agent -> its tasks still to start, in the current plan's order. fixed: task ->
    (agent, start, (expected) finish) of every finished or running task. free: agent -> when
    it is expected to be free. mean: expected duration of every task still to start, for
    either agent that may do it, keyed ``agent:task`` (the person's learned mean, the robot's
    motion duration).
    """

    now: float
    current: Mapping[str, Sequence[str]]
    fixed: Mapping[str, tuple[str, float, float]]
    free: Mapping[str, float]
    mean: Mapping[str, float]


def replan_remainder(
    problem: Problem, progress: Progress, robot_can: frozenset[str],
    spatial: Callable[[str, frozenset[str]], float], gamma: float,
    claimed: frozenset[str] = frozenset(), max_candidates: int = 20_000,
) -> Remainder:
    """The best remainder of the cycle from ``progress.now``, scored by expected makespan +
    gamma x spatial (inf where it deadlocks).

    robot_can: tasks the robot may take (a trajectory of its own exists). spatial(j, C): the
    spatial cost of robot task j beside the person's tasks C. claimed: tasks the person took
    from the robot; they stay the person's.
    """
    now, current, fixed, free, mean = (progress.now, progress.current, progress.fixed,
                                       progress.free, progress.mean)
    cache: dict[tuple[str, frozenset[str]], float] = {}

    def cost(j: str, near: frozenset[str]) -> float:
        if (j, near) not in cache:
            cache[(j, near)] = spatial(j, near)
        return cache[(j, near)]

    def score(h: Sequence[str], r: Sequence[str]) -> float:
        dur = {t: mean[f"{a}:{t}"] for a, seq in (("human", h), ("robot", r)) for t in seq}
        times = _timeline(problem, h, r, now, fixed, free, dur)
        if times is None:
            return float("inf")
        total = sum(cost(j, near) for j, near in _near(times).items() if near)
        return max(times[1].values(), default=now) + gamma * total

    h0, r0 = tuple(current["human"]), tuple(current["robot"])
    first = score(h0, r0)
    best = Remainder(h0, r0, first, 1, first)
    tasks = [*h0, *r0]
    options = []
    for t in tasks:
        can = [a for a in ("human", "robot") if problem.task(t).can(a)
               and (a == "human" or (t in robot_can and t not in claimed))]
        options.append(can)
    n = 1
    for opts in options:
        n *= len(opts)
    if n * math.factorial(len(tasks)) > max_candidates:
        return best
    evaluated = 1
    for alloc in itertools.product(*options):
        mine = {a: [t for t, b in zip(tasks, alloc, strict=True) if b == a]
                for a in ("human", "robot")}
        for h in itertools.permutations(mine["human"]):
            for r in itertools.permutations(mine["robot"]):
                evaluated += 1
                v = score(h, r)
                if v < best.objective - 1e-9:
                    best = Remainder(tuple(h), tuple(r), v, 0, first)
    return Remainder(best.human, best.robot, best.objective, evaluated, first)
