"""Re-planning the rest of a cycle while it runs (the two-layer cell's reactive layer).

Finished tasks keep their times and running ones their agents; the tasks not started yet are
re-allocated and re-sequenced. The jobs rapidds knows have at most five tasks, so the search is
exhaustive: every allocation (the robot only takes tasks it already has a steered trajectory
for: no steering inside the cycle, so a re-plan costs milliseconds) and every order of each
agent's part, scored on the expected timeline (the learned mean durations as they stand) by
makespan + gamma x spatial cost of the robot's motions against the person's tasks that overlap
them. It is warm-started from the current plan: the current remainder is scored first and
only a strictly better one replaces it. Above ``max_candidates`` the current order is kept.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from rapidds.problem import Problem

__all__ = ["Remainder", "replan_remainder"]


@dataclass(frozen=True)
class Remainder:
    """The rest of a cycle: each agent's tasks still to start, in order, and its score."""

    human: tuple[str, ...]
    robot: tuple[str, ...]
    objective: float
    evaluated: int


def _score(problem: Problem, human: Sequence[str], robot: Sequence[str], now: float,
           fixed: Mapping[str, tuple[str, float, float]], free: Mapping[str, float],
           mean: Mapping[str, float], spatial: Callable[[str, frozenset[str]], float],
           gamma: float) -> float:
    """Expected makespan + gamma x spatial of one remainder; inf when it deadlocks."""
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
            return float("inf")
    total = 0.0
    for j, a in agent.items():
        if a != "robot":
            continue
        near = frozenset(i for i, b in agent.items() if b == "human"
                         and max(start[i], start[j]) < min(finish[i], finish[j]) - 1e-9)
        if near:
            total += spatial(j, near)
    return max(finish.values(), default=now) + gamma * total


def replan_remainder(
    problem: Problem, now: float, current: Mapping[str, Sequence[str]],
    fixed: Mapping[str, tuple[str, float, float]], free: Mapping[str, float],
    mean: Mapping[str, float], robot_can: frozenset[str],
    spatial: Callable[[str, frozenset[str]], float], gamma: float,
    claimed: frozenset[str] = frozenset(), max_candidates: int = 20_000,
) -> Remainder:
    """The best remainder of the cycle from ``now``.

    current: agent -> its tasks still to start, in the current plan's order. fixed: task ->
    (agent, start, (expected) finish) of every finished or running task. free: agent -> when
    it is expected to be free. mean: expected duration of every task still to start, for
    either agent that may do it (the person's learned mean, the robot's motion duration).
    robot_can: tasks the robot may take (a trajectory of its own exists). spatial(j, C): the
    spatial cost of robot task j beside the person's tasks C. claimed: tasks the person took
    from the robot; they stay the person's.
    """
    cache: dict[tuple[str, frozenset[str]], float] = {}

    def cost(j: str, near: frozenset[str]) -> float:
        if (j, near) not in cache:
            cache[(j, near)] = spatial(j, near)
        return cache[(j, near)]

    def score(h: Sequence[str], r: Sequence[str]) -> float:
        dur = {t: mean[f"{a}:{t}"] for a, seq in (("human", h), ("robot", r)) for t in seq}
        return _score(problem, h, r, now, fixed, free, dur, cost, gamma)

    h0, r0 = tuple(current["human"]), tuple(current["robot"])
    best = Remainder(h0, r0, score(h0, r0), 1)
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
                    best = Remainder(tuple(h), tuple(r), v, 0)
    return Remainder(best.human, best.robot, best.objective, evaluated)
