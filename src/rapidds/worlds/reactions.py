"""People who react to the robot and deviate from the plan, for every world.

The logic is world-independent: distances are in workspace units, times in seconds. What differs
between cells (a 10 m fetch room against a 1 m painting table) is the population's parameters,
which a world states by its ``reactions`` capability (see
:func:`cell_reactions`); docs/design-notes.md "Reacting inside the cycle" gives the values.

Reaction model: while a MOVING robot body point is within the person's comfort distance of any
of their body points, they go on at a fraction ``slow`` of their pace; within their stop
distance they pause until the robot has passed (moved out of it, or stopped: a robot that has
stopped for them is no threat, so they go on, as people do when a cobot yields).

Deviation model: with probability P per cycle the person deviates once, in one of three ways
drawn uniformly among those the cycle's plan allows (:func:`deviation_kinds`): another order that
precedence allows (at their first choice between two ready tasks they take one that is not the
plan's next), a mid-cycle pause (during one of their tasks, at a random point of it, for a random
time), or taking a robot task that has not started and that the world lets a person do (at
their first choice point where there is one). A kind the plan leaves no room for (painting's
person does a chain of tasks: no other order) is redrawn among the others, so P is the rate at
which people deviate, not at which a deviation is drawn and then cannot happen.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rapidds.problem import Problem
from rapidds.schedule import Schedule
from rapidds.scheduler.operators import closure
from rapidds.worlds.capabilities import capability

__all__ = [
    "DEVIATIONS",
    "Deviation",
    "Reaction",
    "ReactionPopulation",
    "SafetyLimits",
    "cell_reactions",
    "deviation_kinds",
    "draw_deviation",
]

DeviationKind = Literal["order", "pause", "take"]
DEVIATIONS: tuple[DeviationKind, ...] = ("order", "pause", "take")


@dataclass(frozen=True)
class Reaction:
    """One person's reaction to the robot. comfort, stop: distances (workspace units) from a
    moving robot point within which they slow down / pause; slow: their pace while slowed
    (fraction of their own)."""

    comfort: float
    stop: float
    slow: float

    def pace(self, separation: float, robot_moving: bool) -> float:
        """The person's pace (fraction of their own) at ``separation`` from the robot."""
        if not robot_moving or separation >= self.comfort:
            return 1.0
        return 0.0 if separation < self.stop else self.slow


@dataclass(frozen=True)
class ReactionPopulation:
    """How people of a cell react and pause: comfort and stop distances Normal(mean, sd)
    (truncated to stay positive and ordered), slow pace U(lo, hi), a deviation's mid-cycle
    pause U(lo, hi) seconds."""

    comfort: tuple[float, float]
    stop: tuple[float, float]
    slow: tuple[float, float] = (0.3, 0.6)
    pause: tuple[float, float] = (2.0, 5.0)

    def draw(self, rng: np.random.Generator) -> Reaction:
        """One person's reaction, drawn around the population's."""
        comfort = max(float(rng.normal(*self.comfort)), 0.25 * self.comfort[0])
        stop = min(max(float(rng.normal(*self.stop)), 0.25 * self.stop[0]), 0.9 * comfort)
        return Reaction(comfort, stop, float(rng.uniform(*self.slow)))


@dataclass(frozen=True)
class SafetyLimits:
    """The robot's numbers for speed and separation monitoring (ISO/TS 15066 5.5.4):
    reaction time T_r and stopping time T_s (s), intrusion distance C, sensing and robot
    position uncertainties Z_d, Z_r (workspace units)."""

    reaction_time: float
    stopping_time: float
    intrusion: float
    sensing: float
    position: float

    @property
    def margin(self) -> float:
        """C + Z_d + Z_r: the protective distance from a still person to a still robot."""
        return self.intrusion + self.sensing + self.position


@dataclass(frozen=True)
class Deviation:
    """This cycle's deviation: its kind; for a pause, which of the person's tasks (index into
    the tasks they do, modulo their number), at which fraction of it, for how many seconds;
    ``pick`` in [0, 1) chooses among the options the person has when it happens."""

    kind: DeviationKind
    pick: float
    task: int = 0
    at: float = 0.5
    seconds: float = 0.0
    instead_of: DeviationKind | None = None  # the kind drawn first, when the plan had no room

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, **({"seconds": self.seconds} if self.kind == "pause" else {}),
                **({"instead_of": self.instead_of} if self.instead_of else {})}


def deviation_kinds(problem: Problem, schedule: Schedule) -> tuple[DeviationKind, ...]:
    """The deviations a cycle of ``schedule`` leaves room for, in :data:`DEVIATIONS` order:
    "order" when two of the person's tasks are not ordered by precedence (transitively), so
    that both can be ready at once; "pause" when the person has a task; "take" when a robot task
    a person may do has not started at the person's first choice (every robot task but the one
    the robot starts at once: its first, when nothing gates it)."""
    mine = schedule.tasks("human")
    after = closure(problem.ids, problem.precedence)
    free = any(b not in after[a] and a not in after[b]
               for k, a in enumerate(mine) for b in mine[k + 1:])
    seq = schedule.sequence("robot")
    first = seq[0] if seq and isinstance(seq[0], str) and not problem.preceding[seq[0]] else None
    takeable = any(problem.task(t).can("human") and t != first for t in schedule.tasks("robot"))
    room = {"order": free, "pause": bool(mine), "take": takeable}
    return tuple(k for k in DEVIATIONS if room[k])


def draw_deviation(p: float, rng: np.random.Generator, population: ReactionPopulation,
                   kinds: Sequence[DeviationKind] = DEVIATIONS) -> Deviation | None:
    """With probability ``p``, one deviation for this cycle (always the same draws, so a
    cycle's numbers do not depend on whether it deviates). ``kinds``: those the cycle has room
    for (:func:`deviation_kinds`); a kind drawn outside them is redrawn among them from the
    same number (where in its third of [0, 1) it fell), so every draw of a kind that has room
    is the one all kinds would give. None when no kind has room."""
    u, kind, pick, task, at, pause = rng.random(6)
    if u >= p or not kinds:
        return None
    k = min(int(kind * 3), 2)
    drawn: DeviationKind = DEVIATIONS[k]
    chosen = drawn
    if drawn not in kinds:
        chosen = kinds[min(int((kind * 3 - k) * len(kinds)), len(kinds) - 1)]
    lo, hi = population.pause
    return Deviation(chosen, float(pick), int(task * 1000), 0.2 + 0.6 * float(at),
                     lo + (hi - lo) * float(pause), None if chosen == drawn else drawn)


def cell_reactions(world: Any) -> tuple[ReactionPopulation, SafetyLimits]:
    """The world's reaction population and safety limits; a world that states none gets both
    scaled from its workspace's size (a tenth and a twentieth of its diagonal for comfort and
    stop, a hundredth for the margins)."""
    own = capability(world, "reactions")
    if own is not None:
        return own.reaction_population, own.safety_limits
    lo, hi = world.workspace_bounds
    size = float(np.linalg.norm(np.asarray(hi, float) - np.asarray(lo, float)))
    if not math.isfinite(size) or size <= 0:
        size = 1.0
    return (ReactionPopulation((size / 10, size / 40), (size / 20, size / 80)),
            SafetyLimits(0.1, 0.3, size / 100, size / 200, size / 400))
