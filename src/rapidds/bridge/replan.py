"""Re-planning the rest of a live cycle when the person deviates (issue 34 item 4).

The simulated and browser cells re-plan inside their executor (:mod:`rapidds.execution.replan`);
a live cell's hub has no executor while the cycle runs, only the events and the tracking it
receives, so this is the same re-plan on what the hub sees. Deviations, as the executor knows
them: the person started a task of theirs other than their plan's next (``order``), or a task
of theirs ran past the 90 % quantile of its learned duration, mean + z sd (``overran``: a pause,
a slow hand), or the person started a robot task the hub had not sent (``took``: the hub's
observation accepts it for a task the person may do, and the task is theirs from then on).
A pause is seen as an overrun, as in the simulated executor.

The re-plan re-sequences the robot's tasks not yet sent with
:func:`~rapidds.execution.replan.replan_remainder` (the learned means as they stand, the
motions' durations, the spatial costs); the person's tasks stay theirs, in the order they are
doing them (a live person acts on their own: the hub cannot hand them work mid-cycle), and the
robot takes none of theirs (it has no motion steered for them). The hub then sends each robot
task once what precedence and the robot's new order put before it has ended, and names the
task in the trajectory's ``frame_id`` so the robot's driver reports it under that name.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from rapidds.execution.executor import Replanning
from rapidds.execution.replan import Progress, replan_remainder
from rapidds.problem import Problem

__all__ = ["LiveReplanner"]


@dataclass
class LiveReplanner:
    """One live cycle's re-plans. ``order``: agent -> its planned tasks; ``after``: task ->
    what must end before it starts (the plan's, replaced for a re-planned robot task);
    ``rp``: the learned models as they stand (:func:`rapidds.loop.execute.cycle_replanning`)."""

    problem: Problem
    order: dict[str, list[str]]
    after: dict[str, list[str]]
    rp: Replanning
    replans: list[dict[str, Any]] = field(default_factory=list)
    taken: set[str] = field(default_factory=set)  # robot tasks the person took
    _seen: set[str] = field(default_factory=set)  # the person's starts already looked at
    _overran: set[str] = field(default_factory=set)

    def deviations(self, now: float, start: Mapping[str, float], end: Mapping[str, float],
                   human: Sequence[str]) -> list[tuple[str, str]]:
        """What the person did since the last call that the plan did not expect: (reason,
        task). ``start``/``end``: cell times of the tasks' events; ``human``: tasks the person
        started, in the order they started them."""
        out = []
        for task in human:
            if task in self._seen:
                continue
            self._seen.add(task)
            if task in self.order["robot"]:
                self.taken.add(task)
                out.append(("took", task))
                continue
            mine = [t for t in self.order["human"] if t not in start or t == task]
            if mine and mine[0] != task:
                out.append(("order", task))
        for task in human:
            if task in end or task in self._overran or task not in self.rp.mean:
                continue
            if now - start[task] > self.rp.mean[task] + self.rp.z * self.rp.std.get(task, 0.0):
                self._overran.add(task)
                out.append(("overran", task))
        return out

    def replan(self, now: float, reason: str, task: str, start: Mapping[str, float],
               end: Mapping[str, float], sent: Sequence[str]) -> dict[str, Any]:
        """Re-sequence the robot's tasks not yet sent (see the module); the new ``order`` and
        ``after`` take effect at once. Returns the re-plan's entry, as the executor keeps it."""
        t0 = time.perf_counter()
        rp = self.rp
        agent = {t: a for a, o in self.order.items() for t in o}
        agent.update({t: "human" for t in self.taken})
        fixed: dict[str, tuple[str, float, float]] = {}
        free = {"human": now, "robot": now}
        for t, s in start.items():
            a = agent[t]
            f = end.get(t)
            if f is None:  # running: expected to end at its mean (the person's) or motion's
                f = max(now, s + (rp.mean.get(t, 0.0) if a == "human" else rp.robot.get(t, 0.0)))
                free[a] = f
            fixed[t] = (a, s, f)
        current = {"human": [t for t in self.order["human"] if t not in start],
                   "robot": [t for t in self.order["robot"] if t not in sent and t not in start]}
        was = [t for t in self.order["robot"] if t not in self.taken]
        mean = {f"human:{t}": m for t, m in rp.mean.items()}
        mean.update({f"robot:{t}": d for t, d in rp.robot.items()})
        rem = replan_remainder(self.problem, Progress(now, current, fixed, free, mean),
                               frozenset(current["robot"]), rp.spatial, rp.gamma,
                               claimed=frozenset(current["human"]))
        robot = list(rem.robot) if list(rem.human) == current["human"] else current["robot"]
        changed = robot != current["robot"]
        if changed or was != self.order["robot"]:  # unchanged, the plan's order and waits stay
            self.order["robot"] = [t for t in was if t in sent or t in start] + robot
            prev = next((t for t in reversed(self.order["robot"]) if t in sent), None)
            for t in robot:
                self.after[t] = sorted({*self.problem.preceding[t], *([prev] if prev else [])})
                prev = t
        entry = {"time": now, "reason": reason, "task": task, "changed": changed,
                 "before": current,
                 "after": {"human": current["human"], "robot": robot},
                 "expected_makespan_cost": rem.objective,
                 "expected_cost_before": rem.current if math.isfinite(rem.current) else None,
                 "evaluated": rem.evaluated, "latency_s": time.perf_counter() - t0}
        self.replans.append(entry)
        return entry
