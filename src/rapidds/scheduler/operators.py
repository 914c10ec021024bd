"""The GA's mutation operators (move, reorder, crossover, add wait, remove wait) and the
precedence structure they respect: no operator puts a task on an agent that may not do it, and
every child is repaired (:func:`~rapidds.schedule.repair`) before it is used."""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence

import numpy as np

from rapidds.problem import AGENTS, Agent, Problem
from rapidds.schedule import Item, Schedule, Wait, repair
from rapidds.scheduler.config import MUTATIONS

# (parent, rng, parent's expected start times (n,) or None) -> child before repair, or None
Operator = Callable[[Schedule, random.Random, np.ndarray | None], Schedule | None]


def other(agent: Agent) -> Agent:
    return "robot" if agent == "human" else "human"


def closure(ids: Sequence[str], edges: Sequence[tuple[str, str]]) -> dict[str, frozenset[str]]:
    """Transitive successors of every task."""
    succ: dict[str, list[str]] = {i: [] for i in ids}
    for a, b in edges:
        succ[a].append(b)
    out: dict[str, frozenset[str]] = {}

    def visit(u: str) -> frozenset[str]:
        if u not in out:
            acc: set[str] = set()
            for v in succ[u]:
                acc.add(v)
                acc |= visit(v)
            out[u] = frozenset(acc)
        return out[u]

    for i in ids:
        visit(i)
    return out


class Operators:
    """The job's structure (who may do what, precedence closures) and the five operators.

    Args:
        problem: the job.
        weights: default operator weights, in :data:`MUTATIONS` order.
    """

    def __init__(self, problem: Problem, weights: Sequence[float]):
        self.problem = problem
        self.weights = list(weights)
        self.allowed = {t.id: t.allowed for t in problem.tasks}
        self.index = problem.index
        self.shared = problem.shared_tasks
        self.desc = closure(problem.ids, problem.precedence)
        self.anc = closure(problem.ids, [(b, a) for a, b in problem.precedence])
        self._ops: dict[str, Operator] = {
            "move": self.move,
            "reorder": self.reorder,
            "crossover": self.crossover,
            "add_wait": self.add_wait,
            "remove_wait": self.remove_wait,
        }

    def mutate(
        self,
        parent: Schedule,
        rng: random.Random,
        weights: list[float] | None = None,
        start: np.ndarray | None = None,
    ) -> Schedule | None:
        """One repaired mutant that differs from ``parent``; None if no operator applies.
        ``start``: the parent's (n,) expected start times, where known (used by "move")."""
        weights = list(weights or self.weights)
        while sum(weights) > 0:
            k = rng.choices(range(len(MUTATIONS)), weights)[0]
            child = self._ops[MUTATIONS[k]](parent, rng, start)
            if child is not None:
                child = repair(child)
                if child != parent:
                    return child
            weights[k] = 0.0  # operator does not apply here; try the others
        return None

    def window(self, seq: Sequence[Item], task: str) -> tuple[int, int]:
        """Insertion positions [lo, hi] of ``task`` in ``seq`` that keep precedence: after its
        ancestors, before its descendants and before waits on them."""
        anc, desc = self.anc[task], self.desc[task]
        lo, hi = 0, len(seq)
        for k, x in enumerate(seq):
            if isinstance(x, Wait):
                if x.task in desc and k < hi:
                    hi = k
            elif x in anc:
                lo = k + 1
            elif x in desc and k < hi:
                hi = k
        return (lo, hi) if lo <= hi else (0, len(seq))

    def move(self, s: Schedule, rng: random.Random, start: np.ndarray | None) -> Schedule | None:
        """A random shared task to the other agent. With the parent's expected start times it
        goes where its start falls in the other sequence (ahead of any waits there), so the new
        allocation is judged with a sensible order; otherwise to a random position. Either way
        within the precedence window. (Measured: fewer runs stuck above the optimum than with
        random positions only; "reorder" and activation still try the other positions.)"""
        if not self.shared:
            return None
        task = rng.choice(self.shared)
        src = s.agent_of(task)
        dst = other(src)
        seq = list(s.sequence(dst))
        lo, hi = self.window(seq, task)
        if start is not None and start.size:
            at = start[self.index[task]]
            pos = next((k for k, x in enumerate(seq)
                        if isinstance(x, str) and start[self.index[x]] >= at), len(seq))
            while pos > 0 and isinstance(seq[pos - 1], Wait):
                pos -= 1
            seq.insert(min(max(pos, lo), hi), task)
        else:
            seq.insert(rng.randint(lo, hi), task)
        return s.replace(src, (x for x in s.sequence(src) if x != task)).replace(dst, seq)

    def reorder(self, s: Schedule, rng: random.Random, _: np.ndarray | None) -> Schedule | None:
        slots = [(a, k) for a in AGENTS if len(s.sequence(a)) >= 2
                 for k in range(len(s.sequence(a)))]
        if not slots:
            return None
        agent, k = rng.choice(slots)
        seq = list(s.sequence(agent))
        if rng.random() < 0.5:  # swap with another item of the same sequence
            pick = rng.choice([p for p in range(len(seq)) if p != k])
            seq[k], seq[pick] = seq[pick], seq[k]
            return s.replace(agent, seq)
        item = seq.pop(k)
        lo, hi = (0, len(seq)) if isinstance(item, Wait) else self.window(seq, item)
        choices = [p for p in range(lo, hi + 1) if p != k]
        if not choices:
            return None
        seq.insert(rng.choice(choices), item)
        return s.replace(agent, seq)

    def crossover(self, s: Schedule, rng: random.Random, _: np.ndarray | None
                  ) -> Schedule | None:
        """Swap the tails after a cut point in each sequence. A task in a tail that the other
        agent may not do stays with its agent, after the incoming tail."""
        h, r = s.human, s.robot
        ch, cr = rng.randint(0, len(h)), rng.randint(0, len(r))
        if ch == len(h) and cr == len(r):
            return None
        tail_h, tail_r = h[ch:], r[cr:]

        def fits(x: Item, agent: Agent) -> bool:
            return isinstance(x, Wait) or agent in self.allowed[x]

        human = (*h[:ch], *(x for x in tail_r if fits(x, "human")),
                 *(x for x in tail_h if not fits(x, "robot")))
        robot = (*r[:cr], *(x for x in tail_h if fits(x, "robot")),
                 *(x for x in tail_r if not fits(x, "human")))
        return Schedule(human, robot)

    def add_wait(self, s: Schedule, rng: random.Random, _: np.ndarray | None) -> Schedule | None:
        agents = [a for a in AGENTS if s.sequence(a) and s.tasks(other(a))]
        if not agents:
            return None
        agent = rng.choice(agents)
        seq = list(s.sequence(agent))
        seq.insert(rng.randrange(len(seq)), Wait(rng.choice(s.tasks(other(agent)))))
        return s.replace(agent, seq)

    def remove_wait(self, s: Schedule, rng: random.Random, _: np.ndarray | None
                    ) -> Schedule | None:
        slots = [(a, k) for a in AGENTS for k, x in enumerate(s.sequence(a))
                 if isinstance(x, Wait)]
        if not slots:
            return None
        agent, k = rng.choice(slots)
        seq = s.sequence(agent)
        return s.replace(agent, seq[:k] + seq[k + 1 :])
