"""ROS 2 messages without ROS 2: build, serialise (CDR) and read the messages rapidds exchanges
with a real cell, through ``rosbags``' ROS 2 Jazzy type store.

Units and frames follow REP-103 (metres, seconds, right-handed, z up). Times are nanoseconds
since the cycle's start unless a caller passes another epoch. Nothing here knows a world by name:
joint names and body-point names come from the caller (the world).

The default contract (topics and the JSON of task events) lives here so that the bag reader, the
exporter and the live link speak one language.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from rapidds.settings import error_line

if TYPE_CHECKING:
    from rapidds.schedule import Item

__all__ = [
    "EVENTS_TOPIC",
    "JOINT_STATE_TOPIC",
    "PLAN_TOPIC",
    "TOO_CLOSE_TOPIC",
    "TRAJECTORY_TOPIC",
    "Event",
    "MessageError",
    "TrackedPoint",
    "deserialize",
    "event_message",
    "float64_message",
    "header",
    "joint_state",
    "joint_trajectory",
    "parse_event",
    "point_cloud",
    "serialize",
    "string_message",
    "tracked_points",
    "typestore",
    "zenoh_key",
]

TRAJECTORY_TOPIC = "/rapidds/robot/trajectory"
"""``trajectory_msgs/msg/JointTrajectory``, one per robot task."""
PLAN_TOPIC = "/rapidds/plan"
"""``std_msgs/msg/String``: the schedule as JSON."""
EVENTS_TOPIC = "/rapidds/events"
"""``std_msgs/msg/String``: task events as JSON ``{"task", "agent", "event"}``."""
JOINT_STATE_TOPIC = "/rapidds/robot/joint_states"
"""``sensor_msgs/msg/JointState`` of the robot, at the controller's rate."""
TOO_CLOSE_TOPIC = "/rapidds/human/too_close"
"""``std_msgs/msg/Empty`` or ``std_msgs/msg/String`` (content ignored): the person says the
robot is too close now (a button, a spoken word); timed by the bag's receive time."""

Agent = Literal["human", "robot"]


class MessageError(ValueError):
    """A message that does not follow the contract (malformed JSON, unknown fields, NaN)."""


