"""The live cycle's contract beyond :mod:`rapidds.bridge.ros2`: the plan as the nodes read it,
the cell clock, and the person's executions rebuilt from events and tracking.

Clock: stamps are wall-clock nanoseconds since the Unix epoch, as ROS 2 stamps are (the hub and
the nodes share a clock: one machine, or NTP/PTP in a cell). The plan names the cycle's start
``stamp_ns`` and a ``time_scale``: cell seconds = (stamp - stamp_ns) x time_scale / 1e9. A
scale of 1 is real time; a larger one runs the simulated nodes faster than the wall clock (the
tests do); a real cell runs at 1.

A task event may carry its sender's stamp (``stamp_ns``): the hub times it by that, so a
duration is the sender's, not the link's delivery jitter; an unstamped event is timed by when
the hub receives it (a bag's events are timed by its receive time, one clock with its points).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from rapidds.bridge.faults import CLOCK_SKEW, FaultLog
from rapidds.bridge.link import Received, StampGate, log
from rapidds.bridge.ros2 import EVENTS_TOPIC, MessageError, parse_event, plan_payload, stamp_ns
from rapidds.loop.observation import Track, execution_of
from rapidds.worlds.bounds import Plausibility, mostly_implausible

if TYPE_CHECKING:
    from rapidds.problem import Problem
    from rapidds.schedule import Item
    from rapidds.worlds.base import HumanExecution

__all__ = [
    "CONTACTS_TOPIC",
    "SPEED_SCALING_TOPIC",
    "STOP_TOPIC",
    "TRACKING_PREFIX",
    "CycleObservation",
    "LivePlan",
    "live_plan_payload",
    "stop_payload",
    "stop_words",
    "tracking_topic",
]

STOP_TOPIC = "/rapidds/stop"
"""``std_msgs/msg/String`` JSON ``{"cycle", "reason", "sender"}``: every node stops the cycle now
(any message on it stops: a stop is never dropped for its form); the hub too, when it did not
send it: the cycle ends as a fault naming the stop's stated reason and sender."""
CONTACTS_TOPIC = "/rapidds/robot/contacts"
"""``std_msgs/msg/String`` JSON ``{"robot", "person", "depth"}``: the arm touched the person."""
SPEED_SCALING_TOPIC = "/rapidds/robot/speed_scaling"
"""``std_msgs/msg/Float64`` in [0, 1]: the fraction of its trajectory's planned speed the robot
may move at now (0 holds it where it is on its path, 1 is as planned); sent by a hub under
reactive execution at a fixed rate of the cell clock (see docs/design-notes.md)."""
MAX_TIME_SCALE = 1000.0
"""Fastest cell clock a plan may ask of the nodes (the tests run at 4; a real cell at 1)."""
MAX_DT = 10.0
"""Longest trajectory row a plan may name, s (the worlds here: 0.15-0.2 s)."""
MAX_TRACKING_RATE = 1000.0
"""Samples per cell second a body point may bring into a cycle (a tracker at 10x any real
rate): the rest are dropped, so a flood cannot grow the hub's memory past
``cycle_timeout x MAX_TRACKING_RATE`` samples per point."""
TRACKING_PREFIX = "/rapidds/human/"
"""``geometry_msgs/msg/PointStamped`` per body point on ``/rapidds/human/<body point>``."""


def tracking_topic(point: str) -> str:
    return TRACKING_PREFIX + point


def stop_payload(cycle: int, reason: str, sender: str) -> dict[str, Any]:
    """``/rapidds/stop``'s JSON: the cycle, why, who sends it (``hub``, a node's name)."""
    return {"cycle": int(cycle), "reason": reason, "sender": sender}


def stop_words(text: str) -> tuple[str, str]:
    """The stated reason and sender of a stop message, each one short printable line ("no
    reason given", "an unnamed peer" where the message does not say: it stops all the same)."""
    try:
        raw = json.loads(text)
    except (ValueError, RecursionError):
        raw = None
    said = raw if isinstance(raw, dict) else {}

    def line(value: object, default: str) -> str:
        words = "".join(c if c.isprintable() else " " for c in str(value or "")).strip()
        return (words[:120] + "..." if len(words) > 120 else words) or default

    return line(said.get("reason"), "no reason given"), line(said.get("sender"),
                                                             "an unnamed peer")


