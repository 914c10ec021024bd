"""Speed and separation monitoring in a live cell: the hub's reactive layer.

At a fixed rate of the cell clock the layer takes the person's body points (their last tracked
positions), the robot's (its last ``JointState`` through the world's forward kinematics) and
asks the run's policy for the robot's rate, which goes out as the speed scaling
(:data:`~rapidds.bridge.live.SPEED_SCALING_TOPIC`). The policy is built by the same factory as
the simulated executor's, the run's registered execution entry
(:meth:`~rapidds.execution.registry.ExecutionSetting.policy`: speed and separation monitoring,
:class:`~rapidds.execution.SpeedSeparation`, for the built-in entries), so the math is the
executor's: the same policy and :func:`~rapidds.execution.protective_distance`,
the person's speed the fastest body point's (here between its last two tracked samples, by
their stamps); what a live robot changes is the robot's side: its points are measured, not
replayed (its speed measured over ``WINDOW`` cell s of joint states), and its speed
at full rate is that of the running task's trajectory as the hub sent it (ruckig's timing,
:func:`planned_speeds`) at its fastest (the layer does not know how far along its path a
held robot is, so it takes the bound, never the lower value).
Its T_r is the whole reaction time of this safety function (ISO/TS 15066): the world's plus
the live latencies, the person's sample age, a tick period and the scaling's ``DELIVERY``.

A person not tracked for ``STALE`` cell s (a tracker that stalls, a lost link) holds the robot,
as a missing sensor does in a safety controller: their last position says nothing of now. Such
a pause's reason is ``no tracking (stop)``; a robot whose last joint state is that old holds
too (``no robot state (stop)``). Held so for long, the cycle faults
(:class:`~rapidds.bridge.failsafe.MonitorGuard`).

Pauses are kept as the executor keeps them (``{"agent": "robot", "task", "start", "end",
"reason": "protective distance (stop|slow)"}``), and ``protective`` checks every tick at which
the robot moved against the protective distance at its measured speed. Moved: it was allowed
to (the last tick's rate was above 0) and its points went faster than :data:`MOVING` over the
tick; a held arm that the person's body pushes is no robot motion.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.execution.policies import (
    RobotPolicy,
    Scene,
    directed_speeds,
    protective_check,
)
from rapidds.execution.registry import ExecutionSetting, Monitored
from rapidds.motion.timing import TimedTrajectory
from rapidds.worlds.base import World
from rapidds.worlds.reactions import SafetyLimits, cell_reactions

__all__ = ["SpeedMonitor", "planned_speeds"]

WINDOW = 0.1
"""Cell seconds of joint states the robot's measured speed spans (one state to the next is
too short: a node that catches up sends several at once)."""
STALE = 0.5
"""Cell seconds after which the person's last tracked sample no longer counts."""
DELIVERY = 0.05
"""Cell seconds a speed scaling may take to act on the robot: the reference robot reads the
link between 50 ms passes of its physics (a real driver's own figure belongs here)."""
MOVING = 0.01
"""Workspace units per second below which the measured robot counts as still (a held arm's
servo jitter, sensor noise)."""
_LEAD = 1e-4
"""Seconds of a sample's joint velocity whose forward kinematics give its points' speed."""


def planned_speeds(world: World, timed: Mapping[str, TimedTrajectory]) -> dict[str, float]:
    """Each robot task's fastest body-point speed along the trajectory the hub sends it
    (units/s): ruckig's timing, not the path's rows at dt (a row step the arm's limits slow
    down, a rest-to-rest step whose peak is above its mean). At every sample the points'
    speed along the joint velocity (J(q) q' by a forward difference), and the chords between
    samples: the larger."""
    out = {}
    for task, traj in timed.items():
        q, v = np.asarray(traj.positions, float), np.asarray(traj.velocities, float)
        pts = world.robot_points(q)
        ahead = world.robot_points(q + v * _LEAD)
        speed = float(np.linalg.norm(ahead - pts, axis=-1).max() / _LEAD)
        if len(q) > 1:
            chord = np.linalg.norm(np.diff(pts, axis=0), axis=-1).max(axis=-1)
            speed = max(speed, float((chord / np.diff(traj.times)).max()))
        out[task] = speed
    return out


