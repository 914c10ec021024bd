"""The reference robot: a world's arm under MuJoCo physics on the live link.

It takes ``trajectory_msgs/JointTrajectory`` on ``/rapidds/robot/trajectory`` (started at the
header stamp, or on arrival when that has passed; one queued behind the other), runs them with
:class:`~rapidds.bridge.nodes.arm.PhysicsArm` in control periods of 1/``rate`` simulated s,
publishes ``sensor_msgs/JointState`` after each pass (every period while the machine keeps
up), the robot's task events (a trajectory is the task its header's frame_id names, else the
k-th robot task of its plan) and every new touch of the arm on the person's bodies, whom it
places where the tracking says. ``/rapidds/stop`` holds the arm where it is and drops the
cycle's queue. ``/rapidds/robot/speed_scaling`` (``std_msgs/Float64`` in [0, 1]) sets the rate
at which the arm advances along its trajectory, as a speed slider does on a scaled trajectory
controller: at 0 it holds where it is on its path, it resumes when the value rises; a new plan
sets it back to 1 (a hub that does not monitor sends none). Watchdog: once a scaling has come
in a cycle, a silence of over :data:`~rapidds.bridge.failsafe.WATCHDOG` simulated s while a
trajectory runs holds the arm on its path (a monitor that died cannot slow it) until the next
scaling. Simulated time runs ``time_scale`` (from the plan) times faster than the wall.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rapidds.bridge.failsafe import WATCHDOG
from rapidds.bridge.link import Link, Received, StampGate, log
from rapidds.bridge.live import (
    CONTACTS_TOPIC,
    SPEED_SCALING_TOPIC,
    STOP_TOPIC,
    LivePlan,
    joint_rows,
    tracking_topic,
)
from rapidds.bridge.nodes.arm import PhysicsArm
from rapidds.bridge.profiles import DEFAULT_PROFILE, RobotProfile, robot_profile
from rapidds.bridge.ros2 import (
    EVENTS_TOPIC,
    JOINT_STATE_TOPIC,
    PLAN_TOPIC,
    TRAJECTORY_TOPIC,
    Event,
    MessageError,
    event_message,
    joint_state,
    stamp_ns,
    string_message,
    trajectory_positions,
)
from rapidds.errors import RapiddsError
from rapidds.worlds.base import World, body_point_names, joint_names
from rapidds.worlds.capabilities import capability, lacks

__all__ = ["SimRobot"]


@dataclass
class _Queued:
    task: str
    positions: np.ndarray
    times: np.ndarray
    start_ns: int


@dataclass
class SimRobot:
    """The node's state; :meth:`spin` runs it until ``until`` (wall s) or forever."""

    world: World
    link: Link
    rate: float = 100.0
    profile: RobotProfile = field(default_factory=lambda: robot_profile(DEFAULT_PROFILE))
    arm: PhysicsArm = field(init=False)
    plan: LivePlan | None = None
    _tasks: deque[str] = field(default_factory=deque)
    _queue: deque[_Queued] = field(default_factory=deque)
    _current: str | None = None
    _began: tuple[int, float] = (0, 0.0)  # the current task's start: wall ns, simulated s
    _people: dict[str, np.ndarray] = field(default_factory=dict)
    _touching: set[tuple[str, str]] = field(default_factory=set)
    _gate: StampGate = field(default_factory=StampGate)
    _scaled_at: float | None = None  # monotonic s of this cycle's last speed scaling

    def __post_init__(self) -> None:
        physics = capability(self.world, "physics")
        if physics is None:
            raise RapiddsError(lacks(self.world, "physics"))
        self.joints = joint_names(self.world)  # the MJCF's; the driver's on the wire:
        self.driver = self.profile.joint_names(self.world)
        self.offset = self.profile.offset(self.world)
        self.points = body_point_names(self.world)
        self.arm = PhysicsArm(physics.physics_model(), self.joints)
        self.arm.reset(np.asarray(self.world.robot_rest(), dtype=float))
        self._place(np.asarray(self.world.human_rest(), dtype=float))

    @staticmethod
    def topics(points: tuple[str, ...]) -> dict[str, str]:
        string = "std_msgs/msg/String"
        return {PLAN_TOPIC: string, STOP_TOPIC: string,
                SPEED_SCALING_TOPIC: "std_msgs/msg/Float64",
                TRAJECTORY_TOPIC: "trajectory_msgs/msg/JointTrajectory",
                **{tracking_topic(p): "geometry_msgs/msg/PointStamped" for p in points}}

    @property
    def scale(self) -> float:
        return self.plan.time_scale if self.plan is not None else 1.0

    def _place(self, points: np.ndarray) -> None:
        physics = capability(self.world, "physics")
        if physics is not None:
            physics.place_person(self.arm.model, self.arm.data, points)

    def handle(self, rec: Received) -> None:
        if rec.topic == PLAN_TOPIC:
            try:
                self.plan = LivePlan.parse(rec.msg.data)
            except MessageError as exc:
                log.warning("sim-robot dropped a plan: %s", exc)
                return
            self._tasks = deque(self.plan.order["robot"])
            self._queue.clear()
            self.arm.speed = 1.0
            self._scaled_at = None  # the watchdog arms at this cycle's first scaling
        elif rec.topic == SPEED_SCALING_TOPIC:
            value = float(rec.msg.data)
            if not np.isfinite(value):
                log.warning("sim-robot dropped a speed scaling that is not finite")
                return
            self.arm.speed = min(max(value, 0.0), 1.0)
            self._scaled_at = time.monotonic()
        elif rec.topic == STOP_TOPIC:
            log.warning("sim-robot: stop (%s)", rec.msg.data[:120])
            self.plan, self._current = None, None
            self._tasks.clear()
            self._queue.clear()
            self.arm.hold()
        elif rec.topic == TRAJECTORY_TOPIC:
            self._trajectory(rec.msg)
        elif self._gate.accept(rec.topic, stamp_ns(rec.msg.header)):
            p = rec.msg.point
            self._people[rec.topic] = np.array([p.x, p.y, p.z])
            if len(self._people) == len(self.points):
                self._place(np.stack([self._people[tracking_topic(n)] for n in self.points]))

    def _trajectory(self, msg: Any) -> None:
        names, q, t = trajectory_positions(msg)
        rows = joint_rows(names, self.driver)
        if rows is None or not len(t) or not np.isfinite(q).all() or np.any(np.diff(t) < 0):
            log.warning("sim-robot dropped a trajectory: joints %s, %d points", names, len(t))
            return
        if self.plan is None or not self._tasks:
            log.warning("sim-robot dropped a trajectory: no robot task is left in the plan")
            return
        named = msg.header.frame_id  # the hub names the task (its order may be re-planned)
        if named in self._tasks:
            self._tasks.remove(named)
            task = named
        else:
            task = self._tasks.popleft()
        self._queue.append(_Queued(task, q[:, rows] - self.offset, t, stamp_ns(msg.header)))

    def _event(self, task: str, kind: str, stamp: int) -> None:
        self.link.publish(EVENTS_TOPIC, event_message(Event(task, "robot", kind, stamp)))  # type: ignore[arg-type]

    def _watchdog(self) -> None:
        """Hold the arm when the monitor's scaling has been silent for over WATCHDOG simulated
        s while a trajectory runs (once per silence)."""
        if self._scaled_at is None or self._current is None or self.arm.speed == 0.0:
            return
        silent = (time.monotonic() - self._scaled_at) * self.scale
        if silent > WATCHDOG:
            log.warning("sim-robot: no speed scaling for %.2f s (watchdog %g s); holding",
                        silent, WATCHDOG)
            self.arm.speed = 0.0

    def _control(self) -> None:
        """One control period: start a due trajectory, step the physics, report its events and
        new touches."""
        self._watchdog()
        now = time.time_ns()
        if self._current is None and self._queue and now >= self._queue[0].start_ns:
            job = self._queue.popleft()
            self.arm.follow(job.positions, job.times)
            self._current, self._began = job.task, (now, self.arm.time)
            self._event(job.task, "start", now)
        self.arm.step(1.0 / self.rate)
        if self._current is not None and self.arm.settled():
            # stamped on the simulated clock: the task took what the physics took, however
            # late this process got there
            wall, sim = self._began
            self._event(self._current, "end",
                        wall + round((self.arm.time - sim) / self.scale * 1e9))
            self._current = None
        touching = set()
        for touch in self.arm.touches():
            key = (touch.robot, touch.person)
            touching.add(key)
            if key not in self._touching:
                self.link.publish(CONTACTS_TOPIC, string_message(
                    {"robot": touch.robot, "person": touch.person, "depth": touch.depth}))
        self._touching = touching

    def tick(self) -> None:
        """One control period, then the joint state."""
        self._control()
        self.link.publish(JOINT_STATE_TOPIC, joint_state(self.driver, self.arm.q + self.offset,
                                                         self.arm.qdot, stamp_ns=time.time_ns()))

    def spin(self, until: float | None = None) -> None:
        """Run in (scaled) real time: the physics keeps to the cell's clock in control periods
        of 1/rate simulated seconds, and a joint state goes out after each pass. A process
        that falls behind (a loaded machine) catches up on physics alone, one joint state per
        pass, so the robot's motions take the cell's time, not the CPU's; a lag over a second
        (the process was stopped) is dropped, not raced through."""
        last = time.monotonic()
        owed = 0.0  # control periods due
        while until is None or time.monotonic() < until:
            for rec in self.link.drain():
                self.handle(rec)
            now = time.monotonic()
            owed = min(owed + (now - last) * self.scale * self.rate, self.rate * self.scale)
            last = now
            if owed < 1.0:
                time.sleep((1.0 - owed) / (self.rate * self.scale))
                continue
            n = min(int(owed), max(1, round(0.05 * self.rate)))  # 50 ms, then read the link
            for _ in range(n - 1):
                self._control()
            self.tick()
            owed -= n
