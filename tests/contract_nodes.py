"""A lab's nodes written from README's wire contract ("Live link") with eclipse-zenoh and
rosbags' CDR only, not from rapidds's node classes or link: keys are the ROS 2 topic without
its leading slash, payloads CDR, stamps wall-clock ns, the plan JSON's ``order``, ``after``,
``stamp_ns``, ``time_scale`` and ``dt`` as README describes them.

- :class:`Driver`: a joint trajectory driver publishing ``sensor_msgs/JointState`` at 100 Hz
  under the names it is given, playing each received ``JointTrajectory`` (the k-th of a cycle is
  the plan's k-th robot task) and announcing its start and end; ``obey=False`` ignores the speed
  scaling, as a stock joint trajectory controller does.
- :class:`Tracker`: publishes ``geometry_msgs/PointStamped`` for the body points it is given
  (all, or some), until muted.
- :class:`Hub`: the hub's side, listening, for a robot node under test.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)
_T = TS.types


def _session(*, connect: str | None = None, listen: str | None = None) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"' if listen else '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps([connect]))
        conf.insert_json5("connect/timeout_ms", "-1")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps([listen]))
    return zenoh.open(conf)


def cdr(msg: Any) -> bytes:
    return bytes(TS.serialize_cdr(msg, msg.__msgtype__))


def decode(sample: Any, kind: str) -> Any:
    return TS.deserialize_cdr(sample.payload.to_bytes(), kind)


def _header(ns: int) -> Any:
    return _T["std_msgs/msg/Header"](
        stamp=_T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
        frame_id="world")


def string(data: str) -> Any:
    return _T["std_msgs/msg/String"](data=data)


def float64(value: float) -> Any:
    return _T["std_msgs/msg/Float64"](data=float(value))


def joint_state(names: Sequence[str], q: np.ndarray, ns: int) -> Any:
    empty = np.zeros(0, dtype=np.float64)
    return _T["sensor_msgs/msg/JointState"](header=_header(ns), name=list(names),
                                            position=np.asarray(q, np.float64),
                                            velocity=empty, effort=empty)


def point_stamped(xyz: np.ndarray, ns: int) -> Any:
    x, y, z = (float(v) for v in xyz)
    return _T["geometry_msgs/msg/PointStamped"](header=_header(ns),
                                                point=_T["geometry_msgs/msg/Point"](x=x, y=y, z=z))


def joint_trajectory(names: Sequence[str], q: np.ndarray, dt: float) -> Any:
    def duration(s: float) -> Any:
        ns = round(s * 1e9)
        return _T["builtin_interfaces/msg/Duration"](sec=ns // 10**9, nanosec=ns % 10**9)

    empty = np.zeros(0, dtype=np.float64)
    points = [_T["trajectory_msgs/msg/JointTrajectoryPoint"](
        positions=np.asarray(row, np.float64), velocities=empty, accelerations=empty,
        effort=empty, time_from_start=duration(k * dt)) for k, row in enumerate(q)]
    return _T["trajectory_msgs/msg/JointTrajectory"](header=_header(time.time_ns()),
                                                     joint_names=list(names), points=points)


class _Node(threading.Thread):
    """A session and a thread; callbacks queue what comes, the thread acts on it."""

    def __init__(self, endpoint: str, topics: dict[str, str]):
        super().__init__(daemon=True)
        self.session = _session(connect=endpoint)
        self.inbox: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.done = threading.Event()
        self._subs = [self.session.declare_subscriber(
            key, lambda s, k=key, t=kind: self.inbox.put((k, decode(s, t))))
            for key, kind in topics.items()]

    def put(self, key: str, msg: Any) -> None:
        self.session.put(key, cdr(msg))

    def close(self) -> None:
        self.done.set()
        self.join(5)
        for s in self._subs:
            s.undeclare()
        self.session.close()


class Driver(_Node):
    """The robot: at rest at ``rest`` under joint ``names`` until trajectories come."""

    def __init__(self, endpoint: str, names: Sequence[str], rest: np.ndarray, *,
                 obey: bool = True, rate: float = 100.0):
        super().__init__(endpoint, {
            "rapidds/plan": "std_msgs/msg/String",
            "rapidds/robot/trajectory": "trajectory_msgs/msg/JointTrajectory",
            "rapidds/robot/speed_scaling": "std_msgs/msg/Float64",
            "rapidds/stop": "std_msgs/msg/String"})
        self.names, self.q, self.obey, self.rate = list(names), np.asarray(rest, float), obey, rate
        self.plan: dict[str, Any] | None = None
        self.tasks: list[str] = []
        self.queue: list[tuple[str, np.ndarray, np.ndarray]] = []
        self.current: tuple[str, np.ndarray, np.ndarray] | None = None
        self.progress = 0.0  # trajectory seconds done
        self.scaling = 1.0
        self.scalings: list[float] = []  # every one received after the first task started
        self.stops: list[dict[str, Any]] = []
        self.started = threading.Event()
        self.on_start: Callable[[], None] = lambda: None

    def _handle(self, key: str, msg: Any) -> None:
        if key == "rapidds/plan":
            self.plan = json.loads(msg.data)
            self.tasks, self.queue, self.scaling = list(self.plan["order"]["robot"]), [], 1.0
        elif key == "rapidds/robot/speed_scaling":
            self.scaling = min(max(float(msg.data), 0.0), 1.0)
            if self.started.is_set():
                self.scalings.append(self.scaling)
        elif key == "rapidds/stop":
            self.stops.append(json.loads(msg.data))
            self.current, self.queue = None, []
        elif key == "rapidds/robot/trajectory" and self.tasks:
            rows = [list(msg.joint_names).index(n) for n in self.names]
            q = np.stack([np.asarray(p.positions)[rows] for p in msg.points])
            t = np.array([p.time_from_start.sec + p.time_from_start.nanosec / 1e9
                          for p in msg.points])
            self.queue.append((self.tasks.pop(0), q, t))

    def _event(self, task: str, kind: str) -> None:
        self.put("rapidds/events", string(json.dumps(
            {"task": task, "agent": "robot", "event": kind, "stamp_ns": time.time_ns()})))

    def run(self) -> None:
        last = time.monotonic()
        while not self.done.is_set():
            while not self.inbox.empty():
                self._handle(*self.inbox.get())
            now = time.monotonic()
            scale = self.plan["time_scale"] if self.plan else 1.0
            step, last = (now - last) * scale, now
            if self.current is None and self.queue:
                self.current, self.progress = self.queue.pop(0), 0.0
                self._event(self.current[0], "start")
                self.started.set()
                self.on_start()
            elif self.current is not None:
                task, q, t = self.current
                self.progress += step * (self.scaling if self.obey else 1.0)
                self.q = np.array([np.interp(self.progress, t, q[:, j])
                                   for j in range(q.shape[1])])
                if self.progress >= t[-1]:
                    self._event(task, "end")
                    self.current = None
            self.put("rapidds/robot/joint_states", joint_state(self.names, self.q,
                                                               time.time_ns()))
            time.sleep(1.0 / self.rate)


class Tracker(_Node):
    """The person's tracker: each of ``points`` (body point -> world position) every
    ``period`` wall s, until ``mute`` is set."""

    def __init__(self, endpoint: str, points: dict[str, np.ndarray], period: float = 0.02):
        super().__init__(endpoint, {})
        self.points, self.period = points, period
        self.mute = threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            if not self.mute.is_set():
                ns = time.time_ns()
                for name, xyz in self.points.items():
                    self.put(f"rapidds/human/{name}", point_stamped(xyz, ns))
            time.sleep(self.period)


class Hub:
    """The hub's end of the link (a Zenoh router) for a robot node under test: keeps the joint
    states and events that come."""

    def __init__(self, endpoint: str):
        self.session = _session(listen=endpoint)
        self.states: list[tuple[int, np.ndarray]] = []  # (header stamp ns, positions)
        self.events: list[dict[str, Any]] = []
        self._subs = [
            self.session.declare_subscriber("rapidds/robot/joint_states", self._state),
            self.session.declare_subscriber("rapidds/events", lambda s: self.events.append(
                json.loads(decode(s, "std_msgs/msg/String").data)))]

    def _state(self, sample: Any) -> None:
        msg = decode(sample, "sensor_msgs/msg/JointState")
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        self.states.append((stamp, np.asarray(msg.position)))

    def put(self, key: str, msg: Any) -> None:
        self.session.put(key, cdr(msg))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()