@dataclass
class SpeedMonitor:
    """One cycle's monitor. ``speeds``: :func:`planned_speeds` of the cycle's robot tasks
    (their trajectories as the hub sends them);
    ``period``: cell seconds between its ticks; ``execution``: the run's execution entry, which
    builds the policy (one that monitors)."""

    world: World
    speeds: Mapping[str, float]
    period: float = 0.05
    execution: ExecutionSetting = field(default_factory=Monitored)
    limits: SafetyLimits = field(init=False)
    rate: float = 1.0
    pauses: list[dict[str, Any]] = field(default_factory=list)
    # every tick while a robot task ran: (t, separation, person's speed, robot's measured speed
    # over the tick, the rate in force over the tick); the record's ``protective`` comes from it
    trace: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    _robot_seen: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (t, q)
    _held: tuple[float, str, str] | None = None  # since, reason, task
    # why the last tick could not compute the separation (None: it could); bridge.failsafe
    # turns a long one into a fault
    blind: str | None = None

    def __post_init__(self) -> None:
        _, self.limits = cell_reactions(self.world)
        if not self.execution.monitor:
            raise RapiddsError(f"execution '{self.execution.kind}' does not monitor: the cell "
                               "runs no monitor under it")

    def joint_state(self, q: np.ndarray, at: float) -> None:
        """The robot's joint positions at cell time ``at`` (its state's stamp). Kept as they
        come (hundreds a second); the forward kinematics run at the ticks only."""
        seen = self._robot_seen
        seen.append((at, np.asarray(q, float)))
        while len(seen) > 2 and seen[1][0] <= at - WINDOW:
            seen.pop(0)

    def _robot(self) -> tuple[np.ndarray, float] | None:
        """The robot's points now and its fastest point's speed over the last ``WINDOW`` of
        joint states (units/s); None before its first state."""
        seen = self._robot_seen
        if not seen:
            return None
        pts = self.world.robot_points(np.stack([seen[0][1], seen[-1][1]]))
        span = seen[-1][0] - seen[0][0]
        speed = float(np.linalg.norm(pts[1] - pts[0], axis=-1).max() / span) if span > 0 else 0.0
        return pts[1], speed

    def tick(self, now: float, person: tuple[np.ndarray, float, float] | None,
             task: str | None, velocity: np.ndarray | None = None) -> float:
        """The rate at cell time ``now`` with the person's body points, speed and the time of
        their oldest sample ``person`` (None: not tracked yet) while robot task ``task`` runs
        (None: idle, full rate); ``velocity``: their points' velocities (K, 3), for their
        speed towards the robot (None: their speed counts as towards it). Untracked or stale:
        held."""
        robot = self._robot()
        why = "protective distance"
        self.blind = self._blind(now, person)
        if task is None:
            rate = 1.0
        elif self.blind is not None:
            rate, why = 0.0, "no tracking" if "person" in self.blind else "no robot state"
        else:
            (human, speed, _), (points, vr) = person, robot
            # the robot's direction along its path is unknown here (a held arm's, at full
            # rate): its planned fastest speed counts as towards the person, the bound
            scene = Scene(human, velocity, points, None, self.speeds.get(task, 0.0), speed)
            sep, vh, _ = directed_speeds(scene)
            rate = self.policy_now(now - person[2]).rate(scene)
            self.trace.append((now, sep, vh, vr, self.rate))
        self._log(now, rate, task, why)
        self.rate = rate
        return rate

    def _blind(self, now: float, person: tuple[np.ndarray, float, float] | None) -> str | None:
        """Why the separation cannot be computed at ``now``, or None: a person or a robot not
        seen yet, or their last sample over ``STALE`` cell s old (their stamps are late)."""
        if person is None:
            return "the person's body points are not all tracked"
        if now - person[2] > STALE:
            return f"the person's tracking is {now - person[2]:.2f} s old"
        if not self._robot_seen:
            return "no robot joint state"
        if now - self._robot_seen[-1][0] > STALE:
            return f"the robot's joint state is {now - self._robot_seen[-1][0]:.2f} s old"
        return None

    def joint_position(self) -> np.ndarray | None:
        """The robot's last joint positions; None before its first state."""
        return self._robot_seen[-1][1] if self._robot_seen else None

    def joint_speed(self) -> np.ndarray | None:
        """Each joint's measured speed over the last ``WINDOW`` of joint states (units/s);
        None before two states."""
        seen = self._robot_seen
        span = seen[-1][0] - seen[0][0] if len(seen) > 1 else 0.0
        return np.abs(seen[-1][1] - seen[0][1]) / span if span > 0 else None

    def policy_now(self, age: float) -> RobotPolicy:
        """The execution entry's policy with ISO/TS 15066's T_r as the whole reaction time of
        this safety function: the world's (the robot's own) plus the latencies the live monitor
        adds, the age of the person's sample, up to a tick period until it looks again, and the
        scaling's delivery. The arm's T_s stays the world's: the reference arm stops well
        within it (docs/design-notes.md). The protective check keeps the world's limits."""
        late = max(age, 0.0) + self.period + DELIVERY
        policy = self.execution.policy(replace(self.limits,
                                               reaction_time=self.limits.reaction_time + late))
        assert policy is not None  # an entry that monitors builds one (__post_init__)
        return policy

    def _log(self, now: float, rate: float, task: str | None, why: str) -> None:
        kind = "" if rate >= 1.0 or task is None else "stop" if rate <= 0.0 else "slow"
        reason = f"{why} ({kind})"
        if self._held is not None and (self._held[1] != reason or self._held[2] != task):
            since, was, held = self._held
            self.pauses.append({"agent": "robot", "task": held, "start": since, "end": now,
                                "reason": was})
            self._held = None
        if kind and self._held is None and task is not None:
            self._held = (now, reason, task)

    def close(self, now: float) -> None:
        """The cycle is over at ``now``: a pause still open ends there."""
        self._log(now, 1.0, None, "")

    def protective(self) -> dict[str, Any]:
        """As the executor reports it: ticks watched, those at which the robot moved, those
        of them inside the protective distance at its measured speed, the closest margin."""
        return protective_check(self.limits, len(self.trace),
                                ((sep, vh, vr) for _, sep, vh, vr, allowed in self.trace
                                 if allowed > 0.0 and vr > MOVING))
