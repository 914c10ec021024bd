"""The allocation-diversity term z_d (paper Eq. 5, corrected as in docs/design-notes.md item 1).

As printed, Eq. 5 sums signed deviations from the mean and is identically 0. The corrected term
uses absolute imbalance and counts the candidate's own assignment:

    r_i^a = (past cycles in which agent a did task i) + A_i^a
    z_d   = 1 / (2 |tau|) * sum_{i shared} sum_a | (1/2) sum_a' r_i^a' - r_i^a |

where |tau| is the number of all tasks and only tasks both agents may do count. With two agents
the inner sum is |r_i^h - r_i^r|, so minimising z_d pushes each task toward the agent that has
done it less.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from rapidds.errors import StateError
from rapidds.problem import AGENTS, Agent, Problem

if TYPE_CHECKING:  # annotations only: the CLI's --help imports this package without numpy
    from rapidds.schedule import Schedule


class AllocationHistory:
    """r_i^a of past cycles: how often each agent did each task."""

    def __init__(self, counts: Mapping[str, Mapping[str, int]] | None = None):
        self._counts: dict[str, dict[Agent, int]] = {}
        for task, per_agent in (counts or {}).items():
            for agent, c in per_agent.items():
                if agent not in AGENTS:
                    raise StateError(f"allocation history: unknown agent '{agent}' for '{task}'")
                if isinstance(c, bool) or not isinstance(c, int) or c < 0:
                    raise StateError(
                        f"allocation history: count of '{task}' by {agent} must be an integer "
                        f">= 0, got {c!r}"
                    )
                self._counts.setdefault(task, {"human": 0, "robot": 0})[agent] = c

    def count(self, task: str, agent: Agent) -> int:
        """How many past cycles ``agent`` did ``task``."""
        return self._counts.get(task, {}).get(agent, 0)

    def record(self, schedule: Schedule) -> None:
        """Add one cycle: every task of ``schedule`` counts once for the agent that did it."""
        for task, agent in schedule.assignment.items():
            self._counts.setdefault(task, {"human": 0, "robot": 0})[agent] += 1

    def to_dict(self) -> dict[str, dict[str, int]]:
        return {t: dict(c) for t, c in sorted(self._counts.items())}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> AllocationHistory:
        if not isinstance(data, Mapping):
            raise StateError(f"allocation history must be a mapping, got {type(data).__name__}")
        for task, per_agent in data.items():
            if not isinstance(per_agent, Mapping):
                raise StateError(f"allocation history: entry of '{task}' must be a mapping")
        return cls(data)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, AllocationHistory) and self.to_dict() == other.to_dict()

    def __repr__(self) -> str:
        return f"AllocationHistory({self.to_dict()})"


def diversity_term(
    problem: Problem, history: AllocationHistory | None
) -> Callable[[Schedule], float]:
    """z_d as a function of the schedule, with the history's counts looked up once (hot path).

    Without history every allocation scores the same, |shared| / (2 |tau|): each shared task
    has r = (1, 0) or (0, 1).
    """
    if history is None:
        constant = len(problem.shared_tasks) / (2 * len(problem.tasks))
        return lambda schedule: constant
    past = [
        (task, history.count(task, "human"), history.count(task, "robot"))
        for task in problem.shared_tasks
    ]
    scale = 1.0 / (2 * len(problem.tasks))

    def term(schedule: Schedule) -> float:
        assignment = schedule.assignment
        total = 0.0
        for task, r_h, r_r in past:
            agent = assignment.get(task)
            h = r_h + (agent == "human")
            r = r_r + (agent == "robot")
            half_sum = 0.5 * (h + r)
            total += abs(half_sum - h) + abs(half_sum - r)
        return total * scale

    return term


def diversity(problem: Problem, schedule: Schedule, history: AllocationHistory | None) -> float:
    """z_d of ``schedule`` given past allocations (None = empty history)."""
    return diversity_term(problem, history)(schedule)
