"""The loop's part of planning for the safety monitor: a run's hold model, the motion model that
gives every robot motion its predicted hold, and learning the correction from what the executor
recorded (docs/design-notes.md "Plans that expect the safety monitor").

Under ``--execution reactive`` with ``--slowdowns learned`` (its default there) or
``predicted``, every robot motion the scheduler is offered carries the seconds the monitor is
predicted to add (:class:`~rapidds.execution.slowdowns.HoldModel`), steering's value includes
them and the Monte-Carlo makespan adds them to the motion's duration. ``learned`` corrects the
prediction per (robot task, person's task) with a
:class:`~rapidds.human.slowdowns.SlowdownBelief`, stored with the model after every cycle.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rapidds.execution.deployment import Deployment
from rapidds.execution.slowdowns import HoldModel, approach_speeds
from rapidds.human.slowdowns import SlowdownBelief, pair_key
from rapidds.human.spatial import SpatialModel
from rapidds.loop.config import RunConfig
from rapidds.motion.interface import MotionKey, MotionModel, MotionPlan
from rapidds.problem import Problem
from rapidds.record import Slowdowns as SlowdownRecord
from rapidds.worlds.base import World
from rapidds.worlds.reactions import cell_reactions

__all__ = ["Slowdowns", "WithHolds"]


class WithHolds:
    """A motion model whose plans carry ``hold`` from ``model`` (carried plans too: their
    trajectory is still a sample of its steering problem, and its hold is re-predicted with the
    correction as it stands)."""

    def __init__(self, inner: MotionModel, model: HoldModel):
        self.inner, self.model = inner, model

    def nominal_durations(self, problem: Problem) -> np.ndarray:
        return self.inner.nominal_durations(problem)

    def plan(self, requests: Sequence[MotionKey]) -> list[MotionPlan]:
        out = []
        for p in self.inner.plan(requests):
            if p.concurrent and p.trajectory is not None:
                hold = float(self.model.hold(p.task, p.concurrent, p.trajectory[None])[0])
                p = dataclasses.replace(p, hold=hold)
            out.append(p)
        return out


class Slowdowns:
    """A run's slowdown model: what it predicts with and how it learns (``config``'s
    ``slowdown_mode``; ``off``: nothing, the paper's planner)."""

    def __init__(self, world: World, config: RunConfig):
        self.world, self.mode = world, config.slowdown_mode
        self.monitored = config.execution.monitor  # only a monitor holds the robot
        self.limits = cell_reactions(world)[1]
        self._speeds: tuple[Any, dict[str, np.ndarray]] | None = None  # (grid, speeds)
        self.prior = (config.slowdown_mean, config.slowdown_sd)

    def belief(self) -> SlowdownBelief | None:
        """A new run's belief: the prior (``learned`` only)."""
        return SlowdownBelief(*self.prior) if self.mode == "learned" else None

    def model(self, spatial: SpatialModel, belief: SlowdownBelief | None) -> HoldModel | None:
        """The hold model against the path belief ``spatial`` (None when off)."""
        if self.mode == "off":
            return None
        return HoldModel(self.world, spatial, self.limits, self.speeds(spatial),
                         belief if self.mode == "learned" else None)

    def speeds(self, spatial: SpatialModel) -> dict[str, np.ndarray]:
        """The person's approach speeds on ``spatial``'s grid, computed once per grid."""
        grid = (spatial.config.bounds, spatial.config.shape)
        if self._speeds is None or self._speeds[0] != grid:
            self._speeds = (grid, approach_speeds(self.world, spatial, self.limits))
        return self._speeds[1]

    def wrap(self, motion: MotionModel, model: HoldModel | None) -> MotionModel:
        return motion if model is None else WithHolds(motion, model)

    def observe(self, spatial: SpatialModel, motions: Mapping[str, MotionPlan],
                dep: Deployment, belief: SlowdownBelief | None) -> SlowdownRecord | None:
        """The cycle's slowdowns for its record, and the belief learns them: per robot task the
        predicted hold and the time it really lost (its realised duration beyond its motion's);
        per (robot task, person's task it ran beside) the uncorrected prediction and the share
        of the loss in the robot's pauses while that task ran. ``spatial`` must still be the
        path belief the plan was made with. Motions a re-plan replaced are not learned from.
        None under planned execution (its records stay the paper's)."""
        if not self.monitored:
            return None
        model = self.model(spatial, None)
        tl, idx = dep.timeline, dep.timeline.problem.index
        sched = tl.schedule
        swapped = {m["task"] for r in dep.replans for m in r.get("motions", []) if m.get("used")}
        lost: dict[str, float] = {}
        pairs: dict[str, list[float]] = {}
        for j in sched.tasks("robot"):
            m = motions.get(j)
            if m is None or j in swapped:
                continue
            s, f = float(tl.start[0, idx[j]]), float(tl.finish[0, idx[j]])
            lost[j] = max(0.0, f - s - m.duration)
            near = {i: (max(s, float(tl.start[0, idx[i]])), min(f, float(tl.finish[0, idx[i]])))
                    for i in sched.tasks("human")}
            near = {i: w for i, w in near.items() if w[1] > w[0] + 1e-9}
            if not near or model is None or m.trajectory is None:
                continue
            raw = model.raw(j, near, np.asarray(m.trajectory)[None])
            share = _shares(j, near, dep.pauses)
            for i in near:
                pairs[pair_key(j, i)] = [float(raw[i][0]), lost[j] * share[i]]
                if belief is not None:
                    belief.observe(j, i, float(raw[i][0]), lost[j] * share[i])
        return SlowdownRecord(self.mode, {j: m.hold for j, m in motions.items()}, lost,
                              {k: (v[0], v[1]) for k, v in pairs.items()},
                              None if belief is None else belief.summary())


def _shares(task: str, near: Mapping[str, tuple[float, float]],
            pauses: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Each concurrent person's task's share of robot task ``task``'s held time: by the time of
    its pauses inside the task's window, or by the windows' lengths when it has no pause."""
    held = {i: sum(max(0.0, min(e, p["end"]) - max(s, p["start"])) for p in pauses
                   if p.get("agent") == "robot" and p.get("task") == task)
            for i, (s, e) in near.items()}
    total = sum(held.values())
    if total <= 1e-9:
        held = {i: e - s for i, (s, e) in near.items()}
        total = sum(held.values())
    return {i: h / total for i, h in held.items()}
