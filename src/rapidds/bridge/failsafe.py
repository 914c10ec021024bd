"""Fail safe, never silent: the hub's checks that its safety function can do its job.

ISO 10218-2:2025 (which absorbed ISO/TS 15066) asks of a safety function that cannot do its job
that it stop the robot and say so. The live cell's speed and separation monitor cannot when it
does not know where the robot is (joint states under other names, stale), where the person is
(a body point not tracked, stale), or when the robot does not obey its speed scaling. Each of
these here ends as a fault: a stop on ``/rapidds/stop``, one line, nothing recorded (exit 3):

- :class:`ReadyCheck`: before the first cycle, the robot's joint states carry exactly the names
  (and so the count) the robot profile expects, and every body point is tracked within
  :data:`READY_WINDOW` wall s of the first tracked one. During a cycle a joint state under other
  names is a fault too (:func:`joint_state_fault`), not a live robot.
- :class:`MonitorGuard`: during a reactive cycle, the monitor held blind (no robot state, no
  tracking, stale data) for over :data:`BLIND_LIMIT` cell s; a robot that, held at scaling 0,
  still travels over :data:`DRIFT` once its stopping time T_s and :data:`OBEY_TOLERANCE` are
  over (:meth:`MonitorGuard.check`; one outrunning a partial scaling is logged); a cycle in
  which a robot task ran with no watched tick (:meth:`MonitorGuard.unwatched`).

The times and tolerances and why they are what they are: docs/design-notes.md, "Fail safe,
never silent".
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from rapidds.bridge.link import Received, log
from rapidds.bridge.live import TRACKING_PREFIX
from rapidds.bridge.ros2 import JOINT_STATE_TOPIC

if TYPE_CHECKING:
    from rapidds.bridge.reactive import SpeedMonitor
    from rapidds.motion.timing import TimedTrajectory

__all__ = [
    "BLIND_LIMIT",
    "DRIFT",
    "OBEY_TOLERANCE",
    "OVERSPEED",
    "READY_WINDOW",
    "STILL",
    "WATCHDOG",
    "MonitorGuard",
    "ReadyCheck",
    "joint_state_fault",
    "planned_joint_speeds",
]

READY_WINDOW = 1.0
"""Wall s after the first tracked body point by which every body point must have been tracked
(a tracker sends all of them at least every dt, at rest too)."""
BLIND_LIMIT = 1.0
"""Cell s the monitor may hold the robot without being able to compute the separation before
the cycle faults (a short occlusion holds and resumes; a lost tracker or robot state stops)."""
OBEY_TOLERANCE = 0.3
"""Cell s past the robot's stopping time T_s that a robot may take to follow a lower scaling
(the scaling's delivery and the arm's settling tail; measured in docs/design-notes.md)."""
STILL = 0.05
"""Joint speed (rad/s, or the world's joint units per s) that a partial scaling's bound allows
on top (the reference arm's settling tail is under 0.022 rad/s 0.3 s after a hard drop to 0)."""
DRIFT = 0.1
"""Joint travel (rad, or the world's joint units) a robot held at scaling 0 may still make once
T_s and the tolerance are over: a person leaning on a held Panda's wrist moves it (0.13 rad/s
measured, springing back); a driver that ignores the hold travels on at its planned speed."""
OVERSPEED = 1.0
"""Fraction by which a joint's measured speed may exceed the commanded scaling times its
planned speed (the reference arm overshoots its planned speed by up to 61 % on a wrist joint)."""
WATCHDOG = 0.25
"""Cell s without a speed scaling after which a robot that has been scaled in this cycle holds
(five of the monitor's 20 Hz ticks); the reference robot's watchdog."""


def _names(names: Sequence[str]) -> str:
    return ", ".join(names) if names else "none"


def joint_state_fault(names: Sequence[str], positions: Sequence[float],
                      expected: Sequence[str], extra: Sequence[str] = (),
                      profile: str = "the robot profile") -> str | None:
    """Why a ``JointState`` is not the robot the profile expects, or None when it is: each of
    ``expected`` once, nothing else but the profile's ``extra`` joints (a gripper's fingers),
    a finite position per name."""
    got = [str(n) for n in names]
    arm = [n for n in got if n not in extra]
    if sorted(arm) != sorted(expected) or len(positions) != len(got):
        also = f" and may carry {_names(list(extra))}" if extra else ""
        return (f"the robot's joint states carry {len(got)} joint(s) ({_names(got)}) with "
                f"{len(positions)} position(s); {profile} expects {len(expected)} "
                f"({_names(list(expected))}){also}")
    if not np.isfinite(np.asarray(positions, float)).all():
        return "the robot's joint states carry positions that are not finite"
    return None


@dataclass
class ReadyCheck:
    """What the hub has seen of the nodes before its first cycle. ``fault`` is set on the first
    joint state under other names than ``joints``; ``see`` and :meth:`result` say when both the
    robot and every body point of ``points`` are there, or why they are not."""

    joints: tuple[str, ...]
    points: tuple[str, ...]
    extra: tuple[str, ...] = ()  # joints the profile allows beyond ``joints`` (fingers)
    profile: str = "the robot profile"  # how the message names it
    window: float = READY_WINDOW
    robot: bool = False
    fault: str | None = None
    tracked: set[str] = field(default_factory=set)
    _first_track: float | None = None

    def see(self, rec: Received) -> None:
        if rec.topic == JOINT_STATE_TOPIC:
            why = joint_state_fault(rec.msg.name, rec.msg.position, self.joints, self.extra,
                                    self.profile)
            self.robot |= why is None
            self.fault = self.fault or why
        elif rec.topic.startswith(TRACKING_PREFIX):
            name = rec.topic[len(TRACKING_PREFIX):]
            if name in self.points:
                self.tracked.add(name)
                if self._first_track is None:
                    self._first_track = time.monotonic()

    @property
    def ready(self) -> bool:
        return self.robot and self.tracked == set(self.points)

    def result(self, now: float | None = None) -> str | None:
        """A fault now: a robot under other names, or a body point still untracked
        ``window`` s after the first tracked one; None while it may still come."""
        if self.fault is not None:
            return self.fault
        now = time.monotonic() if now is None else now
        if self._first_track is not None and now - self._first_track > self.window:
            missing = [p for p in self.points if p not in self.tracked]
            if missing:
                return (f"body point(s) {_names(missing)} not tracked {self.window:g} s after "
                        f"the tracker's first sample (tracked: {_names(sorted(self.tracked))}); "
                        f"the world expects {_names(list(self.points))}")
        return None


def planned_joint_speeds(timed: Mapping[str, TimedTrajectory]) -> dict[str, np.ndarray]:
    """Each robot task's fastest speed per joint along the trajectory the hub sends it: the
    larger of its samples' velocities and the chords between them (ruckig's timing; a path's
    rows at dt overstate a step the arm's limits slow down and understate a rest-to-rest one)."""
    out = {}
    for task, traj in timed.items():
        speed = np.abs(np.asarray(traj.velocities, float)).max(axis=0)
        if len(traj.times) > 1:
            chord = np.abs(np.diff(traj.positions, axis=0)) / np.diff(traj.times)[:, None]
            speed = np.maximum(speed, chord.max(axis=0))
        out[task] = speed
    return out


@dataclass
class MonitorGuard:
    """Watches one reactive cycle's monitor at its ticks. ``speeds``: the robot tasks'
    :func:`planned_joint_speeds`; ``stopping_time``: the world's T_s."""

    speeds: Mapping[str, np.ndarray]
    stopping_time: float
    blind_limit: float = BLIND_LIMIT
    tolerance: float = OBEY_TOLERANCE
    ran: bool = False  # a robot task ran at some tick
    warned: bool = False  # the robot outran a partial scaling (logged once a cycle)
    _zero_since: float | None = None  # when the scaling last went to 0
    _hold_q: np.ndarray | None = None  # where the held robot was once it had had time to stop
    _blind_since: float | None = None
    _rates: deque[tuple[float, float]] = field(default_factory=deque)  # (tick, rate commanded)

    @property
    def settle(self) -> float:
        """Cell s a robot may take to follow a lower scaling: T_s plus the tolerance."""
        return self.stopping_time + self.tolerance

    def check(self, now: float, monitor: SpeedMonitor, task: str | None) -> str | None:
        """After the monitor's tick at ``now`` (the rate it set is ``monitor.rate``) with robot
        task ``task`` running: why the cycle must fault, or None."""
        self.ran |= task is not None
        blind = monitor.blind if task is not None else None
        if blind is None:
            self._blind_since = None
        elif self._blind_since is None:
            self._blind_since = now
        elif now - self._blind_since > self.blind_limit:
            return (f"the speed and separation monitor could not compute the separation for "
                    f"{now - self._blind_since:.2f} s ({blind}; limit {self.blind_limit:g} s)")
        allowed = self._allowed(now)
        if monitor.rate > 0.0:
            self._zero_since = self._hold_q = None
        elif self._zero_since is None:
            self._zero_since = now
        self._rates.append((now, monitor.rate))
        measured = monitor.joint_speed()
        if task is None or measured is None:
            return None
        if allowed > 0.0:  # slowed, not held: said, not stopped (a pushed arm moves too)
            bound = allowed * self.speeds.get(task, np.inf) * (1.0 + OVERSPEED) + STILL
            if (measured > bound).any() and not self.warned:
                self.warned = True
                j = int(np.argmax(measured - bound))
                log.warning("the robot ran faster than its speed scaling allows: joint %d at "
                            "%.3f/s where scaling %g allows %.3f/s", j + 1, measured[j],
                            allowed, bound[j])
            return None
        q = monitor.joint_position()
        if self._zero_since is None or q is None or now - self._zero_since < self.settle:
            return None
        if self._hold_q is None:  # T_s and the tolerance are over: from here it holds still
            self._hold_q = q
            return None
        drift = np.abs(q - self._hold_q)
        if drift.max() <= DRIFT:
            return None
        j = int(np.argmax(drift))
        return (f"the robot does not obey the speed scaling: joint {j + 1} moved {drift[j]:.3f} "
                f"(at {measured[j]:.3f}/s) while held, {now - self._zero_since:.2f} s after the "
                f"scaling went to 0 (it may take T_s {self.stopping_time:g} s + "
                f"{self.tolerance:g} s to stop, then {DRIFT:g})")

    def _allowed(self, now: float) -> float:
        """The highest scaling in force over the last ``settle`` s before ``now`` (a robot may
        still be slowing down from it); 1 before the cycle's first tick (the hub sends 1
        between cycles)."""
        rates = self._rates
        while len(rates) > 1 and rates[1][0] <= now - self.settle:
            rates.popleft()
        if not rates or rates[0][0] > now - self.settle:
            return 1.0
        return max(r for _, r in rates)

    def unwatched(self, monitor: SpeedMonitor) -> str | None:
        """A robot task ran and the monitor watched no tick of it: never recorded."""
        if self.ran and not monitor.trace:
            return ("a robot task ran and the speed and separation monitor watched none of its "
                    "ticks (protective.watched = 0)")
        return None