def live_plan_payload(problem: Problem, cycle: int, human: Sequence[Item], robot: Sequence[Item],
                      expected: Mapping[str, tuple[float, float]], *, start_ns: int,
                      time_scale: float, dt: float) -> dict[str, Any]:
    """``/rapidds/plan`` for a live cycle: :func:`~rapidds.bridge.ros2.plan_payload` plus what a
    node needs to act on its own: ``after`` (task -> every task that must end before it
    starts: precedence, the agent's previous task, its waits), ``stamp_ns``, ``time_scale``
    and ``dt`` (seconds per trajectory and path row)."""
    payload = plan_payload(cycle, human, robot, expected)
    after: dict[str, list[str]] = {}
    for agent, order in payload["order"].items():
        for i, task in enumerate(order):
            need = set(problem.preceding[task])
            if i:
                need.add(order[i - 1])
            need.update(w["for"] for w in payload["waits"]
                        if w["agent"] == agent and w["before"] == i)
            after[task] = sorted(need)
    payload.update(after=after, stamp_ns=int(start_ns), time_scale=float(time_scale),
                   dt=float(dt))
    return payload


@dataclass(frozen=True)
class LivePlan:
    """A received ``/rapidds/plan`` (validated)."""

    cycle: int
    order: dict[str, list[str]]
    after: dict[str, list[str]]
    stamp_ns: int
    time_scale: float
    dt: float

    @classmethod
    def parse(cls, text: str) -> LivePlan:
        try:
            raw = json.loads(text)
            order = {a: [str(t) for t in raw["order"][a]] for a in ("human", "robot")}
            after = {str(t): [str(x) for x in v] for t, v in raw["after"].items()}
            plan = cls(int(raw["cycle"]), order, after, int(raw["stamp_ns"]),
                       float(raw["time_scale"]), float(raw["dt"]))
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            raise MessageError(f"not a live plan: {str(exc)[:120]}") from exc
        tasks = [t for o in order.values() for t in o]
        if not (0 < plan.time_scale <= MAX_TIME_SCALE and 0 < plan.dt <= MAX_DT
                and 0 <= plan.stamp_ns < 2**63) or set(after) != set(tasks) \
                or any(x not in after for v in after.values() for x in v):
            raise MessageError(f"not a live plan: time_scale must be in (0, {MAX_TIME_SCALE:g}], "
                               f"dt in (0, {MAX_DT:g}] s, stamp_ns int64 ns >= 0, and 'after' "
                               "must name the plan's tasks")
        return plan

    @property
    def agent(self) -> dict[str, str]:
        return {t: a for a, o in self.order.items() for t in o}

    def cell_seconds(self, ns: int) -> float:
        """Cell time (s since the cycle's start) of a wall-clock stamp."""
        return (ns - self.stamp_ns) * self.time_scale / 1e9

    def wall_ns(self, seconds: float) -> int:
        """The wall-clock stamp of cell time ``seconds``."""
        return self.stamp_ns + round(seconds / self.time_scale * 1e9)


