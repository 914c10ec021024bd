"""Speed and separation monitoring in a live cell: the hub's reactive layer.

At a fixed rate of the cell clock the layer takes the person's body points (their last tracked
positions), the robot's (its last ``JointState`` through the world's forward kinematics) and
asks the executor's :class:`~rapidds.execution.SpeedSeparation` policy for the robot's rate,
which goes out as the speed scaling (:data:`~rapidds.bridge.live.SPEED_SCALING_TOPIC`). The
math is the executor's: the same policy and :func:`~rapidds.execution.protective_distance`,
the person's speed measured the same way (the fastest body point over the last tick); what a
live robot changes is the robot's side: its points are measured, not replayed, and its speed
at full rate is the planned one of the running task at its fastest (the layer does not know
how far along its path a held robot is, so it takes the bound, never the lower value).

Pauses are kept as the executor keeps them (``{"agent": "robot", "task", "start", "end",
"reason": "protective distance (stop|slow)"}``), and ``protective`` checks every tick at which
the robot moved against the protective distance at its measured speed. Moved: it was allowed
to (the last tick's rate was above 0) and its points went faster than :data:`MOVING` over the
tick; a held arm that the person's body pushes is no robot motion.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rapidds.execution.policies import SpeedSeparation, protective_distance
from rapidds.worlds.base import World
from rapidds.worlds.reactions import SafetyLimits, cell_reactions

__all__ = ["SpeedMonitor", "planned_speeds"]

MOVING = 0.01
"""Workspace units per second below which the measured robot counts as still (a held arm's
servo jitter, sensor noise)."""


def planned_speeds(world: World, trajectories: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Each robot task's fastest body-point speed along its planned trajectory (units/s)."""
    out = {}
    for task, traj in trajectories.items():
        pts = world.robot_points(np.asarray(traj, float))
        step = np.linalg.norm(np.diff(pts, axis=0), axis=-1).max() if len(pts) > 1 else 0.0
        out[task] = float(step / world.dt)
    return out


@dataclass
class SpeedMonitor:
    """One cycle's monitor. ``speeds``: :func:`planned_speeds` of the cycle's robot tasks."""

    world: World
    speeds: Mapping[str, float]
    limits: SafetyLimits = field(init=False)
    rate: float = 1.0
    pauses: list[dict[str, Any]] = field(default_factory=list)
    # every tick while a robot task ran: (t, separation, person's speed, robot's measured speed
    # over the tick, the rate in force over the tick); the record's ``protective`` comes from it
    trace: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    _robot: np.ndarray | None = None
    _robot_last: tuple[float, np.ndarray] | None = None
    _robot_speed: float = 0.0
    _human_last: tuple[float, np.ndarray] | None = None
    _held: tuple[float, str, str] | None = None  # since, kind, task

    def __post_init__(self) -> None:
        _, self.limits = cell_reactions(self.world)
        self.policy = SpeedSeparation(self.limits)

    def joint_state(self, q: np.ndarray) -> None:
        """The robot's latest joint positions."""
        self._robot = self.world.robot_points(np.asarray(q, float)[None])[0]

    def tick(self, now: float, human: np.ndarray | None, task: str | None) -> float:
        """The rate at cell time ``now`` with the person at ``human`` (P, 3; None: not tracked
        yet, the robot is held) while robot task ``task`` runs (None: idle, full rate)."""
        vh = 0.0
        if human is not None and self._human_last is not None and now > self._human_last[0]:
            step = np.linalg.norm(human - self._human_last[1], axis=-1).max()
            vh = float(step / (now - self._human_last[0]))
        if human is not None:
            self._human_last = (now, human)
        robot = self._robot
        if robot is not None and self._robot_last is not None and now > self._robot_last[0]:
            step = np.linalg.norm(robot - self._robot_last[1], axis=-1).max()
            self._robot_speed = float(step / (now - self._robot_last[0]))
        if robot is not None:
            self._robot_last = (now, robot)
        if task is None:
            rate = 1.0
        elif human is None or robot is None:
            rate = 0.0
        else:
            sep = float(np.linalg.norm(human[:, None] - robot[None], axis=-1).min())
            rate = self.policy.rate(sep, vh, self.speeds.get(task, 0.0))
            self.trace.append((now, sep, vh, self._robot_speed, self.rate))
        self._log(now, rate, task)
        self.rate = rate
        return rate

    def _log(self, now: float, rate: float, task: str | None) -> None:
        kind = "" if rate >= 1.0 or task is None else "stop" if rate <= 0.0 else "slow"
        if self._held is not None and (self._held[1] != kind or self._held[2] != task):
            since, was, held = self._held
            self.pauses.append({"agent": "robot", "task": held, "start": since, "end": now,
                                "reason": f"protective distance ({was})"})
            self._held = None
        if kind and self._held is None and task is not None:
            self._held = (now, kind, task)

    def close(self, now: float) -> None:
        """The cycle is over at ``now``: a pause still open ends there."""
        self._log(now, 1.0, None)

    def protective(self) -> dict[str, Any]:
        """As the executor reports it: ticks watched, those at which the robot moved, those
        of them inside the protective distance at its measured speed, the closest margin."""
        margins = [sep - protective_distance(self.limits, vh, vr)
                   for _, sep, vh, vr, allowed in self.trace if allowed > 0.0 and vr > MOVING]
        return {"watched": len(self.trace), "moving": len(margins),
                "moving_inside": sum(m < -1e-9 for m in margins),
                "closest_margin": min(margins, default=None)}