@cache
def typestore() -> Any:
    """The ROS 2 Jazzy type store (built once: it holds every standard message class)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _type(name: str) -> Any:
    return typestore().types[name]


def serialize(msg: Any) -> bytes:
    """CDR bytes of a message built here (little-endian, as ROS 2 writes)."""
    return bytes(typestore().serialize_cdr(msg, msg.__msgtype__))


def deserialize(data: bytes, msgtype: str) -> Any:
    """The message of type ``msgtype`` in CDR ``data``; :class:`MessageError` when it is not."""
    try:
        return typestore().deserialize_cdr(bytes(data), msgtype)
    except Exception as exc:  # rosbags raises several types for truncated or foreign bytes
        raise MessageError(f"not a {msgtype}: {exc}") from exc


def _time(ns: int) -> Any:
    return _type("builtin_interfaces/msg/Time")(sec=int(ns // 1_000_000_000),
                                                 nanosec=int(ns % 1_000_000_000))


def _duration(seconds: float) -> Any:
    ns = round(seconds * 1e9)
    return _type("builtin_interfaces/msg/Duration")(sec=int(ns // 1_000_000_000),
                                                     nanosec=int(ns % 1_000_000_000))


def _header(stamp_ns: int, frame_id: str = "world") -> Any:
    return _type("std_msgs/msg/Header")(stamp=_time(stamp_ns), frame_id=frame_id)


def header(stamp_ns: int, frame_id: str = "world") -> Any:
    """``std_msgs/msg/Header`` stamped ``stamp_ns`` in ``frame_id``."""
    return _header(stamp_ns, frame_id)


def stamp_ns(header: Any) -> int:
    """A header's stamp in nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def joint_trajectory(joint_names: Sequence[str], positions: np.ndarray, dt: float,
                     stamp_ns: int = 0, frame_id: str = "world", *,
                     times: np.ndarray | None = None, velocities: np.ndarray | None = None,
                     accelerations: np.ndarray | None = None) -> Any:
    """``trajectory_msgs/msg/JointTrajectory``: row k of ``positions`` (H, J) reached at
    ``times[k]`` (default ``k * dt``) after the header stamp (the time the motion is to start),
    with its ``velocities`` and ``accelerations`` (H, J) when given (a parameterized
    trajectory, :mod:`rapidds.motion.timing`)."""
    q = np.asarray(positions, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(joint_names):
        raise MessageError(f"positions must be (H, {len(joint_names)}), got {q.shape}")
    t = np.arange(len(q)) * dt if times is None else np.asarray(times, dtype=float)
    empty = np.zeros((len(q), 0), dtype=np.float64)
    v = empty if velocities is None else np.asarray(velocities, dtype=np.float64)
    a = empty if accelerations is None else np.asarray(accelerations, dtype=np.float64)
    if t.shape != (len(q),) or any(x.shape[0] != len(q) for x in (v, a)):
        raise MessageError("times, velocities and accelerations need one row per position")
    if not (np.isfinite(q).all() and np.isfinite(v).all() and np.isfinite(a).all()
            and np.isfinite(t).all()):
        raise MessageError("a trajectory with NaN or infinite positions")
    point = _type("trajectory_msgs/msg/JointTrajectoryPoint")
    return _type("trajectory_msgs/msg/JointTrajectory")(
        header=_header(stamp_ns, frame_id), joint_names=list(joint_names),
        points=[point(positions=q[k].copy(), velocities=v[k].copy(),
                      accelerations=a[k].copy(), effort=empty[k].copy(),
                      time_from_start=_duration(float(t[k]))) for k in range(len(q))])


def trajectory_positions(msg: Any) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(joint names, positions (H, J), times from start (H,) s) of a JointTrajectory."""
    q = np.array([np.asarray(p.positions, dtype=float) for p in msg.points])
    t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
    return list(msg.joint_names), q.reshape(len(msg.points), len(msg.joint_names)), t


def joint_state(joint_names: Sequence[str], position: np.ndarray,
                velocity: np.ndarray | None = None, stamp_ns: int = 0) -> Any:
    """``sensor_msgs/msg/JointState`` (no effort)."""
    empty = np.zeros(0, dtype=np.float64)
    return _type("sensor_msgs/msg/JointState")(
        header=_header(stamp_ns, ""), name=list(joint_names),
        position=np.asarray(position, dtype=np.float64),
        velocity=empty if velocity is None else np.asarray(velocity, dtype=np.float64),
        effort=empty)


def float64_message(value: float) -> Any:
    """``std_msgs/msg/Float64`` holding ``value``."""
    return _type("std_msgs/msg/Float64")(data=float(value))


def string_message(payload: Any) -> Any:
    """``std_msgs/msg/String`` holding ``payload`` as JSON (NaN refused: JSON has none)."""
    try:
        text = json.dumps(payload, allow_nan=False, separators=(",", ":"))
    except ValueError as exc:
        raise MessageError(f"cannot send as JSON: {exc}") from exc
    return _type("std_msgs/msg/String")(data=text)


@dataclass(frozen=True)
class Event:
    """A task starts or ends: the contract of ``/rapidds/events``. ``stamp_ns`` (optional):
    when it happened, on the sender's clock (wall ns, as tracking stamps are); the live hub
    times a stamped event by it, an unstamped one by its arrival."""

    task: str
    agent: Agent
    event: Literal["start", "end"]
    stamp_ns: int | None = None


class _EventJson(BaseModel):
    """The JSON of an :class:`Event` as it travels (strict: a stamp of 1.5 or true is refused)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    task: str
    agent: Agent
    event: Literal["start", "end"]
    stamp_ns: Annotated[int, Field(ge=0)] | None = None


def event_message(event: Event) -> Any:
    stamp = {} if event.stamp_ns is None else {"stamp_ns": int(event.stamp_ns)}
    return string_message({"task": event.task, "agent": event.agent, "event": event.event,
                           **stamp})


def parse_event(text: str) -> Event:
    """An :class:`Event` from the JSON of an events message; :class:`MessageError` otherwise."""
    try:
        raw = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise MessageError(f"event is not JSON: {exc}") from exc
    try:
        e = _EventJson.model_validate(raw)
    except ValidationError as exc:
        raise MessageError(f"bad event {text[:80]!r}: {error_line(exc, with_input=True)} "
                           "(keys task, agent human|robot, event start|end, stamp_ns whole ns "
                           ">= 0)") from None
    return Event(e.task, e.agent, e.event, e.stamp_ns)


def point_cloud(points: np.ndarray, values: np.ndarray | None = None, value_name: str = "cost",
                stamp_ns: int = 0, frame_id: str = "world") -> Any:
    """``sensor_msgs/msg/PointCloud2`` of (N, 3) points with fields x, y, z (float32) and, given
    ``values`` (N,), a fourth float32 field ``value_name``. A 2-D workspace gets z = 0."""
    p = np.asarray(points, dtype=np.float32)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise MessageError(f"points must be (N, 2) or (N, 3), got {p.shape}")
    if p.shape[1] == 2:
        p = np.concatenate([p, np.zeros((len(p), 1), np.float32)], axis=1)
    names = ["x", "y", "z"]
    cols = [p]
    if values is not None:
        names.append(value_name)
        cols.append(np.asarray(values, dtype=np.float32).reshape(-1, 1))
    data = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    field = _type("sensor_msgs/msg/PointField")
    fields = [field(name=n, offset=4 * i, datatype=field.FLOAT32, count=1)
              for i, n in enumerate(names)]
    step = 4 * len(names)
    return _type("sensor_msgs/msg/PointCloud2")(
        header=_header(stamp_ns, frame_id), height=1, width=len(p), fields=fields,
        is_bigendian=False, point_step=step, row_step=step * len(p),
        data=np.frombuffer(data.tobytes(), dtype=np.uint8), is_dense=True)


def cloud_array(msg: Any) -> tuple[list[str], np.ndarray]:
    """(field names, (N, F) float array) of a PointCloud2 made of float32 fields."""
    names = [f.name for f in msg.fields]
    data = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(msg.width * msg.height, -1)
    return names, data.astype(float)


@dataclass(frozen=True)
class TrackedPoint:
    """One tracked position: the frame (or topic, for a message without child frames) it names,
    its header stamp (ns) and position (3,) in that message's parent frame."""

    name: str
    stamp_ns: int
    position: np.ndarray
    parent: str


def tracked_points(msg: Any, topic: str) -> Iterable[TrackedPoint]:
    """The positions in a tracking message: ``geometry_msgs`` PointStamped, PoseStamped,
    PoseArray (named ``topic/i``), or ``tf2_msgs/msg/TFMessage`` (named by child frame)."""
    kind = msg.__msgtype__
    if kind == "tf2_msgs/msg/TFMessage":
        for tf in msg.transforms:
            t = tf.transform.translation
            yield TrackedPoint(tf.child_frame_id, stamp_ns(tf.header),
                               np.array([t.x, t.y, t.z]), tf.header.frame_id)
    elif kind == "geometry_msgs/msg/PointStamped":
        p = msg.point
        yield TrackedPoint(topic, stamp_ns(msg.header), np.array([p.x, p.y, p.z]),
                           msg.header.frame_id)
    elif kind == "geometry_msgs/msg/PoseStamped":
        p = msg.pose.position
        yield TrackedPoint(topic, stamp_ns(msg.header), np.array([p.x, p.y, p.z]),
                           msg.header.frame_id)
    elif kind == "geometry_msgs/msg/PoseArray":
        for i, pose in enumerate(msg.poses):
            p = pose.position
            yield TrackedPoint(f"{topic}/{i}", stamp_ns(msg.header), np.array([p.x, p.y, p.z]),
                               msg.header.frame_id)
    else:
        raise MessageError(f"{kind} is not a tracking message")


def point_stamped(position: Sequence[float], stamp_ns: int = 0, frame_id: str = "world") -> Any:
    """``geometry_msgs/msg/PointStamped`` (what a simulated tracker publishes)."""
    x, y, z = [*map(float, position), 0.0, 0.0][:3]
    return _type("geometry_msgs/msg/PointStamped")(
        header=_header(stamp_ns, frame_id), point=_type("geometry_msgs/msg/Point")(x=x, y=y, z=z))


def zenoh_key(topic: str) -> str:
    """The Zenoh key zenoh-bridge-ros2dds gives a ROS 2 topic: ``/a/b`` -> ``a/b``."""
    return topic.strip("/")


def plan_payload(cycle: int, human: Sequence[Item], robot: Sequence[Item],
                 times: Mapping[str, tuple[float, float]]) -> dict[str, Any]:
    """The JSON of ``/rapidds/plan``: the cycle, each agent's tasks in order, its waits, and
    the tasks' start and end times (expected for a live plan, realised for a stored cycle)."""
    from rapidds.schedule import Wait

    out: dict[str, Any] = {"cycle": cycle, "agents": {}, "order": {}, "waits": []}
    for agent, items in (("human", human), ("robot", robot)):
        order = []
        for item in items:
            if isinstance(item, Wait):
                out["waits"].append({"agent": agent, "for": item.task, "before": len(order)})
            else:
                order.append(item)
                out["agents"][item] = agent
        out["order"][agent] = order
    out["tasks"] = sorted(out["agents"])
    out["times"] = {t: {"start": se[0], "end": se[1]} for t, se in times.items()}
    return out