@dataclass
class CycleObservation:
    """What the hub saw in one cycle: task starts and ends (cell s), the person's tracked body
    points, the robot's contacts. Bad input is dropped and counted in ``faults`` (one line
    each, up to its limit per kind): an event that is malformed, names a task not in the plan
    or the wrong agent, comes out of order (an end before its start, a second start or end), is
    stamped outside the cycle's window (``-CLOCK_SKEW`` wall s .. ``window`` cell s, and never
    more than ``CLOCK_SKEW`` ahead of its arrival) or ends a person's task longer than
    ``task_bound`` cell s; a tracking sample older than its source's last, stamped ahead of
    its arrival, or implausible (``plausible``: :mod:`rapidds.worlds.bounds`; one line per
    body point). ``gate``: the hub passes one for the whole run, so a sample from before the
    last one accepted is dropped at a cycle's start too, not taken as its first. ``may_take``:
    which robot tasks the person may take (the hub's: ones it has not sent that the person may
    do); a start of one by the person is theirs from then on (``taken``, :meth:`doer`)."""

    plan: LivePlan
    points: tuple[str, ...]
    start: dict[str, float] = field(default_factory=dict)
    end: dict[str, float] = field(default_factory=dict)
    contacts: list[dict[str, Any]] = field(default_factory=list)
    gate: StampGate = field(default_factory=StampGate)
    window: float = math.inf
    task_bound: float = math.inf
    plausible: Plausibility | None = None
    faults: FaultLog = field(default_factory=FaultLog)
    may_take: Callable[[str], bool] | None = None
    taken: set[str] = field(default_factory=set)  # robot tasks the person started instead
    _tracks: dict[str, list[tuple[float, np.ndarray]]] = field(default_factory=dict)
    _implausible: dict[str, list[float]] = field(default_factory=dict)  # cell s of drops

    @property
    def done(self) -> bool:
        return set(self.end) == set(self.plan.agent)

    def _drop_event(self, kind: str, why: str, *args: object) -> None:
        self.faults.warn(kind, "dropped " + why, *args)

    def event(self, rec: Received) -> None:
        try:
            ev = parse_event(rec.msg.data)
        except MessageError as exc:
            self._drop_event("malformed event", "an event: %s", str(exc)[:200])
            return
        agent = self.doer(ev.task)
        stamp = rec.received_ns if ev.stamp_ns is None else ev.stamp_ns
        t = self.plan.cell_seconds(stamp)
        if (agent == "robot" and ev.agent == "human" and ev.event == "start"
                and ev.task not in self.start and self.may_take is not None
                and self.may_take(ev.task)):
            agent = "human"  # the person takes a robot task the hub has not sent
        if agent is None or agent != ev.agent:
            self._drop_event("event not in the plan", "an event of %s task %r: not in cycle "
                             "%d's plan for that agent", ev.agent, ev.task[:80], self.plan.cycle)
        elif (why := self._outside(stamp, rec.received_ns, t)) is not None:
            self._drop_event("event out of window", "the %s of %r: %s", ev.event, ev.task, why)
        elif ev.event == "start" and ev.task in self.start:
            self._drop_event("event out of order", "a second start of %r", ev.task)
        elif ev.event == "end" and (ev.task not in self.start or ev.task in self.end
                                    or t < self.start[ev.task]):
            self._drop_event("event out of order", "an end of %r: %s", ev.task,
                             "it has ended" if ev.task in self.end else "it never started"
                             if ev.task not in self.start else "stamped before its start")
        elif ev.event == "end" and agent == "human" \
                and t - self.start[ev.task] > self.task_bound:
            self._drop_event("task too long", "an end of %r: %.3g s after its start, longer "
                             "than any task of this world (%g s)", ev.task,
                             t - self.start[ev.task], self.task_bound)
        else:
            if agent != self.plan.agent.get(ev.task):
                self.taken.add(ev.task)
            (self.start if ev.event == "start" else self.end)[ev.task] = t
            log.info("cycle %d: %s %s %s at %.2f s", self.plan.cycle, ev.agent, ev.task,
                     ev.event, t)

    def _outside(self, stamp: int, received: int, t: float) -> str | None:
        """Why a stamp is outside the cycle's window (None: inside): ahead of its arrival, or
        before the cycle's start, by more than ``CLOCK_SKEW``; past ``window``."""
        if (stamp - received) / 1e9 > CLOCK_SKEW:
            return f"stamped {(stamp - received) / 1e9:.3g} s ahead of its arrival"
        if t < -CLOCK_SKEW * self.plan.time_scale:
            return f"stamped {-t:.3g} s before the cycle's start"
        if t > self.window:
            return f"stamped at {t:.3g} s, after the cycle's {self.window:g} s"
        return None

    def track(self, rec: Received) -> None:
        name = rec.topic[len(TRACKING_PREFIX):]
        if name not in self.points:
            self.faults.warn("unknown body point", "dropped tracking of unknown body point %r",
                             name[:80])
            return
        ns = stamp_ns(rec.msg.header)
        if (ns - rec.received_ns) / 1e9 > CLOCK_SKEW:  # before the gate: it would block the rest
            self.faults.warn("tracking ahead", "dropped tracking of %r stamped %.3g s ahead of "
                             "its arrival", name, (ns - rec.received_ns) / 1e9)
            return
        if not self.gate.accept(rec.topic, ns):
            return
        p = rec.msg.point
        pos = np.array([p.x, p.y, p.z], dtype=float)
        if not np.isfinite(pos).all():
            self.faults.warn("not finite", "dropped tracking of %r: not finite", name)
            return
        track = self._tracks.setdefault(name, [])
        drops = self._implausible.setdefault(name, [])
        if len(track) + len(drops) >= max(self.window, 1.0) * MAX_TRACKING_RATE:
            self.faults.warn("tracking flood", "dropped tracking of %r: over %g samples a "
                             "second", name, MAX_TRACKING_RATE)
            return
        t = self.plan.cell_seconds(ns)
        why = None if self.plausible is None else self.plausible.check(name, t, pos)
        if why is not None:
            self.faults.warn(f"implausible {name}", "dropped implausible tracking of %r at "
                             "%.2f s: %s", name, t, why, lines=1)
            drops.append(t)
            return
        track.append((t, pos))

    def handle(self, rec: Received) -> None:
        """Route a received message to its handler (events, tracking); others are ignored."""
        if rec.topic == EVENTS_TOPIC:
            self.event(rec)
        elif rec.topic.startswith(TRACKING_PREFIX):
            self.track(rec)

    def latest(self) -> tuple[np.ndarray, float, float] | None:
        """Each body point's last tracked position (P, 3), the person's speed (the fastest
        point between its last two samples, by their stamps: the tracker's rate, not the
        reader's) and the cell time of the oldest point's last sample; None until every
        point is tracked."""
        if not all(self._tracks.get(n) for n in self.points):
            return None
        speed = 0.0
        for n in self.points:
            track = self._tracks[n]
            if len(track) > 1 and track[-1][0] > track[-2][0]:
                step = float(np.linalg.norm(track[-1][1] - track[-2][1]))
                speed = max(speed, step / (track[-1][0] - track[-2][0]))
        return (np.stack([self._tracks[n][-1][1] for n in self.points]), speed,
                min(self._tracks[n][-1][0] for n in self.points))

    def velocities(self) -> np.ndarray | None:
        """Each body point's velocity (P, 3) between its last two samples, by their stamps (0
        for a point with one sample); None until every point is tracked. For the person's
        speed towards the robot (ISO/TS 15066's directed v_h)."""
        if not all(self._tracks.get(n) for n in self.points):
            return None
        out = np.zeros((len(self.points), 3))
        for k, n in enumerate(self.points):
            track = self._tracks[n]
            if len(track) > 1 and track[-1][0] > track[-2][0]:
                out[k] = (track[-1][1] - track[-2][1]) / (track[-1][0] - track[-2][0])
        return out

    def tracked_past(self, t: float) -> bool:
        """Every body point has a sample stamped at cell time ``t`` or later."""
        return all(self._tracks.get(n) and self._tracks[n][-1][0] >= t for n in self.points)

    def doer(self, task: str) -> str | None:
        """Who does ``task``: the plan's agent, the person for a robot task they took."""
        return "human" if task in self.taken else self.plan.agent.get(task)

    def durations(self, agent: str) -> dict[str, float]:
        return {t: self.end[t] - self.start[t] for t in self.plan.agent
                if self.doer(t) == agent and t in self.end}

    def human_executions(self, dt: float) -> dict[str, HumanExecution]:
        """The person's tasks as the loop takes them: duration from the events, path (T, K, 3)
        from the tracking (:func:`~rapidds.loop.observation.execution_of`)."""
        out = {}
        for task, d in self.durations("human").items():
            self._check_plausible(task)
            out[task] = execution_of(task, self.start[task], float(d),
                                     self._task_tracks(task, self.start[task] + d, dt), dt)
        return out

    def _check_plausible(self, task: str) -> None:
        """MessageError when a body point's samples during ``task`` were mostly implausible:
        the task would not be learned as the person did it."""
        t0, t1 = self.start[task], self.end[task]
        for name in self.points:
            dropped = sum(t0 <= t <= t1 for t in self._implausible.get(name, ()))
            kept = sum(t0 <= t <= t1 for t, _ in self._tracks.get(name, ()))
            if dropped and mostly_implausible(kept, dropped):
                raise MessageError(f"the tracking of {name} during {task} was mostly "
                                   f"implausible ({dropped} of {dropped + kept} samples "
                                   "dropped); the task cannot be learned")

    def _task_tracks(self, task: str, end: float, dt: float) -> list[Track]:
        """Each body point's samples; MessageError when one has none near ``task``."""
        out = []
        for name in self.points:
            track = self._tracks.get(name, [])
            t = np.array([s for s, _ in track])
            near = ((t >= self.start[task] - dt) & (t <= end + dt) if track
                    else np.zeros(0, bool))
            if not near.any():
                raise MessageError(f"no tracking of {name} during {task}")
            out.append(Track(t, np.stack([p for _, p in track])))
        return out


def joint_rows(names: Iterable[str], known: Sequence[str]) -> list[int] | None:
    """Row of each of ``known`` in a message's joint ``names``; None when one is missing."""
    index = {n: i for i, n in enumerate(names)}
    rows = [index.get(n) for n in known]
    return None if any(r is None for r in rows) else [int(r) for r in rows if r is not None]
