"""Reference answers for scheduler tests, computed independently of rapidds.schedule: the
makespan of per-agent orders by recursion on finish times, and the optimum by brute force."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

from rapidds.problem import Problem


def sequence_makespan(problem: Problem, human: Sequence[str], robot: Sequence[str]) -> float:
    """Makespan of per-agent orders without waits, by recursion on finish times (independent
    of CompiledSchedule); inf on a cycle."""
    on_human = set(human)
    dur = {t.id: (t.human_mean if t.id in on_human else t.robot_duration) for t in problem.tasks}
    before = {b: a for seq in (human, robot) for a, b in itertools.pairwise(seq)}
    preds = {t: problem.predecessors(t) for t in problem.ids}
    finish: dict[str, float] = {}
    active: set[str] = set()

    def f(t: str) -> float:
        if t not in finish:
            if t in active:
                raise RecursionError
            active.add(t)
            gates = [f(p) for p in preds[t]] + ([f(before[t])] if t in before else [])
            finish[t] = max(gates, default=0.0) + dur[t]  # type: ignore[operator]
        return finish[t]

    try:
        return max(f(t) for t in problem.ids)
    except RecursionError:
        return math.inf


def best_order(problem: Problem, human: Sequence[str], robot: Sequence[str]) -> float:
    """Optimal makespan of one allocation over every pair of orders, no waits."""
    return min(sequence_makespan(problem, ph, pr)
               for ph in itertools.permutations(human) for pr in itertools.permutations(robot))


def brute_force(problem: Problem) -> float:
    """Optimal makespan over every allocation and every pair of orders, no waits."""
    best = math.inf
    for agents in itertools.product(*(sorted(t.allowed) for t in problem.tasks)):
        h = [t for t, a in zip(problem.ids, agents, strict=True) if a == "human"]
        r = [t for t, a in zip(problem.ids, agents, strict=True) if a == "robot"]
        best = min(best, best_order(problem, h, r))
    return best
