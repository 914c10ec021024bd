"""No mutual hold lasts: the robot yields to a person who waits for it.

Speed and separation monitoring holds the robot while the person is near; a person who pauses
for a moving robot (:class:`~rapidds.worlds.reactions.Reaction`) may then wait for a robot that
waits for them. Neither moves again: the cycle is stuck (issue 34: one such hold at t = 600 s
stopped a 320-trial study). A real cell resolves it as a cobot does: the robot gives way.

The rule (docs/design-notes.md "No mutual hold lasts"): when the robot has a task and is held
(it made less than one tick ``dt`` of progress) while the person stood still, for ``after``
seconds together, the robot **yields**: it backs along its own path for at most ``retreat``
seconds of it (at the rate the monitor allows for that motion; never past the task's start),
then stands still, brakes on (a stopped robot is no threat: the person goes on), until the
task the person was doing has ended (``after`` seconds when they had none), and resumes. Both
conditions are observable in every cell (positions and the robot's progress), so the rule
needs no knowledge of why the person stopped.

A stall that recurs before any task has finished since the last yield is one yielding did not
resolve: the cycle cannot progress, a :class:`~rapidds.errors.RuntimeFault` (exit 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rapidds.errors import RuntimeFault

__all__ = ["YieldGuard", "YieldRule"]


@dataclass(frozen=True)
class YieldRule:
    """The stated times of the rule (see the module). after: seconds of a mutual hold before
    the robot yields; retreat: at most this many seconds of its own path it backs along;
    still: a person whose body points moved less (workspace units) stood still."""

    after: float = 2.0
    retreat: float = 1.0
    still: float = 1e-3

    def __post_init__(self) -> None:
        if not (self.after > 0 and self.retreat >= 0 and self.still >= 0):
            raise ValueError(f"a yield rule needs after > 0, retreat >= 0, still >= 0: {self}")


@dataclass
class _Stall:
    since: float
    person: np.ndarray
    progress: float


@dataclass
class _Yielding:
    entry: dict[str, Any]
    origin: float  # the robot's progress (s) when it yielded
    target: float  # the progress it backs to
    hold_from: float | None = None  # when it stopped backing and stood still


class YieldGuard:
    """Watches one cycle's robot for mutual holds and yields (see the module). ``yields``: one
    entry per yield, as the record keeps them."""

    def __init__(self, rule: YieldRule, dt: float):
        self.rule, self.dt = rule, dt
        self.yields: list[dict[str, Any]] = []
        self._stall: _Stall | None = None
        self._active: _Yielding | None = None
        self._finished_at_last: int | None = None

    @property
    def phase(self) -> str:
        """"" (not yielding), "retreat" or "hold"."""
        a = self._active
        return "" if a is None else "retreat" if a.hold_from is None else "hold"

    def retreat_left(self, progress: float) -> float:
        """Seconds of path the robot still backs in this yield (0 when not retreating)."""
        a = self._active
        return 0.0 if a is None or a.hold_from is not None else max(progress - a.target, 0.0)

    def rate(self, now: float, robot: tuple[str, float], person_task: str | None,
             person: np.ndarray, rates: tuple[float, float], finished: int) -> float:
        """The robot's rate at ``now`` (negative: backing along its path). robot: its task and
        progress (s); person_task: the person's running task; person: their body points;
        rates: what the monitor allows forwards and backwards; finished: tasks done so far."""
        forward = rates[0]
        task, progress = robot
        a = self._active
        if a is not None and a.entry["task"] != task:
            self._close(now)
            a = None
        if a is not None:
            return self._yielding(now, a, progress, person_task, rates)
        if forward >= 1.0:
            self._stall = None
            return forward
        s = self._stall
        if (s is None or float(np.abs(person - s.person).max(initial=0.0)) > self.rule.still
                or progress - s.progress >= self.dt - 1e-9):
            self._stall = _Stall(now, person.copy(), progress)
            return forward
        if now - s.since < self.rule.after - 1e-9:
            return forward
        if self._finished_at_last == finished:
            raise RuntimeFault(
                f"the cycle cannot progress at t = {now:.2f} s: the robot yielded on '{task}' "
                f"and is held again with no task finished since (the person "
                f"{'does ' + repr(person_task) if person_task else 'has no task to do'})")
        self._finished_at_last = finished
        self._stall = None
        entry = {"task": task, "person_task": person_task, "start": now,
                 "held": now - s.since, "retreat": 0.0, "end": None}
        self.yields.append(entry)
        self._active = _Yielding(entry, progress, max(progress - self.rule.retreat, 0.0))
        return self._yielding(now, self._active, progress, person_task, rates)

    def _yielding(self, now: float, a: _Yielding, progress: float, person_task: str | None,
                  rates: tuple[float, float]) -> float:
        forward, backward = rates
        if a.hold_from is None:
            a.entry["retreat"] = a.origin - progress
            backed = now - a.entry["start"] >= self.rule.retreat - 1e-9
            if progress <= a.target + 1e-9 or backed or backward <= 0.0:
                a.hold_from = now
            else:
                return -min(backward, 1.0)
        mine = a.entry["person_task"]
        if (person_task != mine) if mine is not None else now - a.hold_from >= self.rule.after:
            self._close(now)  # the person's task is done: the robot goes on from here
            return forward
        return 0.0

    def _close(self, now: float) -> None:
        a = self._active
        if a is not None:
            a.entry["end"] = now
            self._active = None
            self._stall = None

    def finish(self, now: float) -> list[dict[str, Any]]:
        """The cycle ended at ``now``: the yields, the open one closed."""
        self._close(now)
        return [dict(y) for y in self.yields]
